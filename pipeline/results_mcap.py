"""A run's results as an MCAP file with ROS 2 messages, to open beside the log in Foxglove (or play with ros2 bag).

Topics (message definitions embedded, CDR encoding, profile ``ros2``):

* ``/slamobs/pose`` (geometry_msgs/PoseStamped) and ``/tf`` (tf2_msgs/TFMessage): the estimated body pose in
  the observer's map frame, rows of ``poses.parquet`` at up to ``rate_hz`` per second (default 50: a viewer
  shows no difference, and writing every row of a 200 Hz hour takes the MCAP library half a minute);
* ``/slamobs/path`` (nav_msgs/Path): the whole trajectory, thinned, once at the first stamp (latched);
* ``/slamobs/landmarks`` (visualization_msgs/MarkerArray): the map as estimated so far (from
  ``landmark_tracks.parquet``) about once a second, and the final map (``landmarks.parquet``) at the end;
* ``/slamobs/gyro_bias``, ``/slamobs/velocity_bias`` (geometry_msgs/Vector3Stamped, body frame);
* ``/slamobs/innovation/landmark_<id>`` (geometry_msgs/Vector3Stamped, map frame): ``e_i`` per detection;
* ``/tf_static``: when the run has a report and the truth's frame is known, the report's SE(3) alignment as
  the transform from the truth frame to the map frame, so the estimate lies on the log's ground truth.

Frames are prefixed (``slamobs/map``, ``slamobs/<body frame>``) so they never clash with the log's own TF
tree. High-rate topics are serialised in bulk: one message is serialised by rosbags as a template and the
changing fields are written into copies of its bytes (every message of such a topic has the same layout).
The file is written under a temporary name next to the target and renamed into place when complete.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.paths import check_utf8
from slamobs.pipeline.readers.mcap import mcap_library
from slamobs.pipeline.writers import atomic_file, kept_unless, update_manifest

RESULTS_MCAP = "results.mcap"
MAP_FRAME = "slamobs/map"
FRAME_PREFIX = "slamobs/"
TOPIC_POSE = "/slamobs/pose"
TOPIC_TF = "/tf"
TOPIC_TF_STATIC = "/tf_static"
TOPIC_PATH = "/slamobs/path"
TOPIC_LANDMARKS = "/slamobs/landmarks"
TOPIC_GYRO_BIAS = "/slamobs/gyro_bias"
TOPIC_VEL_BIAS = "/slamobs/velocity_bias"
TOPIC_INNOVATION = "/slamobs/innovation/landmark_{id}"
#: Poses in the path message (the path is a picture of the trajectory; the pose topic has every row).
PATH_POINTS = 5000
#: Seconds between two map messages at most (the map of a long run is sent at most MAX_MAP_MESSAGES times).
MAP_PERIOD_S = 1.0
MAX_MAP_MESSAGES = 600
#: Pose, TF and bias messages per second at most (None or 0: every table row).
DEFAULT_RATE_HZ = 50.0
#: Rows serialised and written per block (bounded memory on long runs).
BLOCK_ROWS = 65_536

_POSE_TYPE = "geometry_msgs/msg/PoseStamped"
_TF_TYPE = "tf2_msgs/msg/TFMessage"
_VEC_TYPE = "geometry_msgs/msg/Vector3Stamped"
_PATH_TYPE = "nav_msgs/msg/Path"
_MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"
_NS = 1_000_000_000
_STAMP = (("header", "stamp", "sec"), ("header", "stamp", "nanosec"))


class BulkMessages:
    """Serialised copies of one template message with some numeric fields replaced, without a message
    object per row. The byte offset of each field is found by serialising the template twice, the second
    time with that field's bits inverted: the bytes that differ are the field's."""

    def __init__(self, typestore, msgtype: str, template, fields: dict[tuple, str]) -> None:
        self.template = np.frombuffer(bytes(typestore.serialize_cdr(template, msgtype)), np.uint8)
        self.fields: dict[tuple, tuple[int, str]] = {}
        for path, dtype in fields.items():
            value = _get(template, path)
            flipped = (np.array([value], dtype).view(np.uint8) ^ 0xFF).view(dtype)[0].item()
            _set(template, path, flipped)
            other = np.frombuffer(bytes(typestore.serialize_cdr(template, msgtype)), np.uint8)
            _set(template, path, value)
            size = np.dtype(dtype).itemsize
            diff = np.flatnonzero(other != self.template)
            if other.shape != self.template.shape or diff.size != size or diff[-1] - diff[0] != size - 1:
                raise ValueError(f"{msgtype}: field {'.'.join(map(str, path))} has no fixed place")
            self.fields[path] = (int(diff[0]), dtype)

    def rows(self, columns: dict[tuple, np.ndarray]) -> np.ndarray:
        """``(n, size)`` bytes, row ``k`` the template with every field ``path`` set to ``columns[path][k]``."""
        n = len(next(iter(columns.values())))
        out = np.empty((n, self.template.shape[0]), np.uint8)
        out[:] = self.template
        for path, values in columns.items():
            offset, dtype = self.fields[path]
            size = np.dtype(dtype).itemsize
            out[:, offset : offset + size] = np.ascontiguousarray(values, dtype=dtype).view(np.uint8).reshape(n, size)
        return out


def _payloads(rows: np.ndarray) -> list[bytes]:
    """The rows of an ``(n, size)`` byte array as ``bytes`` objects, sliced from one copy."""
    size = rows.shape[1]
    data = rows.tobytes()
    return [data[k : k + size] for k in range(0, len(data), size)]


def _get(obj, path: tuple):
    for key in path:
        obj = obj[key] if isinstance(key, int) else getattr(obj, key)
    return obj


def _set(obj, path: tuple, value) -> None:
    obj = _get(obj, path[:-1])
    if isinstance(path[-1], int):
        obj[path[-1]] = value
    else:
        setattr(obj, path[-1], value)


#: A ROS 2 stamp (builtin_interfaces/Time) holds int32 seconds: 1901-12-13 to 2038-01-19.
_STAMP_NS = (-(2**31) * _NS, 2**31 * _NS)


def check_stamps(lo_ns: int, hi_ns: int, path: str | Path, hint: str = "") -> None:
    """One line naming ``path`` when stamps from ``lo_ns`` to ``hi_ns`` do not fit a ROS 2 stamp (a serialiser
    error otherwise, or a stamp wrapped silently by the bulk writer)."""
    if lo_ns < _STAMP_NS[0] or hi_ns >= _STAMP_NS[1]:
        bad = hi_ns if hi_ns >= _STAMP_NS[1] else lo_ns
        raise InputError(
            path,
            f"stamp {bad / _NS:.0f} s is outside the int32 seconds of a ROS 2 message stamp "
            f"(1901-12-13 to 2038-01-19): the results cannot be written as MCAP{hint}",
        )


def _stamp_fields(prefix: tuple = ()) -> dict[tuple, str]:
    return {prefix + _STAMP[0]: "<i4", prefix + _STAMP[1]: "<u4"}


def _stamp_columns(t_ns: np.ndarray, prefix: tuple = ()) -> dict[tuple, np.ndarray]:
    return {prefix + _STAMP[0]: t_ns // _NS, prefix + _STAMP[1]: t_ns % _NS}


def _vec_fields(prefix: tuple, names: str = "xyz") -> dict[tuple, str]:
    return {prefix + (a,): "<f8" for a in names}


class _Messages:
    """The rosbags message objects and bulk serialisers of the results file."""

    def __init__(self, body_frame: str) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.ts = ts = get_typestore(Stores.ROS2_JAZZY)
        t = ts.types
        self.t = t
        self.body_frame = body_frame
        pose = self.pose_stamped(0, MAP_FRAME, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
        self.pose = BulkMessages(
            ts,
            _POSE_TYPE,
            pose,
            {**_stamp_fields(), **_vec_fields(("pose", "position")), **_vec_fields(("pose", "orientation"), "xyzw")},
        )
        tf = t[_TF_TYPE](transforms=[self.transform(0, MAP_FRAME, body_frame, np.zeros(3), np.array([0, 0, 0, 1.0]))])
        item = ("transforms", 0)
        self.tf = BulkMessages(
            ts,
            _TF_TYPE,
            tf,
            {
                **_stamp_fields(item),
                **_vec_fields(item + ("transform", "translation")),
                **_vec_fields(item + ("transform", "rotation"), "xyzw"),
            },
        )
        self.vec_body = BulkMessages(
            ts, _VEC_TYPE, self.vector(0, body_frame, np.zeros(3)), {**_stamp_fields(), **_vec_fields(("vector",))}
        )
        self.vec_map = BulkMessages(
            ts, _VEC_TYPE, self.vector(0, MAP_FRAME, np.zeros(3)), {**_stamp_fields(), **_vec_fields(("vector",))}
        )

    def header(self, t_ns: int, frame: str):
        t = self.t
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=int(t_ns // _NS), nanosec=int(t_ns % _NS)), frame_id=frame
        )

    def pose_msg(self, p: np.ndarray, q: np.ndarray):
        t = self.t
        return t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=t["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        )

    def pose_stamped(self, t_ns: int, frame: str, p: np.ndarray, q: np.ndarray):
        return self.t[_POSE_TYPE](header=self.header(t_ns, frame), pose=self.pose_msg(p, q))

    def transform(self, t_ns: int, parent: str, child: str, p: np.ndarray, q: np.ndarray):
        t = self.t
        return t["geometry_msgs/msg/TransformStamped"](
            header=self.header(t_ns, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                rotation=t["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
            ),
        )

    def vector(self, t_ns: int, frame: str, v: np.ndarray):
        t = self.t
        return t[_VEC_TYPE](
            header=self.header(t_ns, frame),
            vector=t["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2])),
        )

    def serialize(self, msg, msgtype: str) -> bytes:
        return bytes(self.ts.serialize_cdr(msg, msgtype))

    def path(self, stamp_ns: int, t_ns: np.ndarray, xyz: np.ndarray, quat: np.ndarray) -> bytes:
        poses = [self.pose_stamped(int(t), MAP_FRAME, p, q) for t, p, q in zip(t_ns, xyz, quat)]
        msg = self.t[_PATH_TYPE](header=self.header(stamp_ns, MAP_FRAME), poses=poses)
        return self.serialize(msg, _PATH_TYPE)

    def markers(self, t_ns: int, ids: np.ndarray, xyz: np.ndarray, final: bool, known: np.ndarray) -> bytes:
        """The map as one sphere list (green while estimating, blue for the final map) and an id label each
        (marker ids from :func:`_marker_ids` over ``known``, every landmark id of the run)."""
        t = self.t
        marker_t = t["visualization_msgs/msg/Marker"]
        point = t["geometry_msgs/msg/Point"]
        color = t["std_msgs/msg/ColorRGBA"]
        vec3 = t["geometry_msgs/msg/Vector3"]
        duration = t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)  # 0: forever
        rgba = color(r=0.1, g=0.4, b=1.0, a=1.0) if final else color(r=0.1, g=0.8, b=0.2, a=1.0)
        white = color(r=1.0, g=1.0, b=1.0, a=1.0)
        ident = self.pose_msg(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))

        def marker(ns, mid, kind, pose, scale, col, points=(), text=""):
            return marker_t(
                header=self.header(t_ns, MAP_FRAME),
                ns=ns,
                id=mid,
                type=kind,
                action=0,
                pose=pose,
                scale=scale,
                color=col,
                lifetime=duration,
                frame_locked=False,
                points=list(points),
                colors=[],
                texture_resource="",
                texture=t["sensor_msgs/msg/CompressedImage"](
                    header=self.header(0, ""), format="", data=np.zeros(0, np.uint8)
                ),
                uv_coordinates=[],
                text=text,
                mesh_resource="",
                mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
                mesh_use_embedded_materials=False,
            )

        spheres = marker(
            "landmarks",
            0,
            7,
            ident,
            vec3(x=0.2, y=0.2, z=0.2),
            rgba,  # 7: SPHERE_LIST
            points=[point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in xyz],
        )
        labels = [
            marker(
                "landmark_ids",
                int(m),
                9,
                self.pose_msg(
                    p + np.array([0.0, 0.0, 0.25]),  # 9: TEXT
                    np.array([0.0, 0.0, 0.0, 1.0]),
                ),
                vec3(x=0.0, y=0.0, z=0.2),
                white,
                text=str(int(i)),
            )
            for i, m, p in zip(ids, _marker_ids(ids, known), xyz)
        ]
        return self.serialize(t[_MARKERS_TYPE](markers=[spheres, *labels]), _MARKERS_TYPE)


def _marker_ids(ids: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Marker ids (int32 in visualization_msgs/Marker) of landmarks ``ids``: the ids themselves, or, when an id of
    the run (``known``, sorted) does not fit an int32 (a TF tag frame may name any integer), every id's rank
    among them, so each landmark keeps one label across map messages; the label's text is the id either way."""
    if known.size == 0 or (int(known[0]) >= -(2**31) and int(known[-1]) < 2**31):
        return ids
    return np.searchsorted(known, ids)


def _latched_qos() -> str:
    from slamobs.pipeline.simulate.logwriter import LATCHED_QOS_YAML

    return LATCHED_QOS_YAML


#: The columns of each run table the MCAP export and the viewer need (schemas/<table>.json describes them all).
RUN_TABLE_COLUMNS = {
    "poses": ("t_ns", "x", "y", "z", "qx", "qy", "qz", "qw"),
    "biases": ("t_ns", *(f"{b}_bias_{a}" for b in ("gyro", "vel") for a in "xyz")),
    "innovations": ("t_ns", "id", "ex", "ey", "ez"),
    "landmark_tracks": ("t_ns", "id", "x", "y", "z"),
    "landmarks": ("id", "x", "y", "z"),
}


def read_run_table(run_dir: Path, name: str):
    """Table ``name`` of the run (None when the run has none); unreadable or lacking a column read here is one
    line naming the file."""
    from slamobs.pipeline.writers import read_frame

    path = run_dir / f"{name}.parquet"
    if path.is_file():
        try:
            frame = read_frame(path)
        except (OSError, ValueError) as err:  # pyarrow's ArrowInvalid is a ValueError
            raise InputError(path, f"unreadable table: {' '.join(str(err).split())}") from None
    else:
        from slamobs.pipeline.stored_runs import run_tables  # a batch run directory: tables are in the dataset

        found = (run_tables(run_dir) or {}).get(name)
        if found is None:
            return None
        frame, path = found.to_pandas(), run_dir
    missing = [c for c in RUN_TABLE_COLUMNS.get(name, ()) if c not in frame.columns]
    if missing:
        raise InputError(
            path,
            f"the {name} table has no column {', '.join(missing)} (see schemas/{name}.json): "
            "edited or written by another program; run slamobs run again",
        )
    if "t_ns" in frame.columns and len(frame):
        t_ns = frame["t_ns"].to_numpy(np.int64)
        check_stamps(int(t_ns.min()), int(t_ns.max()), path)
    return frame


def _every(t_ns: np.ndarray, rate_hz: float | None) -> np.ndarray:
    """Rows kept for at most ``rate_hz`` messages per second (the median spacing decides; the last row too)."""
    n = t_ns.shape[0]
    if not rate_hz or n < 2:
        return np.arange(n)
    step = max(1, int(round(1e9 / rate_hz / max(float(np.median(np.diff(t_ns))), 1.0))))
    keep = np.arange(0, n, step)
    return keep if keep[-1] == n - 1 else np.append(keep, n - 1)


def _map_updates(tracks, t_end: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """``(t_ns, ids, xyz)``: each landmark's latest estimate at about every MAP_PERIOD_S (only when the map
    changed), from the per-detection tracks."""
    if tracks is None or len(tracks) == 0:
        return []
    t = tracks["t_ns"].to_numpy(np.int64)
    order = np.argsort(t, kind="stable")
    t = t[order]
    ids, idx = np.unique(tracks["id"].to_numpy(np.int64)[order], return_inverse=True)
    xyz = tracks[["x", "y", "z"]].to_numpy(np.float64)[order]
    latest = np.zeros((ids.shape[0], 3))
    seen = np.zeros(ids.shape[0], bool)
    period = max(int(MAP_PERIOD_S * _NS), (int(t_end) - int(t[0])) // MAX_MAP_MESSAGES + 1)
    marks = np.arange(int(t[0]) + period, max(int(t_end), int(t[-1])) + period, period)
    ends = np.searchsorted(t, marks, side="right")
    out, done = [], 0
    for mark, end in zip(marks, ends):
        if end == done:
            continue
        part, last = np.unique(idx[done:end][::-1], return_index=True)  # latest row of each landmark
        latest[part] = xyz[end - 1 - last]
        seen[part] = True
        out.append((int(min(mark, max(t_end, t[end - 1]))), ids[seen], latest[seen].copy()))
        done = end
    return out


def write_results_mcap(
    run_dir: str | Path,
    out: str | Path,
    *,
    meta: dict | None = None,
    report: dict | None = None,
    rate_hz: float | None = DEFAULT_RATE_HZ,
    force: bool = True,
) -> Path:
    """Write the results of the run directory ``run_dir`` to the MCAP file ``out`` (atomically).

    ``meta`` and ``report`` default to the run's ``run.json`` and ``report.json``; ``rate_hz`` caps the pose,
    TF and bias messages per second (None or 0: one per table row). An existing ``out`` is replaced only with
    ``force``.
    """
    from slamobs.pipeline.evaluation.run_dir import read_json

    run_dir, out = Path(run_dir), Path(out)
    check_utf8(run_dir)
    if meta is None:
        if not (run_dir / "run.json").is_file():
            from slamobs.pipeline.stored_runs import not_a_run

            raise not_a_run(run_dir)
        meta = read_json(run_dir / "run.json")
    if report is None and (run_dir / "report.json").is_file():
        report = read_json(run_dir / "report.json")
    if not (run_dir / "poses.parquet").is_file() and not (run_dir / "batch.json").is_file():
        raise InputError(run_dir, "run directory has no poses.parquet")
    from slamobs.pipeline.errors import OutputError
    from slamobs.pipeline.paths import check_output_file

    if not str(out).strip() or out.name in ("", ".", ".."):
        raise OutputError(f"--mcap {str(out)!r}", "name an .mcap file to write")
    parent = next((p for p in out.parents if os.path.lexists(p)), None)
    if parent is not None and not parent.is_dir():
        raise OutputError(out, f"{parent} is a file, not a directory")
    check_output_file(out, [p for p in run_dir.iterdir() if p.suffix != ".mcap"])  # the files read, not a results MCAP
    why_kept = kept_unless(
        lambda head: mcap_library(head).startswith("slamobs "),
        "exists and is not a results MCAP slamobs wrote: --force replaces only those; it is kept, remove it "
        "or choose another -o",
        force=force,
    )
    if os.path.lexists(out) and (why := why_kept(out)) is not None:
        raise OutputError(out, why)
    with atomic_file(out, why_kept=why_kept) as tmp:
        with open(tmp, "wb") as stream:
            _write(stream, run_dir, meta, report, rate_hz)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # the results file is ordinary output
    update_manifest(out.parent, written=[out])  # exported into a run directory: still slamobs's
    return out


class _Out:
    """The MCAP writer: each message type's schema registered once, channels, per-channel sequence numbers."""

    def __init__(self, stream, msgs: _Messages) -> None:
        from mcap.writer import CompressionType, Writer

        from slamobs.pipeline.version import __version__

        self.msgs = msgs
        self.writer = Writer(stream, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library=f"slamobs {__version__}")
        self.schemas: dict[str, int] = {}
        self.seq: dict[int, int] = {}

    def channel(self, topic: str, msgtype: str, latched: bool = False) -> int:
        if msgtype not in self.schemas:
            msgdef, _ = self.msgs.ts.generate_msgdef(msgtype, ros_version=2)
            self.schemas[msgtype] = self.writer.register_schema(name=msgtype, encoding="ros2msg", data=msgdef.encode())
        return self.writer.register_channel(
            topic=topic,
            message_encoding="cdr",
            schema_id=self.schemas[msgtype],
            metadata={"offered_qos_profiles": _latched_qos() if latched else ""},
        )

    def add(self, chan: int, t_ns: int, data: bytes) -> None:
        n = self.seq.get(chan, 0)
        self.writer.add_message(chan, log_time=t_ns, data=data, publish_time=t_ns, sequence=n)
        self.seq[chan] = n + 1


@dataclass
class _Topics:
    """The per-row topics of a run: each table's stamps (and rows kept at the rate), its values and channels."""

    t_pose: np.ndarray
    keep: np.ndarray
    xyz: np.ndarray
    quat: np.ndarray
    ch_pose: int
    ch_tf: int
    innov: Any
    t_i: np.ndarray
    biases: Any = None
    t_b: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    keep_b: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    ch_gyro: int | None = None
    ch_vel: int | None = None
    inn_chan: dict[int, int] = field(default_factory=dict)
    updates: list = field(default_factory=list)
    t_u: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    ch_map: int = 0
    known: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def _write(stream, run_dir: Path, meta: dict, report: dict | None, rate_hz: float | None) -> None:
    """The results MCAP: the latched alignment and path first, then every per-row topic block by block in
    time order, the final map last (channels registered in this order: their ids are part of the file)."""
    body = FRAME_PREFIX + str((meta.get("input") or {}).get("body_frame") or "base_link").lstrip("/")
    out = _Out(stream, _Messages(body))
    poses = read_run_table(run_dir, "poses")
    t_pose = poses["t_ns"].to_numpy(np.int64)
    t0, t_end = (int(t_pose[0]), int(t_pose[-1])) if len(t_pose) else (0, 0)
    ch_pose, ch_tf = out.channel(TOPIC_POSE, _POSE_TYPE), out.channel(TOPIC_TF, _TF_TYPE)
    innov = read_run_table(run_dir, "innovations")
    t_i = innov["t_ns"].to_numpy(np.int64) if innov is not None else np.zeros(0, np.int64)
    t0 = min(t0, int(t_i[0])) if t_i.size else t0  # detections may come before the first velocity sample
    _write_latched(out, meta, report, poses, t0, body)
    topics = _Topics(
        t_pose,
        _every(t_pose, rate_hz),
        poses[["x", "y", "z"]].to_numpy(np.float64),
        poses[["qx", "qy", "qz", "qw"]].to_numpy(np.float64),
        ch_pose,
        ch_tf,
        innov,
        t_i,
    )
    del poses
    landmarks = _add_other_topics(out, topics, run_dir, t_end, rate_hz)
    for block in _blocks(topics):
        _write_block(out, *_block_messages(out.msgs, topics, *block))
    if landmarks is not None and len(landmarks):
        t_end = max([t_end] + [int(t[-1]) for t in (t_i, topics.t_u) if t.size])  # after every other message
        out.add(
            topics.ch_map,
            t_end,
            out.msgs.markers(
                t_end,
                landmarks["id"].to_numpy(np.int64),
                landmarks[["x", "y", "z"]].to_numpy(np.float64),
                final=True,
                known=topics.known,
            ),
        )
    out.writer.finish()


def _write_latched(out: _Out, meta: dict, report: dict | None, poses, t0: int, body: str) -> None:
    """The latched messages: the alignment onto the truth frame, the (thinned) path."""
    static = _alignment_transform(out.msgs, meta, report, t0, body)
    if static is not None:
        out.add(out.channel(TOPIC_TF_STATIC, _TF_TYPE, latched=True), t0, static)
    t_pose = poses["t_ns"].to_numpy(np.int64)
    if len(t_pose):
        rows = np.unique(np.linspace(0, len(t_pose) - 1, min(PATH_POINTS, len(t_pose))).astype(np.int64))
        out.add(
            out.channel(TOPIC_PATH, _PATH_TYPE, latched=True),
            t0,
            out.msgs.path(
                t0,
                t_pose[rows],
                poses[["x", "y", "z"]].to_numpy()[rows],
                poses[["qx", "qy", "qz", "qw"]].to_numpy()[rows],
            ),
        )


def _add_other_topics(out: _Out, topics: _Topics, run_dir: Path, t_end: int, rate_hz: float | None):
    """Read the biases, the map's tracks and the final map into ``topics`` and register their channels; returns
    the final map (landmarks table, or None)."""
    biases = read_run_table(run_dir, "biases")
    topics.biases = biases
    topics.ch_gyro = out.channel(TOPIC_GYRO_BIAS, _VEC_TYPE) if biases is not None else None
    topics.ch_vel = out.channel(TOPIC_VEL_BIAS, _VEC_TYPE) if biases is not None else None
    innov = topics.innov
    if innov is not None and len(innov):
        for i in np.unique(innov["id"].to_numpy(np.int64)):
            topics.inn_chan[int(i)] = out.channel(TOPIC_INNOVATION.format(id=int(i)), _VEC_TYPE)
    topics.ch_map = out.channel(TOPIC_LANDMARKS, _MARKERS_TYPE)
    topics.updates = _map_updates(read_run_table(run_dir, "landmark_tracks"), t_end)
    landmarks = read_run_table(run_dir, "landmarks")
    topics.known = np.unique(
        np.concatenate(
            [np.zeros(0, np.int64)]
            + [u[1] for u in topics.updates]
            + ([landmarks["id"].to_numpy(np.int64)] if landmarks is not None else [])
        )
    )
    topics.t_b = biases["t_ns"].to_numpy(np.int64) if biases is not None else np.zeros(0, np.int64)
    topics.keep_b = _every(topics.t_b, rate_hz)
    topics.t_u = np.array([u[0] for u in topics.updates], np.int64)
    return landmarks


def _blocks(topics: _Topics):
    """Per block of pose rows, the rows of each topic up to the block's last stamp ``(poses, biases,
    innovations, map updates)``; the last block takes everything left."""
    t_pose, keep, t_b, keep_b, t_i, t_u = topics.t_pose, topics.keep, topics.t_b, topics.keep_b, topics.t_i, topics.t_u
    bounds = [int(t_pose[keep[min(k + BLOCK_ROWS, len(keep)) - 1]]) for k in range(0, len(keep), BLOCK_ROWS)]
    bounds[-1:] = [np.iinfo(np.int64).max]
    pos = {"p": 0, "b": 0, "i": 0, "u": 0}
    for bound in bounds:
        sp = pos["p"] + int(np.searchsorted(t_pose[keep[pos["p"] :]], bound, side="right"))
        rows = keep[pos["p"] : sp]
        pos["p"] = sp
        sb = pos["b"] + int(np.searchsorted(t_b[keep_b[pos["b"] :]], bound, side="right"))
        rows_b = keep_b[pos["b"] : sb]
        pos["b"] = sb
        si = pos["i"] + int(np.searchsorted(t_i[pos["i"] :], bound, side="right")) if topics.innov is not None else 0
        rows_i = np.arange(pos["i"], si)
        pos["i"] = si
        su = pos["u"] + int(np.searchsorted(t_u[pos["u"] :], bound, side="right"))
        rows_u = np.arange(pos["u"], su)
        pos["u"] = su
        yield rows, rows_b, rows_i, rows_u


def _block_messages(
    msgs: _Messages, topics: _Topics, rows: np.ndarray, rows_b: np.ndarray, rows_i: np.ndarray, rows_u: np.ndarray
) -> tuple[list, list, list]:
    """One block's messages of every per-row topic: their stamps, channels and payloads (lists of parts)."""
    out_t, out_c, out_d = [], [], []
    if rows.size:
        t = topics.t_pose[rows]
        xyz_p, quat_p = topics.xyz, topics.quat
        cols = {
            **_stamp_columns(t),
            **{("pose", "position", a): xyz_p[rows, k] for k, a in enumerate("xyz")},
            **{("pose", "orientation", a): quat_p[rows, k] for k, a in enumerate("xyzw")},
        }
        out_t += [t, t]
        out_c += [np.full(t.shape, topics.ch_pose), np.full(t.shape, topics.ch_tf)]
        item = ("transforms", 0)
        tf_cols = {
            **_stamp_columns(t, item),
            **{item + ("transform", "translation", a): xyz_p[rows, k] for k, a in enumerate("xyz")},
            **{item + ("transform", "rotation", a): quat_p[rows, k] for k, a in enumerate("xyzw")},
        }
        out_d += [_payloads(msgs.pose.rows(cols)), _payloads(msgs.tf.rows(tf_cols))]
    if rows_b.size:
        t = topics.t_b[rows_b]
        for ch, prefix in ((topics.ch_gyro, "gyro_bias_"), (topics.ch_vel, "vel_bias_")):
            cols = {
                **_stamp_columns(t),
                **{("vector", a): topics.biases[prefix + a].to_numpy(np.float64)[rows_b] for a in "xyz"},
            }
            out_t.append(t)
            out_c.append(np.full(t.shape, ch))
            out_d.append(_payloads(msgs.vec_body.rows(cols)))
    if rows_i.size:
        t, innov = topics.t_i[rows_i], topics.innov
        cols = {**_stamp_columns(t), **{("vector", a): innov["e" + a].to_numpy(np.float64)[rows_i] for a in "xyz"}}
        out_t.append(t)
        out_c.append(np.array([topics.inn_chan[int(i)] for i in innov["id"].to_numpy(np.int64)[rows_i]]))
        out_d.append(_payloads(msgs.vec_map.rows(cols)))
    if rows_u.size:
        t = topics.t_u[rows_u]
        out_t.append(t)
        out_c.append(np.full(t.shape, topics.ch_map))
        out_d.append([msgs.markers(*topics.updates[k], final=False, known=topics.known) for k in rows_u])
    return out_t, out_c, out_d


def _write_block(out: _Out, out_t: list, out_c: list, out_d: list) -> None:
    """A block's messages in time order (channel order on a tie)."""
    if not out_t:
        return
    t_all = np.concatenate(out_t)
    c_all = np.concatenate(out_c)
    d_all = [d for part in out_d for d in part]
    order = np.lexsort((c_all, t_all))
    for t, c, k in zip(t_all[order].tolist(), c_all[order].tolist(), order.tolist()):  # plain ints: fast
        out.add(c, t, d_all[k])


def _alignment_transform(msgs: _Messages, meta: dict, report: dict | None, t0: int, body: str) -> bytes | None:
    """The report's alignment (estimate -> truth frame) as a static transform truth frame -> map frame, when it
    is rigid (scale 1) and the truth's frame is known."""
    truth_frame = (meta.get("input") or {}).get("truth_frame")
    al = ((report or {}).get("method") or {}).get("alignment")
    if not truth_frame or not al or abs(float(al.get("scale", 1.0)) - 1.0) > 1e-12:
        return None
    q = np.asarray(al["rotation_quat_xyzw"], float)
    tf = msgs.transform(t0, truth_frame.lstrip("/"), MAP_FRAME, np.asarray(al["translation_m"], float), q)
    return msgs.serialize(msgs.t[_TF_TYPE](transforms=[tf]), _TF_TYPE)
