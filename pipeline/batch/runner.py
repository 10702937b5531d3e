"""A batch: plan (hash, skip what is done), dispatch to an executor, record each finished run in the summary.

Only the parent process touches ``summary.parquet``; it is rewritten atomically after every finished run,
so an interrupted batch leaves a summary that matches the files on disk, and the next batch resumes from it.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import closing
from dataclasses import dataclass, field, replace
from pathlib import Path

from slamobs.pipeline.batch.dataset import batch_lock, cleanup_stale, read_summary, remove_run, run_complete, write_summary
from slamobs.pipeline.batch.discover import LogEntry, content_hash, run_id_for
from slamobs.pipeline.batch.executor import EXECUTORS, Task, dask_available, dask_results, failed_row, local_results, one_line
from slamobs.pipeline.config import RunConfig, load_config
from slamobs.pipeline.errors import InputError

DASK_MISSING = "--executor dask needs Dask: pip install 'slamobs[dask]' (or: pip install \"dask[distributed]\")"


class DaskMissing(RuntimeError):
    """The Dask executor was asked for but ``distributed`` is not installed."""


@dataclass(frozen=True)
class BatchOptions:
    out: Path
    config: RunConfig = field(default_factory=RunConfig)
    observer: str | None = None  # overrides the observer of every config, per-log ones included
    force: bool = False
    executor: str = "local"
    jobs: int = field(default_factory=lambda: os.cpu_count() or 1)
    scheduler: str | None = None  # a Dask scheduler address implies the Dask executor


@dataclass
class Progress:
    """Counts so far and a throughput-based ETA, handed to the caller after every finished run."""

    total: int
    to_run: int = 0
    ok: int = 0
    failed: int = 0
    skipped: int = 0
    ran: int = 0
    started: float = field(default_factory=time.perf_counter)

    @property
    def done(self) -> int:
        return self.ok + self.failed + self.skipped

    def add(self, row: dict, dispatched: bool) -> None:
        setattr(self, row["status"], getattr(self, row["status"]) + 1)
        self.ran += dispatched

    def eta_s(self) -> float | None:
        if not self.ran:
            return None
        return (time.perf_counter() - self.started) / self.ran * max(0, self.to_run - self.ran)


@dataclass
class BatchResult:
    rows: list[dict]  # this batch's logs, in input order
    elapsed_s: float
    summary_path: Path

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.rows)

    @property
    def exit_code(self) -> int:
        """0: every log ok or skipped; 1: some failed; 2: none succeeded."""
        failed = self.count("failed")
        return 0 if not failed else (1 if failed < len(self.rows) else 2)


def config_hash(config: RunConfig) -> str:
    """Digest of the effective configuration (after defaults and the --observer override)."""
    text = json.dumps(config.to_dict(), sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_config(config: RunConfig) -> None:
    """Fail early on an unknown observer or bad gains (GainError), before any log is touched."""
    from slamobs.pipeline.observers import get_observer

    spec = get_observer(config.observer)
    spec.resolve_gains(config.gains.get(spec.name))
    spec.directions_needed(config)  # checks the reference estimators' settings


def _plan(entries: Sequence[LogEntry], options: BatchOptions) -> list[Task | dict]:
    """A task per log, or its failed row when it cannot even start (missing log, bad per-log config)."""
    configs: dict[Path, RunConfig | str] = {}
    out = str(Path(options.out).resolve())

    def config_for(entry: LogEntry) -> RunConfig | str:
        if entry.config is None:
            return replace(options.config, observer=options.observer) if options.observer else options.config
        if entry.config not in configs:
            try:
                cfg = load_config(entry.config)
                if options.observer:
                    cfg = replace(cfg, observer=options.observer)
                check_config(cfg)
                configs[entry.config] = cfg
            except Exception as err:  # noqa: BLE001 - a bad per-log config fails that log only
                configs[entry.config] = one_line(err, str(entry.config))
        return configs[entry.config]

    def prepare(entry: LogEntry, cfg: RunConfig | str) -> Task | dict:
        log = entry.path.resolve()
        task = Task.make(run_id_for(log), str(log), out, cfg if isinstance(cfg, RunConfig) else options.config,
                         config_file=str(entry.config.resolve()) if entry.config else None,
                         config_hash=config_hash(cfg) if isinstance(cfg, RunConfig) else "")
        if isinstance(cfg, str):
            return failed_row(task, cfg)
        if not log.exists():
            return failed_row(task, str(InputError(entry.path, "no such file or directory")))
        try:
            return replace(task, content_hash=content_hash(log))
        except OSError as err:
            return failed_row(task, str(InputError(entry.path, f"cannot read: {err.strerror}")))

    cfgs = [config_for(e) for e in entries]
    with ThreadPoolExecutor(max_workers=8) as pool:  # hashing is I/O: overlap it
        items = list(pool.map(prepare, entries, cfgs))
    ids: dict[str, str] = {}
    for item in items:
        rid, log = (item.run_id, item.log) if isinstance(item, Task) else (item["run_id"], item["log"])
        if ids.setdefault(rid, log) != log:
            raise InputError(log, f"run_id {rid} collides with {ids[rid]}; rename one of the logs")
    return items


def _still_valid(prev: dict | None, task: Task, out: Path) -> bool:
    return (prev is not None and prev["status"] in ("ok", "skipped") and prev["content_hash"] == task.content_hash
            and prev["config_hash"] == task.config_hash and run_complete(out, task.run_id))


def run_batch(entries: Sequence[LogEntry], options: BatchOptions,
              on_row: Callable[[dict, Progress], None] = lambda _row, _p: None,
              on_start: Callable[[Progress], None] = lambda _p: None) -> BatchResult:
    """Run every log of ``entries`` into ``options.out``; ``on_row`` sees each row once it is recorded.

    ``on_start`` sees the plan (``total`` logs, ``to_run`` of them not up to date) before anything runs.

    Raises:
        InputError: Another batch holds ``out``, or two logs map to one run_id.
        DaskMissing: The Dask executor without ``distributed`` installed.

    """
    if options.executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {EXECUTORS}, got {options.executor!r}")
    use_dask = options.executor == "dask" or bool(options.scheduler)
    if use_dask and not dask_available():
        raise DaskMissing(DASK_MISSING)
    t0 = time.perf_counter()
    out = Path(options.out)
    with batch_lock(out):
        cleanup_stale(out)
        summary = read_summary(out)
        items = _plan(entries, options)
        order = [i.run_id if isinstance(i, Task) else i["run_id"] for i in items]
        rows: dict[str, dict] = {}
        immediate, tasks = [], []
        for item in items:
            if isinstance(item, dict):
                immediate.append(item)
            elif not options.force and _still_valid(prev := summary.get(item.run_id), item, out):
                immediate.append({**prev, "status": "skipped", "error": None, "log": item.log,
                                  "config_file": item.config_file})
            else:
                tasks.append(item)
        progress = Progress(total=len(items), to_run=len(tasks))
        on_start(progress)
        for row in immediate:
            if row["status"] == "failed":
                remove_run(out, row["run_id"])
            summary[row["run_id"]] = rows[row["run_id"]] = row
        write_summary(out, summary)
        for row in immediate:
            progress.add(row, dispatched=False)
            on_row(row, progress)
        progress.started = time.perf_counter()
        results = (dask_results(tasks, options.jobs, options.scheduler) if use_dask and tasks
                   else local_results(tasks, options.jobs))
        with closing(results):
            for row in results:
                summary[row["run_id"]] = rows[row["run_id"]] = row
                write_summary(out, summary)
                progress.add(row, dispatched=True)
                on_row(row, progress)
    return BatchResult(rows=[rows[r] for r in order], elapsed_s=time.perf_counter() - t0,
                       summary_path=out / "summary.parquet")
