"""Noise levels of the reference estimators (``batch``, ``riekf``): the ``noise`` section of ``run.yaml``,
else what the log's messages state (:mod:`pipeline.readers.covariance`), else documented defaults.

Velocity noises are white-noise densities, so that one number describes a sensor at any rate: a
per-sample standard deviation σ at period T is the density σ·√T. The defaults are the simulator's sensors
(:class:`pipeline.simulate.NoiseModel` at its default rates); a detection's standard deviation per axis grows
with range as on a fiducial detector: ``detection + detection_per_m * range``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: key -> (default, unit, meaning); the config schema lists the same keys.
DEFAULTS: dict[str, tuple[float, str, str]] = {
    "gyro": (0.005 * np.sqrt(1 / 200), "rad/s/sqrt(Hz)", "angular-velocity white-noise density"),
    "velocity": (0.02 * np.sqrt(1 / 50), "m/s/sqrt(Hz)", "linear-velocity white-noise density"),
    "detection": (0.01, "m", "detection standard deviation per axis at zero range"),
    "detection_per_m": (0.002, "m/m", "growth of the detection standard deviation with range"),
    "gyro_bias": (0.2, "rad/s", "prior standard deviation of each gyro-bias component (unknown start)"),
    "velocity_bias": (0.2, "m/s", "prior standard deviation of each velocity-bias component"),
    "gyro_bias_walk": (1e-4, "rad/s/sqrt(s)", "gyro-bias random walk (riekf; batch with bias: random-walk)"),
    "velocity_bias_walk": (1e-4, "m/s/sqrt(s)", "velocity-bias random walk (as gyro_bias_walk)"),
}
#: keys that may come from the log's message covariances, and the role whose topic states them
STATED = {"gyro": "angular_velocity", "velocity": "linear_velocity"}


@dataclass(frozen=True)
class NoiseConfig:
    """The ``noise`` section of run.yaml as given: None = not set (the log's message covariance for ``gyro`` and
    ``velocity`` where it states one, else the default in :data:`DEFAULTS`)."""

    gyro: float | tuple[float, float, float] | None = None
    velocity: float | tuple[float, float, float] | None = None
    detection: float | None = None
    detection_per_m: float | None = None
    gyro_bias: float | None = None
    velocity_bias: float | None = None
    gyro_bias_walk: float | None = None
    velocity_bias_walk: float | None = None

    @classmethod
    def from_section(cls, section: dict | None) -> NoiseConfig:
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in (section or {}).items()})

    def given(self) -> dict:
        """The keys set, with their values."""
        return {k: v for k in DEFAULTS if (v := getattr(self, k)) is not None}


@dataclass(frozen=True)
class NoiseSettings:
    gyro: np.ndarray  # (3,) rad/s/sqrt(Hz)
    velocity: np.ndarray  # (3,) m/s/sqrt(Hz)
    detection: float
    detection_per_m: float
    gyro_bias: float
    velocity_bias: float
    gyro_bias_walk: float
    velocity_bias_walk: float
    sources: dict[str, str] = field(default_factory=dict)  # key -> "config", "default" or "<topic> covariance"

    def as_dict(self) -> dict:
        """For run.json: every value and where it came from."""
        out = {
            k: (getattr(self, k).tolist() if isinstance(getattr(self, k), np.ndarray) else getattr(self, k))
            for k in DEFAULTS
        }
        return {**out, "sources": dict(self.sources)}

    def detection_sigma(self, ranges: np.ndarray) -> np.ndarray:
        return self.detection + self.detection_per_m * np.asarray(ranges, dtype=float)


def _vec(value) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()


def resolve_noise(
    config: NoiseConfig | None = None, log: str | Path | None = None, topics: dict[str, str] | None = None
) -> NoiseSettings:
    """The settings of a run: what ``config`` (the run's ``noise`` section) sets, the message covariances of
    ``log`` for the velocity densities not set there, defaults for the rest."""
    section = (config or NoiseConfig()).given()
    values: dict = {}
    sources: dict[str, str] = {}
    stated = {}
    if log is not None and topics and any(k not in section for k in STATED):
        from slamobs.pipeline.readers.covariance import stated_noise

        stated = stated_noise(log, topics, tuple(STATED[k] for k in STATED if k not in section))
    for key, (default, _, _) in DEFAULTS.items():
        if key in section:
            values[key], sources[key] = section[key], "config"
        elif key in STATED and STATED[key] in stated:
            found = stated[STATED[key]]
            values[key] = found.density
            sources[key] = f"{found.topic} covariance ({1.0 / found.period_s:.4g} Hz)"
        else:
            values[key], sources[key] = default, "default"
    return NoiseSettings(
        gyro=_vec(values["gyro"]),
        velocity=_vec(values["velocity"]),
        **{k: float(values[k]) for k in DEFAULTS if k not in ("gyro", "velocity")},
        sources=sources,
    )
