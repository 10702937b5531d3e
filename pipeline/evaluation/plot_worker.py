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
(:func:`~slamobs.pipeline.lifetime.bind_to_parent`): a run killed by SIGKILL takes it along at once,
even in the middle of a figure. Each batch is drawn by a child forked from the warm helper and bound to the
helper the same way, so batches are drawn side by side on free cores (:class:`_Batches`).
"""

from __future__ import annotations

import io
import os
import pickle
import subprocess
import sys
import threading
import warnings
from pathlib import Path
from typing import Any

from slamobs.pipeline.cores import cores

#: A figure to draw: the name of a ``plots`` function, the file name it goes to, its keyword arguments.
Job = tuple[str, str, dict[str, Any]]

#: Exit status of a helper (or one of its children) that ran out of memory or threads (it prints nothing): the
#: run fails with one line saying so, instead of a traceback and a report without figures.
OUT_OF_MEMORY = 3


def free_cores(loadavg: str | None = None) -> int:
    """CPUs this process may use that nothing else keeps busy right now: the CPUs of its affinity less this
    process and the other runnable threads (``/proc/loadavg``, or ``loadavg`` as its text), at least 0; where
    that is not known, less the one-minute load average. 0 on one core or on a loaded machine, where a helper
    only adds its own imports (90 s log on 2 cores: 0.8 s slower at load 2.6-5, 0.3-0.8 s faster at load
    1.6-2). Not the load average alone: it still counts runs that have ended in the last minutes (back-to-back
    runs, a benchmark) and left the machine idle."""
    cpus = cores()
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


#: ``0`` never starts the figure helper of ``slamobs run``, ``1`` starts it even without a free core (else: where
#: :func:`free_cores` finds one); a benchmark on a shared machine measures the run as a quiet one would run it.
ENV = "SLAMOBS_FIGURE_HELPER"


def helper_wanted(spare_cores: int) -> bool:
    """Whether ``slamobs run`` draws its figures in a helper process: with a core to spare, unless :data:`ENV` says
    otherwise."""
    choice = os.environ.get(ENV, "")
    if choice in ("0", "1"):
        return choice == "1"
    return spare_cores > 0


class PlotWorkers:
    """Up to ``count`` helper processes, started at once; :meth:`submit` shares the figures out among them."""

    def __init__(self, count: int) -> None:
        self.procs: list[subprocess.Popen] = []
        self.jobs: list[Job] = []
        self.shares: list[list[int]] = [[] for _ in range(count)]
        self._feeds: list[threading.Thread | None] = [None] * count
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "agg"}
        for _ in range(count):
            self.procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", __name__, str(os.getpid())],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    env=env,
                )
            )

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
                try:
                    proc.stdin.close()  # the helper's cue to answer
                except OSError:  # a helper gone before a small batch left the buffer: reported below
                    pass
                data = proc.stdout.read()
                if proc.wait() == OUT_OF_MEMORY:
                    from slamobs.pipeline.errors import resource_error

                    raise resource_error(MemoryError(), out, "drawing the report's figures")
                if proc.returncode < 0 and share:  # killed (the kernel's OOM killer sends SIGKILL): drawn here
                    images.update(zip(share, _drawn_here([self.jobs[k] for k in share]), strict=True))
                    continue
                if proc.returncode != 0 or (share and not data):
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


class LocalFigures:
    """:class:`PlotWorkers`' interface drawn in this process at :meth:`collect`: where no core is free the report
    still hands its figure jobs over as it goes, so that what it computed for them (the segment errors of the
    box plots) is not computed again for the figures, and they come in the same order."""

    def __init__(self) -> None:
        self.jobs: list[Job] = []

    @property
    def submitted(self) -> bool:
        return bool(self.jobs)

    def submit(self, jobs: list[Job]) -> None:
        self.jobs += jobs

    def collect(self, out: Path) -> list[Path]:
        """Draw the submitted figures into ``out``; their paths in the order of the jobs."""
        return draw(self.jobs, lambda name: Path(out) / name)

    def close(self) -> None:
        """Nothing to stop."""


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


def _drawn_here(jobs: list[Job]) -> list[bytes]:
    """The PNG bytes of ``jobs`` drawn in this process (the same bytes a helper returns)."""
    files = draw(jobs, lambda _name: io.BytesIO())
    return [f.getvalue() for f in files]


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
    """The helper: out of memory or threads it ends with :data:`OUT_OF_MEMORY` (and no traceback)."""
    try:
        _serve()
    except Exception as err:
        from slamobs.pipeline.errors import machine_failure

        if machine_failure(err):
            os._exit(OUT_OF_MEMORY)
        raise


def _serve() -> None:
    import signal

    from slamobs.pipeline.lifetime import bind_to_parent

    bind_to_parent(int(sys.argv[1]))
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from slamobs.pipeline.native import start_blas

    start_blas()  # OpenBLAS's start-up under a memory limit: a MemoryError here, not "OpenBLAS error" and exit 1
    from slamobs.pipeline.evaluation.plots import warm_up

    warm_up()
    batches = _Batches()
    while True:  # batches as the run hands them over, each drawn at once
        try:
            jobs = pickle.load(sys.stdin.buffer)
        except EOFError:
            break
        batches.start(jobs)
    images = batches.images()
    if images:  # none: the run needed no figures
        sys.stdout.buffer.write(pickle.dumps(images, protocol=pickle.HIGHEST_PROTOCOL))
    sys.stdout.flush()
    os._exit(0)  # matplotlib's teardown is ~0.1 s the run would wait for; nothing is left to clean up


class _Batches:
    """A helper's batches, each drawn by a child forked from the warm helper (matplotlib already imported, so
    a child costs a few milliseconds), up to one per CPU at once: the figures of a short log are drawn side by
    side instead of one after another (90 s log: 0.6-0.8 s of drawing). A child binds itself to the helper as
    the helper is bound to its run, and leaves its PNG bytes in an unlinked in-memory file (it never waits
    for a reader). Where ``os.fork`` is missing, the helper draws each batch itself."""

    def __init__(self) -> None:
        self.slots = max(1, cores())
        self.children: list[tuple[int, Any]] = []  # (pid, file) per batch, in order
        self.drawn: list[list[bytes]] = []  # batches drawn here (no fork)
        self.status: dict[int, int] = {}  # exit status of reaped children
        self.running: set[int] = set()

    def start(self, jobs: list[Job]) -> None:
        if not hasattr(os, "fork"):
            self.drawn.append(_pngs(jobs))
            return
        while len(self.running) >= self.slots:
            self._reap(*os.wait())
        out, helper = _scratch_file(), os.getpid()
        with warnings.catch_warnings():  # Python >= 3.12 warns of fork() beside threads: the lifeline's
            warnings.simplefilter("ignore", DeprecationWarning)  # watchdog only sleeps, it holds no lock
            pid = os.fork()
        if pid == 0:
            _child(jobs, out, helper)
        self.running.add(pid)
        self.children.append((pid, out))

    def _reap(self, pid: int, status: int) -> None:
        self.running.discard(pid)
        self.status[pid] = os.waitstatus_to_exitcode(status)

    def images(self) -> list[bytes]:
        """The PNG bytes of every batch, in order; exits with status 1 when a child failed (it printed why)."""
        if self.drawn:
            return [png for batch in self.drawn for png in batch]
        images = []
        for pid, out in self.children:
            if pid not in self.status:
                self._reap(*os.waitpid(pid, 0))
            if self.status[pid] != 0:
                sys.stderr.flush()
                os._exit(self.status[pid] if self.status[pid] == OUT_OF_MEMORY else 1)
            out.seek(0)
            images += pickle.load(out)
        return images


def _pngs(jobs: list[Job]) -> list[bytes]:
    import io

    return [buffer.getvalue() for buffer in draw(jobs, lambda _name: io.BytesIO())]


def _scratch_file():
    """An unlinked file for one child's PNGs: in memory where Linux offers it."""
    if hasattr(os, "memfd_create"):
        return open(os.memfd_create("slamobs-figures"), "w+b")
    import tempfile

    return tempfile.TemporaryFile()


def _child(jobs: list[Job], out, helper: int) -> None:
    """A forked child of ``helper``: draw ``jobs`` into ``out`` and end (never returns)."""
    status = 1
    try:
        from slamobs.pipeline.lifetime import bind_to_parent

        bind_to_parent(helper)
        pickle.dump(_pngs(jobs), out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()
        status = 0
    except BaseException as err:  # noqa: BLE001 - a child must never return into the helper's loop
        from slamobs.pipeline.errors import machine_failure

        if machine_failure(err):
            status = OUT_OF_MEMORY
        else:
            import traceback

            traceback.print_exc()
            sys.stderr.flush()
    finally:
        os._exit(status)


if __name__ == "__main__":
    _main()
