"""Message decoding into NumPy columns, and the cleaning every stream gets before it leaves the reader.

The layouts of the stream messages and detection arrays (``LAYOUTS``, ``ITEM_LAYOUTS``) are in :mod:`.rows`, where
:mod:`.fastdecode` reads its vectorised plans from too, and the ``decode_*`` functions here; the layouts of
tag corner messages are in :mod:`.cameradecode` (``CORNER_LAYOUTS``), the covariance fields the reference
estimators weight by in :mod:`.covariance`, and the TF walker in :mod:`.tfdecode`.
Messages are deserialised with the typestore rosbags builds from the definitions stored in the log, so custom
types such as ``fiducial_msgs`` need no ROS installation.

The topics :mod:`.fastdecode` can read from the bytes (fixed layouts, detection arrays) are decoded together
in one pass over the log (:func:`decode_topics`); the others are deserialised one topic at a time: rosbags
merges connections by record time, which re-decompresses chunks over and over when chunks overlap in time
(seen in real bags written topic by topic).
"""

from __future__ import annotations

import json
import re
import struct
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from slamobs.pipeline.blocks import far_repeats, finite_rows, repeated_pairs
from slamobs.pipeline.errors import InputError, one_line, plural, resource_error
from slamobs.pipeline.lie import quat_angles_to
from slamobs.pipeline.streams import DetectionStream, PoseStream, Transform, TransformSeries, Vec3Stream

from . import fastdecode, tfdecode
from .container import iter_raw, require_definitions
from .roles import APRILTAG_ROS, IMU, MAGNETIC_FIELD, MARKER_ARRAY, ODOMETRY, TWIST_COV_STAMPED, TWIST_STAMPED
from .rows import ITEM_LAYOUTS, LAYOUTS, Frames, Notes, Rows, TfRows, frame_name, quat, split_stated, vec

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

HEADER = "std_msgs/msg/Header"
_NS = 1_000_000_000


#: (role, type) -> (column of the layout, where the frame comes from: header ``frame`` or ``child``).
VEC3_ROLES: dict[tuple[str, str], tuple[str, str]] = {
    ("angular_velocity", IMU): ("angular_velocity", "frame"),
    ("angular_velocity", ODOMETRY): ("angular", "child"),
    ("angular_velocity", TWIST_STAMPED): ("angular", "frame"),
    ("angular_velocity", TWIST_COV_STAMPED): ("angular", "frame"),
    ("linear_velocity", ODOMETRY): ("linear", "child"),
    ("linear_velocity", TWIST_STAMPED): ("linear", "frame"),
    ("linear_velocity", TWIST_COV_STAMPED): ("linear", "frame"),
    ("accel", IMU): ("linear_acceleration", "frame"),
    ("magnetic", MAGNETIC_FIELD): ("magnetic_field", "frame"),
}


def gyro_not_filled(xyz: np.ndarray) -> bool:
    """Whether angular velocities ``xyz`` (N, 3) are those of an IMU that does not fill the field: every one exactly
    zero (a still IMU measures noise, never 0.0 on three axes). The linear-velocity topic's own angular velocity then
    stands in, when its type has one (:func:`has_angular_velocity`) and it is not all zero too."""
    return xyz.shape[0] >= 2 and not xyz.any()


def gyro_stand_in(
    gyro: str | None,
    gyro_xyz: Callable[[], np.ndarray],
    other: str | None,
    other_msgtype: str | None,
    other_xyz: Callable[[], np.ndarray],
) -> bool:
    """Whether the linear-velocity topic ``other``'s angular velocity stands in for the angular-velocity topic
    ``gyro``'s: ``gyro``'s is not filled (:func:`gyro_not_filled`), ``other`` is another topic whose type has an
    angular velocity (:func:`has_angular_velocity`) and its angular velocity is not all zero. The one rule of
    ``read_log`` (every message) and ``slamobs info`` (the first few); the vectors are read only when needed."""
    if gyro is None or other is None or other == gyro or other_msgtype is None:
        return False
    if not has_angular_velocity(other_msgtype) or not gyro_not_filled(gyro_xyz()):
        return False
    return bool(other_xyz().any())


def has_angular_velocity(msgtype: str) -> bool:
    """Whether messages of ``msgtype`` carry an angular velocity the readers read (odometry, twists, IMU)."""
    return ("angular_velocity", msgtype) in VEC3_ROLES


def first_vectors(reader: AnyReader, conns: Collection[Connection], msgtype: str, role: str, n: int) -> np.ndarray:
    """The ``role`` vectors (:data:`VEC3_ROLES`) of the first ``n`` messages of a topic, (≤ n, 3): a look at a few
    samples (``slamobs info``) without decoding the whole topic."""
    layout = LAYOUTS[msgtype]
    cols = layout.columns[VEC3_ROLES[role, msgtype][0]]
    out = []
    for _, _, raw in reader.messages(connections=list(conns)):
        out.append(layout.row(reader.deserialize(raw, msgtype))[cols])
        if len(out) >= n:
            break
    return np.asarray(out, np.float64).reshape(-1, 3)


#: A step back of the stamps at least this long (ns) is named in the out-of-order note: a clock set back.
CLOCK_STEP_NS = 500_000_000


#: Messages a header clock's step needs on either side (:func:`clock_step_forward`).
STEP_SIDE = 5


def clock_step_forward(t_ns: np.ndarray, rec_ns: np.ndarray) -> tuple[int, int]:
    """The largest jump ahead of the header stamps against the record times between two messages in a row (record
    order), when it lasts (the median header-minus-record after it at least ``CLOCK_STEP_NS`` above the one before):
    a header clock set forward, which no stamp out of order shows (a 30 s step of a detection topic's clock left
    its later frames 30 s off the velocities' without a word). ``(step ns, record ns of the first message after
    it)``; ``(0, 0)`` when none. A recorder that stalls and then writes a burst moves the record times, not ahead of
    them; a gap in both clocks moves neither. A step needs ``STEP_SIDE`` messages either side: a stale first stamp
    (nav2's first /amcl_pose, 4.9 s older than the next) is no clock."""
    if t_ns.shape[0] < 2 * STEP_SIDE:
        return 0, 0
    lag = t_ns - rec_ns
    jumps = np.diff(lag)
    jumps[: STEP_SIDE - 1] = jumps[jumps.shape[0] - STEP_SIDE + 1 :] = np.iinfo(np.int64).min
    k = int(np.argmax(jumps))
    if jumps[k] < CLOCK_STEP_NS or np.median(lag[k + 1 :]) - np.median(lag[: k + 1]) < CLOCK_STEP_NS:
        return 0, 0
    return int(jumps[k]), int(rec_ns[k + 1])


def clock_steps(step_back_ns: int, step_forward_ns: int) -> bool:
    """A header clock set back (a step back of ``CLOCK_STEP_NS`` or more) or set forward (:func:`clock_step_forward`)
    mid-log: no reading of its header stamps is right (set back 5 s, every MR.CLAM topic's samples of those 5 s
    interleave with the next 5 s'; riekf lost the log), so a run that reads header stamps reads record time for every
    topic instead (``readers._with_clocks``)."""
    return step_back_ns >= CLOCK_STEP_NS or step_forward_ns > 0


def out_of_order_text(count: int, step_back_ns: int) -> str:
    """Out-of-order stamps in run's notes and info's warnings alike: a step back of ``CLOCK_STEP_NS`` or more (not
    a driver's jitter) is named with its size, a clock set back."""
    text = plural(count, "out-of-order stamp")
    if step_back_ns >= CLOCK_STEP_NS:
        text += f" (a step back of {step_back_ns * 1e-9:.3f} s: a clock set back? time.source: auto or record)"
    return text


def clock_step_text(step_ns: int, at_s: float) -> str:
    """The words of a :func:`clock_step_forward` step, alike in run's notes and info's warnings."""
    return (
        f"header stamps jump {step_ns * 1e-9:.3f} s ahead of record time {at_s:.1f} s into the topic (a clock set "
        "forward? time.source: record, or the topic in time.topics: record, reads record time)"
    )


#: Header stamps advancing this many times faster or slower than the record times of the same messages are on
#: another unit (milliseconds or microseconds written as seconds, nanoseconds as microseconds), not on a clock.
STAMP_PACE_FACTOR = 100.0


def stamp_pace(t: np.ndarray, rec: np.ndarray) -> float | None:
    """How fast the header stamps advance against the record times (1: as fast), the median over stretches of the
    recording of ~1 s (up to 20; so that a clock jump, a recorder's bursts and a gap sway one stretch at most);
    None when no stretch spans 0.2 s of recording (or fewer than 20 stamps)."""
    if t.shape[0] < 20:
        return None
    order = np.argsort(rec, kind="stable")
    t, rec = t[order], rec[order]
    stretches = int(np.clip((int(rec[-1]) - int(rec[0])) // 1_000_000_000, 1, 20))
    bounds = np.linspace(0, t.shape[0] - 1, min(stretches, t.shape[0] // 10) + 1).astype(np.int64)
    d_rec = np.diff(rec[bounds]).astype(np.float64)
    d_t = np.diff(t[bounds]).astype(np.float64)
    keep = d_rec >= 2e8
    if not keep.any():
        return None
    return float(np.median(d_t[keep] / d_rec[keep]))


def off_pace(paces: dict[str, float | None]) -> dict[str, float]:
    """The topics whose header stamps advance ``STAMP_PACE_FACTOR`` times faster or slower than the log's other
    topics' (their :func:`stamp_pace` over the median of all): topic -> that ratio. Measured against the other
    topics, not against record time alone: a converter that wrote an hour of messages in a few seconds puts every
    topic off the record clock's pace, and the stamps are right. One topic alone is never off."""
    known = {topic: p for topic, p in paces.items() if p is not None and p > 0}
    if len(known) < 2:
        return {}
    ref = float(np.median(list(known.values())))
    return {topic: p / ref for topic, p in known.items() if not 1 / STAMP_PACE_FACTOR < p / ref < STAMP_PACE_FACTOR}


def duplicates_text(duplicates: int, distinct: int, done: str = "") -> str:
    """``N exact duplicates`` (+ ``done``); when every message is there twice or more (a driver or recorder
    publishing twice), said so: the stream is its distinct samples, at their rate, as a log holding each once.
    ``distinct``: the messages left once each (0: not known)."""
    text = plural(duplicates, "exact duplicate") + done
    if distinct and duplicates >= distinct:
        times = "twice" if duplicates == distinct else "twice or more"
        text += (
            f" (every message recorded {times}: a driver publishing twice? the stream is its {distinct} distinct "
            "samples, read as a log holding each once)"
        )
    return text


@dataclass
class Cleaning:
    """What cleaning did to a stream; rendered into LogStreams.warnings."""

    nonfinite: int = 0
    out_of_order: int = 0
    duplicates: int = 0
    repeated: int = 0
    zero_stamps: bool = False
    step_back_ns: int = 0  # the largest step back between consecutive stamps (record order)
    step_forward: tuple[int, int] = (0, 0)  # a header clock set forward: clock_step_forward, at from the first
    #: (stamps 0, stamps) when some but not all header stamps are 0 (left unset by a publisher: each a step back to
    #: the epoch, no clock), and the step back and forward of the set stamps alone (what a clock did)
    unset: tuple[int, int] = (0, 0)
    set_step_back_ns: int = 0
    set_step_forward: tuple[int, int] = (0, 0)
    kept: int = 0  # samples left (clean_order's streams; 0: not counted)
    extra: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # said as warnings, apart from :meth:`text`

    def count_order(self, t_ns: np.ndarray, rec_ns: np.ndarray) -> None:
        """Count the stamps (in record order) earlier than the one before, the largest step back, and a step of
        the header clock ahead of the record times."""
        steps = np.diff(t_ns)
        self.out_of_order = int(np.count_nonzero(steps < 0))
        self.step_back_ns = int(-steps.min()) if self.out_of_order else 0
        step, at = clock_step_forward(t_ns, rec_ns)
        self.step_forward = (step, at - int(rec_ns.min())) if step else (0, 0)
        zero = t_ns == 0
        if zero.any() and not zero.all():
            self.unset = (int(np.count_nonzero(zero)), int(t_ns.shape[0]))
            steps = np.diff(t_ns[~zero])
            self.set_step_back_ns = int(max(0, -steps.min())) if steps.size else 0
            step, at = clock_step_forward(t_ns[~zero], rec_ns[~zero])
            self.set_step_forward = (step, at - int(rec_ns.min())) if step else (0, 0)

    @property
    def clock_steps(self) -> bool:
        """Whether the header clock steps mid-log against record time (:func:`clock_steps`)."""
        return clock_steps(self.step_back_ns, self.step_forward[0]) and not self.zero_stamps

    @property
    def clock_set(self) -> bool:
        """Whether a header clock steps (:attr:`clock_steps`) beyond stamps left 0 (:attr:`unset`): the set stamps
        step too."""
        if not self.unset[0]:
            return self.clock_steps
        return clock_steps(self.set_step_back_ns, self.set_step_forward[0])

    def clock_step_words(self) -> str:
        """How the header clock steps (:attr:`clock_steps`): stamps left 0 (named as such, not as a step back to
        the epoch), back, ahead, or both."""
        back, forward, words = self.step_back_ns, self.step_forward, []
        if self.unset[0]:
            back, forward = self.set_step_back_ns, self.set_step_forward
            words.append(f"{self.unset[0]} of its {self.unset[1]} header stamps 0: left unset by its publisher?")
        if back >= CLOCK_STEP_NS:
            words.append(f"stamps step back {back * 1e-9:.3f} s")
        if forward[0]:
            words.append(f"jump {forward[0] * 1e-9:.3f} s ahead {forward[1] * 1e-9:.1f} s in")
        return ", ".join(words)

    def text(self, on_record_time: bool = False) -> str:
        """One warning fragment, empty when nothing happened. ``on_record_time``: the run reads the stream's record
        times (``time.source: record``, the topic's ``time.topics``), so what its header stamps do (all zero, out of
        order, repeated) is left out: it does not describe the run."""
        parts = []
        if self.zero_stamps and not on_record_time:
            parts.append("header stamps are all zero, using record time")
        if self.out_of_order and not on_record_time:
            step_back = 0 if self.zero_stamps else self.step_back_ns
            parts.append(out_of_order_text(self.out_of_order, step_back))
        if self.step_forward[0] and not on_record_time and not self.zero_stamps:
            parts.append(clock_step_text(self.step_forward[0], self.step_forward[1] * 1e-9))
        if self.duplicates:
            parts.append(duplicates_text(self.duplicates, self.kept, " dropped"))
        if self.repeated and not on_record_time:
            parts.append(repeated_text(self.repeated))
        if self.nonfinite:
            parts.append(nonfinite_text(self.nonfinite))
        return ", ".join(parts + self.extra)


def nonfinite_text(n: int) -> str:
    """What cleaning says of a stream's ``n`` samples that hold a NaN or Inf (a run's note; ``info`` says it ahead)."""
    return plural(n, "NaN/Inf sample") + " dropped"


def _deserialize(reader: AnyReader, path: str | Path, raw: bytes, conn: Connection) -> Any:
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as err:  # rosbags raises struct/index errors on bad payloads too
        if (machine := resource_error(err, path, "decoding the log")) is not None:
            raise machine from None
        reason = one_line(err) or type(err).__name__
        raise InputError(path, f"cannot decode {conn.msgtype} message: {reason}", conn.topic) from None


def decoded_messages(
    reader: AnyReader,
    path: str | Path,
    connections: Collection[Connection],
) -> Iterator[tuple[int, Any]]:
    """``(record_ns, message)`` of ``connections``, definitions checked first."""
    require_definitions(reader, path, connections)
    for conn, rec_ns, raw in iter_raw(reader, path, connections):
        yield rec_ns, _deserialize(reader, path, raw, conn)


@contextmanager
def layout_errors(path: str | Path, connections: Collection[Connection]) -> Iterator[None]:
    """A type whose stored definition lacks the fields we read (same name, other layout) is bad input."""
    try:
        yield
    except (AttributeError, TypeError, ValueError) as err:
        conn = next(iter(connections))
        reason = one_line(err)
        raise InputError(path, f"unexpected {conn.msgtype} layout: {reason}", conn.topic) from None


def _stamp(msg: Any) -> int:
    stamp = msg.header.stamp
    return stamp.sec * _NS + stamp.nanosec


def decode_rows(reader: AnyReader, path: str | Path, topic: str, connections: Collection[Connection]) -> Rows:
    """Decode a topic of a type in ``LAYOUTS`` into columns.

    Types whose fields sit at computable offsets (all of ``LAYOUTS`` as defined in ROS) are decoded
    chunk-wise from the raw bytes by :mod:`.fastdecode`; anything else (a log's own variant behind a
    dynamic array, a row function that computes) is deserialised message by message by rosbags.
    """
    conns = list(connections)
    if (fast := fastdecode.read_rows(reader, path, {topic: conns}).get(topic)) is not None:
        return fast
    msgtype = conns[0].msgtype
    layout = LAYOUTS[msgtype]
    size = max(sum(c.msgcount for c in conns), 16)
    t_ns = np.empty(size, np.int64)
    rec_ns = np.empty(size, np.int64)
    values = np.empty((size, layout.width), np.float64)
    frame = np.empty(size, np.int32)
    child = np.zeros(size, np.int32)
    frames = Frames()
    row, child_of = layout.row, layout.child
    i = 0
    with layout_errors(path, conns):
        for rec, msg in decoded_messages(reader, path, conns):
            if i == size:  # counts in the index were short: grow
                size *= 2
                t_ns, rec_ns, frame, child = (np.resize(a, size) for a in (t_ns, rec_ns, frame, child))
                values = np.resize(values, (size, layout.width))
            t_ns[i] = _stamp(msg)
            rec_ns[i] = rec
            values[i] = row(msg)
            frame[i] = frames.code(msg.header.frame_id)
            if child_of is not None:
                child[i] = frames.code(child_of(msg))
            i += 1
    kept, stated = split_stated(msgtype, values[:i])
    return Rows(topic, msgtype, t_ns[:i], rec_ns[:i], kept, frame[:i], child[:i], frames.names(), stated=stated)


def duplicate_mask(t_sorted: np.ndarray, key: Callable[[int], bytes]) -> tuple[np.ndarray, int]:
    """Rows equal (same stamp, same key) to an earlier row of the same stamp; and repeated stamps kept.
    Public: tests/test_readers.py checks it on made-up keys."""
    drop = np.zeros(t_sorted.shape[0], bool)
    repeated = 0
    seen: set[bytes] = set()
    last = -2
    for i in np.flatnonzero(t_sorted[1:] == t_sorted[:-1]) + 1:
        if i != last + 1:
            seen = {key(i - 1)}
        last = i
        k = key(i)
        if k in seen:
            drop[i] = True
        else:
            seen.add(k)
            repeated += 1
    return drop, repeated


def repeated_text(repeated: int) -> str:
    """``N repeated stamps with different values`` (:func:`duplicate_mask`'s second count): a run's note and
    ``info`` say it in these words."""
    return plural(repeated, "repeated stamp") + " with different values"


def column_duplicates(t_ns: np.ndarray, cols: fastdecode.TopicColumns) -> tuple[int, int]:
    """Exact duplicates and repeated stamps among one topic's decoded messages (``cols``, record order) on the
    stamps ``t_ns``, judged by :func:`duplicate_mask` as a run judges its stream: two messages of one stamp are the
    same message when the values a run decodes of them are equal (a detection array's elements too), whatever their
    sequence numbers (ROS1's header ``seq``, a driver's own counter such as ``image_seq``); a topic decoded without
    values (no run reads it) by its payload's digest (ROS1: after the header ``seq``)."""
    order = np.argsort(t_ns, kind="stable")
    offsets = None if cols.counts is None or cols.items is None else _offsets(cols.counts)
    by_values = cols.values.shape[1] > 0 or offsets is not None or cols.digest is None

    def key(i: int) -> bytes:
        k = order[i]
        if not by_values:
            return cols.digest[k].tobytes()  # type: ignore[index]
        row = cols.values[k].tobytes()
        return row if offsets is None else row + cols.items[offsets[k] : offsets[k + 1]].tobytes()  # type: ignore[index]

    drop, repeated = duplicate_mask(t_ns[order], key)
    return int(np.count_nonzero(drop)), repeated


def _effective_stamps(t_ns: np.ndarray, rec_ns: np.ndarray, cleaning: Cleaning) -> np.ndarray:
    if t_ns.size and not t_ns.any():
        cleaning.zero_stamps = True
        return rec_ns
    return t_ns


def clean_order(t_ns: np.ndarray, rec_ns: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, Cleaning]:
    """Indices (into the record-ordered rows) of the clean stream, and the stamps to use.

    NaN/Inf rows are dropped, rows are stably sorted by stamp, and exact duplicates (same stamp, same
    values) are dropped; every step is counted.
    """
    cleaning = Cleaning()
    t_ns = _effective_stamps(t_ns, rec_ns, cleaning)
    finite = finite_rows(values)
    idx = np.flatnonzero(finite)
    cleaning.nonfinite = int(values.shape[0] - idx.size)
    kept_t = t_ns if not cleaning.nonfinite else t_ns[idx]
    cleaning.count_order(kept_t, rec_ns if not cleaning.nonfinite else rec_ns[idx])
    if cleaning.out_of_order:  # else the stable sort keeps every row in place
        idx = idx[np.argsort(kept_t, kind="stable")]
        kept_t = t_ns[idx]
    drop, cleaning.repeated = duplicate_mask(kept_t, lambda i: values[idx[i]].tobytes())
    cleaning.duplicates = int(drop.sum())
    cleaning.kept = idx.size - cleaning.duplicates
    return idx[~drop] if cleaning.duplicates else idx, t_ns, cleaning


def _dominant(
    codes: np.ndarray, names: list[str], cleaning: Cleaning, what: str = "frame id", placed: bool = False
) -> str:
    """Most common frame id; a topic mixing frames is reported: as a warning where the frame places what the
    topic measures (``placed``: detections, by their camera's extrinsic) and the frames differ by more than a
    leading '/', whose other frames' samples are then placed by the most common one's extrinsic."""
    if not codes.size:
        return names[0] if names else ""
    counts = np.bincount(codes, minlength=len(names))
    best = int(np.argmax(counts))
    if np.count_nonzero(counts) > 1:
        label = [name or "<empty>" for name in names]
        seen = ", ".join(f"{label[k]} {counts[k]}" for k in np.argsort(-counts) if counts[k])
        if placed and len({names[k].lstrip("/") for k in np.flatnonzero(counts)}) > 1:
            cleaning.warnings.append(
                f"its messages name {np.count_nonzero(counts)} {what}s ({seen}): every one is taken in "
                f"{label[best]} (the most common) and placed by its extrinsic, so the others' detections are "
                "misplaced unless their frames coincide with it: split the topic by frame, or fix the driver's "
                "frame_id"
            )
            return names[best]
        cleaning.extra.append(f"{np.count_nonzero(counts)} {what}s ({seen}), using {label[best]}")
    elif not names[best]:
        cleaning.extra.append(f"empty {what}")
    return names[best]


#: Rows at most this wide are shared by the streams cut from them when no cleaning was needed (an IMU row holds the
#: gyro and the accelerometer; its stated variances are runs, ``Rows.stated``); wider rows (odometry) are copied so
#: unused columns can go.
SHARE_WIDTH = 6


def _is_identity(idx: np.ndarray, n: int) -> bool:
    """Whether cleaning kept every row in place (nothing dropped, already in order)."""
    return idx.shape[0] == n and (n == 0 or (int(idx[0]) == 0 and bool(np.all(np.diff(idx) == 1))))


#: A stream's note when every value is zero, and what a velocity stream that is all zero makes of the run.
ALL_ZERO = "all values are zero (field not filled by the publisher?)"
ZERO_MEANS = {
    "angular_velocity": ": the run takes the body as never turning",
    "linear_velocity": ": the run takes the body as never moving",
}


def vec3_stream(rows: Rows, role: str) -> tuple[Vec3Stream, Cleaning]:
    """The role's 3-vector out of decoded rows, cleaned; a clean stream shares the decoded arrays (no copy)."""
    frame_from = VEC3_ROLES[role, rows.msgtype][1]
    xyz = rows.values[:, role_columns(rows.msgtype, role)]
    idx, t_ns, cleaning = clean_order(rows.t_ns, rows.rec_ns, xyz)
    frame = _dominant((rows.child if frame_from == "child" else rows.frame)[idx], rows.frame_names, cleaning)
    kept_all = _is_identity(idx, xyz.shape[0])  # every row, in place: no gather of the rows
    if idx.size and not (xyz if kept_all else xyz[idx]).any():
        cleaning.extra.append(ALL_ZERO + ZERO_MEANS.get(role, ""))
    if kept_all and rows.values.shape[1] <= SHARE_WIDTH:
        return Vec3Stream(rows.topic, frame, t_ns, rows.rec_ns, xyz), cleaning
    stream = Vec3Stream(rows.topic, frame, t_ns[idx], rows.rec_ns[idx], np.ascontiguousarray(xyz[idx]))
    return stream, cleaning


def role_columns(msgtype: str, role: str) -> slice | None:
    """The columns of a ``LAYOUTS`` row that a run reads for ``role``: a 3-vector (:data:`VEC3_ROLES`), or a pose's
    position and quaternion (truth, of a pose type); None when the type gives the role nothing."""
    cols = LAYOUTS[msgtype].columns if msgtype in LAYOUTS else {}
    if (role, msgtype) in VEC3_ROLES:
        return cols[VEC3_ROLES[role, msgtype][0]]
    if role == "truth" and "position" in cols and "quat_xyzw" in cols:
        return slice(cols["position"].start, cols["quat_xyzw"].stop)
    return None


def _zero_quaternions(quat: np.ndarray) -> np.ndarray:
    """Rows of ``quat`` (N, 4) that are no rotation: every component finite and under 1e-6 (a column at a time)."""
    zero = finite_rows(quat)
    for c in range(quat.shape[1]):
        zero &= np.abs(quat[:, c]) < 1e-6
    return zero


def nonfinite_count(values: np.ndarray, msgtype: str, role: str) -> int:
    """How many of a topic's decoded rows ``values`` (``LAYOUTS[msgtype]``, record order) the run drops as NaN/Inf
    for ``role`` (:meth:`Cleaning.text`'s count: :func:`vec3_stream`'s, :func:`pose_stream`'s, whose zero
    quaternions are counted apart), without building the stream."""
    sl = role_columns(msgtype, role)
    if sl is None:
        return 0
    bad = ~finite_rows(values[:, sl])
    if (role, msgtype) not in VEC3_ROLES:
        bad &= ~_zero_quaternions(values[:, LAYOUTS[msgtype].columns["quat_xyzw"]])
    return int(np.count_nonzero(bad))


def pose_stream(rows: Rows) -> tuple[PoseStream, Cleaning]:
    """Stamped poses out of decoded pose rows (PoseStamped, PoseWithCovarianceStamped, TransformStamped,
    Odometry), cleaned; ``child_frame_id`` is ``''`` for types that do not name it."""
    layout = LAYOUTS[rows.msgtype]
    cols = layout.columns
    values = rows.values[:, cols["position"].start : cols["quat_xyzw"].stop]
    zero = _zero_quaternions(rows.values[:, cols["quat_xyzw"]])
    if nzero := int(np.count_nonzero(zero)):  # no rotation at all: dropped like NaN, counted apart
        values = np.where(zero[:, None], np.nan, values)
    idx, t_ns, cleaning = clean_order(rows.t_ns, rows.rec_ns, values)
    if nzero:
        cleaning.nonfinite -= nzero
        cleaning.extra.append(plural(nzero, "zero quaternion") + " dropped")
    frame = _dominant(rows.frame[idx], rows.frame_names, cleaning)
    child = _dominant(rows.child[idx], rows.frame_names, cleaning, "child frame id") if layout.child else ""
    stream = PoseStream(
        rows.topic,
        frame,
        child,
        t_ns[idx],
        rows.rec_ns[idx],
        np.ascontiguousarray(rows.values[idx, cols["position"]]),
        np.ascontiguousarray(rows.values[idx, cols["quat_xyzw"]]),
    )
    return stream, cleaning


def _render(notes: Notes) -> list[str]:
    return [f"{plural(n, noun)} {rest}" for (noun, rest), n in sorted(notes.items())]


def _apriltags(msg: Any, notes: Notes) -> Iterator[tuple[int, Any]]:
    """apriltag_ros: a detection lists one id, or several for a tag bundle (whose pose is the bundle origin)."""
    for det in msg.detections:
        ids = det.id
        if len(ids) == 0:
            notes["detection", "without id skipped"] += 1
            continue
        if len(ids) > 1:
            notes["bundle detection", "named by its first tag id"] += 1
        yield int(ids[0]), det.pose.pose.pose.position


#: Detection types with a header (one message = one frame, kept even when empty): message -> (id, position).
DETECTIONS: dict[str, Callable[[Any, Notes], Iterator[tuple[int, Any]]]] = {
    **{msgtype: layout.detections for msgtype, layout in ITEM_LAYOUTS.items()},
    APRILTAG_ROS: _apriltags,
}

_MARKER_ADD = 0  # visualization_msgs/Marker ADD (= MODIFY); DELETE and DELETEALL carry no detection


class _DetectionFrames:
    """Detection frames as they are decoded: per-frame stamp, record time, frame code, and the detections."""

    def __init__(self) -> None:
        self.t_ns: list[int] = []
        self.rec_ns: list[int] = []
        self.frame: list[int] = []
        self.lengths: list[int] = []
        self.ids: list[int] = []
        self.xyz: list[float] = []

    def add(self, t_ns: int, rec_ns: int, frame: int, items: Iterable[tuple[int, Any]]) -> None:
        n = len(self.ids)
        for ident, pos in items:
            self.ids.append(int(ident))
            self.xyz.extend(vec(pos))
        self.t_ns.append(t_ns)
        self.rec_ns.append(rec_ns)
        self.frame.append(frame)
        self.lengths.append(len(self.ids) - n)

    def stream(self, topic: str, frame_names: list[str], notes: Notes) -> tuple[DetectionStream, Cleaning]:
        stream, cleaning = _clean_detections(
            topic,
            np.asarray(self.t_ns, np.int64),
            np.asarray(self.rec_ns, np.int64),
            np.asarray(self.lengths, np.int64),
            np.asarray(self.ids, np.int64),
            np.asarray(self.xyz, np.float64).reshape(-1, 3),
            np.asarray(self.frame, np.int32),
            frame_names,
        )
        cleaning.extra += _render(notes)
        return stream, cleaning


def decode_detections(
    reader: AnyReader,
    path: str | Path,
    topic: str,
    connections: Collection[Connection],
    marker_ns: str | None = None,
) -> tuple[DetectionStream, Cleaning]:
    """Detection messages (``DETECTIONS`` types or ``MarkerArray``) as a CSR detection stream.

    A ``MarkerArray`` has no header: its ADD markers are grouped into frames by their own (stamp, frame id),
    and arrays without ADD markers are skipped. Marker ids are unique only within a namespace: ``marker_ns``
    keeps the markers of one namespace; without it, several namespaces on the topic are reported.
    """
    msgtype = next(iter(connections)).msgtype
    fast = (
        fastdecode.read_rows(reader, path, {topic: connections}, [topic]).get(topic)
        if msgtype in ITEM_LAYOUTS
        else None
    )
    if fast is not None:
        return detection_stream(fast)
    frames, acc, notes = Frames(), _DetectionFrames(), Notes()
    namespaces: set[str] = set()
    with layout_errors(path, connections):
        if msgtype == MARKER_ARRAY:
            for rec, msg in decoded_messages(reader, path, connections):
                groups: dict[tuple[int, str], list[tuple[int, Any]]] = {}
                for marker in msg.markers:
                    if marker.action != _MARKER_ADD:
                        notes["DELETE marker", "skipped"] += 1
                        continue
                    namespaces.add(marker.ns)
                    if marker_ns is not None and marker.ns != marker_ns:
                        notes["marker", f"of another namespace than {marker_ns!r} skipped"] += 1
                        continue
                    key = (_stamp(marker), marker.header.frame_id)
                    groups.setdefault(key, []).append((marker.id, marker.pose.position))
                for (stamp, frame), items in groups.items():
                    acc.add(stamp, rec, frames.code(frame), items)
        else:
            items_of = DETECTIONS[msgtype]
            for rec, msg in decoded_messages(reader, path, connections):
                acc.add(_stamp(msg), rec, frames.code(msg.header.frame_id), items_of(msg, notes))
    stream, cleaning = acc.stream(topic, frames.names(), notes)
    if marker_ns is None and len(namespaces) > 1:
        names = ", ".join(repr(n) for n in sorted(namespaces))
        cleaning.extra.append(
            f"markers of {len(namespaces)} namespaces ({names}) taken together although ids are "
            "unique only within one; choose one with frames.marker_namespace"
        )
    elif marker_ns is not None and marker_ns not in namespaces:
        names = ", ".join(repr(n) for n in sorted(namespaces)) or "none"
        raise InputError(
            path,
            f"frames.marker_namespace {marker_ns!r} names no namespace of its markers (namespaces: {names})",
            topic,
        )
    return stream, cleaning


def detection_stream(rows: Rows) -> tuple[DetectionStream, Cleaning]:
    """A detection stream out of the rows of a vectorised detection array (``ITEM_LAYOUTS``), cleaned."""
    assert rows.counts is not None and rows.items is not None
    layout = ITEM_LAYOUTS[rows.msgtype]
    if layout.ident is None:  # the index within the message
        ids = np.arange(rows.items.shape[0], dtype=np.int64) - np.repeat(_offsets(rows.counts)[:-1], rows.counts)
    else:
        ids = rows.items[:, 0].astype(np.int64)
    xyz = np.ascontiguousarray(rows.items[:, -3:])
    return _clean_detections(rows.topic, rows.t_ns, rows.rec_ns, rows.counts, ids, xyz, rows.frame, rows.frame_names)


def decode_topics(
    reader: AnyReader,
    path: str | Path,
    rows: Mapping[str, Collection[Connection]],
    detections: Mapping[str, Collection[Connection]],
    marker_ns: str | None = None,
) -> tuple[dict[str, Rows], dict[str, Rows | tuple[DetectionStream, Cleaning]]]:
    """``decode_rows`` of ``rows`` and the detection topics, every topic that can be decoded from the bytes in
    one pass over the log (each chunk decompressed once), the others through rosbags. A detection topic comes
    back as rows for :func:`detection_stream` (decoded from the bytes; cleaned when the caller is ready for it)
    or as the stream :func:`decode_detections` made."""
    fast = fastdecode.read_rows(
        reader,
        path,
        {**rows, **detections},
        [t for t, c in detections.items() if next(iter(c)).msgtype in ITEM_LAYOUTS],
    )
    got_rows = {t: fast[t] if t in fast else decode_rows(reader, path, t, c) for t, c in rows.items()}
    got_dets = {
        t: fast[t] if t in fast else decode_detections(reader, path, t, c, marker_ns) for t, c in detections.items()
    }
    return got_rows, got_dets


def _offsets(lengths: np.ndarray) -> np.ndarray:
    return np.concatenate(([0], np.cumsum(lengths))).astype(np.int64)


def _clean_detections(
    topic: str,
    t_ns: np.ndarray,
    rec_ns: np.ndarray,
    lengths: np.ndarray,
    ids: np.ndarray,
    xyz: np.ndarray,
    frame: np.ndarray,
    frame_names: list[str],
) -> tuple[DetectionStream, Cleaning]:
    """Drop NaN detections and repeated ids within a frame, sort frames by stamp, drop duplicate frames."""
    t_ns, rec_ns, offsets, ids, xyz, frame_id, cleaning = clean_frames(
        t_ns, rec_ns, lengths, ids, xyz, frame, frame_names
    )
    return DetectionStream(topic, frame_id, t_ns, rec_ns, offsets, ids, xyz), cleaning


def shared_id_text(ids: np.ndarray, apart: np.ndarray, seen: int) -> str:
    """The warning on repeated ids within a frame that lie apart (:func:`blocks.far_repeats`), without its topic;
    ``seen``: the frames that hold those ids. Two tags on one id repeat in every frame that sees both; an id
    misread repeats where the misread tag is in view beside the one whose id it took (1 % of the ids misread at
    random: id 33 twice in 1 of the 217 frames holding it, and the warning named only two tags sharing the id),
    so both are named."""
    ids = np.unique(ids)
    return (
        f"id{'s' if ids.size > 1 else ''} {', '.join(str(v) for v in ids[:5])}{' ...' if ids.size > 5 else ''} seen "
        f"twice in {apart.size} of the {seen} frames holding it, {float(np.median(apart)):.3g} m apart (median): two "
        "tags share the id (two tag families or dictionaries, or an id reused), so its landmark's detections mix two "
        "places, or another tag's id was misread there (a decoding error; then only those detections are wrong); the "
        "second of each frame is dropped, the rest used as read: give the tags distinct ids (or read one family only)"
    )


def clean_frames(
    t_ns: np.ndarray,
    rec_ns: np.ndarray,
    lengths: np.ndarray,
    ids: np.ndarray,
    values: np.ndarray,
    frame: np.ndarray,
    frame_names: list[str],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, str, Cleaning]:
    """Detection frames (CSR: ``lengths`` per frame, ``ids`` and ``values`` rows per detection) cleaned: NaN
    detections and repeated ids within a frame dropped, frames sorted by stamp, duplicate frames dropped.
    Returns stamps, record times, offsets, ids, values, the dominant frame id and what was done."""
    cleaning = Cleaning()
    t_ns = _effective_stamps(t_ns, rec_ns, cleaning)
    nframes = t_ns.shape[0]
    owner = np.repeat(np.arange(nframes), lengths)
    flat = values.reshape(values.shape[0], int(np.prod(values.shape[1:])))

    # (arrays are copied only where something is dropped or moved: an hour of detections is tens of MB)
    finite = finite_rows(flat)
    cleaning.nonfinite = int(finite.size - np.count_nonzero(finite))
    if cleaning.nonfinite:
        ids, values, flat, owner = ids[finite], values[finite], flat[finite], owner[finite]
    del finite
    same = repeated_pairs(owner, ids)  # the first detection of an id in a frame is kept
    if nsame := int(np.count_nonzero(same)):
        cleaning.extra.append(plural(nsame, "repeated id") + " within a frame dropped")
        if values.ndim == 2 and values.shape[1] == 3:  # positions (not corners): two tags sharing an id said
            far_ids, apart, seen = far_repeats(owner, ids, values)
            if far_ids.size:
                cleaning.warnings.append(shared_id_text(far_ids, apart, seen))
        ids, values, flat, owner = ids[~same], values[~same], flat[~same], owner[~same]
    del same
    lengths = np.bincount(owner, minlength=nframes).astype(np.int64)
    del owner
    offsets = _offsets(lengths)

    cleaning.count_order(t_ns, rec_ns)
    forder = np.argsort(t_ns, kind="stable")

    def key(i: int) -> bytes:
        f = forder[i]
        return ids[offsets[f] : offsets[f + 1]].tobytes() + flat[offsets[f] : offsets[f + 1]].tobytes()

    drop, cleaning.repeated = duplicate_mask(t_ns[forder], key)
    cleaning.duplicates = int(drop.sum())
    forder = forder[~drop]
    cleaning.kept = int(forder.shape[0])  # frames: the note says when every one was there twice, as info does

    frame_id = _dominant(frame[forder], frame_names, cleaning, placed=True)
    if forder.shape[0] == nframes and bool(np.all(np.diff(forder) == 1)):  # every frame, in order: keep as is
        return t_ns[forder], rec_ns[forder], offsets, ids, np.ascontiguousarray(values), frame_id, cleaning
    sel_len = lengths[forder]
    new_offsets = _offsets(sel_len)
    gather = np.repeat(offsets[:-1][forder] - new_offsets[:-1], sel_len) + np.arange(new_offsets[-1])
    return (
        t_ns[forder],
        rec_ns[forder],
        new_offsets,
        ids[gather],
        np.ascontiguousarray(values[gather]),
        frame_id,
        cleaning,
    )


#: TF topics with at least this many messages are decoded by :mod:`.tfdecode` (rosbags takes ~40 µs a message).
TF_FAST_MESSAGES = 1000


def decode_tf(
    reader: AnyReader,
    path: str | Path,
    topic: str,
    connections: Collection[Connection],
    fast_from: int | None = None,
) -> TfRows:
    """Flatten the transforms of a TF topic into columns (each message may hold many edges).

    The standard TF layouts are decoded batch-wise from the raw bytes by :mod:`.tfdecode`; a log whose stored
    definition differs, and a topic of fewer than ``fast_from`` messages (default ``TF_FAST_MESSAGES``, read at the
    call; ``/tf_static``, a few tag frames: rosbags reads them in milliseconds, and their compiled decoder need not
    be loaded or compiled), are deserialised message by message by rosbags (the same values and frame numbering).
    """
    if sum(c.msgcount for c in connections) >= (TF_FAST_MESSAGES if fast_from is None else fast_from):
        if (fast := tfdecode.read_tf(reader, path, topic, connections)) is not None:
            return fast
    frames = Frames()
    t_ns: list[int] = []
    rec_ns: list[int] = []
    parent: list[int] = []
    child: list[int] = []
    values: list[tuple[float, ...]] = []
    with layout_errors(path, connections):
        for rec, msg in decoded_messages(reader, path, connections):
            for tf in msg.transforms:
                t_ns.append(_stamp(tf))
                rec_ns.append(rec)
                parent.append(frames.code(tf.header.frame_id))
                child.append(frames.code(tf.child_frame_id))
                values.append((*vec(tf.transform.translation), *quat(tf.transform.rotation)))
    return TfRows(
        topic,
        np.asarray(t_ns, np.int64),
        np.asarray(rec_ns, np.int64),
        np.asarray(parent, np.int32),
        np.asarray(child, np.int32),
        np.asarray(values, np.float64).reshape(-1, 7),
        frames.names(),
    )


def _valid_transforms(values: np.ndarray) -> np.ndarray:
    """Finite rows with a usable quaternion (a zero quaternion is how some publishers say 'unknown')."""
    return np.isfinite(values).all(axis=1) & (np.linalg.norm(values[:, 3:7], axis=1) > 1e-6)


#: how many characters of frame pairs a warning names: more are counted, the first named, run.json lists all
PAIRS_SHOWN_CHARS = 50


def frame_pairs(edges: Sequence[tuple[str, str]], where: str) -> str:
    """``edges`` as a warning names them: all when they are few, else their count, the first that fit in
    :data:`PAIRS_SHOWN_CHARS` and where run.json lists them all (``where``: the key under ``input``)."""
    names = [f"{p}->{c}" for p, c in edges]
    text = ", ".join(names)
    if len(text) <= PAIRS_SHOWN_CHARS:
        return text
    shown = names[:1]
    for name in names[1:]:
        if len(", ".join([*shown, name])) > PAIRS_SHOWN_CHARS:
            break
        shown.append(name)
    return f"{len(names)} frame pairs ({', '.join(shown)}, ...; run.json: input.{where} lists all)"


def static_transforms(
    rows: TfRows,
) -> tuple[list[Transform], list[str], dict[tuple[str, str], str], list[tuple[str, str]]]:
    """``/tf_static`` transforms, the last one per (parent, child) pair winning; the warnings; the (parent, child)
    pairs dropped as NaN/Inf, each with its warning (for an error that later misses one of those frames); the pairs
    published with different values."""
    found: dict[tuple[str, str], Transform] = {}
    changed: dict[tuple[str, str], list[int]] = {}  # pair -> its rows, in record order
    rows_of: dict[tuple[str, str], list[int]] = {}
    ok = _valid_transforms(rows.values)
    names = rows.frame_names
    for i in np.flatnonzero(ok):
        key = (names[rows.parent[i]], names[rows.child[i]])
        translation, quat = rows.values[i, :3].copy(), rows.values[i, 3:].copy()
        old = found.get(key)
        rows_of.setdefault(key, []).append(int(i))
        if old is not None and not (
            np.array_equal(old.translation, translation) and np.array_equal(old.quat_xyzw, quat)
        ):
            changed[key] = rows_of[key]
        found[key] = Transform(*key, translation, quat)
    warnings: list[str] = []
    dropped: dict[tuple[str, str], str] = {}
    if changed:
        warnings.append(static_change_text(rows, changed))
    nonfinite = ~np.isfinite(rows.values).all(axis=1)
    kinds = ((nonfinite, "NaN/Inf static transform", ""), (~ok & ~nonfinite, "static transform", _ZERO_QUATERNION))
    for rows_of_kind, kind, why in kinds:
        if nbad := int(np.count_nonzero(rows_of_kind)):
            edges = sorted({(names[rows.parent[i]], names[rows.child[i]]) for i in np.flatnonzero(rows_of_kind)})
            warnings.append(f"{plural(nbad, kind)}{why} dropped: {frame_pairs(edges, 'static_tf_dropped')}")
            dropped.update(dict.fromkeys(edges, warnings[-1]))
    return list(found.values()), warnings, dropped, sorted(changed)


#: the words that start the warning of :func:`static_change_text` (the readers say it as a warning)
STATIC_CHANGED = "static transforms published with different values, using the last"


def static_change_text(rows: TfRows, changed: Mapping[tuple[str, str], list[int]]) -> str:
    """The warning of ``/tf_static`` pairs published with different values (``changed``: pair -> its rows in record
    order): how far the values lie from the last one, the one every sample is taken with (turned, moved), and when
    the last took over. A camera's extrinsic republished 23 deg and 0.3 m apart 20 s in was named with neither
    size nor time, riekf's APE 0.76 m where either value alone gives 0.011 m."""
    sizes = []
    for key, idx in changed.items():
        vals = rows.values[idx]
        turned = float(np.degrees(quat_angles_to(vals[:, 3:], vals[-1, 3:])).max())
        moved = float(np.linalg.norm(vals[:, :3] - vals[-1, :3], axis=1).max())
        other = np.flatnonzero(~(vals == vals[-1]).all(axis=1))
        since = (rows.rec_ns[idx[other[-1] + 1]] - rows.rec_ns[idx[0]]) * 1e-9
        sizes.append((turned, moved, since, key))
    turned, moved, since, worst = max(sizes)
    pairs = frame_pairs(sorted(changed), "static_tf_changed")
    at = f"{worst[0]}->{worst[1]}: " if len(changed) > 1 else ""
    return (
        f"{STATIC_CHANGED}: {pairs} ({at}turned up to {turned:.1f} deg, moved up to {moved:.3f} m, the last value "
        f"from {since:.1f} s after the first): every sample is taken with the last, as tf2 gives a static transform; "
        "if that frame moved mid-log, the samples before are taken in a wrong frame and the estimate is off "
        "(time.start and time.end run one value's span); if a calibration was republished, the last is right"
    )


def static_tf_notes(topic: str, warnings: Iterable[str]) -> list[str]:
    """``/tf_static``'s warnings as run and info say them: the topic named, a pair published with different values
    (:func:`static_change_text`) said as a warning."""
    return [f"{'warning: ' * w.startswith(STATIC_CHANGED)}{topic}: {w}" for w in warnings]


#: what a transform with a zero quaternion (its norm under 1e-6: how some publishers say 'unknown') is, where it is
#: dropped: no rotation, so no transform
_ZERO_QUATERNION = " with a zero quaternion (0, 0, 0, 0: not a rotation)"


def decode_static_tf(
    reader: AnyReader,
    path: str | Path,
    connections: Collection[Connection],
) -> tuple[list[Transform], list[str]]:
    """Transforms of the ``/tf_static`` messages, the last one per (parent, child) pair winning."""
    topic = next(iter(connections)).topic
    found, warnings, _, _ = static_transforms(decode_tf(reader, path, topic, connections))
    return found, warnings


def transform_series(rows: TfRows, on_record_time: bool = False) -> tuple[list[TransformSeries], list[str]]:
    """``/tf`` edges as time series, each cleaned like a stream (sorted, duplicates and invalid rows dropped).

    Two different transforms of one edge at one stamp keep the first, as tf2 does (``TF_REPEATED_DATA``).
    ``on_record_time``: the run reads the edges on their record times (``time.source: record``), so they are
    sorted and cleaned on those, and the warnings say nothing of the header stamps (as :meth:`Cleaning.text`).
    """
    series: list[TransformSeries] = []
    reports: dict[str, list[str]] = {}  # cleaning text -> edges
    names = rows.frame_names
    edge_key = rows.parent.astype(np.int64) * len(names) + rows.child
    by_edge = np.argsort(edge_key, kind="stable")  # record order kept within an edge
    bounds = np.flatnonzero(np.diff(edge_key[by_edge])) + 1
    for sel in np.split(by_edge, bounds) if by_edge.size else ():
        values = rows.values[sel]
        values = np.where(_valid_transforms(values)[:, None], values, np.nan)  # invalid quaternions as NaN
        rec = rows.rec_ns[sel]
        idx, t_ns, cleaning = clean_order(rec if on_record_time else rows.t_ns[sel], rec, values)
        t = t_ns[idx]
        first = np.concatenate(([True], t[1:] != t[:-1])) if t.size else np.zeros(0, bool)
        if cleaning.repeated:
            cleaning.repeated = 0
            cleaning.extra.append(plural(int(np.count_nonzero(~first)), "repeated stamp") + " dropped (first kept)")
        idx = idx[first]
        parent, child = names[rows.parent[sel[0]]], names[rows.child[sel[0]]]
        vals = rows.values[sel][idx]
        series.append(
            TransformSeries(
                rows.topic,
                parent,
                child,
                t_ns[idx],  # on_record_time: the record times, the clock every reader of the run takes
                rec[idx],
                np.ascontiguousarray(vals[:, :3]),
                np.ascontiguousarray(vals[:, 3:]),
            ),
        )
        if text := cleaning.text():
            reports.setdefault(text, []).append(f"{parent}->{child}")
    warnings = []
    for text, edges in reports.items():
        shown = ", ".join(edges[:4]) + (", ..." if len(edges) > 4 else "")
        warnings.append(f"{text} ({plural(len(edges), 'edge')}: {shown})" if len(edges) > 1 else f"{edges[0]}: {text}")
    return series, warnings


def tag_regex(pattern: str, path: str | Path = "") -> re.Pattern[str]:
    """``"tag_{id}"`` -> a regex matching whole frame names and capturing the integer id.

    Raises:
        InputError: The pattern does not hold ``{id}`` exactly once.

    """
    if pattern.count("{id}") != 1:
        raise InputError(path, f"tag frame pattern {pattern!r} must contain {{id}} exactly once (e.g. 'tag_{{id}}')")
    before, _, after = frame_name(pattern).partition("{id}")
    return re.compile(f"^{re.escape(before)}(-?[0-9]+){re.escape(after)}$")


def tag_detections(rows: TfRows, pattern: str, path: str | Path = "") -> tuple[DetectionStream, Cleaning]:
    """TF tag frames (children named by ``pattern``) as detections in their parent frame (the camera).

    Tag frames are grouped into detection frames by (stamp, parent): a detector may publish one TF message per
    tag. Only the most common parent is kept; tags under other parents are dropped and counted.
    """
    regex = tag_regex(pattern, path)
    tag_id = {code: int(m.group(1)) for code, name in enumerate(rows.frame_names) if (m := regex.match(name))}
    if huge := [rows.frame_names[c] for c, i in tag_id.items() if not -(2**63) <= i < 2**63]:
        raise InputError(
            path,
            f"TF tag frame {huge[0][:60]!r} has an id outside the 64-bit integers that landmark ids "
            f"are ({len(huge)} such frame(s)): not a tag id; narrow frames.tag_pattern",
            rows.topic,
        )
    sel = np.flatnonzero(np.isin(rows.child, list(tag_id)))
    if sel.size == 0:
        shown = ", ".join(sorted(set(rows.frame_names))[:8]) or "none"
        raise InputError(path, f"no TF frame matches tag frame pattern {pattern!r} (frames: {shown})", rows.topic)
    notes = Notes()
    parents = np.bincount(rows.parent[sel], minlength=len(rows.frame_names))
    parent = int(np.argmax(parents))
    if other := int(sel.size - parents[parent]):
        notes["tag transform", f"under another parent than {rows.frame_names[parent]} dropped"] = other
        sel = sel[rows.parent[sel] == parent]
    t_ns = _effective_stamps(rows.t_ns[sel], rows.rec_ns[sel], Cleaning())
    order = np.lexsort((rows.child[sel], t_ns))  # stable: record order within a stamp and tag
    sel, t_ns = sel[order], t_ns[order]
    same = (t_ns[1:] == t_ns[:-1]) & (rows.child[sel][1:] == rows.child[sel][:-1])
    same &= (rows.values[sel][1:] == rows.values[sel][:-1]).all(axis=1)
    if ndup := int(np.count_nonzero(same)):  # a re-sent TF message: not a repeated detection
        notes["exact duplicate", ""] = ndup
        keep = np.concatenate(([True], ~same))
        sel, t_ns = sel[keep], t_ns[keep]
    starts = np.flatnonzero(np.concatenate(([True], t_ns[1:] != t_ns[:-1])))
    lengths = np.diff(np.append(starts, sel.size)).astype(np.int64)
    ids = np.array([tag_id[c] for c in rows.child[sel]], np.int64)
    stream, cleaning = _clean_detections(
        rows.topic,
        t_ns[starts],
        rows.rec_ns[sel][starts],
        lengths,
        ids,
        np.ascontiguousarray(rows.values[sel, :3]),
        np.full(starts.size, parent, np.int32),
        rows.frame_names,
    )
    cleaning.duplicates += notes.pop(("exact duplicate", ""), 0)
    cleaning.extra += _render(notes)
    return stream, cleaning


def _vector3(value: object, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        msg = f"{what} must be 3 finite numbers"
        raise ValueError(msg)
    return arr


def decode_sim_truth(
    reader: AnyReader,
    path: str | Path,
    topic: str,
    connections: Collection[Connection],
) -> tuple[dict[int, np.ndarray], dict[str, np.ndarray], list[str], dict[str, object]]:
    """Landmark and bias truth of a simulated log (JSON in a ``std_msgs/String``; the last message wins), and
    what the simulator recorded for reading the log (:func:`recorded_settings`)."""
    with layout_errors(path, connections):
        texts = [str(msg.data) for _, msg in decoded_messages(reader, path, connections)]
    if not texts:
        return {}, {}, [], {}
    warnings = [f"{topic}: {len(texts)} messages, using the last"] if len(texts) > 1 else []
    try:
        doc = json.loads(texts[-1])
        if not isinstance(doc, dict):
            msg = "expected a JSON object"
            raise TypeError(msg)
        landmarks = {int(k): _vector3(v, f"landmark {k}") for k, v in dict(doc.get("landmarks", {})).items()}
        bias = {
            name: _vector3(doc[key], key)
            for name, key in (("gyro", "gyro_bias"), ("velocity", "velocity_bias"))
            if key in doc
        }
        recorded = recorded_settings(doc)
    except (ValueError, TypeError) as err:
        reason = one_line(err)
        raise InputError(path, f"invalid simulation truth JSON: {reason}", topic) from None
    except RecursionError:  # json's decoder recurses per level: '[' * 100000 does not end in a clean error
        raise InputError(path, "invalid simulation truth JSON: nested too deeply", topic) from None
    return landmarks, bias, warnings, recorded


def recorded_settings(doc: dict) -> dict[str, object]:
    """The tag size (m, a positive number) and family a simulated log's truth document records for its camera."""
    out: dict[str, object] = {}
    size = doc.get("tag_size")
    if size is not None:
        size = float(size)
        if not (np.isfinite(size) and size > 0):
            raise ValueError(f"tag_size must be a positive number, got {doc['tag_size']!r}")
        out["tag_size"] = size
    if doc.get("tag_family") is not None:
        out["tag_family"] = str(doc["tag_family"])
    return out


# --- header scan (inspect) -------------------------------------------------------------------------

_ROS1_HEADER = struct.Struct("<III")  # sec, nsec, frame_id length (after the uint32 seq)
_CDR_HEADER = {True: struct.Struct("<iII"), False: struct.Struct(">iII")}


def has_header(reader: AnyReader, msgtype: str) -> bool:
    """Whether messages of ``msgtype`` start with a ``std_msgs/Header`` (so stamps can be read raw)."""
    fielddef = reader.typestore.fielddefs.get(msgtype)
    if not fielddef or not fielddef[1]:
        return False
    return fielddef[1][0][1][1] == HEADER


@dataclass
class HeaderScan:
    """Header stamps and frame ids of one topic, read straight from the serialised bytes."""

    t_ns: np.ndarray  # (N,) int64 in record order
    frames: Counter[str]
    duplicates: int  # same stamp and byte-identical payload (ROS1 seq ignored)


def scan_headers(reader: AnyReader, path: str | Path, connections: Collection[Connection]) -> HeaderScan:
    """Read stamps and frame ids without deserialising whole messages (fast for images and clouds)."""
    size = max(sum(c.msgcount for c in connections), 1)
    t_ns = np.empty(size, np.int64)
    frames: Counter[str] = Counter()
    seen: set[tuple[int, int]] = set()
    duplicates = 0
    is2 = reader.is2
    i = 0
    for conn, _, raw in iter_raw(reader, path, connections):
        try:
            if is2:
                sec, nsec, length = _CDR_HEADER[bool(raw[1] & 1)].unpack_from(raw, 4)
                frame = bytes(raw[16 : 16 + max(length - 1, 0)])
                body = hash(bytes(raw))
            else:
                sec, nsec, length = _ROS1_HEADER.unpack_from(raw, 4)
                frame = bytes(raw[16 : 16 + length])
                body = hash(bytes(raw[4:]))
        except (struct.error, IndexError):
            raise InputError(path, f"cannot decode {conn.msgtype} header: message too short", conn.topic) from None
        if i == size:
            size *= 2
            t_ns = np.resize(t_ns, size)
        stamp = sec * _NS + nsec
        t_ns[i] = stamp
        i += 1
        frames[frame_name(frame.decode(errors="replace"))] += 1
        if (stamp, body) in seen:
            duplicates += 1
        else:
            seen.add((stamp, body))
    return HeaderScan(t_ns[:i], frames, duplicates)
