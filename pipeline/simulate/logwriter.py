"""Write a :class:`SimLog` as a ROS1 bag, a rosbag2 (sqlite3) directory or a bare ROS2 MCAP file.

Every container embeds the full message definitions (including the custom ``fiducial_msgs`` types), so
the readers decode them with rosbags alone, without a ROS install. Files appear atomically: the log is
written under a hidden temporary directory next to the target and renamed into place at the end.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Collection, Iterable, Iterator
from functools import cached_property, partial
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag1 import Writer as Bag1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Bag2Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from slamobs.pipeline.paths import log_size
from slamobs.pipeline.readers.fastdecode import leaf_offsets, make_plan
from slamobs.pipeline.simulate.sensors import (
    FRAME_BODY,
    FRAME_CAMERA,
    FRAME_IMU,
    FRAME_ODOM,
    FRAME_WORLD,
    TOPIC_DETECTIONS,
    TOPIC_IMU,
    TOPIC_MAG,
    TOPIC_CAMERA_INFO,
    TOPIC_MOCAP,
    TOPIC_ODOM,
    TOPIC_TF_STATIC,
    TOPIC_TRUTH,
    CameraSim,
    SimLog,
    Simulation,
    camera_topic,
    camera_topics,
)

CONTAINERS = ("bag", "mcap", "ros2")

FIDUCIAL_TRANSFORM_MSG = """\
int32 fiducial_id
geometry_msgs/Transform transform
float64 image_error
float64 object_error
float64 fiducial_area
"""

FIDUCIAL_TRANSFORM_ARRAY_MSG = """\
std_msgs/Header header
int32 image_seq
fiducial_msgs/FiducialTransform[] transforms
"""

TF_MESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms\n"  # missing from rosbags' ROS1 store

# apriltag_msgs (ROS1 apriltag_ros of KumarRobotics, TagSLAM's detector): corners in pixels, no pose
APRILTAG_MSG = """\
int32 id
string family
int32 hamming
int32 border
int32 bits
geometry_msgs/Point center
geometry_msgs/Point[4] corners
"""
APRILTAG_ARRAY_MSG = """\
std_msgs/Header header
apriltag_msgs/Apriltag[] apriltags
"""

# Topic -> message type, in the order ties in record time are broken (latched topics first).
TOPIC_TYPES: dict[str, str] = {
    TOPIC_TF_STATIC: "tf2_msgs/msg/TFMessage",
    TOPIC_TRUTH: "std_msgs/msg/String",
    TOPIC_IMU: "sensor_msgs/msg/Imu",
    TOPIC_ODOM: "nav_msgs/msg/Odometry",
    TOPIC_MAG: "sensor_msgs/msg/MagneticField",
    TOPIC_DETECTIONS: "fiducial_msgs/msg/FiducialTransformArray",
    TOPIC_MOCAP: "geometry_msgs/msg/PoseStamped",
}
LATCHED = frozenset({TOPIC_TF_STATIC, TOPIC_TRUTH})
#: Topic -> the SimLog stream it is written from (camera topics: the detection stamps).
TOPIC_STREAMS: dict[str, str] = {
    TOPIC_IMU: "imu",
    TOPIC_ODOM: "odom",
    TOPIC_MAG: "mag",
    TOPIC_DETECTIONS: "detections",
    TOPIC_MOCAP: "mocap",
}
#: Message types of the simulated camera's topics.
CAMERA_TYPES = {
    "corners": "apriltag_msgs/msg/ApriltagArrayStamped",
    "raw": "sensor_msgs/msg/Image",
    "jpeg": "sensor_msgs/msg/CompressedImage",
    "info": "sensor_msgs/msg/CameraInfo",
}


def topic_types(cam: CameraSim) -> dict[str, str]:
    """Topic -> message type of a simulated log, in tie-breaking order (the camera's topics replace the
    fiducial detections when it reports corners or images)."""
    if cam.output == "fiducials":
        return dict(TOPIC_TYPES)
    kind = "corners" if cam.output == "corners" else ("raw" if cam.jpeg_quality is None else "jpeg")
    types = {camera_topic(cam): CAMERA_TYPES[kind], TOPIC_CAMERA_INFO: CAMERA_TYPES["info"]}
    return {tp: types.get(tp, TOPIC_TYPES.get(tp)) for tp in camera_topics(dict.fromkeys(TOPIC_TYPES, 0), cam)}


def _stream_of(topic: str) -> str:
    return TOPIC_STREAMS.get(topic, "detections" if topic.startswith("/camera/") else "")


# ROS2 "latched" QoS (transient local, keep last 1), as ros2 bag records /tf_static.
_LATCHED_QOS = Qos(
    QosHistory.KEEP_LAST,
    1,
    QosReliability.RELIABLE,
    QosDurability.TRANSIENT_LOCAL,
    QosTime(0, 0),
    QosTime(0, 0),
    QosLiveliness.AUTOMATIC,
    QosTime(0, 0),
    False,
)
#: rosbag2's offered QoS of a latched (transient-local, depth 1) topic such as /tf_static, as its MCAP metadata
LATCHED_QOS_YAML = (
    "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
    "  avoid_ros_namespace_conventions: false"
)


def make_typestore(ros1: bool) -> Typestore:
    """ROS1 Noetic or ROS2 Jazzy typestore with the fiducial (and, for ROS1, tf2) types registered."""
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_JAZZY)
    types = {}
    types.update(get_types_from_msg(FIDUCIAL_TRANSFORM_MSG, "fiducial_msgs/msg/FiducialTransform"))
    types.update(get_types_from_msg(FIDUCIAL_TRANSFORM_ARRAY_MSG, "fiducial_msgs/msg/FiducialTransformArray"))
    if "tf2_msgs/msg/TFMessage" not in ts.fielddefs:
        types.update(get_types_from_msg(TF_MESSAGE_MSG, "tf2_msgs/msg/TFMessage"))
    types.update(get_types_from_msg(APRILTAG_MSG, "apriltag_msgs/msg/Apriltag"))
    types.update(get_types_from_msg(APRILTAG_ARRAY_MSG, "apriltag_msgs/msg/ApriltagArrayStamped"))
    ts.register(types)
    return ts


def infer_container(path: str | Path) -> str:
    """``.bag`` -> ROS1 bag, ``.mcap`` -> MCAP, anything else -> rosbag2 directory."""
    suffix = Path(path).suffix.lower()
    return {".bag": "bag", ".mcap": "mcap"}.get(suffix, "ros2")


def _per_axis(sigma) -> np.ndarray:
    """One standard deviation or one per axis, as three."""
    return np.broadcast_to(np.asarray(sigma, dtype=float), (3,))


class Builder:
    """Makes the rosbags message objects of one :class:`SimLog` (or piece of one) for one typestore.
    Public: tests/test_simulate.py checks its bytes against rosbags'."""

    def __init__(self, sim: SimLog, ts: Typestore, ros1: bool) -> None:
        self.sim, self.ts, self.ros1 = sim, ts, ros1
        self.types = topic_types(sim.camera_sim)
        t = ts.types
        self.Time, self.Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self.Vector3, self.Quaternion = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
        self.Point, self.Pose = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Pose"]
        self.Transform = t["geometry_msgs/msg/Transform"]
        self.cov9_imu = self._cov(9, _per_axis(sim.noise.gyro) ** 2)
        self.cov9_acc = self._cov(9, [sim.noise.accel**2] * 3)
        self.cov9_mag = self._cov(9, [sim.noise.mag**2] * 3)
        self.cov36_twist = self._cov(36, np.r_[_per_axis(sim.noise.odom_linear) ** 2, [sim.noise.odom_angular**2] * 3])
        self.orient_cov = np.zeros(9)
        self.orient_cov[0] = -1.0  # REP 145: no orientation estimate

    @staticmethod
    def _cov(size: int, diag: list[float]) -> np.ndarray:
        n = int(round(size**0.5))
        out = np.zeros((n, n))
        out[np.diag_indices(n)] = diag
        return out.ravel()

    def header(self, stamp_ns: int, frame_id: str, seq: int) -> object:
        stamp = self.Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))
        if self.ros1:
            return self.Header(seq=seq, stamp=stamp, frame_id=frame_id)
        return self.Header(stamp=stamp, frame_id=frame_id)

    def vec(self, v: np.ndarray) -> object:
        return self.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quat(self, q: np.ndarray) -> object:
        return self.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    def pose(self, p: np.ndarray, q: np.ndarray) -> object:
        return self.Pose(position=self.Point(x=float(p[0]), y=float(p[1]), z=float(p[2])), orientation=self.quat(q))

    def tf_static(self, _i: int) -> object:
        t = self.ts.types
        items = [
            t["geometry_msgs/msg/TransformStamped"](
                header=self.header(self.sim.start_ns, tf.parent, 0),
                child_frame_id=tf.child,
                transform=self.Transform(translation=self.vec(tf.translation), rotation=self.quat(tf.quat_xyzw)),
            )
            for tf in self.sim.static_tf
        ]
        return t["tf2_msgs/msg/TFMessage"](transforms=items)

    def truth(self, _i: int) -> object:
        return self.ts.types["std_msgs/msg/String"](data=self.sim.truth_json)

    def imu(self, i: int) -> object:
        d = self.sim.imu
        return self.ts.types["sensor_msgs/msg/Imu"](
            header=self.header(int(d.t_ns[i]), FRAME_IMU, self.sim.first["imu"] + i),
            orientation=self.Quaternion(x=0.0, y=0.0, z=0.0, w=0.0),
            orientation_covariance=self.orient_cov,
            angular_velocity=self.vec(d.gyro[i]),
            angular_velocity_covariance=self.cov9_imu,
            linear_acceleration=self.vec(d.accel[i]),
            linear_acceleration_covariance=self.cov9_acc,
        )

    def odom(self, i: int) -> object:
        d, t = self.sim.odom, self.ts.types
        return t["nav_msgs/msg/Odometry"](
            header=self.header(int(d.t_ns[i]), FRAME_ODOM, self.sim.first["odom"] + i),
            child_frame_id=FRAME_BODY,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=self.pose(d.position[i], d.quat_xyzw[i]), covariance=np.zeros(36)
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](linear=self.vec(d.linear[i]), angular=self.vec(d.angular[i])),
                covariance=self.cov36_twist,
            ),
        )

    def mag(self, i: int) -> object:
        d = self.sim.mag
        return self.ts.types["sensor_msgs/msg/MagneticField"](
            header=self.header(int(d.t_ns[i]), FRAME_IMU, self.sim.first["mag"] + i),
            magnetic_field=self.vec(d.field[i]),
            magnetic_field_covariance=self.cov9_mag,
        )

    def detections(self, i: int) -> object:
        d, t = self.sim.detections, self.ts.types
        ft = t["fiducial_msgs/msg/FiducialTransform"]
        items = [
            ft(
                fiducial_id=int(d.ids[k]),
                transform=self.Transform(translation=self.vec(d.xyz[k]), rotation=self.quat(d.quat_xyzw[k])),
                image_error=float(d.image_error[k]),
                object_error=float(d.object_error[k]),
                fiducial_area=float(d.area[k]),
            )
            for k in range(int(d.offsets[i]), int(d.offsets[i + 1]))
        ]
        seq = self.sim.first["detections"] + i
        return t["fiducial_msgs/msg/FiducialTransformArray"](
            header=self.header(int(d.t_ns[i]), FRAME_CAMERA, seq), image_seq=seq, transforms=items
        )

    def tags(self, i: int) -> object:
        """Tag corners of camera frame ``i`` in the AprilTag order (bottom-left first, counter-clockwise)."""
        c, t = self.sim.camera, self.ts.types
        tag, point = t["apriltag_msgs/msg/Apriltag"], self.Point
        items = []
        for k in range(int(c.offsets[i]), int(c.offsets[i + 1])):
            px = c.corners[k][[3, 2, 1, 0]]
            centre = px.mean(axis=0)
            items.append(
                tag(
                    id=int(c.ids[k]),
                    family=self.sim.camera_sim.family,
                    hamming=0,
                    border=1,
                    bits=6,
                    center=point(x=float(centre[0]), y=float(centre[1]), z=0.0),
                    corners=[point(x=float(x), y=float(y), z=0.0) for x, y in px],
                )
            )
        seq = self.sim.first["detections"] + i
        return t["apriltag_msgs/msg/ApriltagArrayStamped"](
            header=self.header(int(c.t_ns[i]), FRAME_CAMERA, seq), apriltags=items
        )

    def camera_info(self, i: int) -> object:
        cam, t = self.sim.camera_sim, self.ts.types
        k = cam.k
        roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        p = np.column_stack([k, np.zeros(3)]).ravel()
        fields = {"d": cam.ros_coeffs.astype(np.float64), "k": k.ravel(), "r": np.eye(3).ravel(), "p": p}
        if self.ros1:
            fields = {key.upper(): v for key, v in fields.items()}
        seq = self.sim.first["detections"] + i
        return t["sensor_msgs/msg/CameraInfo"](
            header=self.header(int(self.sim.camera.t_ns[i]), FRAME_CAMERA, seq),
            height=cam.height,
            width=cam.width,
            distortion_model=cam.ros_distortion,
            binning_x=0,
            binning_y=0,
            roi=roi,
            **fields,
        )

    def image(self, i: int) -> object:
        """Camera frame ``i`` rendered (noise drawn from a generator of the seed and the frame: reproducible)."""
        c, cam, t = self.sim.camera, self.sim.camera_sim, self.ts.types
        seq = self.sim.first["detections"] + i
        gray = self.renderer.render(c.r_wc[i], c.t_wc[i], np.random.default_rng([self.sim.seed, 11, seq]))
        header = self.header(int(c.t_ns[i]), FRAME_CAMERA, seq)
        if cam.jpeg_quality is None:
            return t["sensor_msgs/msg/Image"](
                header=header,
                height=gray.shape[0],
                width=gray.shape[1],
                encoding="mono8",
                is_bigendian=0,
                step=gray.shape[1],
                data=np.ascontiguousarray(gray).ravel(),
            )
        cv2 = self.renderer.cv2
        ok, buf = cv2.imencode(".jpg", gray, [cv2.IMWRITE_JPEG_QUALITY, int(cam.jpeg_quality)])
        assert ok
        return t["sensor_msgs/msg/CompressedImage"](header=header, format="jpeg", data=buf.ravel())

    @cached_property
    def renderer(self):
        from slamobs.pipeline.simulate.camera import TagRenderer
        from slamobs.pipeline.simulate.scenarios import get_scenario

        sc = get_scenario(self.sim.scenario)
        return TagRenderer(self.sim.camera_sim, sc.landmarks, sc.landmark_rots, sc.landmark_ids)

    def mocap(self, i: int) -> object:
        d = self.sim.mocap
        return self.ts.types["geometry_msgs/msg/PoseStamped"](
            header=self.header(int(d.t_ns[i]), FRAME_WORLD, self.sim.first["mocap"] + i),
            pose=self.pose(d.position[i], d.quat_xyzw[i]),
        )

    def serialize(self, msg: object, topic: str) -> bytes:
        msgtype = self.types[topic]
        return bytes(self.ts.serialize_ros1(msg, msgtype) if self.ros1 else self.ts.serialize_cdr(msg, msgtype))

    def columns(self, topic: str) -> dict[tuple[str, ...], np.ndarray] | None:
        """The fields that change from message to message of a fixed-layout topic, by path (None: not fixed);
        the header stamp first, as :func:`~pipeline.readers.fastdecode.make_plan` orders its leaves."""

        def vec(path: tuple[str, ...], values: np.ndarray, names: str = "xyz") -> dict:
            return {(*path, a): values[:, k] for k, a in enumerate(names)}

        s = self.sim
        stream = TOPIC_STREAMS.get(topic)
        if stream is None or topic == TOPIC_DETECTIONS:
            return None
        t_ns = getattr(s, stream).t_ns
        cols = {("header", "stamp", "sec"): t_ns // 1_000_000_000, ("header", "stamp", "nanosec"): t_ns % 1_000_000_000}
        if self.ros1:
            cols[("header", "seq")] = s.first[stream] + np.arange(t_ns.shape[0])
        if topic == TOPIC_IMU:
            return {**cols, **vec(("angular_velocity",), s.imu.gyro), **vec(("linear_acceleration",), s.imu.accel)}
        if topic == TOPIC_ODOM:
            return {
                **cols,
                **vec(("pose", "pose", "position"), s.odom.position),
                **vec(("pose", "pose", "orientation"), s.odom.quat_xyzw, "xyzw"),
                **vec(("twist", "twist", "linear"), s.odom.linear),
                **vec(("twist", "twist", "angular"), s.odom.angular),
            }
        if topic == TOPIC_MAG:
            return {**cols, **vec(("magnetic_field",), s.mag.field)}
        return {
            **cols,
            **vec(("pose", "position"), s.mocap.position),
            **vec(("pose", "orientation"), s.mocap.quat_xyzw, "xyzw"),
        }

    def payloads(self, topic: str, make: Callable[[int], object], n: int) -> Callable[[int], bytes]:
        """Serialised message ``i`` of ``topic``: fixed-layout topics from one template message whose changing
        fields are overwritten in bulk (the bytes rosbags would write, without an object per message)."""
        columns = self.columns(topic) if n else None
        if columns is None:
            return lambda i: self.serialize(make(i), topic)
        rows = fixed_rows(self.ts, self.types[topic], self.serialize(make(0), topic), columns, ros1=self.ros1)
        return lambda i: rows[i].tobytes()

    def makers(self, latched: bool = True) -> dict[str, tuple[np.ndarray, Callable[[int], bytes]]]:
        """Topic -> (record times, serialised message factory); the latched topics only if ``latched``."""
        s = self.sim
        one = np.array([s.start_ns], dtype=np.int64)
        objects = {
            TOPIC_TF_STATIC: (one, self.tf_static),
            TOPIC_TRUTH: (one, self.truth),
            TOPIC_IMU: (s.imu.rec_ns, self.imu),
            TOPIC_ODOM: (s.odom.rec_ns, self.odom),
            TOPIC_MAG: (s.mag.rec_ns, self.mag),
            TOPIC_DETECTIONS: (s.detections.rec_ns, self.detections),
            TOPIC_MOCAP: (s.mocap.rec_ns, self.mocap),
        }
        if s.camera is not None:
            del objects[TOPIC_DETECTIONS]
            cam = s.camera_sim
            objects[camera_topic(cam)] = (s.camera.rec_ns, self.tags if cam.output == "corners" else self.image)
            objects[TOPIC_CAMERA_INFO] = (s.camera.rec_ns, self.camera_info)
        out = {}
        for topic in self.types:
            if latched or topic not in LATCHED:
                rec, make = objects[topic]
                out[topic] = (rec, self.payloads(topic, make, len(rec)))
        return out


def fixed_rows(
    ts: Typestore, msgtype: str, template: bytes, columns: dict[tuple[str, ...], np.ndarray], *, ros1: bool
) -> np.ndarray:
    """The serialised messages of a fixed-layout type, one row of bytes each: copies of ``template`` (one message
    serialised by rosbags) with the changing fields, ``columns`` by path (header stamp sec and nanosec first),
    written in bulk: the bytes rosbags would write, without an object per message."""
    raw = np.frombuffer(template, np.uint8)
    n = len(next(iter(columns.values())))
    plan = make_plan(ts, msgtype, list(columns)[2:], (), cdr=not ros1)
    assert plan is not None, msgtype
    rows = np.empty((n, raw.shape[0]), np.uint8)
    rows[:] = raw
    for (size, kind), offset, values in zip(plan.leaves, leaf_offsets(plan, raw), columns.values()):
        little = np.asarray(values).astype(f"<{kind}{size}")
        rows[:, offset : offset + size] = little.view(np.uint8).reshape(n, size)
    return rows


#: messages between two progress lines of :func:`iter_messages` (an image costs milliseconds, a vector microseconds)
PROGRESS_EVERY = 200


def build_message(factory: Callable[[int], bytes], index: int) -> bytes:
    """One serialised message (a module-level seam so tests can inject a failure mid-write)."""
    return factory(index)


def _pieces(sim: SimLog | Simulation) -> Iterator[SimLog]:
    return iter([sim]) if isinstance(sim, SimLog) else sim.pieces()


def iter_messages(
    sim: SimLog | Simulation, ts: Typestore, ros1: bool, progress: Callable[[str], None] | None = None
) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, record time ns, serialised message)`` over all topics in record-time order (ties: topic order,
    then message order), piece by piece for a :class:`Simulation`; ``progress`` hears how far the log is
    written, every :data:`PROGRESS_EVERY` messages.

    A piece's messages are written once no later piece can precede them: record times are never before the
    stamps, so everything recorded before the next piece's first stamp is final; the rest waits for that piece.
    """
    topics = list(topic_types(sim.camera_sim if isinstance(sim, SimLog) else sim.camera))
    factories: dict[int, dict[str, Callable[[int], bytes]]] = {}
    waiting: list[np.ndarray] = []  # columns: record time, topic, index in the log, index in the piece, piece

    count = [0]

    def emit(cols: list[np.ndarray]) -> Iterator[tuple[str, int, bytes]]:
        rec, topic, glob, local, piece = cols
        for j in np.lexsort((glob, topic, rec)):
            name = topics[topic[j]]
            yield name, int(rec[j]), build_message(factories[int(piece[j])][name], int(local[j]))
            count[0] += 1
            if progress is not None and count[0] % PROGRESS_EVERY == 0:
                progress(f"simulate: {(int(rec[j]) - sim.start_ns) / 1e9:.1f} of {sim.duration:g} s written")

    for p, part in enumerate(_pieces(sim)):
        makers = Builder(part, ts, ros1).makers(latched=p == 0)
        factories[p] = {topic: make for topic, (_, make) in makers.items()}
        sizes = {tp: len(rec) for tp, (rec, _) in makers.items()}
        new = [
            np.concatenate([rec for rec, _ in makers.values()]),
            np.concatenate([np.full(n, topics.index(tp)) for tp, n in sizes.items()]),
            np.concatenate([part.first.get(_stream_of(tp), 0) + np.arange(n) for tp, n in sizes.items()]),
            np.concatenate([np.arange(n) for n in sizes.values()]),
            np.full(sum(sizes.values()), p),
        ]
        if waiting:
            stamps = [getattr(part, name).t_ns[:1] for name in TOPIC_STREAMS.values()]
            bound = min((int(t[0]) for t in stamps if t.size), default=np.iinfo(np.int64).max)
            ready = waiting[0] < bound
            yield from emit([c[ready] for c in waiting])
            new = [np.concatenate([c[~ready], n]) for c, n in zip(waiting, new)]
            for old in set(factories) - set(np.unique(new[4]).tolist()):
                del factories[old]
        waiting = new
    if waiting:
        yield from emit(waiting)


class _Bag1Writer(Bag1Writer):
    """rosbags' ROS1 writer, but a written chunk keeps only its message count per connection (rosbags keeps
    every message's index entry until ``close``: gigabytes of tuples for a multi-hour log). Same bytes."""

    def write_chunk(self, chunk) -> None:  # noqa: ANN001 - rosbags' WriteChunk
        super().write_chunk(chunk)
        if chunk.pos != -1:  # written; close() only asks len() of these
            chunk.connections = {cid: range(len(items)) for cid, items in chunk.connections.items()}


def _types_of(sim: SimLog | Simulation) -> dict[str, str]:
    return topic_types(sim.camera_sim if isinstance(sim, SimLog) else sim.camera)


def _write_bag(sim: SimLog | Simulation, path: Path, progress=None) -> None:
    ts = make_typestore(ros1=True)
    writer = _Bag1Writer(path)
    writer.set_compression(_Bag1Writer.CompressionFormat.LZ4)
    with writer:
        conns = {
            tp: writer.add_connection(
                tp, typ, typestore=ts, callerid="/slamobs_simulate", latching=1 if tp in LATCHED else None
            )
            for tp, typ in _types_of(sim).items()
        }
        for topic, rec, raw in iter_messages(sim, ts, ros1=True, progress=progress):
            writer.write(conns[topic], rec, raw)


def _write_ros2(sim: SimLog | Simulation, path: Path, progress=None) -> None:
    ts = make_typestore(ros1=False)
    with Bag2Writer(path, version=9) as writer:
        writer.set_custom_data(*WRITER_ROS2)
        conns = {
            tp: writer.add_connection(
                tp, typ, typestore=ts, offered_qos_profiles=[_LATCHED_QOS] if tp in LATCHED else []
            )
            for tp, typ in _types_of(sim).items()
        }
        for topic, rec, raw in iter_messages(sim, ts, ros1=False, progress=progress):
            writer.write(conns[topic], rec, raw)


def _write_mcap(sim: SimLog | Simulation, path: Path, progress=None) -> None:
    ts = make_typestore(ros1=False)
    write_mcap(path, _types_of(sim), iter_messages(sim, ts, ros1=False, progress=progress), ts, latched=LATCHED)


def write_mcap(
    path: Path,
    types: dict[str, str],
    messages: Iterable[tuple[str, int, bytes]],
    ts: Typestore,
    *,
    latched: Collection[str] = (),
    library: str | None = None,
) -> None:
    """A new bare ROS2 MCAP file (zstd chunks, message definitions embedded) of ``(topic, record ns, CDR bytes)``
    in record-time order; ``types`` is topic -> message type in channel order, ``library`` names the writer
    (default :data:`WRITER_MCAP`)."""
    with path.open("xb") as stream:
        writer = McapWriter(stream, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library=library or WRITER_MCAP)
        channels: dict[str, int] = {}
        for tp, typ in types.items():
            msgdef, _ = ts.generate_msgdef(typ, ros_version=2)
            schema = writer.register_schema(name=typ, encoding="ros2msg", data=msgdef.encode())
            meta = {"offered_qos_profiles": LATCHED_QOS_YAML if tp in latched else ""}
            channels[tp] = writer.register_channel(topic=tp, message_encoding="cdr", schema_id=schema, metadata=meta)
        seq = dict.fromkeys(channels, 0)
        for topic, rec, data in messages:
            writer.add_message(channels[topic], log_time=rec, data=data, publish_time=rec, sequence=seq[topic])
            seq[topic] += 1
        writer.finish()


#: Public: tests/test_simulate.py puts a failing writer in it.
WRITERS: dict[str, Callable[..., None]] = {
    "bag": _write_bag,
    "mcap": _write_mcap,
    "ros2": _write_ros2,
}


def write_raw_log(
    path: Path,
    container: str,
    topics: dict[str, list[tuple[int, bytes]]],
    msgtype: str,
    ts: Typestore,
    *,
    chunk_threshold: int | None = None,
) -> Path:
    """Already serialised messages of one type, ``topic -> [(record ns, payload)]``, as a ROS1 bag (lz4 chunks
    of ``chunk_threshold`` bytes), a rosbag2 sqlite3 directory or a bare MCAP: hand-made logs for tests and
    benchmarks (payloads in the container's encoding: ROS1 or CDR, either byte order)."""
    path = Path(path)
    if container == "bag":
        writer = Bag1Writer(path)
        writer.set_compression(Bag1Writer.CompressionFormat.LZ4)
        if chunk_threshold is not None:
            writer.chunk_threshold = chunk_threshold
        with writer:
            for topic, msgs in topics.items():
                conn = writer.add_connection(topic, msgtype, typestore=ts)
                for rec, raw in msgs:
                    writer.write(conn, rec, raw)
        return path
    plugin = StoragePlugin.SQLITE3 if container == "ros2" else StoragePlugin.MCAP
    bagdir = path if container == "ros2" else path.with_name(path.name + ".dir")
    with Bag2Writer(bagdir, version=9, storage_plugin=plugin) as writer:
        for topic, msgs in topics.items():
            conn = writer.add_connection(topic, msgtype, typestore=ts)
            for rec, raw in msgs:
                writer.write(conn, rec, raw)
    if bagdir != path:  # the rosbag2 writer makes a directory; keep only its MCAP file
        (inner,) = bagdir.glob("*.mcap")
        inner.rename(path)
        shutil.rmtree(bagdir)
    return path


#: How a simulated log names its writer: the MCAP header's library, every ROS1 connection's caller id, the rosbag2
#: metadata's custom data. ``--force`` replaces only a log that carries it (anything else is the user's).
WRITER_MCAP, WRITER_CALLERID, WRITER_ROS2 = "slamobs-simulate", "/slamobs_simulate", ("writer", "slamobs-simulate")


def why_kept(path: Path, *, overwrite: bool) -> str | None:
    """Why the existing ``path`` must not be replaced by a new log: anything without ``overwrite``, and anything
    but a log ``slamobs simulate`` wrote with it (:func:`.writers.kept_unless`)."""
    from slamobs.pipeline.writers import kept_unless

    return kept_unless(
        _simulated,
        "exists and is not a log slamobs simulate wrote: --force replaces only those; it is kept, remove it or "
        "choose another -o",
        force=overwrite,
        nbytes=None,
    )(path)


def _simulated(path: Path) -> bool:
    """Whether ``path`` is a log this module wrote (see :data:`WRITER_MCAP`), holding nothing else."""
    from slamobs.pipeline.readers.mcap import mcap_library

    try:
        if path.is_symlink():
            return False
        if path.is_dir():
            import yaml

            meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
            files = {"metadata.yaml", *meta.get("relative_file_paths", [])}
            key, value = WRITER_ROS2
            return (meta.get("custom_data") or {}).get(key) == value and set(os.listdir(path)) <= files
        with open(path, "rb") as f:
            head = f.read(4096)
        if head.startswith(b"#ROSBAG V2.0"):
            from rosbags.rosbag1 import Reader

            with Reader(path) as reader:
                ids = {c.ext.callerid for c in reader.connections}
            return ids == {WRITER_CALLERID}
        return mcap_library(head) == WRITER_MCAP
    except Exception:  # noqa: BLE001 - unreadable, damaged or foreign: not ours
        return False


def write_log(
    sim: SimLog | Simulation,
    path: str | Path,
    container: str | None = None,
    *,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write ``sim`` to ``path`` as ``container`` ("bag", "mcap", "ros2"; inferred from the suffix if None).

    A :class:`Simulation` is generated and written piece by piece: memory stays bounded for any duration.

    Refuses to replace an existing path unless ``overwrite``, and then replaces only a log written here
    (:func:`why_kept`). Nothing is left behind if writing fails; a full disk is one line naming ``path``.
    """
    from slamobs.pipeline.writers import atomic_file

    final = Path(path)
    container = infer_container(final) if container is None else container
    if container not in WRITERS:
        raise ValueError(f"unknown container {container!r}; expected one of {', '.join(CONTAINERS)}")
    with atomic_file(final, why_kept=partial(why_kept, overwrite=overwrite)) as tmp:
        WRITERS[container](sim, tmp, progress)
    return final


__all__ = [
    "CONTAINERS",
    "FIDUCIAL_TRANSFORM_ARRAY_MSG",
    "FIDUCIAL_TRANSFORM_MSG",
    "LATCHED",
    "TOPIC_TYPES",
    "infer_container",
    "iter_messages",
    "log_size",
    "fixed_rows",
    "make_typestore",
    "write_log",
    "write_mcap",
]
