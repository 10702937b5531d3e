"""rosbag2 sqlite3 storage (``.db3``, bare or a rosbag2 directory's): rosbags' reader, its rows read in bulk.

rosbags' own reader (and its file-wise zstd decompression of a directory) opens the database; the messages of
the requested topics are read in blocks of rows instead of one query result at a time, each block one
:class:`.storage.RawBatch`: straight from the ``messages`` table's pages in the file (:mod:`.sqlitefile`), or,
where those are not read directly, by SQLite in windows of row ids.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import tempfile
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

from slamobs.pipeline import interrupts
from slamobs.pipeline.lifetime import owner_alive, owner_marker

from . import sqlitefile, storage
from .storage import ConnIds, RawBatch, joined, read_ahead

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from apsw import Connection

#: What an sqlite3 database starts with.
MAGIC = b"SQLite format 3\x00"

SQL_ROWS, SQL_BYTES = 8192, 1 << 20  # an ordered batch of rows stops at either (like a chunk: bounded memory)

WINDOW_ROWS = 1 << 20  # a window of row ids holds at most this many (its three number texts stay a few MB)
#: ... and at most the rows of this many decoding groups at the database's bytes per row: a window sized after a
#: stretch of light rows (IMU alone, before a camera started) then holds at most a few groups of the heavy ones.
WINDOW_SPAN = 4

THREAD = "slamobs-sqlite-reader"  # the read-ahead thread's name


#: A write-ahead log longer than its header holds frames (SQLite's WAL header is 32 bytes).
WAL_HEADER = 32
#: The temporary directory holding a WAL recording's checkpointed copy (in the system's temporary directory), and
#: the marker naming the process that made it (:func:`remove_stale_copies`).
COPY_PREFIX, COPY_OWNER = "slamobs-wal-", "slamobs-owner.json"


def remove_stale_copies(root: str | Path | None = None) -> list[str]:
    """Remove the WAL copies that killed readers left in ``root`` (default: the system's temporary directory; a
    SIGKILL runs no cleanup, and a copy is as large as the recording); returns their names. Only directories named
    ``slamobs-wal-*`` holding an owner marker whose process is no longer running are touched: a live reader's copy,
    and anything without the marker, are left alone."""
    removed = []
    for d in Path(root or tempfile.gettempdir()).glob(f"{COPY_PREFIX}*"):
        try:
            owner = json.loads((d / COPY_OWNER).read_text())
            if not isinstance(owner, dict) or owner_alive(owner):
                continue
        except (OSError, ValueError):
            continue  # no marker (not ours, or one being made), or unreadable
        shutil.rmtree(d, ignore_errors=True)
        removed.append(d.name)
    return removed


class Sqlite3Storage(Sqlite3Reader):
    """rosbags' sqlite3 reader with the messages of several topics read in blocks of rows.

    rosbags opens the database ``immutable``: of a recording in WAL mode (rosbag2's ``resilient`` storage preset)
    that was not closed, the messages still in its ``-wal`` file would not be read. Such a file is applied to a
    temporary copy of the database, which is read instead (the log itself is never written); a copy that a killed
    reader left behind is removed by the next one (:func:`remove_stale_copies`)."""

    _copy: tempfile.TemporaryDirectory | None = None
    _wal_note: str = ""

    def open(self) -> None:
        """Open the database, or a copy with its write-ahead log applied."""
        wal = Path(f"{self.path}-wal") if isinstance(self.path, Path) else None
        if wal is not None and wal.is_file() and wal.stat().st_size > WAL_HEADER:
            remove_stale_copies()
            self._copy = tempfile.TemporaryDirectory(prefix=COPY_PREFIX)
            interrupts.at_end(self._copy.cleanup)  # a signal that ends the process in numba's compiler removes it
            (Path(self._copy.name) / COPY_OWNER).write_text(json.dumps(owner_marker()))  # before the copy
            original, self.path = self.path, _checkpointed(self.path, wal, Path(self._copy.name))
            self._wal_note = (
                f"{original.name}: a recording in WAL mode that was not closed: its {wal.name} "
                f"({wal.stat().st_size} bytes written after the last checkpoint) was applied to a temporary copy"
            )
        try:
            super().open()
        except BaseException:
            self._drop_copy()
            raise

    def close(self) -> None:
        """Close the database and remove the copy, if any."""
        try:
            super().close()
        finally:
            self._drop_copy()

    def _drop_copy(self) -> None:
        copy, self._copy = self._copy, None
        if copy is not None:
            interrupts.not_at_end(copy.cleanup)
            copy.cleanup()

    def batches(self, ids: ConnIds, ordered: bool) -> Iterator[RawBatch]:
        """Rows of the requested topics (see :func:`_sqlite_batches`)."""
        return _sqlite_batches(self, ids, ordered)

    def damage_texts(self) -> list[str]:
        """A write-ahead log applied to a copy; a damaged database is refused, not recovered."""
        return [self._wal_note] if self._wal_note else []


def _checkpointed(db: Path, wal: Path, into: Path) -> Path:
    """A copy of ``db`` in ``into`` with the frames of its write-ahead log ``wal`` written into it."""
    copy = into / db.name
    shutil.copyfile(db, copy)
    shutil.copyfile(wal, into / wal.name)
    con = sqlite3.connect(copy)
    try:
        con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    finally:
        con.close()
    return copy


def _sqlite_batches(reader: Sqlite3Reader, ids: ConnIds, ordered: bool) -> Iterator[RawBatch]:
    """Rows of the requested topics in blocks.

    Unordered (the columnar path), in row id order: read from the table's pages (:func:`_from_pages`), else
    SQLite itself concatenates the payloads of a window of row ids (``group_concat``, in C; :func:`_windows`), so
    Python handles a few objects per block instead of three per row; the decoded columns are sorted by record time
    afterwards. Ordered, rows come by timestamp, in
    blocks of about ``SQL_BYTES`` (ordered reads are rare: decoding through rosbags, e.g. a type without a plan).
    """
    assert reader.dbconn
    db = reader.dbconn
    wanted = ids.ids.tolist()
    among = f"topic_id IN ({','.join('?' * len(wanted))})"
    text_is_bytes = next(iter(db.execute("PRAGMA encoding")))[0] == "UTF-8"
    if ordered or not text_is_bytes:
        cursor = db.execute(f"SELECT topic_id, timestamp, data FROM messages WHERE {among} ORDER BY timestamp", wanted)
        rows: list[tuple[int, int, bytes]] = []
        nbytes = 0
        for row in cursor:
            rows.append(row)
            nbytes += len(row[2])
            if nbytes >= SQL_BYTES or len(rows) == SQL_ROWS:
                yield _rows_batch(rows, ids)
                rows, nbytes = [], 0
        if rows:
            yield _rows_batch(rows, ids)
        return
    by_sql = partial(rows_by_sql, db, (wanted, among, ids))
    table = _table(reader)
    yield from by_sql(sqlitefile.NO_ROW) if table is None else _from_pages(table, ids, by_sql)


def _table(reader: Sqlite3Reader) -> sqlitefile.Table | None:
    """The ``messages`` table of the file, read (:mod:`.sqlitefile`); None when its pages are not walked directly
    (a path rosbags reads through a VFS, a table of other columns or without rowids, a file too large to read)."""
    assert reader.dbconn
    if not isinstance(reader.path, Path):
        return None
    found = list(
        reader.dbconn.execute("SELECT rootpage, sql FROM sqlite_master WHERE type = 'table' AND name = 'messages'")
    )
    columns = tuple(row[1] for row in reader.dbconn.execute("PRAGMA table_info(messages)"))
    if len(found) != 1 or columns != sqlitefile.COLUMNS or "WITHOUT" in (found[0][1] or "").upper():
        return None
    return sqlitefile.open_table(reader.path, int(found[0][0] or 0))


def _from_pages(
    table: sqlitefile.Table, ids: ConnIds, by_sql: Callable[[int], Iterator[RawBatch]]
) -> Iterator[RawBatch]:
    """The requested rows read from the table's pages (:func:`.sqlitefile.read_window`) in windows aimed at a
    decoding group; from where a walk stops (a page it does not take) SQLite reads the rest (``by_sql``: the rows
    after the last rowid read). The first window is read by the caller; when more follow, a thread reads them while
    the caller decodes."""

    def windows(window: tuple[RawBatch | None, int, int, bool]) -> Iterator[RawBatch]:
        while True:
            batch, at, last, stopped = window
            if batch is not None:
                yield batch
            if stopped:
                yield from by_sql(last)
                return
            if at == table.leaves.shape[0]:
                return
            window = sqlitefile.read_window(table, at, storage.GROUP_BYTES, ids)

    first = sqlitefile.read_window(table, 0, storage.GROUP_BYTES, ids)
    more = not first[3] and first[1] < table.leaves.shape[0]
    yield from read_ahead(windows(first), THREAD) if more else windows(first)


def rows_by_sql(db: Connection, among: tuple[list[int], str, ConnIds], after: int) -> Iterator[RawBatch]:
    """The requested rows with ids after ``after`` (:data:`.sqlitefile.NO_ROW`: all), queried in windows of row ids
    (:func:`_windows`). Public: tests/test_readers_sqlite.py watches where SQLite takes over."""
    # two subqueries: SQLite reads one end of the table for each (min and max in one select scan every row)
    first, last = next(iter(db.execute("SELECT (SELECT min(id) FROM messages), (SELECT max(id) FROM messages)")))
    if last is None:
        return
    pages, page = (next(iter(db.execute(f"PRAGMA {name}")))[0] for name in ("page_count", "page_size"))
    window = _rows_for(storage.GROUP_BYTES, pages * page / (last - first + 1))  # from the database's bytes per row
    lo = first if after == sqlitefile.NO_ROW else after + 1
    windows = _windows(db, among, (lo, last), window, min(WINDOW_SPAN * window, WINDOW_ROWS))
    # one window: nothing to overlap; several: the next is queried by a thread while the caller decodes
    yield from windows if window > last - lo else read_ahead(windows, THREAD)


def _windows(
    db: Connection, among: tuple[list[int], str, ConnIds], span: tuple[int, int], window: int, most: int
) -> Iterator[RawBatch]:
    """The rows with ids ``span`` (first, last) of the topics ``among`` (ids, SQL condition, lookup) in windows of
    row ids, the first ``window`` rows long, none longer than ``most``.

    SQLite concatenates each window's payloads (one ``group_concat`` query); a window is aimed at a decoding
    group of payload (:data:`.storage.GROUP_BYTES`), so :func:`.storage.grouped` passes it on as it is instead
    of copying windows of 1 MB into one buffer (~0.5 ms a MB). Each next window's rows follow from the payload
    per row of the one before (at most 4x more, and at most ``most``: see :data:`WINDOW_SPAN`).
    """
    wanted, where, ids = among
    query = (
        "SELECT CAST(group_concat(data, x'') AS BLOB), group_concat(length(data)), group_concat(timestamp), "
        f"group_concat(topic_id) FROM messages WHERE {where} AND id >= ? AND id < ?"
    )
    aim = storage.GROUP_BYTES
    lo, last = span
    while lo <= last:
        blob, sizes, stamps, topics = next(iter(db.execute(query, [*wanted, lo, lo + window])))
        lo += window
        if blob is None:
            window = min(window * 4, most)
            continue
        size = _numbers(sizes)
        start = np.zeros(size.shape[0], np.int64)
        np.cumsum(size[:-1], out=start[1:])
        yield RawBatch(np.frombuffer(blob, np.uint8), ids.lookup(_numbers(topics)), _numbers(stamps), start, size)
        window = min(_rows_for(aim, len(blob) / window), window * 4, most)


def _rows_for(aim: float, per_row: float) -> int:
    """Rows holding ``aim`` bytes at ``per_row`` bytes a row: at least one, at most ``WINDOW_ROWS``."""
    return int(min(max(aim / max(per_row, 1.0), 1), WINDOW_ROWS))


def _numbers(text: str) -> np.ndarray:
    """Comma-separated integers (a ``group_concat``) as int64."""
    return np.fromstring(text, dtype=np.int64, sep=",")


def _rows_batch(rows: list[tuple[int, int, bytes]], ids: ConnIds) -> RawBatch:
    topic, stamp, blobs = zip(*rows, strict=True)
    conn = ids.lookup(np.fromiter(topic, np.int64, len(topic)))
    return joined(blobs, conn, np.fromiter(stamp, np.int64, len(stamp)))
