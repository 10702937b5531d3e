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
    landmarks in ``frame_id`` (the camera frame).
    """

    topic: str
    frame_id: str
    t_ns: np.ndarray  # (F,) int64
    rec_ns: np.ndarray  # (F,) int64
    offsets: np.ndarray  # (F + 1,) int64
    ids: np.ndarray  # (M,) int64
    xyz: np.ndarray  # (M, 3)

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
    static_tf: list[Transform] = field(default_factory=list)
    tf: list[TransformSeries] = field(default_factory=list)  # dynamic /tf edges
    landmark_truth: dict[int, np.ndarray] | None = None  # id -> (3,) in the truth frame
    bias_truth: dict[str, np.ndarray] | None = None  # {"gyro": (3,), "velocity": (3,)} body frame (simulated logs)
    warnings: list[str] = field(default_factory=list)
    clocks: dict[str, str] = field(default_factory=dict)  # topic -> "record" where record time replaced the stamp
