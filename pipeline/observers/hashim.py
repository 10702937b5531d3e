"""Algorithms B and C: the Hashim–Eltoukhy SLAM filter without and with IMU directions (docs/observers.md §5).

One kernel serves both: B is C with ``k_1 = k_2 = 0`` and no directions. Per sub-step it applies

* the landmark part (docs/observers.md §5.1): constant landmark gain ``k_p``, body-frame pose correction
  ``W_U = −k_w Σ g_i/α``, bias law ``−Γ Σ g_i/α`` with ``Γ = diag(γ_ω I₃, γ_v I₃)``;
* the IMU part (docs/observers.md §5.2): attitude innovation ``σ_R = ½ Σ_j s_j (υ̂_j × υ_j)``, a rotation of
  the vehicle attitude *and of every landmark estimate about the vehicle* by ``ω_A = −k_1 R̂ σ_R`` (the
  "gain mapping": it rotates each ``e_i`` without changing its norm, so the IMU and landmark corrections
  decouple), and the gyro-bias term ``+γ_ω k_2 σ_R``.

The IMU rotation is applied as a separate rigid rotation after the SE(3) step (a first-order splitting of
the single exponential of the continuous law, §5.2) so that ``‖e_i‖`` is preserved exactly in discrete time too.

Integration is A's sub-stepped zero-order hold with measurement prediction (docs/observers.md §6.1): the
interval between events is cut into steps short enough for the stiffest loop, and between sub-steps the
landmark measurements *and the direction measurements* are predicted forward with the bias-corrected
odometry. Direction samples are held measurements too: holding them while R̂ moves on would compare the
current estimate with a body vector that is up to ``‖Ω‖Δt`` old, a lag that ``k_2`` feeds into the gyro
bias; predicting them costs one 3×3 product per direction and sub-step.

Only visible landmarks enter the sums; invisible ones are frozen except for the rigid co-rotation, which
moves the whole map (docs/observers.md §3.2). Bias adaptation (including the IMU term) is frozen below
``min_landmarks_bias`` visible landmarks; the IMU attitude correction keeps running, but then turns the
vehicle alone: with nothing tying the vehicle to the map, the attitude error the IMU sees is the vehicle's
own dead-reckoning drift, and turning the unseen map with it moved the map by the drift times its distance
(12° of gyro-bias drift turned a figure 8's map over a 50 s outage).

The co-rotation turns the whole estimate about the moving vehicle at every IMU correction, noise included:
it re-frames the estimate and adds nothing about the map, but as the pivot moves it shifts the map against the
poses already written (0.5 m on a 3-minute loop). The kernel therefore keeps the map frame ``F`` (what the
turns did to it, :mod:`pipeline.observers.shared_steps`) and writes poses, tracks, innovations and the map in
that frame, where a landmark stays where it was last seen; the mean orientation of ``F`` is the observer's
estimate of gravity and north in it (``output.frame: gravity``).

On logs, C starts from the attitude of the first usable direction sample (Algorithm 2 allows an
attitude-determination start) and re-compensates the accelerometer's gravity direction with the bias
estimates (:func:`pipeline.directions.load_directions`). Γ is two gains, ``gamma_omega`` and ``gamma_v``: on noisy
logs the
gyro-bias loop (gain ∝ range²) wants a different rate than the velocity-bias loop.
"""

from __future__ import annotations

import math

import numpy as np
from slamobs.pipeline.kernel_cache import njit

from slamobs.pipeline.directions import direction_arrays, first_attitude, load_directions
from slamobs.pipeline.lie import project_so3, se3_exp_into
from slamobs.pipeline.observers.base import (
    GainError,
    GainSpec,
    KernelState,
    ObserverSpec,
    Outputs,
    Stepper,
    max_per_frame,
)
from slamobs.pipeline.observers.shared_steps import (
    FRAME_SETTLE,
    count_capped,
    frame_rows,
    frame_sample,
    landmark_sums,
    load_frame,
    predict_points,
    record_step,
    substep_count,
    turn_frame,
)

#: Largest ``h * lambda`` of one explicit sub-step (docs/observers.md §6.1).
STEP_RATIO = 0.5
#: Re-orthonormalise R̂ every this many sub-steps (docs/observers.md §6.1).
REORTHO_EVERY = 1000


@njit(cache=True)
def _substeps(dt, y, nvis, dir_w, k_p, k_w, alpha, gamma_max, k_1, k_2):
    """Sub-steps for an interval of ``dt`` seconds (docs/observers.md §6.1 bound, extended by the IMU loops).

    Rates: rotational correction ``k_w Σ(‖y‖²+1)/α``, landmark gain ``k_p``, IMU attitude gain
    ``k_1 Σ s_j`` (an upper bound of ``k_1 λ_max(M̄)/2``); the bias integrator's natural frequency
    ``sqrt(γ (Σ(‖y‖²+1)/α + k_2 Σ s_j))`` is kept at ``h ω_n ≤ 0.1``.
    """
    if dt <= 0.0:
        return 1
    s = 0.0
    for j in range(nvis):
        s += y[j, 0] * y[j, 0] + y[j, 1] * y[j, 1] + y[j, 2] * y[j, 2] + 1.0
    sw = 0.0
    for j in range(dir_w.shape[0]):
        sw += dir_w[j]
    lam = k_w * s / alpha + (k_p if nvis > 0 else 0.0) + k_1 * sw
    lam_bias = 5.0 * math.sqrt(gamma_max * (s / alpha + k_2 * sw))
    if lam_bias > lam:
        lam = lam_bias
    return substep_count(dt, lam, STEP_RATIO)


@njit(cache=True)
def _integrate(
    dt,
    omega_m,
    vel_m,
    y,
    nvis,
    vis_idx,
    dir_i,
    dir_b,
    dir_w,
    r_hat,
    p_hat,
    lm,
    lm_init,
    b_om,
    b_v,
    k_p,
    k_w,
    alpha,
    gamma_om,
    gamma_v,
    k_1,
    k_2,
    min_landmarks_bias,
    counter,
    f_r,
    f_p,
    f_stat,
):
    """Advance the state over ``dt`` in place; ``y`` and ``dir_b`` are predicted forward in place, and the
    map frame ``(f_r, f_p)`` follows the co-rotations.

    Scalar code (no temporaries): it runs many times per sample. Returns the number of sub-steps.
    """
    n_dir = dir_w.shape[0]
    m = _substeps(dt, y, nvis, dir_w, k_p, k_w, alpha, max(gamma_om, gamma_v), k_1, k_2)
    h = dt / m
    adapt = nvis >= min_landmarks_bias
    g_om = h * gamma_om if adapt else 0.0
    g_v = h * gamma_v if adapt else 0.0
    imu = k_1 > 0.0 and n_dir > 0
    hkp = h * k_p
    om_odo = np.empty(3)
    v_odo = np.empty(3)
    d_r = np.empty((3, 3))
    d_p = np.empty(3)
    r_new = np.empty((3, 3))
    zero = np.zeros(3)
    for _ in range(m):
        r00, r01, r02 = r_hat[0, 0], r_hat[0, 1], r_hat[0, 2]
        r10, r11, r12 = r_hat[1, 0], r_hat[1, 1], r_hat[1, 2]
        r20, r21, r22 = r_hat[2, 0], r_hat[2, 1], r_hat[2, 2]
        # Landmark innovations a_L = Σ[y]x R̂ᵀe/α, c_L = Σ R̂ᵀe/α and the landmark step (visible only).
        a0, a1, a2, c0, c1, c2 = landmark_sums(nvis, vis_idx, y, lm, r_hat, p_hat, hkp, False)
        a0 /= alpha
        a1 /= alpha
        a2 /= alpha
        c0 /= alpha
        c1 /= alpha
        c2 /= alpha
        # IMU attitude innovation σ_R = ½ Σ s_j (R̂ᵀυ_I × υ_B), body frame.
        s0 = s1 = s2 = 0.0
        if imu:
            for j in range(n_dir):
                w = dir_w[j]
                if w <= 0.0:
                    continue
                x0, x1, x2 = dir_i[j, 0], dir_i[j, 1], dir_i[j, 2]
                u0 = r00 * x0 + r10 * x1 + r20 * x2
                u1 = r01 * x0 + r11 * x1 + r21 * x2
                u2 = r02 * x0 + r12 * x1 + r22 * x2
                b0, b1, b2 = dir_b[j, 0], dir_b[j, 1], dir_b[j, 2]
                s0 += 0.5 * w * (u1 * b2 - u2 * b1)
                s1 += 0.5 * w * (u2 * b0 - u0 * b2)
                s2 += 0.5 * w * (u0 * b1 - u1 * b0)
        om_odo[0] = omega_m[0] - b_om[0]
        om_odo[1] = omega_m[1] - b_om[1]
        om_odo[2] = omega_m[2] - b_om[2]
        v_odo[0] = vel_m[0] - b_v[0]
        v_odo[1] = vel_m[1] - b_v[1]
        v_odo[2] = vel_m[2] - b_v[2]
        # Biases: b_Ω ← b_Ω − hγ_ω(a_L − k_2σ_R), b_V ← b_V − hγ_v c_L.
        b_om[0] -= g_om * (a0 - k_2 * s0)
        b_om[1] -= g_om * (a1 - k_2 * s1)
        b_om[2] -= g_om * (a2 - k_2 * s2)
        b_v[0] -= g_v * c0
        b_v[1] -= g_v * c1
        b_v[2] -= g_v * c2
        # Landmark part of the pose step: T̂ ← T̂ exp(h[Ω_m − b̂_Ω + k_w a_L; V_m − b̂_V + k_w c_L]∧).
        se3_exp_into(
            h * (om_odo[0] + k_w * a0),
            h * (om_odo[1] + k_w * a1),
            h * (om_odo[2] + k_w * a2),
            h * (v_odo[0] + k_w * c0),
            h * (v_odo[1] + k_w * c1),
            h * (v_odo[2] + k_w * c2),
            d_r,
            d_p,
        )
        p_hat[0] += r00 * d_p[0] + r01 * d_p[1] + r02 * d_p[2]
        p_hat[1] += r10 * d_p[0] + r11 * d_p[1] + r12 * d_p[2]
        p_hat[2] += r20 * d_p[0] + r21 * d_p[1] + r22 * d_p[2]
        for a in range(3):
            for b in range(3):
                r_new[a, b] = r_hat[a, 0] * d_r[0, b] + r_hat[a, 1] * d_r[1, b] + r_hat[a, 2] * d_r[2, b]
        r_hat[:, :] = r_new
        if imu:
            # IMU attitude correction exp(h[ω_A]x), ω_A = −k_1 R̂σ_R. While the vehicle is tied to the map (bias
            # adaptation on) it turns the vehicle and the whole map rigidly about P̂ (docs/observers.md §5.2,
            # §5.3); otherwise it is the vehicle's own dead-reckoning drift, and the map, which nothing has
            # moved, stays.
            wa0 = -k_1 * (r00 * s0 + r01 * s1 + r02 * s2)
            wa1 = -k_1 * (r10 * s0 + r11 * s1 + r12 * s2)
            wa2 = -k_1 * (r20 * s0 + r21 * s1 + r22 * s2)
            se3_exp_into(h * wa0, h * wa1, h * wa2, 0.0, 0.0, 0.0, d_r, d_p)
            for a in range(3):
                for b in range(3):
                    r_new[a, b] = d_r[a, 0] * r_hat[0, b] + d_r[a, 1] * r_hat[1, b] + d_r[a, 2] * r_hat[2, b]
            r_hat[:, :] = r_new
            if adapt:
                for i in range(lm.shape[0]):
                    if lm_init[i]:
                        x0 = lm[i, 0] - p_hat[0]
                        x1 = lm[i, 1] - p_hat[1]
                        x2 = lm[i, 2] - p_hat[2]
                        lm[i, 0] = p_hat[0] + d_r[0, 0] * x0 + d_r[0, 1] * x1 + d_r[0, 2] * x2
                        lm[i, 1] = p_hat[1] + d_r[1, 0] * x0 + d_r[1, 1] * x1 + d_r[1, 2] * x2
                        lm[i, 2] = p_hat[2] + d_r[2, 0] * x0 + d_r[2, 1] * x1 + d_r[2, 2] * x2
                turn_frame(d_r, p_hat, f_r, f_p)
                f_stat[0] += h
        counter[0] += 1
        if counter[0] % REORTHO_EVERY == 0:
            r_hat[:, :] = project_so3(r_hat)
            f_r[:, :] = project_so3(f_r)
        if nvis > 0 or imu:
            # Predict the held measurements over the sub-step with the bias-corrected odometry:
            # y ← dRᵀ(y − dp), υ ← dRᵀυ.
            se3_exp_into(
                h * om_odo[0], h * om_odo[1], h * om_odo[2], h * v_odo[0], h * v_odo[1], h * v_odo[2], d_r, d_p
            )
            predict_points(y, nvis, d_r, d_p)
            if imu:
                predict_points(dir_b, n_dir, d_r, zero)  # directions: rotation only
    return m


#: Kernel scalars kept between stretches: ``fs = [t, meas_t]``, ``ns = [iv, jf, nvis, started, substeps]``.
_T, _MEAS_T = 0, 1
_IV, _JF, _NVIS, _STARTED, _SUBSTEPS = 0, 1, 2, 3, 4


@njit(cache=True, nogil=True)
def _advance(
    vel_t,
    omega,
    vel,
    dir_inertial,
    dir_body,
    dir_weight,
    dir_gscale,
    make_cross,
    det_t,
    det_offsets,
    det_idx,
    det_y,
    lm,
    lm_init,
    k_p,
    k_w,
    alpha,
    gamma_om,
    gamma_v,
    k_1,
    k_2,
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
    dir_b,
    dir_w,
    om_m,
    v_m,
    counter,
    fs,
    ns,
    f_r,
    f_p,
    f_sum,
    f_stat,
    map_frame,
    settle_s,
    out_k,
    out_r,
    out_p,
    out_b,
    trk_p,
    innov,
    det_base,
):
    """The event loop of :func:`run_kernel` from the state in the arrays, until the next event is velocity
    sample ``iv_stop`` or ``budget`` work units are spent; stores the state back and returns the number of
    rows recorded. With ``map_frame`` the rows, tracks and innovations are written in the map frame (``F⁻¹``
    of the working frame)."""
    n_vel = vel_t.shape[0]
    n_frames = det_t.shape[0]
    n_dir = dir_inertial.shape[0]
    t, meas_t = fs[_T], fs[_MEAS_T]
    iv, jf, nvis, started, substeps = ns[_IV], ns[_JF], ns[_NVIS], ns[_STARTED] != 0, ns[_SUBSTEPS]
    o = 0
    work = 0
    corotated = lm.shape[0] if k_1 > 0.0 and n_dir > 0 else 0  # landmarks each IMU sub-step rotates
    while (iv < n_vel or jf < n_frames) and work < budget:
        is_frame = jf < n_frames and (iv >= n_vel or det_t[jf] < vel_t[iv])
        if not is_frame and iv >= iv_stop:
            break
        t_next = det_t[jf] if is_frame else vel_t[iv]
        work += 1
        if started and t_next > t:
            if t - meas_t > max_meas_age:
                nvis = 0
            m = _integrate(
                t_next - t,
                om_m,
                v_m,
                y,
                nvis,
                vis_idx,
                dir_inertial,
                dir_b,
                dir_w,
                r_hat,
                p_hat,
                lm,
                lm_init,
                b_om,
                b_v,
                k_p,
                k_w,
                alpha,
                gamma_om,
                gamma_v,
                k_1,
                k_2,
                min_landmarks_bias,
                counter,
                f_r,
                f_p,
                f_stat,
            )
            substeps += m
            work += m * (nvis + 1 + corotated)
            count_capped(m, iv, ns)
            t = t_next
        if is_frame:
            a = det_offsets[jf]
            b = det_offsets[jf + 1]
            nvis = b - a
            load_frame(a, nvis, det_idx, det_y, r_hat, p_hat, lm, lm_init, vis_idx, y, innov, trk_p, a - det_base)
            if map_frame:
                frame_rows(f_r, f_p, trk_p, innov, a - det_base, nvis)
            meas_t = t_next
            jf += 1
        else:
            om_m[:] = omega[iv]
            v_m[:] = vel[iv]
            if n_dir > 0:
                load_directions(
                    dir_body[iv], dir_weight[iv], dir_gscale, make_cross, om_m, v_m, b_om, b_v, dir_b, dir_w
                )
            if not started:
                started = True
                t = t_next
            frame_sample(f_r, f_sum, f_stat, settle_s)
            o = record_step(
                o, iv, n_vel, out_every, map_frame, f_r, f_p, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b
            )
            iv += 1
    fs[_T], fs[_MEAS_T] = t, meas_t
    ns[_IV], ns[_JF], ns[_NVIS], ns[_STARTED], ns[_SUBSTEPS] = iv, jf, nvis, 1 if started else 0, substeps
    return o


class _State(KernelState):
    """Algorithm B/C's state: the common one and the latest inertial directions."""

    def __init__(
        self, n_max: int, n_dir: int, r0: np.ndarray, p0: np.ndarray, b_om0: np.ndarray, b_v0: np.ndarray
    ) -> None:
        super().__init__(n_max, r0, p0, b_om0, b_v0)
        self.dir_b = np.zeros((n_dir, 3))
        self.dir_w = np.zeros(n_dir)

    def arrays(self) -> tuple:
        return (
            self.r_hat,
            self.p_hat,
            self.b_om,
            self.b_v,
            self.y,
            self.vis_idx,
            self.dir_b,
            self.dir_w,
            self.om_m,
            self.v_m,
            self.counter,
            self.fs,
            self.ns,
            self.f_r,
            self.f_p,
            self.f_sum,
            self.f_stat,
        )


def run_kernel(
    vel_t,
    omega,
    vel,
    dir_inertial,
    dir_body,
    dir_weight,
    dir_gscale,
    make_cross,
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
    gamma_om,
    gamma_v,
    k_1,
    k_2,
    min_landmarks_bias,
    max_meas_age,
    out_every,
    map_frame=False,
):
    """Run algorithm C (B when ``k_1 = k_2 = 0`` or there are no directions) over an ordered event stream.

    Arguments as :func:`pipeline.observers.fast_adaptation.run_kernel`, plus the directions on the
    velocity time base as made by :func:`pipeline.directions.direction_arrays`: ``dir_inertial (J, 3)`` unit vectors
    (the
    third one the cross product when ``make_cross``), ``dir_body (N, J0, 3)`` unit body measurements,
    ``dir_weight (N, J0)`` the weights ``s_j`` (0 = unavailable) and ``dir_gscale (J0,)`` (``‖g‖`` for an
    accelerometer direction, else 0; see :func:`pipeline.directions.load_directions`). ``J`` may be 0.
    ``lm``/``lm_init`` are updated in place (final map). Everything is in the working (inertial) frame, the
    map as co-rotated (the state of the law); with ``map_frame`` the outputs and, on return, ``lm`` are in the map
    frame instead, as :class:`Hashim` writes them.

    Returns ``(out_k, out_r, out_p, out_b, trk_p, innov, substeps)`` exactly like algorithm A's kernel.
    """
    n_vel = vel_t.shape[0]
    state = _State(max_per_frame(det_offsets), dir_inertial.shape[0], r0, p0, b_om0, b_v0)
    out = Outputs.whole_log(n_vel, out_every, det_y.shape[0])
    o = _advance(
        vel_t,
        omega,
        vel,
        dir_inertial,
        dir_body,
        dir_weight,
        dir_gscale,
        make_cross,
        det_t,
        det_offsets,
        det_idx,
        det_y,
        lm,
        lm_init,
        k_p,
        k_w,
        alpha,
        gamma_om,
        gamma_v,
        k_1,
        k_2,
        min_landmarks_bias,
        max_meas_age,
        out_every,
        n_vel,
        np.iinfo(np.int64).max,
        *state.arrays(),
        map_frame,
        np.inf,
        *out.arrays(),
    )
    if map_frame:
        lm[:, :3] = (lm[:, :3] - state.f_p) @ state.f_r
    return *out.recorded(o), int(state.ns[_SUBSTEPS])


def k_2_limit(gains: dict[str, float]) -> float:
    """k_2's upper bound: the Lyapunov derivative of docs/observers.md §5.2 is negative only when
    ``k_w k_2 < 4 k_1``."""
    return 4.0 * gains["k_1"] / gains["k_w"]


def check_imu_gains(gains: dict[str, float]) -> None:
    """``k_2 < k_2_limit`` (docs/observers.md §5.2)."""
    k_w, k_1, k_2 = gains["k_w"], gains["k_1"], gains["k_2"]
    if not k_2 < k_2_limit(gains):
        raise GainError(
            f"hashim-imu gains violate k_w*k_2 < 4*k_1 (k_w={k_w:g}, k_2={k_2:g}, k_1={k_1:g}): "
            f"lower k_2 below {4.0 * k_1 / k_w:g} or raise k_1"
        )


class Hashim(Stepper):
    """Algorithm B (no directions) or C on an aligned stream, a stretch of samples at a time."""

    def __init__(self, stream, gains: dict[str, float], options, dirs=None, r0=None) -> None:
        super().__init__(stream, options)
        n = stream.vel_t_ns.shape[0]
        if dirs is None:
            dirs = (np.zeros((0, 3)), np.zeros((n, 0, 3)), np.zeros((n, 0)), np.zeros(0), False)
        self.dirs = dirs
        self.gains = (
            gains["k_p"],
            gains["k_w"],
            gains["alpha"],
            gains["gamma_omega"],
            gains["gamma_v"],
            gains.get("k_1", 0.0),
            gains.get("k_2", 0.0),
        )
        self.state = _State(
            self.n_max, dirs[0].shape[0], np.eye(3) if r0 is None else r0, np.zeros(3), np.zeros(3), np.zeros(3)
        )
        k_1 = self.gains[5]
        self.keeps_map_frame = k_1 > 0.0 and dirs[0].shape[0] > 0
        self.settle_s = FRAME_SETTLE / k_1 if self.keeps_map_frame else np.inf

    def _kernel(self, iv_stop: int, out: Outputs, budget: int) -> int:
        s, o = self.stream, self.options
        rows = _advance(
            self.vel_t,
            s.omega,
            s.velocity,
            *self.dirs,
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
            True,
            self.settle_s,
            *out.arrays(),
        )
        self.stats["substeps"] = int(self.state.ns[_SUBSTEPS])
        return rows


def start(stream, gains: dict[str, float], options) -> Hashim:
    """Algorithm B: landmarks and velocities only."""
    return Hashim(stream, gains, options)


def start_imu(stream, gains: dict[str, float], options) -> Hashim:
    """Algorithm C: B plus the IMU attitude innovation from ≥ 2 inertial directions."""
    check_imu_gains(gains)
    if stream.directions is None or len(stream.directions.names) < 2:
        have = stream.directions.names if stream.directions is not None else ()
        raise ValueError(f"hashim-imu needs 2 inertial directions, the stream has {len(have)}")
    dirs = direction_arrays(stream.directions, gains)
    return Hashim(stream, gains, options, dirs, first_attitude(*dirs))


_PAPER = (
    "Hashim, Eltoukhy: Nonlinear Filter for Simultaneous Localization and Mapping on a Matrix Lie Group "
    "using IMU and Feature Measurements (arXiv 2101.01648)"
)


def _landmark_gains(gamma_omega: float) -> tuple[GainSpec, ...]:
    return (
        GainSpec(
            "alpha",
            1.0,
            "per-landmark weight alpha_i (enters as 1/alpha) [100 Hz reference set: 1, paper: 0.1]",
            (0.05, 10.0),
        ),
        GainSpec(
            "gamma_omega",
            gamma_omega,
            "gyro-bias adaptation gain; Gamma = diag(gamma_omega I, gamma_v I) [100 Hz reference set: 0.3]",
            (0.01, 50.0),
        ),
        GainSpec("gamma_v", 1.0, "velocity-bias adaptation gain [100 Hz reference set: 0.3]", (0.01, 50.0)),
        GainSpec("k_p", 1.0, "constant landmark gain [reference: 1]", (0.1, 10.0)),
        GainSpec("k_w", 1.0, "pose correction gain [100 Hz reference set: 0.02, paper: 2]", (0.005, 10.0)),
    )


# Defaults tuned on the noisy sample logs (sample_logs/README.md) and checked on unseen simulator seeds; the
# reference sets (100 Hz: alpha 1, k_w 0.02, gamma 0.3, k_p 1; the paper's: alpha 0.1, k_w 2, gamma 30) also run,
# sub-stepped. C needs a faster gyro-bias loop than B: until b̂_Ω is right, the IMU keeps rotating the
# map about the vehicle, which moves the unobservable translation offset P_c.
SPEC = ObserverSpec(
    name="hashim",
    algorithm="B",
    paper=_PAPER,
    summary="SE(3) pose + landmarks + velocity biases; constant landmark gain k_p (no IMU)",
    gains=_landmark_gains(gamma_omega=0.3),
    start=start,
)

SPEC_IMU = ObserverSpec(
    name="hashim-imu",
    algorithm="C",
    paper=_PAPER,
    summary="algorithm B + IMU attitude innovation from gravity/magnetic directions, map co-rotation; "
    "needs k_w*k_2 < 4*k_1",
    gains=_landmark_gains(gamma_omega=1.0)
    + (
        GainSpec("k_1", 1.0, "IMU attitude gain [reference: 1]", (0.1, 10.0)),
        GainSpec(
            "k_2",
            1.0,
            "IMU share of the gyro-bias law; needs k_w*k_2 < 4*k_1 [reference: k_1/k_w]",
            (0.01, 0.95),
            limit=k_2_limit,
        ),
        GainSpec("s_gravity", 1.0, "confidence s_j of the accelerometer gravity direction", (0.1, 10.0)),
        GainSpec("s_magnetic", 1.0, "confidence s_j of the magnetometer direction", (0.1, 10.0)),
    ),
    start=start_imu,
    check_gains=check_imu_gains,
    min_directions=2,
)
