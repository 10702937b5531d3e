"""Observer registry: one entry per observer algorithm of docs/observers.md, selectable by name (the reference
smoother `batch` is added beside them in `pipeline/estimators.py`)."""

from __future__ import annotations

from slamobs.pipeline.observers.base import GainError, GainSpec, ObserverOptions, ObserverResult, ObserverSpec
from slamobs.pipeline.observers.fast_adaptation import SPEC as FAST_ADAPTATION
from slamobs.pipeline.observers.hashim import SPEC as HASHIM, SPEC_IMU as HASHIM_IMU
from slamobs.pipeline.observers.wang_tayebi import SPEC as WANG_TAYEBI
from slamobs.pipeline.observers.hybrid import SPEC as HYBRID
from slamobs.pipeline.observers.riekf import SPEC as RIEKF

OBSERVERS: dict[str, ObserverSpec] = {
    s.name: s for s in (FAST_ADAPTATION, HASHIM, HASHIM_IMU, WANG_TAYEBI, HYBRID, RIEKF)
}


def get_observer(name: str) -> ObserverSpec:
    try:
        return OBSERVERS[name]
    except KeyError:
        raise GainError(f"unknown observer '{name}' (available: {', '.join(OBSERVERS)})") from None


__all__ = ["OBSERVERS", "GainError", "GainSpec", "ObserverOptions", "ObserverResult", "ObserverSpec", "get_observer"]
