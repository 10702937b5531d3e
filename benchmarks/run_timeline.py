"""Where the wall time of one ``slamobs run`` goes, stage by stage, and how busy the cores are in each (issue 27).

    .venv/bin/python benchmarks/run_timeline.py LOG [-o OUT] [--repeat 2] [--figure-helper] [--observer NAME]

The run is ``slamobs run LOG -o OUT --force -q`` in this process, with a sampler thread that reads every 10 ms
the CPU time of each thread of the process (``/proc/self/task``) and of its descendant processes (the figure
helper and the children it forks). Each interval's CPU goes to the stage the main thread is in then: ``start``
(the run's imports and checks before the read; the first run imports the pipeline, later runs in this process
find it imported), ``read``, ``align``, ``observer`` (the estimator's stretches, written on a thread beside it),
``report`` (the error report and the figures), ``end`` (run.json, the rename, stopping the helpers). Per stage
the table gives the wall seconds, the CPU seconds of the main thread, of the other threads (by Python thread
name; threads Python did not start by their kernel name) and of the child processes, and the idle
core-seconds: the cores times the wall less all of that CPU. Idle core-seconds in a stage are what moving work
into it from another stage could use; a stage without them is bound by its CPU. ``main alone s``: the wall seconds
of the stage in which the main thread used at least half a core and every other lane together less than a tenth
of one (sample by sample): the serial part, where a second core sits idle while the main thread works. On a
shared machine idle core-seconds include what other processes took (the load average and the speed of a plain
loop are printed before and after). The sampler's own CPU (~1-2 %) is left out.

``--chart SECONDS`` also draws each run as a chart: one row per lane (thread or child process), one column per
``SECONDS`` of wall time, each cell the share of a core the lane used then (``1``-``9``: 10-90 %, ``#``: a whole
core, blank: none), under a row of the main thread's stage letters: where a core sits idle and what runs beside.

``--figure-helper`` starts the figure helper process as ``slamobs run`` does when a core is free, even if none
is free now (``free_cores``: on a shared VM there often is none, and the figures are then drawn at the end of
the report in this process).
"""

from __future__ import annotations

import argparse
import functools
import importlib.abc
import importlib.util
import os
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from end_to_end import load  # noqa: E402

STAGES = ("start", "read", "align", "observer", "report", "end")
TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def _cpu_of(stat: str) -> float:
    """CPU seconds (user + system) from a ``/proc/.../stat`` line."""
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read()
    except OSError:  # the thread or process ended
        return None


def _comm(pid: int, tid: str) -> str:
    """A thread Python did not start (pyarrow's pools, for one): its name in the kernel."""
    return "native " + (_read(f"/proc/{pid}/task/{tid}/comm") or "?").strip()


def _descendants(pid: int) -> list[int]:
    """The process's children, their children, and so on (the figure helper forks one child per batch)."""
    kids = [int(k) for k in (_read(f"/proc/{pid}/task/{pid}/children") or "").split()]
    return kids + [d for k in kids for d in _descendants(k)]


class Sampler(threading.Thread):
    """Every ``period`` seconds: CPU seconds used since the last sample by each thread (by name) and by the child
    processes, credited to the stage in :attr:`stage`."""

    def __init__(self, period: float = 0.01) -> None:
        super().__init__(name="timeline-sampler", daemon=True)
        self.period = period
        self.stage = "start"
        self.cpu: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
        self.last: dict[str, float] = {}
        self.names: dict[str, str] = {}
        self.stopped = threading.Event()
        self.pid = os.getpid()
        #: (time, stage, CPU seconds used since the last sample by each key) of every sample, for ``--chart``
        self.series: list[tuple[float, str, dict[str, float]]] = []
        #: the largest resident set of this process (MB) seen in each stage (the figure helper's is its own)
        self.rss: dict[str, float] = defaultdict(float)

    def snapshot(self) -> dict[str, float]:
        """CPU seconds so far of each thread (``tid``) and each descendant process (``pid:N``); names noted."""
        names = {t.native_id: t.name for t in threading.enumerate()}
        main = threading.main_thread().native_id
        out: dict[str, float] = {}
        for tid in os.listdir(f"/proc/{self.pid}/task"):
            if int(tid) == self.native_id:
                continue
            text = _read(f"/proc/{self.pid}/task/{tid}/stat")
            if text is not None:
                out[tid] = _cpu_of(text)
                name = "main" if int(tid) == main else names.get(int(tid))
                if name is not None:  # a Python thread (its name); else the kernel's, unless Python's is known
                    self.names[tid] = name.removeprefix("slamobs-")
                else:
                    self.names.setdefault(tid, _comm(self.pid, tid))
        for pid in _descendants(self.pid):  # each process's own CPU: a reaped child's is not counted twice
            text = _read(f"/proc/{pid}/stat")
            if text is not None:
                out[f"pid:{pid}"] = _cpu_of(text)
                self.names[f"pid:{pid}"] = "children"
        return out

    def sample(self) -> None:
        now = self.snapshot()
        step = {}
        for key, value in now.items():
            used = value - self.last.get(key, 0.0)
            if used > 0:
                self.cpu[self.stage][key] += used
                step[key] = used
        self.series.append((time.perf_counter(), self.stage, step))
        statm = _read(f"/proc/{self.pid}/statm")
        if statm is not None:
            rss = int(statm.split()[1]) * PAGE / 2**20
            self.rss[self.stage] = max(self.rss[self.stage], rss)
        self.last.update(now)

    def alone(self) -> dict[str, float]:
        """Wall seconds per stage in which the main thread worked (>= half a core) and nothing else did (all other
        lanes together < a tenth of a core), from consecutive samples."""
        out: dict[str, float] = defaultdict(float)
        main = {k for k, n in self.names.items() if n == "main"}
        for (t0, _, _), (t1, stage, step) in zip(self.series, self.series[1:]):
            dt = t1 - t0
            mine = sum(v for k, v in step.items() if k in main)
            others = sum(v for k, v in step.items() if k not in main)
            if dt > 0 and mine >= 0.5 * dt and others < 0.1 * dt:
                out[stage] += dt
        return dict(out)

    def by_name(self) -> dict[str, dict[str, float]]:
        """CPU seconds per stage and thread name (threads of one name added up)."""
        out: dict[str, dict[str, float]] = {}
        for stage, per in self.cpu.items():
            named: dict[str, float] = defaultdict(float)
            for key, used in per.items():
                named[self.names.get(key, "?")] += used
            out[stage] = dict(named)
        return out

    def run(self) -> None:
        while not self.stopped.wait(self.period):
            self.sample()


def _staged(sampler: Sampler, walls: dict[str, float], stage: str, func):
    """``func`` that marks ``stage`` while it runs (and the stage after it once it returns)."""

    @functools.wraps(func)
    def wrapped(*args, **kwargs):
        sampler.sample()
        sampler.stage, start = stage, time.perf_counter()
        try:
            return func(*args, **kwargs)
        finally:
            walls[stage] += time.perf_counter() - start
            sampler.sample()
            sampler.stage = {"read": "align", "align": "observer", "observer": "report", "report": "end"}[stage]

    return wrapped


class _Hooks(importlib.abc.MetaPathFinder):
    """Wraps the stage functions as their modules are first imported (by the run itself: its imports stay in
    the ``start`` stage, as in ``slamobs run``), or at once where they were imported already (a second run)."""

    def __init__(self, wrap: dict[str, list[str]], sampler: Sampler, walls: dict[str, float]) -> None:
        self.wrap, self.sampler, self.walls = wrap, sampler, walls

    def patch(self, module) -> None:
        for attr, stage in self.wrap.get(module.__name__, []):
            setattr(module, attr, _staged(self.sampler, self.walls, stage, getattr(module, attr)))

    def find_spec(self, name, path=None, target=None):
        if name not in self.wrap:
            return None
        sys.meta_path.remove(self)
        try:
            spec = importlib.util.find_spec(name)
        finally:
            sys.meta_path.insert(0, self)
        loader, hooks = spec.loader, self

        class Loader(importlib.abc.Loader):
            def create_module(self, spec):
                return loader.create_module(spec)

            def exec_module(self, module):
                loader.exec_module(module)
                hooks.patch(module)

        spec.loader = Loader()
        return spec


STAGE_FUNCTIONS = {
    "slamobs.pipeline.readers": [("read_log", "read")],
    "slamobs.pipeline.run": [("align", "align"), ("estimate", "observer"), ("evaluate_run", "report")],
}


def chart(sampler: Sampler, bucket: float) -> None:
    """The run's lanes over time, ``bucket`` seconds a column (see the module's docstring)."""
    if not sampler.series:
        return
    t0 = sampler.series[0][0]
    used: dict[str, dict[int, float]] = defaultdict(lambda: defaultdict(float))
    stages: dict[int, str] = {}
    for t, stage, step in sampler.series:
        col = int((t - t0) / bucket)
        stages.setdefault(col, stage)
        for key, cpu in step.items():
            used[sampler.names.get(key, "?")][col] += cpu
    cols = max(stages) + 1
    print(f"# each column {bucket:g} s; stages: " + ", ".join(f"{s[0]} {s}" for s in STAGES))
    print(f"{'stage':<16} " + "".join(stages.get(c, " ")[0] for c in range(cols)))
    for name in sorted(used, key=lambda n: (n != "main", min(used[n]))):
        total = sum(used[name].values())
        if total < 0.02:
            continue
        cells = (used[name].get(c, 0.0) / bucket for c in range(cols))
        row = "".join(" " if x < 0.05 else "#" if x >= 0.95 else str(max(1, int(x * 10))) for x in cells)
        print(f"{name[:16]:<16} {row} {total:.2f}")


def one_run(
    log: Path, out: Path, helper: bool, bucket: float | None = None, extra: tuple[str, ...] = ()
) -> tuple[dict[str, float], dict[str, dict[str, float]], float, dict[str, float]]:
    """Stage walls, CPU per stage and thread, the run's wall and the peak RSS per stage (and its chart, ``bucket``
    seconds a column)."""
    from slamobs.cli import main as cli
    from slamobs.pipeline.evaluation import plot_worker

    sampler = Sampler()
    walls: dict[str, float] = defaultdict(float)
    hooks = _Hooks(STAGE_FUNCTIONS, sampler, walls)
    saved = {}
    for name, attrs in STAGE_FUNCTIONS.items():
        if name in sys.modules:  # imported by an earlier run: wrapped now, put back afterwards
            saved[name] = {a: getattr(sys.modules[name], a) for a, _ in attrs}
            hooks.patch(sys.modules[name])
    sys.meta_path.insert(0, hooks)
    free_cores = plot_worker.free_cores
    if helper:
        plot_worker.free_cores = lambda *_: 1
    sampler.last = sampler.snapshot()  # what was used before the run is not the run's
    start = time.perf_counter()
    sampler.start()
    try:
        cli.main(["run", str(log), "-o", str(out), "--force", "-q", *extra], standalone_mode=False)
    finally:
        wall = time.perf_counter() - start
        sampler.stopped.set()
        sampler.join()
        sampler.sample()
        sys.meta_path.remove(hooks)
        plot_worker.free_cores = free_cores
        for name, attrs in STAGE_FUNCTIONS.items():
            for attr, _ in attrs:  # the originals, for the next run to wrap
                original = saved.get(name, {}).get(attr)
                module = sys.modules.get(name)
                if module is not None:
                    setattr(module, attr, original or getattr(module, attr).__wrapped__)
    walls["start"] = wall - sum(walls.values())  # the rest: before the read and after the report
    if bucket:
        chart(sampler, bucket)
    return dict(walls), sampler.by_name(), wall, dict(sampler.rss), sampler.alone()


def show(
    walls: dict[str, float], cpu: dict[str, dict[str, float]], wall: float, cores: int, rss: dict, alone: dict
) -> None:
    threads = sorted({k for per in cpu.values() for k in per if k != "main"})
    print(
        f"{'stage':<9} {'wall s':>7} {'main':>6} "
        + " ".join(f"{k[:14]:>14}" for k in threads)
        + f" {'idle core-s':>11} {'main alone s':>12} {'peak RSS MB':>11}"
    )
    total = defaultdict(float)
    for stage in STAGES:
        per = cpu.get(stage, {})
        w = walls.get(stage, 0.0) if stage not in ("start", "end") else None
        used = sum(per.values())
        cols = " ".join(f"{per.get(k, 0.0):>14.2f}" for k in threads)
        wall_s = f"{w:>7.2f}" if w is not None else f"{'':>7}"
        idle = f"{cores * w - used:>11.2f}" if w is not None else f"{'':>11}"
        lone = f"{alone.get(stage, 0.0):>12.2f}"
        print(f"{stage:<9} {wall_s} {per.get('main', 0.0):>6.2f} {cols} {idle} {lone} {rss.get(stage, 0.0):>11.0f}")
        for k, v in per.items():
            total[k] += v
    cols = " ".join(f"{total.get(k, 0.0):>14.2f}" for k in threads)
    idle, peak = cores * wall - sum(total.values()), max(rss.values(), default=0.0)
    lone = sum(alone.values())
    print(f"{'all':<9} {wall:>7.2f} {total.get('main', 0.0):>6.2f} {cols} {idle:>11.2f} {lone:>12.2f} {peak:>11.0f}")
    print(f"# 'start' and 'end' together took {walls['start']:.2f} s of wall (imports before the read, run.json after)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("-o", "--out", type=Path, default=None, help="run directory (default: a temporary one)")
    ap.add_argument("--repeat", type=int, default=2, help="runs (the kernels are loaded by the first)")
    ap.add_argument("--figure-helper", action="store_true", help="start the figure helper even without a free core")
    ap.add_argument("--chart", type=float, default=None, metavar="SECONDS", help="each run's lanes over time")
    ap.add_argument("--observer", default=None, help="the run's observer (default: the run's default)")
    args = ap.parse_args()
    extra = ("--observer", args.observer) if args.observer else ()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as `slamobs` (cli/main.py)
    import slamobs

    cores = len(os.sched_getaffinity(0))
    print(f"# {args.log}, slamobs from {Path(slamobs.__file__).parent}, {cores} cores; {load()}")
    with tempfile.TemporaryDirectory(prefix="slamobs-timeline-") as tmp:
        out = args.out or Path(tmp) / "run"
        for k in range(max(1, args.repeat)):
            walls, cpu, wall, rss, alone = one_run(args.log, out, args.figure_helper, args.chart, extra)
            print(f"## run {k + 1}: {wall:.2f} s wall")
            show(walls, cpu, wall, cores, rss, alone)
    print(f"# {load()}")


if __name__ == "__main__":
    main()
