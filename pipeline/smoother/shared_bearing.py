"""A bearing error shared by the detections near in time: the sensor's own slow heading error.

On MR.CLAM two landmarks seen in one frame err in bearing together (r 0.53–0.94 against Vicon, hardly in range)
and the error is slow (docs/benchmarks.md "MR.CLAM's batch against its grid, session 20"). To the smoother a
bearing error common to the detections is a heading error of the robot; weighed as independent, ``n`` detections
count it ``n`` times and the trajectory follows it, where the odometry would have held the heading.

From a solution's residuals: each detection's bearing residual about the body's vertical axis, the angle a yaw
of the sensor would turn it by, ``β = (y × r)_z / (y_x² + y_y²)``, standardised; the pairs of detections of
*different* landmarks (one frame: lag 0) give the correlation per lag bin (``correlation.LAG_EDGES``), and

    ρ(h) = a · exp(−h / τ)

is fitted as :func:`pipeline.smoother.correlation.fitted` does (pairs of one landmark are left to
:mod:`pipeline.smoother.correlation`, which weighs a track's own slow error). Where ``a`` is significant (the same
test), each detection's variance along its yaw direction ``v = e_z × y / |e_z × y|`` is scaled by the
effective-sample factor of the common part over the other landmarks' detections,

    gᵢ = 1 + Σⱼ ρ(|tᵢ − tⱼ|)            (j of another landmark),

exact for equally correlated bearings: ``n`` of them with correlation ``ρ`` tell the heading as well as
``n / (1 + (n − 1) ρ)`` independent ones. The information shape becomes (``Σ + (g − 1) vvᵀ / vᵀSv``, inverted)

    S' = S − (1 − 1/g) (S v)(S v)ᵀ / (vᵀ S v),

the range and the vertical untouched. Logs whose detections err independently (the simulator's, unless told
otherwise) fit ``a`` ≈ 0, every ``g`` is 1 and nothing changes. Pure numerics, no I/O.
"""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.smoother import correlation as dc

#: A bearing residual beyond this many robust standard deviations is clipped before the pairs are formed (an
#: outlier the Huber kernel still listens to would otherwise set a pair's product).
CLIP = 5.0


def bearing_residuals(det_y: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Each detection's residual ``r`` (M, 3, body frame) as the yaw that turns the detection ``y`` by it (rad);
    0 for a detection along the vertical."""
    h2 = det_y[:, 0] ** 2 + det_y[:, 1] ** 2
    cross = det_y[:, 0] * r[:, 1] - det_y[:, 1] * r[:, 0]
    return np.where(h2 > 1e-12, cross / np.maximum(h2, 1e-12), 0.0)


def standardised(beta: np.ndarray) -> np.ndarray:
    """``β`` less its median over its robust standard deviation, clipped at ``CLIP``."""
    centred = beta - np.median(beta)
    scale = 1.4826 * np.median(np.abs(centred))
    if not scale > 0.0:
        return np.zeros_like(beta)
    return np.clip(centred / scale, -CLIP, CLIP)


def cross_pairs(t: np.ndarray, landmark: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per lag bin: mean lag, number of pairs and ``1 − ρ̂`` (``ρ̂`` the mean product of ``w`` over pairs of
    detections of different landmarks, ``w`` scaled to unit variance), as :func:`correlation.variogram` returns."""
    o = np.argsort(t, kind="stable")
    t, landmark, w = t[o], landmark[o], w[o]
    w = w / max(float(np.sqrt(np.mean(w * w))), 1e-300)
    edges = dc.LAG_EDGES
    nb = edges.shape[0] - 1
    n, s, h = np.zeros(nb), np.zeros(nb), np.zeros(nb)
    first = np.arange(0, t.shape[0], max(1, -(-t.shape[0] // dc.MAX_ANCHORS)))
    for k in range(1, min(dc.MAX_OFFSET, t.shape[0] - 1) + 1):
        a = first[first + k < t.shape[0]]
        lag = t[a + k] - t[a]
        within = lag < edges[-1]
        if not within.any():
            break
        ok = within & (landmark[a + k] != landmark[a])
        a, lag = a[ok], lag[ok]
        b = np.searchsorted(edges, lag, side="right") - 1
        n += np.bincount(b, minlength=nb)
        s += np.bincount(b, weights=w[a] * w[a + k], minlength=nb)
        h += np.bincount(b, weights=lag, minlength=nb)
    full = n > 0
    return h[full] / n[full], n[full], 1.0 - s[full] / n[full]


def fit(t: np.ndarray, landmark: np.ndarray, det_y: np.ndarray, r: np.ndarray) -> dc.Correlation:
    """``ρ(h) = a·exp(−h/τ)`` of the bearing residuals over pairs of different landmarks (module docstring)."""
    lag, n, g = cross_pairs(t, landmark, standardised(bearing_residuals(det_y, r)))
    if lag.size == 0:
        return dc.Correlation(0.0, float(dc.TAUS[0]), float("inf"), 0, {})
    return dc.fitted(lag, n, g, 1.0)  # a product of two independent unit normals has variance 1


def factor(t: np.ndarray, landmark: np.ndarray, corr: dc.Correlation) -> np.ndarray:
    """Each detection's bearing variance factor ``gᵢ = 1 + Σⱼ ρ(|tᵢ − tⱼ|)`` over the other landmarks'
    detections (exactly 1 everywhere when the correlation is not significant)."""
    if not corr.significant:
        return np.ones(t.shape[0])
    every = dc.track_sums(t, np.zeros(t.shape[0], np.int64), corr.tau)
    return 1.0 + corr.share * np.maximum(every - dc.track_sums(t, landmark, corr.tau), 0.0)


def shape(det_y: np.ndarray, base: np.ndarray | None, g: np.ndarray) -> np.ndarray:
    """The detections' information shape (M, 3, 3; ``base`` None: the identity) with the variance along each
    one's yaw direction scaled by ``g`` (module docstring)."""
    m = det_y.shape[0]
    s = np.broadcast_to(np.eye(3), (m, 3, 3)) if base is None else base
    v = np.zeros((m, 3))
    v[:, 0], v[:, 1] = -det_y[:, 1], det_y[:, 0]
    norm = np.linalg.norm(v, axis=1)
    g = np.where(norm > 1e-9, g, 1.0)
    v /= np.maximum(norm, 1e-12)[:, None]
    sv = np.einsum("mij,mj->mi", s, v)
    vsv = np.maximum(np.einsum("mi,mi->m", v, sv), 1e-300)
    return s - ((1.0 - 1.0 / g) / vsv)[:, None, None] * np.einsum("mi,mj->mij", sv, sv)


def skipped(mode: str, fixed_bias: bool, inverse_depth: bool) -> str | None:
    """Why the shared bearing error is not modelled here, or None."""
    if mode == "off":
        return "batch.detection_shared_bearing is off"
    if fixed_bias:
        return "the biases are fixed (a reference run)"
    if inverse_depth:
        return "the detections are weighed in inverse depth"
    return None


def record(corr: dc.Correlation, g: np.ndarray | None) -> dict:
    """The fit for run.json (observer.smoother.detection_shared_bearing)."""
    out = dc.record(corr, None)
    out["model"] = "rho(lag) = share * exp(-lag / tau_s), bearing residuals of pairs of different landmarks"
    out["applied"] = g is not None
    if g is not None:
        out["bearing_variance_factor"] = {
            "median": round(float(np.median(g)), 3),
            "mean": round(float(np.mean(g)), 3),
            "max": round(float(np.max(g)), 3),
        }
    return out


def note(corr: dc.Correlation, g: np.ndarray) -> str:
    return (
        f"batch: the detections' bearing errors are shared across landmarks (share {corr.share:.2f} of their "
        f"variance, time constant {corr.tau:.2g} s, {corr.pairs} pairs of different landmarks): each detection's "
        f"bearing variance scaled by the effective-sample factor of the shared part (median {np.median(g):.3g}, "
        f"max {np.max(g):.3g})"
    )
