"""Stereo-like detections weighed in inverse depth: whether they are, and the two levels (``riekf`` and ``batch``).

A point triangulated by a stereo camera (or a tag's PnP depth) has, in its optical frame ``c = (x, y, z)``, pixel
noise that is close to Gaussian and constant in ``h(c) = (x/z, y/z, 1/z)``: ``σ_u`` across the image (the pixel
over the focal length) and ``σ_w`` in inverse depth (the disparity's over ``f·b``). One decision for both reference
estimators (:func:`why_not`) and one pair of levels from the detection law (:func:`levels`); how each weighs a
detection with them is its own: batch's factors in :mod:`pipeline.smoother.inverse_depth`, riekf's update in
:mod:`pipeline.observers.riekf` (the covariance ``J⁻¹ D J⁻ᵀ`` at the predicted point).
"""

from __future__ import annotations

import numpy as np

#: ``batch.detection_inverse_depth`` (both estimators follow it): "auto", weighed so when :func:`why_not` finds no
#: reason against; "off", never. The default, also when an estimator is given no ``batch`` section.
MODES = ("off", "auto")
DEFAULT_MODE = "auto"
#: Median of ``z / |c|`` at or above which the sensor frame's z is taken as its optical axis (a camera's field of
#: view: a point is never far off the axis; MR.CLAM's range-bearing points in the body plane have z = 0).
ON_AXIS = 0.5
#: Nearest depth (m) of a measured point (every one must lie beyond it: 1/z of a point behind the camera is no
#: measurement) and of a predicted one (one nearer keeps the measurement's linearization).
MIN_DEPTH = 1e-3


def why_not(noise, det_sensor, det_y: np.ndarray, mode: str) -> str | None:
    """None when the detections are weighed in inverse depth: ``mode`` auto, the law grows as r² (and not
    linearly), its range error larger than its bearing error (the triplets' ratio above 1: a depth from a
    disparity or a tag's size in the image), one constant sensor frame whose z is the optical axis, the ratio not
    set under ``noise:`` (a configured ratio keeps the Cartesian split); else why not."""
    if mode == "off":
        return "off"
    if noise.detection_per_m2 <= 0.0 or noise.detection_per_m != 0.0:
        return "the detection law is not b + a·r²"
    if noise.detection_ratio <= 1.0:
        return "the range's error is not larger than the bearing's (detection_ratio 1)"
    if det_sensor is None:
        return "the detections are not in one fixed sensor frame"
    if det_y.shape[0] == 0:
        return "no detection"
    c = sensor_points(det_sensor, det_y)
    z = c[:, 2]
    if np.median(z / np.maximum(np.linalg.norm(c, axis=1), 1e-12)) < ON_AXIS:
        return "the detections' sensor frame is not a camera's (z forward)"
    if (behind := int(np.count_nonzero(z <= MIN_DEPTH))) > 0:
        return f"{behind} detections lie behind their camera (z <= {MIN_DEPTH} m)"
    if noise.sources.get("detection_ratio") == "config":
        return "noise.detection_ratio is set"
    return None


def sensor_points(det_sensor, y: np.ndarray) -> np.ndarray:
    """Body-frame points ``y`` (M, 3) in the detections' sensor frame."""
    rot, trans = det_sensor
    return (y - trans) @ rot


def typical(det_sensor, y: np.ndarray) -> tuple[float, float]:
    """The median depth and range (m) of the body-frame points ``y`` in the detections' sensor frame."""
    c = sensor_points(det_sensor, y)
    return float(np.median(c[:, 2])), float(np.median(np.linalg.norm(c, axis=1)))


def levels(noise, depth: float, rng: float) -> tuple[float, float]:
    """``σ_u`` (across the image, per unit depth) and ``σ_w`` (inverse depth, 1/m) from the law ``σ(r)`` and its
    range/bearing ratio (the mean over the axes, as riekf weighs it: ``NoiseSettings.ratio_split``) at a typical
    ``depth`` and range ``rng`` (:func:`typical`)."""
    across, along = noise.ratio_split()
    s = float(noise.detection_sigma(np.array([rng]))[0])
    return float(np.sqrt(across) * s / depth), float(np.sqrt(along) * s / (depth * depth))
