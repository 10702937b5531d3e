"""Algorithm A: the fast-adaptation nonlinear SLAM observer (seed 000, spec §2).

The continuous-time law (spec §2.2) is integrated with the spec's "sub-stepped zero-order hold with
measurement prediction" (§2.4): each interval between events is split into ``m`` Euler steps of the
discrete law (§2.3, with the corrected Δt in the velocity-bias update and the closed-form ψ), and between
sub-steps the landmark measurements are predicted forward with the bias-corrected odometry. That keeps the
paper's very stiff gains stable at native log rates without ever changing them.

Events are velocity samples (zero-order hold of Ω_m, V_m until the next sample) and landmark frames
(the set of visible landmarks and their body-frame positions). A frame's measurements are predicted
forward until the next frame; after ``max_meas_age`` seconds without a frame no landmark is visible and
the observer dead-reckons. Only visible landmarks enter the sums (spec §8); bias adaptation is frozen
while fewer than ``min_landmarks_bias`` are visible (Assumption 1 needs three).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pipeline.observers.base import GainSpec, ObserverResult, ObserverSpec
from pipeline.lie import mat3_mul, mat3_vec, mat3t_vec, project_so3, se3_exp

#: Largest stable ``h * lambda`` of one explicit sub-step (spec §2.4 uses 0.5).
STEP_RATIO = 0.5
#: Re-orthonormalise R̂ every this many sub-steps (spec §7.3).
REORTHO_EVERY = 1000


@njit(cache=True)
def _substeps(dt, y, nvis, lm, vis_idx, r_hat, p_hat, k_p, k_w, alpha, gamma):
    """Number of sub-steps for an interval of length ``dt`` (spec §2.4 rate bound).

    The rotational correction rate is ``k_w Σ(‖y‖²+1)/α`` plus the largest landmark gain ψ; the bias
    loop is an integrator whose natural frequency is ``sqrt(Γ Σ(‖y‖²+1)/α)``, kept at ``h ω_n ≤ 0.1``.
    """
    if nvis == 0 or dt <= 0.0:
        return 1
    s = 0.0
    psi_max = 0.0
    for j in range(nvis):
        yy = y[j, 0] * y[j, 0] + y[j, 1] * y[j, 1] + y[j, 2] * y[j, 2]
        s += yy + 1.0
        ry = mat3_vec(r_hat, y[j])
        i = vis_idx[j]
        e0 = lm[i, 0] - ry[0] - p_hat[0]
        e1 = lm[i, 1] - ry[1] - p_hat[1]
        e2 = lm[i, 2] - ry[2] - p_hat[2]
        psi = k_p * (1.0 + e0 * e0 + e1 * e1 + e2 * e2) / 4.0
        if psi > psi_max:
            psi_max = psi
    lam = k_w * s / alpha + psi_max
    lam_bias = 5.0 * math.sqrt(gamma * s / alpha)
    if lam_bias > lam:
        lam = lam_bias
    return max(1, int(math.ceil(dt * lam / STEP_RATIO)))


@njit(cache=True)
def _integrate(dt, omega_m, vel_m, y, nvis, vis_idx, r_hat, p_hat, lm, b_om, b_v,
               k_p, k_w, alpha, gamma, min_landmarks_bias, counter):
    """Advance the state over ``dt`` seconds in place; ``y`` (visible measurements) is predicted in place.

    Returns the number of sub-steps taken.
    """
    m = _substeps(dt, y, nvis, lm, vis_idx, r_hat, p_hat, k_p, k_w, alpha, gamma)
    h = dt / m
    g_bias = gamma if nvis >= min_landmarks_bias else 0.0
    w_om = np.empty(3)
    w_v = np.empty(3)
    for _ in range(m):
        # Steps 2-4 and 6-7 of spec §2.3 with the state at the start of the sub-step.
        w_om[:] = 0.0
        w_v[:] = 0.0
        for j in range(nvis):
            i = vis_idx[j]
            ry = mat3_vec(r_hat, y[j])
            e = np.empty(3)
            e[0] = lm[i, 0] - ry[0] - p_hat[0]
            e[1] = lm[i, 1] - ry[1] - p_hat[1]
            e[2] = lm[i, 2] - ry[2] - p_hat[2]
            rte = mat3t_vec(r_hat, e)
            # [y]x R̂ᵀe = y x (R̂ᵀe)
            c0 = y[j, 1] * rte[2] - y[j, 2] * rte[1]
            c1 = y[j, 2] * rte[0] - y[j, 0] * rte[2]
            c2 = y[j, 0] * rte[1] - y[j, 1] * rte[0]
            w_om[0] += c0
            w_om[1] += c1
            w_om[2] += c2
            w_v[0] += rte[0]
            w_v[1] += rte[1]
            w_v[2] += rte[2]
            psi = k_p * (1.0 + e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) / 4.0
            step = h * psi
            if step > 1.0:  # never move past the measured point (spec §2.4)
                step = 1.0
            lm[i, 0] -= step * e[0]
            lm[i, 1] -= step * e[1]
            lm[i, 2] -= step * e[2]
        # W = -k_w/α Σ(...); corrected twist = measured - bias - W = measured - bias + k_w/α Σ(...)
        om_c = np.empty(3)
        v_c = np.empty(3)
        for a in range(3):
            om_c[a] = omega_m[a] - b_om[a] + (k_w / alpha) * w_om[a]
            v_c[a] = vel_m[a] - b_v[a] + (k_w / alpha) * w_v[a]
        # Measurement prediction uses the bias-corrected odometry, not the corrected twist (spec §2.4).
        om_odo = np.empty(3)
        v_odo = np.empty(3)
        for a in range(3):
            om_odo[a] = h * (omega_m[a] - b_om[a])
            v_odo[a] = h * (vel_m[a] - b_v[a])
        # Step 7 (biases, with Δt): b ← b − h Γ/α Σ(...)
        for a in range(3):
            b_om[a] -= h * (g_bias / alpha) * w_om[a]
            b_v[a] -= h * (g_bias / alpha) * w_v[a]
        # Step 5: T̂ ← T̂ exp(h [ω; v]∧)
        for a in range(3):
            om_c[a] *= h
            v_c[a] *= h
        d_r, d_p = se3_exp(om_c, v_c)
        dp_i = mat3_vec(r_hat, d_p)
        p_hat[0] += dp_i[0]
        p_hat[1] += dp_i[1]
        p_hat[2] += dp_i[2]
        r_hat[:, :] = mat3_mul(r_hat, d_r)
        counter[0] += 1
        if counter[0] % REORTHO_EVERY == 0:
            r_hat[:, :] = project_so3(r_hat)
        if nvis > 0:
            o_r, o_p = se3_exp(om_odo, v_odo)
            for j in range(nvis):
                d = np.empty(3)
                d[0] = y[j, 0] - o_p[0]
                d[1] = y[j, 1] - o_p[1]
                d[2] = y[j, 2] - o_p[2]
                y[j, :] = mat3t_vec(o_r, d)
    return m


@njit(cache=True)
def run_kernel(vel_t, omega, vel, det_t, det_offsets, det_idx, det_y, lm, lm_init,
               r0, p0, b_om0, b_v0, k_p, k_w, alpha, gamma, min_landmarks_bias, max_meas_age,
               out_every):
    """Run algorithm A over an ordered event stream.

    Times are float64 seconds on one base. ``lm`` (L, 3) / ``lm_init`` (L,) hold the initial map
    (landmarks with ``lm_init`` False are initialised at first sighting as ``P̂ + R̂ y``, spec §8).
    Outputs are recorded after every ``out_every``-th velocity sample (and the last one).

    Returns ``(out_k, out_r, out_p, out_b, trk_p, innov, substeps)``: indices of recorded velocity
    samples, R̂ (K,3,3), P̂ (K,3), biases (K,6) [b_Ω, b_V], per-detection landmark estimates (M,3)
    and innovations e_i (M,3) at the frame time, and the total number of sub-steps.
    """
    n_vel = vel_t.shape[0]
    n_frames = det_t.shape[0]
    n_max = 0
    for f in range(n_frames):
        c = det_offsets[f + 1] - det_offsets[f]
        if c > n_max:
            n_max = c
    y = np.zeros((max(n_max, 1), 3))
    vis_idx = np.zeros(max(n_max, 1), dtype=np.int64)
    nvis = 0
    meas_t = -np.inf

    r_hat = r0.copy()
    p_hat = p0.copy()
    b_om = b_om0.copy()
    b_v = b_v0.copy()

    n_out = (n_vel + out_every - 1) // out_every
    if n_vel > 0 and (n_vel - 1) % out_every != 0:
        n_out += 1
    out_k = np.empty(n_out, dtype=np.int64)
    out_r = np.empty((n_out, 3, 3))
    out_p = np.empty((n_out, 3))
    out_b = np.empty((n_out, 6))
    n_det = det_y.shape[0]
    trk_p = np.empty((n_det, 3))
    innov = np.empty((n_det, 3))
    counter = np.zeros(1, dtype=np.int64)
    substeps = 0

    iv = 0
    jf = 0
    started = False
    t = 0.0
    om_m = np.zeros(3)
    v_m = np.zeros(3)
    o = 0
    while iv < n_vel or jf < n_frames:
        is_frame = jf < n_frames and (iv >= n_vel or det_t[jf] < vel_t[iv])
        t_next = det_t[jf] if is_frame else vel_t[iv]
        if started:
            if t_next > t:
                if t - meas_t > max_meas_age:
                    nvis = 0
                substeps += _integrate(t_next - t, om_m, v_m, y, nvis, vis_idx, r_hat, p_hat, lm,
                                       b_om, b_v, k_p, k_w, alpha, gamma, min_landmarks_bias,
                                       counter)
                t = t_next
        if is_frame:
            a = det_offsets[jf]
            b = det_offsets[jf + 1]
            nvis = b - a
            for j in range(nvis):
                i = det_idx[a + j]
                vis_idx[j] = i
                y[j, :] = det_y[a + j]
                ry = mat3_vec(r_hat, det_y[a + j])
                if not lm_init[i]:
                    for c in range(3):
                        lm[i, c] = p_hat[c] + ry[c]
                    lm_init[i] = True
                for c in range(3):
                    innov[a + j, c] = lm[i, c] - ry[c] - p_hat[c]
                    trk_p[a + j, c] = lm[i, c]
            meas_t = t_next
            jf += 1
        else:
            om_m[:] = omega[iv]
            v_m[:] = vel[iv]
            if not started:
                started = True
                t = t_next
            if iv % out_every == 0 or iv == n_vel - 1:
                out_k[o] = iv
                out_r[o] = r_hat
                out_p[o] = p_hat
                out_b[o, :3] = b_om
                out_b[o, 3:] = b_v
                o += 1
            iv += 1
    return out_k[:o], out_r[:o], out_p[:o], out_b[:o], trk_p, innov, substeps


@njit(cache=True)
def innovation_norms(lm, vis_idx, y, r_hat, p_hat):
    """‖e_i‖ for the given measurements (used by tests and diagnostics)."""
    out = np.empty(vis_idx.shape[0])
    for j in range(vis_idx.shape[0]):
        ry = mat3_vec(r_hat, y[j])
        s = 0.0
        for c in range(3):
            d = lm[vis_idx[j], c] - ry[c] - p_hat[c]
            s += d * d
        out[j] = math.sqrt(s)
    return out



def run(stream, gains: dict[str, float], options) -> ObserverResult:
    """Run algorithm A on an aligned stream (Python side: prepare arrays, call the kernel)."""
    n_lm = stream.landmark_ids.shape[0]
    lm = np.zeros((n_lm, 3))
    lm_init = np.zeros(n_lm, dtype=np.bool_)
    out_k, out_r, out_p, out_b, trk, innov, substeps = run_kernel(
        stream.seconds(stream.vel_t_ns), stream.omega, stream.velocity,
        stream.seconds(stream.det_t_ns), stream.det_offsets, stream.det_idx, stream.det_y,
        lm, lm_init, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3),
        gains["k_p"], gains["k_w"], gains["alpha"], gains["gamma"],
        options.min_landmarks_bias, options.max_meas_age, options.out_every,
    )
    det_t = np.repeat(stream.det_t_ns, np.diff(stream.det_offsets))
    return ObserverResult(
        t_ns=stream.vel_t_ns[out_k], rotation=out_r, position=out_p,
        gyro_bias=out_b[:, :3], vel_bias=out_b[:, 3:],
        landmark_ids=stream.landmark_ids, landmark_xyz=lm,
        det_t_ns=det_t, det_ids=stream.det_ids, track_xyz=trk, innovation=innov,
        stats={"substeps": int(substeps)},
    )


SPEC = ObserverSpec(
    name="fast-adaptation",
    algorithm="A",
    paper="Drayton, Jaiyeola, Hoque, Maurer, Hashim: Fast Adaptation Nonlinear Observer for SLAM (seed 000)",
    summary="SE(3) pose + landmarks + velocity biases; landmark gain psi(e) = k_p (1 + |e|^2) / 4",
    gains=(
        GainSpec("alpha", 0.1, "per-landmark weight alpha_i (enters as 1/alpha)"),
        GainSpec("gamma", 30.0, "bias adaptation gain Gamma (times identity)"),
        GainSpec("k_p", 1.0, "landmark gain scale of psi(e)"),
        GainSpec("k_w", 2.0, "pose correction gain"),
    ),
    run=run,
)
