"""``slamobs info``: what a log holds, read from headers only, so a user can pick topics and spot bad stamps.

Stamps and frame ids are read straight from the serialised header bytes; messages are never fully
deserialised, so logs with images stay quick to inspect.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Any

from .container import LABELS, detect_container, open_log
from .decode import has_header, mean_rate, plural, scan_headers
from .roles import ROLES, select_roles, topics_of

if TYPE_CHECKING:
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

_NS = 1_000_000_000
_EPOCH_2000_NS = 946_684_800 * _NS  # record times before this are simulation clocks, not dates


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
    duplicates: int | None = None  # same stamp and byte-identical message
    note: str = ""


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

    @property
    def duration_s(self) -> float:
        """Record time span in seconds."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / _NS

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        doc = asdict(self)
        doc["duration_s"] = self.duration_s
        doc["topics"] = [{**asdict(t), "frame_ids": list(t.frame_ids)} for t in self.topics]
        doc["warnings"] = list(self.warnings)
        return doc


def _summary(
    reader: AnyReader,
    path: str | Path,
    topic: str,
    msgtype: str,
    count: int,
    conns: list[Connection],
) -> TopicSummary:
    if msgtype not in reader.typestore.fielddefs:
        return TopicSummary(topic, msgtype, count, note="message definition not stored in the log")
    if not has_header(reader, msgtype):
        return TopicSummary(topic, msgtype, count, note="no header")
    if not count:
        return TopicSummary(topic, msgtype, count, out_of_order=0, duplicates=0)
    scan = scan_headers(reader, path, conns)
    t_ns = scan.t_ns
    return TopicSummary(
        topic,
        msgtype,
        count,
        frame_ids=tuple(f for f, _ in scan.frames.most_common()),
        stamp_start_ns=int(t_ns.min()),
        stamp_end_ns=int(t_ns.max()),
        rate_hz=mean_rate(t_ns),
        out_of_order=int((t_ns[1:] < t_ns[:-1]).sum()),
        duplicates=scan.duplicates,
    )


def inspect_log(path: str | Path) -> LogInfo:
    """Summarise a log: container, time span, per-topic type/count/frames/stamps, detected roles.

    Raises:
        InputError: The log cannot be opened or read.

    """
    container = detect_container(path)
    with open_log(path) as reader:
        table = topics_of(reader)
        selection = select_roles({t: m for t, (m, _) in table.items()}, None, path)
        topics = tuple(
            _summary(reader, path, topic, meta.msgtype, meta.count, conns)
            for topic, (meta, conns) in sorted(table.items())
        )
        count = reader.message_count
        start = reader.start_time if count else None
        end = reader.end_time - 1 if count else None
    warnings = list(selection.warnings)
    for t in topics:
        problems = []
        if t.out_of_order:
            problems.append(plural(t.out_of_order, "out-of-order stamp"))
        if t.duplicates:
            problems.append(plural(t.duplicates, "exact duplicate"))
        if len(t.frame_ids) > 1:
            problems.append(f"{len(t.frame_ids)} frame ids")
        if t.stamp_end_ns == 0:
            problems.append("header stamps are all zero")
        if problems:
            warnings.append(f"{t.topic}: " + ", ".join(problems))
    return LogInfo(
        str(path),
        container.kind,
        container.storage,
        start,
        end,
        count,
        topics,
        selection.roles,
        tuple(warnings),
    )


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


def format_info(info: LogInfo) -> str:
    """Aligned plain-text report for a terminal."""
    label = LABELS[info.container] + (f" ({info.storage})" if info.storage else "")
    lines = [info.path, f"  container  {label}"]
    if info.start_ns is not None and info.end_ns is not None:
        lines.append(
            f"  recorded   {_when(info.start_ns)} .. {_when(info.end_ns)}"
            f"  ({info.duration_s:.3f} s, {info.message_count} messages)",
        )
    else:
        lines.append("  recorded   no messages")
    rows = []
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
                stamps,
            ),
        )
    header = ("topic", "type", "count", "rate Hz", "frame_id", "out-of-order", "duplicates", "stamps [s]")
    lines += ["", *_table(header, rows, right={2, 3, 5, 6})]
    lines += ["", "  roles"]
    roles = [(f"  {role}", info.roles[role]) for role in ROLES if role in info.roles]
    lines += _table(("", ""), roles, set())[1:] if roles else ["    none detected"]
    if info.warnings:
        lines += ["", "  warnings", *(f"    {w}" for w in info.warnings)]
    return "\n".join(lines)
