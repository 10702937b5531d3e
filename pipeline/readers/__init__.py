"""Readers: ROS1 bags, rosbag2 directories and MCAP/db3 files into the columnar streams of the pipeline.

``read_log`` opens the log, assigns topics to roles by message type (overridable per role), decodes each
needed topic once into NumPy columns and cleans them (stamp order, exact duplicates, NaN/Inf), reporting
every repair in ``LogStreams.warnings``. Every failure is an :class:`~pipeline.errors.InputError`.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.streams import LogStreams

from .container import Container, detect_container, open_log
from .decode import (
    VEC3_ROLES,
    Rows,
    decode_detections,
    decode_rows,
    decode_sim_truth,
    decode_static_tf,
    pose_stream,
    vec3_stream,
)
from .inspect import LogInfo, TopicSummary, format_info, inspect_log
from .roles import ROLES, accepted_types, select_roles, topics_of

if TYPE_CHECKING:
    from collections.abc import Mapping

    from .decode import Cleaning

__all__ = [
    "ROLES",
    "Container",
    "LogInfo",
    "TopicSummary",
    "accepted_types",
    "detect_container",
    "format_info",
    "inspect_log",
    "open_log",
    "read_log",
]


def read_log(path: str | Path, topics: Mapping[str, str | None] | None = None) -> LogStreams:
    """Decode the topics of each role into streams.

    Args:
        path: ROS1 ``.bag``, rosbag2 directory, ``.mcap`` or ``.db3`` file.
        topics: Role -> topic overrides (``angular_velocity``, ``linear_velocity``, ``detections``,
            ``truth``, ``accel``, ``magnetic``, ``static_tf``, ``sim_truth``); ``''`` or ``None``
            leaves a role out.

    Raises:
        InputError: Unreadable log, bad override, undecodable topic or invalid simulation truth.

    """
    path = Path(path)
    with open_log(path) as reader:
        table = topics_of(reader)
        selection = select_roles({t: m for t, (m, _) in table.items()}, topics, path)
        streams = LogStreams(path=str(path), warnings=list(selection.warnings))
        rows: dict[str, Rows] = {}
        reports: dict[str, dict[str, list[str]]] = defaultdict(dict)  # topic -> text -> roles

        def note(topic: str, role: str, cleaning: Cleaning) -> None:
            if text := cleaning.text():
                reports[topic].setdefault(text, []).append(role)

        for role in ROLES:
            if (topic := selection.roles.get(role)) is None:
                continue
            meta, conns = table[topic]
            if (role, meta.msgtype) in VEC3_ROLES:
                if topic not in rows:
                    rows[topic] = decode_rows(reader, path, topic, conns)
                stream, cleaning = vec3_stream(rows[topic], role)
                setattr(streams, role, stream)
                note(topic, role, cleaning)
            elif role == "truth":
                streams.truth, cleaning = pose_stream(decode_rows(reader, path, topic, conns))
                note(topic, role, cleaning)
            elif role == "detections":
                streams.detections, cleaning = decode_detections(reader, path, topic, conns)
                note(topic, role, cleaning)
            elif role == "static_tf":
                streams.static_tf, warnings = decode_static_tf(reader, path, conns)
                streams.warnings += [f"{topic}: {w}" for w in warnings]
            elif role == "sim_truth":
                landmarks, bias, warnings = decode_sim_truth(reader, path, topic, conns)
                streams.landmark_truth = landmarks or None
                streams.bias_truth = bias or None
                streams.warnings += warnings

    for topic, texts in reports.items():
        for text, roles in texts.items():
            where = topic if len(texts) == 1 else f"{topic} ({', '.join(roles)})"
            streams.warnings.append(f"{where}: {text}")
    return streams
