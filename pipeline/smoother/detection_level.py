"""The detection law's level again from the smoother's own residuals, robustly (issue 23).

``noise: auto`` fits the detection law ``σ(r)`` to second differences of detection triplets under 1 s, as white,
isotropic errors (``noise_estimation.detection_law``). Once batch has weighed range apart from bearing
(:mod:`pipeline.smoother.anisotropy`) and modelled the errors' correlation in time
(:mod:`pipeline.smoother.correlation`), the law's level means something else: the geometric mean of a range and a
bearing standard deviation of one detection, its correlated share counted apart. Nothing checked that level
against what the final model's residuals say; on MR.CLAM the best hand-set law was x0.3 of it on 7-r3 and 7-r5.

The residuals at the solution, whitened by each detection's marginal model (the law at its predicted range and
its range/bearing shape; not the correlation's effective-sample factor, which is not a variance of the error),
are ``χ²₃`` under that model. Their mean square is not a usable estimate there: the bearing residuals are
heavy-tailed (MR.CLAM 7-r5: root mean square 1.09 of the model across the line of sight, but 0.53 by the
median), as mis-associated barcodes, the robot turning between a detection and its stamp, and the commands'
slip that the trajectory cannot follow put a few detections far out, and the Huber kernel and the χ² gate weigh
those little anyway. The scale adopted is the median's

    s = sqrt(median |w|² / median χ²₃)        (w the whitened residual of every detection, gated ones included)

and the law's three coefficients are multiplied by it (the shape and the correlation's factors kept), the
smoother solved again from its solution, once. The residuals are a solution's, a little smaller than the errors
(the fit absorbs part of them): the scale leans low by that share, small where a landmark is seen many times and
the odometry holds the trajectory. Only where the correlation is applied: on white detections (every generated
log) the triplets' law is the model's, and nothing changes. Pure numerics, no I/O.
"""

from __future__ import annotations

import numpy as np

#: The median of the χ² distribution with 3 degrees of freedom.
CHI2_3_MEDIAN = 2.365973884375338
#: A scale within this share of 1 leaves the law as it is (no solve).
MIN_CHANGE = 0.05


def scale(whitened: np.ndarray) -> float:
    """The law's scale from the residuals ``whitened`` (M, 3) by each detection's marginal model (module docstring);
    1 when none is finite."""
    w2 = np.sum(whitened * whitened, axis=1)
    w2 = w2[np.isfinite(w2)]
    if w2.size == 0:
        return 1.0
    s = float(np.sqrt(np.median(w2) / CHI2_3_MEDIAN))
    return s if np.isfinite(s) and s > 0 else 1.0


def moved(s: float) -> bool:
    return abs(s - 1.0) > MIN_CHANGE


def skipped(mode: str, law_configured: bool, fixed_bias: bool, correlation: dict, inverse_depth: bool) -> str | None:
    """Why the law's level is not taken again from the solution's residuals, or None (``correlation``: the
    correlation's run.json record)."""
    if mode == "off":
        return "batch.detection_level is off"
    if law_configured:
        return "the detection law is set in the configuration"
    if fixed_bias:
        return "the biases are fixed (a reference run)"
    if inverse_depth:
        return "the detections are weighed in inverse depth"
    if not correlation.get("applied"):
        return "the detections' errors are white (the triplets' law is the model's)"
    return None


def record(whitened: np.ndarray, s: float) -> dict:
    """run.json's ``observer.smoother.detection_level``: the scale, the mean square's for comparison, the count."""
    w2 = np.sum(whitened * whitened, axis=1)
    return {
        "model": "s = sqrt(median |w|^2 / median chi2_3), w each detection's residual whitened by sigma(r) and shape",
        "scale": round(s, 4),
        "rms_scale": round(float(np.sqrt(np.mean(w2) / 3.0)), 4),
        "detections": int(w2.size),
        "applied": moved(s),
    }


def note(s: float) -> str:
    return (
        f"batch: the detection law x{s:.3g}: the median of its solution's detection residuals whitened by the law "
        "and its range/bearing shape (their heavy tail left out; batch.detection_level)"
    )
