"""A generated figure-8 whose velocity and gyro noise are well above the defaults (so their levels matter to
batch), aligned, with the true noise levels: the logs of the noise-scale choice tests (evidence, cross-validation)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import align
from slamobs.pipeline.noise import NoiseConfig, resolve_noise
from slamobs.pipeline.simulate import NoiseModel, expected_streams, simulate

#: velocity and gyro noise of the generated log, times the defaults: large enough that their levels matter
VELOCITY_FACTOR, GYRO_FACTOR = 10.0, 30.0


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
