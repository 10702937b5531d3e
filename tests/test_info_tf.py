"""``slamobs info``'s TF section on short simulated logs: the /tf_static tree (alike tag frames on one line), the body
frame a run takes, each sensor frame's transform into it (the camera extrinsic named), and a missing one named with
what to set, as ``run`` then stops on it."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from slamobs.pipeline.simulate.logwriter import write_log
from slamobs.pipeline.simulate.sensors import simulate
from slamobs.pipeline.streams import Transform

from cli_checks import invoke


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A 3 s circle with its extrinsics and twelve surveyed tag frames on /tf_static; one without the camera's."""
    sim = simulate("circle", duration=3.0, seed=5)
    tags = [Transform("map", f"tag_{k}", np.array([k, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])) for k in range(12)]
    root = tmp_path_factory.mktemp("info_tf")
    made = {
        "full": dataclasses.replace(sim, static_tf=[*sim.static_tf, *tags]),
        "no_camera": dataclasses.replace(sim, static_tf=[t for t in sim.static_tf if t.child != "camera"]),
    }
    paths = {}
    for name, log in made.items():
        paths[name] = root / f"{name}.mcap"
        write_log(log, paths[name])
    return paths


def _section(out: str) -> str:
    return out.split("  TF frames", 1)[1].split("  readiness", 1)[0]


def test_info_draws_the_tf_tree_and_names_the_camera_extrinsic(logs):
    res = invoke("info", logs["full"])
    assert res.exit_code == 0, res.output
    tf = _section(res.output)
    assert "(14 static edges, 0 time-stamped edges; parent -> child)" in tf
    assert "├─ camera  static  <- detections" in tf
    assert "tag_0 .. tag_11 (12 frames)  static" in tf  # one line, not twelve
    assert "tag_5" not in tf
    assert "frames into the body 'base_link' (the child frame of /odom" in tf
    assert "'camera' -> 'base_link': the camera extrinsic, static base_link->camera (/tf_static), turned" in tf
    tree = json.loads(invoke("info", "--json", logs["full"]).output)["tf"]
    assert len(tree["edges"]) == 14  # the JSON lists every edge
    assert {s["role"]: s["how"] for s in tree["sensors"]}["detections"] == "static"


def test_info_names_a_missing_camera_extrinsic_as_run_stops_on_it(logs, tmp_path):
    tf = _section(invoke("info", logs["no_camera"]).output)
    assert "'camera' -> 'base_link' MISSING ('camera' is in no transform" in tf
    assert "list 'camera' in frames.assume_identity" in tf
    run = invoke("run", logs["no_camera"], "-o", tmp_path / "out")
    assert run.exit_code == 2
    assert "no transform from frame 'camera' to body frame 'base_link'" in run.output
    config = tmp_path / "run.yaml"
    config.write_text("frames:\n  assume_identity: [camera]\n  override_identity: [imu_link]\n")
    tf = _section(invoke("info", logs["no_camera"], "--config", config).output)
    assert "'camera' taken as the body (frames.assume_identity" in tf
    assert "'imu_link' taken as the body (frames.override_identity" in tf


def test_info_does_not_advise_taking_an_imu_frame_without_a_transform_as_the_body(tmp_path):
    """robot_localization's test1: 'imu_link' has no transform, and `info` (which reads no samples) said to list it
    in frames.assume_identity "if it is the body's frame"; that IMU is turned 90 deg (its yaw rate on y), so the
    advice read its axes wrong. The advice now points to the check that can tell (`info --noise`); a camera's keeps
    its words."""
    sim = simulate("circle", duration=3.0, seed=5)
    log = write_log(
        dataclasses.replace(sim, static_tf=[t for t in sim.static_tf if t.child != "imu_link"]), tmp_path / "x.mcap"
    )
    line = next(
        x for x in _section(invoke("info", log).output).splitlines() if "'imu_link' -> 'base_link' MISSING" in x
    )
    assert "frames.assume_identity if it is the body's frame" not in line, line
    assert "frames.assume_identity only if it is mounted as the body, axes and all" in line, line
    assert "slamobs info --noise LOG warns when its gyro turns about another axis" in line, line
    assert "or its accelerometer's gravity is not along the body's up axis" in line, line
