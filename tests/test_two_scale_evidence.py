"""A velocity error with two time scales (white plus slowly varying): the smoother's evidence tells it from white
noise (issue 23; docs/noise.md "Two time scales"). On a generated log whose odometry velocity carries a slow error
beside the white one (``NoiseModel.odom_linear_drift``), the model with a random-walk velocity bias
(``batch.bias: random-walk``) beats the white-only model at every scale of its level by more than the evidence's
margin, and its trajectory is closer to the truth than the white-only model the evidence would keep; on the same
log without the slow error the white-only model is kept. The random walk's factors count in log Z
(``evidence.walk_log_det``): without them the two models' evidences would not be comparable."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.lie import umeyama
from slamobs.pipeline.noise import NoiseConfig, resolve_noise
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.simulate import NoiseModel, expected_streams, get_scenario, simulate
from slamobs.pipeline.simulate.sensors import PIECE_S
from slamobs.pipeline.smoother import evidence as ev
from slamobs.pipeline.smoother.estimator import BatchSmoother
from slamobs.pipeline.smoother.settings import BatchSettings

#: the slow part of the velocity error: RMS m/s and time scale s (the white part is the simulator's default)
DRIFT, DRIFT_S = 0.03, 10.0
#: the two-scale model: the white level at the truth, a velocity-bias random walk over segments of SEGMENT_S
SEGMENT_S, WALK = 2.0, 0.01


def generated(drift: float):
    nm = replace(NoiseModel(), odom_linear_drift=drift, odom_linear_drift_s=DRIFT_S)
    sim = simulate("figure8", duration=60.0, seed=1, noise=nm)
    stream = align(expected_streams(sim), keep_directions=False)
    return nm, sim, stream


def solved(log, velocity_scale: float = 1.0, walk: float | None = None) -> tuple[float, float]:
    """log Z of the smoother's solution (all detections, no gate: every model scored on the same data) and its
    APE against the truth at the keyframes: white-only at ``velocity_scale`` x the true white level, or with a
    random-walk velocity bias of level ``walk``."""
    nm, sim, stream = log
    noise = resolve_noise(
        NoiseConfig(
            velocity=nm.odom_linear * np.sqrt(1 / 50) * velocity_scale,
            gyro=nm.gyro * np.sqrt(1 / 200),
            detection=nm.detection_base,
            detection_per_m=nm.detection_per_m,
            velocity_bias_walk=walk,
        )
    )
    bias = {"bias": "random-walk", "segment_s": SEGMENT_S} if walk is not None else {}
    settings = BatchSettings(noise_evidence="off", gate_chi2=None, **bias)
    smoother = BatchSmoother(stream, {}, ObserverOptions(), settings=settings, noise=noise)
    smoother.solve()
    sol, kf_t = smoother.result["solution"], smoother.result["kf_t"]
    problem, _ = smoother.first_problem()
    z = ev.log_evidence(problem, sol)
    truth = get_scenario("figure8").sample(kf_t + (stream.t0_ns - sim.start_ns) * 1e-9)
    r, t, _ = umeyama(sol.pos, truth.P)
    return z, float(np.sqrt(np.mean(np.sum((sol.pos @ r.T + t - truth.P) ** 2, axis=1))))


@pytest.fixture(scope="module")
def drifting():
    return generated(DRIFT)


@pytest.fixture(scope="module")
def white():
    return generated(0.0)


def test_a_slow_velocity_error_is_told_from_white_noise_and_the_trajectory_follows(drifting):
    whites = {s: solved(drifting, s) for s in (1.0, 3.0, 10.0)}
    z_two, ape_two = solved(drifting, 1.0, WALK)
    kept = max(whites, key=lambda s: whites[s][0])  # the white-only model the evidence would keep
    assert ev.better(z_two, whites[kept][0]), (z_two, whites)
    assert ape_two < 0.8 * whites[kept][1], (ape_two, whites)


def test_white_noise_keeps_the_white_model(white):
    z_white, _ = solved(white)
    z_two, _ = solved(white, 1.0, WALK)
    assert not ev.better(z_two, z_white), (z_two, z_white)


def test_the_simulated_slow_error_has_its_rms_and_time_scale():
    """``odom_linear_drift`` alone (no white noise): per axis about its RMS, nearly unchanged over a tenth of its
    time scale and decorrelated over several; the pieces of a long log join (the error is a function of time)."""
    sc = get_scenario("figure8")
    nm = replace(NoiseModel.zero(), odom_linear_drift=DRIFT, odom_linear_drift_s=DRIFT_S)
    sim = simulate(sc, duration=600.0, seed=2, noise=nm)
    t = (sim.odom.t_ns - sim.start_ns) * 1e-9
    err = sim.odom.linear - sc.sample(t).v - sc.velocity_bias
    assert np.allclose(np.sqrt(np.mean(err**2, axis=0)), DRIFT, rtol=0.4), np.sqrt(np.mean(err**2, axis=0))

    def corr(lag_s: float) -> float:
        k = int(round(lag_s * 50.0))
        return float(np.mean([np.corrcoef(err[:-k, i], err[k:, i])[0, 1] for i in range(3)]))

    assert corr(0.1 * DRIFT_S) > 0.9 and abs(corr(5.0 * DRIFT_S)) < 0.5, (corr(0.1 * DRIFT_S), corr(5.0 * DRIFT_S))
    step = np.abs(np.diff(err, axis=0))
    at = int(np.searchsorted(t, PIECE_S))  # the first sample of the second piece
    assert step[at - 1].max() <= 2.0 * np.percentile(step, 99), (step[at - 1], np.percentile(step, 99))
