"""One log through the whole pipeline, as named steps: read -> align -> estimate -> write -> evaluate -> export.

:func:`run_log` is the whole run; its steps are public so that compare, tune and batch compose them instead of
copying them: :func:`prepare_log` (read and align, once per log), :func:`resolve_estimator` (the estimator and
its gains, checked before a long log is read), :func:`estimator_input` (what the estimator needs from a prepared
log), :func:`run_prepared` (estimate and write, :func:`evaluate_run`, :func:`export_run`, run.json). Nothing
here parses arguments or prints.

Memory stays bounded by what the stages need at once, not by the sum of everything a long log produces:
after alignment only the ground truth of the decoded streams is kept, the observer runs a stretch of
``STRETCH_SAMPLES`` velocity samples at a time with each stretch written to Parquet straight away, its
input is released when it is done (single runs), and the report reads back the columns it needs.
"""

from __future__ import annotations

import copy
import platform
import time
from dataclasses import dataclass, field, replace
from functools import cache, partial
from pathlib import Path
from typing import Callable

import numpy as np

from slamobs.pipeline.version import __version__
from slamobs.pipeline.alignment import (
    ACCEL_NOTE,
    AlignedStream,
    TimeWindow,
    align,
    check_required,
    time_window,
    windowed,
)
from slamobs.pipeline.compile_clock import CompileMark, compile_mark, compiled_since
from slamobs.pipeline.config import RunConfig
from slamobs.pipeline.errors import (
    GainError,
    InputError,
    TruthUnusable,
    Unwind,
    machine_failure,
    one_line,
    resource_error,
)
from slamobs.pipeline.observers import ObserverOptions, ObserverResult, ObserverSpec
from slamobs.pipeline.estimators import ESTIMATORS, get_estimator
from slamobs.pipeline.observers.base import (
    InnovationRecord,
    ObserverDiverged,
    held_bias_note,
    jump_note,
    landmark_jumps,
    lost_note,
    split_jumps,
    split_places,
)
from slamobs.pipeline.observers.shared_steps import MAX_SUBSTEPS
from slamobs.pipeline.observers.time_offset import misread as time_offset_misread
from slamobs.pipeline.observers.time_offset import output_clock
from slamobs.pipeline.streams import LogStreams


@dataclass
class RunSummary:
    """What a finished run reports back to its caller."""

    out_dir: Path
    metadata: dict
    timings: dict[str, float]
    report: dict | None = None
    notes: list[str] = field(default_factory=list)
    #: the notes that say the input was damaged or implausible: the readers' repairs (salvaged file, NaN/Inf or
    #: duplicate samples dropped, clock problems) and what the plausibility gates dropped (notes naming a
    #: ``limits.*`` setting); a batch counts them as the run's warnings
    input_warnings: list[str] = field(default_factory=list)

    def status_caveats(self) -> list[str]:
        """What the estimator's own status says where that is off (:func:`.evaluation.report.own_status`: riekf's
        ``observer.filter.status`` lost or gated_at_end, an observer without a gate likely lost), for the tables
        that show a run's :meth:`status`: the words beside its ``lost``, ``gated_at_end`` or ``likely_lost``, the
        sentence report.md's own-record line says (:func:`.evaluation.markdown.own_said`)."""
        from slamobs.pipeline.evaluation.markdown import own_said
        from slamobs.pipeline.evaluation.report import own_status

        own = own_status(self.metadata)
        return [own_said(own)] if own else []

    def status(self) -> str:
        """A finished run's ``status`` in ``compare``'s table and a batch's summary: :func:`run_status`. A run that
        could not start reads ``failed`` (its caller's row)."""
        return run_status(self.metadata)

    def headline(self) -> dict[str, float | None]:
        """The few numbers a comparison or batch summary shows per run (None where not available)."""
        return headline_metrics(self.report, self.metadata)


def run_status(metadata: dict) -> str:
    """A finished run's ``status`` (its run.json ``metadata``): the estimator's own status where its record says
    its estimate is off (``lost``, ``gated_at_end``, ``likely_lost``: :func:`.evaluation.report.own_status`, the
    reason in :meth:`RunSummary.status_caveats`), else ``ok``: ``compare``'s table, a batch's summary.parquet and
    ``stats``' runs.csv. Before session 33 it read ``ok`` whenever the run finished, beside a likely-lost note."""
    from slamobs.pipeline.evaluation.report import own_status

    own = own_status(metadata)
    return own["status"] if own else "ok"


#: Without trajectory truth but with landmark truth (``evaluation.map_truth``): a run's map error RMSE after a
#: map-only SE(3) alignment (run.json ``map_error``): a column of a comparison (after ``landmarks``) and of a batch
#: summary.
MAP_ERROR = "map_error_m"


def headline_metrics(report: dict | None, meta: dict | None = None) -> dict[str, float | None]:
    """APE, RPE, map and final bias errors and convergence time from a report dict (None if absent); with the
    run's run.json ``meta``, ``map_error_m``: its ``map_error`` RMSE (landmark truth without trajectory truth: the
    map after a map-only SE(3) alignment, where ``landmark_rmse_m`` is blank)."""
    r = report or {}

    def get(*keys):
        cur = r
        for k in keys:
            if not isinstance(cur, dict) or cur.get(k) is None:
                return None
            cur = cur[k]
        return float(cur)

    return {
        "ape_trans_rmse_m": get("ape", "translation_m", "rmse"),
        "ape_rot_rmse_deg": get("ape", "rotation_deg", "rmse"),
        "rpe_trans_rmse_m": get("rpe", "translation_m", "rmse"),
        "rpe_rot_rmse_deg": get("rpe", "rotation_deg", "rmse"),
        "landmark_rmse_m": get("landmarks", "error_m", "rmse"),
        "gyro_bias_err": get("biases", "error_norm", "gyro"),
        "vel_bias_err": get("biases", "error_norm", "velocity"),
        "convergence_s": get("convergence", "t_since_start_s"),
        MAP_ERROR: map_error_rmse(meta),
    }


def map_error_rmse(meta: dict | None) -> float | None:
    """run.json ``map_error``'s RMSE in m (the map against landmark truth after a map-only SE(3) alignment, written
    when the log has landmark truth and no trajectory truth), None without one. Public: a comparison and a batch
    summary show it as ``map_error_m``."""
    rmse = (((meta or {}).get("map_error") or {}).get("error_m") or {}).get("rmse")
    return None if rmse is None else float(rmse)


def _out_every(aligned: AlignedStream, rate_hz: float | None) -> int:
    if rate_hz is None or aligned.vel_t_ns.shape[0] < 2:
        return 1
    native = 1e9 / float(np.median(np.diff(aligned.vel_t_ns)))
    return max(1, int(round(native / rate_hz)))


#: Velocity samples per observer stretch and Parquet row group (about 11 min at 200 Hz).
STRETCH_SAMPLES = 131_072
#: The run's tables its error report reads (handed over from the writer as written: :meth:`.TableWriter.kept`).
REPORT_TABLES = ("poses", "biases", "landmarks")
#: Handed over while the values kept for them take at most this many bytes; past it the report reads them back:
#: the writer holds them while the estimator runs, which adds them to the run's peak memory. An observer keeps
#: 120 bytes a sample (one hour at 200 Hz: 86 MB); riekf and batch 336, with the pose covariances (one hour:
#: 242 MB, which took batch's peak from 954 to 1130 MB when the limit counted samples).
HANDOVER_BYTES = 1 << 27


def _diverged(log: Path, observer: str, t_s: float, stats: dict) -> InputError:
    capped = stats.get("capped_intervals", 0)
    why = (
        f"; {capped} intervals needed more than {MAX_SUBSTEPS} sub-steps: its gains are too stiff for the "
        "input rates, lower them"
        if capped
        else "; lower its gains or check the input rates"
    )
    return InputError(log, f"observer '{observer}' diverged (non-finite state) {t_s:.2f} s into the log{why}")


def _check_finite(res: ObserverResult, log: Path, observer: str, t0_ns: int) -> None:
    bad = ~np.isfinite(res.position).all(axis=1)
    if bad.any():
        raise _diverged(log, observer, (res.t_ns[np.argmax(bad)] - t0_ns) * 1e-9, res.stats)


def _cap_note(spec, stats: dict, t0_ns: int) -> list[str]:
    """What hitting the sub-step cap means, when it was hit."""
    n = stats.get("capped_intervals", 0)
    if not n:
        return []
    t = (stats["first_capped_ns"] - t0_ns) * 1e-9
    return [
        f"observer '{spec.name}': {n} intervals between events needed more than {MAX_SUBSTEPS} sub-steps "
        f"(first {t:.2f} s into the log) and were integrated with {MAX_SUBSTEPS}: the estimate there is "
        "approximate (gains too stiff for the input rates, or an implausible measurement; see limits)"
    ]


def _segment_note(spec, stats: dict) -> list[str]:
    """How the observer went on after each gap between segments."""
    moved, held = stats.get("relocalised", 0), stats.get("held", 0)
    if not moved + held:
        return []
    text = (
        f"observer '{spec.name}' after the gaps: pose re-anchored to the map at {moved} of {moved + held} (by "
        "the first frame within time.max_meas_age seeing 3 or more mapped landmarks)"
    )
    if held:
        text += f", held at {held} (the landmarks correct it from there)"
    return [text]


#: Share of a run without a landmark in view above which the run says so (and at least BLIND_NOTE_MIN_S seconds).
BLIND_NOTE_SHARE = 0.2
BLIND_NOTE_MIN_S = 5.0


def blind_note(vel_t_ns: np.ndarray, det_t_ns: np.ndarray, det_offsets: np.ndarray, max_meas_age: float) -> list[str]:
    """Say when no landmark is in view for much of the run: the observer then dead-reckons on its velocities and
    its error grows (detections ending 5 s into a 40 s log gave an APE of 0.41 m against 0.06 m, and nothing said
    why). A frame keeps its landmarks in view for ``max_meas_age`` seconds, as the observers hold them."""
    if vel_t_ns.shape[0] < 2:
        return []
    t0, t1 = int(vel_t_ns[0]), int(vel_t_ns[-1])
    seen = det_t_ns[np.diff(det_offsets) > 0]
    seen = seen[(seen <= t1)]
    age = int(round(max_meas_age * 1e9))
    starts = np.concatenate(([t0], np.minimum(seen + age, t1)))  # each blind stretch starts where cover ends
    ends = np.concatenate((np.maximum(seen, t0), [t1]))
    gaps = np.maximum(ends - starts, 0)
    blind, span = float(gaps.sum()) * 1e-9, (t1 - t0) * 1e-9
    if blind <= max(BLIND_NOTE_SHARE * span, BLIND_NOTE_MIN_S):
        return []
    k = int(np.argmax(gaps))
    return [
        f"no landmark in view for {blind:.1f} s of the {span:.1f} s run (longest {gaps[k] * 1e-9:.1f} s, from "
        f"{(starts[k] - t0) * 1e-9:.1f} s to {(ends[k] - t0) * 1e-9:.1f} s after the start): the observer "
        "dead-reckons on its velocity inputs there, and its error grows"
    ]


def run_inputs(log: Path, config: RunConfig) -> list[str | Path]:
    """Every path a run reads: an output must never replace or hold one of them."""
    return [
        p
        for p in (
            log,
            config.source,
            config.msg_dir,
            config.evaluation.truth_file,
            config.evaluation.truth_times,
            config.map.file,
            config.evaluation.map_truth,
            *config.cameras,
        )
        if p
    ]


def check_directions(spec, aligned: AlignedStream, log: Path, needed: int | None = None) -> None:
    """The log gives the inertial directions the estimator needs (``needed``; default: the observer's own)."""
    needed = spec.min_directions if needed is None else needed
    have = aligned.directions.names if aligned.directions is not None else ()
    if len(have) < needed:
        raise InputError(
            log,
            f"observer '{spec.name}' needs {needed} inertial directions "
            f"(accelerometer in sensor_msgs/Imu, sensor_msgs/MagneticField); the log gives "
            f"{len(have)}{': ' + ', '.join(have) if have else ''}",
        )


@dataclass
class PreparedLog:
    """A log read and aligned once; any number of observers can run on it.

    ``streams`` keeps what the runs need of the decoded log (truth, simulation truth, warnings, clocks), not
    the sensor samples, which live on in ``aligned``; ``topics`` names the topic of each role.
    """

    log: Path
    streams: LogStreams
    aligned: AlignedStream | None  # None once a run that owned it has released it
    timings: dict[str, float]
    topics: dict[str, str] = field(default_factory=dict)
    #: numba compilation not yet reported by a run (kernels compiled while reading, then by each run)
    compiled_from: CompileMark | None = None
    #: tag corners / images made landmarks (pipeline.vision.landmarks.TagLandmarks), None otherwise
    tags: object | None = None
    #: a known map (pipeline.known_map.KnownMap), None otherwise
    known_map: object | None = None
    notes: list[str] = field(default_factory=list)
    #: the linear-velocity noise density of the samples as recorded (pipeline.noise_estimation.Estimate; None:
    #: not estimated, noise.auto false or too few samples)
    velocity_noise: object | None = None
    #: the part of the log used (time.start / time.end, alignment.TimeWindow), None: all of it
    window: TimeWindow | None = None
    #: what the log's samples say about its noise (pipeline.noise.LogNoise), estimated by the first run that
    #: needs it (compare and tune run several estimators on one prepared log)
    estimated_noise: object | None = None


Progress = Callable[[str], None]


def silent(_message: str) -> None:
    """The progress callback that shows nothing."""


def prepare_log(
    log: Path,
    config: RunConfig,
    *,
    directions: bool = True,
    progress: Progress = silent,
    needs_directions: int = 0,
    noise: bool = True,
    estimator: str | None = None,
    warn_only_later: bool = False,
) -> PreparedLog:
    """Read the log and build the observer input (readers -> alignment).

    ``directions=False`` leaves the inertial direction samples out of the aligned stream (observers without
    IMU directions never read them, nor get the accelerometer note). ``needs_directions``: how many inertial
    directions the estimator needs, named with the other missing inputs when the log lacks them. ``noise=False``
    skips the recorded velocity's noise density (0.5 s on an hour of log), which only estimators with noise
    levels use (``uses_noise``: riekf, batch), nor the accelerometer's blocks their velocity-scale check reads.
    ``estimator``: the name(s) the missing-inputs error gives as needing
    them (None: every estimator). ``warn_only_later=True`` leaves the alignment's warn-only checks to
    :func:`run_prepared`, which runs them beside the observer (``alignment.WarnOnly``).
    """
    from slamobs.pipeline.readers import read_log

    from slamobs.pipeline.known_map import read_map, restrict_to_map
    from slamobs.pipeline.vision.cameras import check_camera_files

    log = Path(log)
    mark = compile_mark()
    timings: dict[str, float] = {}
    notes: list[str] = []
    # map files are checked before a long log is read
    known = read_map(config.map.file, config.map.mode) if config.map.file else None
    map_truth = read_map(config.evaluation.map_truth).positions() if config.evaluation.map_truth else None
    check_camera_files(config.cameras)  # a camera file given is read even where the log has no camera topics
    t = time.perf_counter()
    progress(f"reading {log}")
    streams = read_log(log, config.topics or None, **config.reader_options(), progress=progress)
    timings["read_s"] = time.perf_counter() - t
    check_required(streams, needs_directions, estimator)  # every missing input at once, before tag poses
    tags = None
    if streams.tag_corners:
        from slamobs.pipeline.vision.landmarks import tag_landmarks

        t = time.perf_counter()
        progress("tag poses")
        tags = tag_landmarks(
            streams,
            recorded_tags(config, streams, notes).options(),
            camera_files=config.cameras,
            identity_frames=config.frames.assume_identity,
            body_frame=config.frames.body,
        )
        streams.detections = tags.detections
        streams.static_tf = [*streams.static_tf, *tags.transforms]
        streams.tag_corners = []
        timings["tags_s"] = time.perf_counter() - t
    elif config.cameras:
        notes.append("cameras: files given but the log's detections are not tag corners or images: not used")
    if map_truth is not None:
        if streams.landmark_truth:
            notes.append(f"landmark truth from {config.evaluation.map_truth} (evaluation.map_truth) replaces the log's")
        streams.landmark_truth = map_truth
    velocity_noise = _recorded_velocity_noise(streams, config) if noise else None
    t = time.perf_counter()
    progress("aligning the streams")
    topics = _topics(streams)
    aligned = align(
        streams,
        body_frame=config.frames.body,
        truth_frame=config.frames.truth,
        time_source=config.align_time_source,
        identity_frames=config.frames.assume_identity,
        override_identity=config.frames.override_identity,
        gravity=config.directions.gravity,
        magnetic_field=config.directions.magnetic_field,
        keep_directions=directions,
        keep_accel=noise,
        release=True,
        limits=config.limits.as_dict(),
        warn_only_later=warn_only_later,
    )
    if known is not None and known.fixed:
        aligned, note = restrict_to_map(aligned, known)
        if note:
            notes.append(note)
        if aligned.landmark_ids.size == 0:
            raise InputError(log, f"no detection of a landmark of the fixed map {config.map.file}")
    window = time_window(config.time.start, config.time.end, aligned.t0_ns)
    aligned = windowed(aligned, window, log)
    if velocity_noise is not None:  # for the detection pairs' velocity-scale check (time_offset.velocity_scale)
        # the samples' own level where an axis took its pairs' (the motion they miss is in the pairs' regressor)
        # and the white level (the pairs' there) apart, which the check pools over the axes
        level = velocity_noise.value if velocity_noise.sampled is None else velocity_noise.sampled
        level, white = np.resize(np.asarray(level, float), 3), np.resize(np.asarray(velocity_noise.value, float), 3)
        aligned = replace(aligned, velocity_density=level, velocity_white_density=white)
    timings["align_s"] = time.perf_counter() - t
    kept = LogStreams(
        path=streams.path,
        truth=window_truth(streams.truth, window, config),
        landmark_truth=streams.landmark_truth,
        bias_truth=streams.bias_truth,
        warnings=streams.warnings,
        clocks=streams.clocks,
        derived=streams.derived,
        static_tf_dropped=streams.static_tf_dropped,
        static_tf_changed=streams.static_tf_changed,
        stated_covariance=streams.stated_covariance,
        odometry_poses=streams.odometry_poses,
    )
    return PreparedLog(log, kept, aligned, timings, topics, mark, tags, known, notes, velocity_noise, window)


def _recorded_velocity_noise(streams: LogStreams, config: RunConfig):
    """The linear-velocity noise density from the samples as recorded: the alignment interpolates them onto the
    angular velocity's stamps, which would smooth the noise away (None when ``noise.auto`` is off)."""
    lv = streams.linear_velocity
    if not config.noise.auto or lv is None:
        return None
    from slamobs.pipeline.noise import stream_density

    return stream_density(lv.t_ns, lv.xyz)


def log_noise(prepared: PreparedLog, config: RunConfig):
    """The noise levels of the reference estimators on ``prepared`` (``pipeline.noise.NoiseSettings``): the
    config's keys, else plausible message covariances, else estimated from the log (``noise.auto``), else the
    defaults; the gyro level of an angular velocity derived, not measured, says so (:func:`.noise.of_derived`)."""
    from slamobs.pipeline.noise import estimate_log_noise, of_derived, resolve_noise

    if config.noise.auto and prepared.estimated_noise is None and prepared.aligned is not None:
        prepared.estimated_noise = estimate_log_noise(prepared.aligned, prepared.velocity_noise)
    estimated = prepared.estimated_noise if config.noise.auto else None
    settings = resolve_noise(
        config.noise,
        estimated=estimated,
        stated=prepared.streams.stated_covariance,
        odometry=prepared.streams.odometry_poses,
    )
    return of_derived(settings, prepared.streams.derived.get("angular_velocity"))


def detection_checks(prepared: PreparedLog) -> list[str]:
    """What the alignment and the detection pairs say of the detections, the odometry and the camera before any
    estimator runs (the alignment's warnings, e.g. two tags sharing an id; the tag stage's, e.g. a tag size other
    than a tagslam.yaml states or a camera dropped, which ``info --noise --config`` did not show though a run warns;
    and the checks riekf and batch make in a run: a gyro misread, a camera extrinsic turned, a velocity axis
    scaled; ``time_offset.note``), one warning each; none without the aligned streams."""
    from slamobs.pipeline.observers import time_offset

    if prepared.aligned is None or prepared.aligned.det_y.shape[0] == 0:
        return []
    tags = prepared.tags.notes if prepared.tags is not None else []
    said = [n for n in [*prepared.streams.warnings, *prepared.aligned.notes, *tags] if n.startswith("warning: ")]
    return said + time_offset.note(None, time_offset.estimate(prepared.aligned))


def recorded_tags(config: RunConfig, streams: LogStreams, notes: list[str]):
    """The config's ``tags`` section, with the tag size a simulated log records where the config gives none."""
    size = streams.recorded.get("tag_size")
    if size is None or config.tags.size is not None or config.tags.sizes:
        return config.tags
    default = type(config.tags).__dataclass_fields__["family"].default
    family = streams.recorded.get("tag_family") if config.tags.family == default else None
    notes.append(
        f"tag size {size:g} m{f' and family {family}' if family else ''} as the simulated log records them "
        "(tags.size and tags.family in the config override them)"
    )
    return replace(config.tags, size=float(size))


def run_log(
    log: Path,
    out_dir: Path,
    config: RunConfig,
    *,
    force: bool = False,
    progress: Progress = silent,
    plot_workers=None,
) -> RunSummary:
    """Run ``config.observer`` on ``log`` and write a complete run directory ``out_dir`` atomically;
    ``progress`` receives a short line at each stage (and each observer stretch). ``plot_workers`` (started
    :class:`.evaluation.plot_worker.PlotWorkers`, which import matplotlib while the log is read; worth it where a
    core is free: the CLI's ``run`` starts them before its own imports) draw the report's figures, and are
    stopped here at the end (at once without ``evaluation.plots``); without them the figures are drawn in this
    process."""
    from slamobs.pipeline.paths import check_output, run_memory_mb

    try:
        spec = resolve_estimator(config)  # fail on bad gains (and estimator settings) before reading a large log
        check_output(out_dir, run_inputs(Path(log), config), force=force)  # and on an output that must not be
        check_map_mode(spec, config, log)
    except BaseException:
        if plot_workers is not None:  # the caller's helpers end with the run, whenever it ends
            plot_workers.close()
        raise
    # the gravity output frame of an observer without directions comes from the accelerometer
    needed = spec.directions_needed(config)
    directions = needed > 0 or config.output.frame == "gravity"
    workers = plot_workers if config.evaluation.plots else None
    if plot_workers is not None and workers is None:
        plot_workers.close()
    try:
        prepared = prepare_log(
            log,
            config,
            directions=directions,
            progress=progress,
            needs_directions=needed,
            noise=spec.uses_noise,
            estimator=spec.name,
            warn_only_later=True,
        )
        return run_prepared(
            prepared, out_dir, config, force=force, release=True, progress=progress, plot_workers=workers
        )
    except Exception as err:
        if (machine := resource_error(err, log, "a run of this log", run_memory_mb(log))) is not None:
            raise machine from None
        raise
    finally:
        if workers is not None:
            workers.close()


def resolve_estimator(config: RunConfig):
    """The observer and its gains (and a reference estimator's settings), a bad one named with the config it
    came from."""
    try:
        spec = get_estimator(config.observer)
        spec.resolve_gains(config.gains.get(spec.name))
        spec.directions_needed(config)
    except GainError as err:
        raise InputError(config.source or "<config>", str(err)) from None
    return spec


@dataclass
class EstimatorInput:
    """What an estimator needs besides the aligned stream: itself, its gains, its options."""

    spec: ObserverSpec
    gains: dict
    options: ObserverOptions
    #: inertial directions it uses (batch: those of its seed)
    directions: int
    notes: list[str] = field(default_factory=list)


def estimator_input(prepared: PreparedLog, config: RunConfig) -> EstimatorInput:
    """The estimator of ``config`` ready for ``prepared``: gains resolved, map mode and inertial directions checked,
    a known map's starting pose found."""
    aligned, log = prepared.aligned, prepared.log
    if aligned is None:
        raise ValueError("the prepared log's observer input was released by an earlier run")
    spec = resolve_estimator(config)
    gains = spec.resolve_gains(config.gains.get(spec.name))
    check_map_mode(spec, config, log)
    needed = spec.directions_needed(config)
    check_directions(spec, aligned, log, needed)
    start, notes = None, []
    if prepared.known_map is not None:
        from slamobs.pipeline.known_map import map_start

        start = map_start(aligned, prepared.known_map)
        notes.append(start.note)
    noise = None
    if spec.uses_noise:  # the config's levels, else plausible covariances, else estimated, else the defaults
        noise = log_noise(prepared, config).of_estimator(spec.name)
        notes += [f"noise: {line}" for line in noise.lines()] + list(noise.notes)
    options = ObserverOptions(
        max_meas_age=config.time.max_meas_age,
        out_every=_out_every(aligned, config.output.rate_hz),
        known_map=start,
        source=str(log),
        noise=noise,
        batch=config.batch,
        seed_gains=config.gains.get(config.batch.seed),
    )
    return EstimatorInput(spec, gains, options, needed, notes)


def run_metadata(prepared: PreparedLog, config: RunConfig, est: EstimatorInput) -> dict:
    """run.json's description of the run before it starts: software, input, estimator, counts, limits, output."""
    log, streams, aligned, tags = prepared.log, prepared.streams, prepared.aligned, prepared.tags
    spec, options = est.spec, est.options
    return {
        "software": {"slamobs": __version__, "python": platform.python_version()},
        "input": {
            "path": str(log.resolve()),
            "topics": dict(prepared.topics),
            "time_source": config.align_time_source,
            "clocks": dict(streams.clocks),
            "body_frame": aligned.body_frame,
            "body_frame_from": aligned.body_from,
            "base_frame": aligned.base_frame,
            "truth_body": aligned.truth_body,
            # a saturating gyro's stretches (AlignedStream.gyro_clipped): the verdict of an observer integrating them
            "gyro_clipped": (
                {
                    "stretches": int(aligned.gyro_clipped.shape[0]),
                    "seconds": round(float(np.sum(np.diff(aligned.gyro_clipped, axis=1))) * 1e-9, 3),
                    "range_rad_s": aligned.gyro_range,
                }
                if aligned.gyro_clipped.shape[0]
                else None
            ),
            "truth_frame": streams.truth.frame_id if streams.truth is not None else None,
            "derived": dict(streams.derived),
            # every frame pair the readers' warnings name only the first of (decode.frame_pairs)
            "static_tf_changed": [f"{p}->{c}" for p, c in streams.static_tf_changed],
            "static_tf_dropped": [f"{p}->{c}" for p, c in streams.static_tf_dropped],
            "cameras": dict(tags.cameras) if tags is not None else {},
            # per camera topic: its distortion check (vision.distortion), where it had pairs of tags in one image
            "distortion_check": dict(tags.distortion) if tags is not None else {},
            "map": (
                {"file": prepared.known_map.source, "mode": prepared.known_map.mode}
                if prepared.known_map is not None
                else None
            ),
            # the truth read from a file (evaluation.truth_file): `slamobs report` reads it again from here
            "truth_file": (
                {
                    "path": str(Path(config.evaluation.truth_file).resolve()),
                    "format": config.evaluation.truth_format,
                    "times": str(Path(config.evaluation.truth_times).resolve())
                    if config.evaluation.truth_times
                    else None,
                }
                if config.evaluation.truth_file
                else None
            ),
        },
        "observer": {
            "name": spec.name,
            "algorithm": spec.algorithm,
            "gains": est.gains,
            "directions": list(aligned.directions.names) if spec.min_directions and aligned.directions else [],
            "options": {
                "max_meas_age": options.max_meas_age,
                "min_landmarks_bias": options.min_landmarks_bias,
                "out_every": options.out_every,
            },
        },
        "counts": {
            "velocity_samples": int(aligned.vel_t_ns.shape[0]),
            "detection_frames": int(aligned.det_t_ns.shape[0]),
            "detections": int(aligned.det_idx.shape[0]),
            "landmarks": int(aligned.landmark_ids.shape[0]),
        },
        "span_ns": [int(aligned.vel_t_ns[0]), int(aligned.vel_t_ns[-1])],
        **({"time_window": prepared.window.describe()} if prepared.window is not None else {}),
        "segments": aligned.segments(),
        "limits": config.limits.as_dict(),
        "output": {
            "rate_hz": config.output.rate_hz,
            "float_bits": config.output.float_bits,
            "export": list(config.output.export),
            "plots": config.evaluation.plots,  # `slamobs report` draws figures as the run did, or none
        },
    }


def run_prepared(
    prepared: PreparedLog,
    out_dir: Path,
    config: RunConfig,
    *,
    force: bool = False,
    release: bool = False,
    progress: Progress = silent,
    plot_workers=None,
) -> RunSummary:
    """Estimate -> write -> evaluate -> export on an already prepared log, into a run directory made atomically.

    ``release`` drops ``prepared.aligned`` once the estimator is done (the caller runs nothing else on it), so the
    report does not share memory with it.
    """
    from slamobs.pipeline import native
    from slamobs.pipeline.writers import atomic_directory, remove_stale_temporaries, write_json

    log, streams = prepared.log, prepared.streams  # not the aligned stream: released below, it must go
    est = estimator_input(prepared, config)
    check_export(prepared, config)
    needed = est.directions
    # a log read once for several observers (compare) has the accelerometer note: only its users keep it
    aligned_notes = [n for n in prepared.aligned.notes if needed or not n.startswith(ACCEL_NOTE)]
    notes = list(streams.warnings) + aligned_notes
    notes += list(prepared.notes) + est.notes
    warn_only = warn_only_beside(prepared)
    if prepared.tags is not None:
        notes += prepared.tags.notes
    metadata = run_metadata(prepared, config, est)
    timings = dict(prepared.timings)
    if stale := remove_stale_temporaries(Path(out_dir).parent):
        notes.append(
            f"removed {len(stale)} temporary director{'y' if len(stale) == 1 else 'ies'} of killed runs "
            f"next to the output ({', '.join(stale[:3])}{', ...' if len(stale) > 3 else ''})"
        )
    with atomic_directory(out_dir, force=force, inputs=run_inputs(log, config)) as tmp:
        # the report's tables handed over as written, not read back from the files (when there is truth)
        tables = {} if streams.truth is not None and len(streams.truth) else None
        found_offset = offset_beside(prepared, config) if tables is not None else None
        timings.update(
            estimate_splitting(
                prepared, config, est, tmp, metadata, notes, release=release, progress=progress, handover=tables
            )
        )
        native.return_freed_memory()  # what the estimator freed, before the report allocates its own
        if warn_only is not None:  # their notes where the alignment's would have been
            at = len(streams.warnings)
            notes[at : at + len(aligned_notes)] = aligned_notes = warn_only(aligned_notes)
        report, report_error = evaluate_run(
            tmp,
            streams,
            config,
            notes,
            metadata,
            timings,
            progress,
            plot_workers,
            tables=tables,
            found_offset=found_offset,
            check=lambda report: camera_check(prepared, config, report, metadata),  # nothing on a clean run
        )
        export_run(tmp, config, metadata, report, timings, progress)
        note_compilation(prepared, notes, metadata)
        write_json(
            tmp / "run.json",
            {
                **metadata,
                "timings_s": timings,
                "notes": notes,
                "hints": (report or {}).get("hints") or [],  # what to try next (report.run_hints), as `report` says
                "report": "report.json" if report else None,
                "report_error": report_error,
            },
        )
    return RunSummary(
        out_dir=Path(out_dir),
        metadata=metadata,
        timings=timings,
        report=report,
        notes=notes,
        input_warnings=list(streams.warnings) + [n for n in aligned_notes if "limits." in n],
    )


def estimate(
    prepared: PreparedLog,
    config: RunConfig,
    est: EstimatorInput,
    tmp: Path,
    metadata: dict,
    notes: list[str],
    *,
    release: bool = False,
    progress: Progress = silent,
    handover: dict | None = None,
    split: list[dict] | None = None,
) -> dict[str, float]:
    """Run the estimator a stretch at a time, each stretch written to the tables in ``tmp`` while the next one is
    computed (in the output frame fixed from the first stretch); then the map. Adds to ``metadata`` and ``notes``;
    returns the stage timings. A ``handover`` dict receives the report's tables as written
    (:meth:`.TableWriter.kept`). A landmark whose detections jump (:func:`.landmark_jumps`) raises
    :class:`_LandmarksJumped` unless ``split`` lists the jumps already split (or a known map fixes the ids)."""
    from slamobs.pipeline import interrupts, output_frame
    from slamobs.pipeline.writers import BackgroundWrites, TableWriter

    log, aligned, tags = prepared.log, prepared.aligned, prepared.tags
    spec, gains, options = est.spec, est.gains, est.options
    frame_choice = output_frame.parse_frame(config.output.frame)
    frame = None
    t0_ns = int(aligned.vel_t_ns[0])
    n_out = -(-int(aligned.vel_t_ns.shape[0]) // options.out_every)  # rows of the poses and biases, about
    sink = TableWriter(
        tmp,
        config.output.float_bits,
        keep=REPORT_TABLES if handover is not None else (),
        keep_bytes=HANDOVER_BYTES,
        expected_rows={"poses": n_out, "biases": n_out},
    )
    writes = None
    try:
        if tags is not None:
            sink.write({"tag_detections": tags.table})
        observer_s = 0.0
        t = time.perf_counter()
        n_vel = int(aligned.vel_t_ns.shape[0])
        progress(f"{spec.name}: 0 of {n_vel} samples")
        parts = spec.chunks(aligned, gains, replace(options, progress=progress), STRETCH_SAMPLES)
        innovations = InnovationRecord() if spec.uses_noise else None
        for done, part in enumerate(_diverging_as_error(parts, log, spec.name, t0_ns), 1):
            observer_s += time.perf_counter() - t
            interrupts.check()
            _check_finite(part, log, spec.name, t0_ns)
            if innovations is not None:
                innovations.add(part)
            if frame is None:  # fixed from the first stretch, before anything is written
                frame = _output_frame(frame_choice, part, prepared, config, spec, notes)
                metadata["output"]["frame"] = frame.describe()
                writes = BackgroundWrites(partial(_write_stretch, sink, frame))
            # the map as it is now: the observer moves its live map on while this stretch is written
            writes.put(replace(part, landmark_xyz=np.array(part.landmark_xyz)))
            progress(f"{spec.name}: {min(done * STRETCH_SAMPLES, n_vel)} of {n_vel} samples")
            t = time.perf_counter()
        t_end = time.perf_counter()
        observer_s += t_end - t  # the whole run's checks, made while the last stretch is written (spec.chunks)
        part = writes.finish()  # the last stretch, in the output frame
        _write_map(sink, part, aligned)
        _record_estimator(spec, part, aligned, options, t0_ns, metadata, notes)
        if spec.uses_noise:  # the estimators with a gate: an observer's innovations jump once it is lost
            _record_jumps(spec.name, part, innovations, prepared.known_map, split, aligned, t0_ns, metadata, notes)
        metadata["observer"].update(part.stats.get("metadata", {}))  # e.g. the smoother's summary
        metadata["output"]["clock"] = output_clock(part.stats.get("metadata", {}).get("time_offset"))
        stage_timings = dict(part.timings)
        del part
        if release:
            prepared.aligned = aligned = None
        sink.close(metadata)
        if handover is not None:
            handover.update({k: sink.kept(k, skip_null=k == "poses") for k in REPORT_TABLES})
    except BaseException:
        if writes is not None:
            writes.cancel()  # nothing writes into the output any more
        sink.abort()
        raise
    # parts of observer_s (batch: seed_s, smoother_s); the writer's own time (it overlaps the observer) and the
    # landmarks and footers after the last stretch
    return {"observer_s": observer_s, **stage_timings, "write_s": writes.busy_s + time.perf_counter() - t_end}


def _output_frame(
    frame_choice, part: ObserverResult, prepared: PreparedLog, config: RunConfig, spec: ObserverSpec, notes
):
    """The output frame (:func:`.output_frame.resolve`), fixed from the first stretch ``part`` before anything
    is written: every later stretch is written in it."""
    from slamobs.pipeline import output_frame

    return output_frame.resolve(
        frame_choice,
        part,
        aligned=prepared.aligned,
        log=prepared.log,
        gravity=config.directions.gravity,
        truth=truth_on_run_clock(prepared.streams, config),
        t_max_diff=config.evaluation.t_max_diff,
        uses_directions=spec.min_directions > 0,
        known_map=prepared.known_map is not None,
        notes=notes,
    )


def _write_map(sink, part: ObserverResult, aligned: AlignedStream) -> None:
    """The map of the last stretch ``part`` (in the output frame) into ``sink``'s landmarks table, each landmark
    with the stamps of its detections."""
    from slamobs.pipeline.writers import landmark_table

    sink.write(
        {
            "landmarks": landmark_table(
                part.landmark_ids,
                part.landmark_xyz,
                np.repeat(aligned.det_t_ns, np.diff(aligned.det_offsets)),
                aligned.det_ids,
                landmark_cov=part.landmark_cov,
            )
        }
    )


def _record_estimator(spec, part, aligned: AlignedStream, options, t0_ns: int, metadata: dict, notes: list[str]):
    """What the finished estimator says about its run, added to ``metadata``'s counts and to ``notes``: capped
    intervals, segments, blind stretches, its own notes, a lost pose, a held bias."""
    metadata["counts"]["internal_steps"] = int(part.stats.get("substeps", 0))
    metadata["counts"]["capped_intervals"] = int(part.stats.get("capped_intervals", 0))
    notes += _cap_note(spec, part.stats, t0_ns) + _segment_note(spec, part.stats)
    notes += blind_note(aligned.vel_t_ns, aligned.det_t_ns, aligned.det_offsets, options.max_meas_age)
    notes += part.stats.get("notes", [])  # the estimator's own (batch: a solution failing its gate)
    checks = part.stats.get("metadata", {})
    notes += lost_note(spec.name, checks.get("resightings"), checks.get("velocity_bias"))
    notes += held_bias_note(spec.name, checks.get("bias_held"))


def _record_jumps(name, part, innovations, known_map, split, aligned, t0_ns, metadata: dict, notes: list[str]):
    """The landmarks whose detections jump in a gated estimator's innovations, recorded in ``metadata`` and
    ``notes``; raises :class:`_LandmarksJumped` for a first run that should be made again with them split
    (``split``: the jumps already split, placed here in the run made again)."""
    checks = part.stats.get("metadata", {})
    # batch's own residuals may hide a jump its riekf start shows (batch.seed's record), and where both show one the
    # start's are taken: a filter's innovations come before each update, while the smoother's fit spreads over both
    # places (a second tag on the id, seed=3653: its whitened residuals' far stretches left detections of the other
    # tag under the id, which the run made again named again; the start's split them all)
    jumps = checks.get("start_landmark_jumps") or landmark_jumps(*innovations.arrays())
    # after a misread input the detections named, the jumps are the lost pose's: not split (round 7)
    lost = time_offset_misread(checks.get("time_offset"))
    if jumps and split is None and known_map is None and not lost:
        raise _LandmarksJumped(jumps)  # made again with them split (estimate_splitting)
    if split:  # where the run made again put each split landmark's two places
        split_places(split, part.landmark_ids, part.landmark_xyz, part.landmark_cov)
    metadata["observer"]["landmark_jumps"] = (split or []) + jumps
    notes += jump_note(name, split or [], t0_ns, topics=aligned.topics)
    notes += jump_note(name, jumps, t0_ns, lost and not split, aligned.topics)


class _LandmarksJumped(Unwind):
    """Landmarks whose detections jump (``jumps``: :func:`.landmark_jumps`), found once the estimator is done:
    :func:`estimate_splitting` runs it again with them split."""

    def __init__(self, jumps: list[dict]) -> None:
        super().__init__(jumps)
        self.jumps = jumps


def estimate_splitting(
    prepared: PreparedLog, config: RunConfig, est: EstimatorInput, tmp: Path, metadata: dict, notes: list[str], **kw
) -> dict[str, float]:
    """:func:`estimate`, made again when a landmark's detections jump (an id reused for another landmark, or a
    landmark moved: MR.CLAM 6 r1 with landmark 6's id given to landmark 16 from mid-log took batch's map from
    0.09 to 2.2 m) with the detections after each jump as a landmark of their own (:func:`.split_jumps`, the next
    id free of the log's and the landmark truth's); ``first_pass_s`` times the run that found them."""
    kept_notes, kept_metadata, t = len(notes), copy.deepcopy(metadata), time.perf_counter()
    try:
        return estimate(prepared, config, est, tmp, metadata, notes, **kw)
    except _LandmarksJumped as jumped:
        jumps = jumped.jumps
    del notes[kept_notes:]
    metadata.clear()
    metadata.update(kept_metadata)
    first_pass_s = time.perf_counter() - t
    truth = prepared.streams.landmark_truth or {}
    split = replace(prepared, aligned=split_jumps(prepared.aligned, jumps, np.array(list(truth), np.int64)))
    timings = estimate(split, config, est, tmp, metadata, notes, split=jumps, **kw)
    if split.aligned is None:  # released by the run
        prepared.aligned = None
    return {**timings, "first_pass_s": first_pass_s}


def camera_check(prepared: PreparedLog, config: RunConfig, report: dict | None, metadata: dict) -> list[str]:
    """The detection pairs' warnings (``time_offset.misread_warnings``: a camera extrinsic turned or inverted, a gyro
    misread, with their topics and the camera frame) when the report found the estimate's body frame turned against the
    truth's (report.json ``ape.truth_frame_turn``, which a wrong extrinsic also gives) and the run's own notes say
    nothing of the camera: observers do not make those checks (0.18-0.32 CPU s and ~17 s of first compile a run), so
    only a run the report already doubts pays them (the log read and aligned again when the run released it). Made
    before the report is written, so that its notes (:func:`.report.add_run_context`) name the camera."""
    from slamobs.pipeline.evaluation.sections import detections_named_camera
    from slamobs.pipeline.observers import time_offset

    if not ((report or {}).get("ape") or {}).get("truth_frame_turn") or detections_named_camera(metadata):
        return []

    aligned = prepared.aligned
    if aligned is None:
        try:
            aligned = prepare_log(prepared.log, config, directions=False, noise=False).aligned
        except InputError:  # the log changed since it was read: the run's results stand, without the check
            return []
    record = time_offset.estimate(aligned)
    metadata["observer"]["camera_check"] = {"camera_turned": time_offset.camera_turned(record)}  # run.json's flag
    found = time_offset.misread_warnings(config.observer, record)
    return [f"{n} (checked since the report found the estimate turned)" for n in found]


def checked_notes(check, report: dict) -> list[str]:
    """The notes of a check made before the report is written (:func:`camera_check`); a check that fails says so in
    one warning instead of costing the run its report (the report's own errors are :func:`evaluate_run`'s)."""
    if check is None:
        return []
    try:
        return check(report)
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - an extra check never takes the report with it
        return [f"warning: a check before the report failed ({type(err).__name__}: {err}); report written without it"]


def evaluate_run(
    out: Path,
    streams: LogStreams,
    config: RunConfig,
    notes: list[str],
    metadata: dict,
    timings: dict[str, float],
    progress: Progress = silent,
    plot_workers=None,
    *,
    tables: dict | None = None,
    found_offset=None,
    check=None,
) -> tuple[dict | None, str | None]:
    """The error report against the log's truth (report.json, report.md, figures in ``out``), or the map error
    alone where the log has landmark truth only; (report, why there is none). Every run draws its own figures
    (:mod:`.evaluation.figure_jobs`), with the report's on top when there is truth; run.json lists them.
    ``tables`` may hold the run's tables as written (else they are read from ``out``); ``found_offset`` is
    :func:`offset_beside`'s (else the report searches the clock offset against the estimate); ``check``
    (:func:`camera_check`) gives the notes the report's findings call for, added before the report is written."""
    report = report_error = None
    t = time.perf_counter()
    had_truth = streams.truth is not None and len(streams.truth)
    unusable = False  # a truth too short to judge the run by: as none (the map error alone), with its note
    if had_truth:
        progress("error report")
        try:
            report, report_error = _evaluate(
                out, streams, config, notes, metadata, plot_workers, tables or {}, found_offset, check
            )
        except TruthUnusable as err:
            report_error, unusable = one_line(err), True
        timings["report_s"] = time.perf_counter() - t
    if unusable or not had_truth:
        from slamobs.pipeline.evaluation.figure_jobs import NO_TRUTH_NOTE

        why = f"no error report: {report_error}" if unusable else "no trajectory truth: no trajectory error report"
        if not streams.landmark_truth:
            notes.append(why if unusable else NO_TRUTH_NOTE)
        else:
            metadata["map_error"] = _map_error(out, streams.landmark_truth)
            found = (
                _map_error_words(metadata["map_error"])
                if metadata["map_error"]
                else " (fewer than three matched landmarks off one line: none computed)"
            )
            notes.append(f"{why}; the map error against the landmark truth{found}")
            notes += metadata["map_error"].pop("notes") if metadata["map_error"] else []  # its σ against its error
    if report is not None:
        metadata["figures"] = list(report.get("figures") or [])
    elif config.evaluation.plots:
        progress("figures")
        t = time.perf_counter()
        workers = plot_workers if report_error is None else None  # after a failed report: drawn here
        metadata["figures"] = _run_figures(out, notes, workers, config.evaluation.plots, metadata.get("map_error"))
        timings["figures_s"] = time.perf_counter() - t
    return report, report_error


def _run_figures(
    out: Path, notes: list[str], plot_workers=None, plots: bool | str = True, map_error: dict | None = None
) -> list[str]:
    """The run's own figures and its summary report.md (a run without an error report); the figures' names.
    Figures that cannot be drawn are a note: the run's tables stand (out of memory and interruptions still end
    the run)."""
    from slamobs.pipeline import interrupts
    from slamobs.pipeline.evaluation.figure_jobs import RUN_FIGURES, run_tables, write_run_figures

    try:
        written = write_run_figures(out, run_tables(out), notes, plot_workers, plots, map_error)
    except OSError:
        raise
    except Exception as err:  # noqa: BLE001 - the run's outputs are complete without their figures
        if (stop := interrupts.interruption(err)) is not None:
            raise stop from None
        if machine_failure(err):
            raise
        for name in (*RUN_FIGURES, "report.md"):
            (out / name).unlink(missing_ok=True)
        notes.append(f"no figures: {one_line(err) or type(err).__name__}")
        return []
    return [p.name for p in written if p.suffix == ".png"]


def check_export(prepared: PreparedLog, config: RunConfig) -> None:
    """The log's stamps fit the export formats asked for: checked before the work, not after it."""
    aligned = prepared.aligned
    if "mcap" in config.output.export:
        from slamobs.pipeline.results_mcap import check_stamps

        times = [t for t in (aligned.vel_t_ns, aligned.det_t_ns) if t.size]
        if times:
            check_stamps(
                min(int(t.min()) for t in times),
                max(int(t.max()) for t in times),
                prepared.log,
                " (leave mcap out of --export and output.export)",
            )


def export_run(
    out: Path,
    config: RunConfig,
    metadata: dict,
    report: dict | None,
    timings: dict[str, float],
    progress: Progress = silent,
) -> None:
    """The extra formats written inside the run (``output.export``): the results MCAP."""
    if "mcap" in config.output.export:
        from slamobs.pipeline.results_mcap import RESULTS_MCAP, write_results_mcap

        t = time.perf_counter()
        progress("results MCAP")
        write_results_mcap(out, out / RESULTS_MCAP, meta=metadata, report=report)
        timings["export_s"] = time.perf_counter() - t


def note_compilation(prepared: PreparedLog, notes: list[str], metadata: dict) -> None:
    """Say what numba compiled since the last run on this prepared log (a first run's time is mostly that)."""
    compiled = compiled_since(prepared.compiled_from or compile_mark())
    prepared.compiled_from = compile_mark()
    if compiled.functions:
        notes.append(
            f"first run: compiled {compiled.functions} numeric functions in {compiled.seconds:.1f} s "
            "(included in the times above; cached on disk, later runs load them)"
        )
        from slamobs.pipeline.kernel_cache import prune

        prune()  # kernels of sources that changed since: a compiling run has time for it
    metadata["compiled"] = {"functions": compiled.functions, "seconds": round(compiled.seconds, 3)}


def _write_stretch(sink, frame, part):
    """One stretch in the output frame into the tables (on the writer thread); the stretch as written."""
    from slamobs.pipeline.writers import stretch_tables

    part = frame.apply(part)
    sink.write({**stretch_tables(part), **part.extra_tables})
    return part


def check_map_mode(spec, config: RunConfig, log: Path) -> None:
    """A fixed map is an absolute frame: observers that rotate the whole map with their inertial-direction
    correction cannot keep it fixed (pipeline.known_map); the reference estimators take no known map."""
    if config.map.file and not spec.takes_known_map:
        able = ", ".join(s.name for s in ESTIMATORS.values() if s.takes_known_map)
        raise InputError(
            log,
            f"observer '{spec.name}' does not take a known map (map.file); run it without the map "
            f"section, or use an observer ({able})",
        )
    if config.map.file and config.map.mode == "fixed" and spec.min_directions > 0:
        able = ", ".join(s.name for s in ESTIMATORS.values() if s.takes_known_map and not s.min_directions)
        raise InputError(
            log,
            f"map mode 'fixed' does not work with observer '{spec.name}': it rotates the whole map "
            "about the vehicle with its inertial-direction correction; use map.mode: prior, or an "
            f"observer without directions ({able})",
        )


def _map_error(out: Path, landmark_truth: dict) -> dict | None:
    """Map error against landmark truth after a map-only SE(3) alignment, for runs without trajectory truth."""
    from slamobs.pipeline.evaluation.sections import map_only_section
    from slamobs.pipeline.writers import read_columns

    return map_only_section(read_columns(out / "landmarks.parquet"), landmark_truth)


def _map_error_words(map_error: dict) -> str:
    """The map error as report.md's note gives it: the number with its definition (a note without it said only
    that there was one)."""
    err = map_error["error_m"]
    return (
        f": rmse {err['rmse']:.4f} m over {map_error['n_matched']} landmarks after a map-only SE(3) alignment"
        " (run.json map_error)"
    )


def _topics(streams: LogStreams) -> dict[str, str]:
    roles = ("angular_velocity", "linear_velocity", "detections", "truth", "accel", "magnetic")
    return {r: getattr(streams, r).topic for r in roles if getattr(streams, r) is not None}


def _diverging_as_error(parts, log: Path, observer: str, t0_ns: int):
    """The observer's stretches; a diverged estimate ends the run with the one-line divergence error."""
    try:
        yield from parts
    except ObserverDiverged as err:
        raise _diverged(log, observer, (err.t_ns - t0_ns) * 1e-9, err.stats) from None


def window_truth(truth, window: TimeWindow | None, config: RunConfig):
    """The ground truth within the run's time window, by its stamps on the run's clock (all without a window)."""
    if truth is None or window is None:
        return truth
    return window.poses(truth, truth.rec_ns if config.align_time_source == "record" else truth.t_ns)


def offset_beside(prepared: PreparedLog, config: RunConfig):
    """The report's clock-offset search, the truth against the log's own velocity samples
    (:func:`.evaluation.trajectory_evaluation.log_time_offset`: it needs no estimate), started on a thread beside the
    observer, whose kernel leaves the second core idle but for the writer (docs/benchmarks.md, session 18); returns
    the function that gives it (waits for it). A log of more samples than ``OFFSET_BESIDE_SAMPLES`` (its buffers
    would add to the run's peak), or no room for the thread, has it searched when the report asks."""
    from slamobs.pipeline.evaluation.trajectory_evaluation import (
        OFFSET_BESIDE_SAMPLES,
        Pending,
        log_time_offset,
        truth_in_body,
    )

    aligned, truth = prepared.aligned, truth_on_run_clock(prepared.streams, config)
    search = cache(  # the report asks twice: to check it, and for run.json's record
        partial(
            log_time_offset,
            truth,
            aligned.vel_t_ns,
            aligned.omega,
            aligned.velocity,
            truth_rotation_xyzw=config.frames.truth_rotation,
            truth_in_body=truth_in_body(aligned.truth_body),
        )
    )
    if aligned.vel_t_ns.shape[0] + len(truth) > OFFSET_BESIDE_SAMPLES:
        return search
    try:
        return Pending(search, helper=True).result  # the estimator's thread goes first
    except MemoryError:
        return search


def warn_only_beside(prepared: PreparedLog):
    """The alignment's warn-only checks left to the run (``prepare_log(warn_only_later=True)``;
    ``alignment.WarnOnly``: notes only, nothing the observer reads), started on a thread beside the observer like
    :func:`offset_beside` (0.17 CPU s of the one-hour log's align stage moved off the main thread, docs/benchmarks.md
    session 26), but at the run's priority: niced, on a loaded machine they ran late in the observer stage, at the
    run's memory peak (+90 MB on the hour). Returns the function that puts their notes into the alignment's notes it
    is given (waits for them), None when the alignment ran them. No room for the thread: they run when their notes
    are asked for."""
    from slamobs.pipeline.evaluation.trajectory_evaluation import Pending

    warn = prepared.aligned.warn_only
    if warn is None:
        return None
    try:
        found = Pending(warn.run).result
    except MemoryError:
        found = warn.run
    return lambda notes: warn.joined(notes, found())


def truth_on_run_clock(streams: LogStreams, config: RunConfig):
    """The ground truth on the clock the run used (None without truth)."""
    truth = streams.truth
    if truth is not None and config.align_time_source == "record":
        truth = type(truth)(**{**truth.__dict__, "t_ns": truth.rec_ns})
    return truth


def _evaluate(
    out: Path,
    streams: LogStreams,
    config: RunConfig,
    notes: list[str],
    metadata: dict,
    plot_workers=None,
    tables: dict | None = None,
    found_offset=None,
    check=None,
) -> tuple[dict | None, str | None]:
    """Error report against the log's ground truth, and the reason when there is none (``check``: see
    :func:`evaluate_run`).

    The observer's outputs are already complete: a report that cannot be made (truth that cannot be associated,
    or bad truth such as zero quaternions) becomes a note and ``report_error`` in run.json and the run still
    succeeds; only a failure to write (disk full) fails the run.
    """
    from slamobs.pipeline.evaluation import evaluate_tables, write_report
    from slamobs.pipeline.evaluation.figure_jobs import bias_plot_rows
    from slamobs.pipeline.evaluation.report import add_run_context, aligned_rows, with_verdict_warnings
    from slamobs.pipeline.evaluation.figure_jobs import BIASES_PNG, drawn, run_figure_jobs
    from slamobs.pipeline.evaluation.trajectory_evaluation import offset_record
    from slamobs.pipeline.writers import read_columns

    rows = {}  # the aligned tables' rows, written while the report's threads finish (pipeline.evaluation.report)
    try:
        frames = _report_tables(out, tables)
        plots = config.evaluation.plots
        own = []  # the run's own figures (trajectory, map, measurements) are none of the main ones
        if plots == "all":
            own = run_figure_jobs(
                {**frames, "innovations": read_columns(out / "innovations.parquet")}, with_biases=False
            )
        truth = truth_on_run_clock(streams, config)
        options = _report_options(config, metadata)
        # The tables are handed over (the report frees each once used); the bias plot needs only the rows it draws.
        drawn_biases = bias_plot_rows(frames["biases"]) if drawn(BIASES_PNG, plots) else None
        landmarks = frames["landmarks"]
        early, figures = _figure_helpers(plots, plot_workers, own)
        report, evaluation = evaluate_tables(
            frames,
            truth,
            streams.landmark_truth,
            streams.bias_truth,
            options=options,
            drawn_biases=drawn_biases,
            figures=figures,
            aligned=lambda ev: rows.setdefault("sink", aligned_rows(out, ev, landmarks, metadata)),
            found_offset=found_offset,
        )
        if found_offset is not None:  # searched against the log: `slamobs report` checks this one again
            metadata["truth_clock_offset"] = offset_record(found_offset())
        # which clock the truth's stamps are on, as `slamobs report` records it (docs/outputs.md)
        clock = streams.clocks.get(truth.topic, config.align_time_source)
        report["truth_source"]["time_source"] = "file stamps" if config.evaluation.truth_file else clock
        notes += checked_notes(check, report)
        notes[:] = with_verdict_warnings(notes, report, metadata)  # the truth's verdict among the warnings
        add_run_context(report, notes, metadata)
        write_report(
            report,
            out,
            None,
            drawn_biases,
            landmarks,
            truth,
            streams.landmark_truth,
            evaluation=evaluation,
            plots=plots,
            exports=config.output.export,
            metadata=metadata,
            plot_workers=early,
            more_figures=own,
            aligned=rows.get("sink"),
        )
    except OSError:
        raise
    except Exception as err:  # noqa: BLE001 - whatever the truth holds, the observer output stands
        if "sink" in rows:  # closed before the files are removed
            rows["sink"].abort()
        reason = _failed_report(err, out)
        notes.append(f"no error report: {reason}")
        return None, reason
    finally:
        if "sink" in rows:  # an interruption: its files closed (nothing once write_report closed them)
            rows["sink"].abort()
    return report, None


def _report_tables(out: Path, tables: dict | None) -> dict:
    """The report's tables: those handed over in ``tables`` (taken out of it: the report frees each once used),
    the others read from ``out``'s Parquet files. An observer's poses have no uncertainty: their null columns are
    not read (the report needs none of them; the landmarks' are copied into landmarks_aligned.parquet), nor a
    reference estimator's columns the report does not use."""
    from slamobs.pipeline.evaluation.trajectory_evaluation import report_pose_column
    from slamobs.pipeline.writers import read_columns

    wanted = {"poses": report_pose_column}
    handed = tables if tables is not None else {}
    frames = {k: handed.pop(k, None) for k in REPORT_TABLES}
    return {
        k: read_columns(out / f"{k}.parquet", skip_null=k == "poses", wanted=wanted.get(k)) if v is None else v
        for k, v in frames.items()
    }


def _report_options(config: RunConfig, metadata: dict):
    """The report's options from the run's config. Observers that measure gravity fix roll and pitch: written in
    the gravity frame, the report adds the 4-DoF (translation + yaw) alignment; a truth of another frame placed on
    the body is carried to it (:func:`.evaluation.run_dir.options_for_run` reads both from run.json)."""
    from slamobs.pipeline.evaluation.run_dir import options_for_run

    return options_for_run(
        metadata,
        t_max_diff_s=config.evaluation.t_max_diff,
        convergence_threshold_m=config.evaluation.convergence_threshold,
        align=config.evaluation.align or None,
        truth_rotation_xyzw=config.frames.truth_rotation,
    )


def _figure_helpers(plots, plot_workers, own: list) -> tuple:
    """Where the figures are drawn (``plot_workers``, else a :class:`.LocalFigures`), handed the run's ``own``
    figures at once, and the report's ``figures`` callback submitting its chosen jobs there; (None, None) without
    plots. Helpers draw while the report is computed; else drawn at the end."""
    from slamobs.pipeline.evaluation.figure_jobs import chosen
    from slamobs.pipeline.evaluation.plot_worker import LocalFigures

    if not plots:
        return None, None
    early = plot_workers if plot_workers is not None else LocalFigures()
    early.submit(own)

    def figures(jobs: list) -> None:
        early.submit(chosen(jobs, plots))

    return early, figures


def _failed_report(err: Exception, out: Path) -> str:
    """The one-line reason a report could not be made, its half-written files removed from ``out``; re-raises an
    interruption (a SIGTERM or Ctrl-C, not a bad truth), a machine failure (out of memory or threads: the run
    fails, never a run without its report) and :class:`.TruthUnusable` (the caller reports without it)."""
    from slamobs.pipeline import interrupts
    from slamobs.pipeline.evaluation.figure_jobs import RUN_FIGURES
    from slamobs.pipeline.evaluation.report import REPORT_FILES

    if (stop := interrupts.interruption(err)) is not None:
        raise stop from None
    if machine_failure(err):
        raise err
    for name in REPORT_FILES + RUN_FIGURES:  # a report that failed half way is removed
        (out / name).unlink(missing_ok=True)
    if isinstance(err, TruthUnusable):
        raise err
    reason = one_line(err) or type(err).__name__
    if not isinstance(err, ValueError):
        reason = f"{type(err).__name__}: {reason}"
    return reason
