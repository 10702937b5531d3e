"""The time offset between the detection stream and the velocity streams, estimated from the data (the reference
estimators riekf and batch use it; docs/observers.md, "Time offset").

Two detections of one landmark ``PAIR_SPAN_S`` to ``PAIR_MAX_S`` apart see the same point, and the odometry says
how the body moved between them. With the detection stamps moved by ``δ`` onto the velocity clock, the second
detection carried back through the odometry's motion between the two (shifted) times lands on the first at the
true offset; a wrong one shows as the change of the body's motion between the two ends, times ``δ`` (hence
pairs a second or more apart: over a short span a shift moves both ends alike). Each pair's residual is taken
in the body frame of its first detection, so only its own interval enters (not the drift over the log), and
the odometry's bias, which would otherwise pass for an offset, is fitted away at every shift (the residuals
are linear in a small bias change; their Jacobian is computed once). The estimate minimises the trimmed mean
of the squared residuals over a grid of shifts (``MAX_OFFSET_S`` either side, ``COARSE_S`` steps, then
``FINE_S`` steps around the best); its standard error comes from the cost's curvature there.

It is applied (the detection stamps moved by it before the estimator runs) only when it is reliable: at least
``MIN_PAIRS`` pairs, the minimum inside the grid, more than ``MIN_SIGMAS`` standard errors and at least
``MIN_APPLY_S`` away from zero, the cost at zero shift at least ``MIN_GAIN`` times the minimum, and the two halves
of the log (pairs split at the median time) giving estimates within ``HALVES_SIGMAS`` combined standard errors
of each other (a constant offset shows in both). Otherwise it is only reported.
"""

from __future__ import annotations

import threading

import numpy as np

from slamobs.pipeline.cores import cores
from slamobs.pipeline.kernel_cache import njit
from slamobs.pipeline.lie import (
    integrate_body_twists,
    integrate_body_twists_at,
    integrate_body_twists_at_columns,
    se3_exp_into,
)

PAIR_SPAN_S = 1.0
PAIR_MAX_S = 2.0
MAX_OFFSET_S = 0.5
COARSE_S = 0.02
FINE_S = 0.001
TRIM = 0.9
MIN_PAIRS = 30
MAX_PAIRS = 2000
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
    omega, vel = omega[:-1].copy(), vel[:-1].copy()
    gap = stream.segment_starts - 1
    omega[gap], vel[gap] = 0.0, 0.0
    return t, (omega, vel, dt)


def _pairs(stream) -> tuple[np.ndarray, np.ndarray]:
    """Detection indices (a, b): each detection and the first detection of the same landmark at least
    ``PAIR_SPAN_S`` later, when that one is within ``PAIR_MAX_S``."""
    t = np.repeat(stream.seconds(stream.det_t_ns), np.diff(stream.det_offsets))
    order = np.lexsort((t, stream.det_idx))
    key = stream.det_idx[order].astype(np.float64) * (2.0 * (t.max() - t.min() + PAIR_MAX_S) + 1.0) + t[order]
    j = np.searchsorted(key, key + PAIR_SPAN_S)  # sorted by landmark, then time: the partner is the next ≥ span
    ok = j < order.shape[0]
    a, b = order[ok], order[j[ok]]
    same = np.flatnonzero((stream.det_idx[a] == stream.det_idx[b]) & (t[b] - t[a] <= PAIR_MAX_S))
    if same.shape[0] > MAX_PAIRS:  # evenly over the log: the estimate's cost stays bounded on long logs
        same = same[np.linspace(0, same.shape[0] - 1, MAX_PAIRS).astype(np.int64)]
    return a[same], b[same]


@njit(cache=True)
def _pose_at(t_s, rot_s, pos_s, omega, vel, t, rot, pos, d_r, unused, lo):
    """The pose at time ``t``: sample ``k`` before it (the first one before the samples) carried on for
    ``h = t − t_k`` with its twist: ``R_k Exp(h ω_k)``, ``P_k + R_k h v_k`` (``d_r``, ``unused``: scratch).
    ``lo``: a guess of the first sample after ``t`` (walked from to the true one, which is returned)."""
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


class _Consistency:
    """The pairs' cost as a function of the shift, the odometry's bias profiled out."""

    def __init__(self, stream, bias: np.ndarray) -> None:
        self.stream, self.bias = stream, bias
        self.det_t = np.repeat(stream.seconds(stream.det_t_ns), np.diff(stream.det_offsets))
        self.a, self.b = _pairs(stream)
        self.y = stream.det_y
        self.poses = self._poses(bias)
        # the pairs' residuals move with the bias: their Jacobian (numerical, at zero shift, from the poses of
        # the samples the pairs read there only)
        base = self.residuals(0.0)[0]
        t_s = self.poses[0]
        at = np.searchsorted(t_s, self.det_t[np.concatenate([self.a, self.b])], side="right") - 1
        self.keep = keep = np.unique(np.clip(at, 0, t_s.shape[0] - 1))  # the samples the pairs read
        self.jac = np.empty((base.shape[0], 3, 6))
        for c in range(3):
            db = np.zeros(6)
            db[c] = BIAS_STEP
            self.jac[:, :, c] = (self.residuals(0.0, self._moved_poses(bias + db, c, keep))[0] - base) / BIAS_STEP
        for c, poses in enumerate(self._moved_velocity_poses(bias, keep), 3):
            self.jac[:, :, c] = (self.residuals(0.0, poses)[0] - base) / BIAS_STEP
        self.jtj = np.einsum("kci,kcj->kij", self.jac, self.jac)

    def _poses(self, bias: np.ndarray):
        """The samples' times, poses and bias-corrected twists; the integrator's inputs are kept for
        :meth:`_moved_poses`."""
        s = self.stream
        omega, vel = s.omega - bias[:3], s.velocity - bias[3:]
        t, self._steps = _sample_steps(s, omega, vel)
        return (t, *integrate_body_twists(np.eye(3), np.zeros(3), *self._steps), omega, vel)

    def _moved_poses(self, bias: np.ndarray, c: int, keep: np.ndarray):
        """:meth:`_poses` (the samples ``keep`` only) with ``bias``, which differs from the first poses' in entry
        ``c`` only: the twists copied and that column computed again (the same numbers as from scratch)."""
        s, t_s, _, _, omega, vel = self.stream, *self.poses
        twists, steps = [omega[keep], vel[keep]], [self._steps[0], self._steps[1]]
        w, j = divmod(c, 3)
        raw = (s.omega, s.velocity)[w][:, j] - bias[c]
        twists[w][:, j] = raw[keep]
        steps[w] = steps[w].copy()
        steps[w][:, j] = raw[:-1]
        steps[w][s.segment_starts - 1, j] = 0.0
        poses = integrate_body_twists_at(np.eye(3), np.zeros(3), *steps, self._steps[2], keep)
        return (t_s[keep], *poses, *twists)

    def _moved_velocity_poses(self, bias: np.ndarray, keep: np.ndarray) -> list[tuple]:
        """:meth:`_moved_poses` for each velocity-bias entry (3..5) moved by ``BIAS_STEP``, the three in one dead
        reckoning (their rotations are the first poses' and shared: the same numbers as three calls)."""
        s, t_s, _, _, omega, vel = self.stream, *self.poses
        cols = s.velocity[:-1] - (bias[3:] + BIAS_STEP)  # entry j of bias + BIAS_STEP e_(3+j), as _moved_poses
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

    def subset(self, keep: np.ndarray) -> _Consistency:
        """The same consistency over the pairs ``keep`` (a mask) only."""
        out = object.__new__(_Consistency)
        out.__dict__.update(self.__dict__)
        out.a, out.b, out.jac, out.jtj = self.a[keep], self.b[keep], self.jac[keep], self.jtj[keep]
        return out

    def costs(self, shifts) -> np.ndarray:
        """:meth:`cost` at each of ``shifts``, the residuals of all of them computed in one pass."""
        return np.array([self.cost(e) for e in self.residuals(shifts)])

    def cost(self, e: np.ndarray) -> float:
        """Trimmed mean squared residual of the pairs' residuals ``e`` at one shift after the bias correction
        that fits the pairs best (least squares on all pairs, then again on the ``TRIM`` share with the smallest
        residuals)."""
        keep = np.arange(e.shape[0])
        for _ in range(2):  # normal equations (6 unknowns; a small ridge keeps them regular on straight motion)
            a = self.jtj[keep].sum(axis=0) + 1e-9 * np.eye(6)
            db = np.linalg.solve(a, -np.einsum("kci,kc->i", self.jac[keep], e[keep]))
            d2 = np.sum((e + self.jac @ db) ** 2, axis=1)
            n = max(1, int(TRIM * d2.shape[0]))
            keep = np.argpartition(d2, n - 1)[:n]
        return float(np.mean(d2[keep]))


def _search(c: _Consistency) -> tuple[float, float, float]:
    """The shift of least cost on the grid (coarse, then fine around the best), its standard error from the
    curvature there, and the cost at zero over the cost there."""
    coarse = np.arange(-MAX_OFFSET_S, MAX_OFFSET_S + COARSE_S / 2, COARSE_S)
    best = float(coarse[int(np.argmin(c.costs(coarse)))])
    fine = best + np.arange(-COARSE_S, COARSE_S + FINE_S / 2, FINE_S)
    fine_costs = c.costs(fine)
    j = int(np.argmin(fine_costs))
    shift, c_min = float(fine[j]), float(fine_costs[j])
    curv = np.polyfit(fine - shift, fine_costs, 2)[0]  # cost ≈ c_min + curv (δ − shift)²
    sigma = float(np.sqrt(c_min / (c.a.shape[0] * curv))) if curv > 0 else np.inf
    return shift, sigma, float(c.costs(0.0)[0]) / max(c_min, 1e-300)


def _halves_disagree(c: _Consistency, stream) -> str | None:
    """Why the two halves of the log (the pairs by the time of their first detection) do not give one offset
    within ``HALVES_SIGMAS`` combined standard errors, or None: a constant offset shows in both."""
    t = np.repeat(stream.seconds(stream.det_t_ns), np.diff(stream.det_offsets))[c.a]
    first = t < np.median(t)
    found = [_search(c.subset(part)) for part in (first, ~first)]
    (s1, e1, _), (s2, e2, _) = found
    if abs(s1 - s2) > HALVES_SIGMAS * np.hypot(e1, e2):
        return f"the log's halves disagree ({s1:+.4f} ± {e1:.2g} s and {s2:+.4f} ± {e2:.2g} s)"
    return None


#: Angular velocities a log may hold misread, as the factor that would undo it: the sign (a left-handed or
#: upside-down gyro), degrees per second (the ROS unit is rad/s).
GYRO_MISREADS = {
    "with its angular velocity's sign flipped": -1.0,
    "with its angular velocity divided by 57.3 (deg/s?)": float(np.radians(1.0)),
}
#: A turn of the wrong sign is also what mirrored detections show (one axis of the camera frame flipped: a
#: left-handed extrinsic, a bearing of the wrong sign): to the pairs a mirror and a flipped gyro are the same, on a
#: robot that does not move sideways exactly (MR.CLAM 6 r1 with its bearings negated: the sign flip 8.35x better).
MIRROR_ADVICE = (
    ", or whether the detections are mirrored (an axis of their frame flipped: a left-handed camera extrinsic, a "
    "bearing of the wrong sign), which the detections cannot tell from it"
)
#: A misread is named when the pairs' trimmed mean squared residual with the angular velocity so undone is this
#: many times smaller than as read (MR.CLAM 6 r1 as recorded: 2.4x and 8.6x larger; in deg/s 712x smaller, its
#: sign flipped 8.6x smaller).
GYRO_MISREAD_GAIN = 4.0


def _trimmed_cost(e: np.ndarray) -> float:
    d2 = np.sum(e**2, axis=1)
    n = max(1, int(TRIM * d2.shape[0]))
    return float(np.mean(np.partition(d2, n - 1)[:n]))


def gyro_misreads(c: _Consistency) -> dict[str, float]:
    """How many times better the detection pairs fit the odometry with its angular velocity undone by each of
    ``GYRO_MISREADS`` than as read (no bias fitted: a misread dwarfs a bias): the angular velocity in deg/s or of
    the wrong sign is no noise the estimators can absorb (MR.CLAM in deg/s: riekf APE 0.49 -> 3.8 m, no word)."""
    omega_steps, vel_steps, dt = c._steps
    t_s, *_, omega, vel = c.poses
    base = _trimmed_cost(c.residuals(0.0)[0])
    out = {}
    for what, g in GYRO_MISREADS.items():
        poses = (t_s, *integrate_body_twists(np.eye(3), np.zeros(3), omega_steps * g, vel_steps, dt), omega * g, vel)
        out[what] = base / max(_trimmed_cost(c.residuals(0.0, poses)[0]), 1e-300)
    return out


#: A velocity axis's scale is named when the detections put it outside ``1 / VELOCITY_SCALE_OFF .. VELOCITY_SCALE_OFF``
#: times the velocity as read and more than ``VELOCITY_SCALE_SIGMAS`` standard errors from 1 (MR.CLAM's ten robots
#: as recorded: 0.84-1.09, ± 0.04-0.08; 6 r1 in km/h: 0.25 ± 0.02, of the wrong sign: -0.92; its ranges in cm:
#: 116 ± 12, the detections' unit this time).
VELOCITY_SCALE_OFF = 1.5
VELOCITY_SCALE_SIGMAS = 5.0
#: An axis's scale is left unsaid when fitting the bias with it inflates its variance more than this (constant
#: motion, where a scale and a bias are the same change: the simulator's circle 300-1,300,000; MR.CLAM 4-29, the
#: figure 8 and the ground robot 1-26).
MAX_SCALE_INFLATION = 100.0
#: An axis's scale is fitted only where the body's displacement along it is at least this share of the largest
#: axis's (RMS over the pairs): along a ground robot's or a figure 8's lateral axis (shares 0.02-0.045) the velocity
#: as read is mostly noise and its fitted scale is too (-1.45 ± 0.34 on a generated ground robot); a figure 8's or a
#: loop's vertical axis (0.06-0.11) is fitted to ± 0.004-0.011.
MIN_AXIS_SHARE = 0.05
#: Units a velocity may be misread in, as the scale the detections would find, with what to say of it.
VELOCITY_MISREADS = (
    (-1.0, "of the wrong sign"),
    (1.0 / 3.6, "in km/h?"),
    (0.3048, "in ft/s?"),
    (0.01, "in cm/s?"),
    (0.001, "in mm/s?"),
)


def _velocity_displacements(c: _Consistency) -> np.ndarray:
    """Per pair and velocity axis (pairs, 3, 3): how the pair's residual moves when that axis's velocity is
    doubled (the displacement it contributes between the two detections, in the first one's body frame), so that
    scaling the axes by ``g`` moves the residuals by ``-Σ_j (g_j - 1) D[:, :, j]`` (the rotations do not depend on
    the velocity: the relation is exact)."""
    (t_s, _, _, omega, vel), keep = c.poses, c.keep
    omega_steps, vel_steps, dt = c._steps
    rs, ps = integrate_body_twists_at_columns(np.eye(3), np.zeros(3), omega_steps, vel_steps, 2.0 * vel_steps, dt, keep)
    base = c.residuals(0.0)[0]
    out = np.empty((base.shape[0], 3, 3))
    for j in range(3):
        twist = vel[keep]
        twist[:, j] *= 2.0
        out[:, :, j] = base - c.residuals(0.0, (t_s[keep], rs, ps[j], omega[keep], twist))[0]
    return out


def velocity_scale(c: _Consistency) -> dict:
    """The factor per velocity axis that makes the odometry's motion between the pairs' detections fit them
    best, with its standard error: ``x`` = [g - 1, bias change] minimising the trimmed squared residuals
    ``base - D (g - 1) + J δb`` (the odometry's bias fitted with it, as :meth:`_Consistency.cost`). An axis along
    which the body hardly moves (``MIN_AXIS_SHARE``) has no scale (None), nor one whose scale is not told from a
    bias (its variance inflated over ``MAX_SCALE_INFLATION`` times by the bias fit: a constant velocity). The velocity
    in another unit or of the wrong sign on an axis is no noise the estimators can absorb (MR.CLAM 6 r1 in km/h:
    riekf 0.49 -> 0.89 m, with its sign flipped: lost, and no word of the velocity)."""
    d = _velocity_displacements(c)
    base = c.residuals(0.0)[0]
    rms = np.sqrt(np.einsum("mcj,mcj->j", d, d) / max(1, d.shape[0]))
    moved = rms >= MIN_AXIS_SHARE * rms.max() if rms.max() > 0.0 else np.zeros(3, np.bool_)
    a = np.concatenate([-d[:, :, moved], c.jac], axis=2)  # (pairs, 3, unknowns)
    keep = np.arange(base.shape[0])
    for _ in range(3):  # least squares on all pairs, then twice on the TRIM share with the smallest residuals
        ata = np.einsum("mci,mcj->ij", a[keep], a[keep]) + 1e-9 * np.eye(a.shape[2])
        x = np.linalg.solve(ata, -np.einsum("mci,mc->i", a[keep], base[keep]))
        d2 = np.sum((base + a @ x) ** 2, axis=1)
        n = max(1, int(TRIM * d2.shape[0]))
        keep = np.argpartition(d2, n - 1)[:n]
    ata = np.einsum("mci,mcj->ij", a[keep], a[keep]) + 1e-9 * np.eye(a.shape[2])
    sigma = np.sqrt(np.diag(np.linalg.inv(ata)) * float(np.mean(d2[keep])) / 3.0)
    inflation = np.diag(np.linalg.inv(ata)) * np.diag(ata)
    scale, err = [None] * 3, [None] * 3
    for i, j in enumerate(np.flatnonzero(moved)):
        if inflation[i] <= MAX_SCALE_INFLATION:
            scale[j], err[j] = round(1.0 + float(x[i]), 6), float(sigma[i])
    return {"scale": scale, "sigma": err}


def velocity_misread(scale: dict) -> list[str]:
    """What the scales say of the velocity's axes that are off (``VELOCITY_SCALE_OFF``, ``VELOCITY_SCALE_SIGMAS``),
    one phrase each: the axis, the factor and the unit it suggests."""
    out = []
    for axis, g, e in zip("xyz", scale["scale"], scale["sigma"], strict=True):
        if (
            g is None
            or 1.0 / VELOCITY_SCALE_OFF <= g <= VELOCITY_SCALE_OFF
            or abs(g - 1.0) <= VELOCITY_SCALE_SIGMAS * e
        ):
            continue
        hint = next((what for f, what in VELOCITY_MISREADS if abs(g / f - 1.0) < 0.25), "in another unit or scale?")
        out.append(f"along {axis} {g:.3g}x as far as its velocity says (± {e:.2g}: {hint})")
    return out


def estimate(stream, bias: np.ndarray | None = None) -> dict:
    """The offset (seconds to add to the detection stamps), its standard error, the pairs used and whether it is
    reliable enough to apply (module docstring); ``bias`` ``[b_Ω, b_V]`` is taken off the odometry (a seed's)."""
    c = _Consistency(stream, np.zeros(6) if bias is None else np.asarray(bias, dtype=float))
    n = int(c.a.shape[0])
    out = {"estimate_s": None, "sigma_s": None, "pairs": n, "applied": False}
    if n < MIN_PAIRS or stream.vel_t_ns.shape[0] < 2:
        return {**out, "why_not_applied": f"{n} detection pairs of one landmark within {PAIR_MAX_S} s"}
    out["gyro_misreads"] = gyro_misreads(c)
    out["velocity_scale"] = velocity_scale(c)
    shift, sigma, gain = _search(c)
    out.update({"estimate_s": round(shift, 6), "sigma_s": sigma, "cost_gain": gain})
    why = None
    if abs(shift) >= MAX_OFFSET_S - COARSE_S:
        why = f"the best shift is at the edge of the search (±{MAX_OFFSET_S} s)"
    elif not abs(shift) > MIN_SIGMAS * sigma:
        why = f"within {MIN_SIGMAS:g} standard errors of zero"
    elif abs(shift) < MIN_APPLY_S:
        why = f"below {MIN_APPLY_S} s"
    elif gain < MIN_GAIN:
        why = f"the detections fit it only {gain:.3g}x better than no shift"
    else:  # only an offset about to be applied pays for the check of the halves
        why = _halves_disagree(c, stream)
    return {**out, "applied": why is None, **({"why_not_applied": why} if why else {})}


class Background:
    """:func:`estimate` on a thread of its own (its compiled loops release the GIL), for an estimator that starts on
    the stamps as recorded meanwhile (``riekf``: the estimate is applied on few logs); :meth:`result` waits for it.
    Without a second core it runs at once, in the caller's thread. The thread is a daemon that writes nothing: an
    interrupted run does not wait for it, and a killed one leaves nothing behind."""

    def __init__(self, stream) -> None:
        self._value: dict | None = None
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        if cores() < 2:
            self._value = estimate(stream)
            return
        self._thread = threading.Thread(target=self._run, args=(stream,), name="time-offset", daemon=True)
        self._thread.start()

    def _run(self, stream) -> None:
        try:
            self._value = estimate(stream)
        except BaseException as err:  # handed to the caller by result()
            self._error = err

    def done(self) -> bool:
        """Whether the estimate (or its error) is there: :meth:`result` returns at once."""
        return self._thread is None or not self._thread.is_alive()

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
    from dataclasses import replace

    if not offset["applied"]:
        return stream
    return replace(stream, det_t_ns=stream.det_t_ns + int(round(offset["estimate_s"] * 1e9)))


def note(name: str, offset: dict) -> list[str]:
    """The run's note on the offset when it was applied (run.json ``observer.time_offset`` has it always), and on
    an angular velocity the detections say is misread (``gyro_misreads``)."""
    notes = [
        f"warning: {name}: the detections fit the odometry {gain:.3g}x better {what} "
        f"({offset['pairs']} detection pairs, trimmed mean squared residual): check the gyro's unit and axes"
        + (MIRROR_ADVICE if GYRO_MISREADS[what] < 0 else "")
        + "; the estimate used it as read"
        for what, gain in (offset.get("gyro_misreads") or {}).items()
        if gain >= GYRO_MISREAD_GAIN
    ]
    notes += [
        f"warning: {name}: the detections say the body moved {what} ({offset['pairs']} detection pairs, the "
        "odometry's bias fitted with it): check the velocity's unit and axes (and the detections'); the estimate used "
        "them as read"
        for what in velocity_misread(offset.get("velocity_scale") or {"scale": [], "sigma": []})
    ]
    if not offset["applied"]:
        return notes
    return [
        f"{name}: detection stamps moved by {offset['estimate_s']:+.4f} s (± {offset['sigma_s']:.2g}) onto the "
        f"velocity clock, estimated from the data ({offset['pairs']} detection pairs; docs/observers.md, Time "
        "offset): applied",
        *notes,
    ]
