"""``slamobs batch``: many logs in parallel (local processes or Dask) into one partitioned dataset."""

from __future__ import annotations

import json
import math
import os
import sys
from datetime import datetime
from pathlib import Path

import click

from slamobs.cli.errors import exit_input_error


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _jsonable(row: dict) -> dict:
    def conv(v):
        if isinstance(v, datetime):
            return v.isoformat()
        if isinstance(v, float) and not math.isfinite(v):
            return None
        return v

    return {k: conv(v) for k, v in row.items()}


def _duration(s: float | None) -> str:
    if s is None:
        return "?"
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def _row_line(row: dict, progress) -> str:
    head = f"[{progress.done}/{progress.total}] {row['status']:<7} {row['run_id']}"
    if row["status"] == "failed":
        return f"{head}  {row['error']}"
    ape = row.get("ape_trans_rmse_m")
    tail = f"  APE {ape:.4f} m" if ape is not None else ""
    if row["status"] == "ok":
        return f"{head}  {row['total_s']:.1f} s{tail}"
    return head + tail


class _Reporter:
    """Progress as the runs finish: a live line on a terminal, log lines otherwise, JSON lines with --json."""

    def __init__(self, quiet: bool, as_json: bool) -> None:
        self.quiet, self.as_json = quiet, as_json
        self.live = not quiet and not as_json and sys.stderr.isatty()

    def start(self, progress, where: str) -> None:
        if self.quiet or self.as_json:
            return
        text = f"batch: {progress.total} logs, {progress.to_run} to run on {where}"
        click.echo(f"\r\x1b[K[0/{progress.total}] {text}" if self.live else text, nl=not self.live, err=True)

    def __call__(self, row: dict, progress) -> None:
        if self.as_json:
            if not self.quiet:
                click.echo(json.dumps({"event": "run", "done": progress.done, "total": progress.total,
                                       **_jsonable(row)}))
            return
        if self.quiet:
            return
        if not self.live:
            click.echo(_row_line(row, progress), err=True)
            return
        if row["status"] == "failed":
            click.echo("\r\x1b[K" + _row_line(row, progress), err=True)
        click.echo(f"\r\x1b[K[{progress.done}/{progress.total}] {progress.ok} ok, {progress.failed} failed, "
                   f"{progress.skipped} skipped  ETA {_duration(progress.eta_s())}  last {row['run_id']}",
                   nl=False, err=True)

    def finish(self, result, out: Path) -> None:
        if self.live:
            click.echo("\r\x1b[K", nl=False, err=True)
        counts = {s: result.count(s) for s in ("ok", "skipped", "failed")}
        summary = out / "summary.parquet"
        if self.as_json:
            click.echo(json.dumps({"event": "done", "logs": len(result.rows), **counts,
                                   "elapsed_s": round(result.elapsed_s, 3), "summary": str(summary),
                                   "exit_code": result.exit_code}))
        else:
            click.echo(f"batch: {len(result.rows)} logs, {counts['ok']} ok, {counts['skipped']} skipped, "
                       f"{counts['failed']} failed in {result.elapsed_s:.1f} s; summary {summary}")


@click.command("batch")
@click.argument("inputs", nargs=-1, required=True)
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(path_type=Path, file_okay=False),
              help="dataset directory (created; reused to resume)")
@click.option("--observer", default=None, help="observer for every log (overrides configs)")
@click.option("--config", "config_path", type=click.Path(path_type=Path), default=None,
              help="run.yaml for logs without a per-log config in a manifest")
@click.option("--msg-dir", type=click.Path(path_type=Path, file_okay=False), default=None,
              help="pkg/msg/Type.msg definitions for types the logs do not store (for logs without a per-log "
                   "config that names msg_dir)")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=None,
              help="parallel worker processes (default: all cores)")
@click.option("--executor", type=click.Choice(["local", "dask"]), default=None,
              help="local processes (default) or Dask (a local cluster unless --scheduler)")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Dask scheduler, e.g. tcp://host:8786 (implies --executor dask)")
@click.option("--force", is_flag=True, help="re-run logs whose results are up to date")
@click.option("-q", "--quiet", is_flag=True, help="print only the final line")
@click.option("--json", "as_json", is_flag=True, help="one JSON object per finished run, then a final one")
def batch(inputs: tuple[str, ...], out_dir: Path, observer: str | None, config_path: Path | None,
          msg_dir: Path | None, jobs: int | None, executor: str | None, scheduler: str | None, force: bool, quiet: bool,
          as_json: bool) -> None:
    """Run an observer on many logs into one dataset under OUT.

    INPUTS are logs (.bag, .mcap, rosbag2 directories), directories searched recursively, glob patterns,
    or manifests (.csv / .yaml: log path and optional per-log config). Finished runs with unchanged log and
    config are skipped, so re-running the same command resumes an interrupted batch.

    Exit code: 0 all runs ok or skipped, 1 some failed, 2 none succeeded or bad arguments.
    """
    from dataclasses import replace

    from slamobs.pipeline.batch import BatchOptions, DaskMissing, check_config, discover, run_batch
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.observers import GainError

    if executor == "local" and scheduler:
        exit_input_error("--scheduler runs on Dask; it cannot be combined with --executor local")
    try:
        config = load_config(config_path)
        if observer:
            config = replace(config, observer=observer)
        if msg_dir:
            config = replace(config, msg_dir=str(msg_dir.resolve()))
        check_config(config)
        entries = discover(inputs)
        options = BatchOptions(out=out_dir, config=config, observer=observer, force=force,
                               executor=executor or ("dask" if scheduler else "local"),
                               jobs=jobs or _cores(), scheduler=scheduler)
        reporter = _Reporter(quiet, as_json)
        where = (f"Dask at {scheduler}" if scheduler else f"a local Dask cluster of {options.jobs} workers"
                 if options.executor == "dask" else f"{options.jobs} local worker processes")
        result = run_batch(entries, options, on_row=reporter, on_start=lambda p: reporter.start(p, where))
    except (InputError, GainError, DaskMissing) as err:
        exit_input_error(str(err))
    except KeyboardInterrupt:
        click.echo("\ninterrupted: finished runs are recorded; run the same command again to resume", err=True)
        sys.exit(130)
    reporter.finish(result, out_dir)
    sys.exit(result.exit_code)
