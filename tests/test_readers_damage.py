"""Readers on every container x compression, and on damaged files: truncated, unindexed, corrupt, empty."""

from __future__ import annotations

import io
import re
import struct
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader
from rosbags.rosbag1 import Reader as Bag1Reader
from rosbags.rosbag1 import Writer as Bag1Writer
from rosbags.rosbag1.reader import Header
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Reader as Bag2Reader
from rosbags.rosbag2 import Writer as Bag2Writer

from slamobs.cli.info_cmd import info
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.readers import inspect_log, read_log
from slamobs.pipeline.readers import chunks, storage
from slamobs.pipeline.readers.container import damage_notes, iter_batches, open_log
from slamobs.pipeline.readers.container import storages as container_storages
from slamobs.pipeline.readers.rows import LAYOUTS
from slamobs.pipeline.readers.fastdecode import read_rows
from slamobs.pipeline.readers.roles import topics_of
from slamobs.pipeline.simulate import expected_streams, make_typestore, simulate

from container_logs import CHUNK, write_container

FIDUCIALS = "fiducial_msgs/msg/FiducialTransformArray"


@pytest.fixture(scope="module")
def sim():
    return simulate("figure8", duration=2.0, seed=3)


def _same_streams(got, want, prefix: bool = False) -> None:
    """Every role equal (``prefix``: ``got`` is the first part of ``want``)."""
    for role in ("angular_velocity", "linear_velocity", "accel", "magnetic", "truth"):
        g, w = getattr(got, role), getattr(want, role)
        n = len(g) if prefix else len(w)
        assert len(g) == n, role
        np.testing.assert_array_equal(g.t_ns, w.t_ns[:n], err_msg=role)
        np.testing.assert_array_equal(g.rec_ns, w.rec_ns[:n], err_msg=role)
        for name in ("xyz", "position", "quat_xyzw"):
            if hasattr(g, name):
                np.testing.assert_array_equal(getattr(g, name), getattr(w, name)[:n], err_msg=role)
    g, w = got.detections, want.detections
    n = len(g) if prefix else len(w)
    np.testing.assert_array_equal(g.t_ns, w.t_ns[:n])
    np.testing.assert_array_equal(g.offsets, w.offsets[: n + 1])
    np.testing.assert_array_equal(g.xyz, w.xyz[: w.offsets[n]])


# --------------------------------------------------------------------------- containers x compression

MATRIX = [
    ("bag", ""),
    ("bag", "bz2"),
    ("bag", "lz4"),
    ("mcap", ""),
    ("mcap", "zstd"),
    ("mcap", "lz4"),
    ("ros2-sqlite3", ""),
    ("ros2-sqlite3", "file"),
    ("ros2-sqlite3", "message"),
    ("ros2-mcap", ""),
    ("ros2-mcap", "storage"),
    ("ros2-mcap", "file"),
    ("ros2-mcap", "message"),
]


@pytest.mark.parametrize(("container", "compression"), MATRIX)
def test_every_container_and_compression(tmp_path, sim, container, compression):
    name = {"bag": "log.bag", "mcap": "log.mcap"}.get(container, "log_ros2")
    path = write_container(sim, tmp_path / name, container, compression)
    got = read_log(path)
    assert got.warnings == []
    _same_streams(got, expected_streams(sim, str(path)))
    summary = inspect_log(path)
    assert {t.topic: t.count for t in summary.topics} == sim.topic_counts()
    assert not any("incomplete" in w for w in summary.warnings)


@pytest.mark.parametrize(
    ("container", "compression"), [("bag", "lz4"), ("mcap", "zstd"), ("mcap", ""), ("mcap", "lz4")]
)
def test_a_group_of_chunks_is_loaded_into_one_buffer(tmp_path, monkeypatch, sim, container, compression):
    """Chunks are decompressed into their decoding group's buffer (no copy joining them for the decoder): each
    group reaches the decoder as one batch, in order, and the streams are the simulated ones."""
    path = write_container(sim, tmp_path / f"log.{container}", container, compression)
    monkeypatch.setattr(storage, "GROUP_BYTES", 2 * CHUNK)  # several groups of several chunks: the loading thread runs
    joins = []
    concat = storage.concat
    monkeypatch.setattr(storage, "concat", lambda batches: joins.append(len(batches)) or concat(batches))
    with open_log(path) as reader:
        table = {t: c for t, (m, c) in topics_of(reader).items() if m.msgtype in LAYOUTS}
        conns = [c for cs in table.values() for c in cs]
        storages = [s for s, _, _ in container_storages(reader, conns)]
        ids = {c.id for c in conns}
        units = [u for s in storages for u in s.units if not u.conns or u.conns & ids]
        batches = list(iter_batches(reader, path, conns))
    groups = chunks.load_groups(units)
    assert len(units) > len(groups) >= 2, (len(units), len(groups))
    assert [b.data.shape[0] for b in batches] == [sum(map(chunks.slot_bytes, g)) for g in groups]
    assert all(np.all(np.diff(b.start) > 0) for b in batches)  # messages in file order within the buffer
    _same_streams(read_log(path), expected_streams(sim, str(path)))
    assert max(joins, default=1) == 1  # storage.grouped passed each group through without joining


@pytest.mark.parametrize(("container", "compression"), [("bag", "lz4"), ("mcap", "zstd")])
def test_a_groups_chunks_are_decompressed_on_two_lanes(tmp_path, monkeypatch, sim, container, compression):
    """A log of several decoding groups has each group's compressed chunks read in order by the loading thread,
    then decompressed, checked and walked on two lanes (it and ``slamobs-inflate``): the streams are the
    simulated ones, the same as on one lane (one core), and no thread is left once the log is read."""
    import threading

    path = write_container(sim, tmp_path / f"log.{container}", container, compression)
    monkeypatch.setattr(storage, "GROUP_BYTES", 4 * CHUNK)
    lanes = []
    unpack = chunks.unpack_unit
    monkeypatch.setattr(chunks, "unpack_unit", lambda *a: lanes.append(threading.current_thread().name) or unpack(*a))
    two = read_log(path)
    assert {"slamobs-chunk-reader", "slamobs-inflate"} <= {name.split("_")[0] for name in lanes}, lanes
    assert not [t for t in threading.enumerate() if t.name.startswith("slamobs-inflate")]
    lanes.clear()
    monkeypatch.setattr(chunks, "cores", lambda: 1)
    one = read_log(path)
    assert "slamobs-chunk-reader" in lanes, lanes  # one core: each unit read and decompressed in turn, as before
    assert not [name for name in lanes if name.startswith("slamobs-inflate")], lanes
    _same_streams(two, expected_streams(sim, str(path)))
    _same_streams(two, one)


def test_stream_builds_on_a_second_thread_give_the_streams_of_one(tmp_path, monkeypatch, sim):
    """A long log's streams are built on two threads (the caller from the first role, ``slamobs-streams`` from the
    last): the same streams and notes as built on the caller's thread, which a short log keeps to."""
    import threading

    import slamobs.pipeline.readers as readers

    path = write_container(sim, tmp_path / "log.mcap", "mcap", "zstd")
    where = []
    for name in ("vec3_stream", "pose_stream", "detection_stream"):
        build = getattr(readers, name)
        monkeypatch.setattr(readers, name, lambda *a, b=build: where.append(threading.current_thread().name) or b(*a))
    one = read_log(path)  # a 2 s log: fewer rows than AHEAD_ROWS
    assert where and set(where) == {"MainThread"}, where
    where.clear()
    monkeypatch.setattr(readers, "AHEAD_ROWS", 0)
    two = read_log(path)
    assert any(name.startswith("slamobs-streams") for name in where), where
    assert not [t for t in threading.enumerate() if t.name.startswith("slamobs-streams")]
    _same_streams(two, one)
    assert two.warnings == one.warnings


@pytest.mark.parametrize(("container", "compression"), [("bag", "lz4"), ("mcap", "zstd"), ("ros2-sqlite3", "")])
def test_memory_does_not_grow_with_log_length(tmp_path, monkeypatch, container, compression):
    """Peak memory beyond the decoded columns is the same for a 3 s and a 12 s log (read chunk by chunk)."""
    monkeypatch.setattr(storage, "GROUP_BYTES", CHUNK)  # chunks (and sqlite windows) decoded in groups of (16 MB) bytes
    overhead = []
    for seconds in (3.0, 12.0):
        name = f"{seconds:g}" + {"bag": ".bag", "mcap": ".mcap"}.get(container, "_ros2")
        path = write_container(simulate("circle", duration=seconds, seed=1), tmp_path / name, container, compression)
        with open_log(path) as reader:
            table = {t: c for t, (m, c) in topics_of(reader).items() if m.msgtype in LAYOUTS}
            read_rows(reader, path, table)  # warm up (kernels, typestore classes)
            tracemalloc.start()
            rows = read_rows(reader, path, table)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        columns = sum(
            r.t_ns.nbytes + r.rec_ns.nbytes + r.values.nbytes + r.frame.nbytes + r.child.nbytes for r in rows.values()
        )
        overhead.append(peak - columns)
    # the loading thread may hold PREFETCH_GROUPS decoding groups and the chunk in hand ahead of the decoder: a
    # constant, whichever log it reads ahead of (the short one may end before it is reached)
    ahead = (storage.AHEAD_GROUPS + 1) * CHUNK
    assert overhead[1] < 1.25 * overhead[0] + 64 * 1024 + ahead, overhead


# --------------------------------------------------------------------------- truncation


def _ros1_message_ends(path: Path) -> np.ndarray:
    """File offset just past each message record of an uncompressed bag, from rosbags' index."""
    ends = []
    with Bag1Reader(path) as reader, path.open("rb") as fobj:
        for entries in reader.indexes.values():
            for entry in entries:
                pos = reader.chunks[entry.chunk_pos].datapos + entry.offset
                while True:  # a connection record may precede the message the index points at
                    fobj.seek(pos)
                    header = Header.read(fobj)
                    (dlen,) = struct.unpack("<I", fobj.read(4))
                    pos = fobj.tell() + dlen
                    if header.get_uint8("op") == 2:
                        break
                ends.append(pos)
    return np.sort(np.array(ends))


def _mcap_message_ends(path: Path) -> np.ndarray:
    """File offset just past each message record of an uncompressed MCAP, from its message indexes."""
    ends = []
    with path.open("rb") as fobj:
        summary = make_reader(fobj).get_summary()
        for chunk in summary.chunk_indexes:
            records = chunk.chunk_start_offset + 9 + 28 + 4 + len(chunk.compression) + 8
            for offset in chunk.message_index_offsets.values():
                fobj.seek(offset + 9 + 2)
                (size,) = struct.unpack("<I", fobj.read(4))
                for _, at in struct.iter_unpack("<QQ", fobj.read(size)):
                    fobj.seek(records + at + 1)
                    (length,) = struct.unpack("<Q", fobj.read(8))
                    ends.append(records + at + 9 + length)
    return np.sort(np.array(ends))


def _data_end(path: Path, container: str) -> int:
    """Where the index (ROS1) or summary (MCAP) section starts."""
    if container == "bag":
        with Bag1Reader(path) as reader:
            return max(reader.chunks[c.pos].datapos + reader.chunks[c.pos].datasize for c in reader.chunk_infos)
    with path.open("rb") as fobj:
        fobj.seek(-37 + 9, 2)
        return struct.unpack("<Q", fobj.read(8))[0]


def _cut(src: Path, dst: Path, at: int) -> Path:
    dst.write_bytes(src.read_bytes()[:at])
    return dst


def _count(note: str) -> int:
    match = re.search(r"recovered (\d+) complete messages", note)
    assert match, note
    return int(match.group(1))


@pytest.mark.parametrize("container", ["bag", "mcap"])
def test_truncated_uncompressed_keeps_every_complete_message(tmp_path, sim, container):
    src = write_container(sim, tmp_path / f"full.{container}", container)
    ends = _ros1_message_ends(src) if container == "bag" else _mcap_message_ends(src)
    data_end, size = _data_end(src, container), src.stat().st_size
    full = read_log(src)
    total = len(ends)
    mid_record = int((ends[total // 3] + ends[total // 3 + 1]) // 2)  # inside one message record
    cuts = {
        "mid-record": mid_record,
        "one byte short of a record": int(ends[total // 2]) - 1,
        "right after a record": int(ends[2 * total // 3]),
        "inside the index/summary": (data_end + size) // 2,
        "last byte missing": size - 1,
    }
    for what, at in cuts.items():
        path = _cut(src, tmp_path / f"cut.{container}", at)
        want = int(np.count_nonzero(ends <= at))
        with open_log(path) as reader:
            (note,) = damage_notes(reader)
            assert reader.message_count == want, what
        assert _count(note) == want, (what, note)
        assert "stopped at byte" in note and f"of {at}" in note, note
        got = read_log(path)
        _same_streams(got, full, prefix=True)
        if at >= data_end:
            assert want == total
            _same_streams(got, full)


@pytest.mark.parametrize(
    ("container", "compression"), [("bag", "lz4"), ("bag", "bz2"), ("mcap", "zstd"), ("mcap", "lz4")]
)
def test_truncated_compressed_keeps_complete_chunks(tmp_path, sim, container, compression):
    src = write_container(sim, tmp_path / f"full.{container}", container, compression)
    data_end, size = _data_end(src, container), src.stat().st_size
    full = read_log(src)
    total = sum(sim.topic_counts().values())
    for at in (data_end // 3, data_end // 2 + 17, data_end - 5, (data_end + size) // 2):
        path = _cut(src, tmp_path / f"cut.{container}", at)
        if container == "mcap":  # the mcap library's non-seeking reader keeps complete chunks only
            kept = 0
            with pytest.raises(Exception):  # noqa: B017, PT011 - it ends with EndOfFile or struct.error
                for record in StreamReader(io.BytesIO(path.read_bytes())).records:
                    kept += isinstance(record, Message)
        else:
            kept = _complete_chunk_messages(src, at)
        with open_log(path) as reader:
            (note,) = damage_notes(reader)
        assert kept <= _count(note) <= total, (at, note)
        if at >= data_end:
            assert _count(note) == total
        got = read_log(path)
        _same_streams(got, full, prefix=True)


def _complete_chunk_messages(path: Path, at: int) -> int:
    with Bag1Reader(path) as reader:
        return sum(
            sum(info.connection_counts.values())
            for info in reader.chunk_infos
            if reader.chunks[info.pos].datapos + reader.chunks[info.pos].datasize <= at
        )


def test_unindexed_bag_is_scanned(tmp_path, sim):
    src = write_container(sim, tmp_path / "full.bag", "bag", "lz4")
    data = bytearray(src.read_bytes())
    at = data.index(b"index_pos=") + len(b"index_pos=")
    data[at : at + 8] = bytes(8)  # as a recorder leaves it until the bag is closed
    path = tmp_path / "open.bag"
    path.write_bytes(bytes(data))
    with open_log(path) as reader:
        (note,) = damage_notes(reader)
    assert "not indexed" in note and f"recovered {sum(sim.topic_counts().values())} complete" in note
    _same_streams(read_log(path), read_log(src))


def test_truncated_log_runs_and_says_so(tmp_path, sim):
    src = write_container(sim, tmp_path / "full.mcap", "mcap", "zstd")
    path = _cut(src, tmp_path / "crashed.mcap", src.stat().st_size // 2)
    summary = inspect_log(path)
    assert summary.message_count > 0 and "MCAP file is incomplete" in summary.warnings[0]
    result = CliRunner().invoke(info, [str(path)])
    assert result.exit_code == 0 and "recovered" in result.output and "Traceback" not in result.output


def test_nothing_recoverable_is_an_input_error(tmp_path, sim):
    for container in ("bag", "mcap"):
        src = write_container(sim, tmp_path / f"full.{container}", container)
        path = _cut(src, tmp_path / f"stub.{container}", 20)  # inside the file header
        with pytest.raises(InputError) as err:
            read_log(path)
        assert str(path) in str(err.value) and "\n" not in str(err.value)
    # only the magic bytes: rosbags' own words were "ord() expected a character, but string of length 0 found"
    magic = _cut(write_container(sim, tmp_path / "full2.mcap", "mcap"), tmp_path / "magic.mcap", 8)
    with pytest.raises(
        InputError, match=r"corrupt or truncated MCAP file: the file ends after its magic bytes, before"
    ):
        read_log(magic)


# --------------------------------------------------------------------------- corruption


def _chunk_messages(path: Path, container: str, k: int) -> int:
    """Messages in chunk ``k`` according to the file's index (ROS1) or message indexes (MCAP)."""
    if container == "bag":
        with Bag1Reader(path) as reader:
            return sum(reader.chunk_infos[k].connection_counts.values())
    with path.open("rb") as fobj:
        chunk = make_reader(fobj).get_summary().chunk_indexes[k]
        count = 0
        for offset in chunk.message_index_offsets.values():
            fobj.seek(offset + 9 + 2)
            (size,) = struct.unpack("<I", fobj.read(4))
            count += size // 16
        return count


@pytest.mark.parametrize(
    ("container", "compression", "where", "group"),
    [
        ("bag", "lz4", "data", 0),
        ("bag", "", "header", 0),
        ("mcap", "zstd", "data", 0),
        ("mcap", "", "data", 0),
        ("mcap", "zstd", "data", 2 * CHUNK),
    ],
)
def test_damaged_chunk_in_indexed_file_is_skipped_and_counted(
    tmp_path, monkeypatch, sim, container, compression, where, group
):
    """The index says where the next chunk starts: reading goes on after a damaged chunk (header or data), the
    damaged chunk's messages are counted as lost, every other message is read (``group``: chunks decompressed
    into decoding groups of that many bytes, loaded on the reading thread; 0: the whole log is one group)."""
    if group:
        monkeypatch.setattr(storage, "GROUP_BYTES", group)
    src = write_container(sim, tmp_path / f"full.{container}", container, compression)
    data = bytearray(src.read_bytes())
    if container == "bag":
        with Bag1Reader(src) as reader:
            info = reader.chunk_infos[1]
            chunk = reader.chunks[info.pos]
            middle = chunk.datapos + chunk.datasize // 2
        if where == "header":
            data[info.pos + 4 : info.pos + 12] = b"\xff" * 8  # the first header field's length and name
    else:
        with src.open("rb") as fobj:
            chunk = make_reader(fobj).get_summary().chunk_indexes[1]
            middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    if where == "data":  # no checksum in ROS1: break the compressed stream itself; MCAP: compression or CRC
        data[middle : middle + 1024] = bytes(1024)
    path = tmp_path / f"bad.{container}"
    path.write_bytes(bytes(data))
    full, got = read_log(src), read_log(path)
    lost = _chunk_messages(src, container, 1)
    notes = [w for w in got.warnings if "damaged chunk" in w]
    assert len(notes) == 1 and f"{lost} messages lost" in notes[0], got.warnings
    roles = ("angular_velocity", "linear_velocity", "truth")
    missing = sum(len(getattr(full, r)) - len(getattr(got, r)) for r in roles)
    assert 0 < missing <= lost, (missing, lost)
    for role in roles:  # the chunks after the damaged one are read
        assert getattr(got, role).t_ns[-1] == getattr(full, role).t_ns[-1], role


# --------------------------------------------------------------------------- unusual content


def test_empty_topic_nan_inf_and_odd_detections(tmp_path):
    ts = make_typestore(ros1=True)
    t = ts.types
    path = tmp_path / "odd.bag"
    stamp = t["builtin_interfaces/msg/Time"]
    vec = t["geometry_msgs/msg/Vector3"]
    quat = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    zeros9 = np.zeros(9)
    gyro = [(0.1, 0, 0), (float("nan"), 0, 0), (float("inf"), 0, 0), (0.4, -0.0, 0), (0.5, 0, float("-inf"))]
    with Bag1Writer(path) as writer:
        imu_conn = writer.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
        writer.add_connection("/empty", "sensor_msgs/msg/Imu", typestore=ts)
        det_conn = writer.add_connection("/fiducial_transforms", FIDUCIALS, typestore=ts)
        for k, g in enumerate(gyro):
            header = t["std_msgs/msg/Header"](seq=k, stamp=stamp(sec=100, nanosec=k * 10_000_000), frame_id="imu")
            msg = t["sensor_msgs/msg/Imu"](
                header=header,
                orientation=quat,
                orientation_covariance=zeros9,
                angular_velocity=vec(x=float(g[0]), y=float(g[1]), z=float(g[2])),
                angular_velocity_covariance=zeros9,
                linear_acceleration=vec(x=0.0, y=0.0, z=9.8),
                linear_acceleration_covariance=zeros9,
            )
            writer.write(imu_conn, 100 * 10**9 + k * 10**7, ts.serialize_ros1(msg, "sensor_msgs/msg/Imu"))
            dets = [] if k % 2 else [(7, 1.0), (7, 2.0), (8, float("nan"))]  # empty frames, repeated id, NaN
            items = [
                t["fiducial_msgs/msg/FiducialTransform"](
                    fiducial_id=i,
                    transform=t["geometry_msgs/msg/Transform"](translation=vec(x=x, y=0.0, z=1.0), rotation=quat),
                    image_error=0.0,
                    object_error=0.0,
                    fiducial_area=0.0,
                )
                for i, x in dets
            ]
            array = t[FIDUCIALS](header=header, image_seq=k, transforms=items)
            writer.write(det_conn, 100 * 10**9 + k * 10**7, ts.serialize_ros1(array, FIDUCIALS))
    streams = read_log(path)
    np.testing.assert_array_equal(streams.angular_velocity.xyz[:, 0], [0.1, 0.4])
    assert np.signbit(streams.angular_velocity.xyz[1, 1])  # -0.0 survives the raw decoding
    np.testing.assert_array_equal(streams.accel.xyz[:, 2], np.full(5, 9.8))
    assert any("3 NaN/Inf samples dropped" in w for w in streams.warnings)
    det = streams.detections
    np.testing.assert_array_equal(det.offsets, [0, 1, 1, 2, 2, 3])
    np.testing.assert_array_equal(det.ids, [7, 7, 7])
    empty = read_log(path, {"angular_velocity": "/empty", "accel": ""}).angular_velocity
    assert empty is not None and len(empty) == 0
    summary = inspect_log(path)
    assert next(t for t in summary.topics if t.topic == "/empty").count == 0


@pytest.mark.parametrize("container", ["ros2-sqlite3", "ros2-mcap"])
def test_rosbag2_directory_without_metadata(tmp_path, sim, container):
    """A recording that crashed leaves its storage file but no metadata.yaml: the file is read, and the run
    says how; with several storage files it is a one-line error naming the directory."""
    path = write_container(sim, tmp_path / "crashed", container)
    (path / "metadata.yaml").unlink()
    (storage,) = [p for p in path.iterdir() if p.suffix in {".db3", ".mcap"}]
    got = read_log(path)
    assert got.warnings[0] == f"crashed has no metadata.yaml (recording not closed?): read {storage.name} directly"
    _same_streams(got, expected_streams(sim, str(path)))
    assert inspect_log(path).warnings[0] == got.warnings[0]

    (path / f"second{storage.suffix}").write_bytes(storage.read_bytes())
    with pytest.raises(InputError, match=r"crashed.*no metadata.yaml and 2 storage files") as err:
        read_log(path)
    assert "\n" not in str(err.value)
    # both named, with the command that writes a metadata.yaml for the parts of an unclosed split recording
    assert f"second{storage.suffix}" in str(err.value) and storage.name in str(err.value)
    assert f"`ros2 bag reindex {path}` writes its metadata.yaml" in str(err.value)


@pytest.mark.parametrize(
    ("container", "said", "files"), [("ros2-sqlite3", "mcap", "sqlite3"), ("ros2-mcap", "sqlite3", "mcap")]
)
def test_rosbag2_metadata_naming_another_storage(tmp_path, sim, container, said, files):
    """A metadata.yaml whose storage_identifier is not its files' storage was 'corrupt or truncated rosbag2
    directory (mcap): File magic is invalid.': now one line naming both and the fix."""
    path = write_container(sim, tmp_path / "swapped", container)
    meta = path / "metadata.yaml"
    meta.write_text(re.sub(r"storage_identifier: \S+", f"storage_identifier: {said}", meta.read_text()))
    for read in (read_log, inspect_log):
        with pytest.raises(InputError) as err:
            read(path)
        msg = str(err.value)
        assert msg.startswith(f"{path}: metadata.yaml says storage_identifier: {said}, but its storage files are")
        assert f"set storage_identifier: {files} " in msg and "\n" not in msg


@pytest.mark.parametrize("text", ["", "\n  \n"])
def test_rosbag2_directory_with_an_empty_metadata_file(tmp_path, sim, text):
    """A recording that crashed while writing metadata.yaml leaves it empty: read like one without it (rosbags
    failed with "Invalid bag metadata: 'NoneType' object is not subscriptable")."""
    path = write_container(sim, tmp_path / "crashed", "ros2-sqlite3")
    (path / "metadata.yaml").write_text(text)
    (storage,) = [p for p in path.iterdir() if p.suffix == ".db3"]
    got = read_log(path)
    assert got.warnings[0] == (
        f"crashed has an empty metadata.yaml (recording not closed?): read {storage.name} directly"
    )
    _same_streams(got, expected_streams(sim, str(path)))
    storage.unlink()
    with pytest.raises(InputError, match=r"crashed: not a ROS1 bag, .* \(its metadata.yaml is empty\)$"):
        inspect_log(path)


@pytest.mark.parametrize("container", ["ros2-sqlite3", "ros2-mcap"])
def test_the_parts_of_an_unclosed_split_rosbag2_recording_are_read_in_order(tmp_path, sim, container):
    """A split recording that crashed leaves NAME_0, NAME_1, ... without metadata.yaml: every part is read, in order
    (it was an error asking to open one file, half the recording)."""
    whole = write_container(sim, tmp_path / "whole", container)
    crashed = tmp_path / "crashed"
    crashed.mkdir()
    plugin = StoragePlugin.MCAP if container == "ros2-mcap" else StoragePlugin.SQLITE3
    with Bag2Reader(whole) as reader:
        cut = (reader.start_time + reader.end_time) // 2
        writers = [Bag2Writer(tmp_path / f"part{k}", version=9, storage_plugin=plugin) for k in (0, 1)]
        conns: list[dict] = [{}, {}]
        for w in writers:
            w.open()
        for conn, t, raw in reader.messages():
            k = int(t >= cut)
            if conn.id not in conns[k]:
                conns[k][conn.id] = writers[k].add_connection(
                    conn.topic,
                    conn.msgtype,
                    msgdef=conn.msgdef.data,
                    rihs01=conn.digest,
                    offered_qos_profiles=conn.ext.offered_qos_profiles,
                )
            writers[k].write(conns[k][conn.id], t, raw)
        for w in writers:
            w.close()
    for k in (0, 1):
        (storage_file,) = [p for p in (tmp_path / f"part{k}").iterdir() if p.suffix in {".db3", ".mcap"}]
        storage_file.rename(crashed / f"crashed_{k}{storage_file.suffix}")  # named after the directory, as rosbag2 does
    got = read_log(crashed)
    suffix = ".mcap" if container == "ros2-mcap" else ".db3"
    assert got.warnings[0] == "crashed has no metadata.yaml (recording not closed?): read its 2 files"
    assert got.warnings[1].startswith(f"split recording of 2 {suffix} files read as one: crashed_0{suffix} 0.000–")
    _same_streams(got, expected_streams(sim, str(crashed)))


def test_corrupt_uncompressed_chunk_is_damaged(tmp_path):
    """A byte changed inside an uncompressed chunk's records (their structure intact) fails the chunk's CRC: the
    chunk is skipped and counted, as zlib's CRC-32 would say."""
    sim = simulate("figure8", duration=2.0, seed=3)
    src = write_container(sim, tmp_path / "full.mcap", "mcap")
    data = bytearray(src.read_bytes())
    with src.open("rb") as fobj:
        index = make_reader(fobj).get_summary().chunk_indexes[1]
    assert index.compression == "" and index.uncompressed_size > 0
    last = index.chunk_start_offset + index.chunk_length - 1  # the last byte of the last message's payload
    data[last] ^= 0x01
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(data))
    got = read_log(path)
    notes = [w for w in got.warnings if "damaged chunk" in w]
    assert len(notes) == 1 and "fails its checksum" in notes[0], got.warnings


def _ros2_log_with_metadata(out, old: str, new: str):
    """A generated ROS2 .db3 directory (a 2 s figure 8) whose metadata.yaml has ``old`` replaced by ``new``."""
    from slamobs.pipeline.simulate import write_log

    log = write_log(simulate("figure8", seed=5, duration=2.0), out, "ros2")
    meta = log / "metadata.yaml"
    assert old in meta.read_text()
    meta.write_text(meta.read_text().replace(old, new))
    return log


def test_a_db3_whose_metadata_leaves_a_topic_type_empty_names_that_topic(tmp_path):
    # a generated ROS2 .db3 whose metadata.yaml gives /fiducial_transforms the type '': the run said only that the
    # detections were missing
    from slamobs.pipeline.alignment import check_required

    log = _ros2_log_with_metadata(
        tmp_path / "damaged_ros2", "type: fiducial_msgs/msg/FiducialTransformArray", "type: ''"
    )
    streams = read_log(log)
    assert streams.untyped == ["/fiducial_transforms"] and streams.detections is None
    with pytest.raises(InputError) as err:
        check_required(streams, needed_by="riekf")
    assert str(err.value) == (
        f"{log}: the log cannot run: 1 of the 3 inputs needed by riekf is missing (detections), and "
        "/fiducial_transforms has its message type empty in the log's metadata (not read); `slamobs info` shows what "
        "it has"
    )


def test_a_db3_whose_metadata_lost_a_topic_type_line_names_the_topic_and_the_stored_type(tmp_path):
    # a generated ROS2 .db3 whose metadata.yaml has /fiducial_transforms' `type:` line removed: it was "corrupt or
    # truncated rosbag2 directory (sqlite3): A metadata key is missing KeyError('type')." (no file, no topic)
    log = _ros2_log_with_metadata(
        tmp_path / "untyped_ros2", "      type: fiducial_msgs/msg/FiducialTransformArray\n", ""
    )
    (db3,) = log.glob("*.db3")
    for read in (read_log, inspect_log):
        with pytest.raises(InputError) as err:
            read(log)
        assert str(err.value) == (
            f"{log}: metadata.yaml: topic /fiducial_transforms has no `type:` key (rosbags reads no topic of the "
            f"directory without it); {db3.name} records its type, fiducial_msgs/msg/FiducialTransformArray: add "
            "`type: fiducial_msgs/msg/FiducialTransformArray` to that topic's topic_metadata in metadata.yaml, or "
            f"give {db3} itself (its topics are read without metadata.yaml)"
        )
    assert read_log(db3).detections is not None  # the way out the message names reads the detections
