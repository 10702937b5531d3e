"""Columnar containers passed from the readers to the alignment stage.

Everything is NumPy: times are int64 nanoseconds, values float64. ``t_ns`` is the measurement time
(``header.stamp``), ``rec_ns`` the time the recorder wrote the message. Frames are the ``frame_id`` of
the messages so the alignment stage can bring them into the body frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Vec3Stream:
    """A stream of 3-vectors: angular velocity, body linear velocity, acceleration or magnetic field."""

    topic: str
    frame_id: str
    t_ns: np.ndarray  # (N,) int64
    rec_ns: np.ndarray  # (N,) int64
    xyz: np.ndarray  # (N, 3) float64

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass(frozen=True)
class PoseStream:
    """Stamped poses (ground truth): position and ``(x, y, z, w)`` quaternion of ``child`` in ``frame_id``."""

    topic: str
    frame_id: str
    child_frame_id: str
    t_ns: np.ndarray  # (N,) int64
    rec_ns: np.ndarray  # (N,) int64
    position: np.ndarray  # (N, 3)
    quat_xyzw: np.ndarray  # (N, 4)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass(frozen=True)
class DetectionStream:
    """Landmark detections grouped in frames (one message = one frame), CSR layout.

    Detections of frame ``f`` are ``ids[offsets[f]:offsets[f+1]]`` and ``xyz[...]``, positions of the
    landmarks in ``frame_id`` (the camera frame). Several cameras feed one stream through ``camera_of``:
    detection ``m`` is then in frame ``cameras[camera_of[m]]`` (``frame_id`` is the first).
    """

    topic: str
    frame_id: str
    t_ns: np.ndarray  # (F,) int64
    rec_ns: np.ndarray  # (F,) int64
    offsets: np.ndarray  # (F + 1,) int64
    ids: np.ndarray  # (M,) int64
    xyz: np.ndarray  # (M, 3)
    cameras: tuple[str, ...] = ()  # frame ids of several cameras; empty: every detection is in ``frame_id``
    camera_of: np.ndarray | None = None  # (M,) int index into ``cameras``

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass(frozen=True)
class CornerStream:
    """Tag detections as corner pixels of one camera, one frame per message (or image), CSR layout.

    ``corners[m]`` holds the four corners of detection ``m`` in OpenCV's marker order (top-left, top-right,
    bottom-right, bottom-left of the tag seen from the front), pixels of the raw (distorted) image.
    ``source`` says where they come from: ``"corners"`` (a detector's messages) or ``"images"`` (found here).
    """

    topic: str
    frame_id: str
    t_ns: np.ndarray  # (F,) int64
    rec_ns: np.ndarray  # (F,) int64
    offsets: np.ndarray  # (F + 1,) int64
    ids: np.ndarray  # (M,) int64
    corners: np.ndarray  # (M, 4, 2) px
    source: str = "corners"
    #: (width, height) px of the images the tags were found in (``source == "images"``); None for corner messages
    image_size: tuple[int, int] | None = None

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass(frozen=True)
class Transform:
    """A static transform: ``x_parent = R(quat) x_child + translation``."""

    parent: str
    child: str
    translation: np.ndarray  # (3,)
    quat_xyzw: np.ndarray  # (4,)


@dataclass(frozen=True)
class TransformSeries:
    """One ``/tf`` edge over time: ``x_parent = R(quat_xyzw[k]) x_child + translation[k]`` at ``t_ns[k]``.

    Stamps are strictly increasing (cleaned like every stream); lookups interpolate between them.
    """

    topic: str
    parent: str
    child: str
    t_ns: np.ndarray  # (N,) int64
    rec_ns: np.ndarray  # (N,) int64
    translation: np.ndarray  # (N, 3)
    quat_xyzw: np.ndarray  # (N, 4)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass
class LogStreams:
    """Everything the pipeline takes out of one log, by role. Missing roles are ``None``."""

    path: str
    angular_velocity: Vec3Stream | None = None
    linear_velocity: Vec3Stream | None = None
    detections: DetectionStream | None = None
    truth: PoseStream | None = None
    accel: Vec3Stream | None = None
    magnetic: Vec3Stream | None = None
    #: the linear-velocity topic's own angular velocity when the gyro is another topic's (odometry beside an IMU):
    #: the alignment times the gyro's stamps against it (``alignment.GYRO_LAG_WARN_S``)
    twist_angular: Vec3Stream | None = None
    static_tf: list[Transform] = field(default_factory=list)
    #: (parent, child) pairs of ``/tf_static`` dropped as NaN/Inf, each with the warning that says so
    static_tf_dropped: dict[tuple[str, str], str] = field(default_factory=dict)
    #: (parent, child) pairs of ``/tf_static`` published with different values (the last kept)
    static_tf_changed: list[tuple[str, str]] = field(default_factory=list)
    tf: list[TransformSeries] = field(default_factory=list)  # dynamic /tf edges
    landmark_truth: dict[int, np.ndarray] | None = None  # id -> (3,) in the truth frame
    bias_truth: dict[str, np.ndarray] | None = None  # {"gyro": (3,), "velocity": (3,)} body frame (simulated logs)
    warnings: list[str] = field(default_factory=list)
    #: topics whose message type the log's metadata leaves empty (a damaged rosbag2 metadata.yaml): no role can read
    #: them, so the error of a missing role names them
    untyped: list[str] = field(default_factory=list)
    #: per role, the log's topics of a type it accepts that hold no message (``topic (type)``): the error of a
    #: missing role names them, not only the types that would give it
    empty: dict[str, list[str]] = field(default_factory=dict)
    #: record-time spans (first, last ns) that missing files of a split recording leave between the files read:
    #: the alignment starts a new segment after each rather than interpolate across it
    missing_spans: list[tuple[int, int]] = field(default_factory=list)
    clocks: dict[str, str] = field(default_factory=dict)  # topic -> "record" where record time replaced the stamp
    #: Tag corners per camera topic (corner messages, or tags found in images), made landmarks by
    #: :mod:`pipeline.vision.landmarks` into ``detections``.
    tag_corners: list[CornerStream] = field(default_factory=list)
    #: Camera models of the ``camera_info`` topics (:class:`pipeline.vision.cameras.CameraModel`).
    camera_info: list = field(default_factory=list)
    #: Roles whose values were derived rather than read, and how (e.g. angular velocity from orientations).
    derived: dict[str, str] = field(default_factory=dict)
    #: What each sample of an odometry's twist is, read from the topic's own poses when both velocities are that
    #: twist (:func:`.readers.odometry.twist_sampling`), else None; read as interval means, both velocities were
    #: restamped to their intervals' midpoints (:func:`.readers.odometry.midpoint_restamped`, ``restamped``).
    twist_sampling: dict | None = None
    #: Where they were so restamped: per sample of the angular velocity, the nanoseconds from its new stamp back to
    #: the start of the interval it averages (:func:`.readers.odometry.interval_spans`), which the alignment turns
    #: into ``AlignedStream.vel_start_ns``; else None.
    twist_to_start_ns: np.ndarray | None = None
    #: What the log says about reading it (a simulated log's ``tag_size`` and ``tag_family``): used where the
    #: config leaves them unset.
    recorded: dict[str, object] = field(default_factory=dict)
    #: Role -> what the velocity topic's messages state of its noise, every message judged
    #: (``readers.covariance.StatedNoise``; roles whose message type states none are left out).
    stated_covariance: dict[str, object] = field(default_factory=dict)
    #: Role -> (the odometry's poses, the velocity stream read) on the same stamps, where the velocity topic is an
    #: odometry whose messages carry poses: a stated level is tested against the twist's drift from them
    #: (``noise.drift_evidence``)
    odometry_poses: dict[str, tuple] = field(default_factory=dict)
