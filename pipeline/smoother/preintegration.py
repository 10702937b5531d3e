"""Compiled parts of the batch smoother: keyframes, preintegrated relative motion with its bias Jacobians and
covariance, the relative-motion residual with its analytic Jacobians, and the per-sample trajectory.

GTSAM has a preintegrated factor for accelerometers (``ImuFactor``) and one for gyros alone (``AHRSFactor``),
none for a body-velocity odometer with a velocity bias, so this one is written here (Forster et al.,
"On-Manifold Preintegration", 2017, with the body velocity in place of the accelerometer's double integral):

    ΔR_ij = Π exp(h(Ω_m − b̄_Ω)),   Δp_ij = Σ ΔR_ik J(h(Ω_m − b̄_Ω)) h (V_m − b̄_V)   (the twist linear between
    samples, :func:`~slamobs.pipeline.observers.shared_steps.twist_at`), with ∂ΔR/∂b_Ω, ∂Δp/∂b_Ω, ∂Δp/∂b_V and the
    covariance of (δφ, δp) from the
    white-noise densities. The residual between keyframe poses T_i, T_j and the bias b is

    r_R = Log((ΔR_ij Exp(J_R δb_Ω))ᵀ R_iᵀ R_j),   r_p = R_iᵀ(P_j − P_i) − (Δp_ij + J_pΩ δb_Ω + J_pV δb_V),
    δb = b − b̄, whitened by the preintegrated covariance.

Tangent conventions are GTSAM's: a pose moves as ``T Exp([θ; ρ])`` (rotation first), so ``R ← R Exp(θ)``,
``P ← P + Rρ`` to first order.
"""

from __future__ import annotations

import math

import numpy as np
from slamobs.pipeline.kernel_cache import njit

from slamobs.pipeline.lie import se3_exp_into, skew_into, so3_jacobians_into, so3_log
from slamobs.pipeline.observers.shared_steps import gap_factor, twist_at

#: Row layout of the per-interval data array: ΔR (9, row-major), Δp (3), J_R (9), J_pΩ (9), J_pV (9), W (36).
D_R, D_P, D_JR, D_JPW, D_JPV, D_W, D_END = 0, 9, 12, 21, 30, 39, 75


def keyframe_times(
    vel_t: np.ndarray, det_t: np.ndarray, max_dt: float, gaps_between: np.ndarray | None = None
) -> np.ndarray:
    """Every detection frame time, the first and last velocity sample, and evenly spaced fillers so that no two
    keyframes are more than ``max_dt`` apart (seconds, sorted, unique), except across the gaps between segments
    (``gaps_between``: (G, 2) start and end times), which one keyframe interval spans. A frame that an applied
    detection time offset moved past either end of the velocity samples keeps its own keyframe there, the motion
    held beyond the samples (:func:`~slamobs.pipeline.observers.shared_steps.twist_at`, as riekf holds it): its
    keyframe index was one past the last (a generated log whose offset was +0.28 s: an IndexError, or a compiled
    kernel writing out of bounds and the process aborting) or the first keyframe's, 0.3 s off its stamp."""
    base = np.unique(np.concatenate([[vel_t[0]], det_t, [vel_t[-1]]]))
    gaps = np.diff(base)
    pieces = np.maximum(1, np.ceil(gaps / max_dt - 1e-9).astype(np.int64))
    for lo, hi in gaps_between if gaps_between is not None else ():
        pieces[(base[:-1] <= lo) & (base[1:] >= hi)] = 1
    if np.all(pieces == 1):
        return base
    extra = [base[i] + gaps[i] * np.arange(1, pieces[i]) / pieces[i] for i in np.flatnonzero(pieces > 1)]
    return np.unique(np.concatenate([base, *extra]))


@njit(cache=True)
def _mm(a, b):
    out = np.empty((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            s = 0.0
            for k in range(a.shape[1]):
                s += a[i, k] * b[k, j]
            out[i, j] = s
    return out


@njit(cache=True)
def _mmt(a, b):
    """``a @ b.T``."""
    out = np.empty((a.shape[0], b.shape[0]))
    for i in range(a.shape[0]):
        for j in range(b.shape[0]):
            s = 0.0
            for k in range(a.shape[1]):
                s += a[i, k] * b[j, k]
            out[i, j] = s
    return out


@njit(cache=True)
def preintegrate(vel_t, omega, vel, kf_t, b_bar, q_om, q_v, gaps, vel_gap, om_gap, data, cov):
    """Relative motion over every keyframe interval ``[kf_t[j], kf_t[j+1]]`` at the bias ``b_bar`` (6,).

    Velocity sample ``s`` covers ``[vel_t[s], vel_t[s+1])`` (the twist in it:
    :func:`~slamobs.pipeline.observers.shared_steps.twist_at`). ``q_om``,
    ``q_v`` (3,) are noise densities squared (per axis); across a gap in the samples they take
    :func:`~slamobs.pipeline.observers.shared_steps.gap_factor` as riekf's propagation does (``gaps`` (2,): the
    gyro's and the velocity's median interval, 0 for a held stream; ``vel_gap`` (N,): the factor of the linear
    velocity's own gap hidden by the alignment over the interval ending at each sample, ``om_gap`` (N,) the gyro's
    over a saturating gyro's stretches, ``shared_steps.gap_levels``). Fills ``data`` (K−1, 75) in the layout of
    the ``D_*`` offsets (``W`` left empty) and ``cov`` (K−1, 6, 6), the covariance of ``(δφ, δp)``.
    """
    n = vel_t.shape[0]
    s = 0
    d_r = np.empty((3, 3))
    d_p = np.empty(3)
    jl = np.empty((3, 3))
    jr = np.empty((3, 3))
    sk = np.empty((3, 3))
    a = np.zeros((6, 6))
    bw = np.zeros((6, 3))
    bv = np.zeros((6, 3))
    for j in range(kf_t.shape[0] - 1):
        rr = np.eye(3)
        pp = np.zeros(3)
        j_r = np.zeros((3, 3))
        j_pw = np.zeros((3, 3))
        j_pv = np.zeros((3, 3))
        c = np.zeros((6, 6))
        t = kf_t[j]
        t_end = kf_t[j + 1]
        while s + 1 < n and vel_t[s + 1] <= t:
            s += 1
        while t < t_end:
            t_next = t_end
            if s + 1 < n and vel_t[s + 1] < t_end:
                t_next = vel_t[s + 1]
            h = t_next - t
            if h > 0.0:
                w0, w1, w2, v0, v1, v2 = twist_at(vel_t, omega, vel, s, t + 0.5 * h, b_bar)
                g_om = g_v = 1.0
                if s + 1 < n and t >= vel_t[s]:  # inside the interval from sample s to s + 1
                    span = vel_t[s + 1] - vel_t[s]
                    g_om = max(gap_factor(span, gaps[0]), om_gap[s + 1])
                    g_v = max(gap_factor(span, gaps[1]), vel_gap[s + 1])
                se3_exp_into(h * w0, h * w1, h * w2, h * v0, h * v1, h * v2, d_r, d_p)
                so3_jacobians_into(h * w0, h * w1, h * w2, jl, jr)
                # transition A = [[dRᵀ, 0], [−ΔR[dp]×, I]] and noise maps (rotation noise, velocity noise)
                skew_into(d_p[0], d_p[1], d_p[2], sk)
                rdp = _mm(rr, sk)
                skew_into(v0, v1, v2, sk)
                rv = _mm(rr, sk)
                rjl = _mm(rr, jl)
                a[:, :] = 0.0
                for p in range(3):
                    for q in range(3):
                        a[p, q] = d_r[q, p]
                        a[3 + p, q] = -rdp[p, q]
                    a[3 + p, 3 + p] = 1.0
                for p in range(3):
                    for q in range(3):
                        bw[p, q] = jr[p, q] * h
                        bw[3 + p, q] = -0.5 * h * h * rv[p, q]
                        bv[p, q] = 0.0
                        bv[3 + p, q] = rjl[p, q] * h
                ac = _mm(a, c)
                c = _mmt(ac, a)
                for p in range(6):
                    for q in range(6):
                        x = 0.0
                        for k in range(3):
                            x += g_om * bw[p, k] * q_om[k] * bw[q, k] + g_v * bv[p, k] * q_v[k] * bv[q, k]
                        c[p, q] += x / h
                # bias Jacobians (the bias enters exactly as the noise does)
                jpw_new = j_pw - _mm(rdp, j_r) + 0.5 * h * h * rv
                j_pv = j_pv - rjl * h
                j_r = _mm(d_r.T.copy(), j_r) - jr * h
                j_pw = jpw_new
                # mean: (ΔR, Δp) ← (ΔR, Δp)·exp(h[w; v])
                for p in range(3):
                    pp[p] += rr[p, 0] * d_p[0] + rr[p, 1] * d_p[1] + rr[p, 2] * d_p[2]
                rr = _mm(rr, d_r)
            t = t_next
            if s + 1 < n and vel_t[s + 1] <= t:
                s += 1
        for p in range(3):
            for q in range(3):
                data[j, D_R + 3 * p + q] = rr[p, q]
                data[j, D_JR + 3 * p + q] = j_r[p, q]
                data[j, D_JPW + 3 * p + q] = j_pw[p, q]
                data[j, D_JPV + 3 * p + q] = j_pv[p, q]
            data[j, D_P + p] = pp[p]
        cov[j] = c


def whitening(cov: np.ndarray, floor: float = 1e-12) -> np.ndarray:
    """``W`` with ``Wᵀ W = Σ⁻¹`` for every (6, 6) covariance (``W = L⁻¹``, ``Σ = L Lᵀ``); a tiny floor keeps
    intervals of almost no duration well posed."""
    chol = np.linalg.cholesky(cov + floor * np.eye(6))
    return np.linalg.inv(chol)


@njit(cache=True)
def _inv_right_jacobian(r0, r1, r2, out):
    """``J_r⁻¹(r) = I + ½[r]× + (1/θ² − (1 + cos θ)/(2θ sin θ))[r]×²``."""
    t2 = r0 * r0 + r1 * r1 + r2 * r2
    theta = math.sqrt(t2)
    if theta < 1e-6:
        c = 1.0 / 12.0
    else:
        c = 1.0 / t2 - (1.0 + math.cos(theta)) / (2.0 * theta * math.sin(theta))
    r = (r0, r1, r2)
    for i in range(3):
        for j in range(3):
            out[i, j] = (1.0 if i == j else 0.0) + c * (r[i] * r[j] - (t2 if i == j else 0.0))
    out[0, 1] -= 0.5 * r2
    out[0, 2] += 0.5 * r1
    out[1, 0] += 0.5 * r2
    out[1, 2] -= 0.5 * r0
    out[2, 0] -= 0.5 * r1
    out[2, 1] += 0.5 * r0


@njit(cache=True)
def motion_residual(data, j, b_bar, ti, tj, b, out_r, out_h, want_h):
    """Whitened residual (6,) of interval ``j`` between poses ``ti``, ``tj`` (4, 4) and the bias ``b`` (6,) into
    ``out_r``, and with ``want_h`` its Jacobians into ``out_h`` (3, 6, 6): wrt ``T_i``, ``T_j``, ``b``.
    Returns the unwhitened residual ``(r_R, r_p)``."""
    dr = data[j, D_R : D_R + 9].reshape(3, 3)
    j_r = data[j, D_JR : D_JR + 9].reshape(3, 3)
    j_pw = data[j, D_JPW : D_JPW + 9].reshape(3, 3)
    j_pv = data[j, D_JPV : D_JPV + 9].reshape(3, 3)
    w = data[j, D_W : D_W + 36].reshape(6, 6)
    dbw = np.empty(3)
    dbv = np.empty(3)
    for c in range(3):
        dbw[c] = b[c] - b_bar[c]
        dbv[c] = b[3 + c] - b_bar[3 + c]
    # corrected ΔR = ΔR̄ Exp(J_R δb_Ω)
    phi = np.empty(3)
    for c in range(3):
        phi[c] = j_r[c, 0] * dbw[0] + j_r[c, 1] * dbw[1] + j_r[c, 2] * dbw[2]
    e_phi = np.empty((3, 3))
    unused = np.empty(3)
    se3_exp_into(phi[0], phi[1], phi[2], 0.0, 0.0, 0.0, e_phi, unused)
    drc = _mm(dr, e_phi)
    ri = ti[:3, :3]
    rj = tj[:3, :3]
    rirj = np.empty((3, 3))  # R_iᵀ R_j
    for p in range(3):
        for q in range(3):
            rirj[p, q] = ri[0, p] * rj[0, q] + ri[1, p] * rj[1, q] + ri[2, p] * rj[2, q]
    e = np.empty((3, 3))  # ΔR_cᵀ R_iᵀ R_j
    for p in range(3):
        for q in range(3):
            e[p, q] = drc[0, p] * rirj[0, q] + drc[1, p] * rirj[1, q] + drc[2, p] * rirj[2, q]
    r_rot = so3_log(e)
    dpos = np.empty(3)
    for c in range(3):
        dpos[c] = tj[c, 3] - ti[c, 3]
    rel = np.empty(3)  # R_iᵀ(P_j − P_i)
    for c in range(3):
        rel[c] = ri[0, c] * dpos[0] + ri[1, c] * dpos[1] + ri[2, c] * dpos[2]
    r = np.empty(6)
    for c in range(3):
        r[c] = r_rot[c]
        r[3 + c] = (
            rel[c]
            - data[j, D_P + c]
            - (j_pw[c, 0] * dbw[0] + j_pw[c, 1] * dbw[1] + j_pw[c, 2] * dbw[2])
            - (j_pv[c, 0] * dbv[0] + j_pv[c, 1] * dbv[1] + j_pv[c, 2] * dbv[2])
        )
    for p in range(6):
        x = 0.0
        for q in range(6):
            x += w[p, q] * r[q]
        out_r[p] = x
    if not want_h:
        return r
    jinv = np.empty((3, 3))
    _inv_right_jacobian(r_rot[0], r_rot[1], r_rot[2], jinv)
    h = np.zeros((3, 6, 6))
    # rotation rows
    hj = jinv
    hi = -_mm(jinv, rirj.T.copy())  # −J_r⁻¹ R_jᵀ R_i
    jl = np.empty((3, 3))
    jr_phi = np.empty((3, 3))
    so3_jacobians_into(phi[0], phi[1], phi[2], jl, jr_phi)
    exp_r = np.empty((3, 3))
    se3_exp_into(r_rot[0], r_rot[1], r_rot[2], 0.0, 0.0, 0.0, exp_r, unused)
    hb = -_mm(_mm(_mm(jinv, exp_r.T.copy()), jr_phi), j_r)  # −J_r⁻¹(r) Exp(r)ᵀ J_r(J_R δb) J_R
    for p in range(3):
        for q in range(3):
            h[0, p, q] = hi[p, q]
            h[1, p, q] = hj[p, q]
            h[2, p, q] = hb[p, q]
    # position rows: ∂/∂θ_i = [R_iᵀ(P_j − P_i)]×, ∂/∂ρ_i = −I, ∂/∂ρ_j = R_iᵀR_j, ∂/∂b = (−J_pΩ, −J_pV)
    sk = np.empty((3, 3))
    skew_into(rel[0], rel[1], rel[2], sk)
    for p in range(3):
        for q in range(3):
            h[0, 3 + p, q] = sk[p, q]
            h[1, 3 + p, 3 + q] = rirj[p, q]
            h[2, 3 + p, q] = -j_pw[p, q]
            h[2, 3 + p, 3 + q] = -j_pv[p, q]
        h[0, 3 + p, 3 + p] = -1.0
    for k in range(3):
        for p in range(6):
            for q in range(6):
                x = 0.0
                for m in range(6):
                    x += w[p, m] * h[k, m, q]
                out_h[k, p, q] = x
    return r


@njit(cache=True)
def motion_linearize(data, b_bar, rot, pos, bias, seg_of, damping, r_out, h_out):
    """Whitened residuals and Jacobians of every interval at the poses ``rot``, ``pos`` and the biases
    ``bias[seg_of[j]]``: rows 0-5 of ``r_out`` (K−1, 12) / ``h_out`` (K−1, 3, 12, 6) are the relative motion,
    rows 6-11 the Levenberg–Marquardt damping ``√λ I`` of interval j's first pose (residual 0). Returns the
    squared norm of the residuals."""
    k = data.shape[0]
    ti = np.eye(4)
    tj = np.eye(4)
    rw = np.empty(6)
    hh = np.empty((3, 6, 6))
    total = 0.0
    for j in range(k):
        ti[:3, :3] = rot[j]
        ti[:3, 3] = pos[j]
        tj[:3, :3] = rot[j + 1]
        tj[:3, 3] = pos[j + 1]
        motion_residual(data, j, b_bar, ti, tj, bias[seg_of[j]], rw, hh, True)
        h_out[j] = 0.0
        r_out[j] = 0.0
        for p in range(6):
            r_out[j, p] = rw[p]
            total += rw[p] * rw[p]
            for q in range(6):
                h_out[j, 0, p, q] = hh[0, p, q]
                h_out[j, 1, p, q] = hh[1, p, q]
                h_out[j, 2, p, q] = hh[2, p, q]
            h_out[j, 0, 6 + p, p] = damping
    return total


@njit(cache=True)
def motion_error(data, b_bar, rot, pos, bias, seg_of):
    """Squared norm of all whitened relative-motion residuals."""
    k = data.shape[0]
    ti = np.eye(4)
    tj = np.eye(4)
    rw = np.empty(6)
    hh = np.empty((3, 6, 6))
    total = 0.0
    for j in range(k):
        ti[:3, :3] = rot[j]
        ti[:3, 3] = pos[j]
        tj[:3, :3] = rot[j + 1]
        tj[:3, 3] = pos[j + 1]
        motion_residual(data, j, b_bar, ti, tj, bias[seg_of[j]], rw, hh, False)
        for p in range(6):
            total += rw[p] * rw[p]
    return total


@njit(cache=True)
def motion_residuals(data, b_bar, rot, pos, bias, seg_of):
    """Per interval: rotation residual (rad), position residual (m) and whitened norm, for the solver summary;
    ``rot`` (K, 3, 3), ``pos`` (K, 3) are the keyframe poses, ``bias[seg_of[j]]`` the bias of interval ``j``."""
    k = data.shape[0]
    out = np.empty((k, 3))
    ti = np.eye(4)
    tj = np.eye(4)
    rw = np.empty(6)
    hh = np.empty((3, 6, 6))
    for j in range(k):
        ti[:3, :3] = rot[j]
        ti[:3, 3] = pos[j]
        tj[:3, :3] = rot[j + 1]
        tj[:3, 3] = pos[j + 1]
        r = motion_residual(data, j, b_bar, ti, tj, bias[seg_of[j]], rw, hh, False)
        out[j, 0] = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        out[j, 1] = math.sqrt(r[3] * r[3] + r[4] * r[4] + r[5] * r[5])
        out[j, 2] = math.sqrt(rw[0] ** 2 + rw[1] ** 2 + rw[2] ** 2 + rw[3] ** 2 + rw[4] ** 2 + rw[5] ** 2)
    return out


@njit(cache=True)
def dead_reckon(vel_t, omega, vel, kf_t, bias, r0, p0, rot, pos):
    """Keyframe poses by integrating the bias-corrected odometry
    (:func:`~slamobs.pipeline.observers.shared_steps.twist_at`) from ``(r0, p0)`` at
    ``kf_t[0]``: the dead-reckoning seed, and the motion the smoother's solution is checked against."""
    n = vel_t.shape[0]
    s = 0
    rr = r0.copy()
    pp = p0.copy()
    rot[0] = rr
    pos[0] = pp
    d_r = np.empty((3, 3))
    d_p = np.empty(3)
    t = kf_t[0]
    for j in range(1, kf_t.shape[0]):
        t_end = kf_t[j]
        while s + 1 < n and vel_t[s + 1] <= t:
            s += 1
        while t < t_end:
            t_next = t_end
            if s + 1 < n and vel_t[s + 1] < t_end:
                t_next = vel_t[s + 1]
            h = t_next - t
            if h > 0.0:
                w0, w1, w2, v0, v1, v2 = twist_at(vel_t, omega, vel, s, t + 0.5 * h, bias)
                se3_exp_into(h * w0, h * w1, h * w2, h * v0, h * v1, h * v2, d_r, d_p)
                for p in range(3):
                    pp[p] += rr[p, 0] * d_p[0] + rr[p, 1] * d_p[1] + rr[p, 2] * d_p[2]
                rr = _mm(rr, d_r)
            t = t_next
            if s + 1 < n and vel_t[s + 1] <= t:
                s += 1
        rot[j] = rr
        pos[j] = pp


@njit(cache=True)
def sample_poses(vel_t, omega, vel, kf_t, rot, pos, bias_rows, rows, out_r, out_p):
    """Poses at the velocity samples ``rows`` (sorted indices): from the keyframe before each sample, the
    bias-corrected odometry (bias ``bias_rows[s]`` during sample ``s``), with the mismatch at the next keyframe
    spread linearly over the interval (rotation on the manifold, position in the map frame), so the
    trajectory passes through every keyframe and is continuous."""
    n = vel_t.shape[0]
    k_n = kf_t.shape[0]
    m = rows.shape[0]
    d_r = np.empty((3, 3))
    d_p = np.empty(3)
    corr = np.empty((3, 3))
    unused = np.empty(3)
    q = 0
    s = 0
    for j in range(k_n - 1):
        t0 = kf_t[j]
        t1 = kf_t[j + 1]
        final = j == k_n - 2
        q_end = q
        while q_end < m and (vel_t[rows[q_end]] < t1 or (final and vel_t[rows[q_end]] <= t1)):
            q_end += 1
        if q_end == q:
            continue
        rr = rot[j].copy()
        pp = pos[j].copy()
        t = t0
        while s + 1 < n and vel_t[s + 1] <= t:
            s += 1
        qq = q
        while True:
            while qq < q_end and vel_t[rows[qq]] <= t:
                out_r[qq] = rr
                out_p[qq] = pp
                qq += 1
            if t >= t1:
                break
            t_next = t1
            if s + 1 < n and vel_t[s + 1] < t1:
                t_next = vel_t[s + 1]
            h = t_next - t
            w0, w1, w2, v0, v1, v2 = twist_at(vel_t, omega, vel, s, t + 0.5 * h, bias_rows[s])
            se3_exp_into(h * w0, h * w1, h * w2, h * v0, h * v1, h * v2, d_r, d_p)
            for p in range(3):
                pp[p] += rr[p, 0] * d_p[0] + rr[p, 1] * d_p[1] + rr[p, 2] * d_p[2]
            rr = _mm(rr, d_r)
            t = t_next
            while s + 1 < n and vel_t[s + 1] <= t:
                s += 1
        # the mismatch with keyframe j + 1, spread over the interval
        mis_r = np.empty((3, 3))
        r1 = rot[j + 1]
        for p in range(3):
            for c in range(3):
                mis_r[p, c] = rr[0, p] * r1[0, c] + rr[1, p] * r1[1, c] + rr[2, p] * r1[2, c]
        phi = so3_log(mis_r)
        span = t1 - t0
        for k in range(q, q_end):
            f = (vel_t[rows[k]] - t0) / span if span > 0.0 else 0.0
            se3_exp_into(f * phi[0], f * phi[1], f * phi[2], 0.0, 0.0, 0.0, corr, unused)
            out_r[k] = _mm(out_r[k].copy(), corr)
            for p in range(3):
                out_p[k, p] += f * (pos[j + 1, p] - pp[p])
        q = q_end


@njit(cache=True)
def advance_poses(rot, pos, omega, vel, bias, dt):
    """``(R, P) ← (R, P) exp(dt [Ω − b_Ω; V − b_V])`` row by row (a seed's pose at a sample carried to the
    keyframe just after it)."""
    d_r = np.empty((3, 3))
    d_p = np.empty(3)
    for k in range(rot.shape[0]):
        h = dt[k]
        se3_exp_into(
            h * (omega[k, 0] - bias[k, 0]),
            h * (omega[k, 1] - bias[k, 1]),
            h * (omega[k, 2] - bias[k, 2]),
            h * (vel[k, 0] - bias[k, 3]),
            h * (vel[k, 1] - bias[k, 4]),
            h * (vel[k, 2] - bias[k, 5]),
            d_r,
            d_p,
        )
        r = rot[k].copy()
        for p in range(3):
            pos[k, p] += r[p, 0] * d_p[0] + r[p, 1] * d_p[1] + r[p, 2] * d_p[2]
        rot[k] = _mm(r, d_r)
