"""The batch smoother's preintegration kernel called as the tests call it: on an odometry with no gap and a gyro that
never saturates (``preintegrate``'s gap and clip arguments at their neutral values)."""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.smoother.preintegration import preintegrate


def preintegrated(vel_t, omega, vel, kf_t, b_bar, q_om: float, q_v: float) -> tuple[np.ndarray, np.ndarray]:
    """The preintegrated intervals between the keyframes ``kf_t`` (data, covariance) at the bias ``b_bar`` and
    the gyro's and velocity's white-noise densities ``q_om`` and ``q_v`` (per axis); no gap, no clipped stretch."""
    data, cov = np.zeros((kf_t.size - 1, 75)), np.zeros((kf_t.size - 1, 6, 6))
    ones = np.ones(vel_t.size)
    preintegrate(vel_t, omega, vel, kf_t, b_bar, np.full(3, q_om), np.full(3, q_v), np.zeros(2), ones, ones, data, cov)
    return data, cov
