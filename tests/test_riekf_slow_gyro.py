"""riekf on a rig whose only angular velocity is slower than its motion (a VIO's twist at 4 Hz on a hand-held
camera): the rotation the linear twist misses between samples, its level (``noise.gyro_unresolved``) and riekf's
gyro level raised to it (docs/benchmarks.md, "riekf's gyro level on a rig whose only angular velocity is slow",
session 33)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np

from slamobs.pipeline.noise_estimation import unresolved_motion_density
from slamobs.pipeline.simulate import NoiseModel, simulate
from slamobs.pipeline.simulate.scenarios import handheld


def _wobble(t: np.ndarray, hz: float) -> np.ndarray:
    """A yaw rate wobbling 0.3 rad at ``hz`` (rad/s), sampled at ``t``, and each axis's white noise of 0.01
    rad/s/sqrt(Hz) at the samples' rate."""
    rng = np.random.default_rng(11)
    w = 2 * np.pi * hz
    rate = np.zeros((t.size, 3))
    rate[:, 2] = 0.3 * w * np.cos(w * t)
    return rate + 0.01 / np.sqrt(t[1] - t[0]) * rng.standard_normal((t.size, 3))


def test_the_rotation_a_slow_gyro_misses_is_measured_where_its_rate_does_not_resolve_it():
    """A 0.6 Hz yaw wobble sampled at 4 Hz: the trapezoid error of the linear twist over each 0.25 s, Δ³ẍ/12, is a
    density of 0.3 ω³ · Δ²/(12 √2) = 0.021 rad/s/sqrt(Hz) on yaw (ẍ's RMS 0.3 ω³/√2, ω = 2π 0.6); the white noise's
    share is taken off, so the other axes read about zero. At 50 Hz the same motion is resolved: 1e-3 of the white
    level."""
    t4, t50 = np.arange(0.0, 300.0, 0.25), np.arange(0.0, 120.0, 0.02)
    slow = unresolved_motion_density(t4, _wobble(t4, 0.6), 0.01)
    w = 2 * np.pi * 0.6
    expected = 0.3 * w**3 * 0.25**2 / (12 * np.sqrt(2)) * np.sqrt(0.25)
    assert abs(slow.value[2] / expected - 1) < 0.1, (slow.value, expected)
    assert np.all(slow.value[:2] < 0.2 * expected), slow.value
    assert "Δ³ẍ/12" in slow.method and np.all(slow.uncertainty < 0.1 * expected)
    fast = unresolved_motion_density(t50, _wobble(t50, 0.6), 0.01)
    assert np.all(fast.value < 1e-3), fast.value


def test_riekf_on_a_4_hz_gyro_weighs_the_rotation_it_misses_not_the_white_level(tmp_path):
    """The hand-held rig (``scenarios.handheld``) with its IMU and odometry both at 4 Hz (a VIO's twist its only angular
    velocity, benchmarks/odometry_rate.py --slow-gyro, seed=3305's rig): weighing the twist at its white level, riekf
    believed an attitude the 4 Hz samples cannot give and carried the map off with it (0.26-5.5 m APE on 21 such logs,
    against fast-adaptation's 0.4-0.6); with the gyro level raised to the rotation the linear twist misses it keeps the
    track and says so."""
    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import write_log

    nm = replace(
        NoiseModel(),
        gyro=30 * DEFAULTS["gyro"][0] * np.sqrt(4.0),
        odom_linear=10 * DEFAULTS["velocity"][0] * np.sqrt(4.0),
        detection_base=0.03,
        detection_per_m=0.006,
    )
    sim = simulate(handheld(), noise=nm, duration=60.0, seed=3305, imu_rate=4.0, odom_rate=4.0, detection_rate=15.0)
    write_log(replace(sim, noise=replace(nm, gyro=0.0, odom_linear=0.0)), tmp_path / "walker.mcap", overwrite=True)

    def run(name: str, noise: dict) -> tuple[dict, float]:
        config = {"evaluation": {"plots": False}, **({"noise": noise} if noise else {})}
        run_log(tmp_path / "walker.mcap", tmp_path / name, observer="riekf", config=config, force=True)
        meta = json.loads((tmp_path / name / "run.json").read_text())
        report = json.loads((tmp_path / name / "report.json").read_text())
        return meta, report["ape"]["translation_m"]["rmse"]

    meta, ape = run("auto", {})
    f = meta["observer"]["filter"]
    levels = f["noise"]["levels"]
    missed, used = np.array(levels["gyro_unresolved"]["value"]), np.array(f["noise"]["gyro"])
    assert missed[2] > 2 * max(missed[:2]) and "Δ³ẍ/12" in levels["gyro_unresolved"]["method"], levels
    assert "gyro_unresolved" in levels["gyro"]["method"] and used[2] > 1.5 * used[0], levels["gyro"]
    assert any("does not resolve its motion on z" in n for n in meta["notes"]), meta["notes"]
    # the same run with the white level given (no level added to a configured one): the track lost
    estimated = float(np.sqrt(np.mean(np.square(used[:2]))))
    base_meta, base = run("white", {"gyro": estimated})
    assert "gyro_unresolved" not in base_meta["observer"]["filter"]["noise"]["levels"]
    assert ape < 0.3 and base > 3 * ape, (ape, base)
