"""Run configuration: ``run.yaml`` validated against ``schemas/config.json``, with defaults filled in."""

from __future__ import annotations

import difflib
import math
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from slamobs.pipeline.directions import DEFAULT_GRAVITY, DEFAULT_MAGNETIC_FIELD
from slamobs.pipeline.alignment import ABSOLUTE_AFTER_S, DEFAULT_LIMITS, Limits
from slamobs.pipeline.errors import GainError, InputError
from slamobs.pipeline.noise import NoiseConfig
from slamobs.pipeline.smoother.settings import BatchSettings, batch_settings
from slamobs.schemas import DEFAULT_FLOAT_BITS

DEFAULT_OBSERVER = "fast-adaptation"
#: Plausible magnitudes of the configured inertial references: gravity in m/s^2 (the Moon 1.6, Earth 9.8),
#: the magnetic field in Tesla (Earth 25-65 µT).
GRAVITY_RANGE = (1.0, 25.0)
MAGNETIC_RANGE = (1e-6, 1e-3)
#: The largest tag edge (m) a config may give: printed fiducials are centimetres to a metre or two; a size in mm
#: (800 for 0.8 m) or in cm is over it (the camera sample with tags.size 800: every detection 1.55e4 m off,
#: stopped by the range gate naming only limits.max_range).
TAG_SIZE_MAX_M = 5.0
#: Optional extra files of a run directory (``output.export``, ``--export``): the TUM trajectories of estimate
#: and truth, the evo APE result zip, the results MCAP for Foxglove. None by default: the Parquet tables and
#: the report hold the results, the extras only repeat them in other formats.
EXPORTS = ("tum", "evo", "mcap")


@dataclass(frozen=True)
class TimeConfig:
    """``time:``: which clock each stream is put on, and how long a landmark frame stays valid."""

    source: str = "header"  # header | record | auto
    #: per-topic clock (topic -> header | record)
    topics: dict[str, str] = field(default_factory=dict)
    max_meas_age: float = 0.5
    #: the part of the log the run uses (alignment.time_window: seconds from the log's start, or absolute
    #: stamps above alignment.ABSOLUTE_AFTER_S); None: from the beginning / to the end
    start: float | None = None
    end: float | None = None


@dataclass(frozen=True)
class FramesConfig:
    """``frames:``: the body frame and how TF frames are read."""

    body: str | None = None
    assume_identity: tuple[str, ...] = ()
    #: frames whose TF transform is replaced by the identity anyway (a warning in run.json)
    override_identity: tuple[str, ...] = ()
    tag_pattern: str | None = None
    marker_namespace: str | None = None
    #: the frame the truth's poses are of (default: the truth message's child_frame_id): the report carries the truth
    #: to the body by static TF (alignment.truth_frame_in_body)
    truth: str | None = None
    #: quaternion (x, y, z, w) of the truth's body frame in the estimate's: applied to the truth in evaluation only
    truth_rotation: tuple[float, float, float, float] | None = None


@dataclass(frozen=True)
class TagsConfig:
    """``tags:``: tag corners and camera images made landmarks (pipeline.vision)."""

    size: float | None = None
    sizes: dict[int, float] = field(default_factory=dict)
    family: str = "36h11"
    detector: dict[str, float] = field(default_factory=dict)
    max_rate_hz: float | None = None
    max_reprojection_px: float = 2.0
    min_view_angle_deg: float = 12.0
    max_ambiguity: float = 0.6
    max_range_m: float | None = None
    min_side_px: float = 15.0
    ignore: tuple[int, ...] = ()
    sync_s: float | None = None

    def options(self):
        """What :func:`pipeline.vision.landmarks.tag_landmarks` takes."""
        from slamobs.pipeline.vision.landmarks import TagOptions
        from slamobs.pipeline.vision.tagpose import TagQuality

        quality = TagQuality(
            self.max_reprojection_px,
            self.min_view_angle_deg,
            self.max_ambiguity,
            max_range_m=self.max_range_m,
            min_side_px=self.min_side_px,
        )
        return TagOptions(
            self.size,
            {int(k): float(v) for k, v in self.sizes.items()},
            quality,
            frozenset(int(i) for i in self.ignore),
            self.sync_s,
        )


@dataclass(frozen=True)
class EvaluationConfig:
    """``evaluation:``: where the truth comes from and how the report measures against it."""

    truth_file: str | None = None
    truth_format: str | None = None
    truth_times: str | None = None
    t_max_diff: float = 0.01
    convergence_threshold: float = 0.1
    align: str | None = None  # the report's alignment (align.NAMES); None = the report's default (SE(3))
    #: the report's PNG figures: True the main ones, "all" every one, False none (figure_jobs.chosen; figures are
    #: most of the report's time on short logs)
    plots: bool | str = True
    map_truth: str | None = None


@dataclass(frozen=True)
class OutputConfig:
    """``output:``: what the run directory holds."""

    rate_hz: float | None = None
    #: ``start`` | ``gravity`` | ``truth`` | an initial pose (pipeline.output_frame); None = the observer's default
    frame: str | dict | None = None
    float_bits: int = DEFAULT_FLOAT_BITS
    export: tuple[str, ...] = ()  # subset of EXPORTS, in that order


@dataclass(frozen=True)
class DirectionsConfig:
    """``directions:``: the inertial reference vectors in the map frame."""

    gravity: tuple[float, float, float] = DEFAULT_GRAVITY
    magnetic_field: tuple[float, float, float] = DEFAULT_MAGNETIC_FIELD


@dataclass(frozen=True)
class MapConfig:
    """``map:``: a known map (pipeline.known_map)."""

    file: str | None = None
    mode: str = "fixed"  # fixed | prior


#: The typed object of each section of run.yaml that is one.
SECTIONS = {
    "time": TimeConfig,
    "frames": FramesConfig,
    "limits": Limits,
    "tags": TagsConfig,
    "evaluation": EvaluationConfig,
    "output": OutputConfig,
    "directions": DirectionsConfig,
    "map": MapConfig,
    "noise": NoiseConfig,
    "batch": BatchSettings,
}


@dataclass(frozen=True)
class RunConfig:
    """A run's configuration: run.yaml's sections as typed, frozen objects, each default stated once (in its
    section's class)."""

    observer: str = DEFAULT_OBSERVER
    topics: dict[str, str] = field(default_factory=dict)
    msg_dir: str | None = None
    cameras: tuple[str, ...] = ()
    gains: dict[str, dict[str, float]] = field(default_factory=dict)
    time: TimeConfig = TimeConfig()
    frames: FramesConfig = FramesConfig()
    limits: Limits = Limits()
    tags: TagsConfig = TagsConfig()
    evaluation: EvaluationConfig = EvaluationConfig()
    output: OutputConfig = OutputConfig()
    directions: DirectionsConfig = DirectionsConfig()
    map: MapConfig = MapConfig()
    #: reference estimators (batch, riekf): noise levels as given (pipeline.noise) and the smoother's settings
    noise: NoiseConfig = NoiseConfig()
    batch: BatchSettings = BatchSettings()
    #: The file this config was read from (named in errors; not part of the effective configuration).
    source: str | None = None

    def to_dict(self) -> dict:
        """The effective configuration (what a batch hashes and ships to its workers), without ``source``."""
        doc = asdict(self)
        doc.pop("source")
        return doc

    @classmethod
    def from_dict(cls, doc: dict) -> RunConfig:
        """The inverse of :meth:`to_dict`."""
        return cls(**{k: SECTIONS[k](**v) if k in SECTIONS else v for k, v in doc.items()})

    def reader_options(self) -> dict:
        """Keyword arguments of :func:`pipeline.readers.read_log` that this config sets."""
        clocks = self.time.source if self.time.source in ("auto", "record") else (dict(self.time.topics) or None)
        from slamobs.pipeline.readers import ImageSearch

        ev, tags = self.evaluation, self.tags
        return {
            "msg_dir": self.msg_dir,
            "tag_pattern": self.frames.tag_pattern,
            "marker_ns": self.frames.marker_namespace,
            "truth_file": ev.truth_file,
            "truth_format": ev.truth_format,
            "truth_times": ev.truth_times,
            "clocks": clocks,
            "images": ImageSearch(
                tags.family,
                dict(tags.detector) or None,
                tags.max_rate_hz,
                recorded_family=tags.family == TagsConfig.__dataclass_fields__["family"].default,
            ),
        }

    @property
    def align_time_source(self) -> str:
        """What the alignment stage reads: per-topic and automatic choices are applied by the readers."""
        return "record" if self.time.source == "record" else "header"

    def with_section(self, name: str, **changes) -> RunConfig:
        """This config with some fields of one section changed."""
        return replace(self, **{name: replace(getattr(self, name), **changes)})

    def with_window(self, start: float | None = None, end: float | None = None) -> RunConfig:
        """This config with the time window bounds given (``--start`` / ``--end``) as ``time.start`` / ``time.end``."""
        given = {k: v for k, v in (("start", start), ("end", end)) if v is not None}
        return self.with_section("time", **given) if given else self

    def with_plots(self, plots: bool | None) -> RunConfig:
        """This config with ``--plots`` / ``--no-plots`` (None: as it says): :func:`plots_setting`."""
        return self.with_section("evaluation", plots=plots_setting(self.evaluation.plots, plots))


def plots_setting(configured: bool | str, forced: bool | None) -> bool | str:
    """``evaluation.plots`` after ``--plots`` / ``--no-plots`` (``forced``; None: ``configured``, the config's or
    the run's): ``--no-plots`` draws none, ``--plots`` keeps a setting that draws figures and turns ``false`` into
    ``true`` (the main ones). One rule for ``run``, ``compare``, ``batch`` and ``report``."""
    if forced is None:
        return configured
    return (configured or True) if forced else False


def _non_finite(data, where: tuple[str, ...] = ()) -> tuple[tuple[str, ...], float] | None:
    """Where the first NaN or infinite number of a loaded config is, and the number."""
    if isinstance(data, float) and not math.isfinite(data):
        return where, data
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else ()
    for key, value in items:
        found = _non_finite(value, (*where, str(key)))
        if found is not None:
            return found
    return None


def parse_config(data: dict | None, source: str = "<config>") -> RunConfig:
    """Validate a config mapping (as loaded from YAML) and build a :class:`RunConfig`.

    Beyond the schema, every key that names something is checked against what exists (observer names, also
    under ``gains``, and each observer's gains) and the inertial reference vectors must be physically
    plausible; topics and frames are checked against the log when it is read.
    """
    import jsonschema

    from slamobs.schemas import config_schema

    data = data or {}
    bad = _non_finite(data)
    if bad is not None:  # YAML's .nan passes every bound of the schema, .inf the upper ones
        where, value = bad
        hint = " (null switches the gate off)" if where[:1] == ("limits",) else ""
        raise InputError(source, f"invalid config at {'.'.join(where)}: {value} is not a finite number{hint}")
    try:
        jsonschema.validate(data, config_schema())
    except jsonschema.ValidationError as err:
        raise InputError(source, _schema_message(err, data)) from None
    frame = data.get("output", {}).get("frame")
    if isinstance(frame, dict) and sum(q * q for q in frame["orientation_xyzw"]) < 1e-18:
        raise InputError(source, "invalid config at output.frame.orientation_xyzw: a zero quaternion is no rotation")
    if sum(q * q for q in data.get("frames", {}).get("truth_rotation") or (1.0,)) < 1e-18:
        raise InputError(source, "invalid config at frames.truth_rotation: a zero quaternion is no rotation")
    limits = {**DEFAULT_LIMITS, **data.get("limits", {})}
    lo, hi = limits.get("min_range"), limits.get("max_range")
    if lo is not None and hi is not None and lo >= hi:  # every detection would be dropped
        raise InputError(source, f"invalid config at limits: min_range {lo:g} m is not below max_range {hi:g} m")
    tags = dict(data.get("tags", {}))
    for key in tags.get("sizes", {}):
        if not str(key).lstrip("-").isdigit():
            raise InputError(source, f"invalid config at tags.sizes: key {key!r} is not a tag id")
    _check_tag_sizes(tags, source)
    if tags.get("detector"):  # OpenCV's own limits, named with the config (not only at the log's first image)
        from slamobs.pipeline.vision.detector import check_detector_settings

        check_detector_settings(str(tags.get("family", TagsConfig.family)), tags.get("detector"), source)
    known = data.get("map") or {}
    known = {"file": known} if isinstance(known, str) else known
    cameras = data.get("cameras", ())
    output = dict(data.get("output", {}))
    output["export"] = export_kinds(list(output.get("export", [])) + (["mcap"] if output.pop("mcap", None) else []))
    if "frame" in output and isinstance(output["frame"], dict):
        output["frame"] = dict(output["frame"])
    try:
        batch = batch_settings(data.get("batch"))
    except GainError as err:
        raise InputError(source, str(err)) from None
    time = dict(data.get("time", {}))
    time["topics"] = dict(time.get("topics", {}))
    config = RunConfig(
        observer=data.get("observer", DEFAULT_OBSERVER),
        topics=dict(data.get("topics", {})),
        msg_dir=data.get("msg_dir"),
        cameras=(cameras,) if isinstance(cameras, str) else tuple(cameras),
        gains={k: dict(v) for k, v in data.get("gains", {}).items()},
        time=_section(TimeConfig, time),
        frames=_section(FramesConfig, data.get("frames", {})),
        limits=_section(Limits, limits),
        tags=_section(
            TagsConfig,
            {
                **tags,
                "sizes": {int(k): float(v) for k, v in tags.get("sizes", {}).items()},
                "ignore": tuple(int(i) for i in tags.get("ignore", ())),
                "detector": dict(tags.get("detector", {})),
            },
        ),
        evaluation=_section(EvaluationConfig, data.get("evaluation", {})),
        output=_section(OutputConfig, output),
        directions=_section(DirectionsConfig, data.get("directions", {})),
        map=_section(MapConfig, known),
        noise=NoiseConfig.from_section(data.get("noise")),
        batch=batch,
        source=None if source == "<config>" else source,
    )
    check_config(config, source)
    return config


def _section(cls, values: dict):
    """A section object from its validated YAML mapping: lists become tuples, whole numbers where the field is a
    float become floats (YAML's ``1`` for ``1.0``)."""
    types = {f.name: str(f.type) for f in fields(cls)}
    out = {}
    for key, value in values.items():
        if isinstance(value, list):
            value = tuple(float(x) if "float" in types[key] and isinstance(x, int) else x for x in value)
        elif isinstance(value, int) and not isinstance(value, bool) and types[key].startswith("float"):
            value = float(value)
        out[key] = value
    return cls(**out)


def check_config(config: RunConfig, source: str = "<config>") -> None:
    """Names and physics of a config (see :func:`parse_config`); ``--observer`` is checked again by callers
    that override it.

    Raises:
        InputError: An unknown observer (also as a key under ``gains``), a bad gain, or an implausible
            gravity or magnetic field.

    """
    from slamobs.pipeline.estimators import ESTIMATORS, get_estimator

    if config.observer not in ESTIMATORS:
        raise InputError(source, f"observer: {_unknown_observer(config.observer)}")
    start, end = config.time.start, config.time.end
    if (
        start is not None
        and end is not None
        and (start > ABSOLUTE_AFTER_S) == (end > ABSOLUTE_AFTER_S)
        and end <= start
    ):
        raise InputError(source, f"time window: end {end:g} is not after start {start:g}")
    for name, gains in config.gains.items():
        if name not in ESTIMATORS:
            raise InputError(source, f"gains.{name}: {_unknown_observer(name)}")
        try:
            get_estimator(name).resolve_gains(gains)
        except GainError as err:
            raise InputError(source, f"gains.{name}: {err}") from None
    _check_vectors(config, source)


def _schema_message(err, data: dict) -> str:
    """The schema's complaint with what the user meant: gains not under an observer's name (``gains: {k_p: 2}``
    said "'2' is not of type 'object'"), the nearest allowed name for an unknown key (``topic:``, ``plot:``)."""
    path = list(err.absolute_path)
    where = ".".join(str(p) for p in path) or "top level"
    gains = data.get("gains") if isinstance(data, dict) else None
    if path[:1] == ["gains"] and isinstance(gains, dict):
        stray = next((k for k in gains if not isinstance(gains[k], dict)), None)
        if stray is not None:
            example = f"gains: {{{data.get('observer') or DEFAULT_OBSERVER}: {{{stray}: ...}}}}"
            return (
                f"invalid config at gains.{stray}: gains are given per observer, e.g. {example} "
                "(`slamobs observers` lists each one's gains)"
            )
    message = err.message
    if err.validator == "additionalProperties" and isinstance(err.instance, dict):
        allowed = list(err.schema.get("properties", {}))
        for key in err.instance:
            if key not in allowed and (close := difflib.get_close_matches(str(key), allowed, n=1, cutoff=0.6)):
                message += f" (did you mean '{close[0]}'?)"
                break
        else:
            message += f" (allowed: {', '.join(allowed)})" if allowed else ""
    return f"invalid config at {where}: {message}"


def _unknown_observer(name: str) -> str:
    from slamobs.pipeline.estimators import ESTIMATORS

    close = difflib.get_close_matches(name.replace("_", "-"), ESTIMATORS, n=1, cutoff=0.6)
    hint = f"did you mean '{close[0]}'? " if close else ""
    return f"unknown observer '{name}' ({hint}observers: {', '.join(ESTIMATORS)})"


def with_observer(config: RunConfig, name: str | None, option: str = "--observer") -> RunConfig:
    """``config`` running observer ``name`` (None: unchanged); an unknown name is an error naming ``option``."""
    from slamobs.pipeline.estimators import ESTIMATORS

    if not name:
        return config
    if name not in ESTIMATORS:
        raise InputError(option, _unknown_observer(name))
    return replace(config, observer=name)


#: ``--truth none``: no trajectory truth, none detected either (a run as on a log without one)
NO_TRUTH = "none"


def with_truth(config: RunConfig, truth: str | None) -> RunConfig:
    """``config`` with its truth given in the one grammar (``readers.parse_truth``; None: unchanged): a topic or
    TF edge of the log becomes ``topics.truth``, a trajectory file or another log's ``LOG:TOPIC``
    ``evaluation.truth_file`` (read on its own stamps, and again by ``slamobs report``); ``NO_TRUTH``: none, the
    config's and a detected one dropped (``topics.truth`` empty: the role unused)."""
    from slamobs.pipeline.readers import parse_truth

    if not truth:
        return config
    topics = {k: v for k, v in config.topics.items() if k != "truth"}
    if truth.strip() == NO_TRUTH:
        return replace(config, topics={**topics, "truth": ""}).with_section("evaluation", truth_file=None)
    spec = parse_truth(truth)
    if spec.kind == "file" or spec.log is not None:
        return replace(config, topics=topics).with_section("evaluation", truth_file=str(truth))
    return replace(config, topics={**topics, "truth": spec.name}).with_section("evaluation", truth_file=None)


def _check_tag_sizes(tags: dict, source: str) -> None:
    """A tag size over ``TAG_SIZE_MAX_M``: a size in mm or cm, which the range gate met as every detection too far
    ("dropped by the range gate (... farther than limits.max_range 500 m)", naming no tag size) or, under it, the
    run read as a velocity scale."""
    sizes = [("tags.size", tags.get("size"))] + [(f"tags.sizes.{k}", v) for k, v in tags.get("sizes", {}).items()]
    for where, size in sizes:
        if size is not None and size > TAG_SIZE_MAX_M:
            raise InputError(
                source,
                f"invalid config at {where}: {size:g} m is no tag's edge (at most {TAG_SIZE_MAX_M:g} m): the black "
                f"square's edge in metres (in mm? {size / 1000:g} m"
                + (f"; in cm? {size / 100:g} m)" if size / 100 <= TAG_SIZE_MAX_M else ")"),
            )


def _check_vectors(config: RunConfig, source: str) -> None:
    g, m = np.asarray(config.directions.gravity, float), np.asarray(config.directions.magnetic_field, float)
    for key, v, (lo, hi), unit, example in (
        ("gravity", g, GRAVITY_RANGE, "m/s^2", "[0, 0, -9.81]"),
        ("magnetic_field", m, MAGNETIC_RANGE, "T", "[2.0e-5, 0, -4.5e-5] (Tesla)"),
    ):
        norm = float(np.linalg.norm(v)) if np.isfinite(v).all() else float("nan")
        if not lo <= norm <= hi:
            raise InputError(
                source,
                f"directions.{key} {list(map(float, v))} has magnitude {norm:.4g} {unit}, "
                f"physically implausible (expected {lo:g} to {hi:g} {unit}, e.g. {example})",
            )
    sin = float(np.linalg.norm(np.cross(g, m))) / (np.linalg.norm(g) * np.linalg.norm(m))
    if sin < MIN_DIRECTION_SIN:
        raise InputError(
            source, "directions.gravity and directions.magnetic_field are parallel: together they give no heading"
        )


#: Gravity and the magnetic field closer than ~1.1 deg to parallel (or anti-parallel) give no heading.
MIN_DIRECTION_SIN = 0.02


def export_kinds(kinds) -> tuple[str, ...]:
    """``kinds`` (names of EXPORTS; "none" means none) without repeats, in the order of EXPORTS."""
    wanted = set(kinds) - {"none"}
    unknown = wanted - set(EXPORTS)
    if unknown:
        raise ValueError(f"unknown export(s) {', '.join(sorted(unknown))} (choose from {', '.join(EXPORTS)})")
    return tuple(k for k in EXPORTS if k in wanted)


def _beside(truth: str | None, folder: Path) -> str | None:
    """A truth specification whose file, or whose log in ``LOG:TOPIC``, is relative to ``folder`` (the config's),
    made absolute; topics and TF edges as they are."""
    if not truth:
        return truth
    head, sep, tail = truth.partition(":")
    name = head if sep else truth
    if Path(name).is_absolute() or not (folder / name).exists():
        return truth
    return str((folder / name).resolve()) + sep + tail


def load_config(path: Path | None) -> RunConfig:
    """Read ``run.yaml`` (or defaults when ``path`` is None)."""
    if path is None:
        return RunConfig()
    from slamobs.pipeline.paths import check_input, read_yaml

    path = Path(path)
    check_input(path, "config file (YAML)", directory_ok=False)
    data = read_yaml(path, "config")
    if data is not None and not isinstance(data, dict):
        raise InputError(path, "config must be a mapping of sections (observer, topics, gains, ...)")
    config = parse_config(data, str(path))

    # paths in the config are relative to the config file, not to the working directory
    def resolve(v: str | None) -> str | None:
        return v if v is None or Path(v).is_absolute() else str((path.parent / v).resolve())

    ev = config.evaluation
    config = replace(
        config,
        msg_dir=resolve(config.msg_dir),
        cameras=tuple(resolve(v) for v in config.cameras),
        evaluation=replace(
            ev,
            truth_file=_beside(ev.truth_file, path.parent) if ":" in (ev.truth_file or "") else resolve(ev.truth_file),
            truth_times=resolve(ev.truth_times),
            map_truth=resolve(ev.map_truth),
        ),
        map=replace(config.map, file=resolve(config.map.file)),
    )
    truth = config.topics.get("truth")  # a truth file or LOG:TOPIC here is relative to the config file too
    if not isinstance(truth, str) or not truth:
        return config
    from slamobs.pipeline.readers import parse_truth

    truth = _beside(truth, path.parent)
    return with_truth(config, truth) if parse_truth(truth).kind == "file" or ":" in truth else config
