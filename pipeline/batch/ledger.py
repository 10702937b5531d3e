"""The record of a batch dataset's runs: append-only records, compacted into ``summary.parquet``.

Recording a finished run costs one appended line (``_slamobs/records-<gen>.jsonl``), whatever the number
of runs; ``summary.parquet`` is rewritten from the records during a batch at most once a second and at most
1/``REFRESH_COST`` of the time (:meth:`Ledger.refresh_every`), and at its end, so its cost does not grow with
every run, and a batch killed by SIGKILL leaves a summary that lacks only its last second or so of runs. The
summary stores in its metadata the generation of records it already holds; the state is that summary plus the
records of its generation and later, so a batch killed at any point loses nothing that was recorded.

A record is ``{"op": "put", "row": {...}}`` (a run's summary row, replacing any earlier one of that
run_id) or ``{"op": "drop", "run_id": ...}``. Each is written by one ``write`` call: a kill leaves at
most a torn last line, which is ignored (and cut off by the next writer).
"""

from __future__ import annotations

import json
import math
import os
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from slamobs.pipeline.errors import InputError, output_error

SUMMARY = "summary.parquet"
META_DIR = "_slamobs"
RECORDS = "records-{gen:06d}.jsonl"
GEN_KEY = b"slamobs.records_gen"
#: Seconds between rewrites of summary.parquet while a batch runs (records are current at all times): at least
#: REFRESH_MIN_S, and REFRESH_COST times what the last rewrite took (10k rows: 60-80 ms), at most REFRESH_S.
REFRESH_S = 30.0
REFRESH_MIN_S = 1.0
REFRESH_COST = 20

_F, _I, _S = pa.float64(), pa.int64(), pa.string()
#: Columns of ``summary.parquet`` (units in the names; null where a run did not get that far).
SUMMARY_SCHEMA = pa.schema(
    [
        ("run_id", _S),
        ("log", _S),
        ("config_file", _S),
        ("content_hash", _S),
        ("observer", _S),
        ("config_hash", _S),
        ("status", _S),
        ("error", _S),
        ("warning_count", _I),
        ("warnings", _S),
        ("tables", _S),
        ("finished_at", pa.timestamp("us", tz="UTC")),
        ("worker", _S),
        ("slamobs_version", _S),
        ("total_s", _F),
        ("read_s", _F),
        ("align_s", _F),
        ("observer_s", _F),
        ("write_s", _F),
        ("report_s", _F),
        ("dataset_s", _F),
        ("velocity_samples", _I),
        ("detection_frames", _I),
        ("detections", _I),
        ("landmarks", _I),
        ("internal_steps", _I),
        # pipeline.run.headline_metrics: gyro_bias_err in rad/s, vel_bias_err in m/s (final error norms)
        ("ape_trans_rmse_m", _F),
        ("ape_rot_rmse_deg", _F),
        ("landmark_rmse_m", _F),
        ("gyro_bias_err", _F),
        ("vel_bias_err", _F),
        ("convergence_s", _F),
        # added later (a summary written before has no such columns: readers treat them as missing)
        ("rpe_trans_rmse_m", _F),
        ("rpe_rot_rmse_deg", _F),
        # landmark truth without trajectory truth: the map error after a map-only SE(3) alignment (run.json
        # map_error; landmark_rmse_m, after the trajectory's alignment, is blank then)
        ("map_error_m", _F),
        # the stages a run's timings_s has beside the ones above, so that total_s is their sum plus the checks
        ("tags_s", _F),
        ("figures_s", _F),
        ("export_s", _F),
        ("first_pass_s", _F),
    ]
)
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
#: The summary's ``status`` of a run that did not finish (its ``error`` says why). Every other stored status is a
#: finished run's: ``ok``, or its estimator's own status where its record says its estimate is off (``lost``,
#: ``gated_at_end``, ``likely_lost``: :meth:`.run.RunSummary.status`, the word ``compare``'s table shows).
#: ``skipped`` exists only in a batch's own output (the run it skipped is recorded with the outcome it had when it
#: ran).
FAILED = "failed"
SKIPPED = "skipped"


def finished(status: str | None) -> bool:
    """Whether a run of this ``status`` finished (ok, or off by its estimator's own status): the batch keeps it on
    resume, and ``stats`` counts its metrics. Before session 33 a finished run was stored as ``ok`` whatever its own
    status said."""
    return status not in (None, FAILED, SKIPPED)


def meta_dir(out: Path) -> Path:
    return Path(out) / META_DIR


def encode_row(row: dict) -> dict:
    """A summary row as JSON values (timestamps as ISO text, NumPy scalars as Python ones, non-finite as None)."""
    out = {}
    for name in SUMMARY_SCHEMA.names:
        v = row.get(name)
        if isinstance(v, datetime):
            v = v.isoformat()
        elif hasattr(v, "item") and not isinstance(v, str):  # NumPy scalars
            v = v.item()
        if isinstance(v, float) and not math.isfinite(v):
            v = None
        out[name] = v
    return out


def _decode(row: dict) -> dict:
    if isinstance(row.get("finished_at"), str):
        row["finished_at"] = datetime.fromisoformat(row["finished_at"])
    return row


def _record_files(out: Path) -> list[tuple[int, Path]]:
    found = []
    for p in meta_dir(out).glob("records-*.jsonl"):
        try:
            found.append((int(p.stem.split("-")[1]), p))
        except (IndexError, ValueError):
            continue
    return sorted(found)


def _read_summary_file(path: Path) -> tuple[dict[str, dict], int]:
    try:
        table = pq.ParquetFile(path).read()  # not pq.read_table: that imports pyarrow.dataset and pandas (1-2 s)
    except (pa.ArrowException, OSError) as err:
        raise InputError(path, f"unreadable batch summary ({err}); move it away to start afresh") from None
    meta = table.schema.metadata or {}
    if GEN_KEY not in meta or "warning_count" not in table.schema.names:
        raise InputError(
            path.parent,
            "written by an older slamobs batch (run ids from log paths); write this batch to a new directory",
        )
    # timestamps converted here: pyarrow's to_pylist would import pandas for the time zone (1-2 s per batch)
    micros = table["finished_at"].cast(pa.int64()).to_pylist()
    rows = table.drop_columns(["finished_at"]).to_pylist()
    for row, us in zip(rows, micros):
        row["finished_at"] = None if us is None else _EPOCH + timedelta(microseconds=us)
    return {r["run_id"]: r for r in rows}, int(meta[GEN_KEY])


def _apply(rows: dict[str, dict], path: Path, strict_tail: bool) -> int:
    """Apply one records file to ``rows``; returns the byte length of its complete lines."""
    data = path.read_bytes()
    good = 0
    for line in data.splitlines(keepends=True):
        if not line.endswith(b"\n"):
            break  # torn last line of a killed writer
        try:
            rec = json.loads(line)
        except ValueError:
            if strict_tail:
                break
            continue
        if rec.get("op") == "put":
            row = _decode(rec["row"])
            rows[row["run_id"]] = row
        elif rec.get("op") == "drop":
            rows.pop(rec.get("run_id"), None)
        good += len(line)
    return good


def read_summary(out: Path) -> dict[str, dict]:
    """The current rows by run_id (summary.parquet plus newer records), readable while a batch runs."""
    out = Path(out)
    for _ in range(5):  # the writer may compact between reading the summary and its records: read again
        path = out / SUMMARY
        rows, gen = _read_summary_file(path) if path.is_file() else ({}, 0)
        try:
            for g, f in _record_files(out):
                if g >= gen:
                    _apply(rows, f, strict_tail=False)
        except FileNotFoundError:
            continue
        return rows
    return rows


class Ledger:
    """The writer's view (one per batch, under the batch lock): current rows, appends, compaction."""

    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        meta_dir(self.out).mkdir(parents=True, exist_ok=True)
        path = self.out / SUMMARY
        self.rows, self.gen = _read_summary_file(path) if path.is_file() else ({}, 0)
        self.pending = 0  # bytes of records not yet in summary.parquet (from a batch that did not end cleanly)
        for g, f in _record_files(self.out):
            if g < self.gen:
                f.unlink(missing_ok=True)  # already in the summary (a compaction was cut short)
                continue
            good = _apply(self.rows, f, strict_tail=True)
            self.pending += good
            if good < f.stat().st_size:
                os.truncate(f, good)
            self.gen = max(self.gen, g)
        self._fd: int | None = None
        self.appended = 0
        self.compact_s = 0.0  # seconds the last rewrite of the summary took
        self.rewrites = 0

    def refresh_every(self) -> float:
        """Seconds a batch waits between rewrites of the summary (see REFRESH_S)."""
        return min(REFRESH_S, max(REFRESH_MIN_S, REFRESH_COST * self.compact_s))

    def _file(self) -> int:
        if self._fd is None:
            path = meta_dir(self.out) / RECORDS.format(gen=self.gen)
            self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        return self._fd

    def _append(self, rec: dict) -> None:
        try:
            os.write(self._file(), (json.dumps(rec, separators=(",", ":"), allow_nan=False) + "\n").encode())
        except OSError as err:  # a torn line is ignored by every reader, so nothing half-recorded remains
            raise output_error(meta_dir(self.out) / RECORDS.format(gen=self.gen), err, "cannot record a run") from None
        self.appended += 1

    def put(self, row: dict) -> None:
        """Record ``row`` as the state of its run (one appended line)."""
        self._append({"op": "put", "row": encode_row(row)})
        self.rows[row["run_id"]] = _decode(encode_row(row))

    def drop(self, run_id: str) -> None:
        if run_id in self.rows:
            self._append({"op": "drop", "run_id": run_id})
            del self.rows[run_id]

    def compact(self, force: bool = False) -> Path:
        """Write every row into ``summary.parquet`` (atomically) and start a new records generation; nothing
        to do when the summary is current, unless ``force``."""
        self.close()
        path = self.out / SUMMARY
        if not force and not self.appended and not self.pending and path.is_file():
            return path  # already current
        t0 = time.perf_counter()
        table = pa.Table.from_pylist(
            list(self.rows.values()), schema=SUMMARY_SCHEMA.with_metadata({GEN_KEY: str(self.gen + 1).encode()})
        )
        tmp = path.parent / f".{SUMMARY}.tmp-{os.getpid()}"
        try:
            pq.write_table(table, tmp, compression="zstd")
            os.replace(tmp, path)
        except OSError as err:
            tmp.unlink(missing_ok=True)
            raise output_error(
                path,
                err,
                "cannot rewrite the batch summary",
                "; every run is recorded (in _slamobs): `slamobs batch compact OUT` rewrites it once there is room",
            ) from None
        for g, f in _record_files(self.out):
            if g <= self.gen:
                f.unlink(missing_ok=True)
        self.gen += 1
        self.appended = self.pending = 0
        # the first rewrite of a process is not a measure: pyarrow imports pandas for it (0.3-0.8 s)
        self.compact_s = time.perf_counter() - t0 if self.rewrites else 0.0
        self.rewrites += 1
        return path

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
