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
    sigma: np.ndarray  # (3,); NaN where ``problem`` says why the stated values are not believed
    period_s: float
    problem: str | None = None

    @property
    def density(self) -> np.ndarray:
        """White-noise density ``sigma * sqrt(period)`` (units per sqrt(Hz))."""
        return self.sigma * np.sqrt(self.period_s)


#: Diagonal variances drivers write when they know nothing: a value this large or this small that is an exact
#: power of ten is a placeholder, not a measurement.
PLACEHOLDER_ABOVE, PLACEHOLDER_BELOW = 1e2, 1e-8


def implausible(diag: np.ndarray) -> str | None:
    """Why three stated variances are not a measurement (None: plausible): REP 145's -1 ("no estimate"),
    zeros ("unknown"), negative or non-finite values, placeholders such as 1e-9, 1e3 or 1e6."""
    diag = np.asarray(diag, dtype=float)
    if not np.all(np.isfinite(diag)):
        return "not finite"
    if diag[0] == -1:
        return "-1 (REP 145: no estimate)"
    if np.any(diag < 0):
        return "negative"
    if np.any(diag == 0):
        return "zero (unknown)"
    exact = np.isclose(np.log10(diag), np.round(np.log10(diag)), rtol=0, atol=1e-9)
    if np.any(exact & ((diag >= PLACEHOLDER_ABOVE) | (diag <= PLACEHOLDER_BELOW))):
        return f"placeholder ({', '.join(f'{d:g}' for d in diag)})"
    return None


def _diagonal(msg, msgtype: str, role: str) -> np.ndarray | None:
    """The 3 variances of ``role`` stated by one message, None when the message type states none."""
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
    return cov[list(idx)]


def stated_noise(
    path: str | Path, topics: dict[str, str], roles: tuple[str, ...] = ("angular_velocity", "linear_velocity")
) -> dict[str, StatedNoise]:
    """Role -> the noise stated by the first messages of that role's topic (roles without one are left out;
    a topic whose messages state only implausible values (:func:`implausible`) is given with its ``problem``).

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
                diags, stamps, problems = [], [], []
                for conn, _rec, raw in iter_raw(reader, path, conns):
                    msg = reader.deserialize(raw, conn.msgtype)
                    diag = _diagonal(msg, conn.msgtype, role)
                    if diag is not None:
                        if (problem := implausible(diag)) is None:
                            diags.append(diag)
                        else:
                            problems.append(problem)
                    stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
                    if len(stamps) >= SAMPLE_MESSAGES:
                        break
                steps = np.diff(np.sort(np.asarray(stamps, dtype=np.int64))) * 1e-9
                steps = steps[steps > 0]
                if steps.size == 0 or not (diags or problems):
                    continue
                if not diags:
                    found[role] = StatedNoise(topic, np.full(3, np.nan), float(np.median(steps)), problems[0])
                    continue
                found[role] = StatedNoise(topic, np.sqrt(np.median(np.array(diags), axis=0)), float(np.median(steps)))
    except (InputError, AttributeError, KeyError, TypeError, ValueError):
        return found
    return found
