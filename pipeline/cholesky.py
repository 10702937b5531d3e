"""The in-place Cholesky factor of a small symmetric positive definite block, for the numeric kernels.

One loop shared by riekf's innovation covariances (3×3 up to a frame's 3k×3k) and the time offset's 6×6 normal
equations: the same operations in the same order wherever it is called, so a caller's bits do not depend on which
copy it took.
"""

from __future__ import annotations

import math

from numba import types

from slamobs.pipeline.kernel_cache import subroutine


@subroutine(types.boolean)
def cholesky_lower(s, m):
    """In-place lower Cholesky factor of the leading ``m``×``m`` block of ``s`` (its upper triangle left as it
    was); False if it is not positive definite (the block then holds a partial factor). Four rows of a column at a
    time below its diagonal: four independent running sums (each entry's subtractions in the same order as one at a
    time, the same bits) instead of one chain waiting on the last (riekf's 24×24 frames: ~2x faster alone). A
    subroutine (compiled into each kernel that calls it, without numba's runtime): as a kernel of its own each call
    took and dropped a reference to ``s``, about as long as a 3×3 factor."""
    for j in range(m):
        v = s[j, j]
        for k in range(j):
            v -= s[j, k] * s[j, k]
        if not v > 0.0:
            return False
        v = math.sqrt(v)
        s[j, j] = v
        i = j + 1
        while i + 4 <= m:
            w0, w1, w2, w3 = s[i, j], s[i + 1, j], s[i + 2, j], s[i + 3, j]
            for k in range(j):
                sjk = s[j, k]
                w0 -= s[i, k] * sjk
                w1 -= s[i + 1, k] * sjk
                w2 -= s[i + 2, k] * sjk
                w3 -= s[i + 3, k] * sjk
            s[i, j], s[i + 1, j], s[i + 2, j], s[i + 3, j] = w0 / v, w1 / v, w2 / v, w3 / v
            i += 4
        for i in range(i, m):
            w = s[i, j]
            for k in range(j):
                w -= s[i, k] * s[j, k]
            s[i, j] = w / v
    return True
