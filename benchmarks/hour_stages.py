"""The fast-adaptation run's two longest stages after the read, in one process: CPU seconds (issue 27).

    .venv/bin/python benchmarks/hour_stages.py LOG [--repeat 3]

The log is read, aligned and run once (``run_prepared``, figures off: they are drawn by a helper process in a
run); then, ``--repeat`` times each, the observer's stretches on the aligned stream (this thread's CPU: the
kernel runs on it, nothing is written) and the error report of the run directory (``evaluate_run``, this
process's CPU: the clock-offset search runs on a thread beside it; the tables read from the files, where a run
hands them over from its writer). CPU seconds are the measure on a shared VM; wall seconds and the load are
printed beside them. Run it with two trees' ``PYTHONPATH`` in turn to compare them side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as `slamobs` runs (cli/main.py)
sys.path.insert(0, str(Path(__file__).resolve().parent))
from end_to_end import load  # noqa: E402


def _timed(fn, clock) -> tuple[float, float]:
    """CPU (``clock``) and wall seconds of ``fn()``."""
    c, w = clock(), time.perf_counter()
    fn()
    return clock() - c, time.perf_counter() - w


def main() -> None:
    import slamobs
    from slamobs.pipeline import run as R
    from slamobs.pipeline.config import load_config

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    config = replace(load_config(None), observer="fast-adaptation")
    config = replace(config, evaluation=replace(config.evaluation, plots=False))
    spec = R.resolve_estimator(config)
    needed = spec.directions_needed(config)
    directions = needed > 0 or config.output.frame == "gravity"
    prepared = R.prepare_log(args.log, config, directions=directions, needs_directions=needed, noise=spec.uses_noise)
    est = R.estimator_input(prepared, config)
    tmp = Path(tempfile.mkdtemp(prefix="slamobs-hour-stages-"))
    try:
        out = tmp / "run"
        R.run_prepared(prepared, out, config)  # numba's cache loaded, the run directory to report on
        metadata = json.loads((out / "run.json").read_text())

        def observe() -> None:
            for _ in spec.chunks(prepared.aligned, est.gains, est.options, R.STRETCH_SAMPLES):
                pass

        def report() -> None:
            R.evaluate_run(out, prepared.streams, config, [], dict(metadata), {})

        rows = {
            "observer (thread CPU)": (observe, time.thread_time),
            "report (process CPU)": (report, time.process_time),
        }
        found = {name: [_timed(fn, clock) for _ in range(args.repeat)] for name, (fn, clock) in rows.items()}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"# {args.log}, fast-adaptation, slamobs from {Path(slamobs.__file__).parent}; {load()}")
    print(f"{'stage':22s} {'best CPU s':>10s} {'CPU s, every run':>28s} {'best wall s':>11s}")
    for name, runs in found.items():
        cpu = ", ".join(f"{c:.2f}" for c, _ in runs)
        print(f"{name:22s} {min(c for c, _ in runs):10.2f} {cpu:>28s} {min(w for _, w in runs):11.2f}")
    print(f"# {load()}")


if __name__ == "__main__":
    main()
