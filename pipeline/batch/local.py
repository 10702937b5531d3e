"""Local worker processes: ``jobs`` spawned processes, one log each at a time, none outliving the batch.

Each worker is bound to the batch process (:mod:`slamobs.pipeline.lifetime`: parent-death signal and watchdog), ignores
SIGINT (a Ctrl-C on the terminal reaches the whole process group; the batch decides what it means) and
talks to the batch over its own pipe, so the batch knows which log each worker runs. That makes the
three ways a run can go wrong exact and cheap:

- a log that hangs (a run longer than ``timeout``) has its worker killed and is reported as timed out;
- a worker that dies (crash, OOM kill, someone's ``kill``) fails only its own log: the log is tried once
  more in a fresh process, then reported with the signal that ended the worker; workers that die before
  they take a log (a broken installation) stop the batch as an infrastructure problem;
- on any exit of the batch (end, Ctrl-C, SIGTERM, an error) every worker is killed before control returns.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from multiprocessing.connection import wait

from slamobs.pipeline.batch.executor import InfrastructureError, Task, failed_row, run_task
from slamobs.pipeline.batch.lifeline import worker_main
from slamobs.pipeline.lifetime import BindOnArrival

#: How many times a log is run again after its worker process died under it.
RETRIES_AFTER_DEATH = 1
#: Seconds a new worker may take to start (imports) before its first log's timeout starts counting.
STARTUP_S = 300.0
#: Workers dying before they take a log, in a row, that make the batch give up (exit 3): e.g. a broken install.
STARTUP_FAILURES = 3


def _ended(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            return f"killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"killed by signal {-exitcode}"
    return f"exit status {exitcode}"


@dataclass
class _Slot:
    proc: multiprocessing.Process
    conn: object
    task: Task | None = None
    deaths: int = 0
    started: float = 0.0  # when the worker took the task (it says so), else when it was sent
    running: bool = False


class LocalPool:
    """Run tasks on ``jobs`` local worker processes; see the module doc.

    ``run`` is the worker function (a picklable top-level function; tests pass ones that crash or hang);
    ``timeout`` is seconds per log (None: no limit). With ``keep_workers`` idle workers outlive a finished
    :meth:`results` for the next call (a tune's rounds reuse the logs each worker holds) until :meth:`close`;
    a worker still running a task when ``results`` ends early is killed either way.
    """

    def __init__(
        self,
        jobs: int,
        run: Callable[[Task], dict] = run_task,
        timeout: float | None = None,
        keep_workers: bool = False,
    ) -> None:
        self.jobs = max(1, jobs)
        self.run = run
        self.timeout = timeout
        self.keep_workers = keep_workers
        self.ctx = multiprocessing.get_context("spawn")  # numba and threads do not survive fork well
        self.slots: list[_Slot] = []

    def _start(self) -> _Slot:
        # started from the batch's main thread: the parent-death signal is tied to the thread that forks
        ours, theirs = self.ctx.Pipe(duplex=True)
        proc = self.ctx.Process(
            target=worker_main,
            args=(BindOnArrival(os.getpid()), theirs, self.run),
            daemon=True,
            name="slamobs-batch-worker",
        )
        # an ignored SIGINT survives exec: the worker ignores Ctrl-C from its first instruction (a terminal
        # sends it to the whole process group; the batch decides what it means and stops its workers)
        main = threading.current_thread() is threading.main_thread()
        old = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            proc.start()
        finally:
            if main:
                signal.signal(signal.SIGINT, old)
        theirs.close()
        slot = _Slot(proc, ours)
        self.slots.append(slot)
        return slot

    def _discard(self, slot: _Slot) -> None:
        if slot.proc.is_alive():
            slot.proc.kill()
        slot.proc.join(5)
        slot.conn.close()
        self.slots.remove(slot)

    def pids(self) -> list[int]:
        return [s.proc.pid for s in self.slots if s.proc.pid]

    def results(self, tasks: Sequence[Task]) -> Iterator[tuple[Task, dict]]:
        """(task, row) in completion order; every worker is gone when this generator ends or is closed."""
        queue: deque[tuple[Task, int]] = deque((t, 0) for t in tasks)
        failed_starts = 0
        try:
            while queue or any(s.task for s in self.slots):
                self._dispatch(queue)
                busy = [s for s in self.slots if s.task is not None]
                ready = set(wait([s.conn for s in busy] + [s.proc.sentinel for s in busy], timeout=self._poll(busy)))
                now = time.monotonic()
                for slot in busy:
                    task = slot.task
                    if slot.conn in ready or slot.proc.sentinel in ready:
                        got = self._receive(slot)
                        if slot.running:
                            failed_starts = 0
                        if got is not None:
                            slot.task = None
                            yield task, got
                            continue
                        if slot.proc.is_alive():  # it only said it started
                            continue
                        slot.proc.join(1)
                        ended = _ended(slot.proc.exitcode)
                        self._discard(slot)
                        if not slot.running:  # died before taking the log: not the log's doing
                            failed_starts += 1
                            if failed_starts >= STARTUP_FAILURES:
                                raise InfrastructureError(
                                    f"local worker processes die while starting ({ended}, "
                                    f"{failed_starts} times in a row)"
                                )
                            queue.appendleft((task, slot.deaths))
                        elif slot.deaths < RETRIES_AFTER_DEATH:
                            queue.appendleft((task, slot.deaths + 1))
                        else:
                            yield (
                                task,
                                failed_row(
                                    task,
                                    f"{task.log}: worker process died twice while running this "
                                    f"log ({ended}): crash or out of memory",
                                ),
                            )
                    elif self.timeout and now - slot.started > (
                        self.timeout if slot.running else max(self.timeout, STARTUP_S)
                    ):
                        self._discard(slot)
                        yield (
                            task,
                            failed_row(
                                task,
                                f"{task.log}: timed out after {self.timeout:g} s (worker killed; "
                                "raise --timeout for longer logs)",
                            ),
                        )
            if not self.keep_workers:
                self.close(gently=True)
        finally:
            for slot in list(self.slots):
                if not self.keep_workers or slot.task is not None or not slot.proc.is_alive():
                    self._discard(slot)

    def close(self, gently: bool = False) -> None:
        """End every worker (``gently``: idle ones are told to exit and given two seconds first)."""
        if gently:
            for slot in list(self.slots):
                try:
                    slot.conn.send(None)
                except OSError:
                    pass
            for slot in list(self.slots):
                slot.proc.join(2)
        for slot in list(self.slots):
            self._discard(slot)

    def _poll(self, busy: list[_Slot]) -> float:
        if not self.timeout or not busy:
            return 1.0
        left = min(s.started + (self.timeout if s.running else max(self.timeout, STARTUP_S)) for s in busy)
        left -= time.monotonic()
        return min(1.0, max(0.01, left))

    def _dispatch(self, queue: deque[tuple[Task, int]]) -> None:
        while queue:
            idle = next((s for s in self.slots if s.task is None), None)
            if idle is not None and not idle.proc.is_alive():
                self._discard(idle)
                continue
            if idle is None:
                if len(self.slots) >= self.jobs:
                    return
                idle = self._start()
            task, deaths = queue.popleft()
            try:
                idle.conn.send(task)
            except OSError:  # the idle worker died in between: a new one takes the task
                queue.appendleft((task, deaths))
                self._discard(idle)
                continue
            idle.task, idle.deaths, idle.started, idle.running = task, deaths, time.monotonic(), False

    def _receive(self, slot: _Slot) -> dict | None:
        """The row the worker sent, or None (nothing yet, or the worker is gone)."""
        try:
            while slot.conn.poll():
                kind, value = slot.conn.recv()
                if kind == "started":
                    slot.started, slot.running = time.monotonic(), True
                elif kind == "mismatch":
                    raise InfrastructureError(f"local worker: {value}")
                else:
                    return value
        except (EOFError, OSError):
            pass
        return None
