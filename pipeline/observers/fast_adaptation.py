"""Algorithm A: the fast-adaptation nonlinear SLAM observer (Drayton et al., docs/observers.md §4).

The continuous-time law (docs/observers.md §4) is integrated with the "sub-stepped zero-order hold with
measurement prediction" of §6.1: each interval between events is split into ``m`` Euler steps of the
discrete law (§4, with the corrected Δt in the velocity-bias update and the closed-form ψ), and between
sub-steps the landmark measurements are predicted forward with the bias-corrected odometry. That keeps the
paper's very stiff gains stable at native log rates without ever changing them.

Events are velocity samples (zero-order hold of Ω_m, V_m until the next sample) and landmark frames
(the set of visible landmarks and their body-frame positions). A frame's measurements are predicted
forward until the next frame; after ``max_meas_age`` seconds without a frame no landmark is visible and
the observer dead-reckons. Only visible landmarks enter the sums (docs/observers.md §3.2); bias adaptation is frozen
while fewer than ``min_landmarks_bias`` are visible (Assumption 1 needs three).
"""

from __future__ import annotations

import math

import numpy as np
from numba import types
from slamobs.pipeline.kernel_cache import njit, subroutine

from slamobs.pipeline.observers.base import (
    GainSpec,
    KernelState,
    ObserverSpec,
    Outputs,
    Stepper,
    max_per_frame,
)
from slamobs.pipeline.observers.shared_steps import (
    count_capped,
    landmark_sums,
    load_frame,
    predict_points,
    record_row,
    substep_count,
)
from slamobs.pipeline.lie import mat3_vec, project_so3_into, se3_exp_into

#: Largest stable ``h * lambda`` of one explicit sub-step (docs/observers.md §6.1 uses 0.5).
STEP_RATIO = 0.5
#: Re-orthonormalise R̂ every this many sub-steps (docs/observers.md §6.1).
REORTHO_EVERY = 1000


@subroutine(types.int64)
def _substeps(dt, y, nvis, lm, vis_idx, r_hat, p_hat, k_p, k_w, alpha, gamma):
    """Number of sub-steps for an interval of length ``dt`` (docs/observers.md §6.1 rate bound).

    The rotational correction rate is ``k_w Σ(‖y‖²+1)/α`` plus the largest landmark gain ψ; the bias
    loop is an integrator whose natural frequency is ``sqrt(Γ Σ(‖y‖²+1)/α)``, kept at ``h ω_n ≤ 0.1``.
    Scalars only: it runs once per event, and at a few landmarks an allocation costs as much as a sub-step.
    """
    if nvis == 0 or dt <= 0.0:
        return 1
    s = 0.0
    psi_max = 0.0
    # R̂ and P̂ read once (numba lowers every element read with a copy of the array's struct: less to compile)
    r00, r01, r02 = r_hat[0, 0], r_hat[0, 1], r_hat[0, 2]
    r10, r11, r12 = r_hat[1, 0], r_hat[1, 1], r_hat[1, 2]
    r20, r21, r22 = r_hat[2, 0], r_hat[2, 1], r_hat[2, 2]
    p0, p1, p2 = p_hat[0], p_hat[1], p_hat[2]
    for j in range(nvis):
        y0, y1, y2 = y[j, 0], y[j, 1], y[j, 2]
        yy = y0 * y0 + y1 * y1 + y2 * y2
        s += yy + 1.0
        i = vis_idx[j]
        e0 = lm[i, 0] - (r00 * y0 + r01 * y1 + r02 * y2) - p0
        e1 = lm[i, 1] - (r10 * y0 + r11 * y1 + r12 * y2) - p1
        e2 = lm[i, 2] - (r20 * y0 + r21 * y1 + r22 * y2) - p2
        psi = k_p * (1.0 + e0 * e0 + e1 * e1 + e2 * e2) / 4.0
        if psi > psi_max:
            psi_max = psi
    lam = k_w * s / alpha + psi_max
    lam_bias = 5.0 * math.sqrt(gamma * s / alpha)
    if lam_bias > lam:
        lam = lam_bias
    return substep_count(dt, lam, STEP_RATIO)


@subroutine(types.int64)
def _integrate(
    dt,
    omega_m,
    vel_m,
    y,
    nvis,
    vis_idx,
    r_hat,
    p_hat,
    lm,
    b_om,
    b_v,
    k_p,
    k_w,
    alpha,
    gamma,
    min_landmarks_bias,
    counter,
    d_r,
    d_p,
):
    """Advance the state over ``dt`` seconds in place; ``y`` (visible measurements) is predicted in place.

    Written with scalars and the caller's scratch ``d_r`` (3, 3) / ``d_p`` (3,) (no allocation at all)
    because it runs hundreds of times per sample, and once per event when there are few sub-steps.
    Returns the number of sub-steps taken.
    """
    m = _substeps(dt, y, nvis, lm, vis_idx, r_hat, p_hat, k_p, k_w, alpha, gamma)
    h = dt / m
    g_bias = gamma if nvis >= min_landmarks_bias else 0.0
    kwa = k_w / alpha
    gba = h * g_bias / alpha
    # The held twist and the biases as scalars over the sub-steps (the biases written back after them): numba
    # lowers every element read or write of an array with a copy of its struct, so fewer of them compile faster.
    om0, om1, om2 = omega_m[0], omega_m[1], omega_m[2]
    vm0, vm1, vm2 = vel_m[0], vel_m[1], vel_m[2]
    bo0, bo1, bo2 = b_om[0], b_om[1], b_om[2]
    bv0, bv1, bv2 = b_v[0], b_v[1], b_v[2]
    for _ in range(m):
        # docs/observers.md §4's discrete step but the pose update, with the state at the start of the sub-step.
        r00, r01, r02 = r_hat[0, 0], r_hat[0, 1], r_hat[0, 2]
        r10, r11, r12 = r_hat[1, 0], r_hat[1, 1], r_hat[1, 2]
        r20, r21, r22 = r_hat[2, 0], r_hat[2, 1], r_hat[2, 2]
        w0, w1, w2, u0, u1, u2 = landmark_sums(nvis, vis_idx, y, lm, r_hat, p_hat, h * k_p, True)
        # Corrected twist = measured − bias − W with W = −(k_w/α) Σ(...); prediction uses odometry only.
        o0, o1, o2 = om0 - bo0, om1 - bo1, om2 - bo2
        v0, v1, v2 = vm0 - bv0, vm1 - bv1, vm2 - bv2
        # Step 7 (biases, with the Δt the paper's b̂_V update omits): b ← b − h Γ/α Σ(...)
        bo0 -= gba * w0
        bo1 -= gba * w1
        bo2 -= gba * w2
        bv0 -= gba * u0
        bv1 -= gba * u1
        bv2 -= gba * u2
        # Step 5: T̂ ← T̂ exp(h [ω; v]∧)
        se3_exp_into(
            h * (o0 + kwa * w0),
            h * (o1 + kwa * w1),
            h * (o2 + kwa * w2),
            h * (v0 + kwa * u0),
            h * (v1 + kwa * u1),
            h * (v2 + kwa * u2),
            d_r,
            d_p,
        )
        dp0, dp1, dp2 = d_p[0], d_p[1], d_p[2]
        p_hat[0] += r00 * dp0 + r01 * dp1 + r02 * dp2
        p_hat[1] += r10 * dp0 + r11 * dp1 + r12 * dp2
        p_hat[2] += r20 * dp0 + r21 * dp1 + r22 * dp2
        for b in range(3):  # R̂ ← R̂ dR from the row scalars read above (R̂ is unchanged until here)
            c0, c1, c2 = d_r[0, b], d_r[1, b], d_r[2, b]
            r_hat[0, b] = r00 * c0 + r01 * c1 + r02 * c2
            r_hat[1, b] = r10 * c0 + r11 * c1 + r12 * c2
            r_hat[2, b] = r20 * c0 + r21 * c1 + r22 * c2
        count = counter[0] + 1
        counter[0] = count
        if count % REORTHO_EVERY == 0:
            project_so3_into(r_hat)
        if nvis > 0:
            # Predict the measurements over the sub-step: y ← dRᵀ(y − dp) with bias-corrected odometry.
            se3_exp_into(h * o0, h * o1, h * o2, h * v0, h * v1, h * v2, d_r, d_p)
            predict_points(y, nvis, d_r, d_p)
    b_om[0], b_om[1], b_om[2] = bo0, bo1, bo2
    b_v[0], b_v[1], b_v[2] = bv0, bv1, bv2
    return m


#: Kernel scalars kept between stretches: ``fs = [t, meas_t]``, ``ns = [iv, jf, nvis, started, substeps]``.
_T, _MEAS_T = 0, 1
_IV, _JF, _NVIS, _STARTED, _SUBSTEPS = 0, 1, 2, 3, 4


@njit(cache=True, nogil=True, nrt=False)
def _advance(
    vel_t,
    omega,
    vel,
    det_t,
    det_offsets,
    det_idx,
    det_y,
    lm,
    lm_init,
    k_p,
    k_w,
    alpha,
    gamma,
    min_landmarks_bias,
    max_meas_age,
    out_every,
    iv_stop,
    budget,
    r_hat,
    p_hat,
    b_om,
    b_v,
    y,
    vis_idx,
    om_m,
    v_m,
    counter,
    d_r,
    d_p,
    fs,
    ns,
    out_k,
    out_r,
    out_p,
    out_b,
    trk_p,
    innov,
    det_base,
):
    """The event loop of :func:`run_kernel` from the state in the arrays, until the next event is velocity
    sample ``iv_stop`` (all events when ``iv_stop`` is the sample count) or ``budget`` work units are spent;
    stores the state back and returns the number of rows recorded (detection rows are written from
    ``det_base`` on)."""
    n_vel = vel_t.shape[0]
    n_frames = det_t.shape[0]
    # one statement per element (a five-element tuple assignment compiles a tuple and its unpacking)
    t = fs[_T]
    meas_t = fs[_MEAS_T]
    iv = ns[_IV]
    jf = ns[_JF]
    nvis = ns[_NVIS]
    started = ns[_STARTED] != 0
    substeps = ns[_SUBSTEPS]
    o = np.int64(0)  # not the literal 0: callees would compile for it too
    work = 0
    while (iv < n_vel or jf < n_frames) and work < budget:
        is_frame = jf < n_frames and (iv >= n_vel or det_t[jf] < vel_t[iv])
        if not is_frame and iv >= iv_stop:
            break
        t_next = det_t[jf] if is_frame else vel_t[iv]
        work += 1
        if started:
            if t_next > t:
                if t - meas_t > max_meas_age:
                    nvis = 0
                m = _integrate(
                    t_next - t,
                    om_m,
                    v_m,
                    y,
                    nvis,
                    vis_idx,
                    r_hat,
                    p_hat,
                    lm,
                    b_om,
                    b_v,
                    k_p,
                    k_w,
                    alpha,
                    gamma,
                    min_landmarks_bias,
                    counter,
                    d_r,
                    d_p,
                )
                substeps += m
                work += m * (nvis + 1)
                count_capped(m, iv, ns)
                t = t_next
        if is_frame:
            a = det_offsets[jf]
            b = det_offsets[jf + 1]
            nvis = b - a
            load_frame(a, nvis, det_idx, det_y, r_hat, p_hat, lm, lm_init, vis_idx, y, innov, trk_p, a - det_base)
            meas_t = t_next
            jf += 1
        else:
            for c in range(3):
                om_m[c] = omega[iv, c]
                v_m[c] = vel[iv, c]
            if not started:
                started = True
                t = t_next
            if iv % out_every == 0 or iv == n_vel - 1:
                record_row(o, iv, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b)
                o += 1
            iv += 1
    fs[_T] = t
    fs[_MEAS_T] = meas_t
    ns[_IV] = iv
    ns[_JF] = jf
    ns[_NVIS] = nvis
    ns[_STARTED] = 1 if started else 0
    ns[_SUBSTEPS] = substeps
    return o


class _State(KernelState):
    """Algorithm A's state: the common one and the scratch of :func:`_integrate`."""

    def __init__(self, n_max: int, r0: np.ndarray, p0: np.ndarray, b_om0: np.ndarray, b_v0: np.ndarray) -> None:
        super().__init__(n_max, r0, p0, b_om0, b_v0)
        self.d_r = np.empty((3, 3))
        self.d_p = np.empty(3)

    def arrays(self) -> tuple:
        return (
            self.r_hat,
            self.p_hat,
            self.b_om,
            self.b_v,
            self.y,
            self.vis_idx,
            self.om_m,
            self.v_m,
            self.counter,
            self.d_r,
            self.d_p,
            self.fs,
            self.ns,
        )


def run_kernel(
    vel_t,
    omega,
    vel,
    det_t,
    det_offsets,
    det_idx,
    det_y,
    lm,
    lm_init,
    r0,
    p0,
    b_om0,
    b_v0,
    k_p,
    k_w,
    alpha,
    gamma,
    min_landmarks_bias,
    max_meas_age,
    out_every,
):
    """Run algorithm A over an ordered event stream.

    Times are float64 seconds on one base. ``lm`` (L, 3) / ``lm_init`` (L,) hold the initial map
    (landmarks with ``lm_init`` False are initialised at first sighting as ``P̂ + R̂ y``, docs/observers.md §3.2).
    Outputs are recorded after every ``out_every``-th velocity sample (and the last one).

    Returns ``(out_k, out_r, out_p, out_b, trk_p, innov, substeps)``: indices of recorded velocity
    samples, R̂ (K,3,3), P̂ (K,3), biases (K,6) [b_Ω, b_V], per-detection landmark estimates (M,3)
    and innovations e_i (M,3) at the frame time, and the total number of sub-steps.
    """
    n_vel = vel_t.shape[0]
    state = _State(max_per_frame(det_offsets), r0, p0, b_om0, b_v0)
    out = Outputs.whole_log(n_vel, out_every, det_y.shape[0])
    o = _advance(
        vel_t,
        omega,
        vel,
        det_t,
        det_offsets,
        det_idx,
        det_y,
        lm,
        lm_init,
        k_p,
        k_w,
        alpha,
        gamma,
        min_landmarks_bias,
        max_meas_age,
        out_every,
        n_vel,
        np.iinfo(np.int64).max,
        *state.arrays(),
        *out.arrays(),
    )
    return *out.recorded(o), int(state.ns[_SUBSTEPS])


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


class FastAdaptation(Stepper):
    """Algorithm A on an aligned stream, a stretch of samples at a time."""

    def __init__(self, stream, gains: dict[str, float], options) -> None:
        super().__init__(stream, options)
        self.gains = (gains["k_p"], gains["k_w"], gains["alpha"], gains["gamma"])
        self.state = _State(self.n_max, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3))

    def _kernel(self, iv_stop: int, out: Outputs, budget: int) -> int:
        s, o = self.stream, self.options
        rows = _advance(
            self.vel_t,
            s.omega,
            s.velocity,
            self.det_t,
            s.det_offsets,
            s.det_idx,
            s.det_y,
            self.lm,
            self.lm_init,
            *self.gains,
            o.min_landmarks_bias,
            o.max_meas_age,
            o.out_every,
            iv_stop,
            budget,
            *self.state.arrays(),
            *out.arrays(),
        )
        self.stats["substeps"] = int(self.state.ns[_SUBSTEPS])
        return rows


SPEC = ObserverSpec(
    name="fast-adaptation",
    algorithm="A",
    paper="Drayton, Jaiyeola, Hoque, Maurer, Hashim: Fast Adaptation Nonlinear Observer for SLAM",
    summary="SE(3) pose + landmarks + velocity biases; landmark gain psi(e) = k_p (1 + |e|^2) / 4",
    # Defaults for noisy logs; the paper's simulation gains (alpha 0.1, gamma 30, k_p 1, k_w 2) are far
    # stiffer and amplify measurement noise into the bias estimates (std ~0.05 rad/s on the samples).
    gains=(
        GainSpec("alpha", 1.0, "per-landmark weight alpha_i (enters as 1/alpha) [paper: 0.1]", (0.05, 10.0)),
        GainSpec("gamma", 1.0, "bias adaptation gain Gamma (times identity) [paper: 30]", (0.01, 50.0)),
        GainSpec("k_p", 1.0, "landmark gain scale of psi(e) = k_p (1 + |e|^2) / 4 [paper: 1]", (0.1, 10.0)),
        GainSpec("k_w", 1.0, "pose correction gain [paper: 2]", (0.01, 10.0)),
    ),
    start=FastAdaptation,
)
