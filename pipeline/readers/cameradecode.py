"""Camera topics: tag corner messages, ``CameraInfo``, and camera images searched for tags while they are read.

Corner messages are deserialised by rosbags (their elements hold strings, so the vectorised decoder does not
apply) into :class:`~pipeline.streams.CornerStream` s with the corners in OpenCV's marker order. The AprilTag
detectors (MIT, AprilTag 3) list the corners counter-clockwise from the tag's bottom-left, ArUco (OpenCV,
aruco_detect) clockwise from its top-left; a detection whose corners wind the other way than its type says (a
mirrored or unknown convention) is reversed and counted, so the tag still faces the camera.

Images are never held: each one is decoded to grey, searched (:class:`~pipeline.vision.detector.TagDetector`)
and dropped, one pass over all image topics; ``max_rate_hz`` skips frames per camera, and ``progress`` gets a
line about once a second.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from slamobs.pipeline.errors import InputError, machine_failure, plural
from slamobs.pipeline.streams import CornerStream
from slamobs.pipeline.vision.cameras import CameraModel, from_camera_info
from slamobs.pipeline.vision.detector import TagDetector, compressed_to_gray, is_depth, raw_to_gray
from slamobs.pipeline.vision.tagpose import winding

from .container import iter_raw, require_definitions
from .decode import Cleaning, clean_frames, decoded_messages, layout_errors
from .roles import IMAGE
from .rows import Frames

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Mapping
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

_NS = 1_000_000_000
_CLOCKWISE = (0, 1, 2, 3)  # OpenCV / ArUco order
_APRILTAG = (3, 2, 1, 0)  # bottom-left, bottom-right, top-right, top-left -> top-left, top-right, ...


@dataclass(frozen=True)
class CornerLayout:
    """Where a corner message keeps its detections: the sequence, the id field, the four corners, their order."""

    items: str
    ident: str
    corners: Callable[[Any], list[tuple[float, float]]]
    order: tuple[int, int, int, int]  # OpenCV corner j is the message's corner order[j]


def _points(item: Any) -> list[tuple[float, float]]:
    return [(c.x, c.y) for c in item.corners]


def _fiducial(item: Any) -> list[tuple[float, float]]:
    return [(item.x0, item.y0), (item.x1, item.y1), (item.x2, item.y2), (item.x3, item.y3)]


#: Tag corner message types (``roles.TAG_CORNER_TYPES``) and how to read them.
CORNER_LAYOUTS: dict[str, CornerLayout] = {
    "apriltag_msgs/msg/ApriltagArrayStamped": CornerLayout("apriltags", "id", _points, _APRILTAG),
    "apriltag_detector_msgs/msg/ApriltagArrayStamped": CornerLayout("apriltags", "id", _points, _APRILTAG),
    "apriltag_msgs/msg/AprilTagDetectionArray": CornerLayout("detections", "id", _points, _APRILTAG),
    "fiducial_msgs/msg/FiducialArray": CornerLayout("fiducials", "fiducial_id", _fiducial, _CLOCKWISE),
    "fiducial_pose/msg/FiducialArray": CornerLayout("fiducials", "fiducial_id", _fiducial, _CLOCKWISE),
}


def _stamp(msg: Any) -> int:
    stamp = msg.header.stamp if hasattr(msg, "header") else msg.timestamp
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def _frame(msg: Any) -> str:
    return str(msg.header.frame_id if hasattr(msg, "header") else msg.frame_id)


def to_opencv_order(corners: np.ndarray, order: tuple[int, ...]) -> tuple[np.ndarray, int]:
    """Corners (M, 4, 2) of a message's convention in OpenCV's order; mirrored ones reversed, and their count."""
    out = corners[:, list(order)]
    mirrored = winding(out) < 0
    if mirrored.any():
        out[mirrored] = out[mirrored][:, [0, 3, 2, 1]]
    return out, int(np.count_nonzero(mirrored))


class _CornerFrames:
    """Detection frames as they are decoded (corner rows)."""

    def __init__(self) -> None:
        self.t_ns: list[int] = []
        self.rec_ns: list[int] = []
        self.frame: list[int] = []
        self.lengths: list[int] = []
        self.ids: list[int] = []
        self.corners: list[np.ndarray] = []

    def add(self, t_ns: int, rec_ns: int, frame: int, ids: np.ndarray, corners: np.ndarray) -> None:
        self.t_ns.append(t_ns)
        self.rec_ns.append(rec_ns)
        self.frame.append(frame)
        self.lengths.append(int(ids.shape[0]))
        self.ids.extend(int(i) for i in ids)
        self.corners.append(np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2))

    def stream(
        self, topic: str, frames: Frames, source: str, image_size: tuple[int, int] | None = None
    ) -> tuple[CornerStream, Cleaning]:
        corners = np.concatenate(self.corners) if self.corners else np.zeros((0, 4, 2))
        t, rec, offsets, ids, corners, frame_id, cleaning = clean_frames(
            np.asarray(self.t_ns, np.int64),
            np.asarray(self.rec_ns, np.int64),
            np.asarray(self.lengths, np.int64),
            np.asarray(self.ids, np.int64),
            corners,
            np.asarray(self.frame, np.int32),
            frames.names(),
        )
        return CornerStream(topic, frame_id, t, rec, offsets, ids, corners, source, image_size), cleaning


def decode_corners(
    reader: AnyReader, path: str | Path, topic: str, connections: Collection[Connection]
) -> tuple[CornerStream, Cleaning]:
    """A tag corner topic (``CORNER_LAYOUTS``) as a corner stream in OpenCV's corner order, cleaned."""
    msgtype = next(iter(connections)).msgtype
    layout = CORNER_LAYOUTS[msgtype]
    frames, acc = Frames(), _CornerFrames()
    mirrored = 0
    with layout_errors(path, connections):
        for rec, msg in decoded_messages(reader, path, connections):
            items = getattr(msg, layout.items)
            ids = np.array([int(getattr(it, layout.ident)) for it in items], np.int64)
            corners = np.array([layout.corners(it) for it in items], np.float64).reshape(-1, 4, 2)
            corners, flipped = to_opencv_order(corners, layout.order)
            mirrored += flipped
            acc.add(_stamp(msg), rec, frames.code(_frame(msg)), ids, corners)
    stream, cleaning = acc.stream(topic, frames, "corners")
    if mirrored:
        cleaning.extra.append(plural(mirrored, "detection") + " with mirrored corner order reversed")
    return stream, cleaning


def decode_camera_info(
    reader: AnyReader, path: str | Path, topic: str, connections: Collection[Connection]
) -> tuple[CameraModel, list[str]]:
    """The camera model of a ``CameraInfo`` topic: its first calibrated message (the topic repeats it)."""
    last_error: InputError | None = None
    with layout_errors(path, connections):
        for k, (_, msg) in enumerate(decoded_messages(reader, path, connections)):
            try:
                return from_camera_info(msg, topic, path), (
                    [f"{topic}: first {k} messages uncalibrated, skipped"] if k else []
                )
            except InputError as err:
                last_error = err
                if k >= 50:
                    break
    raise last_error or InputError(path, "no CameraInfo message", topic)


# --------------------------------------------------------------------------- images


def _image_of(msgtype: str, msg: Any, topic: str) -> np.ndarray | None:
    """Grey image of an image message; None for a depth image (nothing to search)."""
    if msgtype == IMAGE:
        if is_depth(msg.encoding, topic):
            return None
        return raw_to_gray(
            int(msg.height), int(msg.width), str(msg.encoding), int(msg.step), bool(msg.is_bigendian), msg.data
        )
    if is_depth(str(msg.format), topic):
        return None
    return compressed_to_gray(msg.data)


@dataclass
class _Camera:
    """One image topic while its images are searched."""

    topic: str
    msgtype: str
    period_ns: int
    last_ns: int | None = None
    frames: Frames | None = None
    acc: _CornerFrames | None = None
    size: tuple[int, int] | None = None
    skipped: int = 0
    bad: Counter | None = None
    depth: bool = False

    def __post_init__(self) -> None:
        self.frames, self.acc, self.bad = Frames(), _CornerFrames(), Counter()


def detect_in_images(
    reader: AnyReader,
    path: str | Path,
    topics: Mapping[str, Collection[Connection]],
    detector: TagDetector,
    *,
    max_rate_hz: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, tuple[CornerStream, Cleaning] | None]:
    """Tags in every image of ``topics`` (one pass over the log), as a corner stream per topic (None for a topic
    of depth images, which is left out whole).

    ``max_rate_hz`` keeps at most that many frames per second of each topic (by header stamp). Images that
    cannot be decoded are skipped and counted.
    """
    conns = [c for cs in topics.values() for c in cs]
    require_definitions(reader, path, conns)
    period = int(round(_NS / max_rate_hz)) if max_rate_hz else 0
    cams = {t: _Camera(t, next(iter(cs)).msgtype, period) for t, cs in topics.items()}
    total = sum(c.msgcount for c in conns)
    done = searched = 0
    start = last = time.perf_counter()
    for conn, rec, raw in iter_raw(reader, path, conns):
        done += 1
        cam = cams[conn.topic]
        if cam.depth:
            continue
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as err:  # rosbags raises struct/index errors on bad payloads
            if machine_failure(err):
                raise
            cam.bad[f"undecodable message ({type(err).__name__})"] += 1
            continue
        t_ns = _stamp(msg)
        if cam.period_ns and cam.last_ns is not None and 0 <= t_ns - cam.last_ns < cam.period_ns:
            cam.skipped += 1
            continue
        try:
            gray = _image_of(cam.msgtype, msg, cam.topic)
        except ValueError as err:  # ImageError: unknown encoding, short or corrupt data
            cam.bad[str(err)] += 1
            continue
        if gray is None:
            cam.depth = True
            continue
        cam.last_ns = t_ns
        cam.size = (int(gray.shape[1]), int(gray.shape[0]))
        ids, corners = detector.detect(gray)
        cam.acc.add(t_ns, rec, cam.frames.code(_frame(msg)), ids, corners)
        searched += 1
        now = time.perf_counter()
        if progress is not None and now - last >= 1.0:
            last = now
            progress(
                f"tags in images: {done} of {total} messages, {searched} searched "
                f"({searched / (now - start):.0f} images/s)"
            )
    out = {}
    for topic, cam in cams.items():
        if cam.depth:
            out[topic] = None
            continue
        stream, cleaning = cam.acc.stream(topic, cam.frames, "images", cam.size)
        if cam.skipped:
            cleaning.extra.append(f"{cam.skipped} images skipped (tags.max_rate_hz {max_rate_hz:g})")
        cleaning.extra += [f"{plural(n, 'image')} not searched: {why}" for why, n in sorted(cam.bad.items())]
        out[topic] = (stream, cleaning)
    return out
