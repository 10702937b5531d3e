"""KITTI-style drift: relative error over path segments of fixed length, in % of distance and deg/m.

Geiger et al., "Are we ready for autonomous driving? The KITTI vision benchmark suite" (CVPR 2012),
odometry devkit ``evaluate_odometry.cpp``: from every ``step``-th pose, for each segment length L, take the
first pose whose reference path distance exceeds the start's by more than L; the error pose of the segment is
``E = (P_i⁻¹ P_j)⁻¹ (Q_i⁻¹ Q_j)``; translation error ‖t_E‖ / L and rotation error angle(R_E) / L are averaged.
Unlike APE it does not depend on the (unobservable) global alignment, only on the estimate's scale.

:func:`segment_errors` is the same relative error with rpg_trajectory_evaluation's rules (Zhang and
Scaramuzza, "A Tutorial on Quantitative Trajectory Evaluation for Visual(-Inertial) Odometry", IROS 2018;
``compute_trajectory_errors.compute_relative_error``): sub-trajectory lengths are 10–50 % of the truth path
(truncated to centimetres), every pair starts a segment that ends at the pair whose truth path distance is
nearest to the start's + L (within 0.2 L), the error is ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` with the estimate's
relative translation times the alignment's scale, and each length keeps the distribution of its errors (the
box plots) rather than their mean only: translation in m and % of L, rotation in deg and deg/m, and the yaw
and gravity (roll-pitch) parts of the error rotated into the world by the estimate's attitude at the end.
"""

from __future__ import annotations

import math

import numpy as np
from slamobs.pipeline.evaluation import metrics
from slamobs.pipeline.evaluation.metrics import RotationRows, relative_angles, statistics
from slamobs.pipeline.evaluation.rpe import accumulated_distances, equal_runs
from slamobs.pipeline.kernel_cache import njit
from slamobs.pipeline.simd import fma

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
        t_err = metrics.row_norms(np.einsum("nji,nj->ni", p_rot, q_t - p_t)) / length
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


#: rpg_trajectory_evaluation's ``max_dist_diff``: a segment ends at most this fraction of L off the length
RPG_MAX_DIFF_FRACTION = 0.2
#: the errors :func:`segment_errors` gives per length, with their units
SEGMENT_ERROR_KINDS = (
    "translation_m",
    "translation_pct",
    "rotation_deg",
    "rotation_deg_per_m",
    "yaw_deg",
    "gravity_deg",
)


def rpg_lengths(path_length_m: float, fractions: tuple[float, ...] = SHORT_PATH_FRACTIONS) -> tuple[float, ...]:
    """rpg's sub-trajectory lengths: each fraction of the truth path, truncated to two decimals."""
    return tuple(math.trunc(f * path_length_m * 100.0) / 100.0 for f in fractions)


def rpg_segment_ends(
    dist: np.ndarray, length: float, max_diff: float, runs: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Start and end index of every segment: from each pose, the later pose whose path distance is nearest to
    the start's + ``length`` (the first of equals, the shorter on a tie, as rpg's scan), kept within
    ``max_diff``. Long paths (``metrics.KERNEL_ROWS`` poses) take a compiled sweep, the same indices, over
    ``runs`` (``equal_runs(dist)``: give it for several lengths, it is the same for all)."""
    d = np.ascontiguousarray(dist, dtype=np.float64)
    if d.shape[0] >= metrics.KERNEL_ROWS:
        return _segment_ends(d, equal_runs(d) if runs is None else runs, float(length), float(max_diff))
    n = d.shape[0]
    start = np.arange(n)
    target = d + length
    k = np.searchsorted(d, target, side="left")  # first with d >= target
    lo = np.maximum(np.searchsorted(d, d[np.maximum(k - 1, 0)], side="left"), start)
    hi = np.minimum(k, n - 1)
    e_lo = np.abs(d[lo] - target)
    e_hi = np.where(k < n, np.abs(d[hi] - target), np.inf)
    ok = np.minimum(e_lo, e_hi) < max_diff
    return start[ok], np.where(e_hi < e_lo, hi, lo)[ok]


@njit(cache=True)
def _segment_ends(dist, run_start, length, max_diff):
    """:func:`rpg_segment_ends` in one sweep: the targets ``dist + length`` never decrease, so the first pose at
    or past each target (``searchsorted``'s left side) only moves on. Same comparisons, same indices."""
    n = dist.shape[0]
    out_i = np.empty(n, dtype=np.int64)
    out_j = np.empty(n, dtype=np.int64)
    m = 0
    k = 0
    for s in range(n):
        target = dist[s] + length
        while k < n and dist[k] < target:  # first k with dist[k] >= target
            k += 1
        lo = max(run_start[max(k - 1, 0)], s)  # the first of the poses at dist[k - 1], not before the start
        e_lo = abs(dist[lo] - target)
        e_hi = abs(dist[min(k, n - 1)] - target) if k < n else np.inf
        if min(e_lo, e_hi) < max_diff:
            out_i[m] = s
            out_j[m] = min(k, n - 1) if e_hi < e_lo else lo
            m += 1
    return out_i[:m], out_j[:m]


@njit(cache=True, nogil=True)
def _segment_errors(turn, est_pos, ref_pos, i, j, scale):  # pragma: no cover - compiled
    """Per segment ``r_w = D_jᵀ D_i`` and ``‖s D_i (p̂_j − p̂_i) − (p_j − p_i)‖`` without gathering ``D_i`` and
    ``D_j`` into stacks first, and :func:`_error_kinds`' angles of ``r_w`` (rotation angle, |yaw|, roll-pitch
    magnitude, in degrees) in the same pass, no ``(m, 3, 3)`` stack. The sums round as NumPy's stacked ``matmul``
    does through OpenBLAS on an FMA CPU (its 3×3 products as :func:`.simd.fma` says, its matrix-vector ones
    ``fma(a₂, x₂, fma(a₀, x₀, a₁x₁))``): the translation errors' bits of :func:`relative_errors_numpy` there; the
    angles through the C library's ``acos``, ``atan2`` and ``hypot``, within a few ulps of NumPy's
    (``tests/test_segment_errors.py``)."""
    m = i.shape[0]
    trans, rot, yaw, gravity = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    r_w = np.empty((3, 3))
    to_deg = 180.0 / np.pi
    for s in range(m):
        a, b = turn[j[s]], turn[i[s]]
        for r in range(3):
            for c in range(3):
                r_w[r, c] = fma(a[2, r], b[2, c], fma(a[1, r], b[1, c], a[0, r] * b[0, c]))
        d0 = est_pos[j[s], 0] - est_pos[i[s], 0]
        d1 = est_pos[j[s], 1] - est_pos[i[s], 1]
        d2 = est_pos[j[s], 2] - est_pos[i[s], 2]
        sq = 0.0
        for r in range(3):
            moved = fma(b[r, 2], d2, fma(b[r, 0], d0, b[r, 1] * d1))
            e = scale * moved - (ref_pos[j[s], r] - ref_pos[i[s], r])
            sq += e * e
        trans[s] = np.sqrt(sq)
        cos = ((r_w[0, 0] + r_w[1, 1] + r_w[2, 2]) - 1.0) / 2.0
        rot[s] = np.arccos(min(max(cos, -1.0), 1.0)) * to_deg
        yaw[s] = abs(np.arctan2(r_w[1, 0], r_w[0, 0])) * to_deg
        pitch = np.arctan2(-r_w[2, 0], np.hypot(r_w[0, 0], r_w[1, 0]))
        gravity[s] = np.hypot(pitch, np.arctan2(r_w[2, 1], r_w[2, 2])) * to_deg
    return trans, rot, yaw, gravity


def yaw_gravity(rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|yaw| and the roll-pitch magnitude (radians) of ``R = R_z(yaw) R_y(pitch) R_x(roll)`` (euler 'rzyx')."""
    yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
    pitch = np.arctan2(-rot[:, 2, 0], np.hypot(rot[:, 0, 0], rot[:, 1, 0]))
    roll = np.arctan2(rot[:, 2, 1], rot[:, 2, 2])
    return np.abs(yaw), np.hypot(pitch, roll)


def relative_errors(ref_pos, est_pos, turn: np.ndarray, i, j, length: float, scale: float = 1.0) -> dict:
    """rpg's relative error of each segment ``i → j`` (arrays named as :data:`SEGMENT_ERROR_KINDS`), from the
    per-pose ``turn = R_ref R_estᵀ`` (:func:`turns`).

    rpg forms ``E = T_m⁻¹ T_c`` (``T_m = Q_i⁻¹ Q_j``, ``T_c = P_i⁻¹ P_j`` with its translation times ``scale``) and
    rotates it into the world by ``R_c`` at ``j``; that rotation is ``D_jᵀ D_i`` with ``D = R_ref R_estᵀ``, the
    norm of its translation ``‖s D_i (p̂_j − p̂_i) − (p_j − p_i)‖``: one product per segment instead of eight,
    in a compiled loop (:func:`_segment_errors`) from ``metrics.KERNEL_ROWS`` segments on.
    """
    if len(i) < metrics.KERNEL_ROWS:
        return relative_errors_numpy(ref_pos, est_pos, turn, i, j, length, scale)
    trans, rot, yaw, gravity = _segment_errors(
        np.ascontiguousarray(turn, dtype=np.float64),
        np.ascontiguousarray(est_pos, dtype=np.float64),
        np.ascontiguousarray(ref_pos, dtype=np.float64),
        np.ascontiguousarray(i, dtype=np.int64),
        np.ascontiguousarray(j, dtype=np.int64),
        float(scale),
    )
    return dict(zip(SEGMENT_ERROR_KINDS, (trans, percent(trans, length), rot, per_metre(rot, length), yaw, gravity)))


def percent(trans: np.ndarray, length: float) -> np.ndarray:
    """The translation error in % of the segment length."""
    return 100.0 * trans / length


def per_metre(rot: np.ndarray, length: float) -> np.ndarray:
    """The rotation error per metre of the segment length."""
    return rot / length


#: the kinds that are another kind scaled by a positive constant: their order statistics come from its ranks
SCALED_KINDS = {"translation_pct": ("translation_m", percent), "rotation_deg_per_m": ("rotation_deg", per_metre)}


def kind_statistics(errs: dict[str, np.ndarray], length: float) -> dict[str, dict]:
    """``metrics.statistics`` of each error array of a length; the % and per-metre kinds take their order
    statistics from the metre and degree kinds' ranks (:func:`metrics.monotone_part`: the same bits, two
    partitions of six saved)."""
    parts, out = {}, {}
    for kind, v in errs.items():
        if kind in SCALED_KINDS and SCALED_KINDS[kind][0] in parts:
            base, f = SCALED_KINDS[kind]
            parts[kind] = metrics.monotone_part(parts[base], lambda x, f=f: f(x, length))
        elif v.shape[0] >= metrics.RANKED_ROWS:
            parts[kind] = metrics.ranked(v, metrics.statistic_ranks(v.shape[0]))
        out[kind] = statistics(v, parts.get(kind))
    return out


def relative_errors_numpy(ref_pos, est_pos, turn: np.ndarray, i, j, length: float, scale: float = 1.0) -> dict:
    """:func:`relative_errors` with NumPy's stacked products (the formulation it replaced; the tests' and
    ``benchmarks/segment_errors.py``'s reference)."""
    r_w = np.matmul(turn[j].transpose(0, 2, 1), turn[i])
    moved = np.matmul(turn[i], (est_pos[j] - est_pos[i])[:, :, None])[:, :, 0]
    return _error_kinds(r_w, np.linalg.norm(scale * moved - (ref_pos[j] - ref_pos[i]), axis=1), length)


def _error_kinds(r_w: np.ndarray, trans: np.ndarray, length: float) -> dict:
    """The error arrays of :data:`SEGMENT_ERROR_KINDS` from each segment's world-frame error rotation and
    translation error."""
    rot = np.degrees(np.arccos(np.clip((np.trace(r_w, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
    yaw, gravity = yaw_gravity(r_w)
    return dict(
        zip(
            SEGMENT_ERROR_KINDS,
            (trans, percent(trans, length), rot, per_metre(rot, length), np.degrees(yaw), np.degrees(gravity)),
        )
    )


def turns(ref_rot, est_rot) -> np.ndarray:
    """``R_ref R_estᵀ`` of every pair (rotation matrices, or :class:`RotationRows`: all rows as a slice, which
    gives the matrices it keeps without a copy; an index of every row copied them, 26 MB each on the hour)."""
    ref, est = (np.asarray(r[:] if isinstance(r, RotationRows) else r, np.float64) for r in (ref_rot, est_rot))
    if ref.shape[0] < metrics.KERNEL_ROWS:
        return np.matmul(ref, est.transpose(0, 2, 1))
    out = np.empty_like(ref)
    _turn_products(np.ascontiguousarray(ref), np.ascontiguousarray(est), out)
    return out


@njit(cache=True, nogil=True)
def _turn_products(ref, est, out):  # pragma: no cover - compiled
    """``out_k = ref_k est_kᵀ``, rounded as ``np.matmul`` (:func:`.simd.fma`)."""
    for s in range(ref.shape[0]):
        for r in range(3):
            for c in range(3):
                first = ref[s, r, 0] * est[s, c, 0]
                out[s, r, c] = fma(ref[s, r, 2], est[s, c, 2], fma(ref[s, r, 1], est[s, c, 1], first))


def segment_errors(
    ref_pos: np.ndarray,
    ref_rot: np.ndarray,
    est_pos: np.ndarray,
    est_rot: np.ndarray,
    path_length_m: float | None = None,
    scale: float = 1.0,
    fractions: tuple[float, ...] = SHORT_PATH_FRACTIONS,
) -> tuple[dict, dict[float, dict[str, np.ndarray]]]:
    """rpg's relative errors per sub-trajectory length on associated pairs (the estimate not aligned: only
    ``scale`` of its alignment matters). ``path_length_m`` sets the lengths (rpg: the whole truth's path;
    default the pairs'). Returns the JSON-ready statistics and the error arrays per length (the box plots)."""
    rp, ep = np.asarray(ref_pos, dtype=np.float64), np.asarray(est_pos, dtype=np.float64)
    dist = accumulated_distances(rp)
    total = float(dist[-1]) if path_length_m is None else float(path_length_m)
    rows, arrays, turn, runs = [], {}, turns(ref_rot, est_rot), equal_runs(dist)
    for length in rpg_lengths(total, fractions):
        i, j = rpg_segment_ends(dist, length, RPG_MAX_DIFF_FRACTION * length, runs) if length > 0 else ((), ())
        row = {"length_m": length, "n_segments": len(i)}
        if len(i) < 2:  # rpg: "Too few samples! Will not compute."
            rows.append({**row, **{k: None for k in SEGMENT_ERROR_KINDS}})
            continue
        errs = relative_errors(rp, ep, turn, i, j, length, scale)
        arrays[length] = errs
        rows.append({**row, **kind_statistics(errs, length)})
    return {
        "fractions": [float(f) for f in fractions],
        "path_length_m": total,
        "scale": float(scale),
        "per_length": rows,
    }, arrays
