"""Camera models: intrinsics and lens distortion from ``sensor_msgs/CameraInfo`` messages or from calibration
files, and the rig transforms those files carry.

Distortion models: ``radtan`` (ROS ``plumb_bob``; 4, 5 or 8 coefficients, ``rational_polynomial``) and
``equidistant`` (ROS ``equidistant``, OpenCV ``fisheye``; 4 coefficients). Pixels are undistorted to the
pixels of the ideal pinhole camera with the same ``K`` (so reprojection errors stay in pixels).

Files (``cameras:`` in the config; the kind is recognised from the content):

* Kalibr camchain YAML (``camN: {camera_model: pinhole, intrinsics: [fu, fv, pu, pv], distortion_model,
  distortion_coeffs, resolution, rostopic, T_cn_cnm1, T_cam_imu}``; TagSLAM's ``cameras.yaml`` is this format
  with ``tagtopic`` and ``rig_body``). ``T_cn_cnm1`` chains camera n to camera n-1, ``T_cam_imu`` places a camera
  relative to the IMU (the frame of the angular-velocity stream).
* ROS camera_info YAML (``camera_calibration``'s output: ``camera_matrix``, ``distortion_model``,
  ``distortion_coefficients``, ``image_width``, ``camera_name``).
* TagSLAM ``camera_poses.yaml`` (``camN: {pose: {position, rotation}}``, rotation vector): camera poses in the rig
  body named by ``rig_body`` (default ``rig``).
* TagSLAM ``tagslam.yaml``: the pose of the odometry frame in a dynamic body (``T_body_odom`` with
  ``odom_frame_id``), i.e. the odometry-to-rig extrinsic.

Rig transforms are :class:`RigTransform` edges between named ends (a camera of a file, a frame, or the IMU)
that :mod:`.landmarks` resolves to frame ids once cameras are matched to topics.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from slamobs.pipeline.errors import InputError

#: Distortion model names as logs and tools spell them -> the two models implemented.
DISTORTION_MODELS: dict[str, str] = {
    "plumb_bob": "radtan",
    "radtan": "radtan",
    "rational_polynomial": "radtan",
    "equidistant": "equidistant",
    "fisheye": "equidistant",
    "kannala_brandt": "equidistant",
    "none": "none",
    "": "none",
}
_RADTAN_SIZES = (4, 5, 8, 12, 14)
#: Iterative undistortion: enough iterations for strong (fisheye, ToF) lenses.
_CRITERIA = (3, 100, 1e-12)  # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, max iterations, epsilon


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with lens distortion. ``topics``/``frame`` say what it was declared for (matching)."""

    name: str
    k: np.ndarray  # (3, 3)
    dist: np.ndarray  # distortion coefficients of ``model``
    model: str  # "radtan" | "equidistant" | "none"
    size: tuple[int, int] | None  # (width, height) px
    source: str  # where it came from, for notes: "CameraInfo /cam/camera_info" or the file
    topics: tuple[str, ...] = ()
    frame: str = ""
    #: For CameraInfo: the rectified model (P, no distortion) used for ``*rect*`` image topics.
    rectified_k: np.ndarray | None = None

    def undistort(self, px: np.ndarray) -> np.ndarray:
        """Distorted pixels (N, 2) -> pixels of the ideal pinhole camera ``K`` (N, 2)."""
        from slamobs.pipeline.vision import opencv

        cv2 = opencv()
        pts = np.ascontiguousarray(px, dtype=np.float64).reshape(-1, 1, 2)
        if pts.shape[0] == 0 or self.model == "none":
            return pts.reshape(-1, 2).copy()
        fn = cv2.fisheye.undistortPoints if self.model == "equidistant" else cv2.undistortPoints
        try:
            out = fn(pts, self.k, self.dist, R=np.eye(3), P=self.k, criteria=_CRITERIA)
        except TypeError:  # OpenCV builds without the criteria argument: their default iterations
            out = fn(pts, self.k, self.dist, R=np.eye(3), P=self.k)
        return out.reshape(-1, 2)

    def project(self, xyz: np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) with ``z > 0`` -> distorted pixels (N, 2)."""
        from slamobs.pipeline.vision import opencv

        cv2 = opencv()
        pts = np.ascontiguousarray(xyz, dtype=np.float64).reshape(-1, 1, 3)
        if pts.shape[0] == 0:
            return np.empty((0, 2))
        zero = np.zeros(3)
        if self.model == "equidistant":
            out, _ = cv2.fisheye.projectPoints(pts, zero, zero, self.k, self.dist)
        else:
            out, _ = cv2.projectPoints(pts, zero, zero, self.k, self.dist if self.model != "none" else None)
        return out.reshape(-1, 2)

    def rectified(self) -> CameraModel:
        """The model of the rectified image (``P`` of the CameraInfo, no distortion)."""
        if self.rectified_k is None:
            return self
        return CameraModel(
            self.name,
            self.rectified_k,
            np.zeros(0),
            "none",
            self.size,
            self.source + " (rectified)",
            self.topics,
            self.frame,
        )

    def resized(self, width: int, height: int) -> CameraModel:
        """The model of this camera's images scaled to ``width`` x ``height`` px (a camera calibrated at another
        resolution): the focal lengths and the principal point scale with the image, as binning divides them in
        :func:`from_camera_info`; the distortion, of normalised coordinates, does not."""
        scale = np.diag([width / self.size[0], height / self.size[1], 1.0])
        return replace(
            self,
            k=scale @ self.k,
            size=(width, height),
            source=f"{self.source} scaled to {width}x{height}",
            rectified_k=None if self.rectified_k is None else scale @ self.rectified_k,
        )

    def describe(self) -> str:
        fx, fy, cx, cy = self.k[0, 0], self.k[1, 1], self.k[0, 2], self.k[1, 2]
        size = f" {self.size[0]}x{self.size[1]}" if self.size else ""
        return f"{self.model}{size} px, f=({fx:.1f}, {fy:.1f}) px, c=({cx:.1f}, {cy:.1f}) px, from {self.source}"


@dataclass(frozen=True)
class RigTransform:
    """``x_parent = rot x_child + trans`` between two named ends: ``("camera", name)`` (a camera of a file),
    ``("frame", frame_id)`` or ``("imu", "")`` (the frame of the angular-velocity stream)."""

    parent: tuple[str, str]
    child: tuple[str, str]
    rot: np.ndarray
    trans: np.ndarray
    source: str


@dataclass
class CameraFiles:
    """What the ``cameras:`` files hold."""

    models: list[CameraModel] = field(default_factory=list)
    transforms: list[RigTransform] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    rig_body: str = ""  # the body TagSLAM camera poses refer to (``rig_body`` of a Kalibr/TagSLAM cameras.yaml)
    #: the tag edges a TagSLAM tagslam.yaml states, in words (``default_tag_size`` per body, the listed tags' own
    #: ``size`` where another): said when the config gives no tags.size, never taken on their own
    stated_tag_sizes: list[str] = field(default_factory=list)
    #: each listed tag's edge (m) as a tagslam.yaml states it (its own ``size``, else its body's
    #: ``default_tag_size``) and the file's name: held against the config's sizes, never taken on their own
    tag_sizes: dict[int, tuple[float, str]] = field(default_factory=dict)


def distortion_model(name: str, coeffs: np.ndarray, where: str, path: str | Path, topic: str | None = None) -> str:
    """The implemented model for a distortion name, after checking the coefficient count.

    All-zero coefficients are no distortion only for radtan (the pinhole ``r = f tan θ``); for equidistant they are
    the ideal fisheye ``r = f θ`` (OpenCV's ``cv2.fisheye`` with zeros), so the model decides, not the zeros. A
    radtan (``plumb_bob``) list that is empty is no distortion too, as ROS's ``image_geometry`` reads it.
    """
    model = DISTORTION_MODELS.get(str(name).strip().lower())
    if model is None:
        raise InputError(
            path,
            f"{where}: distortion model {name!r} is not supported "
            "(plumb_bob/radtan, rational_polynomial, equidistant/fisheye)",
            topic,
        )
    n = coeffs.shape[0]
    if model == "equidistant" and n != 4:
        raise InputError(path, f"{where}: equidistant distortion needs 4 coefficients, got {n}", topic)
    if model == "radtan" and n not in (0, *_RADTAN_SIZES):  # an empty D: no distortion, as image_geometry reads it
        raise InputError(path, f"{where}: radtan distortion needs 4, 5, 8, 12 or 14 coefficients, got {n}", topic)
    if model == "radtan" and not np.any(coeffs):
        return "none"  # radtan's zeros are the pinhole; equidistant's are the ideal fisheye r = f θ, still that model
    return model


def _k_matrix(fx: float, fy: float, cx: float, cy: float, where: str, path, topic=None) -> np.ndarray:
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)
    if not (np.isfinite(k).all() and fx > 0 and fy > 0):
        raise InputError(
            path, f"{where}: camera matrix has no usable focal length (fx={fx}, fy={fy}; uncalibrated?)", topic
        )
    return k


def _field(msg: Any, *names: str) -> Any:
    for name in names:
        if hasattr(msg, name):
            return getattr(msg, name)
    raise AttributeError(names[0])


def from_camera_info(msg: Any, topic: str, path: str | Path = "") -> CameraModel:
    """A ``sensor_msgs/CameraInfo`` message (ROS1 ``K``/``D``/``P`` or ROS2 ``k``/``d``/``p``) as a camera model.

    Binning and a region of interest scale and shift the intrinsics as ``image_geometry`` does.
    """
    kk = np.asarray(_field(msg, "k", "K"), dtype=np.float64).reshape(3, 3)
    pp = np.asarray(_field(msg, "p", "P"), dtype=np.float64).reshape(3, 4)
    dist = np.asarray(_field(msg, "d", "D"), dtype=np.float64).ravel()
    where = f"CameraInfo on {topic}"
    model = distortion_model(msg.distortion_model, dist, where, path, topic)
    k = _k_matrix(kk[0, 0], kk[1, 1], kk[0, 2], kk[1, 2], where, path, topic)
    rect = pp[:, :3].copy() if pp[0, 0] > 0 and pp[1, 1] > 0 else None
    width, height = int(msg.width), int(msg.height)
    bx, by = max(int(msg.binning_x), 1), max(int(msg.binning_y), 1)
    roi = msg.roi
    if roi.width or roi.height or bx > 1 or by > 1:
        for m in (k, rect) if rect is not None else (k,):
            m[0, 2] -= roi.x_offset
            m[1, 2] -= roi.y_offset
            m[0] /= bx
            m[1] /= by
        width, height = (roi.width or width) // bx, (roi.height or height) // by
    return CameraModel(
        topic,
        k,
        dist if model != "none" else np.zeros(0),
        model,
        (width, height) if width and height else None,
        f"CameraInfo {topic}",
        frame=str(msg.header.frame_id).lstrip("/"),
        rectified_k=rect,
    )


# --------------------------------------------------------------------------- files


def _load_yaml(path: Path) -> Any:
    if not path.is_file():
        raise InputError(path, "a directory, not a camera file" if path.is_dir() else "camera file not found")
    from slamobs.pipeline.paths import read_yaml

    return read_yaml(path, "camera file")


def _numbers(value: Any, n: int | None, what: str, path: Path) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError, OverflowError):
        raise InputError(path, f"{what} must be a list of numbers") from None
    if (n is not None and arr.shape[0] != n) or not np.isfinite(arr).all():
        raise InputError(path, f"{what} must be {n} finite numbers" if n else f"{what} must be finite numbers")
    return arr


def _count(value: Any, what: str, path: Path) -> int:
    """A pixel count (``image_width``); 0 when not given."""
    if value is None:
        return 0
    value = value.item() if isinstance(value, np.generic) else value
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not np.isfinite(value)
        or value != int(value)
        or value < 0
    ):
        raise InputError(path, f"{what} must be a whole number of pixels, got {value!r}")
    return int(value)


def _vec3(node: Any, what: str, path: Path) -> np.ndarray:
    if isinstance(node, dict):
        node = [node.get(a, 0.0) for a in "xyz"]
    return _numbers(node, 3, what, path)


def _rotvec(v: np.ndarray) -> np.ndarray:
    from slamobs.pipeline.lie import so3_exp

    return so3_exp(np.asarray(v, dtype=np.float64))


def _invert(t4: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rot, trans = t4[:3, :3], t4[:3, 3]
    return rot.T.copy(), -rot.T @ trans


def _kalibr(doc: dict, path: Path, out: CameraFiles) -> None:
    names = sorted(doc, key=lambda n: (len(str(n)), str(n)))
    rig = next((str(doc[n]["rig_body"]) for n in names if isinstance(doc[n], dict) and doc[n].get("rig_body")), "")
    previous = None
    for key in names:
        cam, name = doc[key], str(key)
        if not isinstance(cam, dict) or "intrinsics" not in cam:
            continue
        where = f"{name}"
        kind = str(cam.get("camera_model", "pinhole")).lower()
        if kind != "pinhole":
            raise InputError(path, f"{where}: camera model {kind!r} is not supported (pinhole)")
        fx, fy, cx, cy = _numbers(cam["intrinsics"], 4, f"{where}.intrinsics", path)
        dist = _numbers(cam.get("distortion_coeffs", []), None, f"{where}.distortion_coeffs", path)
        model = distortion_model(cam.get("distortion_model", "none"), dist, where, path)
        res = cam.get("resolution")
        size = (
            tuple(_count(v, f"{where}.resolution", path) for v in _numbers(res, 2, f"{where}.resolution", path))
            if res is not None
            else None
        )
        topics = tuple(str(cam[key]) for key in ("rostopic", "tagtopic") if cam.get(key))
        out.models.append(
            CameraModel(
                name,
                _k_matrix(fx, fy, cx, cy, where, path),
                dist if model != "none" else np.zeros(0),
                model,
                size,
                f"{path.name} ({name})",
                topics,
            )
        )
        if "T_cn_cnm1" in cam and previous is not None:
            t4 = _numbers(cam["T_cn_cnm1"], 16, f"{where}.T_cn_cnm1", path).reshape(4, 4)
            rot, trans = _invert(t4)  # x_cnm1 = T^-1 x_cn
            out.transforms.append(
                RigTransform(("camera", previous), ("camera", name), rot, trans, f"{path.name} {name}.T_cn_cnm1")
            )
        if "T_cam_imu" in cam:
            t4 = _numbers(cam["T_cam_imu"], 16, f"{where}.T_cam_imu", path).reshape(4, 4)
            rot, trans = _invert(t4)  # x_imu = T^-1 x_cam
            out.transforms.append(
                RigTransform(("imu", ""), ("camera", name), rot, trans, f"{path.name} {name}.T_cam_imu")
            )
        previous = name
    out.rig_body = out.rig_body or rig


def _ros_yaml(doc: dict, path: Path, out: CameraFiles) -> None:
    def matrix(key: str, n: int | None) -> np.ndarray:
        # {rows, cols, data} as camera_calibration writes it, or the plain list of numbers people type
        node = doc.get(key)
        node = node.get("data") if isinstance(node, dict) else node
        return _numbers([] if node is None and n is None else node, n, f"{key}.data", path)

    name = str(doc.get("camera_name") or path.stem)
    kk = matrix("camera_matrix", 9).reshape(3, 3)
    dist = matrix("distortion_coefficients", None)
    model = distortion_model(doc.get("distortion_model", "plumb_bob"), dist, name, path)
    rect = None
    if doc.get("projection_matrix"):
        pp = matrix("projection_matrix", 12).reshape(3, 4)
        rect = pp[:, :3].copy() if pp[0, 0] > 0 and pp[1, 1] > 0 else None
    width, height = (_count(doc.get(key), key, path) for key in ("image_width", "image_height"))
    out.models.append(
        CameraModel(
            name,
            _k_matrix(kk[0, 0], kk[1, 1], kk[0, 2], kk[1, 2], name, path),
            dist if model != "none" else np.zeros(0),
            model,
            (width, height) if width and height else None,
            path.name,
            (),
            name.lstrip("/"),
            rectified_k=rect,
        )
    )


def _pose(node: Any, what: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(node, dict):
        raise InputError(path, f"{what} must have position and rotation")
    trans = _vec3(node.get("position", {}), f"{what}.position", path)
    rotvec = _vec3(node.get("rotation", node.get("rotvec", {})), f"{what}.rotation", path)
    return _rotvec(rotvec), trans


def _camera_poses(doc: dict, path: Path, out: CameraFiles, rig: str) -> None:
    for name, cam in sorted(doc.items(), key=lambda item: str(item[0])):
        if isinstance(cam, dict) and "pose" in cam:
            rot, trans = _pose(cam["pose"], f"{name}.pose", path)
            out.transforms.append(
                RigTransform(("frame", rig or "rig"), ("camera", str(name)), rot, trans, f"{path.name} {name}.pose")
            )


def _tagslam_bodies(doc: dict, path: Path, out: CameraFiles) -> None:
    found = False
    bodies = doc.get("bodies") or []
    if not isinstance(bodies, list) or not all(isinstance(e, dict) or e is None for e in bodies):
        raise InputError(path, "bodies must be a list of {name: body} entries")
    for entry in bodies:
        for name, body in (entry or {}).items():
            if not isinstance(body, dict) or body.get("is_static") or "T_body_odom" not in body:
                continue
            frame = body.get("odom_frame_id")
            if not frame:
                out.notes.append(f"{path.name}: body '{name}' has T_body_odom but no odom_frame_id: not used")
                continue
            rot, trans = _pose(body["T_body_odom"], f"{name}.T_body_odom", path)
            out.transforms.append(
                RigTransform(
                    ("frame", str(name)),
                    ("frame", str(frame).lstrip("/")),
                    rot,
                    trans,
                    f"{path.name} {name}.T_body_odom",
                )
            )
            found = True
    if not found:
        out.notes.append(f"{path.name}: no dynamic body with T_body_odom and odom_frame_id (nothing used)")
    stated, per_id = _tagslam_sizes(bodies)
    if stated:
        out.stated_tag_sizes.append(f"{path.name} states {stated}")
    out.tag_sizes.update({i: (size, path.name) for i, size in per_id.items()})


#: at most this many tag ids are named per size where a tagslam.yaml states sizes (the rest counted)
NAMED_IDS = 12


def _number(value: Any) -> float | None:
    try:
        size = float(value)
    except (TypeError, ValueError):
        return None
    return size if np.isfinite(size) and size > 0 else None


def _tagslam_sizes(bodies: list) -> tuple[str, dict[int, float]]:
    """What a tagslam.yaml's ``bodies`` state about tag edges, in words: each body's ``default_tag_size`` and the
    listed tags whose own ``size`` is another ("default_tag_size 0.16 m (body 'house'); 0.1 m for tags 100, 101");
    "" when they state none; and each listed tag's edge by id (its own ``size``, else its body's default)."""
    parts, other, per_id = [], {}, {}
    for entry in bodies:
        for name, body in (entry or {}).items():
            if not isinstance(body, dict):
                continue
            default = _number(body.get("default_tag_size"))
            if default is not None:
                parts.append(f"default_tag_size {default:g} m (body '{name}')")
            tags = body.get("tags")
            for tag in tags if isinstance(tags, list) else []:
                if not isinstance(tag, dict) or not isinstance(tag.get("id"), int):
                    continue
                size = _number(tag.get("size"))
                if size is not None and size != default:
                    other.setdefault(size, []).append(int(tag["id"]))
                if size is not None or default is not None:
                    per_id[int(tag["id"])] = size if size is not None else default
    for size, ids in sorted(other.items()):
        named = ", ".join(str(i) for i in sorted(ids)[:NAMED_IDS])
        more = f" and {len(ids) - NAMED_IDS} more" if len(ids) > NAMED_IDS else ""
        parts.append(f"{size:g} m for tag{'s' if len(ids) > 1 else ''} {named}{more}")
    return "; ".join(parts), per_id


def read_camera_files(paths: list[str | Path]) -> CameraFiles:
    """Camera models and rig transforms of ``cameras:`` files (Kalibr, ROS camera_info YAML, TagSLAM)."""
    out = CameraFiles()
    docs = []
    for p in paths:
        path = Path(p)
        doc = _load_yaml(path)
        if not isinstance(doc, dict):
            raise InputError(
                path,
                "camera file must be a YAML mapping (Kalibr camchain, ROS camera_info YAML, "
                "TagSLAM camera_poses.yaml or tagslam.yaml)",
            )
        docs.append((path, doc))
    for path, doc in docs:  # intrinsics first: they name the rig body the camera poses refer to
        cams = [v for v in doc.values() if isinstance(v, dict)]
        if "camera_matrix" in doc:
            _ros_yaml(doc, path, out)
        elif any("intrinsics" in c for c in cams):
            _kalibr(doc, path, out)
    for path, doc in docs:
        cams = [v for v in doc.values() if isinstance(v, dict)]
        if "camera_matrix" in doc or any("intrinsics" in c for c in cams):
            continue
        if "bodies" in doc:
            _tagslam_bodies(doc, path, out)
        elif cams and all("pose" in c for c in cams):
            _camera_poses(doc, path, out, out.rig_body)
        else:
            raise InputError(
                path,
                "not a camera file: expected a Kalibr camchain (camN.intrinsics), a ROS camera_info "
                "YAML (camera_matrix), a TagSLAM camera_poses.yaml (camN.pose) or a tagslam.yaml "
                "(bodies)",
            )
    return out


def check_camera_files(paths: list[str | Path] | tuple[str | Path, ...]) -> None:
    """Read the ``cameras:`` files before a long log is, and on logs that do not use them: a camera file that
    is missing or unreadable is an error, never a setting silently dropped."""
    if paths:
        read_camera_files(list(paths))
