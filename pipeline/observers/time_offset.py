"""The time offset between the detection stream and the velocity streams, estimated from the data (the reference
estimators riekf and batch use :func:`estimate`, the observers :func:`decide`, its decision alone;
docs/observers.md, "Time offset").

Two detections of one landmark ``PAIR_SPAN_S`` to ``PAIR_MAX_S`` apart see the same point, and the odometry says
how the body moved between them. With the detection stamps moved by ``δ`` onto the velocity clock, the second
detection carried back through the odometry's motion between the two (shifted) times lands on the first at the
true offset; a wrong one shows as the change of the body's motion between the two ends, times ``δ`` (hence
pairs a second or more apart: over a short span a shift moves both ends alike). Each pair's residual is taken
in the body frame of its first detection, so only its own interval enters (not the drift over the log), and
the odometry's bias, which would otherwise pass for an offset, is fitted away at every shift (the residuals
are linear in a small bias change; their Jacobian is computed once). The estimate minimises the trimmed mean
of the squared residuals over a grid of shifts (``MAX_OFFSET_S`` either side, ``COARSE_S`` steps, then
``FINE_S`` steps around the best); its standard error comes from the cost's curvature there, except where no shift
fits ``MIN_GAIN`` times better than none while that error would put the best more than ``MIN_SIGMAS`` of them off
zero: then none is given, but the shifts not told from the best (:func:`_indistinct`).

It is applied (the detection stamps moved by it before the estimator runs) only when it is reliable: at least
``MIN_PAIRS`` pairs, the minimum inside the grid, more than ``MIN_SIGMAS`` standard errors and at least
``MIN_APPLY_S`` away from zero, not inside the search's own lag (:func:`hold_lag`: a positive shift no more than
half the velocity samples' median interval, plus ``MIN_SIGMAS`` standard errors), the cost at zero shift and at that
lag each at least ``MIN_GAIN`` times the minimum (:func:`_gain_over_lag`), and the two halves of the log (pairs
split at the median time) giving estimates within ``HALVES_SIGMAS`` combined standard errors of each other (a
constant offset shows in both). Otherwise it is only reported.
"""

from __future__ import annotations

import itertools
import threading
from dataclasses import replace

import numpy as np
from numba import types

from slamobs.pipeline.alignment import MEAN_STAMPS, held_stamps
from slamobs.pipeline.blocks import id_time_order
from slamobs.pipeline.cholesky import cholesky_lower
from slamobs.pipeline.cores import cores, lower_this_thread
from slamobs.pipeline.kernel_cache import njit, subroutine
from slamobs.pipeline.lie import (
    integrate_body_twists,
    integrate_body_twists_at,
    integrate_body_twists_at_columns,
    integrate_body_twists_at_rotation_columns,
    se3_exp_into,
    so3_exp,
    so3_exps,
    so3_jacobians_into,
    so3_log,
)
from slamobs.pipeline.observers.accel_scale import DETECTION_SCALES, scale_cause, velocity_scale_by_accel
from slamobs.pipeline.noise import LEVEL_CHOICE_P, chi2_quantile

PAIR_SPAN_S = 1.0
PAIR_MAX_S = 2.0
MAX_OFFSET_S = 0.5
COARSE_S = 0.02
FINE_S = 0.001
TRIM = 0.9
MIN_PAIRS = 30
MAX_PAIRS = 2000
#: Stretches of the log a log of more than ``MAX_PAIRS`` pairs gives them from (:func:`_in_blocks`).
BLOCKS = 10
MIN_SIGMAS = 5.0
MIN_APPLY_S = 0.005
MIN_GAIN = 1.2
HALVES_SIGMAS = 3.0
#: Bias step of the residuals' numerical Jacobian (rad/s, m/s).
BIAS_STEP = 1e-4


def _sample_steps(stream, omega: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, tuple]:
    """The velocity samples' times and the dead-reckoning steps between them (twists, lengths), nothing
    integrated across a segment gap."""
    t = stream.seconds(stream.vel_t_ns)
    dt = np.diff(t)
    gap = stream.segment_starts - 1
    if gap.shape[0] == 0:  # one segment: the twists themselves (no copy of a long log's 17 MB each)
        return t, (omega[:-1], vel[:-1], dt)
    omega, vel = omega[:-1].copy(), vel[:-1].copy()
    omega[gap], vel[gap] = 0.0, 0.0
    return t, (omega, vel, dt)


def _pairs(stream, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Detection indices (a, b): each detection and the first detection of the same landmark at least
    ``PAIR_SPAN_S`` later, when that one is within ``PAIR_MAX_S`` (``t``: each detection's time); on a log of more
    than ``MAX_PAIRS``, those :func:`_in_blocks` chooses."""
    idx = stream.det_idx
    order = id_time_order(idx, t)
    key = stream.det_idx[order].astype(np.float64) * (2.0 * (t.max() - t.min() + PAIR_MAX_S) + 1.0) + t[order]
    a, b = _partners(order, key, idx, t)
    return _in_blocks(t, a, b) if a.shape[0] > MAX_PAIRS else (a, b)


def _in_blocks(t: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``MAX_PAIRS`` of the pairs ``(a, b)`` (``t``: each detection's time), evenly over those whose first detection
    is in one of ``BLOCKS`` stretches of the log spread evenly over it (so both halves alike), each
    ``WORLD_TWIST_WINDOW_S`` long (one window of :func:`world_twist`, which needs a heading that turns) or long
    enough that together they hold twice ``MAX_PAIRS`` at the log's mean rate: the estimate then reads those
    stretches' samples only (:func:`_read_only`), not the whole log's (the hour's 720,000 samples, dead-reckoned
    over and over by the Jacobian and the checks, were 1.1 CPU s). A log shorter than the stretches: evenly over
    all its pairs. In the order given."""
    ta = t[a]
    t0, span = ta.min(), ta.max() - ta.min()
    width = max(WORLD_TWIST_WINDOW_S, 2.0 * MAX_PAIRS * span / (a.shape[0] * BLOCKS))
    if BLOCKS * width < span:
        k = np.minimum(np.floor((ta - t0) * (BLOCKS / span)), BLOCKS - 1)
        inside = np.abs(ta - (t0 + (k + 0.5) * (span / BLOCKS))) < 0.5 * width
        a, b = a[inside], b[inside]
    same = np.linspace(0, a.shape[0] - 1, min(MAX_PAIRS, a.shape[0])).astype(np.int64)
    return a[same], b[same]


def _reach(stream) -> float:
    """The largest shift searched: ``MAX_OFFSET_S`` beyond the seconds the alignment moved the IMU's stamps by onto
    the odometry's clock (``gyro_moved_s``): detections stamped on the IMU's clock need that move too, and a generated
    hand-held rig whose odometry's clock is 0.5 s off had its IMU moved +0.500 s and the detections' +0.503 s held
    back at the search's edge (riekf lost at 14.6 m, its warnings blaming the detections' scale; docs/benchmarks.md,
    "Logs nobody has run yet, round 7")."""
    return MAX_OFFSET_S + abs(float(getattr(stream, "gyro_moved_s", 0.0) or 0.0))


def _read_only(stream, t: np.ndarray, a: np.ndarray, b: np.ndarray):
    """The stream with the velocity samples the pairs ``(a, b)`` read at any shift only (``t``: each detection's
    time; from the sample before a margin ahead of a pair's first detection to the one after the margin past its
    second: the largest shift searched and ``velocity_lag``'s largest lag of the velocity), each run of them a
    segment of its own (the dead reckoning carried across a cut without moving, as across a gap); the stream itself
    when there are no pairs or they read half its samples or more. A pair's residual is in its first detection's
    body frame: only the motion inside it enters, and it is the same (to rounding) dead-reckoned from its run's
    start as from the log's. Its detections are the stream's, all of them."""
    if not a.shape[0]:
        return stream
    t_s = stream.seconds(stream.vel_t_ns)
    n, margin = t_s.shape[0], _reach(stream) + 2 * COARSE_S + VELOCITY_LAG_MAX_S
    lo = np.maximum(np.searchsorted(t_s, t[a] - margin, "right") - 1, 0)
    hi = np.minimum(np.searchsorted(t_s, t[b] + margin, "right") + 1, n)
    inside = np.zeros(n + 1, np.int64)
    np.add.at(inside, lo, 1)
    np.add.at(inside, hi, -1)
    rows = np.flatnonzero(np.cumsum(inside[:n]) > 0)
    if 2 * rows.shape[0] >= n:
        return stream
    was_start = np.zeros(n, np.bool_)
    was_start[stream.segment_starts] = True
    cut = (np.diff(rows) > 1) | was_start[rows[1:]]
    return replace(
        stream,
        vel_t_ns=stream.vel_t_ns[rows],
        omega=stream.omega[rows],
        velocity=stream.velocity[rows],
        segment_starts=np.flatnonzero(cut) + 1,
        directions=None,  # the time offset reads none; they would not match the samples kept
    )


@njit(cache=True, nogil=True)
def _partners(order, key, idx, t):
    """The pairs of :func:`_pairs` from the detections sorted by landmark then time (``order``, ``key``): for each,
    the first sorted detection whose key is at least ``PAIR_SPAN_S`` above its own (``np.searchsorted(key, key +
    PAIR_SPAN_S)``: a walk, as those keys never decrease), kept when it is the same landmark's within ``PAIR_MAX_S``;
    in sorted order."""
    n = order.shape[0]
    a, b = np.empty(n, np.int64), np.empty(n, np.int64)
    m, j = 0, 0
    for p in range(n):
        v = key[p] + PAIR_SPAN_S
        while j < n and key[j] < v:
            j += 1
        if j == n:
            break
        i, k = order[p], order[j]
        if idx[i] == idx[k] and t[k] - t[i] <= PAIR_MAX_S:
            a[m], b[m] = i, k
            m += 1
    return a[:m], b[:m]


@subroutine(types.int64)
def _pose_at(t_s, rot_s, pos_s, omega, vel, t, rot, pos, d_r, unused, lo):
    """The pose at time ``t``: sample ``k`` before it (the first one before the samples) carried on for
    ``h = t − t_k`` with its twist: ``R_k Exp(h ω_k)``, ``P_k + R_k h v_k`` (``d_r``, ``unused``: scratch).
    ``lo``: a guess of the first sample after ``t`` (walked from to the true one, which is returned). A subroutine
    (compiled into :func:`_pair_residuals`, without numba's runtime): as a kernel of its own, each of its two calls
    per pair and shift took and dropped a reference to each of its nine arrays, a third of the search's CPU."""
    n = t_s.shape[0]
    while lo < n and t_s[lo] <= t:
        lo += 1
    while lo > 0 and t_s[lo - 1] > t:
        lo -= 1
    k = min(max(lo - 1, 0), n - 1)
    h = t - t_s[k]
    se3_exp_into(h * omega[k, 0], h * omega[k, 1], h * omega[k, 2], 0.0, 0.0, 0.0, d_r, unused)
    for i in range(3):
        dp = rot_s[k, i, 0] * (h * vel[k, 0]) + rot_s[k, i, 1] * (h * vel[k, 1]) + rot_s[k, i, 2] * (h * vel[k, 2])
        pos[i] = pos_s[k, i] + dp
        for j in range(3):
            rot[i, j] = rot_s[k, i, 0] * d_r[0, j] + rot_s[k, i, 1] * d_r[1, j] + rot_s[k, i, 2] * d_r[2, j]
    return lo


@njit(cache=True)
def _first_after(t_s, t):
    """The first sample after ``t`` (binary search)."""
    lo, hi = 0, t_s.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if t_s[mid] <= t:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def _pair_residuals(t_s, rot_s, pos_s, omega, vel, det_t, y, a, b, shifts, out):
    """``out[s, m] = y_a − R_aᵀ (P_b + R_b y_b − P_a)`` for the pairs ``(a[m], b[m])`` at the stamps moved by
    ``shifts[s]`` (:func:`_pose_at`): a pair at every shift in turn (its samples stay in the cache: a long log's
    poses do not fit there, and a pass over all pairs per shift read them from memory each time)."""
    if shifts.shape[0] == 0:
        return
    r_a, r_b = np.empty((3, 3)), np.empty((3, 3))
    p_a, p_b, w = np.empty(3), np.empty(3), np.empty(3)
    d_r, unused = np.empty((3, 3)), np.empty(3)
    for m in range(a.shape[0]):
        i, j = a[m], b[m]
        ka = _first_after(t_s, det_t[i] + shifts[0])
        kb = _first_after(t_s, det_t[j] + shifts[0])
        for s in range(shifts.shape[0]):
            ka = _pose_at(t_s, rot_s, pos_s, omega, vel, det_t[i] + shifts[s], r_a, p_a, d_r, unused, ka)
            kb = _pose_at(t_s, rot_s, pos_s, omega, vel, det_t[j] + shifts[s], r_b, p_b, d_r, unused, kb)
            for c in range(3):
                w[c] = (p_b[c] + (r_b[c, 0] * y[j, 0] + r_b[c, 1] * y[j, 1] + r_b[c, 2] * y[j, 2])) - p_a[c]
            for c in range(3):
                out[s, m, c] = y[i, c] - (r_a[0, c] * w[0] + r_a[1, c] * w[1] + r_a[2, c] * w[2])


class Consistency:
    """The pairs' cost as a function of the shift, the odometry's bias profiled out.
    Public: tests/test_riekf_exactness.py checks its one-pass grid."""

    def __init__(self, stream, bias: np.ndarray) -> None:
        self.source, self.bias = stream, bias
        self.det_t = np.repeat(stream.seconds(stream.det_t_ns), np.diff(stream.det_offsets))
        self.a, self.b = _pairs(stream, self.det_t)
        self.stream = _read_only(stream, self.det_t, self.a, self.b)
        self.y = stream.det_y
        self.poses = self._poses(bias)
        # the pairs' residuals move with the bias: their Jacobian (numerical, at zero shift, from the poses of
        # the samples the pairs read there only)
        self.keep = self.read_at(0.0)  # the samples the pairs read
        self.jac = self.bias_jacobian(0.0, self.keep, self.residuals(0.0)[0])
        self.jtj = np.einsum("kci,kcj->kij", self.jac, self.jac)

    def read_at(self, shift: float) -> np.ndarray:
        """The samples the pairs read at the detection shift ``shift`` (each detection's sample before)."""
        t_s = self.poses[0]
        at = np.searchsorted(t_s, self.det_t[np.concatenate([self.a, self.b])] + shift, side="right") - 1
        return np.unique(np.clip(at, 0, t_s.shape[0] - 1))

    def bias_jacobian(self, shift: float, keep: np.ndarray, base: np.ndarray) -> np.ndarray:
        """The pairs' residuals' Jacobian (pairs, 3, 6) in the odometry's bias at the detection shift ``shift``
        (numerical, from the poses of the samples the pairs read there only: ``keep``, :meth:`read_at`; ``base``
        the residuals there)."""
        jac = np.empty((base.shape[0], 3, 6))
        for c, poses in enumerate(self._moved_gyro_poses(self.bias, keep)):
            jac[:, :, c] = (self.residuals(shift, poses)[0] - base) / BIAS_STEP
        for c, poses in enumerate(self._moved_velocity_poses(self.bias, keep), 3):
            jac[:, :, c] = (self.residuals(shift, poses)[0] - base) / BIAS_STEP
        return jac

    def at_shift(self, shift: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pairs' residuals at the detection shift ``shift``, the samples they read there (:meth:`read_at`) and
        the residuals' bias Jacobian there (:meth:`bias_jacobian`); at zero shift those made once (``keep``,
        ``jac``)."""
        base = self.residuals(shift)[0]
        if shift == 0.0:
            return base, self.keep, self.jac
        read = self.read_at(shift)
        return base, read, self.bias_jacobian(shift, read, base)

    def _poses(self, bias: np.ndarray):
        """The samples' times, poses and bias-corrected twists; the integrator's inputs are kept for the Jacobian's
        dead reckonings (:meth:`_moved_gyro_poses`, :meth:`_moved_velocity_poses`)."""
        s = self.stream
        omega, vel = (s.omega - bias[:3], s.velocity - bias[3:]) if bias.any() else (s.omega, s.velocity)
        t, self._steps = _sample_steps(s, omega, vel)
        return (t, *integrate_body_twists(np.eye(3), np.zeros(3), *self._steps), omega, vel)

    def _moved_gyro_poses(self, bias: np.ndarray, keep: np.ndarray) -> list[tuple]:
        """:meth:`_poses` (the samples ``keep`` only) with each gyro-bias entry (0..2) moved by ``BIAS_STEP``: that
        twist column computed again, the three dead reckonings in one pass
        (``lie.integrate_body_twists_at_rotation_columns``: the same numbers as three from scratch)."""
        s, t_s, _, _, omega, vel = self.stream, *self.poses
        cols = s.omega[:-1] - (bias[:3] + BIAS_STEP)  # column j: entry j of bias + BIAS_STEP e_j
        cols[s.segment_starts - 1] = 0.0
        omega_steps, vel_steps, dt = self._steps
        rs, ps = integrate_body_twists_at_rotation_columns(
            np.eye(3), np.zeros(3), omega_steps, vel_steps, cols, dt, keep
        )
        out = []
        for j in range(3):
            twist = omega[keep]
            twist[:, j] = s.omega[keep, j] - (bias[j] + BIAS_STEP)
            out.append((t_s[keep], rs[j], ps[j], twist, vel[keep]))
        return out

    def _moved_velocity_poses(self, bias: np.ndarray, keep: np.ndarray) -> list[tuple]:
        """:meth:`_moved_gyro_poses` for each velocity-bias entry (3..5), the three in one dead reckoning (their
        rotations are the first poses' and shared: the same numbers as three from scratch)."""
        s, t_s, _, _, omega, vel = self.stream, *self.poses
        cols = s.velocity[:-1] - (bias[3:] + BIAS_STEP)  # column j: entry j of bias + BIAS_STEP e_(3+j)
        cols[s.segment_starts - 1] = 0.0
        omega_steps, vel_steps, dt = self._steps
        rs, ps = integrate_body_twists_at_columns(np.eye(3), np.zeros(3), omega_steps, vel_steps, cols, dt, keep)
        out = []
        for j in range(3):
            twist = vel[keep]
            twist[:, j] = s.velocity[keep, j] - (bias[3 + j] + BIAS_STEP)
            out.append((t_s[keep], rs, ps[j], omega[keep], twist))
        return out

    def residuals(self, shifts, poses=None) -> np.ndarray:
        """Per shift and pair (shifts, pairs, 3), in the body frame of the pair's first detection:
        ``y_a − (R_aᵀ R_b y_b + R_aᵀ (P_b − P_a))``, the poses at the detection stamps moved by the shift carried
        on from the sample before with its twist."""
        t_s, rot_s, pos_s, omega, vel = self.poses if poses is None else poses
        shifts = np.atleast_1d(np.asarray(shifts, dtype=np.float64))
        out = np.empty((shifts.shape[0], self.a.shape[0], 3))
        _pair_residuals(t_s, rot_s, pos_s, omega, vel, self.det_t, self.y, self.a, self.b, shifts, out)
        return out

    def varied(self, **changes) -> Consistency:
        """A copy of this consistency with the attributes ``changes`` replaced (the rest shared, not recomputed)."""
        out = object.__new__(Consistency)
        out.__dict__.update(self.__dict__)
        out.__dict__.update(changes)
        return out

    def subset(self, keep: np.ndarray) -> Consistency:
        """The same consistency over the pairs ``keep`` (a mask) only."""
        return self.varied(a=self.a[keep], b=self.b[keep], jac=self.jac[keep], jtj=self.jtj[keep])

    def costs(self, shifts) -> np.ndarray:
        """The cost at each of ``shifts`` (:func:`_trimmed_costs`), the residuals of all of them computed in one
        pass."""
        e = self.residuals(shifts)
        out = np.empty(e.shape[0])
        _trimmed_costs(self.jac, self.jtj, e, out)
        return out


@njit(cache=True, nogil=True)
def _trimmed_costs(jac, jtj, e, out):
    """``out[s]``: the trimmed mean squared residual of the pairs' residuals ``e[s]`` at shift ``s`` after the bias
    correction that fits the pairs best (least squares on all pairs, then again on the ``TRIM`` share with the
    smallest residuals; normal equations in 6 unknowns, a small ridge keeps them regular on straight motion):
    one compiled loop (the NumPy calls per shift were 60 ms of the 1 h log's 93 shifts)."""
    k = e.shape[1]
    n = max(1, int(TRIM * k))
    keep, d2 = np.empty(k, np.int64), np.empty(k)
    a, rhs = np.empty((6, 6)), np.empty(6)
    for s in range(e.shape[0]):
        m = k
        for q in range(k):
            keep[q] = q
        for _ in range(2):
            a[:, :] = 0.0
            rhs[:] = 0.0
            for q in range(m):
                p = keep[q]
                for i in range(6):
                    for j in range(6):
                        a[i, j] += jtj[p, i, j]
                    rhs[i] -= jac[p, 0, i] * e[s, p, 0] + jac[p, 1, i] * e[s, p, 1] + jac[p, 2, i] * e[s, p, 2]
            for i in range(6):
                a[i, i] += 1e-9
            _solve_spd(a, rhs)
            for p in range(k):
                v = 0.0
                for c in range(3):
                    r = e[s, p, c]
                    for i in range(6):
                        r += jac[p, c, i] * rhs[i]
                    v += r * r
                d2[p] = v
            m = _smallest(d2, n, keep)
        total = 0.0
        for q in range(m):
            total += d2[keep[q]]
        out[s] = total / m


@njit(cache=True, nogil=True)
def _smallest(d2, n, keep):
    """``keep[:n]``: the indices of the ``n`` smallest of ``d2`` (ties at the n-th value taken in index order);
    returns ``n``."""
    thr = np.partition(d2, n - 1)[n - 1]
    m = 0
    for p in range(d2.shape[0]):
        if d2[p] < thr:
            keep[m] = p
            m += 1
    for p in range(d2.shape[0]):
        if m < n and d2[p] == thr:
            keep[m] = p
            m += 1
    return m


@njit(cache=True, nogil=True)
def _solve_spd(a, b):
    """``b ← a⁻¹ b`` for a symmetric positive definite ``a`` (overwritten by its Cholesky factor); NaN when it is
    not positive definite."""
    n = b.shape[0]
    if not cholesky_lower(a, n):
        b[:] = np.nan
        return
    for i in range(n):
        v = b[i]
        for k in range(i):
            v -= a[i, k] * b[k]
        b[i] = v / a[i, i]
    for i in range(n - 1, -1, -1):
        v = b[i]
        for k in range(i + 1, n):
            v -= a[k, i] * b[k]
        b[i] = v / a[i, i]


def _search(c: Consistency) -> tuple[float, float, float, list[float]]:
    """The shift of least cost on the grid (coarse, then fine around the best), its standard error from the
    curvature there, the cost at zero over the cost there, and the span of the coarse grid around it whose cost
    is within ``MIN_GAIN`` times that cost (:func:`_indistinct`)."""
    reach = _reach(c.stream)
    coarse = np.arange(-reach, reach + COARSE_S / 2, COARSE_S)
    coarse_costs = c.costs(coarse)
    best = int(np.argmin(coarse_costs))
    fine = float(coarse[best]) + np.arange(-COARSE_S, COARSE_S + FINE_S / 2, FINE_S)
    fine_costs = c.costs(fine)
    j = int(np.argmin(fine_costs))
    shift, c_min = float(fine[j]), float(fine_costs[j])
    curv = np.polyfit(fine - shift, fine_costs, 2)[0]  # cost ≈ c_min + curv (δ − shift)²
    sigma = float(np.sqrt(c_min / (c.a.shape[0] * curv))) if curv > 0 else np.inf
    span = _indistinct(coarse, coarse_costs <= MIN_GAIN * c_min, best)
    return shift, sigma, float(c.costs(0.0)[0]) / max(c_min, 1e-300), span


def _indistinct(shifts: np.ndarray, within: np.ndarray, best: int) -> list[float]:
    """``[lo, hi]``: the run of ``shifts`` around ``shifts[best]`` all ``within`` (cost within ``MIN_GAIN`` of the
    least): the shifts the detections do not tell from the best by the evidence that decides whether it is applied
    (a profile interval). Where the cost curve is flat and ragged the curvature at its least point is that of a
    local wiggle, not of the fit: seed=3230 (2 Hz detections, no offset) gave -0.242 s ± 0.011 from it, zero inside
    this span."""
    lo = hi = best
    while lo > 0 and within[lo - 1]:
        lo -= 1
    while hi < shifts.shape[0] - 1 and within[hi + 1]:
        hi += 1
    return [round(float(shifts[lo]), 6), round(float(shifts[hi]), 6)]


def hold_lag(stream) -> float:
    """The search's own lag (s): half the median interval between the velocity samples. The search holds each
    sample from its stamp until the next where riekf and batch take the twist linear between samples, which
    lags a changing motion by half an interval: on a clean log with no offset it finds that lag as one (a generated
    figure 8 at 10 / 20 / 4.26 Hz: +0.051 / +0.023-0.026 / +0.119 s), so a positive shift no larger is not told
    from it (issue 23). A shift of the other sign is the lag's opposite: a true offset read short by it (10 Hz,
    detections 0.1-0.3 s late: -0.049 / -0.148 / -0.247 s). Samples read as interval means (:func:`interval_means`)
    the search holds from their intervals' starts (``alignment.held_stamps``), each over exactly the interval it
    averages: no lag. Public: tests/test_robust_reference.py checks it."""
    if interval_means(stream):
        return 0.0
    t = stream.vel_t_ns
    return 0.5e-9 * float(np.median(np.diff(t))) if t.shape[0] > 1 else 0.0


def interval_means(stream) -> bool:
    """Whether the velocity samples were read as means over the interval before each stamp: an odometry twist that
    is both velocities, against its own poses (``AlignedStream.twist_sampling``, read by
    :func:`.readers.odometry.twist_sampling`), and restamped to the intervals' midpoints where they were read
    (:func:`.readers.odometry.midpoint_restamped`). Otherwise each is taken as the motion at its stamp as stamped."""
    read = getattr(stream, "twist_sampling", None)
    return bool(read) and read.get("model") == "mean"


#: Why the search's lag assumes the sampling model it does (:func:`sampling_record`), by the odometry's reading
#: (``readers.odometry.SAMPLING_CANDIDATES``; None: not told, "": no reading).
_SAMPLING_WHY = {
    "mean": "the twist fits its own poses' increment over the interval before each stamp",
    "instant": "the twist fits its own poses' central difference at each stamp",
    "held": "the poses were dead-reckoned from the twist, which says nothing of its sampling",
    None: "its own poses do not tell the twist's sampling",
    "": "nothing in the log tells",
}


def sampling_record(stream) -> dict:
    """The record's ``sampling``: what each velocity sample was read as (``mean`` or ``instant``) and why, with the
    odometry's reading where there is one (:func:`interval_means`); means were restamped to their intervals'
    midpoints (``stamps``: riekf's and batch's; the observers' their starts, ``observers.base``), and the search holds
    each from its interval's start, so it has no lag (:func:`hold_lag`)."""
    read = getattr(stream, "twist_sampling", None)
    why = _SAMPLING_WHY[read["model"] if read else ""]
    if interval_means(stream):
        why += ": " + read.get("restamped", "") + ", each then the motion at its stamp; the search holds each from its"
        why += " interval's start, over the interval it averages"
    else:
        why += ": each velocity sample taken as the motion at its stamp"
    stamps = {"stamps": MEAN_STAMPS["interpolates"]} if interval_means(stream) else {}  # the observers': _started
    return {
        "model": "mean" if interval_means(stream) else "instant",
        "why": why,
        **stamps,
        **({"read": read} if read else {}),
    }


#: How ``why_not_applied`` begins where only the halves' check held an offset back (:func:`unapplied_note`).
HALVES_DISAGREE = "the log's halves disagree"


def _halves_disagree(c: Consistency, stream) -> str | None:
    """Why the two halves of the log (the pairs by the time of their first detection) do not give one offset
    within ``HALVES_SIGMAS`` combined standard errors, or None: a constant offset shows in both."""
    t = np.repeat(stream.seconds(stream.det_t_ns), np.diff(stream.det_offsets))[c.a]
    first = t < np.median(t)
    found = [_search(c.subset(part)) for part in (first, ~first)]
    (s1, e1, _, _), (s2, e2, _, _) = found
    if abs(s1 - s2) > HALVES_SIGMAS * np.hypot(e1, e2):
        return f"{HALVES_DISAGREE} ({s1:+.4f} ± {e1:.2g} s and {s2:+.4f} ± {e2:.2g} s)"
    return None


#: What the warning of a turned or inverted camera extrinsic says: how a run and its report find that warning.
CAMERA_ADVICE = "check the camera's extrinsic"
#: The angular velocity's sign flipped: the misread a mirror of the detections also reads as (``MIRROR_ADVICE``).
SIGN_FLIPPED = "with its angular velocity's sign flipped"


def _swapped(a: int, b: int) -> np.ndarray:
    m = np.eye(3)
    m[[a, b]] = m[[b, a]]
    return m


#: Angular velocities a log may hold misread, as the matrix that would undo it (``omega @ m.T``): the sign (a
#: left-handed or upside-down gyro), degrees per second (the ROS unit is rad/s), z swapped with x or y (an IMU
#: mounted on its side with the extrinsic of another, a driver's axis map: a generated figure 8 with its gyro's x and
#: z swapped fits 17.6x better so undone; riekf lost at 22 m with only a velocity-scale warning). Not x with y, nor
#: one of them flipped: the detection pairs, a few seconds long, hardly see the roll and pitch rates (a figure 8 with
#: its gyro's x and y swapped fits 0.68x as well undone, riekf 0.87 m against 0.011 m: docs/benchmarks.md "Silent
#: wrong results, round 9").
GYRO_MISREADS = {
    SIGN_FLIPPED: -np.eye(3),
    "with its angular velocity divided by 57.3 (deg/s?)": float(np.radians(1.0)) * np.eye(3),
    "with its angular velocity's x and z swapped": _swapped(0, 2),
    "with its angular velocity's y and z swapped": _swapped(1, 2),
}
#: A turn of the wrong sign is also what mirrored detections show (one axis of the camera frame flipped: a
#: left-handed extrinsic, a bearing of the wrong sign): to the pairs a mirror and a flipped gyro are the same, on a
#: robot that does not move sideways exactly (MR.CLAM 6 r1 with its bearings negated: the sign flip 8.35x better).
MIRROR_ADVICE = (
    ", or whether the detections are mirrored (an axis of their frame flipped: a left-handed camera extrinsic, a "
    "bearing of the wrong sign), which the detections cannot tell from it"
)
#: The gyro-misread warning when the misread undoes the turn the alignment measured between the gyro and the
#: odometry's own angular velocity (``AlignedStream.gyro_turn``): the gyro's axes turned against the body, of which
#: an axis swap is the nearest misread tried; on a ground robot's yaw alone a mount turned 90 deg and a driver's swap
#: read alike (a generated figure 8 whose IMU is rolled 90 deg, its frame taken as the body:
#: "y and z swapped" 35.9x better; without this, two warnings naming two causes, session 26).
GYRO_TURN_SEEN = (
    "the same turn the warning on {topic}'s gyro measures ({angle:.0f} deg from the odometry's own turn; {nearest} "
    "is the nearest misread tried): its axes reach the body turned, by the IMU's mount ({advice}) or by its "
    "driver's axis map (fix it there)"
)
#: The nearest misread ``GYRO_TURN_SEEN`` names: an IMU upside down (its gyro turning the other way, ~180 deg) is
#: undone by the sign flip, which it named "a swap of two axes" before session 30.
NEAREST_MISREAD = {SIGN_FLIPPED: "the sign flip"}
#: Added to the velocity-scale warnings beside it: their pairs are read along the turned gyro's heading (that
#: figure 8's odometry alone, with the IMU's transform given, draws no velocity warning).
GYRO_TURN_UPSETS = "; the turned gyro upsets this reading too: look again once its axes are right"
#: A misread is named when the pairs' trimmed mean squared residual with the angular velocity so undone is this
#: many times smaller than as read (MR.CLAM 6 r1 as recorded: 2.4x and 8.6x larger; in deg/s 712x smaller, its
#: sign flipped 8.6x smaller).
GYRO_MISREAD_GAIN = 4.0


def _trimmed_cost(e: np.ndarray) -> float:
    d2 = np.sum(e**2, axis=1)
    n = max(1, int(TRIM * d2.shape[0]))
    return float(np.mean(np.partition(d2, n - 1)[:n]))


def gyro_misreads(c: Consistency) -> dict[str, float]:
    """How many times better the detection pairs fit the odometry with its angular velocity undone by each of
    ``GYRO_MISREADS`` than as read (no bias fitted: a misread dwarfs a bias): the angular velocity in deg/s, of
    the wrong sign or with two axes swapped is no noise the estimators can absorb (MR.CLAM in deg/s: riekf APE
    0.49 -> 3.8 m, no word)."""
    omega_steps, vel_steps, dt = c._steps
    (t_s, *_, omega, vel), keep = c.poses, c.keep  # at zero shift the pairs read the samples keep only
    base = _trimmed_cost(c.residuals(0.0)[0])
    out = {}
    for what, g in GYRO_MISREADS.items():
        undone = np.ascontiguousarray(omega_steps @ g.T)
        rs, ps = integrate_body_twists_at(np.eye(3), np.zeros(3), undone, vel_steps, dt, keep)
        poses = (t_s[keep], rs, ps, omega[keep] @ g.T, vel[keep])
        out[what] = base / max(_trimmed_cost(c.residuals(0.0, poses)[0]), 1e-300)
    return out


#: A velocity axis's scale is named when the detections put it outside ``1 / VELOCITY_SCALE_OFF .. VELOCITY_SCALE_OFF``
#: times the velocity as read and more than ``VELOCITY_SCALE_SIGMAS`` standard errors from 1 (MR.CLAM's ten robots
#: as recorded: 0.84-1.09, ± 0.04-0.08; 6 r1 in km/h: 0.25 ± 0.02, of the wrong sign: -0.92; its ranges in cm:
#: 116 ± 12, the detections' unit this time).
VELOCITY_SCALE_OFF = 1.5
VELOCITY_SCALE_SIGMAS = 5.0
#: Every fitted axis's scale off 1 the same way (a tag size or a depth camera's scale stretches all three alike; a
#: VIO's scale too) is named inside ``VELOCITY_SCALE_OFF`` (:func:`common_scale`) where at least ``COMMON_SCALE_AXES``
#: axes are fitted (one axis cannot tell a common scale from a wheel's: MR.CLAM's ten robots and every generated
#: ground robot fit x alone), each axis is off 1 on the same side, and their weighted mean, as fitted and with the
#: dilution taken off, is past ``VELOCITY_SCALE_SIGMAS`` standard errors from 1 and outside ``1 / COMMON_SCALE_OFF ..
#: COMMON_SCALE_OFF``: 5 %, the smallest common scale whose cost docs/benchmarks.md's session 36 measured (a flight's
#: every axis 5 % off: riekf's APE 1.2-1.5x, batch's 1.3-1.9x; a detection scale of 1.1 on a hand-held rig: 10x),
#: where the real logs' means are 1.9-2.2 % off (TagSLAM 21 and 11, 15-40 standard errors: their calibration's,
#: which taking off made the runs worse).
COMMON_SCALE_AXES = 2
COMMON_SCALE_OFF = 1.05
#: An axis's scale is left unsaid when fitting the bias with it inflates its variance more than this (constant
#: motion, where a scale and a bias are the same change: the simulator's circle 300-1,300,000; MR.CLAM 4-29, the
#: figure 8 and the ground robot 1-26).
MAX_SCALE_INFLATION = 100.0
#: An axis's scale is fitted only where the body's displacement along it is at least this share of the largest
#: axis's (RMS over the pairs): along a ground robot's or a figure 8's lateral axis (shares 0.02-0.045) the velocity
#: as read is mostly noise and its fitted scale is too (-1.45 ± 0.34 on a generated ground robot); a figure 8's or a
#: loop's vertical axis (0.06-0.11) is fitted to ± 0.004-0.011.
MIN_AXIS_SHARE = 0.05
#: What the velocity-scale warning asks to check: the pairs cannot tell a velocity in another unit from detections
#: of another scale (a tag size 2x off: `tags.size` 1.6 where the tags' is 0.8 read as the velocity 2.01x; a tag
#: size in mm, 1000x), so it names both and the key of each.
SCALE_CAUSES = (
    "either the velocity or the detections are off by that factor, and they cannot tell which: the velocity's unit "
    f"and axes (at the odometry's driver), or the detections' scale ({DETECTION_SCALES}), or their frame's extrinsic: "
    "a camera turned or given as the inverse transform reads this way"
)
#: An axis's scale is left unsaid when the velocity's own noise (``AlignedStream.velocity_density``) is more than
#: this share of what the fit sees of the axis (:func:`velocity_scale`'s dilution): the fitted scale is pulled toward
#: 0 by that share, and its correction is no longer stable (a generated figure 8 at velocity noise x300: dilution
#: 0.70 on x, the scale 0.21 read as a misread unit; x100: 0.28, 0.66 -> 0.91 corrected).
MAX_SCALE_DILUTION = 0.5
#: Units a velocity may be misread in, as the scale the detections would find, with what to say of it.
VELOCITY_MISREADS = (
    (-1.0, "of the wrong sign"),
    (1.0 / 3.6, "in km/h?"),
    (0.3048, "in ft/s?"),
    (0.01, "in cm/s?"),
    (0.001, "in mm/s?"),
)


#: A turn of the detections (about the body's origin, by a multiple of 90 deg about the body's axes: the 23 turns
#: that map the axes onto the axes) is named when the pairs' trimmed mean squared residual with the detections so
#: turned is this many times smaller than as read: a camera extrinsic turned about one of its axes, or given as the
#: inverse transform, reads so when the camera sits along the body's axes (a generated figure 8 with its camera
#: turned 90 deg about its z: 5.5x, its extrinsic inverted: 11.2x, riekf APE 9-11 m with only a velocity-scale
#: warning; as recorded the best turn fits 0.044x as well, MR.CLAM's ten robots 0.27-0.78x (docs/benchmarks.md,
#: "Silent wrong results, round 7")).
EXTRINSIC_TURN_GAIN = 3.0


def _axis_turns() -> list[np.ndarray]:
    """The 23 rotations other than the identity that map the body's axes onto its axes (signed permutations of
    determinant 1)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[[0, 1, 2], list(perm)] = signs
            if np.linalg.det(m) > 0.0 and not np.array_equal(m, np.eye(3)):
                out.append(m)
    return out


def _turnable(c: Consistency) -> tuple[np.ndarray, np.ndarray, Consistency]:
    """The pairs' detections (a copy), a buffer for them turned and the consistency that reads that buffer: the
    pairs' detections only (the hour's 576,000 took 0.5 CPU s; a copy of them all, 14 MB, another 0.01)."""
    used, ends = np.unique(np.concatenate([c.a, c.b]), return_inverse=True)
    turned, y = np.empty((used.shape[0], 3)), np.ascontiguousarray(c.y[used], dtype=np.float64)
    n = c.a.shape[0]
    return y, turned, c.varied(y=turned, det_t=c.det_t[used], a=ends[:n], b=ends[n:])


def extrinsic_turn(c: Consistency) -> dict:
    """The turn of the detections (``EXTRINSIC_TURN_GAIN``'s set) that fits the pairs best, as a rotation vector
    in the body frame (deg), and how many times better it fits than the detections as read (no bias fitted, as
    :func:`gyro_misreads`): a camera extrinsic turned or inverted is no noise the estimators can absorb."""
    base = _trimmed_cost(c.residuals(0.0)[0])
    best, turn = 0.0, None
    y, turned, with_turned = _turnable(c)
    for q in _axis_turns():
        np.matmul(y, q.T, out=turned)
        gain = base / max(_trimmed_cost(with_turned.residuals(0.0)[0]), 1e-300)
        if gain > best:
            best, turn = gain, q
    return {"gain": best, "rotvec_deg": np.round(np.degrees(so3_log(turn)), 3).tolist()}


#: A small turn of the detections (a camera extrinsic stated a few degrees off: riekf and batch then fit within their
#: plain logs' APE but overconfident, NEES 89-463, named by nothing) is named when the turn that fits the pairs best
#: (the odometry's bias fitted, as the offset's cost) is at most ``SMALL_TURN_MAX_DEG``, fits ``SMALL_TURN_GAIN``
#: times better than as read and better by the χ² rule of a deviance with its three unknowns (:func:`_beats`), and each
#: half of the pairs (in time) finds the same turn within ``SMALL_TURN_HALVES`` of its angle. Generated hand-held and
#: flight logs (stated yaw 3-20 deg off): recovered within 0.7 deg (a figure 8: a fifth short, the velocity's bias
#: taking it), gains 1.10-8.3, halves 0.5-0.9 deg apart; right
#: extrinsics: controls 0.1-0.6 deg at 1.00-1.01, TagSLAM 11 / 21 1.2 / 0.2 deg at 1.06 / 1.01, while MR.CLAM, TagSLAM
#: 22 and the stereo sweep's logs fit 0.5-85 deg at up to 1.5x, their halves 7-110 deg apart (a flat cost). Set from
#: those logs (docs/benchmarks.md, "A camera extrinsic stated a few degrees off"). A floor of 3 deg on the angle went
#: with them until session 39: a camera stated 3 deg tilted fits 2.86-2.95 deg (seed=9993, seed=4706, seed=4708; gains
#: 1.18-1.33, halves 0.6-0.8 deg apart) and went unnamed by it alone, while no control or real log passes the gain and
#: the halves without it (docs/benchmarks.md, "The review's leftovers of session 38").
SMALL_TURN_GAIN = 1.1
SMALL_TURN_MAX_DEG = 30.0
SMALL_TURN_HALVES = 0.3
#: The coordinate search's first and last step (rad).
_SMALL_TURN_STEPS = (np.radians(4.0), np.radians(0.05))


def _small_turn_fit(c: Consistency) -> tuple[np.ndarray, float]:
    """The rotation vector (rad) of the detections' turn that fits the pairs best near the identity (a coordinate
    search, halving its step) and how many times better its cost (:func:`_trimmed_costs`, the bias fitted) is than
    as read."""
    y, turned, with_turned = _turnable(c)
    out = np.empty(1)

    def cost(rv: np.ndarray) -> float:
        np.matmul(y, so3_exp(rv).T, out=turned)
        _trimmed_costs(c.jac, c.jtj, with_turned.residuals(0.0), out)
        return float(out[0])

    rv, base = np.zeros(3), cost(np.zeros(3))
    cur, step = base, _SMALL_TURN_STEPS[0]
    while step > _SMALL_TURN_STEPS[1]:
        moved = False
        for k, sign in itertools.product(range(3), (1.0, -1.0)):
            trial = rv.copy()
            trial[k] += sign * step
            if (got := cost(trial)) < cur:
                cur, rv, moved = got, trial, True
        if not moved:
            step /= 2.0
    return rv, base / max(cur, 1e-300)


def small_turn(c: Consistency) -> dict | None:
    """The small turn of the detections ``SMALL_TURN_GAIN``'s rule names (a rotation vector in the body frame, deg,
    and its gain), or None; the halves are fitted only where the whole fits (a clean run pays one search over its
    at most ``MAX_PAIRS`` pairs)."""
    rv, gain = _small_turn_fit(c)
    angle = float(np.degrees(np.linalg.norm(rv)))
    if gain < SMALL_TURN_GAIN or angle > SMALL_TURN_MAX_DEG or not _beats(_frames(c), gain, 3):
        return None
    first = c.det_t[c.a] < np.median(c.det_t[c.a])
    h1, h2 = (_small_turn_fit(c.subset(part))[0] for part in (first, ~first))
    if np.degrees(np.linalg.norm(h1 - h2)) > SMALL_TURN_HALVES * angle:
        return None
    return {"gain": gain, "rotvec_deg": np.round(np.degrees(rv), 2).tolist()}


#: The odometry's twist turned by one of the body's axis turns (``_axis_turns``; a robot's twist given in a frame
#: turned from base_link, e.g. 180 deg about z: a robot driving "backwards") is named when the pairs fit it
#: ``EXTRINSIC_TURN_GAIN`` times better turned than as read, and better than the camera turned (``extrinsic_turn``)
#: and the twist read as a world frame's (``world_twist``) by more than ``TWIST_TURN_TIE``; within it of the camera's
#: turn both are named (on planar motion a camera turned about the vertical and a twist turned the other way fit
#: alike). Generated, the twist turned 180 deg about z: a hand-held rig 26.8x (the world frame's 7.55x, named alone
#: before), a 180 s ground robot 19.2x against the camera's 14.9x (both named), a 30 s one 134x against 52x (the
#: 1.5 a margin, not tuned; docs/benchmarks.md, "Logs nobody has run yet, round 7").
TWIST_TURN_TIE = 1.5


def twist_turn(c: Consistency) -> dict:
    """The axis turn of the odometry's twist (``_axis_turns``) that fits the pairs best, as a rotation vector in the
    body frame (deg) taking the velocity as read into the body's, and how many times better it fits than as read
    (no bias fitted, as :func:`extrinsic_turn`): each turn dead-reckoned again (23 over the samples the pairs read)."""
    base = _trimmed_cost(c.residuals(0.0)[0])
    s = c.stream
    omega, vel = s.omega - c.bias[:3], s.velocity - c.bias[3:]
    best, turn = 0.0, None
    for q in _axis_turns():
        turned = vel @ q.T
        t, steps = _sample_steps(s, omega, turned)
        poses = (t, *integrate_body_twists(np.eye(3), np.zeros(3), *steps), omega, turned)
        gain = base / max(_trimmed_cost(c.residuals(0.0, poses)[0]), 1e-300)
        if gain > best:
            best, turn = gain, q
    return {"gain": best, "rotvec_deg": np.round(np.degrees(so3_log(turn)), 3).tolist()}


def _twist_turn_gain(offset: dict) -> float:
    """The gain of :func:`twist_turn` where it names the twist (over ``EXTRINSIC_TURN_GAIN``, no gyro misread named,
    not under the world frame's by ``TWIST_TURN_TIE``), else 0."""
    gain = (offset.get("twist_turn") or {"gain": 0.0})["gain"]
    world = (offset.get("world_twist") or {"gain": 0.0})["gain"]
    if gain < EXTRINSIC_TURN_GAIN or gain * TWIST_TURN_TIE < world:
        return 0.0
    return 0.0 if _best_misread(offset.get("gyro_misreads") or {}) else gain


def turn_phrase(rotvec_deg) -> str:
    """ "by 90 deg about the body's -x" for a rotation vector in degrees (its axis as a unit vector when it is not
    one of the body's)."""
    w = np.asarray(rotvec_deg, dtype=float)
    angle = float(np.linalg.norm(w))
    axis = w / angle
    k = int(np.argmax(np.abs(axis)))
    if abs(axis[k]) > 0.999:
        about = ("-" if axis[k] < 0 else "") + "xyz"[k]
    else:
        about = "(" + ", ".join(f"{a:.2f}" for a in axis) + ")"
    return f"by {angle:.0f} deg about the body's {about}"


#: A twist in a world frame (not the body's, where ``nav_msgs/Odometry`` gives it in ``child_frame_id``; the reader
#: turns one in the odometry's own parent frame into the body, not one in another frame) is named when the pairs'
#: trimmed mean squared residual with the velocity read as a world frame's, turned into the body by the dead-reckoned
#: heading (one constant turn between the two frames fitted per ``WORLD_TWIST_WINDOW_S``: the heading drifts), is
#: this many times smaller than as read: generated figure 8 / figure8-wide / ground / loop with the twist in the
#: truth's world frame 14-84x (riekf APE 1.85 m with only velocity-scale warnings), circle 3.0x; as recorded the
#: generated logs 0.07-0.86x, MR.CLAM's ten robots 0.92-1.13x, TagSLAM 0.01-1.24x (docs/benchmarks.md, "Silent
#: wrong results, round 8").
WORLD_TWIST_GAIN = 4.0
WORLD_TWIST_WINDOW_S = 20.0
#: A window's turn is fitted only from at least this many pairs (its pairs are left out of both costs otherwise).
WORLD_TWIST_MIN_PAIRS = 10


def _dead_reckoned_at(c: Consistency, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dead-reckoned rotations at the times ``t`` (the sample before carried on with its angular velocity) and
    the velocity integrated without them (the positions it gives as a world frame's, segment gaps left out)."""
    t_s, rot_s, _, omega, vel = c.poses
    _, vel_steps, dt = c._steps
    summed = np.concatenate([np.zeros((1, 3)), np.cumsum(vel_steps * dt[:, None], axis=0)])
    k = np.clip(np.searchsorted(t_s, t, side="right") - 1, 0, t_s.shape[0] - 1)
    h = t - t_s[k]
    return rot_s[k] @ so3_exps(np.ascontiguousarray(h[:, None] * omega[k])), summed[k] + h[:, None] * vel[k]


def _twist_windows(c: Consistency, ta: np.ndarray) -> np.ndarray:
    """Per pair (``ta``: its first detection's time), its window of :func:`world_twist`: ``WORLD_TWIST_WINDOW_S``
    from the first pair of its segment of the samples read (:func:`_read_only`'s runs: each is dead-reckoned from
    its own heading, not the log's)."""
    if not ta.shape[0]:
        return ta.astype(np.int64)
    t_s, starts = c.stream.seconds(c.stream.vel_t_ns), c.stream.segment_starts
    seg = np.searchsorted(starts, np.searchsorted(t_s, ta, "right") - 1, "right")
    first = np.full(starts.shape[0] + 1, np.inf)
    np.minimum.at(first, seg, ta)
    window = np.floor((ta - first[seg]) / WORLD_TWIST_WINDOW_S).astype(np.int64)
    return seg * (int(window.max()) + 1) + window


def world_twist(c: Consistency) -> dict:
    """How many times better the detection pairs fit the velocity read as a world frame's than as read (no bias
    fitted, as :func:`gyro_misreads`): per pair the detections' displacement in the dead-reckoned frame
    ``R_a y_a − R_b y_b`` against the velocity's integral between the two times turned by one rotation per
    ``WORLD_TWIST_WINDOW_S`` (least squares, Kabsch). A twist in a frame the body turns in is no noise the
    estimators can absorb (a generated figure 8: riekf APE 1.85 m, named only as velocity scales)."""
    ta, tb = c.det_t[c.a], c.det_t[c.b]
    r_a, p_a = _dead_reckoned_at(c, ta)
    r_b, p_b = _dead_reckoned_at(c, tb)
    u = np.einsum("nij,nj->ni", r_a, c.y[c.a]) - np.einsum("nij,nj->ni", r_b, c.y[c.b])
    v = p_b - p_a
    window = _twist_windows(c, ta)
    e, used = np.zeros_like(u), np.zeros(u.shape[0], np.bool_)
    for w in np.unique(window):
        m = window == w
        if np.count_nonzero(m) < WORLD_TWIST_MIN_PAIRS:
            continue
        left, _, right = np.linalg.svd(u[m].T @ v[m])
        flip = np.array([1.0, 1.0, np.sign(np.linalg.det(left @ right)) or 1.0])
        e[m], used[m] = u[m] - v[m] @ ((left * flip) @ right).T, True
    if not used.any():
        return {"gain": 0.0}
    base = _trimmed_cost(c.residuals(0.0)[0][used])
    return {"gain": base / max(_trimmed_cost(e[used]), 1e-300)}


#: A lever arm between the odometry's point and the body's origin (:func:`lever_arm`) is named when its length over
#: the axes fitted beyond ``LEVER_ARM_SIGMAS`` standard errors is ``LEVER_ARM_MIN_M`` or more and it fits the pairs
#: ``LEVER_ARM_GAIN`` times better than the bias alone (a generated figure 8 with its twist 0.5 m beside the body,
#: no TF: (0.019, 0.497, 0.010) m, 5.85x; clean figure 8s, a ground robot and a loop: at most 0.07 m, 1.00x; the
#: real logs fit arms of 0.3-1.0 m at 1.02-1.41x, MR.CLAM's ten robots 0.30-0.74 m forward, TagSLAM 22 1.0 m at 1.25x:
#: not named). An arm seen that explains a lag or scale the pairs name without it is named whatever its gain
#: (:func:`arm_explains`, a χ² rule).
LEVER_ARM_MIN_M = 0.1
LEVER_ARM_SIGMAS = 5.0
LEVER_ARM_GAIN = 2.0


def _trimmed_fit(base: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
    """``x`` minimising the trimmed squared residuals ``base + a x`` (least squares on all pairs, then twice on the
    ``TRIM`` share with the smallest residuals), its standard errors, the trimmed mean squared residual, the pairs
    kept and their normal matrix (the velocity scale's inflation and dilution read it)."""
    keep = np.arange(base.shape[0])
    for _ in range(3):
        ata = np.einsum("mci,mcj->ij", a[keep], a[keep]) + 1e-9 * np.eye(a.shape[2])
        x = np.linalg.solve(ata, -np.einsum("mci,mc->i", a[keep], base[keep]))
        d2 = np.sum((base + a @ x) ** 2, axis=1)
        n = max(1, int(TRIM * d2.shape[0]))
        keep = np.argpartition(d2, n - 1)[:n]
    ata = np.einsum("mci,mcj->ij", a[keep], a[keep]) + 1e-9 * np.eye(a.shape[2])
    cost = float(np.mean(d2[keep]))
    return x, np.sqrt(np.diag(np.linalg.inv(ata)) * cost / 3.0), cost, keep, ata


def _arm_jacobian(c: Consistency, shift: float) -> np.ndarray:
    """Per pair (pairs, 3, 3): how its residual at the detection shift ``shift`` moves with the lever arm ``r``
    (:func:`lever_arm`): ``(R_aᵀ R_b − I)``, the rotations dead-reckoned to the two detections."""
    ta, tb = c.det_t[c.a] + shift, c.det_t[c.b] + shift
    r_a, r_b = _dead_reckoned_at(c, ta)[0], _dead_reckoned_at(c, tb)[0]
    return np.einsum("nji,njk->nik", r_a, r_b) - np.eye(3)


def lever_arm(
    c: Consistency,
    shift: float,
    fit: tuple[np.ndarray, np.ndarray, np.ndarray],
    arm: np.ndarray,
    scale: dict,
    covered: np.ndarray,
) -> dict | None:
    """The lever arm ``r`` (m, body frame) between the point whose velocity the odometry gives and the body's
    origin, fitted to the pairs with the odometry's bias: that point moves by ``v + ω × r``, so its integral
    between two detections is off the body's by ``(R_b − R_a) r`` and each pair's residual by ``−(R_aᵀ R_b − I) r``
    (exact: the rotations do not depend on the velocity; ``arm``: :func:`_arm_jacobian`). A camera's stated position
    off by ``+r`` (stated minus true) moves the residuals alike (a camera stated 0.05 m off along x fits
    r = (0.050, 0.005, 0.004) m, seed=4380): the pairs cannot tell the two apart. ``gain``: the trimmed
    mean squared residual with the bias alone over that with the arm too; ``over_scale``: the velocity scale's
    (``scale``, :func:`velocity_scale`, fitted on the same pairs) over the arm's; ``frames``: the detection frames
    the pairs join (what :func:`lever_arm_sentence`'s comparisons count). An odometry frame beside the body that no TF
    gives reads so (a generated figure 8, 0.5 m: riekf APE 0.170 m against 0.011, with notes of wheel slip only). At
    the detection shift ``shift`` (the applied offset's: at zero, TagSLAM test_22's -0.357 s was fitted as an arm of
    2.1 m), with the residuals and their bias Jacobian there (``fit``: :meth:`Consistency.at_shift`, as
    :func:`velocity_scale`). Only the pairs ``covered`` (:func:`_covered_pairs`) are fitted, the scale's own: the
    arm's cost and the scale's compared (``over_scale``) are then of the same pairs, and a gap's interpolated velocity
    is no arm either. None with fewer covered pairs than the fit's unknowns and three (as :func:`_scale_fit`)."""
    base, _, jac = fit
    base, jac, arm = base[covered], jac[covered], arm[covered]
    if base.shape[0] < arm.shape[2] + jac.shape[2] + 3:
        return None
    x, sigma, cost = _trimmed_fit(base, np.concatenate([arm, jac], axis=2))[:3]
    alone = _trimmed_fit(base, jac)[2]
    frames = _frames(c, covered)
    return {
        "r_m": [round(float(v), 4) for v in x[:3]],
        "sigma_m": [float(v) for v in sigma[:3]],
        "gain": alone / cost,
        "over_scale": None if scale.get("cost") is None else float(scale["cost"]) / max(cost, 1e-300),
        "frames": frames,
    }


def _arm_seen(offset: dict) -> bool:
    """Whether the lever arm's length over its axes fitted beyond ``LEVER_ARM_SIGMAS`` standard errors is
    ``LEVER_ARM_MIN_M`` or more."""
    arm = offset.get("lever_arm")
    if not arm:
        return False
    r, sigma = np.asarray(arm["r_m"]), np.asarray(arm["sigma_m"])
    return float(np.linalg.norm(r[np.abs(r) > LEVER_ARM_SIGMAS * sigma])) >= LEVER_ARM_MIN_M


def _frames(c: Consistency, keep: np.ndarray | None = None) -> int:
    """How many detection frames the pairs (those ``keep`` selects, all without) join: what the χ² rule of
    :func:`_beats` counts (one frame's detections are in many pairs)."""
    a, b = (c.a, c.b) if keep is None else (c.a[keep], c.b[keep])
    return int(np.unique(c.det_t[np.concatenate([a, b])]).shape[0])


def _beats(frames: int, ratio: float, dof: int) -> bool:
    """Whether a model whose trimmed mean squared residual is ``ratio`` times smaller than another's, with ``dof``
    more unknowns, fits the pairs better by the χ² rule of a deviance: ``frames ln(ratio)`` above the
    ``LEVEL_CHOICE_P`` quantile of χ² with ``dof`` degrees of freedom (above 0 for as many unknowns or fewer). The
    detection frames count, not the pairs: one frame's detections are in many pairs."""
    return frames * np.log(max(ratio, 1e-300)) > (chi2_quantile(LEVEL_CHOICE_P, dof) if dof > 0 else 0.0)


def arm_explains(offset: dict) -> dict[str, str]:
    """What the lever arm (:func:`lever_arm`, seen beyond its standard errors: :func:`_arm_seen`) explains of the
    other misreads the pairs name without it: the velocity lag (:func:`velocity_lag_sentence`) where the arm
    (three unknowns) fits the pairs better than the lag (one) by :func:`_beats`; each velocity axis named as scaled
    (:func:`velocity_misread`) that the scales fitted with the arm (``velocity_scale["with_arm"]``) measure and no
    longer name, where the arm fits better than the scales by the same rule (an axis the arm leaves unmeasured is
    not explained: on a figure 8's curves a sideways arm moves the pairs as a forward scale does, and a velocity
    3.6x off had its z scale so taken). A point 0.2 m ahead of a hand-held rig's origin
    (seed=4127) reads without it as a lag of 0.124 s (1.11x) and a y scale of 0.546x; the arm fits 1.30x, and
    with it the y scale is 0.997. Keyed ``lag`` and ``scale``, each the phrase that names what it explains; empty
    otherwise."""
    arm = offset.get("lever_arm")
    if not _arm_seen(offset) or "frames" not in arm:
        return {}
    said, scale = {}, offset.get("velocity_scale") or {}
    lag = offset.get("velocity_lag")
    if velocity_lag_sentence(lag, offset["pairs"]) is not None and _beats(arm["frames"], arm["gain"] / lag["gain"], 2):
        said["lag"] = f"the linear velocity's lag ({lag['lag_s']:.3f} s)"
    fitted = scale.get("with_arm") and arm.get("over_scale") is not None
    if fitted and _beats(arm["frames"], arm["over_scale"], 3 - int(scale["axes"])):
        kept = {phrase.split(" ", 2)[1] for phrase in velocity_misread(scale["with_arm"])}
        measured = {axis for axis, g in zip("xyz", scale["with_arm"]["scale"], strict=True) if g is not None}
        named = [(phrase.split(" ", 2)[1], g) for phrase, g in _misread_axes(scale)]
        gone = [f"{axis} {g:.3g}x" for axis, g in named if axis in measured and axis not in kept]
        if gone:
            said["scale"] = f"the velocity's scale along {' and '.join(gone)}"
    return said


def lever_arm_sentence(offset: dict) -> str | None:
    """The warning of :func:`lever_arm` (``LEVER_ARM_*``): where the arm is seen (:func:`_arm_seen`) and fits
    ``LEVER_ARM_GAIN`` times better than the bias alone, or explains a lag or scale the pairs name without it
    (:func:`arm_explains`), unless the velocity's scales fit the pairs better (:func:`_beats`: a velocity 3.6x off
    on a figure 8 fits a sideways arm of 4.8 m at 2.26x, and its scales 130x better than that); None otherwise."""
    arm, explained = offset.get("lever_arm"), arm_explains(offset)
    if not _arm_seen(offset) or (arm["gain"] < LEVER_ARM_GAIN and not explained):
        return None
    scale = offset.get("velocity_scale") or {}
    over = arm.get("over_scale")
    if over is not None and _beats(arm["frames"], 1.0 / over, int(scale.get("axes", 3)) - 3):
        return None  # the scales fit the pairs better than the arm: a velocity scale (a figure 8's twist x3.6: 130x)
    r, sigma = np.asarray(arm["r_m"]), np.asarray(arm["sigma_m"])
    where = ", ".join(f"{v:+.3f}" for v in r)
    read = " and ".join(explained.values())
    instead = f"; fitted without it, the pairs read {read}, which it explains" if explained else ""
    return (
        f"the detections fit the odometry {arm['gain']:.3g}x better as the velocity of a point ({where}) m from the "
        f"body's origin (± {float(np.max(sigma)):.2g} m; {offset['pairs']} detection pairs, the odometry's bias "
        f"fitted with it{instead}): a lever arm no TF gives (the odometry's child_frame_id a frame beside the body, "
        "its twist taken as the body's: give its transform to the body, or frames.body: that frame), or the "
        "detections' frame's stated position off by that same translation (stated minus true), which the detections "
        "cannot tell from it; "
        "a forward arm with sideways residuals can also be a yaw rate off the motion (commanded, or lagging it), "
        "whose heading error a far landmark turns sideways (docs/observers.md)"
    )


def _velocity_displacements(c: Consistency, shift: float, keep: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Per pair and velocity axis (pairs, 3, 3): how the pair's residual at the detection shift ``shift`` moves
    when that axis's velocity is doubled (the displacement it contributes between the two detections, in the first
    one's body frame), so that scaling the axes by ``g`` moves the residuals by ``-Σ_j (g_j - 1) D[:, :, j]`` (the
    rotations do not depend on the velocity: the relation is exact). ``keep``, ``base``: the samples the pairs read
    at that shift and the residuals there."""
    t_s, _, _, omega, vel = c.poses
    omega_steps, vel_steps, dt = c._steps
    rs, ps = integrate_body_twists_at_columns(np.eye(3), np.zeros(3), omega_steps, vel_steps, 2.0 * vel_steps, dt, keep)
    out = np.empty((base.shape[0], 3, 3))
    for j in range(3):
        twist = vel[keep]
        twist[:, j] *= 2.0
        out[:, :, j] = base - c.residuals(shift, (t_s[keep], rs, ps[j], omega[keep], twist))[0]
    return out


def velocity_scale(
    c: Consistency,
    shift: float,
    fit: tuple[np.ndarray, np.ndarray, np.ndarray],
    covered: np.ndarray,
    arm: np.ndarray | None = None,
) -> dict:
    """The factor per velocity axis that makes the odometry's motion between the pairs' detections fit them
    best, with its standard error: ``x`` = [g - 1, bias change] minimising the trimmed squared residuals
    ``base - D (g - 1) + J δb`` (the odometry's bias fitted with it, as :meth:`Consistency.cost`). An axis along
    which the body hardly moves (``MIN_AXIS_SHARE``) has no scale (None), nor one whose scale is not told from a
    bias (its variance inflated over ``MAX_SCALE_INFLATION`` times by the bias fit: a constant velocity), nor one
    along which the detections see the body hardly move (the scale times the velocity's displacement, against the
    largest axis's: a ground robot's y or z whose velocity as read is noise, 0.0016 ± 0.12 and -0.07 ± 0.16 on
    ``unseen_logs.py``'s ground logs, which were named as misread). Only the pairs whose span holds no gap of the
    velocity's samples are fitted (``covered``, :func:`_covered_pairs`: across a gap the velocity is interpolated,
    not measured; :func:`lever_arm` fits the same pairs). The velocity
    in another unit or of the wrong sign on an axis is no noise the estimators can absorb (MR.CLAM 6 r1 in km/h:
    riekf 0.49 -> 0.89 m, with its sign flipped: lost, and no word of the velocity).

    The velocity's own noise is in the regressor ``D`` and pulls each scale toward 0 by ``δ = q² Σ Δt [(AᵀA)⁻¹]_jj``
    (errors in variables, first order: ``q²`` the recorded density's square on that axis where below the axes' mean
    square, else that mean, ``AlignedStream.velocity_density``, its axes taken as the body's, ``Σ Δt`` over the pairs
    fitted): the scale is reported as fitted over ``1 − δ`` (its standard error too), and left unsaid where ``δ``
    with either the axis's own level or the mean exceeds ``MAX_SCALE_DILUTION`` (``dilution`` per axis in the record; 0
    where the density is not known). ``fitted``: each axis's scale before the dilution is taken off; the levels are
    upper bounds of the white noise (motion the rate does not resolve adds to them), so the axis's scale lies between
    the two and :func:`velocity_misread` names it only where both are off. The axes' mean square is pooled from their
    white levels (``AlignedStream.velocity_white_density``: an axis's samples' level of such motion does not dilute
    the others'). At the detection shift ``shift`` (the applied offset's, as :func:`lever_arm`), with the residuals,
    the samples they read and their bias Jacobian there (``fit``: :meth:`Consistency.at_shift`). ``cost``: the fit's
    trimmed mean squared residual, ``axes``: how many axes it fitted. ``arm`` (:func:`_arm_jacobian`): the same
    fit with the lever arm fitted too, under ``with_arm`` (:func:`lever_arm_sentence` reads the scales so)."""
    base, read, jac = fit
    d = _velocity_displacements(c, shift, read, base)
    # only the pairs whose span the velocity's samples cover: across a gap of the odometry (samples lost) the velocity
    # is interpolated, its noise held over the gap: 70 % of a 10 Hz odometry lost at random (seed=4392, gaps up to
    # 2.3 s) gave a ground robot's lateral axis a "motion" of held noise, read 0.276x as far "in km/h?"
    if not covered.all():
        base, d, jac, c = base[covered], d[covered], jac[covered], _PairsOf(c, covered)
        arm = None if arm is None else arm[covered]
    out = _scale_fit(c, d, base, jac)
    return out if arm is None else {**out, "with_arm": _scale_fit(c, d, base, np.concatenate([arm, jac], axis=2))}


def _scale_fit(c: Consistency, d: np.ndarray, base: np.ndarray, jac: np.ndarray) -> dict:
    """:func:`velocity_scale`'s fit of the axes' displacements ``d`` with the columns ``jac`` (the bias's, the
    lever arm's too where given); no scale (``cost`` None) with fewer pairs than the fit's unknowns and three."""
    if base.shape[0] < jac.shape[2] + 3:  # fewer pairs than the fit's unknowns at most
        none = [None] * 3
        return {"scale": none, "sigma": none, "dilution": [0.0] * 3, "fitted": none, "cost": None, "axes": 0}
    rms = np.sqrt(np.einsum("mcj,mcj->j", d, d) / max(1, d.shape[0]))
    moved = rms >= MIN_AXIS_SHARE * rms.max() if rms.max() > 0.0 else np.zeros(3, np.bool_)
    a = np.concatenate([-d[:, :, moved], jac], axis=2)  # (pairs, 3, unknowns)
    x, sigma, cost, keep, ata = _trimmed_fit(base, a)
    inv = np.linalg.inv(ata)
    inflation = np.diag(inv) * np.diag(ata)
    # taken off with each axis's own level where it is below the axes' mean (each is an upper bound of its white noise:
    # motion the rate does not resolve adds to it; the mean pools the axes' scatter, ±10 % at velocity noise x100):
    # a slow stream's axis whose samples' level is such motion (a hand-held's bob at 5 Hz, 8x the white level) no
    # longer dilutes the others' (the mean put 0.49 on seed=3347's x, as fitted 0.976, read 1.92x); left unsaid, as
    # before, where the mean dilutes it over MAX_SCALE_DILUTION, and where its own level does. The mean is pooled from
    # the white levels: a folded axis's samples' level in it diluted x over 0.5 on 17 of 21 hand-held logs at 3-5 Hz,
    # where a velocity 2x off then went unsaid (docs/benchmarks.md, "A velocity scale on a slow odometry")
    density, spans = np.asarray(c.source.velocity_density, float), c.det_t[c.b[keep]] - c.det_t[c.a[keep]]
    white = np.asarray(c.source.velocity_white_density, float)
    white = np.where(white > 0.0, white, density)
    per_q2, q2 = float(np.sum(spans)) * np.diag(inv)[: int(moved.sum())], np.square(density)[moved]
    mean_dilution = float(np.mean(np.square(white))) * per_q2
    dilution, most = np.minimum(q2 * per_q2, mean_dilution), np.maximum(q2 * per_q2, mean_dilution)
    scale, err, diluted, fitted = [None] * 3, [None] * 3, [0.0] * 3, [None] * 3
    # the displacement along each axis the detections see (its scale times the velocity's): an axis along which they
    # see the body hardly move (MIN_AXIS_SHARE) has a velocity as read that is noise, and no measurable scale
    seen = np.abs(1.0 + x[: int(moved.sum())]) * rms[moved]
    for i, j in enumerate(np.flatnonzero(moved)):
        diluted[j] = round(float(dilution[i]), 4)
        if inflation[i] <= MAX_SCALE_INFLATION and seen[i] >= MIN_AXIS_SHARE * seen.max():
            if most[i] <= MAX_SCALE_DILUTION:
                kept = 1.0 - float(dilution[i])
                scale[j], err[j] = round((1.0 + float(x[i])) / kept, 6), float(sigma[i]) / kept
                fitted[j] = round(1.0 + float(x[i]), 6)
    return {"scale": scale, "sigma": err, "dilution": diluted, "fitted": fitted, "cost": cost, "axes": int(moved.sum())}


def _covered_pairs(c: Consistency, shift: float) -> np.ndarray:
    """Per detection pair (at the detection shift ``shift``): whether no gap of the velocity's own samples
    (``AlignedStream.velocity_gaps``: intervals over ``alignment.GAP_FACTOR`` median intervals, messages lost) lies
    within its span, so the velocity it integrates is the samples', not their interpolation across the gap."""
    gaps = c.source.velocity_gaps
    covered = np.ones(c.a.shape[0], np.bool_)
    if gaps.shape[0] == 0:
        return covered
    g0, g1 = c.source.seconds(gaps[:, 0]), c.source.seconds(gaps[:, 1])
    ta, tb = c.det_t[c.a] + shift, c.det_t[c.b] + shift
    # a pair spans a gap where the gap starts before the pair's end and ends after its start (gaps sorted, disjoint)
    first = np.searchsorted(g1, ta, side="right")  # the first gap ending after the pair's start
    inside = first < g0.shape[0]
    covered[inside] = g0[first[inside]] >= tb[inside]
    return covered


class _PairsOf:
    """The detection pairs ``keep`` of a :class:`Consistency`: what :func:`velocity_scale` reads of them (the
    stream, the detections' times and each pair's two ends)."""

    def __init__(self, c: Consistency, keep: np.ndarray) -> None:
        self.source, self.det_t, self.a, self.b = c.source, c.det_t, c.a[keep], c.b[keep]


def velocity_misread(scale: dict) -> list[str]:
    """What the scales say of the velocity's axes that are off (``VELOCITY_SCALE_OFF``, ``VELOCITY_SCALE_SIGMAS``),
    one phrase each: the axis, the factor and the unit it suggests; an axis whose scale as fitted (before its
    dilution is taken off, ``fitted``) is inside the band is not named."""
    return [phrase for phrase, _ in _misread_axes(scale)]


def _misread_axes(scale: dict) -> list[tuple[str, float]]:
    """:func:`velocity_misread`'s phrases, each with its axis's factor."""
    out = []
    fitted = scale.get("fitted") or scale["scale"]  # as fitted, before the dilution is taken off
    for axis, g, e, g0 in zip("xyz", scale["scale"], scale["sigma"], fitted, strict=True):
        if (
            g is None
            or 1.0 / VELOCITY_SCALE_OFF <= g <= VELOCITY_SCALE_OFF
            or 1.0 / VELOCITY_SCALE_OFF <= (g if g0 is None else g0) <= VELOCITY_SCALE_OFF
            or abs(g - 1.0) <= VELOCITY_SCALE_SIGMAS * e
        ):
            continue
        hint = next((what for f, what in VELOCITY_MISREADS if abs(g / f - 1.0) < 0.25), "in another unit or scale?")
        out.append((f"along {axis} {g:.3g}x as far as its velocity says (± {e:.2g}: {hint})", g))
    return out


def common_scale(scale: dict) -> dict | None:
    """The factor every fitted axis's scale says alike (``COMMON_SCALE_AXES``, ``COMMON_SCALE_OFF``,
    ``VELOCITY_SCALE_SIGMAS``): ``{"scale", "sigma", "axes"}``, the axes' inverse-variance weighted mean, its standard
    error and the axes' phrases (``x 1.08 ± 0.012``); None where fewer axes are fitted, an axis is off on the other
    side of 1, or the mean is within ``COMMON_SCALE_OFF`` or ``VELOCITY_SCALE_SIGMAS`` standard errors of 1, as fitted
    or with the dilution taken off (the truth lies between the two: :func:`velocity_scale`)."""
    fitted = scale.get("fitted") or scale["scale"]
    axes = [
        (axis, g, e, g if g0 is None else g0)
        for axis, g, e, g0 in zip("xyz", scale["scale"], scale["sigma"], fitted, strict=True)
        if g is not None
    ]
    if len(axes) < COMMON_SCALE_AXES:
        return None
    w = np.array([1.0 / e**2 for _, _, e, _ in axes])
    sigma = float(1.0 / np.sqrt(np.sum(w)))
    means = [float(np.sum(w * np.array([a[k] for a in axes])) / np.sum(w)) for k in (1, 3)]
    sides = {g > 1.0 for _, g, _, g0 in axes for g in (g, g0)}
    if len(sides) > 1 or any(
        1.0 / COMMON_SCALE_OFF <= g <= COMMON_SCALE_OFF or abs(g - 1.0) <= VELOCITY_SCALE_SIGMAS * sigma for g in means
    ):
        return None
    return {"scale": means[0], "sigma": sigma, "axes": ", ".join(f"{a} {g:.3g} ± {e:.2g}" for a, g, e, _ in axes)}


#: The velocity's lag against the angular velocity (two topics only: one odometry message's twist has one stamp):
#: searched over ``±VELOCITY_LAG_MAX_S`` in ``VELOCITY_LAG_STEP_S`` steps; named (not applied) when the detections
#: fit the velocity moved by it ``VELOCITY_LAG_GAIN`` times better than as stamped, it is at least
#: ``VELOCITY_LAG_MIN_S`` and inside the search (docs/benchmarks.md "Clock offsets on real logs (session 18,
#: h-tagoff)": 1.20x for an odometry stamped 80-90 ms late on a generated figure 8, 1.00x clean).
VELOCITY_LAG_MAX_S = 0.2
VELOCITY_LAG_STEP_S = 0.02
VELOCITY_LAG_GAIN = 1.1
VELOCITY_LAG_MIN_S = 0.02


def velocity_lag(c: Consistency, shift: float) -> dict | None:
    """How late the linear velocity's stamps look against the angular velocity's: the detection pairs' cost (at
    the detection shift ``shift``, the bias profiled out) with the velocity read ``lag`` seconds later, over a grid
    (the best refined by a parabola through it and its neighbours; the bias's Jacobian is ``c``'s; the positions
    of all lags in one pass, :func:`lagged_positions`); None when both come from one topic.
    ``{"lag_s", "gain", "edge"}``: the lag of least cost, the cost as stamped over the cost there, and whether
    it is at the edge of the grid."""
    if not getattr(c.stream, "two_twist_topics", False):
        return None
    lags = np.arange(-VELOCITY_LAG_MAX_S, VELOCITY_LAG_MAX_S + VELOCITY_LAG_STEP_S / 2, VELOCITY_LAG_STEP_S)
    t_s, rot_s, _, omega, vel = c.poses
    at = np.searchsorted(t_s, c.det_t[np.concatenate([c.a, c.b])] + shift, side="right") - 1
    keep = np.unique(np.clip(at, 0, t_s.shape[0] - 1))  # the samples the pairs read at this shift
    omega_steps, _, dt = c._steps
    still = np.zeros(dt.shape[0], np.bool_)
    still[c.stream.segment_starts - 1] = True  # the steps across a gap (or a cut: :func:`_read_only`)
    moved = np.empty((lags.shape[0], keep.shape[0], 3))
    lagged_positions(t_s, rot_s, omega_steps, vel, dt, still, lags, keep, moved)
    costs = np.empty(lags.shape[0])
    for k, lag in enumerate(lags):
        twist = np.column_stack([np.interp(t_s[keep] + lag, t_s, vel[:, a]) for a in range(3)])
        lagged = c.varied(poses=(t_s[keep], rot_s[keep], moved[k], omega[keep], twist))
        costs[k] = lagged.costs(shift)[0]
    j = int(np.argmin(costs))
    zero = int(np.argmin(np.abs(lags)))
    lag = float(lags[j])
    if 0 < j < lags.shape[0] - 1:
        c0, c1, c2 = costs[j - 1 : j + 2]
        curv = c0 - 2.0 * c1 + c2
        if curv > 0:
            lag += 0.5 * VELOCITY_LAG_STEP_S * (c0 - c2) / curv
    return {
        "lag_s": round(float(lag), 4),
        "gain": float(costs[zero] / max(costs[j], 1e-300)),
        "edge": j in (0, lags.shape[0] - 1),
    }


@njit(cache=True, nogil=True)
def lagged_positions(t, rot, omega, vel, dt, still, lags, keep, out):
    """``out[l, q]``: the position at sample ``keep[q]`` (sorted) dead-reckoned with the rotations ``rot`` of the
    samples (times ``t``), the steps' angular velocities ``omega`` and lengths ``dt`` and the velocity ``vel`` read
    ``lags[l]`` seconds later (linear between samples, the first and last held beyond: ``np.interp``'s), the steps
    ``still`` not moving (segment gaps): ``P_(i+1) = P_i + R_i J_l(dt ω_i) v_i dt``, the rotations not depending on
    the velocity; every lag in one pass over the steps. Public: tests/test_riekf_exactness.py checks it against a
    dead reckoning per lag."""
    n_lag, n = lags.shape[0], t.shape[0]
    pos, at = np.zeros((n_lag, 3)), np.zeros(n_lag, np.int64)
    jl, jr, m = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    q = 0
    for i in range(dt.shape[0] + 1):
        while q < keep.shape[0] and keep[q] == i:
            out[:, q] = pos
            q += 1
        if q == keep.shape[0] or i == dt.shape[0]:
            break
        if still[i]:
            continue
        h = dt[i]
        so3_jacobians_into(omega[i, 0] * h, omega[i, 1] * h, omega[i, 2] * h, jl, jr)
        for a in range(3):
            for b in range(3):
                m[a, b] = (rot[i, a, 0] * jl[0, b] + rot[i, a, 1] * jl[1, b] + rot[i, a, 2] * jl[2, b]) * h
        for k in range(n_lag):
            x = t[i] + lags[k]
            j = at[k]
            while j < n and t[j] <= x:
                j += 1
            at[k] = j
            if j == 0:
                v0, v1, v2 = vel[0, 0], vel[0, 1], vel[0, 2]
            elif j == n:
                v0, v1, v2 = vel[n - 1, 0], vel[n - 1, 1], vel[n - 1, 2]
            else:
                f = (x - t[j - 1]) / (t[j] - t[j - 1])
                v0 = vel[j - 1, 0] + f * (vel[j, 0] - vel[j - 1, 0])
                v1 = vel[j - 1, 1] + f * (vel[j, 1] - vel[j - 1, 1])
                v2 = vel[j - 1, 2] + f * (vel[j, 2] - vel[j - 1, 2])
            for a in range(3):
                pos[k, a] += m[a, 0] * v0 + m[a, 1] * v1 + m[a, 2] * v2


#: Velocity samples the pairs read (:func:`_read_only`) past which the checks that dead-reckon them once per trial
#: (:func:`gyro_misreads`, :func:`velocity_lag`) read the log's first this many only, where they hold ``MIN_PAIRS``
#: detection pairs (a misread axis or a stamping lag is the same all along): the lag's 21 dead reckonings of the
#: whole hour's 720,000 samples cost 1.5 CPU s and made riekf's filter stage 1.67 -> 2.5 s wall on the one-hour log,
#: where the checks run beside the filter; the misreads' four, 0.27 CPU s and 1.67 -> 1.75-1.84 s (session 19).
#: Since the pairs come from stretches of a long log (:func:`_in_blocks`), the hour's read 44,640 samples: none.
PREFIX_SAMPLES = 1 << 17


def _prefix_of(c: Consistency) -> Consistency:
    """``c``, or when its pairs read more than ``PREFIX_SAMPLES`` velocity samples (:func:`_read_only`) the pairs'
    cost on the log's first that many when they hold ``MIN_PAIRS`` pairs or more."""
    if c.stream.vel_t_ns.shape[0] <= PREFIX_SAMPLES:
        return c
    from slamobs.pipeline.alignment import TimeWindow, windowed

    t = c.source.vel_t_ns
    end = int(t[PREFIX_SAMPLES - 1])
    head = Consistency(windowed(c.source, TimeWindow(None, end, int(t[0]), (None, None)), "log prefix"), c.bias)
    return head if head.a.shape[0] >= MIN_PAIRS else c


def velocity_lag_sentence(lag: dict | None, pairs: int) -> str | None:
    """The sentence naming a lag between the velocity streams (:func:`velocity_lag`), or None when there is none
    to name."""
    if not lag or lag["edge"] or lag["gain"] < VELOCITY_LAG_GAIN or abs(lag["lag_s"]) < VELOCITY_LAG_MIN_S:
        return None
    late = "late" if lag["lag_s"] > 0 else "early"
    return (
        f"the linear velocity's stamps look {abs(lag['lag_s']):.3f} s {late} against the angular velocity's: the "
        f"detections fit it {lag['gain']:.3g}x better so moved ({pairs} detection pairs, trimmed mean squared "
        "residual; a topic stamped with its record time, or on another clock?): stamp both at the measurement"
    )


def _decided(c: Consistency, stream) -> tuple[float, float, float, list[float], str | None, float]:
    """The search's best shift, its standard error, cost gain and indistinct span (:func:`_search`), why it is
    not applied (None: it is; module docstring): the rule both :func:`estimate` and :func:`decide` apply; and the
    shift :func:`estimate`'s velocity scale and lever arm read the pairs at: the applied one, or the search's own
    where only its lag held it back (:func:`hold_lag`: the pairs' dead reckoning holds each sample until the next,
    so at zero shift it reads the motion half an interval late; on a hand-held rig with IMU and twist both at 4 Hz,
    seed=9957, that lag, 0.125 s, read the lateral velocity as 10.9x, 1.31 at the search's 0.124 s) or only the
    log's halves (:func:`_halves_disagree`: the offset is found, the pairs read best there; at zero shift a detection
    latency of 0-0.3 s per frame, seed=4126, read its lag as a lateral scale of -6.36x, sending the user to the tag
    size), else zero."""
    shift, sigma, gain, span = _search(c)
    why, lagged, lag = None, False, hold_lag(c.stream)
    if abs(shift) >= (reach := _reach(c.stream)) - COARSE_S:
        why = f"the best shift is at the edge of the search (±{reach:g} s)"
    elif not abs(shift) > MIN_SIGMAS * sigma:
        why = f"within {MIN_SIGMAS:g} standard errors of zero"
    elif abs(shift) < MIN_APPLY_S:
        why = f"below {MIN_APPLY_S} s"
    elif 0.0 < shift <= lag + MIN_SIGMAS * sigma:
        why = (
            f"within the search's own lag ({lag:.4f} s, half the velocity samples' median interval: it holds each "
            f"sample until the next, the estimators interpolate) and {MIN_SIGMAS:g} standard errors of zero"
        )
        lagged = True
    elif gain < MIN_GAIN:
        why = f"the detections fit it only {gain:.3g}x better than no shift"
    elif (over_lag := _gain_over_lag(c, shift, lag)) < MIN_GAIN:
        why = f"the detections fit it only {over_lag:.3g}x better than the search's own lag ({lag:.4f} s)"
        lagged = True
    else:  # only an offset about to be applied pays for the check of the halves
        why = _halves_disagree(c, stream)
        lagged = True  # applied or held back by the halves alone, the offset found is where the pairs read best
    return shift, sigma, gain, span, why, shift if why is None or lagged else 0.0


def _gain_over_lag(c: Consistency, shift: float, lag: float) -> float:
    """The cost at the search's own lag (:func:`hold_lag`: the shift it finds on a log with no offset) over the cost
    at its best ``shift``: how much better the detections fit the offset than no offset as the search sees it. A
    misread velocity scale pulls the best shift a few ms off the lag at any rate: on a 4 Hz rig past the lag's
    standard errors (seed=9957's hand-held rig, its twist read x0.5: +0.133 s ± 0.0008 against a 0.125 s lag, 1.07x
    better than the lag; the same misread on a 200 Hz rig: +0.009 s, 1.11x better than zero)."""
    if lag <= 0.0:
        return np.inf
    at_lag, at_shift = c.costs(np.array([lag, shift]))
    return float(at_lag) / max(float(at_shift), 1e-300)


def _record(stream, n: int) -> dict:
    """The record's fields known before the search: the pairs, the topics, the alignment's turned gyro (which its
    misreads name) and the seconds the IMU's stamps were moved by (:func:`odometry_late`)."""
    return {
        "estimate_s": None,
        "sigma_s": None,
        "pairs": n,
        "applied": False,
        "topics": dict(stream.topics),
        "gyro_turn": getattr(stream, "gyro_turn", None),
        "gyro_moved_s": float(getattr(stream, "gyro_moved_s", 0.0)),
        "sampling": sampling_record(stream),
    }


def _searched(out: dict, shift: float, sigma: float, gain: float, span: list[float], why: str | None) -> dict:
    """``out`` with the search's result and the decision (:func:`_decided`)."""
    out = {**out, "estimate_s": round(shift, 6), "sigma_s": sigma, "cost_gain": gain}
    if gain < MIN_GAIN and abs(shift) > MIN_SIGMAS * sigma:  # the σ says significant, the costs say not: no σ
        out.update({"sigma_s": None, "indistinct_s": span})
    return {**out, "applied": why is None, **({"why_not_applied": why} if why else {})}


def _too_few(stream, n: int) -> str | None:
    """Why there is no search (too few pairs, or velocity samples), or None."""
    if n < MIN_PAIRS or stream.vel_t_ns.shape[0] < 2:
        return f"{n} detection pairs of one landmark within {PAIR_MAX_S} s"
    return None


def decide(stream) -> dict:
    """The offset and whether it is applied, by :func:`estimate`'s rule, without the checks that only report (the
    gyro's and velocity's misreads, the camera's turn, the lever arm, the velocity lag: what the observers, which
    need only the decision, leave to the run's camera check): the observers' record (run.json
    ``observer.time_offset``, :func:`found_note`). Bounded on a long log as :func:`estimate` is (``MAX_PAIRS`` pairs
    from ``BLOCKS`` stretches)."""
    if not stream.det_idx.shape[0] or stream.vel_t_ns.shape[0] < 2:  # nothing to pair or to dead-reckon
        return {**_record(stream, 0), "why_not_applied": _too_few(stream, 0)}
    c = Consistency(held_stamps(stream), np.zeros(6))  # the search holds each sample: means from their starts
    out = _record(stream, int(c.a.shape[0]))
    if (why := _too_few(stream, out["pairs"])) is not None:
        return {**out, "why_not_applied": why}
    return _searched(out, *_decided(c, stream)[:5])


def estimate(stream, bias: np.ndarray | None = None, decided=None) -> dict:
    """The offset (seconds to add to the detection stamps), its standard error, the pairs used and whether it is
    reliable enough to apply (module docstring); ``bias`` ``[b_Ω, b_V]`` is taken off the odometry (a seed's).
    ``decided``, when given, is called with ``{"applied", "estimate_s"}`` as soon as they are known, before the
    checks that only report (``gyro_misreads``, ``velocity_scale``), so that a caller waiting for whether the offset
    is applied (:class:`Background`) need not wait for those."""
    c = Consistency(held_stamps(stream), np.zeros(6) if bias is None else np.asarray(bias, dtype=float))
    out = _record(stream, int(c.a.shape[0]))
    if (why := _too_few(stream, out["pairs"])) is not None:
        return {**out, "why_not_applied": why}
    shift, sigma, gain, span, why, at = _decided(c, stream)
    if decided is not None:
        decided({"applied": why is None, "estimate_s": round(shift, 6)})
    # the velocity scale and the lever arm read the pairs at ``at`` (:func:`_decided`), the velocity lag at the applied
    # shift: at the search's own lag it fitted a velocity in km/h's misfit as a lag (seed=3637, IMU at 4 Hz and twist
    # at 5 Hz, the twist x3.6: "0.149 s late", 1.19x; 1.00x at zero shift)
    head, applied = _prefix_of(c), shift if why is None else 0.0
    fit = c.at_shift(at)  # the residuals and bias Jacobian there, for the velocity scale and the lever arm both
    out["gyro_misreads"] = gyro_misreads(head)
    arm = _arm_jacobian(c, at)
    covered = _covered_pairs(c, at)  # one selection: the pairs the velocity scale and the lever arm both fit
    out["velocity_scale"] = velocity_scale(c, at, fit, covered, arm)
    if velocity_misread(out["velocity_scale"]):  # which of the two causes, where an accelerometer can tell
        out["accel_scale"] = velocity_scale_by_accel(stream)
    out["extrinsic_turn"] = extrinsic_turn(c)
    # not where an axis turn is named (it says the camera's turn already), nor on constant motion, where no velocity
    # axis's scale is fitted: a small turn is a velocity scale across axes, a bias there too (a generated circle fits
    # 5 deg 3.8-4.5x better, its extrinsic right)
    fitted = any(f is not None for f in out["velocity_scale"]["fitted"])
    named = out["extrinsic_turn"]["gain"] >= EXTRINSIC_TURN_GAIN
    out["small_turn"] = small_turn(c) if fitted and not named else None
    out["world_twist"] = world_twist(c)
    # only where a turned or misread velocity is in question (a clean log's run pays nothing for it)
    if (
        out["extrinsic_turn"]["gain"] >= EXTRINSIC_TURN_GAIN
        or out["world_twist"]["gain"] >= WORLD_TWIST_GAIN
        or velocity_misread(out["velocity_scale"])
    ):
        out["twist_turn"] = twist_turn(c)
    out["lever_arm"] = lever_arm(c, at, fit, arm, out["velocity_scale"], covered)
    out["camera_turned"] = camera_turned(out)  # the flag the report and the run's camera check read
    out["velocity_lag"] = velocity_lag(head, applied)
    return _searched(out, shift, sigma, gain, span, why)


class Background:
    """:func:`estimate` on a thread of its own (its compiled loops release the GIL), for an estimator that starts on
    the stamps as recorded meanwhile (``riekf``: the estimate is applied on few logs); :meth:`decision` waits for
    whether it is applied, :meth:`result` for all of it. Without a second core it runs at once, in the caller's
    thread. The thread is a daemon that writes nothing: an interrupted run does not wait for it, and a killed one
    leaves nothing behind."""

    def __init__(self, stream) -> None:
        self._value: dict | None = None
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._decision: dict | None = None
        self._decided = threading.Event()
        if cores() < 2:
            self._value = estimate(stream)
            return
        self._thread = threading.Thread(target=self._run, args=(stream,), name="time-offset", daemon=True)
        self._thread.start()

    def _run(self, stream) -> None:
        try:
            self._value = estimate(stream, decided=self._decide)
        except BaseException as err:  # handed to the caller by result()
            self._error = err
        finally:
            self._decided.set()

    def _decide(self, decision: dict) -> None:
        self._decision = decision
        self._decided.set()
        lower_this_thread()  # the reporting checks left are a helper's beside the filter (which waited for this only)

    def done(self) -> bool:
        """Whether the estimate (or its error) is there: :meth:`result` returns at once."""
        return self._thread is None or not self._thread.is_alive()

    def decided(self) -> bool:
        """Whether :meth:`decision` returns at once."""
        return self._thread is None or self._decided.is_set()

    def decision(self) -> dict:
        """``{"applied", "estimate_s"}`` of the estimate (all of it when it ended before the reporting checks),
        waited for only until they are known (:func:`estimate`'s ``decided``); the estimate's error raised here."""
        if self._thread is not None:
            self._decided.wait()
        return self._decision if self._decision is not None else self.result()

    def result(self) -> dict:
        """The estimate (as :func:`estimate` returns it), once it is done; its error raised here."""
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._error is not None:
            raise self._error
        return self._value


def shifted(stream, offset: dict):
    """The stream with its detection stamps moved by the offset when it is applied, else the stream itself."""
    if not offset["applied"]:
        return stream
    return replace(stream, det_t_ns=stream.det_t_ns + int(round(offset["estimate_s"] * 1e9)))


#: The tables whose rows carry a detection's stamp as the estimate used it (moved onto the velocity clock when an
#: offset is applied), and those that keep the stamps as recorded (run.json ``output.clock``).
MOVED_TABLES = ("innovations", "landmark_tracks")
RECORDED_TABLES = ("tag_detections", "landmarks")


def output_clock(offset: dict | None) -> dict:
    """run.json ``output.clock``: the clock a run's stamps are on, decided here for every estimator. The poses and
    biases are at the velocity samples, on their clock (the output grid is theirs, and a run's report searches its
    truth's clock against those samples: ``truth_clock_offset``); an applied offset (``offset``: the estimate's
    record: :func:`estimate`'s or :func:`decide`'s, None where there is none) moved the detection stamps onto it by
    ``detections_moved_s``, and ``MOVED_TABLES`` carry the moved stamps, ``RECORDED_TABLES`` the recorded ones
    (``t_recorded = t - detections_moved_s``). Kept on the velocity clock, not moved back onto the detections': on
    the real logs where an offset is applied the APE moved by at most 0.005 m either way on MR.CLAM and by the
    pairing's noise on TagSLAM test_22 (docs/benchmarks.md, session 26)."""
    moved = float(offset["estimate_s"]) if offset is not None and offset.get("applied") else 0.0
    return {
        "stamps": "velocity",
        "detections_moved_s": moved,
        "moved_tables": list(MOVED_TABLES),
        "recorded_tables": list(RECORDED_TABLES),
    }


#: What the estimate used, said of the warnings after which it is whole (on the odometry's clock, of the
#: odometry's point, with a camera a few degrees off: :func:`odometry_late`, :func:`lever_arm_sentence`,
#: :func:`small_turn`), which :func:`misread` does not count.
WHOLE_ESTIMATES = ("the odometry's clock", "its twist", "the camera's extrinsic")


def misread(offset: dict | None) -> bool:
    """Whether the detection pairs named a misread input (a :func:`note` warning: the gyro, the camera extrinsic or
    a velocity axis): an estimate on it is likely lost, and its landmarks' innovations jump with its pose. The
    odometry's clock (:func:`odometry_late`) and a lever arm (:func:`lever_arm_sentence`) are not: the estimate
    is whole, on another clock or another point."""
    return offset is not None and any(used not in WHOLE_ESTIMATES for _, used in _misreads(offset))


def camera_turned(offset: dict | None) -> bool:
    """Whether the detection pairs name the camera's extrinsic turned or inverted (the :data:`CAMERA_ADVICE`
    warning): the detections fit ``EXTRINSIC_TURN_GAIN`` times better turned and no gyro misread is named (a gyro of
    the wrong sign fits as well turned). Public: :func:`estimate` records it as ``camera_turned``, which the report
    (``sections.camera_named_notes``) and the run's camera check read instead of searching the notes' words."""
    if not offset:
        return False
    turn = offset.get("extrinsic_turn") or {"gain": 0.0}
    if turn["gain"] * TWIST_TURN_TIE < _twist_turn_gain(offset):  # the twist turned fits clearly better
        return False
    return turn["gain"] >= EXTRINSIC_TURN_GAIN and not _best_misread(offset.get("gyro_misreads") or {})


def _small_turn_named(offset: dict) -> dict | None:
    """The small turn (:func:`small_turn`) the camera's warning names where no axis turn is (:func:`camera_turned`,
    which it leaves unset: a few degrees do not turn the estimate's frame against the truth's), by its rule: no gyro
    misread named, the twist turned not clearly better."""
    small = offset.get("small_turn")
    if not small or camera_turned(offset) or _best_misread(offset.get("gyro_misreads") or {}):
        return None
    return None if small["gain"] * TWIST_TURN_TIE < _twist_turn_gain(offset) else small


def camera_named(offset: dict | None) -> bool:
    """Whether the camera's warning names the detections turned (an axis turn, :func:`camera_turned`, or a small
    turn, :func:`small_turn`): batch's fit of the sensor's position (``pipeline.smoother.extrinsic``) then applies
    no shift and adds no sentence of its own (one cause, one message)."""
    return bool(offset) and (camera_turned(offset) or _small_turn_named(offset) is not None)


def _misreads(offset: dict) -> list[tuple[str, str]]:
    """What the detection pairs say is misread, one ``(sentence, what the estimate used)`` each: the sentence
    without an estimator's name or the run's tail, which :func:`note` adds ("it" / "them" as read). Each sentence
    ends with the topics (and the camera frame) it is about (``alignment.stream_topics``)."""
    from slamobs.pipeline.alignment import stream_topics

    topics = offset.get("topics") or {}
    best = _best_misread(offset.get("gyro_misreads") or {})
    # the alignment's turned gyro, when the misread the pairs fit best undoes that same turn: one cause, named once
    seen = bool(best) and _same_turn(GYRO_MISREADS[best[0][0]], offset.get("gyro_turn"))
    found = [
        (
            f"the detections fit the odometry {gain:.3g}x better {what} ({offset['pairs']} detection pairs, trimmed "
            "mean squared residual): "
            + (
                _gyro_turn_seen(offset["gyro_turn"], what)
                if seen
                else "check the gyro's unit and axes" + (MIRROR_ADVICE if what == SIGN_FLIPPED else "")
            ),
            "it",
            ("gyro", "odometry", "detections"),
        )
        for what, gain in best
    ]
    upset = GYRO_TURN_UPSETS if seen else ""  # the velocity's scale is read along the gyro's dead-reckoned heading
    turn = offset.get("extrinsic_turn") or {"gain": 0.0}
    # only where the gyro reads right (a gyro of the wrong sign, or mirrored detections, fit as well turned by 180
    # deg about a horizontal axis: 57-138x on generated figure 8s and ground robots; in deg/s the detections fit
    # turned 2.3-7.1x better), and before the velocity's scale, which a turned camera also upsets
    twist = _twist_turn_gain(offset)
    small = _small_turn_named(offset)
    if camera_turned(offset) or small:  # found holds the gyro's misread at most: none named here
        alike = (
            f", or the odometry's twist given in a frame turned from the body's (a robot driving backwards: the pairs "
            f"fit its twist turned {twist:.3g}x better; on this motion the two fit alike)"
            if twist
            else ""
        )
        how = (
            "its stated rotation a few degrees off: the estimates stay near, their uncertainty too small, NEES high"
            if small
            else "turned about one of its axes, or given as the inverse transform"
        )
        turn = small or turn
        found.append(
            (
                f"the detections fit the odometry {turn['gain']:.3g}x better turned {turn_phrase(turn['rotvec_deg'])} "
                f"({offset['pairs']} detection pairs, trimmed mean squared residual): {CAMERA_ADVICE} ({how}){alike}",
                WHOLE_ESTIMATES[2] if small and not twist else "it",
                ("detections", "camera", "odometry") if twist else ("detections", "camera"),
            )
        )
    elif twist and not found:  # the turn is the twist's alone: the world frame's and the velocity's scale follow
        twisted = turn_phrase(offset["twist_turn"]["rotvec_deg"])
        return [
            (
                f"the detections fit the odometry {twist:.3g}x better with its twist turned {twisted} "
                f"({offset['pairs']} detection pairs, trimmed mean squared residual): its twist is in a frame turned "
                "from the body's (nav_msgs/Odometry gives it in child_frame_id; a robot driving backwards, or the "
                "twist of another link): check the odometry's frame and axes at its driver"
                + stream_topics(topics, "odometry"),
                "it",
            )
        ]
    world = (offset.get("world_twist") or {"gain": 0.0})["gain"]
    if world >= WORLD_TWIST_GAIN and not found:  # the dead-reckoned heading is the gyro's: only where it reads right
        # the velocity's scale on each axis is then a consequence: not said besides
        return [(_world_twist_sentence(offset, world) + stream_topics(topics, "odometry"), "it")]
    arm = lever_arm_sentence(offset)
    scale, lag = offset.get("velocity_scale"), offset.get("velocity_lag")
    arm_named = arm is not None and not found
    if arm_named:  # the rotations are the gyro's: only where it reads right (as world_twist)
        found.append((arm, WHOLE_ESTIMATES[1], ("odometry", "detections", "camera")))
        # the lag and the scales the arm explains are not said (arm_explains); the scales are those fitted with it
        explained = arm_explains(offset)
        lag = None if "lag" in explained else lag
        # where it explains a scale, the scales said are those fitted with it (an arm named by its gain alone leaves
        # them as fitted without it)
        scale = scale["with_arm"] if scale and "scale" in explained else scale
    late = odometry_late(offset, topics.get("linear_velocity", "ODOMETRY"))
    if late is not None:
        found.append((late, WHOLE_ESTIMATES[0], ("gyro", "odometry", "detections")))
    lag = velocity_lag_sentence(lag, offset["pairs"])
    if lag is not None:
        found.append((lag, "them", ("gyro", "odometry")))
    # the accelerometer's scale rides on the gyro's attitude: not where the gyro is misread or turned
    accel = None if best or seen else offset.get("accel_scale")
    found += [
        (
            f"the detections say the body moved {what} ({offset['pairs']} detection pairs, the odometry's bias fitted "
            f"with it): {scale_cause(g, accel, SCALE_CAUSES)}{upset}",
            "them",
            ("odometry", "detections", "camera"),
        )
        # none on a log of too few pairs (:func:`estimate` returns before its checks)
        for what, g in (_misread_axes(scale) if scale else [])
    ]
    # with the arm named, a scale common to the axes is judged on the scales fitted with it: the arm moves the pairs
    # as a scale does (a point 0.5 m beside a figure 8's body read without it as x 0.84)
    judged = scale.get("with_arm") or scale if arm_named and scale else scale
    common = common_scale(judged) if judged and not _misread_axes(scale) else None
    if common is not None:  # inside VELOCITY_SCALE_OFF on every axis, but every axis off alike
        found.append(
            (
                f"the detections say the body moved {common['scale']:.3g}x as far as its velocity says on every axis "
                f"the pairs fit ({common['axes']}; {offset['pairs']} detection pairs, the odometry's bias fitted with "
                f"it): {scale_cause(common['scale'], accel, SCALE_CAUSES)}{upset}",
                "them",
                ("odometry", "detections", "camera"),
            )
        )
    return [(sentence + stream_topics(topics, *names), used) for sentence, used, names in found]


#: An applied detection offset within this of the seconds the alignment moved the IMU's stamps by (plus
#: ``ODOMETRY_LATE_SIGMAS`` of its standard error) says the detections agree with the IMU as stamped: the odometry
#: is the stream off (:func:`odometry_late`). Twice the gyro lag's fine grid (``alignment.GYRO_LAG_FINE_S``);
#: a generated figure 8 with its odometry 85 ms late: +0.0850 s applied against +0.085 moved.
ODOMETRY_LATE_TOLERANCE_S = 0.01
ODOMETRY_LATE_SIGMAS = 3.0


def odometry_late(offset: dict, topic: str = "ODOMETRY") -> str | None:
    """The warning that the odometry, not the IMU, is stamped off, when the alignment moved the IMU's stamps onto
    the odometry's clock (``gyro_moved_s``) and the detections needed the same move (the offset applied within
    ``ODOMETRY_LATE_TOLERANCE_S``): two streams of three agree as stamped, and the estimate (on the odometry's
    clock) is that much off theirs. Its poses are not moved: the run's clock is the velocity samples' (a generated
    figure 8, the odometry 85 ms late: riekf 0.180 m against 0.011 m with the report's truth-clock offset applied);
    None otherwise. ``topic``: the odometry's, which the advice names."""
    moved = float(offset.get("gyro_moved_s") or 0.0)
    if moved == 0.0 or not offset.get("applied"):
        return None
    est, sigma = float(offset["estimate_s"]), float(offset.get("sigma_s") or 0.0)
    if abs(est - moved) > ODOMETRY_LATE_TOLERANCE_S + ODOMETRY_LATE_SIGMAS * sigma:
        return None
    late = "late" if moved > 0 else "early"
    return (
        f"the detections needed the same {est:+.4f} s (± {sigma:.2g}) the IMU's stamps were moved by onto the "
        f"odometry's clock ({moved:+.3f} s): the IMU and the detections agree as stamped, so the odometry is the "
        f"stream stamped {abs(moved):.3f} s {late}, not the IMU, and the poses (on its clock) are {abs(moved):.3f} s "
        f"{late} against the IMU's and the detections' clock (the report's truth-clock offset shows it: `slamobs "
        "report RUN_DIR --t-offset auto` applies it): correct the odometry's stamps at the driver (or time.topics: "
        f"{{{topic}: record}} if its record times are right)"
    )


def _best_misread(gains: dict[str, float]) -> list[tuple[str, float]]:
    """The gyro misread the detection pairs fit best, when over ``GYRO_MISREAD_GAIN`` (one at most: on a generated
    ground robot whose gyro has the wrong sign, or whose detections are mirrored, its yaw rate swapped into x also
    fits better than as read, 6.2-6.3x, against 92-258x with the sign undone)."""
    best = max(gains.items(), key=lambda item: item[1], default=("", 0.0))
    return [best] if best[1] >= GYRO_MISREAD_GAIN else []


def _same_turn(undo: np.ndarray, gyro_turn: dict | None) -> bool:
    """Whether a gyro misread's undoing (``GYRO_MISREADS``' matrix) takes the gyro's axis of the alignment's turned
    gyro (``AlignedStream.gyro_turn``) onto the odometry's within ``alignment.GYRO_AXIS_WARN_DEG``: the pairs then
    see the turn the alignment measured, of which an axis swap is the nearest misread they try."""
    from slamobs.pipeline.alignment import GYRO_AXIS_WARN_DEG

    if not gyro_turn:
        return False
    moved = np.asarray(undo, dtype=float) @ np.asarray(gyro_turn["gyro_axis"], dtype=float)
    cos = abs(float(moved @ np.asarray(gyro_turn["odometry_axis"], dtype=float))) / max(np.linalg.norm(moved), 1e-300)
    return cos >= np.cos(np.radians(GYRO_AXIS_WARN_DEG))


def _gyro_turn_seen(gyro_turn: dict, what: str) -> str:
    """What the gyro-misread warning says when it sees the alignment's turned gyro (:func:`_same_turn`), the misread
    ``what`` (a ``GYRO_MISREADS`` key) the nearest."""
    from slamobs.pipeline.alignment import GYRO_TURN_ADVICE

    return GYRO_TURN_SEEN.format(
        topic=gyro_turn["topic"],
        angle=gyro_turn["angle_deg"],
        nearest=NEAREST_MISREAD.get(what, "a swap of two axes"),
        advice=GYRO_TURN_ADVICE.format(frame=gyro_turn["frame"]),
    )


def _world_twist_sentence(offset: dict, gain: float) -> str:
    return (
        "the odometry's twist looks like it is in a world frame, not the body's (nav_msgs/Odometry gives it in "
        f"child_frame_id): the detections fit it {gain:.3g}x better turned into the body by the dead-reckoned heading "
        f"({offset['pairs']} detection pairs, trimmed mean squared residual; a twist in the odometry's own parent "
        "frame is turned into the body when read, one in another frame is not): publish the twist in child_frame_id"
    )


def note(name: str | None, offset: dict) -> list[str]:
    """The run's note on the offset when it was applied (run.json ``observer.time_offset`` has it always), its
    warning when only the log's halves held it back (:func:`unapplied_note`: every estimator decides by the one rule,
    so every one says it), and :func:`misread_warnings`; ``name`` None: the held-back offset's warning and the
    misread warnings, as ``slamobs info --noise`` says them before any estimator runs (the same sentences, without an
    estimator's name and what it used)."""
    if name is None:
        return unapplied_note(None, offset) + [f"warning: {sentence}" for sentence, _ in _misreads(offset)]
    said = misread_warnings(name, offset)
    if not offset["applied"]:
        return unapplied_note(name, offset) + said
    return [
        f"{name}: detection stamps moved by {offset['estimate_s']:+.4f} s (± {offset['sigma_s']:.2g}) onto the "
        f"velocity clock, estimated from the data ({offset['pairs']} detection pairs; docs/observers.md, Time "
        "offset): applied",
        *said,
    ]


def misread_warnings(name: str, offset: dict) -> list[str]:
    """The warnings of an angular velocity the detections say is misread (``gyro_misreads``), a camera extrinsic
    they say is turned (``extrinsic_turn``), a twist they say is in a world frame (``world_twist``; then no velocity
    scale is said), a lag between the velocity streams (``velocity_lag``) and a velocity axis they say is scaled
    (``velocity_scale``), each with what the estimate ``name`` did about it (none from :func:`decide`'s record,
    which has no such checks)."""
    return [f"warning: {name}: {sentence}; the estimate used {used} as read" for sentence, used in _misreads(offset)]


def unapplied_note(name: str | None, offset: dict) -> list[str]:
    """The warning of an offset found but not applied: the search's best clear of zero and of its own lag, fitting
    at least ``MIN_GAIN`` times better than none, held back only by the log's halves disagreeing (the checks run in
    that order: :func:`estimate`), which a clock that drifts or an offset that changes mid-log gives. Every estimator
    judges it by this one rule (:func:`decide`, :func:`estimate`) and says this (:func:`note`), so none applies it:
    the warning says what was found and why not, for the stamps to be corrected at their source. Nothing otherwise
    (no offset, or one applied: :func:`note`). ``name`` None: without an estimator's name (``slamobs info --noise``)."""
    why = offset.get("why_not_applied") or ""
    if offset["applied"] or not why.startswith(HALVES_DISAGREE):
        return []
    est, sigma = float(offset["estimate_s"]), offset["sigma_s"]
    late, who = "late" if est < 0 else "early", f"{name}: " if name else ""
    return [
        f"warning: {who}the detection stamps look {abs(est):.3f} s {late} against the velocity clock "
        f"({est:+.4f} s ± {sigma:.2g} to add, {offset['pairs']} detection pairs; docs/observers.md, Time offset), "
        f"not applied: {why}; every estimator applies an offset by this one rule, so none does here: an offset that "
        "drifts or changes mid-log wants the detections' stamps corrected at their source"
    ]
