"""The documented Python API (re-exported as ``slamobs.run_log``, ``slamobs.read_log``, ``slamobs.load_run``).

Thin compositions of the pipeline stages with keyword arguments a notebook user expects; the CLI composes
the same functions.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any


if TYPE_CHECKING:
    import pandas as pd

    from slamobs.pipeline.run import RunSummary
    from slamobs.pipeline.streams import LogStreams


def run_log(
    log: str | Path,
    out: str | Path,
    *,
    observer: str | None = None,
    config: str | Path | dict | None = None,
    force: bool = False,
) -> RunSummary:
    """Run an observer on ``log`` and write the run directory ``out`` (atomically), as ``slamobs run`` does.

    ``config`` is a ``run.yaml`` path or the same mapping as a dict; ``observer`` overrides its observer.
    Returns the run summary (metadata, timings, report dict, notes).
    """
    from slamobs.pipeline.config import load_config, parse_config, with_observer
    from slamobs.pipeline.run import run_log as _run_log

    cfg = parse_config(config) if isinstance(config, dict) else load_config(Path(config) if config else None)
    cfg = with_observer(cfg, observer, "observer")
    return _run_log(Path(log), Path(out), cfg, force=force)


def read_log(log: str | Path, topics: dict[str, str] | None = None, **options: Any) -> LogStreams:
    """Decode ``log`` into the pipeline's columnar streams (angular and linear velocity, directions,
    detections, truth, TF); ``topics`` overrides role -> topic. See :func:`slamobs.pipeline.readers.read_log`."""
    from slamobs.pipeline.readers import read_log as _read_log

    return _read_log(Path(log), topics, **options)


@dataclass
class RunData:
    """A run directory loaded into pandas: ``tables["poses"]`` etc. (also ``run.poses``), ``meta`` (run.json)
    and ``report`` (report.json, or None without ground truth)."""

    path: Path
    meta: dict[str, Any]
    report: dict[str, Any] | None
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)

    def __getattr__(self, name: str) -> pd.DataFrame:
        tables = self.__dict__.get("tables", {})
        if name in tables:
            return tables[name]
        raise AttributeError(f"run {self.__dict__.get('path')} has no table {name!r}")


def load_run(run_dir: str | Path) -> RunData:
    """Every Parquet table of a run directory as a pandas DataFrame, with run.json and report.json."""
    import pandas as pd

    from slamobs.pipeline.evaluation.run_dir import read_json

    run_dir = Path(run_dir)
    meta_path = run_dir / "run.json"
    if not meta_path.is_file():
        from slamobs.pipeline.stored_runs import not_a_run

        raise not_a_run(run_dir)

    report_path = run_dir / "report.json"
    from slamobs.pipeline.stored_runs import run_tables

    # a batch run directory (OUT/runs/<id>) keeps its tables in the dataset; files in the directory (e.g. the
    # aligned tables a later `slamobs report` wrote) take precedence
    tables = {k: v.to_pandas() for k, v in (run_tables(run_dir) or {}).items()}
    tables.update({p.stem: pd.read_parquet(p) for p in sorted(run_dir.glob("*.parquet"))})
    return RunData(run_dir, read_json(meta_path), read_json(report_path) if report_path.is_file() else None, tables)
