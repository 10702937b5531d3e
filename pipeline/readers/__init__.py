"""Readers: ROS1 bags, rosbag2 directories and MCAP/db3 files into the columnar streams of the pipeline.

``read_log`` opens the log, assigns topics to roles by message type (overridable per role), decodes each
needed topic once into NumPy columns and cleans them (stamp order, exact duplicates, NaN/Inf), reporting
every repair in ``LogStreams.warnings``. Every failure is an :class:`~pipeline.errors.InputError`.
"""

from __future__ import annotations

import functools
from concurrent.futures import Future, ThreadPoolExecutor
from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slamobs.pipeline.errors import InputError, TruthUnusable
from slamobs.pipeline.streams import LogStreams, PoseStream, Vec3Stream
from slamobs.pipeline.vision.detector import TagDetector

from .cameradecode import decode_camera_info, decode_corners, detect_in_images
from .container import Container, damage_notes, detect_container, missing_spans, open_log
from .decode import (
    ALL_ZERO,
    VEC3_ROLES,
    decode_sim_truth,
    decode_topics,
    detection_stream,
    decode_tf,
    gyro_stand_in,
    has_angular_velocity,
    pose_stream,
    static_tf_notes,
    static_transforms,
    tag_detections,
    transform_series,
    vec3_stream,
)
from .inspect import (
    LogInfo,
    TopicSummary,
    apply_clocks,
    clock_set_back,
    format_info,
    inspect_log,
    recommend_clocks,
)
from .msgdefs import complete_definitions, require_types
from .roles import (
    IMAGE_TYPES,
    ODOMETRY,
    REQUIRED_ROLES,
    ROLES,
    TAG_CORNER_TYPES,
    TF_TYPES,
    accepted_types,
    empty_topics,
    select_roles,
    topics_of,
)
from .covariance import stated_from_rows
from .rows import Rows, TfRows
from .trajectory_files import Trajectory, TruthSpec, parse_truth, read_trajectory

if TYPE_CHECKING:
    from collections.abc import Callable

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
    "parse_truth",
    "read_log",
    "read_truth",
]


def _untyped(table: dict) -> list[str]:
    """The topics of :func:`~.roles.topics_of`'s table whose type the log's metadata leaves empty."""
    return sorted(topic for topic, (meta, _) in table.items() if not meta.msgtype)


def _empty(table: dict) -> dict[str, list[str]]:
    """Per required role, the topics of :func:`~.roles.topics_of`'s table of a type it accepts that hold no message."""
    listed = [(topic, meta.msgtype, meta.count) for topic, (meta, _) in table.items()]
    return {role: found for role in REQUIRED_ROLES if (found := empty_topics(role, listed))}


def _every_one(n: int, role: str) -> str:
    """``all 3 samples are`` / ``its one sample is``: a stream all of whose values were NaN or Inf."""
    what = "detection" if role == "detections" else "sample"
    return f"its one {what} is" if n == 1 else f"all {n} {what}s are"


def read_log(
    path: str | Path,
    topics: Mapping[str, str | None] | None = None,
    *,
    msg_dir: str | Path | None = None,
    tag_pattern: str | None = None,
    marker_ns: str | None = None,
    truth_file: str | Path | None = None,
    truth_format: str | None = None,
    truth_times: str | Path | None = None,
    clocks: str | Mapping[str, str] | None = None,
    images: ImageSearch | None = None,
    progress: Callable[[str], None] | None = None,
) -> LogStreams:
    """Decode the topics of each role into streams.

    Args:
        path: ROS1 ``.bag``, rosbag2 directory, ``.mcap`` or ``.db3`` file.
        topics: Role -> topic overrides (``angular_velocity``, ``linear_velocity``, ``detections``,
            ``truth``, ``accel``, ``magnetic``, ``static_tf``, ``tf``, ``sim_truth``); ``''`` or ``None``
            leaves a role out. ``truth`` may be a TF edge ``"parent->child"`` (looked up through ``/tf`` and
            ``/tf_static``, chains allowed).
        msg_dir: Directory of ``pkg/msg/Type.msg`` files for types whose definitions the log lacks.
        tag_pattern: TF tag frames as detections, e.g. ``"tag_{id}"`` (children of the camera frame).
        marker_ns: Detections from a ``MarkerArray``: only the markers of this namespace.
        truth_file: Ground truth from a TUM, EuRoC CSV or KITTI file instead of a topic.
        truth_format: ``tum``, ``euroc`` or ``kitti`` (detected from the content by default).
        truth_times: KITTI ``times.txt`` (KITTI poses carry no stamps).
        clocks: ``None``/``"header"`` keeps header stamps; ``"record"``: the run reads every stream's record
            times (``time.source: record``, applied by the alignment; the notes leave header stamps out);
            ``"auto"`` takes record times for the topics whose
            stamps look unusable next to the reference stream (:func:`recommend_clocks`); a mapping
            ``topic -> "header" | "record"`` chooses per topic. The choice is in ``LogStreams.clocks``.
        images: How camera images are searched for tags (family, detector settings, frame rate); tags found
            in images and tag corner messages land in ``LogStreams.tag_corners`` (made landmarks later, by
            :mod:`pipeline.vision.landmarks`), ``camera_info`` topics in ``LogStreams.camera_info``.
        progress: Receives a line about once a second while images are searched.

    Raises:
        InputError: Unreadable log, bad override, undecodable topic, missing message definition, invalid
            simulation truth or truth file.

    """
    path = Path(path)
    overrides = dict(topics or {})
    truth_file = _outside_truth(overrides, truth_file)
    with open_log(path) as reader, _StreamsAhead() as ahead:
        complete_definitions(reader, msg_dir)
        table = topics_of(reader)
        _check_clock_topics(path, clocks, table)
        selection = select_roles({t: m for t, (m, _) in table.items()}, overrides, path, tag_pattern=tag_pattern)
        streams = LogStreams(
            path=str(path), warnings=list(selection.warnings), untyped=_untyped(table), empty=_empty(table)
        )
        tf_rows: dict[str, TfRows] = {}
        reports: dict[str, list[tuple[str, Cleaning]]] = defaultdict(list)  # topic -> (role, cleaning)
        note = functools.partial(_note_cleaning, path, streams, reports)

        def tf_of(topic: str) -> TfRows:
            if topic not in tf_rows:
                tf_rows[topic] = decode_tf(reader, path, topic, table[topic][1])
            return tf_rows[topic]

        multi = {t for topics_ in selection.multi.values() for t in topics_}
        # the roles in order, what the log records for reading it (a simulated log's tag family) first
        chosen = sorted(_chosen_roles(selection), key=lambda pair: pair[0] != "sim_truth")
        for topic in [t for _, t in chosen] + sorted(multi):
            require_types(reader, path, table[topic][1])
        # the numeric topics and the detections in one pass over the log (each chunk decompressed once)
        rows, detections = ahead.start(reader, path, chosen, table, selection, multi, marker_ns)
        last_use = {topic: k for k, (_, topic) in enumerate(chosen)}
        for k, (role, topic) in enumerate(chosen):
            meta, conns = table[topic]
            if (role, meta.msgtype) in VEC3_ROLES:
                stream, cleaning = _checked_velocity(
                    role, topic, ahead(vec3_stream, rows[topic], role), selection, table, rows, streams, note, overrides
                )
                setattr(streams, role, stream)
                note(stream.topic, role, cleaning)
            elif role == "truth" and selection.truth_edge is None:
                streams.truth, cleaning = ahead(pose_stream, rows[topic])
                note(topic, role, cleaning)
            elif role == "detections" and topic in multi:
                _camera_topics(reader, path, table, selection.multi["detections"], streams, note, images, progress)
            elif role == "camera_info":
                _read_camera_infos(reader, path, table, selection.multi["camera_info"], streams)
            elif role == "detections":
                if meta.msgtype in TF_TYPES:
                    streams.detections, cleaning = tag_detections(tf_of(topic), str(selection.tag_pattern), path)
                else:
                    streams.detections, cleaning = _decoded_detections(detections.pop(topic), ahead)
                note(topic, role, cleaning)
            elif role in ("static_tf", "tf"):
                _read_transforms(role, topic, tf_of(topic), streams, on_record_time=clocks == "record")
            elif role == "sim_truth":
                _read_sim_truth(reader, path, topic, conns, streams)
            if last_use[topic] == k:  # decoded columns no longer needed (streams keep what they share)
                rows.pop(topic, None)
        if selection.truth_edge is not None:
            streams.truth = _truth_from_tf(streams, selection.roles["truth"], selection.truth_edge, tf_of)
        # damage found while decoding (a chunk skipped by its index) is known only now
        streams.warnings[:0] = damage_notes(reader)
        streams.missing_spans = missing_spans(reader)

    if truth_file is not None:
        streams.truth = _truth_from_file(truth_file, truth_format, truth_times)
    return _on_chosen_clocks(streams, clocks, reports)


def _note_cleaning(path: Path, streams: LogStreams, reports, topic: str, role: str, cleaning: Cleaning) -> None:
    """A role's ``cleaning`` kept in ``reports`` (topic -> (role, cleaning)); an InputError when a required role's
    stream in ``streams`` has no sample left once its NaN or Inf ones are dropped."""
    reports[topic].append((role, cleaning))
    stream = getattr(streams, role, None)
    left = (stream.ids.shape[0] if role == "detections" else len(stream)) if stream is not None else 0
    if cleaning.nonfinite and not left and role in REQUIRED_ROLES:
        raise InputError(path, f"{_every_one(cleaning.nonfinite, role)} NaN or Inf ({role})", topic)


def _read_camera_infos(reader, path: Path, table, topics, streams: LogStreams) -> None:
    """Each ``camera_info`` topic's camera model into ``streams.camera_info``, its warnings into the streams'."""
    for info_topic in topics:
        model, warnings = decode_camera_info(reader, path, info_topic, table[info_topic][1])
        streams.camera_info.append(model)
        streams.warnings += warnings


def _decoded_detections(found, ahead: _StreamsAhead) -> tuple:
    """The detection stream and its cleaning from what the pass over the log ``found`` for the detections topic:
    rows still to decode (on the reading thread, ``ahead``), or the stream already made."""
    return ahead(detection_stream, found) if isinstance(found, Rows) else found


def _read_transforms(role: str, topic: str, rows: TfRows, streams: LogStreams, *, on_record_time: bool) -> None:
    """A ``static_tf`` or ``tf`` topic's decoded rows into the streams' static transforms (with those dropped or
    changed) or transform series, their warnings into the streams' named by ``topic``."""
    if role == "static_tf":
        streams.static_tf, warnings, dropped, streams.static_tf_changed = static_transforms(rows)
        streams.warnings += static_tf_notes(topic, warnings)
        streams.static_tf_dropped = {edge: f"{topic}: {w}" for edge, w in dropped.items()}
    else:
        streams.tf, warnings = transform_series(rows, on_record_time=on_record_time)
        streams.warnings += [f"{topic}: {w}" for w in warnings]


def _read_sim_truth(reader, path: Path, topic: str, conns, streams: LogStreams) -> None:
    """A simulated log's truth topic: the landmarks' and biases' truth, what the log records (its tag family),
    and its warnings, into ``streams``."""
    landmarks, bias, warnings, streams.recorded = decode_sim_truth(reader, path, topic, conns)
    streams.landmark_truth = landmarks or None
    streams.bias_truth = bias or None
    streams.warnings += warnings


def _on_chosen_clocks(
    streams: LogStreams, clocks: str | Mapping[str, str] | None, reports: Mapping[str, list[tuple[str, Cleaning]]]
) -> LogStreams:
    """The streams on the clocks chosen (:func:`_clocked`), the cleaning ``reports`` described among the warnings
    on the clock the run reads each topic on (known once the clocks are chosen)."""
    at = len(streams.warnings)
    streams = _clocked(streams, clocks, _stepped(reports))
    streams.warnings[at:at] = _cleaning_notes(reports, set(reports) if clocks == "record" else set(streams.clocks))
    return streams


def _checked_velocity(role, topic, built, selection, table, rows, streams, note, overrides):
    """:func:`_velocity_checks`, and the noise the chosen stream's messages state (``LogStreams.stated_covariance``:
    every message judged, :func:`.covariance.stated_from_rows`)."""
    stream, cleaning = _velocity_checks(role, topic, built, selection, table, rows, streams, note, overrides)
    if stream.topic in rows and (stated := stated_from_rows(rows[stream.topic], role)) is not None:
        streams.stated_covariance[role] = stated
    return stream, cleaning


def _velocity_checks(role, topic, built, selection, table, rows, streams, note, overrides):
    """A velocity stream (``built``: it and its cleaning) checked against what else the log says: an odometry twist
    against its poses, an angular velocity that is all zero against the linear-velocity topic's (not when the config
    names the topic). The linear-velocity topic's own angular velocity, when the gyro is another topic's, is kept
    (``LogStreams.twist_angular``) for the alignment to time the gyro's stamps against."""
    stream, cleaning = built
    gyro = streams.angular_velocity
    if (
        role == "linear_velocity"
        and gyro is not None
        and gyro.topic != topic
        and has_angular_velocity(table[topic][0].msgtype)
    ):
        twist = vec3_stream(rows[topic], "angular_velocity")[0]
        streams.twist_angular = twist if len(twist) > 1 and twist.xyz.any() else None
    if table[topic][0].msgtype == ODOMETRY and role in ("angular_velocity", "linear_velocity"):
        stream, cleaning = _odometry_twist(rows[topic], role, stream, cleaning, streams)
        if (
            role == "linear_velocity"
            and gyro is not None
            and gyro.topic == topic
            and "angular_velocity" not in streams.derived
        ):
            read = streams.odometry_poses.get(role)  # the poses at this twist's stamps, where every one has one
            streams.twist_sampling = _sampling_read(read[0], gyro, stream) if read else None
            if streams.twist_sampling and streams.twist_sampling["model"] == "mean":
                streams.angular_velocity, stream, streams.twist_to_start_ns = _midpoints(
                    streams.twist_sampling, gyro, stream
                )
        return stream, cleaning
    if role == "angular_velocity" and "angular_velocity" not in overrides:
        return _filled_gyro(topic, stream, cleaning, selection, table, rows, streams, note)
    return stream, cleaning


def _sampling_read(poses: PoseStream, angular: Vec3Stream, linear: Vec3Stream) -> dict | None:
    """What each sample of an odometry twist that is both velocities is (:func:`.odometry.twist_sampling`), read
    against the topic's own ``poses`` at the twist's stamps (those :func:`_odometry_twist` kept)."""
    from .odometry import twist_sampling  # lazy, as :func:`_odometry_twist`

    return twist_sampling(poses, angular, linear)


def _midpoints(read: dict, angular: Vec3Stream, linear: Vec3Stream) -> tuple[Vec3Stream, Vec3Stream, np.ndarray | None]:
    """An odometry twist read as interval means, both velocities restamped to the midpoints of their intervals
    (:func:`.odometry.midpoint_restamped`), which ``read`` (``LogStreams.twist_sampling``) records, and per sample
    the nanoseconds from its midpoint back to its interval's start (``LogStreams.twist_to_start_ns``; None for a
    single sample): an estimator that takes the twist linear between samples (riekf, batch) takes each sample at its
    midpoint, one that holds each sample until the next (the observers, the detection offset search) at its
    interval's start (``alignment.held_stamps``)."""
    from .odometry import RESTAMPED, interval_spans, midpoint_restamped  # lazy, as :func:`_odometry_twist`

    read["restamped"] = RESTAMPED
    span = interval_spans(angular) if len(angular) > 1 else None
    to_start = None if span is None else span - span // 2
    return midpoint_restamped(angular), midpoint_restamped(linear), to_start


def _filled_gyro(topic: str, stream: Vec3Stream, cleaning: Cleaning, selection, table, rows, streams, note):
    """An angular velocity that is all zero (an IMU that does not fill the field) replaced by the angular velocity
    of the linear-velocity topic (odometry, a twist) when that one holds some; the IMU's cleaning is noted here."""
    other = selection.roles.get("linear_velocity")
    if other not in rows:
        return stream, cleaning
    decoded = functools.cache(lambda: vec3_stream(rows[other], "angular_velocity"))  # decoded only when asked
    if not gyro_stand_in(topic, lambda: stream.xyz, other, table[other][0].msgtype, lambda: decoded()[0].xyz):
        return stream, cleaning
    found, found_cleaning = decoded()
    cleaning.extra = [e for e in cleaning.extra if not e.startswith(ALL_ZERO)]  # said below, with what replaces it
    note(topic, "angular_velocity", cleaning)
    streams.warnings.append(
        f"{topic}: every angular velocity is zero (not measured): the angular velocity is {other}'s instead "
        "(topics.angular_velocity chooses one)"
    )
    streams.derived["angular_velocity"] = f"{other}'s angular velocity: {topic}'s is all zero"
    return found, found_cleaning


def _outside_truth(overrides: dict, truth_file: str | Path | None) -> str | Path | None:
    """The truth read apart from the log's topics: ``truth_file``, or ``overrides["truth"]`` naming a file or another
    log's topic (the one truth grammar); the truth role is then left out of the log's roles."""
    given = overrides.get("truth")
    if truth_file is None and isinstance(given, str) and given:
        spec = parse_truth(given)
        if spec.kind == "file" or spec.log is not None:
            truth_file = given
    if truth_file is not None:
        overrides["truth"] = ""  # the file is the truth; no topic is read for it
    return truth_file


def _check_clock_topics(path: Path, clocks, table: Mapping) -> None:
    """Every topic ``time.topics`` names is in the log."""
    if isinstance(clocks, Mapping) and (missing := [t for t in clocks if t not in table]):
        raise InputError(
            path,
            f"time.topics names {', '.join(missing)}, which the log does not have (topics: {', '.join(sorted(table))})",
        )


def _one_pass_topics(chosen, table, selection, multi) -> tuple[dict, dict]:
    """The numeric topics (vector roles, truth as a topic) and the detection topics that one pass over the log
    decodes, each with its connections."""
    numeric = {
        t: table[t][1]
        for r, t in chosen
        if (r, table[t][0].msgtype) in VEC3_ROLES or (r == "truth" and selection.truth_edge is None)
    }
    found = {
        t: table[t][1]
        for r, t in chosen
        if r == "detections" and table[t][0].msgtype not in TF_TYPES and t not in multi
    }
    return numeric, found


#: Rows of the streams to build below which :class:`_StreamsAhead` builds them all on the caller's thread (about
#: five minutes of the benchmark's figure-8 logs; the 90 s log has 37,803 messages, the hour 1.5 million).
AHEAD_ROWS = 1 << 17


class _StreamsAhead:
    """Streams built on a second thread while the caller builds the others in role order: each of the builds that
    need nothing but their own topic's decoded rows (:func:`vec3_stream`, :func:`pose_stream`,
    :func:`detection_stream`: pure functions of the rows, most of their time in NumPy without the GIL). The helper
    takes them from the last role backwards and the caller from the first, so the caller waits only for a build
    the helper has started and builds itself one it has not; every stream, its cleaning and the order of the
    notes are those of one thread."""

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._builds: dict[tuple, Future] = {}

    def __enter__(self) -> _StreamsAhead:
        return self

    def __exit__(self, *_exc) -> None:  # a failure or Ctrl-C: the build in hand finishes, the others are dropped
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    @staticmethod
    def _key(build, rows, *args) -> tuple:
        return (build, id(rows), *args)

    def start(self, reader, path: Path, chosen, table, selection, multi, marker_ns) -> tuple[dict, dict]:
        """The numeric topics and the detections decoded in one pass over the log (each chunk decompressed once,
        :func:`decode_topics`), their stream builds started."""
        rows, detections = decode_topics(reader, path, *_one_pass_topics(chosen, table, selection, multi), marker_ns)
        self._start(_own_row_builds(chosen, table, selection, rows, detections))
        return rows, detections

    def _start(self, builds: list[tuple]) -> None:
        """``builds``: ``(function, rows, *args)`` in the order the caller asks for them; on a short log (fewer than
        :data:`AHEAD_ROWS` rows in all, a few ms of builds) none: a second thread would not pay."""
        if len(builds) < 2 or sum(int(rows.t_ns.shape[0]) for _, rows, *_ in builds) < AHEAD_ROWS:
            return
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="slamobs-streams")
        for build, *args in reversed(builds):
            self._builds[self._key(build, *args)] = self._pool.submit(build, *args)

    def __call__(self, build, rows, *args):
        """``build(rows, *args)``: the helper's result if it has started it, else built here."""
        found = self._builds.pop(self._key(build, rows, *args), None)
        if found is not None and not found.cancel():
            return found.result()
        return build(rows, *args)


def _own_row_builds(chosen, table, selection, rows, detections) -> list[tuple]:
    """The builds :class:`_StreamsAhead` may run ahead, in role order (as :func:`read_log`'s loop asks for them)."""
    builds = []
    for role, topic in chosen:
        msgtype = table[topic][0].msgtype
        if (role, msgtype) in VEC3_ROLES:
            builds.append((vec3_stream, rows[topic], role))
        elif role == "truth" and selection.truth_edge is None:
            builds.append((pose_stream, rows[topic]))
        elif role == "detections" and isinstance(found := detections.get(topic), Rows):
            builds.append((detection_stream, found))
    return builds


def _cleaning_notes(reports: Mapping[str, list[tuple[str, Cleaning]]], on_record_time: set[str]) -> list[str]:
    """One warning per topic and cleaning text; the roles are named where a topic serves several. A topic the run
    reads on record time (``on_record_time``) has no header-stamp notes (:meth:`Cleaning.text`)."""
    notes = []
    for topic, cleanings in reports.items():
        texts: dict[str, list[str]] = {}
        for role, cleaning in cleanings:
            if text := cleaning.text(topic in on_record_time):
                texts.setdefault(text, []).append(role)
        for text, roles in texts.items():  # the roles named unless the text is of every role the topic serves
            where = topic if len(roles) == len(cleanings) else f"{topic} ({', '.join(roles)})"
            notes.append(f"{where}: {text}")
        notes += [f"warning: {topic}: {w}" for w in dict.fromkeys(w for _, c in cleanings for w in c.warnings)]
    return notes


def _chosen_roles(selection) -> list[tuple[str, str]]:
    """``(role, topic)`` of every role the selection found a topic for, in the order of ``ROLES``."""
    return [(role, topic) for role in ROLES if (topic := selection.roles.get(role)) is not None]


@dataclass(frozen=True)
class ImageSearch:
    """How camera images are searched for tags (``tags`` section of the config)."""

    family: str = "36h11"
    detector: dict | None = None  # cv2.aruco.DetectorParameters fields
    max_rate_hz: float | None = None  # images per second and camera
    #: a tag family the log records (a simulated log's) replaces ``family`` (the config did not choose one)
    recorded_family: bool = True


def _camera_topics(
    reader,
    path: Path,
    table,
    topics: list[str],
    streams: LogStreams,
    note,
    images: ImageSearch | None,
    progress: Callable[[str], None] | None,
) -> None:
    """Tag corner topics decoded, image topics searched for tags: one corner stream per camera topic."""
    corner_topics = [t for t in topics if table[t][0].msgtype in TAG_CORNER_TYPES]
    image_topics = [t for t in topics if table[t][0].msgtype in IMAGE_TYPES]
    for topic in corner_topics:
        stream, cleaning = decode_corners(reader, path, topic, table[topic][1])
        streams.tag_corners.append(stream)
        note(topic, "detections", cleaning)
    if image_topics:
        search = images or ImageSearch()
        family = streams.recorded.get("tag_family") if search.recorded_family else None
        detector = TagDetector(family or search.family, search.detector, path)
        found = detect_in_images(
            reader,
            path,
            {t: table[t][1] for t in image_topics},
            detector,
            max_rate_hz=search.max_rate_hz,
            progress=progress,
        )
        for topic, result in found.items():
            if result is None:
                streams.warnings.append(f"{topic}: depth images, not searched for tags")
                continue
            streams.tag_corners.append(result[0])
            note(topic, "detections", result[1])


def _poses_at(poses: PoseStream, t_ns: np.ndarray) -> PoseStream | None:
    """The odometry's poses at the twist's stamps ``t_ns`` (cleaning may have dropped other rows of each: NaN
    twists, NaN poses); None when a stamp has no pose."""
    if len(poses) == t_ns.shape[0] and np.array_equal(poses.t_ns, t_ns):
        return poses
    k = np.searchsorted(poses.t_ns, t_ns)
    if not t_ns.shape[0] or k.max() >= len(poses) or not np.array_equal(poses.t_ns[k], t_ns):
        return None
    return PoseStream(
        poses.topic, poses.frame_id, poses.child_frame_id, t_ns, poses.rec_ns[k], poses.position[k], poses.quat_xyzw[k]
    )


def _odometry_twist(
    rows: Rows, role: str, stream: Vec3Stream, cleaning: Cleaning, streams: LogStreams
) -> tuple[Vec3Stream, Cleaning]:
    """An odometry twist checked against the odometry's poses: a zero angular velocity is differentiated from the
    orientations, a linear velocity given in the parent frame is rotated into the child frame (both recorded in
    ``streams.derived``); the linear velocity read is kept with its poses (``streams.odometry_poses``)."""
    derived = streams.derived
    from .odometry import SMOOTH_S, angular_from_poses, rotate_into_child, twist_in_parent  # lazy: ~0.1 s of kernels

    poses, _ = pose_stream(rows)
    # The orientations stand in for a zero twist.angular on their own stamps, whatever rows of the twist cleaning
    # dropped (NaN twists: those rows used to keep the zero twist, the run turning nowhere)
    if role == "angular_velocity" and len(stream) > 1 and not stream.xyz.any():
        derived[role] = (
            f"differentiated from the orientations of {rows.topic} (twist.angular is all zero), "
            f"smoothed over {SMOOTH_S:g} s"
        )
        cleaning.extra = [x for x in cleaning.extra if not x.startswith("all values are zero")]
        cleaning.extra.append("twist.angular is all zero: angular velocity differentiated from the orientations")
        return angular_from_poses(poses, stream.frame_id), cleaning
    if role == "linear_velocity" and (poses := _poses_at(poses, stream.t_ns)) is not None:
        parent, fit_parent, fit_child = twist_in_parent(poses, stream)
        if parent:
            derived[role] = (
                f"twist.linear of {rows.topic} is in the parent frame '{poses.frame_id}' (misfit to the "
                f"position derivative {fit_parent:.3f} m/s there, {fit_child:.3f} m/s in the child frame): "
                f"rotated into '{stream.frame_id}' with the orientations"
            )
            cleaning.extra.append(
                f"twist.linear is in the parent frame '{poses.frame_id}': rotated into the child frame"
            )
            stream = rotate_into_child(poses, stream)
        streams.odometry_poses[role] = (poses, stream)
    return stream, cleaning


#: The run's answer to a clock warning of :func:`recommend_clocks` when it reads header stamps (a topic on another
#: machine's clock, minutes off the velocities', was read on its header stamps with no word of it).
_HEADER_READ = "this run reads header stamps (time.source: header): time.source: auto takes that advice"


def _stepped(reports: Mapping[str, list[tuple[str, Cleaning]]]) -> dict[str, Cleaning]:
    """The topics whose header clock steps mid-log (:attr:`Cleaning.clock_steps`) and their cleaning."""
    return {t: c for t, cleanings in sorted(reports.items()) for _, c in cleanings if c.clock_steps}


def _clocked(
    streams: LogStreams, clocks: str | Mapping[str, str] | None, stepped: Mapping[str, Cleaning]
) -> LogStreams:
    """:func:`_with_clocks`, then a recording clock set back mid-log said, on the clocks the run reads
    (:func:`.inspect.clock_set_back`)."""
    streams = _with_clocks(streams, clocks, stepped)
    streams.warnings += clock_set_back(streams)
    return streams


def _with_clocks(
    streams: LogStreams, clocks: str | Mapping[str, str] | None, stepped: Mapping[str, Cleaning]
) -> LogStreams:
    """``streams`` on the clocks chosen; ``stepped``: the topics whose header clock steps mid-log
    (:func:`decode.clock_steps`) and how, read on record time, every topic with them, when header stamps would be
    read."""
    if clocks == "record":  # the alignment reads every record time
        return streams
    if (clocks is None or clocks == "header") and stepped:
        said = "; ".join(f"{t}: {c.clock_step_words()}" for t, c in stepped.items())
        clock = any(c.clock_set for c in stepped.values())  # else only stamps left 0 step
        what = "header clock set back or forward mid-log" if clock else "some header stamps 0"
        streams.warnings.append(
            f"warning: {what} ({said}): this run reads record time for every "
            "topic (time.source: header reads header stamps only where no clock steps; time.topics: "
            f"{{{next(iter(stepped))}: header}} reads them anyway)"
        )
        clocks = {s.topic: "record" for role in ROLES if hasattr(s := getattr(streams, role, None), "t_ns")}
    if clocks is None or clocks == "header":  # info's clock rule, said where the run does not follow it
        streams.warnings += [f"warning: {w}; {_HEADER_READ}" for w in recommend_clocks(streams)[1]]
        return streams
    if clocks == "auto":
        chosen, warnings = recommend_clocks(streams)
        streams.warnings += warnings
    elif isinstance(clocks, str):
        raise InputError(streams.path, f"unknown clock choice {clocks!r} (header, record, auto or a topic mapping)")
    else:
        chosen = dict(clocks)
    try:
        streams = apply_clocks(streams, chosen)
    except ValueError as err:
        raise InputError(streams.path, str(err)) from None
    used = {s.topic for role in ROLES if (s := getattr(streams, role, None)) is not None and hasattr(s, "t_ns")}
    streams.clocks = {t: c for t, c in chosen.items() if c == "record" and t in used}  # what was applied
    return streams


def _truth_from_tf(
    streams: LogStreams,
    topic: str,
    edge: tuple[str, str],
    tf_of: Callable[[str], TfRows],
) -> PoseStream:
    """Poses of a TF edge ``parent->child`` (a chain through ``/tf_static`` and ``/tf`` is fine)."""
    from slamobs.pipeline.frames import TfBuffer  # lazy: TF chains (~0.1 s) serve only truth from a TF edge

    series = streams.tf if streams.tf and streams.tf[0].topic == topic else transform_series(tf_of(topic))[0]
    truth = TfBuffer(streams.static_tf, series, path=streams.path).pose_stream(*edge, topic)
    if len(truth) == 0:
        raise InputError(streams.path, f"TF edge {edge[0]}->{edge[1]} has no samples", topic)
    return truth


def read_truth(
    source: str | Path,
    log: str | Path | None = None,
    *,
    fmt: str | None = None,
    times: str | Path | None = None,
    clocks: Mapping[str, str] | None = None,
) -> Trajectory:
    """A truth given in the one grammar (``trajectory_files.parse_truth``): a file, ``LOG:TOPIC``,
    ``LOG:parent->child``, or a topic or TF edge of ``log`` (the run's log; ``clocks`` its per-topic clocks).

    Raises:
        InputError: The specification matches nothing; :class:`~slamobs.pipeline.errors.TruthUnusable` when what it
            names holds no poses (e.g. every one NaN).

    """
    spec = parse_truth(source) if fmt in (None, "topic") else TruthSpec("file", str(source))
    if spec.kind == "file" or (spec.kind == "topic" and spec.log is not None):
        return read_trajectory(source, fmt, kitti_times=times)
    where = spec.log or log
    if where is None:
        raise InputError(source, f"a {'TF edge' if spec.kind == 'edge' else 'topic'} needs its log: give LOG:{source}")
    keep = ("truth", "static_tf", "tf") if spec.kind == "edge" else ("truth",)
    own = spec.log is None
    streams = read_log(
        where,
        {**{r: None for r in ROLES if r not in keep}, "truth": spec.name},
        clocks=(clocks or None) if own else None,
    )
    if streams.truth is None or len(streams.truth) == 0:
        why = [w for w in streams.warnings if w.startswith(f"{spec.name}:")]  # e.g. every pose NaN
        raise TruthUnusable(where, "no truth poses" + (f" ({'; '.join(why)})" if why else ""), spec.name)
    return Trajectory(streams.truth, "tf_edge" if spec.kind == "edge" else "topic", str(source))


def _truth_from_file(source: str | Path, fmt: str | None, times: str | Path | None) -> PoseStream:
    """Ground truth from a trajectory file or another log's topic; it must carry stamps to be matched to the log's
    clock."""
    traj = read_truth(source, fmt=fmt, times=times)
    if traj.format not in ("tum", "euroc", "kitti", "topic", "tf_edge"):
        raise InputError(source, f"a {traj.format} trajectory is not a ground-truth file (TUM, EuRoC CSV or KITTI)")
    if not traj.timed:
        raise InputError(source, "KITTI poses carry no stamps: give the sequence's times.txt as truth_times")
    return traj.stream
