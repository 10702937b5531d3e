"""Batch bookkeeping at scale: 10k synthetic runs through the batch's own commit, records, summary, compaction,
and the time to query the dataset with duckdb, pandas and polars before and after compaction.

    .venv/bin/python benchmarks/batch_scale.py [--runs 10000] [--rows 600] [--dir /tmp/x]

The runs are synthetic (random tables of the output schemas, ``--rows`` pose rows each, about what a 30 s log
at 20 Hz output gives) so that 10k of them take minutes, not hours; every file is written and committed the
way a worker and the batch do it (:func:`dataset.commit_run`, :class:`ledger.Ledger`). Also timed: an
up-to-date batch over 10k log files (every run skipped), the first time (each log hashed) and again (hashes
from the cache, no log opened); and, for comparison, what the previous design paid per run, rewriting
summary.parquet with every row.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from slamobs.pipeline.batch import BatchOptions, LogEntry, run_batch
from slamobs.pipeline.batch.compact import compact_dataset
from slamobs.pipeline.batch.dataset import DatasetIndex, commit_run, with_run_id, write_run_meta
from slamobs.pipeline.batch.executor import Task, base_row
from slamobs.pipeline.batch.identity import content_hash, run_id_for, run_key
from slamobs.pipeline.batch.ledger import SUMMARY_SCHEMA, Ledger, meta_dir
from slamobs.pipeline.batch.runner import config_hash
from slamobs.pipeline.config import RunConfig
from slamobs.pipeline.writers import FLOAT_BITS, parquet_options, round_mantissa, round_step
from slamobs.schemas import TABLES, arrow_schema, fixed_steps

ROWS_PER_TABLE = {"poses": 1.0, "biases": 1.0, "landmark_tracks": 0.5, "innovations": 0.5, "landmarks": None}


def _table(name: str, n: int, rng: np.random.Generator):
    import pyarrow as pa

    schema = arrow_schema(name)
    cols = []
    for f in schema:
        if f.name.endswith("_ns"):
            cols.append(pa.array(np.arange(n, dtype=np.int64) * 50_000_000, f.type))
        elif pa.types.is_integer(f.type):
            cols.append(pa.array(rng.integers(0, 30, n), f.type))
        else:  # a smooth series rounded like the real writer's (step or float_bits), so files have real sizes
            v = np.cumsum(rng.normal(scale=0.01, size=n))
            steps = fixed_steps(name)
            v = round_step(v, steps[f.name]) if f.name in steps else round_mantissa(v, FLOAT_BITS)
            cols.append(pa.array(v, f.type))
    return pa.Table.from_arrays(cols, schema=schema)


def make_runs(out: Path, logs: list[Path], rows: int, cfg_hash: str) -> tuple[float, float, float]:
    """Stage and commit one synthetic run per log; returns seconds spent in (staging, commit, records)."""
    rng = np.random.default_rng(0)
    led = Ledger(out)
    staging = meta_dir(out) / "staging" / "bench"
    staging.mkdir(parents=True, exist_ok=True)
    t_stage = t_commit = t_record = 0.0
    for log in logs:
        chash = content_hash(log)
        rid = run_id_for(log, run_key(chash, cfg_hash))
        t = time.perf_counter()
        staged = staging / rid
        (staged / "run").mkdir(parents=True)
        counts = {}
        for name in TABLES:
            share = ROWS_PER_TABLE[name]
            n = 10 if share is None else int(rows * share)
            data = with_run_id(_table(name, n, rng), rid)
            pq.write_table(data, staged / f"{name}.parquet", **parquet_options(data.schema))
            counts[name] = n
        (staged / "run" / "run.json").write_text(json.dumps({"counts": counts}))
        task = Task.make(rid, str(log), str(out), RunConfig(), content_hash=chash, config_hash=cfg_hash)
        row = {**base_row(task), "status": "ok", "tables": ",".join(counts), **realistic_numbers(rng)}
        write_run_meta(staged, rid, counts, row)
        t1 = time.perf_counter()
        commit_run(out, staged, rid, counts)
        t2 = time.perf_counter()
        led.put(row)
        t3 = time.perf_counter()
        staged.rmdir()
        t_stage += t1 - t
        t_commit += t2 - t1
        t_record += t3 - t2
    led.compact()
    led.close()
    return t_stage, t_commit, t_record


def realistic_numbers(rng: np.random.Generator) -> dict:
    """Timings, counts and metrics of a summary row (random, of the sizes real runs have)."""
    import pyarrow as pa

    row = {}
    for f in SUMMARY_SCHEMA:
        if pa.types.is_floating(f.type):
            row[f.name] = float(rng.uniform(0.001, 10.0))
        elif pa.types.is_integer(f.type) and f.name != "warning_count":
            row[f.name] = int(rng.integers(100, 200_000))
    return row


def old_summary_rewrite_ms(rows: list[dict], n: int, tmp: Path) -> float:
    """What the previous design paid after every run: summary.parquet rewritten with all n rows."""
    import pyarrow as pa

    rows = {f"run-{i}": {**rows[i % len(rows)], "run_id": f"run-{i}"} for i in range(n)}
    best = float("inf")
    for _ in range(3):
        t = time.perf_counter()  # as the previous write_summary did, from the rows to the file
        cols = {f.name: [r.get(f.name) for r in rows.values()] for f in SUMMARY_SCHEMA}
        table = pa.table(cols, schema=SUMMARY_SCHEMA)
        pq.write_table(table, tmp / "old_summary.parquet", compression="zstd")
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def queries(out: Path) -> dict[str, float]:
    import duckdb
    import pandas as pd
    import polars as pl

    times = {}
    t = time.perf_counter()
    duckdb.sql(
        f"SELECT run_id, count(*), avg(x) FROM read_parquet('{out}/poses/**/*.parquet') GROUP BY run_id"
    ).fetchall()
    times["duckdb"] = time.perf_counter() - t
    t = time.perf_counter()
    pd.read_parquet(out / "poses").groupby("run_id", observed=True)["x"].mean()
    times["pandas"] = time.perf_counter() - t
    t = time.perf_counter()
    pl.scan_parquet(f"{out}/poses/**/*.parquet").group_by("run_id").agg(pl.len(), pl.col("x").mean()).collect()
    times["polars"] = time.perf_counter() - t
    return times


def count_files(out: Path) -> int:
    return sum(1 for _ in out.rglob("*") if _.is_file())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--rows", type=int, default=600, help="pose rows per run")
    ap.add_argument("--dir", type=Path, default=None, help="work directory (default: a temporary one, removed)")
    args = ap.parse_args()
    work = Path(args.dir or tempfile.mkdtemp(prefix="batch_scale-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        logs_dir, out = work / "logs", work / "OUT"
        logs_dir.mkdir()
        rng = np.random.default_rng(1)
        logs = []
        for i in range(args.runs):
            p = logs_dir / f"flight_{i:05d}.mcap"
            p.write_bytes(rng.bytes(64 << 10))
            logs.append(p)
        cfg_hash = config_hash(RunConfig())
        t = time.perf_counter()
        t_stage, t_commit, t_record = make_runs(out, logs, args.rows, cfg_hash)
        t_make = time.perf_counter() - t
        n = args.runs
        files_before = count_files(out)
        q_before = queries(out)

        led = Ledger(out)
        t = time.perf_counter()
        led.compact(force=True)
        t_summary = time.perf_counter() - t
        led.close()
        from slamobs.pipeline.batch import compact as compact_mod

        apply, t_delete = compact_mod.apply_journal, []

        def timed_apply(o):
            t0 = time.perf_counter()
            apply(o)
            t_delete.append(time.perf_counter() - t0)

        compact_mod.apply_journal = timed_apply
        t = time.perf_counter()
        report = compact_dataset(out, DatasetIndex.scan(out))
        t_compact = time.perf_counter() - t
        compact_mod.apply_journal = apply
        files_after = count_files(out)
        q_after = queries(out)

        entries = [LogEntry(p) for p in logs]
        (meta_dir(out) / "hashes.json").unlink(missing_ok=True)
        t = time.perf_counter()
        first = run_batch(entries, BatchOptions(out=out, jobs=1))
        t_first = time.perf_counter() - t
        t = time.perf_counter()
        again = run_batch(entries, BatchOptions(out=out, jobs=1))
        t_again = time.perf_counter() - t
        assert first.count("skipped") == again.count("skipped") == n, (first.count("skipped"), again.count("skipped"))

        rows = list(Ledger(out).rows.values())
        old = {k: old_summary_rewrite_ms(rows, k, work) for k in (1_000, 10_000, 50_000)}
        print(
            f"\n{n} synthetic runs, {args.rows} pose rows each ({n * args.rows / 1e6:.1f} M pose rows), "
            f"{os.cpu_count()} cores; generating and committing them took {t_make:.0f} s\n"
        )
        print("| step | time |")
        print("| --- | --- |")
        print(f"| per run: commit (renames of {len(TABLES)} tables + run dir) | {t_commit / n * 1e3:.2f} ms |")
        print(f"| per run: record (one appended line) | {t_record / n * 1e6:.0f} µs |")
        print(
            "| per run, previous design: summary.parquet rewritten at 1k / 10k / 50k rows | "
            + " / ".join(f"{old[k]:.0f} ms" for k in sorted(old))
            + " |"
        )
        print(f"| summary.parquet from the records, once at the end ({n} rows) | {t_summary * 1e3:.0f} ms |")
        rows_total = sum(t.rows for t in report if t.table == "poses")
        print(
            f"| compaction ({n} runs x {len(report)} tables, {rows_total / 1e6:.1f} M pose rows): merge / switch "
            f"(renames, deleting the per-run files) | {t_compact - sum(t_delete):.1f} s / {sum(t_delete):.1f} s |"
        )
        print(f"| files in OUT before / after compaction | {files_before} / {files_after} |")
        for k in ("duckdb", "pandas", "polars"):
            print(
                f"| {k}: group poses by run_id, per-run partitions / compacted | "
                f"{q_before[k]:.2f} s / {q_after[k]:.2f} s |"
            )
        print(
            f"| up-to-date batch over {n} logs: first (hashing 64 KiB each) / again (hash cache) | "
            f"{t_first:.1f} s / {t_again:.1f} s |"
        )
    finally:
        if args.dir is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
