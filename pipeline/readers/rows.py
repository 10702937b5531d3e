"""What the decoders share: the layouts of the messages read as rows, and the rows they decode into.

:mod:`.decode` deserialises messages with rosbags and turns rows into cleaned streams; :mod:`.fastdecode` and
:mod:`.tfdecode` decode the same rows straight from the bytes. ``LAYOUTS`` and ``ITEM_LAYOUTS`` are the one place
naming the fields they read: :func:`.fastdecode.layout_paths` reads its plans off the row functions here.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .roles import (
    FIDUCIALS,
    FIDUCIALS_LEGACY,
    IMU,
    MAGNETIC_FIELD,
    ODOMETRY,
    POSE_ARRAY,
    POSE_COV_STAMPED,
    POSE_STAMPED,
    TRANSFORM_STAMPED,
    TWIST_COV_STAMPED,
    TWIST_STAMPED,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator


def frame_name(frame: str) -> str:
    """tf2 convention: frame ids carry no leading slash (ROS1 tf1 bags often have one)."""
    return frame.lstrip("/")


class Frames:
    """Per-message frame ids as small integer codes (a decoder keeps its strings in one of these)."""

    def __init__(self) -> None:
        self.codes: dict[str, int] = {}

    def code(self, frame: str) -> int:
        return self.codes.setdefault(frame_name(frame), len(self.codes))

    def names(self) -> list[str]:
        return list(self.codes)


@dataclass
class Rows:
    """Decoded columns of one topic, in record order."""

    topic: str
    msgtype: str
    t_ns: np.ndarray  # (N,) int64 header stamps
    rec_ns: np.ndarray  # (N,) int64
    values: np.ndarray  # (N, width) float64
    frame: np.ndarray  # (N,) int32 codes into frame_names
    child: np.ndarray  # (N,) int32 codes into frame_names
    frame_names: list[str]
    counts: np.ndarray | None = None  # (N,) int64 elements per message (detection arrays)
    items: np.ndarray | None = None  # (sum(counts), width) float64: ``ItemLayout.columns`` of every element
    #: the stated variances (``STATED_COLUMNS``, the layout's last columns, not in ``values``) in run-length form
    stated: StatedRuns | None = None


@dataclass(frozen=True)
class StatedRuns:
    """A topic's stated-variance columns (from :func:`stated_start` on) as runs of equal rows: drivers state one
    constant, so an hour's 720,000 IMU messages are one run, not three float64 columns of 17 MB.
    Equal as ``==`` says: a row with a NaN is a run of its own."""

    starts: np.ndarray  # (R,) int64 first row of each run, ascending, starts[0] == 0 when n > 0
    values: np.ndarray  # (R, k) float64 the run's row: columns from stated_start(msgtype) on
    n: int  # rows in all

    @property
    def lengths(self) -> np.ndarray:
        """(R,) rows in each run."""
        return np.diff(self.starts, append=self.n)

    def expanded(self) -> np.ndarray:
        """The (n, k) rows as decoded."""
        return np.repeat(self.values, self.lengths, axis=0)


def run_heads(values: np.ndarray) -> np.ndarray:
    """Rows of ``values`` (N, k) that differ from the row before in some column (``!=``; row 0 always)."""
    head = np.zeros(values.shape[0], bool)
    head[:1] = True
    for c in range(values.shape[1]):
        head[1:] |= values[1:, c] != values[:-1, c]
    return head


def stated_runs(values: np.ndarray, starts: np.ndarray | None = None, n: int | None = None) -> StatedRuns:
    """Runs of ``values``: its rows (``starts`` None), or runs given by their ``starts`` among ``n`` rows whose
    neighbours may be equal (batches' runs joined: a run that goes on in the next batch becomes one)."""
    heads = np.flatnonzero(run_heads(values))
    at = heads if starts is None else starts[heads]
    return StatedRuns(at.astype(np.int64), values[heads], values.shape[0] if n is None else n)


def stated_start(msgtype: str) -> int | None:
    """The first of ``msgtype``'s stated-variance columns in its layout (they are its last), None without."""
    starts = [LAYOUTS[m].columns[c].start for (_, m), c in STATED_COLUMNS.items() if m == msgtype]
    return min(starts) if starts else None


def split_stated(msgtype: str, values: np.ndarray) -> tuple[np.ndarray, StatedRuns | None]:
    """Decoded rows of a ``LAYOUTS`` type as ``Rows`` keeps them: the columns before the stated variances, and
    those in run-length form (None for a type that states none)."""
    first = stated_start(msgtype)
    if first is None:
        return values, None
    return values[:, :first], stated_runs(values[:, first:])


@dataclass(frozen=True)
class Layout:
    """How one message type becomes a row of float64 columns (named slices of the row)."""

    columns: dict[str, slice]
    width: int
    row: Callable[[Any], tuple[float, ...]]
    child: Callable[[Any], str] | None = None


def vec(v: Any) -> tuple[float, float, float]:
    """A deserialised Point / Vector3 as a tuple."""
    return (v.x, v.y, v.z)


def quat(q: Any) -> tuple[float, float, float, float]:
    """A deserialised Quaternion as (x, y, z, w)."""
    return (q.x, q.y, q.z, q.w)


def diagonal(cov: Any, n: int, first: int = 0) -> tuple[float, ...]:
    """Three diagonal entries of a row-major ``n`` x ``n`` covariance, from ``first`` on (the stated variances of a
    velocity: every message's are read, so :mod:`.covariance` judges the whole stream, not its first messages)."""
    return tuple(cov[(first + k) * (n + 1)] for k in range(3))


#: The stated variances' columns of each velocity role, by message type (``LAYOUTS``' column names).
STATED_COLUMNS: dict[tuple[str, str], str] = {
    ("angular_velocity", IMU): "angular_velocity_covariance",
    ("angular_velocity", ODOMETRY): "angular_covariance",
    ("linear_velocity", ODOMETRY): "linear_covariance",
    ("angular_velocity", TWIST_COV_STAMPED): "angular_covariance",
    ("linear_velocity", TWIST_COV_STAMPED): "linear_covariance",
}

LAYOUTS: dict[str, Layout] = {
    IMU: Layout(
        {
            "angular_velocity": slice(0, 3),
            "linear_acceleration": slice(3, 6),
            "angular_velocity_covariance": slice(6, 9),
        },
        9,
        lambda m: (*vec(m.angular_velocity), *vec(m.linear_acceleration), *diagonal(m.angular_velocity_covariance, 3)),
    ),
    ODOMETRY: Layout(
        {
            "linear": slice(0, 3),
            "angular": slice(3, 6),
            "position": slice(6, 9),
            "quat_xyzw": slice(9, 13),
            "linear_covariance": slice(13, 16),
            "angular_covariance": slice(16, 19),
        },
        19,
        lambda m: (
            *vec(m.twist.twist.linear),
            *vec(m.twist.twist.angular),
            *vec(m.pose.pose.position),
            *quat(m.pose.pose.orientation),
            *diagonal(m.twist.covariance, 6),
            *diagonal(m.twist.covariance, 6, 3),
        ),
        child=lambda m: m.child_frame_id,
    ),
    TWIST_STAMPED: Layout(
        {"linear": slice(0, 3), "angular": slice(3, 6)},
        6,
        lambda m: (*vec(m.twist.linear), *vec(m.twist.angular)),
    ),
    MAGNETIC_FIELD: Layout({"magnetic_field": slice(0, 3)}, 3, lambda m: vec(m.magnetic_field)),
    TWIST_COV_STAMPED: Layout(
        {
            "linear": slice(0, 3),
            "angular": slice(3, 6),
            "linear_covariance": slice(6, 9),
            "angular_covariance": slice(9, 12),
        },
        12,
        lambda m: (
            *vec(m.twist.twist.linear),
            *vec(m.twist.twist.angular),
            *diagonal(m.twist.covariance, 6),
            *diagonal(m.twist.covariance, 6, 3),
        ),
    ),
    POSE_STAMPED: Layout(
        {"position": slice(0, 3), "quat_xyzw": slice(3, 7)},
        7,
        lambda m: (*vec(m.pose.position), *quat(m.pose.orientation)),
    ),
    POSE_COV_STAMPED: Layout(
        {"position": slice(0, 3), "quat_xyzw": slice(3, 7)},
        7,
        lambda m: (*vec(m.pose.pose.position), *quat(m.pose.pose.orientation)),
    ),
    TRANSFORM_STAMPED: Layout(
        {"position": slice(0, 3), "quat_xyzw": slice(3, 7)},
        7,
        lambda m: (*vec(m.transform.translation), *quat(m.transform.rotation)),
        child=lambda m: m.child_frame_id,
    ),
}

#: Counted remarks of a decoder: (noun, rest) -> count, rendered "3 DELETE markers skipped".
Notes = Counter[tuple[str, str]]


@dataclass(frozen=True)
class ItemLayout:
    """A detection array whose detections are the elements of one sequence field (fixed-layout elements)."""

    items: str  # the sequence field
    ident: tuple[str, ...] | None  # path of the id in an element; None: the element's index is the id
    position: tuple[str, ...]  # path of the position (Point / Vector3) in an element

    @property
    def columns(self) -> tuple[tuple[str, ...], ...]:
        """Element leaves read by the vectorised decoder: the id (if any), then x, y, z."""
        return ((self.ident,) if self.ident else ()) + tuple((*self.position, a) for a in "xyz")

    def detections(self, msg: Any, _notes: Notes) -> Iterator[tuple[int, Any]]:
        """``(id, position)`` of every element of a deserialised message (the rosbags path)."""
        for k, item in enumerate(getattr(msg, self.items)):
            yield (k if self.ident is None else _field(item, self.ident)), _field(item, self.position)


def _field(obj: Any, path: tuple[str, ...]) -> Any:
    for name in path:
        obj = getattr(obj, name)
    return obj


#: Detection types decoded straight from the bytes when their stored definition matches (else by rosbags).
ITEM_LAYOUTS: dict[str, ItemLayout] = {
    FIDUCIALS: ItemLayout("transforms", ("fiducial_id",), ("transform", "translation")),
    FIDUCIALS_LEGACY: ItemLayout("transforms", ("fiducial_id",), ("transform", "translation")),
    POSE_ARRAY: ItemLayout("poses", None, ("position",)),
}


@dataclass
class TfRows:
    """Every transform of a TF topic (``tf2_msgs/TFMessage`` or ROS1 ``tf/tfMessage``), in record order."""

    topic: str
    t_ns: np.ndarray  # (N,) int64 header stamps
    rec_ns: np.ndarray  # (N,) int64
    parent: np.ndarray  # (N,) int32 codes into frame_names
    child: np.ndarray  # (N,) int32
    values: np.ndarray  # (N, 7) translation xyz, quaternion xyzw
    frame_names: list[str]
