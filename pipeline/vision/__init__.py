"""Tag landmarks from what camera logs carry: tag corners in pixels and camera images.

Corner messages (``apriltag_msgs``, ``fiducial_msgs/FiducialArray``) and tags found in images by OpenCV's
ArUco/AprilTag detector become 3D landmark points through the camera model (:mod:`.cameras`) and a
square-tag PnP (:mod:`.tagpose`); :mod:`.landmarks` turns them into the detection stream the alignment stage
takes, one stream for all cameras of a rig. OpenCV is an optional dependency (``pip install
'slamobs[vision]'``): :func:`opencv` imports it or says which extra to install.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from slamobs.pipeline.errors import InputError

#: The ArucoDetector API (OpenCV >= 4.7) is used; older versions are refused with the same message.
MIN_OPENCV = (4, 8)
EXTRA_HINT = "install it with: pip install 'slamobs[vision]'"


def opencv(path: str | Path = "", why: str = "tag corners and camera images") -> ModuleType:
    """The ``cv2`` module; a one-line :class:`InputError` naming the extra when it is missing or too old."""
    try:
        import cv2
    except ImportError:
        raise InputError(
            path, f"{why} need OpenCV (opencv-python-headless), which is not installed; {EXTRA_HINT}"
        ) from None
    version = tuple(int(x) for x in cv2.__version__.split(".")[:2] if x.isdigit())
    if version < MIN_OPENCV or not hasattr(cv2, "aruco"):
        raise InputError(
            path,
            f"{why} need OpenCV >= {MIN_OPENCV[0]}.{MIN_OPENCV[1]} with the aruco module "
            f"(found {cv2.__version__}); {EXTRA_HINT}",
        )
    return cv2
