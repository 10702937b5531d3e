"""Run configuration: ``run.yaml`` validated against ``schemas/config.json``, with defaults filled in."""

from __future__ import annotations

import difflib
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from slamobs.pipeline.directions import DEFAULT_GRAVITY, DEFAULT_MAGNETIC_FIELD
from slamobs.pipeline.alignment import DEFAULT_LIMITS
from slamobs.pipeline.errors import GainError, InputError

DEFAULT_OBSERVER = "fast-adaptation"
#: Plausible magnitudes of the configured inertial references: gravity in m/s^2 (the Moon 1.6, Earth 9.8),
#: the magnetic field in Tesla (Earth 25-65 µT).
GRAVITY_RANGE = (1.0, 25.0)
MAGNETIC_RANGE = (1e-6, 1e-3)
#: Significant mantissa bits kept in float outputs (pipeline.writers.round_mantissa; 52 = float64 exactly).
DEFAULT_FLOAT_BITS = 28
#: Optional extra files of a run directory (``output.export``, ``--export``): the TUM trajectories of estimate
#: and truth, the evo APE result zip, the results MCAP for Foxglove. None by default: the Parquet tables and
#: the report hold the results, the extras only repeat them in other formats.
EXPORTS = ("tum", "evo", "mcap")


@dataclass(frozen=True)
class RunConfig:
    observer: str = DEFAULT_OBSERVER
    topics: dict[str, str] = field(default_factory=dict)
    body_frame: str | None = None
    identity_frames: tuple[str, ...] = ()
    #: frames whose TF transform is replaced by the identity anyway (a warning in run.json)
    override_identity: tuple[str, ...] = ()
    time_source: str = "header"  # header | record | auto
    topic_clocks: dict[str, str] = field(default_factory=dict)
    msg_dir: str | None = None
    tag_pattern: str | None = None
    marker_ns: str | None = None
    truth_file: str | None = None
    truth_format: str | None = None
    truth_times: str | None = None
    max_meas_age: float = 0.5
    gains: dict[str, dict[str, float]] = field(default_factory=dict)
    output_rate_hz: float | None = None
    float_bits: int = DEFAULT_FLOAT_BITS
    #: ``start`` | ``gravity`` | ``truth`` | an initial pose (pipeline.output_frame); None = the observer's default
    output_frame: str | dict | None = None
    export: tuple[str, ...] = ()  # subset of EXPORTS, in that order
    t_max_diff: float = 0.01
    convergence_threshold: float = 0.1
    plots: bool = True  # the report's PNG figures (most of its time on short logs; batch jobs may skip them)
    gravity: tuple[float, float, float] = DEFAULT_GRAVITY
    magnetic_field: tuple[float, float, float] = DEFAULT_MAGNETIC_FIELD
    min_range: float | None = DEFAULT_LIMITS["min_range"]
    max_range: float | None = DEFAULT_LIMITS["max_range"]
    max_angular_rate: float | None = DEFAULT_LIMITS["max_angular_rate"]
    max_speed: float | None = DEFAULT_LIMITS["max_speed"]
    max_gap: float | None = DEFAULT_LIMITS["max_gap"]
    # tag corners and camera images (``cameras`` and ``tags`` sections)
    cameras: tuple[str, ...] = ()
    tag_size: float | None = None
    tag_sizes: dict[int, float] = field(default_factory=dict)
    tag_family: str = "36h11"
    tag_detector: dict[str, float] = field(default_factory=dict)
    tag_max_rate_hz: float | None = None
    tag_max_reprojection_px: float = 2.0
    tag_min_view_angle_deg: float = 12.0
    tag_max_ambiguity: float = 0.6
    tag_max_range_m: float | None = None
    tag_min_side_px: float = 15.0
    tag_ignore: tuple[int, ...] = ()
    tag_sync_s: float | None = None
    # a known map, and landmark truth from a file
    map_file: str | None = None
    map_mode: str = "fixed"  # fixed | prior
    map_truth: str | None = None
    #: reference estimators (batch, riekf): noise levels (pipeline.noise) and the smoother's settings
    #: (pipeline.smoother.settings), as given in run.yaml; unset keys take their documented defaults
    noise: dict = field(default_factory=dict)
    batch: dict = field(default_factory=dict)
    #: The file this config was read from (named in errors; not part of the effective configuration).
    source: str | None = None

    def to_dict(self) -> dict:
        """The effective configuration (what a batch hashes and ships to its workers), without ``source``."""
        doc = asdict(self)
        doc.pop("source")
        return doc

    @property
    def limits(self) -> dict[str, float | None]:
        """The plausibility gates, as :func:`pipeline.alignment.align` takes them."""
        return {k: getattr(self, k) for k in DEFAULT_LIMITS}

    def reader_options(self) -> dict:
        """Keyword arguments of :func:`pipeline.readers.read_log` that this config sets."""
        clocks = "auto" if self.time_source == "auto" else (dict(self.topic_clocks) or None)
        from slamobs.pipeline.readers import ImageSearch

        return {"msg_dir": self.msg_dir, "tag_pattern": self.tag_pattern, "marker_ns": self.marker_ns,
                "truth_file": self.truth_file,
                "truth_format": self.truth_format, "truth_times": self.truth_times, "clocks": clocks,
                "images": ImageSearch(self.tag_family, dict(self.tag_detector) or None, self.tag_max_rate_hz)}

    def tag_options(self):
        """What :func:`pipeline.vision.landmarks.tag_landmarks` needs of this config."""
        from slamobs.pipeline.vision.landmarks import TagOptions
        from slamobs.pipeline.vision.tagpose import TagQuality

        quality = TagQuality(self.tag_max_reprojection_px, self.tag_min_view_angle_deg, self.tag_max_ambiguity,
                             max_range_m=self.tag_max_range_m, min_side_px=self.tag_min_side_px)
        return TagOptions(self.tag_size, {int(k): float(v) for k, v in self.tag_sizes.items()}, quality,
                          frozenset(int(i) for i in self.tag_ignore), self.tag_sync_s)

    @property
    def align_time_source(self) -> str:
        """What the alignment stage reads: per-topic and automatic choices are applied by the readers."""
        return "record" if self.time_source == "record" else "header"


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
        where = ".".join(str(p) for p in err.absolute_path) or "top level"
        raise InputError(source, f"invalid config at {where}: {err.message}") from None
    frame = data.get("output", {}).get("frame")
    if isinstance(frame, dict) and sum(q * q for q in frame["orientation_xyzw"]) < 1e-18:
        raise InputError(source, "invalid config at output.frame.orientation_xyzw: a zero quaternion is no rotation")
    frames = data.get("frames", {})
    time = data.get("time", {})
    ev = data.get("evaluation", {})
    dirs = data.get("directions", {})
    limits = {**DEFAULT_LIMITS, **data.get("limits", {})}
    lo, hi = limits.get("min_range"), limits.get("max_range")
    if lo is not None and hi is not None and lo >= hi:  # every detection would be dropped
        raise InputError(source, f"invalid config at limits: min_range {lo:g} m is not below max_range {hi:g} m")
    tags = data.get("tags", {})
    known = data.get("map") or {}
    known = {"file": known} if isinstance(known, str) else known
    cameras = data.get("cameras", ())
    for key in tags.get("sizes", {}):
        if not str(key).lstrip("-").isdigit():
            raise InputError(source, f"invalid config at tags.sizes: key {key!r} is not a tag id")
    if tags.get("detector"):  # OpenCV's own limits, named with the config (not only at the log's first image)
        from slamobs.pipeline.vision.detector import check_detector_settings

        check_detector_settings(str(tags.get("family", "36h11")), tags.get("detector"), source)
    config = RunConfig(
        observer=data.get("observer", DEFAULT_OBSERVER),
        topics=dict(data.get("topics", {})),
        body_frame=frames.get("body"),
        identity_frames=tuple(frames.get("assume_identity", ())),
        override_identity=tuple(frames.get("override_identity", ())),
        time_source=time.get("source", "header"),
        topic_clocks=dict(time.get("topics", {})),
        msg_dir=data.get("msg_dir"),
        tag_pattern=frames.get("tag_pattern"),
        marker_ns=frames.get("marker_namespace"),
        truth_file=ev.get("truth_file"),
        truth_format=ev.get("truth_format"),
        truth_times=ev.get("truth_times"),
        max_meas_age=float(time.get("max_meas_age", 0.5)),
        gains={k: dict(v) for k, v in data.get("gains", {}).items()},
        output_rate_hz=data.get("output", {}).get("rate_hz"),
        output_frame=data.get("output", {}).get("frame"),
        float_bits=int(data.get("output", {}).get("float_bits", DEFAULT_FLOAT_BITS)),
        export=export_kinds(list(data.get("output", {}).get("export", []))
                            + (["mcap"] if data.get("output", {}).get("mcap") else [])),
        t_max_diff=float(ev.get("t_max_diff", 0.01)),
        convergence_threshold=float(ev.get("convergence_threshold", 0.1)),
        plots=bool(ev.get("plots", True)),
        gravity=tuple(float(x) for x in dirs.get("gravity", DEFAULT_GRAVITY)),
        magnetic_field=tuple(float(x) for x in dirs.get("magnetic_field", DEFAULT_MAGNETIC_FIELD)),
        **{k: (None if v is None else float(v)) for k, v in limits.items()},
        cameras=(cameras,) if isinstance(cameras, str) else tuple(cameras),
        tag_size=tags.get("size"),
        tag_sizes={int(k): float(v) for k, v in tags.get("sizes", {}).items()},
        tag_family=str(tags.get("family", "36h11")),
        tag_detector=dict(tags.get("detector", {})),
        tag_max_rate_hz=tags.get("max_rate_hz"),
        tag_max_reprojection_px=float(tags.get("max_reprojection_px", 2.0)),
        tag_min_view_angle_deg=float(tags.get("min_view_angle_deg", 12.0)),
        tag_max_ambiguity=float(tags.get("max_ambiguity", 0.6)),
        tag_max_range_m=tags.get("max_range_m"),
        tag_min_side_px=float(tags.get("min_side_px", 15.0)),
        tag_ignore=tuple(int(i) for i in tags.get("ignore", ())),
        tag_sync_s=tags.get("sync_s"),
        map_file=known.get("file"),
        map_mode=str(known.get("mode", "fixed")),
        map_truth=ev.get("map_truth"),
        noise=dict(data.get("noise", {})),
        batch=dict(data.get("batch", {})),
        source=None if source == "<config>" else source,
    )
    check_config(config, source)
    return config


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
    for name, gains in config.gains.items():
        if name not in ESTIMATORS:
            raise InputError(source, f"gains.{name}: {_unknown_observer(name)}")
        try:
            get_estimator(name).resolve_gains(gains)
        except GainError as err:
            raise InputError(source, f"gains.{name}: {err}") from None
    if config.batch:
        from slamobs.pipeline.smoother.settings import batch_settings

        try:
            batch_settings(config.batch)
        except GainError as err:
            raise InputError(source, str(err)) from None
    _check_vectors(config, source)


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


def _check_vectors(config: RunConfig, source: str) -> None:
    g, m = np.asarray(config.gravity, float), np.asarray(config.magnetic_field, float)
    for key, v, (lo, hi), unit, example in (
        ("gravity", g, GRAVITY_RANGE, "m/s^2", "[0, 0, -9.81]"),
        ("magnetic_field", m, MAGNETIC_RANGE, "T", "[2.0e-5, 0, -4.5e-5] (Tesla)"),
    ):
        norm = float(np.linalg.norm(v)) if np.isfinite(v).all() else float("nan")
        if not lo <= norm <= hi:
            raise InputError(source, f"directions.{key} {list(map(float, v))} has magnitude {norm:.4g} {unit}, "
                                     f"physically implausible (expected {lo:g} to {hi:g} {unit}, e.g. {example})")
    sin = float(np.linalg.norm(np.cross(g, m))) / (np.linalg.norm(g) * np.linalg.norm(m))
    if sin < MIN_DIRECTION_SIN:
        raise InputError(source, "directions.gravity and directions.magnetic_field are parallel: together they "
                                 "give no heading")


#: Gravity and the magnetic field closer than ~1.1 deg to parallel (or anti-parallel) give no heading.
MIN_DIRECTION_SIN = 0.02


def export_kinds(kinds) -> tuple[str, ...]:
    """``kinds`` (names of EXPORTS; "none" means none) without repeats, in the order of EXPORTS."""
    wanted = set(kinds) - {"none"}
    unknown = wanted - set(EXPORTS)
    if unknown:
        raise ValueError(f"unknown export(s) {', '.join(sorted(unknown))} (choose from {', '.join(EXPORTS)})")
    return tuple(k for k in EXPORTS if k in wanted)


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
    def resolve(v: str) -> str:
        return v if Path(v).is_absolute() else str((path.parent / v).resolve())

    rel = {k: resolve(v) for k in ("msg_dir", "truth_file", "truth_times", "map_file", "map_truth")
           if (v := getattr(config, k)) is not None}
    if config.cameras:
        rel["cameras"] = tuple(resolve(v) for v in config.cameras)
    return replace(config, **rel) if rel else config
