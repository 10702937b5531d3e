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
