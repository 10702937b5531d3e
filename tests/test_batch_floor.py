"""batch's floor (pipeline.smoother.graph, :func:`floor_terms`): on a ground robot whose floor riekf holds, the
smoother holds it too (the same decision and setting, ``noise.floor``); on a body driving over hills (a floor that is
no plane) the evidence turns it off, and forced on there it would bend the trajectory; a floor its own residuals
reject is dropped."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import align
from slamobs.pipeline.estimators import get_estimator
from slamobs.pipeline.lie import umeyama
from slamobs.pipeline.noise import NoiseConfig, resolve_noise
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.simulate import NoiseModel, expected_streams, get_scenario, simulate


def _batch(scenario, floor, gyro: float = 4.0, velocity: float = 4.0) -> tuple[float, float, dict]:
    """batch given the true noise on 60 s of ``scenario`` (gyro ``gyro`` and wheel velocity ``velocity`` times the
    simulator's default densities at 20 Hz, stereo-like detections at 12 Hz, seed=4), ``noise.floor`` ``floor``: the
    APE and the height's RMS error (m, SE(3)-aligned to the truth) and run.json's ``smoother.floor``."""
    rate, nm, seed = 20.0, NoiseModel(), 4
    nm = replace(nm, gyro=gyro * nm.gyro, odom_linear=velocity * nm.odom_linear, stereo_pixel=4.0, stereo_focal=1000.0)
    nm = replace(nm, stereo_baseline=0.5)
    sim = simulate(scenario, noise=nm, duration=60.0, seed=seed, imu_rate=rate, odom_rate=rate, detection_rate=12.0)
    streams = expected_streams(sim)
    stream = align(streams, keep_directions=False)
    noise = resolve_noise(
        NoiseConfig(
            gyro=nm.gyro / np.sqrt(rate), velocity=nm.odom_linear / np.sqrt(rate), detection=0.01,
            detection_per_m2=0.008, floor=floor,
        )
    )  # fmt: skip
    res = get_estimator("batch").run(stream, {}, ObserverOptions(noise=noise))
    t = streams.truth.t_ns
    truth = streams.truth.position[np.clip(np.searchsorted(t, res.t_ns), 0, t.size - 1)]
    r, tr, _ = umeyama(res.position, truth)
    err = res.position @ r.T + tr - truth
    rec = res.stats["metadata"]["smoother"]["floor"]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1)))), float(np.sqrt(np.mean(err[:, 2] ** 2))), rec


def test_batch_holds_the_ground_robot_s_floor_as_riekf_decides():
    """The ground robot's roll, pitch and vertical velocity are the gyro's and the wheels' noise: riekf's evidence
    says planar, and batch holds the floor at every keyframe (its height error a fraction of the free graph's)."""
    ape, dz, rec = _batch(get_scenario("ground"), "auto")
    assert rec["planar"] and rec["held"] and rec["floor"] == "auto" and rec["tilt_sigma_rad"] > 0.0
    ape0, dz0, rec0 = _batch(get_scenario("ground"), False)  # the switch: planar motion, the floor not held
    assert rec0["planar"] and not rec0["held"] and "tilt_sigma_rad" not in rec0
    assert dz < 0.5 * dz0 and ape < ape0


def test_on_hills_the_evidence_turns_batch_s_floor_off_and_forced_it_bends_the_trajectory():
    """Over hills (the simulator's gyro noise times 4: the roll and pitch rates above their noise) the angles they
    integrate to spread far beyond the floor's σ: not planar, the floor not held, batch as without it;
    ``noise.floor: true`` holds it anyway, and the trajectory it gives is worse (0.33 -> 1.68 m)."""
    hills = get_scenario("ground-hills")
    ape, _, rec = _batch(hills, "auto")
    assert max(rec["ratios"][:2]) > 1.25 and not rec["planar"] and not rec["held"]
    ape0, *_ = _batch(hills, False)
    assert ape == ape0
    forced, _, rec1 = _batch(hills, True)
    assert rec1["held"] and not rec1["planar"]
    assert forced > 1.5 * ape


def test_a_floor_the_data_reject_is_dropped_and_the_log_solved_as_without_it(monkeypatch):
    """Where imposing the floor raises the other factors' cost by more than its degrees of freedom allow (the nested
    test, ``FLOOR_Z``) the whole solve runs again without it from the same start: the same trajectory as with the
    floor switched off. Here the true floor with the bound put far below: every change the first solve made to the
    estimator is put back."""
    from slamobs.pipeline.smoother import estimator

    monkeypatch.setattr(estimator, "FLOOR_Z", -1e9)
    ape, dz, rec = _batch(get_scenario("ground"), "auto")
    assert rec["planar"] and not rec["held"] and rec["dropped"]["test"]["rejected"]
    assert 0.0 < max(rec["dropped"]["chi2"].values()) < 1.0
    ape0, dz0, rec0 = _batch(get_scenario("ground"), False)
    assert (ape, dz) == (ape0, dz0) and "dropped" not in rec0
    monkeypatch.undo()
    rec1 = _batch(get_scenario("ground"), "auto")[2]
    assert "dropped" not in rec1 and not rec1["test"]["rejected"] and rec1["test"]["z"] < 0.0


def test_a_climb_the_gyro_cannot_show_is_rejected_by_the_detections_and_the_floor_dropped():
    """Over hills under a gyro 30 times the simulator's (the roll and pitch rates at their noise: the evidence says
    planar) the floor's own rows at the solution it shaped stay within their σ (χ² about 0.1), but imposing it raises
    the other factors' cost far beyond its effective degrees of freedom: the floor is dropped and batch solves as
    without it (1.01 m with it held, 0.43 m without)."""
    hills = get_scenario("ground-hills")
    ape, _, rec = _batch(hills, "auto", gyro=30.0)
    assert rec["planar"] and not rec["held"]
    t = rec["dropped"]["test"]
    assert t["rejected"] and t["delta_chi2"] > t["dof"] > 0.0 and max(rec["dropped"]["chi2"].values()) < 1.0
    ape0, *_ = _batch(hills, False, gyro=30.0)
    assert ape == ape0
