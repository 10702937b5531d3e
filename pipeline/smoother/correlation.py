"""Time-correlated detection errors: how many independent detections a landmark's track is worth.

A detector's error need not be white: on MR.CLAM a landmark's range error changes over seconds (the viewing
geometry, docs/benchmarks.md "The held streams against Vicon"). Weighed as independent, ``n`` detections of one
landmark within a second count the same slow error ``n`` times, and the smoother trusts them over the odometry.

From a solution's detection residuals, whitened by their standard deviations, the pairs of detections of one
landmark at a lag ``h`` give the variogram ``γ(h) = ½ E|wᵢ − wⱼ|²`` relative to the residuals' variance ``v``:
flat at 1 for a white error, below it where the error is correlated. The model

    γ(h) / v = 1 − a · exp(−h / τ)        (ρ(h) = a · exp(−h / τ) for h > 0)

is fitted by least squares over lag bins (``τ`` on a grid, ``a`` in closed form). Each detection's variance is
then scaled by its row sum of the correlation matrix of its landmark's detections,

    fᵢ = 1 + Σⱼ ρ(|tᵢ − tⱼ|)            (j ≠ i, the same landmark),

the effective-sample-size correction (exact for equally correlated detections: ``n`` of them with correlation
``ρ`` are worth ``n / (1 + (n − 1) ρ)``). Where the correlation is not significant (``a`` within
``SIGNIFICANCE`` standard errors of 0, or below ``MIN_CORRELATION``: white detections, as the simulator writes)
every factor is exactly 1 and nothing changes. Pure numerics, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Longest lag (s) of the pairs the variogram is fitted on, and the bins' edges below it (s).
LAG_EDGES = np.array([0.0, 0.15, 0.3, 0.6, 1.2, 2.5, 5.0, 10.0])
#: Correlation times tried (s).
TAUS = np.geomspace(0.05, 20.0, 41)
#: The correlated share ``a`` must exceed this many of its standard errors (white under the null hypothesis) ...
SIGNIFICANCE = 5.0
#: ... and this value: a correlation this small changes the weights by less than the levels' own uncertainty.
MIN_CORRELATION = 0.2
#: Pairs at most this many detections apart along a landmark's track (the bins below ``LAG_EDGES[-1]`` fill long
#: before), from at most ``MAX_ANCHORS`` first detections spread evenly over the log: bounds the work on long logs
#: (the one-hour benchmark log's 577,200 detections: 4.7 CPU s with every one, the sample logs use all).
MAX_OFFSET, MAX_ANCHORS = 64, 50_000


@dataclass(frozen=True)
class Correlation:
    """The fitted detection-error correlation ``ρ(h) = share · exp(−h / tau)`` and how sure it is."""

    share: float  # a: the correlated share of the residuals' variance at lag 0+
    tau: float  # s
    stderr: float  # of ``share`` under white residuals
    pairs: int
    bins: dict  # lag bin centre (s) -> (pairs, γ/v)

    @property
    def significant(self) -> bool:
        return self.share > max(SIGNIFICANCE * self.stderr, MIN_CORRELATION)

    def rho(self, lag: np.ndarray) -> np.ndarray:
        return self.share * np.exp(-np.abs(lag) / self.tau)


def _tracks(t: np.ndarray, landmark: np.ndarray) -> np.ndarray:
    """The detections' order by landmark, then time."""
    return np.lexsort((t, landmark))


def variogram(t: np.ndarray, landmark: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per lag bin (``LAG_EDGES``): mean lag, number of pairs and ``γ/v`` of the whitened residuals ``w`` (M, 3)
    over pairs of detections of one landmark."""
    o = _tracks(t, landmark)
    t, landmark, w = t[o], landmark[o], w[o]
    v = float(np.mean(np.sum(w * w, axis=1)))
    nb = LAG_EDGES.shape[0] - 1
    n, s, h = np.zeros(nb), np.zeros(nb), np.zeros(nb)
    first = np.arange(0, t.shape[0], max(1, -(-t.shape[0] // MAX_ANCHORS)))  # every detection, or evenly spread
    for k in range(1, min(MAX_OFFSET, t.shape[0] - 1) + 1):
        a = first[first + k < t.shape[0]]
        lag = t[a + k] - t[a]
        ok = (landmark[a + k] == landmark[a]) & (lag > 0.0) & (lag < LAG_EDGES[-1])
        if not ok.any():
            break
        a, lag = a[ok], lag[ok]
        b = np.searchsorted(LAG_EDGES, lag, side="right") - 1
        d2 = 0.5 * np.sum((w[a + k] - w[a]) ** 2, axis=1)
        n += np.bincount(b, minlength=nb)
        s += np.bincount(b, weights=d2, minlength=nb)
        h += np.bincount(b, weights=lag, minlength=nb)
    full = n > 0
    return h[full] / n[full], n[full], s[full] / n[full] / max(v, 1e-300)


def fit(t: np.ndarray, landmark: np.ndarray, w: np.ndarray) -> Correlation:
    """``ρ(h) = a·exp(−h/τ)`` fitted to the variogram of the whitened residuals ``w`` (module docstring)."""
    lag, n, g = variogram(t, landmark, w)
    if lag.size == 0:
        return Correlation(0.0, float(TAUS[0]), float("inf"), 0, {})
    best = (np.inf, 0.0, float(TAUS[0]), np.inf)
    for tau in TAUS:
        e = np.exp(-lag / tau)
        a = float(np.clip(np.sum(n * e * (1.0 - g)) / np.sum(n * e * e), 0.0, 1.0))
        sse = float(np.sum(n * (1.0 - g - a * e) ** 2))
        if sse < best[0]:
            # a pair's ½|Δw|²/v is χ²₃/3 under white residuals (variance 2/3); the pairs taken as independent
            best = (sse, a, float(tau), float(np.sqrt((2.0 / 3.0) / np.sum(n * e * e))))
    bins = {round(float(h), 3): (int(k), round(float(x), 3)) for h, k, x in zip(lag, n, g, strict=True)}
    return Correlation(best[1], best[2], best[3], int(n.sum()), bins)


def inflation(t: np.ndarray, landmark: np.ndarray, corr: Correlation) -> np.ndarray:
    """Each detection's variance factor ``fᵢ = 1 + Σⱼ ρ(|tᵢ − tⱼ|)`` over the other detections of its landmark
    (exactly 1 everywhere when the correlation is not significant). The exponential's sums run forwards and
    backwards along each landmark's detections in one pass each (``Sᵢ = xᵢ (1 + Sᵢ₋₁)``, ``xᵢ = exp(−Δtᵢ/τ)``)."""
    f = np.ones(t.shape[0])
    if not corr.significant:
        return f
    o = _tracks(t, landmark)
    ts, ls = t[o], landmark[o]
    x = np.zeros(ts.shape[0])
    same = np.flatnonzero(ls[1:] == ls[:-1]) + 1  # a link within a track (across two, the time steps back)
    x[same] = np.exp(-(ts[same] - ts[same - 1]) / corr.tau)
    fwd = np.asarray(_chain(x.tolist()))
    bwd = np.asarray(_chain([0.0, *x[:0:-1].tolist()]))[::-1]  # the same, from the end: link i to i + 1 is x[i + 1]
    f[o] = 1.0 + corr.share * (fwd + bwd)
    return f


def thinned(t: np.ndarray, landmark: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of the detections, along each landmark's track in time, at least ``spacing`` (s) after the last
    one kept (the first of each track kept): with ``spacing`` the correlation time ``τ`` the errors of the ones
    kept are nearly independent (``ρ(τ) = a/e``), where a likelihood that treats them so is honest."""
    o = _tracks(t, landmark)
    keep, last_landmark, last_t = [], None, 0.0
    for i, lm, ti in zip(o.tolist(), landmark[o].tolist(), t[o].tolist(), strict=True):
        if lm != last_landmark or ti - last_t >= spacing:
            keep.append(i)
            last_landmark, last_t = lm, ti
    return np.sort(np.asarray(keep, np.int64))


def _chain(x: list[float]) -> list[float]:
    """``Sᵢ = xᵢ (1 + Sᵢ₋₁)``, ``S₀ = x₀``: the sum of ``exp(−(tᵢ − tⱼ)/τ)`` over the earlier detections."""
    out, acc = [], 0.0
    for xi in x:
        acc = xi * (1.0 + acc)
        out.append(acc)
    return out


def skipped(mode: str, fixed_bias: bool) -> str | None:
    """Why the correlation is not modelled here, or None. A detection level set under ``noise:`` is the marginal
    σ of one detection: it says nothing of how many of them are independent, so it does not turn this off."""
    if mode == "off":
        return "batch.detection_correlation is off"
    if fixed_bias:
        return "the biases are fixed (a reference run)"
    return None


def record(corr: Correlation, factor: np.ndarray | None) -> dict:
    """The fit for run.json (observer.smoother.detection_correlation)."""
    out = {
        "model": "rho(lag) = share * exp(-lag / tau_s), pairs of detections of one landmark",
        "share": round(corr.share, 4),
        "tau_s": round(corr.tau, 3),
        "stderr": round(corr.stderr, 5) if np.isfinite(corr.stderr) else None,
        "pairs": corr.pairs,
        "variogram": {f"{h:g}": list(v) for h, v in corr.bins.items()},
        "applied": factor is not None,
    }
    if factor is not None:
        out["variance_factor"] = {
            "median": round(float(np.median(factor)), 3),
            "mean": round(float(np.mean(factor)), 3),
            "max": round(float(np.max(factor)), 3),
        }
    return out


def share_held(before: dict, after: dict) -> bool:
    """Whether the correlation fitted again at batch's held velocity level (``after``, a :func:`record`) kept the
    correlated share fitted at the detection pairs' level (``before``): applied, and not lower by more than
    ``SIGNIFICANCE`` of ``before``'s standard errors. On the ten MR.CLAM robots the share moved by +0.5 to +6.9
    standard errors where the new ratio and correlation time helped or cost under 2 % (7-r1, 7-r3, 7-r4, 7-r5)
    and by -14 to -47 on the other six (6-r1 to 6-r5, 7-r2), four of which they cost up to 7 % APE or 37 % map:
    there the higher ratio had taken over the slow range error the correlation modelled (docs/benchmarks.md,
    "batch's detection model again at the held level, session 29")."""
    if not (before.get("applied") and after.get("applied")) or before.get("stderr") is None:
        return False
    return after["share"] >= before["share"] - SIGNIFICANCE * before["stderr"]


def again_note(again: dict) -> str:
    """The report's note of batch's detection model chosen again at the held velocity level (``again``: its record,
    run.json's ``observer.smoother.held_velocity.detections_again``)."""
    said = (
        f"range/bearing ratio {again['ratio']}, correlated share {again['share']} (was {again['share_before']}), "
        f"time constant {again['tau_s']:g} s"
    )
    if again["kept"]:
        return f"batch: the detections' model chosen again at the held velocity's level and kept: {said}"
    return (
        f"batch: the detections' model chosen again at the held velocity's level, not kept ({said}): the share "
        f"fell by more than {SIGNIFICANCE:g} standard errors, the ratio taking over the slow error"
    )


def note(corr: Correlation, factor: np.ndarray) -> str:
    return (
        f"batch: the detections' errors are correlated in time (share {corr.share:.2f} of their variance, "
        f"time constant {corr.tau:.2g} s, {corr.pairs} pairs of detections of one landmark): each detection's "
        f"variance scaled by its track's effective-sample factor (median {np.median(factor):.3g}, "
        f"max {np.max(factor):.3g})"
    )
