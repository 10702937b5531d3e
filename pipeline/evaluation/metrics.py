"""Error metrics with the definitions evo 1.38.1 uses, written from the mathematics.

A SLAM observer without absolute references recovers the pose only up to a constant rigid transform
(spec §1.6), so every comparison with ground truth goes: associate stamps -> rigid (Umeyama) alignment of
the estimate onto the truth -> absolute pose error (APE). The definitions are chosen so that numbers are
comparable with ``evo_ape`` (translation part / rotation angle in degrees, ``-a`` or no alignment).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.lie import mat3_mul, rotation_angle

NS_PER_S = 1_000_000_000


def _as_stamps(t_ns: np.ndarray, name: str) -> np.ndarray:
    t = np.asarray(t_ns)
    if t.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array of int64 nanosecond stamps, got shape {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"{name}: expected integer nanosecond stamps, got dtype {t.dtype}")
    return t.astype(np.int64, copy=False)


def _nearest(query: np.ndarray, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index into ``stamps`` of the nearest stamp to each query and the absolute difference (ns).

    Ties go to the earlier stamp; among equal stamps the last one at or before the query is taken.
    """
    order = np.argsort(stamps, kind="stable")
    s = stamps[order]
    hi = np.searchsorted(s, query, side="right")  # first stamp strictly after the query
    lo = hi - 1  # last stamp at or before the query
    has_lo = lo >= 0
    has_hi = hi < s.shape[0]
    lo_c = np.clip(lo, 0, s.shape[0] - 1)
    hi_c = np.clip(hi, 0, s.shape[0] - 1)
    d_lo = np.where(has_lo, query - s[lo_c], np.iinfo(np.int64).max)
    d_hi = np.where(has_hi, s[hi_c] - query, np.iinfo(np.int64).max)
    take_hi = d_hi < d_lo
    pos = np.where(take_hi, hi_c, lo_c)
    return order[pos], np.where(take_hi, d_hi, d_lo)


def associate(
    t_ref_ns: np.ndarray,
    t_est_ns: np.ndarray,
    t_max_diff_s: float = 0.01,
    t_offset_s: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-timestamp association of estimate and reference stamps (evo's ``nearest_time`` sync).

    ``t_offset_s`` is added to the estimate stamps. Like evo, the series with fewer stamps drives the
    association (the estimate when both have the same length) so that none of its samples is lost: each of
    its stamps is paired with the nearest stamp of the other series (ties to the earlier one) and the pair
    is kept when the two are at most ``t_max_diff_s`` apart. Returns ``(idx_ref, idx_est)``, int64 arrays of
    equal length, sorted by the driving series; the driving indices are unique, the other ones may repeat
    if the longer series has gaps. Arithmetic is exact on integer nanoseconds; evo works on float seconds,
    whose round-off can break an exact tie the other way (seen once in 2174 pairs of TUM fr2_desk).
    """
    ref = _as_stamps(t_ref_ns, "t_ref_ns")
    est = _as_stamps(t_est_ns, "t_est_ns")
    if t_max_diff_s < 0:
        raise ValueError(f"t_max_diff_s must be >= 0, got {t_max_diff_s}")
    empty = np.empty(0, dtype=np.int64)
    if ref.shape[0] == 0 or est.shape[0] == 0:
        return empty, empty.copy()
    max_diff = int(round(t_max_diff_s * NS_PER_S))
    est = est + int(round(t_offset_s * NS_PER_S))
    if ref.shape[0] < est.shape[0]:
        idx_est, diff = _nearest(ref, est)
        keep = diff <= max_diff
        return np.flatnonzero(keep).astype(np.int64), idx_est[keep].astype(np.int64)
    idx_ref, diff = _nearest(est, ref)
    keep = diff <= max_diff
    return idx_ref[keep].astype(np.int64), np.flatnonzero(keep).astype(np.int64)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity ``dst ≈ s R src + t`` (Umeyama 1991, "Least-squares estimation of
    transformation parameters between two point patterns"), with ``s = 1`` unless ``with_scale``.

    With the cross-covariance ``Σ = 1/n Σ (dst_i − μ_dst)(src_i − μ_src)ᵀ = U D Vᵀ``, the optimum is
    ``R = U S Vᵀ`` with ``S = diag(1, 1, −1)`` when ``det U det V < 0`` (otherwise the best orthogonal
    matrix would be a reflection), ``s = tr(D S) / σ²_src`` and ``t = μ_dst − s R μ_src``. The solution
    is unique iff ``rank Σ ≥ 2``, i.e. the points are not all collinear.
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape != y.shape:
        raise ValueError(f"umeyama: src and dst must both be (N, 3), got {x.shape} and {y.shape}")
    n = x.shape[0]
    if n < 3:
        raise ValueError(f"umeyama: need at least 3 point pairs for a unique rigid alignment, got {n}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("umeyama: input contains NaN or infinite coordinates")
    mu_x = x.mean(axis=0)
    mu_y = y.mean(axis=0)
    xc = x - mu_x
    yc = y - mu_y
    cov = yc.T @ xc / n
    u, d, vt = np.linalg.svd(cov)
    if d[0] <= 0.0 or d[1] <= 1e-12 * d[0]:
        raise ValueError(
            f"umeyama: degenerate input ({n} points are all collinear or coincident; cross-covariance "
            f"singular values {d.tolist()}), the rotation about the common line is undetermined"
        )
    s_diag = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        s_diag[2] = -1.0
    rot = (u * s_diag) @ vt
    scale = 1.0
    if with_scale:
        var_x = float(np.mean(np.sum(xc * xc, axis=1)))
        scale = float(np.sum(d * s_diag) / var_x)
    trans = mu_y - scale * rot @ mu_x
    return rot, trans, scale


def apply_alignment(rot: np.ndarray, trans: np.ndarray, scale: float, points: np.ndarray) -> np.ndarray:
    """``s R p + t`` for each row ``p`` of an ``(N, 3)`` array."""
    return scale * np.asarray(points, dtype=np.float64) @ rot.T + trans


def ape_translation(ref_pos: np.ndarray, est_pos: np.ndarray) -> np.ndarray:
    """Per-pair ``‖p_est − p_ref‖`` (evo APE, translation part), metres."""
    ref = np.asarray(ref_pos, dtype=np.float64)
    est = np.asarray(est_pos, dtype=np.float64)
    if ref.shape != est.shape or ref.ndim != 2 or ref.shape[1] != 3:
        raise ValueError(f"ape_translation: expected two (N, 3) arrays, got {ref.shape} and {est.shape}")
    return np.linalg.norm(est - ref, axis=1)


@njit(cache=True)
def _relative_angles(ref_r, est_r):
    out = np.empty(ref_r.shape[0])
    for k in range(ref_r.shape[0]):
        out[k] = rotation_angle(mat3_mul(np.ascontiguousarray(ref_r[k].T), est_r[k]))
    return out


def ape_rotation_deg(ref_R: np.ndarray, est_R: np.ndarray) -> np.ndarray:
    """Per-pair angle of ``R_refᵀ R_est`` in degrees, in [0, 180] (evo APE, rotation_angle_deg)."""
    ref = np.ascontiguousarray(ref_R, dtype=np.float64)
    est = np.ascontiguousarray(est_R, dtype=np.float64)
    if ref.shape != est.shape or ref.ndim != 3 or ref.shape[1:] != (3, 3):
        raise ValueError(f"ape_rotation_deg: expected two (N, 3, 3) arrays, got {ref.shape} and {est.shape}")
    if ref.shape[0] == 0:
        return np.empty(0)
    return np.degrees(_relative_angles(ref, est))


def statistics(errors: np.ndarray) -> dict[str, float | int]:
    """Summary of an error vector as evo reports it: rmse, mean, median, std (population, ddof=0),
    min, max, sse (sum of squares) and the count n. Plain Python numbers (JSON-ready)."""
    e = np.asarray(errors, dtype=np.float64).ravel()
    if e.size == 0:
        raise ValueError("statistics: empty error vector")
    sse = float(np.dot(e, e))
    return {
        "rmse": float(np.sqrt(sse / e.size)),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": sse,
        "n": int(e.size),
    }


@dataclass(frozen=True)
class LandmarkErrors:
    """Map error after alignment: distances for ids known to both sides, and the ids known to one only."""

    ids: np.ndarray  # (K,) int64, ids with an estimate and a truth, ascending
    errors: np.ndarray  # (K,) metres, ‖s R p̂_i + t − p_i‖
    est_aligned: np.ndarray  # (K, 3) aligned estimates of those ids
    truth: np.ndarray  # (K, 3)
    estimated_without_truth: list[int]
    truth_never_estimated: list[int]


def landmark_errors(
    est_ids: np.ndarray,
    est_xyz: np.ndarray,
    truth: dict[int, np.ndarray],
    rot: np.ndarray,
    trans: np.ndarray,
    scale: float = 1.0,
) -> LandmarkErrors:
    """Distance of each aligned landmark estimate to its true position.

    The estimated map lives in the observer's frame, like the trajectory, so it is moved by the same
    alignment that was fitted on the trajectory (the map is not re-fitted: that would hide map errors).
    """
    ids = np.asarray(est_ids, dtype=np.int64).ravel()
    xyz = np.asarray(est_xyz, dtype=np.float64).reshape(-1, 3)
    if ids.shape[0] != xyz.shape[0]:
        raise ValueError(f"landmark_errors: {ids.shape[0]} ids but {xyz.shape[0]} positions")
    truth_ids = {int(k) for k in truth}
    est_set = {int(i) for i in ids}
    common = np.array(sorted(est_set & truth_ids), dtype=np.int64)
    row_of = {int(i): k for k, i in enumerate(ids)}
    rows = np.array([row_of[int(i)] for i in common], dtype=np.int64)
    aligned = apply_alignment(rot, trans, scale, xyz[rows]) if rows.size else np.empty((0, 3))
    true_xyz = (
        np.array([np.asarray(truth[int(i)], dtype=np.float64).reshape(3) for i in common])
        if common.size
        else np.empty((0, 3))
    )
    return LandmarkErrors(
        ids=common,
        errors=np.linalg.norm(aligned - true_xyz, axis=1) if common.size else np.empty(0),
        est_aligned=aligned,
        truth=true_xyz,
        estimated_without_truth=sorted(est_set - truth_ids),
        truth_never_estimated=sorted(truth_ids - est_set),
    )
