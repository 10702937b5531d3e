"""Vectorised decoding gives exactly what rosbags' deserialiser gives, for every layout and encoding."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.interfaces import Nodetype
from rosbags.typesys import get_types_from_msg

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.readers import fastdecode
from slamobs.pipeline.readers.container import open_log
from slamobs.pipeline.readers.decode import decode_rows
from slamobs.pipeline.readers.rows import LAYOUTS, stated_runs, stated_start
from slamobs.pipeline.readers.storage import RawBatch
from slamobs.pipeline.readers.fastdecode import FRAME_ID, DecodeError, decode, layout_paths, make_plan, read_rows
from slamobs.pipeline.readers.roles import topics_of
from slamobs.pipeline.simulate import make_typestore, simulate, write_log
from serialization import ENCODINGS, as_buffer, deserialize, serialize

#: frame ids of many lengths, empty and odd ones included (CDR pads after the string to 4 or 8 bytes)
FRAMES = ["", "a", "ab", "abc", "abcd", "imu_link", "base_link", "/odom", "x" * 13, "camera_optical_frame_left"]
PRIMITIVE_DTYPES = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
    "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
    "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64,
}  # fmt: skip
SPECIAL = [np.nan, np.inf, -np.inf, -0.0, 5e-324, 1.7976931348623157e308]


def _value(prim: str, rng: np.random.Generator) -> object:
    if prim == "bool":
        return bool(rng.integers(2))
    dtype = np.dtype(PRIMITIVE_DTYPES[prim])
    if dtype.kind == "f":
        if rng.random() < 0.2:  # a special value, the largest float32 for a float64 it cannot hold
            special = float(rng.choice(SPECIAL))
            most = float(np.finfo(dtype).max)
            return special if not np.isfinite(special) or abs(special) <= most else most
        return float(dtype.type(rng.normal() * 100))
    info = np.iinfo(dtype)
    return int(rng.integers(max(info.min, -(2**40)), min(info.max, 2**40), endpoint=True))


def _random(ts, msgtype: str, rng: np.random.Generator, strings: list[str]) -> object:
    """A message with random numbers (special floats included) and strings taken in turn from ``strings``."""
    fields = {}
    for name, (node, detail) in ts.fielddefs[msgtype][1]:
        if node == Nodetype.NAME:
            fields[name] = _random(ts, detail, rng, strings)
        elif node == Nodetype.BASE and detail[0] == "string":
            fields[name] = strings.pop(0) if strings else "s"
        elif node == Nodetype.BASE:
            fields[name] = _value(detail[0], rng)
        elif node == Nodetype.ARRAY:
            prim = detail[0][1][0]
            fields[name] = np.array([_value(prim, rng) for _ in range(detail[1])], dtype=PRIMITIVE_DTYPES[prim])
        else:
            fields[name] = np.zeros(0, dtype=PRIMITIVE_DTYPES.get(detail[0][1][0], np.uint8))
    return ts.types[msgtype](**fields)


def _batch(payloads: list[bytes], rng: np.random.Generator) -> RawBatch:
    """Payloads at random, unaligned offsets in one buffer (as in a decompressed chunk)."""
    data, starts, size = as_buffer(payloads, rng)
    n = len(payloads)
    return RawBatch(data, np.zeros(n, np.int64), np.arange(n), starts, size)


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("msgtype", sorted(LAYOUTS))
def test_identical_to_rosbags(msgtype, encoding):
    ts = make_typestore(ros1=encoding == "ros1")
    rng = np.random.default_rng(abs(hash((msgtype, encoding))) % 2**32)
    layout = LAYOUTS[msgtype]
    paths = layout_paths(layout.row, layout.child)
    assert paths is not None, "every layout reads plain fields"
    strings = (FRAME_ID,) + ((paths[1],) if paths[1] else ())
    plan = make_plan(ts, msgtype, paths[0], strings, cdr=encoding != "ros1")
    assert plan is not None and len(plan.leaves) - 2 == layout.width

    msgs = []
    for frame in FRAMES:
        for child in FRAMES[::3]:
            msgs.append(_random(ts, msgtype, rng, [frame, child]))
    raws = [serialize(ts, m, msgtype, encoding) for m in msgs]
    got = decode(plan, _batch(raws, rng))

    for i, raw in enumerate(raws):
        want = deserialize(ts, raw, msgtype, encoding)
        stamp = want.header.stamp.sec * 1_000_000_000 + want.header.stamp.nanosec
        assert got.t_ns[i] == stamp
        row = np.array(layout.row(want), np.float64)
        np.testing.assert_array_equal(got.values[i].view(np.uint64), row.view(np.uint64), err_msg=f"message {i}")
        codes, names = got.strings[0]
        assert names[codes[i]] == want.header.frame_id
        if layout.child is not None:
            codes, names = got.strings[1]
            assert names[codes[i]] == layout.child(want)


def test_mixed_endianness_in_one_batch():
    ts = make_typestore(ros1=False)
    rng = np.random.default_rng(5)
    msgtype = "sensor_msgs/msg/MagneticField"
    msgs = [_random(ts, msgtype, rng, [f]) for f in FRAMES]
    raws = [serialize(ts, m, msgtype, "cdr" if i % 2 else "cdr-big-endian") for i, m in enumerate(msgs)]
    plan = make_plan(ts, msgtype, [("magnetic_field", c) for c in "xyz"], cdr=True)
    got = decode(plan, _batch(raws, rng))
    for i, m in enumerate(msgs):
        np.testing.assert_array_equal(got.values[i], [m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z])
        codes, names = got.strings[0]
        assert names[codes[i]] == m.header.frame_id


def test_frame_ids_numbered_by_first_appearance():
    ts = make_typestore(ros1=True)
    rng = np.random.default_rng(1)
    msgtype = "geometry_msgs/msg/PoseStamped"
    frames = ["b", "a", "b", "ccc", "a", "dd", "b"]
    raws = [serialize(ts, _random(ts, msgtype, rng, [f]), msgtype, "ros1") for f in frames]
    plan = make_plan(ts, msgtype, [("pose", "position", "x")], cdr=False)
    codes, names = decode(plan, _batch(raws, rng)).strings[0]
    assert names == ["b", "a", "ccc", "dd"]
    assert [names[c] for c in codes] == frames


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_a_string_equal_to_the_one_before_is_read_where_that_one_lies(encoding):
    """The pass gives a frame id equal to the message before's (a topic's own, message after message) the position
    of that one's bytes, so coding it reads bytes in cache; a different one (same length or not) its own place."""
    ts = make_typestore(ros1=encoding == "ros1")
    rng = np.random.default_rng(7)
    msgtype = "geometry_msgs/msg/PoseStamped"
    frames = ["odom", "odom", "odom", "map_", "odom", "", "", "base_link", "odom"]
    raws = [serialize(ts, _random(ts, msgtype, rng, [f]), msgtype, encoding) for f in frames]
    plan = make_plan(ts, msgtype, [("pose", "position", "x")], cdr=encoding != "ros1")
    batch = _batch(raws, rng)
    head = 4 if plan.cdr else 0
    big = encoding == "cdr-big-endian"
    _, _, strings, _, _ = fastdecode.walked_columns(plan, batch.data, batch.start, batch.size, big)
    pos, length = strings[0]
    at = [int(batch.data[p : p + n].tobytes() == f.encode()) for p, n, f in zip(pos, length, frames, strict=True)]
    assert at == [1] * len(frames)  # every position holds its message's frame id
    own = batch.start + head  # each message's own bytes start after this
    assert pos[1] == pos[2] == pos[0] < own[1] and pos[6] == pos[5]
    assert all(pos[i] > own[i] for i in (0, 3, 4, 7, 8))
    codes, names = decode(plan, batch).strings[0]
    assert [names[c] for c in codes] == frames


def test_many_distinct_strings_numbered_by_first_appearance():
    """More distinct strings than the first string table holds (tag frames: hundreds), repeats among them: the
    table made again for every string gives the same codes a dict gives."""
    rng = np.random.default_rng(5)
    texts = [f"tag_{int(k)}" for k in rng.integers(0, 300, 2000)] + ["", "a" * 40]
    data, starts, sizes = as_buffer([t.encode() for t in texts], rng)
    codes, names = fastdecode.string_codes(data, starts, sizes)
    want = list(dict.fromkeys(texts))
    assert len(want) > 2 * fastdecode.SMALL_TABLE and names == want
    assert [names[c] for c in codes] == texts


@pytest.mark.parametrize(
    "texts",
    [
        ["odom"] * 50,  # one frame id: array code, no kernel
        [],
        [""] * 3,
        ["odom"] * 49 + ["odon"],  # one byte differs in the last string
        ["odom"] * 49 + ["odo"],  # a shorter one
        ["odo"] + ["odom"] * 49,
    ],
)
def test_one_string_without_the_kernel_as_with_it(texts, monkeypatch):
    """A short array whose strings are all one (a topic's frame id) is coded without :func:`fastdecode.dedup`, so
    that a short log's first run does not compile it; the codes and names are those the kernel gives."""
    rng = np.random.default_rng(len(texts))
    data, starts, sizes = as_buffer([t.encode() for t in texts], rng)
    with_kernel = fastdecode.dedup
    calls = []

    def counted(*args):
        calls.append(1)
        return with_kernel(*args)

    monkeypatch.setattr(fastdecode, "dedup", counted)
    codes, names = fastdecode.string_codes(data, starts, sizes)
    assert names == list(dict.fromkeys(texts)) and [names[c] for c in codes] == texts
    assert codes.dtype == np.int32
    assert bool(calls) == (len(set(texts)) > 1)


def test_what_is_not_planned():
    assert layout_paths(lambda m: (m.a.x * 2,)) is None  # computes
    assert layout_paths(lambda m: (m.data[0] + 1,)) is None  # computes on an element
    assert layout_paths(lambda m: (m.data[4],)) == ([("data", "4")], None)  # an element: planned if fixed-size
    assert layout_paths(lambda m: (m.a.x, m.b)) == ([("a", "x"), ("b",)], None)
    ts = make_typestore(ros1=False)
    ts.register(get_types_from_msg("std_msgs/Header header\nfloat64[] samples\nfloat64 tail\n", "test_msgs/msg/Tail"))
    assert make_plan(ts, "test_msgs/msg/Tail", [("tail",)], cdr=True) is None  # behind a sequence
    assert make_plan(ts, "test_msgs/msg/Tail", [("samples", "0")], cdr=True) is None  # an element of a sequence
    assert make_plan(ts, "test_msgs/msg/Tail", [], cdr=True) is not None  # the header alone is fine
    assert make_plan(ts, "geometry_msgs/msg/Vector3", [("x",)], cdr=True) is None  # no header
    assert make_plan(ts, "geometry_msgs/msg/PoseStamped", [("pose",)], cdr=True) is None  # not a number
    assert make_plan(ts, "geometry_msgs/msg/PoseStamped", [("pose", "nope")], cdr=True) is None


@pytest.mark.parametrize("encoding", ["ros1", "cdr"])
def test_bad_payloads_raise(encoding):
    ts = make_typestore(ros1=encoding == "ros1")
    rng = np.random.default_rng(2)
    msgtype = "sensor_msgs/msg/Imu"
    layout = LAYOUTS[msgtype]
    plan = make_plan(ts, msgtype, layout_paths(layout.row)[0], cdr=encoding == "cdr")
    good = serialize(ts, _random(ts, msgtype, rng, ["imu"]), msgtype, encoding)
    with pytest.raises(DecodeError, match="shorter"):
        decode(plan, _batch([good, good[: len(good) // 2]], rng))
    with pytest.raises(DecodeError, match="string|shorter"):  # frame_id length field pointing past the end
        bad = bytearray(good)
        bad[12:16] = (10**6).to_bytes(4, "little")  # after seq/encapsulation, sec and nanosec
        decode(plan, _batch([bytes(bad)], rng))
    with pytest.raises(DecodeError, match="UTF-8"):
        bad = bytearray(good)
        bad[16] = 0xFF  # first byte of frame_id
        decode(plan, _batch([bytes(bad)], rng))
    if encoding == "cdr":
        with pytest.raises(DecodeError, match="encapsulation"):
            decode(plan, _batch([b"\x00\x03\x00\x00" + good[4:]], rng))


def test_cdr_headers_are_checked_before_the_layouts():
    """The compiled pass checks every message's CDR header: a header too short wins over a header that is not plain
    CDR, which wins over any message's layout error, wherever each lies in the batch (as when the headers were
    checked over the whole batch before the pass); a batch whose first message is big-endian reads as rosbags."""
    ts = make_typestore(ros1=False)
    rng = np.random.default_rng(3)
    msgtype = "sensor_msgs/msg/Imu"
    layout = LAYOUTS[msgtype]
    plan = make_plan(ts, msgtype, layout_paths(layout.row)[0], cdr=True)
    good = serialize(ts, _random(ts, msgtype, rng, ["imu"]), msgtype, "cdr")
    short, foreign, cut = good[:3], b"\x00\x03\x00\x00" + good[4:], good[: len(good) // 2]
    for batch, error in (
        ([good, short, foreign], "shorter than its CDR header"),
        ([foreign, good, short], "shorter than its CDR header"),
        ([good, cut, foreign], "encapsulation"),
        ([cut, foreign, good], "encapsulation"),
        ([good, cut], "shorter than its sensor_msgs/msg/Imu layout"),
    ):
        with pytest.raises(DecodeError, match=error):
            decode(plan, _batch(batch, rng))
    msgs = [_random(ts, msgtype, rng, ["imu"]) for _ in range(5)]
    raws = [serialize(ts, m, msgtype, "cdr" if i else "cdr-big-endian") for i, m in enumerate(msgs)]
    got = decode(plan, _batch(raws, rng))
    for i, raw in enumerate(raws):
        row = np.array(layout.row(deserialize(ts, raw, msgtype, "cdr" if i else "cdr-big-endian")), np.float64)
        np.testing.assert_array_equal(got.values[i].view(np.uint64), row.view(np.uint64))


#: a header, then every primitive between strings (alignment after a string is per message) and an array skipped
EVERY_KIND = """std_msgs/Header header
uint8 a_uint8
float64 a_float64
string label
int16 a_int16
float32 a_float32
int64 a_int64
bool a_bool
string other
uint64 a_uint64
int8 an_int8
float64[3] skipped
uint16 a_uint16
int32 an_int32
uint32 a_uint32
"""
KIND_FIELDS = [
    "a_uint8", "a_float64", "a_int16", "a_float32", "a_int64", "a_bool", "a_uint64", "an_int8", "a_uint16",
    "an_int32", "a_uint32",
]  # fmt: skip


def _every_kind(encoding: str):
    ts = make_typestore(ros1=encoding == "ros1")
    ts.register(get_types_from_msg(EVERY_KIND, "test_msgs/msg/EveryKind"))
    strings = (FRAME_ID, ("label",), ("other",))
    return ts, make_plan(ts, "test_msgs/msg/EveryKind", [(f,) for f in KIND_FIELDS], strings, cdr=encoding != "ros1")


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_the_compiled_walk_reads_every_primitive_as_rosbags(encoding):
    """Each primitive (special floats, the extremes of every integer) read by the one compiled pass, strings of
    every length before them: the bits rosbags' deserialiser gives."""
    ts, plan = _every_kind(encoding)
    assert fastdecode.walks(plan)
    rng = np.random.default_rng(7)
    msgs = [_random(ts, "test_msgs/msg/EveryKind", rng, [f, FRAMES[-1 - k], f[::-1]]) for k, f in enumerate(FRAMES)]
    raws = [serialize(ts, m, "test_msgs/msg/EveryKind", encoding) for m in msgs * 3]
    got = decode(plan, _batch(raws, rng))
    for i, raw in enumerate(raws):
        want = deserialize(ts, raw, "test_msgs/msg/EveryKind", encoding)
        assert got.t_ns[i] == want.header.stamp.sec * 1_000_000_000 + want.header.stamp.nanosec
        row = np.array([getattr(want, f) for f in KIND_FIELDS], np.float64)
        np.testing.assert_array_equal(got.values[i].view(np.uint64), row.view(np.uint64), err_msg=f"message {i}")
        for k, text in enumerate((want.header.frame_id, want.label, want.other)):
            codes, names = got.strings[k]
            assert names[codes[i]] == text


def _mangled(raw: bytes, rng, cut: float, byteorder: str) -> bytes:
    """``raw`` cut short with probability ``cut``, and a length field pointing anywhere with probability 0.2."""
    raw = bytearray(raw)
    if rng.random() < cut:
        raw = raw[: rng.integers(len(raw) + 1)]
    if rng.random() < 0.2 and len(raw) > 20:
        at = int(rng.integers(4, len(raw) - 4))
        raw[at : at + 4] = int(rng.integers(0, 80)).to_bytes(4, byteorder)
    return bytes(raw)


def _both_ways(monkeypatch, plan, batch, summary) -> list[tuple]:
    """``batch`` decoded by the compiled walk, then by the array steps: ``summary`` of each, or its error."""
    outcomes = []
    for walks in (True, False):
        monkeypatch.setattr(fastdecode, "walks", lambda plan, walks=walks: walks)
        try:
            outcomes.append(summary(decode(plan, batch)))
        except DecodeError as err:
            outcomes.append(("error", str(err)))
    return outcomes


@pytest.mark.parametrize("encoding", ["ros1", "cdr", "mixed"])
def test_the_compiled_walk_fails_as_the_array_steps_do(encoding, monkeypatch):
    """Batches with cut messages and string lengths pointing anywhere: the compiled pass raises the error the array
    steps (the reference kept for this test) raise, or decodes the same bits."""
    ts, plan = _every_kind("ros1" if encoding == "ros1" else "cdr")
    rng = np.random.default_rng(11)
    seen = set()
    for case in range(300):
        raws = []
        for k in range(6):
            kind = "cdr-big-endian" if encoding == "mixed" and k % 2 else ("ros1" if encoding == "ros1" else "cdr")
            raw = serialize(ts, _random(ts, "test_msgs/msg/EveryKind", rng, []), plan.msgtype, kind)
            raws.append(_mangled(raw, rng, 0.3, "little"))
        batch = _batch(raws, rng)

        def summary(got):
            return ("ok", got.t_ns.tolist(), got.values.view(np.uint64).tolist(), got.strings)

        outcomes = _both_ways(monkeypatch, plan, batch, summary)
        assert outcomes[0][:3] == outcomes[1][:3], f"case {case}"
        if outcomes[0][0] == "ok":
            assert [[names[c] for c in codes] for codes, names in outcomes[0][3]] == [
                [names[c] for c in codes] for codes, names in outcomes[1][3]
            ]
        seen.add(outcomes[0][0] if outcomes[0][0] == "ok" else outcomes[0][1].split(" ")[0])
    assert len(seen) >= 3, seen  # decoded, cut and bad strings all met


# --------------------------------------------------------------------------- through the readers


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    sim = simulate("figure8", duration=3.0, seed=11)
    tmp = tmp_path_factory.mktemp("fast")
    return [write_log(sim, tmp / name, kind) for kind, name in (("bag", "l.bag"), ("mcap", "l.mcap"), ("ros2", "l2"))]


def test_fast_rows_equal_rosbags_rows(logs, monkeypatch):
    """decode_rows through fastdecode equals decode_rows through rosbags (plans switched off)."""
    for path in logs:
        with open_log(path) as reader:
            table = {t: conns for t, (meta, conns) in topics_of(reader).items() if meta.msgtype in LAYOUTS}
            fast = read_rows(reader, path, table)
            assert fast.keys() == table.keys()
            with monkeypatch.context() as patch:
                patch.setattr(fastdecode, "plan_for", lambda *args: None)
                slow = {t: decode_rows(reader, path, t, conns) for t, conns in table.items()}
        for topic, want in slow.items():
            got = fast[topic]
            for name in ("t_ns", "rec_ns", "values"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=f"{path} {topic}")
            assert (got.stated is None) == (want.stated is None) == (stated_start(got.msgtype) is None)
            if got.stated is not None:  # the stated variances: runs, not columns of ``values``
                assert got.values.shape[1] == stated_start(got.msgtype) < LAYOUTS[got.msgtype].width
                assert got.stated.starts.tolist() == want.stated.starts.tolist() == [0]  # the simulator's constant
                np.testing.assert_array_equal(got.stated.expanded(), want.stated.expanded())
            assert [got.frame_names[k] for k in got.frame] == [want.frame_names[k] for k in want.frame]
            assert [got.frame_names[k] for k in got.child] == [want.frame_names[k] for k in want.child]


def test_stated_runs_joined_over_batches_are_the_runs_of_the_whole():
    """Runs found batch by batch (a run going on across a batch's end, NaN rows each a run of their own) and joined
    are the runs of all the rows; expanded, the rows as decoded."""
    rng = np.random.default_rng(3)
    rows = np.repeat(rng.choice([1e-4, 2e-4, -1.0], size=(60, 3)), rng.integers(1, 40, 60), axis=0)
    rows[::97, 1] = np.nan
    whole = stated_runs(rows)
    cuts = np.sort(rng.choice(np.arange(1, rows.shape[0]), 9, replace=False))
    parts = [(a, stated_runs(rows[a:b])) for a, b in zip((0, *cuts), (*cuts, rows.shape[0]), strict=True)]
    starts = np.concatenate([a + r.starts for a, r in parts])
    joined = stated_runs(np.concatenate([r.values for _, r in parts]), starts, rows.shape[0])
    assert joined.starts.tolist() == whole.starts.tolist() and joined.n == whole.n == rows.shape[0]
    assert whole.starts.size < rows.shape[0] // 4  # runs, not rows
    np.testing.assert_array_equal(joined.values, whole.values)
    np.testing.assert_array_equal(whole.expanded(), rows)


@pytest.mark.parametrize("backwards", [False, True])
def test_stated_runs_of_a_topic_in_many_batches(tmp_path, monkeypatch, backwards):
    """A topic read in five batches per chunk (``backwards``: each chunk's messages in reverse): its stated variances
    are the runs of the topic read in one batch in record order (a run going on across batches is one run; sorted
    into record order with the rows). The IMU states one variance for 40 % of its messages, another after."""
    from slamobs.pipeline.simulate.logwriter import Builder
    from slamobs.pipeline.simulate.sensors import TOPIC_IMU

    columns = Builder.columns

    def stepped(self, topic):
        cols = columns(self, topic)
        if topic == TOPIC_IMU and cols is not None:
            n = self.sim.imu.t_ns.shape[0]
            cols[("angular_velocity_covariance", "0")] = np.where(np.arange(n) < int(0.4 * n), 2.5e-5, 4e-5)
        return cols

    monkeypatch.setattr(Builder, "columns", stepped)
    path = write_log(simulate("figure8", duration=3.0, seed=11), tmp_path / "stepped.mcap")
    read = fastdecode.iter_batches

    def pieces(*args):
        for batch in read(*args):
            rows = np.arange(batch.rec_ns.shape[0])
            for part in np.array_split(rows[::-1] if backwards else rows, 5):
                yield batch.take(part)

    with open_log(path) as reader:
        table = {t: conns for t, (meta, conns) in topics_of(reader).items() if meta.msgtype in LAYOUTS}
        want = read_rows(reader, path, table)
        monkeypatch.setattr(fastdecode, "iter_batches", pieces)
        monkeypatch.setattr(fastdecode, "grouped", lambda batches: batches)
        got = read_rows(reader, path, table)
    assert want[TOPIC_IMU].stated.starts.tolist() == [0, int(0.4 * want[TOPIC_IMU].t_ns.size)]
    for topic in (topic for topic, rows in want.items() if rows.stated is not None):
        np.testing.assert_array_equal(got[topic].values, want[topic].values)
        assert got[topic].stated.starts.tolist() == want[topic].stated.starts.tolist()
        np.testing.assert_array_equal(got[topic].stated.values, want[topic].stated.values)
        assert got[topic].stated.n == want[topic].stated.n == want[topic].t_ns.size


def test_undecodable_message_is_one_line_input_error(tmp_path):
    ts = make_typestore(ros1=True)
    from rosbags.rosbag1 import Writer

    path = tmp_path / "short.bag"
    rng = np.random.default_rng(3)
    msgtype = "sensor_msgs/msg/MagneticField"
    raw = serialize(ts, _random(ts, msgtype, rng, ["mag"]), msgtype, "ros1")
    with Writer(path) as writer:
        conn = writer.add_connection("/mag", msgtype, typestore=ts)
        writer.write(conn, 1, raw)
        writer.write(conn, 2, raw[:30])
    with open_log(path) as reader:
        conns = reader.topics["/mag"].connections
        with pytest.raises(InputError) as err:
            decode_rows(reader, path, "/mag", conns)
    assert str(err.value).startswith(f"{path} [/mag]: cannot decode {msgtype} message") and "\n" not in str(err.value)


# --------------------------------------------------------------------------- detection arrays (sequences)


def _detection_message(ts, msgtype: str, rng: np.random.Generator, frame: str, n: int) -> object:
    """A detection array of ``n`` elements with random numbers (special floats included)."""
    from slamobs.pipeline.readers.rows import ITEM_LAYOUTS

    layout = ITEM_LAYOUTS[msgtype]
    fields = dict(ts.fielddefs[msgtype][1])
    elem = fields[layout.items][1][0][1]
    items = [_random(ts, elem, rng, []) for _ in range(n)]
    msg = _random(ts, msgtype, rng, [frame])
    return type(msg)(**{**{k: getattr(msg, k) for k in msg.__dataclass_fields__}, layout.items: items})


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("msgtype", ["fiducial_msgs/msg/FiducialTransformArray", "geometry_msgs/msg/PoseArray"])
def test_detection_arrays_identical_to_rosbags(msgtype, encoding):
    """Every element's id and position, for frame ids of every length (CDR alignment of the sequence moves with
    it) and 0..5 elements per message."""
    from slamobs.pipeline.readers.rows import ITEM_LAYOUTS
    from slamobs.pipeline.readers.fastdecode import item_plan_for

    ts = make_typestore(ros1=encoding == "ros1")
    rng = np.random.default_rng(abs(hash((msgtype, encoding))) % 2**32)
    layout = ITEM_LAYOUTS[msgtype]
    plan = item_plan_for(ts, msgtype, cdr=encoding != "ros1")
    assert plan is not None and plan.items is not None
    msgs = [_detection_message(ts, msgtype, rng, frame, n) for frame in FRAMES for n in range(6)]
    raws = [serialize(ts, m, msgtype, encoding) for m in msgs]
    got = decode(plan, _batch(raws, rng))
    assert got.counts.tolist() == [len(getattr(m, layout.items)) for m in msgs]
    want = []
    for raw in raws:
        for k, (ident, pos) in enumerate(layout.detections(deserialize(ts, raw, msgtype, encoding), None)):
            want.append([float(ident), pos.x, pos.y, pos.z] if layout.ident else [pos.x, pos.y, pos.z])
    np.testing.assert_array_equal(
        got.items.view(np.uint64), np.array(want, np.float64).reshape(-1, got.items.shape[1]).view(np.uint64)
    )
    codes, names = got.strings[0]
    assert [names[c] for c in codes] == [m.header.frame_id for m in msgs]


def test_detection_arrays_mixed_endianness_and_bad_counts():
    ts = make_typestore(ros1=False)
    rng = np.random.default_rng(8)
    msgtype = "fiducial_msgs/msg/FiducialTransformArray"
    from slamobs.pipeline.readers.fastdecode import item_plan_for

    plan = item_plan_for(ts, msgtype, cdr=True)
    msgs = [_detection_message(ts, msgtype, rng, f, i % 4) for i, f in enumerate(FRAMES)]
    raws = [serialize(ts, m, msgtype, "cdr" if i % 2 else "cdr-big-endian") for i, m in enumerate(msgs)]
    got = decode(plan, _batch(raws, rng))
    ids = [t.fiducial_id for m in msgs for t in m.transforms]
    assert got.items[:, 0].astype(int).tolist() == ids  # elements back in message order
    bad = bytearray(serialize(ts, msgs[3], msgtype, "cdr"))
    count_at = 4 + 8 + 4 + 4 * ((len(FRAMES[3]) + 1 + 3) // 4) + 4  # CDR: stamp, frame id, image_seq, then the count
    bad[count_at : count_at + 4] = (10**8).to_bytes(4, "little")
    with pytest.raises(DecodeError, match="sequence"):
        decode(plan, _batch([bytes(bad)], rng))


def test_fast_detections_equal_rosbags_detections(logs, monkeypatch):
    """read_log's detection stream decoded from the bytes equals the one from rosbags' deserialiser."""
    from slamobs.pipeline.readers import read_log

    for path in logs:
        fast = read_log(path).detections
        with monkeypatch.context() as patch:
            patch.setattr(fastdecode, "item_plan_for", lambda *args: None)
            slow = read_log(path).detections
        for name in ("t_ns", "rec_ns", "offsets", "ids", "xyz"):
            np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=f"{path} {name}")
        assert fast.frame_id == slow.frame_id and fast.topic == slow.topic


@pytest.mark.parametrize("encoding", ["ros1", "cdr", "mixed"])
def test_the_compiled_walk_of_detection_arrays_fails_as_the_array_steps_do(encoding, monkeypatch):
    """Detection arrays cut anywhere, with element counts and string lengths pointing anywhere: the compiled pass
    (one kernel for the header and the elements) raises the error the array steps raise, or decodes the same
    counts, element bits and frame ids."""
    from slamobs.pipeline.readers.fastdecode import item_plan_for

    msgtype = "fiducial_msgs/msg/FiducialTransformArray"
    ts = make_typestore(ros1=encoding == "ros1")
    plan = item_plan_for(ts, msgtype, cdr=encoding != "ros1")
    rng = np.random.default_rng(12)
    seen = set()
    for case in range(200):
        raws = []
        for k in range(5):
            kind = "cdr-big-endian" if encoding == "mixed" and k % 2 else ("ros1" if encoding == "ros1" else "cdr")
            msg = _detection_message(ts, msgtype, rng, FRAMES[(case + k) % len(FRAMES)], int(rng.integers(4)))
            raw = serialize(ts, msg, msgtype, kind)
            raws.append(_mangled(raw, rng, 0.2, "big" if kind == "cdr-big-endian" else "little"))
        batch = _batch(raws, rng)

        def summary(got):
            codes, names = got.strings[0]
            items = got.items.view(np.uint64).tolist()
            return ("ok", got.t_ns.tolist(), got.counts.tolist(), items, [names[c] for c in codes])

        outcomes = _both_ways(monkeypatch, plan, batch, summary)
        assert outcomes[0] == outcomes[1], f"case {case}"
        seen.add(outcomes[0][0] if outcomes[0][0] == "ok" else outcomes[0][1].split(" ")[0])
    assert len(seen) >= 3, seen  # decoded, cut and overlong sequences or strings all met


def test_gather_and_item_offsets_by_array_code_as_by_their_kernels():
    """A short log's first run gathers words and places detection elements by array code (``fastdecode.gather``,
    ``fastdecode.item_offsets`` below ``kernel_cache.KERNEL_ROWS`` rows): the kernels' words and offsets, for every
    word size in both byte orders and for elements after a string (any alignment), and the same first message whose
    elements run past its end."""
    from slamobs.pipeline.kernel_cache import KERNEL_ROWS
    from slamobs.pipeline.readers.fastdecode import gather, item_offsets, item_plan_for

    rng = np.random.default_rng(3)
    data = rng.integers(0, 256, 4096, dtype=np.uint8)
    sizes = np.array([8, 1, 4, 2, 8, 4], np.int64)
    offsets = rng.integers(0, 4096 - 8, (KERNEL_ROWS, sizes.size))
    few = KERNEL_ROWS // 64 - 1  # array code even once the kernel is loaded (kernel_cache.compiled_for)
    for big in (False, True):
        words = gather(data, offsets, sizes, big)  # the kernel
        np.testing.assert_array_equal(gather(data, offsets[:few], sizes, big), words[:few])
    items = item_plan_for(make_typestore(ros1=False), "fiducial_msgs/msg/FiducialTransformArray", cdr=True).items
    program = (*items.program, len(items.leaves))
    n = 50_000
    counts = rng.integers(0, 4, n)
    origin = np.cumsum(rng.integers(50, 900, n))
    first = rng.integers(0, 40, n)  # elements after a string: any alignment
    limit = first + counts * 200 + 8
    assert counts.sum() >= KERNEL_ROWS
    rows = np.concatenate(([0], np.cumsum(counts)))
    want, bad = item_offsets(origin, first, counts, limit, *program)  # the kernel
    assert bad == -1
    for lo in range(0, 3000, 200):  # fewer than KERNEL_ROWS // 64 elements each
        got, bad = item_offsets(
            origin[lo : lo + 200], first[lo : lo + 200], counts[lo : lo + 200], limit[lo : lo + 200], *program
        )
        assert bad == -1 and got.shape[0] < KERNEL_ROWS // 64
        np.testing.assert_array_equal(got, want[rows[lo] : rows[lo + 200]])
    k = int(np.flatnonzero(counts[100:] > 0)[0]) + 100
    limit[k] = first[k] + 3  # its elements run past its end
    limit[k + 5] = 0
    assert item_offsets(origin, first, counts, limit, *program)[1] == k
    got, bad = item_offsets(
        origin[k - 50 : k + 50], first[k - 50 : k + 50], counts[k - 50 : k + 50], limit[k - 50 : k + 50], *program
    )
    assert bad == 50
    np.testing.assert_array_equal(got[: rows[k] - rows[k - 50]], want[rows[k - 50] : rows[k]])
