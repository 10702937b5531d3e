"""Which topic plays which role, decided from message types (and three fixed topic names).

Detection is deterministic: within the preferred type the topic with the most messages wins (ties by
name), and the losers are named in a warning so a user knows which role to override. Some types fit a role
only when a user says so (``EXPLICIT_TYPES``): a ``PoseArray``, ``MarkerArray`` or TF tag frames are as often
a map or a visualisation as a detection, and odometry or AMCL poses are estimates, not ground truth.
Topics named like commanded velocities (``cmd_vel``) are never picked as measurements.

Detections without a 3D pose, tag corners in pixels and camera images (the last two tiers), are the cameras
of a rig: every topic of the chosen tier is used (``RoleSelection.multi``), each with its camera model from
the ``camera_info`` topics (also all of them) or the config. Of an image topic also recorded compressed
(``X`` and ``X/compressed``) only ``X`` is searched, and topics named like depth images are left out.
"""

from __future__ import annotations

import difflib

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from slamobs.pipeline.errors import InputError

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
TWIST_COV_STAMPED = "geometry_msgs/msg/TwistWithCovarianceStamped"
MAGNETIC_FIELD = "sensor_msgs/msg/MagneticField"
FIDUCIALS = "fiducial_msgs/msg/FiducialTransformArray"
FIDUCIALS_LEGACY = "fiducial_pose/msg/FiducialTransformArray"  # same layout, pre-2017 package name
APRILTAG_ROS = "apriltag_ros/msg/AprilTagDetectionArray"  # ROS1 apriltag_ros: id list + pose per detection
POSE_ARRAY = "geometry_msgs/msg/PoseArray"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
TF2 = "tf2_msgs/msg/TFMessage"
TF1 = "tf/msg/tfMessage"  # ROS1 tf (not tf2) bags
TF_TYPES = (TF2, TF1)
STRING = "std_msgs/msg/String"
DET = "detections"
#: Tag corners in pixels (no 3D pose): a PnP with the camera model and the tag size makes them landmarks.
TAG_CORNER_TYPES = (
    "apriltag_msgs/msg/ApriltagArrayStamped",  # ROS1 apriltag_ros (KumarRobotics / TagSLAM's detector)
    "apriltag_detector_msgs/msg/ApriltagArrayStamped",  # berndpfrommer/apriltag_detector (ROS1 and ROS2)
    "apriltag_msgs/msg/AprilTagDetectionArray",  # ROS2 christianrauch/apriltag_ros
    "fiducial_msgs/msg/FiducialArray",  # UbiquityRobotics aruco_detect
    "fiducial_pose/msg/FiducialArray",  # same, pre-2017 package name
)
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
FOXGLOVE_IMAGE = "foxglove_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE, FOXGLOVE_IMAGE)
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

#: Separator of a TF edge given as a topic (``topics.truth: "map->base_link"``).
EDGE_ARROW = "->"

#: The forms a truth may be given in, everywhere one is accepted (``trajectory_files.parse_truth`` reads them).
TRUTH_FORMS = (
    "a truth is a topic of the log, a TF edge 'parent->child', a TUM / EuRoC CSV / KITTI file, or another "
    "log's topic LOG:TOPIC"
)

#: Roles in the order they are reported.
ROLES: tuple[str, ...] = (
    "angular_velocity",
    "linear_velocity",
    "accel",
    "magnetic",
    "detections",
    "truth",
    "static_tf",
    "tf",
    "sim_truth",
    "camera_info",
)

#: Types each role accepts, as tiers in order of preference; a lower tier is used only if the one
#: above has no topic.
ROLE_TYPES: dict[str, tuple[tuple[str, ...], ...]] = {
    "angular_velocity": ((IMU,), (ODOMETRY,), (TWIST_STAMPED, TWIST_COV_STAMPED)),
    "linear_velocity": ((ODOMETRY,), (TWIST_STAMPED, TWIST_COV_STAMPED)),
    "accel": ((IMU,),),
    "magnetic": ((MAGNETIC_FIELD,),),
    "detections": ((FIDUCIALS,), (FIDUCIALS_LEGACY,), (APRILTAG_ROS,), TAG_CORNER_TYPES, IMAGE_TYPES),
    "truth": ((POSE_STAMPED,), (TRANSFORM_STAMPED,)),
    "static_tf": (TF_TYPES,),
    "tf": (TF_TYPES,),
    "sim_truth": ((STRING,),),
    "camera_info": ((CAMERA_INFO,),),
}

#: Tiers whose topics are all used together (the cameras of a rig), and roles that always take every topic.
MULTI_TIERS = (TAG_CORNER_TYPES, IMAGE_TYPES)
MULTI_ROLES = frozenset({"camera_info"})

#: Types a role accepts only as an explicit override (never detected). TF types as detections also need a
#: tag frame pattern; TF truth is given as an edge ``parent->child``, not as a topic.
EXPLICIT_TYPES: dict[str, tuple[str, ...]] = {
    "detections": (POSE_ARRAY, MARKER_ARRAY, *TF_TYPES),
    "truth": (POSE_COV_STAMPED, ODOMETRY),
}

#: Roles every estimator needs (a run without one cannot start), and the roles that give inertial directions
#: (gravity from the accelerometer, the magnetic field) for the estimators that need them.
REQUIRED_ROLES = ("angular_velocity", "linear_velocity", "detections")
DIRECTION_ROLES = ("accel", "magnetic")

#: What each role is, in a user's words.
ROLE_PURPOSE: dict[str, str] = {
    "angular_velocity": "angular velocity, gyro",
    "linear_velocity": "body linear velocity",
    "accel": "accelerometer, gravity direction",
    "magnetic": "magnetic field direction",
    "detections": "landmark detections",
    "truth": "ground-truth trajectory, for the error report",
    "static_tf": "static transforms",
    "tf": "transforms",
    "sim_truth": "simulation truth",
    "camera_info": "camera models",
}

#: What the tool does with a type in a role beyond decoding it, or what more it needs (config keys).
TYPE_NEEDS: dict[tuple[str, str], str] = {
    ("angular_velocity", ODOMETRY): "a zero twist.angular is differentiated from the orientations",
    ("linear_velocity", ODOMETRY): "a twist.linear in the parent frame is rotated into the child frame",
    **{(DET, t): "tags.size (edge, m) and camera_info or cameras:" for t in TAG_CORNER_TYPES},
    **{(DET, t): "tags.size and tags.family; tags found in the images" for t in IMAGE_TYPES},
    (DET, MARKER_ARRAY): "frames.marker_namespace picks one namespace",
    **{(DET, t): "frames.tag_pattern, e.g. 'tag_{id}'" for t in TF_TYPES},
}

#: Other ways to give a role than a topic of the log (config keys).
ROLE_ALTERNATIVES: dict[str, str] = {
    "truth": "or as topics.truth: a TF edge 'parent->child', a TUM / EuRoC CSV / KITTI file, or another log's "
    "LOG:TOPIC",
}


#: the motion roles: a log without either runs no estimator, and its truth is a trajectory to measure others against
MOTION_ROLES = ("angular_velocity", "linear_velocity")


def trajectory_use(path: str, topic: str, others: Iterable[str] = (), missing: Iterable[str] = MOTION_ROLES) -> str:
    """What a log of poses without a velocity is good for (evo's example bags; ETH's dataset.bag, an IMU with no
    linear velocity beside its Vicon truth, whose error did not say it, round 26), in one wording and one rule for
    ``run``'s error and ``info``'s readiness: its pose topic ``topic`` is a trajectory ``slamobs evaluate`` measures
    another against; ``others``, the log's other pose topics, name one such estimate. "" where the log has both
    motion roles (``missing``: the required roles it lacks): it runs once its detections are given."""
    if not set(MOTION_ROLES) & set(missing):
        return ""
    first = next(iter(others), None)
    also = f" (EST: e.g. {path}:{first}, another pose topic of this log)" if first else ""
    return f"its poses ({topic}) are a trajectory: `slamobs evaluate {path}:{topic} EST` measures another's error{also}"


def how_to_satisfy(role: str) -> list[str]:
    """Lines saying what would give ``role``: every accepted type, grouped by what it needs, and the config keys
    (types only named, never detected, are marked)."""
    groups: dict[str, list[str]] = {}
    for msgtype in accepted_types(role):
        need = TYPE_NEEDS.get((role, msgtype), "")
        if msgtype in EXPLICIT_TYPES.get(role, ()) and msgtype not in TF_TYPES:  # TF tag frames: by the pattern
            need = "; ".join(x for x in (f"only when named in topics.{role}", need) if x)
        groups.setdefault(need, []).append(msgtype)
    lines = [", ".join(types) + (f"  [{need}]" if need else "") for need, types in groups.items()]
    lines = [f"set topics.{role} to a topic of type {lines[0]}", *(f"or {x}" for x in lines[1:])]
    return [*lines, ROLE_ALTERNATIVES[role]] if role in ROLE_ALTERNATIVES else lines


#: Roles found by topic name (their types are too generic to detect by type alone).
ROLE_TOPIC_NAMES: dict[str, str] = {
    "static_tf": "/tf_static",
    "tf": "/tf",
    "sim_truth": "/slamobs/sim_truth",
}

#: Roles that take measurements: topics named like commands are not candidates for them.
_MEASURED = frozenset({"angular_velocity", "linear_velocity"})


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
    """Role -> topic, plus warnings about ambiguous choices.

    ``truth_edge`` is ``(parent, child)`` when the truth is a TF edge (``roles["truth"]`` is then its TF topic);
    ``tag_pattern`` is set when the detections are TF tag frames (``roles["detections"]`` is a TF topic).
    """

    roles: dict[str, str] = field(default_factory=dict)
    #: Roles played by several topics together (tag corners or images of several cameras, camera_info):
    #: every topic; ``roles`` holds the first.
    multi: dict[str, list[str]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    truth_edge: tuple[str, str] | None = None
    tag_pattern: str | None = None


def accepted_types(role: str) -> tuple[str, ...]:
    """All types ``role`` accepts, most preferred first (detected ones, then override-only ones)."""
    return tuple(t for tier in ROLE_TYPES[role] for t in tier) + EXPLICIT_TYPES.get(role, ())


def empty_topics(role: str, topics: Iterable[tuple[str, str, int]]) -> list[str]:
    """``topic (type)`` of each of ``topics`` (name, type, message count) of a type ``role`` accepts that holds no
    message: a topic recorded empty is why the role is missing, and what ``info`` and a run's error name."""
    types = accepted_types(role)
    return [f"{topic} ({msgtype})" for topic, msgtype, count in topics if msgtype in types and not count]


def parse_edge(text: str) -> tuple[str, str] | None:
    """``"map -> base_link"`` -> ``("map", "base_link")``; None if ``text`` is a topic name."""
    if EDGE_ARROW not in text:
        return None
    parent, _, child = (x.strip().lstrip("/") for x in text.partition(EDGE_ARROW))
    return (parent, child) if parent and child and EDGE_ARROW not in child else ("", "")


def _is_command(topic: str) -> bool:
    return "cmd_vel" in topic.rsplit("/", 1)[-1]


def _same_name(topic: str, name: str) -> bool:
    """Compare topic names ignoring the leading slash (ROS1 bags may omit it)."""
    return topic.lstrip("/") == name.lstrip("/")


def is_multi(msgtype: str) -> bool:
    """Whether topics of this type play their role together (cameras of a rig)."""
    return any(msgtype in tier for tier in MULTI_TIERS) or msgtype == CAMERA_INFO


def _cameras(found: list[str], topics: Mapping[str, TopicMeta]) -> tuple[list[str], list[str]]:
    """Image topics worth searching (not depth, not the compressed copy of a raw topic) and what was left out."""
    keep, dropped = [], []
    for topic in found:
        parent = topic.rsplit("/", 1)[0]
        if "depth" in topic.lower():
            dropped.append(f"{topic} (depth)")
        elif topics[topic].msgtype != IMAGE and parent in found and topics[parent].msgtype == IMAGE:
            dropped.append(f"{topic} (compressed copy of {parent})")
        else:
            keep.append(topic)
    return keep, dropped


def _pick_all(role: str, topics: Mapping[str, TopicMeta]) -> tuple[list[str], str | None]:
    """Every topic of the first tier of ``role`` that has one, when that tier is played together."""
    for tier in ROLE_TYPES[role]:
        found = sorted(t for t, m in topics.items() if m.msgtype in tier and m.count > 0)
        if not found:
            continue
        if tier not in MULTI_TIERS and role not in MULTI_ROLES:
            return [], None
        warning = None
        if tier is IMAGE_TYPES:
            found, dropped = _cameras(found, topics)
            if dropped:
                warning = f"{role}: image topics not searched: {', '.join(dropped)}"
        return found, warning
    return [], None


def _pick(role: str, topics: Mapping[str, TopicMeta]) -> tuple[str | None, str | None]:
    """Best topic for ``role`` and a warning if other topics could have played it."""
    name = ROLE_TOPIC_NAMES.get(role)
    for tier in ROLE_TYPES[role]:
        found = [
            (topic, meta)
            for topic, meta in topics.items()
            if meta.msgtype in tier
            and meta.count > 0
            and (name is None or _same_name(topic, name))
            and not (role in _MEASURED and _is_command(topic))
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


def did_you_mean(topic: str, *candidates: list[str]) -> str:
    """ "did you mean NAME? " for the topic name closest to a mistyped ``topic`` in the first list of ``candidates``
    that has one, or "": what every error naming a topic not in a log offers."""
    for names in candidates:
        if close := difflib.get_close_matches(topic, names, n=1, cutoff=0.6):
            return f"did you mean {close[0]}? "
    return ""


def _check_override(
    role: str,
    topic: str,
    topics: Mapping[str, TopicMeta],
    path: str | Path,
    tag_pattern: str | None,
) -> None:
    if topic not in topics:
        names = sorted(topics)
        known = ", ".join(names[:12]) + (f", ... ({len(names)} topics)" if len(names) > 12 else "") or "none"
        hint = f"; a truth that is no existing file reads as a topic; {TRUTH_FORMS}" if role == "truth" else ""
        fitting = [name for name in names if topics[name].msgtype in accepted_types(role)]  # of the role's types
        mean = did_you_mean(topic, fitting, names)  # among all, also those not listed
        raise InputError(path, f"topic for role {role} is not in the log ({mean}topics: {known}){hint}", topic)
    msgtype = topics[topic].msgtype
    if msgtype not in accepted_types(role):
        expected = " or ".join(accepted_types(role))
        hint = "; a TF edge is given as 'parent->child'" if role == "truth" and msgtype in TF_TYPES else ""
        raise InputError(path, f"type {msgtype} is not supported for role {role} (expected {expected}){hint}", topic)
    if role == "detections" and msgtype in TF_TYPES and not tag_pattern:
        raise InputError(
            path, "TF tag frames as detections need a tag frame pattern (frames.tag_pattern, e.g. 'tag_{id}')", topic
        )


def select_roles(
    topics: Mapping[str, TopicMeta],
    overrides: Mapping[str, str | None] | None = None,
    path: str | Path = "",
    *,
    tag_pattern: str | None = None,
) -> RoleSelection:
    """Assign topics to roles; ``overrides`` (role -> topic, ``''``/``None`` = unused) win over detection.

    ``overrides["truth"]`` may be a TF edge ``"parent->child"`` (read from the ``/tf`` topic, or ``tf``'s
    override). A ``tag_pattern`` (``"tag_{id}"``) makes TF tag frames the detections unless ``detections`` is
    overridden with a non-TF topic: asking for tag frames is explicit, so it wins over detected types.

    Raises:
        InputError: Unknown role, an override naming a topic that is absent or of the wrong type, a malformed
            TF edge, or a TF source without a TF topic.

    """
    overrides = dict(overrides or {})
    selection = RoleSelection()
    edge = None
    for role, topic in overrides.items():
        if role not in ROLE_TYPES:
            raise InputError(path, f"unknown role {role!r} (roles: {', '.join(ROLES)})")
        if not topic:
            continue
        if role == "truth" and isinstance(topic, str) and (edge := parse_edge(topic)) is not None:
            if not all(edge):
                raise InputError(path, f"truth TF edge {topic!r} is not 'parent->child'")
            continue
        names = _names(topic)
        for name in names:
            _check_override(role, name, topics, path, tag_pattern)
        if len(names) > 1 and not all(role in MULTI_ROLES or is_multi(topics[n].msgtype) for n in names):
            raise InputError(
                path,
                f"several topics for role {role} only work for tag corners, camera images and "
                f"camera_info (got {', '.join(names)})",
            )

    for role in ROLES:
        if role in overrides:
            if overrides[role] and not (role == "truth" and edge):
                names = _names(overrides[role])
                selection.roles[role] = names[0]
                if role in MULTI_ROLES or is_multi(topics[names[0]].msgtype):
                    selection.multi[role] = names
            continue
        gyro = selection.roles.get("angular_velocity", "")
        if role == "accel" and gyro in topics and topics[gyro].msgtype == IMU:
            selection.roles[role] = gyro  # same Imu as the gyro: one clock, one frame
            continue
        topic, warning = _pick(role, topics)
        if topic is not None and (role in MULTI_ROLES or is_multi(topics[topic].msgtype)):
            found, warning = _pick_all(role, topics)
            if found:
                selection.multi[role] = found
            topic = found[0] if found else None
        if topic is not None:
            selection.roles[role] = topic
        if warning:
            selection.warnings.append(warning)

    if "truth" not in overrides and "truth" not in selection.roles and (hint := _named_truth_hint(topics, selection)):
        selection.warnings.append(hint)
    tf_topic = overrides.get("tf") or _pick("tf", topics)[0]
    if edge is not None:
        if not tf_topic:
            raise InputError(path, f"truth TF edge {edge[0]}->{edge[1]} needs a /tf topic; the log has none")
        selection.roles["truth"], selection.truth_edge = tf_topic, edge
    _tag_frames(selection, overrides, topics, tf_topic, tag_pattern, path)
    return selection


def _named_truth_hint(topics: Mapping[str, TopicMeta], selection: RoleSelection) -> str | None:
    """With no truth found: the topics of a type taken as truth only when named (a PoseWithCovarianceStamped, an
    odometry no other role reads), so that a run without an error report says where a truth may be."""
    used = set(selection.roles.values())
    found = [t for t, m in sorted(topics.items()) if m.msgtype in EXPLICIT_TYPES["truth"] and m.count and t not in used]
    if not found:
        return None
    listed = ", ".join(f"{t} ({topics[t].msgtype})" for t in found)
    return (
        f"truth: none found; {listed}: a truth only when named (topics.truth: {found[0]}), "
        "as such poses are often estimates (odometry, AMCL)"
    )


def _names(value: str | list[str] | tuple[str, ...]) -> list[str]:
    """An override as a list of topics (``detections`` and ``camera_info`` may name several)."""
    return [str(v) for v in value] if isinstance(value, (list, tuple)) else [str(value)]


def _tag_frames(
    selection: RoleSelection,
    overrides: Mapping[str, str | None],
    topics: Mapping[str, TopicMeta],
    tf_topic: str | None,
    tag_pattern: str | None,
    path: str | Path,
) -> None:
    """Detections from TF tag frames when a pattern asks for them."""
    chosen = selection.roles.get("detections")
    if tag_pattern and "detections" not in overrides:
        if not tf_topic:
            raise InputError(path, f"tag frame pattern {tag_pattern!r} given but the log has no /tf topic")
        if chosen:
            selection.warnings.append(
                f"detections: using TF tag frames {tag_pattern!r} on {tf_topic}; ignored {chosen} "
                "(override detections to use it)"
            )
        selection.roles["detections"] = chosen = tf_topic
        selection.multi.pop("detections", None)
    if chosen and topics[chosen].msgtype in TF_TYPES:
        selection.tag_pattern = tag_pattern
    elif tag_pattern and chosen:
        selection.warnings.append(f"tag frame pattern {tag_pattern!r} unused: detections come from {chosen}")
