"""A rosbag2 ``messages`` table read straight from the SQLite database file's pages (compiled walks).

SQLite hands each row over through its virtual machine: ~3 ms of a 60 s db3's 25,000 rows for a bare
``count(*)``; concatenating the payloads and printing the numbers as text (``group_concat``) for the decoders was
more than half of that log's read. The file format is documented and stable (https://sqlite.org/fileformat.html):
a rowid table is a b-tree whose leaf pages hold the rows' records, a payload too long for its page going on in
a chain of overflow pages. Here the file is mapped, the tree's leaf pages listed in key order
(:func:`_leaf_pages`), the records on them walked (:func:`_window`) and the payloads of the requested topics
copied out (:func:`_assemble`): the same rows in the same order (rowid) as SQLite's scan, payload bytes,
``topic_id`` and ``timestamp`` as stored.

This reads only what SQLite itself would: rosbags opens the database ``immutable`` (no journal, no WAL), so the
main file's pages are the whole database. Anything the walks do not take exactly as SQLite would (a page or cell
that is not a valid table b-tree's, a record of other columns, a ``data`` that is not a blob, an int that is not
an int) stops them at the page before: the caller reads the rest through SQLite, which then reads it or reports
the damage in its own words. Every byte offset is checked before it is read, so a damaged file cannot make a
walk read outside the mapping.
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slamobs.pipeline.kernel_cache import njit

from .storage import RawBatch

if TYPE_CHECKING:
    from .storage import ConnIds

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
    """A mapped database file and the leaf pages of one of its rowid tables, in key order."""

    mapped: mmap.mmap  # the file, read only
    buf: np.ndarray  # (file bytes,) uint8: the mapping's bytes
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


def open_table(path: Path, root: int) -> Table | None:
    """``path`` mapped, and the leaf pages of the table b-tree whose root is page ``root``; None when the file
    cannot be mapped or its tree is not one the walks read (the caller then asks SQLite)."""
    try:
        with path.open("rb") as fobj:
            size = fobj.seek(0, 2)
            if size < 512:
                return None
            mapped = mmap.mmap(fobj.fileno(), 0, access=mmap.ACCESS_READ)  # kept alive by the array
    except (OSError, ValueError):
        return None
    buf = np.frombuffer(mapped, np.uint8)
    fields = _header_fields(bytes(buf[:100]), size)
    if fields is None or not 2 <= root <= fields[2]:
        return None
    leaves, ok = _leaf_pages(buf, root, *fields)
    return Table(mapped, buf, *fields, leaves) if ok else None


def read_window(table: Table, at: int, aim: int, ids: ConnIds) -> tuple[RawBatch | None, int, int, bool]:
    """The rows of the topics ``ids`` asks for on the leaf pages from ``table.leaves[at]`` on, whole pages until
    their data make ``aim`` bytes: their payloads copied one after the other into the batch's buffer (those that go
    on in overflow pages put together). When the table is read in several windows, the pages of the mapping are
    given back after each (the file's pages stay in the page cache, not in this process's memory).

    Returns the batch (None: no such row there), the index of the next leaf page, the rowid of the last row on the
    pages read (:data:`NO_ROW`: none) and whether the walk stopped at a page it does not take (SQLite reads from
    there on).
    """
    page, leaves = table.page_size, table.leaves
    got = _window(table.buf, leaves, page, table.usable, table.npages, ids.ids, ids.index, at, aim)
    conn, stamp, start, size, local, chain, stop, last, ok = got
    batch = None
    if conn.shape[0]:
        batch = RawBatch(_assemble(table.buf, page, table.usable, start, size, local, chain), conn, stamp, start, size)
    if (at or stop < leaves.shape[0]) and hasattr(mmap, "MADV_DONTNEED"):  # read again from the page cache if needed
        table.mapped.madvise(mmap.MADV_DONTNEED)
    return batch, int(stop), int(last), not ok


# --------------------------------------------------------------------------- compiled walks
# The small helpers are inlined into the walks (numba calls a compiled function otherwise: 4x slower here).


@njit(cache=True, nogil=True, inline="always")
def _be(buf, at, width):  # pragma: no cover - compiled
    """Big-endian unsigned int of ``width`` bytes (``width`` <= 8, bounds checked by the caller)."""
    v = np.int64(0)
    for k in range(width):
        v = (v << np.int64(8)) | np.int64(buf[at + k])
    return v


@njit(cache=True, nogil=True, inline="always")
def _varint(buf, at, end):  # pragma: no cover - compiled
    """SQLite varint at ``at``: (value, position after it); the position is -1 when it runs to ``end`` or ``at``
    is -1 already (a chain of reads stops at the first that fails)."""
    if at < 0:
        return np.int64(0), np.int64(-1)
    v = np.int64(0)
    for k in range(8):
        if at + k >= end:
            return np.int64(0), np.int64(-1)
        b = np.int64(buf[at + k])
        v = (v << np.int64(7)) | (b & np.int64(0x7F))
        if b < 0x80:
            return v, np.int64(at + k + 1)
    if at + 8 >= end:
        return np.int64(0), np.int64(-1)
    return (v << np.int64(8)) | np.int64(buf[at + 8]), np.int64(at + 9)


@njit(cache=True, nogil=True, inline="always")
def _page_ok(pgno, page_size, npages):  # pragma: no cover - compiled
    """A page number a b-tree may name: 2 .. npages (page 1 is the schema's), not the lock-byte page."""
    return 2 <= pgno <= npages and (pgno - 1) * page_size != _LOCK_BYTE


@njit(cache=True, nogil=True)
def _leaf_pages(buf, root, page_size, usable, npages):  # pragma: no cover - compiled
    """Leaf pages of the table b-tree rooted at ``root`` in key order (left to right), and whether the tree is one
    (every page in the file, of a table b-tree's type, none visited twice)."""
    leaves = np.empty(npages, np.int64)
    stack = np.empty(npages + 1, np.int64)
    nleaves = 0
    visits = 0
    sp = 1
    stack[0] = root
    while sp > 0:
        sp -= 1
        pgno = stack[sp]
        visits += 1
        if visits > npages:  # a page named twice: a loop
            return leaves[:0], False
        base = (pgno - 1) * page_size
        kind = buf[base]
        if kind == _LEAF:
            leaves[nleaves] = pgno
            nleaves += 1
            continue
        ncells = _be(buf, base + 3, 2)
        if kind != _INTERIOR or 12 + 2 * ncells > usable or sp + ncells + 1 > stack.shape[0]:
            return leaves[:0], False
        right = _be(buf, base + 8, 4)
        if not _page_ok(right, page_size, npages):
            return leaves[:0], False
        stack[sp] = right  # visited last
        sp += 1
        for i in range(ncells - 1, -1, -1):  # pushed last to first: popped first to last
            cell = _be(buf, base + 12 + 2 * i, 2)
            if cell < 12 + 2 * ncells or cell + 4 > usable:
                return leaves[:0], False
            child = _be(buf, base + cell, 4)
            if not _page_ok(child, page_size, npages):
                return leaves[:0], False
            stack[sp] = child
            sp += 1
    return leaves[:nleaves], True


@njit(cache=True, nogil=True, inline="always")
def _copy(out, to, buf, at, count):  # pragma: no cover - compiled
    """``out[to : to + count] = buf[at : at + count]``; unsigned indices let LLVM vectorise the loop (numba's slice
    assignment and signed indices, which may wrap around, copy ten times slower)."""
    to_, at_ = np.uint64(to), np.uint64(at)
    for b in range(np.uint64(count)):
        out[to_ + b] = buf[at_ + b]


@njit(cache=True, nogil=True, inline="always")
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


@njit(cache=True, nogil=True, inline="always")
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
def _window(buf, leaves, page_size, usable, npages, ids, index, at, aim):  # pragma: no cover - compiled
    """The rows whose ``topic_id`` is in ``ids`` (sorted; ``index``: their connection indices) on the leaf pages
    from ``leaves[at]`` on, whole pages until their data make ``aim`` bytes (or ``aim`` bytes of pages are walked).

    Returns per row its connection index, timestamp, the file offset of its data, the data's size, the part of it
    on the leaf page and the first overflow page (0: none); the next leaf index, the last rowid of the pages walked
    and False when the walk stopped at a page holding something it does not take (the rows of the pages before it
    are returned).
    """
    most = usable - 35  # the longest payload a leaf page keeps whole
    least = (usable - 12) * 32 // 255 - 23  # the least it keeps of a longer one
    spill = usable - 4  # payload bytes an overflow page holds
    until = min(leaves.shape[0], at + max(aim // page_size, 1))  # the window's pages are at most these
    cap = 0
    for k in range(at, until):
        cap += min(_be(buf, (leaves[k] - 1) * page_size + 3, 2), usable // 2)
    conn = np.empty(cap, np.int64)
    stamp = np.empty(cap, np.int64)
    start = np.empty(cap, np.int64)  # the payload's data: in the file, then in ``data``
    size = np.empty(cap, np.int64)
    local = np.empty(cap, np.int64)  # data bytes on the leaf page
    chain = np.empty(cap, np.int64)  # first overflow page (0: none)
    n = 0
    nbytes = 0  # the rows' data
    last = _NO_ROW
    ok = True
    k = at
    while ok and k < until and (k == at or nbytes < aim):
        base = (leaves[k] - 1) * page_size
        end = base + usable
        ncells = _be(buf, base + 3, 2)
        ok = 8 + 2 * ncells <= usable
        page_n, page_bytes, page_last = 0, 0, last
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
            t0, q = _varint(buf, q, types_end)
            t1, q = _varint(buf, q, types_end)
            t2, q = _varint(buf, q, types_end)
            t3, q = _varint(buf, q, types_end)
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
            row = n + page_n
            conn[row] = index[j]
            stamp[row] = _int(buf, p + head + w1, t2)
            size[row] = dlen
            start[row] = p + skip
            local[row] = min(here - skip, dlen)
            chain[row] = _be(buf, p + here, 4) if here < payload else 0
            page = chain[row]
            for _ in range((payload - here + spill - 1) // spill):  # the overflow pages must be there
                if not _page_ok(page, page_size, npages):
                    ok = False
                    break
                page = _be(buf, (page - 1) * page_size, 4)
            if not ok:
                break
            page_bytes += dlen
            page_n += 1
        if not ok:
            break
        n += page_n
        nbytes += page_bytes
        last = page_last
        k += 1
    return conn[:n], stamp[:n], start[:n], size[:n], local[:n], chain[:n], k, last, ok


@njit(cache=True, nogil=True)
def _assemble(buf, page_size, usable, start, size, local, chain):  # pragma: no cover - compiled
    """The rows' data one after the other in one buffer (see :func:`_window`); ``start`` becomes each row's offset
    there. A copy in row order: the decoders read a leaf page's rows in place ~2x slower (its cells lie from the
    page's end backwards)."""
    spill = usable - 4
    data = np.empty(size.sum(), np.uint8)
    to = 0
    for row in range(start.shape[0]):
        got = local[row]
        _copy(data, to, buf, start[row], got)
        page = chain[row]
        while got < size[row]:  # the rest in the overflow pages
            take = min(spill, size[row] - got)
            first = (page - 1) * page_size + 4
            _copy(data, to + got, buf, first, take)
            got += take
            page = _be(buf, first - 4, 4)
        start[row] = to
        to += size[row]
    return data
