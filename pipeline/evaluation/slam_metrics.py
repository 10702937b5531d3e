"""Errors evo has no notion of: the landmark map on its own, bias stability, convergence.

Pure functions over arrays; the report (:mod:`.report`) decides what to feed them and how to describe them.
"""

from __future__ import annotations

from collections.abc import Callable
from statistics import NormalDist

import numpy as np

from slamobs.pipeline.evaluation import metrics
from slamobs.pipeline.kernel_cache import njit
from slamobs.pipeline.lie import umeyama


def rms_extent(xyz: np.ndarray, centre: np.ndarray | None = None) -> float:
    """RMS distance of the points from their centre (m), or from ``centre``: a trajectory's size that its jitter
    does not lengthen, as a path length would (a scene's about a rig: its landmarks from the rig's position). (N, 3)
    float rows take each centred column's squares in turn, added left to right as NumPy's reduction along the short
    axis adds them (the same bits, without its slow short-axis reduction and the centred copy: 13 against ~5 ms on
    an hour's pairs; the report asks three times)."""
    x = np.asarray(xyz)
    centre = x.mean(axis=0) if centre is None else np.asarray(centre, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or x.dtype != np.float64:
        return float(np.sqrt(np.mean(np.sum((x - centre) ** 2, axis=1))))
    d = x[:, 0] - centre[0]
    sq = np.multiply(d, d)
    for c in (1, 2):
        np.subtract(x[:, c], centre[c], out=d)
        sq += np.multiply(d, d, out=d)
    return float(np.sqrt(np.mean(sq)))


def map_only_alignment(est_xyz: np.ndarray, truth_xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """SE(3) Umeyama fitted on the matched landmarks themselves, or None if they cannot fix a rotation
    (fewer than 3, or collinear). Compared with the trajectory-fitted alignment it separates the map's shape
    error from its placement relative to the trajectory."""
    if np.asarray(est_xyz).shape[0] < 3:
        return None
    try:
        rot, trans, _ = umeyama(est_xyz, truth_xyz)
    except ValueError:
        return None
    return rot, trans


#: The trajectory's alignment holds the turn about the truth trajectory's main axis only as far as a turn that raises
#: the APE's rmse by this share: a trajectory along a line fixes no turn about that line, and landmarks off the line
#: move with it (TagSLAM test_22: 0.11 m across a 1.8 m line, a 41 deg turn for 10 %, tags 0.6-2.4 m off it).
LOOSE_APE_SHARE = 0.1


def loose_turn(truth_xyz: np.ndarray, ape_rmse: float, share: float = LOOSE_APE_SHARE) -> dict:
    """How far the trajectory's alignment leaves the turn about the paired truth positions' main axis (their first
    principal direction, through their centre) free: ``turn_deg`` is θ with ``2(1 − cos θ)·across² =
    ((1 + share)² − 1)·rmse²`` (the rise in the APE's mean square when the aligned estimate is turned by θ about
    that axis, its residuals left uncorrelated with the turn; 180 when no turn reaches it), ``across_m`` the RMS
    distance of the truth positions from the axis."""
    x = np.asarray(truth_xyz, dtype=np.float64)
    centre = x.mean(axis=0)
    d = x - centre
    values, vectors = np.linalg.eigh(d.T @ d / max(x.shape[0], 1))  # the scatter's: 7 ms, not an SVD's 0.15 s/hour
    axis = vectors[:, -1] * np.sign(vectors[np.argmax(np.abs(vectors[:, -1])), -1])  # its largest part positive
    across2 = max(float(values[0] + values[1]), 0.0)
    rise = ((1.0 + share) ** 2 - 1.0) * float(ape_rmse) ** 2
    cos = 1.0 - rise / (2.0 * across2) if across2 > 0 else -1.0
    return {
        "axis": [float(v) for v in axis],
        "centre": [float(v) for v in centre],
        "across_m": float(np.sqrt(across2)),
        "turn_deg": float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
    }


def turn_about(axis, centre, angle_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of the turn by ``angle_rad`` about the line through ``centre`` along the unit ``axis``."""
    a, c = np.asarray(axis, dtype=np.float64), np.asarray(centre, dtype=np.float64)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    rot = np.eye(3) + np.sin(angle_rad) * k + (1.0 - np.cos(angle_rad)) * (k @ k)
    return rot, c - rot @ c


def best_turn(est_xyz: np.ndarray, truth_xyz: np.ndarray, axis, centre, limit_rad: float) -> float:
    """The turn about the line (``axis`` through ``centre``) within ±``limit_rad`` that brings ``est_xyz`` nearest
    ``truth_xyz`` in the sum of squares: ``atan2(Σ a·(p⊥ × q⊥), Σ p⊥·q⊥)`` of the points' parts across the axis,
    clipped to the limit (the sum of squares is ``const − A cos(φ − φ*)``: nearest at the clip)."""
    a, c = np.asarray(axis, dtype=np.float64), np.asarray(centre, dtype=np.float64)
    p, q = np.asarray(est_xyz, dtype=np.float64) - c, np.asarray(truth_xyz, dtype=np.float64) - c
    p, q = p - np.outer(p @ a, a), q - np.outer(q @ a, a)
    best = float(np.arctan2(float(np.sum(np.cross(p, q) @ a)), float(np.sum(p * q))))
    return float(np.clip(best, -limit_rad, limit_rad))


def landmark_nees(errors: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``eᵢᵀ Σᵢ⁻¹ eᵢ`` of (K, 3) errors against (K, 3, 3) covariances in the same frame; NaN where Σᵢ is not finite
    or not positive definite."""
    e, c = np.asarray(errors, dtype=np.float64), np.asarray(cov, dtype=np.float64)
    out = np.full(e.shape[0], np.nan)
    for k in range(e.shape[0]):
        if np.all(np.isfinite(c[k])) and np.all(np.linalg.eigvalsh(c[k]) > 0):
            out[k] = float(e[k] @ np.linalg.solve(c[k], e[k]))
    return out


def map_residuals(
    det_ids: np.ndarray, track_xyz: np.ndarray, innovation: np.ndarray, map_ids: np.ndarray, map_xyz: np.ndarray
) -> np.ndarray:
    """How far the final map lies from where the run's own poses put each detection: per detection
    ``‖p̂_i(final) − (R̂y_i + P̂)‖`` with ``R̂y_i + P̂ = p̂_i(t) − e_i`` (its landmark_tracks row minus its innovation:
    the detection made a point by the pose the estimator held at its time). Needs no truth: the check that map and
    trajectory agree. NaN for a detection whose id is not in the map."""
    det_ids = np.asarray(det_ids, dtype=np.int64)
    map_ids = np.asarray(map_ids, dtype=np.int64)
    placed = np.asarray(track_xyz, dtype=np.float64) - np.asarray(innovation, dtype=np.float64)
    order = np.argsort(map_ids, kind="stable")
    k = np.clip(np.searchsorted(map_ids[order], det_ids), 0, max(len(map_ids) - 1, 0))
    out = np.full(len(det_ids), np.nan)
    if len(map_ids):
        row = order[k]
        known = map_ids[row] == det_ids
        out[known] = np.linalg.norm(np.asarray(map_xyz, dtype=np.float64)[row[known]] - placed[known], axis=1)
    return out


def window_stats(t_ns: np.ndarray, values, fraction: float) -> dict:
    """Behaviour of a (N, 3) history (an array or its three columns) over its last ``fraction`` of time:
    per-axis mean, population std, range (max − min) and least-squares slope per second;
    ``drift_norm_per_s`` is the norm of the slope. Only the window's rows are copied."""
    t = np.asarray(t_ns, dtype=np.int64)
    if not 0 < fraction <= 1:
        raise ValueError(f"window fraction must be in (0, 1], got {fraction}")
    t0 = int(t[-1] - round(fraction * (t[-1] - t[0])))
    sel = t >= t0
    ts = (t[sel] - t0) / 1e9
    if isinstance(values, np.ndarray):
        w = np.asarray(values, dtype=np.float64)[sel]
    else:
        w = np.column_stack([np.asarray(c, dtype=np.float64)[sel] for c in values])
    if ts.size >= 2 and np.ptp(ts) > 0:
        tc = ts - ts.mean()
        slope = (tc @ (w - w.mean(axis=0))) / float(tc @ tc)
    else:
        slope = np.full(3, np.nan)
    return {
        "t_start_ns": t0,
        "duration_s": float((t[-1] - t0) / 1e9),
        "n_samples": int(sel.sum()),
        "mean": [float(x) for x in w.mean(axis=0)],
        "std": [float(x) for x in w.std(axis=0)],
        "range": [float(x) for x in np.ptp(w, axis=0)],
        "slope_per_s": [None if not np.isfinite(x) else float(x) for x in slope],
        "drift_norm_per_s": float(np.linalg.norm(slope)) if np.all(np.isfinite(slope)) else None,
    }


#: Convergence (see :func:`convergence`): the error level is the running median over WINDOW_FRACTION of the log,
#: the steady part the last TAIL_FRACTION, the band BAND_FACTOR times the highest steady level.
WINDOW_FRACTION = 0.05
TAIL_FRACTION = 0.2
BAND_FACTOR = 1.5
#: the error still grows when its median level over the last TAIL_FRACTION exceeds this times the stretch before
GROWTH_FACTOR = 1.5
#: ... and when that rise exceeds this many standard errors (:func:`growth_standard_error`): the one-sided 1 %
#: normal quantile. A hand-held or ground robot's level wanders with its path (0.04-0.3 m on seed=4630), and a
#: tail of 18 s holds one or two of its swings: riekf on 3 of 17 plain generated logs "never settled" without it
GROWTH_SES = NormalDist().inv_cdf(0.99)
#: a converged estimate is coarse when its steady level is above this share of the trajectory's extent (and above
#: the threshold): it follows the motion, but "converged" alone would not say how loosely
COARSE_SHARE = 0.1
#: The level is evaluated at this many evenly spaced times at most, each median over at most WINDOW_SAMPLES
#: evenly strided errors of its window (a long log's pairs are not all needed for a level).
LEVEL_POINTS = 2000
#: the pairs a frame of the run's end is fitted on at least (:func:`settled_in_tail_frame`): a rigid fit's minimum
TAIL_FRAME_MIN_PAIRS = 3
WINDOW_SAMPLES = 2001


def error_level(
    t_ns: np.ndarray, errors: np.ndarray, window_fraction: float = WINDOW_FRACTION, points: int = LEVEL_POINTS
) -> tuple[np.ndarray, np.ndarray]:
    """``(t, level)``: the median of ``errors`` over a centred window of ``window_fraction`` of the time span, at
    every stamp (at most ``points`` evenly spaced ones; over long windows the median of an even stride of it):
    the error's level with single outliers removed."""
    t = np.asarray(t_ns, dtype=np.int64)
    e = np.asarray(errors, dtype=np.float64)
    half = 0.5 * window_fraction * float(t[-1] - t[0])
    grid = t if t.shape[0] <= points else t[np.linspace(0, t.shape[0] - 1, points).round().astype(np.int64)]
    lo = np.searchsorted(t, grid - half, side="left")
    hi = np.searchsorted(t, grid + half, side="right")
    step = np.maximum(1, (hi - lo) // WINDOW_SAMPLES)
    return grid, _strided_medians(e, lo, step, (hi - lo + step - 1) // step)


def _strided_medians(e: np.ndarray, lo: np.ndarray, step: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``median(e[lo_k : lo_k + count_k * step_k : step_k])`` for every k; windows of one length share one
    ``np.median`` over the rows of a gathered matrix (the same numbers as one call per window, 2000 calls
    took 0.2 s on a long log); from ``metrics.KERNEL_ROWS`` errors on, a compiled loop without the gathered matrix."""
    if e.shape[0] >= metrics.KERNEL_ROWS:
        return _strided_medians_compiled(np.ascontiguousarray(e, dtype=np.float64), lo, step, count)
    out = np.empty(lo.shape[0])
    for n in np.unique(count):
        rows = np.flatnonzero(count == n)
        out[rows] = np.median(e[lo[rows, None] + step[rows, None] * np.arange(n)], axis=1)
    return out


@njit(cache=True)
def _strided_medians_compiled(e, lo, step, count):
    """:func:`_strided_medians` window by window. A median is an order statistic, or the two middle ones'
    ``(a + b) / 2`` as NumPy's mean of the two: the same numbers whatever selects them."""
    out = np.empty(lo.shape[0])
    buf = np.empty(max(count.max(), 1) if count.shape[0] else 1)
    for k in range(lo.shape[0]):
        n = count[k]
        for m in range(n):
            buf[m] = e[lo[k] + step[k] * m]
        out[k] = np.median(buf[:n])
    return out


def convergence(
    t_ns: np.ndarray,
    errors: np.ndarray,
    threshold: float,
    level: tuple[np.ndarray, np.ndarray] | None = None,
    extent: float | None = None,
    refit: Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict:
    """When the error reaches the observer's own steady level and stays there.

    The level is the running median (:func:`error_level`); the steady level is its highest value over the last
    ``TAIL_FRACTION`` of the time span, and the band ``max(threshold, BAND_FACTOR × steady level)``: a fixed
    threshold alone would report the last time noise crossed it, and an observer whose error varies along the
    path would never have "converged". Returns the band, the steady median error and level, the window in
    seconds and ``t_ns``, the first level time after which the level stays within the band (None if the last
    level is above it, or if the error still grows: its median level over the last ``TAIL_FRACTION`` above
    ``GROWTH_FACTOR`` times that over the ``TAIL_FRACTION`` before or times that over everything before the tail,
    and above ``threshold``, and by more than ``GROWTH_SES`` standard errors of that rise
    (:func:`growth_standard_error`, ``growth_se``: the level's own wander with the path is no growth); a drifting
    estimate would otherwise be "converged" at its start, inside a band as wide as its final error; the second
    comparison catches a drift that began earlier than the stretch before the tail, e.g. dead reckoning after the
    landmarks left view), or if that steady level is
    above ``extent`` (the truth's RMS distance from its centre) and ``threshold``: an estimate that far off never
    locked on to the motion, whatever its level does, or if the level was within the band before for at least as
    long as from that time on and left it again (``recurring``, :func:`longest_earlier_stretch`; ``coarse``:
    above ``COARSE_SHARE`` of ``extent``, converged
    or not, but loosely). ``level`` is :func:`error_level` of these errors when
    already computed. ``refit(mask)``: the errors of all pairs under the report's alignment kind fitted on the pairs
    of ``mask`` only; with it, a growth is checked in the tail's own frame (:func:`settled_in_tail_frame`) and
    dropped when the error settled there: ``tail_frame`` then holds that settling, and ``t_ns`` is its time.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    e = np.asarray(errors, dtype=np.float64)
    grid, level = error_level(t, e) if level is None else level
    cut, steady_level, band, window_ns, k = _within_band(t, grid, level, threshold)
    before = level[(grid >= cut - (t[-1] - cut)) & (grid < cut)]
    earlier = float(np.median(before)) if before.size else None
    before_tail = float(np.median(level[grid < cut])) if np.any(grid < cut) else None
    tail_level = float(np.median(level[grid >= cut]))
    lowest = min((x for x in (earlier, before_tail) if x is not None), default=None)
    share = TAIL_FRACTION if earlier is not None and lowest == earlier else 1.0 - TAIL_FRACTION
    growth_se = growth_standard_error(grid, level, cut, share) if lowest is not None else None
    risen = lowest is not None and tail_level > max(GROWTH_FACTOR * lowest, threshold)
    recurring = longest_earlier_stretch(grid, level, band, k, window_ns)
    refit_tail = risen and refit is not None and np.count_nonzero(t >= cut) >= TAIL_FRAME_MIN_PAIRS
    tail_frame = settled_in_tail_frame(t, refit(t >= cut), threshold) if refit_tail else None
    growing = risen and tail_frame is None and tail_level - lowest > GROWTH_SES * growth_se
    if tail_frame is not None:
        recurring, k = None, int(np.searchsorted(grid, tail_frame["t_ns"]))
    settled = steady_level if tail_frame is None else tail_frame["steady_level"]
    lost = extent is not None and settled > max(extent, threshold)
    coarse = extent is not None and not lost and settled > max(COARSE_SHARE * extent, threshold)
    return {
        "band": band,
        "earlier_level": earlier,
        "before_tail_level": before_tail,
        "tail_level": tail_level,
        "growing": bool(growing),
        "growth_se": growth_se,
        "lost": bool(lost),
        "coarse": bool(coarse),
        "steady_error": metrics.median(e[t >= cut]),
        "steady_level": steady_level,
        "settled_level": settled,
        "window_s": WINDOW_FRACTION * float(t[-1] - t[0]) / 1e9,
        "recurring": recurring,
        "tail_frame": tail_frame,
        "t_ns": None if k is None or growing or lost or recurring is not None else int(grid[k]),
    }


def growth_standard_error(grid: np.ndarray, level: np.ndarray, cut: int, share: float) -> float:
    """The standard error of the tail's median level less that of the stretch it is compared with (``share`` of
    the span long, the tail ``TAIL_FRACTION``), were the level before the tail one process that neither grows nor
    falls: the medians of the level over every stretch as long as the tail before ``cut`` (as many grid points),
    their scatter ``s`` about a straight line fitted to them (a trend there is not scatter) is that of one
    tail-long median, however the level is correlated (its swings with the path last as long as the tail: an
    autocorrelation time summed over them cancels where the tail holds one crest); the compared stretch's median
    scatters ``√(tail / share)`` times as much: ``s √(1 + TAIL_FRACTION / share)``."""
    before, n = level[grid < cut], int(np.count_nonzero(grid >= cut))
    if before.shape[0] < n + 2:
        return 0.0
    medians = np.median(np.lib.stride_tricks.sliding_window_view(before, n), axis=1)
    x = np.arange(medians.shape[0], dtype=np.float64)
    scatter = medians - np.polyval(np.polyfit(x, medians, 1), x)
    return float(np.sqrt(np.mean(scatter**2)) * np.sqrt(1.0 + TAIL_FRACTION / share))


def _within_band(t: np.ndarray, grid: np.ndarray, level: np.ndarray, threshold: float) -> tuple:
    """``(cut, steady_level, band, window_ns, k)`` of :func:`convergence`: the tail's start, its highest level, the
    band, a window and the first level index from which the level stays within the band (None if none)."""
    cut = t[-1] - round(TAIL_FRACTION * (t[-1] - t[0]))
    steady_level = float(np.max(level[grid >= cut]))
    band = max(float(threshold), BAND_FACTOR * steady_level)
    window_ns = WINDOW_FRACTION * float(t[-1] - t[0])
    k = settled_index(grid, level, band, convergence_index(level, np.nextafter(band, np.inf)), window_ns)
    return cut, steady_level, band, window_ns, k


def settled_in_tail_frame(t_ns: np.ndarray, errors: np.ndarray, threshold: float) -> dict | None:
    """Where an error that grows under the whole-run alignment settled in the frame of its own end. ``errors``:
    the position errors under the report's alignment kind fitted on the last ``TAIL_FRACTION`` of the pairs only.
    Their level (:func:`error_level`), steady level and band are :func:`convergence`'s; the estimate settled when
    the level is within that band from at least ``2 × TAIL_FRACTION`` before the end (a stretch before the fitted
    one as long as it, so the frame holds beyond the pairs that chose it) to the end, without an earlier as long
    stay in the band that it left (:func:`longest_earlier_stretch`). Returns ``t_ns`` (from when), ``steady_level``
    and ``band``, or None.

    Why: one rigid fit over the whole run is pulled toward a long bad stretch. A filter whose first lap is 3 m off
    until its loop closes and whose second lap is right to 0.4 m (relative to its first pose, both laps) had a
    whole-run SE(3) fit that turned the second lap off: a level of 1.93 m over the last 20 % against 0.40 m before,
    "growing". In the frame of its last 20 % the level is 0.05-0.11 m from 90 s of 180 s on. An estimate that
    drifts does not settle in that frame: its error there falls toward the fitted stretch (the drift run
    backwards), a level within the band for little more than the fitted stretch itself."""
    t = np.asarray(t_ns, dtype=np.int64)
    grid, level = error_level(t, errors)
    cut, steady_level, band, window_ns, k = _within_band(t, grid, level, threshold)
    if k is None or grid[k] > cut - (t[-1] - cut) or longest_earlier_stretch(grid, level, band, k, window_ns):
        return None
    return {"t_ns": int(grid[k]), "steady_level": steady_level, "band": band}


def settled_index(
    grid: np.ndarray, level: np.ndarray, band: float, k: int | None, min_excursion_ns: float
) -> int | None:
    """``k`` (the first level index after which ``level`` stays within ``band``) moved back over every earlier
    stretch within the band that the level left for less than ``min_excursion_ns`` (a window of the level) before
    coming back: such a touch outside is no departure, as a touch of the band is no return
    (:func:`longest_earlier_stretch`). TagSLAM test_22, fast-adaptation: within the band from the start but for
    0.2 s at 27.1 s, reported "converged at 27.31 s" with a window of 1.74 s."""
    inside = level <= band
    while k:
        within = np.flatnonzero(inside[:k])
        if not within.size or grid[k] - grid[within[-1]] >= min_excursion_ns:
            return k
        left = np.flatnonzero(~inside[: within[-1]])
        k = int(left[-1]) + 1 if left.size else 0
    return k


def longest_earlier_stretch(
    grid: np.ndarray, level: np.ndarray, band: float, k: int | None, min_excursion_ns: float
) -> tuple[int, int] | None:
    """``(start_ns, end_ns)`` of the longest stretch before ``grid[k]`` over which ``level`` was already within
    ``band`` and then left it for at least ``min_excursion_ns`` (a window of the level: a touch of the band is no
    return), when that stretch lasted at least as long as the final one (``grid[k]`` to the end); else None. A
    level that was as long within the band before and left it again recurs (an error that returns once a lap):
    the final stretch may be one more such, and its start is no convergence time. Stretches of noise crossing the
    band are short against a settled final stretch."""
    if k is None or k == 0:
        return None
    inside = level[:k] <= band
    edges = np.flatnonzero(np.diff(np.concatenate(([0], inside.astype(np.int8), [0]))))
    starts, ends = edges[0::2], edges[1::2] - 1  # stretches [start, end] within the band, each left at end + 1
    left_for = grid[np.append(starts[1:], k)] - grid[ends]  # how long the level stayed out after each
    keep = left_for >= min_excursion_ns
    starts, ends = starts[keep], ends[keep]
    if not starts.size:
        return None
    i = int(np.argmax(grid[ends] - grid[starts]))
    if grid[ends[i]] - grid[starts[i]] < grid[-1] - grid[k]:
        return None
    return int(grid[starts[i]]), int(grid[ends[i]])


def convergence_index(errors: np.ndarray, threshold: float) -> int | None:
    """First index from which ``errors`` stay below ``threshold`` to the end (None if the last is not)."""
    above = np.flatnonzero(np.asarray(errors) >= threshold)
    if above.size == 0:
        return 0
    if above[-1] == len(errors) - 1:
        return None
    return int(above[-1]) + 1
