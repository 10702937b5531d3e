"""`slamobs stats` at scale: a synthetic batch dataset of 1,000 and 10,000 runs, and the time to summarise it.

    .venv/bin/python benchmarks/stats_scale.py [--runs 1000 10000] [--estimators 5] [--dir /tmp/x]

Each dataset is written by the batch's own record keeping (:class:`pipeline.batch.ledger.Ledger`: one record
per run, then ``summary.parquet``), the file ``stats`` reads; the per-run tables and run directories are left
out because ``stats`` never opens them (a 10k-run dataset of them takes minutes to synthesise, see
``benchmarks/batch_scale.py``). Runs spread over ``--estimators`` estimators and runs/(5 × estimators) logs, a
tenth of the logs without truth (no APE, RPE or bias errors). Timed: gathering the runs (one pyarrow read), the
statistics and ranking, the text outputs, the figures, and the whole command in a fresh process.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from slamobs.pipeline.batch.ledger import Ledger
from slamobs.pipeline.stats import cell_stats, gather_runs, ranking, write_figures
from slamobs.pipeline.stats.inputs import METRICS
from slamobs.pipeline.stats.render import latex, markdown


def make_dataset(out: Path, runs: int, estimators: int) -> float:
    """Record ``runs`` synthetic finished runs (one in fifty failed); returns the seconds it took."""
    rng = np.random.default_rng(0)
    logs = max(1, runs // (5 * estimators))
    t = time.perf_counter()
    ledger = Ledger(out)
    for k in range(runs):
        est, log = k % estimators, (k // estimators) % logs
        truth = log % 10 != 9
        row = {"run_id": f"r{k:06d}", "log": f"/data/log{log:04d}.mcap", "observer": f"est{est}"}
        row["status"] = "failed" if k % 50 == 49 else "ok"
        if row["status"] == "ok":
            scale = 1.0 + 0.2 * est
            row.update({m: float(rng.gamma(4.0, 0.01 * scale)) for m in METRICS if truth or m == "landmark_rmse_m"})
            row["observer_s"] = float(rng.gamma(4.0, 0.5))
        ledger.put(row)
    ledger.compact()
    ledger.close()
    return time.perf_counter() - t


def time_stats(out: Path, work: Path) -> dict[str, float]:
    """Seconds of each step of ``stats`` in this process, and of the whole command in a fresh one."""
    times = {}
    t = time.perf_counter()
    runs = gather_runs([out])
    times["gather runs (summary.parquet)"] = time.perf_counter() - t
    t = time.perf_counter()
    stats = cell_stats(runs)
    rank = ranking(stats)
    times["statistics and ranking"] = time.perf_counter() - t
    t = time.perf_counter()
    markdown(stats, rank, "rpg", [str(out)])
    latex(stats, rank, "table")
    times["Markdown and LaTeX"] = time.perf_counter() - t
    t = time.perf_counter()
    write_figures(runs, work / "figures")
    times["box and violin figures"] = time.perf_counter() - t
    cli = [sys.executable, "-c", "from slamobs.cli.main import entry; entry()"]
    cmd = [*cli, "stats", str(out), "-o", str(work / "st"), "-q"]
    for label, extra in (("whole command, --no-plots", ["--no-plots"]), ("whole command", [])):
        t = time.perf_counter()
        subprocess.run([*cmd, *extra, "--force"], check=True, env={**os.environ})
        times[label] = time.perf_counter() - t
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, nargs="+", default=[1000, 10000])
    parser.add_argument("--estimators", type=int, default=5)
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: a temporary directory)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        rows = {}
        for n in args.runs:
            base = Path(tmp) / f"runs{n}"
            made = make_dataset(base / "ds", n, args.estimators)
            rows[n] = {"write the dataset (not part of stats)": made, **time_stats(base / "ds", base)}
        print(f"| step ({args.estimators} estimators) | " + " | ".join(f"{n} runs" for n in args.runs) + " |")
        print("| --- |" + " --- |" * len(args.runs))
        for step in rows[args.runs[0]]:
            print(f"| {step} | " + " | ".join(f"{rows[n][step]:.2f} s" for n in args.runs) + " |")


if __name__ == "__main__":
    main()
