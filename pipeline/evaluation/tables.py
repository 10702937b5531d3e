"""The run's tables as the report reads them: a pandas DataFrame or its columns as NumPy arrays, alike.

A run reads its tables back without pandas (:func:`slamobs.pipeline.writers.read_columns`; importing pandas is
~0.8 s of a short run), ``slamobs report`` and the Python API hand DataFrames: every report section and figure
reads a table through these few helpers only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Mapping, Union

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

#: A run table: a pandas DataFrame, or its columns as NumPy arrays.
Table = Union["pd.DataFrame", Mapping[str, np.ndarray]]

POSE_COLUMNS = ("t_ns", "x", "y", "z", "qx", "qy", "qz", "qw")
GYRO_COLUMNS = ("gyro_bias_x", "gyro_bias_y", "gyro_bias_z")
VEL_COLUMNS = ("vel_bias_x", "vel_bias_y", "vel_bias_z")
LANDMARK_COLUMNS = ("id", "x", "y", "z")
#: Landmark covariance columns (map frame, m²), upper triangle; null for estimators without covariance.
LANDMARK_COV = ("cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz")


def column_names(table: Table) -> list[str]:
    return list(table.columns) if hasattr(table, "columns") else list(table)


def column(table: Table, name: str, dtype=None) -> np.ndarray:
    col = table[name]
    return col.to_numpy(dtype) if hasattr(col, "to_numpy") else np.asarray(col, dtype=dtype)


def columns(table: Table, names: list[str], dtype) -> np.ndarray:
    """Columns ``names`` as one ``(N, k)`` array (as ``DataFrame[names].to_numpy(dtype)``)."""
    if hasattr(table, "columns"):
        return table[list(names)].to_numpy(dtype)
    return np.stack([np.asarray(table[c], dtype=dtype) for c in names], axis=1)


def n_rows(table: Table) -> int:
    return len(table) if hasattr(table, "columns") else (len(next(iter(table.values()))) if len(table) else 0)


def require_columns(table: Table, names: tuple[str, ...], what: str) -> None:
    missing = [c for c in names if c not in column_names(table)]
    if missing:
        raise ValueError(f"{what} table lacks column(s) {missing}; has {column_names(table)}")


def time_order(t_ns: np.ndarray) -> np.ndarray | slice:
    """Rows in time order (stable): all of them as they are when already sorted (no copy), else an index."""
    if t_ns.shape[0] < 2 or bool(np.all(t_ns[1:] >= t_ns[:-1])):
        return slice(None)
    return np.argsort(t_ns, kind="stable")


def landmark_table(landmarks: Table | None) -> tuple[np.ndarray, np.ndarray]:
    """The final map's ids and positions (none without a landmarks table)."""
    if landmarks is None:
        return np.empty(0, dtype=np.int64), np.empty((0, 3))
    require_columns(landmarks, LANDMARK_COLUMNS, "landmarks")
    return column(landmarks, "id", np.int64), columns(landmarks, ["x", "y", "z"], np.float64)


def landmark_covariances(landmarks: Table | None) -> np.ndarray | None:
    """The final map's (N, 3, 3) position covariances in the table's frame, row for row with
    :func:`landmark_table` (NaN where a row has none); None without covariance columns or with none filled."""
    if landmarks is None or not set(LANDMARK_COV) <= set(column_names(landmarks)):
        return None
    xx, xy, xz, yy, yz, zz = columns(landmarks, list(LANDMARK_COV), np.float64).T
    if not np.isfinite(xx).any():
        return None
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], 1)
