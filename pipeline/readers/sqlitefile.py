"""A rosbag2 ``messages`` table read straight from the SQLite database file's pages (compiled walks).

SQLite hands each row over through its virtual machine: ~3 ms of a 60 s db3's 25,000 rows for a bare
``count(*)``; concatenating the payloads and printing the numbers as text (``group_concat``) for the decoders was
more than half of that log's read. The file format is documented and stable (https://sqlite.org/fileformat.html):
a rowid table is a b-tree whose leaf pages hold the rows' records, a payload too long for its page going on in
a chain of overflow pages. Here the tree's interior pages are read level by level to list the leaf pages in key
order (:func:`open_table`), then the leaf pages are read a window at a time and their records walked
(:func:`_window`): the same rows in the same order (rowid) as SQLite's scan, payload bytes (where they lie in the
window's buffer), ``topic_id`` and ``timestamp`` as stored.

This reads only what SQLite itself would: rosbags opens the database ``immutable`` (no journal, no WAL), so the
main file's pages are the whole database. Anything the walks do not take exactly as SQLite would (a page or cell
that is not a valid table b-tree's, a record of other columns, a ``data`` that is not a blob, an int that is not
an int, a payload that goes on in overflow pages) stops them at the page before: the caller reads the rest
through SQLite, which then reads it or reports the damage in its own words. Every byte offset is checked before
it is read, so a damaged file cannot make a walk read outside its buffer.

The pages are read (``readinto``), not mapped: a file cut or rewritten while it is mapped ends the process with
SIGBUS instead of a one-line error (why ``PRAGMA mmap_size`` is not used either). Memory stays bounded: a window
holds at most a decoding group of pages.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from numba import types
from slamobs.pipeline.kernel_cache import njit, subroutine
from slamobs.pipeline.simd import prefetch

from .storage import RawBatch

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from .storage import ConnIds

#: A tree deeper than this is not one SQLite wrote (its own limit is 20 levels).
_MAX_DEPTH = 40
#: Bytes 0-15 of every SQLite database file.
HEADER = b"SQLite format 3\x00"
#: The page holding the byte at 1 GiB (SQLite's lock byte) is never a b-tree page.
_LOCK_BYTE = 1 << 30
#: Page types of a table b-tree.
_INTERIOR, _LEAF = 5, 13
#: The last rowid of no row (rowids are int64, any may be stored).
NO_ROW = -(2**63)
_NO_ROW = np.int64(NO_ROW)
#: The ``messages`` columns rosbag2 writes (``id`` the rowid, so stored as NULL).
COLUMNS = ("id", "topic_id", "timestamp", "data")


@dataclass(frozen=True)
class Table:
    """A database file and the leaf pages of one of its rowid tables, in key order."""

    path: Path
    page_size: int
    usable: int  # page size less the reserved bytes at each page's end
    npages: int  # pages a reference may name
    leaves: np.ndarray  # (L,) int64 page numbers


def _header_fields(head: bytes, file_size: int) -> tuple[int, int, int] | None:
    """Page size, usable size and page count from the 100-byte database header (None: not one these walks read)."""
    if len(head) < 100 or not head.startswith(HEADER):
        return None
    page_size = int.from_bytes(head[16:18], "big")
    page_size = 65536 if page_size == 1 else page_size
    if page_size < 512 or page_size & (page_size - 1) or head[18] not in (1, 2) or head[19] not in (1, 2):
        return None
    usable = page_size - head[20]
    if usable < 480:
        return None
    pages = file_size // page_size
    stated = int.from_bytes(head[28:32], "big")  # valid while the change counter is the one it was written with
    if stated and head[24:28] == head[92:96]:
        pages = min(pages, stated)
    return page_size, usable, pages


def cut_short(path: Path) -> str:
    """What to say of the database files at ``path`` (a ``.db3`` file or a rosbag2 directory's) whose header states
    more pages than the file holds: a copy or a recording cut short, which SQLite refuses to open at all ("database
    disk image is malformed"); empty when none is."""
    said = []
    for db in [path] if path.is_file() else sorted(path.glob("*.db3")):
        try:
            with db.open("rb") as fobj:
                head, size = fobj.read(100), fobj.seek(0, 2)
        except OSError:
            continue
        fields = _header_fields(head, size)
        stated = int.from_bytes(head[28:32], "big") if fields is not None else 0
        if fields is not None and stated * fields[0] > size and head[24:28] == head[92:96]:
            said.append(f"{db.name} holds {size // fields[0]} of the {stated} pages its header states")
    if not said:
        return ""
    return (
        f"; {', '.join(said)}: cut short (a copy not finished, a disk that filled up?), and SQLite reads no part "
        "of a cut database: copy it again from the recording"
    )


def open_table(path: Path, root: int) -> Table | None:
    """The leaf pages of the table b-tree whose root is page ``root``, its interior pages read level by level
    (a level's first page says whether it is the leaves' level; the windows check every leaf page's type); None
    when the file cannot be read or the tree is not one the walks read (the caller then asks SQLite)."""
    try:
        with path.open("rb") as fobj:
            fields = _header_fields(fobj.read(100), fobj.seek(0, 2))
            if fields is None or not 2 <= root <= fields[2]:
                return None
            page_size, usable, npages = fields
            level = np.array([root], np.int64)
            visited = 0
            for _ in range(_MAX_DEPTH):
                buf = _read_pages(fobj, level[:1], page_size)
                if buf is None or buf[0] == _LEAF:
                    return Table(path, *fields, level) if buf is not None else None
                if level.shape[0] > 1:  # a level of one page (the root) is read already
                    buf = _read_pages(fobj, level, page_size)
                visited += level.shape[0]
                if buf is None or visited > npages:  # cut, or a page named twice (a loop)
                    return None
                level, ok = _children(buf, level.shape[0], page_size, usable, npages)
                if not ok:
                    return None
    except OSError:
        return None
    return None


def _read_pages(fobj: BinaryIO, pages: np.ndarray, page_size: int) -> np.ndarray | None:
    """The pages one after the other in one buffer (runs of consecutive pages read at once); None if the file
    ends before one of them."""
    buf = np.empty(pages.shape[0] * page_size, np.uint8)
    breaks = np.flatnonzero(np.diff(pages) != 1) + 1
    for first, last in zip((0, *breaks.tolist()), (*breaks.tolist(), pages.shape[0]), strict=True):
        fobj.seek((int(pages[first]) - 1) * page_size)
        if fobj.readinto(buf[first * page_size : last * page_size]) != (last - first) * page_size:
            return None
    buf.flags.writeable = False  # the compiled walks are compiled for read-only buffers (as RawBatch's)
    return buf


def read_window(table: Table, at: int, aim: int, ids: ConnIds) -> tuple[RawBatch | None, int, int, bool]:
    """The rows of the topics ``ids`` asks for on the leaf pages from ``table.leaves[at]`` on, ``aim`` bytes of
    pages (at least one): the buffer the pages were read into is the batch's (the decoders read the payloads where
    they lie: copying them out first cost more than it saved).

    The pages are walked :data:`PIECE` pages at a time right after they are read, while the kernel's copy is still
    in the core's cache: walked after the whole window was read, each page was a cache miss again.

    Returns the batch (None: no such row there), the index of the next leaf page, the rowid of the last row on the
    pages read (:data:`NO_ROW`: none) and whether the walk stopped at a page it does not take (SQLite reads from
    there on).
    """
    pages = table.leaves[at : at + max(aim // table.page_size, 1)]
    count, page_size = pages.shape[0], table.page_size
    buf = np.empty(count * page_size, np.uint8)
    # the rows' arrays made here (numba compiles each allocation it is asked for), grown when a piece's pages hold
    # more cells than they have room for (the walk stops before such a page)
    rows = np.empty((4, count * 16 + 64), np.int64)
    n, done, last, ok = 0, 0, _NO_ROW, True
    with table.path.open("rb") as fobj:
        for end in _pieces(fobj, pages, page_size, buf):
            if end < 0:  # the file was cut since it was opened: SQLite's to report
                ok = False
                break
            while ok and done < end:
                n, walked, last, ok = _window(
                    buf, done, end, page_size, table.usable, ids.ids, ids.index, *rows, n, last
                )
                if ok and walked < end:  # no room for the next page's cells
                    rows = grown_rows(rows, n, walked, count)
                done = walked
            if not ok:
                break
    batch = None
    if n:
        buf.flags.writeable = False  # the compiled walks are compiled for read-only buffers (as RawBatch's)
        conn, stamp, start, size = rows[:, :n]
        batch = RawBatch(buf, conn, stamp, start, size)
    return batch, at + done, int(last), not ok


#: Leaf pages read then walked at a time (256 kB of 4 kB pages: in the core's cache when walked).
PIECE = 64


def _pieces(fobj: BinaryIO, pages: np.ndarray, page_size: int, buf: np.ndarray) -> Iterator[int]:
    """Reads the pages into ``buf`` one after the other, runs of consecutive pages at once; yields the end of each
    :data:`PIECE` of pages read (the number of pages read), -1 when the file ends before a page."""
    breaks = np.flatnonzero(np.diff(pages) != 1) + 1
    count = pages.shape[0]
    first = 0
    for stop in (*breaks.tolist(), count):
        while first < stop:
            last = min(stop, (first // PIECE + 1) * PIECE)
            fobj.seek((int(pages[first]) - 1) * page_size)
            if fobj.readinto(buf[first * page_size : last * page_size]) != (last - first) * page_size:
                yield -1
                return
            first = last
            if last % PIECE == 0 or last == count:
                yield last


def grown_rows(rows: np.ndarray, n: int, walked: int, count: int) -> np.ndarray:
    """``rows`` with room for the rest of ``count`` pages at twice the rows per page so far (the first ``n`` kept).
    Public: tests/test_readers_sqlite.py watches it grow."""
    more = np.empty((4, max(2 * rows.shape[1], n + 2 * (n // max(walked, 1) + 64) * (count - walked))), np.int64)
    more[:, :n] = rows[:, :n]
    return more


# --------------------------------------------------------------------------- compiled walks
# The byte readers and the integer of a serial type are subroutines of the walk (kernel_cache.subroutine): typed
# and lowered once each, and LLVM inlines them into it. As inline="always" numba typed and lowered their bodies
# at every call site (compiling), as kernels of their own it called them (~2x slower here).


@subroutine(types.int64)
def _be(buf, at, width):  # pragma: no cover - compiled
    """Big-endian unsigned int of ``width`` bytes (``width`` <= 8, bounds checked by the caller)."""
    v = np.int64(0)
    a = np.uint64(at)  # unsigned indices: no wrap-around checks
    for k in range(np.uint64(width)):
        v = (v << np.int64(8)) | np.int64(buf[a + k])
    return v


@subroutine(types.UniTuple(types.int64, 2))
def _varint(buf, at, end):  # pragma: no cover - compiled
    """SQLite varint at ``at``: (value, position after it); the position is -1 when it runs to ``end`` or ``at``
    is -1 already (a chain of reads stops at the first that fails)."""
    if at < 0:
        return np.int64(0), np.int64(-1)
    a = np.uint64(at)  # unsigned indices: no wrap-around checks
    v = np.int64(0)
    for k in range(8):
        if at + k >= end:
            return np.int64(0), np.int64(-1)
        b = np.int64(buf[a + np.uint64(k)])
        v = (v << np.int64(7)) | (b & np.int64(0x7F))
        if b < 0x80:
            return v, np.int64(at + k + 1)
    if at + 8 >= end:
        return np.int64(0), np.int64(-1)
    return (v << np.int64(8)) | np.int64(buf[a + np.uint64(8)]), np.int64(at + 9)


def _children(buf: np.ndarray, count: int, page_size: int, usable: int, npages: int) -> tuple[np.ndarray, bool]:
    """The child pages of ``count`` interior pages of a table b-tree (one after the other in ``buf``), left to
    right, and whether each is one (its type, its cells inside it, every child a page of the file).

    In array steps over the whole level (a tree has a few levels, the interior pages are a few hundredth of the
    pages): a compiled walk cost ~0.6 s of a first db3 read's compiling for ~1 ms of reading."""
    none = np.zeros(0, np.int64)
    base = np.arange(count, dtype=np.int64) * page_size
    ncells = _be_at(buf, base + 3, 2)
    if np.any(buf[base] != _INTERIOR) or np.any(12 + 2 * ncells > usable):
        return none, False
    # cell k of page c at out[first[c] + k], its right-most child at out[first[c] + ncells[c]]
    first = np.concatenate(([0], np.cumsum(ncells + 1)[:-1]))
    page = np.repeat(np.arange(count), ncells)
    k = np.arange(page.shape[0]) - np.repeat(first - np.arange(count), ncells)  # cell index within its page
    cell = _be_at(buf, base[page] + 12 + 2 * k, 2)
    if np.any(cell < 12 + 2 * ncells[page]) or np.any(cell + 4 > usable):
        return none, False
    out = np.empty(int(ncells.sum()) + count, np.int64)
    out[first[page] + k] = _be_at(buf, base[page] + cell, 4)
    out[first + ncells] = _be_at(buf, base + 8, 4)
    if np.any((out < 2) | (out > npages) | ((out - 1) * page_size == _LOCK_BYTE)):
        return none, False
    return out, True


def _be_at(buf: np.ndarray, at: np.ndarray, width: int) -> np.ndarray:
    """Big-endian unsigned ints of ``width`` bytes at each of ``at`` (in bounds: the caller checks)."""
    v = np.zeros(at.shape[0], np.int64)
    for b in range(width):
        v = (v << 8) | buf[at + b]
    return v


@subroutine(types.int64)
def _int_size(serial):  # pragma: no cover - compiled
    """Bytes of an integer of this serial type (-1: the value is not an integer)."""
    if 1 <= serial <= 4:
        return serial
    if serial == 5:
        return 6
    if serial == 6:
        return 8
    if serial == 8 or serial == 9:
        return 0
    return -1


@subroutine(types.int64)
def _int(buf, at, serial):  # pragma: no cover - compiled
    """The integer of serial type ``serial`` at ``at`` (big-endian two's complement; 8 and 9 are 0 and 1)."""
    if serial == 8 or serial == 9:
        return np.int64(serial - 8)
    width = _int_size(serial)
    v = _be(buf, at, width)
    if width < 8 and v >= (np.int64(1) << np.int64(8 * width - 1)):
        v -= np.int64(1) << np.int64(8 * width)
    return v


@njit(cache=True, nogil=True)
def _window(
    buf, first, count, page_size, usable, ids, index, conn, stamp, start, size, n, last
):  # pragma: no cover - compiled
    """The rows whose ``topic_id`` is in ``ids`` (sorted; ``index``: their connection indices) on leaf pages
    ``first`` to ``count`` - 1 (one after the other in ``buf``), after ``n`` rows found before whose last rowid
    was ``last``.

    Writes per row its connection index, timestamp, the offset of its data in ``buf`` and the data's size, from
    row ``n`` on. Returns the number of rows then, the next page to walk, the last rowid walked and False when the
    walk stopped at a page holding something it does not take (the rows of the pages before it are returned): a
    page that is not a table leaf, a cell or record that is not as SQLite writes them, rowids that do not rise, a
    wanted payload that goes on in overflow pages (SQLite puts those together). It stops (True) before a page
    whose cells the arrays have no room for.

    The next page's lines are asked for (:func:`.simd.prefetch`) while a page is walked: its cells are met at
    scattered places, each a cache miss when the window's pages are not in cache (~2x the walk's time).
    """
    most = usable - 35  # the longest payload a leaf page keeps whole
    least = (usable - 12) * 32 // 255 - 23  # the least it keeps of a longer one
    spill = usable - 4  # payload bytes an overflow page holds
    ok = True
    k = first
    while ok and k < count:
        base = k * page_size
        end = base + usable
        if k + 1 < count:
            for q in range(base + page_size, base + 2 * page_size, 64):
                prefetch(buf, q)
        ncells = _be(buf, base + 3, 2)
        ok = buf[base] == _LEAF and 8 + 2 * ncells <= usable
        if ok and n + ncells > conn.shape[0]:
            break
        page_n, page_last = 0, last
        for i in range(ncells if ok else 0):
            cell = _be(buf, base + 8 + 2 * i, 2)
            payload, p = _varint(buf, base + cell, end)
            rowid, p = _varint(buf, p, end)
            if cell < 8 + 2 * ncells or p < 0 or payload < 0 or rowid <= page_last:  # rowids rise in a table
                ok = False
                break
            page_last = rowid
            here = payload
            if payload > most:
                here = least + (payload - least) % spill
                if here > most:
                    here = least
            # the record's header: its size, the serial types of id (NULL: the rowid), topic_id, timestamp, data
            head, q = _varint(buf, p, min(p + here, end))
            types_end = min(p + head, p + here, end)
            t0 = t1 = t2 = t3 = np.int64(0)
            for c in range(4):  # one varint read for the four
                t, q = _varint(buf, q, types_end)
                if c == 0:
                    t0 = t
                elif c == 1:
                    t1 = t
                elif c == 2:
                    t2 = t
                else:
                    t3 = t
            w1, w2 = _int_size(t1), _int_size(t2)
            skip = head + w1 + w2  # payload bytes before the data
            dlen = (t3 - 12) // 2
            if p + here + (4 if here < payload else 0) > end or q != p + head or t0 != 0 or w1 < 0 or w2 < 0:
                ok = False
                break
            if t3 < 12 or t3 % 2 or skip + dlen != payload or skip > here:
                ok = False
                break
            topic = _int(buf, p + head, t1)
            j = 0
            while j < ids.shape[0] and ids[j] != topic:
                j += 1
            if j == ids.shape[0]:
                continue
            if here < payload:  # a wanted payload in overflow pages: SQLite's to put together
                ok = False
                break
            row = n + page_n
            conn[row] = index[j]
            stamp[row] = _int(buf, p + head + w1, t2)
            start[row] = p + skip
            size[row] = dlen
            page_n += 1
        if not ok:
            break
        n += page_n
        last = page_last
        k += 1
    return n, k, last, ok
