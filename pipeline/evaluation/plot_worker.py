"""The report's figures drawn in helper processes that import matplotlib while the run reads and computes.

On a short log matplotlib's import (0.5-1 s) and the four figures (0.3-0.5 s each) are most of the run; they
need no result but the report's, so a run started with :class:`PlotWorkers` has them import matplotlib on a
free core while it reads, runs the observer and evaluates. Each figure is handed over as soon as the report
has what it draws (the bias figure before the trajectory is even associated), and the PNG bytes come back
at the end (written by the run itself: a helper never touches the run directory). The PNGs are
byte-identical to figures drawn in the run's own process: same code, same arguments, same interpreter.

A helper reads batches of jobs from stdin until it closes, then writes all its PNGs to stdout (so it never
waits for the run to read), ignores SIGINT (the run decides what Ctrl-C means), is killed by
:meth:`PlotWorkers.close` if it still runs, and is bound to its run as a batch worker is
(:func:`~slamobs.pipeline.batch.lifeline.bind_to_parent`): a run killed by SIGKILL takes it along at once,
even in the middle of a figure.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

#: A figure to draw: the name of a ``plots`` function, the file name it goes to, its keyword arguments.
Job = tuple[str, str, dict[str, Any]]


def free_cores(loadavg: str | None = None) -> int:
    """CPUs this process may use that nothing else keeps busy right now: the CPUs of its affinity less this
    process and the other runnable threads (``/proc/loadavg``, or ``loadavg`` as its text), at least 0; where
    that is not known, less the one-minute load average. 0 on one core or on a loaded machine, where a helper
    only adds its own imports (90 s log on 2 cores: 0.8 s slower at load 2.6-5, 0.3-0.8 s faster at load
    1.6-2). Not the load average alone: it still counts runs that have ended in the last minutes (back-to-back
    runs, a benchmark) and left the machine idle."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    try:
        text = loadavg if loadavg is not None else Path("/proc/loadavg").read_text()
        others = int(text.split()[3].split("/")[0]) - 1  # runnable now, this process (its reading thread) one
        return max(0, cpus - 1 - max(others, 0))
    except (OSError, IndexError, ValueError):
        pass
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = float(cpus)
    return max(0, round(cpus - max(load, 1.0)))


class PlotWorkers:
    """Up to ``count`` helper processes, started at once; :meth:`submit` shares the figures out among them."""

    def __init__(self, count: int) -> None:
        self.procs: list[subprocess.Popen] = []
        self.jobs: list[Job] = []
        self.shares: list[list[int]] = [[] for _ in range(count)]
        self._feeds: list[threading.Thread | None] = [None] * count
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "agg"}
        for _ in range(count):
            self.procs.append(subprocess.Popen([sys.executable, "-m", __name__, str(os.getpid())], stdin=subprocess.PIPE,
                                               stdout=subprocess.PIPE, env=env))

    @property
    def submitted(self) -> bool:
        return bool(self.jobs)

    def submit(self, jobs: list[Job]) -> None:
        """Hand ``jobs`` out (in turn, after those submitted before) and return at once: a feeder thread writes
        them to the helper (a long log's arrays fill the pipe while the helper still draws earlier figures)."""
        first = len(self.jobs)
        self.jobs += jobs
        for i, proc in enumerate(self.procs):
            mine = [k for k in range(first, len(self.jobs)) if k % len(self.procs) == i]
            if not mine:
                continue
            self.shares[i] += mine
            data = pickle.dumps([self.jobs[k] for k in mine], protocol=pickle.HIGHEST_PROTOCOL)
            feed = threading.Thread(target=_feed, args=(proc, data, self._feeds[i]), daemon=True)
            feed.start()
            self._feeds[i] = feed

    def collect(self, out: Path) -> list[Path]:
        """Wait for the submitted figures and write each PNG into ``out``; their paths in the order of the jobs.
        The helpers are done afterwards."""
        procs, self.procs = self.procs, []
        try:
            images: dict[int, bytes] = {}
            for proc, share, feed in zip(procs, self.shares, self._feeds):
                if feed is not None:
                    feed.join()
                proc.stdin.close()  # the helper's cue to answer
                data = proc.stdout.read()
                if proc.wait() != 0 or (share and not data):
                    raise RuntimeError(f"the figure helper process ended with status {proc.returncode}")
                if share:
                    images.update(zip(share, pickle.loads(data), strict=True))
        finally:
            _stop(procs)
        paths = []
        for k, (_, name, _) in enumerate(self.jobs):
            path = Path(out) / name
            path.write_bytes(images[k])
            paths.append(path)
        return paths

    def close(self) -> None:
        """Stop helpers that were not used (no truth, or the run failed)."""
        procs, self.procs = self.procs, []
        _stop(procs)

    def __enter__(self) -> PlotWorkers:
        return self

    def __exit__(self, *_exc) -> None:
        self.close()


def _feed(proc: subprocess.Popen, data: bytes, before: threading.Thread | None) -> None:
    """Write one batch of jobs to a helper, after the batch before it; a helper that was stopped (the run
    failed) is no error here: :meth:`PlotWorkers.collect` reports a helper that did not answer."""
    if before is not None:
        before.join()
    try:
        proc.stdin.write(data)
        proc.stdin.flush()
    except (BrokenPipeError, ValueError, OSError):  # killed helper, or its pipe closed by close()
        pass


def _stop(procs: list[subprocess.Popen]) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        for stream in (proc.stdin, proc.stdout):
            if stream is not None and not stream.closed:
                try:
                    stream.close()
                except OSError:  # a pipe whose reader was killed
                    pass


def draw(jobs: list[Job], target=None) -> list[Any]:
    """Draw ``jobs`` in this process: each into ``target(name)`` (a path or a file object); the targets."""
    from slamobs.pipeline.evaluation import plots

    done = []
    for func, name, kwargs in jobs:
        dest = target(name)
        getattr(plots, func)(dest, **kwargs)
        done.append(dest)
    return done


def _main() -> None:
    import io
    import signal

    from slamobs.pipeline.batch.lifeline import bind_to_parent

    bind_to_parent(int(sys.argv[1]))
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from slamobs.pipeline.evaluation.plots import warm_up

    warm_up()
    buffers = []
    while True:  # batches as the run hands them over, each drawn at once
        try:
            jobs = pickle.load(sys.stdin.buffer)
        except EOFError:
            break
        buffers += draw(jobs, lambda _name: io.BytesIO())
    if buffers:  # none: the run needed no figures
        sys.stdout.buffer.write(pickle.dumps([b.getvalue() for b in buffers], protocol=pickle.HIGHEST_PROTOCOL))
        sys.stdout.buffer.flush()


if __name__ == "__main__":
    _main()
