"""KITTI-style drift: relative error over path segments of fixed length, in % of distance and deg/m.

Geiger et al., "Are we ready for autonomous driving? The KITTI vision benchmark suite" (CVPR 2012),
odometry devkit ``evaluate_odometry.cpp``: from every ``step``-th pose, for each segment length L, take the
first pose whose reference path distance exceeds the start's by more than L; the error pose of the segment is
``E = (P_i⁻¹ P_j)⁻¹ (Q_i⁻¹ Q_j)``; translation error ‖t_E‖ / L and rotation error angle(R_E) / L are averaged.
Unlike APE it does not depend on the (unobservable) global alignment, only on the estimate's scale.
"""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.evaluation.metrics import RotationRows, relative_angles
from slamobs.pipeline.evaluation.rpe import accumulated_distances

KITTI_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
SHORT_PATH_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5)


def _round2(x: float) -> float:
    """Two significant digits: segment lengths a reader can quote."""
    if x <= 0:
        return 0.0
    e = int(np.floor(np.log10(x))) - 1
    return float(round(x / 10.0**e) * 10.0**e)


def segment_lengths(path_length_m: float) -> tuple[float, ...]:
    """KITTI's 100..800 m when the reference path is long enough (> 1600 m), else 10..50 % of the path."""
    if path_length_m > 2 * KITTI_LENGTHS_M[-1]:
        return KITTI_LENGTHS_M
    return tuple(sorted({_round2(f * path_length_m) for f in SHORT_PATH_FRACTIONS} - {0.0}))


def segment_drift(
    ref_pos: np.ndarray,
    ref_rot: np.ndarray,
    est_pos: np.ndarray,
    est_rot: np.ndarray,
    lengths_m: tuple[float, ...] | None = None,
    step: int = 10,
) -> dict:
    """Mean segment errors per length and over all segments (JSON-ready); lengths with no segment are listed
    with ``n_segments = 0`` and null errors."""
    rp, ep = np.asarray(ref_pos, dtype=np.float64), np.asarray(est_pos, dtype=np.float64)
    rr, er = (r if isinstance(r, RotationRows) else np.asarray(r, dtype=np.float64) for r in (ref_rot, est_rot))
    dist = accumulated_distances(rp)
    lengths = tuple(float(x) for x in (lengths_m or segment_lengths(float(dist[-1]) if dist.size else 0.0)))
    starts = np.arange(0, rp.shape[0], max(int(step), 1))
    rows, all_t, all_r = [], [], []
    for length in lengths:
        last = np.searchsorted(dist, dist[starts] + length, side="right")  # first with d > d_i + L
        ok = last < rp.shape[0]
        i, j = starts[ok], last[ok]
        if i.size == 0:
            rows.append({"length_m": length, "n_segments": 0, "translation_pct": None, "rotation_deg_per_m": None})
            continue
        rr_i, er_i = rr[i], er[i]
        q_rot = np.einsum("nji,njk->nik", rr_i, rr[j])
        p_rot = np.einsum("nji,njk->nik", er_i, er[j])
        q_t = np.einsum("nji,nj->ni", rr_i, rp[j] - rp[i])
        p_t = np.einsum("nji,nj->ni", er_i, ep[j] - ep[i])
        # E = P⁻¹ Q: R_E = R_Pᵀ R_Q, t_E = R_Pᵀ (t_Q − t_P)
        t_err = np.linalg.norm(np.einsum("nji,nj->ni", p_rot, q_t - p_t), axis=1) / length
        r_err = np.degrees(relative_angles(p_rot, q_rot)) / length
        all_t.append(t_err)
        all_r.append(r_err)
        rows.append(
            {
                "length_m": length,
                "n_segments": int(i.size),
                "translation_pct": float(100 * t_err.mean()),
                "rotation_deg_per_m": float(r_err.mean()),
            }
        )
    t_all = np.concatenate(all_t) if all_t else np.empty(0)
    r_all = np.concatenate(all_r) if all_r else np.empty(0)
    return {
        "lengths_m": list(lengths),
        "step_poses": int(step),
        "per_length": rows,
        "n_segments": int(t_all.size),
        "translation_pct": float(100 * t_all.mean()) if t_all.size else None,
        "rotation_deg_per_m": float(r_all.mean()) if r_all.size else None,
        "path_length_m": float(dist[-1]) if dist.size else 0.0,
    }
