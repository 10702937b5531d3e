"""Stereo-like detections weighed in inverse-depth coordinates (batch, the ``b + a·r²`` law).

A point triangulated by a stereo camera (or a tag's PnP depth) has, in its optical frame ``c = (x, y, z)``, pixel
noise that is close to Gaussian and constant in ``h(c) = (x/z, y/z, 1/z)``: ``σ_u`` across the image (the pixel
over the focal length) and ``σ_w`` in inverse depth (the disparity's over ``f·b``). In Cartesian terms the depth's
σ is ``z²·σ_w`` (the r² law), the lateral one ``z·σ_u``, so their ratio grows with the range, and the depth is
heavy-tailed and biased (``1/disparity``), which no constant range/bearing ratio can represent.

The smoother keeps its Cartesian body-frame factor and is given, at a linearization point ``ĉ`` (the solution's
predicted point; the measurement before any solution), the pseudo-measurement and information

    y* = ĉ − J⁻¹ (h(ĉ) − h(c)),   Λ = Jᵀ D⁻¹ J,   J = ∂h/∂c at ĉ,   D = diag(σ_u², σ_u², σ_w²)

(carried into the body frame), so that its whitened residual at ``ĉ`` is exactly the inverse-depth one,
``D^(-1/2) (h(ĉ) − h(c))``, and its gradient there is the inverse-depth objective's: a solution re-linearized
until it stops moving is a stationary point of the inverse-depth problem. ``Λ`` is passed as ``det_sigma``
(``det(Λ)^(-1/6)``) and a shape of determinant 1, as :mod:`pipeline.smoother.anisotropy`'s.

The two levels come from the detection law the triplets fitted (``noise_estimation``): the law's variance split
along and across the line of sight by its ratio ``ρ``, along ``= z²·σ_w``, across ``= z·σ_u``, at the detections'
median depth.
"""

from __future__ import annotations

import numpy as np

#: Median of ``z / |c|`` at or above which the sensor frame's z is taken as its optical axis (a camera's field of
#: view: a point is never far off the axis; MR.CLAM's range-bearing points in the body plane have z = 0).
ON_AXIS = 0.5
#: Nearest depth (m) of a measured point (every one must lie beyond it: 1/z of a point behind the camera is no
#: measurement) and of a predicted one (one nearer keeps the measurement's linearization).
MIN_DEPTH = 1e-3


def why_not(noise, det_sensor, det_y: np.ndarray, mode: str) -> str | None:
    """None when the detections are weighed in inverse depth: ``mode`` auto, the law grows as r² (and not
    linearly), its range error larger than its bearing error (the triplets' ratio above 1: a depth from a
    disparity or a tag's size in the image), one constant sensor frame whose z is the optical axis; else why
    not."""
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


def factors(
    det_sensor, y: np.ndarray, at: np.ndarray | None, sigma_u: float, sigma_w: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body-frame pseudo-measurements (M, 3), ``det_sigma`` (M,) and shapes (M, 3, 3, determinant 1) of the
    measured body-frame points ``y`` linearized at the body-frame points ``at`` (None: at the measurements)."""
    rot, trans = det_sensor
    c = sensor_points(det_sensor, y)
    hat = c if at is None else sensor_points(det_sensor, at)
    behind = hat[:, 2] < MIN_DEPTH
    hat = np.where(behind[:, None], c, hat)
    h = c / c[:, 2:3]
    h[:, 2] = 1.0 / c[:, 2]
    w = 1.0 / hat[:, 2]
    u, v = hat[:, 0] * w, hat[:, 1] * w
    dh = np.stack([u, v, w], axis=1) - h  # h(ĉ) − h(c)
    jinv = np.zeros((c.shape[0], 3, 3))  # ∂c/∂h at ĉ: c = (u/w, v/w, 1/w)
    jinv[:, 0, 0] = jinv[:, 1, 1] = 1.0 / w
    jinv[:, 0, 2], jinv[:, 1, 2], jinv[:, 2, 2] = -u / w**2, -v / w**2, -1.0 / w**2
    y_cam = hat - np.einsum("mij,mj->mi", jinv, dh)
    jac = np.zeros((c.shape[0], 3, 3))  # ∂h/∂c at ĉ
    jac[:, 0, 0] = jac[:, 1, 1] = w
    jac[:, 0, 2], jac[:, 1, 2], jac[:, 2, 2] = -u * w, -v * w, -w * w
    d_inv = np.array([1.0 / sigma_u**2, 1.0 / sigma_u**2, 1.0 / sigma_w**2])
    info = np.einsum("mki,k,mkj->mij", jac, d_inv, jac)
    info = np.einsum("ik,mkl,jl->mij", rot, info, rot)  # into the body frame
    # det Λ = det(J)² / (σ_u⁴ σ_w²), det J = −w⁴: σ = det(Λ)^(-1/6)
    sigma = (sigma_u**4 * sigma_w**2 / w**8) ** (1.0 / 6.0)
    return y_cam @ rot.T + trans, sigma, info * (sigma**2)[:, None, None]


def record(sigma_u: float, sigma_w: float, passes: int) -> dict:
    return {"applied": True, "sigma_u": sigma_u, "sigma_w_per_m": sigma_w, "passes": passes}


def note(sigma_u: float, sigma_w: float) -> str:
    return (
        f"batch: detections weighed in inverse depth (x/z, y/z, 1/z) in their camera's frame: σ_u {sigma_u:.3g}, "
        f"σ_w {sigma_w:.3g} 1/m from the r² law and its range/bearing ratio; range and bearing not scanned apart"
    )
