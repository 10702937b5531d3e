"""Every estimator selectable by name: the observers and the reference estimators beside them.

The registry lives above both packages because the factor-graph smoother (`batch`) runs an observer as its seed:
`observers` cannot list `batch` without importing the smoother that imports it.
"""

from __future__ import annotations

from slamobs.pipeline.errors import GainError
from slamobs.pipeline.observers import OBSERVERS, ObserverSpec
from slamobs.pipeline.smoother.estimator import SPEC as BATCH

ESTIMATORS: dict[str, ObserverSpec] = {**OBSERVERS, BATCH.name: BATCH}


def get_estimator(name: str) -> ObserverSpec:
    try:
        return ESTIMATORS[name]
    except KeyError:
        raise GainError(f"unknown observer '{name}' (available: {', '.join(ESTIMATORS)})") from None


__all__ = ["ESTIMATORS", "get_estimator"]
