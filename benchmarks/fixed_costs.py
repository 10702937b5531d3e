"""Where a short run's fixed time goes: CPU seconds of each import, each cached kernel loaded, each stage.

    .venv/bin/python benchmarks/fixed_costs.py [--seconds 90] [--cache DIR]

One ``slamobs run`` of a generated ``--seconds`` log (``end_to_end.py``'s scenario and cache), in this process
(``cli.main`` without its exit at once), after the imports of a run done one group at a time in the order a run
meets them. Each row is the CPU seconds of this process's thread doing it (``time.thread_time``: a reader
thread's or the figure helper's work is not in the rows); the kernels are numba's cache loads of the run, each
with its own CPU time (the first also starts numba's runtime). Then the figure helper on its own: a process
that starts, imports matplotlib and draws its warm-up figure, its CPU time (``RUSAGE_CHILDREN``). Run it twice:
the first run after a change to the sources compiles the kernels. Bytecode: run with ``PYTHONDONTWRITEBYTECODE``
unset (see the caution in docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import importlib
import json
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from end_to_end import make_log  # noqa: E402

#: Import groups, in the order a ``slamobs run`` imports them (each row: the modules a group adds).
IMPORTS = (
    ("click, slamobs.cli.main", ("slamobs.cli.main",)),
    ("numpy", ("numpy",)),
    ("numba", ("numba",)),
    ("kernel_cache (BLAS start, cache hooks)", ("slamobs.pipeline.kernel_cache",)),
    ("readers (rosbags, zstandard, lz4; reader kernels)", ("slamobs.pipeline.readers",)),
    ("config (yaml, alignment, lie, noise)", ("slamobs.pipeline.config",)),
    ("run (observers, estimators)", ("slamobs.pipeline.run",)),
    ("writers (pyarrow.parquet)", ("slamobs.pipeline.writers",)),
    ("report modules", ("slamobs.pipeline.evaluation.report", "slamobs.pipeline.evaluation.sections")),
)


def timed_imports() -> list[tuple[str, float]]:
    rows = []
    for name, modules in IMPORTS:
        t = time.thread_time()
        for module in modules:
            importlib.import_module(module)
        rows.append((name, time.thread_time() - t))
    return rows


def count_loads() -> list[tuple[str, float]]:
    """Record each cache load of a kernel (name, CPU seconds of the loading thread) from now on."""
    from numba.core import caching

    loads: list[tuple[str, float]] = []
    load = caching.Cache.load_overload

    def timed(self, sig, target_context):
        t = time.thread_time()
        try:
            return load(self, sig, target_context)
        finally:
            loads.append((self._py_func.__qualname__, time.thread_time() - t))

    caching.Cache.load_overload = timed
    return loads


def count_local_figures() -> list[float]:
    """Record the CPU seconds of figures drawn in this process (no core free for the helper) from now on."""
    from slamobs.pipeline.evaluation import plot_worker

    spent: list[float] = []
    draw = plot_worker.draw

    def timed(jobs, target=None):
        t = time.thread_time()
        try:
            return draw(jobs, target)
        finally:
            spent.append(time.thread_time() - t)

    plot_worker.draw = timed
    return spent


def helper_cpu() -> float:
    """CPU seconds of a figure helper that starts, imports matplotlib, draws its warm-up figure and ends."""
    from slamobs.pipeline.evaluation.plot_worker import PlotWorkers

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    workers = PlotWorkers(1)
    proc = workers.procs[0]
    proc.stdin.close()
    proc.wait()
    workers.close()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=90.0, help="length of the generated log")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-bench")
    args = ap.parse_args()
    log = make_log(args.cache, args.seconds, "mcap")
    start = time.thread_time()
    imports = timed_imports()
    loads = count_loads()
    local = count_local_figures()
    from slamobs.cli.main import main as cli

    out = Path(tempfile.mkdtemp(prefix="slamobs-fixed-")) / "run"
    t = time.thread_time()
    try:
        cli(["run", str(log), "-o", str(out), "-q"], standalone_mode=False)
        stages = json.loads((out / "run.json").read_text())["timings_s"]
    finally:
        shutil.rmtree(out.parent, ignore_errors=True)
    run_cpu = time.thread_time() - t
    print(f"# fixed costs of `slamobs run {log.name}` (CPU seconds of the main thread; {sys.version.split()[0]})")
    print(f"{'imports, before the run':58s} {sum(v for _, v in imports):6.3f}")
    for name, v in imports:
        print(f"  {name:56s} {v:6.3f}")
    print(f"{'the run (stages, kernel loads included; threads not)':58s} {run_cpu:6.3f}")
    print(f"  {f'{len(loads)} kernels loaded from the cache':56s} {sum(v for _, v in loads):6.3f}")
    for name, v in loads:
        print(f"    {name:54s} {v:6.3f}")
    if local:
        print(f"  {'figures drawn here (no core free for the helper)':56s} {sum(local):6.3f}")
    print("  stages (wall s, from run.json): " + ", ".join(f"{k[:-2]} {v:.3f}" for k, v in stages.items()))
    print(f"{'main thread in all':58s} {time.thread_time() - start:6.3f}")
    print(f"{'figure helper: start, matplotlib, warm-up figure (its CPU)':58s} {helper_cpu():6.3f}")


if __name__ == "__main__":
    main()
