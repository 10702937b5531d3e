"""Algorithm D: the Wang–Tayebi smooth SLAM observer (docs/observers.md §8.1), and the flow it shares with E (§8.2).

D corrects in the inertial frame: the position and the map move along the landmark innovations
``e_i = p̂_i − p̂ − R̂ y_i``; the attitude is corrected only through the gyro-bias estimate, a lightly
damped integral loop. E adds inertial unit directions ``a_j`` (measured in the body as ``υ_j``): their
potential ``Φ(R̂) = ½ Σ ρ_j ‖a_j − R̂ υ_j‖²`` gives the inertial rotational innovation ``ω_c``, which
rotates the vehicle *and the whole map* (the landmark innovations only co-rotate, so their norms are
untouched), and the synergistic jumps of :mod:`pipeline.observers.hybrid`. One kernel runs both:
D is the flow with no directions and an empty candidate set.

Integration is algorithm A's sub-stepped zero-order hold (docs/observers.md §6.1): each interval is split so
that the position loop, the direction loop and the bias loop (``ω_n² ≈ γ_ω Σ k‖y‖²``, docs/observers.md
§6.2) stay well inside the explicit step's stability region, and the bias laws are applied before the propagation
(semi-implicit Euler) so the lightly damped loop is not anti-damped. Sub-stepping alone is not enough
here: with pure measurement prediction the innovation cannot see the bias estimate until the next frame,
and that sampling delay destabilises the bias loop once ``ω_n T_frame ≳ 0.2`` whatever the step (a limit
once put down to the Euler step). So the measurement between two frames is the prediction from the
first corrected towards the second (:func:`run_kernel`): stable for any gains, at the price of using data
up to one frame ahead — harmless for logs.

Rigid rotations of the estimate (co-rotation and jumps) pivot about the vehicle position ``p̂`` rather
than the map origin (docs/observers.md §8.2): ``R̂``, ``e_i``, the biases and the Lyapunov function
evolve identically (the two differ by a translation of the whole estimate, which nothing measures), but
with the vehicle as pivot the observer does not depend on where the inertial origin is, and a jump does
not move the vehicle position estimate. They re-frame the estimate without adding information about it, so
the kernel keeps the map frame they define and writes everything in it, as algorithm C's
(:mod:`pipeline.observers.hashim`); the direction innovation turns the map with the vehicle only while bias
adaptation is on (enough landmarks tie the vehicle to the map), and the vehicle alone otherwise (its own
dead-reckoning drift). D never turns its estimate: its map frame is its working frame.
"""

from __future__ import annotations

import math

import numpy as np
from slamobs.pipeline.kernel_cache import njit

from slamobs.pipeline.lie import project_so3, se3_exp_into
from slamobs.pipeline.observers.base import (
    GainSpec,
    KernelState,
    ObserverOptions,
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
    landmark_weight,
    load_frame,
    predict_points,
    record_step,
    substep_count,
    turn_frame,
)
from slamobs.pipeline.observers.fast_adaptation import REORTHO_EVERY, STEP_RATIO
from slamobs.pipeline.directions import load_directions

#: Bias loop: keep ``h ω_n`` at or below ``STEP_RATIO / BIAS_RATE_FACTOR = 0.1``.
BIAS_RATE_FACTOR = 5.0


@njit(cache=True)
def _substeps(dt, y, nvis, rho, nd, k_l, k_x, g_w, g_v):
    """Sub-steps for an interval ``dt``: the largest loop rate times ``dt`` over ``STEP_RATIO``.

    Rates: position/map ``k_X k (n+1)`` (eigenvalues of ``ė_i = −k_X k(e_i + Σ e_j)``), attitude from
    directions ``k_X Σρ / 2`` (bound of ``∂ω_c/∂θ``), bias loop ``ω_n = sqrt(γ_ω(kΣ‖y‖² + Σρ) + γ_v k n)``.
    ``g_w``/``g_v`` are zero while bias adaptation is frozen.
    """
    if dt <= 0.0:
        return 1
    yy = 0.0
    for j in range(nvis):
        yy += y[j, 0] * y[j, 0] + y[j, 1] * y[j, 1] + y[j, 2] * y[j, 2]
    srho = 0.0
    for j in range(nd):
        srho += rho[j]
    lam = k_x * k_l * (nvis + 1) if nvis > 0 else 0.0
    lam_dir = 0.5 * k_x * srho
    if lam_dir > lam:
        lam = lam_dir
    lam_bias = BIAS_RATE_FACTOR * math.sqrt(g_w * (k_l * yy + srho) + g_v * k_l * nvis)
    if lam_bias > lam:
        lam = lam_bias
    return substep_count(dt, lam, STEP_RATIO)


@njit(cache=True)
def rotate_estimate(rot, r_hat, p_hat, lm, whole_map=True):
    """Rotate the estimate rigidly about the vehicle: ``R̂ ← rot R̂`` and, with ``whole_map``,
    ``p̂_i ← p̂ + rot(p̂_i − p̂)`` for every landmark, seen or not, so the map stays rigid
    (docs/observers.md §3.2); ``e_i`` only rotates.
    """
    r_new = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            r_new[a, b] = rot[a, 0] * r_hat[0, b] + rot[a, 1] * r_hat[1, b] + rot[a, 2] * r_hat[2, b]
    r_hat[:, :] = r_new
    if not whole_map:
        return
    for i in range(lm.shape[0]):
        d0 = lm[i, 0] - p_hat[0]
        d1 = lm[i, 1] - p_hat[1]
        d2 = lm[i, 2] - p_hat[2]
        lm[i, 0] = p_hat[0] + rot[0, 0] * d0 + rot[0, 1] * d1 + rot[0, 2] * d2
        lm[i, 1] = p_hat[1] + rot[1, 0] * d0 + rot[1, 1] * d1 + rot[1, 2] * d2
        lm[i, 2] = p_hat[2] + rot[2, 0] * d0 + rot[2, 1] * d1 + rot[2, 2] * d2


@njit(cache=True)
def direction_potential(left, r_hat, ups, rho, ref, nd):
    """``Φ(leftᵀ R̂) = ½ Σ_j ρ_j ‖left a_j − R̂ υ_j‖²`` (``left = I`` gives ``Φ(R̂)``)."""
    s = 0.0
    for j in range(nd):
        for a in range(3):
            d = (
                left[a, 0] * ref[j, 0]
                + left[a, 1] * ref[j, 1]
                + left[a, 2] * ref[j, 2]
                - (r_hat[a, 0] * ups[j, 0] + r_hat[a, 1] * ups[j, 1] + r_hat[a, 2] * ups[j, 2])
            )
            s += rho[j] * d * d
    return 0.5 * s


@njit(cache=True)
def best_jump(r_hat, ups, rho, ref, nd, cand):
    """Switching variable of docs/observers.md §8.2: ``(q*, Φ(R̂), Φ(R_q*ᵀ R̂))`` with
    ``q* = argmin_q Φ(R_qᵀ R̂)``.

    ``μ = Φ(R̂) − Φ(R_q*ᵀ R̂)``; the caller jumps when ``μ ≥ δ``. ``q* = −1`` without candidates.
    """
    eye = np.eye(3)
    phi = direction_potential(eye, r_hat, ups, rho, ref, nd)
    q_best = -1
    phi_best = np.inf
    for q in range(cand.shape[0]):
        v = direction_potential(cand[q], r_hat, ups, rho, ref, nd)
        if v < phi_best:
            phi_best = v
            q_best = q
    return q_best, phi, phi_best


@njit(cache=True)
def _flow(
    dt,
    s_lm,
    rate_lm,
    s_dir,
    rate_dir,
    omega_m,
    vel_m,
    y,
    y_d,
    nvis,
    vis_idx,
    ups,
    ups_d,
    rho,
    ref,
    nd,
    r_hat,
    p_hat,
    lm,
    b_om,
    b_v,
    b_pred,
    k_l,
    k_x,
    gamma_w,
    gamma_v,
    min_landmarks_bias,
    counter,
    f_r,
    f_p,
    f_stat,
):
    """Flow the state over ``dt`` in place (docs/observers.md §8.1 / §8.2 flow); returns the sub-step count.

    The direction innovation turns the vehicle and the whole map (the map frame ``(f_r, f_p)`` follows) while
    bias adaptation is on, i.e. while enough landmarks tie the vehicle to the map; otherwise it corrects the
    vehicle's own drift and turns the vehicle alone.

    The measurements used are ``y + s y_d`` and ``ups + s ups_d``: the base ``y``/``ups`` is predicted in
    place with the odometry corrected by the bias ``b_pred`` frozen at the last frame, and ``s`` runs
    from ``s_lm``/``s_dir`` at ``rate_lm``/``rate_dir`` per second (see :func:`run_kernel`).
    """
    adapt = nvis >= min_landmarks_bias
    g_w = gamma_w if adapt else 0.0
    g_v = gamma_v if adapt else 0.0
    m = _substeps(dt, y, nvis, rho, nd, k_l, k_x, g_w, g_v)
    h = dt / m
    d_r = np.empty((3, 3))
    d_p = np.empty(3)
    r_new = np.empty((3, 3))
    r_c = np.empty((3, 3))
    zero = np.zeros(3)
    for step_i in range(m):
        sl = s_lm + step_i * h * rate_lm
        sd = s_dir + step_i * h * rate_dir
        r00, r01, r02 = r_hat[0, 0], r_hat[0, 1], r_hat[0, 2]
        r10, r11, r12 = r_hat[1, 0], r_hat[1, 1], r_hat[1, 2]
        r20, r21, r22 = r_hat[2, 0], r_hat[2, 1], r_hat[2, 2]
        s0 = s1 = s2 = 0.0  # Σ e_i (inertial)
        w0 = w1 = w2 = 0.0  # σ_ω
        u0 = u1 = u2 = 0.0  # σ_v / k
        for j in range(nvis):
            i = vis_idx[j]
            y0 = y[j, 0] + sl * y_d[j, 0]
            y1 = y[j, 1] + sl * y_d[j, 1]
            y2 = y[j, 2] + sl * y_d[j, 2]
            e0 = lm[i, 0] - p_hat[0] - (r00 * y0 + r01 * y1 + r02 * y2)
            e1 = lm[i, 1] - p_hat[1] - (r10 * y0 + r11 * y1 + r12 * y2)
            e2 = lm[i, 2] - p_hat[2] - (r20 * y0 + r21 * y1 + r22 * y2)
            q0 = r00 * e0 + r10 * e1 + r20 * e2  # R̂ᵀ e
            q1 = r01 * e0 + r11 * e1 + r21 * e2
            q2 = r02 * e0 + r12 * e1 + r22 * e2
            w0 += k_l * (y1 * q2 - y2 * q1)
            w1 += k_l * (y2 * q0 - y0 * q2)
            w2 += k_l * (y0 * q1 - y1 * q0)
            u0 += q0
            u1 += q1
            u2 += q2
            s0 += e0
            s1 += e1
            s2 += e2
            step = h * k_x * k_l * landmark_weight(lm, i)
            lm[i, 0] -= step * e0
            lm[i, 1] -= step * e1
            lm[i, 2] -= step * e2
        c0 = c1 = c2 = 0.0  # ω_c = ½ Σ ρ (R̂υ) × a
        for j in range(nd):
            ux = ups[j, 0] + sd * ups_d[j, 0]
            uy = ups[j, 1] + sd * ups_d[j, 1]
            uz = ups[j, 2] + sd * ups_d[j, 2]
            v0 = r00 * ux + r01 * uy + r02 * uz
            v1 = r10 * ux + r11 * uy + r12 * uz
            v2 = r20 * ux + r21 * uy + r22 * uz
            a0, a1, a2 = ref[j, 0], ref[j, 1], ref[j, 2]
            c0 += 0.5 * rho[j] * (v1 * a2 - v2 * a1)
            c1 += 0.5 * rho[j] * (v2 * a0 - v0 * a2)
            c2 += 0.5 * rho[j] * (v0 * a1 - v1 * a0)
            t0 = r00 * a0 + r10 * a1 + r20 * a2  # σ_ω += ρ υ × R̂ᵀa
            t1 = r01 * a0 + r11 * a1 + r21 * a2
            t2 = r02 * a0 + r12 * a1 + r22 * a2
            w0 += rho[j] * (uy * t2 - uz * t1)
            w1 += rho[j] * (uz * t0 - ux * t2)
            w2 += rho[j] * (ux * t1 - uy * t0)
        # Bias laws first, so the propagation below already uses the new bias (semi-implicit Euler: the
        # lightly damped bias/attitude loop is not anti-damped by the discretisation).
        b_om[0] -= h * g_w * w0
        b_om[1] -= h * g_w * w1
        b_om[2] -= h * g_w * w2
        gv = h * g_v * k_l
        b_v[0] -= gv * u0
        b_v[1] -= gv * u1
        b_v[2] -= gv * u2
        # Right propagation with the bias-corrected odometry, then the inertial corrections.
        se3_exp_into(
            h * (omega_m[0] - b_om[0]),
            h * (omega_m[1] - b_om[1]),
            h * (omega_m[2] - b_om[2]),
            h * (vel_m[0] - b_v[0]),
            h * (vel_m[1] - b_v[1]),
            h * (vel_m[2] - b_v[2]),
            d_r,
            d_p,
        )
        p_hat[0] += r00 * d_p[0] + r01 * d_p[1] + r02 * d_p[2] + h * k_x * k_l * s0
        p_hat[1] += r10 * d_p[0] + r11 * d_p[1] + r12 * d_p[2] + h * k_x * k_l * s1
        p_hat[2] += r20 * d_p[0] + r21 * d_p[1] + r22 * d_p[2] + h * k_x * k_l * s2
        for a in range(3):
            for b in range(3):
                r_new[a, b] = r_hat[a, 0] * d_r[0, b] + r_hat[a, 1] * d_r[1, b] + r_hat[a, 2] * d_r[2, b]
        r_hat[:, :] = r_new
        if nd > 0:
            se3_exp_into(h * k_x * c0, h * k_x * c1, h * k_x * c2, 0.0, 0.0, 0.0, r_c, zero)
            rotate_estimate(r_c, r_hat, p_hat, lm, adapt)
            if adapt:
                turn_frame(r_c, p_hat, f_r, f_p)
                f_stat[0] += h
        counter[0] += 1
        if counter[0] % REORTHO_EVERY == 0:
            r_hat[:, :] = project_so3(r_hat)
            f_r[:, :] = project_so3(f_r)
        # Predict the base measurements over the sub-step with the frozen-bias odometry.
        se3_exp_into(
            h * (omega_m[0] - b_pred[0]),
            h * (omega_m[1] - b_pred[1]),
            h * (omega_m[2] - b_pred[2]),
            h * (vel_m[0] - b_pred[3]),
            h * (vel_m[1] - b_pred[4]),
            h * (vel_m[2] - b_pred[5]),
            d_r,
            d_p,
        )
        predict_points(y, nvis, d_r, d_p)
        predict_points(ups, nd, d_r, zero)
    return m


@njit(cache=True)
def _odometry(t0, t1, iv, vel_t, omega, vel, om_m, v_m, b_pred, r_acc, p_acc):
    """Body motion ``(r_acc, p_acc)`` from ``t0`` to ``t1`` by the held sample and samples ``iv...`` before ``t1``."""
    r_acc[:, :] = np.eye(3)
    p_acc[:] = 0.0
    d_r = np.empty((3, 3))
    d_p = np.empty(3)
    r_new = np.empty((3, 3))
    o0, o1, o2 = om_m[0] - b_pred[0], om_m[1] - b_pred[1], om_m[2] - b_pred[2]
    v0, v1, v2 = v_m[0] - b_pred[3], v_m[1] - b_pred[4], v_m[2] - b_pred[5]
    t = t0
    k = iv
    while t < t1:
        load = k < vel_t.shape[0] and vel_t[k] < t1
        t_end = vel_t[k] if load else t1
        seg = t_end - t
        if seg > 0.0:
            se3_exp_into(seg * o0, seg * o1, seg * o2, seg * v0, seg * v1, seg * v2, d_r, d_p)
            for a in range(3):
                p_acc[a] += r_acc[a, 0] * d_p[0] + r_acc[a, 1] * d_p[1] + r_acc[a, 2] * d_p[2]
            for a in range(3):
                for b in range(3):
                    r_new[a, b] = r_acc[a, 0] * d_r[0, b] + r_acc[a, 1] * d_r[1, b] + r_acc[a, 2] * d_r[2, b]
            r_acc[:, :] = r_new
        if load:
            o0, o1, o2 = omega[k, 0] - b_pred[0], omega[k, 1] - b_pred[1], omega[k, 2] - b_pred[2]
            v0, v1, v2 = vel[k, 0] - b_pred[3], vel[k, 1] - b_pred[4], vel[k, 2] - b_pred[5]
            k += 1
        t = t_end


#: Kernel scalars kept between stretches: ``fs = [t, meas_t, t_lm, rate_lm, t_dir, rate_dir]``,
#: ``ns = [iv, jf, nvis, started, substeps]``.
_T, _MEAS_T, _T_LM, _RATE_LM, _T_DIR, _RATE_DIR = 0, 1, 2, 3, 4, 5
_IV, _JF, _NVIS, _STARTED, _SUBSTEPS = 0, 1, 2, 3, 4


@njit(cache=True, nogil=True)
def _advance(
    vel_t,
    omega,
    vel,
    dir_ref,
    dir_body,
    dir_rho,
    dir_gscale,
    make_cross,
    det_t,
    det_offsets,
    det_idx,
    det_y,
    lm,
    lm_init,
    k_l,
    k_x,
    gamma_w,
    gamma_v,
    cand,
    delta,
    min_landmarks_bias,
    max_meas_age,
    out_every,
    iv_stop,
    budget,
    r_hat,
    p_hat,
    b_om,
    b_v,
    b_pred,
    r_acc,
    p_acc,
    y,
    y_d,
    vis_idx,
    ups,
    ups_d,
    ups_next,
    rho,
    rho_next,
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
    jump_k,
    jump_q,
    jump_phi,
):
    """The event loop of :func:`run_kernel` from the state in the arrays, until the next event is velocity
    sample ``iv_stop`` or ``budget`` work units are spent; stores the state back and returns ``(rows
    recorded, jumps recorded)``. With ``map_frame`` the rows, tracks and innovations are written in the map
    frame."""
    n_vel = vel_t.shape[0]
    n_frames = det_t.shape[0]
    nd = dir_ref.shape[0]
    t, meas_t = fs[_T], fs[_MEAS_T]
    t_lm, rate_lm, t_dir, rate_dir = fs[_T_LM], fs[_RATE_LM], fs[_T_DIR], fs[_RATE_DIR]
    iv, jf, nvis, started, substeps = ns[_IV], ns[_JF], ns[_NVIS], ns[_STARTED] != 0, ns[_SUBSTEPS]
    n_jumps = 0
    o = 0
    work = 0
    corotated = lm.shape[0] if nd > 0 else 0  # landmarks each direction sub-step rotates
    while (iv < n_vel or jf < n_frames) and work < budget:
        is_frame = jf < n_frames and (iv >= n_vel or det_t[jf] < vel_t[iv])
        if not is_frame and iv >= iv_stop:
            break
        t_next = det_t[jf] if is_frame else vel_t[iv]
        work += 1
        if started and t_next > t:
            if t - meas_t > max_meas_age:
                nvis = 0
            n_sub = _flow(
                t_next - t,
                (t - t_lm) * rate_lm,
                rate_lm,
                (t - t_dir) * rate_dir,
                rate_dir,
                om_m,
                v_m,
                y,
                y_d,
                nvis,
                vis_idx,
                ups,
                ups_d,
                rho,
                dir_ref,
                nd,
                r_hat,
                p_hat,
                lm,
                b_om,
                b_v,
                b_pred,
                k_l,
                k_x,
                gamma_w,
                gamma_v,
                min_landmarks_bias,
                counter,
                f_r,
                f_p,
                f_stat,
            )
            substeps += n_sub
            work += n_sub * (nvis + 1 + corotated)
            count_capped(n_sub, iv, ns)
            t = t_next
        if is_frame:
            a = det_offsets[jf]
            b = det_offsets[jf + 1]
            nvis = b - a
            load_frame(a, nvis, det_idx, det_y, r_hat, p_hat, lm, lm_init, vis_idx, y, innov, trk_p, a - det_base)
            if map_frame:
                frame_rows(f_r, f_p, trk_p, innov, a - det_base, nvis)
            y_d[:nvis, :] = 0.0
            b_pred[:3] = b_om
            b_pred[3:] = b_v
            t_lm, rate_lm = t_next, 0.0
            if started and jf + 1 < n_frames and 0.0 < det_t[jf + 1] - t_next <= max_meas_age:
                rate_lm = 1.0 / (det_t[jf + 1] - t_next)
                _odometry(t_next, det_t[jf + 1], iv, vel_t, omega, vel, om_m, v_m, b_pred, r_acc, p_acc)
                for j in range(nvis):
                    for m in range(det_offsets[jf + 1], det_offsets[jf + 2]):
                        if det_idx[m] == vis_idx[j]:
                            for c in range(3):
                                y_d[j, c] = det_y[m, c] - (
                                    r_acc[0, c] * (y[j, 0] - p_acc[0])
                                    + r_acc[1, c] * (y[j, 1] - p_acc[1])
                                    + r_acc[2, c] * (y[j, 2] - p_acc[2])
                                )
            meas_t = t_next
            jf += 1
        else:
            om_m[:] = omega[iv]
            v_m[:] = vel[iv]
            if nvis == 0:
                b_pred[:3] = b_om
                b_pred[3:] = b_v
            t_dir, rate_dir = t_next, 0.0
            ups_d[:, :] = 0.0
            if nd > 0:
                load_directions(dir_body[iv], dir_rho[iv], dir_gscale, make_cross, om_m, v_m, b_om, b_v, ups, rho)
                if iv + 1 < n_vel and vel_t[iv + 1] > t_next:
                    rate_dir = 1.0 / (vel_t[iv + 1] - t_next)
                    load_directions(
                        dir_body[iv + 1],
                        dir_rho[iv + 1],
                        dir_gscale,
                        make_cross,
                        omega[iv + 1],
                        vel[iv + 1],
                        b_om,
                        b_v,
                        ups_next,
                        rho_next,
                    )
                    _odometry(t_next, vel_t[iv + 1], iv + 1, vel_t, omega, vel, om_m, v_m, b_pred, r_acc, p_acc)
                    for j in range(nd):
                        if rho[j] > 0.0 and rho_next[j] > 0.0:
                            for c in range(3):
                                ups_d[j, c] = ups_next[j, c] - (
                                    r_acc[0, c] * ups[j, 0] + r_acc[1, c] * ups[j, 1] + r_acc[2, c] * ups[j, 2]
                                )
            if not started:
                started = True
                t = t_next
            frame_sample(f_r, f_sum, f_stat, settle_s)
            if cand.shape[0] > 0:
                q, phi, phi_q = best_jump(r_hat, ups, rho, dir_ref, nd, cand)
                if q >= 0 and phi - phi_q >= delta:
                    turn = cand[q].T.copy()
                    rotate_estimate(turn, r_hat, p_hat, lm, True)
                    turn_frame(turn, p_hat, f_r, f_p)
                    jump_k[n_jumps] = iv
                    jump_q[n_jumps] = q
                    jump_phi[n_jumps, 0] = phi
                    jump_phi[n_jumps, 1] = phi_q
                    n_jumps += 1
            o = record_step(
                o, iv, n_vel, out_every, map_frame, f_r, f_p, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b
            )
            iv += 1
    fs[_T], fs[_MEAS_T] = t, meas_t
    fs[_T_LM], fs[_RATE_LM], fs[_T_DIR], fs[_RATE_DIR] = t_lm, rate_lm, t_dir, rate_dir
    ns[_IV], ns[_JF], ns[_NVIS], ns[_STARTED], ns[_SUBSTEPS] = iv, jf, nvis, 1 if started else 0, substeps
    return o, n_jumps


class _State(KernelState):
    """The flow's state: the common one, the prediction bias, the look-ahead corrections of the visible
    measurements and of the directions, and the accumulated flow (four more clocks)."""

    def __init__(
        self, n_max: int, nd: int, r0: np.ndarray, p0: np.ndarray, b_om0: np.ndarray, b_v0: np.ndarray
    ) -> None:
        super().__init__(n_max, r0, p0, b_om0, b_v0, n_clocks=6)
        self.b_pred = np.concatenate([self.b_om, self.b_v])
        self.r_acc = np.empty((3, 3))
        self.p_acc = np.empty(3)
        self.y_d = np.zeros((max(n_max, 1), 3))
        self.ups = np.zeros((max(nd, 1), 3))
        self.ups_d = np.zeros((max(nd, 1), 3))
        self.ups_next = np.zeros((max(nd, 1), 3))
        self.rho = np.zeros(max(nd, 1))
        self.rho_next = np.zeros(max(nd, 1))

    def restart(self, t: float) -> None:
        """A new segment: also no look-ahead from before the gap."""
        super().restart(t)
        self.fs[_RATE_LM] = self.fs[_RATE_DIR] = 0.0

    def arrays(self) -> tuple:
        return (
            self.r_hat,
            self.p_hat,
            self.b_om,
            self.b_v,
            self.b_pred,
            self.r_acc,
            self.p_acc,
            self.y,
            self.y_d,
            self.vis_idx,
            self.ups,
            self.ups_d,
            self.ups_next,
            self.rho,
            self.rho_next,
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


def _jump_arrays(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Room for a jump at each of ``n`` velocity samples (at most one per sample)."""
    return np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty((n, 2))


def run_kernel(
    vel_t,
    omega,
    vel,
    dir_ref,
    dir_body,
    dir_rho,
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
    k_l,
    k_x,
    gamma_w,
    gamma_v,
    cand,
    delta,
    min_landmarks_bias,
    max_meas_age,
    out_every,
    map_frame=False,
):
    """Run D (``dir_ref`` with 0 rows, ``cand`` with 0 rows) or E over an ordered event stream.

    Times are float64 seconds. Velocity samples ``k`` carry ``Ω_m, V_m`` and the directions as made by
    :func:`pipeline.directions.direction_arrays`: inertial ``dir_ref (J, 3)``, body ``dir_body[k]
    (J0, 3)``, weights ``ρ_j = dir_rho[k] (J0,)``, ``dir_gscale``/``make_cross`` for the bias-corrected
    gravity direction and the cross-product third direction (built per sample by ``load_directions``).
    At each sample, with that sample's directions, the switching variable is evaluated and at most one
    jump ``R_q*ᵀ`` applied when ``μ ≥ delta`` (docs/observers.md §8.2). Landmarks with ``lm_init`` False are
    initialised at first sighting as ``p̂ + R̂ y`` (docs/observers.md §3.2); only visible landmarks enter the
    sums.

    Between two measurements of the same landmark (frames at most ``max_meas_age`` apart) the measurement
    is the odometry prediction from the first plus the share ``s = (t − t_f)/T`` of its mismatch with the
    second; directions likewise between velocity samples. Pure prediction (algorithm A) makes ``e_i``
    blind to the bias estimate until the next frame: that delay, not the Euler step, is what destabilises
    the bias loop at ``ω_n T ≳ 0.2`` (docs/observers.md §6.2). With the look-ahead the flow sees the
    measurements the continuous-time observer would, so it is stable for any gains; the estimate at ``t`` uses data
    up to one frame after ``t``.

    Outputs and ``lm`` are in the working (inertial) frame, the map as turned by the law; with ``map_frame``
    in the map frame, as :class:`Flow` writes them (:mod:`pipeline.observers.shared_steps`).

    Returns ``(out_k, out_r, out_p, out_b, trk_p, innov, substeps, jump_k, jump_q, jump_phi)``: as
    algorithm A's kernel, plus per jump the velocity-sample index, candidate and ``(Φ before, Φ after)``.
    """
    n_vel = vel_t.shape[0]
    state = _State(max_per_frame(det_offsets), dir_ref.shape[0], r0, p0, b_om0, b_v0)
    out = Outputs.whole_log(n_vel, out_every, det_y.shape[0])
    jump_k, jump_q, jump_phi = _jump_arrays(n_vel)
    o, n_jumps = _advance(
        vel_t,
        omega,
        vel,
        dir_ref,
        dir_body,
        dir_rho,
        dir_gscale,
        make_cross,
        det_t,
        det_offsets,
        det_idx,
        det_y,
        lm,
        lm_init,
        k_l,
        k_x,
        gamma_w,
        gamma_v,
        cand,
        delta,
        min_landmarks_bias,
        max_meas_age,
        out_every,
        n_vel,
        np.iinfo(np.int64).max,
        *state.arrays(),
        map_frame,
        np.inf,
        *out.arrays(),
        jump_k,
        jump_q,
        jump_phi,
    )
    if map_frame:
        lm[:, :3] = (lm[:, :3] - state.f_p) @ state.f_r
    return (
        *out.recorded(o),
        int(state.ns[_SUBSTEPS]),
        jump_k[:n_jumps],
        jump_q[:n_jumps],
        jump_phi[:n_jumps],
    )


class Flow(Stepper):
    """The D/E flow on an aligned stream, a stretch of samples at a time; the jumps of each stretch go to
    its ``extra_tables["jumps"]`` when ``jumps`` is set (algorithm E)."""

    def __init__(
        self,
        stream,
        gains: dict[str, float],
        options: ObserverOptions,
        directions=None,
        r0=None,
        cand: np.ndarray | None = None,
        delta: float = np.inf,
        jumps: bool = False,
    ) -> None:
        super().__init__(stream, options)
        n = stream.vel_t_ns.shape[0]
        if directions is None:
            directions = (np.zeros((0, 3)), np.zeros((n, 0, 3)), np.zeros((n, 0)), np.zeros(0), False)
        self.directions = directions
        self.cand = np.zeros((0, 3, 3)) if cand is None else np.ascontiguousarray(cand, dtype=np.float64)
        self.delta = float(delta)
        self.gains = (gains["k_l"], gains["k_x"], gains["gamma_w"], gains["gamma_v"])
        self.state = _State(
            self.n_max, directions[0].shape[0], np.eye(3) if r0 is None else r0, np.zeros(3), np.zeros(3), np.zeros(3)
        )
        # the direction loop's rate is k_X Σρ / 2 (see _substeps); its settling time as algorithm C's
        rate = 0.5 * gains["k_x"] * float(np.max(directions[2].sum(axis=1), initial=0.0))
        self.keeps_map_frame = directions[0].shape[0] > 0 and rate > 0.0
        self.settle_s = FRAME_SETTLE / rate if self.keeps_map_frame else np.inf
        self.jumps = jumps
        self._jumps: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # per kernel call of a stretch

    def _kernel(self, iv_stop: int, out: Outputs, budget: int) -> int:
        s, o = self.stream, self.options
        jump_k, jump_q, jump_phi = _jump_arrays(max(iv_stop - int(self.state.ns[_IV]), 0))
        rows, n_jumps = _advance(
            self.vel_t,
            s.omega,
            s.velocity,
            *self.directions,
            self.det_t,
            s.det_offsets,
            s.det_idx,
            s.det_y,
            self.lm,
            self.lm_init,
            *self.gains,
            self.cand,
            self.delta,
            o.min_landmarks_bias,
            o.max_meas_age,
            o.out_every,
            iv_stop,
            budget,
            *self.state.arrays(),
            True,
            self.settle_s,
            *out.arrays(),
            jump_k,
            jump_q,
            jump_phi,
        )
        self._jumps.append((jump_k[:n_jumps], jump_q[:n_jumps], jump_phi[:n_jumps]))
        self.stats["substeps"] = int(self.state.ns[_SUBSTEPS])
        if self.jumps:
            self.stats["jumps"] = self.stats.get("jumps", 0) + n_jumps
        return rows

    def _extra(self) -> dict[str, dict[str, np.ndarray]]:
        parts, self._jumps = self._jumps, []
        if not self.jumps:
            return {}
        jk, jq, jphi = (np.concatenate([p[i] for p in parts]) if parts else _jump_arrays(0)[i] for i in range(3))
        return {
            "jumps": {
                "t_ns": self.stream.vel_t_ns[jk],
                "candidate": jq.astype(np.int64),
                "potential_before": jphi[:, 0],
                "potential_after": jphi[:, 1],
            }
        }


#: Gains of the shared flow: the set of docs/observers.md §12.4, which converges on the circle and is also the best
#: of those tried on the noisy sample logs (larger gamma_w stays stable but puts more noise in the biases).
FLOW_GAINS = (
    GainSpec("k_l", 1.0, "landmark innovation weight k_i (all landmarks) [reference: 1]", (0.1, 10.0)),
    GainSpec("k_x", 1.0, "inertial correction gain k_X [reference: 1]", (0.1, 10.0)),
    GainSpec("gamma_w", 0.05, "gyro-bias adaptation gain gamma_omega [reference: 0.05]", (0.001, 2.0)),
    GainSpec("gamma_v", 0.5, "velocity-bias adaptation gain gamma_v [reference: 0.5]", (0.01, 10.0)),
)

SPEC = ObserverSpec(
    name="wang-tayebi",
    algorithm="D",
    paper="Wang, Tayebi: Geometric Nonlinear Observer Design for SLAM on a Matrix Lie Group (CDC 2018; the "
    "smooth baseline of Hashemi, Mattila: A Global Asymptotic Convergent Observer for SLAM)",
    summary="smooth SLAM observer, inertial-frame innovation; attitude corrected only through the gyro bias",
    gains=FLOW_GAINS,
    start=Flow,
)
