"""``slamobs tune``: what reading each log once per worker (not once per trial) saves.

Runs the same tune twice on generated logs with two local workers: as slamobs does it (each worker keeps the logs
it has read and aligned) and with every trial reading its logs again (the worker's cache cleared before each
task), after a warm-up that fills the numba cache. Prints wall time, seconds spent reading, and trials per minute.

    .venv/bin/python benchmarks/tune_read_once.py [--duration 60] [--logs 3] [--trials 20]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path


def read_every_trial(task):
    """The worker function without the per-process log cache (what a tune that re-read the logs would do)."""
    from slamobs.pipeline.tune import worker

    worker.PREPARED.clear()
    return worker.run_trial_log(task)


def main() -> None:
    import pandas as pd

    from slamobs.pipeline.simulate import simulation, write_log
    from slamobs.pipeline.tune.study import TuneOptions, run_tune

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per generated log")
    ap.add_argument("--logs", type=int, default=3)
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--observer", default="fast-adaptation")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        logs = [
            write_log(simulation("figure8-wide", duration=args.duration, seed=i), tmp / f"l{i}.mcap")
            for i in range(args.logs)
        ]
        run_tune(logs[:1], TuneOptions(out=tmp / "warm", observer=args.observer, trials=2, jobs=2))  # numba cache
        rows = []
        for name, run in (("read once per worker (slamobs)", None), ("read every trial", read_every_trial)):
            t = time.perf_counter()
            run_tune(
                logs,
                TuneOptions(out=tmp / name.split()[1], observer=args.observer, trials=args.trials, jobs=2),
                run=run,
            )
            wall = time.perf_counter() - t
            trials = pd.read_parquet(tmp / name.split()[1] / "trials.parquet")
            rows.append(
                {
                    "variant": name,
                    "wall_s": wall,
                    "reads": int((trials["read_s"] > 0).sum()),
                    "read_s": trials["read_s"].sum(),
                    "observer_s": trials["observer_s"].sum(),
                    "trials_per_min": args.trials / wall * 60,
                }
            )
        print(
            f"{args.logs} logs of {args.duration:g} s (figure8-wide), {args.trials} trials of {args.observer}, "
            "2 local workers"
        )
        print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.2f}"))


if __name__ == "__main__":
    main()
