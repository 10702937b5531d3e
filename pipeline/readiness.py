"""Whether a log can run, per estimator: which inputs were found, which are missing and what would give them.

Pure over the log's inspection (:class:`pipeline.readers.LogInfo`): the roles every estimator needs
(``roles.REQUIRED_ROLES``), the inertial directions some need (``ObserverSpec.directions_needed``, from the
``roles.DIRECTION_ROLES``) and the truth the error report needs. What would give a missing role comes from the
readers' own tables (``roles.how_to_satisfy``), and a ``run.yaml`` names the topics found, so a user sees in one
screen whether and how the log runs. ``slamobs info`` renders it (``cli/info_cmd.py``).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace

from slamobs.pipeline.config import DEFAULT_OBSERVER, RunConfig, TagsConfig
from slamobs.pipeline.errors import SlamobsError, one_line
from slamobs.pipeline.estimators import ESTIMATORS
from slamobs.pipeline.readers.inspect import LogInfo
from slamobs.pipeline.readers.roles import (
    DIRECTION_ROLES,
    IMAGE_TYPES,
    REQUIRED_ROLES,
    ROLE_PURPOSE,
    TAG_CORNER_TYPES,
    accepted_types,
    empty_topics,
    how_to_satisfy,
    trajectory_use,
)

#: The roles the readiness section lists, in order: what every estimator needs, the directions, the truth.
LISTED_ROLES = (*REQUIRED_ROLES, *DIRECTION_ROLES, "truth")


@dataclass(frozen=True)
class RoleStatus:
    """One role: the topic(s) found for it (empty when missing), the type and rate of the first."""

    role: str
    topic: str = ""
    msgtype: str = ""
    rate_hz: float | None = None

    @property
    def found(self) -> bool:
        return bool(self.topic)


@dataclass(frozen=True)
class EstimatorStatus:
    """One estimator: the inputs it lacks on this log (empty: it can run), or why it cannot be used at all."""

    name: str
    missing: tuple[str, ...] = ()
    unavailable: str = ""  # e.g. an optional dependency not installed
    #: settings the run will ask for on this log (e.g. ``tags.size`` for tag corners): it has the inputs, but
    #: ``slamobs run`` stops with one line until the config gives these
    needs: tuple[str, ...] = ()

    @property
    def ready(self) -> bool:
        return not self.missing and not self.unavailable


@dataclass(frozen=True)
class Readiness:
    """The readiness of one log: role statuses, per-estimator statuses, what satisfies each missing role."""

    roles: tuple[RoleStatus, ...]
    estimators: tuple[EstimatorStatus, ...]
    satisfy: dict[str, list[str]]
    run_yaml: str
    #: the sim_truth topic and what it holds (``LogInfo.sim_truth``: an MR.CLAM import's landmark survey, a
    #: simulated log's map and biases), "" when the log has none: the map error's truth, beside the trajectory's
    map_truth: str = ""
    #: a log of poses without the velocities (evo's example bags): what it is good for instead
    #: (``roles.trajectory_use``, the words ``run``'s error ends with), "" otherwise
    trajectory: str = ""

    def to_dict(self) -> dict:
        """JSON-ready dictionary."""
        doc = asdict(self)
        doc["ready"] = [e.name for e in self.estimators if e.ready]
        return doc


def _role_status(info: LogInfo, role: str) -> RoleStatus:
    topic = info.roles.get(role, "")
    first = topic.split(", ")[0]
    summary = next((t for t in info.topics if t.topic == first), None)
    if summary is None:
        return RoleStatus(role, topic)
    return RoleStatus(role, topic, summary.msgtype, summary.rate_hz)


def _estimator_status(name: str, found: set[str]) -> EstimatorStatus:
    """What ``name`` lacks given the roles found: every required role, and enough direction roles."""
    missing = [r for r in REQUIRED_ROLES if r not in found]
    try:
        needed = ESTIMATORS[name].directions_needed(RunConfig())
    except SlamobsError as err:  # an estimator whose optional dependency is missing
        return EstimatorStatus(name, tuple(missing), one_line(err))
    have = [r for r in DIRECTION_ROLES if r in found]
    if len(have) < needed:
        missing += [r for r in DIRECTION_ROLES if r not in found][: needed - len(have)]
    return EstimatorStatus(name, tuple(missing))


#: what a log of tag corners without a CameraInfo topic asks of the config (besides the tag size)
CAMERAS_NEED = "cameras: (calibration files; the log has no CameraInfo topic)"


def _settings_needed(info: LogInfo, detections: RoleStatus, config: RunConfig | None = None) -> tuple[str, ...]:
    """What a run on tag corners or images asks of the config: the tag size (a simulated log records it), and
    for corners without a CameraInfo topic the camera calibration files; none of what ``config`` gives."""
    needs = []
    sized = config is not None and (config.tags.size is not None or bool(config.tags.sizes))
    tags = detections.msgtype in TAG_CORNER_TYPES or detections.msgtype in IMAGE_TYPES
    if tags and "sim_truth" not in info.roles and not sized:
        needs.append("tags.size")
    calibrated = config is not None and bool(config.cameras)
    if detections.msgtype in TAG_CORNER_TYPES and "camera_info" not in info.roles and not calibrated:
        needs.append(CAMERAS_NEED)
    return tuple(needs)


def _candidates(info: LogInfo, role: str) -> list[str]:
    """Topics of this log whose type ``role`` accepts when named (never picked on their own), and those of an
    accepted type that hold no messages (a detections topic recorded empty is why the role is missing)."""
    types = accepted_types(role)
    used = {t for r, topics in info.roles.items() if r != role and r in LISTED_ROLES for t in topics.split(", ")}
    found = [f"{t.topic} ({t.msgtype})" for t in info.topics if t.msgtype in types and t.count and t.topic not in used]
    empty = empty_topics(role, ((t.topic, t.msgtype, t.count) for t in info.topics))
    return ([f"this log has: {', '.join(found)}"] if found else []) + (
        [f"this log has no messages on: {', '.join(empty)}"] if empty else []
    )


def readiness(info: LogInfo, config: RunConfig | None = None) -> Readiness:
    """Whether and how ``info``'s log can run, per estimator (see the module docstring); the settings ``config``
    gives (``tags.size``, ``cameras``) are not asked for again."""
    roles = tuple(_role_status(info, r) for r in LISTED_ROLES)
    found = {r.role for r in roles if r.found}
    needs = _settings_needed(info, next(r for r in roles if r.role == "detections"), config)
    estimators = tuple(replace(_estimator_status(name, found), needs=needs) for name in ESTIMATORS)
    satisfy = {r.role: how_to_satisfy(r.role) + _candidates(info, r.role) for r in roles if not r.found}
    sim = info.roles.get("sim_truth")
    map_truth = f"{sim}  ({info.sim_truth})" if sim and info.sim_truth else ""
    truth = info.roles.get("truth", "")
    trajectory = ""
    if truth:
        others = [t.topic for t in info.topics if t.count and t.msgtype in accepted_types("truth") and t.topic != truth]
        trajectory = trajectory_use(info.path, truth, others, missing=[r for r in REQUIRED_ROLES if r not in found])
    return Readiness(roles, estimators, satisfy, run_yaml(roles, estimators), map_truth, trajectory)


def run_yaml(roles: tuple[RoleStatus, ...], estimators: tuple[EstimatorStatus, ...]) -> str:
    """A ``run.yaml`` naming the topics found (valid against the config schema); what it still needs as comments."""
    ready = [e.name for e in estimators if e.ready]
    observer = DEFAULT_OBSERVER if DEFAULT_OBSERVER in ready or not ready else ready[0]
    lines = [f"observer: {observer}", "topics:"]
    for r in roles:
        if r.found:
            topics = r.topic.split(", ")
            value = json.dumps(topics[0]) if len(topics) == 1 else json.dumps(topics)
            lines.append(f"  {r.role}: {value}")
        else:
            what = "<topic, 'parent->child', a trajectory file or LOG:TOPIC>" if r.role == "truth" else "<topic>"
            lines.append(f"  # {r.role}: {what}  # missing: {ROLE_PURPOSE[r.role]}")
    detections = next(r for r in roles if r.role == "detections")
    if detections.msgtype in TAG_CORNER_TYPES or detections.msgtype in IMAGE_TYPES:
        lines += ["# tag corners and images need the tag edge (m) and family:", "# tags:", "#   size: <edge in m>"]
        if detections.msgtype in IMAGE_TYPES:
            lines.append(f"#   family: {TagsConfig.family}")
    if any(CAMERAS_NEED in e.needs for e in estimators):
        lines += _cameras_comment(len(detections.topic.split(", ")))
    return "\n".join(lines) + "\n"


def _cameras_comment(cameras: int) -> list[str]:
    """The ``cameras:`` lines of a ``run.yaml`` for tag corners without CameraInfo: the calibration file, and with
    several cameras the files that place each on the rig (``run`` drops a camera it cannot place, TagSLAM test_21:
    three of four without ``camera_poses.yaml``, all four without ``tagslam.yaml``'s ``T_body_odom``)."""
    lines = ["# no CameraInfo topic: name the cameras' calibration files (paths relative to this file):"]
    if cameras == 1:
        return lines + ["# cameras: <Kalibr camchain or ROS camera_info YAML>"]
    return lines + [
        "# cameras:",
        "#   - <Kalibr camchain (intrinsics; T_cn_cnm1 between the cameras) or ROS camera_info YAML per camera>",
        "#   - <where each camera sits on the rig, unless on /tf: e.g. TagSLAM camera_poses.yaml>",
        "#   - <where the odometry's frame sits on the rig: e.g. TagSLAM tagslam.yaml (T_body_odom)>",
    ]
