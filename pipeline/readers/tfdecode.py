"""Vectorised decoding of TF topics (``tf2_msgs/TFMessage``, ROS1 ``tf/tfMessage``) from the serialised bytes.

A TF message is a sequence of ``geometry_msgs/TransformStamped``, each with two strings (``header.frame_id``
and ``child_frame_id``), so the element offsets move with every string and :mod:`.fastdecode`'s fixed-layout
element plans do not apply. Here a compiled walker steps through every element of every message of a batch
(ROS1: little endian, header ``seq`` before the stamp, strings without terminator; CDR: either byte order per
message, alignment relative to the end of the encapsulation header, strings with a NUL) and returns flat
columns: stamps, (position, length) of both strings and the bits of the seven doubles. Identical strings get
one code in compiled code (:func:`.fastdecode.string_codes`: a hash table confirmed byte for byte, so hundreds of
tag frames cost no Python object per string), then the distinct names go through :class:`.rows.Frames`.

The walker is written for the standard layout only: :func:`tf_layout` checks the definition stored in the
log against it (through fastdecode's plan walk), and a log with another layout is decoded by rosbags.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from slamobs.pipeline.kernel_cache import cached, njit
from rosbags.interfaces import Nodetype

from slamobs.pipeline.errors import InputError

from .container import iter_batches, require_definitions
from .fastdecode import FRAME_ID, STAMP_NSEC, STAMP_SEC, DecodeError, Op, merged_ops, string_codes, walk_fields
from .rows import Frames, TfRows
from .storage import grouped

if TYPE_CHECKING:
    from collections.abc import Collection
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
CHILD_FRAME_ID = ("child_frame_id",)
VALUES = tuple(
    ("transform", part, axis) for part, axes in (("translation", "xyz"), ("rotation", "xyzw")) for axis in axes
)
_NS = 1_000_000_000


def _standard_ops(cdr: bool) -> tuple[Op, ...]:
    """The merged plan ops of a standard ``TransformStamped`` (what the walker below hard-codes)."""
    if cdr:  # stamp, frame_id, child_frame_id, 7 doubles (8-aligned)
        head = (Op("leaf", 4, 4, 0), Op("leaf", 4, 4, 1), Op("string", 4, 0, 0), Op("string", 4, 0, 1))
        return head + tuple(Op("leaf", 8, 8, k) for k in range(2, 9))
    head = (
        Op("skip", 1, 4),
        Op("leaf", 1, 4, 0),
        Op("leaf", 1, 4, 1),
        Op("string", 1, 0, 0),
        Op("string", 1, 0, 1),
    )  # seq first
    return head + tuple(Op("leaf", 1, 8, k) for k in range(2, 9))


@dataclass(frozen=True)
class TfLayout:
    """A TF type whose stored definition is the standard one, in one encoding."""

    msgtype: str
    cdr: bool
    signed: tuple[bool, bool]  # whether stamp sec / nanosec are signed (as the stored definition says)


def tf_layout(typestore: Typestore, msgtype: str, cdr: bool) -> TfLayout | None:
    """The layout of ``msgtype`` if its stored definition is the standard TF message, else None (rosbags)."""
    fields = typestore.fielddefs.get(msgtype)
    if not fields or len(fields[1]) != 1:
        return None
    name, (node, detail) = fields[1][0]
    if name != "transforms" or node != Nodetype.SEQUENCE or detail[0] != (Nodetype.NAME, TRANSFORM_STAMPED):
        return None
    if TRANSFORM_STAMPED not in typestore.fielddefs:
        return None
    want = {path: k for k, path in enumerate((STAMP_SEC, STAMP_NSEC, *VALUES))}
    ops: list[Op] = []
    leaves: dict[int, tuple[int, str]] = {}
    try:
        walked = walk_fields(typestore, TRANSFORM_STAMPED, (), cdr, want, {FRAME_ID: 0, CHILD_FRAME_ID: 1}, ops, leaves)
    except KeyError:  # a nested type without a definition
        return None
    if not walked or merged_ops(ops) != _standard_ops(cdr):
        return None
    if any(leaves[k] != (8, "f") for k in range(2, 9)) or any(leaves[k][0] != 4 for k in (0, 1)):
        return None
    return TfLayout(msgtype, cdr, (leaves[0][1] == "i", leaves[1][1] == "i"))


# --------------------------------------------------------------------------- kernels

# error codes of the kernels (0: none)
_SHORT_CDR, _ENCAPSULATION, _SHORT, _STRING, _SEQUENCE = 1, 2, 3, 4, 5
_ROS1_MIN, _CDR_MIN = 76, 72  # bytes of a transform with empty strings (without padding)


@njit(cache=True)
def _u32(data, p, big):  # pragma: no cover - compiled
    """The uint32 at ``p`` (unaligned) as int64."""
    b0, b1, b2, b3 = np.int64(data[p]), np.int64(data[p + 1]), np.int64(data[p + 2]), np.int64(data[p + 3])
    return (b0 << 24) | (b1 << 16) | (b2 << 8) | b3 if big else b0 | (b1 << 8) | (b2 << 16) | (b3 << 24)


@njit(cache=True)
def _u64(data, p, big):  # pragma: no cover - compiled
    """The 8 bytes at ``p`` (unaligned) as a little-endian word."""
    w = np.uint64(0)
    if big:
        for b in range(8):
            w = (w << np.uint64(8)) | np.uint64(data[p + b])
        return w
    return (
        np.uint64(data[p])
        | (np.uint64(data[p + 1]) << np.uint64(8))
        | (np.uint64(data[p + 2]) << np.uint64(16))
        | (np.uint64(data[p + 3]) << np.uint64(24))
        | (np.uint64(data[p + 4]) << np.uint64(32))
        | (np.uint64(data[p + 5]) << np.uint64(40))
        | (np.uint64(data[p + 6]) << np.uint64(48))
        | (np.uint64(data[p + 7]) << np.uint64(56))
    )


@njit(cache=True)
def _tf_counts(data, start, size, cdr):  # pragma: no cover - compiled
    """Transforms per message and byte order (CDR); (counts, big, error code, message) with code 0 if fine.

    A count is checked against the bytes left so that a corrupt one cannot allocate gigabytes."""
    n = start.shape[0]
    counts = np.zeros(n, np.int64)
    big = np.zeros(n, np.bool_)
    head = 4 if cdr else 0
    least = _CDR_MIN if cdr else _ROS1_MIN
    for i in range(n):
        if cdr:
            if size[i] < 4:
                return counts, big, _SHORT_CDR, i
            if data[start[i]] != 0 or data[start[i] + 1] > 1:
                return counts, big, _ENCAPSULATION, i
            big[i] = data[start[i] + 1] == 0
        limit = size[i] - head
        if limit < 4:
            return counts, big, _SHORT, i
        c = _u32(data, start[i] + head, big[i])
        if c * least > limit - 4:
            return counts, big, _SEQUENCE, i
        counts[i] = c
    return counts, big, 0, -1


@njit(cache=True)
def _tf_walk(data, start, size, cdr, big, counts, total):  # pragma: no cover - compiled
    """Every transform of every message: stamp words; (position, length) of frame_id and child_frame_id,
    interleaved (string ``2 j`` is the parent of transform ``j``, ``2 j + 1`` its child); the bits of
    translation xyz + rotation xyzw as little-endian words; then an error code (0: none) and its message."""
    sec = np.empty(total, np.int64)
    nsec = np.empty(total, np.int64)
    pos = np.empty(2 * total, np.int64)
    length = np.empty(2 * total, np.int64)
    words = np.empty((total, 7), np.uint64)
    head = 4 if cdr else 0
    m = 0
    for i in range(start.shape[0]):
        origin = start[i] + head  # CDR alignment is relative to the end of the encapsulation header
        limit = size[i] - head
        b = big[i]
        p = 4  # after the element count
        for _ in range(counts[i]):
            if cdr:
                p = (p + 3) // 4 * 4
            else:
                p += 4  # header seq
            if p + 12 > limit:
                return sec, nsec, pos, length, words, _SHORT, i
            sec[m] = _u32(data, origin + p, b)
            nsec[m] = _u32(data, origin + p + 4, b)
            p += 8
            for s in range(2 * m, 2 * m + 2):  # frame_id, child_frame_id
                if cdr:
                    p = (p + 3) // 4 * 4
                if p + 4 > limit:
                    return sec, nsec, pos, length, words, _SHORT, i
                n = _u32(data, origin + p, b)
                p += 4
                if n > limit - p:
                    return sec, nsec, pos, length, words, _STRING, i
                pos[s] = origin + p
                length[s] = max(n - 1, 0) if cdr else n  # CDR: without the NUL
                p += n
            if cdr:
                p = (p + 7) // 8 * 8
            if p + 56 > limit:
                return sec, nsec, pos, length, words, _SHORT, i
            for k in range(7):
                words[m, k] = _u64(data, origin + p + 8 * k, b)
            p += 56
            m += 1
    return sec, nsec, pos, length, words, 0, -1


def _error(code: int, msgtype: str) -> DecodeError:
    return DecodeError(
        {
            _SHORT_CDR: "message shorter than its CDR header",
            _ENCAPSULATION: "unsupported CDR encapsulation (only plain CDR is read)",
            _SHORT: f"message shorter than its {msgtype} layout",
            _STRING: f"string runs past the end of a {msgtype} message",
            _SEQUENCE: f"sequence runs past the end of a {msgtype} message",
        }[code]
    )


def _stamps(sec: np.ndarray, nsec: np.ndarray, signed: tuple[bool, bool]) -> np.ndarray:
    """Header stamps in ns from the uint32 words (sign-extended where the definition says int32)."""
    sec = (sec ^ 0x80000000) - 0x80000000 if signed[0] else sec
    nsec = (nsec ^ 0x80000000) - 0x80000000 if signed[1] else nsec
    return sec * _NS + nsec


@dataclass
class TfBatch:
    """The transforms of one batch in message order (string codes into the batch-local ``names``)."""

    counts: np.ndarray  # (n,) int64 transforms per message
    t_ns: np.ndarray  # (m,) int64
    values: np.ndarray  # (m, 7) float64
    parent: np.ndarray  # (m,) int32
    child: np.ndarray  # (m,) int32
    names: list[str]  # frame ids as stored, in order of first appearance (parent before child)


def decode_batch(layout: TfLayout, data: np.ndarray, start: np.ndarray, size: np.ndarray) -> TfBatch:
    """Decode the TF messages ``data[start[i] : start[i] + size[i]]``.

    Raises:
        DecodeError: A message is shorter than its layout, has a count or string running past its end, an
            unsupported CDR encapsulation or a frame id that is not UTF-8.

    """
    counts, big, code, _ = _tf_counts(data, start, size, layout.cdr)
    if code:
        raise _error(code, layout.msgtype)
    sec, nsec, pos, length, words, code, _ = _tf_walk(data, start, size, layout.cdr, big, counts, int(counts.sum()))
    if code:
        raise _error(code, layout.msgtype)
    codes, names = string_codes(data, pos, length)  # parent before child: the order rosbags reads them
    return TfBatch(counts, _stamps(sec, nsec, layout.signed), words.view(np.float64), codes[0::2], codes[1::2], names)


class _Parts:
    """Decoded batches of one topic, joined at the end; frame ids numbered across batches as stored."""

    def __init__(self) -> None:
        self.parts: list[tuple[np.ndarray, ...]] = []
        self.names: dict[str, int] = {}

    def add(self, got: TfBatch, rec_ns: np.ndarray) -> None:
        lut = np.array([self.names.setdefault(name, len(self.names)) for name in got.names], np.int32)
        self.parts.append((got.t_ns, np.repeat(rec_ns, got.counts), lut[got.parent], lut[got.child], got.values))

    def joined(self) -> tuple[list[np.ndarray], bool]:
        """[t_ns, rec_ns, parent, child, values] in record order (stable: ties keep file order), and whether
        that moved rows (else the frame ids appear in the order they were numbered)."""
        if not self.parts:
            empty = np.zeros(0, np.int64)
            return [empty, empty, np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros((0, 7))], False
        cols = [np.concatenate(c) if len(self.parts) > 1 else c[0] for c in zip(*self.parts, strict=True)]
        self.parts = []
        rec = cols[1]
        if rec.size > 1 and not bool(np.all(rec[1:] >= rec[:-1])):
            order = np.argsort(rec, kind="stable")
            return [c[order] for c in cols], True
        return cols, False


def compiled() -> bool:
    """Whether the walker's kernels are compiled, in this process or in the kernel cache: ``slamobs info`` decodes
    a short TF topic with them only then, so a first ``info`` does not compile them (~1.7 CPU s) to draw a tree."""
    kernels = (_tf_counts, _tf_walk)
    return all(k.signatures or cached(k.py_func.__module__, k.py_func.__qualname__) for k in kernels)


def read_tf(reader: AnyReader, path: str | Path, topic: str, connections: Collection[Connection]) -> TfRows | None:
    """``rows.TfRows`` of a TF topic decoded from the bytes, batch by batch; None if its stored definition
    is not the standard TF layout (decode it with rosbags then).

    Rows come in record order (ties in file order) and frame codes are numbered by first appearance in that
    order, parent before child, as the rosbags path numbers them.

    Raises:
        InputError: Missing definition, unreadable data, or a message that does not match its definition.

    """
    conns = list(connections)
    require_definitions(reader, path, conns)
    if not conns or len({c.msgtype for c in conns}) != 1:
        return None
    layout = tf_layout(reader.typestore, conns[0].msgtype, reader.is2)
    if layout is None:
        return None
    parts = _Parts()
    for batch in grouped(iter_batches(reader, path, conns)):
        try:
            got = decode_batch(layout, batch.data, batch.start, batch.size)
        except DecodeError as err:
            raise InputError(path, f"cannot decode {layout.msgtype} message: {err}", topic) from None
        parts.add(got, batch.rec_ns)
    (t_ns, rec_ns, parent, child, values), moved = parts.joined()
    # frames numbered by first appearance in record order, parent before child, normalised as tf2 names them
    names = list(parts.names)
    appearance: list[int] = list(range(len(names)))
    if moved:
        seen = np.empty(2 * parent.shape[0], np.int32)
        seen[0::2], seen[1::2] = parent, child
        raw, first = np.unique(seen, return_index=True)
        appearance = raw[np.argsort(first)].tolist()
    frames = Frames()
    lut = np.zeros(max(len(names), 1), np.int32)
    for k in appearance:
        lut[k] = frames.code(names[k])
    return TfRows(topic, t_ns, rec_ns, lut[parent], lut[child], values, frames.names())
