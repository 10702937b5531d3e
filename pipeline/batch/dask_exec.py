"""Runs on Dask: an existing cluster (``--scheduler``) or a local one, with the failure modes of a real cluster
turned into clear outcomes instead of waits.

- Before anything is submitted: at least one worker within ``wait_workers`` seconds, and every worker
  imports slamobs at the batch's version and code hash (:mod:`probe`); otherwise
  :class:`InfrastructureError` naming the worker (exit 3).
- While running: a lost scheduler, or no worker for ``wait_workers`` seconds, is an InfrastructureError;
  a log whose workers keep dying is failed once Dask gives up (``KilledWorker``); a log running longer
  than ``timeout`` is failed and its worker restarted through its nanny. The clock starts when the task is
  handed to a worker, whatever the worker does next: a task counts as running from the moment its staging
  directory appears, and a worker that holds tasks without taking or finishing any for ``timeout`` seconds
  (at least ``local.STARTUP_S``: a new worker imports first) is restarted too (stopped, hung before it
  could start), so the logs queued on it go to other workers.
- Tasks only write into their staging directory and watch the batch's lease (:mod:`executor`): a task
  whose batch died cannot commit anything and ends its worker process within a minute.
"""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import CancelledError
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

from slamobs.pipeline.batch.executor import (
    DIED,
    EnvironmentMismatch,
    InfrastructureError,
    Task,
    failed_row,
    failure_text,
    retry_row,
    run_task,
    starts,
)
from slamobs.pipeline.batch.local import STARTUP_S
from slamobs.pipeline.errors import plural
from slamobs.pipeline.interrupts import critical
from slamobs.pipeline.lifetime import others_leave

POLL_S = 1.0
#: A scheduler address that refuses connections this long has nothing listening (a scheduler not started or
#: killed): the batch says so then, instead of after Dask's connect timeout (``--wait-workers``, up to 30 s).
REFUSED_S = 3.0

#: The warnings filter multiprocessing's resource tracker starts with (``PYTHONWARNINGS``): its shutdown's leaked
#: semaphore warnings, about semaphores it unlinks itself, ignored (see ``DaskPool``'s cluster start).
TRACKER_WARNINGS = "ignore::UserWarning:multiprocessing.resource_tracker"


@contextmanager
def _environ(**values: str) -> Iterator[None]:
    """``os.environ`` with ``values`` set while a child process is started, then as it was."""
    before = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def dask_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("distributed") is not None


def check_workers(client, where: str, version: str, code: str, within: float) -> int:
    """Every worker's answer to :func:`probe.probe` (within ``within`` seconds); raises on the first that cannot
    run this batch. Public: tests/test_batch_kills_dask.py asks it with a stand-in client."""
    from concurrent.futures import ThreadPoolExecutor
    from concurrent.futures import TimeoutError as Late

    import cloudpickle

    from slamobs.pipeline.batch import probe

    cloudpickle.register_pickle_by_value(probe)
    pool = ThreadPoolExecutor(max_workers=1)
    try:
        answers = pool.submit(client.run, probe.probe, on_error="return").result(timeout=within)
    except Late:
        raise InfrastructureError(f"{where}: the Dask workers did not answer within {within:g} s") from None
    except Exception as err:  # noqa: BLE001 - e.g. the scheduler went away meanwhile
        raise InfrastructureError(
            f"{where}: cannot ask the Dask workers for their environment ({failure_text(err)})"
        ) from None
    finally:
        pool.shutdown(wait=False)
        cloudpickle.unregister_pickle_by_value(probe)
    # a worker that died while asked (killed, out of memory: its connection closed) is not checked; the batch goes on
    # with the others (exit 3 "cannot run the environment check (CommClosedError ...)", kill_matrix seed 75 trial 5);
    # a worker that joins later is checked by its first task (EnvironmentMismatch)
    gone = [addr for addr, ans in answers.items() if isinstance(ans, OSError)]
    if gone and len(gone) < len(answers):
        answers = {addr: ans for addr, ans in answers.items() if addr not in gone}
    if not answers:
        raise InfrastructureError(f"{where}: no Dask workers")
    for addr, ans in sorted(answers.items()):
        if not isinstance(ans, dict):
            raise InfrastructureError(f"Dask worker {addr}: cannot run the environment check ({failure_text(ans)})")
        if not ans["ok"]:
            raise InfrastructureError(
                f"Dask worker {addr} ({ans['host']}, {ans['python']}): cannot import slamobs "
                f"({ans['error']}); install slamobs {version} on every worker"
            )
        if ans["version"] != version or ans["code"] != code:
            raise InfrastructureError(
                f"Dask worker {addr} ({ans['host']}): runs slamobs {ans['version']} "
                f"(code {ans['code']}), the batch {version} (code {code}); install the same "
                "version on every worker"
            )
    return len(answers)


def _refused(address: str, within: float = REFUSED_S) -> bool:
    """True when every TCP connection to a ``tcp://`` scheduler address is refused for ``within`` seconds (nothing
    listens there); False as soon as one is accepted, or on any other failure (a host that does not answer, a name
    that does not resolve, another transport): Dask's own connect then says what is wrong, within its timeout."""
    import socket

    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        host, port = parse_host_port(location)
    except (ValueError, TypeError):
        return False
    if scheme != "tcp" or not port:
        return False
    deadline = time.monotonic() + within
    while True:
        try:
            with socket.create_connection((host, port), timeout=max(0.2, deadline - time.monotonic())):
                return False
        except ConnectionRefusedError:
            if time.monotonic() >= deadline:
                return True
            time.sleep(0.2)
        except OSError:
            return False


@dataclass
class _Watch:
    """Where each pending task is and since when, for the timeouts (see the module doc)."""

    handed: dict[str, tuple[str, float]] = field(default_factory=dict)  # key -> (worker, when it got the task)
    taken: dict[str, float] = field(default_factory=dict)  # key -> when its staging directory appeared
    alive: dict[str, float] = field(default_factory=dict)  # worker -> its last task taken or finished
    restarted: set[str] = field(default_factory=set)  # workers being restarted (their tasks move elsewhere)
    back: list[str] = field(default_factory=list)  # restarts that returned (appended by their threads)

    def finished(self, key: str, now: float) -> None:
        worker = self.handed.pop(key, (None, 0.0))[0]
        self.taken.pop(key, None)
        if worker is not None:
            self.alive[worker] = now


def kill_workers(cluster) -> None:
    """SIGKILL a local cluster's worker processes, their nannies told first not to start them again.

    What distributed then logs of the killed workers is noise, silenced first: its comms ("Batched Comm Closed" and
    a CommClosedError traceback at INFO once a cluster's close restored distributed's handlers, kill_matrix seed 46;
    a signal while the cluster starts, as its constructor's clean-up kills them), a nanny restarting a worker killed
    mid-batch (an ERROR traceback: seed 48). Public: tests/test_batch_kills_local_cluster.py signals the batch in it."""
    import os

    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    # a nanny whose start was cut by the stop fails ("Nanny failed to start."): its task, abandoned by the cluster's
    # interrupted start, was reported by asyncio as "Task exception was never retrieved" and a traceback when
    # collected at exit, under the batch's line (a SIGHUP while the local cluster started)
    logging.getLogger("asyncio").setLevel(logging.CRITICAL)
    for nanny in list(getattr(cluster, "workers", {}).values()):
        pid = getattr(nanny, "pid", None)
        if hasattr(nanny, "close_gracefully"):
            nanny.close_gracefully(reason="slamobs batch stopped")  # the nanny must not start it again
        if pid:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _launching(frame) -> bool:
    return frame.f_code.co_name == "_launch" and "multiprocessing" in frame.f_code.co_filename


def spawns_settled(within: float = 5.0) -> None:
    """Wait (at most ``within`` seconds) until no other thread is between starting a child process and writing it
    its start data (multiprocessing's ``Popen._launch``): a local cluster's nanny starts its worker process in a
    thread of its own, and a batch that ended then (stopped as its cluster started) left the child to read a closed
    pipe and print ``EOFError: Ran out of input`` under the batch's line (1 of 5 Ctrl-C trials, kill5). Once its
    start returns, the child is one of multiprocessing's daemonic children, which the exit kills."""
    others_leave(_launching, within)


class DaskPool:
    """Tasks on Dask; ``scheduler`` None starts a ``LocalCluster`` of ``jobs`` single-threaded processes."""

    def __init__(
        self,
        jobs: int,
        scheduler: str | None = None,
        timeout: float | None = None,
        wait_workers: float = 60.0,
        run=run_task,
    ) -> None:
        self.jobs, self.scheduler, self.timeout, self.wait_workers = max(1, jobs), scheduler, timeout, wait_workers
        self.run = run  # the task function (tests pass run_task with a stand-in pipeline)
        self.where = scheduler or "local Dask cluster"
        self.client = self.cluster = None
        self.notes: list[str] = []  # what the batch should say as it starts (one line each)
        self.allowed = 3  # the scheduler's allowed-failures (asked as the pool connects)
        self.requeued: dict[str, int] = {}  # run_id -> times submitted again after a KilledWorker (see _killed)

    def connect(self) -> int:
        """Connect (or start the local cluster), wait for a worker, check every worker; returns their count."""
        from slamobs.pipeline.version import __version__
        from distributed import Client

        from slamobs.pipeline.batch.identity import code_hash

        # the client logs a lost scheduler as tracebacks on stderr; results() turns it into one error line
        logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
        if self.scheduler:
            if _refused(self.scheduler):
                raise InfrastructureError(
                    f"{self.scheduler}: cannot reach the Dask scheduler (connection refused for {REFUSED_S:g} s: "
                    "is it running at this address?)"
                )
            try:
                self.client = Client(self.scheduler, timeout=f"{max(1.0, min(self.wait_workers, 30.0))}s")
            except (OSError, TimeoutError, ValueError) as err:
                raise InfrastructureError(
                    f"{self.scheduler}: cannot reach the Dask scheduler ({failure_text(err)})"
                ) from None
        else:
            # Not in critical(), which batch's and tune's on_signal (cli/jobs.py) now honour too: a stop cuts the
            # start (in distributed's sync() wait) and Local's clean-up closes its half-built cluster (left to
            # distributed's exit hook, it printed a traceback, AssertionError: Status.init, under the batch's line);
            # deferred to the start's end, the exit waited for the workers to start (7.0-8.7 s at load 18-21).
            try:
                self.cluster = self._local_cluster()
                self.client = Client(self.cluster)
                self.notes += self._lost_at_start()
            except (OSError, TimeoutError, RuntimeError) as err:  # no port, no processes: the machine, not a log
                raise InfrastructureError(f"{self.where}: cannot start ({failure_text(err)})") from None
        try:
            self.client.wait_for_workers(1, timeout=self.wait_workers)
        except TimeoutError:
            raise InfrastructureError(
                f"{self.where}: no Dask workers after {self.wait_workers:g} s (--wait-workers)"
            ) from None
        except OSError as err:  # the scheduler went away while we waited (connection closed or refused)
            raise self._lost(err) from None
        self.allowed = self._allowed_failures()
        return check_workers(self.client, self.where, __version__, code_hash(), max(self.wait_workers, 10.0))

    def _allowed_failures(self) -> int:
        """The scheduler's ``distributed.scheduler.allowed-failures`` (a cluster's own configuration), or this
        process's where the scheduler cannot say."""
        import dask

        try:
            return int(self.client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.allowed_failures))
        except Exception:  # noqa: BLE001 - an older or stripped scheduler: Dask's default is the best guess
            return int(dask.config.get("distributed.scheduler.allowed-failures"))

    def _lost_at_start(self) -> list[str]:
        """One line when worker processes of the local cluster died as it started (see ``_local_cluster``)."""
        lost = getattr(self.cluster, "lost", [])
        if not lost:
            return []
        why = lost[-1][1]
        running = len(self.cluster.workers)
        if running == self.jobs:
            return [f"{self.where}: a worker process died as it started ({why}); started it again"]
        return [
            f"{self.where}: {self.jobs - running} of {self.jobs} worker processes did not start ({why}); "
            f"the batch runs on {running}"
        ]

    def _local_cluster(self):
        from distributed import LocalCluster
        from distributed.core import Status

        class Local(LocalCluster):
            """A cluster whose start failed (its workers ended by the same Ctrl-C, as they import) is closed here,
            errors ignored, and not left to distributed's exit hook: it printed a traceback (AssertionError:
            Status.init) under the batch's line (kill_matrix seed 45).

            A worker process that dies as the cluster starts (killed, out of memory) failed the whole start, and
            the batch with it (exit 3 "Nanny failed to start.", kill_matrix seed 72): its nanny is started again
            once, then left out; the start fails only when no worker started. ``lost`` says what happened."""

            lost: list[tuple[int, str, bool]] = []  # (nannies, why, started again) per failed start

            async def _correct_state_internal(self) -> None:
                if threading.current_thread() is not threading.main_thread():  # the cluster's event loop thread
                    # its nannies start their worker processes from threads it makes: they inherit the mask, and
                    # the processes too, across exec; Ctrl-C or a closed terminal (SIGINT, SIGHUP to the group) as
                    # they imported printed their KeyboardInterrupt tracebacks under the batch's line (8 of 10
                    # Ctrl-C trials at load 15-20); the batch kills them itself, and SIGTERM still ends them.
                    # multiprocessing's resource tracker is started here, with them blocked too: started by a
                    # nanny's thread, a SIGHUP to the group killed it (it ignores SIGINT and SIGTERM only), and the
                    # one relaunched printed a KeyError traceback per semaphore it had not seen (kill_matrix seed 75);
                    # its start unblocks SIGINT and SIGTERM in the thread that starts it (bpo-33613): blocked again
                    # It also starts with its own UserWarnings ignored: a semaphore a nanny's queue left as the batch
                    # stopped is unlinked by the tracker either way, but its "1 leaked semaphore objects" and
                    # "[Errno 2] No such file or directory" printed under the batch's line when the unlink raced
                    # the exit's (1 Ctrl-C trial of the fresh-clone suite, session 24; cli.errors waits 2 s for it)
                    from multiprocessing import resource_tracker

                    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGHUP})
                    with _environ(PYTHONWARNINGS=TRACKER_WARNINGS):
                        resource_tracker.ensure_running()
                    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGHUP})
                for again in (True, False):
                    try:
                        return await super()._correct_state_internal()
                    except Exception as err:  # noqa: BLE001 - the nannies that did not start are known below
                        failed = [name for name, nanny in self.workers.items() if nanny.status != Status.running]
                        if not failed or len(failed) == len(self.workers) and not again:
                            raise
                        why = failure_text(err.__cause__ or err)
                        for name in failed:
                            del self.workers[name]
                            if not again:
                                del self.worker_spec[name]
                        self.lost = [*self.lost, (len(failed), why, again)]

            def __init__(self, **kwargs) -> None:
                try:
                    super().__init__(**kwargs)
                except BaseException:
                    kill_workers(self)
                    try:
                        self.close(timeout=5)
                    except BaseException:  # noqa: BLE001 - half built: nothing of it to keep
                        pass
                    self.shutdown_on_close = False  # the exit hook leaves it alone
                    spawns_settled()
                    raise

        return Local(
            n_workers=self.jobs,
            processes=True,
            threads_per_worker=1,
            dashboard_address=None,
            # its HTTP server (health routes) still starts: on a free port, not 8787 with a warning
            # ("Port 8787 is already in use") printed above the batch's lines when another cluster has it
            scheduler_kwargs={"dashboard_address": ":0"},
            # not ERROR: the scheduler, in the batch's process, printed "Task ... marked as failed because 4 workers
            # died while trying to run it" and "Couldn't gather keys" between the batch's lines when a worker was
            # killed under a log (an OOM kill); the batch's row says what happened, in one line
            silence_logs=logging.CRITICAL,
        )

    def close(self) -> None:
        """Close the client, and the local cluster if we started one, its worker processes killed first, as local
        workers are: they hold nothing the batch needs. Closed gracefully, each waited for its running log (11 s
        after a SIGTERM in the kill matrix), and idle ones took seconds under load to stop (a SIGTERM as the batch
        ended: exit 12.4 s later). Not cut in two by a signal (it is raised after): a cluster cut while closing
        was left "closing", and closing it again waited for that until its timeout."""
        with critical():
            self._close()

    def _close(self) -> None:
        if self.cluster is not None:
            kill_workers(self.cluster)
        if self.client is not None:
            try:
                self.client.close(timeout=5)
            except Exception:  # noqa: BLE001 - closing after a lost scheduler may fail; nothing to keep
                pass
        if self.cluster is not None:
            try:
                self.cluster.close(timeout=10)
            except Exception:  # noqa: BLE001
                pass
            spawns_settled()
        self.client = self.cluster = None

    def _lost(self, err: BaseException) -> InfrastructureError:
        return InfrastructureError(f"{self.where}: lost the Dask scheduler ({failure_text(err)})")

    def _fetch(self, get):
        """A finished task's result (or error) comes from the scheduler: losing it then (the connection closed or
        refused while fetching, or the client giving the scheduler up and cancelling every future: distributed's
        ``FutureCancelledError`` is a ``concurrent.futures.CancelledError``, not asyncio's) is the same lost
        scheduler, not a failure of the log."""
        try:
            return get(timeout=max(self.wait_workers, 10.0))
        except (OSError, TimeoutError, asyncio.CancelledError, CancelledError) as err:
            raise self._lost(err) from None

    def _workers(self) -> int:
        try:
            return len(self.client.scheduler_info().get("workers", {}))
        except Exception:  # noqa: BLE001
            return 0

    def results(self, tasks: Sequence[Task]) -> Iterator[tuple[Task, dict]]:
        """(task, row) in completion order; raises InfrastructureError as described in the module doc."""
        from distributed import KilledWorker, wait

        if self.client is None:
            self.connect()
        client = self.client
        pending = {}
        for task in tasks:
            fut = self._submit(task)
            pending[fut.key] = (fut, task)
        watch = _Watch()
        ours_cancelled: set[str] = set()
        no_workers_since: float | None = None
        try:
            while pending:
                try:
                    done, _ = wait([f for f, _ in pending.values()], timeout=POLL_S, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = ()
                except Exception:  # noqa: BLE001 - e.g. FuturesCancelledError when the scheduler is lost
                    done = [f for f, _ in pending.values() if f.done()]
                if client.status not in ("running", "connecting"):
                    raise InfrastructureError(f"{self.where}: lost the Dask scheduler ({client.status})")
                for fut in done:
                    task = pending.pop(fut.key)[1]
                    watch.finished(fut.key, time.monotonic())
                    if fut.status == "finished":
                        yield task, self._fetch(fut.result)
                    elif fut.status == "cancelled" and fut.key not in ours_cancelled:
                        raise InfrastructureError(f"{self.where}: lost the Dask scheduler (tasks cancelled)")
                    elif fut.status == "error":
                        err = self._fetch(fut.exception)
                        if isinstance(err, EnvironmentMismatch):
                            raise InfrastructureError(f"Dask worker: {err}")
                        if isinstance(err, ImportError):
                            raise InfrastructureError(
                                f"a Dask worker cannot import slamobs ({failure_text(err)}); install it on every worker"
                            )
                        if isinstance(err, KilledWorker):
                            if (row := self._killed(task)) is None:
                                fut = self._submit(task)
                                pending[fut.key] = (fut, task)
                            else:
                                yield task, row
                        else:
                            yield task, failed_row(task, failure_text(err, task.log))
                now = time.monotonic()
                if self._workers() == 0:
                    no_workers_since = no_workers_since or now
                    if now - no_workers_since > self.wait_workers:
                        raise InfrastructureError(
                            f"{self.where}: no Dask workers for {self.wait_workers:g} s (--wait-workers)"
                        )
                else:
                    no_workers_since = None
                if self.timeout:
                    yield from self._timeouts(pending, watch, ours_cancelled, now)
        finally:
            for fut, _ in pending.values():
                fut.cancel()

    def _submit(self, task: Task):
        from distributed.client import ClosedClientError

        try:
            return self.client.submit(
                self.run,
                replace(task, starts_limit=self.allowed + 1),
                pure=False,
                retries=0,
                key=f"slamobs-{task.run_id}-{time.time_ns():x}",
            )
        except (ClosedClientError, OSError) as err:  # a tune's next round: the client gave the scheduler up
            raise self._lost(err) from None

    def _killed(self, task: Task) -> dict | None:
        """The row of a log Dask gave up on (``KilledWorker``: workers died ``allowed-failures`` + 1 times while it
        held the log), or None to submit it again: Dask counts a death against the logs queued on the worker too,
        and one queued behind a log that killed its workers failed with it (kill7: 2 of 6 logs failed after one
        kill -9 at allowed-failures 0). It fails once workers began it that often (:data:`executor.STARTS`; the
        task itself refuses one more start); one that never got that far is submitted again, as a new key, at
        most ``allowed-failures`` + 1 times, then fails as the machine's failure (the next batch runs it again)."""
        if not task.staged or starts(task) > self.allowed:  # a tune's trial counts no starts: as Dask says
            return failed_row(task, f"{task.log}: {DIED}")
        again = self.requeued[task.run_id] = self.requeued.get(task.run_id, 0) + 1
        if again <= self.allowed + 1:
            return None
        return retry_row(
            task,
            f"{task.log}: Dask workers died {again * (self.allowed + 1)} times while they held this log, before "
            f"it could run (it began {plural(starts(task), 'time')})",
            "machine",
        )

    def _restart(self, worker: str, back: list[str]) -> None:
        try:
            self.client.restart_workers([worker], timeout=30, raise_for_error=False)
        except Exception:  # noqa: BLE001 - a worker without nanny cannot be restarted; it cannot commit either
            pass
        back.append(worker)

    def _timeouts(self, pending, watch: _Watch, ours_cancelled, now) -> Iterator[tuple[Task, dict]]:
        """Fail the logs that have run longer than ``timeout`` and restart their workers; restart a worker that
        has held tasks for ``timeout`` without taking or finishing one (its tasks go to other workers)."""
        try:
            processing = self.client.processing()
        except Exception:  # noqa: BLE001
            return
        while watch.back:  # a worker back at the same address starts afresh
            worker = watch.back.pop()
            watch.restarted.discard(worker)
            for key in [k for k, (w, _) in watch.handed.items() if w == worker]:
                del watch.handed[key]
                watch.taken.pop(key, None)
        where = {k: w for w, keys in processing.items() for k in keys if k in pending}
        for key in [k for k, (w, _) in watch.handed.items() if where.get(k) != w]:  # moved, or back in the queue
            del watch.handed[key]
            watch.taken.pop(key, None)
        for key, worker in where.items():
            watch.handed.setdefault(key, (worker, now))
            if key not in watch.taken and Path(pending[key][1].staged).exists():
                watch.taken[key] = watch.alive[worker] = now
        silent = set()
        for key, (worker, since) in list(watch.handed.items()):
            if worker in watch.restarted:
                continue
            if key in watch.taken:
                if now - watch.taken[key] <= self.timeout:
                    continue
                fut, task = pending.pop(key)
                watch.finished(key, now)
                ours_cancelled.add(key)
                fut.cancel()
                silent.add(worker)
                yield (
                    task,
                    failed_row(
                        task,
                        f"{task.log}: timed out after {self.timeout:g} s (Dask worker {worker} "
                        "restarted; raise --timeout for longer logs)",
                    ),
                )
            elif now - max(since, watch.alive.get(worker, since)) > max(self.timeout, STARTUP_S):
                silent.add(worker)  # a new worker's imports may take a while: as long as a local one's
        for worker in silent:
            watch.restarted.add(worker)
            threading.Thread(target=self._restart, args=(worker, watch.back), daemon=True).start()  # the batch goes on
