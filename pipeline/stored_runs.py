"""Where a batch dataset keeps each run, and reading one run's tables back.

A batch (:mod:`pipeline.batch.dataset`) writes; ``slamobs report``, ``export`` and ``load_run`` read a batch run
directory ``OUT/runs/<id>`` through :func:`run_tables`. Kept below both so that reading a run does not depend on
the batch runner.
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from slamobs.pipeline.errors import InputError, output_error

RUNS = "runs"
PART = "part-0.parquet"
COMPACTED = "compacted-"
RUN_META = "batch.json"  # in runs/<id>/: run_id, its tables and row counts, and its summary row
RUN_IDS_KEY = "slamobs.run_ids"  # footer key of a compacted file: the run_ids it holds (JSON list)


def not_a_run(path: Path) -> InputError:
    """The one error of a command given a directory without ``run.json`` (``report``, ``export``, ``view``,
    ``load_run``); where it holds run directories (a compare output's, a batch dataset's ``runs/<id>``) it names the
    first of them to give instead."""
    path = Path(path)
    found: list[Path] = []
    for parent in (path, path / RUNS):
        try:
            found += sorted(p for p in parent.iterdir() if (p / "run.json").is_file())
        except OSError:  # not a directory, or unreadable: nothing to name
            continue
    words = "not a run directory (no run.json)"
    if found:
        shown = ", ".join(map(str, found[:3])) + (f" and {len(found) - 3} more" if len(found) > 3 else "")
        words += f"; it holds run directories ({shown}): give one of them"
    return InputError(path, words)


def run_dir(out: Path, run_id: str) -> Path:
    return Path(out) / RUNS / run_id


def partition_file(out: Path, table: str, run_id: str) -> Path:
    return Path(out) / table / f"run_id={run_id}" / PART


def read_run_meta(path: Path) -> dict | None:
    try:
        meta = json.loads((path / RUN_META).read_text())
        return meta if isinstance(meta, dict) and isinstance(meta.get("tables"), dict) else None
    except (OSError, ValueError):
        return None


def compacted_run_ids(path: Path) -> list[str]:
    """The run_ids a compacted file holds (its footer). A damaged file (truncated, overwritten) is refused in one
    line: its rows are nowhere else (compaction deleted the per-run files), so the runs must run again."""
    try:
        meta = pq.read_metadata(path).metadata or {}
        return json.loads(meta.get(RUN_IDS_KEY.encode(), b"[]"))
    except OSError as err:
        raise output_error(path, err, "cannot read") from None
    except (pa.ArrowException, ValueError) as err:
        raise InputError(
            path,
            f"damaged compacted file ({' '.join(str(err).split())[:200]}): move it out of the "
            "dataset and run the batch again (the runs it held are run again)",
        ) from None


def run_tables(path: Path) -> dict[str, pa.Table] | None:
    """The tables of the batch run directory ``path`` (``OUT/runs/<id>``) read back from the dataset, without
    the run_id column; None if ``path`` is not a batch run directory."""
    meta = read_run_meta(Path(path))
    if meta is None:
        return None
    out, rid = Path(path).resolve().parent.parent, meta["run_id"]
    found = {}
    for table in meta["tables"]:
        part = partition_file(out, table, rid)
        if part.is_file():
            data = pq.read_table(part)
        else:
            pieces = [
                pq.read_table(f, filters=[("run_id", "=", rid)])
                for f in sorted((out / table).glob(f"{COMPACTED}*.parquet"))
                if rid in compacted_run_ids(f)
            ]
            if not pieces:
                raise InputError(path, f"table {table} of run {rid} is missing from the dataset {out / table}")
            data = pa.concat_tables(pieces)
        found[table] = data.drop_columns(["run_id"]).replace_schema_metadata(None)
    return found
