"""``slamobs batch``: many logs in parallel (local processes or Dask) into one partitioned dataset;
``slamobs batch compact OUT`` merges a dataset's per-run partitions."""

from __future__ import annotations

import json
import math
import signal
import sys
from datetime import datetime
from pathlib import Path

import click

from slamobs.cli.errors import exit_input_error
from slamobs.cli.jobs import EXIT_INFRA, EXIT_SIGNAL, Stopped, on_signal, signals_to_the_main_thread
from slamobs.pipeline.cores import cores
from slamobs.cli.options import (
    Finite,
    OutPath,
    config_option,
    msg_dir_option,
    plots_option,
    wait_workers_option,
    window_options,
)
from slamobs.pipeline.errors import plural


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


def _kept(row: dict) -> bool:
    """A log whose run the batch kept as it was (a file of the user's in its directory): its line says why."""
    from slamobs.pipeline.batch.executor import KEPT, RETRY

    return row.get(RETRY) == KEPT


def _row_line(row: dict, progress) -> str:
    from slamobs.pipeline.batch import finished

    status = row["status"]
    if status == "ok" and row.get("warning_count"):
        status = f"ok ({plural(row['warning_count'], 'warning')})"
    head = f"[{progress.done}/{progress.total}] {status:<7} {row['run_id']}"
    if row["status"] == "failed" or _kept(row):
        return f"{head}  {row['error']}"
    ape, map_m = row.get("ape_trans_rmse_m"), row.get("map_error_m")
    tail = (
        f"  APE {ape:.4f} m"
        if ape is not None
        else f"  map error {map_m:.4f} m (map-only alignment; no trajectory truth)"
        if map_m is not None
        else ""
    )
    # ok, or its estimator's own status; the log too: TagSLAM's tests all name theirs tag_detections.bag
    if finished(row["status"]):
        return f"{head}  {row['total_s']:.1f} s{tail or '  no truth'}  {row['log']}"
    # skipped: the log too, and why where it is not a finished run (--skip-failed, a copy of another log of the batch)
    why = f"  ({row['error']})" if row.get("error") else ""
    return f"{head}{tail}  {row['log']}{why}"


class _Reporter:
    """Progress as the runs finish: a live line on a terminal, log lines otherwise, JSON lines with --json."""

    def __init__(self, quiet: bool, as_json: bool) -> None:
        self.quiet, self.as_json = quiet, as_json
        self.live = not quiet and not as_json and sys.stderr.isatty()

    def start(self, progress, where: str) -> None:
        if self.quiet or self.as_json:
            return
        text = f"batch: {plural(progress.total, 'log')}, {progress.to_run} to run on {where}"
        for note in progress.notes:  # a local Dask worker that did not start: the batch goes on without it
            click.echo(f"note: {note}", err=True)
        click.echo(f"\r\x1b[K[0/{progress.total}] {text}" if self.live else text, nl=not self.live, err=True)

    def __call__(self, row: dict, progress) -> None:
        if self.as_json:
            if not self.quiet:
                click.echo(
                    json.dumps({"event": "run", "done": progress.done, "total": progress.total, **_jsonable(row)})
                )
            return
        if self.quiet:
            return
        if not self.live:
            click.echo(_row_line(row, progress), err=True)
            return
        if row["status"] == "failed" or row.get("warning_count") or _kept(row):
            click.echo("\r\x1b[K" + _row_line(row, progress), err=True)
        click.echo(
            f"\r\x1b[K[{progress.done}/{progress.total}] {progress.ok} ok, "
            f"{f'{progress.off} off by their own status, ' if progress.off else ''}{progress.failed} failed, "
            f"{progress.skipped} skipped  ETA {_duration(progress.eta_s())}  last {row['run_id']}",
            nl=False,
            err=True,
        )

    def clear(self) -> None:
        if self.live:
            click.echo("\r\x1b[K", nl=False, err=True)

    def finish(self, result, out: Path) -> None:
        self.clear()
        counts = {s: result.count(s) for s in ("ok", "skipped", "failed")}
        summary = out / "summary.parquet"
        fixed = result.reconciled
        if self.as_json:
            click.echo(
                json.dumps(
                    {
                        "event": "done",
                        "logs": len(result.rows),
                        **counts,
                        "off": result.off,
                        "warned": result.warned,
                        "pruned": len(result.pruned),
                        "adopted": len(fixed.adopted),
                        "removed": len(fixed.removed) + len(fixed.dropped),
                        "elapsed_s": round(result.elapsed_s, 3),
                        "summary": str(summary),
                        "kept": result.kept,
                        "exit_code": result.exit_code,
                    }
                )
            )
            return
        if not self.quiet:
            if fixed.adopted or fixed.removed or fixed.dropped:
                click.echo(
                    f"batch: settled an interrupted batch: {plural(len(fixed.adopted), 'finished run')} adopted, "
                    f"{plural(len(fixed.removed), 'partial run')} removed, "
                    f"{plural(len(fixed.dropped), 'run')} with missing files dropped",
                    err=True,
                )
            if result.pruned:
                click.echo(f"batch: pruned {plural(len(result.pruned), 'run')} whose logs are gone", err=True)
        warned = f" ({result.warned} with warnings)" if result.warned else ""
        off = "".join(f", {n} {status}" for status, n in result.off.items())  # finished, off by its own status
        click.echo(
            f"batch: {plural(len(result.rows), 'log')}, {counts['ok']} ok{warned}{off}, {counts['skipped']} skipped, "
            f"{counts['failed']} failed in {result.elapsed_s:.1f} s; summary {summary}"
        )
        if result.kept:
            listed = {r["run_id"] for r in result.rows if _kept(r)}
            for rid, why in result.kept.items():
                if rid not in listed or self.quiet:  # the others' lines said so already
                    click.echo(f"batch: {why}", err=True)
            click.echo(
                f"batch: {plural(len(result.kept), 'run')} kept as it was because its directory holds a file "
                f"slamobs did not write (see above); exit {result.exit_code}",
                err=True,
            )
        if machine := result.machine_failures:
            click.echo(
                f"batch: {plural(len(machine), 'log')} failed because of the machine, not the log (first: "
                f"{machine[0]['error']}); not recorded: run the same command again once that is fixed",
                err=True,
            )


class _BatchGroup(click.Group):
    """``slamobs batch INPUTS...`` runs a batch (the ``run`` subcommand is implied); ``slamobs batch compact
    OUT`` compacts. A log literally named ``compact`` is given as ``./compact``."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        if not args or args[0] not in self.commands:
            args = ["run", *args]
        return super().parse_args(ctx, args)


@click.group("batch", cls=_BatchGroup)
def batch() -> None:
    """Run an observer on many logs into one dataset (see `slamobs batch --help`)."""


def _timeout(value: float) -> float | None:
    return None if value <= 0 else value


class _RunCommand(click.Command):
    """``run`` is implied: its usage reads ``slamobs batch [OPTIONS] INPUTS...``."""

    def format_usage(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        path = ctx.command_path.rsplit(" ", 1)[0] if ctx.command_path.endswith(" run") else ctx.command_path
        formatter.write_usage(path, " ".join(self.collect_usage_pieces(ctx)))


@batch.command("run", cls=_RunCommand)
@click.argument("inputs", nargs=-1, required=True)
@click.option(
    "-o",
    "--out",
    "out_dir",
    required=True,
    type=OutPath(path_type=Path, file_okay=False),
    help="dataset directory (created; reused to resume)",
)
@click.option("--observer", default=None, help="observer for every log (overrides configs)")
@config_option("run.yaml for logs without a per-log config in a manifest")
@msg_dir_option(
    "pkg/msg/Type.msg definitions for types the logs do not store (for logs without a per-log config that names "
    "msg_dir)",
    exists=True,
)
@click.option(
    "-j", "--jobs", type=click.IntRange(min=1), default=None, help="parallel worker processes (default: all cores)"
)
@click.option(
    "--executor",
    type=click.Choice(["local", "dask"]),
    default=None,
    help="local processes (default) or Dask (a local cluster unless --scheduler)",
)
@click.option(
    "--scheduler",
    default=None,
    metavar="ADDRESS",
    help="Dask scheduler, e.g. tcp://host:8786 (implies --executor dask)",
)
@click.option(
    "--timeout",
    type=Finite(min=0),
    default=3600.0,
    show_default=True,
    metavar="SECONDS",
    help="per log: a run taking longer is killed and fails (0: no limit)",
)
@wait_workers_option
@click.option("--force", is_flag=True, help="re-run logs whose results are up to date")
@click.option("--skip-failed", is_flag=True, help="do not retry logs that failed with the same content and config")
@click.option(
    "--prune",
    is_flag=True,
    help="drop runs whose logs are gone (no longer at their recorded path with the same content)",
)
@click.option("--no-compact", is_flag=True, help="leave the per-run partitions (compact later: slamobs batch compact)")
@window_options
@plots_option("evaluation.plots of each log's config")
@click.option("-q", "--quiet", is_flag=True, help="print only the final line")
@click.option("--json", "as_json", is_flag=True, help="one JSON object per finished run, then a final one")
def run(
    inputs: tuple[str, ...],
    out_dir: Path,
    observer: str | None,
    config_path: Path | None,
    msg_dir: Path | None,
    jobs: int | None,
    executor: str | None,
    scheduler: str | None,
    timeout: float,
    wait_workers: float,
    force: bool,
    skip_failed: bool,
    prune: bool,
    no_compact: bool,
    start: float | None,
    end: float | None,
    plots: bool | None,
    quiet: bool,
    as_json: bool,
) -> None:
    """Run an observer on many logs into one dataset under OUT.

    INPUTS are logs (.bag, .mcap, rosbag2 directories), directories searched recursively, glob patterns,
    or manifests (.csv / .yaml: log path and optional per-log config). A run is identified by the log's
    content and the config: finished runs are skipped (also after the log was moved), so re-running the
    same command resumes an interrupted batch. `slamobs batch compact OUT` merges the per-run files (done
    at the end of every batch unless --no-compact).

    \b
    Exit codes:
      0    every log finished (ok, or off by its estimator's own status:
           likely_lost, lost, gated_at_end) or skipped
      1    some logs failed (bad log, timeout, a worker died twice on it, a log
           changed while it ran)
      4    none failed, but some runs were kept as they were (not deleted, not
           run) because OUT/runs/<id>/ holds a file slamobs did not write (named)
      2    bad arguments or config, nothing found, OUT locked by another batch
           (or a report of one of its runs)
      3    infrastructure: Dask scheduler unreachable or lost, no workers, a worker
           without slamobs or with another version, workers dying at start-up;
           the machine failed (disk full, out of memory, permission): such logs
           are not recorded as failed, the next batch runs them again
      130  interrupted (SIGINT), 143 terminated (SIGTERM), 129 hangup (SIGHUP):
           workers stopped, finished runs kept; run the same command to resume
    """
    from dataclasses import replace

    from slamobs.cli.errors import working_on

    working_on(out_dir, "the batch")  # a lack of memory, threads or descriptors is reported against OUT

    from slamobs.pipeline.lifetime import collected_after_imports

    # as `run`: the collector off while the pipeline is imported, its modules frozen out of the collections after
    with collected_after_imports() as imported:
        from slamobs.pipeline.batch import (
            BatchOptions,
            DaskMissing,
            InfrastructureError,
            check_config,
            discover,
            run_batch,
        )
        from slamobs.pipeline.config import load_config
        from slamobs.pipeline.errors import InputError, ResourceError
        from slamobs.pipeline.interrupts import as_interruption, take_pending
        from slamobs.pipeline.observers import GainError

        imported()
        if executor == "local" and scheduler:
            exit_input_error("--scheduler runs on Dask; it cannot be combined with --executor local")
        handlers = {sig: signal.signal(sig, on_signal) for sig in EXIT_SIGNAL}
        reporter = _Reporter(quiet, as_json)
        try:
            if (pending := take_pending()) is not None:  # arrived before these handlers: stop as they would
                on_signal(pending, None)
            config = load_config(config_path)
            if observer:
                config = replace(config, observer=observer)
            if msg_dir:
                config = replace(config, msg_dir=str(msg_dir.resolve()))
            check_config(config)
            links: list[Path] = []
            entries = discover(inputs, links)
            for link in links if not quiet else ():  # a night's folder of links: say which were not searched
                click.echo(
                    f"note: {link}: a symbolic link to a directory, not searched (give it as an input)", err=True
                )
            options = BatchOptions(
                out=out_dir,
                config=config,
                observer=observer,
                msg_dir=str(msg_dir.resolve()) if msg_dir else None,
                window=(start, end),
                plots=plots,
                force=force,
                skip_failed=skip_failed,
                prune=prune,
                compact=not no_compact,
                executor=executor or ("dask" if scheduler else "local"),
                jobs=jobs or cores(),
                scheduler=scheduler,
                timeout=_timeout(timeout),
                wait_workers=wait_workers,
            )
            where = (
                f"Dask at {scheduler}"
                if scheduler
                else f"a local Dask cluster of {plural(options.jobs, 'worker')}"
                if options.executor == "dask"
                else plural(options.jobs, "local worker process", "local worker processes")
            )
            with as_interruption(), signals_to_the_main_thread():
                result = run_batch(entries, options, on_row=reporter, on_start=lambda p: reporter.start(p, where))
        except (InfrastructureError, ResourceError) as err:  # ResourceError before InputError: it is one
            reporter.clear()
            click.echo(f"error: {' '.join(str(err).split())}", err=True)
            sys.exit(EXIT_INFRA)
        except (InputError, GainError, DaskMissing) as err:
            reporter.clear()
            exit_input_error(str(err))
        except KeyboardInterrupt as err:
            reporter.clear()
            signum = err.signum if isinstance(err, Stopped) else signal.SIGINT
            click.echo(
                f"\n{signal.Signals(signum).name}: batch stopped, its workers killed; finished runs are recorded; "
                "run the same command again to resume",
                err=True,
            )
            sys.exit(EXIT_SIGNAL[signum])
        finally:
            for sig, old in handlers.items():
                signal.signal(sig, old)
        reporter.finish(result, out_dir)
        sys.exit(result.exit_code)


@batch.command("compact")
@click.argument("out_dir", metavar="OUT", type=click.Path(path_type=Path))
@click.option("-q", "--quiet", is_flag=True, help="print nothing but errors")
def compact(out_dir: Path, quiet: bool) -> None:
    """Merge the per-run partitions of the batch dataset OUT into a few large files per table.

    Same columns (run_id included), same readers; a batch does this at its end unless --no-compact.
    Exit code 2 when OUT is not a batch dataset or another batch (or a report) is writing to it.
    """
    from slamobs.pipeline.batch import compact_batch
    from slamobs.pipeline.errors import InputError

    try:
        fixed, report = compact_batch(out_dir)
    except InputError as err:
        exit_input_error(str(err))
    if quiet:
        return
    if fixed.adopted or fixed.removed or fixed.dropped:
        click.echo(
            f"settled an interrupted batch: {plural(len(fixed.adopted), 'run')} adopted, "
            f"{plural(len(fixed.removed), 'partial run')} removed",
            err=True,
        )
    if not report:
        click.echo(f"{out_dir}: nothing to compact")
    for t in report:
        click.echo(f"{t.table}: {t.files_before} files -> {t.files_after} ({plural(t.runs, 'run')}, {t.rows} rows)")
