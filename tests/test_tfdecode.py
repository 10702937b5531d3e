"""TF topics decoded from the bytes (tfdecode) equal what rosbags' deserialiser gives, bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import get_types_from_msg

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.readers import decode, read_log, tfdecode
from slamobs.pipeline.readers.container import open_log
from slamobs.pipeline.readers.decode import decode_tf
from slamobs.pipeline.readers.rows import TfRows, frame_name
from slamobs.pipeline.readers.fastdecode import DecodeError
from slamobs.pipeline.readers.roles import TF1, TF2, TF_TYPES, topics_of
from slamobs.pipeline.readers.tfdecode import decode_batch, tf_layout
from slamobs.pipeline.simulate import make_typestore
from slamobs.pipeline.simulate.logwriter import write_raw_log
from serialization import as_buffer, deserialize, serialize
from realdata import REALDATA

#: frame ids of every length 0..25 (ROS1 has no padding; CDR pads after each string to 4, before the doubles to 8)
#: (some with a leading slash, as tf1 wrote them: "/" alone becomes the empty frame name)
ALPHABET = "abcdefghijklmnopqrstuvwxyz"
FRAMES = ["/" + ALPHABET[: n - 1] if n % 5 == 1 else ALPHABET[:n] for n in range(26)]
SPECIAL = [np.nan, np.inf, -np.inf, -0.0, 5e-324, 1.7976931348623157e308]
NAN_PAYLOAD = np.array([0x7FF0_0000_0000_0001], np.uint64).view(np.float64)[0]  # a signalling NaN's bits
T0 = 1_700_000_000
SEC_RANGES = [(0, 0), (T0, T0 + 10), (-(2**31), 2**31 - 1)]  # zero, realistic, the extremes of int32 sec


def typestore(ros1: bool):
    """The simulator's typestore (tf2_msgs registered) plus ROS1 ``tf/tfMessage``."""
    ts = make_typestore(ros1=ros1)
    if ros1:
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", TF1))
    return ts


def _float(rng: np.random.Generator) -> float:
    r = rng.random()
    return float(rng.choice(SPECIAL)) if r < 0.1 else float(NAN_PAYLOAD) if r < 0.12 else float(rng.normal() * 100)


def tf_message(ts, msgtype: str, rng: np.random.Generator, frames: list[tuple[str, str]], sec=(T0, T0 + 10)):
    """A TF message with one transform per (parent, child), random stamps and values."""
    make = ts.types
    items = []
    for parent, child in frames:
        stamp = make["builtin_interfaces/msg/Time"](
            sec=int(rng.integers(sec[0], sec[1], endpoint=True)), nanosec=int(rng.integers(0, 10**9))
        )
        header = (
            make["std_msgs/msg/Header"](seq=int(rng.integers(0, 2**32)), stamp=stamp, frame_id=parent)
            if "seq" in dict(ts.fielddefs["std_msgs/msg/Header"][1])
            else make["std_msgs/msg/Header"](stamp=stamp, frame_id=parent)
        )
        vec = make["geometry_msgs/msg/Vector3"](x=_float(rng), y=_float(rng), z=_float(rng))
        quat = make["geometry_msgs/msg/Quaternion"](x=_float(rng), y=_float(rng), z=_float(rng), w=_float(rng))
        items.append(
            make["geometry_msgs/msg/TransformStamped"](
                header=header,
                child_frame_id=child,
                transform=make["geometry_msgs/msg/Transform"](translation=vec, rotation=quat),
            )
        )
    return make[msgtype](transforms=items)


def mixed_messages(ts, msgtype: str, rng: np.random.Generator, many: bool = False) -> list[object]:
    """Frame ids of every length as parent and child, 0..4 transforms per message, extreme stamps."""
    msgs = []
    for i, parent in enumerate(FRAMES):
        children = [FRAMES[(i * 7 + j) % 26] for j in range(4)]
        for n in range(5):
            msgs.append(tf_message(ts, msgtype, rng, [(parent, c) for c in children[:n]], SEC_RANGES[(i + n) % 3]))
    if many:  # more distinct frames than the compiled string matcher keeps (np.unique path)
        msgs.append(tf_message(ts, msgtype, rng, [("map", f"tag_{k}") for k in range(100)]))
    return msgs


def expected(ts, raws: list[bytes], msgtype: str, encoding: str) -> tuple[list[int], list[str], list[str], np.ndarray]:
    t_ns, parent, child, values = [], [], [], []
    for raw in raws:
        for tf in deserialize(ts, raw, msgtype, encoding).transforms:
            t_ns.append(tf.header.stamp.sec * 1_000_000_000 + tf.header.stamp.nanosec)
            parent.append(tf.header.frame_id)
            child.append(tf.child_frame_id)
            tr, rot = tf.transform.translation, tf.transform.rotation
            values.append([tr.x, tr.y, tr.z, rot.x, rot.y, rot.z, rot.w])
    return t_ns, parent, child, np.array(values, np.float64).reshape(-1, 7)


# --------------------------------------------------------------------------- the walker on bytes


@pytest.mark.parametrize(("encoding", "msgtype"), [("ros1", TF1), ("ros1", TF2), ("cdr", TF2), ("cdr-big-endian", TF2)])
def test_walker_identical_to_rosbags(encoding, msgtype):
    ts = typestore(ros1=encoding == "ros1")
    rng = np.random.default_rng(abs(hash((msgtype, encoding))) % 2**32)
    layout = tf_layout(ts, msgtype, cdr=encoding != "ros1")
    assert layout is not None and layout.signed == (True, False)
    raws = [serialize(ts, m, msgtype, encoding) for m in mixed_messages(ts, msgtype, rng, many=True)]
    got = decode_batch(layout, *as_buffer(raws, rng))
    t_ns, parent, child, values = expected(ts, raws, msgtype, encoding)
    assert got.counts.tolist() == [len(deserialize(ts, r, msgtype, encoding).transforms) for r in raws]
    assert got.t_ns.tolist() == t_ns
    assert [got.names[c] for c in got.parent] == parent
    assert [got.names[c] for c in got.child] == child
    np.testing.assert_array_equal(got.values.view(np.uint64), values.view(np.uint64))
    first_seen = list(dict.fromkeys(x for pair in zip(parent, child, strict=True) for x in pair))
    assert got.names == first_seen


def test_mixed_endianness_in_one_batch():
    ts = typestore(ros1=False)
    rng = np.random.default_rng(4)
    msgs = mixed_messages(ts, TF2, rng)
    raws = [serialize(ts, m, TF2, "cdr" if i % 3 else "cdr-big-endian") for i, m in enumerate(msgs)]
    got = decode_batch(tf_layout(ts, TF2, cdr=True), *as_buffer(raws, rng))
    t_ns, parent, child, values = expected(ts, raws, TF2, "cdr")
    assert got.t_ns.tolist() == t_ns and [got.names[c] for c in got.child] == child
    np.testing.assert_array_equal(got.values.view(np.uint64), values.view(np.uint64))


def test_empty_batch_and_empty_messages():
    ts = typestore(ros1=False)
    layout = tf_layout(ts, TF2, cdr=True)
    none = np.zeros(0, np.int64)
    got = decode_batch(layout, np.zeros(0, np.uint8), none, none)
    assert got.t_ns.shape == (0,) and got.values.shape == (0, 7) and got.names == []
    raw = serialize(ts, ts.types[TF2](transforms=[]), TF2, "cdr")
    got = decode_batch(layout, np.frombuffer(raw * 3, np.uint8), np.arange(3) * len(raw), np.full(3, len(raw)))
    assert got.counts.tolist() == [0, 0, 0] and got.t_ns.size == 0


def test_only_the_standard_layout_is_walked():
    for ros1 in (True, False):
        ts = typestore(ros1=ros1)
        assert tf_layout(ts, TF2, cdr=not ros1) is not None
        assert tf_layout(ts, "geometry_msgs/msg/TransformStamped", cdr=not ros1) is None  # not a TF message
        ts.register(
            get_types_from_msg("geometry_msgs/TransformStamped[] transforms\nuint8 extra\n", "test_msgs/msg/Extra")
        )
        assert tf_layout(ts, "test_msgs/msg/Extra", cdr=not ros1) is None  # a field after the sequence
        ts.register(get_types_from_msg("test_msgs/Stamped[] transforms\n", "test_msgs/msg/Other"))
        ts.register(
            get_types_from_msg(
                "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Pose transform\n", "test_msgs/msg/Stamped"
            )
        )
        assert tf_layout(ts, "test_msgs/msg/Other", cdr=not ros1) is None  # other element type
    assert tf_layout(typestore(ros1=True), TF2, cdr=True) is None  # a ROS1 header (seq) read as CDR


@pytest.mark.parametrize("encoding", ["ros1", "cdr"])
def test_bad_payloads_raise(encoding):
    ts = typestore(ros1=encoding == "ros1")
    rng = np.random.default_rng(2)
    layout = tf_layout(ts, TF2, cdr=encoding == "cdr")
    good = serialize(ts, tf_message(ts, TF2, rng, [("odom", "base_link"), ("map", "odom")]), TF2, encoding)
    head = 4 if encoding == "cdr" else 0

    def run(*payloads: bytes) -> None:
        decode_batch(layout, *as_buffer(list(payloads), rng))

    for cut in (len(good) - 1, len(good) // 2, head + 30, head + 5, head + 2):  # cut inside values, strings, count
        with pytest.raises(DecodeError, match="shorter|runs past"):
            run(good, good[:cut])
    bad = bytearray(good)
    bad[head : head + 4] = (10**6).to_bytes(4, "little")  # transform count
    with pytest.raises(DecodeError, match="sequence runs past"):
        run(bytes(bad))
    bad = bytearray(good)
    bad[head : head + 4] = (3).to_bytes(4, "little")  # one transform more than there are bytes for
    with pytest.raises(DecodeError, match="sequence runs past|shorter"):
        run(bytes(bad))
    at = head + 4 + (4 if encoding == "ros1" else 0) + 8  # frame_id length of the first transform
    bad = bytearray(good)
    bad[at : at + 4] = (10**6).to_bytes(4, "little")
    with pytest.raises(DecodeError, match="string runs past"):
        run(bytes(bad))
    bad = bytearray(good)
    bad[at + 4] = 0xFF  # first byte of frame_id
    with pytest.raises(DecodeError, match="UTF-8"):
        run(bytes(bad))
    if encoding == "cdr":
        with pytest.raises(DecodeError, match="encapsulation"):
            run(b"\x00\x03\x00\x00" + good[4:])
        with pytest.raises(DecodeError, match="CDR header"):
            run(good[:3])


# --------------------------------------------------------------------------- through the readers


@pytest.fixture(autouse=True)
def every_topic_walked(monkeypatch):
    """The logs here are small: the fast path is taken for topics of any size (by default only from
    ``decode.TF_FAST_MESSAGES`` messages on, see test_small_tf_topics_are_read_by_rosbags)."""
    monkeypatch.setattr(decode, "TF_FAST_MESSAGES", 0)


def write_tf_log(path: Path, container: str, topics: dict[str, list[tuple[int, bytes]]], msgtype: str, ts) -> Path:
    """Serialised TF messages ``topic -> [(record ns, payload)]``; ROS1 bags in several chunks that overlap in
    record time."""
    return write_raw_log(path, container, topics, msgtype, ts, chunk_threshold=16 << 10)


def fallback(reader, path, topic, conns, monkeypatch) -> TfRows:
    with monkeypatch.context() as patch:
        patch.setattr(tfdecode, "tf_layout", lambda *args: None)
        return decode_tf(reader, path, topic, conns)


def assert_identical(got: TfRows, want: TfRows, where: str) -> None:
    for name in ("t_ns", "rec_ns"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=f"{where} {name}")
    assert got.values.shape == want.values.shape and got.values.dtype == want.values.dtype == np.float64, where
    np.testing.assert_array_equal(got.values.view(np.uint64), want.values.view(np.uint64), err_msg=where)
    assert [got.frame_names[k] for k in got.parent] == [want.frame_names[k] for k in want.parent], where
    assert [got.frame_names[k] for k in got.child] == [want.frame_names[k] for k in want.child], where
    # the codes too: numbered in the same order (first appearance in record order, parent before child)
    assert got.frame_names == want.frame_names, where
    np.testing.assert_array_equal(got.parent, want.parent, err_msg=where)
    np.testing.assert_array_equal(got.child, want.child, err_msg=where)
    assert got.parent.dtype == got.child.dtype == np.int32 and got.t_ns.dtype == got.rec_ns.dtype == np.int64


LOGS = [
    ("bag", TF1, "ros1"),
    ("bag", TF2, "ros1"),
    ("ros2", TF2, "cdr"),
    ("mcap", TF2, "cdr"),
    ("mcap", TF2, "cdr-big-endian"),
    ("ros2", TF2, "cdr-big-endian"),
]


@pytest.fixture(scope="module", params=LOGS, ids=["-".join(p).replace("/", "_") for p in LOGS])
def tf_log(request, tmp_path_factory):
    """/tf with every frame id length and 0..4 transforms per message, record times partly out of file order
    and tied; /tf_static with one message; a dynamic topic of 3 transforms at 100 Hz in between."""
    container, msgtype, encoding = request.param
    ts = typestore(ros1=encoding == "ros1")
    rng = np.random.default_rng(9)
    ns = 1_000_000_000
    tf = []
    for i, msg in enumerate(mixed_messages(ts, msgtype, rng, many=True)):
        rec = T0 * ns + (i // 3) * 10_000_000 - (5_000_000 if i % 7 == 3 else 0)  # ties, and some out of order
        tf.append((rec, serialize(ts, msg, msgtype, encoding)))
    robot = [("/odom", "base_link"), ("map", "/odom"), ("base_link", "laser")]
    dyn = [
        (T0 * ns + k * 10_000_000 + 1, serialize(ts, tf_message(ts, msgtype, rng, robot), msgtype, encoding))
        for k in range(300)
    ]
    static = [
        (
            T0 * ns,
            serialize(
                ts, tf_message(ts, msgtype, rng, [("base_link", "imu"), ("base_link", "cam")]), msgtype, encoding
            ),
        )
    ]
    name = {"bag": "tf.bag", "ros2": "tf_ros2", "mcap": "tf.mcap"}[container]
    path = tmp_path_factory.mktemp("tf") / name
    return write_tf_log(path, container, {"/tf": tf, "/robot_tf": dyn, "/tf_static": static}, msgtype, ts)


def test_fast_tf_equals_rosbags(tf_log, monkeypatch):
    calls = []
    real = tfdecode.read_tf
    monkeypatch.setattr(tfdecode, "read_tf", lambda *args: calls.append(args[2]) or real(*args))
    with open_log(tf_log) as reader:
        table = topics_of(reader)
        assert sorted(t for t, (meta, _) in table.items() if meta.msgtype in TF_TYPES) == [
            "/robot_tf",
            "/tf",
            "/tf_static",
        ]
        for topic in ("/tf", "/robot_tf", "/tf_static"):
            conns = table[topic][1]
            got = decode_tf(reader, tf_log, topic, conns)
            assert calls[-1] == topic and got is not None
            assert tfdecode.read_tf(reader, tf_log, topic, conns) is not None  # the fast path, not the fallback
            want = fallback(reader, tf_log, topic, conns, monkeypatch)
            assert_identical(got, want, f"{tf_log} {topic}")
            assert got.t_ns.size == {"/tf": 26 * (0 + 1 + 2 + 3 + 4) + 100, "/robot_tf": 900, "/tf_static": 2}[topic]
    assert all("/" not in name[:1] for name in got.frame_names)


def test_small_tf_topics_are_read_by_rosbags(tf_log, monkeypatch):
    """Below ``TF_FAST_MESSAGES`` messages the compiled walker is not used (nor compiled): same rows."""
    monkeypatch.setattr(decode, "TF_FAST_MESSAGES", 301)
    calls = []
    real = tfdecode.read_tf
    monkeypatch.setattr(tfdecode, "read_tf", lambda *args: calls.append(args[2]) or real(*args))
    with open_log(tf_log) as reader:
        table = topics_of(reader)
        small = decode_tf(reader, tf_log, "/robot_tf", table["/robot_tf"][1])  # 300 messages
        assert calls == []
        monkeypatch.setattr(decode, "TF_FAST_MESSAGES", 0)
        assert_identical(small, decode_tf(reader, tf_log, "/robot_tf", table["/robot_tf"][1]), "/robot_tf")
    assert calls == ["/robot_tf"]


@pytest.mark.filterwarnings("ignore:.*encountered in multiply:RuntimeWarning")  # NaN/Inf transforms
def test_read_log_tf_roles_unchanged(tf_log, monkeypatch):
    """What read_log makes of the TF topics (static transforms, edge series) is the same on both paths."""
    fast = read_log(tf_log, {"tf": "/robot_tf"})
    with monkeypatch.context() as patch:
        patch.setattr(tfdecode, "tf_layout", lambda *args: None)
        slow = read_log(tf_log, {"tf": "/robot_tf"})
    assert fast.warnings == slow.warnings
    assert [(t.parent, t.child) for t in fast.static_tf] == [(t.parent, t.child) for t in slow.static_tf]
    assert len(fast.tf) == len(slow.tf) == 3
    for f, s in zip(fast.tf, slow.tf, strict=True):
        assert (f.parent, f.child) == (s.parent, s.child)
        for name in ("t_ns", "rec_ns", "translation", "quat_xyzw"):
            np.testing.assert_array_equal(getattr(f, name), getattr(s, name))


def test_variant_definition_falls_back_to_rosbags(tmp_path):
    """A TF type stored with another layout is still read (by rosbags), not misread by the walker."""
    ts = make_typestore(ros1=True)
    ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\nuint8 tail\n", TF1))
    rng = np.random.default_rng(3)
    base = tf_message(ts, TF2, rng, [("/odom", "base_link")])
    msg = ts.types[TF1](transforms=base.transforms, tail=7)
    path = write_tf_log(
        tmp_path / "variant.bag", "bag", {"/tf": [(T0 * 10**9, serialize(ts, msg, TF1, "ros1"))]}, TF1, ts
    )
    with open_log(path) as reader:
        conns = topics_of(reader)["/tf"][1]
        assert tfdecode.read_tf(reader, path, "/tf", conns) is None
        rows = decode_tf(reader, path, "/tf", conns)
    assert rows.frame_names == ["odom", "base_link"] and rows.t_ns.size == 1
    assert rows.values[0, 0] == base.transforms[0].transform.translation.x


@pytest.mark.parametrize("container", ["bag", "ros2", "mcap"])
def test_undecodable_tf_message_is_one_line_input_error(tmp_path, container):
    ros1 = container == "bag"
    ts = typestore(ros1=ros1)
    rng = np.random.default_rng(6)
    encoding = "ros1" if ros1 else "cdr"
    good = serialize(ts, tf_message(ts, TF2, rng, [("odom", "base_link"), ("map", "odom")]), TF2, encoding)
    bad_count = bytearray(good)
    at = 0 if ros1 else 4  # the transform count
    bad_count[at : at + 4] = (2**32 - 1).to_bytes(4, "little")
    for k, bad in enumerate([good[: len(good) - 9], bytes(bad_count)]):
        path = tmp_path / f"bad{k}{'.bag' if ros1 else '.mcap' if container == 'mcap' else ''}"
        write_tf_log(path, container, {"/tf": [(1, good), (2, bad), (3, good)]}, TF2, ts)
        with open_log(path) as reader, pytest.raises(InputError) as err:
            decode_tf(reader, path, "/tf", topics_of(reader)["/tf"][1])
        text = str(err.value)
        assert text.startswith(f"{path} [/tf]: cannot decode {TF2} message: "), text
        assert "\n" not in text and ("shorter" in text or "runs past" in text)


# --------------------------------------------------------------------------- real logs


def _real_logs() -> list[Path]:
    if not REALDATA.is_dir():
        return []
    logs = {p for p in REALDATA.rglob("*") if p.suffix in {".bag", ".mcap"} and p.is_file()}
    logs |= {p.parent for p in REALDATA.rglob("metadata.yaml")}  # rosbag2 directories
    return sorted(logs)


def test_real_tf_topics_identical(monkeypatch):
    """Every TF topic of every log in ../shared/realdata (ROS1 tf and tf2 bags, rosbag2, MCAP) on both paths."""
    logs = _real_logs()
    if not logs:
        pytest.skip(f"{REALDATA} not available")
    compared = []
    for log in logs:
        with open_log(log) as reader:
            for topic, (meta, conns) in topics_of(reader).items():
                if meta.msgtype not in TF_TYPES:
                    continue
                got = tfdecode.read_tf(reader, log, topic, conns)
                assert got is not None, f"{log} {topic}: standard layout expected"
                assert_identical(got, fallback(reader, log, topic, conns, monkeypatch), f"{log} {topic}")
                assert all(name == frame_name(name) for name in got.frame_names)
                compared.append((log.name, topic, got.t_ns.size))
    assert compared
