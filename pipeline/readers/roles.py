"""Which topic plays which role, decided from message types (and two fixed topic names).

Detection is deterministic: within the preferred type the topic with the most messages wins (ties by
name), and the losers are named in a warning so a user knows which role to override.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from pipeline.errors import InputError

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
MAGNETIC_FIELD = "sensor_msgs/msg/MagneticField"
FIDUCIALS = "fiducial_msgs/msg/FiducialTransformArray"
FIDUCIALS_LEGACY = "fiducial_pose/msg/FiducialTransformArray"  # same layout, pre-2017 package name
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF2 = "tf2_msgs/msg/TFMessage"
TF1 = "tf/msg/tfMessage"  # ROS1 tf (not tf2) bags
STRING = "std_msgs/msg/String"

#: Roles in the order they are reported.
ROLES: tuple[str, ...] = (
    "angular_velocity",
    "linear_velocity",
    "accel",
    "magnetic",
    "detections",
    "truth",
    "static_tf",
    "sim_truth",
)

#: Types each role accepts, as tiers in order of preference; a lower tier is used only if the one
#: above has no topic.
ROLE_TYPES: dict[str, tuple[tuple[str, ...], ...]] = {
    "angular_velocity": ((IMU,), (ODOMETRY,)),
    "linear_velocity": ((ODOMETRY,), (TWIST_STAMPED,)),
    "accel": ((IMU,),),
    "magnetic": ((MAGNETIC_FIELD,),),
    "detections": ((FIDUCIALS,), (FIDUCIALS_LEGACY,)),
    "truth": ((POSE_STAMPED,),),
    "static_tf": ((TF2, TF1),),
    "sim_truth": ((STRING,),),
}

#: Roles found by topic name (their types are too generic to detect by type alone).
ROLE_TOPIC_NAMES: dict[str, str] = {
    "static_tf": "/tf_static",
    "sim_truth": "/slamobs/sim_truth",
}


@dataclass(frozen=True)
class TopicMeta:
    """What role selection needs to know about a topic."""

    msgtype: str
    count: int


def topics_of(reader: AnyReader) -> dict[str, tuple[TopicMeta, list[Connection]]]:
    """Topics of an opened log with their type, message count and connections.

    A topic recorded with several types keeps the type with the most messages (and only its connections).
    """
    table: dict[str, tuple[TopicMeta, list[Connection]]] = {}
    for topic, info in reader.topics.items():
        per_type: dict[str, list[Connection]] = {}
        for conn in info.connections:
            per_type.setdefault(conn.msgtype, []).append(conn)
        msgtype, conns = max(per_type.items(), key=lambda x: (sum(c.msgcount for c in x[1]), x[0]))
        table[topic] = (TopicMeta(msgtype, sum(c.msgcount for c in conns)), conns)
    return table


@dataclass
class RoleSelection:
    """Role -> topic, plus warnings about ambiguous choices."""

    roles: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def accepted_types(role: str) -> tuple[str, ...]:
    """All types ``role`` accepts, most preferred first."""
    return tuple(t for tier in ROLE_TYPES[role] for t in tier)


def _same_name(topic: str, name: str) -> bool:
    """Compare topic names ignoring the leading slash (ROS1 bags may omit it)."""
    return topic.lstrip("/") == name.lstrip("/")


def _pick(role: str, topics: Mapping[str, TopicMeta]) -> tuple[str | None, str | None]:
    """Best topic for ``role`` and a warning if other topics could have played it."""
    name = ROLE_TOPIC_NAMES.get(role)
    for tier in ROLE_TYPES[role]:
        found = [
            (topic, meta)
            for topic, meta in topics.items()
            if meta.msgtype in tier and meta.count > 0 and (name is None or _same_name(topic, name))
        ]
        if not found:
            continue
        found.sort(key=lambda x: (-x[1].count, x[0]))
        best, meta = found[0]
        warning = None
        if len(found) > 1:
            others = ", ".join(f"{t} ({m.count})" for t, m in found[1:])
            warning = (
                f"{role}: {len(found)} candidate topics, using {best} ({meta.count} messages); "
                f"ignored {others}; override {role} to choose another"
            )
        return best, warning
    return None, None


def select_roles(
    topics: Mapping[str, TopicMeta],
    overrides: Mapping[str, str | None] | None = None,
    path: str | Path = "",
) -> RoleSelection:
    """Assign topics to roles; ``overrides`` (role -> topic, ``''``/``None`` = unused) win over detection.

    Raises:
        InputError: Unknown role, or an override naming a topic that is absent or of the wrong type.

    """
    overrides = dict(overrides or {})
    selection = RoleSelection()
    for role, topic in overrides.items():
        if role not in ROLE_TYPES:
            raise InputError(path, f"unknown role {role!r} (roles: {', '.join(ROLES)})")
        if not topic:
            continue
        if topic not in topics:
            names = sorted(topics)
            known = ", ".join(names[:12]) + (f", ... ({len(names)} topics)" if len(names) > 12 else "") or "none"
            raise InputError(path, f"topic for role {role} is not in the log (topics: {known})", topic)
        if (msgtype := topics[topic].msgtype) not in accepted_types(role):
            expected = " or ".join(accepted_types(role))
            raise InputError(path, f"type {msgtype} is not supported for role {role} (expected {expected})", topic)

    for role in ROLES:
        if role in overrides:
            if overrides[role]:
                selection.roles[role] = str(overrides[role])
            continue
        gyro = selection.roles.get("angular_velocity", "")
        if role == "accel" and gyro in topics and topics[gyro].msgtype == IMU:
            selection.roles[role] = gyro  # same Imu as the gyro: one clock, one frame
            continue
        topic, warning = _pick(role, topics)
        if topic is not None:
            selection.roles[role] = topic
        if warning:
            selection.warnings.append(warning)
    return selection
