"""riekf's innovation deviance (run.json ``observer.filter.likelihood``, issue 23): the prediction-error
decomposition's −2 log-likelihood over the known-landmark detections (``log det S + d²``, a gated detection's d² at
the gate), lower at the levels the log was drawn with than at levels its messages state ten times too loud."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from slamobs.pipeline.noise import DEFAULTS
from slamobs.pipeline.simulate import NoiseModel, get_scenario, simulate, write_log

RATE = 100.0
GYRO, VELOCITY = 10 * DEFAULTS["gyro"][0], 10 * DEFAULTS["velocity"][0]  # densities drawn with
LAW = {"detection": 0.01, "detection_per_m": 0.002, "detection_per_m2": 0.0, "detection_ratio": 1.0}


@pytest.fixture(scope="module")
def tenfold(tmp_path_factory):
    """A 40 s circle whose IMU and odometry state ten times the density they are drawn with."""
    nm = replace(
        NoiseModel(),
        gyro=GYRO * np.sqrt(RATE),
        odom_linear=VELOCITY * np.sqrt(RATE),
        detection_base=LAW["detection"],
        detection_per_m=LAW["detection_per_m"],
    )
    sim = simulate(get_scenario("circle"), noise=nm, duration=40.0, seed=3320, imu_rate=RATE, odom_rate=RATE)
    log = tmp_path_factory.mktemp("tenfold") / "tenfold.mcap"
    write_log(replace(sim, noise=replace(nm, gyro=10 * nm.gyro, odom_linear=10 * nm.odom_linear)), log)
    return log


def _filter(log, out, noise: dict | None) -> dict:
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import run_log

    cfg = {"observer": "riekf", "evaluation": {"plots": False}, **({"noise": noise} if noise else {})}
    run_log(log, out, parse_config(cfg))
    return json.loads((out / "run.json").read_text())["observer"]["filter"]


def test_the_deviance_is_lowest_at_the_levels_the_log_was_drawn_with(tenfold, tmp_path):
    auto = _filter(tenfold, tmp_path / "auto", None)  # riekf weighs the stated levels against the samples'
    assert auto["stated_levels"]["tried"][0]["levels"] == {"gyro": "stated", "velocity": "stated"}, auto
    assert auto["stated_levels"]["used"] == {"gyro": "samples", "velocity": "samples"}, auto["stated_levels"]
    stated = _filter(tenfold, tmp_path / "stated", {"gyro": 10 * GYRO, "velocity": 10 * VELOCITY, **LAW})
    true = _filter(tenfold, tmp_path / "true", {"gyro": GYRO, "velocity": VELOCITY, **LAW})
    tight = _filter(tenfold, tmp_path / "tight", {"gyro": GYRO / 10, "velocity": VELOCITY / 10, **LAW})
    lik = {k: r["likelihood"] for k, r in (("stated", stated), ("true", true), ("tight", tight))}
    assert all(v["tested"] > 100 and np.isfinite(v["deviance"]) for v in lik.values()), lik
    assert lik["true"]["mean"] < lik["stated"]["mean"] - 0.5, lik  # ten times too loud explains it worse
    assert lik["true"]["mean"] < lik["tight"]["mean"] - 0.5, lik  # ten times too quiet: larger d², gated ones
    assert lik["stated"]["deviance"] == pytest.approx(lik["stated"]["mean"] * lik["stated"]["tested"])
