"""Float outputs rounded to fewer mantissa bits (:func:`slamobs.pipeline.writers.round_mantissa`) or to a fixed
step (:func:`slamobs.pipeline.writers.round_step`) in one compiled pass over a long column: the same operations
as the array code, so the same bits, without its masks, gathers and temporaries (half of a long run's write
time). Imported by the writers only for
long columns, so that what writes a few rows (stats, compare, export) does not import numba.
"""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.kernel_cache import njit

_EXPONENT = np.uint64(0x7FF0_0000_0000_0000)
_SHIFT = np.uint64(52)
_ONE = np.uint64(1)


@njit(cache=True)
def round_bits(a, bits, finest, use_finest):  # pragma: no cover - compiled
    """``a`` (float64, 1-D, contiguous) rounded in place on ``bits`` mantissa bits, ties away from zero, finite
    values only; a value that would round into Inf is truncated. With ``use_finest`` a value whose step would
    be coarser than ``2**finest`` keeps more bits, unless no value needs them (then all take ``bits``)."""
    u = a.view(np.uint64)
    n = u.shape[0]
    if use_finest:
        top = -1
        for k in range(n):
            ex = np.int64((u[k] & _EXPONENT) >> _SHIFT)
            if ex != 2047 and ex > top:
                top = ex
        if top >= 0 and top - 1023 - finest <= bits:
            use_finest = False
    drop = np.uint64(52 - bits)
    for k in range(n):
        b = u[k]
        ex = np.int64((b & _EXPONENT) >> _SHIFT)
        if ex == 2047:  # NaN, ±Inf
            continue
        if use_finest:
            drop = np.uint64(52 - min(max(ex - 1023 - finest, bits), 52))
        half = (_ONE << (drop - _ONE)) if drop > 0 else np.uint64(0)
        keep = ~((_ONE << drop) - _ONE)
        r = (b + half) & keep
        if r & _EXPONENT == _EXPONENT:
            r = b & keep
        u[k] = r


@njit(cache=True)
def round_step_into(a, exp):  # pragma: no cover - compiled
    """``a`` (float64, 1-D, contiguous) rounded in place to the nearest multiple of ``2**exp`` (ties to even), as
    :func:`slamobs.pipeline.writers.round_step` does with arrays: the same bits. NaN, ±Inf and the values already
    a multiple (``|x| >= 2**(52 + exp)``) are kept; -0.0 becomes 0.0."""
    step = 2.0**exp
    inv = 2.0**-exp
    whole = 2.0 ** (52 + exp)
    for k in range(a.shape[0]):
        v = a[k]
        if abs(v) < whole:
            a[k] = np.rint(v * inv) * step + 0.0
