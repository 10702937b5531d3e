"""A generated figure-8 whose velocity and gyro noise are well above the defaults (so their levels matter to
batch), aligned, with the true noise levels: the logs of the noise-scale choice tests (evidence, cross-validation);
and the smoother's keyframe APE on a generated figure-8, which those tests and the detection-model tests compare."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import align
from slamobs.pipeline.lie import umeyama
from slamobs.pipeline.noise import NoiseConfig, resolve_noise
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.simulate import NoiseModel, expected_streams, get_scenario, simulate
from slamobs.pipeline.smoother.estimator import BatchSmoother

#: velocity and gyro noise of the generated log, times the defaults: large enough that their levels matter
VELOCITY_FACTOR, GYRO_FACTOR = 10.0, 30.0


def rig_noise(imu_hz: float, odom_hz: float) -> NoiseModel:
    """The generated rigs' noise (benchmarks/handheld_logs.py's ``Case`` defaults): the gyro's and the velocity's
    densities ``GYRO_FACTOR`` and ``VELOCITY_FACTOR`` times the defaults, per sample at the streams' rates, and the
    detection law 0.03 m + 0.006 m per m of range."""
    from slamobs.pipeline.noise import DEFAULTS

    return replace(
        NoiseModel(),
        gyro=GYRO_FACTOR * DEFAULTS["gyro"][0] * np.sqrt(imu_hz),
        odom_linear=VELOCITY_FACTOR * DEFAULTS["velocity"][0] * np.sqrt(odom_hz),
        detection_base=0.03,
        detection_per_m=0.006,
    )


def noisy_figure8(duration: float, seed: int):
    """The simulation, its aligned stream and the resolved true noise levels (gyro at 200 Hz, velocity at 50 Hz)."""
    nm = replace(
        NoiseModel(), odom_linear=VELOCITY_FACTOR * NoiseModel().odom_linear, gyro=GYRO_FACTOR * NoiseModel().gyro
    )
    sim = simulate("figure8", duration=duration, seed=seed, noise=nm)
    stream = align(expected_streams(sim), keep_directions=False)
    truth = resolve_noise(
        NoiseConfig(
            gyro=nm.gyro * np.sqrt(1 / 200),
            velocity=nm.odom_linear * np.sqrt(1 / 50),
            detection=nm.detection_base,
            detection_per_m=nm.detection_per_m,
            detection_per_m2=nm.detection_per_m2,
        )
    )
    return sim, stream, truth


def smoothed(sim, stream, settings, noise=None) -> tuple[BatchSmoother, float]:
    """The smoother on ``stream`` (of the figure-8 ``sim``) with ``settings``, solved, and its keyframes' APE
    against the scenario's truth (m, after Umeyama's fit)."""
    smoother = BatchSmoother(stream, {}, ObserverOptions(), settings=settings, noise=noise)
    smoother.solve()
    sol, kf_t = smoother.result["solution"], smoother.result["kf_t"]
    truth = get_scenario("figure8").sample(kf_t + (stream.t0_ns - sim.start_ns) * 1e-9)
    r, t, _ = umeyama(sol.pos, truth.P)
    return smoother, float(np.sqrt(np.mean(np.sum((sol.pos @ r.T + t - truth.P) ** 2, axis=1))))


def exponential(t: np.ndarray, tau: float, rng: np.random.Generator) -> np.ndarray:
    """A unit-variance exponentially correlated sequence at the (sorted) times ``t``."""
    x, out = rng.normal(), np.empty(t.size)
    for k, r in enumerate(np.exp(-np.diff(t, prepend=t[0]) / tau)):
        x = r * x + np.sqrt(1.0 - r * r) * rng.normal() if k else x
        out[k] = x
    return out


def with_slow_range_error(stream, sd: float, tau: float, seed: int):
    """``stream`` with an exponentially correlated error per landmark along each detection's line of sight."""
    rng = np.random.default_rng(seed)
    t = np.repeat((stream.det_t_ns - stream.t0_ns) * 1e-9, np.diff(stream.det_offsets))
    err = np.zeros(t.size)
    for j in np.unique(stream.det_idx):
        idx = np.flatnonzero(stream.det_idx == j)
        idx = idx[np.argsort(t[idx], kind="stable")]
        err[idx] = sd * exponential(t[idx], tau, rng)
    y = stream.det_y
    return replace(stream, det_y=y + y / np.linalg.norm(y, axis=1, keepdims=True) * err[:, None])
