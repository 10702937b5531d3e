"""TF buffer: static and time-stamped chains, interpolation, inverses, missing edges; alignment through /tf."""

from __future__ import annotations

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.frames import TfBuffer, static_transform
from slamobs.pipeline.lie import quat_to_rot, rot_to_quat, so3_exp, so3_log
from slamobs.pipeline.streams import DetectionStream, LogStreams, Transform, TransformSeries, Vec3Stream

NS = 1_000_000_000
T0 = 5 * NS


def _q(w) -> np.ndarray:
    return rot_to_quat(so3_exp(np.asarray(w, dtype=float)))


def _series(parent: str, child: str, t_s, trans, rotvecs, topic: str = "/tf") -> TransformSeries:
    t = T0 + (np.asarray(t_s, dtype=float) * NS).astype(np.int64)
    quats = np.array([_q(w) for w in rotvecs])
    return TransformSeries(topic, parent, child, t, t + 7, np.asarray(trans, dtype=float), quats)


def _compose(*rts):
    """``(R, t)`` of x_a = R x_z from transforms listed target-first (a<-b, b<-c, ...)."""
    r, t = np.eye(3), np.zeros(3)
    for ri, ti in reversed(rts):
        r, t = ri @ r, ri @ t + ti
    return r, t


def _slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    """Textbook quaternion slerp (shortest path), as an independent reference."""
    dot = float(q0 @ q1)
    if dot < 0:
        q1, dot = -q1, -dot
    theta = np.arccos(min(dot, 1.0))
    q = (np.sin((1 - a) * theta) * q0 + np.sin(a * theta) * q1) / np.sin(theta)
    return q / np.linalg.norm(q)


# --------------------------------------------------------------------------- buffer


def test_static_chain_inverse_and_compat_api():
    q1, q2 = _q([0.1, -0.2, 0.3]), _q([0.0, 0.5, 0.0])
    tfs = [Transform("a", "b", np.array([1.0, 2, 3]), q1), Transform("/b", "c", np.array([0.0, 1, 0]), q2)]
    buf = TfBuffer(tfs)
    r_ac, t_ac = buf.static_lookup("a", "c")
    r_want, t_want = _compose((quat_to_rot(q1), np.array([1.0, 2, 3])), (quat_to_rot(q2), np.array([0.0, 1, 0])))
    np.testing.assert_allclose(r_ac, r_want, atol=1e-12)
    np.testing.assert_allclose(t_ac, t_want, atol=1e-12)
    r_ca, t_ca = buf.static_lookup("c", "/a")  # inverse direction, slash-insensitive
    np.testing.assert_allclose(r_ca @ r_ac, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(r_ca @ t_ac + t_ca, 0.0, atol=1e-12)
    assert static_transform(tfs, "a", "c") is not None and static_transform(tfs, "a", "zzz") is None
    # A lookup at times of an all-static chain broadcasts the constant transform.
    res = buf.lookup("a", "c", np.array([1, 2, 3]))
    assert res.valid.all() and res.dynamic == ()
    np.testing.assert_allclose(res.rot, np.broadcast_to(r_ac, (3, 3, 3)), atol=1e-12)


def test_dynamic_edge_interpolates_translation_and_slerps_rotation():
    rng = np.random.default_rng(3)
    w0, w1 = rng.normal(size=3), rng.normal(size=3)
    s = _series("world", "body", [0.0, 1.0], [[0.0, 0, 0], [2.0, -4, 6]], [w0, w1])
    buf = TfBuffer(dynamic=[s])
    t_q = T0 + np.array([0, NS // 4, NS // 2, NS], dtype=np.int64)
    res = buf.lookup("world", "body", t_q)
    assert res.valid.all() and res.dynamic == ("world->body",)
    np.testing.assert_allclose(res.trans[1], [0.5, -1, 1.5], atol=1e-12)
    np.testing.assert_allclose(res.rot[0], quat_to_rot(s.quat_xyzw[0]), atol=1e-12)  # exact at samples
    np.testing.assert_allclose(res.rot[3], quat_to_rot(s.quat_xyzw[1]), atol=1e-12)
    for k, a in ((1, 0.25), (2, 0.5)):
        want = quat_to_rot(_slerp(s.quat_xyzw[0], s.quat_xyzw[1], a))
        np.testing.assert_allclose(res.rot[k], want, atol=1e-9)
    # Inverse lookup: body <- world is the inverse at every time.
    inv = buf.lookup("body", "world", t_q)
    np.testing.assert_allclose(
        np.einsum("nij,njk->nik", inv.rot, res.rot), np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-12
    )
    np.testing.assert_allclose(np.einsum("nij,nj->ni", inv.rot, res.trans) + inv.trans, 0.0, atol=1e-12)


def test_slerp_takes_the_short_way_near_half_turn():
    # 170 deg about z, then -170 deg (= 190 deg): the short way passes through 180 deg, not 0.
    s = _series("w", "b", [0.0, 1.0], np.zeros((2, 3)), [[0, 0, np.radians(170)], [0, 0, np.radians(-170)]])
    res = TfBuffer(dynamic=[s]).lookup("w", "b", np.array([T0 + NS // 2]))
    angle = np.linalg.norm(so3_log(res.rot[0]))
    assert angle == pytest.approx(np.pi, abs=1e-6)


def test_outside_span_is_invalid_and_holds_the_nearest_sample():
    s = _series("w", "b", [1.0, 2.0], [[1.0, 0, 0], [3.0, 0, 0]], [[0, 0, 0], [0, 0, 0.2]])
    res = TfBuffer(dynamic=[s]).lookup("w", "b", T0 + np.array([0, NS, 3 * NS], dtype=np.int64))
    np.testing.assert_array_equal(res.valid, [False, True, False])
    np.testing.assert_allclose(res.trans[:, 0], [1.0, 1.0, 3.0])


def test_chain_of_static_and_dynamic_edges():
    # world -> odom (/tf, moving) -> base (/tf, moving) -> camera (/tf_static)
    odom = _series(
        "world", "odom", [0.0, 1.0, 2.0], [[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [0, 0, 0.1], [0, 0, 0.3]]
    )
    base = _series(
        "odom",
        "base",
        np.arange(0, 2.01, 0.1),
        np.column_stack([np.arange(21) * 0.1] + [np.zeros(21)] * 2),
        [[0, 0.01 * k, 0] for k in range(21)],
    )
    cam = Transform("base", "camera", np.array([0.2, 0.0, 0.1]), _q([0.0, 0.3, 0.0]))
    buf = TfBuffer([cam], [odom, base])
    t_q = np.array([T0 + 1_500_000_000], dtype=np.int64)
    res = buf.lookup("world", "camera", t_q)
    assert res.valid.all() and set(res.dynamic) == {"world->odom", "odom->base"}
    r_wo, t_wo = buf.lookup("world", "odom", t_q).rot[0], buf.lookup("world", "odom", t_q).trans[0]
    r_ob, t_ob = buf.lookup("odom", "base", t_q).rot[0], buf.lookup("odom", "base", t_q).trans[0]
    r_want, t_want = _compose((r_wo, t_wo), (r_ob, t_ob), (quat_to_rot(cam.quat_xyzw), cam.translation))
    np.testing.assert_allclose(res.rot[0], r_want, atol=1e-12)
    np.testing.assert_allclose(res.trans[0], t_want, atol=1e-12)
    # The chain from the camera to the odom frame crosses one moving edge; camera <- world is the inverse.
    back = buf.lookup("camera", "world", t_q)
    np.testing.assert_allclose(back.rot[0] @ res.rot[0], np.eye(3), atol=1e-12)
    assert buf.is_static("base", "camera") and not buf.is_static("world", "camera")


def test_static_wins_over_tf_for_the_same_pair_and_chain():
    fixed = Transform("base", "imu", np.array([0.0, 0, 1]), _q([0, 0, 0]))
    moving = _series("base", "imu", [0.0, 1.0], [[5.0, 0, 0], [6.0, 0, 0]], [[0, 0, 0], [0, 0, 1]])
    buf = TfBuffer([fixed], [moving])
    assert any("base->imu" in n for n in buf.notes)
    res = buf.lookup("base", "imu", np.array([T0 + NS // 2]))
    np.testing.assert_allclose(res.trans[0], [0, 0, 1])
    # A static path is preferred to a shorter path through /tf.
    shortcut = _series("base", "cam", [0.0, 1.0], [[9.0, 0, 0], [9.0, 0, 0]], [[0, 0, 0], [0, 0, 0]])
    via = [
        Transform("base", "mount", np.array([1.0, 0, 0]), _q([0, 0, 0])),
        Transform("mount", "cam", np.array([0.0, 1, 0]), _q([0, 0, 0])),
    ]
    np.testing.assert_allclose(TfBuffer(via, [shortcut]).lookup("base", "cam", np.array([T0])).trans[0], [1, 1, 0])


def test_missing_edge_is_a_one_line_error_naming_both_trees():
    buf = TfBuffer(
        [Transform("base", "imu", np.zeros(3), _q([0, 0, 0]))],
        [_series("map", "odom", [0.0, 1.0], np.zeros((2, 3)), np.zeros((2, 3)))],
        path="log.bag",
    )
    assert buf.chain("base", "odom") is None
    with pytest.raises(InputError) as err:
        buf.lookup("base", "odom", np.array([T0]), "/odom")
    msg = str(err.value)
    assert msg.startswith("log.bag [/odom]: no transform chain from frame 'odom' to 'base'")
    assert "'odom' connects to map" in msg and "'base' connects to imu" in msg and "\n" not in msg
    with pytest.raises(InputError, match="'nowhere' is in no transform"):
        buf.lookup("base", "nowhere", np.array([T0]))
    assert "no /tf_static or /tf" in TfBuffer().explain("a", "b")


def test_pose_stream_of_an_edge_or_chain():
    odom = _series("map", "odom", [0.0, 2.0], [[0, 0, 0], [2, 0, 0]], np.zeros((2, 3)))
    base = _series("odom", "base", [0.5, 1.0, 1.5, 2.5], np.eye(4, 3), np.zeros((4, 3)))
    buf = TfBuffer([Transform("base", "imu", np.array([0, 0, 1.0]), _q([0, 0, 0]))], [odom, base], path="x")
    truth = buf.pose_stream("map", "imu", "/tf")
    # Densest edge is odom->base; its last stamp (2.5 s) lies outside map->odom and is left out.
    np.testing.assert_array_equal(truth.t_ns, base.t_ns[:3])
    np.testing.assert_array_equal(truth.rec_ns, base.rec_ns[:3])
    np.testing.assert_allclose(truth.position, [[1.5, 0, 1], [1, 1, 1], [1.5, 0, 2]], atol=1e-12)
    assert (truth.frame_id, truth.child_frame_id, truth.topic) == ("map", "imu", "/tf")
    with pytest.raises(InputError, match="TF edge base->imu is static"):
        buf.pose_stream("base", "imu", "/tf")


def test_record_time_source_interpolates_on_record_times():
    s = _series("w", "b", [0.0, 1.0], [[0.0, 0, 0], [1.0, 0, 0]], np.zeros((2, 3)))
    res = TfBuffer(dynamic=[s], time_source="record").lookup("w", "b", s.rec_ns)
    assert res.valid.all()
    np.testing.assert_allclose(res.trans[:, 0], [0.0, 1.0])


# --------------------------------------------------------------------------- alignment through /tf


def _vec(topic: str, frame: str, t_s: np.ndarray, xyz: np.ndarray) -> Vec3Stream:
    t = T0 + (t_s * NS).astype(np.int64)
    return Vec3Stream(topic, frame, t, t, xyz)


def _streams(static_tf: list[Transform], tf: list[TransformSeries]) -> LogStreams:
    t_om, t_v = np.arange(0, 2.0, 0.01), np.arange(0, 2.0, 0.05)
    t_det = T0 + np.array([0.5, 1.0, 1.9]).__mul__(NS).astype(np.int64)
    return LogStreams(
        path="mem.bag",
        angular_velocity=_vec("/imu", "imu", t_om, np.tile([0.0, 0.0, 0.5], (t_om.size, 1))),
        linear_velocity=_vec("/odom", "base_link", t_v, np.tile([1.0, 0.0, 0.0], (t_v.size, 1))),
        detections=DetectionStream(
            "/fid",
            "camera",
            t_det,
            t_det,
            np.array([0, 1, 2, 3]),
            np.array([4, 5, 6]),
            np.array([[0.0, 0, 1], [0.0, 0, 2], [0.0, 0, 3]]),
        ),
        static_tf=static_tf,
        tf=tf,
    )


def test_alignment_uses_tf_when_static_is_absent():
    yaw = np.pi / 2
    # IMU extrinsic re-published on /tf (constant, starts late); camera on a pan unit turning about z.
    imu = _series("base_link", "imu", [0.5, 1.0, 1.5, 1.99], np.zeros((4, 3)), [[0, 0, yaw]] * 4)
    pan = _series("base_link", "camera", [0.0, 1.5], [[0.1, 0, 0], [0.1, 0, 0]], [[0, 0, 0], [0, 0, 1.5]])
    a = align(_streams([], [imu, pan]))
    np.testing.assert_allclose(a.omega, np.tile([0.0, 0.0, 0.5], (a.omega.shape[0], 1)), atol=1e-12)
    assert any("frame 'imu' -> body 'base_link' through /tf (base_link->imu)" in n for n in a.notes)
    assert any("/imu: 50 samples outside the /tf span use the nearest transform" in n for n in a.notes)
    # Camera frames at 0.5 s and 1.0 s turn by 0.5 and 1.0 rad; the frame at 1.9 s is after the pan's last stamp.
    np.testing.assert_array_equal(a.det_ids, [4, 5])
    for k, (angle, y) in enumerate(((0.5, [0, 0, 1.0]), (1.0, [0, 0, 2.0]))):
        want = so3_exp(np.array([0, 0, angle])) @ np.array(y) + [0.1, 0, 0]
        np.testing.assert_allclose(a.det_y[k], want, atol=1e-12)
    assert any("/fid: 1 detection frame outside the /tf span dropped" in n for n in a.notes)
    assert any("time-varying" in n and "/fid" in n for n in a.notes)


def test_alignment_prefers_static_and_explains_missing_frames():
    static = [
        Transform("base_link", "imu", np.zeros(3), _q([0, 0, 0])),
        Transform("base_link", "camera", np.zeros(3), _q([0, 0, 0])),
    ]
    bogus = _series("base_link", "imu", [0.0, 2.0], np.zeros((2, 3)), [[0, 0, 1], [0, 0, 1]])
    a = align(_streams(static, [bogus]))
    np.testing.assert_allclose(a.omega[0], [0, 0, 0.5])
    assert not any("through /tf" in n for n in a.notes)
    with pytest.raises(InputError) as err:
        align(_streams(static[:1], [_series("odom", "camera", [0.0, 2.0], np.zeros((2, 3)), np.zeros((2, 3)))]))
    msg = str(err.value)
    assert "[/fid]" in msg and "no transform from frame 'camera' to body frame 'base_link'" in msg
    assert "'camera' connects to odom" in msg and "frames.assume_identity" in msg and "\n" not in msg
