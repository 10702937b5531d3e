"""Pose pairs of the relative pose error (RPE), selected as evo 1.38.1 selects them (``filters.filter_pairs_by_*``).

A pair ``(i, j)`` spans a delta in frames, travelled metres or rotated angle. Consecutive pairs chain
(``j`` of one pair is ``i`` of the next); all pairs take every start ``i`` with its best-matching ``j``
(within ``rel_tol · delta`` for metres and angles). The errors of the pairs are :func:`metrics.rpe_errors`.
"""

from __future__ import annotations

import math

import numpy as np
from slamobs.pipeline.kernel_cache import KERNEL_ROWS, njit, worth_compiling

from slamobs.pipeline.evaluation.metrics import matrix_quats, relative_angles, row_norms

DELTA_UNITS = {"f": "frames", "m": "m", "d": "deg", "r": "rad"}
#: Consecutive pairs found by array code (one NumPy pass per pair) before the kernel takes the rest: a short path cut
#: into more pairs than this (a delta of a few steps) costs about what compiling the kernel does (~0.1 s).
ARRAY_PAIRS = 2048


def pairs_by_frames(n: int, delta: int, all_pairs: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(i, i + delta)``: every ``i`` with all pairs, else ``i = 0, delta, 2 delta, ...``."""
    if delta < 1:
        raise ValueError(f"delta in frames must be a positive integer, got {delta}")
    if all_pairs:
        i = np.arange(max(n - delta, 0), dtype=np.int64)
        return i, i + delta
    ids = np.arange(0, n, delta, dtype=np.int64)
    return ids[:-1], ids[1:]


@njit(cache=True, nrt=False)
def _consecutive_by_accumulation(steps, delta, ids):
    """Indices where the quantity accumulated since the last index reaches ``delta`` (then it restarts at 0),
    written into ``ids`` (``steps.shape[0] + 1`` long; made by the caller: a first run compiles no allocation);
    returns how many."""
    ids[0] = 0
    m = 1
    acc = 0.0
    for k in range(steps.shape[0]):
        acc += steps[k]
        if acc >= delta:
            ids[m] = k + 1
            m += 1
            acc = 0.0
    return m


def consecutive_by_accumulation(steps: np.ndarray, delta: float, kernel: bool | None = None) -> np.ndarray:
    """Indices where the quantity accumulated since the last index reaches ``delta`` (then it restarts at 0), from 0
    on: the kernel :func:`_consecutive_by_accumulation` where :func:`.kernel_cache.worth_compiling` says so (from
    :data:`.kernel_cache.KERNEL_ROWS` steps, a kernel compiled or cached, a second core), else the same indices by
    array code, so a one-core first run of a short log compiles nothing for its RPE pairs. ``kernel``: True or False
    takes that one (tests compare them)."""
    if kernel is None:
        kernel = worth_compiling(_consecutive_by_accumulation, steps.shape[0], KERNEL_ROWS)
    if kernel:
        ids = np.empty(steps.shape[0] + 1, dtype=np.int64)
        return ids[: _consecutive_by_accumulation(steps, delta, ids)]
    return _consecutive_by_cumsum(steps, delta)


def _consecutive_by_cumsum(steps: np.ndarray, delta: float) -> np.ndarray:
    """:func:`_consecutive_by_accumulation`'s indices by array code: from each index the running sum of the steps
    (``np.cumsum``, added in order from 0 as the kernel adds them: the same sums bit for bit) over a window that
    doubles until one reaches ``delta`` (a NaN sum never does, as in the kernel). After :data:`ARRAY_PAIRS` pairs
    the kernel takes the rest (from an index the accumulation restarts at 0: the same indices as one pass)."""
    n = steps.shape[0]
    ids = [0]
    start = 0
    window = 64
    while start < n:
        if len(ids) > ARRAY_PAIRS:
            rest = np.empty(n - start + 1, dtype=np.int64)
            rest = rest[: _consecutive_by_accumulation(steps[start:], delta, rest)]
            return np.concatenate([np.array(ids[:-1], dtype=np.int64), rest + start])
        reached = np.cumsum(steps[start : start + window]) >= delta
        if reached.any():
            k = int(reached.argmax())
            start += k + 1
            ids.append(start)
            window = max(64, 2 * (k + 1))
        elif start + window >= n:
            break
        else:
            window *= 2
    return np.array(ids, dtype=np.int64)


@njit(cache=True)
def _all_pairs_by_path(d, run_start, delta, tol):
    """For each i the j > i minimising |(d_j − d_i) − delta| (first on ties), kept when within ``tol``."""
    n = d.shape[0]
    out_i = np.empty(n, dtype=np.int64)
    out_j = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n - 1):
        lo, hi = i + 1, n
        while lo < hi:  # first k with (d_k − d_i) − delta >= 0; the expression is monotone in d_k
            mid = (lo + hi) // 2
            if (d[mid] - d[i]) - delta >= 0.0:
                hi = mid
            else:
                lo = mid + 1
        best = -1
        best_v = 0.0
        if lo - 1 >= i + 1:
            k = max(run_start[lo - 1], i + 1)  # first index of equal distances: argmin takes the first
            best, best_v = k, abs((d[k] - d[i]) - delta)
        if lo < n:
            v = abs((d[lo] - d[i]) - delta)
            if best < 0 or v < best_v:
                best, best_v = lo, v
        if best >= 0 and best_v <= tol:
            out_i[m] = i
            out_j[m] = best
            m += 1
    return out_i[:m], out_j[:m]


def accumulated_distances(pos: np.ndarray) -> np.ndarray:
    """Path length from the first position to each position (0 first)."""
    p = np.asarray(pos, dtype=np.float64)
    return np.concatenate([[0.0], np.cumsum(row_norms(p[1:], p[:-1]))])


def equal_runs(d: np.ndarray) -> np.ndarray:
    """For each index of the non-decreasing ``d``, the first index holding the same value."""
    if not d.shape[0]:
        return np.zeros(0, dtype=np.int64)
    new_run = np.concatenate([[True], d[1:] != d[:-1]])
    return np.maximum.accumulate(np.where(new_run, np.arange(d.shape[0]), 0))


def pairs_by_path(pos: np.ndarray, delta: float, tol: float = 0.0, all_pairs: bool = False):
    """Pairs whose travelled path is ``delta`` metres (consecutive: reaching ``delta`` closes a pair)."""
    p = np.asarray(pos, dtype=np.float64)
    if all_pairs:
        d = accumulated_distances(p)
        return _all_pairs_by_path(d, equal_runs(d), float(delta), float(tol))
    steps = row_norms(p[1:], p[:-1]) if p.shape[0] > 1 else np.empty(0)
    ids = consecutive_by_accumulation(steps, float(delta))
    return ids[:-1], ids[1:]


@njit(cache=True)
def _all_pairs_by_angle(q, lower, upper):
    """Pairs i < j whose relative rotation angle, from the unit quaternions ``q``, lies in [lower, upper]."""
    n = q.shape[0]
    cap = 1024
    out_i = np.empty(cap, dtype=np.int64)
    out_j = np.empty(cap, dtype=np.int64)
    m = 0
    for i in range(n - 1):
        a = q[i]
        for j in range(i + 1, n):
            b = q[j]
            # conj(a) * b, w-last
            w = a[3] * b[3] + a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
            x = a[3] * b[0] - a[0] * b[3] - a[1] * b[2] + a[2] * b[1]
            y = a[3] * b[1] + a[0] * b[2] - a[1] * b[3] - a[2] * b[0]
            z = a[3] * b[2] - a[0] * b[1] + a[1] * b[0] - a[2] * b[3]
            ang = 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))
            if lower <= ang <= upper:
                if m == cap:
                    cap *= 2
                    ni = np.empty(cap, dtype=np.int64)
                    nj = np.empty(cap, dtype=np.int64)
                    ni[:m] = out_i[:m]
                    nj[:m] = out_j[:m]
                    out_i, out_j = ni, nj
                out_i[m] = i
                out_j[m] = j
                m += 1
    return out_i[:m], out_j[:m]


def pairs_by_angle(rot: np.ndarray, delta: float, tol: float = 0.0, degrees: bool = False, all_pairs: bool = False):
    """Pairs rotated by ``delta``: consecutive pairs accumulate the step angles along the path, all pairs take
    every ``j > i`` whose direct angle to ``i`` is within ``delta ± tol`` (O(n²))."""
    bound = 180.0 if degrees else math.pi
    if not 0.0 <= delta <= bound:
        raise ValueError(f"delta angle must be within [0, {bound:g}], got {delta}")
    if degrees:
        delta, tol = math.radians(delta), math.radians(tol)
    r = np.ascontiguousarray(rot, dtype=np.float64)
    if all_pairs:  # each rotation normalised to its quaternion first, as evo does through SciPy
        return _all_pairs_by_angle(matrix_quats(r), delta - tol, delta + tol)
    steps = relative_angles(r[:-1], r[1:]) if r.shape[0] > 1 else np.empty(0)
    ids = consecutive_by_accumulation(steps, float(delta))
    return ids[:-1], ids[1:]


def rpe_pairs(
    pos: np.ndarray, rot: np.ndarray, delta: float, unit: str = "f", rel_tol: float = 0.1, all_pairs: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(i, j)`` for a delta in ``unit`` (``f`` frames, ``m`` metres, ``d`` degrees, ``r`` radians)."""
    if unit not in DELTA_UNITS:
        raise ValueError(f"delta unit must be one of {tuple(DELTA_UNITS)}, got {unit!r}")
    if delta < 0:
        raise ValueError("delta must be a positive number")
    n = np.asarray(pos).shape[0]
    if unit == "f":
        if not float(delta).is_integer():
            raise ValueError(f"delta must be an integer for frames, got {delta}")
        i, j = pairs_by_frames(n, int(delta), all_pairs)
    elif unit == "m":
        i, j = pairs_by_path(pos, delta, delta * rel_tol, all_pairs)
    else:
        i, j = pairs_by_angle(rot, delta, delta * rel_tol, unit == "d", all_pairs)
    if i.shape[0] == 0:
        raise ValueError(
            f"delta = {delta} ({DELTA_UNITS[unit]}) gives no pose pair among {n} poses; "
            "use a smaller delta or a looser tolerance"
        )
    return i.astype(np.int64), j.astype(np.int64)
