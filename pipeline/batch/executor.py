"""Where the runs execute: local worker processes or a Dask cluster, one log per worker at a time.

A task is self-contained and picklable; :func:`run_task` runs in the worker, writes that run's files under
``OUT`` (so on a cluster ``OUT`` and the logs must be on a file system every worker sees at the same path)
and returns the run's summary row. A task never raises: a failure is a row with ``status == "failed"``.
"""

from __future__ import annotations

import importlib.util
import multiprocessing
import os
import socket
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from slamobs.pipeline.config import RunConfig

EXECUTORS = ("local", "dask")
_DIED = "worker process died (crash or out of memory) while running this log"


@dataclass(frozen=True)
class Task:
    """One log to run, with everything the worker needs and the identities recorded in the summary.

    Plain data only (the config as a dict, not a RunConfig): a worker with another slamobs version then
    fails that run with a clear error instead of unpickling a mismatched object.
    """

    run_id: str
    log: str
    out: str
    config: dict
    config_file: str | None
    content_hash: str | None
    config_hash: str
    version: str = ""

    @classmethod
    def make(cls, run_id: str, log: str, out: str, config: RunConfig, config_file: str | None = None,
             content_hash: str | None = None, config_hash: str = "") -> Task:
        import slamobs

        return cls(run_id, log, out, config.to_dict(), config_file, content_hash, config_hash, slamobs.__version__)


def one_line(err: BaseException, where: str | None = None) -> str:
    """An exception as one summary line naming the file (InputError texts already do)."""
    from slamobs.pipeline.errors import InputError

    text = " ".join(str(err).split())
    if not isinstance(err, InputError):
        text = f"{type(err).__name__}: {text}" if text else type(err).__name__
        text = f"{where}: {text}" if where else text
    return text[:500]


def base_row(task: Task) -> dict:
    import slamobs

    return {"run_id": task.run_id, "log": task.log, "config_file": task.config_file,
            "content_hash": task.content_hash, "observer": task.config.get("observer"), "config_hash": task.config_hash,
            "slamobs_version": slamobs.__version__, "finished_at": datetime.now(UTC),
            "worker": f"{socket.gethostname()}:{os.getpid()}"}


def failed_row(task: Task, error: str) -> dict:
    return {**base_row(task), "status": "failed", "error": error}


def _check_version(task: Task) -> None:
    import slamobs

    if task.version and task.version != slamobs.__version__:
        raise RuntimeError(f"worker runs slamobs {slamobs.__version__}, the batch {task.version}: "
                           "install the same version on every worker")


def run_task(task: Task) -> dict:
    """Run one log (worker side): run directory via ``run_log``, then its partitions; returns the row."""
    from slamobs.pipeline.batch.dataset import remove_run, run_dir, write_partitions
    from slamobs.pipeline.run import run_log

    t0 = time.perf_counter()
    out = Path(task.out)
    # warnings go into the summary row: worker stderr would interleave with the batch's progress output
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        try:
            _check_version(task)
            summary = run_log(Path(task.log), run_dir(out, task.run_id), RunConfig(**task.config), force=True)
            t = time.perf_counter()
            write_partitions(out, task.run_id)
            row = {**base_row(task), "status": "ok", "error": None, "dataset_s": time.perf_counter() - t,
                   **summary.timings, **summary.metadata["counts"], **summary.headline()}
        except Exception as err:  # noqa: BLE001 - one failing log must never stop the batch
            remove_run(out, task.run_id)
            row = failed_row(task, one_line(err, task.log))
    texts = list(dict.fromkeys(f"{w.category.__name__}: {w.message} ({Path(w.filename).name}:{w.lineno})"
                               for w in caught))
    row["warnings"] = "; ".join(texts)[:500] or None
    row["total_s"] = time.perf_counter() - t0
    return row


def local_results(tasks: Sequence[Task], jobs: int, run: Callable[[Task], dict] = run_task) -> Iterator[dict]:
    """Rows of ``tasks`` run in ``jobs`` spawned worker processes, in completion order.

    ``run`` is the worker function (a picklable top-level function; tests pass one that crashes).

    At most ``jobs`` tasks are in flight, so when a worker dies (which breaks the whole pool) the suspects
    are exactly those; they are retried one at a time in a fresh single-worker pool, so a log that kills
    its worker fails alone and the rest of the batch carries on.
    """
    todo: deque[Task] = deque(tasks)
    suspects: deque[Task] = deque()
    ctx = multiprocessing.get_context("spawn")  # numba and threads do not survive fork well
    while todo or suspects:
        isolated = bool(suspects)
        source, width = (suspects, 1) if isolated else (todo, max(1, jobs))
        pool = ProcessPoolExecutor(max_workers=width, mp_context=ctx)
        inflight: dict[Future, Task] = {}
        broken = False
        try:
            while inflight or (source and not broken):
                while source and not broken and len(inflight) < width:
                    task = source.popleft()
                    inflight[pool.submit(run, task)] = task
                done, _ = wait(inflight, return_when=FIRST_COMPLETED)
                for fut in done:
                    task = inflight.pop(fut)
                    try:
                        yield fut.result()
                    except BrokenProcessPool:
                        broken = True
                        if isolated:
                            yield failed_row(task, f"{task.log}: {_DIED}")
                        else:
                            suspects.append(task)
                    except Exception as err:  # noqa: BLE001 - e.g. a task that cannot be pickled
                        yield failed_row(task, one_line(err, task.log))
        finally:
            # on an interruption: drop queued work, let running logs finish so no writer outlives the batch
            pool.shutdown(wait=True, cancel_futures=True)


def dask_available() -> bool:
    return importlib.util.find_spec("distributed") is not None


def dask_results(tasks: Sequence[Task], jobs: int, scheduler: str | None = None) -> Iterator[dict]:
    """Rows of ``tasks`` run on Dask: the cluster at ``scheduler``, else a local cluster of ``jobs`` processes.

    Start remote workers with ``--nthreads 1`` to keep one log per worker process at a time.
    """
    import logging

    from distributed import Client, LocalCluster, as_completed

    from slamobs.pipeline.errors import InputError

    cluster = None
    if scheduler:
        try:
            client = Client(scheduler)
        except (OSError, TimeoutError, ValueError) as err:
            raise InputError(scheduler, f"cannot reach the Dask scheduler ({one_line(err)})") from None
    else:
        cluster = LocalCluster(n_workers=max(1, jobs), processes=True, threads_per_worker=1,
                               dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(cluster)
    by_key: dict[str, tuple] = {}
    try:
        for task in tasks:
            fut = client.submit(run_task, task, pure=False, key=f"slamobs-{task.run_id}-{os.urandom(4).hex()}")
            by_key[fut.key] = (fut, task)
        for fut in as_completed([f for f, _ in by_key.values()]):
            task = by_key[fut.key][1]
            try:
                yield fut.result()
            except Exception as err:  # noqa: BLE001 - e.g. KilledWorker after a worker died on this log
                yield failed_row(task, one_line(err, task.log))
    finally:
        for fut, _ in by_key.values():
            fut.cancel()
        client.close()
        if cluster is not None:
            cluster.close()
