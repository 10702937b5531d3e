"""Tags found in camera images by OpenCV's ArUco module (AprilTag and ArUco dictionaries), and the image
decoding that feeds it.

Images are searched in grey: ``sensor_msgs/Image`` (mono, colour, Bayer, YUV 4:2:2, 16-bit mono scaled to 8
bits), ``sensor_msgs/CompressedImage`` and Foxglove's ``CompressedImage`` (JPEG, PNG, ... through
``cv2.imdecode``). Depth images (``16UC1``/``32FC1`` with a depth topic name, ``compressedDepth``) carry no tags
and are refused by :func:`is_depth`.

Speed: OpenCV's default detector thresholds each image at three adaptive-threshold window sizes; two (7 and
23 px) find the same tags on the logs tried at about two thirds of the cost, and sub-pixel corner refinement
gives the corner accuracy the PnP needs (``benchmarks/tag_detection.py`` measures frames per second at
640x480 on one core). ``tags.detector`` in the config sets any ``cv2.aruco.DetectorParameters`` field.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from slamobs.pipeline.errors import InputError

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
    "adaptiveThreshWinSizeMin": 7,
    "adaptiveThreshWinSizeMax": 23,
    "adaptiveThreshWinSizeStep": 16,
    "cornerRefinementMethod": 1,  # CORNER_REFINE_SUBPIX
}


def family_constant(name: str, path: object = "") -> str:
    """The OpenCV dictionary constant of a tag family name (``36h11``, ``tag36h11``, ``4x4_50``, ``DICT_...``)."""
    key = str(name).strip().lower()
    for prefix in ("dict_", "apriltag_", "tag", "aruco_") if key not in FAMILIES else ():
        if key.startswith(prefix) and key[len(prefix):] in FAMILIES:
            key = key[len(prefix):]
            break
    if key == "original":
        key = "aruco_original"
    if key not in FAMILIES:
        raise InputError(path, f"unknown tag family {name!r} (known: 36h11, 36h10, 25h9, 16h5, 4x4_50 ... 7x7_1000, "
                               "aruco_original, aruco_mip_36h12)")
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
            if not hasattr(params, name) or name.startswith("_"):
                raise InputError(self.path, f"tags.detector: {name!r} is not a cv2.aruco.DetectorParameters field")
            current = getattr(params, name)
            try:
                setattr(params, name, type(current)(value) if isinstance(current, (bool, int, float)) else value)
            except (TypeError, ValueError, cv2.error) as err:
                raise InputError(self.path, f"tags.detector: {name} = {value!r}: {err}") from None
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tag ids (K,) and corners (K, 4, 2) in OpenCV's marker order, in pixels of ``gray``."""
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is None or len(ids) == 0:
            return np.zeros(0, np.int64), np.zeros((0, 4, 2))
        return (np.asarray(ids, dtype=np.int64).ravel(),
                np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2))


# --------------------------------------------------------------------------- image decoding

_BAYER = {"bayer_rggb8": "COLOR_BayerRG2GRAY", "bayer_bggr8": "COLOR_BayerBG2GRAY",
          "bayer_gbrg8": "COLOR_BayerGB2GRAY", "bayer_grbg8": "COLOR_BayerGR2GRAY"}
_COLOUR = {"rgb8": ("COLOR_RGB2GRAY", 3), "bgr8": ("COLOR_BGR2GRAY", 3), "rgba8": ("COLOR_RGBA2GRAY", 4),
           "bgra8": ("COLOR_BGRA2GRAY", 4), "8uc3": ("COLOR_BGR2GRAY", 3), "8uc4": ("COLOR_BGRA2GRAY", 4)}
_YUV = {"yuv422": "COLOR_YUV2GRAY_UYVY", "uyvy": "COLOR_YUV2GRAY_UYVY", "yuv422_yuy2": "COLOR_YUV2GRAY_YUY2",
        "yuyv": "COLOR_YUV2GRAY_YUY2"}


class ImageError(ValueError):
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
    raise ImageError(f"image encoding {encoding!r} is not supported (mono8/16, rgb8, bgr8, rgba8, bgra8, bayer_*8, "
                     "yuv422)")


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
