"""Vectorised decoding of fixed-layout messages straight from their serialised bytes (ROS1 and CDR).

Deserialising message by message costs tens of microseconds each; here a whole chunk of messages is
decoded with a handful of array operations. The byte layout is computed from the message definition
stored in the log (so a log with an older variant of a type still decodes right), walking the fields
once for all messages of a batch: ``frame_id`` and other strings make the offsets variable, so each
message carries its own position array, and CDR alignment (relative to the end of the 4-byte
encapsulation header) is applied to those arrays only where a string left it unknown.

Which fields to read is not listed here: :func:`layout_paths` runs the row function of a
``rows.LAYOUTS`` entry on a recording stand-in, so the layout table stays the one place naming them.
Detection arrays (one header, then a sequence of fixed-layout elements such as
``fiducial_msgs/FiducialTransform``) are planned too: the prefix as above, then a compiled walk over the
elements of every message (:class:`ItemPlan`). Types whose fields cannot be reached otherwise (a dynamic
field before the wanted ones, strings inside elements) fall back to rosbags.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from functools import cache, cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import types
from slamobs.pipeline.kernel_cache import KERNEL_ROWS, compiled_for, njit, subroutine, worth_compiling
from slamobs.pipeline.simd import prefetch
from rosbags.interfaces import Nodetype

from slamobs.pipeline.errors import BadInput, InputError

from .container import iter_batches, require_definitions
from .rows import ITEM_LAYOUTS, LAYOUTS, Frames, Rows, StatedRuns, stated_runs, stated_start
from .storage import grouped

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Mapping, Sequence
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

    from .storage import RawBatch

Path_ = tuple[str, ...]

HEADER = "std_msgs/msg/Header"
STAMP_SEC: Path_ = ("header", "stamp", "sec")
STAMP_NSEC: Path_ = ("header", "stamp", "nanosec")
FRAME_ID: Path_ = ("header", "frame_id")
_NS = 1_000_000_000

# primitive -> (size, kind of its bits: f float, i signed, u unsigned)
_PRIMITIVES: dict[str, tuple[int, str]] = {
    "bool": (1, "u"),
    "byte": (1, "u"),
    "char": (1, "u"),
    "int8": (1, "i"),
    "uint8": (1, "u"),
    "int16": (2, "i"),
    "uint16": (2, "u"),
    "int32": (4, "i"),
    "uint32": (4, "u"),
    "int64": (8, "i"),
    "uint64": (8, "u"),
    "float32": (4, "f"),
    "float64": (8, "f"),
}
_BASE, _NAME, _ARRAY, _SEQUENCE = Nodetype.BASE, Nodetype.NAME, Nodetype.ARRAY, Nodetype.SEQUENCE
#: Op kinds and leaf kinds as the compiled walk (:func:`_walk`) reads them.
_LEAF, _SKIP, _STRING = 0, 1, 2
#: The compiled passes ask for the cache lines of the message (string) this many ahead of the one they read.
_AHEAD = 8
_KINDS = {"f": 0, "i": 1, "u": 2}


class DecodeError(BadInput, ValueError):
    """A message does not match its definition (too short, bad string); the text names the problem."""


class _Probe:
    """Stands in for a message and remembers which attribute path was read."""

    __slots__ = ("path",)

    def __init__(self, path: Path_ = ()) -> None:
        self.path = path

    def __getattr__(self, name: str) -> _Probe:
        return _Probe((*self.path, name))

    def __getitem__(self, index: int) -> _Probe:  # an element of a fixed array of numbers, e.g. a covariance's
        return _Probe((*self.path, str(index)))


def layout_paths(
    row: Callable[[Any], Any],
    child: Callable[[Any], Any] | None = None,
) -> tuple[list[Path_], Path_ | None] | None:
    """Field paths a layout's row (and child frame) function reads, or None if they do more than read fields."""
    try:
        leaves = row(_Probe())
        other = child(_Probe()) if child is not None else None
    except Exception:  # arithmetic, indexing, calls: not a plain field read
        return None
    if isinstance(leaves, _Probe):
        leaves = (leaves,)
    if not isinstance(leaves, tuple) or not all(isinstance(x, _Probe) for x in leaves):
        return None
    if other is not None and not isinstance(other, _Probe):
        return None
    return [x.path for x in leaves], (other.path if other is not None else None)


# --------------------------------------------------------------------------- plans


@dataclass(frozen=True)
class Op:
    """One step of a plan: ``align`` then read a ``leaf`` / ``string`` into ``slot``, or ``skip`` bytes."""

    kind: str  # "leaf", "string" or "skip"
    align: int  # CDR alignment before the step (1 = none)
    size: int  # leaf or skipped bytes
    slot: int = -1  # column (leaf) or string slot; -1 = not wanted


class _Leaves:
    """Sizes and kinds of a plan's leaves, grouped for conversion (shared by messages and elements)."""

    leaves: tuple[tuple[int, str], ...]  # per leaf: (size, kind)

    @cached_property
    def sizes(self) -> np.ndarray:
        """Byte size per leaf."""
        return np.array([s for s, _ in self.leaves], np.int64)

    @cached_property
    def kinds(self) -> dict[tuple[int, str], np.ndarray]:
        """Leaves grouped by (size, kind), converted together."""
        groups: dict[tuple[int, str], list[int]] = {}
        for j, leaf in enumerate(self.leaves):
            groups.setdefault(leaf, []).append(j)
        return {k: np.array(v, np.int64) for k, v in groups.items()}


@dataclass(frozen=True)
class ItemPlan(_Leaves):
    """The fixed-layout elements of the sequence that follows a plan's prefix (one row of leaves each)."""

    ops: tuple[Op, ...]  # leaves and skips only
    leaves: tuple[tuple[int, str], ...]

    @cached_property
    def program(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The ops as arrays for the compiled walk: is-leaf, alignment, size, slot."""
        return (
            np.array([op.kind == "leaf" for op in self.ops], np.bool_),
            np.array([op.align for op in self.ops], np.int64),
            np.array([op.size for op in self.ops], np.int64),
            np.array([op.slot for op in self.ops], np.int64),
        )

    @cached_property
    def walk_kinds(self) -> np.ndarray:
        """Per leaf the kind of its bits (:data:`_KINDS`), for the compiled walk."""
        return np.array([_KINDS[kind] for _, kind in self.leaves], np.int64)

    @cached_property
    def min_size(self) -> int:
        """Bytes of one element without padding: bounds the element count a message can hold."""
        return max(1, sum(op.size for op in self.ops))


@dataclass(frozen=True)
class Plan(_Leaves):
    """How to find the wanted fields of one type in one encoding (leaf 0, 1: stamp sec, nanosec)."""

    msgtype: str
    cdr: bool
    ops: tuple[Op, ...]
    leaves: tuple[tuple[int, str], ...]  # per leaf: (size, kind)
    nstrings: int
    items: ItemPlan | None = None  # the sequence right after ``ops``, if its elements are read
    #: value column from which on the rows are kept as runs (``rows.split_stated``: stated variances), if any
    stated_from: int | None = None

    @cached_property
    def program(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The ops as arrays for the compiled walk (:func:`_walk`): kind (:data:`_LEAF`, :data:`_SKIP`,
        :data:`_STRING`), alignment, size, slot; and per leaf the kind of its bits (:data:`_KINDS`)."""
        return (
            np.array([{"leaf": _LEAF, "skip": _SKIP, "string": _STRING}[op.kind] for op in self.ops], np.int64),
            np.array([op.align for op in self.ops], np.int64),
            np.array([op.size for op in self.ops], np.int64),
            np.array([op.slot for op in self.ops], np.int64),
            np.array([_KINDS[kind] for _, kind in self.leaves], np.int64),
        )


def walk_fields(
    typestore: Typestore,
    msgtype: str,
    prefix: Path_,
    cdr: bool,
    want: dict[Path_, int],
    strings: dict[Path_, int],
    ops: list[Op],
    leaves: dict[int, tuple[int, str]],
    fields: Sequence[tuple[str, Any]] | None = None,
) -> bool:
    """Append the ops of ``msgtype`` (or of its ``fields``); False at the first field without a fixed size."""
    for name, (node, detail) in typestore.fielddefs[msgtype][1] if fields is None else fields:
        path = (*prefix, name)
        if node == _NAME:
            if not walk_fields(typestore, detail, path, cdr, want, strings, ops, leaves):
                return False
        elif node == _BASE:
            prim = detail[0]
            if prim == "string":
                ops.append(Op("string", 4 if cdr else 1, 0, strings.get(path, -1)))
            elif prim in _PRIMITIVES:
                size, kind = _PRIMITIVES[prim]
                slot = want.get(path, -1)
                if slot >= 0:
                    leaves[slot] = (size, kind)
                ops.append(Op("leaf" if slot >= 0 else "skip", size if cdr else 1, size, slot))
            else:
                return False
        elif node == _ARRAY and detail[0][0] == _BASE and detail[0][1][0] in _PRIMITIVES:
            size, kind = _PRIMITIVES[detail[0][1][0]]
            slots = [want.get((*path, str(k)), -1) for k in range(detail[1])]  # elements read, e.g. a diagonal
            if max(slots) < 0:
                ops.append(Op("skip", size if cdr else 1, size * detail[1]))
            for slot in slots if max(slots) >= 0 else ():
                if slot >= 0:
                    leaves[slot] = (size, kind)
                ops.append(Op("leaf" if slot >= 0 else "skip", size if cdr else 1, size, slot))
        elif node == _ARRAY and detail[0][0] == _NAME:
            for k in range(detail[1]):
                if not walk_fields(typestore, detail[0][1], (*path, str(k)), cdr, want, strings, ops, leaves):
                    return False
        else:
            return False
    return True


def merged_ops(ops: list[Op]) -> tuple[Op, ...]:
    """Runs of unwanted fixed fields become one skip (their alignment is implied)."""
    merged: list[Op] = []
    for op in ops:
        last = merged[-1] if merged else None
        if op.kind == "skip" and last and last.kind == "skip" and op.align <= last.align and last.size % op.align == 0:
            merged[-1] = Op("skip", last.align, last.size + op.size)
        else:
            merged.append(op)
    return tuple(merged)


def _item_plan(
    typestore: Typestore, fields: Sequence[tuple[str, Any]], name: str, columns: Sequence[Path_], cdr: bool
) -> tuple[int, ItemPlan] | None:
    """Index of the sequence field ``name`` and the plan of its elements (None unless all fixed-size)."""
    index = next((k for k, (field, _) in enumerate(fields) if field == name), None)
    if index is None:
        return None
    node, detail = fields[index][1]
    if node != _SEQUENCE or detail[0][0] != _NAME:
        return None
    want = {path: k for k, path in enumerate(columns)}
    ops: list[Op] = []
    leaves: dict[int, tuple[int, str]] = {}
    if not walk_fields(typestore, detail[0][1], (), cdr, want, {}, ops, leaves) or len(leaves) != len(want):
        return None
    if any(op.kind == "string" for op in ops):
        return None
    return index, ItemPlan(merged_ops(ops), tuple(leaves[k] for k in range(len(want))))


def make_plan(
    typestore: Typestore,
    msgtype: str,
    columns: Sequence[Path_],
    strings: Sequence[Path_] = (FRAME_ID,),
    *,
    cdr: bool,
    items: tuple[str, Sequence[Path_]] | None = None,
) -> Plan | None:
    """Plan reading the header stamp, ``columns`` (numbers) and ``strings`` of ``msgtype``.

    With ``items = (field, element columns)`` the plan also reads those columns from every element of the
    top-level sequence ``field``; everything before it must then have a fixed size.

    Returns None when the type has no ``std_msgs/Header`` first, a path is missing or not a number/string,
    or a wanted field lies behind a dynamic sequence (those types go through rosbags instead).
    """
    fields = typestore.fielddefs.get(msgtype)
    if not fields or not fields[1] or fields[1][0][0] != "header" or fields[1][0][1] != (_NAME, HEADER):
        return None
    want = {path: k for k, path in enumerate((STAMP_SEC, STAMP_NSEC, *columns))}
    if len(want) != len(columns) + 2:
        return None
    string_slots = {path: k for k, path in enumerate(strings)}
    ops: list[Op] = []
    leaves: dict[int, tuple[int, str]] = {}
    item_plan = None
    if items is None:
        walk_fields(typestore, msgtype, (), cdr, want, string_slots, ops, leaves)  # may stop early: checked below
    else:
        found = _item_plan(typestore, fields[1], items[0], items[1], cdr)
        if found is None or not walk_fields(
            typestore, msgtype, (), cdr, want, string_slots, ops, leaves, fields[1][: found[0]]
        ):
            return None
        item_plan = found[1]
    found_strings = {op.slot for op in ops if op.kind == "string" and op.slot >= 0}
    if len(leaves) != len(want) or len(found_strings) != len(string_slots):
        return None
    return Plan(msgtype, cdr, merged_ops(ops), tuple(leaves[k] for k in range(len(want))), len(string_slots), item_plan)


# --------------------------------------------------------------------------- kernels


@njit(cache=True, nogil=True)
def _gather(data, offsets, sizes, big):  # pragma: no cover - compiled
    """Words of ``sizes[j]`` bytes at ``offsets[i, j]`` (unaligned reads), normalised to little endian."""
    n, m = offsets.shape
    out = np.empty((n, m), np.uint64)
    for i in range(n):
        for j in range(m):
            out[i, j] = _word(data, offsets[i, j], sizes[j], big)
    return out


@subroutine(types.uint64)
def _word(data, p, width, big):  # pragma: no cover - compiled
    """The ``width`` bytes at ``p`` (unaligned; big endian when ``big``) as a little-endian word; unsigned indices
    (no wrap-around checks). The one reading of a serialised word for this module's kernels (:func:`_gather`,
    :func:`_walk`): a subroutine, compiled into each kernel that calls it. (``tfdecode._u64`` keeps its own
    unrolled 8-byte copy: this one inlined into its walker cost it ~0.15 CPU s more to compile, docs/benchmarks.md.)"""
    w = np.uint64(0)
    at = np.uint64(p)
    if big:
        for b in range(np.uint64(width)):
            w = (w << np.uint64(8)) | np.uint64(data[at + b])
    elif width == 8:  # the common case, unrolled
        for b in range(8):
            w = w | (np.uint64(data[at + np.uint64(b)]) << np.uint64(8 * b))
    else:
        for b in range(np.uint64(width)):
            w = w | (np.uint64(data[at + b]) << np.uint64(8 * b))
    return w


@subroutine(types.int64)
def _integer(w, width, signed):  # pragma: no cover - compiled
    """A word of ``width`` bytes as int64 (sign-extended if ``signed``)."""
    v = np.int64(w)
    if signed and width < 8 and v >= np.int64(1) << np.int64(8 * width - 1):
        v -= np.int64(1) << np.int64(8 * width)
    return v


@subroutine(types.none)
def _store(w, s, kind, bits, values, row, col, bits32, float32):  # pragma: no cover - compiled
    """A leaf's word ``w`` of ``s`` bytes into row ``row``, column ``col``: a float64's bits into ``bits``, the other
    kinds (float32 ``0``, signed ``1``, unsigned integers) as float64 into ``values``; ``bits32`` and ``float32`` one
    word's two views. The message's and the elements' leaves share it (one copy of the dispatch to compile)."""
    if kind == 0 and s == 8:
        bits[row, col] = w
    elif kind == 0:
        bits32[0] = np.uint32(w)
        values[row, col] = np.float64(float32[0])
    elif kind == 1:
        values[row, col] = np.float64(_integer(w, s, True))
    else:
        values[row, col] = np.float64(w)


@njit(cache=True, nogil=True, nrt=False)
def _walk(  # pragma: no cover - compiled
    data, origin, limit, big, cdr, check,
    kinds, aligns, sizes, slots, leaf_kinds,
    with_items, item_leaf, item_align, item_size, item_slot, item_kinds, min_size,
    t_ns, bits, values, bits32, float32, spos, slen, counts, item_bits, item_values,
):  # fmt: skip
    """The wanted fields of every message in one compiled pass: header stamps in ns, the other leaves as float64,
    (position, length) of each wanted string, and for a plan with items the elements of the sequence after them: what
    :func:`_offsets`, :func:`_decode_items`, :func:`_gather` and :func:`_convert` do in array steps, without
    their temporary arrays, message by message (one sweep over the bytes instead of one per op: ~25% faster than
    op by op; and a first run compiles one kernel, not three).

    Its arguments: the bytes, where each message's fields start and how many bytes it has from there, the byte
    order, CDR or not, whether to check each message's CDR header (the 4 bytes before its origin);
    :attr:`Plan.program`; whether the plan has items, :attr:`ItemPlan.program` and the bytes of an element without
    padding; the arrays written (see :func:`walked_columns`), element rows in message order. Each message's lines are
    asked for (:func:`.simd.prefetch`) :data:`_AHEAD` messages before they are read: a topic's messages lie apart
    in a chunk or a db3 window, and without it each message start was a cache miss (~2x the pass's time). A
    string equal to the same field's string of the message before (a topic's frame id, message after message) is
    given that string's position, its first occurrence's: :func:`string_codes` then reads bytes in cache, not a
    cache miss per message again.

    Returns the number of element rows and where the array steps, which go op by op over all messages, stop: the
    least of every message's first failure, (op index, 0) for "message shorter than its layout" (op index =
    number of ops: the end of the walk, or of the sequence length after it), (op index, 1) for "string runs past
    the end", (number of ops, 2) for "sequence runs past the end"; (-1, 0) when every message fits. A leaf past a
    message's end is not read, as there: the next string or the end then fails. Last, the headers' code (0 when
    not checked): 2 a message shorter than its header, else 1 an encapsulation that is not plain CDR, else -1 a
    message in the other byte order, else 0.
    """
    n = origin.shape[0]
    nops = kinds.shape[0]
    fail_op, fail_stage = nops + 1, 0
    header = 0
    m = 0  # element rows written
    for i in range(n):
        if i + _AHEAD < n:
            ahead = origin[i + _AHEAD]
            for q in range(-4, limit[i + _AHEAD], 64):
                prefetch(data, ahead + q)
        o, lim = origin[i], limit[i]
        if check:  # the CDR header before the origin
            if lim < 0:
                header = 2
            elif data[o - 4] != 0 or data[o - 3] > 1:
                header = 1 if header < 1 else header
            elif header == 0 and (data[o - 3] == 0) != big:
                header = -1
        p = 0  # relative to the origin (CDR aligns relative to the end of the encapsulation header)
        op, stage = nops + 1, 0
        for k in range(nops):
            if aligns[k] > 1:  # a power of two
                p = (p + aligns[k] - 1) & -aligns[k]
            s, slot = sizes[k], slots[k]
            if kinds[k] == _SKIP:
                p += s
            elif kinds[k] == _LEAF:
                if p + s <= lim:
                    kind = leaf_kinds[slot]
                    w = _word(data, o + p, s, big)
                    if slot < 2:  # header stamp (integers: see :func:`walks`)
                        t_ns[i] += _integer(w, s, kind == 1) * (_NS if slot == 0 else 1)
                    else:
                        _store(w, s, kind, bits, values, i, slot - 2, bits32, float32)
                p += s
            else:
                if p + 4 > lim:
                    op = k
                    break
                length = np.int64(_word(data, o + p, 4, big))
                p += 4 + length
                if p > lim:
                    op, stage = k, 1
                    break
                if slot >= 0:
                    at = o + p - length
                    nbytes = (length - 1 if length > 0 else 0) if cdr else length
                    if i > 0 and slen[slot, i - 1] == nbytes:  # the bytes of the message before: in cache
                        before = spos[slot, i - 1]
                        q = 0  # 8 bytes at a time, then byte by byte
                        while q + 8 <= nbytes and _word(data, before + q, 8, False) == _word(data, at + q, 8, False):
                            q += 8
                        while q < nbytes and data[np.uint64(before + q)] == data[np.uint64(at + q)]:
                            q += 1
                        if q == nbytes:  # the same string: its first occurrence's bytes (string_codes reads them)
                            at = before
                    spos[slot, i] = at
                    slen[slot, i] = nbytes
        if op > nops and p > lim:
            op = nops
        if with_items and op > nops:  # the sequence: its uint32 length, then the elements
            if cdr:
                p = (p + 3) & -4
            if p + 4 > lim:
                op = nops
            else:
                count = np.int64(_word(data, o + p, 4, big))
                p += 4
                # a corrupt count must not run past the rows made for the batch (nor allocate gigabytes)
                if count * min_size > lim - p or m + count > item_bits.shape[0]:
                    op, stage = nops, 2
                else:
                    counts[i] = count
                    for _ in range(count):
                        for k in range(item_leaf.shape[0]):
                            a = item_align[k]
                            if a > 1:
                                p = (p + a - 1) & -a
                            s = item_size[k]
                            if item_leaf[k] and p + s <= lim:
                                slot, kind = item_slot[k], item_kinds[item_slot[k]]
                                w = _word(data, o + p, s, big)
                                _store(w, s, kind, item_bits, item_values, m, slot, bits32, float32)
                            p += s
                        m += 1
                    if p > lim:
                        op, stage = nops, 2
        if op < fail_op or (op == fail_op and stage < fail_stage):
            fail_op, fail_stage = op, stage
    return m, (fail_op if fail_op <= nops else -1), fail_stage, header


_U32 = np.array([4], np.int64)  # one leaf of 4 bytes, for _gather


def _u32(data: np.ndarray, offsets: np.ndarray, big: bool) -> np.ndarray:
    """The uint32 at each of ``offsets`` (unaligned) as int64, through :func:`gather` (a NumPy fancy index of the
    4 bytes per offset took a tenth of a db3 read; the kernel or its array code gather whole words)."""
    where = np.ascontiguousarray(offsets, np.int64).reshape(-1, 1)
    return gather(data, where, _U32, big)[:, 0].astype(np.int64)


def gather(data: np.ndarray, offsets: np.ndarray, sizes: np.ndarray, big: bool) -> np.ndarray:
    """What :func:`_gather` returns, by array code for fewer than :data:`.kernel_cache.KERNEL_ROWS` rows
    (:func:`.kernel_cache.compiled_for`): a short log's first run need not compile it. Each size's columns are one
    fancy index into a view of ``data`` as that size's unsigned words in its byte order at every byte offset
    (strides of one byte: no copy), widened to uint64: the same words. Public: tests/test_fastdecode.py checks it
    against the kernel."""
    if compiled_for(offsets.shape[0], _gather) or not data.flags.c_contiguous:
        return _gather(data, offsets, sizes, big)
    out = np.empty(offsets.shape, np.uint64)
    for size in np.unique(sizes).tolist():
        cols = np.flatnonzero(sizes == size)
        words = np.ndarray((max(data.shape[0] - size + 1, 0),), f"{'>' if big else '<'}u{size}", data, 0, (1,))
        out[:, cols] = words[offsets[:, cols]]
    return out


#: Elements per message up to which :func:`item_offsets` takes array code (one array step per element and leaf).
ARRAY_ITEMS = 256


def item_offsets(
    origin: np.ndarray, first: np.ndarray, counts: np.ndarray, limit: np.ndarray, *program: Any
) -> tuple[np.ndarray, int]:
    """What :func:`_item_offsets` returns (the offsets of a message past its end's first failing message aside),
    by array code for fewer than :data:`.kernel_cache.KERNEL_ROWS` elements of at most :data:`ARRAY_ITEMS` per
    message: element ``e`` of every message that has one, one step per leaf. Public: tests/test_fastdecode.py
    checks it against the kernel."""
    n = origin.shape[0]
    most = int(counts.max()) if n else 0
    if most > ARRAY_ITEMS or compiled_for(int(counts.sum()), _item_offsets):
        return _item_offsets(origin, first, counts, limit, *program)
    is_leaf, align, size, slot, nleaves = program
    out = np.empty((int(counts.sum()), nleaves), np.int64)
    row = np.cumsum(counts) - counts
    p = first.astype(np.int64)  # relative to origin
    for e in range(most):
        live = np.flatnonzero(counts > e)
        q = p[live]
        for k in range(is_leaf.shape[0]):
            if align[k] > 1:
                q = (q + align[k] - 1) // align[k] * align[k]
            if is_leaf[k]:
                out[row[live] + e, slot[k]] = origin[live] + q
            q = q + size[k]
        p[live] = q
    over = np.flatnonzero(p > limit)
    return out, int(over[0]) if over.size else -1


@njit(cache=True, nogil=True)
def payload_hashes(data, start, size, skip):  # pragma: no cover - compiled
    """64-bit FNV-1a of each payload after its first ``skip`` bytes (duplicate detection without copies)."""
    out = np.empty(start.shape[0], np.uint64)
    prime = np.uint64(1099511628211)
    for i in range(start.shape[0]):
        h = np.uint64(14695981039346656037)
        for p in range(start[i] + min(skip, size[i]), start[i] + size[i]):
            h = (h ^ np.uint64(data[p])) * prime
        out[i] = h
    return out


@njit(cache=True, nogil=True)
def _item_offsets(origin, first, counts, limit, is_leaf, align, size, slot, nleaves):  # pragma: no cover - compiled
    """Absolute offsets of every element's leaves (rows in message order); CDR alignment is relative to
    ``origin``. Returns the offsets and the first message whose elements run past its end (-1: none)."""
    out = np.empty((counts.sum(), nleaves), np.int64)
    m = 0
    for i in range(origin.shape[0]):
        p = first[i]  # relative to origin[i]
        for _ in range(counts[i]):
            for k in range(is_leaf.shape[0]):
                a = align[k]
                if a > 1:
                    p = (p + a - 1) // a * a
                if is_leaf[k]:
                    out[m, slot[k]] = origin[i] + p
                p += size[k]
            m += 1
        if p > limit[i]:
            return out, i
    return out, -1


def _as_float(words: np.ndarray, size: int, kind: str) -> np.ndarray:
    """Reinterpret normalised words (columns of one size and kind) as float64 (ints exact up to 2**53)."""
    if size == 8:
        return words.view({"f": np.float64, "i": np.int64, "u": np.uint64}[kind]).astype(np.float64, copy=False)
    narrow = words.astype(np.dtype(f"u{size}"))
    return narrow.view(np.dtype(f"{kind}{size}")).astype(np.float64)


# --------------------------------------------------------------------------- decoding


@dataclass
class Decoded:
    """Columns of one batch: stamps, numbers and per-string codes into batch-local name lists."""

    t_ns: np.ndarray  # (n,) int64
    values: np.ndarray  # (n, ncolumns) float64
    strings: list[tuple[np.ndarray, list[str]]]  # per string slot: (codes (n,) int32, names)
    counts: np.ndarray | None = None  # (n,) int64 elements per message (plans with items)
    items: np.ndarray | None = None  # (sum(counts), nitems) float64, elements in message order


@njit(cache=True, nogil=True, nrt=False)
def dedup(data, pos, length, codes, firsts, hashes, table):  # pragma: no cover - compiled
    """Per-string ``codes``, distinct strings numbered by first appearance, and the first string of every code
    (``firsts``); returns the number of distinct strings, or -1 when they would fill ``table`` more than half.

    An open-addressing table (``table``: all -1, a power of two long) keyed by a 64-bit FNV-1a hash; a hit is
    confirmed byte for byte, so two strings with one hash stay apart. A string equal to the one before it (a
    topic's frame id, message after message) takes its code without hashing.
    Public: tests/test_fastdecode.py counts its calls."""
    n = pos.shape[0]
    cap = table.shape[0]
    k = 0
    prime = np.uint64(1099511628211)
    for i in range(n):
        if i + _AHEAD < n:
            prefetch(data, pos[i + _AHEAD])
        if i > 0 and length[i] == length[i - 1]:
            same = True
            a, b = np.uint64(pos[i - 1]), np.uint64(pos[i])  # unsigned: no wrap-around checks
            for q in range(np.uint64(length[i])):
                if data[a + q] != data[b + q]:
                    same = False
                    break
            if same:
                codes[i] = codes[i - 1]
                continue
        h = (np.uint64(14695981039346656037) ^ np.uint64(length[i])) * prime
        for q in range(pos[i], pos[i] + length[i]):
            h = (h ^ np.uint64(data[q])) * prime
        slot = np.int64(h & np.uint64(cap - 1))
        code = -1
        while table[slot] >= 0:
            c = table[slot]
            f = firsts[c]
            if hashes[c] == h and length[f] == length[i]:
                same = True
                for q in range(length[i]):
                    if data[pos[f] + q] != data[pos[i] + q]:
                        same = False
                        break
                if same:
                    code = c
                    break
            slot = (slot + 1) & (cap - 1)
        if code < 0:
            code = k
            firsts[k] = i
            hashes[k] = h
            table[slot] = k
            k += 1
            if 2 * k > cap:  # the table is kept at most half full: the caller gives a larger one
                return -1
        codes[i] = code
    return k


#: Public: tests/test_fastdecode.py fills a table of this size.
SMALL_TABLE = 64


def _table_size(n: int) -> int:
    """A power of two at least twice ``n`` (and at least :data:`SMALL_TABLE`)."""
    return max(SMALL_TABLE, 1 << (2 * n).bit_length())


def _one_string(data: np.ndarray, pos: np.ndarray, length: np.ndarray) -> bool:
    """Whether every string is the first one (or there are none), checked by array code: a topic's frame id is one
    string message after message, and a short log's first run need not compile :func:`dedup` for it (~0.25 s of
    CPU). One gather of every string's byte per position: for arrays shorter than :data:`.kernel_cache.KERNEL_ROWS`."""
    if not pos.shape[0]:
        return True
    size = int(length[0])
    if np.any(length != size):
        return False
    first = int(pos[0])
    return all(np.all(data[pos + q] == data[first + q]) for q in range(size))


def string_codes(data: np.ndarray, pos: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Per-string codes and the distinct strings in order of first appearance, coded in compiled code
    (:func:`dedup`) however many distinct values a field has (a frame id takes a handful, tag frames
    hundreds).

    Raises:
        DecodeError: A string is not UTF-8.

    """
    n = pos.shape[0]
    if not compiled_for(n, dedup) and _one_string(data, pos, length):
        codes, firsts = np.zeros(n, np.int32), np.zeros(min(n, 1), np.int64)
    else:
        codes, firsts, hashes = np.empty(n, np.int32), np.empty(n, np.int64), np.empty(n, np.uint64)
        # the arrays made here, not in the kernel (see walked_columns); a table for 32 distinct strings, a frame id's
        # few, else one that holds every string
        k = dedup(data, pos, length, codes, firsts, hashes, np.full(SMALL_TABLE, -1, np.int64))
        if k < 0:
            k = dedup(data, pos, length, codes, firsts, hashes, np.full(_table_size(n), -1, np.int64))
        firsts = firsts[:k]
    try:
        names = [data[pos[f] : pos[f] + length[f]].tobytes().decode() for f in firsts.tolist()]
    except UnicodeDecodeError as err:
        raise DecodeError(f"string is not UTF-8 ({err.reason})") from None
    return codes, names


def decode(plan: Plan, batch: RawBatch, rows: np.ndarray | None = None, walk: bool = True) -> Decoded:
    """Decode messages ``rows`` (default all) of ``batch`` with ``plan``: by the compiled pass (:func:`_walk`) where
    it decodes the plan (:func:`walks`) and ``walk`` says so, else by the array steps (the same bits).

    Raises:
        DecodeError: A message is shorter than its layout, has an unsupported CDR encapsulation or a
            string that is not UTF-8.

    """
    data = batch.data
    start = batch.start if rows is None else batch.start[rows]
    size = batch.size if rows is None else batch.size[rows]
    if walk and walks(plan):  # the common case: one byte order, the compiled pass's arrays are the columns
        # the byte order of the first message; the pass checks every CDR header against it
        big = bool(plan.cdr and start.shape[0] and size[0] >= 4 and data[start[0] + 1] == 0)
        walked = walked_columns(plan, data, start, size, big, check=plan.cdr)
        if walked is not None:
            t_ns, values, strings, counts, items = walked
            return Decoded(t_ns, values, [string_codes(data, pos, length) for pos, length in strings], counts, items)
    groups = _byte_orders(plan, data, start, size)
    n = start.shape[0]
    t_ns = np.empty(n, np.int64)
    values = np.empty((n, len(plan.leaves) - 2), np.float64)
    codes = [np.empty(n, np.int32) for _ in range(plan.nstrings)]
    names: list[list[str]] = [[] for _ in range(plan.nstrings)]
    counts = np.zeros(n, np.int64) if plan.items is not None else None
    item_parts: list[tuple[np.ndarray, np.ndarray]] = []  # per group: (message rows, element values)
    for idx, big in groups:
        if not start[idx].size:
            continue
        if walk and walks(plan):
            t_ns[idx], values[idx], strings, group_counts, group_items = walked_columns(
                plan, data, start[idx], size[idx], big
            )
            if counts is not None and group_counts is not None and group_items is not None:
                counts[idx] = group_counts
                item_parts.append((np.arange(n)[idx], group_items))
        else:
            origin = start[idx] + (4 if plan.cdr else 0)
            limit = size[idx] - (4 if plan.cdr else 0)
            offsets, strings, end = _offsets(plan, data, origin, limit, big)
            if np.any(end > limit):
                raise DecodeError(f"message shorter than its {plan.msgtype} layout")
            if plan.items is not None:
                counts[idx], values_of_group = _decode_items(plan, data, origin, limit, end, big)
                item_parts.append((np.arange(n)[idx], values_of_group))
            got = _convert(gather(data, offsets, plan.sizes, big), plan)
            t_ns[idx] = got[:, 0].astype(np.int64) * _NS + got[:, 1].astype(np.int64)
            values[idx] = got[:, 2:]
        for k, (pos, length) in enumerate(strings):
            sub_codes, sub_names = string_codes(data, pos, length)
            codes[k][idx] = sub_codes + len(names[k])
            names[k] += sub_names
    items = None
    if plan.items is not None:
        items = _in_message_order(counts, item_parts, len(plan.items.leaves))
    return Decoded(t_ns, values, [(c, nm) for c, nm in zip(codes, names, strict=True)], counts, items)


#: The CDR header's errors, by :func:`_walk`'s header code less one (the greater code wins, as the checks' order).
_CDR_HEADER_ERRORS = ("unsupported CDR encapsulation (only plain CDR is read)", "message shorter than its CDR header")


def _byte_orders(
    plan: Plan, data: np.ndarray, start: np.ndarray, size: np.ndarray
) -> list[tuple[slice | np.ndarray, bool]]:
    """The messages by byte order: (rows, big endian) per group, little endian first (CDR says per message).

    Raises:
        DecodeError: A CDR message shorter than its header, or not plain CDR.
    """
    n = start.shape[0]
    if not plan.cdr:
        return [(slice(None), False)]
    if n and int(size.min()) < 4:
        raise DecodeError(_CDR_HEADER_ERRORS[1])
    flag = data[start + 1]
    if n and (np.any(data[start] != 0) or np.any(flag > 1)):
        raise DecodeError(_CDR_HEADER_ERRORS[0])
    little = flag == 1
    if little.all():
        return [(slice(None), False)]
    return [(np.flatnonzero(little), False), (np.flatnonzero(~little), True)]


def walked_columns(
    plan: Plan, data: np.ndarray, start: np.ndarray, size: np.ndarray, big: bool, check: bool = False
) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray]], np.ndarray | None, np.ndarray | None] | None:
    """Stamps, values, (position, length) per string, and with items the element counts and rows of messages of
    one byte order, by :func:`_walk`.

    ``check``: the pass also checks each message's CDR header (what :func:`_byte_orders` checks, where the pass
    reads the message: its cache miss is met once) and returns None when a message is in the other byte order
    (the caller then walks each byte order apart).

    Raises:
        DecodeError: A CDR header too short or not plain CDR (``check``), a message shorter than its layout, or
            a string or sequence running past its end.

    Public: tests/test_fastdecode.py checks it against the array steps."""
    head = 4 if plan.cdr else 0
    n = start.shape[0]
    limit = size - head
    # the outputs made here, not in the kernel: numba compiles every allocation and view it is asked for (~0.6 s
    # of a first run's compiling), NumPy makes them for nothing
    t_ns = np.zeros(n, np.int64)
    bits = np.empty((n, len(plan.leaves) - 2), np.uint64)  # float64 leaves are their bits: stored as read
    bits32 = np.empty(1, np.uint32)  # a float32 leaf's bits (its view made once: one made per value costs more)
    spos = np.zeros((plan.nstrings, n), np.int64)
    slen = np.zeros((plan.nstrings, n), np.int64)
    if plan.items is not None:  # rows for as many elements as the bytes can hold: a count beyond is an error
        counts = np.zeros(n, np.int64)
        item_bits = np.empty((max(int(limit.sum()), 0) // plan.items.min_size, len(plan.items.leaves)), np.uint64)
        items = (True, *plan.items.program, plan.items.walk_kinds, plan.items.min_size)
    else:
        counts, item_bits, items = _NO_COUNTS, _NO_ITEM_BITS, _NO_ITEMS
    values, item_values = bits.view(np.float64), item_bits.view(np.float64)
    out = (t_ns, bits, values, bits32, bits32.view(np.float32), spos, slen, counts, item_bits, item_values)
    rows, op, stage, header = _walk(data, start + head, limit, big, plan.cdr, check, *plan.program, *items, *out)
    if header > 0:  # as _byte_orders finds them, before any layout's error
        raise DecodeError(_CDR_HEADER_ERRORS[header - 1])
    if header < 0:
        return None
    if op >= 0:
        what = ("message shorter than its {} layout", "string runs past the end of a {} message")
        raise DecodeError((*what, "sequence runs past the end of a {} message")[stage].format(plan.msgtype))
    strings = list(zip(spos, slen, strict=True))
    if plan.items is None:
        return t_ns, values, strings, None, None
    return t_ns, values, strings, counts, item_values[:rows]


#: What :func:`_walk` is given for a plan without items: the types of a plan with items, nothing in them (one
#: compiled version serves both).
_NO_ITEMS = (False, np.zeros(0, np.bool_), *(np.zeros(0, np.int64) for _ in range(4)), 1)
_NO_COUNTS = np.zeros(0, np.int64)
_NO_ITEM_BITS = np.zeros((0, 0), np.uint64)


def walk_compiled(messages: int) -> bool:
    """Whether a read whose longest topic has ``messages`` messages decodes by :func:`_walk`
    (:func:`.kernel_cache.worth_compiling`: from :data:`.kernel_cache.KERNEL_ROWS` messages on, or a kernel compiled
    already or with a second core). Else by the array steps: a short log's first run on one core compiles none of
    the readers' decoding kernels (~1 s of CPU) and decodes in ~1.3x the pass's CPU (~0.02 s more on a 90 s log)."""
    return worth_compiling(_walk, messages, KERNEL_ROWS)


def walks(plan: Plan) -> bool:
    """Whether :func:`_walk` decodes ``plan``: header stamps of integers (as every ROS header's are).
    Public: tests/test_fastdecode.py turns the walk off with it."""
    return all(kind in "iu" for _, kind in plan.leaves[:2])


def _convert(words: np.ndarray, leaves: _Leaves) -> np.ndarray:
    got = np.empty(words.shape, np.float64)
    for (width, kind), cols in leaves.kinds.items():
        got[:, cols] = _as_float(words[:, cols], width, kind)
    return got


def _decode_items(
    plan: Plan, data: np.ndarray, origin: np.ndarray, limit: np.ndarray, end: np.ndarray, big: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Element counts and element values of the sequence that starts at ``end`` (relative to ``origin``)."""
    items = plan.items
    at = (end + 3) // 4 * 4 if plan.cdr else end  # the uint32 length
    if np.any(at + 4 > limit):
        raise DecodeError(f"message shorter than its {plan.msgtype} layout")
    counts = _u32(data, origin + at, big)
    if np.any(counts * items.min_size > limit - at - 4):  # a corrupt count must not allocate gigabytes
        raise DecodeError(f"sequence runs past the end of a {plan.msgtype} message")
    offsets, bad = item_offsets(origin, at + 4, counts, limit, *items.program, len(items.leaves))
    if bad >= 0:
        raise DecodeError(f"sequence runs past the end of a {plan.msgtype} message")
    return counts, _convert(gather(data, offsets, items.sizes, big), items)


def _in_message_order(counts: np.ndarray, parts: list[tuple[np.ndarray, np.ndarray]], width: int) -> np.ndarray:
    """Element rows of the endianness groups merged into message order."""
    if len(parts) == 1:
        return parts[0][1]
    out = np.empty((int(counts.sum()), width), np.float64)
    first = np.concatenate(([0], np.cumsum(counts)))
    for rows, values in parts:
        out[_csr_rows(first[rows], counts[rows])] = values
    return out


def _csr_rows(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Indices ``starts[k] .. starts[k] + lengths[k] - 1`` for all k, concatenated."""
    total = int(lengths.sum())
    shift = np.repeat(starts - np.concatenate(([0], np.cumsum(lengths)[:-1])), lengths)
    return shift + np.arange(total)


def _offsets(
    plan: Plan, data: np.ndarray, origin: np.ndarray, limit: np.ndarray, big: bool
) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """Absolute byte offsets of every leaf, (position, length) of every string, and the end of the walk.

    Positions are ``dynamic + static``: ``dynamic`` is a per-message array that changes only after a
    string, ``static`` a constant; ``known`` is the alignment ``dynamic`` is known to have, so CDR
    alignment costs an array operation only right after a string.
    """
    n = origin.shape[0]
    dynamic = np.zeros(n, np.int64)
    static = 0
    known = 8
    offsets = np.empty((n, len(plan.leaves)), np.int64)
    strings: list[tuple[np.ndarray, np.ndarray]] = [(np.empty(0, np.int64), np.empty(0, np.int64))] * plan.nstrings
    for op in plan.ops:
        if op.align > 1:
            if known >= op.align:
                static = -(-static // op.align) * op.align
            else:
                dynamic = (dynamic + static + op.align - 1) // op.align * op.align
                static, known = 0, op.align
        if op.kind == "leaf":
            offsets[:, op.slot] = origin + dynamic + static
            static += op.size
        elif op.kind == "skip":
            static += op.size
        else:
            at = dynamic + static + 4
            if np.any(at > limit):
                raise DecodeError(f"message shorter than its {plan.msgtype} layout")
            length = _u32(data, origin + at - 4, big)
            dynamic = at + length
            if np.any(dynamic > limit):
                raise DecodeError(f"string runs past the end of a {plan.msgtype} message")
            if op.slot >= 0:
                strings[op.slot] = (origin + at, np.maximum(length - 1, 0) if plan.cdr else length)
            static, known = 0, 1
    return offsets, strings, dynamic + static


# --------------------------------------------------------------------------- topics


@dataclass
class TopicColumns:
    """Decoded columns of one topic in record order; ``frame``/``child`` are codes into ``names``."""

    t_ns: np.ndarray  # (N,) int64 header stamps
    rec_ns: np.ndarray  # (N,) int64
    values: np.ndarray  # (N, width) float64
    frame: np.ndarray  # (N,) int32
    child: np.ndarray  # (N,) int32 (zeros when the plan reads no second string)
    names: list[str]  # frame ids as stored
    digest: np.ndarray | None = None  # (N,) uint64 payload hashes (ROS1: without the header seq), if asked
    counts: np.ndarray | None = None  # (N,) int64 elements per message (plans with items)
    items: np.ndarray | None = None  # (sum(counts), nitems) float64 element values, in message order
    stated: StatedRuns | None = None  # the columns from ``Plan.stated_from`` on, as runs (not in ``values``)


class _Columns:
    """Column buffers preallocated from the index counts, grown by doubling if the counts were short.

    A topic without items keeps its first batch's decoded arrays as they are until a second batch comes: a topic
    read in one batch (every topic of a log up to a decoding group) is not copied into the buffers at all (the
    60 s logs' four topics: ~0.4 ms of a ~10 ms read, its values' 2 MB copied from memory the cache no longer
    held)."""

    def __init__(
        self, capacity: int, width: int, digests: bool, item_width: int | None = None, stated_from: int | None = None
    ) -> None:
        self.capacity, self.width, self.digests = capacity, width if stated_from is None else stated_from, digests
        # the stated variances as each batch's runs, joined at the end: never a float64 column per message
        self.stated_from, self.stated_width = stated_from, width - (stated_from or width)
        self.runs: list[StatedRuns] = []
        self.n = 0
        self.names: dict[str, int] = {}
        # plans with items: elements per message, and the elements in a buffer sized from the first batch
        self.item_width = item_width
        self.items: np.ndarray | None = None
        self.m = 0
        self.alone: _Part | None = None  # the first batch as decoded (see the class)
        self.made = False  # the buffers below

    def _make(self) -> None:
        capacity, self.made = self.capacity, True
        self.digest = np.empty(capacity, np.uint64) if self.digests else None
        self.t_ns = np.empty(capacity, np.int64)
        self.rec_ns = np.empty(capacity, np.int64)
        self.values = np.empty((capacity, self.width), np.float64)
        self.frame = np.empty(capacity, np.int32)
        self.child = np.zeros(capacity, np.int32)
        self.counts = np.zeros(capacity, np.int64) if self.item_width is not None else None

    def append(self, dec: Decoded, rec_ns: np.ndarray, digest: np.ndarray | None) -> None:
        codes = []
        for string_codes_, names in dec.strings:  # coded by first appearance over the batches, in their order
            lut = np.array([self.names.setdefault(name, len(self.names)) for name in names], np.int32)
            codes.append(lut[string_codes_] if string_codes_.size else string_codes_)
        if self.stated_from is not None:
            values, runs = dec.values[:, : self.stated_from], stated_runs(dec.values[:, self.stated_from :])
            self.runs.append(StatedRuns(runs.starts + sum(r.n for r in self.runs), runs.values, runs.n))
            dec = replace(dec, values=values)
        part = _Part(dec, rec_ns, digest, codes)
        if not self.made and self.alone is None and self.item_width is None:
            self.alone = part
            return
        if not self.made:
            self._make()
        if self.alone is not None:
            first, self.alone = self.alone, None
            self._put(first)
        self._put(part)

    def _put(self, part: _Part) -> None:
        dec, rec_ns, digest = part.dec, part.rec_ns, part.digest
        k = rec_ns.shape[0]
        if self.n + k > self.t_ns.shape[0]:
            size = max(2 * self.t_ns.shape[0], self.n + k)
            self.t_ns, self.rec_ns, self.frame, self.child = (
                np.resize(a, size) for a in (self.t_ns, self.rec_ns, self.frame, self.child)
            )
            self.values = np.resize(self.values, (size, self.values.shape[1]))
            if self.digest is not None:
                self.digest = np.resize(self.digest, size)
            if self.counts is not None:
                self.counts = np.resize(self.counts, size)
        at = slice(self.n, self.n + k)
        if self.digest is not None and digest is not None:
            self.digest[at] = digest
        self.t_ns[at] = dec.t_ns
        self.rec_ns[at] = rec_ns
        self.values[at] = dec.values
        for target, codes in zip((self.frame, self.child), part.codes, strict=False):
            target[at] = codes
        if self.counts is not None and dec.counts is not None and dec.items is not None:
            self.counts[at] = dec.counts
            self._add_items(dec.items, k)
        self.n += k

    def _add_items(self, items: np.ndarray, messages: int) -> None:
        need = self.m + items.shape[0]
        if self.items is None:  # as many per message as in this batch, for every message of the topic, + 10 %
            guess = int(items.shape[0] / max(messages, 1) * self.t_ns.shape[0] * 1.1) + 16
            self.items = np.empty((max(guess, need), items.shape[1]))
        elif need > self.items.shape[0]:
            grown = np.empty((max(2 * self.items.shape[0], need), self.items.shape[1]))
            grown[: self.m] = self.items[: self.m]
            self.items = grown
        self.items[self.m : need] = items
        self.m = need

    def stated(self) -> StatedRuns | None:
        """The batches' runs joined (a run going on in the next batch is one run)."""
        if self.stated_from is None:
            return None
        if not self.runs:
            return StatedRuns(np.zeros(0, np.int64), np.zeros((0, self.stated_width)), 0)
        starts = np.concatenate([r.starts for r in self.runs])
        return stated_runs(np.concatenate([r.values for r in self.runs]), starts, sum(r.n for r in self.runs))

    def done(self) -> TopicColumns:
        if self.alone is not None:
            return self._sorted(*self.alone.columns(), None, None)
        if not self.made:
            self._make()
        n = self.n
        digest = self.digest[:n] if self.digest is not None else None
        cols = [self.t_ns[:n], self.rec_ns[:n], self.values[:n], self.frame[:n], self.child[:n]]
        counts = items = None
        if self.counts is not None and self.item_width is not None:
            counts = self.counts[:n]
            items = self.items[: self.m] if self.items is not None else np.zeros((0, self.item_width))
        return self._sorted(cols, digest, counts, items)

    def _sorted(
        self, cols: list[np.ndarray], digest: np.ndarray | None, counts: np.ndarray | None, items: np.ndarray | None
    ) -> TopicColumns:
        """The columns in record order (stably sorted when the file's order was another)."""
        n = cols[0].shape[0]
        stated = self.stated()
        if n > 1 and not bool(np.all(cols[1][1:] >= cols[1][:-1])):  # file order -> record order
            order = np.argsort(cols[1], kind="stable")
            cols = [a[order] for a in cols]
            stated = stated_runs(stated.expanded()[order]) if stated is not None else None
            digest = digest[order] if digest is not None else None
            if counts is not None and items is not None:
                first = np.concatenate(([0], np.cumsum(counts)))
                items = items[_csr_rows(first[order], counts[order])]
                counts = counts[order]
        return TopicColumns(*cols, list(self.names), digest, counts, items, stated)


@dataclass(frozen=True)
class _Part:
    """One batch's decoded columns of a topic, its frame ids coded as the topic's (:class:`_Columns`)."""

    dec: Decoded
    rec_ns: np.ndarray
    digest: np.ndarray | None
    codes: list[np.ndarray]  # per string slot

    def columns(self) -> tuple[list[np.ndarray], np.ndarray | None]:
        """t_ns, rec_ns, values, frame and child codes (zeros without such a string), and the digests."""
        n = self.rec_ns.shape[0]
        frame, child = (*self.codes, *(np.zeros(n, np.int32) for _ in range(2)))[:2]
        return [self.dec.t_ns, self.rec_ns, self.dec.values, frame, child], self.digest


def read_columns(
    reader: AnyReader,
    path: str | Path,
    topics: Mapping[str, tuple[Sequence[Connection], Plan]],
    *,
    digests: bool = False,
) -> dict[str, TopicColumns]:
    """Decode several topics in one pass over the log (each chunk is decompressed once).

    ``digests`` adds a 64-bit hash of every payload (ROS1: after the header ``seq``, which differs
    between otherwise identical messages), for finding duplicates without keeping the bytes.

    Raises:
        InputError: Unreadable data, or a message that does not match its definition.

    """
    names = list(topics)
    conns: list[Connection] = []
    owner: list[int] = []
    for k, topic in enumerate(names):
        conns += topics[topic][0]
        owner += [k] * len(topics[topic][0])
    owner_of = np.array(owner, np.int64)
    out = []
    for t in names:
        conns_t, plan = topics[t]
        item_width = len(plan.items.leaves) if plan.items is not None else None
        capacity = sum(c.msgcount for c in conns_t)
        out.append(_Columns(capacity, len(plan.leaves) - 2, digests, item_width, plan.stated_from))

    walk = walk_compiled(max((cols.capacity for cols in out), default=0))

    def decode_topic(k: int, batch: RawBatch, rows: np.ndarray | None) -> None:
        plan = topics[names[k]][1]
        try:
            dec = decode(plan, batch, rows, walk)
        except DecodeError as err:
            raise InputError(path, f"cannot decode {plan.msgtype} message: {err}", names[k]) from None
        digest = None
        if digests:
            sub = batch if rows is None else batch.take(rows)
            digest = payload_hashes(sub.data, sub.start, sub.size, 0 if plan.cdr else 4)
        out[k].append(dec, batch.rec_ns if rows is None else batch.rec_ns[rows], digest)

    def run_lane(batch: RawBatch, todo: list[tuple[int, np.ndarray]]) -> tuple[int, InputError] | None:
        for k, rows in todo:
            try:
                decode_topic(k, batch, rows)
            except InputError as err:
                return k, err
        return None

    # Several topics are decoded on two threads (the kernels run without the GIL): the topics of each group
    # are dealt to the caller's thread and one helper by message count, the helper's first.
    helper = ThreadPoolExecutor(1, thread_name_prefix="slamobs-decode") if len(names) > 1 else None
    try:
        for batch in grouped(iter_batches(reader, path, conns)):
            if helper is None:
                decode_topic(0, batch, None)
                continue
            which = owner_of[batch.conn]
            parts = [(k, rows) for k in range(len(names)) if (rows := np.flatnonzero(which == k)).size]
            lanes: list[list[tuple[int, np.ndarray]]] = [[], []]
            load = [0, 0]
            for k, rows in sorted(parts, key=lambda part: -part[1].size):
                lane = 0 if load[0] <= load[1] else 1
                lanes[lane].append((k, rows))
                load[lane] += rows.size
            there = helper.submit(run_lane, batch, lanes[0])
            failures = [f for f in (run_lane(batch, lanes[1]), there.result()) if f is not None]
            if failures:  # the first topic's error, as one thread would have met it
                raise min(failures, key=lambda f: f[0])[1]
    finally:
        if helper is not None:
            helper.shutdown(wait=True, cancel_futures=True)
    return {t: cols.done() for t, cols in zip(names, out, strict=True)}


@cache
def _row_paths(msgtype: str) -> tuple[tuple[Path_, ...], Path_ | None] | None:
    """:func:`layout_paths` of a ``rows.LAYOUTS`` type (None: no layout, or not plain field reads), found once
    per process: running the row functions on probes was a tenth of a small log's read."""
    layout = LAYOUTS.get(msgtype)
    paths = layout_paths(layout.row, layout.child) if layout is not None else None
    return (tuple(paths[0]), paths[1]) if paths is not None else None


def plan_for(typestore: Typestore, msgtype: str, cdr: bool) -> Plan | None:
    """The plan reading a ``rows.LAYOUTS`` type's row and frames, None if it needs rosbags."""
    layout = LAYOUTS.get(msgtype)
    paths = _row_paths(msgtype)
    if layout is None or paths is None:
        return None
    strings = (FRAME_ID,) + ((paths[1],) if paths[1] is not None else ())
    plan = make_plan(typestore, msgtype, paths[0], strings, cdr=cdr)
    if plan is None or len(plan.leaves) - 2 != layout.width:
        return None
    return replace(plan, stated_from=stated_start(msgtype))


def item_plan_for(typestore: Typestore, msgtype: str, cdr: bool) -> Plan | None:
    """The plan reading a ``rows.ITEM_LAYOUTS`` detection array (frames and elements), None if it needs rosbags."""
    layout = ITEM_LAYOUTS.get(msgtype)
    if layout is None:
        return None
    return make_plan(typestore, msgtype, (), (FRAME_ID,), cdr=cdr, items=(layout.items, layout.columns))


def read_rows(
    reader: AnyReader,
    path: str | Path,
    topics: Mapping[str, Collection[Connection]],
    items: Collection[str] = (),
) -> dict[str, Rows]:
    """``rows.Rows`` of every topic of ``topics`` that has a plan, all read in one pass over the log.

    Topics named in ``items`` are detection arrays (:func:`item_plan_for`): their rows carry the elements
    (``Rows.counts``, ``Rows.items``). Topics without a plan (see :func:`plan_for`) are left out: decode
    them with ``decode.decode_rows`` / ``decode.decode_detections``.

    Raises:
        InputError: Missing definition, unreadable data, or a message that does not match its definition.

    """
    planned: dict[str, tuple[Sequence[Connection], Plan]] = {}
    for topic, connections in topics.items():
        conns = list(connections)
        require_definitions(reader, path, conns)
        choose = item_plan_for if topic in items else plan_for
        if conns and (plan := choose(reader.typestore, conns[0].msgtype, reader.is2)) is not None:
            planned[topic] = (conns, plan)
    out = {}
    for topic, cols in read_columns(reader, path, planned).items():
        frames = Frames()  # frame ids as tf2 names them; two stored spellings may become one
        lut = np.array([frames.code(name) for name in cols.names] or [0], np.int32)
        has_child = planned[topic][1].nstrings > 1
        child = lut[cols.child] if has_child else cols.child
        msgtype = planned[topic][1].msgtype
        out[topic] = Rows(
            topic,
            msgtype,
            cols.t_ns,
            cols.rec_ns,
            cols.values,
            lut[cols.frame],
            child,
            frames.names(),
            cols.counts,
            cols.items,
            cols.stated,
        )
    return out


def leaf_offsets(plan: Plan, payload: np.ndarray) -> np.ndarray:
    """Byte offsets of the plan's leaves in one serialised (little-endian) message, e.g. to fill a template."""
    origin = np.array([4 if plan.cdr else 0], np.int64)
    limit = np.array([payload.shape[0]], np.int64) - origin
    offsets, _, end = _offsets(plan, payload, origin, limit, False)
    if np.any(end > limit):
        raise DecodeError(f"message shorter than its {plan.msgtype} layout")
    return offsets[0]
