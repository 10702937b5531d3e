"""Run configuration: ``run.yaml`` validated against ``schemas/config.json``, with defaults filled in."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

from pipeline.directions import DEFAULT_GRAVITY, DEFAULT_MAGNETIC_FIELD
from pipeline.errors import InputError

DEFAULT_OBSERVER = "fast-adaptation"


@dataclass(frozen=True)
class RunConfig:
    observer: str = DEFAULT_OBSERVER
    topics: dict[str, str] = field(default_factory=dict)
    body_frame: str | None = None
    identity_frames: tuple[str, ...] = ()
    time_source: str = "header"
    max_meas_age: float = 0.5
    gains: dict[str, dict[str, float]] = field(default_factory=dict)
    output_rate_hz: float | None = None
    t_max_diff: float = 0.01
    convergence_threshold: float = 0.1
    gravity: tuple[float, float, float] = DEFAULT_GRAVITY
    magnetic_field: tuple[float, float, float] = DEFAULT_MAGNETIC_FIELD

    def to_dict(self) -> dict:
        return asdict(self)


def parse_config(data: dict | None, source: str = "<config>") -> RunConfig:
    """Validate a config mapping (as loaded from YAML) and build a :class:`RunConfig`."""
    import jsonschema

    from schemas import config_schema

    data = data or {}
    try:
        jsonschema.validate(data, config_schema())
    except jsonschema.ValidationError as err:
        where = ".".join(str(p) for p in err.absolute_path) or "top level"
        raise InputError(source, f"invalid config at {where}: {err.message}") from None
    frames = data.get("frames", {})
    time = data.get("time", {})
    ev = data.get("evaluation", {})
    dirs = data.get("directions", {})
    return RunConfig(
        observer=data.get("observer", DEFAULT_OBSERVER),
        topics=dict(data.get("topics", {})),
        body_frame=frames.get("body"),
        identity_frames=tuple(frames.get("assume_identity", ())),
        time_source=time.get("source", "header"),
        max_meas_age=float(time.get("max_meas_age", 0.5)),
        gains={k: dict(v) for k, v in data.get("gains", {}).items()},
        output_rate_hz=data.get("output", {}).get("rate_hz"),
        t_max_diff=float(ev.get("t_max_diff", 0.01)),
        convergence_threshold=float(ev.get("convergence_threshold", 0.1)),
        gravity=tuple(dirs.get("gravity", DEFAULT_GRAVITY)),
        magnetic_field=tuple(dirs.get("magnetic_field", DEFAULT_MAGNETIC_FIELD)),
    )


def load_config(path: Path | None) -> RunConfig:
    """Read ``run.yaml`` (or defaults when ``path`` is None)."""
    if path is None:
        return RunConfig()
    from ruamel.yaml import YAML, YAMLError

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "config file not found")
    try:
        data = YAML(typ="safe").load(path.read_text())
    except YAMLError as err:
        raise InputError(path, f"not valid YAML: {str(err).splitlines()[0]}") from None
    if data is not None and not isinstance(data, dict):
        raise InputError(path, "config must be a mapping of sections (observer, topics, gains, ...)")
    return parse_config(data, str(path))
