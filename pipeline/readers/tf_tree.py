"""``slamobs info``'s TF section: the log's ``/tf_static`` and ``/tf`` frames as a tree (each parent -> child edge
static or time-stamped, with its rate), and for each sensor's frame the transform into the body frame a run would
take (the camera extrinsic among them), or that none exists and what to set.

The edges are read by the readers' own decoders (``decode.static_transforms``, ``decode.transform_series``) and the
chains found by the run's :class:`~slamobs.pipeline.frames.TfBuffer` (static edges preferred, as alignment does), so
what ``info`` names is what ``run`` uses. Leaf frames that differ only in their digits (``tag_0`` .. ``tag_41``)
and hang off one parent the same way are shown as one line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from slamobs.pipeline.errors import InputError, plural
from slamobs.pipeline.frames import TfBuffer

from . import tfdecode
from .decode import TF_FAST_MESSAGES, VEC3_ROLES, decode_tf, static_transforms, transform_series
from .roles import TF_TYPES

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

_NS = 1_000_000_000

#: The roles whose samples a run moves into the body frame, in the order ``info`` lists them.
SENSOR_ROLES = ("angular_velocity", "linear_velocity", "accel", "magnetic", "detections")
#: The roles of an IMU's frame, which ``info`` (reading no samples) cannot tell mounted as the body or turned
#: (robot_localization's test1: 'imu_link' without a transform, its yaw rate on y; frames.assume_identity, which
#: ``info`` used to suggest for it, reads those axes wrong): its advice points to the check that can tell.
IMU_ROLES = ("angular_velocity", "accel", "magnetic")
#: That check (``alignment.gyro_axes_unaligned`` and the alignment's turned-gyro warning).
IMU_MOUNT_CHECK = (
    "slamobs info --noise LOG warns when its gyro turns about another axis than the odometry's own angular velocity "
    "(where the odometry gives one) or its accelerometer's gravity is not along the body's up axis (+z)"
)
#: Leaf siblings alike but for their digits, at least this many, are one line of the tree.
COLLAPSE_AT = 4
#: Lines of the tree shown at most; ``info --json`` lists every edge.
TREE_LINES = 40
#: A TF topic this long is decoded by the compiled walker even when its kernels are not compiled yet (~1.7 CPU s
#: to compile, what rosbags takes for ~40 000 messages at ~40 µs each); a shorter one by rosbags then.
COMPILE_FROM = 40_000


@dataclass(frozen=True)
class TfEdge:
    """One parent -> child edge: on ``/tf_static`` (``rate_hz`` None) or time-stamped on ``/tf``."""

    parent: str
    child: str
    topic: str
    count: int  # transforms published on the edge
    static: bool
    rate_hz: float | None = None  # time-stamped edges: distinct stamps per second over their span
    also_dynamic: bool = False  # a static edge also published on /tf: the run keeps the static value

    def label(self) -> str:
        """How the tree annotates the child: ``static``, or the /tf topic and rate."""
        if self.static:
            return "static" + (" (also on /tf: the static value is used)" if self.also_dynamic else "")
        rate = f"{self.rate_hz:.1f} Hz" if self.rate_hz is not None else "1 transform"
        return f"{self.topic} {rate}"


@dataclass(frozen=True)
class SensorFrame:
    """The frame of one sensor topic and how a run brings it into the body frame."""

    role: str
    topic: str
    frame: str
    how: str  # "body", "static", "tf", "no frame", "assumed", "override", "missing"
    chain: str = ""  # the edges used, e.g. "base_link->camera (/tf_static)"; missing: what each frame reaches
    turn_deg: float | None = None  # a static chain's rotation angle
    offset_m: float | None = None  # and its translation's length

    def text(self, body: str, cameras_given: bool) -> str:
        """The frame, the transform used or what is missing and what to set."""
        name = f"'{self.frame}'"
        if self.how == "no frame":
            return "no frame id: taken as the body frame (no transform applied)"
        if self.how == "body":
            return f"{name}, the body frame (no transform)"
        if self.how == "assumed":
            return f"{name} taken as the body (frames.assume_identity; TF has no transform)"
        if self.how == "override":
            return f"{name} taken as the body (frames.override_identity: any TF transform of it is not used)"
        camera = self.role == "detections"
        if self.how == "missing" and camera and cameras_given:
            return f"{name}: not in TF; the config's cameras: files must place it"
        if self.how == "missing" and self.role in IMU_ROLES:  # read no samples: whether it is the body's is unknown
            return (
                f"{name} -> '{body}' MISSING ({self.chain}): a run stops; record the transform on /tf_static, set "
                f"frames.body, or list '{self.frame}' in frames.assume_identity only if it is mounted as the body, "
                f"axes and all: {IMU_MOUNT_CHECK}"
            )
        if self.how == "missing":
            files = ", or give cameras: files with the extrinsic" if camera else ""
            return (
                f"{name} -> '{body}' MISSING ({self.chain}): a run stops; list '{self.frame}' in "
                f"frames.assume_identity if it is the body's frame, set frames.body{files}, or record the transform "
                "on /tf_static"
            )
        what = "the camera extrinsic, " if camera else ""
        if self.how == "tf":
            return f"{name} -> '{body}': {what}through /tf at each sample: {self.chain}"
        return f"{name} -> '{body}': {what}static {self.chain}, turned {self.turn_deg:.1f} deg, {self.offset_m:.3f} m"


@dataclass(frozen=True)
class TfSummary:
    """The log's TF edges, the body frame a run would take, and each sensor frame's way into it."""

    edges: tuple[TfEdge, ...]
    body: str
    body_from: str  # where the body frame comes from, e.g. "the child frame of /odom"
    sensors: tuple[SensorFrame, ...] = ()
    cameras_given: bool = False  # the config's cameras: files give camera extrinsics

    def lines(self) -> list[str]:
        """The section ``slamobs info`` prints: the tree, then each sensor frame's transform into the body."""
        static = sum(e.static for e in self.edges)
        if self.edges:
            counts = f"{plural(static, 'static edge')}, {plural(len(self.edges) - static, 'time-stamped edge')}"
            out = [f"  TF frames ({counts}; parent -> child)", *(f"    {x}" for x in _tree(self.edges, self.sensors))]
        else:
            out = ["  TF frames: none (no /tf_static or /tf transforms in the log)"]
        if not self.sensors:
            return out
        groups: dict[tuple[str, str], list[SensorFrame]] = {}
        for s in self.sensors:  # one line per topic and frame: an IMU's gyro and accelerometer share theirs
            groups.setdefault((s.topic, s.frame), []).append(s)
        heads = {key: f"{key[0]} ({', '.join(s.role for s in group)})" for key, group in groups.items()}
        width = max(len(h) for h in heads.values())
        out += ["", f"  frames into the body '{self.body}' ({self.body_from}; frames.body sets another)"]
        for key, group in groups.items():
            shown = next((s for s in group if s.role == "detections"), group[0])
            out.append(f"    {heads[key]:<{width}}  {shown.text(self.body, self.cameras_given)}")
        return out


def _pattern(name: str) -> str:
    return re.sub(r"\d+", "#", name)


def _collapsed(children: list[TfEdge], below: Mapping[str, list[TfEdge]]) -> list[tuple[str, str, list[str]]]:
    """(child shown, label, the frames it stands for) per line: alike leaves of one kind make one line."""
    groups: dict[tuple[str, str], list[TfEdge]] = {}
    for e in children:
        key = (_pattern(e.child), e.label()) if e.child not in below else (e.child, "")
        groups.setdefault(key, []).append(e)
    lines = []
    for (_, label), edges in groups.items():
        if len(edges) >= COLLAPSE_AT:
            names = sorted((e.child for e in edges), key=lambda n: [int(x) for x in re.findall(r"\d+", n)] or [0])
            lines.append((f"{names[0]} .. {names[-1]} ({len(names)} frames)", label, names))
        else:
            lines += [(e.child, e.label(), [e.child]) for e in edges]
    return lines


def _tree(edges: tuple[TfEdge, ...], sensors: tuple[SensorFrame, ...]) -> list[str]:
    """The frames as an indented tree from each root, sensor roles marked, at most :data:`TREE_LINES` lines."""
    below: dict[str, list[TfEdge]] = {}
    for e in edges:
        below.setdefault(e.parent, []).append(e)
    children = {e.child for e in edges}
    roles: dict[str, list[str]] = {}
    for s in sensors:
        roles.setdefault(s.frame, []).append(s.role)
    roots = sorted({e.parent for e in edges} - children) or sorted({e.parent for e in edges})[:1]
    out: list[str] = []
    seen: set[str] = set()

    def mark(frames: list[str]) -> str:
        named = [r for f in frames for r in roles.get(f, [])]
        return f"  <- {', '.join(dict.fromkeys(named))}" if named else ""

    def walk(frame: str, prefix: str) -> None:
        seen.add(frame)
        rows = [r for r in _collapsed(below.get(frame, []), below) if r[2][0] not in seen]
        for k, (shown, label, frames) in enumerate(rows):
            last = k == len(rows) - 1
            out.append(f"{prefix}{'└─ ' if last else '├─ '}{shown}  {label}{mark(frames)}")
            seen.update(frames)
            if len(frames) == 1:
                walk(frames[0], prefix + ("   " if last else "│  "))

    for root in roots:
        out.append(root + mark([root]))
        walk(root, "")
    for e in edges:  # a cycle or a frame under two parents: the edges not drawn yet
        if e.child not in seen:
            out.append(f"{e.parent} -> {e.child}  {e.label()}")
            seen.add(e.child)
    if len(out) > TREE_LINES:
        out = [*out[: TREE_LINES - 1], f"... {len(out) - TREE_LINES + 1} more lines (info --json lists every edge)"]
    return out


def _edges(reader: Any, path: Any, table: Mapping[str, Any], roles: Mapping[str, str]) -> tuple[TfBuffer, list]:
    """The run's TF buffer of the log's ``/tf_static`` and ``/tf`` topics, and their edges for the tree."""
    static, dynamic, edges = [], [], []
    for role in ("static_tf", "tf"):
        topic = roles.get(role)
        meta = table[topic][0] if topic is not None else None
        if (
            meta is None
            or meta.msgtype not in TF_TYPES
            or not meta.count
            or meta.msgtype not in reader.typestore.fielddefs
        ):
            continue  # no definition stored: inspect_log's notes say so
        try:
            fast_from = TF_FAST_MESSAGES if tfdecode.compiled() else COMPILE_FROM
            rows = decode_tf(reader, path, topic, table[topic][1], fast_from)
        except InputError:  # inspect_log's notes say why the topic cannot be read
            continue
        if role == "static_tf":
            static, _, _, _ = static_transforms(rows)
            pairs = list(zip(rows.parent.tolist(), rows.child.tolist(), strict=True))
            for tf in static:
                n = sum(rows.frame_names[p] == tf.parent and rows.frame_names[c] == tf.child for p, c in pairs)
                edges.append(TfEdge(tf.parent.lstrip("/"), tf.child.lstrip("/"), topic, n, static=True))
        else:
            dynamic, _ = transform_series(rows)
    known = {(e.parent, e.child) for e in edges}
    shadowed = set()
    for s in dynamic:
        key = (s.parent.lstrip("/"), s.child.lstrip("/"))
        if key in known:
            shadowed.add(key)
            continue
        span = (int(s.t_ns[-1]) - int(s.t_ns[0])) / _NS if len(s) else 0.0
        rate = (len(s) - 1) / span if span > 0 else None
        edges.append(TfEdge(*key, s.topic, len(s), static=False, rate_hz=rate))
    edges = [
        TfEdge(e.parent, e.child, e.topic, e.count, e.static, e.rate_hz, also_dynamic=True)
        if (e.parent, e.child) in shadowed
        else e
        for e in edges
    ]
    return TfBuffer(static, dynamic, path=str(path)), edges


def _frame_of(reader: Any, conns: Iterable[Any], msgtype: str, role: str) -> str | None:
    """The frame a run reads the role's samples in, from the topic's first message (the odometry's child frame for
    its twist); None when the message cannot be read here."""
    frame_from = VEC3_ROLES[role, msgtype][1] if (role, msgtype) in VEC3_ROLES else "frame"
    try:
        for _, _, raw in reader.messages(connections=list(conns)):
            msg = reader.deserialize(raw, msgtype)
            value = getattr(msg, "child_frame_id", None) if frame_from == "child" else None
            value = getattr(getattr(msg, "header", None), "frame_id", None) if frame_from == "frame" else value
            return value.lstrip("/") if isinstance(value, str) else None
    except (Exception, InputError):  # noqa: BLE001 - a message info cannot read names no frame; run says why
        return None
    return None


#: why a frame is the body when ``frames.body`` named it, and when no linear velocity names one (``base_link``): the
#: run's ``input.body_frame_from`` (:func:`.alignment.body_frame_origin`) and ``info``'s frame table say the same
BODY_FROM_CONFIG = "frames.body"
BODY_FROM_DEFAULT = "no linear velocity frame: the default"


def tf_summary(
    reader: Any,
    path: Any,
    table: Mapping[str, Any],
    roles: Mapping[str, str],
    *,
    body_frame: str | None = None,
    identity: Iterable[str] = (),
    override: Iterable[str] = (),
    cameras_given: bool = False,
) -> TfSummary:
    """The TF tree of a log and each sensor frame's transform into the body frame, as a run would find them
    (``body_frame``, ``identity``, ``override``: the config's ``frames.body``, ``frames.assume_identity`` and
    ``frames.override_identity``; ``cameras_given``: its ``cameras:`` files place the camera)."""
    tf, edges = _edges(reader, path, table, roles)
    frames: dict[str, tuple[str, str | None]] = {}
    for role in SENSOR_ROLES:
        topic = roles.get(role)
        if topic is None or topic not in table or table[topic][0].msgtype in TF_TYPES:
            continue  # tag frames on /tf are detections placed by the tree itself
        frames[role] = (topic, _frame_of(reader, table[topic][1], table[topic][0].msgtype, role))
    lv = frames.get("linear_velocity", ("", None))
    if body_frame:
        body, body_from = body_frame.lstrip("/"), BODY_FROM_CONFIG
    elif lv[1]:
        kind = "the child frame of" if table[lv[0]][0].msgtype.endswith("Odometry") else "the frame of"
        body, body_from = lv[1], f"{kind} {lv[0]}"
    else:
        body, body_from = "base_link", BODY_FROM_DEFAULT
    ident = {x.lstrip("/") for x in identity}
    over = {x.lstrip("/") for x in override}
    sensors = [
        _sensor(tf, body, role, topic, frame, ident, over)
        for role, (topic, frame) in frames.items()
        if frame is not None
    ]
    return TfSummary(tuple(edges), body, body_from, tuple(sensors), cameras_given)


def _sensor(tf: TfBuffer, body: str, role: str, topic: str, frame: str, ident: set[str], over: set[str]) -> SensorFrame:
    """How the run brings ``frame`` into ``body`` (alignment's rules: the frame itself, ``frames.override_identity``,
    a static chain, a /tf chain, ``frames.assume_identity``, else the run stops)."""
    if not frame:
        return SensorFrame(role, topic, frame, "no frame")
    if frame == body:
        return SensorFrame(role, topic, frame, "body")
    if frame in over:
        return SensorFrame(role, topic, frame, "override")
    chain = tf.chain(body, frame)
    if chain is None:
        if frame in ident:
            return SensorFrame(role, topic, frame, "assumed")
        return SensorFrame(role, topic, frame, "missing", tf.explain(body, frame))
    used = " + ".join(f"{e.parent}->{e.child} ({e.topic})" for e, _ in chain)
    found = tf.static_lookup(body, frame)
    if found is None:
        return SensorFrame(role, topic, frame, "tf", used)
    turn = float(np.degrees(np.arccos(np.clip((np.trace(found[0]) - 1.0) / 2.0, -1.0, 1.0))))
    return SensorFrame(role, topic, frame, "static", used, turn, float(np.linalg.norm(found[1])))
