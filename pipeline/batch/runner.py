"""A batch: settle what a previous batch left, plan (identify, skip what is done), run, commit, compact.

Only this process changes the dataset: workers stage their runs, and each finished run is committed here
(:func:`dataset.commit_run`, with SIGINT/SIGTERM held back for the few renames) and recorded with one
appended line (:class:`ledger.Ledger`). ``summary.parquet`` is rewritten every second or so
(``Ledger.refresh_every``) and at the end, whatever way the batch ends (but SIGKILL); the per-run partitions are
compacted at the end of a batch that ran to completion.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

from slamobs.pipeline.batch.compact import TableCompaction, compact_dataset
from slamobs.pipeline.batch.dask_exec import DaskPool, dask_available
from slamobs.pipeline.batch.dataset import (
    Reconciled,
    batch_lock,
    check_layout,
    commit_run,
    drop_runs,
    kept_runs,
    reconcile,
    remove_path,
    signals_deferred,
    staging_root,
)
from slamobs.pipeline.stored_runs import partition_file, run_dir
from slamobs.pipeline.batch.discover import LogEntry, outside
from slamobs.pipeline.batch.executor import (
    EXECUTORS,
    KEPT,
    LEASE_POLL_S,
    RETRY,
    Task,
    base_row,
    failed_row,
    failure_text,
    retry_row,
    run_task,
)
from slamobs.pipeline.batch.identity import HashCache, path_key, run_id_for, run_key
from slamobs.pipeline.batch.ledger import SUMMARY, Ledger, finished, meta_dir
from slamobs.pipeline.batch.local import LocalPool
from slamobs.pipeline.config import RunConfig, load_config
from slamobs.pipeline.errors import BadConfig, InputError
from slamobs.pipeline.interrupts import critical

DASK_MISSING = "--executor dask needs Dask: pip install 'slamobs[dask]' (or: pip install \"dask[distributed]\")"
#: Default seconds one log may run before its worker is killed (a 4 h log takes ~1 min on one core).
DEFAULT_TIMEOUT_S = 3600.0
#: Default seconds a Dask batch waits for a worker (at start, and when all workers are gone).
DEFAULT_WAIT_WORKERS_S = 60.0
LEASE_TOUCH_S = 5.0


class DaskMissing(BadConfig, RuntimeError):
    """The Dask executor was asked for but ``distributed`` is not installed."""


@dataclass(frozen=True)
class BatchOptions:
    out: Path
    config: RunConfig = field(default_factory=RunConfig)
    observer: str | None = None  # overrides the observer of every config, per-log ones included
    msg_dir: str | None = None  # for every config that does not name one
    #: ``--start`` / ``--end``: time.start / time.end of every config, per-log ones included (None: as they say)
    window: tuple[float | None, float | None] = (None, None)
    plots: bool | None = None  # ``--plots`` / ``--no-plots``: evaluation.plots of every config (None: as they say)
    force: bool = False
    skip_failed: bool = False  # do not retry a log that failed with the same content and config
    prune: bool = False  # drop runs whose log is gone (not at its recorded path with the same content)
    compact: bool = True
    executor: str = "local"
    jobs: int = field(default_factory=lambda: os.cpu_count() or 1)
    scheduler: str | None = None  # a Dask scheduler address implies the Dask executor
    timeout: float | None = DEFAULT_TIMEOUT_S  # per log; None: no limit
    wait_workers: float = DEFAULT_WAIT_WORKERS_S


@dataclass
class Progress:
    """Counts so far and a throughput-based ETA, handed to the caller after every finished run."""

    total: int
    to_run: int = 0
    ok: int = 0
    off: int = 0  # finished runs whose estimator's own status says the estimate is off (lost, likely_lost, ...)
    failed: int = 0
    skipped: int = 0
    warned: int = 0  # ok runs with warnings (salvaged log, dropped samples, ...)
    ran: int = 0
    started: float = field(default_factory=time.perf_counter)
    notes: list[str] = field(default_factory=list)  # what the executor said as it started (a worker lost)

    @property
    def done(self) -> int:
        return self.ok + self.off + self.failed + self.skipped

    def add(self, row: dict, dispatched: bool) -> None:
        kind = "off" if finished(row["status"]) and row["status"] != "ok" else row["status"]
        setattr(self, kind, getattr(self, kind) + 1)
        self.warned += row["status"] == "ok" and bool(row.get("warning_count"))
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
    pruned: list[str] = field(default_factory=list)
    reconciled: Reconciled = field(default_factory=Reconciled)
    compaction: list[TableCompaction] = field(default_factory=list)
    #: runs left as they were because their directory holds a file of the user's: run_id -> why (rows of this
    #: batch's logs among them are "skipped" rows saying so; the others were runs to delete)
    kept: dict[str, str] = field(default_factory=dict)

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.rows)

    @property
    def off(self) -> dict[str, int]:
        """Runs that finished with their estimator's own status saying the estimate is off, by that status
        (``likely_lost``, ``lost``, ``gated_at_end``: :func:`.ledger.finished`, :meth:`.run.RunSummary.status`)."""
        statuses = [r["status"] for r in self.rows if finished(r["status"]) and r["status"] != "ok"]
        return {s: statuses.count(s) for s in sorted(set(statuses))}

    @property
    def warned(self) -> int:
        return sum(r["status"] == "ok" and bool(r.get("warning_count")) for r in self.rows)

    @property
    def machine_failures(self) -> list[dict]:
        """Rows that failed because of the machine (disk full, memory, permission): not recorded, run again."""
        return [r for r in self.rows if r.get(RETRY) == "machine"]

    @property
    def exit_code(self) -> int:
        """0: every log ok or skipped; 1: some failed; 3: the machine failed some (other infrastructure
        problems raise instead); 4: none failed but some runs were kept as they were (:attr:`kept`)."""
        return 3 if self.machine_failures else 1 if self.count("failed") else 4 if self.kept else 0


def config_hash(config: RunConfig) -> str:
    """Digest of the effective configuration (after defaults and the --observer override); where the config
    was read from is not part of it. Files a config names (map_file, truth_file, msg_dir) count by path."""
    values = {k: v for k, v in config.to_dict().items() if k != "source"}
    text = json.dumps(values, sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_config(config: RunConfig) -> None:
    """Fail early on an unknown observer or bad gains (GainError), before any log is touched."""
    from slamobs.pipeline.estimators import get_estimator

    spec = get_estimator(config.observer)
    spec.resolve_gains(config.gains.get(spec.name))
    spec.directions_needed(config)  # checks the reference estimators' settings


@dataclass
class _Planned:
    """One log of the batch, identified: a task to run, or a row to report at once."""

    log: str
    task: Task | None = None
    row: dict | None = None
    path_id: str = ""


def _overrides(cfg: RunConfig, options: BatchOptions) -> RunConfig:
    if options.observer:
        cfg = replace(cfg, observer=options.observer)
    if options.msg_dir and not cfg.msg_dir:  # a per-log config naming its own msg_dir keeps it
        cfg = replace(cfg, msg_dir=options.msg_dir)
    return cfg.with_window(*options.window).with_plots(options.plots)


def _identify(
    entries: Sequence[LogEntry], options: BatchOptions, cache: HashCache, by_key: dict[str, str]
) -> list[_Planned]:
    """Config, content hash and run_id of every log (hashing overlapped: it is I/O, and cached)."""
    configs: dict[str, RunConfig | str] = {}
    out = str(Path(options.out).resolve())
    default = _overrides(options.config, options)

    def config_for(entry: LogEntry) -> RunConfig | str:
        if entry.config is None:
            return default
        key = os.path.realpath(entry.config)
        if key not in configs:
            try:
                cfg = _overrides(load_config(entry.config), options)
                check_config(cfg)
                configs[key] = cfg
            except Exception as err:  # noqa: BLE001 - a bad per-log config fails that log only
                configs[key] = failure_text(err, str(entry.config))
        return configs[key]

    derived: dict[int, tuple[dict, str]] = {}  # per config object: its dict and hash, computed once

    def identify(entry: LogEntry, cfg: RunConfig | str, skey: str | None, chash: str | InputError) -> _Planned:
        log = os.path.realpath(entry.path)
        named = Path(entry.path)  # a run id takes the name the user gave (a symbolic link's, not its target's)
        path_id = run_id_for(named, path_key(Path(log)))
        cfg_file = os.path.realpath(entry.config) if entry.config else None
        known = cfg if isinstance(cfg, RunConfig) else options.config
        if id(known) not in derived:
            derived[id(known)] = (known.to_dict(), config_hash(known))
        cfg_dict, cfg_hash = derived[id(known)]
        stub = Task.make(path_id, log, out, cfg_dict, config_file=cfg_file)
        try:
            log.encode()
        except UnicodeEncodeError as err:  # the summary stores names as UTF-8 text: report it, do not record it
            shown = os.fsencode(log).decode("utf-8", "backslashreplace")
            byte = os.fsencode(log[err.start])[0]
            return _Planned(
                log,
                row=retry_row(
                    replace(stub, log=shown),
                    f"{shown}: the file name is not UTF-8 (byte 0x{byte:02x}): rename it to run this log",
                    "name",
                ),
                path_id=path_id,
            )
        if isinstance(cfg, str):
            return _Planned(log, row=failed_row(stub, cfg), path_id=path_id)
        if isinstance(chash, InputError):
            return _Planned(log, row=failed_row(stub, str(InputError(entry.path, chash.problem))), path_id=path_id)
        key = run_key(chash, cfg_hash)
        # the first log of a (content, config) names its run: a copy under another name in this batch is that run
        rid = by_key.setdefault(key, run_id_for(named, key))
        return _Planned(
            log,
            task=replace(stub, run_id=rid, content_hash=chash, config_hash=cfg_hash, stat_key=skey),
            path_id=path_id,
        )

    def lookup(entry: LogEntry) -> tuple[str | None, str | InputError | None]:
        try:
            return cache.lookup(Path(os.path.realpath(entry.path)))
        except InputError as err:
            return None, err

    cfgs = [config_for(e) for e in entries]
    found = [lookup(e) for e in entries]  # a stat per file: cheap, and all an up-to-date batch needs
    todo = [i for i, (key, h) in enumerate(found) if key is not None and h is None]

    def read(i: int) -> str | InputError:
        try:
            return cache.content_hash(Path(os.path.realpath(entries[i].path)), found[i][0])
        except InputError as err:
            return err

    with ThreadPoolExecutor(max_workers=8) as pool:  # reading is I/O: overlapped
        for i, h in zip(todo, pool.map(read, todo)):
            found[i] = (found[i][0], h)
    return [identify(e, c, k, h) for e, c, (k, h) in zip(entries, cfgs, found)]


@dataclass
class _Plan:
    tasks: list[Task] = field(default_factory=list)
    rows: dict[int, dict] = field(default_factory=dict)  # position -> row reported at once (failed / skipped)
    order: list[str] = field(default_factory=list)  # run_id per position
    drop: set[str] = field(default_factory=set)  # recorded runs to take out before running
    records: list[dict] = field(default_factory=list)  # rows to record before running (failures, moved logs)


def _decide(planned: list[_Planned], options: BatchOptions, ledger: Ledger) -> _Plan:
    plan = _Plan()
    first: dict[str, str] = {}
    current: dict[str, str] = {}  # log path -> its content hash now
    moved: list[tuple[dict, str, Task]] = []
    for pos, p in enumerate(planned):
        if p.task is None:
            plan.order.append(p.row["run_id"])
            plan.rows[pos] = p.row
            if not p.row.get(RETRY):
                plan.records.append(p.row)
            continue
        task = p.task
        rid = task.run_id
        plan.order.append(rid)
        current[p.log] = task.content_hash
        if p.path_id in ledger.rows and p.path_id != rid:
            plan.drop.add(p.path_id)  # an earlier failure of this path before it could be hashed
        if rid in first:
            plan.rows[pos] = {
                **base_row(task),
                "status": "skipped",
                "error": f"same content and config as {first[rid]} (run {rid})",
            }
            continue
        first[rid] = p.log
        prev = ledger.rows.get(rid)
        status = prev.get("status") if prev else None
        if finished(status) and not options.force:
            if prev["log"] != p.log:
                moved.append((prev, p.log, task))
            plan.rows[pos] = {**prev, "status": "skipped", "error": None, "log": p.log, "config_file": task.config_file}
        elif status == "failed" and options.skip_failed and not options.force:
            plan.rows[pos] = {
                **prev,
                "status": "skipped",
                "log": p.log,
                "error": f"not retried (--skip-failed): {prev.get('error')}",
            }
        else:
            plan.tasks.append(task)
            if prev is not None:
                plan.drop.add(rid)
    # a moved log: the record follows it when its recorded path no longer holds that content
    for prev, log, task in moved:
        if not os.path.exists(prev["log"]) or current.get(prev["log"], prev["content_hash"]) != prev["content_hash"]:
            plan.records.append({**prev, "log": log, "config_file": task.config_file})
    # a log whose content changed replaces its earlier runs (their input is gone), unless they are this batch's
    for rid, row in ledger.rows.items():
        if (
            rid not in first
            and row.get("log") in current
            and row.get("content_hash") not in (None, current[row["log"]])
        ):
            plan.drop.add(rid)
    return plan


def kept_row(task: Task, why: str) -> dict:
    """The row of a log whose run directory holds a file of the user's: skipped, saying why; never recorded (the
    next batch runs it once the file is gone)."""
    return {**base_row(task), "status": "skipped", "error": why, RETRY: KEPT}


def _keep(plan: _Plan, kept: dict[str, str]) -> None:
    """Take the runs of ``kept`` out of ``plan``: neither deleted nor run; a log of them gets a :func:`kept_row`."""
    plan.drop -= kept.keys()
    for i, rid in enumerate(plan.order):
        if i not in plan.rows and rid in kept:
            task = next(t for t in plan.tasks if t.run_id == rid)
            plan.rows[i] = kept_row(task, kept[rid])
    plan.tasks = [t for t in plan.tasks if t.run_id not in kept]


def _gone(row: dict, cache: HashCache) -> bool:
    """The run's log is no longer at its recorded path with its recorded content."""
    log = row.get("log")
    if not log or not os.path.exists(log):
        return True
    if row.get("content_hash") is None:
        return False
    try:
        return cache.content_hash(Path(log)) != row["content_hash"]
    except InputError:
        return True


class _Staging:
    """This batch's staging directory and its lease: a file touched every few seconds while the batch lives
    (Dask tasks whose batch is gone see it go stale and stop)."""

    def __init__(self, out: Path) -> None:
        token = f"{time.strftime('%Y%m%dT%H%M%S')}-{os.getpid()}-{os.urandom(3).hex()}"
        self.dir = staging_root(out) / token
        self.dir.mkdir(parents=True)
        self.lease = self.dir / "LEASE"
        self.lease.touch()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._touch, name="slamobs-lease-touch", daemon=True)
        self._thread.start()

    def _touch(self) -> None:
        while not self._stop.wait(LEASE_TOUCH_S):
            try:
                os.utime(self.lease)
            except OSError:
                return

    def close(self, tasks_may_run: bool = False) -> None:
        """Remove the lease, then the directory. ``tasks_may_run``: tasks of this batch may still run on a Dask
        cluster it lost (their workers outlive a killed scheduler): they end within ``LEASE_POLL_S`` of seeing the
        lease gone, and what they write until then (a run's writer makes its parent directories again) is removed
        as it appears, so that the batch leaves nothing staged (kill_matrix seed 35: scheduler SIGKILLed mid-run,
        two staged runs left after exit 3)."""
        self._stop.set()
        self.lease.unlink(missing_ok=True)
        try:  # only a task that made its run's directory can make it again (a task starting later cannot)
            begun = tasks_may_run and any(p.is_dir() for p in self.dir.iterdir())
        except OSError:
            begun = False
        remove_path(self.dir)
        deadline = time.monotonic() + (LEASE_POLL_S + 1.0 if begun else 0.0)
        while time.monotonic() < deadline:
            time.sleep(0.1)
            remove_path(self.dir)


def run_batch(
    entries: Sequence[LogEntry],
    options: BatchOptions,
    on_row: Callable[[dict, Progress], None] = lambda _row, _p: None,
    on_start: Callable[[Progress], None] = lambda _p: None,
    run: Callable[[Task], dict] = run_task,
) -> BatchResult:
    """Run every log of ``entries`` into ``options.out``; ``on_row`` sees each row once it is recorded.

    ``on_start`` sees the plan (``total`` logs, ``to_run`` of them not up to date) before anything runs.
    ``run`` is the workers' task function (tests pass ones that crash or hang). Entries under ``options.out``
    are left out: a batch's own outputs (``results.mcap`` exports) are never its logs.

    Raises:
        InputError: Another batch holds ``out``, or ``out`` has the older layout.
        DaskMissing: The Dask executor without ``distributed`` installed.
        InfrastructureError: Scheduler lost, no usable workers, worker environment mismatch.

    """
    if options.executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {EXECUTORS}, got {options.executor!r}")
    use_dask = options.executor == "dask" or bool(options.scheduler)
    if use_dask and not dask_available():
        raise DaskMissing(DASK_MISSING)
    t0 = time.perf_counter()
    out = Path(options.out)
    check_layout(out)
    entries = outside(entries, out)
    with batch_lock(out):
        ledger = Ledger(out)
        try:
            index, fixed = reconcile(out, ledger)
            cache = HashCache(meta_dir(out) / "hashes.json")
            try:
                by_key = {}
                for rid, row in ledger.rows.items():
                    if row.get("content_hash") and row.get("config_hash"):
                        by_key[run_key(row["content_hash"], row["config_hash"])] = rid
                plan = _decide(_identify(entries, options, cache, by_key), options, ledger)
                pruned = []
                if options.prune:
                    mentioned = set(plan.order)
                    pruned = sorted(
                        rid
                        for rid, row in ledger.rows.items()
                        if rid not in mentioned and rid not in plan.drop and _gone(row, cache)
                    )
                    plan.drop |= set(pruned)
            finally:
                cache.save()
            kept = fixed.kept | kept_runs(out, plan.drop | {t.run_id for t in plan.tasks})
            _keep(plan, kept)
            with signals_deferred():
                drop_runs(index, ledger, plan.drop)
                for row in plan.records:
                    ledger.put(row)
            if ledger.appended or not (out / SUMMARY).is_file():
                ledger.compact()
            rows: dict[int, dict] = dict(plan.rows)
            pool = None
            if plan.tasks:  # a Dask cluster is checked before the batch says it starts
                pool = (
                    DaskPool(options.jobs, options.scheduler, options.timeout, options.wait_workers, run)
                    if use_dask
                    else LocalPool(options.jobs, run, options.timeout)
                )
            try:
                if use_dask and pool is not None:
                    pool.connect()
                progress = Progress(
                    total=len(plan.order), to_run=len(plan.tasks), notes=list(getattr(pool, "notes", []))
                )
                on_start(progress)
                for pos in sorted(plan.rows):
                    progress.add(plan.rows[pos], dispatched=False)
                    on_row(plan.rows[pos], progress)
                progress.started = time.perf_counter()
                if pool is not None:
                    _execute(plan, pool, options, use_dask, ledger, rows, progress, on_row, kept)
            finally:
                if use_dask and pool is not None:
                    pool.close()
            ledger.compact()  # the summary lists every stored run before compaction takes room
            compaction = compact_dataset(out) if options.compact else []
        finally:
            ledger.compact()
            ledger.close()
    ordered = [rows[i] for i in range(len(plan.order)) if i in rows]
    return BatchResult(
        rows=ordered,
        elapsed_s=time.perf_counter() - t0,
        summary_path=out / SUMMARY,
        pruned=pruned,
        reconciled=fixed,
        compaction=compaction,
        kept=kept,
    )


def _commit(out: Path, task: Task, row: dict) -> dict:
    """Commit a staged run; on a file system error (disk full, permissions) the run fails and leaves nothing."""
    tables = [t for t in row["tables"].split(",") if t]
    try:
        commit_run(out, Path(task.staged), task.run_id, tables)
        return row
    except InputError:  # a file of the user's appeared in the run directory while the run ran: nothing moved
        return kept_row(task, kept_runs(out, [task.run_id]).get(task.run_id, "its run directory changed"))
    except OSError as err:
        for table in tables:
            remove_path(partition_file(out, table, task.run_id).parent)
        remove_path(run_dir(out, task.run_id))
        return {
            **retry_row(task, f"{out}: cannot add the run to the dataset: {err.strerror or err}", "machine"),
            "total_s": row.get("total_s"),
        }


def _execute(
    plan: _Plan,
    pool: LocalPool | DaskPool,
    options: BatchOptions,
    use_dask: bool,
    ledger: Ledger,
    rows: dict[int, dict],
    progress: Progress,
    on_row: Callable[[dict, Progress], None],
    kept: dict[str, str],
) -> None:
    """Run the plan's tasks on ``pool``, committing and recording each as it finishes (a run found kept at its
    commit is added to ``kept``)."""
    out = Path(options.out)
    position = {}
    for i, rid in enumerate(plan.order):
        if i not in plan.rows:
            position.setdefault(rid, i)
    staging = _Staging(out)
    tasks = [
        replace(t, staged=str(staging.dir / t.run_id), lease=str(staging.lease) if use_dask else None)
        for t in plan.tasks
    ]
    results = None
    ended = False
    try:
        results = pool.results(tasks)
        refreshed = time.monotonic()
        for task, row in results:
            with signals_deferred():
                if finished(row["status"]):
                    row = _commit(out, task, row)
                    if row.get(RETRY) == KEPT:
                        kept[task.run_id] = row["error"]
                if not row.get(RETRY):  # not the log's failure: the next batch runs it again
                    ledger.put(row)
            remove_path(Path(task.staged))
            rows[position[task.run_id]] = row
            progress.add(row, dispatched=True)
            on_row(row, progress)
            if time.monotonic() - refreshed > ledger.refresh_every():
                ledger.compact()
                refreshed = time.monotonic()
        ended = True
    finally:  # each step even when a stop signal cut the one before (it left the staging directory behind)
        try:
            if results is not None:
                results.close()  # kills the local workers
        finally:
            try:
                if use_dask and not options.scheduler:
                    pool.close()  # a local cluster's workers killed before its tasks could write into staging again
            finally:
                with critical():  # a stop signal is raised after it, never leaving half of it
                    staging.close(tasks_may_run=use_dask and bool(options.scheduler) and not ended)


def compact_batch(out: Path) -> tuple[Reconciled, list[TableCompaction]]:
    """``slamobs batch compact OUT``: settle what an interrupted batch left, merge the partitions, rewrite the
    summary. Raises InputError when another batch holds ``out`` or it is not a batch directory."""
    out = Path(out)
    check_layout(out)
    if not (out / SUMMARY).is_file() and not meta_dir(out).is_dir():
        raise InputError(
            out, "not a batch output directory (no summary.parquet)" if out.is_dir() else "no such directory"
        )
    with batch_lock(out):
        ledger = Ledger(out)
        try:
            _, fixed = reconcile(out, ledger)
            ledger.compact()
            return fixed, compact_dataset(out)
        finally:
            ledger.compact()
            ledger.close()
