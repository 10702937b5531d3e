"""Compiled steps the landmark observers' kernels share (docs/observers.md §3.2 for the frame handling).

- :func:`load_frame`: a frame replaces the visible set: its landmark indices and body-frame measurements
  become the observer's ``vis_idx``/``y``; a landmark seen for the first time is placed at ``P̂ + R̂y`` so that
  its innovation starts at zero; every detection's innovation ``p̂_i − R̂y_i − P̂`` and the landmark estimate
  it was compared with are recorded.
- :func:`landmark_sums`: the sums ``Σ[y]x R̂ᵀe`` and ``Σ R̂ᵀe`` over the visible landmarks and their landmark
  step (algorithms A and B; A's gain ψ(e) adapts, B's is constant).
- :func:`predict_points`: held body-frame measurements (or directions) carried over a sub-step of odometry.
- :func:`record_row`: one output row of the estimate.
- :func:`turn_frame`, :func:`record_row_framed`, :func:`frame_rows`, :func:`frame_sample`, and
  :func:`record_step` (a sample's row when it is due, in either frame): the map frame of the
  observers whose law turns the whole estimate rigidly (algorithms C and E: IMU co-rotation, jumps). Such a turn
  re-frames the
  estimate without adding information about it; the kernel keeps it in ``F`` (map frame -> working frame)
  and writes poses, tracks and innovations in the map frame, where a landmark stays where it was last seen.
- :func:`substep_count` / :func:`count_capped`: the sub-steps of one interval, at most ``MAX_SUBSTEPS``, and
  the count of intervals that hit that cap.
- :func:`landmark_weight`: how much of its landmark step a landmark takes: 1, or, when a known map gives ``lm``
  a fourth column, that column (0 for a landmark fixed by the map, which is then never updated).

All are written with scalars (no temporaries): they run once per sub-step or event.

- :func:`gap_factor` and :func:`gap_levels`: the velocity noise's variance across a gap in the samples, one
  definition for riekf's propagation and batch's preintegration (both take the twist linear between samples);
  across a bridged gap (the linear velocity alone silent, longer than ``limits.max_gap``) at least
  :func:`motion_factor`'s: the motion's spread over the whole gap.
"""

from __future__ import annotations

import math

import numpy as np
from slamobs.pipeline.kernel_cache import njit

#: Most sub-steps one interval between two events is cut into. Logs need a few to a few hundred; an interval
#: that asks for more (gains far too stiff for the sample rate, an absurd innovation) is integrated with this
#: many and counted (``ns[CAPPED]``, the first at velocity sample ``ns[CAP_IV]``), so the run reports it
#: instead of spinning for hours.
MAX_SUBSTEPS = 10_000
#: Slots of a kernel's integer state ``ns`` (see ``base.KernelState``) after its own five.
CAPPED, CAP_IV = 5, 6
#: Time constants of an observer's attitude loop after which its map frame's orientation enters the mean
#: (:func:`frame_sample`): the start from the first direction sample is over by then.
FRAME_SETTLE = 5.0
#: An interval between velocity samples longer than this many median intervals is a gap (:func:`gap_factor`).
GAP_INTERVALS = 3.0


@njit(cache=True)
def gap_factor(span, interval):
    """The factor on a white noise density's variance over one interval of ``span`` s between two samples, the
    stream's median interval being ``interval`` (0: no factor). The twist between two samples is their linear
    interpolation: its integral's error is ``span (n_0 + n_1) / 2`` with each sample's noise of variance
    ``q² / interval``, so variance ``q² span² / (2 interval)``: ``span / (2 interval)`` times the white density's
    ``q² span``. At the median interval the density's variance is the larger (neighbouring intervals share their
    samples: over many the sums agree); over a gap (more than ``GAP_INTERVALS`` intervals) the two samples' noise is
    all there is. Public: riekf's propagation and batch's preintegration call it, tests/test_riekf.py checks it."""
    if interval > 0.0 and span > GAP_INTERVALS * interval:
        return span / (2.0 * interval)
    return 1.0


def gap_levels(stream, vel_t, held, velocity_density=None, gyro_density=None):
    """What :func:`gap_factor` needs for the gyro and the linear velocity of ``stream`` (an ``AlignedStream``,
    ``vel_t`` its time base in s): the median interval of each (0 where the stream is held, ``noise.held``: a held
    command's interval is the command held, not samples missing), and per time-base sample ``i`` the factor of the
    linear velocity's own gap that the interval from sample ``i - 1`` to ``i`` lies in
    (``AlignedStream.velocity_gaps``: an odometry on a topic of its own, interpolated onto the gyro's stamps, whose
    gap the time base does not show), else 1. Across a bridged gap (``AlignedStream.bridged_gaps``: longer than
    ``limits.max_gap``, the gyro recording through) the factor is at least :func:`motion_factor`'s, given the
    velocity's white density ``velocity_density`` (m/s/√Hz per axis). Last, per sample the gyro's factor over the
    stretches a saturating gyro held its range (``AlignedStream.gyro_clipped``; 1 elsewhere, and everywhere without
    ``gyro_density``): :func:`clip_factor`. Public: riekf and batch's smoother take their gaps from it."""
    interval = float(np.median(np.diff(vel_t))) if vel_t.shape[0] > 2 else 0.0
    t = stream.vel_t_ns
    out = np.ones(t.shape[0])
    om_out = clip_factor(stream, gyro_density) if "gyro" not in held else np.ones(t.shape[0])
    gaps, period = stream.velocity_gaps, stream.velocity_period_ns * 1e-9
    levels = (0.0 if "gyro" in held else interval, 0.0 if "velocity" in held else interval)
    if "velocity" in held or gaps.shape[0] == 0 or t.shape[0] < 2:
        return *levels, out, om_out
    mid = t[:-1] + (t[1:] - t[:-1]) // 2
    k = np.searchsorted(gaps[:, 0], mid, side="right") - 1
    inside = (k >= 0) & (mid < gaps[np.clip(k, 0, None), 1])
    factors = np.array([gap_factor((b - a) * 1e-9, period) for a, b in gaps])
    if velocity_density is not None and stream.bridged_gaps.shape[0]:
        bridged = (gaps[:, None, :] == stream.bridged_gaps[None, :, :]).all(axis=2).any(axis=1)
        spread = motion_spread(stream.velocity)
        for g in np.flatnonzero(bridged):
            span = (gaps[g, 1] - gaps[g, 0]) * 1e-9
            factors[g] = max(factors[g], motion_factor(span, spread, velocity_density))
    out[1:][inside] = factors[k[inside]]
    return *levels, out, om_out


def clip_factor(stream, gyro_density) -> np.ndarray:
    """Per time-base sample ``i``, the factor on the gyro's white variance over the interval from sample ``i - 1``
    to ``i`` where either end lies in a stretch a saturating gyro held its range (``AlignedStream.gyro_clipped``),
    1 elsewhere: the rate the alignment filled there is off by up to the stretch's ``AlignedStream.gyro_excess``
    ``e`` (a share of the fit's peak beyond the range and of the gyro's spread: ``alignment.CLIP_FIT_SHARE``), the
    same sign over the whole stretch: a rotation error of ``e × span`` over its ``span`` s (one interval added),
    :func:`motion_factor` with that spread on every axis against the gyro's density ``gyro_density`` (rad/s/√Hz per
    axis)."""
    t, clipped = stream.vel_t_ns, getattr(stream, "gyro_clipped", None)
    out = np.ones(t.shape[0])
    if gyro_density is None or clipped is None or clipped.shape[0] == 0 or t.shape[0] < 2:
        return out
    # the interval ending at sample i (t[i-1], t[i]) touches stretch [a, b] when t[i] >= a and t[i-1] <= b
    first = np.searchsorted(t, clipped[:, 0], side="left")  # the first sample at or after a: the interval ending there
    last = np.searchsorted(t, clipped[:, 1], side="right")  # the first sample after b: the interval starting at b
    step = float(np.median(np.diff(t))) * 1e-9
    for a, b, (ta, tb), e in zip(first, last, clipped, stream.gyro_excess, strict=True):
        lo, hi = max(int(a), 1), min(int(b) + 1, t.shape[0])
        if hi > lo:
            f = motion_factor((tb - ta) * 1e-9 + step, np.full(3, e), gyro_density)
            out[lo:hi] = np.maximum(out[lo:hi], f)
    return out


def motion_spread(velocity: np.ndarray) -> np.ndarray:
    """The linear velocity's spread about its mean per axis (m/s, its samples' standard deviation): how far the
    velocity across a bridged gap may be from the straight line between its two ends."""
    return np.std(velocity, axis=0) if velocity.shape[0] > 1 else np.zeros(3)


def motion_factor(span, spread, velocity_density) -> float:
    """The factor on the velocity's white variance over a bridged gap of ``span`` s (the linear velocity silent,
    the gyro recording): its interpolated velocity is off by up to the motion's ``spread`` (m/s per axis) for the
    whole gap, a position error of ``spread × span``; spread over the gap's ``span`` s as a density, that is
    ``spread² span`` against the white ``q²``: the largest ratio over the axes."""
    q2 = np.square(np.asarray(velocity_density, np.float64))
    ratio = np.square(spread) * span / np.where(q2 > 0, q2, np.inf)
    return float(np.max(ratio)) if ratio.size else 1.0


@njit(cache=True, inline="always")
def substep_count(dt, lam, step_ratio):
    """Sub-steps for an interval ``dt`` at loop rate ``lam``: ``ceil(dt lam / step_ratio)``, 1 to ``MAX_SUBSTEPS``
    (a NaN or infinite rate gets the cap)."""
    x = dt * lam / step_ratio
    if not x < MAX_SUBSTEPS:
        return MAX_SUBSTEPS
    n = math.ceil(x)  # an int64 in compiled code: no int() and max() of numba's to compile for it
    return n if n > 1 else 1


@njit(cache=True, inline="always")
def count_capped(m, iv, ns):
    """Count an interval integrated with ``m`` sub-steps if that was the cap (``iv``: the next velocity sample)."""
    if m >= MAX_SUBSTEPS:
        ns[CAPPED] += 1
        if ns[CAP_IV] < 0:
            ns[CAP_IV] = iv


@njit(cache=True, inline="always")
def load_frame(a, nvis, det_idx, det_y, r_hat, p_hat, lm, lm_init, vis_idx, y, innov, trk_p, row):
    """Take detections ``a .. a + nvis - 1`` as the visible set; their output rows start at ``row``."""
    for j in range(nvis):
        i = det_idx[a + j]
        vis_idx[j] = i
        for c in range(3):
            y[j, c] = det_y[a + j, c]
        for c in range(3):  # R̂y, written out: no temporary per detection
            ry = r_hat[c, 0] * y[j, 0] + r_hat[c, 1] * y[j, 1] + r_hat[c, 2] * y[j, 2]
            if not lm_init[i]:
                lm[i, c] = p_hat[c] + ry
            innov[row + j, c] = lm[i, c] - ry - p_hat[c]
            trk_p[row + j, c] = lm[i, c]
        lm_init[i] = True


@njit(cache=True, inline="always")
def landmark_weight(lm, i):
    """Update weight of landmark ``i``: the fourth column of ``lm`` if it has one (known map), else 1."""
    if lm.shape[1] > 3:
        return lm[i, 3]
    return 1.0


@njit(cache=True, inline="always")
def landmark_sums(nvis, vis_idx, y, lm, r_hat, p_hat, hkp, adaptive):
    """``(Σ[y_i]x R̂ᵀe_i, Σ R̂ᵀe_i)`` as six scalars over the visible landmarks, with ``e_i = p̂_i − R̂y_i − P̂``
    at the state given, and each landmark stepped ``p̂_i ← p̂_i − g e_i`` in place: ``g = hkp`` (B), or
    with ``adaptive`` the closed-form ``h ψ(e_i) = hkp (1 + ‖e_i‖²)/4`` capped at 1, never past the measured
    point (A, docs/observers.md §4)."""
    r00, r01, r02 = r_hat[0, 0], r_hat[0, 1], r_hat[0, 2]
    r10, r11, r12 = r_hat[1, 0], r_hat[1, 1], r_hat[1, 2]
    r20, r21, r22 = r_hat[2, 0], r_hat[2, 1], r_hat[2, 2]
    w0 = w1 = w2 = 0.0
    u0 = u1 = u2 = 0.0
    for j in range(nvis):
        i = vis_idx[j]
        y0, y1, y2 = y[j, 0], y[j, 1], y[j, 2]
        e0 = lm[i, 0] - (r00 * y0 + r01 * y1 + r02 * y2) - p_hat[0]
        e1 = lm[i, 1] - (r10 * y0 + r11 * y1 + r12 * y2) - p_hat[1]
        e2 = lm[i, 2] - (r20 * y0 + r21 * y1 + r22 * y2) - p_hat[2]
        # R̂ᵀe and [y]x R̂ᵀe = y x (R̂ᵀe)
        q0 = r00 * e0 + r10 * e1 + r20 * e2
        q1 = r01 * e0 + r11 * e1 + r21 * e2
        q2 = r02 * e0 + r12 * e1 + r22 * e2
        w0 += y1 * q2 - y2 * q1
        w1 += y2 * q0 - y0 * q2
        w2 += y0 * q1 - y1 * q0
        u0 += q0
        u1 += q1
        u2 += q2
        step = hkp
        if adaptive:
            step = hkp * (1.0 + e0 * e0 + e1 * e1 + e2 * e2) / 4.0
            if step > 1.0:
                step = 1.0
        step *= landmark_weight(lm, i)
        lm[i, 0] -= step * e0
        lm[i, 1] -= step * e1
        lm[i, 2] -= step * e2
    return w0, w1, w2, u0, u1, u2


@njit(cache=True, inline="always")
def predict_points(x, n, d_r, d_p):
    """``x_j ← dRᵀ(x_j − dp)`` for rows ``0 .. n - 1``: body-frame points after the body moved by ``(dR, dp)``
    over a sub-step (directions: ``dp = 0``)."""
    for j in range(n):
        d0 = x[j, 0] - d_p[0]
        d1 = x[j, 1] - d_p[1]
        d2 = x[j, 2] - d_p[2]
        x[j, 0] = d_r[0, 0] * d0 + d_r[1, 0] * d1 + d_r[2, 0] * d2
        x[j, 1] = d_r[0, 1] * d0 + d_r[1, 1] * d1 + d_r[2, 1] * d2
        x[j, 2] = d_r[0, 2] * d0 + d_r[1, 2] * d1 + d_r[2, 2] * d2


@njit(cache=True, inline="always")
def record_row(o, iv, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b):
    """Row ``o`` of the outputs: velocity sample ``iv``, R̂, P̂ and the biases ``[b̂_Ω, b̂_V]``."""
    out_k[o] = iv
    for a in range(3):  # element by element: a slice assignment compiles numba's shape checks and messages
        for b in range(3):
            out_r[o, a, b] = r_hat[a, b]
        out_p[o, a] = p_hat[a]
        out_b[o, a] = b_om[a]
        out_b[o, 3 + a] = b_v[a]


@njit(cache=True, inline="always")
def turn_frame(rot, pivot, f_r, f_p):
    """The whole estimate turned by ``x ↦ pivot + rot (x − pivot)``: the map frame follows, ``F ← turn ∘ F``."""
    d0, d1, d2 = f_p[0] - pivot[0], f_p[1] - pivot[1], f_p[2] - pivot[2]
    for a in range(3):
        f_p[a] = pivot[a] + rot[a, 0] * d0 + rot[a, 1] * d1 + rot[a, 2] * d2
    for b in range(3):
        c0, c1, c2 = f_r[0, b], f_r[1, b], f_r[2, b]
        for a in range(3):
            f_r[a, b] = rot[a, 0] * c0 + rot[a, 1] * c1 + rot[a, 2] * c2


@njit(cache=True, inline="always")
def record_row_framed(o, iv, f_r, f_p, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b):
    """:func:`record_row` of the estimate in the map frame: ``F⁻¹ T̂ = (F_Rᵀ R̂, F_Rᵀ (P̂ − F_p))``."""
    out_k[o] = iv
    for a in range(3):
        out_p[o, a] = (
            f_r[0, a] * (p_hat[0] - f_p[0]) + f_r[1, a] * (p_hat[1] - f_p[1]) + f_r[2, a] * (p_hat[2] - f_p[2])
        )
        for b in range(3):
            out_r[o, a, b] = f_r[0, a] * r_hat[0, b] + f_r[1, a] * r_hat[1, b] + f_r[2, a] * r_hat[2, b]
        out_b[o, a] = b_om[a]
        out_b[o, 3 + a] = b_v[a]


@njit(cache=True, inline="always")
def frame_rows(f_r, f_p, trk_p, innov, row, n):
    """Rows ``row .. row + n − 1`` of the tracks (points) and innovations (vectors) into the map frame."""
    for j in range(row, row + n):
        x0, x1, x2 = trk_p[j, 0] - f_p[0], trk_p[j, 1] - f_p[1], trk_p[j, 2] - f_p[2]
        e0, e1, e2 = innov[j, 0], innov[j, 1], innov[j, 2]
        for a in range(3):
            trk_p[j, a] = f_r[0, a] * x0 + f_r[1, a] * x1 + f_r[2, a] * x2
            innov[j, a] = f_r[0, a] * e0 + f_r[1, a] * e1 + f_r[2, a] * e2


@njit(cache=True, inline="always")
def record_step(o, iv, n_vel, out_every, map_frame, f_r, f_p, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b):
    """Velocity sample ``iv``'s row ``o`` if it is recorded (every ``out_every``-th and the last of ``n_vel``), in
    the map frame when ``map_frame`` (:func:`record_row_framed`, else :func:`record_row`); returns the next row."""
    if iv % out_every == 0 or iv == n_vel - 1:
        if map_frame:
            record_row_framed(o, iv, f_r, f_p, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b)
        else:
            record_row(o, iv, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b)
        o += 1
    return o


@njit(cache=True, inline="always")
def frame_sample(f_r, f_sum, f_stat, settle_s):
    """Add the map frame's orientation to the running sum once it has been estimated for ``settle_s`` seconds
    (``f_stat[0]``, advanced by the kernel while it turns the frame): the first seconds are the transient
    from the initial attitude."""
    if f_stat[0] >= settle_s:
        for a in range(3):
            for b in range(3):
                f_sum[a, b] += f_r[a, b]
        f_stat[1] += 1.0


@njit(cache=True)
def twist_at(vel_t, omega, vel, s, tau, bias):
    """Bias-corrected twist ``(ω, v)`` at time ``tau`` inside sample interval ``s``: linear between samples ``s``
    and ``s + 1`` (an offline estimator knows the next sample; holding the current one instead lags the motion
    by half a sample period, a drift of ``acceleration × period / 2`` that on a figure 8 at 200 Hz is as large
    as the odometry noise over a few seconds), held after the last sample."""
    f = 0.0
    if s + 1 < vel_t.shape[0]:
        span = vel_t[s + 1] - vel_t[s]
        if span > 0.0:
            f = min(1.0, max(0.0, (tau - vel_t[s]) / span))
    g = 1.0 - f
    s1 = min(s + 1, vel_t.shape[0] - 1)
    return (
        g * omega[s, 0] + f * omega[s1, 0] - bias[0],
        g * omega[s, 1] + f * omega[s1, 1] - bias[1],
        g * omega[s, 2] + f * omega[s1, 2] - bias[2],
        g * vel[s, 0] + f * vel[s1, 0] - bias[3],
        g * vel[s, 1] + f * vel[s1, 1] - bias[4],
        g * vel[s, 2] + f * vel[s1, 2] - bias[5],
    )
