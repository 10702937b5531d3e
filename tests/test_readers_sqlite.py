"""rosbag2 sqlite3 (db3) reading: windows of row ids aimed at a decoding group, the next one queried by a thread.

The decoded columns are the same bits whether the log is read in one window (the caller's thread) or in many
(the read-ahead thread), and the same as from the same simulation written as MCAP; stopping early leaves no
thread running; a database that SQLite finds malformed while a window is read still gives its one-line error.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import tempfile
import struct
import threading
from pathlib import Path

import numpy as np
import pytest

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.readers import read_log, rosbag2_sqlite, sqlitefile, storage
from slamobs.pipeline.readers.container import iter_batches, open_log
from slamobs.pipeline.readers.container import storages as container_storages
from slamobs.pipeline.readers.fastdecode import read_rows
from slamobs.pipeline.readers.roles import topics_of
from slamobs.pipeline.readers.rows import LAYOUTS
from slamobs.pipeline.simulate import make_typestore, simulate, write_log
from slamobs.pipeline.simulate.logwriter import write_raw_log

THREAD = "slamobs-sqlite-reader"
SMALL_GROUP = 64 * 1024  # the 6 s log's ~0.7 MB of payload in about ten windows


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("db3")
    sim = simulate("figure8", duration=6.0, seed=3)
    return write_log(sim, tmp / "log_ros2", "ros2"), write_log(sim, tmp / "log.mcap", "mcap")


def _threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == THREAD]


def _rows(path: Path) -> dict[str, tuple]:
    with open_log(path) as reader:
        table = {t: c for t, (m, c) in topics_of(reader).items() if m.msgtype in LAYOUTS}
        rows = read_rows(reader, path, table)
    return {
        t: (r.t_ns, r.rec_ns, r.values.view(np.uint64), [r.frame_names[k] for k in r.frame]) for t, r in rows.items()
    }


def _assert_same_bits(got: dict[str, tuple], want: dict[str, tuple]) -> None:
    assert got.keys() == want.keys()
    for topic, (t_ns, rec_ns, bits, frames) in got.items():
        np.testing.assert_array_equal(t_ns, want[topic][0], err_msg=topic)
        np.testing.assert_array_equal(rec_ns, want[topic][1], err_msg=topic)
        np.testing.assert_array_equal(bits, want[topic][2], err_msg=topic)
        assert frames == want[topic][3], topic


def test_windows_decode_the_same_bits_in_one_window_or_many(logs, monkeypatch):
    db3, mcap = logs
    whole = _rows(db3)  # the log is one window: read on the caller's thread
    assert len(whole) >= 4 and all(v[0].size for v in whole.values())
    _assert_same_bits(whole, _rows(mcap))  # the same simulation through the MCAP reader

    windows = []
    ahead = rosbag2_sqlite.read_ahead

    def counted(batches, name):
        for batch in ahead(batches, name):
            windows.append(bool(_threads()))  # the reading thread runs while the batch is decoded
            yield batch

    monkeypatch.setattr(rosbag2_sqlite, "read_ahead", counted)
    monkeypatch.setattr(storage, "GROUP_BYTES", SMALL_GROUP)
    _assert_same_bits(_rows(db3), whole)
    assert len(windows) >= 5 and windows[0], windows  # many windows, read ahead by the thread
    assert not _threads()


def _sqlite_batches(reader, path: Path):
    conns = [c for _, (m, cs) in topics_of(reader).items() if m.msgtype in LAYOUTS for c in cs]
    ((db, ids, _),) = list(container_storages(reader, conns))
    return db.batches(ids, False), conns


def test_closing_early_stops_the_reading_thread(logs, monkeypatch):
    db3, _ = logs
    monkeypatch.setattr(storage, "GROUP_BYTES", SMALL_GROUP)
    with open_log(db3) as reader:
        batches, conns = _sqlite_batches(reader, db3)
        first = next(batches)
        assert len(first) and _threads()  # the thread queries the next windows
        batches.close()  # the decoder failed, or the run was cancelled
        assert not _threads()

        with pytest.raises(KeyboardInterrupt):  # Ctrl-C while a batch is decoded
            for k, _batch in enumerate(iter_batches(reader, db3, conns)):
                if k == 1:
                    raise KeyboardInterrupt
        assert not _threads()
        assert sum(map(len, iter_batches(reader, db3, conns))) == sum(c.msgcount for c in conns)  # still readable


def _malformed_copy(src: Path, dst: Path) -> Path:
    """``src`` with one IMU row two thirds in whose record header claims a longer payload than it holds: rosbags
    opens it (its counts read only ``topic_id``), SQLite finds it malformed once a query reads ``data``."""
    shutil.copytree(src, dst)
    (db3,) = dst.glob("*.db3")
    data = bytearray(db3.read_bytes())
    with sqlite3.connect(db3) as db:
        (n,) = db.execute("SELECT count(*) FROM messages").fetchone()
        size, payload = db.execute(
            "SELECT length(data), data FROM messages WHERE id > ? "
            "AND topic_id = (SELECT id FROM topics WHERE name = '/imu/data') LIMIT 1",
            (2 * n // 3,),
        ).fetchone()
    at = data.find(payload)
    serial = 2 * size + 12  # a blob's serial type; its record: header (6 bytes), topic id (1), timestamp (8), data
    assert data[at - 15 : at - 9] == bytes([6, 0, 1, 6, 0x80 | serial >> 7, serial & 0x7F])
    data[at - 11] += 1  # the data now claims 64 bytes more than the record holds
    db3.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize("group", [None, SMALL_GROUP])
def test_a_malformed_database_is_one_line_naming_the_file(logs, tmp_path, monkeypatch, group):
    """The same line whether SQLite meets the damage on the caller's thread (one window) or on the reading
    thread after several windows were decoded."""
    bad = _malformed_copy(logs[0], tmp_path / "bad_ros2")
    if group is not None:
        monkeypatch.setattr(storage, "GROUP_BYTES", group)
    with pytest.raises(InputError) as err:
        read_log(bad)
    assert str(err.value) == (
        f"{bad}: corrupt or truncated rosbag2 directory (sqlite3): database disk image is malformed"
    )
    assert not _threads()


def _string(n: int) -> bytes:
    """A CDR ``std_msgs/String`` of ``n`` characters."""
    return b"\x00\x01\x00\x00" + struct.pack("<I", n + 1) + b"x" * n + b"\x00"


def test_a_window_after_light_rows_holds_a_few_groups_of_heavy_ones(tmp_path, monkeypatch):
    """3,000 light rows, then 300 of 20 kB (a camera that started late): the window sized after the light rows
    (64 kB of them: ~1,300 rows) would hold 26 MB of the heavy ones; it spans at most WINDOW_SPAN groups at the
    database's bytes per row."""
    monkeypatch.setattr(storage, "GROUP_BYTES", SMALL_GROUP)
    monkeypatch.setattr(rosbag2_sqlite, "_table", lambda reader: None)  # SQLite's windows (pages: a group at most)
    topics = {
        "/light": [(k * 1000, _string(50)) for k in range(3000)],
        "/heavy": [(k * 1000 + 500, _string(20_000)) for k in range(300)],
    }
    path = write_raw_log(tmp_path / "late_ros2", "ros2", topics, "std_msgs/msg/String", make_typestore(ros1=False))
    (db3,) = path.glob("*.db3")
    with sqlite3.connect(db3) as db:
        assert db.execute("SELECT topic_id FROM messages ORDER BY id").fetchall()[2999:3001] == [(1,), (2,)]
        (rows,) = db.execute("SELECT count(*) FROM messages").fetchone()
    most = rosbag2_sqlite.WINDOW_SPAN * int(SMALL_GROUP / (db3.stat().st_size / rows))
    with open_log(path) as reader:
        ((db, ids, _),) = list(container_storages(reader, reader.connections))
        sizes = [b.data.shape[0] for b in db.batches(ids, False)]
    assert sum(sizes) == 3000 * len(_string(50)) + 300 * len(_string(20_000))
    assert max(sizes) <= most * len(_string(20_000)), (max(sizes), most)


# --------------------------------------------------------------------------- the messages table's pages read directly


def _interleaved_db3(tmp_path: Path, page_size: int) -> Path:
    """Light rows of two topics and heavy ones (20 kB: their payloads go on in overflow pages), rewritten in record
    time order (the topics' rows interleaved on the pages) with pages of ``page_size`` bytes."""
    topics = {
        "/light": [(k * 1000, _string(50)) for k in range(600)],
        "/heavy": [(k * 10_000 + 500, _string(20_000 + k)) for k in range(60)],
        "/other": [(k * 2000 + 300, _string(100)) for k in range(300)],
    }
    path = write_raw_log(tmp_path / "mixed_ros2", "ros2", topics, "std_msgs/msg/String", make_typestore(ros1=False))
    (db3,) = path.glob("*.db3")
    db = sqlite3.connect(db3, isolation_level=None)
    (n,) = db.execute("SELECT max(id) FROM messages").fetchone()
    columns = "topic_id, timestamp, data"
    db.execute(f"INSERT INTO messages ({columns}) SELECT {columns} FROM messages ORDER BY timestamp")
    db.execute("DELETE FROM messages WHERE id <= ?", (n,))
    db.execute(f"PRAGMA page_size = {page_size}")
    db.execute("VACUUM")
    db.close()
    return path


def _flat_batches(path: Path, topics: set[str]) -> tuple[np.ndarray, np.ndarray, list[bytes]]:
    with open_log(path) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        ((db, ids, _),) = list(container_storages(reader, conns))
        batches = list(db.batches(ids, False))
    conn = np.concatenate([b.conn for b in batches])
    rec = np.concatenate([b.rec_ns for b in batches])
    return conn, rec, [b.payload(i) for b in batches for i in range(len(b))]


def _assert_same_rows(got: tuple, want: tuple) -> None:
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[2] == want[2]


@pytest.mark.parametrize("group", [None, 4096])
@pytest.mark.parametrize("page_size", [1024, 4096])
def test_pages_read_directly_give_the_rows_sqlite_gives(tmp_path, monkeypatch, group, page_size):
    """Rows of two of three interleaved topics (the third's payloads in overflow pages), in one window or many:
    the same rows, in the same order, with the same bytes as SQLite's query hands over. A wanted payload in
    overflow pages stops the walk: SQLite reads from there, and the rows are the same again."""
    path = _interleaved_db3(tmp_path, page_size)
    if group is not None:
        monkeypatch.setattr(storage, "GROUP_BYTES", group)
    walked, after = [], []
    real_window, real_by_sql = sqlitefile.read_window, rosbag2_sqlite.rows_by_sql
    monkeypatch.setattr(sqlitefile, "read_window", lambda *a: walked.append(a[1]) or real_window(*a))
    monkeypatch.setattr(rosbag2_sqlite, "rows_by_sql", lambda *a: after.append(a[-1]) or real_by_sql(*a))
    got = _flat_batches(path, {"/light", "/other"})
    assert len(walked) > 10 if group else len(walked) == 1, walked  # read from the pages, SQLite not asked
    assert not after and len(got[2]) == 900
    heavy = _flat_batches(path, {"/light", "/heavy"})
    assert len(after) == 1 and {len(p) for p in heavy[2]} > {len(_string(20_000))}
    monkeypatch.setattr(rosbag2_sqlite, "_table", lambda reader: None)  # SQLite's group_concat windows
    _assert_same_rows(got, _flat_batches(path, {"/light", "/other"}))
    _assert_same_rows(heavy, _flat_batches(path, {"/light", "/heavy"}))


@pytest.mark.parametrize("piece", [1, 3])
def test_pages_walked_a_few_at_a_time_give_the_rows_sqlite_gives(tmp_path, monkeypatch, piece):
    """Leaf pages read and walked ``PIECE`` at a time, the rows' arrays grown when a page's cells do not fit (light
    rows: ~40 a page against the 16 a page first made room for): the rows SQLite's query hands over."""
    topics = {
        "/light": [(k * 1000, _string(50)) for k in range(600)],
        "/other": [(k * 2000 + 300, _string(100)) for k in range(300)],
    }
    path = write_raw_log(tmp_path / "light_ros2", "ros2", topics, "std_msgs/msg/String", make_typestore(ros1=False))
    grown = []
    real_grown = sqlitefile.grown_rows
    monkeypatch.setattr(sqlitefile, "grown_rows", lambda *a: grown.append(a[1]) or real_grown(*a))
    monkeypatch.setattr(sqlitefile, "PIECE", piece)
    got = _flat_batches(path, {"/light", "/other"})
    assert grown and len(got[2]) == 900
    monkeypatch.setattr(rosbag2_sqlite, "_table", lambda reader: None)  # SQLite's group_concat windows
    _assert_same_rows(got, _flat_batches(path, {"/light", "/other"}))


def test_a_row_the_walk_does_not_take_leaves_the_rest_to_sqlite(tmp_path, monkeypatch):
    """A row whose data SQLite stores as text (a blob is what rosbag2 writes) stops the walk at its page: the rows
    before it come from the pages, the rest from SQLite, and together they are the rows SQLite alone gives."""
    path = _interleaved_db3(tmp_path, 1024)
    (db3,) = path.glob("*.db3")
    with sqlite3.connect(db3) as db:
        (mid,) = db.execute(
            "SELECT id FROM messages WHERE topic_id = (SELECT id FROM topics WHERE name = '/other') LIMIT 1 OFFSET 150"
        ).fetchone()
        db.execute("UPDATE messages SET data = CAST(data AS TEXT) WHERE id = ?", (mid,))
    after = []
    real_by_sql = rosbag2_sqlite.rows_by_sql
    monkeypatch.setattr(rosbag2_sqlite, "rows_by_sql", lambda *a: after.append(a[-1]) or real_by_sql(*a))
    got = _flat_batches(path, {"/light"})
    assert len(after) == 1 and 0 < after[0] < mid  # the pages before the text row were read directly
    monkeypatch.setattr(rosbag2_sqlite, "_table", lambda reader: None)
    _assert_same_rows(got, _flat_batches(path, {"/light"}))


@pytest.mark.parametrize("child", ["past the end", "the root", "page 1"])
def test_a_damaged_tree_is_not_walked(logs, tmp_path, child):
    """An interior page of the messages table naming a page past the file's end, itself (a loop) or the schema's
    page: no leaf list, or the walk stops at the page that is no leaf (SQLite reads such a file, or reports it, as
    before); the intact tree gives its leaves."""
    (db3,) = logs[0].glob("*.db3")
    with sqlite3.connect(db3) as db:
        (root,) = db.execute("SELECT rootpage FROM sqlite_master WHERE name = 'messages'").fetchone()
        (page,) = db.execute("PRAGMA page_size").fetchone()
    data = bytearray(db3.read_bytes())
    intact = sqlitefile.open_table(db3, root)
    assert intact is not None and intact.leaves.size > 10 and data[(root - 1) * page] == 5  # an interior root
    target = {"past the end": len(data) // page + 10, "the root": root, "page 1": 1}[child]
    data[(root - 1) * page + 8 : (root - 1) * page + 12] = target.to_bytes(4, "big")  # its right-most child
    bad = tmp_path / "bad.db3"
    bad.write_bytes(bytes(data))
    table = sqlitefile.open_table(bad, root)
    if child == "the root":  # the leaves' level ends with the root, an interior page: the window stops there
        ids = storage.ConnIds({k: k for k in range(1, 10)})
        _, done, _, stopped = sqlitefile.read_window(table, 0, 1 << 30, ids)
        assert stopped and table.leaves[done] == root
    else:
        assert table is None


def _wal_crash(src: Path, tmp_path: Path) -> Path:
    """A copy of ``src`` as a crashed recording in WAL mode leaves it: its later half still in the -wal file."""
    work = tmp_path / "work" / src.name
    work.parent.mkdir()
    shutil.copyfile(src, work)
    con = sqlite3.connect(work)
    n = con.execute("SELECT count(*) FROM messages").fetchone()[0]
    later = con.execute("SELECT id, topic_id, timestamp, data FROM messages WHERE id > ?", (n // 2,)).fetchall()
    con.execute("DELETE FROM messages WHERE id > ?", (n // 2,))
    con.commit()
    con.execute("VACUUM")
    con.execute("PRAGMA journal_mode=WAL")
    con.execute("PRAGMA wal_autocheckpoint=0")
    con.executemany("INSERT INTO messages (id, topic_id, timestamp, data) VALUES (?, ?, ?, ?)", later)
    con.commit()
    crashed = tmp_path / "crashed"  # the files as the crash left them (the connection never closed)
    crashed.mkdir()
    for suffix in ("", "-wal"):
        shutil.copyfile(f"{work}{suffix}", crashed / f"{src.name}{suffix}")
    con.close()
    return crashed


def test_a_recording_in_wal_mode_that_was_not_closed_is_read_whole(logs, tmp_path):
    # rosbag2's 'resilient' preset writes in WAL mode: a crashed recording leaves the latest messages in its -wal
    # file, which rosbags' immutable open did not read (half the messages were lost without a word)
    src = next(logs[0].glob("*.db3"))
    crashed = _wal_crash(src, tmp_path)
    before = {p.name: p.read_bytes() for p in crashed.iterdir()}
    _assert_same_bits(_rows(crashed / src.name), _rows(src))
    got = read_log(crashed / src.name)
    assert any(
        w.startswith(f"{src.name}: a recording in WAL mode that was not closed: its {src.name}-wal")
        for w in got.warnings
    )
    assert {p.name: p.read_bytes() for p in crashed.iterdir()} == before  # the log itself is never written


def test_a_wal_copy_left_by_a_killed_reader_is_removed_by_the_next(logs, tmp_path, monkeypatch):
    # the copy a WAL recording is read from lives in the temporary directory; a SIGKILL left it there (as large as
    # the recording), and every later kill left one more
    from slamobs.pipeline.lifetime import owner_marker

    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    src = next(logs[0].glob("*.db3"))
    crashed = _wal_crash(src, tmp_path)
    markers = {
        "slamobs-wal-killed": {**owner_marker(), "start": "0"},  # this pid, another start time: a dead process
        "slamobs-wal-live": owner_marker(),  # a reader still running (this process)
        "slamobs-wal-unmarked": None,  # not known to be ours
    }
    for name, owner in markers.items():
        (temp / name).mkdir()
        (temp / name / "copy.db3").write_bytes(b"x" * 1000)
        if owner is not None:
            (temp / name / rosbag2_sqlite.COPY_OWNER).write_text(json.dumps(owner))
    read_log(crashed / src.name)
    assert sorted(p.name for p in temp.iterdir()) == ["slamobs-wal-live", "slamobs-wal-unmarked"]  # its own: gone
