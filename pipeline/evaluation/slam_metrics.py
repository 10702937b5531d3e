"""Errors evo has no notion of: the landmark map on its own, bias stability, convergence.

Pure functions over arrays; the report (:mod:`.report`) decides what to feed them and how to describe them.
"""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.evaluation.align import umeyama


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


#: Convergence band: ``max(threshold, BAND_FACTOR × median error over the last TAIL_FRACTION of the log)``.
TAIL_FRACTION = 0.2
BAND_FACTOR = 1.5


def convergence_band(t_ns: np.ndarray, errors: np.ndarray, threshold: float) -> tuple[float, float]:
    """``(band, steady)``: the observer's steady error (median over the last ``TAIL_FRACTION`` of the time span)
    and the band the error must stay in, ``max(threshold, BAND_FACTOR × steady)``: convergence then measures
    when the observer reaches its own steady level, not when a fixed threshold happens to be crossed."""
    t = np.asarray(t_ns, dtype=np.int64)
    e = np.asarray(errors, dtype=np.float64)
    tail = t >= t[-1] - round(TAIL_FRACTION * (t[-1] - t[0]))
    steady = float(np.median(e[tail]))
    return max(float(threshold), BAND_FACTOR * steady), steady


def convergence_index(errors: np.ndarray, threshold: float) -> int | None:
    """First index from which ``errors`` stay below ``threshold`` to the end (None if the last is not)."""
    above = np.flatnonzero(np.asarray(errors) >= threshold)
    if above.size == 0:
        return 0
    if above[-1] == len(errors) - 1:
        return None
    return int(above[-1]) + 1
