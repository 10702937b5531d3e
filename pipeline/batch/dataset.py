"""The batch output directory: Hive-partitioned tables, per-run directories and ``summary.parquet``.

Layout of ``OUT/``::

    runs/<run_id>/                     the run directory exactly as ``run_log`` writes it
    <table>/run_id=<run_id>/part-0.parquet   its tables with a ``run_id`` column (poses, biases, ...)
    summary.parquet                    one row per log

Every file appears by rename, so a reader never sees half a file. ``run_id`` is stored inside the files as
a dictionary-encoded string: that is the type pyarrow gives a Hive partition key, so the file column and the
directory key merge when ``pd.read_parquet(OUT / "poses")`` reads the whole dataset.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.writers import parquet_options
from slamobs.schemas import OPTIONAL_TABLES, TABLES

RUNS = "runs"
SUMMARY = "summary.parquet"
PART = "part-0.parquet"
LOCK = ".batch.lock"
ALL_TABLES = TABLES + OPTIONAL_TABLES
RUN_ID_TYPE = pa.dictionary(pa.int32(), pa.string())

_F, _I, _S = pa.float64(), pa.int64(), pa.string()
#: Columns of ``summary.parquet`` (units in the names; null where a run did not get that far).
SUMMARY_SCHEMA = pa.schema([
    ("run_id", _S), ("log", _S), ("config_file", _S), ("content_hash", _S), ("observer", _S),
    ("config_hash", _S), ("status", _S), ("error", _S), ("warnings", _S),
    ("finished_at", pa.timestamp("us", tz="UTC")), ("worker", _S), ("slamobs_version", _S),
    ("total_s", _F), ("read_s", _F), ("align_s", _F), ("observer_s", _F), ("write_s", _F), ("report_s", _F),
    ("dataset_s", _F),
    ("velocity_samples", _I), ("detection_frames", _I), ("detections", _I), ("landmarks", _I),
    ("internal_steps", _I),
    # pipeline.run.headline_metrics: gyro_bias_err in rad/s, vel_bias_err in m/s (final error norms)
    ("ape_trans_rmse_m", _F), ("ape_rot_rmse_deg", _F), ("landmark_rmse_m", _F),
    ("gyro_bias_err", _F), ("vel_bias_err", _F), ("convergence_s", _F),
])
STATUSES = ("ok", "failed", "skipped")


def run_dir(out: Path, run_id: str) -> Path:
    return Path(out) / RUNS / run_id


def partition_file(out: Path, table: str, run_id: str) -> Path:
    return Path(out) / table / f"run_id={run_id}" / PART


def write_partitions(out: Path, run_id: str) -> list[str]:
    """Copy the tables of ``runs/<run_id>/`` into the partitioned datasets, adding the ``run_id`` column.

    Partitions of this run_id for tables the run did not write (e.g. an earlier observer's ``jumps``) are
    removed, so the dataset always shows one run per run_id.
    """
    src = run_dir(out, run_id)
    written = []
    for table in ALL_TABLES:
        dest = partition_file(out, table, run_id)
        path = src / f"{table}.parquet"
        if not path.is_file():
            _remove_partition(dest)
            continue
        data = pq.read_table(path)
        ids = pa.DictionaryArray.from_arrays(np.zeros(len(data), np.int32), pa.array([run_id], _S))
        data = data.append_column(pa.field("run_id", RUN_ID_TYPE, nullable=False), ids)
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = dest.parent / f".{PART}.tmp-{os.getpid()}"
        pq.write_table(data, tmp, **parquet_options(data.schema))
        os.replace(tmp, dest)
        written.append(table)
    return written


def _remove_partition(dest: Path) -> None:
    if dest.parent.exists():
        shutil.rmtree(dest.parent, ignore_errors=True)


def remove_run(out: Path, run_id: str) -> None:
    """Drop every file of ``run_id``: the dataset holds only runs the summary reports as done."""
    for table in ALL_TABLES:
        _remove_partition(partition_file(out, table, run_id))
    shutil.rmtree(run_dir(out, run_id), ignore_errors=True)


def run_complete(out: Path, run_id: str) -> bool:
    """The run directory is there and each of its tables has its partition."""
    src = run_dir(out, run_id)
    if not (src / "run.json").is_file():
        return False
    return all(partition_file(out, p.stem, run_id).is_file() for p in src.glob("*.parquet"))


def read_summary(out: Path) -> dict[str, dict]:
    """Rows of ``summary.parquet`` by run_id ({} if there is none yet)."""
    path = Path(out) / SUMMARY
    if not path.is_file():
        return {}
    try:
        rows = pq.read_table(path).to_pylist()
    except (pa.ArrowException, OSError) as err:
        raise InputError(path, f"unreadable batch summary ({err}); move it away to start afresh") from None
    return {r["run_id"]: r for r in rows}


def write_summary(out: Path, rows: Mapping[str, dict]) -> Path:
    """Replace ``summary.parquet`` atomically (a reader sees the old or the new file, never a mix)."""
    path = Path(out) / SUMMARY
    cols = {f.name: [r.get(f.name) for r in rows.values()] for f in SUMMARY_SCHEMA}
    table = pa.table(cols, schema=SUMMARY_SCHEMA)
    tmp = path.parent / f".{SUMMARY}.tmp-{os.getpid()}"
    pq.write_table(table, tmp, compression="zstd")
    os.replace(tmp, path)
    return path


def cleanup_stale(out: Path) -> int:
    """Remove what an interrupted batch left half-written: temporary run dirs and partition files."""
    out = Path(out)
    stale = [p for p in (out / RUNS).glob(".*.tmp-*")] + list((out / RUNS).glob(".*.old-*"))
    stale += list(out.glob(f".{SUMMARY}.tmp-*"))
    for table in ALL_TABLES:
        stale += list((out / table).glob(f"run_id=*/.{PART}.tmp-*"))
    for p in stale:
        shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
    return len(stale)


@contextmanager
def batch_lock(out: Path) -> Iterator[None]:
    """One batch at a time per output directory (cleanup of stale files must not hit a live batch)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / LOCK, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(out, "another batch is writing to this directory") from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
