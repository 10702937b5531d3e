"""What every observer shares: gain specifications and validation, options, and the result arrays."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from pipeline.alignment import AlignedStream
from pipeline.errors import GainError


@dataclass(frozen=True)
class GainSpec:
    name: str
    default: float
    description: str


@dataclass(frozen=True)
class ObserverOptions:
    """Run options that are not gains (they never change the observer's law)."""

    max_meas_age: float = 0.5  # seconds a landmark frame stays valid before landmarks count as unseen
    min_landmarks_bias: int = 3  # bias adaptation frozen below this many visible landmarks (spec §8)
    out_every: int = 1  # record pose/bias every n-th velocity sample


@dataclass
class ObserverResult:
    """Histories and final map of one run, as arrays (the writers turn them into tables)."""

    t_ns: np.ndarray  # (K,)
    rotation: np.ndarray  # (K, 3, 3) body -> map
    position: np.ndarray  # (K, 3)
    gyro_bias: np.ndarray  # (K, 3)
    vel_bias: np.ndarray  # (K, 3)
    landmark_ids: np.ndarray  # (L,)
    landmark_xyz: np.ndarray  # (L, 3) final map
    det_t_ns: np.ndarray  # (M,) per detection
    det_ids: np.ndarray  # (M,)
    track_xyz: np.ndarray  # (M, 3) landmark estimate at the detection time
    innovation: np.ndarray  # (M, 3) e_i at the detection time
    stats: dict = field(default_factory=dict)
    #: Observer-specific tables (e.g. "jumps"), columns named as in ``schemas/<name>.json``.
    extra_tables: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True)
class ObserverSpec:
    name: str
    algorithm: str
    paper: str
    summary: str
    gains: tuple[GainSpec, ...]
    run: Callable[[AlignedStream, dict[str, float], ObserverOptions], ObserverResult]
    #: Minimum number of inertial directions (gravity, magnetic field) the observer needs; 0 = none.
    min_directions: int = 0

    def resolve_gains(self, user: dict | None) -> dict[str, float]:
        """Defaults overlaid with the user's gains, exactly as given; anything invalid is an error."""
        known = {g.name: g.default for g in self.gains}
        user = dict(user or {})
        unknown = sorted(set(user) - set(known))
        if unknown:
            raise GainError(f"unknown gain(s) {', '.join(unknown)} for observer '{self.name}' "
                            f"(known: {', '.join(known)})")
        out = dict(known)
        for name, value in user.items():
            if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
                raise GainError(f"gain {name} of observer '{self.name}' must be a number, got {value!r}")
            if not math.isfinite(value) or value <= 0:
                raise GainError(f"gain {name} of observer '{self.name}' must be finite and > 0, got {value!r}")
            out[name] = float(value)
        return out
