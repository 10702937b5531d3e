"""The in-place Cholesky factor of a small symmetric positive definite block, for the numeric kernels.

One loop shared by riekf's innovation covariances (3×3 up to a frame's 3k×3k) and the time offset's 6×6 normal
equations: the same operations in the same order wherever it is called, so a caller's bits do not depend on which
copy it took.
"""

from __future__ import annotations

import math

from slamobs.pipeline.kernel_cache import njit


@njit(cache=True, nogil=True)
def cholesky_lower(s, m):
    """In-place lower Cholesky factor of the leading ``m``×``m`` block of ``s`` (its upper triangle left as it
    was); False if it is not positive definite (the block then holds a partial factor)."""
    for j in range(m):
        v = s[j, j]
        for k in range(j):
            v -= s[j, k] * s[j, k]
        if not v > 0.0:
            return False
        v = math.sqrt(v)
        s[j, j] = v
        for i in range(j + 1, m):
            w = s[i, j]
            for k in range(j):
                w -= s[i, k] * s[j, k]
            s[i, j] = w / v
    return True
