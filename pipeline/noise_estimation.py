"""Noise levels estimated from a log's own samples (``noise: auto``): pure numerics over arrays, no I/O.

Velocity streams (angular and linear): each sample is predicted from its six neighbours by the quintic through
them at their own stamps (so jittered and irregular sampling is handled exactly), the prediction residual is
scaled by its white-noise gain ``sqrt(1 + Σ w²)`` and its robust spread (1.4826 · MAD) is the per-sample
standard deviation. A quintic follows the stream's own motion up to fifth order, so manoeuvres do not count as
noise; the cubic (four neighbours) is computed too and a large gap between the two is reported as motion
leaking in. The density is ``σ · sqrt(median period)``; the uncertainty is the spread of the estimate over 20
consecutive blocks of the stream (its standard error).

Detections: a landmark is static, so its detected position carried into a common frame by the velocities'
dead reckoning must stay put. Over three consecutive detections of one landmark the middle one minus the
linear interpolation of its neighbours (in time) cancels the landmark's position and any drift linear in
time (the biases); what is left is detection noise and the small odometry noise of the short dead-reckoning
between them (known from the velocity estimates and the time each velocity sample is held in the interval).
Its variance, ``Σ c_j² σ(r_j)² + odometry``, is fitted by variance-component estimation (Fisher scoring of the
Gaussian likelihood, outliers beyond 4 σ dropped and the fit repeated until stable) for two laws of σ against
range r: ``σ0 + k·r`` and ``b + a·r²``; the one with the higher likelihood is chosen.
The uncertainty is a bootstrap over the triplets. The same residuals split along the middle detection's line of
sight and across it give the ratio of the range's standard deviation to the bearing's (a stereo camera's or a
tag's depth is far worse than its direction), the law staying the mean over the three axes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from slamobs.pipeline.lie import integrate_body_twists, quats_to_rots, so3_exps

#: 1.4826 · MAD is the standard deviation of Gaussian samples.
MAD_TO_SIGMA = 1.4826
#: Blocks of a stream for the standard error of its noise estimate.
BLOCKS = 20
#: Triplets of detections span at most this long (s): dead reckoning is short and nearly linear in drift.
MAX_TRIPLET_S = 1.0
#: Residuals beyond this many standard deviations are outliers (mis-associations, missed motion).
OUTLIER_SIGMAS = 4.0
#: Before the first fit, a triplet whose residual is over this many times the median of the triplets at similar
#: range (one of ``GROSS_BINS`` range quantiles) is left out: a gross outlier (a detection carrying another
#: landmark's ID, a point at an absurd range) would otherwise widen the Gaussian fit until it is no longer beyond
#: 4 σ of it. Later rounds judge every triplet again against the fitted law. Two orders of magnitude: a real
#: log's heavy tail (MR.CLAM's slowly varying range errors and mis-associations, 10-100x) stays with the 4 σ rounds
#: (at 10x or 30x the laws of MR.CLAM 6-r2, 7-r3, 7-r4 moved and their riekf/batch APE by -24 to +41 %).
GROSS_FACTOR, GROSS_BINS = 100.0, 10
#: The median of a χ² variable of three degrees of freedom: the median of the residuals' ``|e|²``, each part
#: whitened by its share of the law, is this at the robust start's scale (:func:`robust_scale`).
CHI2_3_MEDIAN = 2.366
#: Bootstrap resamples of the detection-noise fit.
BOOTSTRAP = 20
#: At most this many triplets are fitted (a uniform subsample of longer logs).
MAX_TRIPLETS = 30_000
#: Longest run of velocity samples read at once; a longer log is read in ``WINDOWS`` evenly spaced windows of
#: this much in all (bounded memory and time on a log of hours, and still every part of it).
MAX_SAMPLES, WINDOWS = 400_000, 10
#: Fewest samples (velocity) or triplets (detections) an estimate is made from.
MIN_SAMPLES = 50
#: an axis whose samples repeat the previous value more often than this holds its values (commanded, quantised)
HELD_SHARE = 0.5
#: A white stream's density is the same from the means of consecutive pairs of its samples (half the variance at
#: half the rate; the two estimates agree within their few-% standard errors); motion faster than the stream's
#: rate resolves is not white: the samples' prediction residuals are that motion, folded onto frequencies no
#: quintic follows, and a pair's mean cancels most of it (a hand-held rig's 1.8 Hz step bob in a 4 Hz odometry's
#: vertical velocity: 15x the white density from the samples, 1.1x from the pairs). An axis whose pairs show a
#: density below this share of its samples' takes the pairs' (docs/noise.md, "Motion the rate does not resolve").
FOLDED_SHARE = 0.5
#: Samples per period of a stream's motion from which its linear interpolation resolves it (a common rule of thumb,
#: not fitted): an axis whose missed share of the rotation per interval, ``(2π/N)²/12`` for a sinusoid sampled ``N``
#: times a period, is smaller has no unresolved motion (``unresolved_motion_density``).
RESOLVED_SAMPLES = 10.0
#: The smallest detection standard deviation at zero range a fit gives (m): a law fitted on ranges far from zero
#: may reach zero there, and no detection is exact.
MIN_DETECTION_M = 1e-4
#: Share of the residuals' variance above which the dead reckoning's noise drowns the detections' (the law is
#: then said to be uncertain).
DOMINANT = 0.8
#: A range/across ratio closer to 1 than this share, or within this many standard errors of 1 (in log), is not
#: told from 1: the detections keep the same σ on every axis.
RATIO_CLOSE, RATIO_SIGMAS = 0.1, 3.0
#: The detection laws: name -> (the power of range the second coefficient multiplies, its key in noise.DEFAULTS)
LAWS = {"sigma0 + k*r": (1, "detection_per_m"), "b + a*r^2": (2, "detection_per_m2")}


@dataclass(frozen=True)
class Estimate:
    """One estimated level: its value (one number or one per axis), its standard error and how it was found."""

    value: np.ndarray | float
    uncertainty: np.ndarray | float
    method: str
    samples: int
    #: per axis: the samples hold their value (most repeat the previous one, or the residuals vanish), so no noise
    #: can be seen in them; their value is that of the other axes (the stream is unusable when every axis holds)
    held: tuple[bool, ...] = ()
    #: per axis, the samples' own density where an axis took its sample pairs' (``FOLDED_SHARE``), else None: the
    #: error a quantity built of these samples carries (the detection pairs' velocity-scale check)
    sampled: np.ndarray | None = None


@dataclass(frozen=True)
class DetectionLaw:
    """The detection noise against range: ``sigma(r) = base + slope * r**power`` (each with a standard error)."""

    law: str
    base: Estimate
    slope: Estimate
    power: int
    ranges: tuple[float, float]  # 5th and 95th percentile of the ranges it was fitted on, m
    other_loglik: float  # log-likelihood of the law not chosen minus this one's (negative: this one fits better)
    #: the factor the held streams' fit (``held_motion_noise``) put on the triplets' law for the detections' slow
    #: error (1: none)
    held_scale: float = 1.0

    def sigma(self, r) -> np.ndarray:
        return float(self.base.value) + float(self.slope.value) * np.asarray(r, dtype=float) ** self.power


def _neighbour_weights(t: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Lagrange weights predicting each sample from ``half`` neighbours either side at their own times, and the
    indices of the samples they are defined for: (N', 2 half), (N',)."""
    n = t.shape[0]
    centre = np.arange(half, n - half)
    offs = np.r_[np.arange(-half, 0), np.arange(1, half + 1)]
    tn = t[centre[:, None] + offs[None, :]] - t[centre][:, None]  # neighbour times relative to the sample
    w = np.ones_like(tn)
    for j in range(offs.size):
        for m in range(offs.size):
            if m != j:
                w[:, j] *= (0.0 - tn[:, m]) / (tn[:, j] - tn[:, m])
    return w, centre


def _prediction_residuals(t: np.ndarray, x: np.ndarray, half: int, max_step: float) -> np.ndarray:
    """Each sample minus its prediction from its neighbours, over the white-noise gain (N', axes); samples whose
    neighbours span a gap longer than ``max_step`` are left out."""
    w, centre = _neighbour_weights(t, half)
    offs = np.r_[np.arange(-half, 0), np.arange(1, half + 1)]
    pred = np.einsum("nj,nja->na", w, x[centre[:, None] + offs[None, :]])
    gain = np.sqrt(1.0 + np.sum(w * w, axis=1))
    span = t[centre + half] - t[centre - half]
    keep = span <= 2 * half * max_step
    return ((x[centre] - pred) / gain[:, None])[keep]


def _robust_sigma(z: np.ndarray) -> np.ndarray:
    """Per-column 1.4826 · MAD."""
    return MAD_TO_SIGMA * np.median(np.abs(z - np.median(z, axis=0)), axis=0)


def windows(n: int) -> list[tuple[int, int]]:
    """Index ranges read of ``n`` samples: all of them, or ``WINDOWS`` evenly spaced ones of ``MAX_SAMPLES`` in all."""
    if n <= MAX_SAMPLES:
        return [(0, n)]
    size = MAX_SAMPLES // WINDOWS
    return [(int(lo), int(lo) + size) for lo in np.linspace(0, n - size, WINDOWS)]


def median_rate(period_s: float) -> str:
    """A stream's rate as the noise levels use it, labelled (``10.09 Hz by the median interval``): one over the
    median interval between its stamps, which turns a per-sample level into a density. Public for ``noise`` and
    ``slamobs info --noise``: ``info``'s topic table gives a topic's rate as its count over its stamps' span
    (robot_localization's test1 odometry, whose intervals jitter: 10.09 Hz so, 9.99 Hz in the table)."""
    return f"{1.0 / period_s:.4g} Hz by the median interval"


def _residual_density(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, float, float] | None:
    """Per-axis density and its standard error from the quintic-prediction residuals of sorted, distinct stamps
    ``t``, the residuals counted, the cubic's leak and the median period; None when too short to tell."""
    if t.shape[0] < MIN_SAMPLES + 6:
        return None
    period = float(np.median(np.diff(t)))
    parts = windows(t.shape[0])
    z5 = np.concatenate([_prediction_residuals(t[lo:hi], x[lo:hi], 3, 3 * period) for lo, hi in parts])
    if z5.shape[0] < MIN_SAMPLES:
        return None
    sigma = _robust_sigma(z5)
    z3 = np.concatenate([_prediction_residuals(t[lo:hi], x[lo:hi], 2, 3 * period) for lo, hi in parts])
    leak = float(np.max(_robust_sigma(z3) / np.maximum(sigma, 1e-300)))
    blocks = np.array([_robust_sigma(b) for b in np.array_split(z5, BLOCKS)])
    se = blocks.std(axis=0, ddof=1) / np.sqrt(BLOCKS)
    return sigma * np.sqrt(period), se * np.sqrt(period), int(z5.shape[0]), leak, period


def _pair_means(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The means of consecutive pairs of samples within each window read (:func:`windows`; the last sample of an
    odd count left out), at their mean stamps: half as many samples as the quintic reads of the stream itself."""
    ts, xs = [], []
    for lo, hi in windows(t.shape[0]):
        n = (hi - lo) // 2 * 2
        ts.append(t[lo : lo + n].reshape(-1, 2).mean(axis=1))
        xs.append(x[lo : lo + n].reshape(-1, 2, x.shape[1]).mean(axis=1))
    return np.concatenate(ts), np.concatenate(xs)


def white_noise_density(t_s: np.ndarray, x: np.ndarray) -> Estimate | None:
    """Per-axis white-noise density (units · sqrt(s)) of the samples ``x`` (N, 3) at times ``t_s`` (N,), or None
    when the stream is too short to tell. An axis whose consecutive pairs' means show a density below
    ``FOLDED_SHARE`` of its samples' takes the pairs' (motion faster than the stream's rate resolves)."""
    order = np.argsort(t_s, kind="stable")
    t, x = np.asarray(t_s, float)[order], np.asarray(x, float)[order]
    keep = np.r_[True, np.diff(t) > 0]
    t, x = t[keep], x[keep]
    found = _residual_density(t, x)
    if found is None:
        return None
    density, se, samples, leak, period = found
    method = f"quintic-prediction residuals (MAD) at {median_rate(period)}"
    if leak > 1.2:
        method += f"; motion leaks into lower orders (cubic {leak:.2f}x higher)"
    repeats = np.mean(np.diff(x, axis=0) == 0.0, axis=0)
    held = (repeats > HELD_SHARE) | (density <= 1e-9 * np.sqrt(period) * np.maximum(1.0, np.max(np.abs(x), axis=0)))
    pairs, sampled = _residual_density(*_pair_means(t, x)), None
    if pairs is not None:
        folded = ~held & (pairs[0] < FOLDED_SHARE * density)
        if folded.any():
            method += (
                f"; {', '.join('xyz'[k] for k in np.flatnonzero(folded))} from the means of sample pairs, "
                f"{' / '.join(f'{r:.2g}' for r in pairs[0][folded] / density[folded])}x the samples' "
                "(motion faster than the stream's rate resolves, not white noise)"
            )
            sampled = density
            density, se = np.where(folded, pairs[0], density), np.where(folded, pairs[1], se)
    if held.any() and not held.all():  # e.g. a wheel odometry's lateral and vertical velocity, always zero
        density, se = np.where(held, np.max(density[~held]), density), np.where(held, np.max(se[~held]), se)
        sampled = None if sampled is None else np.where(held, np.max(sampled[~held]), sampled)
        method += f"; {', '.join('xyz'[k] for k in np.flatnonzero(held))} held, given the other axes' level"
    return Estimate(density, se, method, samples, tuple(held.tolist()), sampled)


def unresolved_motion_density(t_s: np.ndarray, x: np.ndarray, white) -> Estimate | None:
    """Per-axis density (units · sqrt(s)) of the motion a stream's rate does not resolve, or None when too short to
    tell: between two samples Δ s apart the linear interpolation of ``x`` misses ``Δ³ẍ/12`` of its integral (the
    trapezoid rule's error; ẍ from the samples' second divided differences at their own stamps), a variance density
    ``Δ⁵ẍ²/144`` per interval, averaged over the stream, less what the white noise ``white`` (per axis, the
    samples' :func:`white_noise_density`) puts there (``white²/24`` at an even rate). The rotation a 4 Hz twist misses
    of a walker's 0.6 Hz yaw wobble, where the stream resolves its motion 0: an axis sampled ``RESOLVED_SAMPLES`` or
    more times per period of its motion (its missed share per interval, the level over ``√Δ`` times the samples'
    standard deviation, is ``(ωΔ)²/12`` for a sinusoid of ``ω``; a 50 Hz gyro on that walker, a VIO's twist at 20-30
    Hz on a hand-held camera). Intervals over three median periods (gaps) are left out; the uncertainty is the
    spread over ``BLOCKS`` consecutive blocks. docs/noise.md, "Motion the rate does not resolve"."""
    t, x = np.asarray(t_s, float), np.asarray(x, float)
    step = np.diff(t)
    if not np.all(step > 0):  # the aligned streams' stamps are sorted and distinct: read in place
        order = np.argsort(t, kind="stable")
        t, x = t[order], x[order]
        keep = np.r_[True, np.diff(t) > 0]
        t, x = t[keep], x[keep]
        step = np.diff(t)
    if t.shape[0] < MIN_SAMPLES + 2:
        return None
    period = float(np.median(step))
    parts, sums = [], np.zeros((3, 3))  # per window: the v's, and the samples' count, sum and sum of squares
    for lo, hi in windows(t.shape[0]):
        h, xw = step[lo : hi - 1], x[lo:hi]
        slope = np.diff(xw, axis=0) / h[:, None]
        ha, hb = h[:-1], h[1:]
        acc = 2.0 * (slope[1:] - slope[:-1]) / (ha + hb)[:, None]
        span = 0.5 * (ha + hb)
        ok = np.maximum(ha, hb) <= 3.0 * period
        parts.append((span[ok, None] ** 5 * acc[ok] ** 2 / 144.0))
        sums += [np.full(3, hi - lo), xw.sum(axis=0), np.square(xw).sum(axis=0)]
    v = np.concatenate(parts)
    if v.shape[0] < MIN_SAMPLES:
        return None
    noise = np.broadcast_to(np.asarray(white, float), (3,)) ** 2 / 24.0
    level = np.sqrt(np.maximum(v.mean(axis=0) - noise, 0.0))
    spread = np.sqrt(np.maximum(sums[2] / sums[0] - (sums[1] / sums[0]) ** 2, 0.0))  # the samples' std read
    share = level / np.sqrt(period) / np.maximum(spread, 1e-300)
    per_period = 2.0 * np.pi / np.sqrt(12.0 * np.maximum(share, 1e-300))  # samples per period of the motion
    resolved = per_period >= RESOLVED_SAMPLES
    blocks = np.array([b.mean(axis=0) for b in np.array_split(v, BLOCKS)])
    se_var = blocks.std(axis=0, ddof=1) / np.sqrt(BLOCKS)
    se = se_var / (2.0 * np.maximum(level, np.sqrt(se_var)))
    method = (
        f"the trapezoid error Δ³ẍ/12 of the samples' linear interpolation at {median_rate(period)}, "
        f"its white part taken off; {' / '.join(f'{n:.3g}' if m > 0 else '-' for n, m in zip(per_period, level))} "
        "samples per period of the motion"
    )
    if resolved.any():
        method += f" ({', '.join('xyz'[k] for k in np.flatnonzero(resolved))} resolved from {RESOLVED_SAMPLES:g}: 0)"
    return Estimate(np.where(resolved, 0.0, level), np.where(resolved, 0.0, se), method, int(v.shape[0]))


def _poses_at(vel_t: np.ndarray, omega: np.ndarray, velocity: np.ndarray, t: np.ndarray):
    """Dead-reckoned body poses (R, P) at times ``t`` from the velocity samples (first-order within a step)."""
    rs, ps = integrate_body_twists(np.eye(3), np.zeros(3), omega[:-1], velocity[:-1], np.diff(vel_t))
    k = np.clip(np.searchsorted(vel_t, t, side="right") - 1, 0, vel_t.shape[0] - 1)
    h = t - vel_t[k]
    r = np.einsum("nij,njk->nik", rs[k], so3_exps(np.ascontiguousarray(omega[k] * h[:, None])))
    p = ps[k] + np.einsum("nij,nj->ni", rs[k], velocity[k] * h[:, None])
    return r, p


@dataclass(frozen=True)
class Triplets:
    """Second differences of static landmarks: residual components (K, 3), the weights c_j² of the three
    detections (K, 3), their ranges (K, 3), the odometry part of each residual's variance (K,) and the middle
    detection's line of sight in the residuals' frame (K, 3, unit)."""

    e: np.ndarray
    c2: np.ndarray
    r: np.ndarray
    motion_var: np.ndarray
    u: np.ndarray


def detection_triplets(
    vel_t: np.ndarray,
    omega: np.ndarray,
    velocity: np.ndarray,
    det_t: np.ndarray,
    det_offsets: np.ndarray,
    det_idx: np.ndarray,
    det_y: np.ndarray,
    gyro_density: float,
    velocity_density: float,
) -> Triplets:
    """Every three consecutive detections of one landmark within ``MAX_TRIPLET_S`` (times in s, body frame)."""
    t_of = np.repeat(det_t, np.diff(det_offsets))
    r_w, p_w = _poses_at(vel_t, omega, velocity, t_of)
    sight = np.einsum("nij,nj->ni", r_w, det_y)
    w = sight + p_w
    rng = np.linalg.norm(det_y, axis=1)
    order = np.lexsort((t_of, det_idx))
    lm, t, w, rng, sight = det_idx[order], t_of[order], w[order], rng[order], sight[order]
    i = np.flatnonzero((lm[:-2] == lm[2:]) & (t[2:] - t[:-2] <= MAX_TRIPLET_S) & (t[2:] > t[1:-1]) & (t[1:-1] > t[:-2]))
    gaps = np.cumsum(np.r_[0, np.diff(vel_t) > 0.5])
    span_ok = gaps[np.searchsorted(vel_t, t[i])] == gaps[np.minimum(np.searchsorted(vel_t, t[i + 2]), vel_t.size - 1)]
    i = i[span_ok]
    t1, t2, t3 = t[i], t[i + 1], t[i + 2]
    a = (t3 - t2) / (t3 - t1)
    e = w[i + 1] - (a[:, None] * w[i] + (1 - a)[:, None] * w[i + 2])
    c2 = np.stack([a * a, np.ones_like(a), (1 - a) ** 2], axis=1)
    r = np.stack([rng[i], rng[i + 1], rng[i + 2]], axis=1)
    period = float(np.median(np.diff(vel_t)))
    gq, vq = gyro_density**2 / period, velocity_density**2 / period  # per-sample variances
    held = _held_squares(vel_t, t1, t2), _held_squares(vel_t, t2, t3)
    motion = (
        c2[:, 0] * (vq + 2 / 3 * gq * r[:, 0] ** 2) * held[0] + c2[:, 2] * (vq + 2 / 3 * gq * r[:, 2] ** 2) * held[1]
    )
    return Triplets(e, c2, r, motion, sight[i + 1] / np.maximum(r[:, 1:2], 1e-300))


def _held_squares(vel_t: np.ndarray, ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
    """Σ over the velocity samples of (time each is held within [ta, tb])²: the dead reckoning's error variance
    over the interval per unit per-sample variance (Δt² within one sample, about Δt·T over many)."""
    csum = np.r_[0.0, np.cumsum(np.diff(vel_t) ** 2)]
    last = vel_t.shape[0] - 1
    ka = np.clip(np.searchsorted(vel_t, ta, side="right") - 1, 0, last)
    kb = np.clip(np.searchsorted(vel_t, tb, side="right") - 1, 0, last)
    inside = csum[kb] - csum[np.minimum(ka + 1, kb)]  # whole samples ka + 1 .. kb - 1
    ends = (vel_t[np.minimum(ka + 1, last)] - ta) ** 2 + (tb - vel_t[kb]) ** 2
    return np.where(ka == kb, (tb - ta) ** 2, inside + ends)


def log_triplets(vel_t, omega, velocity, det_t, det_offsets, det_idx, det_y, gyro_density, velocity_density):
    """:func:`detection_triplets` of the whole log, or of ``windows`` of its velocity samples on a long log."""
    parts = []
    for lo, hi in windows(vel_t.shape[0]):
        f0, f1 = np.searchsorted(det_t, [vel_t[lo], vel_t[hi - 1]])
        d0, d1 = det_offsets[f0], det_offsets[f1]
        parts.append(
            detection_triplets(
                vel_t[lo:hi],
                omega[lo:hi],
                velocity[lo:hi],
                det_t[f0:f1],
                det_offsets[f0 : f1 + 1] - d0,
                det_idx[d0:d1],
                det_y[d0:d1],
                gyro_density,
                velocity_density,
            )
        )
    return Triplets(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Triplets)))


def azimuths_from_degrees(det_t, det_offsets, det_idx, det_y) -> np.ndarray:
    """``det_y`` with each detection's azimuth (about its frame's z) read as degrees: unwrapped along its
    landmark's detections in time and divided by 57.3 (range and height kept). A bearing in degrees read as
    radians wraps 57.3x as fast as the landmark turns; read back, its detections are as smooth as a sensor's."""
    t = np.repeat(det_t, np.diff(det_offsets))
    az = np.arctan2(det_y[:, 1], det_y[:, 0])
    order = np.lexsort((t, det_idx))
    step = np.diff(az[order])
    step = (step + np.pi) % (2.0 * np.pi) - np.pi
    step[det_idx[order][1:] != det_idx[order][:-1]] = 0.0  # each landmark starts from its own first azimuth
    walked = np.r_[0.0, np.cumsum(step)]
    first = np.r_[0, np.flatnonzero(det_idx[order][1:] != det_idx[order][:-1]) + 1]
    counts = np.diff(np.r_[first, order.size])
    unwrapped = np.empty_like(az)
    unwrapped[order] = np.repeat(az[order][first] - walked[first], counts) + walked
    r = np.hypot(det_y[:, 0], det_y[:, 1])
    back = np.radians(unwrapped)
    return np.stack([r * np.cos(back), r * np.sin(back), det_y[:, 2]], axis=1)


def _variance(theta: np.ndarray, tri: Triplets, power: int) -> tuple[np.ndarray, np.ndarray]:
    """Each residual component's variance under ``sigma = theta0 + theta1 r^power`` and its Jacobian (K, 2)."""
    f = tri.r**power
    s = theta[0] + theta[1] * f
    v = np.sum(tri.c2 * s * s, axis=1) + tri.motion_var
    jac = np.stack([np.sum(2 * tri.c2 * s, axis=1), np.sum(2 * tri.c2 * s * f, axis=1)], axis=1)
    return v, jac


def _inliers(tri: Triplets, e2: np.ndarray, v: np.ndarray, ratio: float) -> np.ndarray:
    """The residuals within ``OUTLIER_SIGMAS`` of their variance ``v`` (K,: the law's mean over the axes plus the
    dead reckoning's): every component alike; with a range/bearing ``ratio`` other than 1, the part along the line
    of sight and each axis across it against their own shares of the law (``3ρ²/(ρ²+2)`` and ``3/(ρ²+2)``, as
    riekf weighs them), so that a steep range error is not trimmed at a bearing's spread (a stereo log's law came
    out 10-25 % low: its along-the-line part, nearly all of the variance, was cut at ~2.3 of its σ)."""
    if ratio == 1.0:
        return np.max(e2, axis=1) <= OUTLIER_SIGMAS**2 * v
    law, m = v - tri.motion_var, tri.motion_var
    along2, across2 = _along_across(tri, e2)
    k_along, k_across = _shares(ratio)
    pred_along, pred_across = k_along * law + m, k_across * law + m
    return (along2 <= OUTLIER_SIGMAS**2 * pred_along) & (across2 <= OUTLIER_SIGMAS**2 * pred_across)


def _shares(ratio: float) -> tuple[float, float]:
    """The law's variance (the mean over the axes) along the line of sight and on each axis across it at the
    range/bearing ``ratio``: ``3ρ²/(ρ²+2)`` and ``3/(ρ²+2)``, as riekf weighs them."""
    r2 = ratio * ratio
    return 3.0 * r2 / (r2 + 2.0), 3.0 / (r2 + 2.0)


def _along_across(tri: Triplets, e2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each residual's squared part along the middle detection's line of sight and its mean square per axis across."""
    along2 = np.sum(tri.e * tri.u, axis=1) ** 2
    return along2, (np.sum(e2, axis=1) - along2) / 2.0


def _not_gross(tri: Triplets) -> np.ndarray:
    """The triplets whose residual norm is within ``GROSS_FACTOR`` times the median of their range quantile."""
    norm = np.linalg.norm(tri.e, axis=1)
    keep = np.ones(norm.size, bool)
    for part in np.array_split(np.argsort(tri.r[:, 1], kind="stable"), min(GROSS_BINS, max(1, norm.size // 10))):
        keep[part] = norm[part] <= GROSS_FACTOR * np.median(norm[part])
    return keep


def _robust_start(tri: Triplets, ratio: float) -> np.ndarray:
    """The triplets that are not gross (:func:`_not_gross`) and within ``OUTLIER_SIGMAS`` of their range
    quantile's robust scale (:func:`robust_scale`), judged by :func:`_inliers`: ``GROSS_BINS`` quantiles of the
    median of a triplet's three ranges (a wild detection moved 1-3 m moves its range too: binned by the middle
    one's, the triplets it is the middle of gathered in the extreme quantiles, a majority there on a ground robot
    seeing 3-5 m, and their median was theirs). A wild detection sits in up to three triplets: a Gaussian fit on
    all of them before any is dropped came out 1.4-2.3x too wide at 5 % wild, and three 4 σ rounds from there did
    not bring it back (docs/noise.md, "Wild detections")."""
    scale = np.empty(tri.e.shape[0])
    r = np.median(tri.r, axis=1)  # one wild detection's range does not move its triplets to another quantile
    for part in np.array_split(np.argsort(r, kind="stable"), min(GROSS_BINS, max(1, scale.size // 10))):
        scale[part] = robust_scale(_subset(tri, part), ratio)
    return _not_gross(tri) & _inliers(tri, tri.e * tri.e, scale * np.sum(tri.c2, axis=1) + tri.motion_var, ratio)


def robust_scale(tri: Triplets, ratio: float = 1.0) -> float:
    """The law's variance per unit of a triplet's weights ``c2`` at which the median of the triplets' whitened
    χ²₃ statistic is ``CHI2_3_MEDIAN``: each residual's part along the line of sight and across it
    (:func:`_along_across`) over its own variance at the range/bearing ``ratio`` (:func:`_shares`), the dead
    reckoning's ``motion_var`` added. ``|e|²/Σc2`` alone is a χ²₃ only with ``ratio`` 1: a range error 14x the
    bearing's (PnP on the sample camera log) puts its median at 0.58 of the χ²₃ median, the scale 0.76x in σ."""
    e2 = tri.e * tri.e
    along2, across2 = _along_across(tri, e2)
    k_along, k_across = _shares(ratio)
    c, m = np.sum(tri.c2, axis=1), tri.motion_var

    def median_chi2(s2: float) -> float:
        return float(np.median(along2 / (k_along * c * s2 + m) + 2.0 * across2 / (k_across * c * s2 + m)))

    s2 = float(np.median((along2 / k_along + 2.0 * across2 / k_across) / c)) / CHI2_3_MEDIAN  # motion_var left out
    for _ in range(50):  # s2 times the median over its target: falls to the root from above, at once without motion
        if not s2 > 0.0:
            return 0.0
        new = s2 * median_chi2(s2) / CHI2_3_MEDIAN
        if new >= s2 * (1.0 - 1e-6):
            return new
        s2 = new
    return s2


def _first_fit(tri: Triplets, ratio: float, robust: bool) -> np.ndarray:
    """The triplets a law's first fit reads (:func:`_fit_law`): within 4 σ of their range quantile's robust scale
    (:func:`_robust_start`), or with ``robust`` False those that are not gross outliers (:func:`_not_gross`). The
    same for every law: computed once per set of triplets."""
    return _robust_start(tri, ratio) if robust else _not_gross(tri)


def _fit_law(
    tri: Triplets, power: int, theta0: np.ndarray, first: np.ndarray, rounds: int = 3, ratio: float = 1.0
) -> tuple[np.ndarray, float, np.ndarray]:
    """Variance-component estimation of one law: Fisher scoring on the triplets ``first`` (:func:`_first_fit`),
    then outliers beyond ``OUTLIER_SIGMAS`` of the fitted law dropped (:func:`_inliers`, at the range/bearing
    ``ratio``) and the fit repeated; the coefficients (≥ 0), the mean log-likelihood per component and the inlier
    mask."""
    theta = np.maximum(np.asarray(theta0, float), 0.0)
    e2 = tri.e * tri.e  # (K, 3)
    inl = first
    for _ in range(rounds):
        for _ in range(30):
            v, jac = _variance(theta, tri, power)
            vi, ji, ei = v[inl], jac[inl], e2[inl]
            wgt = 3.0 / (2.0 * vi * vi)  # three components share a variance
            lhs = (ji * wgt[:, None]).T @ ji + 1e-12 * np.eye(2) * max(float(np.trace(ji.T @ ji)), 1e-300)
            rhs = (ji * wgt[:, None]).T @ (ei.mean(axis=1) - vi)
            step = np.linalg.solve(lhs, rhs)
            new = np.maximum(theta + step, 0.0)
            if new[0] <= 0 and new[1] <= 0:
                new = np.maximum(theta * 0.5, 1e-9)
            done = np.all(np.abs(new - theta) <= 1e-6 * np.maximum(np.abs(theta), 1e-9))
            theta = new
            if done:
                break
        v, _ = _variance(theta, tri, power)
        inl = _inliers(tri, e2, v, ratio)
    v, _ = _variance(theta, tri, power)
    ll = float(np.mean(-0.5 * (np.log(v[inl])[:, None] + e2[inl] / v[inl][:, None])))
    return theta, ll, inl


def _subset(tri: Triplets, idx: np.ndarray) -> Triplets:
    return Triplets(*(getattr(tri, f.name)[idx] for f in fields(Triplets)))


def _fitted(tri: Triplets, seed: int) -> tuple[Triplets, np.random.Generator] | None:
    """The triplets a fit reads (a uniform subsample of ``MAX_TRIPLETS`` on a longer log) and the generator its
    bootstrap goes on with; None with fewer than ``MIN_SAMPLES``."""
    k = tri.e.shape[0]
    if k < MIN_SAMPLES:
        return None
    gen = np.random.default_rng(seed)
    if k > MAX_TRIPLETS:
        tri = _subset(tri, np.sort(gen.choice(k, MAX_TRIPLETS, replace=False)))
    return tri, gen


def detection_law(tri: Triplets, seed: int = 0, ratio: float = 1.0, robust: bool = True) -> DetectionLaw | None:
    """The range law of the detection noise that fits the triplets best, or None with too few of them; ``ratio``:
    the range/bearing ratio its outliers are judged at (:func:`_inliers`; 1: every component alike); ``robust``:
    the first fit on the triplets within 4 σ of their range quantile's robust scale (:func:`_robust_start`), else
    on all but the gross outliers (:func:`_not_gross`)."""
    if (fitted := _fitted(tri, seed)) is None:
        return None
    tri, gen = fitted
    start = _robust_sigma(tri.e.ravel()[:, None])[0] / np.sqrt(np.mean(tri.c2.sum(axis=1)))
    first = _first_fit(tri, ratio, robust)
    fits = {name: _fit_law(tri, power, np.array([start, 0.0]), first, ratio=ratio) for name, (power, _) in LAWS.items()}
    best = max(fits, key=lambda name: fits[name][1])
    other = min(fits, key=lambda name: fits[name][1])
    theta, ll, inl = fits[best]
    power = LAWS[best][0]
    boot = []
    n = tri.e.shape[0]
    for _ in range(BOOTSTRAP):
        sample = _subset(tri, gen.integers(0, n, n))
        boot.append(_fit_law(sample, power, theta, _first_fit(sample, ratio, robust), rounds=1, ratio=ratio)[0])
    se = np.std(np.array(boot), axis=0, ddof=1)
    used = int(np.count_nonzero(inl))
    method = (
        f"variance components of {used} detection triplets (second differences of static landmarks, "
        f"{n - used} outliers); law {best} chosen over {other} by log-likelihood"
    )
    if ratio != 1.0:
        method += f"; outliers judged along and across the line of sight at the ratio {ratio:.3g}"
    share = float(np.median(tri.motion_var[inl] / _variance(theta, tri, power)[0][inl]))
    if share > DOMINANT:
        method += f"; uncertain: the dead reckoning's noise is {100 * share:.0f} % of the residuals' variance"
    ranges = tuple(float(q) for q in np.percentile(tri.r[inl, 1], [5, 95]))
    base_method = method
    if theta[0] < MIN_DETECTION_M:  # TagSLAM test_11 said "0.0001 m (estimated, ± 0)": the floor, not a fit
        base_method += (
            f"; at zero range the fit gave {float(theta[0]):.2g} m, raised to the floor {MIN_DETECTION_M:g} m (no "
            f"detection is exact): the detections' ranges ({ranges[0]:.2g}-{ranges[1]:.2g} m, 5-95 %) do not fix it"
        )
    return DetectionLaw(
        best,
        Estimate(max(float(theta[0]), MIN_DETECTION_M), float(se[0]), base_method, used),
        Estimate(float(theta[1]), float(se[1]), method, used),
        power,
        ranges,
        float((fits[other][1] - ll) * used * 3),
    )


def _axis_shares(tri: Triplets, law: DetectionLaw, rounds: int = 20) -> tuple[float, float]:
    """The variance of a detection along its line of sight and of each axis across it, as shares of the law's
    ``σ(r)²``: method of moments weighted by each residual's variance, outliers beyond ``OUTLIER_SIGMAS`` of
    either part dropped and the fit repeated."""
    law_var = np.sum(tri.c2 * law.sigma(tri.r) ** 2, axis=1)
    along2 = np.sum(tri.e * tri.u, axis=1) ** 2
    across2 = (np.sum(tri.e * tri.e, axis=1) - along2) / 2  # per axis across
    m = tri.motion_var
    k_along = k_across = 1.0
    inl = np.ones(law_var.shape[0], bool)
    for _ in range(rounds):
        pred_along, pred_across = k_along * law_var + m, k_across * law_var + m
        inl = (along2 <= OUTLIER_SIGMAS**2 * pred_along) & (across2 <= OUTLIER_SIGMAS**2 * pred_across)
        v, w_a, w_c = law_var[inl], pred_along[inl] ** -2, pred_across[inl] ** -2
        k_along = max(float(np.sum(w_a * (along2[inl] - m[inl]) * v) / np.sum(w_a * v * v)), 1e-9)
        k_across = max(float(np.sum(w_c * (across2[inl] - m[inl]) * v) / np.sum(w_c * v * v)), 1e-9)
    return k_along, k_across


def detection_ratio(tri: Triplets, law: DetectionLaw, seed: int = 0) -> Estimate | None:
    """The ratio of a detection's standard deviation along its line of sight to that across it, or None when
    there are too few triplets or it cannot be told from 1 (``RATIO_CLOSE``, ``RATIO_SIGMAS`` standard errors of
    a bootstrap over the triplets)."""
    if (fitted := _fitted(tri, seed)) is None:
        return None
    tri, gen = fitted
    k = tri.e.shape[0]
    k_along, k_across = _axis_shares(tri, law)
    ratio = float(np.sqrt(k_along / k_across))
    boot = [np.sqrt(np.divide(*_axis_shares(_subset(tri, gen.integers(0, k, k)), law, 3))) for _ in range(BOOTSTRAP)]
    se_log = float(np.std(np.log(boot), ddof=1))
    if abs(np.log(ratio)) < max(np.log1p(RATIO_CLOSE), RATIO_SIGMAS * se_log):
        return None
    method = (
        f"the detection triplets' residuals along the line of sight against across it ({k} triplets): "
        f"{k_along:.3g} and {k_across:.3g} of the law's variance"
    )
    return Estimate(ratio, ratio * se_log, method, k)


# ------------------------------------------------------------------ motion noise of held streams, from detections
#: Lags (s) at which each detection is paired with the next detection of its landmark (``held_motion_noise``): a
#: spread of lags separates the detections' own noise (constant in the lag), the motion's white noise (linear)
#: and its bias (quadratic).
PAIR_LAGS_S = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
#: Variance components of a detection pair, in the order of ``held_motion_noise``'s result.
COMPONENTS = ("detection_scale", "velocity", "gyro", "velocity_bias", "gyro_bias")
#: The smallest level a held stream's fit gives (in each level's unit): a component the pairs cannot see is
#: small, not exactly zero (a zero prior or density would make the estimators trust that part blindly).
MIN_LEVEL = 1e-6


@dataclass(frozen=True)
class HeldMotion:
    """What pairs of detections of one landmark say about held (commanded) velocity streams: the white-noise
    densities and bias spreads of the velocities, and the factor on the detection law's standard deviation."""

    levels: dict[str, Estimate]  # keys of COMPONENTS


def _dead_reckoning_sums(vel_t, omega, velocity):
    """Dead-reckoned poses at the velocity samples and the running integrals the pairs' variances are made of:
    ``∫R``, ``∫P``, ``∫PPᵀ``, ``∫[P]×R`` and the time (left sums over the samples)."""
    h = np.diff(vel_t)
    rs, ps = integrate_body_twists(np.eye(3), np.zeros(3), omega[:-1], velocity[:-1], h)
    cross = np.cross(ps[:-1, :, None], rs[:-1], axis=1)  # [P]×R, column by column
    outer = ps[:-1, :, None] * ps[:-1, None, :]
    parts = (rs[:-1] * h[:, None, None], ps[:-1] * h[:, None], outer * h[:, None, None], cross * h[:, None, None], h)
    sums = tuple(np.concatenate([np.zeros((1, *p.shape[1:])), np.cumsum(p, axis=0)]) for p in parts)
    return rs, ps, sums


def pair_indices(
    t: np.ndarray, lm: np.ndarray, segment: np.ndarray, lags: tuple[float, ...] = PAIR_LAGS_S
) -> tuple[np.ndarray, np.ndarray]:
    """Detection pairs (a, b) of one landmark: each detection and the first one at least each of ``lags`` (s)
    later, within twice the lag and the same segment."""
    order = np.lexsort((t, lm))
    ts, ls = t[order], lm[order]
    firsts, seconds = [], []
    for lag in lags:
        key = ls * (2.0 * (ts.max() - ts.min() + 4 * lag) + 1.0) + ts
        j = np.searchsorted(key, key + lag)
        ok = np.flatnonzero(j < ts.size)
        ok = ok[(ls[j[ok]] == ls[ok]) & (ts[j[ok]] - ts[ok] <= 2 * lag)]
        firsts.append(order[ok])
        seconds.append(order[j[ok]])
    a, b = np.concatenate(firsts), np.concatenate(seconds)
    keep = segment[a] == segment[b]
    return a[keep], b[keep]


def pair_design(vel_t, omega, velocity, det_t, det_offsets, det_idx, det_y, law_sigma, segment_starts):
    """The squared residuals of detection pairs (dead-reckoned landmark positions, the later minus the earlier)
    along the landmark's direction and across it, and their variances per unit of each of ``COMPONENTS``: (K,)
    and (K, 5), one row per pair and direction that moves (a planar log's vertical never does). Along and
    across separate the gyro's noise (it moves the landmark across its direction) from the velocity's."""
    rs, ps, (c_r, c_p, c_pp, c_pr, c_t) = _dead_reckoning_sums(vel_t, omega, velocity)
    t_of = np.repeat(det_t, np.diff(det_offsets))
    k = np.clip(np.searchsorted(vel_t, t_of, side="right") - 1, 0, vel_t.size - 1)
    seen = np.einsum("nij,nj->ni", rs[k], det_y)
    w = seen + ps[k]
    a, b = pair_indices(t_of, det_idx, np.searchsorted(segment_starts, k, side="right"))
    ka, kb = k[a], k[b]
    lm, dt = 0.5 * (w[a] + w[b]), c_t[kb] - c_t[ka]
    int_p = c_p[kb] - c_p[ka]
    # ∫ℓℓᵀ with ℓ = landmark − P, and ∫[ℓ]×R
    lever = dt[:, None, None] * lm[:, :, None] * lm[:, None, :] - lm[:, :, None] * int_p[:, None, :]
    lever += np.swapaxes(lever, 1, 2) - dt[:, None, None] * lm[:, :, None] * lm[:, None, :] + c_pp[kb] - c_pp[ka]
    big_r = c_r[kb] - c_r[ka]
    big_b = np.cross(lm[:, :, None], big_r, axis=1) - (c_pr[kb] - c_pr[ka])
    rng = np.linalg.norm(det_y, axis=1)
    det = law_sigma(rng[a]) ** 2 + law_sigma(rng[b]) ** 2
    e = w[b] - w[a]
    scale = 1e-9 * max(1.0, float(np.max(np.abs(w))) if w.size else 1.0)
    e2, rows = [], []
    for u in _pair_directions(seen[a]):
        eu = np.einsum("ni,ni->n", e, u)
        if eu.size == 0 or np.max(np.abs(eu)) <= scale:
            continue
        gyro = np.trace(lever, axis1=1, axis2=2) - np.einsum("ni,nij,nj->n", u, lever, u)
        bias_v, bias_g = (np.sum(np.einsum("ni,nij->nj", u, m) ** 2, axis=1) for m in (big_r, big_b))
        e2.append(eu**2)
        rows.append(np.stack([det, dt, gyro, bias_v, bias_g], axis=1))
    if not rows:
        return np.zeros(0), np.zeros((0, len(COMPONENTS)))
    return np.concatenate(e2), np.concatenate(rows)


def _pair_directions(seen: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pair, three orthonormal directions: along the landmark as first seen, across it horizontally (in the
    plane of the dead reckoning's first frame) and the third."""
    along = seen / np.maximum(np.linalg.norm(seen, axis=1, keepdims=True), 1e-300)
    across = np.cross(along, np.array([0.0, 0.0, 1.0]))
    flat = np.linalg.norm(across, axis=1) < 1e-6  # looking straight up or down: any horizontal direction
    across[flat] = np.array([1.0, 0.0, 0.0])
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    return along, across, np.cross(along, across)


def _fit_components(e2: np.ndarray, design: np.ndarray, rounds: int = 3) -> tuple[np.ndarray, np.ndarray, int]:
    """Variance-component estimation of a linear variance model ``E[e²] = design · θ``, θ ≥ 0 (Fisher scoring
    with an active set, on columns scaled to a common size; outliers beyond ``OUTLIER_SIGMAS`` dropped and the
    fit repeated): θ, its standard errors and the inliers used."""
    unit = np.maximum(np.mean(design, axis=0), 1e-300)
    x = design / unit
    n_par = x.shape[1]
    theta = np.full(n_par, np.median(e2) / n_par)
    inl = np.ones(e2.size, bool)
    for _ in range(rounds):
        for _ in range(50):
            new = _scoring_step(x[inl], e2[inl], theta)
            done = np.all(np.abs(new - theta) <= 1e-6 * max(float(np.max(theta)), 1e-300))
            theta = new
            if done:
                break
        inl = e2 <= OUTLIER_SIGMAS**2 * np.maximum(x @ theta, 1e-300)
    v = np.maximum(x[inl] @ theta, 1e-300)
    info = (x[inl] * (1.0 / (2.0 * v * v))[:, None]).T @ x[inl]
    se = np.sqrt(np.clip(np.diag(np.linalg.pinv(info)), 0.0, None))
    return theta / unit, se / unit, int(inl.sum())


def _scoring_step(x: np.ndarray, e2: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """One Fisher-scoring step of the linear variance model (weights at ``theta``), components that would turn
    negative held at zero (an active set)."""
    v = np.maximum(x @ theta, 1e-12 * max(float(np.mean(e2)), 1e-300))
    wx = x / (2.0 * v * v)[:, None]
    free = np.ones(x.shape[1], bool)
    new = np.zeros(x.shape[1])
    while free.any():
        new[:] = 0.0
        new[free] = np.linalg.lstsq(wx[:, free].T @ x[:, free], wx[:, free].T @ e2, rcond=None)[0]
        if (new >= 0).all():
            break
        free &= new > 0
    return np.maximum(new, 0.0)


def held_motion_noise(
    vel_t, omega, velocity, det_t, det_offsets, det_idx, det_y, law_sigma, segment_starts
) -> HeldMotion | None:
    """The noise of velocity streams that hold their values (commanded velocities: their samples show no noise)
    from what the detections see over lags of ``PAIR_LAGS_S``; None with fewer than ``MIN_SAMPLES`` pairs."""
    if det_idx.shape[0] < 2 or vel_t.shape[0] < 2:
        return None
    e2, design = pair_design(vel_t, omega, velocity, det_t, det_offsets, det_idx, det_y, law_sigma, segment_starts)
    if e2.size < MIN_SAMPLES:
        return None
    theta, se, used = _fit_components(e2, design)
    method = (
        f"variance components of {used} detection-pair residuals over lags of {PAIR_LAGS_S[0]:g}-{PAIR_LAGS_S[-1]:g} s"
        " (the held velocities' errors as the detections see them)"
    )
    levels = {}
    for name, th, s in zip(COMPONENTS, theta, se, strict=True):
        value = max(float(np.sqrt(th)), MIN_LEVEL)
        # σ = √θ: se(σ) = se(θ) / 2σ, or √se(θ) for a σ the fit cannot tell from zero
        levels[name] = Estimate(value, float(min(s / (2 * value), np.sqrt(s))), method, used)
    return HeldMotion(levels)


# ------------------------------------------------------------------ the biases themselves, from detection pairs
#: Gauss-Newton passes of :func:`pair_bias_estimate` at most (the dead reckoning integrated again with the biases
#: taken off), and the step (rad/s or m/s) below which it stops.
BIAS_PASSES = 4
BIAS_STEP_DONE = 1e-6
#: Resamples of the landmarks for the estimate's spread, and the blocks of time for its other spread
#: (:func:`pair_bias_estimate`).
BIAS_RESAMPLES = 200
BIAS_BLOCKS = 4
#: The pairs :func:`pair_bias_estimate` fits at most, those that end first (six constants need no more; the one-hour
#: benchmark log's first 300 s give 239,000 pairs, over 300 s of dead reckoning: 0.2 CPU s; its first 20,000 end
#: within its first minute).
MAX_BIAS_PAIRS = 10_000


def _bias_pairs(vel_t, det_t, det_offsets, det_idx, segment_starts):
    """The velocity sample before each detection and the detection pairs of one landmark (:func:`pair_indices`),
    at most ``MAX_BIAS_PAIRS``, those that end first: (N,), (K,), (K,)."""
    t_of = np.repeat(det_t, np.diff(det_offsets))
    k = np.clip(np.searchsorted(vel_t, t_of, side="right") - 1, 0, vel_t.size - 1)
    a, b = pair_indices(t_of, det_idx, np.searchsorted(segment_starts, k, side="right"))
    if a.size > MAX_BIAS_PAIRS:  # the pairs that end first: a prior is of the start's bias
        pick = np.sort(np.argsort(k[b], kind="stable")[:MAX_BIAS_PAIRS])
        a, b = a[pick], b[pick]
    return k, a, b


def _pair_bias_system(vel_t, omega, velocity, k, a, b, det_y):
    """Per detection pair: the dead-reckoned landmark's displacement between the two detections, its derivative by
    the gyro and velocity biases (the maps of :func:`pair_design`) and ``∫ℓℓᵀ`` over the pair's lag, ``ℓ`` the
    landmark from the body (what the gyro's white noise moves it by): (K, 3), (K, 3, 6), (K, 3, 3) and the lags."""
    rs, ps, (c_r, c_p, c_pp, c_pr, c_t) = _dead_reckoning_sums(vel_t, omega, velocity)
    w = np.einsum("nij,nj->ni", rs[k], det_y) + ps[k]
    ka, kb = k[a], k[b]
    lm, dt, int_p = 0.5 * (w[a] + w[b]), c_t[kb] - c_t[ka], c_p[kb] - c_p[ka]
    big_r = c_r[kb] - c_r[ka]
    big_b = np.cross(lm[:, :, None], big_r, axis=1) - (c_pr[kb] - c_pr[ka])
    cross_p = lm[:, :, None] * int_p[:, None, :]
    lever = dt[:, None, None] * lm[:, :, None] * lm[:, None, :] - cross_p - np.swapaxes(cross_p, 1, 2)
    return w[b] - w[a], np.concatenate([big_b, big_r], axis=2), lever + c_pp[kb] - c_pp[ka], dt


def _robust_step(y: np.ndarray, jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares step of ``y ≈ jac · x`` (normal equations) with residuals beyond ``OUTLIER_SIGMAS``
    robust standard deviations dropped (three rounds), and the rows kept. einsum, not BLAS: OpenBLAS's threads
    spin after a call, 0.1-0.2 CPU s of the hour's riekf run with ``@``."""
    a, z = jac.reshape(-1, 6), y.reshape(-1)
    keep = np.ones(z.size, bool)
    x = np.zeros(6)
    for _ in range(3):
        ak = a * keep[:, None]
        x = np.linalg.lstsq(np.einsum("ni,nj->ij", ak, a), np.einsum("ni,n->i", ak, z), rcond=None)[0]
        res = np.abs(z - np.einsum("ni,i->n", a, x))
        keep = res <= OUTLIER_SIGMAS * MAD_TO_SIGMA * max(float(np.median(res[keep])), 1e-300)
    return x, keep


def pair_bias_estimate(
    vel_t, omega, velocity, det_t, det_offsets, det_idx, det_y, law_sigma, segment_starts, motion=(0.0, 0.0)
) -> dict | None:
    """The constant gyro and velocity biases (rad/s, m/s, body frame; measured = true + bias) that make the
    landmarks' dead-reckoned positions stay put between pairs of their detections: Gauss-Newton over at most
    ``BIAS_PASSES`` (the dead reckoning integrated again with the biases taken off), each pair weighed by its
    covariance: the two detections' (``law_sigma``) and the dead reckoning's own over the pair's lag, ``motion``
    = the (gyro, velocity) white-noise densities squared: ``q_v² Δt`` on every axis and ``q_g² (tr L − L)``,
    ``L = ∫ℓℓᵀ`` (:func:`pair_design`'s terms). Keys: ``bias`` (6,); ``sd`` (6,), its per-axis standard deviation
    over ``BIAS_RESAMPLES`` resamples of the landmarks (pairs of one landmark share its errors: they do not count
    as independent); ``chi2``, the mean squared whitened residual of the pairs kept (about 1 when constant biases,
    the detection law and the motion noise explain the pairs; far above when not: slip, a gyro noisier than its
    level); ``kept``, their share; ``landmarks``, ``pairs``, ``seconds`` (the dead reckoning's span);
    ``sd_time`` (6,), the standard deviation of the mean of ``BIAS_BLOCKS`` solutions, one per block of the pairs
    by their end's time (what the landmarks seen together share, and a walking bias, are in it). None with fewer
    than ``MIN_SAMPLES`` pairs."""
    if det_idx.shape[0] < 2 or vel_t.shape[0] < 2:
        return None
    k, a, b = _bias_pairs(vel_t, det_t, det_offsets, det_idx, segment_starts)
    if a.size < MIN_SAMPLES:
        return None
    n = int(k[b].max()) + 2  # the dead reckoning up to the last pair's (later detections are in none)
    vel_t, omega, velocity, k = vel_t[:n], omega[:n], velocity[:n], np.minimum(k, n - 1)
    rng = np.linalg.norm(det_y, axis=1)
    bias, white = np.zeros(6), None
    for _ in range(BIAS_PASSES):
        e, jac, lever, dt = _pair_bias_system(vel_t, omega - bias[:3], velocity - bias[3:], k, a, b, det_y)
        if white is None:  # the covariance, from the first dead reckoning (the biases move it little)
            iso = law_sigma(rng[a]) ** 2 + law_sigma(rng[b]) ** 2 + motion[1] * dt
            cov = (iso + motion[0] * np.trace(lever, axis1=1, axis2=2))[:, None, None] * np.eye(3) - motion[0] * lever
            white = np.linalg.inv(np.linalg.cholesky(cov))  # e ~ N(0, C): C^(-1/2) e ~ N(0, I)
        y, jac = np.einsum("nij,nj->ni", white, e), np.einsum("nij,njk->nik", white, jac)
        step, keep = _robust_step(y, jac)
        bias += np.r_[-step[:3], step[3:]]  # the displacement's derivative by the gyro bias carries its sign flipped
        if np.max(np.abs(step)) <= BIAS_STEP_DONE:
            break
    res = (y.reshape(-1) - np.einsum("ni,i->n", jac.reshape(-1, 6), step))[keep]
    ids, of = np.unique(det_idx[a], return_inverse=True)
    am, z = jac.reshape(-1, 6) * keep[:, None], y.reshape(-1) * keep
    rows = np.repeat(of, 3)
    ata = np.zeros((ids.size, 6, 6))
    atz = np.zeros((ids.size, 6))
    for i in range(6):  # each landmark's normal equations (np.add.at's cost, without it)
        atz[:, i] = np.bincount(rows, am[:, i] * z, ids.size)
        for j in range(i, 6):
            ata[:, i, j] = ata[:, j, i] = np.bincount(rows, am[:, i] * am[:, j], ids.size)
    picks = np.random.default_rng(0).integers(0, ids.size, (BIAS_RESAMPLES, ids.size))
    steps = [np.linalg.lstsq(ata[p].sum(0), atz[p].sum(0), rcond=None)[0] for p in picks]
    sd = np.std(np.asarray(steps) * np.r_[-np.ones(3), np.ones(3)], axis=0)
    # the pairs in BIAS_BLOCKS blocks of their end's time, each solved alone: the spread of these solutions is that
    # of the mean over the blocks (errors shared by landmarks seen together, a walking bias), which resampling the
    # landmarks does not see
    block = np.repeat(np.minimum(np.arange(a.size) * BIAS_BLOCKS // a.size, BIAS_BLOCKS - 1)[np.argsort(k[b])], 3)
    parts = [np.linalg.lstsq(np.einsum("ni,nj->ij", am[block == i], am[block == i]),
                             np.einsum("ni,n->i", am[block == i], z[block == i]), rcond=None)[0]
             for i in range(BIAS_BLOCKS)]  # fmt: skip
    sd_time = np.std(parts, axis=0, ddof=1) / np.sqrt(BIAS_BLOCKS)
    return {
        "bias": bias,
        "sd": sd,
        "sd_time": sd_time,
        "chi2": float(np.mean(res**2)),
        "kept": float(np.mean(keep)),
        "landmarks": int(ids.size),
        "pairs": int(a.size),
        "seconds": float(vel_t[-1] - vel_t[0]),
    }


def twist_drift(
    t_ns: np.ndarray, linear: np.ndarray, position: np.ndarray, quat_xyzw: np.ndarray, horizon_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An odometry's twist against its own poses over consecutive windows of at least ``horizon_s``: per window the
    linear velocity integrated (trapezoid, each sample turned by its message's orientation, as riekf and batch take
    it linear between samples) minus the messages' own displacement, in the body frame of the window's first message
    (W, 3); each window's length (W,) s; and what a constant body-frame velocity bias ``b`` adds to that difference,
    ``A b`` (W, 3, 3: the orientations relative to the window's first integrated over it). Windows are disjoint
    (their differences independent for a white velocity noise); one holding a step over a quarter of ``horizon_s``
    (a gap in the stream) is left out."""
    t = np.asarray(t_ns, dtype=np.int64).astype(np.float64) * 1e-9
    n = t.shape[0]
    if n < 3:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3, 3))
    q = np.asarray(quat_xyzw, dtype=np.float64)
    rots = quats_to_rots(np.ascontiguousarray(q / np.linalg.norm(q, axis=1, keepdims=True)))
    world = np.einsum("nij,nj->ni", rots, np.asarray(linear, dtype=np.float64))
    step = np.diff(t)
    moved = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (world[1:] + world[:-1]) * step[:, None], axis=0)])
    big = np.concatenate([[0], np.cumsum(step > 0.25 * horizon_s)])
    diffs, spans, gains = [], [], []
    i = 0
    while True:
        j = int(np.searchsorted(t, t[i] + horizon_s, side="left"))
        if j >= n:
            break
        if big[j] == big[i]:
            d = (moved[j] - moved[i]) - (position[j] - position[i])
            diffs.append(rots[i].T @ d)
            spans.append(t[j] - t[i])
            turned = np.einsum("k,kab->ab", 0.5 * step[i:j], rots[i:j] + rots[i + 1 : j + 1])  # this window's only
            gains.append(rots[i].T @ turned)
        i = j
    return (
        np.asarray(diffs, dtype=float).reshape(-1, 3),
        np.asarray(spans, dtype=float),
        np.asarray(gains, dtype=float).reshape(-1, 3, 3),
    )
