"""The runs ``slamobs stats`` summarises, gathered into one table from batch datasets, compare outputs and run
directories.

A batch dataset is read from its ``summary.parquet`` alone (one row per run, only the columns needed, through
pyarrow): 10k runs are one small file, never 10k opened tables or reports. Compare outputs and run directories
are few; their numbers come from each run's ``report.json`` and ``run.json`` through the same
:func:`pipeline.run.headline_metrics` a batch uses for its summary, so every kind of input gives the same
numbers for the same run.
"""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from slamobs.pipeline.batch.ledger import FAILED, SUMMARY, finished, meta_dir, read_summary
from slamobs.pipeline.errors import InputError, one_line
from slamobs.pipeline.stored_runs import run_dir

#: The metrics summarised, in table order: column -> label (lower is better for every one).
METRICS = {
    "ape_trans_rmse_m": "APE translation RMSE [m]",
    "ape_rot_rmse_deg": "APE rotation RMSE [deg]",
    "rpe_trans_rmse_m": "RPE translation RMSE [m]",
    "rpe_rot_rmse_deg": "RPE rotation RMSE [deg]",
    "landmark_rmse_m": "map error RMSE [m]",
    "map_error_m": "map error RMSE, map-only alignment, no trajectory truth [m]",
    "gyro_bias_err": "final gyro bias error [rad/s]",
    "vel_bias_err": "final velocity bias error [m/s]",
    "run_time_s": "estimator run time [s]",
}
#: Columns of the runs table: what identifies a run (``source``: its run directory), then :data:`METRICS`.
RUN_COLUMNS = ("estimator", "log", "status", "source", *METRICS)
#: The stage whose time is a run's run time (compare's ``run_time_s`` is the same stage).
RUN_TIME_STAGE = "observer_s"
COMPARISON = "comparison.parquet"
RUN_JSON = "run.json"
REPORT_JSON = "report.json"


def gather_runs(inputs: list[Path]) -> pd.DataFrame:
    """One row per run of every input (:data:`RUN_COLUMNS`); missing metrics are NaN, never zero."""
    frames = [f for f in (read_input(Path(p)) for p in inputs) if len(f)]
    runs = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=RUN_COLUMNS)
    if runs.empty:
        raise InputError(inputs[0] if inputs else Path("."), "no runs found in the inputs")
    runs = runs.drop_duplicates(subset="source", keep="first", ignore_index=True)  # a run given twice counts once
    runs["log"] = log_labels(runs["log"])
    return runs.reindex(columns=RUN_COLUMNS)


def read_input(path: Path) -> pd.DataFrame:
    """The runs of one input, whichever of the three kinds it is."""
    if (path / SUMMARY).is_file():
        return read_dataset(path)
    if (path / COMPARISON).is_file():
        return read_comparison(path)
    if (path / RUN_JSON).is_file():
        return pd.DataFrame([read_run_dir(path)])
    why = "does not exist" if not path.exists() else "is not a batch dataset, compare output or run directory"
    raise InputError(path, f"{why} (expected {SUMMARY}, {COMPARISON} or {RUN_JSON} in it)")


def _records_pending(out: Path) -> bool:
    """Whether the batch recorded runs after its last ``summary.parquet`` (a batch running or killed)."""
    return any(p.stat().st_size > 0 for p in meta_dir(out).glob("records-*.jsonl"))


def read_dataset(out: Path) -> pd.DataFrame:
    """The runs of a batch dataset from its summary: only the columns needed, one pyarrow read."""
    wanted = ["run_id", "observer", "log", "status", RUN_TIME_STAGE, *[m for m in METRICS if m != "run_time_s"]]
    if _records_pending(out):  # rare: the records are newer than the summary
        table = pa.Table.from_pylist(list(read_summary(out).values()))
    else:
        try:
            schema = pq.read_schema(out / SUMMARY)
            table = pq.read_table(out / SUMMARY, columns=[c for c in wanted if c in schema.names])
        except (pa.ArrowException, OSError) as err:
            raise InputError(out / SUMMARY, f"unreadable batch summary ({one_line(err)})") from None
    if table.num_rows == 0:
        return pd.DataFrame(columns=RUN_COLUMNS)
    frame = table.select([c for c in wanted if c in table.column_names]).to_pandas()
    frame = frame.rename(columns={"observer": "estimator", RUN_TIME_STAGE: "run_time_s"})
    frame["source"] = str(run_dir(out.resolve(), "")) + os.sep + frame["run_id"].astype(str)  # one string op
    return frame.reindex(columns=RUN_COLUMNS).astype({m: "float64" for m in METRICS})


def read_run_dir(path: Path) -> dict:
    """One run directory (of ``slamobs run``, ``compare`` or a batch's ``runs/<id>``) as a runs-table row."""
    from slamobs.pipeline.evaluation.run_dir import read_json

    # here: a batch dataset alone never imports the run path
    from slamobs.pipeline.run import headline_metrics, run_status

    meta = read_json(path / RUN_JSON)
    report = read_json(path / REPORT_JSON) if (path / REPORT_JSON).is_file() else None
    observer = meta.get("observer")
    name = observer.get("name") if isinstance(observer, dict) else observer
    log = (meta.get("input") or {}).get("path") if isinstance(meta.get("input"), dict) else None
    if not name or not log:
        raise InputError(path / RUN_JSON, "names no estimator or no input log: not a slamobs run directory")
    timing = (meta.get("timings_s") or {}).get(RUN_TIME_STAGE)
    return {
        "estimator": str(name),
        "log": str(log),
        "status": run_status(meta),  # ok, or its estimator's own status (compare's and a batch's column)
        "source": str(path.resolve()),
        **headline_metrics(report, meta),
        "run_time_s": float(timing) if timing is not None else None,
    }


def read_comparison(path: Path) -> pd.DataFrame:
    """A compare output: its run directories, and a failed row for each estimator that could not run."""
    try:
        table = pq.read_table(path / COMPARISON, columns=["observer", "status"]).to_pylist()
    except (pa.ArrowException, OSError) as err:
        raise InputError(path / COMPARISON, f"unreadable comparison ({one_line(err)})") from None
    rows, log = [], None
    for row in table:  # a finished run: ok, or its estimator's own status (likely_lost, ...; its run directory's)
        if finished(row["status"]):
            rows.append(read_run_dir(path / row["observer"]))
            log = rows[-1]["log"]
    for row in table:
        if row["status"] == FAILED:
            source = str((path / row["observer"]).resolve())
            rows.append({"estimator": row["observer"], "log": log or str(path), "status": row["status"]})
            rows[-1]["source"] = source
    return pd.DataFrame(rows)


def log_labels(logs: pd.Series) -> pd.Series:
    """Each log by its file name, or by its whole path where two different logs share a name."""
    paths = pd.Series(logs.unique())
    names = paths.map(lambda p: Path(p).name)
    shared = names.duplicated(keep=False)
    label = dict(zip(paths, names.where(~shared, paths)))
    return logs.map(label)
