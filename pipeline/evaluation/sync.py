"""Time synchronisation of an estimate with a reference: association, interpolation, time-offset estimation.

Association and interpolation follow evo 1.38.1 (``sync.associate_trajectories``, ``nearest_time`` and
``interpolation``) so that the same pairs are compared. The time-offset estimate goes beyond evo: it finds the
clock offset that evo users otherwise guess for ``--t_offset``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from slamobs.pipeline.kernel_cache import njit

NS_PER_S = 1_000_000_000


def _as_stamps(t_ns: np.ndarray, name: str) -> np.ndarray:
    t = np.asarray(t_ns)
    if t.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array of int64 nanosecond stamps, got shape {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"{name}: expected integer nanosecond stamps, got dtype {t.dtype}")
    return t.astype(np.int64, copy=False)


def _nearest(query: np.ndarray, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index into ``stamps`` of the nearest stamp to each query and the absolute difference (ns).

    Ties go to the earlier stamp; among equal stamps the last one at or before the query is taken.
    """
    order = np.argsort(stamps, kind="stable")
    s = stamps[order]
    hi = np.searchsorted(s, query, side="right")  # first stamp strictly after the query
    lo = hi - 1  # last stamp at or before the query
    has_lo = lo >= 0
    has_hi = hi < s.shape[0]
    lo_c = np.clip(lo, 0, s.shape[0] - 1)
    hi_c = np.clip(hi, 0, s.shape[0] - 1)
    d_lo = np.where(has_lo, query - s[lo_c], np.iinfo(np.int64).max)
    d_hi = np.where(has_hi, s[hi_c] - query, np.iinfo(np.int64).max)
    take_hi = d_hi < d_lo
    pos = np.where(take_hi, hi_c, lo_c)
    return order[pos], np.where(take_hi, d_hi, d_lo)


def associate(
    t_ref_ns: np.ndarray,
    t_est_ns: np.ndarray,
    t_max_diff_s: float = 0.01,
    t_offset_s: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-timestamp association of estimate and reference stamps (evo's ``nearest_time`` sync).

    ``t_offset_s`` is added to the estimate stamps. Like evo, the series with fewer stamps drives the
    association (the estimate when both have the same length) so that none of its samples is lost: each of
    its stamps is paired with the nearest stamp of the other series (ties to the earlier one) and the pair
    is kept when the two are at most ``t_max_diff_s`` apart. Returns ``(idx_ref, idx_est)``, int64 arrays of
    equal length, sorted by the driving series; the driving indices are unique, the other ones may repeat
    if the longer series has gaps. Arithmetic is exact on integer nanoseconds; evo works on float seconds,
    whose round-off can break an exact tie the other way (seen once in 2174 pairs of TUM fr2_desk).
    """
    ref = _as_stamps(t_ref_ns, "t_ref_ns")
    est = _as_stamps(t_est_ns, "t_est_ns")
    if t_max_diff_s < 0:
        raise ValueError(f"t_max_diff_s must be >= 0, got {t_max_diff_s}")
    empty = np.empty(0, dtype=np.int64)
    if ref.shape[0] == 0 or est.shape[0] == 0:
        return empty, empty.copy()
    max_diff = int(round(t_max_diff_s * NS_PER_S))
    est = est + int(round(t_offset_s * NS_PER_S))
    if ref.shape[0] < est.shape[0]:
        idx_est, diff = _nearest(ref, est)
        keep = diff <= max_diff
        return np.flatnonzero(keep).astype(np.int64), idx_est[keep].astype(np.int64)
    idx_ref, diff = _nearest(est, ref)
    keep = diff <= max_diff
    return idx_ref[keep].astype(np.int64), np.flatnonzero(keep).astype(np.int64)


@njit(cache=True)
def _slerp_rows(q0, q1, frac):
    """Row-wise slerp of unit-normalised (w-last) quaternions along the shorter arc (evo/transformations)."""
    out = np.empty_like(q0)
    eps = 4.0 * 2.220446049250313e-16
    for k in range(q0.shape[0]):
        n0 = math.sqrt(q0[k, 0] ** 2 + q0[k, 1] ** 2 + q0[k, 2] ** 2 + q0[k, 3] ** 2)
        n1 = math.sqrt(q1[k, 0] ** 2 + q1[k, 1] ** 2 + q1[k, 2] ** 2 + q1[k, 3] ** 2)
        a = q0[k] / n0
        b = q1[k] / n1
        f = frac[k]
        if f == 0.0:
            out[k] = a
            continue
        if f == 1.0:
            out[k] = b
            continue
        d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
        if abs(abs(d) - 1.0) < eps:
            out[k] = a
            continue
        if d < 0.0:
            d = -d
            b = -b
        angle = math.acos(d)
        if abs(angle) < eps:
            out[k] = a
            continue
        isin = 1.0 / math.sin(angle)
        out[k] = a * (math.sin((1.0 - f) * angle) * isin) + b * (math.sin(f * angle) * isin)
    return out


def interpolate_poses(
    t_ns: np.ndarray, position: np.ndarray, quat_xyzw: np.ndarray, query_ns: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Poses at ``query_ns``: linear in position, slerp in rotation, between the bracketing samples.

    Queries outside the stamps are clamped to the first/last pose (evo ``interpolate``, no extrapolation);
    stamps must be ascending.
    """
    t = _as_stamps(t_ns, "t_ns")
    q = _as_stamps(query_ns, "query_ns")
    if t.shape[0] < 2:
        raise ValueError("interpolation needs at least two poses")
    idx = np.clip(np.searchsorted(t, q, side="left"), 1, t.shape[0] - 1)
    dt = (t[idx] - t[idx - 1]).astype(np.float64)
    frac = np.where(dt > 0, (q - t[idx - 1]).astype(np.float64) / np.where(dt > 0, dt, 1.0), 0.0)
    frac = np.clip(frac, 0.0, 1.0)
    pos = np.asarray(position, dtype=np.float64)
    xyz = pos[idx - 1] + frac[:, None] * (pos[idx] - pos[idx - 1])
    quat = np.ascontiguousarray(quat_xyzw, dtype=np.float64)
    return xyz, _slerp_rows(quat[idx - 1], quat[idx], np.ascontiguousarray(frac))


# ------------------------------------------------------------------------------------------ time offset


@dataclass(frozen=True)
class TimeOffset:
    """Estimated clock offset: ``t_est + offset_s`` is on the reference clock (same sign as evo ``--t_offset``)."""

    offset_s: float
    peak_correlation: float  # normalised cross-correlation at the peak, in [-1, 1]
    signal: str  # which frame-invariant signal was correlated
    grid_step_s: float
    search_window_s: float
    at_window_edge: bool  # the best lag is on the search limit: the true offset may lie outside
    #: translation APE rmse with the offset applied and without it (same association rule and alignment; None
    #: where too few poses pair up), when :func:`~.trajectory_error.checked_time_offset` compared them
    checked: bool = False
    rmse_with_m: float | None = None
    rmse_without_m: float | None = None
    #: half the difference of the offsets found in the first and the second half of the log's velocity samples (a
    #: run's truth-clock search, :func:`.trajectory_evaluation.log_time_offset`) or of the estimate's poses
    #: (:func:`.trajectory_error.checked_time_offset`): :func:`halves_spread`; None where a half tells none
    uncertainty_s: float | None = None

    @property
    def reliable(self) -> bool:
        """A clear correlation peak inside the window that the trajectories do not contradict: a lag more than a
        grid step from zero whose association makes the aligned error larger is no clock offset (within a step
        the search cannot tell it from zero). An observer's corrections at every detection frame put a plateau
        into its angular rate: riekf on a simulated loop peaked at -0.86 s with correlation 0.88, where the APE
        grows from 0.05 to 0.64 m."""
        supported = (
            not self.checked
            or abs(self.offset_s) <= self.grid_step_s  # zero is within its resolution
            or (
                self.rmse_with_m is not None
                and (self.rmse_without_m is None or self.rmse_with_m <= self.rmse_without_m)
            )
        )
        return (
            self.peak_correlation >= PEAK_CORRELATION_MIN and not self.at_window_edge and supported and self.consistent
        )

    @property
    def consistent(self) -> bool:
        """The log's halves agree on the offset: its :attr:`uncertainty_s` is within a grid step, or within a quarter of
        the offset (``HALVES_SHARE``); True where none was found. The generated 10 s loop found 0.008 s for a
        truth on the log's clock, its halves 0.19 s apart (docs/benchmarks.md, session 26)."""
        return halves_agree(self.uncertainty_s, self.grid_step_s, self.offset_s)


#: The least peak correlation of a reliable offset (:attr:`TimeOffset.reliable`): a clear peak. Public: the report's
#: NEES notes ask the same of an offset only the halves held back (:func:`.sections.nees_against_offset_truth`).
PEAK_CORRELATION_MIN = 0.5


def halves_agree(uncertainty_s: float | None, grid_step_s: float, offset_s: float) -> bool:
    """:attr:`TimeOffset.consistent` of its fields. Public: report.md says why an offset is not reliable from
    report.json's fields (:func:`.markdown.offset_doubts`)."""
    return uncertainty_s is None or uncertainty_s <= max(grid_step_s, HALVES_SHARE * abs(offset_s))


def halves_spread(search: Callable[[slice], TimeOffset | None], n: int) -> float | None:
    """Half the difference of the offsets ``search(part)`` finds in the first and the second half of ``n`` samples:
    :attr:`TimeOffset.uncertainty_s` of every search (the log's velocity samples, an estimate's poses). None where
    either half tells no offset."""
    first, second = search(slice(0, n // 2)), search(slice(n // 2, n))
    return None if first is None or second is None else 0.5 * abs(first.offset_s - second.offset_s)


def halves_owner(against: str | None) -> str:
    """Whose halves :func:`halves_spread` compared, for a sentence: the estimate's poses, or the log's velocity
    samples (``searched_against``). Public: report.json's note and report.md's reasons say it alike."""
    return "the estimate's halves" if against == "estimate" else "the log's halves"


#: Share of the offset its :attr:`TimeOffset.uncertainty_s` may reach in a reliable offset: four of them from zero.
#: Half let the generated 10 s ground log through 0.39 s off (its halves 0.33 s apart); MR.CLAM's largest share
#: is 0.19 (robot 1 of dataset 6: 0.035 s of 0.188; docs/benchmarks.md, session 26).
HALVES_SHARE = 0.25


def step_angles(q: np.ndarray) -> np.ndarray:
    """Rotation angle between consecutive (x, y, z, w) quaternions: 2 atan2(|v|, |w|) of q_k⁻¹ q_{k+1}. From
    ``metrics.KERNEL_ROWS`` quaternions on, ``|v|`` and ``|w|`` come from a compiled loop (the same operations
    in the same order: the same bits; ``atan2`` stays NumPy's).
    Public: tests/test_report_cost.py checks its compiled loop."""
    from slamobs.pipeline.evaluation import metrics  # its threshold (metrics imports this module)

    q = np.asarray(q, dtype=np.float64)
    if q.shape[0] >= metrics.KERNEL_ROWS:
        v, w = _step_parts(np.ascontiguousarray(q))
        return 2.0 * np.arctan2(v, w)
    a, b = q[:-1], q[1:]
    norm = np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2] + q[:, 3] * q[:, 3])
    nn = norm[:-1] * norm[1:]
    a0, a1, a2, a3 = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    b0, b1, b2, b3 = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    # conj(a) * b, w-last
    w = (a3 * b3 + a0 * b0 + a1 * b1 + a2 * b2) / nn
    x = (a3 * b0 - a0 * b3 - a1 * b2 + a2 * b1) / nn
    y = (a3 * b1 + a0 * b2 - a1 * b3 - a2 * b0) / nn
    z = (a3 * b2 - a0 * b1 + a1 * b0 - a2 * b3) / nn
    return 2.0 * np.arctan2(np.sqrt(x * x + y * y + z * z), np.abs(w))


@njit(cache=True, nogil=True)
def _step_parts(q):  # pragma: no cover - compiled
    """``|v|`` and ``|w|`` of ``q_k⁻¹ q_{k+1}`` (each normalised), as :func:`step_angles`' array code has them."""
    n = q.shape[0] - 1
    v = np.empty(max(n, 0))
    w = np.empty(max(n, 0))
    if n < 1:
        return v, w
    norm_a = np.sqrt(q[0, 0] * q[0, 0] + q[0, 1] * q[0, 1] + q[0, 2] * q[0, 2] + q[0, 3] * q[0, 3])
    for k in range(n):
        a0, a1, a2, a3 = q[k, 0], q[k, 1], q[k, 2], q[k, 3]
        b0, b1, b2, b3 = q[k + 1, 0], q[k + 1, 1], q[k + 1, 2], q[k + 1, 3]
        norm_b = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2 + b3 * b3)
        nn = norm_a * norm_b
        ww = (a3 * b3 + a0 * b0 + a1 * b1 + a2 * b2) / nn
        x = (a3 * b0 - a0 * b3 - a1 * b2 + a2 * b1) / nn
        y = (a3 * b1 + a0 * b2 - a1 * b3 - a2 * b0) / nn
        z = (a3 * b2 - a0 * b1 + a1 * b0 - a2 * b3) / nn
        v[k] = np.sqrt(x * x + y * y + z * z)
        w[k] = abs(ww)
        norm_a = norm_b
    return v, w


def rate_on_grid(
    t_ns: np.ndarray,
    increments: np.ndarray,
    grid_ns: np.ndarray,
    step_ns: int,
    accumulated: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Mean rate of an accumulated quantity over [g, g + step] (NaN outside the stream's span);
    ``accumulated`` is :func:`accumulate` of the stream when sampled repeatedly. ``grid_ns`` is evenly spaced
    by ``step_ns``: the end of one interval is the start of the next, so the sum is interpolated once per edge.
    Public: tests/test_report_cost.py checks it against a plain loop."""
    t, cum = accumulated if accumulated is not None else accumulate(t_ns, increments)
    edges = np.empty(grid_ns.shape[0] + 1, np.int64)
    edges[:-1] = grid_ns
    edges[-1] = grid_ns[-1] + step_ns if grid_ns.shape[0] else 0
    at = np.interp(edges.astype(np.float64), t, cum)
    rate = (at[1:] - at[:-1]) / (step_ns / NS_PER_S)
    # outside the span: a run of grid points at each end (the grid rises), found by bisection instead of two
    # comparisons of every point (the golden-section search samples the estimate ~16 times)
    rate[: int(np.searchsorted(grid_ns, t_ns[0], side="left"))] = np.nan  # g < t_0
    rate[int(np.searchsorted(grid_ns, t_ns[-1] - step_ns, side="right")) :] = np.nan  # g + step > t_last
    return rate


def accumulate(t_ns: np.ndarray, increments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Float stamps and the running sum (from 0) of ``increments`` at them.
    Public: tests/test_report_cost.py builds its reference from it."""
    return t_ns.astype(np.float64), np.concatenate([[0.0], np.cumsum(increments)])


def _step_lengths(pos: np.ndarray) -> np.ndarray:
    """‖p_{k+1} − p_k‖ (as ``np.linalg.norm(np.diff(p), axis=1)``, through :func:`.metrics.row_norms`: the same
    bits, a compiled pass where it decides)."""
    from slamobs.pipeline.evaluation import metrics  # (metrics imports this module)

    p = np.asarray(pos, dtype=np.float64)
    return metrics.row_norms(p[1:], p[:-1])


def pose_steps(pos: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation angle and the distance from each pose of a trajectory to the next (the motion increments the
    clock-offset search resamples as rates)."""
    return step_angles(quat), _step_lengths(pos)


def velocity_steps(t_ns: np.ndarray, omega: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation angle and the distance from each velocity sample to the next, by the trapezoid rule on
    ``|ω|`` and ``|v|`` (body rates: their norms are what a trajectory integrating them rotates and moves by):
    :func:`estimate_time_offset`'s increments of a log's own velocity samples instead of an estimate's poses."""
    dt = np.diff(np.asarray(t_ns, dtype=np.int64)) / NS_PER_S
    rates = []
    for x in (omega, velocity):
        norm = np.sqrt(np.einsum("ij,ij->i", np.asarray(x, np.float64), np.asarray(x, np.float64)))
        rates.append(0.5 * (norm[:-1] + norm[1:]) * dt)
    return rates[0], rates[1]


def rate_bias(t_ns: np.ndarray, x: np.ndarray, t_ref_ns: np.ndarray, ref_steps: np.ndarray) -> np.ndarray:
    """The constant bias ``b`` of measured rate vectors ``x`` (rows at ``t_ns``) whose norm ``|x − b|`` follows the
    reference's rate ``s`` (step angles or lengths ``ref_steps`` between the stamps ``t_ref_ns``, on the same clock):
    least squares of ``|x − b| − k s − d`` over ``b``, a scale ``k`` and an offset ``d`` (Gauss-Newton from
    ``b = 0``; the fit linear in ``|x|²`` took the noise of ``x`` in the turns for bias). A gyro bias makes
    ``|ω + b|`` no shifted copy of ``|ω|``: the generated 20 s figure 8's correlation peaked 0.073 s off, the
    loop's 0.05-0.38 s at any length (docs/benchmarks.md, session 26). Zero where too few samples overlap the
    reference."""
    x = np.asarray(x, dtype=np.float64)
    t_ref = np.asarray(t_ref_ns, dtype=np.float64)
    t = np.asarray(t_ns, dtype=np.float64)
    inside = np.flatnonzero((t >= t_ref[0]) & (t <= t_ref[-1]))
    b = np.zeros(x.shape[1])
    if inside.shape[0] < 16 or t_ref.shape[0] < 3:
        return b
    inside = inside[:: -(-inside.shape[0] // BIAS_SAMPLES)]  # evenly spread: a constant needs no hour of samples
    rate = np.asarray(ref_steps, dtype=np.float64) / (np.diff(t_ref) / NS_PER_S)
    s = np.interp(t[inside], 0.5 * (t_ref[1:] + t_ref[:-1]), rate)
    xi = x[inside]
    jac = np.empty((s.shape[0], x.shape[1] + 2))
    jac[:, -2], jac[:, -1] = s, 1.0
    kd_normal = jac[:, -2:].T @ jac[:, -2:]

    def residual(bias: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = xi - bias
        norm = np.sqrt(np.einsum("ij,ij->i", d, d))
        k, off = np.linalg.lstsq(kd_normal, jac[:, -2:].T @ norm, rcond=None)[0]  # the best scale, offset here
        return k * s + off - norm, d, norm

    r, d, norm = residual(b)
    for _ in range(BIAS_ITERATIONS):
        jac[:, : x.shape[1]] = -d / np.maximum(norm, 1e-12)[:, None]
        # normal equations (5 × 5: an hour's samples cost one pass each); lstsq takes a planar log's zero axes
        step = np.linalg.lstsq(jac.T @ jac, jac.T @ r, rcond=None)[0][: x.shape[1]]
        if not np.all(np.isfinite(step)):
            break
        for _ in range(4):  # halve a step that does not lower the squared residual (a fit far off the lag)
            trial = residual(b + step)
            if trial[0] @ trial[0] < r @ r:
                break
            step = 0.5 * step
        else:
            break
        b, (r, d, norm) = b + step, trial
        if np.max(np.abs(step)) < 1e-7:
            break
    # a rate that keeps one direction (a robot driving forward) has no bias along it to tell from the offset d:
    # the fit runs off along it (to 1e8 m/s on the generated loop's speed); no bias is better than that one
    return b if b @ b <= BIAS_LIMIT**2 * np.mean(np.einsum("ij,ij->i", xi, xi)) else np.zeros(x.shape[1])


#: Gauss-Newton steps of :func:`rate_bias` at most.
BIAS_ITERATIONS = 8
#: Samples :func:`rate_bias` fits at most (every k-th of a longer log: fitting all of MR.CLAM's 60,000, the search
#: took 0.42-0.60 CPU s, main's 0.045).
BIAS_SAMPLES = 8192
#: Largest bias :func:`rate_bias` returns, relative to the rms rate (the generated scenarios' gyro biases are
#: 0.012-0.062 rad/s).
BIAS_LIMIT = 0.5


def _signals(t_ns, steps, grid_ns, step_ns):
    """Angular rate and speed on the grid from the step angles and lengths ``steps``."""
    ang, dist = steps
    return rate_on_grid(t_ns, ang, grid_ns, step_ns), rate_on_grid(t_ns, dist, grid_ns, step_ns)


def _variation(x: np.ndarray) -> float:
    """Coefficient of variation std/mean of the defined samples (0 when flat or undefined)."""
    v = x[np.isfinite(x)]
    if v.size < 2 or not np.mean(np.abs(v)) > 0:
        return 0.0
    return float(np.std(v) / np.mean(np.abs(v)))


def _xcorr(spectrum_x: np.ndarray, conj_spectrum_y: np.ndarray, size: int, lags: np.ndarray) -> np.ndarray:
    """Σ_t x[t + L] y[t] for each lag L from ``rfft(x)`` and ``conj(rfft(y))`` (zero padded to ``size``)."""
    return np.fft.irfft(spectrum_x * conj_spectrum_y, size)[lags % size]


#: Relative variance below which a signal counts as constant over an overlap (its mean square times this).
FLAT = 1e-9


def fft_size(n: int) -> int:
    """The smallest 2^a 3^b 5^c ≥ ``n``: NumPy's FFT of such a length is as fast per sample as a power of two's,
    and the hour's grid (360,300 steps and 201 lags) takes 364,500 points instead of 2^19 = 524,288 (an rfft and
    irfft pair 8.9 against 20.5 ms)."""
    best = 1 << max(int(n) - 1, 0).bit_length()
    p3 = 1
    while p3 < best:
        p35 = p3
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 5
        p3 *= 3
    return best


def _pearson_by_lag(
    a: np.ndarray, b: np.ndarray, max_lag: int, kept: dict | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Pearson correlation of a[t + L] with b[t] over the samples where both are defined, per lag L in
    [-max_lag, max_lag] (NaN where the overlap is under a fifth of the shorter signal or either signal is
    constant over it).

    The six lagged sums share their transforms: each input is transformed once (12 FFTs, not 18), zero padded
    to the smallest :func:`fft_size` that holds the signal and the longest lag (no product wraps around).
    ``kept``: ``a``'s three transforms (and its defined samples' count) by transform size, for the next call with
    the same ``a`` (:class:`ReferenceMotion`)."""
    mb = np.isfinite(b)
    b0 = np.where(mb, b, 0.0)
    size = fft_size(max(a.shape[0], b.shape[0]) + max_lag + 1)
    lags = np.arange(-max_lag, max_lag + 1)

    def spectrum(x: np.ndarray, conj: bool = False) -> np.ndarray:
        f = np.fft.rfft(x, size)
        return np.conjugate(f, out=f) if conj else f

    def spectra_of_a() -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        ma = np.isfinite(a)
        a0 = np.where(ma, a, 0.0)
        return spectrum(ma.astype(np.float64)), spectrum(a0), spectrum(a0 * a0), int(ma.sum())

    kept = {} if kept is None else kept
    if size not in kept:
        kept[size] = spectra_of_a()
    fa, a0_f, a0a0_f, defined_a = kept[size]
    fb = spectrum(mb.astype(np.float64), conj=True)
    n = np.round(_xcorr(fa, fb, size, lags))
    sa = _xcorr(a0_f, fb, size, lags)
    saa = _xcorr(a0a0_f, fb, size, lags)
    del fb
    b0_f = spectrum(b0, conj=True)
    sb = _xcorr(fa, b0_f, size, lags)
    sab = _xcorr(a0_f, b0_f, size, lags)
    del b0_f
    sbb = _xcorr(fa, spectrum(b0 * b0, conj=True), size, lags)
    var_a, var_b = n * saa - sa * sa, n * sbb - sb * sb  # n² times the variances over the overlap
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (n * sab - sa * sb) / np.sqrt(np.maximum(var_a, 0.0) * np.maximum(var_b, 0.0))
    # a signal that does not vary over the overlap (a constant-rate circle) has no correlation, only round-off
    # divided by round-off (it was ±inf and claimed a clock offset at an arbitrary lag)
    flat = (var_a <= FLAT * n * saa) | (var_b <= FLAT * n * sbb)
    r[flat | (n < 0.2 * min(defined_a, mb.sum()))] = np.nan
    return lags, r


def estimate_time_offset(
    t_ref_ns: np.ndarray,
    ref_pos: np.ndarray,
    ref_quat_xyzw: np.ndarray,
    t_est_ns: np.ndarray,
    est_pos: np.ndarray,
    est_quat_xyzw: np.ndarray,
    *,
    max_offset_s: float = 1.0,
    step_s: float | None = None,
) -> TimeOffset | None:
    """Clock offset of the estimate by cross-correlating frame-invariant motion signals.

    The angular rate magnitude ``|ω|`` of a trajectory does not change under the unknown rigid transform
    between estimate and truth frames (nor under a constant body-frame mismatch), so it can be compared
    before any alignment: both are resampled on one grid as mean rates over a grid step, the lag of the highest
    Pearson correlation within ``±max_offset_s`` is found for all grid lags at once (FFT), then refined off the
    grid by a golden-section search within one step. The speed ``|v|`` (invariant too, up to the scale, which
    the correlation ignores) is used instead when it varies clearly more than the angular rate.
    Returns None when the streams do not overlap enough to tell.
    """
    reference = ReferenceMotion(t_ref_ns, ref_pos, ref_quat_xyzw)
    return time_offset_against(reference, t_est_ns, est_pos, est_quat_xyzw, max_offset_s=max_offset_s, step_s=step_s)


def time_offset_against(
    reference: ReferenceMotion,
    t_est_ns: np.ndarray,
    est_pos: np.ndarray,
    est_quat_xyzw: np.ndarray,
    *,
    max_offset_s: float = 1.0,
    step_s: float | None = None,
) -> TimeOffset | None:
    """:func:`estimate_time_offset` against a reference's motion computed once (several searches against one truth:
    the whole estimate and its halves, :func:`.trajectory_error.checked_time_offset`)."""
    te = _as_stamps(t_est_ns, "t_est_ns")
    if te.shape[0] < 4 or np.any(np.diff(te) <= 0):
        return None
    steps = pose_steps(est_pos, est_quat_xyzw)
    return time_offset_of_steps(reference, te, steps, max_offset_s=max_offset_s, step_s=step_s)


class ReferenceMotion:
    """The reference's side of :func:`time_offset_of_steps`: its stamps, its step angles and lengths
    (:func:`pose_steps`), and on the last grid asked for its rates, their variation and the spectra of the sums
    :func:`_pearson_by_lag` takes of them. Each is computed when first needed and kept: several searches against
    one reference share them (:func:`.trajectory_evaluation.log_time_offset` searches one truth up to six times,
    each with the same grid where the truth spans the log: 0.16 of its 0.7 CPU s on the one-hour log,
    docs/benchmarks.md session 27). The same arrays each search computed for itself: the same bits."""

    def __init__(self, t_ns: np.ndarray, pos: np.ndarray, quat_xyzw: np.ndarray) -> None:
        self.t_ns = _as_stamps(t_ns, "t_ref_ns")
        self._pos, self._quat = pos, quat_xyzw
        self._kept: dict = {}
        self._grid: tuple[int, int, int] | None = None
        self._on_grid: dict = {}

    def _once(self, key, make):
        if key not in self._kept:
            self._kept[key] = make()
        return self._kept[key]

    def usable(self) -> bool:
        """At least 4 stamps, strictly rising."""
        return self._once("usable", lambda: self.t_ns.shape[0] >= 4 and not np.any(np.diff(self.t_ns) <= 0))

    def interval_s(self) -> float:
        """The median interval between the stamps, in seconds."""
        from slamobs.pipeline.evaluation.metrics import median  # (metrics imports this module)

        return self._once("interval", lambda: median(np.diff(self.t_ns)) / NS_PER_S)

    def steps(self) -> tuple[np.ndarray, np.ndarray]:
        """:func:`pose_steps` of the reference."""
        return self._once("steps", lambda: pose_steps(self._pos, self._quat))

    def on_grid(self, grid: np.ndarray, step_ns: int) -> dict:
        """What is kept of the reference on ``grid`` (its ``"signals"``, and what :func:`_best_grid_lag` adds):
        emptied when another grid is asked for."""
        key = (int(grid[0]), int(step_ns), int(grid.shape[0]))  # evenly spaced: its start, step and length
        if key != self._grid:
            self._grid, self._on_grid = key, {"signals": _signals(self.t_ns, self.steps(), grid, step_ns)}
        return self._on_grid


def time_offset_of_steps(
    reference: ReferenceMotion,
    t_est_ns: np.ndarray,
    est_steps: tuple[np.ndarray, np.ndarray],
    *,
    max_offset_s: float = 1.0,
    step_s: float | None = None,
) -> TimeOffset | None:
    """:func:`estimate_time_offset`'s search, the other side given by its motion increments ``est_steps`` (the
    rotation angle and the distance from each stamp of ``t_est_ns`` to the next): :func:`pose_steps` of an
    estimate's poses, or :func:`velocity_steps` of a log's velocity samples (a run's clock against the truth's,
    known before the estimate is). ``reference``: the truth's side, kept for the next search against it."""
    te = _as_stamps(t_est_ns, "t_est_ns")
    if not reference.usable() or te.shape[0] < 4 or np.any(np.diff(te) <= 0):
        return None
    found = _search_grid(reference, te, max_offset_s, step_s)
    if found is None:
        return None
    grid, step_ns, max_lag = found
    kept = reference.on_grid(grid, step_ns)
    r_ang, r_spd = kept["signals"]
    sums: dict = {}  # the estimate's running sum of each signal asked for: its rates, then the refinement's

    def est_signal(idx: int) -> np.ndarray:
        sums[idx] = accumulate(te, est_steps[idx])
        return rate_on_grid(te, est_steps[idx], grid, step_ns, sums[idx])

    best = _best_grid_lag((r_ang, r_spd), est_signal, max_lag, kept)
    if best is None:
        return None
    idx, k, c, lags = best
    # c[L] pairs ref[t + L] with est[t]: est at t matches ref at t + L, so t_est + L·step is on the reference
    # clock. Refine off the grid: maximise the correlation of the reference signal with the estimate's signal
    # sampled at grid − τ, by golden-section search over τ within one grid step of the peak.
    bracket = ((lags[k] - 1) * step_ns, (lags[k] + 1) * step_ns)
    corr = offset_correlation((r_ang, r_spd)[idx], te, est_steps[idx], grid, step_ns, bracket, sums[idx])
    tau = _golden_section_max(corr, *bracket, 1e-4 * NS_PER_S)  # 0.1 ms
    peak = max(corr(tau), float(c[k]))
    offset = tau / NS_PER_S
    name = ("angular rate |ω|", "speed |v|")[idx]
    return TimeOffset(
        offset_s=float(offset),
        peak_correlation=float(min(max(peak, -1.0), 1.0)),
        signal=name,
        grid_step_s=step_ns / NS_PER_S,
        search_window_s=float(max_lag * step_ns / NS_PER_S),
        at_window_edge=bool(k == 0 or k == c.shape[0] - 1),
    )


def _search_grid(
    reference: ReferenceMotion, te: np.ndarray, max_offset_s: float, step_s: float | None
) -> tuple[np.ndarray, int, int] | None:
    """The common resampling grid (stamps, step in ns, lags within ``±max_offset_s``); None when too short or huge.

    The default step follows the slower stream (within 1-50 ms) so that each grid step holds a sample.
    """
    tr = reference.t_ns
    if step_s is None:
        from slamobs.pipeline.evaluation.metrics import median  # (metrics imports this module)

        dt = max(reference.interval_s(), median(np.diff(te)) / NS_PER_S)
        step_s = min(max(dt, 1e-3), 0.05)
    step_ns = max(int(round(step_s * NS_PER_S)), 1)
    max_lag = max(int(math.ceil(max_offset_s / step_s)), 1)
    start = min(tr[0], te[0]) - max_lag * step_ns
    stop = max(tr[-1], te[-1]) + max_lag * step_ns
    n = int((stop - start) // step_ns) + 1
    if n > 4_000_000 or n < 8:
        return None
    return start + np.arange(n, dtype=np.int64) * step_ns, step_ns, max_lag


def _best_grid_lag(
    ref: tuple[np.ndarray, np.ndarray], est: Callable[[int], np.ndarray], max_lag: int, kept: dict | None = None
):
    """(signal index, peak index, correlation by lag, lags) of the signal that pins the lag; None if none does.

    The signal that varies more (relative to its mean) pins the lag better; rotation wins unless clearly weaker.
    ``est(idx)``: the estimate's signal ``idx`` on the grid, asked for only when the reference's is tried (the
    speed's was resampled for every search and seldom read; with the halves' velocity steps sliced from the log's,
    the hour's search 0.56 -> 0.48 CPU s, docs/benchmarks.md session 28).
    ``kept``: what is kept of ``ref`` for the next search (:meth:`ReferenceMotion.on_grid`).
    """
    kept = {} if kept is None else kept
    if "variation" not in kept:
        kept["variation"] = [_variation(ref[0]), _variation(ref[1])]
    cv = kept["variation"]
    order = (0, 1) if cv[0] >= 0.5 * cv[1] else (1, 0)
    for idx in order:
        if cv[idx] == 0.0:
            continue
        lags, c = _pearson_by_lag(ref[idx], est(idx), max_lag, kept.setdefault(("spectra", idx), {}))
        if np.isfinite(c).any():
            return idx, int(np.nanargmax(c)), np.nan_to_num(c, nan=-1.0), lags
    return None


def offset_correlation(
    ref_signal: np.ndarray,
    te: np.ndarray,
    steps: np.ndarray,
    grid: np.ndarray,
    step_ns: int,
    bracket: tuple[int, int] | None = None,
    accumulated: tuple[np.ndarray, np.ndarray] | None = None,
):
    """Correlation of ``ref_signal`` with the estimate's rate sampled at ``grid − τ``, as a function of τ (ns).
    ``bracket``: the least and the largest τ it is asked for (the compiled pass then walks only the grid points
    the estimate covers at some τ of it: half the grid for a half of the log's samples, the same pairs in the same
    order, the same bits). ``accumulated``: :func:`accumulate` of ``te`` and ``steps`` where the caller has it.
    Public: tests/test_report_cost.py checks it against a plain loop."""
    if accumulated is None:  # sampled at every trial offset: summed once
        accumulated = accumulate(te, steps)
    ref_defined = np.isfinite(ref_signal)

    if grid.shape[0] >= CORRELATION_KERNEL_ROWS:  # one compiled pass per trial offset
        if bracket is not None:  # a step's margin: the kernel skips the points outside the estimate's span itself
            lo = max(int(np.searchsorted(grid, te[0] + bracket[0] - step_ns, side="left")) - 1, 0)
            hi = int(np.searchsorted(grid, te[-1] + bracket[1] + step_ns, side="right")) + 1
            grid, ref_signal = grid[lo:hi], ref_signal[lo:hi]
        t_float, cum = accumulated
        ref = np.ascontiguousarray(ref_signal, dtype=np.float64)
        pairs = np.empty((2, grid.shape[0]))
        first, last = int(te[0]), int(te[-1])
        return lambda tau_ns: _shifted_correlation(
            t_float, cum, first, last, grid, step_ns, int(round(tau_ns)), ref, pairs
        )

    def corr(tau_ns: float) -> float:
        e = rate_on_grid(te, steps, grid - int(round(tau_ns)), step_ns, accumulated)
        ok = np.isfinite(e) & ref_defined
        if ok.sum() < 8:
            return -1.0
        e, ref = e[ok], ref_signal[ok]  # gathered once for the checks and the correlation (~16 calls an hour)
        if np.std(e) == 0 or np.std(ref) == 0:
            return -1.0
        return float(np.corrcoef(ref, e)[0, 1])

    return corr


#: Grid points from which :func:`offset_correlation` takes its compiled pass (a short log's grid keeps the array
#: code: its first run does not compile the kernel).
CORRELATION_KERNEL_ROWS = 65_536


@njit(cache=True, nogil=True)
def _shifted_correlation(t, cum, t_first, t_last, grid, step_ns, shift_ns, ref, pairs):  # pragma: no cover
    """Pearson correlation of ``ref`` with the estimate's mean rate over [g − shift, g − shift + step] (the
    running sum ``cum`` at the float stamps ``t``, interpolated as ``np.interp``), over the grid points where both
    are defined; -1 where fewer than 8 are or either is constant there. :func:`offset_correlation`'s array
    code in one compiled pass (``pairs`` a (2, grid) scratch buffer): the same values to round-off (its sums in
    another order), so the golden-section search takes the same steps unless two trials tie to ~1e-15."""
    n_t, n_g = t.shape[0], grid.shape[0]
    step_s = step_ns / 1e9
    j, m = 0, 0
    sum_e, sum_r, prev = 0.0, 0.0, 0.0
    for i in range(n_g + 1):
        x = float((grid[i] if i < n_g else grid[n_g - 1] + step_ns) - shift_ns)
        while j < n_t - 2 and t[j + 1] <= x:
            j += 1
        if x <= t[0]:
            at = cum[0]
        elif x >= t[n_t - 1]:
            at = cum[n_t - 1]
        else:
            at = (cum[j + 1] - cum[j]) / (t[j + 1] - t[j]) * (x - t[j]) + cum[j]
        if i > 0:
            g = grid[i - 1] - shift_ns
            v, r = (at - prev) / step_s, ref[i - 1]
            if g >= t_first and g <= t_last - step_ns and np.isfinite(r) and np.isfinite(v):
                pairs[0, m], pairs[1, m] = v, r
                sum_e += v
                sum_r += r
                m += 1
        prev = at
    if m < 8:
        return -1.0
    mean_e, mean_r = sum_e / m, sum_r / m
    see, srr, ser = 0.0, 0.0, 0.0
    for k in range(m):
        de, dr = pairs[0, k] - mean_e, pairs[1, k] - mean_r
        see += de * de
        srr += dr * dr
        ser += de * dr
    if see == 0.0 or srr == 0.0:
        return -1.0
    return min(max(ser / np.sqrt(see * srr), -1.0), 1.0)


def _golden_section_max(f, lo: float, hi: float, tol: float) -> float:
    """Middle of the bracket left by golden-section search for the maximum of ``f`` on ``[lo, hi]``, to ``tol``."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1, f2 = f(x1), f(x2)
    while hi - lo > tol:
        if f1 >= f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - g * (hi - lo)
            f1 = f(x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + g * (hi - lo)
            f2 = f(x2)
    return 0.5 * (lo + hi)
