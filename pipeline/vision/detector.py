"""Tags found in camera images by OpenCV's ArUco module (AprilTag and ArUco dictionaries), and the image
decoding that feeds it.

Images are searched in grey: ``sensor_msgs/Image`` (mono, colour, Bayer, YUV 4:2:2, 16-bit mono scaled to 8
bits), ``sensor_msgs/CompressedImage`` and Foxglove's ``CompressedImage`` (JPEG, PNG, ... through
``cv2.imdecode``). Depth images (``16UC1``/``32FC1`` with a depth topic name, ``compressedDepth``) carry no tags
and are refused by :func:`is_depth`.

Corners: OpenCV's sub-pixel refinement looks for saddle points and pulls the corners of a square 0.1-0.25 px
inwards (a range error of 1-3 %); its AprilTag refinement is exact but runs AprilTag's quad detector over the
whole image (about ten times slower). So the detector runs without refinement, and :func:`refine_corners` fits
each side of every tag instead: along the coarse side it finds the steepest point of the intensity profile
across the edge (sub-pixel), fits a line to those points, and intersects
adjacent lines (only falls from bright to dark going inwards count, so the edges of the data cells next to
the border are not taken for it; the edge point is the centroid of the gradient within 1.5 px of its peak). Unbiased
for blur that is the same on both sides of an edge, and cheap (one
``cv2.remap`` for all tags of an image).

Speed and settings: OpenCV's defaults otherwise (``benchmarks/tag_detection.py`` measures frames per second at
640x480 on one core, and the corner accuracy); ``tags.detector`` in the config sets any
``cv2.aruco.DetectorParameters`` field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from slamobs.pipeline.errors import BadInput, InputError, one_line

#: Tag family names -> OpenCV dictionary constants (``tags.family``; ``tag36h11``, ``DICT_4X4_50`` also work).
FAMILIES: dict[str, str] = {
    "36h11": "DICT_APRILTAG_36h11",
    "36h10": "DICT_APRILTAG_36h10",
    "25h9": "DICT_APRILTAG_25h9",
    "16h5": "DICT_APRILTAG_16h5",
    "aruco_original": "DICT_ARUCO_ORIGINAL",
    "aruco_mip_36h12": "DICT_ARUCO_MIP_36h12",
    **{f"{n}x{n}_{k}": f"DICT_{n}X{n}_{k}" for n in (4, 5, 6, 7) for k in (50, 100, 250, 1000)},
}
DEFAULT_FAMILY = "36h11"

#: Detector settings that differ from OpenCV's defaults (see the module docstring).
DEFAULT_PARAMETERS: dict[str, float] = {
    "cornerRefinementMethod": 0,  # CORNER_REFINE_NONE: refine_corners fits the sides instead
}
#: refine_corners: half-length of the profile across an edge (px), its step, and the samples per side.
EDGE_REACH_PX = 2.5
EDGE_STEP_PX = 0.25
EDGE_SAMPLES = (6, 40)


def family_constant(name: str, path: object = "") -> str:
    """The OpenCV dictionary constant of a tag family name (``36h11``, ``tag36h11``, ``4x4_50``, ``DICT_...``)."""
    key = str(name).strip().lower()
    for prefix in ("dict_", "apriltag_", "tag", "aruco_") if key not in FAMILIES else ():
        if key.startswith(prefix) and key[len(prefix) :] in FAMILIES:
            key = key[len(prefix) :]
            break
    if key == "original":
        key = "aruco_original"
    if key not in FAMILIES:
        raise InputError(
            path,
            f"unknown tag family {name!r} (known: 36h11, 36h10, 25h9, 16h5, 4x4_50 ... 7x7_1000, "
            "aruco_original, aruco_mip_36h12)",
        )
    return FAMILIES[key]


@dataclass
class TagDetector:
    """One OpenCV ArUco detector for a tag family; :meth:`detect` returns ids and corners per image."""

    family: str = DEFAULT_FAMILY
    parameters: dict[str, Any] | None = None
    path: object = ""

    def __post_init__(self) -> None:
        from slamobs.pipeline.vision import opencv

        cv2 = opencv(self.path, "camera images")
        self.dictionary_name = family_constant(self.family, self.path)
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary_name))
        params = cv2.aruco.DetectorParameters()
        for name, value in {**DEFAULT_PARAMETERS, **(self.parameters or {})}.items():
            name = str(name)
            current = getattr(params, name, None) if not name.startswith("_") else None
            if not isinstance(current, (bool, int, float)):
                raise InputError(self.path, f"tags.detector: {name!r} is not a cv2.aruco.DetectorParameters field")
            try:
                setattr(params, name, _setting(name, current, value))
            except (TypeError, ValueError, OverflowError, cv2.error) as err:
                raise InputError(self.path, f"tags.detector: {name} = {value!r}: {_condition(err)}") from None
        self._error = cv2.error
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)
        self.refine = params.cornerRefinementMethod == 0
        if self.parameters:  # OpenCV checks its settings only when it searches: try them on one drawn tag now
            tag = cv2.aruco.generateImageMarker(dictionary, 0, 48)
            self.detect(cv2.copyMakeBorder(tag, 16, 16, 16, 16, cv2.BORDER_CONSTANT, value=255))

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tag ids (K,) and corners (K, 4, 2) in OpenCV's marker order, in pixels of ``gray`` (centres at integers)."""
        try:
            corners, ids, _ = self._detector.detectMarkers(gray)
        except self._error as err:  # settings OpenCV rejects (images are valid 8-bit grey by now)
            raise InputError(
                self.path, f"tags.detector: OpenCV rejects the settings {self.parameters}: {_condition(err)}"
            ) from None
        if ids is None or len(ids) == 0:
            return np.zeros(0, np.int64), np.zeros((0, 4, 2))
        corners = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
        if self.refine:
            corners = refine_corners(gray, corners)
        return np.asarray(ids, dtype=np.int64).ravel(), corners


def check_detector_settings(family: str, settings: dict | None, path: object) -> None:
    """The ``tags`` family and ``detector`` settings of a config, checked when the config is read so the error
    names the config file (a run would otherwise refuse them only when it meets the first image). Without
    OpenCV nothing is checked here: a log with images then gets the missing-extra error."""
    if not settings:
        return
    try:
        import cv2  # noqa: F401
    except ImportError:
        return
    TagDetector(family, settings, path)


#: cv2.aruco.CORNER_REFINE_NONE, _SUBPIX, _CONTOUR, _APRILTAG: OpenCV silently ignores other values.
_REFINE_METHODS = (0, 1, 2, 3)


def _setting(name: str, current: bool | int | float, value: Any) -> bool | int | float:
    """A ``tags.detector`` value as the type of the field; ValueError for what a cast would silently change
    (``"false"`` as True, 3.7 as 3) or OpenCV would only reject when it searches (NaN, infinity)."""
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise ValueError("must be true or false")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError("must be a number")
    if not math.isfinite(value):
        raise ValueError("must be finite")
    if isinstance(current, int):
        if value != int(value):
            raise ValueError("must be an integer")
        if name == "cornerRefinementMethod" and value not in _REFINE_METHODS:
            raise ValueError("must be 0 (none), 1 (subpix), 2 (contour) or 3 (apriltag)")
        return int(value)
    return float(value)


def _condition(err: Exception) -> str:
    """An OpenCV error's condition (``cv2.error.err``) or any error's text, on one line."""
    return one_line(getattr(err, "err", None) or err)


def refine_corners(gray: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Corners (K, 4, 2) of dark squares in ``gray`` refined by fitting a line to each side (module docstring);
    a corner that would move more than ``EDGE_REACH_PX`` keeps its coarse position."""
    from slamobs.pipeline.vision import opencv

    cv2 = opencv("", "camera images")
    k = corners.shape[0]
    start = corners
    end = np.roll(corners, -1, axis=1)
    side = end - start  # (K, 4, 2)
    length = np.linalg.norm(side, axis=2)
    m = int(np.clip(np.median(length) / 2.0, *EDGE_SAMPLES)) if k else EDGE_SAMPLES[0]
    along = np.linspace(0.15, 0.85, m)
    offs = np.arange(-EDGE_REACH_PX, EDGE_REACH_PX + 1e-9, EDGE_STEP_PX)
    unit = side / np.maximum(length, 1e-9)[..., None]
    normal = np.stack([-unit[..., 1], unit[..., 0]], axis=-1)  # (K, 4, 2)
    base = start[:, :, None, :] + along[None, None, :, None] * side[:, :, None, :]  # (K, 4, m, 2)
    pts = base[:, :, :, None, :] + offs[None, None, None, :, None] * normal[:, :, None, None, :]  # (K,4,m,d,2)
    flat = pts.reshape(-1, len(offs), 2).astype(np.float32)
    prof = cv2.remap(
        np.ascontiguousarray(gray, dtype=np.float32),
        flat[..., 0],
        flat[..., 1],
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).reshape(k, 4, m, len(offs))
    # OpenCV's order runs clockwise in the image, so ``normal`` points into the tag: across the outer edge the
    # profile falls from the white margin to the black border (the edges inside the tag rise or fall both ways)
    grad = np.maximum(-np.diff(prof, axis=-1), 0.0)  # between samples j and j + 1
    # the edge: centroid of the gradient within 1.5 px of its peak (a parabola through the peak is biased by
    # up to half a pixel on sharp edges, whose bilinearly sampled gradient is two flat steps 2 px wide)
    n_g = grad.shape[-1]
    j = np.argmax(grad, axis=-1)
    half = int(round(1.5 / EDGE_STEP_PX))
    win = np.arange(-half, half + 1)
    idx = np.clip(j[..., None] + win, 0, n_g - 1)
    g = np.take_along_axis(grad, idx, -1) * ((j[..., None] + win >= 0) & (j[..., None] + win < n_g))
    pos = offs[0] + (idx + 0.5) * EDGE_STEP_PX
    g1 = g.sum(axis=-1)
    d = (g * pos).sum(axis=-1) / np.maximum(g1, 1e-12)  # edge offset along the normal
    edge = base + d[..., None] * normal[:, :, None, :]  # (K, 4, m, 2)
    w = g1 / np.maximum(g1.max(axis=-1, keepdims=True), 1e-9)  # edge strength, relative to the side's strongest
    w = np.where(w > 0.3, w, 0.0)  # weak gradients: another edge, or none
    # weighted total-least-squares line per side: centroid and direction
    ws = np.maximum(w.sum(axis=-1, keepdims=True), 1e-9)
    mean = (w[..., None] * edge).sum(axis=2) / ws
    dev = edge - mean[:, :, None, :]
    cov = np.einsum("ksm,ksmi,ksmj->ksij", w, dev, dev)
    _, vecs = np.linalg.eigh(cov)
    direction = vecs[..., :, 1]  # largest eigenvalue
    # corner i: intersection of side i - 1 (ends at it) and side i (starts at it)
    p1, d1 = np.roll(mean, 1, axis=1), np.roll(direction, 1, axis=1)
    p2, d2 = mean, direction
    cross = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    q = p2 - p1
    t = (q[..., 0] * d2[..., 1] - q[..., 1] * d2[..., 0]) / np.where(np.abs(cross) > 1e-6, cross, 1.0)
    refined = p1 + t[..., None] * d1
    ok = (
        (np.abs(cross) > 1e-6)
        & (np.linalg.norm(refined - corners, axis=2) <= EDGE_REACH_PX)
        & (np.count_nonzero(w, axis=-1) >= 3)
        & (np.roll(np.count_nonzero(w, axis=-1), 1, axis=1) >= 3)
    )
    return np.where(ok[..., None], refined, corners)


# --------------------------------------------------------------------------- image decoding

_BAYER = {
    "bayer_rggb8": "COLOR_BayerRG2GRAY",
    "bayer_bggr8": "COLOR_BayerBG2GRAY",
    "bayer_gbrg8": "COLOR_BayerGB2GRAY",
    "bayer_grbg8": "COLOR_BayerGR2GRAY",
}
_COLOUR = {
    "rgb8": ("COLOR_RGB2GRAY", 3),
    "bgr8": ("COLOR_BGR2GRAY", 3),
    "rgba8": ("COLOR_RGBA2GRAY", 4),
    "bgra8": ("COLOR_BGRA2GRAY", 4),
    "8uc3": ("COLOR_BGR2GRAY", 3),
    "8uc4": ("COLOR_BGRA2GRAY", 4),
}
_YUV = {
    "yuv422": "COLOR_YUV2GRAY_UYVY",
    "uyvy": "COLOR_YUV2GRAY_UYVY",
    "yuv422_yuy2": "COLOR_YUV2GRAY_YUY2",
    "yuyv": "COLOR_YUV2GRAY_YUY2",
}


class ImageError(BadInput, ValueError):
    """An image message that cannot be searched (unknown encoding, truncated data); the text says why."""


def is_depth(encoding: str, topic: str) -> bool:
    """Depth and other non-intensity images: nothing to detect in them."""
    enc = encoding.lower()
    return "compresseddepth" in enc or enc in ("32fc1", "64fc1") or (enc == "16uc1" and "depth" in topic.lower())


def raw_to_gray(height: int, width: int, encoding: str, step: int, big_endian: bool, data: Any) -> np.ndarray:
    """A ``sensor_msgs/Image`` buffer as an 8-bit grey image (a view when it already is one)."""
    from slamobs.pipeline.vision import opencv

    cv2 = opencv("", "camera images")
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8)
    enc = encoding.lower()
    if height <= 0 or width <= 0 or step <= 0 or buf.size < height * step:
        raise ImageError(f"image data too short ({buf.size} bytes for {height} rows of {step})")
    rows = buf[: height * step].reshape(height, step)
    if enc in ("mono8", "8uc1"):
        return rows[:, :width]
    if enc in ("mono16", "16uc1"):
        px = rows[:, : 2 * width].view(">u2" if big_endian else "<u2")
        top = int(px.max()) if px.size else 0
        return cv2.convertScaleAbs(px, alpha=255.0 / top if top else 1.0)
    if enc in _BAYER:
        return cv2.cvtColor(np.ascontiguousarray(rows[:, :width]), getattr(cv2, _BAYER[enc]))
    if enc in _COLOUR:
        code, channels = _COLOUR[enc]
        img = rows[:, : channels * width].reshape(height, width, channels)
        return cv2.cvtColor(img, getattr(cv2, code))
    if enc in _YUV:
        img = rows[:, : 2 * width].reshape(height, width, 2)
        return cv2.cvtColor(np.ascontiguousarray(img), getattr(cv2, _YUV[enc]))
    raise ImageError(
        f"image encoding {encoding!r} is not supported (mono8/16, rgb8, bgr8, rgba8, bgra8, bayer_*8, yuv422)"
    )


def compressed_to_gray(data: Any) -> np.ndarray:
    """A compressed image (JPEG, PNG, ...) decoded to 8-bit grey."""
    from slamobs.pipeline.vision import opencv

    cv2 = opencv("", "camera images")
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8)
    img = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE) if buf.size else None
    if img is None:
        raise ImageError("compressed image cannot be decoded")
    if img.dtype != np.uint8:  # 16-bit PNG
        top = int(img.max()) if img.size else 0
        img = cv2.convertScaleAbs(img, alpha=255.0 / top if top else 1.0)
    return img
