"""What runs in a worker: one log -> a staged run (run directory and dataset tables) and its summary row.

A task is self-contained and picklable. :func:`run_task` writes only inside the task's staging directory
(``OUT/_slamobs/staging/<batch>/<run_id>/``; on a cluster ``OUT`` and the logs must be on a file system
every worker sees at the same path) and returns the row; the batch process commits it
(:func:`dataset.commit_run`). A worker whose batch is gone therefore cannot change the dataset, whatever
it does. A task never raises for a bad log: that is a row with ``status == "failed"``; it raises
:class:`EnvironmentMismatch` when the worker runs other slamobs code than the batch.

A failure that says nothing about the log is a failed row marked with ``retry`` (:func:`retry_row`): the
machine ran out or refused (disk full, memory, permission), or the log changed while it ran (its result
would be stored under the old content's run_id). The batch reports it but does not record it, so the next
batch runs the log again and ``--skip-failed`` never skips it.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from slamobs.pipeline.config import RunConfig
from slamobs.pipeline.errors import InfrastructureFailure, one_line

EXECUTORS = ("local", "dask")
#: Written into a task's staging directory as its run begins (worker and pid): what an operator, or a kill test,
#: looks for to know a log is running and where. Timeouts count from the staging directory itself.
STARTED = "started.json"
#: Next to a task's staging directory (``<run_id>.starts``): one line per time a worker began the log. Dask counts a
#: worker's death against every log it held, the ones queued on it too; this file tells those from the logs that were
#: running (see ``DaskPool``).
STARTS = ".starts"
#: A log whose Dask workers died under it every time (Dask's ``allowed-failures`` + 1 times running).
DIED = "Dask workers died while running this log, every retry (crash or out of memory)"
#: A Dask task gives up (ends its worker process) when its batch's lease file has not been touched for this
#: long: the batch process is gone, nothing the task produces can be committed.
LEASE_STALE_S = 60.0
LEASE_POLL_S = 2.0
#: Row key of a failure that is not the log's (see the module doc): why, one of RETRY_WHY.
RETRY = "retry"
#: "name": a file name the summary cannot store (not UTF-8); "kept": the run directory holds a file of the user's, so
#: the run was neither deleted nor run (a "skipped" row, see runner.kept_row)
KEPT = "kept"
RETRY_WHY = ("machine", "changed", "name", KEPT)


class EnvironmentMismatch(InfrastructureFailure, RuntimeError):
    """The worker runs another slamobs version or code than the batch (an infrastructure problem)."""


class InfrastructureError(InfrastructureFailure, RuntimeError):
    """The batch cannot go on: scheduler lost, no usable workers, worker environment mismatch (exit 3)."""


@dataclass(frozen=True)
class Task:
    """One log to run, with everything the worker needs and the identities recorded in the summary.

    Plain data only (the config as a dict, not a RunConfig): a worker with another slamobs version then
    fails with a clear error instead of unpickling a mismatched object.
    """

    run_id: str
    log: str
    out: str
    config: dict
    config_file: str | None = None
    content_hash: str | None = None
    config_hash: str = ""
    staged: str = ""  # this run's staging directory (its parent is created by the batch)
    version: str = ""
    code: str = ""  # identity.code_hash() of the batch
    lease: str | None = None  # Dask: the batch's lease file (see LEASE_STALE_S)
    stat_key: str | None = None  # identity.stat_key of the log when the batch hashed it (None: not checked)
    starts_limit: int = 0  # Dask: fail at once once workers began the log this often (0: no limit; see STARTS)

    @classmethod
    def make(cls, run_id: str, log: str, out: str, config: RunConfig | dict, **kwargs) -> Task:
        """A task at this installation's version and code; ``config`` may be given as ``RunConfig.to_dict()``
        (a batch converts each config once)."""
        from slamobs.pipeline.version import __version__

        from slamobs.pipeline.batch.identity import code_hash

        config = config if isinstance(config, dict) else config.to_dict()
        return cls(run_id, log, out, config, version=__version__, code=code_hash(), **kwargs)


def failure_text(err: BaseException, where: str | None = None) -> str:
    """A failed run's error for its summary row: one line naming the file (InputError texts already do)."""
    from slamobs.pipeline.errors import InputError

    text = one_line(err)
    if not isinstance(err, InputError):
        text = f"{type(err).__name__}: {text}" if text else type(err).__name__
        text = f"{where}: {text}" if where else text
    return text[:500]


def base_row(task: Task) -> dict:
    from slamobs.pipeline.version import __version__

    return {
        "run_id": task.run_id,
        "log": task.log,
        "config_file": task.config_file,
        "content_hash": task.content_hash,
        "observer": task.config.get("observer"),
        "config_hash": task.config_hash,
        "slamobs_version": __version__,
        "finished_at": datetime.now(UTC),
        "worker": _worker_name(),
        "warning_count": 0,
    }


def failed_row(task: Task, error: str) -> dict:
    return {**base_row(task), "status": "failed", "error": error}


def retry_row(task: Task, error: str, why: str) -> dict:
    """A failure that is not the log's (``why`` in RETRY_WHY): reported, never recorded (see the module doc)."""
    return {**failed_row(task, error), RETRY: why}


def _changed(task: Task, read: bool) -> Exception | None:
    """Why the log is no longer the one the batch identified (its files' identity, and with ``read`` its
    content hash), or None. Checked before and after the run: a log replaced meanwhile (``mv new log``) would
    store another log's result under this content's run_id."""
    from slamobs.pipeline.batch.identity import content_hash, stat_key
    from slamobs.pipeline.errors import InputError

    if not task.stat_key:
        return None
    log = Path(task.log)
    try:
        same = stat_key(log) == task.stat_key and (not read or content_hash(log) == task.content_hash)
    except InputError as err:
        return InputError(task.log, f"changed while the batch ran ({err.problem}); run again by the next batch")
    if same:
        return None
    when = "while it ran" if read else "since the batch identified it"
    return InputError(
        task.log,
        f"the log changed {when} (replaced or rewritten): its result is discarded and the next batch runs it again",
    )


def check_environment(version: str, code: str) -> None:
    from slamobs.pipeline.version import __version__

    from slamobs.pipeline.batch.identity import code_hash

    if (version and version != __version__) or (code and code != code_hash()):
        raise EnvironmentMismatch(
            f"{socket.gethostname()} runs slamobs {__version__} (code {code_hash()}), "
            f"the batch {version} (code {code}): install the same version on every worker"
        )


def _watch_lease(lease: Path, done: threading.Event) -> None:
    """End this worker process once the batch's lease goes stale (the batch process died)."""
    from slamobs.pipeline.lifetime import ORPHANED

    def loop() -> None:
        last, changed = None, time.monotonic()
        while not done.wait(LEASE_POLL_S):
            try:
                mtime = lease.stat().st_mtime_ns
            except OSError:
                os._exit(ORPHANED)
            if mtime != last:
                last, changed = mtime, time.monotonic()
            elif time.monotonic() - changed > LEASE_STALE_S:
                os._exit(ORPHANED)

    threading.Thread(target=loop, name="slamobs-lease", daemon=True).start()


def _run(log: Path, out_dir: Path, config: RunConfig):
    """:func:`pipeline.run.run_log` into ``out_dir``; returns its summary and the warnings it counted: the input's
    and what the estimator's own status says against ``ok`` (:meth:`.run.RunSummary.status_caveats`)."""
    from slamobs.pipeline.run import run_log

    summary = run_log(log, out_dir, config)
    name = summary.metadata["observer"]["name"]
    return summary, list(summary.input_warnings) + [f"{name}: {c}" for c in summary.status_caveats()]


def _worker_name() -> str:
    """The Dask worker's address inside a Dask task, else host:pid."""
    if "distributed" in sys.modules:  # never imported just to ask
        try:
            return sys.modules["distributed"].get_worker().address
        except (AttributeError, ValueError):
            pass
    return f"{socket.gethostname()}:{os.getpid()}"


def _starts_file(staged: Path) -> Path:
    return staged.with_name(staged.name + STARTS)


def starts(task: Task) -> int:
    """How many times a worker began ``task``'s log in this batch (:data:`STARTS`)."""
    try:
        return _starts_file(Path(task.staged)).read_bytes().count(b"\n")
    except (OSError, ValueError):  # not begun; or no staging directory (a tune's trial)
        return 0


def _begin(staged: Path) -> None:
    """Make the staging directory (a Dask retry's anew), count the start, and say who runs the log."""
    from slamobs.pipeline.batch.dataset import remove_path

    if staged.exists():  # a Dask retry after a worker died on this task
        remove_path(staged)
    staged.mkdir()  # not parents: a batch that is gone has removed them, and nothing is recreated
    with open(_starts_file(staged), "a") as fh:
        fh.write(f"{os.getpid()}\n")
    (staged / STARTED).write_text(json.dumps({"worker": _worker_name(), "pid": os.getpid()}))


def run_task(task: Task, pipeline=_run) -> dict:
    """Run one log (worker side) into its staging directory; returns the summary row.

    ``pipeline(log, run_dir, config) -> (RunSummary, warnings)`` writes the run directory (tests pass a fast
    stand-in through ``functools.partial``; the staging and commit contract stays this function's).

    A finished run's row (``ok``, or its estimator's own status: :func:`.ledger.finished`) carries ``tables``
    (comma-separated); ``runs/<id>/batch.json`` in the staged run directory repeats the row, so a run whose
    commit was cut short can be adopted by the next batch.
    """
    from slamobs.pipeline.batch.dataset import remove_path, stage_tables, write_run_meta
    from slamobs.pipeline.batch.ledger import finished
    from slamobs.pipeline.errors import is_resource_failure

    check_environment(task.version, task.code)
    t0 = time.perf_counter()
    staged = Path(task.staged)
    if task.starts_limit and starts(task) >= task.starts_limit:  # died under it every time: not once more
        return {**failed_row(task, f"{task.log}: {DIED}"), "warnings": None, "total_s": 0.0}
    done = threading.Event()
    if task.lease:
        _watch_lease(Path(task.lease), done)
    data_warnings: list[str] = []
    tables: dict[str, int] = {}
    changed: Exception | None = None
    with warnings.catch_warnings(record=True) as caught:
        # warnings go into the summary row: worker stderr would interleave with the batch's progress output
        warnings.simplefilter("default")
        try:
            _begin(staged)
            changed = _changed(task, read=False)
            failure = None
            if changed is None:
                try:
                    summary, data_warnings = pipeline(Path(task.log), staged / "run", RunConfig.from_dict(task.config))
                except Exception as err:  # noqa: BLE001 - unless the log changed meanwhile (then that is why)
                    failure = err
                changed = _changed(task, read=True)
            if changed is not None:
                raise changed
            if failure is not None:
                raise failure
            t = time.perf_counter()
            tables = stage_tables(staged, task.run_id)
            row = {
                **base_row(task),
                "status": summary.status(),  # ok, or the estimator's own where its record says its estimate is off
                "error": None,
                "dataset_s": time.perf_counter() - t,
                **summary.timings,
                **summary.metadata["counts"],
                **summary.headline(),
            }
        except Exception as err:  # noqa: BLE001 - one failing log must never stop the batch
            remove_path(staged)
            if err is changed:
                row = retry_row(task, failure_text(err), "changed")
            elif is_resource_failure(err):
                row = retry_row(task, failure_text(err, task.log), "machine")
            else:
                row = failed_row(task, failure_text(err, task.log))
        finally:
            done.set()
    texts = data_warnings + list(
        dict.fromkeys(f"{w.category.__name__}: {w.message} ({Path(w.filename).name}:{w.lineno})" for w in caught)
    )
    row["warning_count"] = len(texts)
    row["warnings"] = "; ".join(one_line(t) for t in texts)[:1000] or None
    row["total_s"] = time.perf_counter() - t0
    if finished(row["status"]):
        row["tables"] = ",".join(tables)
        try:
            write_run_meta(staged, task.run_id, tables, row)
        except OSError as err:  # e.g. the staging area was removed under an orphaned task, or a full disk
            remove_path(staged)
            row = {**retry_row(task, failure_text(err, str(staged)), "machine"), "total_s": row["total_s"]}
    return row
