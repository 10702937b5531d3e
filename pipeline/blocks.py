"""Row blocks for whole-log array work done a block at a time.

An hour of 200 Hz samples is tens of MB per (N, 3) array; computing per-row results block by block keeps the
temporaries small. The arithmetic per row is the same, so the results are bit-identical to the whole-array
computation, provided no block is tiny: BLAS multiplies a matrix of one or two rows through another kernel.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: Rows per block.
ROW_BLOCK = 65_536
#: A last block shorter than this is merged into the one before it.
MIN_BLOCK = 64


def row_blocks(n: int, size: int = ROW_BLOCK) -> list[slice]:
    """Consecutive slices covering ``n`` rows, none shorter than ``MIN_BLOCK`` (unless ``n`` is)."""
    cuts = list(range(0, n, size))[1:]
    if cuts and n - cuts[-1] < MIN_BLOCK:
        cuts.pop()
    return [slice(a, b) for a, b in zip([0, *cuts], [*cuts, n])] if n else []


def blockwise(fn: Callable[..., np.ndarray], n: int, *arrays) -> np.ndarray:
    """``fn(*(a[rows] for a in arrays))`` over :func:`row_blocks` of ``n``, concatenated (``fn`` row-wise)."""
    blocks = row_blocks(n)
    if len(blocks) <= 1:
        return fn(*(a[0:n] for a in arrays))
    return np.concatenate([fn(*(a[rows] for a in arrays)) for rows in blocks])


def interp_sorted(x: np.ndarray, xp: np.ndarray, fp: np.ndarray, left=None, right=None) -> np.ndarray:
    """``np.interp(x, xp, fp, left, right)`` for non-decreasing ``x`` (a block of queries), computed on the part
    of ``xp``/``fp`` that brackets them, with two samples to spare on each side so that every query falls in
    the same interval as over the whole: identical results, but ``np.interp`` copies only that part of a
    strided ``fp`` (a column of an (N, 3) array) instead of all of it on every call."""
    if x.shape[0] == 0 or xp.shape[0] < 8:
        return np.interp(x, xp, fp, left, right)
    first = max(int(np.searchsorted(xp, x[0], side="right")) - 2, 0)
    stop = min(int(np.searchsorted(xp, x[-1], side="left")) + 2, xp.shape[0])
    return np.interp(x, xp[first:stop], fp[first:stop], left, right)


#: Widest value range (max - min + 1) :func:`unique_inverse` marks in a table (8 MB of flags) instead of sorting.
MAX_ID_TABLE = 1 << 23


def unique_inverse(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(values, return_inverse=True)`` of 1-D integers (the same arrays and dtypes): values within a
    range of ``MAX_ID_TABLE`` (landmark ids) are marked in a table instead of sorted (an hour's 577,000
    detections: ~2 against ~26 ms); others are sorted by ``np.unique``."""
    if values.ndim != 1 or values.size == 0 or values.dtype.kind != "i":
        return np.unique(values, return_inverse=True)
    lo, hi = int(values.min()), int(values.max())
    if hi - lo >= MAX_ID_TABLE:
        return np.unique(values, return_inverse=True)
    at = values - lo
    present = np.zeros(hi - lo + 1, dtype=bool)
    present[at] = True
    rank = np.cumsum(present, dtype=np.intp) - 1
    return (np.flatnonzero(present) + lo).astype(values.dtype), rank[at]


#: Longest run of equal ``a`` (detections in one frame) :func:`repeated_pairs` compares row by row.
MAX_FRAME_RUN = 64


def repeated_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether each row's pair ``(a[i], b[i])`` is in an earlier row (a repeated id within a detection frame: the
    readers drop it, the alignment too). Where ``a`` does not decrease (the detections' frame of each row) and no
    run of equal ``a`` is longer than ``MAX_FRAME_RUN``, each row is compared with the rows before it in its run
    (~3 against ~60 ms for an hour's detections); else by sorting the pairs. The same rows either way."""
    if a.shape[0] > 1 and bool(np.all(a[1:] >= a[:-1])):
        cuts = np.flatnonzero(a[1:] != a[:-1])
        longest = int(np.max(np.diff(cuts, prepend=-1, append=a.shape[0] - 1)))
        if longest <= MAX_FRAME_RUN:
            repeat = np.zeros(a.shape[0], dtype=bool)
            for k in range(1, longest):  # row i repeats row i - k of its run
                repeat[k:] |= (a[k:] == a[:-k]) & (b[k:] == b[:-k])
            return repeat
    order = np.lexsort((b, a))  # stable: equal pairs keep their order, the first one leads
    repeat = np.zeros(a.shape[0], dtype=bool)
    repeat[order[1:]] = (a[order[1:]] == a[order[:-1]]) & (b[order[1:]] == b[order[:-1]])
    return repeat


def first_of_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Indices of the first occurrence of each distinct pair ``(a[i], b[i])``, ascending (:func:`repeated_pairs`)."""
    return np.flatnonzero(~repeated_pairs(a, b))


#: Two detections of one id in one frame (one camera) farther apart than this share of their range, and
#: ``REPEATED_ID_APART_M``, are two tags that share the id (two tag families, or a reused id), not one tag seen twice.
REPEATED_ID_APART = 0.1
REPEATED_ID_APART_M = 0.25


def far_repeats(
    frame: np.ndarray, ids: np.ndarray, xyz: np.ndarray, camera: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """The ids and distances of the repeated ids within a frame (and camera) that lie apart from the detection
    before them of their frame and id (``REPEATED_ID_APART``): two tags that share the id, whose landmark's
    detections would mix two places, or another tag's id misread there; and the number of frames that hold any of
    those ids (how many of them hold it twice tells the two apart). The readers and the alignment drop the
    repeats; both say this."""
    order = np.lexsort((np.arange(ids.shape[0]), ids, frame))
    same = (frame[order][1:] == frame[order][:-1]) & (ids[order][1:] == ids[order][:-1])
    kept, dup = order[:-1][same], order[1:][same]
    if camera is not None:
        one = camera[kept] == camera[dup]
        kept, dup = kept[one], dup[one]
    apart = np.linalg.norm(xyz[dup] - xyz[kept], axis=1)
    far = apart > np.maximum(REPEATED_ID_APART * np.linalg.norm(xyz[kept], axis=1), REPEATED_ID_APART_M)
    seen = int(np.unique(frame[np.isin(ids, ids[dup[far]])]).size) if far.any() else 0
    return ids[dup[far]], apart[far], seen


def finite_rows(x: np.ndarray) -> np.ndarray:
    """``np.isfinite(x).all(axis=1)`` of (N, k) rows (the same booleans), a column at a time: NumPy's reduction along
    the short axis took ~3x as long (16 against 6 ms for the three columns of an hour's 720,000 IMU rows)."""
    if x.ndim != 2 or x.shape[1] == 0:
        return np.isfinite(x).all(axis=1)
    out = np.isfinite(x[:, 0])
    for c in range(1, x.shape[1]):
        out &= np.isfinite(x[:, c])
    return out


def equal_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.all(a == b, axis=1)`` of two (N, k) arrays (the same booleans), a column at a time, as
    :func:`finite_rows` (an hour's 720,000 gyro rows: ~4 against ~13 ms)."""
    if a.ndim != 2 or a.shape != b.shape or a.shape[1] == 0:
        return np.all(a == b, axis=1)
    out = a[:, 0] == b[:, 0]
    for c in range(1, a.shape[1]):
        out &= a[:, c] == b[:, c]
    return out


def row_norms3(x: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(x, axis=1)``, the same bits; (N, 3) float rows summed here: NumPy sums the three squares
    of a row left to right, as here, but its reduction along the short axis took ~4x as long (13 against 3.4 ms
    for an hour's 720,000 rows)."""
    if x.ndim != 2 or x.shape[1] != 3 or x.dtype != np.float64:
        return np.linalg.norm(x, axis=1)
    s = row_squares3(x)
    return np.sqrt(s, out=s)


def row_squares3(x: np.ndarray) -> np.ndarray:
    """``np.sum(x**2, axis=1)`` of (N, 3) float64 rows, the same bits (each row's three squares added left to right,
    as NumPy's reduction along the short axis adds them), a column at a time: ~4x faster than that reduction."""
    if x.ndim != 2 or x.shape[1] != 3 or x.dtype != np.float64:
        return np.sum(x**2, axis=1)
    s = x[:, 0] * x[:, 0]
    s += x[:, 1] * x[:, 1]
    s += x[:, 2] * x[:, 2]
    return s


def rms_sigmas(cov: np.ndarray) -> np.ndarray:
    """Each (3, 3) covariance's RMS standard deviation ``sqrt(trace Σ / 3)`` of (L, 3, 3) ``cov`` (landmarks.parquet
    ``sigma``, the report's map σ); a negative trace (no covariance) gives 0."""
    return np.sqrt(np.clip(np.einsum("lii->l", cov) / 3.0, 0.0, None))


def id_time_order(ids: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``np.lexsort((t, ids))``: the order by id, then time. With ``t`` already sorted (a run's detections) and ids
    that fit 16 bits, NumPy's stable radix sort of the ids gives the same order (5 against 28 ms on an hour's
    577,200 detections)."""
    if ids.size and np.all(t[1:] >= t[:-1]):
        lo, hi = ids.min(), ids.max()
        if 0 <= lo and hi < 1 << 16:
            return np.argsort(ids.astype(np.uint16), kind="stable")
        if -(1 << 15) <= lo and hi < 1 << 15:
            return np.argsort(ids.astype(np.int16), kind="stable")
    return np.lexsort((t, ids))
