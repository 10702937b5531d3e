"""Simulator: kinematic consistency, measurement models, containers round trip, CLI and sample logs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from rosbags.highlevel import AnyReader

from slamobs.cli.simulate_cmd import simulate as simulate_cmd
from slamobs.pipeline.errors import OutputError, ResourceError
from slamobs.pipeline.lie import quat_to_rot, quats_to_rots
from slamobs.pipeline.simulate import logwriter
from slamobs.pipeline.simulate.camera import CameraSim
from slamobs.pipeline.simulate.logwriter import TOPIC_TYPES, write_log
from slamobs.pipeline.lie import integrate_body_twists
from slamobs.pipeline.simulate.scenarios import GRAVITY, MAGNETIC_FIELD, customize, get_scenario
from slamobs.pipeline.simulate.sensors import (
    TOPIC_DETECTIONS,
    TOPIC_IMU,
    TOPIC_MAG,
    TOPIC_MOCAP,
    TOPIC_ODOM,
    TOPIC_TF_STATIC,
    TOPIC_TRUTH,
    body_points,
    simulate,
)

SAMPLE_DIR = Path(__file__).resolve().parents[1] / "sample_logs"
# Must match the regeneration commands of sample_logs/README.md.
SAMPLES = {
    "circle.bag": dict(scenario="circle", imu_rate=100.0, odom_rate=25.0, mag_rate=25.0, mocap_rate=50.0),
    "circle_ros2": dict(scenario="circle", imu_rate=100.0, odom_rate=25.0, mag_rate=25.0, mocap_rate=50.0),
    "figure8.mcap": dict(scenario="figure8", imu_rate=100.0, mocap_rate=50.0),
    "figure8_camera.mcap": dict(
        scenario="figure8",
        duration=15.0,
        imu_rate=100.0,
        mocap_rate=50.0,
        detection_rate=10.0,
        camera=CameraSim("images", 320, 240, 60.0, tag_size=0.8, jpeg_quality=75),
    ),
}


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def vec(v) -> list[float]:
    return [v.x, v.y, v.z]


# --------------------------------------------------------------------------- scenarios


@pytest.mark.parametrize("name", ["circle", "figure8", "loop"])
def test_twists_integrate_to_the_sampled_poses(name):
    sc = get_scenario(name)
    dt, t_end = 1e-3, 20.0
    t = np.arange(0.0, t_end + dt / 2, dt)
    truth = sc.sample(t)
    mid = sc.sample(t[:-1] + dt / 2)  # midpoint twists: second-order accurate steps
    rs, ps = integrate_body_twists(truth.R[0], truth.P[0], mid.omega, mid.v, np.full(t.size - 1, dt))
    assert np.abs(ps - truth.P).max() < 1e-5
    assert np.abs(rs - truth.R).max() < 1e-6
    # Derivatives are consistent with the poses (finite differences only as a check).
    pdot = np.gradient(truth.P, dt, axis=0)[1:-1]
    assert np.allclose(np.einsum("nij,nj->ni", truth.R, truth.v)[1:-1], pdot, atol=1e-5)
    assert np.allclose(np.gradient(pdot, dt, axis=0)[1:-1], truth.accel[2:-2], atol=1e-4)
    assert np.allclose(np.einsum("nji,njk->nik", truth.R, truth.R), np.eye(3), atol=1e-12)


def test_circle_is_the_paper_scenario():
    sc = get_scenario("circle")
    tr = sc.sample(np.linspace(0.0, 30.0, 301))
    assert np.allclose(tr.P[0], [0, 0, 6]) and np.allclose(tr.R[0], np.eye(3))
    assert np.allclose(np.linalg.norm(tr.P - [0.0, 2.5 / 0.3, 6.0], axis=1), 2.5 / 0.3)
    assert np.allclose(tr.omega, [0, 0, 0.3]) and np.allclose(tr.v, [2.5, 0, 0])
    assert sc.landmark_ids.tolist() == [1, 2, 3, 4]
    assert np.allclose(sc.gyro_bias, [0.09, -0.15, -0.1]) and np.allclose(sc.velocity_bias, [0.09, 0.06, -0.07])


def test_figure8_speed_and_landmarks():
    sc = get_scenario("figure8")
    tr = sc.sample(np.linspace(0.0, 60.0, 6001))
    speed = np.linalg.norm(tr.v, axis=1)
    assert 1.3 < speed.min() and speed.max() < 3.1
    assert 24 <= sc.landmark_ids.size <= 30 and np.unique(sc.landmark_ids).size == sc.landmark_ids.size
    assert np.any(np.diff(np.sort(sc.landmark_ids)) > 1)  # ids not contiguous
    assert np.ptp(sc.landmarks[:, 2]) > 2.0  # ground and walls: not coplanar
    dist = np.linalg.norm(sc.landmarks[:, None, :] - tr.P[None, :, :], axis=2).min(axis=1)
    assert dist.max() < 15.0


# --------------------------------------------------------------------------- sensors


def test_noise_free_measurement_models():
    sim = simulate("circle", duration=3.0, noise=False)
    sc = get_scenario("circle")
    t = (sim.imu.t_ns - sim.start_ns) * 1e-9
    tr = sc.sample(t)
    assert np.allclose(sim.imu.gyro - sc.gyro_bias, tr.omega, atol=1e-12)
    assert np.allclose(sim.imu.accel, [0.0, 2.5 * 0.3, 9.81], atol=1e-9)  # centripetal + gravity reaction
    assert np.allclose(np.linalg.norm(sim.mag.field, axis=1), np.linalg.norm(MAGNETIC_FIELD))
    assert np.allclose(sim.odom.linear - sc.velocity_bias, [2.5, 0, 0], atol=1e-12)
    assert np.allclose(sim.odom.angular, [0, 0, 0.3], atol=1e-12)
    assert np.allclose(sim.odom.position[0], 0.0) and np.allclose(sim.odom.quat_xyzw[0], [0, 0, 0, 1])
    pose = sc.sample((sim.mocap.t_ns - sim.start_ns) * 1e-9)
    assert np.allclose(sim.mocap.position, pose.P)
    assert np.allclose(quats_to_rots(sim.mocap.quat_xyzw), pose.R, atol=1e-12)
    assert sim.truth["gravity"] == GRAVITY.tolist()


@pytest.mark.parametrize("name", ["circle", "figure8"])
def test_detection_round_trip_through_extrinsic(name):
    sim = simulate(name, duration=10.0, noise=False)
    sc = get_scenario(name)
    cam_tf = next(tf for tf in sim.static_tf if tf.child == "camera")
    assert cam_tf.parent == "base_link"
    r_bc, t_bc = quat_to_rot(cam_tf.quat_xyzw), cam_tf.translation
    det = sim.detections
    frame = np.repeat(np.arange(len(det.t_ns)), np.diff(det.offsets))
    tr = sc.sample((det.t_ns - sim.start_ns) * 1e-9)
    lm_index = {int(i): k for k, i in enumerate(sc.landmark_ids)}
    expected = body_points(tr.R, tr.P, sc.landmarks)[frame, [lm_index[int(i)] for i in det.ids]]
    assert np.allclose(det.xyz @ r_bc.T + t_bc, expected, atol=1e-9)
    # Tag orientation: camera-frame rotation maps back to the world orientation of the tag.
    r_wt = np.einsum("nij,jk,nkl->nil", tr.R[frame], r_bc, quats_to_rots(det.quat_xyzw))
    assert np.allclose(r_wt, sc.landmark_rots[[lm_index[int(i)] for i in det.ids]], atol=1e-9)


def test_figure8_landmarks_come_and_go():
    sim = simulate("figure8", noise=False)
    det = sim.detections
    counts = np.diff(det.offsets)
    assert counts.min() >= 3
    assert np.mean((counts >= 4) & (counts <= 10)) > 0.8
    seen = np.zeros((counts.size, 256), dtype=bool)
    seen[np.repeat(np.arange(counts.size), counts), det.ids] = True
    frac = seen[:, np.unique(det.ids)].mean(axis=0)
    assert np.unique(det.ids).size == get_scenario("figure8").landmark_ids.size  # every landmark seen
    assert frac.max() < 0.5  # and none always visible
    assert np.count_nonzero(np.any(seen[1:] != seen[:-1], axis=1)) > 100  # the visible set keeps changing


def test_stamps_latency_and_reproducibility():
    a = simulate("figure8", duration=5.0, seed=3)
    b = simulate("figure8", duration=5.0, seed=3)
    c = simulate("figure8", duration=5.0, seed=4)
    assert np.array_equal(a.imu.gyro, b.imu.gyro) and np.array_equal(a.detections.xyz, b.detections.xyz)
    assert not np.array_equal(a.imu.gyro, c.imu.gyro)
    for stream in (a.imu, a.odom, a.mag, a.detections, a.mocap):
        assert stream.t_ns.dtype == np.int64 and np.all(np.diff(stream.t_ns) > 0)
        assert np.all(np.diff(stream.rec_ns) >= 0)
        lat = stream.rec_ns - stream.t_ns
        assert lat.min() >= 1_000_000 and lat.max() <= 5_000_000
        assert stream.t_ns[0] >= a.start_ns and stream.t_ns[-1] <= a.start_ns + 5_000_000_000
    assert len(a.imu.t_ns) == 1001 and len(a.detections.t_ns) == 100


# --------------------------------------------------------------------------- containers


@pytest.mark.parametrize("container,name", [("bag", "log.bag"), ("mcap", "log.mcap"), ("ros2", "log_ros2")])
def test_container_round_trip(tmp_path, container, name):
    sim = simulate("figure8", duration=4.0, seed=7, imu_rate=100.0)
    path = write_log(sim, tmp_path / name)
    assert path == tmp_path / name and sorted(p.name for p in tmp_path.iterdir()) == [name]

    got: dict[str, list] = {tp: [] for tp in TOPIC_TYPES}
    log_times: list[int] = []
    with AnyReader([path]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TOPIC_TYPES
        det_conn = next(c for c in reader.connections if c.topic == TOPIC_DETECTIONS)
        assert "MSG: fiducial_msgs/FiducialTransform" in det_conn.msgdef.data
        if container == "bag":
            latched = {c.topic: c.ext.latching for c in reader.connections}
            assert latched[TOPIC_TF_STATIC] == 1 and latched[TOPIC_IMU] is None
        for conn, timestamp, raw in reader.messages():
            got[conn.topic].append((timestamp, reader.deserialize(raw, conn.msgtype)))
            log_times.append(timestamp)
    assert log_times == sorted(log_times)
    assert {tp: len(v) for tp, v in got.items()} == sim.topic_counts()

    def check_times(topic, stream):
        assert [t for t, _ in got[topic]] == stream.rec_ns.tolist()
        assert [stamp_ns(m.header) for _, m in got[topic]] == stream.t_ns.tolist()

    check_times(TOPIC_IMU, sim.imu)
    imu = [m for _, m in got[TOPIC_IMU]]
    assert np.array_equal([vec(m.angular_velocity) for m in imu], sim.imu.gyro)
    assert np.array_equal([vec(m.linear_acceleration) for m in imu], sim.imu.accel)
    assert imu[0].header.frame_id == "imu_link" and imu[0].orientation_covariance[0] == -1.0

    check_times(TOPIC_ODOM, sim.odom)
    odom = [m for _, m in got[TOPIC_ODOM]]
    assert odom[0].header.frame_id == "odom" and odom[0].child_frame_id == "base_link"
    assert np.array_equal([vec(m.twist.twist.linear) for m in odom], sim.odom.linear)
    assert np.array_equal([vec(m.twist.twist.angular) for m in odom], sim.odom.angular)
    assert np.array_equal([vec(m.pose.pose.position) for m in odom], sim.odom.position)

    check_times(TOPIC_MAG, sim.mag)
    assert np.array_equal([vec(m.magnetic_field) for _, m in got[TOPIC_MAG]], sim.mag.field)

    check_times(TOPIC_MOCAP, sim.mocap)
    mocap = [m for _, m in got[TOPIC_MOCAP]]
    assert mocap[0].header.frame_id == "world"
    assert np.array_equal([vec(m.pose.position) for m in mocap], sim.mocap.position)

    check_times(TOPIC_DETECTIONS, sim.detections)
    frames = [m for _, m in got[TOPIC_DETECTIONS]]
    assert frames[0].header.frame_id == "camera" and [f.image_seq for f in frames] == list(range(len(frames)))
    assert np.array_equal([len(f.transforms) for f in frames], np.diff(sim.detections.offsets))
    items = [x for f in frames for x in f.transforms]
    assert np.array_equal([x.fiducial_id for x in items], sim.detections.ids)
    assert np.array_equal([vec(x.transform.translation) for x in items], sim.detections.xyz)
    assert np.array_equal([x.fiducial_area for x in items], sim.detections.area)

    ((_, tf_msg),) = got[TOPIC_TF_STATIC]
    tfs = {(t.header.frame_id, t.child_frame_id): t.transform for t in tf_msg.transforms}
    assert set(tfs) == {("base_link", "camera"), ("base_link", "imu_link")}
    assert np.allclose(vec(tfs[("base_link", "camera")].translation), sim.static_tf[0].translation)

    ((_, truth_msg),) = got[TOPIC_TRUTH]
    truth = json.loads(truth_msg.data)
    assert truth == sim.truth
    assert truth["frame_id"] == "world" and truth["scenario"] == "figure8"
    assert len(truth["landmarks"]) == 30 and truth["gyro_bias"] == [0.02, -0.03, 0.05]


@pytest.mark.parametrize("container,name", [("bag", "x.bag"), ("mcap", "x.mcap"), ("ros2", "x_ros2")])
def test_failed_write_leaves_nothing(tmp_path, monkeypatch, container, name):
    sim = simulate("circle", duration=2.0)
    calls = {"n": 0}
    original = logwriter.build_message

    def failing(factory, index):
        calls["n"] += 1
        if calls["n"] == 300:
            raise RuntimeError("disk on fire")
        return original(factory, index)

    monkeypatch.setattr(logwriter, "build_message", failing)
    with pytest.raises(RuntimeError, match="disk on fire"):
        write_log(sim, tmp_path / name, container)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["a.mcap", "a.bag", "a_ros2"])
def test_existing_output_is_kept_unless_overwrite_and_ours(tmp_path, name):
    """``overwrite`` replaces only a log written here (issue 28: `simulate --force` deleted whatever was there)."""
    sim = simulate("circle", duration=1.0)
    target = tmp_path / name
    target.write_text("precious")
    for overwrite in (False, True):  # never "use --force" for a file --force would not replace
        with pytest.raises(OutputError, match="not a log slamobs simulate"):
            write_log(sim, target, overwrite=overwrite)
        assert target.read_text() == "precious"
    target.unlink()
    write_log(sim, target)
    write_log(sim, target, overwrite=True)
    with AnyReader([target]) as reader:
        assert reader.message_count == sum(sim.topic_counts().values())
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
    with pytest.raises(ValueError, match="container"):
        write_log(sim, tmp_path / "b.bag", "zip")


def test_a_full_disk_is_one_line_naming_the_log(tmp_path, monkeypatch):
    """A full disk said "No space left on device" without the file (issue 28); now a ResourceError naming it."""
    import errno

    def full(*_args, **_kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(logwriter, "_write_mcap", full)
    monkeypatch.setitem(logwriter.WRITERS, "mcap", full)
    target = tmp_path / "a.mcap"
    with pytest.raises(ResourceError, match="No space left on device") as err:
        write_log(simulate("circle", duration=1.0), target)
    assert err.value.path == str(target) and list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- CLI


def test_cli(tmp_path):
    runner = CliRunner()
    res = runner.invoke(simulate_cmd, ["nowhere", "-o", str(tmp_path / "x.bag")])
    assert res.exit_code == 2 and "unknown scenario 'nowhere'" in res.output

    out = tmp_path / "run"  # no suffix -> rosbag2 directory
    res = runner.invoke(
        simulate_cmd, ["figure8", "-o", str(out), "--duration", "2", "--seed", "5", "--imu-rate", "50", "--no-noise"]
    )
    assert res.exit_code == 0, res.output
    assert len(res.stdout.strip().splitlines()) == 1 and "/imu/data 101" in res.stdout and "ros2" in res.stdout
    assert (out / "metadata.yaml").is_file() and (out / "run.db3").is_file()

    mcap = tmp_path / "c.mcap"
    args = ["circle", "-o", str(mcap), "--duration", "1", "--detection-rate", "25"]
    assert runner.invoke(simulate_cmd, args).exit_code == 0
    res = runner.invoke(simulate_cmd, args)
    assert res.exit_code == 2 and res.output.strip() == f"error: {mcap}: exists already (use --force to replace it)"
    res = runner.invoke(simulate_cmd, [*args, "--force", "--container", "mcap"])
    assert res.exit_code == 0 and "(mcap," in res.output
    with AnyReader([mcap]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts[TOPIC_DETECTIONS] == 25  # 25 Hz over 1 s, first frame 7 ms in


# --------------------------------------------------------------------------- committed sample logs


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_sample_logs_match_the_simulator(name):
    path = SAMPLE_DIR / name
    if not path.exists():
        pytest.skip(f"{path} not generated")
    params = dict(SAMPLES[name])
    sim = simulate(params.pop("scenario"), seed=0, **params)
    with AnyReader([path]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        conn = next(c for c in reader.connections if c.topic == TOPIC_TRUTH)
        ((_, _, raw),) = list(reader.messages(connections=[conn]))
        truth = json.loads(reader.deserialize(raw, conn.msgtype).data)
        conn = next(c for c in reader.connections if c.topic == TOPIC_IMU)
        first = next(iter(reader.messages(connections=[conn])))
        imu0 = reader.deserialize(first[2], conn.msgtype)
    assert counts == sim.topic_counts()
    assert truth == sim.truth
    assert vec(imu0.angular_velocity) == sim.imu.gyro[0].tolist()


def test_expected_streams_mirror_the_log():
    from slamobs.pipeline.simulate import expected_streams

    sim = simulate("figure8", duration=2.0)
    streams = expected_streams(sim, "x.mcap")
    assert streams.angular_velocity.topic == TOPIC_IMU and len(streams.angular_velocity) == len(sim.imu.t_ns)
    assert streams.linear_velocity.frame_id == "base_link" and streams.detections.frame_id == "camera"
    assert set(streams.landmark_truth) == {int(i) for i in get_scenario("figure8").landmark_ids}
    assert np.allclose(streams.bias_truth["gyro"], [0.02, -0.03, 0.05])


# --------------------------------------------------------------------------- long logs: pieces and templates


def test_pieces_join_into_a_continuous_log():
    """A simulation generated in pieces (here 2 s) is one log: stamps on one grid, record times that never go
    back, dead-reckoned odometry that goes on where the previous piece stopped, message indices that continue."""
    from dataclasses import replace

    from slamobs.pipeline.simulate.sensors import STREAMS, simulation

    one = simulation("figure8", duration=5.0, seed=4)
    pieces = replace(one, piece_s=2.0)
    parts = list(pieces.pieces())
    assert len(parts) == 3
    whole, single = pieces.whole(), one.whole()
    for name in STREAMS:
        a, b = getattr(whole, name), getattr(single, name)
        assert np.array_equal(a.t_ns, b.t_ns), name  # the same grid, cut into pieces
        assert np.all(np.diff(a.rec_ns) >= 0) and np.all(a.rec_ns >= a.t_ns)
        sizes = [len(getattr(p, name).t_ns) for p in parts]
        assert [p.first[name] for p in parts] == np.cumsum([0, *sizes[:-1]]).tolist()
    assert pieces.topic_counts() == whole.topic_counts() == single.topic_counts()
    # odometry integrates the measured twist across the piece boundaries exactly as in one go
    o = whole.odom
    rs, ps = integrate_body_twists(
        np.eye(3), np.zeros(3), o.angular[:-1], o.linear[:-1], np.diff((o.t_ns - whole.start_ns) * 1e-9)
    )
    assert np.array_equal(ps, o.position) and np.allclose(quats_to_rots(o.quat_xyzw), rs, atol=1e-12)
    det = whole.detections
    assert det.offsets[-1] == det.ids.size and np.all(np.diff(det.offsets) >= 0)


def test_short_logs_are_one_piece():
    """Logs up to PIECE_S are generated in one piece from ``default_rng(seed)``: sample logs stay as they are."""
    from slamobs.pipeline.simulate.sensors import PIECE_S, simulation

    sim = simulation("circle", duration=PIECE_S)
    assert len(list(sim.pieces())) == 1
    assert len(list(simulation("circle", duration=PIECE_S + 1).pieces())) == 2


@pytest.mark.parametrize("ros1", [True, False])
def test_serialised_messages_are_rosbags_bytes(ros1):
    """The fixed-layout messages are written from a template with their fields overwritten in bulk: every
    message must be byte-for-byte what rosbags serialises from the message object."""
    from slamobs.pipeline.simulate.logwriter import Builder, make_typestore

    sim = simulate("figure8", duration=2.0, seed=9)
    ts = make_typestore(ros1=ros1)
    builder = Builder(sim, ts, ros1)
    objects = {
        TOPIC_IMU: builder.imu,
        TOPIC_ODOM: builder.odom,
        TOPIC_MAG: builder.mag,
        TOPIC_MOCAP: builder.mocap,
        TOPIC_DETECTIONS: builder.detections,
    }
    for topic, (rec, payload) in builder.makers().items():
        if topic not in objects:
            continue
        for i in range(len(rec)):
            assert payload(i) == builder.serialize(objects[topic](i), topic), (topic, i)


def test_long_log_is_written_piece_by_piece(tmp_path):
    """Writing a Simulation (pieces) gives the log of its joined SimLog, messages in record-time order."""
    from dataclasses import replace

    from slamobs.pipeline.simulate.sensors import simulation

    sim = replace(simulation("circle", duration=3.0, seed=2, imu_rate=50.0), piece_s=1.0)
    streamed = write_log(sim, tmp_path / "s.mcap")
    joined = write_log(sim.whole(), tmp_path / "j.mcap")
    read = []
    for path in (streamed, joined):
        with AnyReader([path]) as reader:
            read.append([(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()])
    assert read[0] == read[1]
    assert [t for _, t, _ in read[0]] == sorted(t for _, t, _ in read[0])


def test_figure8_wide_sees_about_eight_landmarks():
    sim = simulate("figure8-wide", duration=60.0, noise=False)
    counts = np.diff(sim.detections.offsets)
    assert 7.0 <= counts.mean() <= 9.0 and counts.min() >= 3
    assert get_scenario("figure8-wide").landmark_ids.size == 30


# --------------------------------------------------------------------------- rig options and issue-12 scenarios


def test_loop_passes_sixty_landmarks_with_a_narrow_camera():
    sc = get_scenario("loop")
    assert sc.landmark_ids.size == 60 and sc.camera.fov_h_deg == 50.0 and sc.duration == 180.0
    sim = simulate("loop", duration=90.0, noise=False, imu_rate=50.0, odom_rate=10.0, mag_rate=10.0, mocap_rate=10.0)
    counts = np.diff(sim.detections.offsets)
    assert 3 <= counts.min() and counts.max() <= 12 and 4.0 < counts.mean() < 9.0
    assert np.unique(sim.detections.ids).size == 60  # every landmark is seen on a lap


def test_rig_options():
    sc = customize(get_scenario("loop"), landmarks=12, fov_deg=80.0, detections_until=5.0, imu_rpy_deg=(180, 0, 0))
    assert sc.landmark_ids.size == 12 and sc.camera.fov_h_deg == 80.0 and sc.camera.fov_v_deg == 64.0
    assert np.allclose(sc.imu_rotation, np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    sub = customize(get_scenario("figure8"), landmarks=10)
    assert sub.landmark_ids.size == 10 and set(sub.landmark_ids) <= set(get_scenario("figure8").landmark_ids)
    with pytest.raises(ValueError, match="choose 3 to 30"):
        customize(get_scenario("figure8"), landmarks=31)
    sim = simulate(sc, duration=8.0, noise=False, imu_rate=50.0)
    t = (sim.detections.t_ns - sim.start_ns) * 1e-9
    counts = np.diff(sim.detections.offsets)
    assert counts[t <= 5.0].min() > 0 and counts[t > 5.0].sum() == 0 and (t > 7.0).any()  # empty messages go on
    imu_tf = next(tf for tf in sim.static_tf if tf.child == "imu_link")
    assert np.allclose(quat_to_rot(imu_tf.quat_xyzw), sc.imu_rotation, atol=1e-12)


def test_blind_figure8_loses_its_landmarks_after_40_s():
    sc = get_scenario("figure8-blind")
    assert sc.duration == 90.0 and sc.detections_until == 40.0


def test_cli_rig_options(tmp_path):
    out = tmp_path / "rig.mcap"
    args = [
        "loop",
        "-o",
        str(out),
        "--duration",
        "2",
        "--imu-rate",
        "20",
        "--landmarks",
        "20",
        "--fov",
        "70",
        "--detections-until",
        "1",
        "--imu-rpy",
        "180",
        "0",
        "0",
    ]
    res = CliRunner().invoke(simulate_cmd, args)
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(simulate_cmd, ["figure8", "-o", str(tmp_path / "x.mcap"), "--landmarks", "99"])
    assert res.exit_code == 2 and "choose 3 to 30" in res.output


def test_a_low_rate_stream_of_interval_means():
    """``sampling="mean"``: each IMU and odometry sample is the mean of the motion over the interval before its stamp
    (a downsampled or integrating stream), the odometry's poses each twist held over that interval; the default is
    the motion at the stamp. Generated in pieces it is the same log."""
    from dataclasses import replace

    from slamobs.pipeline.simulate.sensors import simulation

    sc, rate = get_scenario("figure8"), 4.0
    inst = simulate("figure8", duration=6.0, noise=False, imu_rate=rate, odom_rate=rate)
    mean = simulate("figure8", duration=6.0, noise=False, imu_rate=rate, odom_rate=rate, sampling="mean")
    for stream, read, field in (("odom", "linear", "v"), ("imu", "gyro", "omega")):
        t = (getattr(mean, stream).t_ns - mean.start_ns) * 1e-9
        bias = sc.velocity_bias if stream == "odom" else sc.gyro_bias
        at = getattr(sc.sample(t), field)
        fine = [getattr(sc.sample(t - (j + 0.5) / (200 * rate)), field) for j in range(200)]  # finer than the rule
        avg = np.mean(fine, axis=0)
        assert np.allclose(getattr(getattr(inst, stream), read) - bias, at, atol=1e-12)
        got = getattr(getattr(mean, stream), read) - bias
        assert np.abs(got - avg).max() < 0.02 * np.abs(avg - at).max()  # the mean, not the instant
    t = (mean.odom.t_ns - mean.start_ns) * 1e-9
    o = mean.odom
    rs, ps = integrate_body_twists(np.eye(3), np.zeros(3), o.angular[1:], o.linear[1:], np.diff(t))
    assert np.allclose(ps, o.position, atol=1e-12) and np.allclose(quats_to_rots(o.quat_xyzw), rs, atol=1e-12)
    one = simulation("figure8", duration=5.0, seed=4, noise=False, odom_rate=rate, sampling="mean")
    whole, single = replace(one, piece_s=2.0).whole(), one.whole()
    assert np.allclose(whole.odom.position, single.odom.position, atol=1e-12)
    assert np.allclose(whole.imu.accel, single.imu.accel, atol=1e-12)
    with pytest.raises(ValueError, match="sampling must be one of instant, mean"):
        simulation("figure8", sampling="average")
