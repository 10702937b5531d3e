"""``slamobs info``: what a log holds and how its clocks behave, so a user can pick topics and a time source.

Stamps and frame ids are read straight from the serialised header bytes of every topic at once
(:mod:`.fastdecode`, one pass over the file); messages are never fully deserialised, so logs with
images stay quick to inspect.

Clocks: each message has a header stamp (when the sensor measured) and a record time (when the
recorder wrote it). Per topic this reports whether the header clock is zero, simulation time (before
2000) or wall clock, the median header-minus-record offset and its spread, the offset relative to a
reference topic (the angular-velocity topic), out-of-order, duplicate and repeated stamps, gaps and
rate changes, and recommends a time source per topic (:func:`recommend_clocks`). A topic whose header
clock disagrees with the reference's is measured on record time when the reference's header clock
follows record time, and if it does not, every topic is (record time is then the only common clock).
:func:`apply_clocks` puts the choice into decoded streams.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Any

import numpy as np

from slamobs.pipeline.errors import InputError, plural
from slamobs.pipeline.streams import DetectionStream, LogStreams, PoseStream, Vec3Stream

from .container import LABELS, damage_notes, detect_container, open_log
from .decode import (
    Cleaning,
    CLOCK_STEP_NS,
    clock_steps,
    clock_step_text,
    out_of_order_text,
    decode_sim_truth,
    decode_static_tf,
    static_tf_notes,
    duplicates_text,
    column_duplicates,
    repeated_text,
    gyro_not_filled,
    first_vectors,
    gyro_stand_in,
    has_header,
    nonfinite_count,
    nonfinite_text,
    role_columns,
    off_pace,
    stamp_pace,
)
from .fastdecode import FRAME_ID, TopicColumns, item_plan_for, make_plan, plan_for, read_columns
from .msgdefs import complete_definitions
from .roles import ODOMETRY, ROLE_TOPIC_NAMES, ROLES, TF_TYPES, select_roles, topics_of
from .rows import frame_name
from .tf_tree import TfSummary, tf_summary

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping
    from pathlib import Path

    from rosbags.highlevel import AnyReader

_NS = 1_000_000_000
_EPOCH_2000_NS = 946_684_800 * _NS  # stamps before this are simulation clocks, not dates

#: Header clocks further apart than this (median header-minus-record, between topics) are different clocks;
#: below it the difference is transport/processing latency.
CLOCK_TOLERANCE_S = 0.1
#: The percentile of header-minus-record that stands for a topic's least delay (its fastest messages): a transport
#: that holds messages back (records in bursts, a queue) delays them by varying amounts and moves the median, never
#: this edge; the 99th, not the largest, so that a few stamps set ahead (1 in 100) cannot set it.
LEAST_DELAY_PERCENTILE = 99
#: The fewest stamps of a topic whose header clock is compared with another's: the median of three is the first a
#: single stamp recorded late (an image written after a pause, a latched message) cannot set. Fewer: the topic
#: keeps its own clock, unjudged, and a reference with fewer judges none (fiducials_ubiquity's aruco_images.bag:
#: "header clocks disagree" from its one image's stamp, 0.95 s off 15 camera_info stamps that spread 0.22 s).
MIN_CLOCK_STAMPS = 3
#: An interval longer than this many median periods is a gap.
GAP_FACTOR = 5.0
#: Block rates differing by more than this fraction start a new rate segment.
RATE_TOLERANCE = 0.2


@dataclass(frozen=True)
class TopicSummary:
    """One topic: type, count and what its header stamps look like (``None`` if it has no header)."""

    topic: str
    msgtype: str
    count: int
    frame_ids: tuple[str, ...] = ()
    stamp_start_ns: int | None = None
    stamp_end_ns: int | None = None
    rate_hz: float | None = None
    out_of_order: int | None = None  # stamps earlier than the one before (in record order)
    duplicates: int | None = None  # same stamp, same values as a run judges them (decode.column_duplicates)
    note: str = ""
    repeated_stamps: int | None = None  # same stamp as another message with different values
    header_clock: str | None = None  # "wall", "sim" (before 2000) or "zero"
    offset_s: float | None = None  # median header stamp minus record time
    offset_spread_s: float | None = None  # 5th-95th percentile width of header minus record
    offset_edge_s: float | None = None  # header minus record at LEAST_DELAY_PERCENTILE (the fastest messages')
    relative_offset_s: float | None = None  # offset_s minus the reference topic's
    clock: str | None = None  # the time source time.source: auto picks: "header" or "record"
    run_clock: str | None = None  # the one a run with the config given reads (:func:`run_clocks`)
    gaps: int | None = None  # intervals longer than GAP_FACTOR median periods
    max_gap_s: float | None = None
    max_gap_at_s: float | None = None  # where the longest gap starts, from the first stamp
    rate_segments: tuple[tuple[float, float], ...] = ()  # (start from the first stamp [s], rate [Hz]) if it changes
    stamp_pace: float | None = None  # header stamps' advance per record-time second (1: same pace)
    clock_step_s: float | None = None  # header stamps' jump ahead of record time (decode.clock_step_forward)
    clock_step_at_s: float | None = None  # where it is, from the topic's first record time
    step_back_s: float | None = None  # the largest step back between consecutive stamps (record order)
    #: per role a run reads of the topic: the messages whose values there hold a NaN or Inf (a run drops and counts
    #: them, :func:`.decode.nonfinite_count`); None when not read (no role, or a type decoded only by rosbags)
    nonfinite: dict[str, int] | None = None


@dataclass(frozen=True)
class LogInfo:
    """Summary of a log: container, record time span, topics and the roles they would play."""

    path: str
    container: str  # "ros1", "rosbag2", "mcap" or "db3"
    storage: str  # rosbag2 directories: storage plugin ("sqlite3", "mcap")
    start_ns: int | None  # record time of the first message
    end_ns: int | None  # record time of the last message
    message_count: int
    topics: tuple[TopicSummary, ...]
    roles: dict[str, str]
    warnings: tuple[str, ...] = ()
    record_clock: str | None = None  # "wall" or "sim"
    clock_reference: str | None = None  # topic the relative offsets refer to
    tf: TfSummary | None = None  # the TF tree and each sensor frame's transform into the body frame
    sim_truth: str | None = None  # what the sim_truth topic holds, in a user's words (:func:`_sim_truth_words`)

    @property
    def duration_s(self) -> float:
        """Record time span in seconds."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / _NS

    @property
    def clocks(self) -> dict[str, str]:
        """The time source ``time.source: auto`` picks per topic with a header (for :func:`apply_clocks`)."""
        return {t.topic: t.clock for t in self.topics if t.clock is not None}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        doc = asdict(self)
        doc["duration_s"] = self.duration_s
        doc["topics"] = [
            {**asdict(t), "frame_ids": list(t.frame_ids), "rate_segments": [list(s) for s in t.rate_segments]}
            for t in self.topics
        ]
        doc["warnings"] = list(self.warnings)
        return doc


# --------------------------------------------------------------------------- clock analysis


@dataclass(frozen=True)
class StampStats:
    """How the header stamps of one topic relate to its record times (in record order)."""

    header_clock: str  # "wall", "sim" or "zero"
    offset_ns: int  # median header minus record
    spread_ns: int  # 5th-95th percentile width of header minus record
    out_of_order: int
    gaps: int
    max_gap_ns: int | None
    max_gap_at_ns: int | None  # from the first stamp
    rate_segments: tuple[tuple[float, float], ...]
    rate_hz: float | None = None  # distinct stamps per second of the time recorded (the gaps left out)
    pace: float | None = None  # how fast the header stamps advance against record time (decode.stamp_pace)
    #: header minus record at LEAST_DELAY_PERCENTILE: the least delay's (its fastest messages)
    edge_ns: int | None = None


def clock_kind(t_ns: np.ndarray) -> str:
    """``zero`` (unset stamps), ``sim`` (a simulation clock, before 2000) or ``wall``."""
    if not t_ns.size or not t_ns.any():
        return "zero"
    return "sim" if int(t_ns.max()) < _EPOCH_2000_NS else "wall"


def _rate_segments(times: np.ndarray, period: float) -> tuple[tuple[float, float], ...]:
    """(start, rate) of stretches with a steady rate; one entry per stretch, empty if the rate is steady.

    Rates come from the median interval of blocks of samples, so jitter and single gaps do not count.
    """
    block = max(20, times.size // 50)
    if times.size < 2 * block or period <= 0:
        return ()
    segments: list[tuple[float, float]] = []
    for first in range(0, times.size - block + 1, block):
        dt = np.diff(times[first : first + block])
        dt = dt[dt > 0]
        if not dt.size:
            continue
        rate = _NS / float(np.median(dt))
        if not segments or abs(rate / segments[-1][1] - 1.0) > RATE_TOLERANCE:
            segments.append(((int(times[first]) - int(times[0])) / _NS, rate))
    return tuple(segments) if len(segments) > 1 else ()


def stamp_stats(t_ns: np.ndarray, rec_ns: np.ndarray) -> StampStats:
    """Clock kind, offset to record time, order, gaps and rate changes of one topic's stamps.

    Gaps and rates use the header stamps, or the record times when the stamps are all zero.
    """
    kind = clock_kind(t_ns)
    diff = t_ns - rec_ns
    lo, mid, hi = (np.percentile(diff, q, method="nearest") for q in (5, 50, 95)) if diff.size else (0, 0, 0)
    times = np.sort(rec_ns if kind == "zero" else t_ns)
    steps = np.diff(times)
    positive = steps[steps > 0]
    period = float(np.median(positive)) if positive.size else 0.0
    long = np.flatnonzero(steps > GAP_FACTOR * period) if period > 0 else np.zeros(0, np.int64)
    worst = int(long[np.argmax(steps[long])]) if long.size else None
    return StampStats(
        kind,
        int(mid),
        int(hi) - int(lo),
        int(np.count_nonzero(t_ns[1:] < t_ns[:-1])),
        int(long.size),
        int(steps[worst]) if worst is not None else None,
        int(times[worst]) - int(times[0]) if worst is not None else None,
        _rate_segments(times, period),
        _recorded_rate(steps, long),
        stamp_pace(t_ns, rec_ns) if kind != "zero" else None,
        int(np.percentile(diff, LEAST_DELAY_PERCENTILE, method="nearest")) if diff.size else None,
    )


def _recorded_rate(steps: np.ndarray, gaps: np.ndarray) -> float | None:
    """Distinct stamps per second over the time the topic was recorded: the intervals ``stamp_stats`` counts as
    gaps (a missing split part, a pause) are left out of the span, so a 200 Hz topic with a hole reads 200 Hz."""
    positive = steps > 0
    positive[gaps] = False
    span = int(steps[positive].sum())
    return int(np.count_nonzero(positive)) * _NS / span if span > 0 else None


def choose_clocks(
    offsets: Mapping[str, tuple[str, int, int, int | None]],
    reference: str | None,
    stamps: Mapping[str, int] | None = None,
) -> tuple[dict[str, str], list[str]]:
    """Time source per topic from its (header clock kind, median header-minus-record ns, that difference's 5th-95th
    percentile spread ns, its value at :data:`LEAST_DELAY_PERCENTILE` ns or None), with warnings.

    See the module docstring; ``reference`` is the topic whose clock the others must agree with. ``stamps``: each
    topic's number of stamps; one with fewer than :data:`MIN_CLOCK_STAMPS` is not compared (a reference with fewer:
    none is). A topic whose median is off the reference's but whose fastest messages are not (the edges within
    :data:`CLOCK_TOLERANCE_S`) is on the same clock, its records held back by varying amounts (in bursts, by a
    queue): its header stamps stay (record time would move each message by its delay).
    """
    clocks = {t: "record" if kind == "zero" else "header" for t, (kind, *_) in offsets.items()}
    few = {t for t, n in (stamps or {}).items() if n < MIN_CLOCK_STAMPS}
    if reference not in offsets or offsets[reference][0] == "zero" or reference in few:
        return clocks, []
    ref_kind, ref_offset, _, ref_edge = offsets[reference]
    tol = CLOCK_TOLERANCE_S * _NS
    # a topic held back: its fastest messages at the reference's, which is steady (its median at its own edge; a
    # reference whose median is not is stepped or jittery, and the medians are all there is to go by)
    steady = ref_edge is not None and abs(ref_offset - ref_edge) <= tol
    held = lambda edge: steady and edge is not None and abs(edge - ref_edge) <= tol  # noqa: E731
    odd = [
        t
        for t, (kind, offset, _, edge) in offsets.items()
        if kind != "zero" and t not in few and (kind != ref_kind or (abs(offset - ref_offset) > tol and not held(edge)))
    ]
    if not odd:
        return clocks, []
    if abs(ref_offset) <= tol:
        for t in odd:
            clocks[t] = "record"
        return clocks, [
            f"{t}: header clock is {(offsets[t][1] - ref_offset) / _NS:+.3f} s off {reference}'s "
            f"({offsets[t][0]} clock), use record time for it"
            for t in odd
        ]
    for t in clocks:
        clocks[t] = "record"
    apart = max(abs(offsets[t][1] - ref_offset) for t in odd)
    # medians on either side of one step: the spread within topics as large as the disagreement between them
    if unsteady := [t for t in [reference, *odd] if offsets[t][2] > max(tol, 0.5 * apart)]:
        return clocks, [
            f"header clocks step against record time ({', '.join(unsteady)}: header minus record time spreads over "
            f"{max(offsets[t][2] for t in unsteady) / _NS:.3f} s; a clock set back or forward mid-log?): "
            "use record time for every topic",
        ]
    return clocks, [
        f"header clocks disagree ({', '.join(odd)} vs {reference}) and {reference}'s is not record time "
        f"({ref_offset / _NS:+.3f} s): use record time for every topic",
    ]


_TIMED_ROLES = ("angular_velocity", "linear_velocity", "accel", "magnetic", "detections", "truth", "twist_angular")


def recommend_clocks(streams: LogStreams) -> tuple[dict[str, str], list[str]]:
    """Time source per topic of decoded streams (reference: the angular-velocity topic), with warnings."""
    found, stamps = {}, {}
    for role in _TIMED_ROLES:
        stream = getattr(streams, role)
        if stream is not None and len(stream) and stream.topic not in found:
            stats = stamp_stats(stream.t_ns, stream.rec_ns)
            found[stream.topic] = (stats.header_clock, stats.offset_ns, stats.spread_ns, stats.edge_ns)
            stamps[stream.topic] = len(stream)
    reference = streams.angular_velocity.topic if streams.angular_velocity is not None else None
    return choose_clocks(found, reference, stamps)


#: A window where every timed topic has at least this many times its median count of samples (and none of them is
#: sparse next to it) holds two stretches of the recording interleaved: the recording's clock set back.
DENSER = 1.6
#: Windows of at least this many of each topic's median periods (and at least ``CLOCK_STEP_NS`` long).
SET_BACK_PERIODS = 10
#: Each topic's stamps span at least this share of all of theirs, or they are on no one clock and not compared.
SET_BACK_SHARED = 0.5


def clock_set_back(streams: LogStreams) -> list[str]:
    """A warning (or none) when the recording's clock was set back mid-log (:func:`set_back_text`), on the
    clocks the run reads."""
    series = {}
    for role in _TIMED_ROLES:
        stream = getattr(streams, role)
        if stream is not None and len(stream) >= 50 and stream.topic not in series:
            series[stream.topic] = stream.t_ns
    gyro = streams.angular_velocity
    origin = int(gyro.t_ns[0]) if gyro is not None and len(gyro.t_ns) else None
    text = set_back_text(series, origin)
    return [] if text is None else [f"warning: {text}"]


def set_back_text(series: Mapping[str, np.ndarray], origin: int | None) -> str | None:
    """What a run and ``info`` say (None: nothing) when the recording's clock was set back mid-log, record times
    and header stamps alike (no stamp steps against record time, so :func:`.decode.clock_steps` sees nothing):
    every timed topic's samples (``series``: each topic's stamps in order, on the clock a run reads) come about
    twice as dense over the same stretch, the seconds before the step and those after it interleaved. A figure 8
    whose every clock was set back 1.0037 s 20 s in ran riekf 2.94 m off (0.011 m clean) with a misread id as its
    only word. Windows of ``SET_BACK_PERIODS`` periods of the slowest topic (``CLOCK_STEP_NS`` at least), each
    topic's count against its median; the windows either side of the dense ones must not be sparse (a recorder
    that stalls and then writes a burst leaves a gap before it). Times from ``origin`` (the first angular-velocity
    stamp, as ``time.start`` counts; None: the first stamp)."""
    series = {topic: t for topic, t in series.items() if len(t) >= 50}
    periods = {}
    for topic, t in series.items():
        steps = np.diff(t)
        periods[topic] = float(np.median(steps[steps > 0])) if (steps > 0).any() else 0.0
    if len(series) < 2 or min(periods.values()) <= 0:
        return None
    width = max(CLOCK_STEP_NS, SET_BACK_PERIODS * max(periods.values()))
    start = min(int(t[0]) for t in series.values())
    end = max(int(t[-1]) for t in series.values())
    if any(int(t[-1]) - int(t[0]) < SET_BACK_SHARED * (end - start) for t in series.values()):
        return None  # not one clock (an IMU stamped in ms: 3.4e9 windows, 25 GiB of counts); the pace check says so
    n = int((end - start) // width)
    if n < 5:
        return None
    dense, sparse, rates = np.ones(n, bool), np.zeros(n, bool), {}
    for topic, t in series.items():
        counts = np.bincount(((t - start) // width).astype(np.int64), minlength=n + 1)[:n].astype(np.float64)
        own = counts[int((int(t[0]) - start) // width) + 1 : int((int(t[-1]) - start) // width)]  # whole windows
        median = float(np.median(own)) if own.size else 0.0
        if median < 5:
            return None
        dense &= counts >= DENSER * median
        sparse |= counts < 0.5 * median
        rates[topic] = median * 1e9 / width
    if not dense.any():
        return None
    first, last = int(np.flatnonzero(dense)[0]), int(np.flatnonzero(dense)[-1])
    if (first and sparse[first - 1]) or (last + 1 < n and sparse[last + 1]):
        return None
    t0 = (start + first * width - (start if origin is None else origin)) * 1e-9  # on time.start's scale
    t1 = t0 + (last - first + 1) * width * 1e-9
    shown = ", ".join(f"{topic}'s {rate:.0f} Hz" for topic, rate in list(rates.items())[:3])
    return (
        f"every topic's samples come about twice as dense from {t0:.1f} s to {t1:.1f} s into the log as "
        f"elsewhere (against {shown}{', ...' if len(rates) > 3 else ''}): the recording's clock set back mid-log (its "
        "record times and the header stamps alike), so two stretches of the recording interleave there and the run "
        "takes them as one; the estimate from then on is not to be trusted: run the part before or after it "
        "(time.start, time.end)"
    )


def _on_record_time(stream: Any) -> Any:
    order = np.argsort(stream.rec_ns, kind="stable")
    if isinstance(stream, Vec3Stream):
        return dataclasses.replace(
            stream, t_ns=stream.rec_ns[order], rec_ns=stream.rec_ns[order], xyz=stream.xyz[order]
        )
    if isinstance(stream, PoseStream):
        return dataclasses.replace(
            stream,
            t_ns=stream.rec_ns[order],
            rec_ns=stream.rec_ns[order],
            position=stream.position[order],
            quat_xyzw=stream.quat_xyzw[order],
        )
    lengths = np.diff(stream.offsets)[order]
    offsets = np.concatenate(([0], np.cumsum(lengths))).astype(np.int64)
    gather = np.repeat(stream.offsets[:-1][order] - offsets[:-1], lengths) + np.arange(offsets[-1])
    return dataclasses.replace(
        stream,
        t_ns=stream.rec_ns[order],
        rec_ns=stream.rec_ns[order],
        offsets=offsets,
        ids=stream.ids[gather],
        xyz=stream.xyz[gather],
    )


def apply_clocks(streams: LogStreams, clocks: Mapping[str, str]) -> LogStreams:
    """Streams whose topic maps to ``"record"`` take their record times as measurement times (re-sorted).

    Raises:
        ValueError: A clock other than ``"header"`` or ``"record"``.

    """
    if bad := {c for c in clocks.values() if c not in {"header", "record"}}:
        msg = f"unknown clock {sorted(bad)[0]!r} (expected header or record)"
        raise ValueError(msg)
    changes = {}
    for role in _TIMED_ROLES:
        stream = getattr(streams, role)
        if isinstance(stream, (Vec3Stream, PoseStream, DetectionStream)) and clocks.get(stream.topic) == "record":
            changes[role] = _on_record_time(stream)
    return dataclasses.replace(streams, **changes) if changes else streams


# --------------------------------------------------------------------------- inspect


def _scan(
    reader: AnyReader, path: str | Path, table: Mapping[str, Any], valued: Collection[str]
) -> dict[str, TopicColumns]:
    """Header columns (stamps, record times, frames, payload digests) of every headered topic, one pass; of the
    topics ``valued`` (those a run reads values of) the values too, as the run decodes them (``fastdecode.plan_for``;
    where that needs rosbags, none), and of a detection array its elements (``fastdecode.item_plan_for``): what
    :func:`.decode.column_duplicates` tells a duplicate by, as the run does."""
    planned = {}
    for topic, (meta, conns) in table.items():
        if meta.count and meta.msgtype in reader.typestore.fielddefs and has_header(reader, meta.msgtype):
            plan = plan_for(reader.typestore, meta.msgtype, reader.is2) if topic in valued else None
            if plan is None:
                plan = item_plan_for(reader.typestore, meta.msgtype, reader.is2)
            if plan is not None and plan.stated_from is not None:  # stated covariances: every column as a number
                plan = dataclasses.replace(plan, stated_from=None)
            elif plan is None:
                plan = make_plan(reader.typestore, meta.msgtype, (), (FRAME_ID,), cdr=reader.is2)
            if plan is not None:
                planned[topic] = (conns, plan)
    return read_columns(reader, path, planned, digests=True)


def _valued_roles(table: Mapping[str, Any], roles: Mapping[str, str]) -> dict[str, tuple[str, ...]]:
    """Per topic, the roles whose values a run reads from its rows (:func:`.decode.role_columns`)."""
    out: dict[str, tuple[str, ...]] = {}
    for role, topic in roles.items():
        if role in _TIMED_ROLES and topic in table and role_columns(table[topic][0].msgtype, role) is not None:
            out[topic] = (*out.get(topic, ()), role)
    return out


def _summary(
    topic: str, msgtype: str, count: int, note: str, cols: TopicColumns | None, roles: tuple[str, ...] = ()
) -> TopicSummary:
    if cols is None or not len(cols.t_ns):
        if note:
            return TopicSummary(topic, msgtype, count, note=note)
        return TopicSummary(topic, msgtype, count, out_of_order=0, duplicates=0)
    t_ns, rec_ns = cols.t_ns, cols.rec_ns
    frames = np.bincount(cols.frame, minlength=len(cols.names))
    names: dict[str, int] = {}
    for name, n in zip(cols.names, frames.tolist(), strict=True):
        names[frame_name(name)] = names.get(frame_name(name), 0) + n
    stats = stamp_stats(t_ns, rec_ns)
    # the run's stamps (record times where the header's are all zero) and its rule
    duplicates, repeated = column_duplicates(rec_ns if stats.header_clock == "zero" else t_ns, cols)
    order = Cleaning()  # the run's own rules for a clock stepped forward or set back
    if stats.header_clock != "zero":
        order.count_order(t_ns, rec_ns)
    step, at_s = order.step_forward[0], order.step_forward[1] / _NS
    return TopicSummary(
        topic,
        msgtype,
        count,
        frame_ids=tuple(sorted((n for n in names if names[n]), key=lambda n: -names[n])),
        stamp_start_ns=int(t_ns.min()),
        stamp_end_ns=int(t_ns.max()),
        rate_hz=stats.rate_hz,
        out_of_order=stats.out_of_order,
        duplicates=duplicates,
        note=note,
        repeated_stamps=repeated if stats.header_clock != "zero" else None,
        header_clock=stats.header_clock,
        offset_s=stats.offset_ns / _NS,
        offset_spread_s=stats.spread_ns / _NS,
        offset_edge_s=stats.edge_ns / _NS if stats.edge_ns is not None else None,
        gaps=stats.gaps,
        max_gap_s=stats.max_gap_ns / _NS if stats.max_gap_ns is not None else None,
        max_gap_at_s=stats.max_gap_at_ns / _NS if stats.max_gap_at_ns is not None else None,
        rate_segments=stats.rate_segments,
        stamp_pace=stats.pace,
        clock_step_s=step / _NS if step else None,
        clock_step_at_s=at_s if step else None,
        step_back_s=order.step_back_ns / _NS if order.step_back_ns else None,
        nonfinite={r: nonfinite_count(cols.values, msgtype, r) for r in roles} if roles and cols.values.size else None,
    )


def _problems(t: TopicSummary, pace: float | None) -> list[str]:
    """What is wrong with one topic's stamps; ``pace``: how fast its header stamps advance against the log's other
    topics' when that is off by ``decode.STAMP_PACE_FACTOR`` (:func:`decode.off_pace`), else None."""
    problems = []
    if pace is not None:
        problems.append(
            f"header stamps advance {pace:.3g}x as fast as the other topics' (stamps in another unit?): "
            f"time.topics: {{{t.topic}: record}}"
        )
    if t.out_of_order:
        problems.append(out_of_order_text(t.out_of_order, round((t.step_back_s or 0.0) * _NS)))
    if t.clock_step_s is not None and t.clock_step_at_s is not None:
        problems.append(clock_step_text(round(t.clock_step_s * _NS), t.clock_step_at_s))
    if t.duplicates:
        problems.append(duplicates_text(t.duplicates, t.count - t.duplicates))
    if t.repeated_stamps:
        problems.append(repeated_text(t.repeated_stamps))
    if len(t.frame_ids) > 1:
        problems.append(f"{len(t.frame_ids)} frame ids")
    if t.header_clock == "zero":
        problems.append("header stamps are all zero")
    if t.gaps:
        problems.append(  # what counts as a gap, so it is not read as run's (longer than a fixed 0.5 s)
            plural(t.gaps, "gap")
            + f" over {GAP_FACTOR:g}x the median interval (longest {t.max_gap_s:.3f} s at +{t.max_gap_at_s:.3f} s)"
        )
    if t.rate_segments:
        steps = " -> ".join(f"{rate:.4g} Hz" + (f" at +{at:.1f} s" if at else "") for at, rate in t.rate_segments[:5])
        problems.append(f"rate changes: {steps}" + (" ..." if len(t.rate_segments) > 5 else ""))
    return problems


def nonfinite_notes(t: TopicSummary) -> list[str]:
    """What a run will note of the topic's NaN/Inf values (:attr:`TopicSummary.nonfinite`), in its words
    (``readers._cleaning_notes``: the roles named where they differ), and that it drops those messages."""
    by_count: dict[int, list[str]] = {}
    for role, n in (t.nonfinite or {}).items():
        by_count.setdefault(n, []).append(role)
    notes = []
    for n, roles in by_count.items():
        where = t.topic if len(roles) == len(t.nonfinite or {}) else f"{t.topic} ({', '.join(roles)})"
        if n:
            notes.append(f"{where}: {nonfinite_text(n)} (of its {t.count} messages: a run drops them, noting this)")
    return notes


#: Messages ``info`` reads of the angular-velocity topic (and of the linear-velocity one) to tell an IMU that does not
#: fill its gyro; ``run`` reads them all (an IMU all zero in its first 50 messages and measuring later is named by
#: ``run``: the config's topics.angular_velocity then keeps it)
GYRO_PROBE = 50
#: Messages read further when the first :data:`GYRO_PROBE` are all zero: a robot standing or driving straight at the
#: start has a zero angular velocity that is measured (MR.CLAM's velocity commands: dataset 6 robot 5 turns first at
#: its 173rd message, 7-r2 at its 52nd, 7-r5 at its 650th; 0.07 CPU s for 5000 TwistStamped)
GYRO_PROBE_FURTHER = 5000


def _gyro_source(reader, table: dict, roles: dict[str, str]) -> tuple[dict[str, str], list[str]]:
    """The roles with the angular velocity ``run`` will take: the linear-velocity topic's when the detected one reads
    zero in its first :data:`GYRO_PROBE` messages (and :data:`GYRO_PROBE_FURTHER` then) and that one's does not
    (``decode.gyro_stand_in``, the readers' rule); with a warning saying so."""
    gyro, other = roles.get("angular_velocity"), roles.get("linear_velocity")

    @functools.cache
    def probe(topic: str) -> np.ndarray:  # read only when the rule asks, once; further when the first are all zero
        meta, conns = table[topic]
        first = first_vectors(reader, conns, meta.msgtype, "angular_velocity", GYRO_PROBE)
        if not gyro_not_filled(first):
            return first
        return first_vectors(reader, conns, meta.msgtype, "angular_velocity", GYRO_PROBE_FURTHER)

    if not gyro_stand_in(gyro, lambda: probe(gyro), other, other and table[other][0].msgtype, lambda: probe(other)):
        if gyro is None or table[gyro][0].msgtype == ODOMETRY or not gyro_not_filled(probe(gyro)):
            return roles, []  # an odometry's zero twist.angular is differentiated from its orientations
        return roles, [
            f"{gyro}: every angular velocity of its first {len(probe(gyro))} messages is zero (field not filled by the "
            "publisher?): if all are, the run takes the body as never turning"
        ]
    return {**roles, "angular_velocity": other}, [
        f"{gyro}: every angular velocity of its first {len(probe(gyro))} messages is zero (not measured): the angular "
        f"velocity is {other}'s, as run takes it when all are zero (topics.angular_velocity chooses one)"
    ]


def _static_tf_notes(reader, path: str | Path, table: dict) -> list[str]:
    """What ``run`` says of ``/tf_static`` (a transform published twice with different values, NaN/Inf ones), by
    the readers' rule (``decode.static_transforms``): the topic is small, so it is decoded whole."""
    topic = ROLE_TOPIC_NAMES["static_tf"]
    if topic not in table or table[topic][0].msgtype not in TF_TYPES or not table[topic][0].count:
        return []
    try:
        _, warnings = decode_static_tf(reader, path, table[topic][1])
    except InputError as err:  # info describes a log run refuses; run says this one line
        return [f"{topic}: {err.problem}"]
    return static_tf_notes(topic, warnings)


def _sim_truth_words(reader, path: str | Path, table: dict, roles: Mapping[str, str]) -> tuple[str | None, list[str]]:
    """What the ``sim_truth`` topic (a simulated log's truth, an MR.CLAM import's landmark survey) holds, as ``info``
    lists it beside the role's name, which says little; and the warning a run would give for it. One small latched
    message, decoded whole."""
    topic = roles.get("sim_truth")
    if topic is None or topic not in table or not table[topic][0].count:
        return None, []
    try:
        landmarks, bias, warnings, _ = decode_sim_truth(reader, path, topic, table[topic][1])
    except InputError as err:  # info describes a log run refuses; run says this one line
        return None, [f"{topic}: {err.problem}"]
    said = [f"landmark truth: {plural(len(landmarks), 'position')}, surveyed or simulated"] * bool(landmarks)
    said += [f"{' and '.join(bias)} bias truth"] * bool(bias)
    if not said:
        return "holds no landmark or bias truth", warnings
    errors = " and ".join(["map"] * bool(landmarks) + ["bias"] * bool(bias))
    return f"{', and '.join(said)}; a run reports its {errors} error against it", warnings


def run_clocks(
    topics: Collection[TopicSummary], stepped: bool, source: str | Mapping[str, str] | None
) -> dict[str, str]:
    """The clock a run reads per topic with a header, ``source`` the config's choice (``readers.read_log``'s
    ``clocks``: None or ``header`` the default, ``record``, ``auto`` or a topic mapping), by the readers' rule
    (``readers._with_clocks``): header stamps unless told otherwise; record time for every topic by default when a
    header clock steps mid-log (``stepped``); ``auto``: give the mapping it picks; record time wherever the header
    stamps are all zero."""
    out = {}
    for t in topics:
        if t.header_clock is None:
            continue
        if source in (None, "header"):
            clock = "record" if stepped else "header"
        elif isinstance(source, str):
            clock = source
        else:
            clock = source.get(t.topic, "header")
        out[t.topic] = "record" if t.header_clock == "zero" else clock
    return out


def _set_back(columns: Mapping[str, TopicColumns], roles: Mapping[str, str], clocks: Mapping[str, str]) -> list[str]:
    """The run's words (:func:`set_back_text`) for a recording clock set back mid-log, on the stamps a run reads
    (``clocks``: :func:`run_clocks`) of the topics of its timed ``roles``."""
    series = {}
    for role in _TIMED_ROLES:
        cols = columns.get(roles.get(role, ""))
        if cols is not None and len(cols.t_ns) >= 50 and roles[role] not in series:
            series[roles[role]] = np.sort(cols.rec_ns if clocks.get(roles[role]) == "record" else cols.t_ns)
    gyro = series.get(roles.get("angular_velocity", ""))
    text = set_back_text(series, None if gyro is None else int(gyro[0]))
    return [] if text is None else [text]


def inspect_log(
    path: str | Path,
    msg_dir: str | Path | None = None,
    frames: Mapping[str, Any] | None = None,
    clocks: str | Mapping[str, str] | None = None,
) -> LogInfo:
    """Summarise a log: container, time span, per-topic type/count/frames/stamps/clocks, detected roles, the TF
    tree and each sensor frame's transform into the body frame.

    ``msg_dir`` supplies ``pkg/msg/Type.msg`` definitions the log lacks (see ``read_log``). ``frames``: the keyword
    arguments of :func:`.tf_tree.tf_summary` a config gives (``body_frame``, ``identity``, ``override``,
    ``cameras_given``). ``clocks``: the config's time source, as ``read_log`` takes it (:func:`run_clocks`). A
    truncated log is summarised from what could be recovered, with a warning saying so.

    Raises:
        InputError: The log cannot be opened or read.

    """
    container = detect_container(path)
    with open_log(path) as reader:
        complete_definitions(reader, msg_dir)
        table = topics_of(reader)
        selection = select_roles({t: m for t, (m, _) in table.items()}, None, path)
        gyro_roles, gyro_notes = _gyro_source(reader, table, selection.roles)
        valued = _valued_roles(table, gyro_roles)
        columns = _scan(reader, path, table, valued)
        count = reader.message_count
        start = reader.start_time if count else None
        end = reader.end_time - 1 if count else None
        warnings = [*damage_notes(reader), *selection.warnings, *gyro_notes, *_static_tf_notes(reader, path, table)]
        tf = tf_summary(reader, path, table, gyro_roles, **(frames or {}))
        sim_truth, sim_warnings = _sim_truth_words(reader, path, table, selection.roles)
        warnings += sim_warnings
        notes = {}
        for topic, (meta, _) in table.items():
            if meta.msgtype not in reader.typestore.fielddefs:
                notes[topic] = "message definition not stored in the log"
            elif not has_header(reader, meta.msgtype):
                notes[topic] = "no header"
    summaries = {
        topic: _summary(
            topic, meta.msgtype, meta.count, notes.get(topic, ""), columns.get(topic), valued.get(topic, ())
        )
        for topic, (meta, _) in sorted(table.items())
    }
    offsets = {
        t: (
            s.header_clock,
            round(s.offset_s * _NS),
            round((s.offset_spread_s or 0.0) * _NS),
            round(s.offset_edge_s * _NS) if s.offset_edge_s is not None else None,
        )
        for t, s in summaries.items()
        if s.header_clock is not None and s.offset_s is not None
    }
    reference = selection.roles.get("angular_velocity")
    if reference not in offsets:
        reference = max(offsets, key=lambda t: (summaries[t].count, t), default=None)
    advised, clock_warnings = choose_clocks(offsets, reference, {t: summaries[t].count for t in offsets})
    auto = dict(advised)  # what time.source: auto reads (readers._with_clocks: no stepped rule)
    stepped = [
        t
        for t, s in summaries.items()
        if clock_steps(round((s.step_back_s or 0.0) * _NS), round((s.clock_step_s or 0.0) * _NS))
    ]
    if stepped:  # what a run does by default then (readers._with_clocks)
        advised = dict.fromkeys(advised, "record")
        clock_warnings = [
            f"{w} (a run reads record time for every topic by default: a header clock steps mid-log)"
            for w in clock_warnings
        ] or [
            f"header clock set back or forward mid-log ({', '.join(stepped)}, below): a run reads record time for "
            "every topic (time.source: header reads header stamps only where no clock steps)"
        ]
    else:  # advice here (a run reads header stamps unless told otherwise), what a run with time.source: auto does
        clock_warnings = [f"{w} (set time.source: auto; a run reads header stamps by default)" for w in clock_warnings]
    ref_offset = summaries[reference].offset_s if reference is not None else None
    topics = tuple(
        dataclasses.replace(
            s,
            clock=advised.get(s.topic),
            relative_offset_s=(
                round(s.offset_s - ref_offset, 9) if s.offset_s is not None and ref_offset is not None else None
            ),
        )
        for s in summaries.values()
    )
    used = run_clocks(topics, bool(stepped), auto if clocks == "auto" else clocks)
    topics = tuple(dataclasses.replace(t, run_clock=used.get(t.topic)) for t in topics)
    off = off_pace({t.topic: t.stamp_pace for t in topics})
    record_clock = clock_kind(np.array([start], np.int64)) if start is not None else None
    if record_clock == "wall":
        sim = [t.topic for t in topics if t.header_clock == "sim" and t.topic not in off]
        if sim:
            warnings.append(f"header stamps are simulation time next to wall-clock record times: {', '.join(sim)}")
    warnings += clock_warnings
    warnings += _set_back(columns, gyro_roles, used)
    warnings += [f"{t.topic}: " + ", ".join(p) for t in topics if (p := _problems(t, off.get(t.topic)))]
    warnings += [note for t in topics for note in nonfinite_notes(t)]
    return LogInfo(
        str(path),
        container.kind,
        container.storage,
        start,
        end,
        count,
        topics,
        {**gyro_roles, **{r: ", ".join(t) for r, t in selection.multi.items()}},
        tuple(warnings),
        record_clock,
        reference,
        tf,
        sim_truth,
    )


# --------------------------------------------------------------------------- text


def _when(t_ns: int) -> str:
    if t_ns < _EPOCH_2000_NS:
        return f"{t_ns / _NS:.3f} s"
    stamp = datetime.fromtimestamp(t_ns / _NS, tz=timezone.utc)
    return stamp.strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"


def _table(header: tuple[str, ...], rows: list[tuple[str, ...]], right: set[int]) -> list[str]:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = []
    for row in [header, *rows]:
        cells = [c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths, strict=True))]
        lines.append("  " + "  ".join(cells).rstrip())
    return lines


def _seconds(value: float | None, sign: bool = True) -> str:
    return "-" if value is None else (f"{value:+.3f}" if sign else f"{value:.3f}")


#: What the topic table's columns mean (what ``info`` prints under it).
TOPIC_LEGEND = (
    "  rate: distinct header stamps per second of the time recorded (gaps left out: intervals over "
    f"{GAP_FACTOR:g}x the median);",
    "  out-of-order: stamps earlier than the one before (record order); duplicates: same stamp, same values, the",
    "  sequence numbers aside (what a run drops);",
    "  NaN/Inf: messages whose values a run reads (its roles) hold a NaN or Inf: a run drops them ('-': not read);",
    "  stamps: first header stamp [s] and the span to the last [s]",
)
#: What the clocks table's columns mean.
CLOCK_LEGEND = (
    "  run reads: the clock a run with this config reads (default: header stamps; record time for every topic when "
    "a header clock steps mid-log, or where the stamps are all zero); auto: what time.source: auto reads;",
    "  hdr-rec: median header stamp minus record time; spread: its 5th-95th percentile width; vs ref: hdr-rec minus "
    "the reference's;",
    "  repeated: stamps repeated with different values; gaps: intervals over "
    f"{GAP_FACTOR:g}x the median (longest [s]); rate Hz: rate changes (each over {RATE_TOLERANCE:.0%})",
)


def format_info(info: LogInfo) -> str:
    """Aligned plain-text report for a terminal."""
    label = LABELS[info.container] + (f" ({info.storage})" if info.storage else "")
    lines = [info.path, f"  container  {label}"]
    if info.start_ns is not None and info.end_ns is not None:
        lines.append(
            f"  recorded   {_when(info.start_ns)} .. {_when(info.end_ns)}"
            f"  ({info.duration_s:.3f} s, {plural(info.message_count, 'message')})",
        )
    else:
        lines.append("  recorded   no messages")
    rows = []
    clock_rows = []
    for t in info.topics:
        if t.stamp_start_ns is not None and t.stamp_end_ns is not None:
            stamps = f"{t.stamp_start_ns / _NS:.3f} +{(t.stamp_end_ns - t.stamp_start_ns) / _NS:.3f}"
        else:
            stamps = t.note or "-"
        frames = ",".join(x or '""' for x in t.frame_ids[:3]) + (",..." if len(t.frame_ids) > 3 else "")
        rows.append(
            (
                t.topic,
                t.msgtype,
                str(t.count),
                f"{t.rate_hz:.2f}" if t.rate_hz is not None else "-",
                frames or "-",
                "-" if t.out_of_order is None else str(t.out_of_order),
                "-" if t.duplicates is None else str(t.duplicates),
                "-" if t.nonfinite is None else str(max(t.nonfinite.values())),
                stamps,
            ),
        )
        if t.header_clock is not None:
            gaps = f"{t.gaps} (max {t.max_gap_s:.3f})" if t.gaps else str(t.gaps)
            rates = " -> ".join(f"{r:.4g}" for _, r in t.rate_segments[:4])
            rates += " ..." if len(t.rate_segments) > 4 else ""
            clock_rows.append(
                (
                    t.topic,
                    t.run_clock or "-",
                    t.clock or "-",
                    t.header_clock,
                    _seconds(t.offset_s),
                    _seconds(t.offset_spread_s, sign=False),
                    _seconds(t.relative_offset_s),
                    "-" if t.repeated_stamps is None else str(t.repeated_stamps),
                    gaps,
                    rates or "steady",
                ),
            )
    header = ("topic", "type", "count", "rate Hz", "frame_id", "out-of-order", "duplicates", "NaN/Inf", "stamps [s]")
    lines += ["", *_table(header, rows, right={2, 3, 5, 6, 7}), *TOPIC_LEGEND]
    if clock_rows:
        ref = f"; offsets vs {info.clock_reference}" if info.clock_reference else ""
        lines += ["", f"  clocks (record time: {info.record_clock} clock{ref})"]
        header = (
            "topic", "run reads", "auto", "header", "hdr-rec [s]", "spread [s]", "vs ref [s]", "repeated", "gaps",
            "rate Hz",
        )  # fmt: skip
        lines += [*_table(header, clock_rows, right={4, 5, 6, 7}), *CLOCK_LEGEND]
    lines += ["", "  roles"]
    roles = [(f"  {role}", info.roles[role]) for role in ROLES if role in info.roles]
    if info.sim_truth:  # the role's name says little: what the topic holds
        roles = [(r, f"{t}  ({info.sim_truth})" if r == "  sim_truth" else t) for r, t in roles]
    lines += _table(("", ""), roles, set())[1:] if roles else ["    none detected"]
    if info.tf is not None and (info.tf.edges or info.tf.sensors):
        lines += ["", *info.tf.lines()]
    if info.warnings:
        lines += ["", "  warnings", *(f"    {w}" for w in info.warnings)]
    return "\n".join(lines)
