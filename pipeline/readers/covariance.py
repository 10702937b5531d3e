"""The noise levels a log states about itself: the covariance fields of its velocity messages.

The reference estimators (``batch``, ``riekf``) weight odometry by its noise; ``sensor_msgs/Imu``
(``angular_velocity_covariance``), ``nav_msgs/Odometry`` and ``TwistWithCovarianceStamped``
(``twist.covariance``) carry it. Drivers fill these fields with a constant, so the first messages of a
topic are enough: a few are decoded with rosbags (never the whole topic), together with their stamps,
which give the sample period that turns a per-sample variance into a noise density.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slamobs.pipeline.errors import InputError

from .container import iter_raw, open_log
from .msgdefs import complete_definitions
from .roles import topics_of

#: Messages read per topic (the median of their diagonals is used).
SAMPLE_MESSAGES = 25

_IMU = "sensor_msgs/msg/Imu"
_TWIST_COV = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/TwistWithCovarianceStamped")


@dataclass(frozen=True)
class StatedNoise:
    """Per-axis standard deviation of one sample (body frame of the message) and the sample period."""

    topic: str
    sigma: np.ndarray  # (3,)
    period_s: float

    @property
    def density(self) -> np.ndarray:
        """White-noise density ``sigma * sqrt(period)`` (units per sqrt(Hz))."""
        return self.sigma * np.sqrt(self.period_s)


def _diagonal(msg, msgtype: str, role: str) -> np.ndarray | None:
    """The 3 variances of ``role`` stated by one message, None when the message states none."""
    if msgtype == _IMU:
        if role != "angular_velocity":
            return None
        cov = np.asarray(msg.angular_velocity_covariance, dtype=float)
        idx = (0, 4, 8)
    elif msgtype in _TWIST_COV:
        cov = np.asarray(msg.twist.covariance, dtype=float)
        idx = (0, 7, 14) if role == "linear_velocity" else (21, 28, 35)
    else:
        return None
    diag = cov[list(idx)]
    # REP 145: -1 in the first element means "no estimate"; all zeros is the common "unknown".
    if not np.all(np.isfinite(diag)) or diag[0] < 0 or np.all(diag == 0) or np.any(diag < 0):
        return None
    return diag


def stated_noise(
    path: str | Path, topics: dict[str, str], roles: tuple[str, ...] = ("angular_velocity", "linear_velocity")
) -> dict[str, StatedNoise]:
    """Role -> the noise stated by the first messages of that role's topic (roles without one are left out).

    A topic whose messages cannot be read here is treated as stating nothing (the run reads it properly and
    reports any damage itself).
    """
    found: dict[str, StatedNoise] = {}
    wanted = {role: topics[role] for role in roles if topics.get(role)}
    if not wanted:
        return found
    try:
        with open_log(path) as reader:
            complete_definitions(reader)
            table = topics_of(reader)
            for role, topic in wanted.items():
                if topic not in table:
                    continue
                meta, conns = table[topic]
                if meta.msgtype != _IMU and meta.msgtype not in _TWIST_COV:
                    continue
                diags, stamps = [], []
                for conn, _rec, raw in iter_raw(reader, path, conns):
                    msg = reader.deserialize(raw, conn.msgtype)
                    diag = _diagonal(msg, conn.msgtype, role)
                    if diag is not None:
                        diags.append(diag)
                    stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
                    if len(stamps) >= SAMPLE_MESSAGES:
                        break
                steps = np.diff(np.sort(np.asarray(stamps, dtype=np.int64))) * 1e-9
                steps = steps[steps > 0]
                if not diags or steps.size == 0:
                    continue
                found[role] = StatedNoise(topic, np.sqrt(np.median(np.array(diags), axis=0)), float(np.median(steps)))
    except (InputError, AttributeError, KeyError, TypeError, ValueError):
        return found
    return found
