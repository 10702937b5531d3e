"""``slamobs info``'s readiness section and ``run``'s error naming every missing input, on short simulated logs
with streams left out (and the real logs when ``$SLAMOBS_REALDATA`` has them)."""

from __future__ import annotations

import dataclasses
import json
import re

import pytest

from slamobs.pipeline.config import load_config
from slamobs.pipeline.estimators import ESTIMATORS
from slamobs.pipeline.readers import inspect_log
from slamobs.pipeline.readers.roles import accepted_types
from slamobs.pipeline.readiness import readiness
from slamobs.pipeline.simulate.logwriter import write_log
from slamobs.pipeline.simulate.sensors import simulate

from cli_checks import SAMPLES, invoke
from realdata import REALDATA


def _empty(data):
    """A simulated stream with no samples: its topic is written without messages."""
    return dataclasses.replace(
        data, **{f.name: getattr(data, f.name)[: 1 if f.name == "offsets" else 0] for f in dataclasses.fields(data)}
    )


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Short circle logs: complete, without odometry and detections, without the magnetometer."""
    sim = simulate("circle", duration=4.0, seed=3)
    root = tmp_path_factory.mktemp("readiness")
    made = {
        "full": sim,
        "no_odom_det": dataclasses.replace(sim, odom=_empty(sim.odom), detections=_empty(sim.detections)),
        "no_mag": dataclasses.replace(sim, mag=_empty(sim.mag)),
    }
    paths = {}
    for name, log in made.items():
        paths[name] = root / f"{name}.mcap"
        write_log(log, paths[name])
    return paths


def _run_yaml(out: str) -> str:
    """The run.yaml block ``info`` prints, unindented."""
    block = out.split("run.yaml for what was found:\n", 1)[1]
    return "\n".join(line[4:] for line in block.splitlines()) + "\n"


def test_complete_log_is_ready_and_its_run_yaml_runs(logs, tmp_path):
    res = invoke("info", logs["full"])
    assert res.exit_code == 0
    assert "MISSING" not in res.output.split("  readiness", 1)[1]
    ready = readiness(inspect_log(logs["full"]))
    assert all(e.ready or e.unavailable for e in ready.estimators)
    config = tmp_path / "run.yaml"
    config.write_text(_run_yaml(res.output))
    loaded = load_config(config)
    assert loaded.topics["linear_velocity"] == "/odom"
    assert loaded.topics["detections"] == "/fiducial_transforms"
    run = invoke("run", logs["full"], "--config", config, "-o", tmp_path / "out", "-q")
    assert run.exit_code == 0, run.output
    assert (tmp_path / "out" / "poses.parquet").is_file()


def test_missing_roles_are_named_with_every_accepted_type(logs, tmp_path):
    ready = readiness(inspect_log(logs["no_odom_det"]))
    assert {r.role for r in ready.roles if not r.found} == {"linear_velocity", "detections"}
    assert not any(e.ready for e in ready.estimators)
    res = invoke("info", logs["no_odom_det"])
    section = res.output.split("  readiness", 1)[1]
    assert "linear_velocity   MISSING" in section and "detections        MISSING" in section
    for role in ("linear_velocity", "detections"):
        assert f"topics.{role}" in section
        for msgtype in accepted_types(role):
            assert msgtype in section, msgtype
    assert "tags.size" in section and "frames.tag_pattern" in section
    config = tmp_path / "run.yaml"
    config.write_text(_run_yaml(res.output))
    assert "linear_velocity" not in load_config(config).topics  # a comment, not a key
    doc = json.loads(invoke("info", logs["no_odom_det"], "--json").stdout)["readiness"]
    assert doc["ready"] == [] and set(doc["satisfy"]) == {"linear_velocity", "detections"}


def test_info_noise_on_a_log_that_cannot_run_shows_its_sensors_own_levels(logs, tmp_path):
    """An IMU-only log (no velocity, no detections): `info --noise` refused with run's error (exit 2) and showed no
    level, though the gyro's and accelerometer's own noise is in the log. It now shows each sensor stream's
    white-noise density (near the generated one), says what cannot be estimated and why, and exits 0; a log with
    no sensor stream at all still exits 2 with the error."""
    import numpy as np

    res = invoke("info", "--noise", logs["no_odom_det"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    gyro = next(line for line in lines if line.strip().startswith("gyro = "))
    assert "/imu/data" in gyro and "rad/s/sqrt(Hz)" in gyro, gyro
    assert any(line.strip().startswith("accelerometer = ") and "m/s^2/sqrt(Hz)" in line for line in lines), lines
    assert any("velocity: not estimated (no linear_velocity stream)" in line for line in lines), lines
    said = next(line for line in lines if "not estimated: the detection levels" in line)
    assert "2 of the 3 inputs" in said and "linear_velocity" in said and "detections" in said, said
    doc = json.loads(invoke("info", "--noise", "--json", logs["no_odom_det"]).stdout)
    sim = simulate("circle", duration=4.0, seed=3)  # the fixture's
    expected = sim.noise.gyro * np.sqrt(1.0 / 200.0)  # the generated density at the IMU's rate
    assert np.allclose(doc["sensors"]["gyro"]["value"], expected, rtol=0.3), (doc["sensors"]["gyro"], expected)
    bare = dataclasses.replace(
        sim, imu=_empty(sim.imu), odom=_empty(sim.odom), detections=_empty(sim.detections), mag=_empty(sim.mag)
    )
    res = invoke("info", "--noise", write_log(bare, tmp_path / "bare.mcap"))
    assert res.exit_code == 2 and "cannot run" in res.output, res.output


def test_info_noise_gives_the_magnetometer_level_from_its_finite_samples(logs, tmp_path):
    """``info --noise`` showed no magnetometer line at all (imu_tools' phidgets_imu_upside_down.bag: 6990 of its
    13964 /imu/mag messages NaN). It now gives the magnetometer's density from the finite samples (every other one
    NaN here: near the generated level at half the rate), and when too few are left, one line saying why, with
    the reader's note of the NaN samples dropped."""
    import numpy as np

    sim = simulate("circle", duration=4.0, seed=3)  # the fixture's: magnetometer at 50 Hz
    field = sim.mag.field.copy()
    field[1::2] = np.nan
    half = dataclasses.replace(sim, odom=_empty(sim.odom), detections=_empty(sim.detections))
    half = dataclasses.replace(half, mag=dataclasses.replace(sim.mag, field=field))
    path = write_log(half, tmp_path / "half_nan_mag.mcap")
    res = invoke("info", "--noise", path)
    assert res.exit_code == 0, res.output
    line = next((x for x in res.output.splitlines() if x.strip().startswith("magnetometer = ")), None)
    assert line is not None and "/imu/mag" in line and "T/sqrt(Hz)" in line, res.output
    level = json.loads(invoke("info", "--noise", "--json", path).stdout)["sensors"]["magnetometer"]
    expected = sim.noise.mag * np.sqrt(2.0 / 50.0)  # the generated density at the finite samples' rate, 25 Hz
    assert np.allclose(level["value"], expected, rtol=0.3), (level, expected)
    field[40:] = np.nan  # 20 finite samples left: too few for a level
    few = dataclasses.replace(half, mag=dataclasses.replace(sim.mag, field=field))
    res = invoke("info", "--noise", write_log(few, tmp_path / "few_mag.mcap"))
    assert res.exit_code == 0, res.output
    dropped = len(field) - 20
    said = f"magnetometer: not estimated (too few consecutive samples on /imu/mag (20 read; /imu/mag: {dropped} NaN"
    assert any(x.strip().startswith(said) for x in res.output.splitlines()), res.output


def test_info_noise_says_a_magnetometer_that_holds_its_values_shows_no_noise(logs, tmp_path):
    """imu_tools' sparkfun_razor.bag: /imu/mag repeats its value for ~20 of its 69 Hz messages (103 distinct values
    in 2144), so the quintic residuals are zero and `info --noise` printed "magnetometer = 7.939e-22 ... T/sqrt(Hz)".
    A stream whose every axis holds its values gives no level, and the line says why (the run's words for such a
    stream); the gyro's level beside it is given as before."""
    import numpy as np

    sim = simulate("circle", duration=4.0, seed=3)  # the fixture's: magnetometer at 50 Hz
    held = sim.mag.field[(np.arange(len(sim.mag.field)) // 10) * 10]  # each value held for 10 messages
    log = dataclasses.replace(sim, odom=_empty(sim.odom), detections=_empty(sim.detections))
    path = write_log(dataclasses.replace(log, mag=dataclasses.replace(sim.mag, field=held)), tmp_path / "held.mcap")
    res = invoke("info", "--noise", path)
    assert res.exit_code == 0, res.output
    lines = [x.strip() for x in res.output.splitlines()]
    said = "magnetometer: not estimated (the samples on /imu/mag hold their values (commanded or quantised"
    assert any(x.startswith(said) for x in lines), res.output
    assert any(x.startswith("gyro = ") for x in lines), res.output
    doc = json.loads(invoke("info", "--noise", "--json", path).stdout)["sensors"]["magnetometer"]
    assert "value" not in doc and "hold their values" in doc["why"], doc


def test_run_names_every_missing_role_at_once(logs, tmp_path):
    res = invoke("run", logs["no_odom_det"], "-o", tmp_path / "out")
    assert res.exit_code == 2
    lines = res.output.splitlines()
    first = next(k for k, line in enumerate(lines) if line.startswith("error:"))
    assert "cannot run" in lines[first] and "2 of the 3" in lines[first]
    roles = [line.split()[0] for line in lines[first + 1 :]]
    assert roles == ["linear_velocity", "detections"]
    assert "nav_msgs/msg/Odometry" in lines[first + 1]
    assert not (tmp_path / "out").exists()
    # the error names the estimator that needs them (it said "the estimator", with no name given or defaulted)
    assert "2 of the 3 inputs needed by fast-adaptation are missing" in lines[first]
    res = invoke("run", logs["no_mag"], "-o", tmp_path / "out", "--observer", "hashim-imu")
    assert res.exit_code == 2 and "1 of the 5 inputs needed by hashim-imu is missing (magnetic)" in res.output


def test_direction_needs_per_estimator(logs):
    ready = readiness(inspect_log(logs["no_mag"]))
    lacking = {e.name: e.missing for e in ready.estimators if not e.unavailable}
    needs_two = {n for n, s in ESTIMATORS.items() if s.min_directions >= 2}
    assert needs_two  # hashim-imu and hybrid
    for name, missing in lacking.items():
        assert missing == (("magnetic",) if name in needs_two else ()), name


def test_tag_corners_log_asks_for_the_tag_size(tmp_path):
    res = invoke("info", SAMPLES / "figure8_camera.mcap")
    yaml_text = _run_yaml(res.output)
    assert "#   size:" in yaml_text
    config = tmp_path / "run.yaml"
    config.write_text(yaml_text)
    assert load_config(config).tags.size is None


REAL_LOGS = ("robot_localization/test1.bag", "imu_tools/ardrone_imu.bag", "fiducials_ubiquity/transforms.bag")


@pytest.mark.skipif(not REALDATA.is_dir(), reason="real logs not available ($SLAMOBS_REALDATA)")
@pytest.mark.parametrize("name", REAL_LOGS)
def test_real_logs_readiness(name, tmp_path):
    log = REALDATA / name
    if not log.exists():
        pytest.skip(f"{log} not available")
    res = invoke("info", log)
    assert res.exit_code == 0
    section = res.output.split("  readiness", 1)[1]
    assert "cannot run, missing" in section  # none of these has all three inputs
    config = tmp_path / "run.yaml"
    config.write_text(_run_yaml(res.output))
    load_config(config)


def test_run_names_a_missing_direction_with_the_other_inputs(logs, tmp_path):
    needs_two = next(n for n, s in ESTIMATORS.items() if s.min_directions >= 2)
    res = invoke("run", logs["no_mag"], "-o", tmp_path / "out", "--observer", needs_two)
    assert res.exit_code == 2
    lines = res.output.splitlines()
    first = next(k for k, line in enumerate(lines) if line.startswith("error:"))
    assert "1 of the 5 inputs" in lines[first] and "(magnetic)" in lines[first]
    assert lines[first + 1].split()[0] == "magnetic" and "sensor_msgs/msg/MagneticField" in lines[first + 1]


def test_corners_without_camera_info_are_ready_only_with_the_settings_run_asks_for():
    """A TagSLAM-style log (corners, VIO odometry, no CameraInfo, no simulator record) has every input, but `run`
    stops until the config gives the tag size and the camera files: info says so instead of a bare "ready"; a log
    with CameraInfo needs the tag size only, one that records it (the simulator's) nothing."""
    from slamobs.pipeline.readers.inspect import LogInfo, TopicSummary

    topics = (
        TopicSummary("/odom", "nav_msgs/msg/Odometry", 100, rate_hz=20.0),
        TopicSummary("/tags", "apriltag_msgs/msg/ApriltagArrayStamped", 100, rate_hz=20.0),
        TopicSummary("/camera_info", "sensor_msgs/msg/CameraInfo", 100, rate_hz=20.0),
    )
    roles = {"angular_velocity": "/odom", "linear_velocity": "/odom", "detections": "/tags"}

    def needs(**extra):
        info = LogInfo("x.bag", "ros1", "", 0, 1, 300, topics, {**roles, **extra})
        return {e.needs for e in readiness(info).estimators if not e.missing}

    assert needs() == {("tags.size", "cameras: (calibration files; the log has no CameraInfo topic)")}
    assert needs(camera_info="/camera_info") == {("tags.size",)}
    assert needs(camera_info="/camera_info", sim_truth="/slamobs/sim_truth") == {()}
    text = invoke("info", SAMPLES / "figure8.mcap").output
    assert "ready once" not in text and ": ready" in text  # 3D tag poses: nothing more to give


def test_the_run_yaml_of_corners_without_camera_info_names_the_camera_files():
    """TagSLAM test_21: info said "ready once the config gives tags.size and cameras" and its run.yaml had a
    commented tags.size but no cameras line; with four cameras the run then stopped twice on their extrinsics.
    The run.yaml now shows the key, for a rig with the files that place each camera; it stays valid YAML."""
    import yaml

    from slamobs.pipeline.readers.inspect import LogInfo, TopicSummary

    def run_yaml(detections: str, **extra) -> str:
        topics = tuple(
            TopicSummary(t, "apriltag_msgs/msg/ApriltagArrayStamped", 100, rate_hz=20.0) for t in detections.split(", ")
        ) + (TopicSummary("/odom", "nav_msgs/msg/Odometry", 100, rate_hz=20.0),)
        roles = {"angular_velocity": "/odom", "linear_velocity": "/odom", "detections": detections, **extra}
        return readiness(LogInfo("x.bag", "ros1", "", 0, 1, 300, topics, roles)).run_yaml

    one, rig = run_yaml("/tags"), run_yaml("/left/tags, /right/tags")
    assert "# cameras: <Kalibr camchain or ROS camera_info YAML>" in one.splitlines()
    assert "# cameras:" in rig.splitlines() and "camera_poses.yaml" in rig and "T_body_odom" in rig
    assert yaml.safe_load(rig)["topics"]["detections"] == ["/left/tags", "/right/tags"]
    assert "cameras" not in run_yaml("/tags", camera_info="/camera_info")  # a CameraInfo topic: nothing to give


def test_a_role_whose_topic_is_empty_names_that_topic(logs, tmp_path):
    """A detections topic recorded without messages is named, by ``info`` and by ``run`` when the config names
    it (both said only "missing: set topics.detections to ..." as if the log had no such topic)."""
    ready = readiness(inspect_log(logs["no_odom_det"]))
    assert any("no messages on: /fiducial_transforms (" in w for w in ready.satisfy["detections"])
    assert any("no messages on: /odom (nav_msgs/msg/Odometry)" in w for w in ready.satisfy["linear_velocity"])
    config = tmp_path / "run.yaml"
    config.write_text("topics:\n  detections: /fiducial_transforms\n")
    res = invoke("run", logs["no_odom_det"], "--config", config, "-o", tmp_path / "out")
    assert res.exit_code == 2
    detail = next(line for line in res.output.splitlines() if line.lstrip().startswith("detections ("))
    assert "/fiducial_transforms has no samples" in detail
    assert not (tmp_path / "out").exists()


def test_a_run_without_config_names_the_topics_recorded_empty(logs, tmp_path):
    """A log whose only detections topic was recorded empty (a camera that never published): `run` without a
    config said only "set topics.detections to a topic of type fiducial_msgs/msg/FiducialTransformArray, ..." though
    the log has one of that type; `info` named it, the run's error did not. Each missing role's line names it now."""
    res = invoke("run", logs["no_odom_det"], "-o", tmp_path / "out")
    assert res.exit_code == 2
    lines = res.output.splitlines()
    detections = next(line for line in lines if line.lstrip().startswith("detections ("))
    velocity = next(line for line in lines if line.lstrip().startswith("linear_velocity ("))
    assert "/fiducial_transforms (fiducial_msgs/msg/FiducialTransformArray) has no messages in this log" in detections
    assert "/odom (nav_msgs/msg/Odometry) has no messages in this log" in velocity
    assert not (tmp_path / "out").exists()


def test_the_verdict_says_when_every_ready_estimator_still_needs_settings():
    """TagSLAM test_22: "readiness: 5 of 7 estimators can run" while `run` without a config stopped on the
    camera intrinsics; the verdict now names what the config must give (and stays bare when nothing is needed)."""
    from slamobs.cli.info_cmd import format_readiness
    from slamobs.pipeline.readers.inspect import LogInfo, TopicSummary

    topics = (
        TopicSummary("/odom", "nav_msgs/msg/Odometry", 100, rate_hz=20.0),
        TopicSummary("/tags", "apriltag_msgs/msg/ApriltagArrayStamped", 100, rate_hz=20.0),
    )
    roles = {"angular_velocity": "/odom", "linear_velocity": "/odom", "detections": "/tags"}
    first = format_readiness(readiness(LogInfo("x.bag", "ros1", "", 0, 1, 300, topics, roles))).splitlines()[0]
    assert first == "  readiness: 5 of 7 estimators can run once the config gives tags.size and cameras"
    text = invoke("info", SAMPLES / "figure8.mcap").output
    assert "estimators can run\n" in text


def test_a_mistyped_topic_names_the_nearest_one(logs, tmp_path):
    """``topics.linear_velocity: /odm`` listed every topic; it now says which one was probably meant (and one line,
    exit 2, nothing written, as before)."""
    config = tmp_path / "run.yaml"
    config.write_text("topics:\n  linear_velocity: /odm\n")
    res = invoke("run", logs["full"], "--config", config, "-o", tmp_path / "out")
    assert res.exit_code == 2 and len(res.output.strip().splitlines()) == 1
    assert "[/odm]: topic for role linear_velocity is not in the log (did you mean /odom? topics: " in res.output
    assert not (tmp_path / "out").exists()


def test_the_nearest_topic_is_one_of_the_roles_types():
    """MR.CLAM with ``topics.angular_velocity: /robot1/odom`` was asked 'did you mean /robot1/landmarks?' (the
    nearest name, a detection topic the role refuses); the nearest of the role's types comes first."""
    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.readers.roles import TopicMeta, select_roles

    topics = {
        "/robot1/landmarks": TopicMeta("fiducial_msgs/msg/FiducialTransformArray", 10),
        "/robot1/velocity": TopicMeta("geometry_msgs/msg/TwistStamped", 10),
    }
    with pytest.raises(InputError, match=r"did you mean /robot1/velocity\?"):
        select_roles(topics, {"angular_velocity": "/robot1/odom"})
    with pytest.raises(InputError, match=r"did you mean /robot1/landmarks\?"):  # no fitting name: the nearest
        select_roles(topics, {"angular_velocity": "/robot1/landmark"})


def test_info_with_a_config_does_not_ask_for_what_it_gives():
    """TagSLAM test_11 with its config (tags.size, cameras): `info --config` still said "ready once the config gives
    tags.size and cameras" (the config was read with --noise only)."""
    from slamobs.cli.info_cmd import format_readiness
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.readers.inspect import LogInfo, TopicSummary

    topics = (
        TopicSummary("/odom", "nav_msgs/msg/Odometry", 100, rate_hz=20.0),
        TopicSummary("/tags", "apriltag_msgs/msg/ApriltagArrayStamped", 100, rate_hz=20.0),
    )
    roles = {"angular_velocity": "/odom", "linear_velocity": "/odom", "detections": "/tags"}
    info = LogInfo("x.bag", "ros1", "", 0, 1, 300, topics, roles)
    first = lambda config: format_readiness(readiness(info, config)).splitlines()[0]  # noqa: E731
    assert first(parse_config({"tags": {"size": 0.15}})) == (
        "  readiness: 5 of 7 estimators can run once the config gives cameras"
    )
    assert first(parse_config({"tags": {"sizes": {3: 0.1}}, "cameras": ["cameras.yaml"]})) == (
        "  readiness: 5 of 7 estimators can run"
    )
    assert first(None).endswith("once the config gives tags.size and cameras")


def test_info_noise_names_an_imu_frame_turned_against_the_odometry_before_a_config_takes_it_as_body(tmp_path):
    """robot_localization's test1: IMU and wheel odometry, no detections, no TF; `info` says to list the IMU's frame
    in frames.assume_identity if it is the body's, but that IMU reads its yaw rate on y. A generated ground log so
    (its IMU rolled 90 deg, its /tf_static edge and its detections left out): `info --noise` now says the gyro, taken
    as read, turns 90 deg off the odometry's own angular velocity; with the edge kept it says nothing."""
    from slamobs.pipeline.simulate.scenarios import customize, get_scenario

    sim = simulate(customize(get_scenario("figure8"), imu_rpy_deg=(90.0, 0.0, 0.0)), seed=5, duration=20.0)
    sim = dataclasses.replace(sim, detections=_empty(sim.detections))
    untold = dataclasses.replace(sim, static_tf=[t for t in sim.static_tf if t.child != "imu_link"])
    res = invoke("info", "--noise", write_log(untold, tmp_path / "untold.mcap"))
    assert res.exit_code == 0, res.output
    said = [line.strip() for line in res.output.splitlines() if "its gyro turns about" in line]
    assert len(said) == 1 and said[0].startswith("warning: /imu/data: taken as the body 'base_link' as read"), said
    assert "90 deg apart" in said[0] and "frames.assume_identity would read its axes wrong" in said[0], said
    doc = json.loads(invoke("info", "--noise", "--json", tmp_path / "untold.mcap").stdout)
    assert doc["checks"][0] == said[0] and len(doc["checks"]) == 2, doc["checks"]  # and its gravity, on y
    assert "its accelerometer's mean (gravity's reaction" in doc["checks"][1], doc["checks"]
    res = invoke("info", "--noise", write_log(sim, tmp_path / "told.mcap"))
    assert res.exit_code == 0 and "its gyro turns about" not in res.output, res.output


def test_info_noise_names_an_imu_frame_upside_down_by_its_gravity_where_no_odometry_turns(tmp_path):
    """imu_tools' Phidgets sample: an IMU mounted upside down, no odometry, no TF. `info` says to list its frame in
    frames.assume_identity only if it is mounted as the body and that `info --noise` checks it, but that check held
    the gyro against an odometry's turn, which this log lacks: `info --noise` said nothing. A generated log so (its IMU
    rolled 180 deg, its /tf_static edge, odometry and detections left out): the accelerometer's gravity, along the
    frame's -z, is named; with the edge kept, or the IMU mounted upright, nothing."""
    from slamobs.pipeline.simulate.scenarios import customize, get_scenario

    def imu_only(rpy, keep_edge):
        sim = simulate(customize(get_scenario("figure8"), imu_rpy_deg=rpy), seed=5, duration=20.0)
        sim = dataclasses.replace(sim, detections=_empty(sim.detections), odom=_empty(sim.odom))
        edges = [t for t in sim.static_tf if keep_edge or t.child != "imu_link"]
        return dataclasses.replace(sim, static_tf=edges)

    def said(sim, name):
        res = invoke("info", "--noise", write_log(sim, tmp_path / name))
        assert res.exit_code == 0, res.output
        return [line.strip() for line in res.output.splitlines() if "accelerometer's mean" in line]

    got = said(imu_only((180.0, 0.0, 0.0), False), "upside_down.mcap")
    assert len(got) == 1 and got[0].startswith("warning: /imu/data: taken as the body 'base_link' as read"), got
    assert "from the body's up axis (+z; upside down)" in got[0], got
    assert "frames.assume_identity would read its axes wrong" in got[0], got
    assert not said(imu_only((180.0, 0.0, 0.0), True), "told.mcap")
    assert not said(imu_only((0.0, 0.0, 0.0), False), "upright.mcap")


def test_info_noise_on_a_log_that_cannot_run_says_the_covariance_its_messages_state(logs):
    """robot_localization's test1 (IMU and odometry, no detections): `info --noise` showed the samples' gyro level,
    0.0019 rad/s/sqrt(Hz), and nothing of the 0.0037 its messages state, which riekf and batch would use. Each
    stream's stated covariance is now a line under its level, with whether a run would use it (JSON: ``stated``)."""
    res = invoke("info", "--noise", logs["no_odom_det"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    k = next(k for k, line in enumerate(lines) if line.strip().startswith("gyro = "))
    assert lines[k + 1].strip().startswith("its messages state /imu/data covariance ("), lines[k + 1]
    assert "riekf and batch would use it in place of the level above" in lines[k + 1], lines[k + 1]
    doc = json.loads(invoke("info", "--noise", "--json", logs["no_odom_det"]).stdout)
    stated = doc["sensors"]["gyro"]["stated"]
    assert stated["used"] is True and stated["topic"] == "/imu/data" and len(stated["value"]) == 3, stated


def test_info_noise_labels_its_rates_as_the_median_intervals_not_the_topic_tables(logs):
    """robot_localization's test1: `info --noise` gave the odometry's level `at 10.09 Hz` (one over the median
    interval) and its topic table 9.99 Hz (stamps over the time recorded), one word for two definitions. Every rate
    the noise lines print now says which it is, the level's and the stated covariance's alike."""
    res = invoke("info", "--noise", logs["no_odom_det"])
    assert res.exit_code == 0, res.output
    lines = [x.strip() for x in res.output.splitlines()]
    gyro = next(k for k, line in enumerate(lines) if line.startswith("gyro = "))
    assert "(MAD) at " in lines[gyro] and " Hz by the median interval" in lines[gyro], lines[gyro]
    assert lines[gyro + 1].startswith("its messages state /imu/data covariance ("), lines[gyro + 1]
    assert " Hz by the median interval) = " in lines[gyro + 1], lines[gyro + 1]
    assert not re.search(r"\d Hz[);]", "\n".join(lines[gyro : gyro + 2])), lines[gyro : gyro + 2]


def test_info_says_what_a_log_of_poses_only_is_good_for(logs, tmp_path):
    """evo's ROS_example.bag (three PoseStamped trajectories, no velocities): `run` ended its error with "its poses
    (groundtruth) are a trajectory: `slamobs evaluate LOG:groundtruth EST` ...", but `info`, which a user runs
    first, listed 30 lines of message types for the inputs and not that. Its readiness now says it, in the same
    words, naming another pose topic of the log as an EST; a log with velocities does not get the line."""
    sim = simulate("circle", duration=4.0, seed=3)
    poses = dataclasses.replace(
        sim, imu=_empty(sim.imu), odom=_empty(sim.odom), detections=_empty(sim.detections), mag=_empty(sim.mag)
    )
    path = write_log(poses, tmp_path / "poses.mcap")
    info = inspect_log(path)
    truth = info.roles["truth"]
    said = f"its poses ({truth}) are a trajectory: `slamobs evaluate {path}:{truth} EST` measures another's error"
    assert readiness(info).trajectory == said
    res = invoke("info", path)
    assert res.exit_code == 0 and f"    {said}" in res.output.splitlines(), res.output
    run = invoke("run", path, "-o", tmp_path / "out")
    assert run.exit_code == 2 and said in run.output, run.output  # run's error: the same words
    summary = next(t for t in info.topics if t.topic == truth)
    other = dataclasses.replace(summary, topic="/orb_slam/pose")
    two = dataclasses.replace(info, topics=(*info.topics, other))
    assert readiness(two).trajectory == f"{said} (EST: e.g. {path}:/orb_slam/pose, another pose topic of this log)"
    assert readiness(inspect_log(logs["full"])).trajectory == ""


def test_a_log_of_an_imu_and_its_truth_says_the_truth_is_a_trajectory_in_run_and_info(tmp_path):
    """ETH's dataset.bag (round 26, h-newuser12): an IMU and a Vicon truth, no linear velocity. `run`'s error named
    the missing roles but not what evo's ROS_example.bag is told, that its truth is a trajectory `slamobs evaluate`
    measures another against, though the log runs no estimator either; `info` did not say it. One rule now
    (``roles.trajectory_use``: a motion role missing), the same words in both."""
    sim = simulate("circle", duration=4.0, seed=3)
    imu = dataclasses.replace(sim, odom=_empty(sim.odom), detections=_empty(sim.detections))
    path = write_log(imu, tmp_path / "imu.mcap")
    info = inspect_log(path)
    truth = info.roles["truth"]
    said = f"its poses ({truth}) are a trajectory: `slamobs evaluate {path}:{truth} EST` measures another's error"
    assert readiness(info).trajectory == said
    run = invoke("run", path, "-o", tmp_path / "out")
    assert run.exit_code == 2 and said in run.output, run.output
