"""Readers for real-world message types: velocities, directions, detections with ids, ground-truth sources,
TF edges and tag frames, ``.msg`` definitions a log lacks; generated logs in every container, then real logs."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Nodetype
from rosbags.rosbag1 import Writer as Bag1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Bag2Writer
from rosbags.typesys import get_types_from_msg

from slamobs.cli.info_cmd import info
from slamobs.pipeline.alignment import align
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.frames import TfBuffer
from slamobs.pipeline.lie import quat_to_rot, quats_to_rots, rot_to_quat, so3_exp, so3_log
from slamobs.pipeline.readers import inspect_log, read_log
from slamobs.pipeline.readers.roles import TopicMeta, select_roles
from slamobs.pipeline.simulate import make_typestore
from slamobs.pipeline.simulate.logwriter import FIDUCIAL_TRANSFORM_ARRAY_MSG, FIDUCIAL_TRANSFORM_MSG
from realdata import REALDATA

MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000
K = 4  # messages per topic
CONTAINERS = ["bag", "ros2", "mcap"]

APRILTAG_DETECTION_MSG = "int32[] id\nfloat64[] size\ngeometry_msgs/PoseWithCovarianceStamped pose\n"
APRILTAG_ARRAY_MSG = "std_msgs/Header header\nAprilTagDetection[] detections\n"
TF1_MSG = "geometry_msgs/TransformStamped[] transforms\n"


# --------------------------------------------------------------------------- building logs


def typestore(ros1: bool):
    """The simulator's typestore plus the legacy fiducial type, and for ROS1 apriltag_ros and tf/tfMessage."""
    ts = make_typestore(ros1=ros1)
    types = {}
    types.update(get_types_from_msg(FIDUCIAL_TRANSFORM_MSG, "fiducial_pose/msg/FiducialTransform"))
    types.update(
        get_types_from_msg(
            FIDUCIAL_TRANSFORM_ARRAY_MSG.replace("fiducial_msgs", "fiducial_pose"),
            "fiducial_pose/msg/FiducialTransformArray",
        )
    )
    if ros1:
        types.update(get_types_from_msg(APRILTAG_DETECTION_MSG, "apriltag_ros/msg/AprilTagDetection"))
        types.update(get_types_from_msg(APRILTAG_ARRAY_MSG, "apriltag_ros/msg/AprilTagDetectionArray"))
        types.update(get_types_from_msg(TF1_MSG, "tf/msg/tfMessage"))
    ts.register(types)
    return ts


def _default(ts, kind, desc):
    if kind == Nodetype.BASE:
        typ = desc[0]
        return "" if typ == "string" else False if typ == "bool" else 0.0 if typ.startswith("float") else 0
    if kind == Nodetype.NAME:
        return make(ts, desc)
    (sub_kind, sub_desc), n = desc
    if sub_kind == Nodetype.BASE and sub_desc[0] not in ("string", "bool"):
        dtype = {"byte": "uint8", "char": "uint8"}.get(sub_desc[0], sub_desc[0])
        return np.zeros(n if kind == Nodetype.ARRAY else 0, dtype=dtype)
    return [_default(ts, sub_kind, sub_desc) for _ in range(n)] if kind == Nodetype.ARRAY else []


def make(ts, name: str, **fields):
    """A message of type ``name`` with ``fields`` set and every other field zero or empty."""
    kwargs = {f: fields[f] if f in fields else _default(ts, kind, desc) for f, (kind, desc) in ts.fielddefs[name][1]}
    return ts.types[name](**kwargs)


class Msgs:
    """Message factory for one typestore (ROS1 or ROS2), collecting ``(topic, type, record ns, message)``."""

    def __init__(self, ros1: bool) -> None:
        self.ros1, self.ts, self.items = ros1, typestore(ros1), []

    def add(self, topic: str, msgtype: str, msg: object, rec_ns: int) -> None:
        self.items.append((topic, msgtype, rec_ns, msg))

    def header(self, stamp_ns: int, frame: str):
        stamp = make(self.ts, "builtin_interfaces/msg/Time", sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        return make(self.ts, "std_msgs/msg/Header", stamp=stamp, frame_id=frame)

    def vec(self, xyz, name: str = "geometry_msgs/msg/Vector3"):
        return make(self.ts, name, x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))

    def quat(self, rotvec=(0.0, 0.0, 0.0)):
        q = rot_to_quat(so3_exp(np.asarray(rotvec, dtype=float)))
        return make(self.ts, "geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3])

    def pose(self, xyz, rotvec=(0.0, 0.0, 0.0)):
        return make(
            self.ts,
            "geometry_msgs/msg/Pose",
            position=self.vec(xyz, "geometry_msgs/msg/Point"),
            orientation=self.quat(rotvec),
        )

    def transform(self, xyz, rotvec=(0.0, 0.0, 0.0)):
        return make(self.ts, "geometry_msgs/msg/Transform", translation=self.vec(xyz), rotation=self.quat(rotvec))

    def tf(self, stamp_ns: int, parent: str, child: str, xyz, rotvec=(0.0, 0.0, 0.0)):
        return make(
            self.ts,
            "geometry_msgs/msg/TransformStamped",
            header=self.header(stamp_ns, parent),
            child_frame_id=child,
            transform=self.transform(xyz, rotvec),
        )

    def twist(self, linear, angular):
        return make(self.ts, "geometry_msgs/msg/Twist", linear=self.vec(linear), angular=self.vec(angular))

    def write(self, path: Path, container: str) -> Path:
        """ROS1 bag, rosbag2 sqlite3 directory, or bare MCAP (via the rosbag2 MCAP plugin)."""
        ts = self.ts
        if container == "bag":
            with Bag1Writer(path) as writer:
                conns = {}
                for topic, msgtype, rec, msg in self.items:
                    if topic not in conns:
                        conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
                    writer.write(conns[topic], rec, ts.serialize_ros1(msg, msgtype))
            return path
        plugin = StoragePlugin.SQLITE3 if container == "ros2" else StoragePlugin.MCAP
        bagdir = path if container == "ros2" else path.with_name(path.name + ".dir")
        with Bag2Writer(bagdir, version=9, storage_plugin=plugin) as writer:
            conns = {}
            for topic, msgtype, rec, msg in self.items:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
                writer.write(conns[topic], rec, ts.serialize_cdr(msg, msgtype))
        if bagdir != path:
            (inner,) = bagdir.glob("*.mcap")
            inner.rename(path)
            shutil.rmtree(bagdir)
        return path


def stamp(k: int) -> int:
    return T0 + k * 10 * MS


def zoo(ros1: bool) -> Msgs:
    """Every supported type on its own topic, K messages each (apriltag_ros and tf/tfMessage in ROS1 only)."""
    m = Msgs(ros1)
    ts = m.ts
    for k in range(K):
        t, rec = stamp(k), stamp(k) + MS
        m.add(
            "/imu",
            "sensor_msgs/msg/Imu",
            make(
                ts,
                "sensor_msgs/msg/Imu",
                header=m.header(t, "imu"),
                angular_velocity=m.vec([0.1 * k, 0, 0]),
                linear_acceleration=m.vec([0, 0, 9.8 + k]),
            ),
            rec,
        )
        m.add(
            "/mag",
            "sensor_msgs/msg/MagneticField",
            make(
                ts,
                "sensor_msgs/msg/MagneticField",
                header=m.header(t, "imu"),
                magnetic_field=m.vec([1e-5 * k, 2e-5, 3e-5]),
            ),
            rec,
        )
        odom_pose = make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=m.pose([k, 0, 0]))
        odom_twist = make(ts, "geometry_msgs/msg/TwistWithCovariance", twist=m.twist([0.5 + k, 0, 0], [0, 0, 0.2 * k]))
        m.add(
            "/odom",
            "nav_msgs/msg/Odometry",
            make(
                ts,
                "nav_msgs/msg/Odometry",
                header=m.header(t, "odom"),
                child_frame_id="base_link",
                pose=odom_pose,
                twist=odom_twist,
            ),
            rec,
        )
        m.add(
            "/twist",
            "geometry_msgs/msg/TwistStamped",
            make(
                ts,
                "geometry_msgs/msg/TwistStamped",
                header=m.header(t, "base_link"),
                twist=m.twist([k, 1, 0], [0, 0, -k]),
            ),
            rec,
        )
        m.add(
            "/twist_cov",
            "geometry_msgs/msg/TwistWithCovarianceStamped",
            make(
                ts,
                "geometry_msgs/msg/TwistWithCovarianceStamped",
                header=m.header(t, "wheels"),
                twist=make(ts, "geometry_msgs/msg/TwistWithCovariance", twist=m.twist([2 * k, 0, 0], [0, 0.3 * k, 0])),
            ),
            rec,
        )
        for j in range(3):  # commanded velocity: more messages than any measurement, never picked
            m.add(
                "/cmd_vel",
                "geometry_msgs/msg/TwistStamped",
                make(
                    ts,
                    "geometry_msgs/msg/TwistStamped",
                    header=m.header(t + j, "base_link"),
                    twist=m.twist([9, 9, 9], [9, 9, 9]),
                ),
                rec + j,
            )
        fid = [
            make(ts, "fiducial_msgs/msg/FiducialTransform", fiducial_id=i, transform=m.transform([k, y, y + 1]))
            for i, y in ((1, 1.0), (2, 3.0))
        ]
        m.add(
            "/fiducial_transforms",
            "fiducial_msgs/msg/FiducialTransformArray",
            make(ts, "fiducial_msgs/msg/FiducialTransformArray", header=m.header(t, "camera"), transforms=fid),
            rec,
        )
        legacy = [make(ts, "fiducial_pose/msg/FiducialTransform", fiducial_id=7, transform=m.transform([0, 0, k]))]
        m.add(
            "/fiducial_legacy",
            "fiducial_pose/msg/FiducialTransformArray",
            make(ts, "fiducial_pose/msg/FiducialTransformArray", header=m.header(t, "camera"), transforms=legacy),
            rec,
        )
        m.add(
            "/poses",
            "geometry_msgs/msg/PoseArray",
            make(
                ts,
                "geometry_msgs/msg/PoseArray",
                header=m.header(t, "camera"),
                poses=[m.pose([k, 0, 1]), m.pose([k, 0, 2])],
            ),
            rec,
        )
        markers = [
            make(
                ts,
                "visualization_msgs/msg/Marker",
                header=m.header(t, "camera"),
                id=i,
                action=0,
                pose=m.pose([0, k, i]),
            )
            for i in (5, 6)
        ]
        markers.append(make(ts, "visualization_msgs/msg/Marker", header=m.header(t, "camera"), id=9, action=2))
        m.add(
            "/markers",
            "visualization_msgs/msg/MarkerArray",
            make(ts, "visualization_msgs/msg/MarkerArray", markers=markers),
            rec,
        )
        m.add(
            "/mocap",
            "geometry_msgs/msg/PoseStamped",
            make(ts, "geometry_msgs/msg/PoseStamped", header=m.header(t, "world"), pose=m.pose([k, 0, 0.5])),
            rec,
        )
        amcl = make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=m.pose([k, k, 0]))
        m.add(
            "/amcl",
            "geometry_msgs/msg/PoseWithCovarianceStamped",
            make(ts, "geometry_msgs/msg/PoseWithCovarianceStamped", header=m.header(t, "map"), pose=amcl),
            rec,
        )
        m.add(
            "/vicon",
            "geometry_msgs/msg/TransformStamped",
            m.tf(t, "world", "vicon/body", [k, 0, 1], [0, 0, 0.1 * k]),
            rec,
        )
        if ros1:
            dets = [
                make(
                    ts,
                    "apriltag_ros/msg/AprilTagDetection",
                    id=np.array([3], np.int32),
                    pose=make(
                        ts,
                        "geometry_msgs/msg/PoseWithCovarianceStamped",
                        header=m.header(t, "camera"),
                        pose=make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=m.pose([0, 0, k + 1])),
                    ),
                ),
                make(
                    ts,
                    "apriltag_ros/msg/AprilTagDetection",
                    id=np.array([10, 11], np.int32),
                    pose=make(
                        ts,
                        "geometry_msgs/msg/PoseWithCovarianceStamped",
                        pose=make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=m.pose([1, 1, 1])),
                    ),
                ),
                make(ts, "apriltag_ros/msg/AprilTagDetection"),  # no id: skipped
            ]
            m.add(
                "/tag_detections",
                "apriltag_ros/msg/AprilTagDetectionArray",
                make(ts, "apriltag_ros/msg/AprilTagDetectionArray", header=m.header(t, "camera"), detections=dets),
                rec,
            )
        tf_type = "tf/msg/tfMessage" if ros1 else "tf2_msgs/msg/TFMessage"
        robot = [
            m.tf(t, "world", "odom", [0.5 * k, 0, 0], [0, 0, 0.1 * k]),
            m.tf(t, "odom", "base_link", [0.1 * k, 0, 0]),
        ]
        m.add("/tf", tf_type, make(ts, tf_type, transforms=robot), rec)
        for child, xyz in (("tag_3", [0, 0, 1 + k]), ("tag_12", [1, 0, 2]), ("o_tag_3", [5, 5, 5])):
            # one message per tag, as apriltag_ros broadcasts them
            m.add("/tf", tf_type, make(ts, tf_type, transforms=[m.tf(t, "/camera", child, xyz)]), rec)
        m.add("/tf", tf_type, make(ts, tf_type, transforms=[m.tf(t, "camera2", "tag_4", [0, 0, 1])]), rec)
    m.add(
        "/markers",
        "visualization_msgs/msg/MarkerArray",
        make(ts, "visualization_msgs/msg/MarkerArray", markers=[make(ts, "visualization_msgs/msg/Marker", action=3)]),
        stamp(K) + MS,
    )  # DELETEALL only
    static = [m.tf(T0, "base_link", "camera", [0.2, 0, 0]), m.tf(T0, "base_link", "imu", [0, 0, 0.1])]
    m.add("/tf_static", "tf2_msgs/msg/TFMessage", make(ts, "tf2_msgs/msg/TFMessage", transforms=static), T0)
    return m


@pytest.fixture(scope="module", params=CONTAINERS)
def zoo_log(request, tmp_path_factory):
    container = request.param
    name = {"bag": "zoo.bag", "ros2": "zoo_ros2", "mcap": "zoo.mcap"}[container]
    return zoo(ros1=container == "bag").write(tmp_path_factory.mktemp(container) / name, container)


@pytest.fixture(scope="module")
def zoo_bag(tmp_path_factory):
    return zoo(ros1=True).write(tmp_path_factory.mktemp("bag1") / "zoo.bag", "bag")


# --------------------------------------------------------------------------- roles and values


def test_detected_roles_and_values(zoo_log):
    s = read_log(zoo_log)
    ks = np.arange(K)
    assert inspect_log(zoo_log).roles == {
        "angular_velocity": "/imu",
        "linear_velocity": "/odom",
        "accel": "/imu",
        "magnetic": "/mag",
        "detections": "/fiducial_transforms",
        "truth": "/mocap",
        "static_tf": "/tf_static",
        "tf": "/tf",
    }
    assert (s.angular_velocity.frame_id, s.accel.frame_id, s.magnetic.frame_id) == ("imu", "imu", "imu")
    np.testing.assert_allclose(s.angular_velocity.xyz[:, 0], 0.1 * ks)
    np.testing.assert_allclose(s.accel.xyz[:, 2], 9.8 + ks)
    np.testing.assert_allclose(s.magnetic.xyz, np.column_stack([1e-5 * ks, [2e-5] * K, [3e-5] * K]))
    lv = s.linear_velocity  # odometry twist is in the child frame
    assert lv.frame_id == "base_link"
    np.testing.assert_allclose(lv.xyz[:, 0], 0.5 + ks)
    np.testing.assert_array_equal(s.detections.ids, np.tile([1, 2], K))
    assert (s.truth.topic, s.truth.frame_id, s.truth.child_frame_id) == ("/mocap", "world", "")
    np.testing.assert_array_equal(s.truth.t_ns, [stamp(k) for k in ks])
    assert {(x.parent, x.child) for x in s.tf} == {
        ("world", "odom"),
        ("odom", "base_link"),
        ("camera", "tag_3"),
        ("camera", "tag_12"),
        ("camera", "o_tag_3"),
        ("camera2", "tag_4"),
    }
    assert {(x.parent, x.child) for x in s.static_tf} == {("base_link", "camera"), ("base_link", "imu")}
    assert not any("cmd_vel" in w for w in s.warnings), s.warnings


@pytest.mark.parametrize(
    ("topic", "frame", "angular", "linear"),
    [
        ("/twist", "base_link", [[0, 0, -k] for k in range(K)], [[k, 1, 0] for k in range(K)]),
        ("/twist_cov", "wheels", [[0, 0.3 * k, 0] for k in range(K)], [[2 * k, 0, 0] for k in range(K)]),
        ("/odom", "base_link", [[0, 0, 0.2 * k] for k in range(K)], [[0.5 + k, 0, 0] for k in range(K)]),
    ],
)
def test_velocity_types(zoo_log, topic, frame, angular, linear):
    s = read_log(zoo_log, {"angular_velocity": topic, "linear_velocity": topic})
    for stream, want in ((s.angular_velocity, angular), (s.linear_velocity, linear)):
        assert (stream.topic, stream.frame_id) == (topic, frame)
        np.testing.assert_allclose(stream.xyz, want, atol=1e-12)
        np.testing.assert_array_equal(stream.t_ns, [stamp(k) for k in range(K)])


def test_velocity_tiers_and_commands_are_not_measurements():
    def roles(types: dict[str, tuple[str, int]]) -> dict[str, str]:
        sel = select_roles({t: TopicMeta(m, n) for t, (m, n) in types.items()})
        return {r: t for r, t in sel.roles.items() if r in ("angular_velocity", "linear_velocity")}

    twist, twist_cov = "geometry_msgs/msg/TwistStamped", "geometry_msgs/msg/TwistWithCovarianceStamped"
    assert roles({"/cmd_vel": (twist, 900), "/robot/cmd_vel_nav": (twist, 900), "/vel": (twist_cov, 10)}) == {
        "angular_velocity": "/vel",
        "linear_velocity": "/vel",
    }
    assert roles({"/cmd_vel": (twist, 900)}) == {}
    assert roles({"/odom": ("nav_msgs/msg/Odometry", 5), "/vel": (twist, 50)}) == {
        "angular_velocity": "/odom",
        "linear_velocity": "/odom",
    }
    assert roles({"/imu": ("sensor_msgs/msg/Imu", 5), "/vel": (twist, 50)}) == {
        "angular_velocity": "/imu",
        "linear_velocity": "/vel",
    }


def test_detection_types(zoo_log):
    legacy = read_log(zoo_log, {"detections": "/fiducial_legacy"}).detections
    np.testing.assert_array_equal(legacy.ids, [7] * K)
    np.testing.assert_allclose(legacy.xyz[:, 2], np.arange(K))

    poses = read_log(zoo_log, {"detections": "/poses"}).detections  # index in the array is the id
    assert poses.frame_id == "camera"
    np.testing.assert_array_equal(poses.offsets, np.arange(0, 2 * K + 1, 2))
    np.testing.assert_array_equal(poses.ids, np.tile([0, 1], K))
    np.testing.assert_allclose(poses.xyz[:, 2], np.tile([1, 2], K))

    s = read_log(zoo_log, {"detections": "/markers"})
    markers = s.detections  # DELETE markers and the DELETEALL-only array carry no detection
    assert (markers.frame_id, len(markers)) == ("camera", K)
    np.testing.assert_array_equal(markers.ids, np.tile([5, 6], K))
    np.testing.assert_allclose(markers.xyz[:, 1:], [[k, i] for k in range(K) for i in (5, 6)])
    np.testing.assert_array_equal(markers.t_ns, [stamp(k) for k in range(K)])
    assert f"/markers: {K + 1} DELETE markers skipped" in s.warnings

    s = read_log(zoo_log, {"detections": "/tf"}, tag_pattern="tag_{id}")
    tags = s.detections  # one TF message per tag, grouped by stamp; 'o_tag_3' does not match the pattern
    assert (tags.topic, tags.frame_id, len(tags)) == ("/tf", "camera", K)
    np.testing.assert_array_equal(tags.ids, np.tile([3, 12], K))
    np.testing.assert_allclose(tags.xyz, [xyz for k in range(K) for xyz in ([0, 0, 1 + k], [1, 0, 2])])
    assert f"/tf: {K} tag transforms under another parent than camera dropped" in s.warnings


def test_apriltag_ros_detections(zoo_bag):
    s = read_log(zoo_bag, {"detections": "/tag_detections"})
    det = s.detections
    assert det.frame_id == "camera"
    np.testing.assert_array_equal(det.ids, np.tile([3, 10], K))  # a bundle is named by its first tag id
    np.testing.assert_allclose(det.xyz, [xyz for k in range(K) for xyz in ([0, 0, k + 1], [1, 1, 1])])
    assert (
        f"/tag_detections: {K} bundle detections named by its first tag id, {K} detections without id skipped"
        in s.warnings
    )
    # Detected by type when no fiducial topic exists, after fiducial_msgs and fiducial_pose.
    sel = select_roles({"/tags": TopicMeta("apriltag_ros/msg/AprilTagDetectionArray", 3)})
    assert sel.roles["detections"] == "/tags"


FIDUCIALS_TYPE = "fiducial_msgs/msg/FiducialTransformArray"


def test_tag_pattern_and_explicit_only_types(zoo_log):
    s = read_log(zoo_log, tag_pattern="tag_{id}")
    assert s.detections.topic == "/tf"
    assert any("using TF tag frames 'tag_{id}' on /tf; ignored /fiducial_transforms" in w for w in s.warnings)
    assert read_log(zoo_log, {"detections": "/poses"}, tag_pattern="tag_{id}").detections.topic == "/poses"
    with pytest.raises(InputError, match=r"\[/tf\]: TF tag frames as detections need a tag frame pattern"):
        read_log(zoo_log, {"detections": "/tf"})
    with pytest.raises(InputError, match=r"\[/tf\]: no TF frame matches tag frame pattern 'marker_\{id\}'"):
        read_log(zoo_log, tag_pattern="marker_{id}")
    with pytest.raises(InputError, match=r"must contain \{id\} exactly once"):
        read_log(zoo_log, tag_pattern="tag_")
    # PoseArray / MarkerArray / TF are never detected by type.
    only = select_roles(
        {
            "/p": TopicMeta("geometry_msgs/msg/PoseArray", 9),
            "/m": TopicMeta("visualization_msgs/msg/MarkerArray", 9),
            "/tf": TopicMeta("tf2_msgs/msg/TFMessage", 9),
        }
    )
    assert "detections" not in only.roles
    # Tag corners (no 3D pose) come after every 3D type, and all their topics are the cameras of one rig.
    corners = {
        "/left/tags": TopicMeta("apriltag_msgs/msg/ApriltagArrayStamped", 9),
        "/right/tags": TopicMeta("apriltag_msgs/msg/ApriltagArrayStamped", 5),
    }
    pixels = select_roles(corners)
    assert pixels.multi["detections"] == ["/left/tags", "/right/tags"] and not pixels.warnings
    assert "detections" not in select_roles({**corners, "/f": TopicMeta(FIDUCIALS_TYPE, 1)}).multi
    assert select_roles(corners, {"detections": ["/right/tags"]}).multi["detections"] == ["/right/tags"]
    with pytest.raises(InputError, match=r"several topics for role detections only work for tag corners"):
        select_roles({**corners, "/f": TopicMeta(FIDUCIALS_TYPE, 1)}, {"detections": ["/f", "/left/tags"]})


# --------------------------------------------------------------------------- ground truth


@pytest.mark.parametrize(
    ("topic", "frame", "child", "position"),
    [
        ("/amcl", "map", "", [[k, k, 0] for k in range(K)]),
        ("/vicon", "world", "vicon/body", [[k, 0, 1] for k in range(K)]),
        ("/odom", "odom", "base_link", [[k, 0, 0] for k in range(K)]),
    ],
)
def test_truth_topics(zoo_log, topic, frame, child, position):
    truth = read_log(zoo_log, {"truth": topic}).truth
    assert (truth.topic, truth.frame_id, truth.child_frame_id) == (topic, frame, child)
    np.testing.assert_allclose(truth.position, position, atol=1e-12)
    np.testing.assert_array_equal(truth.t_ns, [stamp(k) for k in range(K)])
    if topic == "/vicon":
        np.testing.assert_allclose(quats_to_rots(truth.quat_xyzw)[2], so3_exp(np.array([0, 0, 0.2])), atol=1e-12)


def test_a_truth_taken_only_when_named_is_pointed_at_when_none_is_found(zoo_log):
    """A ground truth recorded as PoseWithCovarianceStamped (a type taken as truth only when named) left the run
    without an error report and its notes silent about it: the selection now names the topic and the setting."""
    odom, pwcs = TopicMeta("nav_msgs/msg/Odometry", 9), TopicMeta("geometry_msgs/msg/PoseWithCovarianceStamped", 9)
    sel = select_roles({"/odom": odom, "/gt": pwcs, "/f": TopicMeta(FIDUCIALS_TYPE, 9)})
    assert "truth" not in sel.roles
    hint = [w for w in sel.warnings if w.startswith("truth:")]
    assert hint == [
        "truth: none found; /gt (geometry_msgs/msg/PoseWithCovarianceStamped): a truth only when named "
        "(topics.truth: /gt), as such poses are often estimates (odometry, AMCL)"
    ]  # the odometry the velocities read is not offered
    assert not any(
        w.startswith("truth:") for w in select_roles({"/odom": odom, "/gt": pwcs}, {"truth": "/gt"}).warnings
    )
    assert not any(w.startswith("truth:") for w in read_log(zoo_log).warnings)  # a truth found: nothing said


def test_truth_tf_edge_and_chain(zoo_log):
    edge = read_log(zoo_log, {"truth": "world->odom"}).truth
    assert (edge.topic, edge.frame_id, edge.child_frame_id) == ("/tf", "world", "odom")
    np.testing.assert_allclose(edge.position[:, 0], 0.5 * np.arange(K))
    chain = read_log(zoo_log, {"truth": " /world -> camera "}).truth  # world->odom->base_link (/tf) ->camera (static)
    assert (chain.frame_id, chain.child_frame_id, len(chain)) == ("world", "camera", K)
    for k in range(K):
        r = so3_exp(np.array([0, 0, 0.1 * k]))
        want = np.array([0.5 * k, 0, 0]) + r @ (np.array([0.1 * k, 0, 0]) + [0.2, 0, 0])
        np.testing.assert_allclose(chain.position[k], want, atol=1e-12)
        np.testing.assert_allclose(quat_to_rot(chain.quat_xyzw[k]), r, atol=1e-12)
    with pytest.raises(InputError, match="no transform chain from frame 'nowhere' to 'world'"):
        read_log(zoo_log, {"truth": "world->nowhere"})
    with pytest.raises(InputError, match="TF edge base_link->camera is static"):
        read_log(zoo_log, {"truth": "base_link->camera"})
    with pytest.raises(InputError, match="truth TF edge '->camera' is not 'parent->child'"):
        read_log(zoo_log, {"truth": "->camera"})
    with pytest.raises(InputError, match="a TF edge is given as 'parent->child'"):
        read_log(zoo_log, {"truth": "/tf"})


def test_truth_files(tmp_path, zoo_bag):
    t_s = ["1700000000.000000000", "1700000000.010000000"]
    tum = tmp_path / "gt.tum"
    tum.write_text("".join(f"{t} {k} 0 0 0 0 0 1\n" for k, t in enumerate(t_s)))
    euroc = tmp_path / "data.csv"
    euroc.write_text(
        "#timestamp, p_x, p_y, p_z, q_w, q_x, q_y, q_z\n"
        + "".join(f"{T0 + k * 10 * MS},{k},0,0,1,0,0,0\n" for k in range(2))
    )
    kitti, times = tmp_path / "00.txt", tmp_path / "times.txt"
    kitti.write_text("".join(f"1 0 0 {k} 0 1 0 0 0 0 1 0\n" for k in range(2)))
    times.write_text("0.0\n0.01\n")
    for path, fmt, extra in ((tum, None, {}), (euroc, "euroc", {}), (kitti, None, {"truth_times": times})):
        s = read_log(zoo_bag, truth_file=path, truth_format=fmt, **extra)
        np.testing.assert_allclose(s.truth.position[:, 0], [0, 1])
        np.testing.assert_allclose(s.truth.quat_xyzw, [[0, 0, 0, 1]] * 2)
        if path is not kitti:
            np.testing.assert_array_equal(s.truth.t_ns, [T0, T0 + 10 * MS])
    assert read_log(zoo_bag, {"truth": "/amcl"}, truth_file=tum).truth.frame_id == ""  # the file wins
    with pytest.raises(InputError, match="KITTI poses carry no stamps"):
        read_log(zoo_bag, truth_file=kitti)
    with pytest.raises(InputError, match="no such file"):
        read_log(zoo_bag, truth_file=tmp_path / "missing.txt", truth_format="tum")


# --------------------------------------------------------------------------- message definitions


def _msg_dir(root: Path, with_item: bool = True) -> Path:
    pkg = root / "src" / "fiducial_msgs" / "msg"
    pkg.mkdir(parents=True)
    (pkg / "FiducialTransformArray.msg").write_text(FIDUCIAL_TRANSFORM_ARRAY_MSG)
    if with_item:
        (pkg / "FiducialTransform.msg").write_text(FIDUCIAL_TRANSFORM_MSG)
    (root / "src" / "fiducial_msgs" / "CMakeLists.txt").write_text("not a message\n")
    return root


def _db3_without_definitions(tmp_path: Path) -> Path:
    m = zoo(ros1=False)
    m.items = [x for x in m.items if x[0] in ("/imu", "/odom", "/fiducial_transforms")]
    bagdir = m.write(tmp_path / "old_ros2", "ros2")
    (db3,) = bagdir.glob("*.db3")
    with sqlite3.connect(db3) as db:  # as rosbag2 wrote sqlite3 logs before Iron
        db.execute("DELETE FROM message_definitions")
    return bagdir


def _mcap_without_fiducial_schema(path: Path) -> Path:
    """An MCAP whose fiducial channel has an empty schema while the standard types carry theirs."""
    m = zoo(ros1=False)
    with path.open("wb") as stream:
        writer = McapWriter(stream)
        writer.start(profile="ros2", library="test")
        channels = {}
        for topic, msgtype, rec, msg in m.items:
            if topic not in ("/imu", "/odom", "/fiducial_transforms"):
                continue
            if topic not in channels:
                data = b"" if "fiducial" in msgtype else m.ts.generate_msgdef(msgtype, ros_version=2)[0].encode()
                schema = writer.register_schema(msgtype, "" if not data else "ros2msg", data)
                channels[topic] = writer.register_channel(topic, "cdr", schema)
            writer.add_message(
                channels[topic], log_time=rec, data=bytes(m.ts.serialize_cdr(msg, msgtype)), publish_time=rec
            )
        writer.finish()
    return path


@pytest.mark.parametrize("kind", ["db3", "mcap"])
def test_msg_dir_supplies_missing_definitions(tmp_path, kind):
    log = _db3_without_definitions(tmp_path) if kind == "db3" else _mcap_without_fiducial_schema(tmp_path / "x.mcap")
    with pytest.raises(InputError) as err:
        read_log(log)
    msg = str(err.value)
    assert "[/fiducial_transforms]: message definition for fiducial_msgs/msg/FiducialTransformArray is not" in msg
    assert "--msg-dir" in msg and "\n" not in msg
    half = _msg_dir(tmp_path / "half", with_item=False)
    with pytest.raises(
        InputError,
        match=r"definition for fiducial_msgs/msg/FiducialTransform \(used by "
        r"fiducial_msgs/msg/FiducialTransformArray\) is not stored",
    ):
        read_log(log, msg_dir=half)
    full = _msg_dir(tmp_path / "full")
    s = read_log(log, msg_dir=full)
    np.testing.assert_array_equal(s.detections.ids, np.tile([1, 2], K))
    np.testing.assert_allclose(s.detections.xyz[:, 0], np.repeat(np.arange(K), 2))
    fid = next(t for t in inspect_log(log, msg_dir=full).topics if t.topic == "/fiducial_transforms")
    assert fid.note == "" and fid.frame_ids == ("camera",)
    result = CliRunner().invoke(info, [str(log), "--msg-dir", str(full), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["roles"]["detections"] == "/fiducial_transforms"


def test_bad_msg_dir(tmp_path, zoo_bag):
    with pytest.raises(InputError, match="message definition directory not found"):
        read_log(zoo_bag, msg_dir=tmp_path / "nope")
    bad = tmp_path / "bad" / "my_msgs" / "msg"
    bad.mkdir(parents=True)
    (bad / "Broken.msg").write_text("float64[ x\n")
    with pytest.raises(InputError, match=r"Broken.msg: cannot parse message definition my_msgs/msg/Broken"):
        read_log(zoo_bag, msg_dir=tmp_path / "bad")
    result = CliRunner().invoke(info, [str(zoo_bag), "--msg-dir", str(tmp_path / "nope")])
    assert result.exit_code == 2 and result.output.count("\n") == 1 and "not found" in result.output


# --------------------------------------------------------------------------- real logs


def _real(rel: str) -> Path:
    path = REALDATA / rel
    if not path.exists():
        pytest.skip(f"{path} not available")
    return path


def test_real_vicon_transform_stamped_truth():
    s = read_log(_real("ethz_msf_dataset/dataset.bag"))
    truth, gyro = s.truth, s.angular_velocity
    assert (truth.topic, truth.frame_id, truth.child_frame_id, len(truth)) == (
        "/vicon/auk/auk",
        "world",
        "vicon/auk/auk",
        11161,
    )
    # PROVENANCE: body rates from the Vicon attitude follow the gyro axis by axis (Vicon body ~ IMU frame).
    r = quats_to_rots(truth.quat_xyzw)
    rel = np.einsum("nji,njk->nik", r[:-1], r[1:])  # R_k^T R_k+1
    dt = np.diff(truth.t_ns) * 1e-9
    rates = np.column_stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]])
    rates = rates / (2 * dt[:, None])
    t_mid = (truth.t_ns[:-1] + truth.t_ns[1:]) // 2
    ok = dt > 0
    for axis in range(3):
        g = np.interp(t_mid[ok], gyro.t_ns, gyro.xyz[:, axis])
        kernel = np.ones(5) / 5  # Vicon differences are noisy: a short moving average
        v = np.convolve(rates[ok, axis], kernel, mode="same")
        assert np.corrcoef(g, v)[0, 1] > 0.98, axis  # measured 0.993 .. 0.997


def test_real_tagslam_tf_tag_frames():
    path = _real("tagslam_test/test_16/reference.bag")
    s = read_log(path, tag_pattern="tag_{id}")
    det = s.detections
    assert (det.topic, det.frame_id, len(det)) == ("/tf", "lab", 297)
    np.testing.assert_array_equal(np.diff(det.offsets), 5)
    np.testing.assert_array_equal(np.unique(det.ids), [0, 1, 2, 3, 4])
    # Tags are static in the lab body: tag_2 sits at its tagslam.yaml prior (0, 0, 1); the five tags are in a line.
    mean = np.array([det.xyz[det.ids == i].mean(axis=0) for i in range(5)])
    assert np.ptp(det.xyz[det.ids == 2], axis=0).max() == 0.0
    np.testing.assert_allclose(mean[2], [0, 0, 1], atol=1e-12)
    assert np.all(np.diff(mean[:, 0]) > 0.3) and np.abs(mean[:, 1]).max() < 0.01 and np.abs(mean[:, 2] - 1).max() < 0.03
    # cam_rig -> cam0 is camera_poses.yaml: position (0.10, 0, 0), rotation vector (-1.571, 0, 0).
    buf = TfBuffer(s.static_tf, s.tf)
    res = buf.lookup("cam_rig", "cam0", det.t_ns[:3])
    np.testing.assert_allclose(res.trans, [[0.1, 0, 0]] * 3, atol=1e-12)
    np.testing.assert_allclose(so3_log(res.rot[0]), [-1.571, 0, 0], atol=1e-9)
    # Into the moving rig: lab -> map -> cam_rig through /tf at each detection stamp.
    a = align(s, body_frame="cam_rig")
    assert a.det_t_ns.shape[0] == 297 and a.det_y.shape == (297 * 5, 3)
    assert any("frame 'lab' -> body 'cam_rig' through /tf" in n for n in a.notes)
    first = buf.lookup("cam_rig", "lab", det.t_ns[:1])
    np.testing.assert_allclose(a.det_y[:5], det.xyz[:5] @ first.rot[0].T + first.trans[0], atol=1e-12)


def test_real_tf_edges_in_two_containers():
    ros1 = read_log(_real("evo/tf_example.bag"), {"truth": "odom->base_footprint"}).truth
    ros2 = read_log(_real("evo/tf_example"), {"truth": "odom->base_footprint"}).truth
    assert len(ros1) == len(ros2) == 517
    np.testing.assert_array_equal(ros1.t_ns, ros2.t_ns)
    np.testing.assert_array_equal(ros1.position, ros2.position)
    # Through the identity static base_footprint -> base_link: the same poses.
    chained = read_log(_real("evo/tf_example"), {"truth": "odom->base_link"}).truth
    assert chained.child_frame_id == "base_link"
    np.testing.assert_allclose(chained.position, ros2.position, atol=1e-12)


def test_real_nav2_odometry_and_amcl_truth():
    path = _real("evo/nav2_turtlebot.mcap")
    odom = read_log(path, {"truth": "/odom"}).truth
    assert (odom.frame_id, odom.child_frame_id, len(odom)) == ("odom", "base_link", 2639)
    tf_odom = read_log(path, {"truth": "odom->base_link"}).truth  # the same estimate, broadcast on /tf
    np.testing.assert_array_equal(tf_odom.t_ns, odom.t_ns)
    np.testing.assert_allclose(tf_odom.position, odom.position, atol=1e-12)
    amcl = read_log(path, {"truth": "/amcl_pose"}).truth
    assert (amcl.topic, amcl.frame_id, amcl.child_frame_id, len(amcl)) == ("/amcl_pose", "map", "", 135)
    # AMCL publishes map->odom from its pose: map->base_link through /tf at AMCL stamps is close to it.
    s = read_log(path)
    res = TfBuffer(s.static_tf, s.tf).lookup("map", "base_link", amcl.t_ns)
    assert res.valid.sum() >= 130
    err = np.linalg.norm(res.trans[res.valid] - amcl.position[res.valid], axis=1)
    assert np.median(err) < 0.1


@pytest.mark.parametrize("container", ["bag", "mcap"])
def test_marker_namespaces(container, tmp_path):
    """Marker ids are unique per namespace: two namespaces on one topic are reported, and
    ``marker_ns`` (config ``frames.marker_namespace``) keeps one."""
    m = Msgs(ros1=container == "bag")
    for k in range(K):
        t = stamp(k)
        markers = [
            make(
                m.ts,
                "visualization_msgs/msg/Marker",
                header=m.header(t, "camera"),
                ns=ns,
                id=i,
                action=0,
                pose=m.pose([z, k, i]),
            )
            for ns, z in (("tags", 1.0), ("labels", 9.0))
            for i in (5, 6)
        ]
        m.add(
            "/markers",
            "visualization_msgs/msg/MarkerArray",
            make(m.ts, "visualization_msgs/msg/MarkerArray", markers=markers),
            t + MS,
        )
    log = m.write(tmp_path / f"ns.{container}", container)

    mixed = read_log(log, {"detections": "/markers"})
    assert any(
        "markers of 2 namespaces ('labels', 'tags')" in w and "frames.marker_namespace" in w for w in mixed.warnings
    )
    tags = read_log(log, {"detections": "/markers"}, marker_ns="tags")
    np.testing.assert_array_equal(tags.detections.ids, np.tile([5, 6], K))
    np.testing.assert_allclose(tags.detections.xyz[:, 0], 1.0)
    assert f"/markers: {2 * K} markers of another namespace than 'tags' skipped" in tags.warnings
    assert not any("namespaces" in w for w in tags.warnings)
    with pytest.raises(
        InputError,
        match=r"frames.marker_namespace 'nope' names no namespace of its markers "
        r"\(namespaces: 'labels', 'tags'\)",
    ):
        read_log(log, {"detections": "/markers"}, marker_ns="nope")
