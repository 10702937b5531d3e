"""``batch`` with its noise scales chosen by the evidence (the default) and by blocked cross-validation
(``batch.noise_selection: cross_validation``), on the real logs of ``real_logs.py``, one after the other in one
process: the score of each (APE, else map error), the best point of ``real_logs.py``'s hand-set grid around the
evidence run's levels (``--grid``; a coordinate search, 5 more runs per log), the ratio of the cross-validated
score to that best, the pair cross-validation kept and the CPU seconds of each run. Prints a Markdown table.

    .venv/bin/python benchmarks/noise_cross_validation.py --logs mrclam6-r3,mrclam7-r1 --cache /tmp/rl [--grid]

Truth is used only to measure; neither choice reads it.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import real_logs  # noqa: E402  (the benchmark's logs, scoring and grid, one place)

score = real_logs.score_text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default="mrclam6,mrclam7", help="comma-separated log names or prefixes")
    ap.add_argument("--grid", action="store_true", help="the hand-set grid's best too (5 more runs per log)")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-real-logs")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    print("| log | score evidence | score cv | best grid | cv / best | evidence / best | cv kept | CPU s ev / cv |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for log in real_logs.all_logs(args.cache, args.logs.split(",")):
        if log.skip or log.path is None:
            continue
        runs = args.cache / "runs"
        ev, cpu_ev = real_logs.run_batch_with(
            log, "noise_selection", "evidence", runs / f"{log.name}-selection-evidence"
        )
        cv, cpu_cv = real_logs.run_batch_with(
            log, "noise_selection", "cross_validation", runs / f"{log.name}-selection-cv"
        )
        best, where = real_logs.best_of_grid(log, "batch", runs, ev, False) if args.grid else (None, "")
        b = best.score if best is not None else float("nan")
        ratios = [f"{x / b:.2f}" if best is not None else "" for x in (cv.score, ev.score)]
        record = (cv.smoother.get("noise_scale") or {}).get("cross_validation") or {}
        kept = record.get("winner") or record.get("skipped") or cv.error
        if isinstance(kept, dict):
            kept = f"motion x{kept['motion']:g}, det x{kept['detection']:g}"
        print(
            f"| {log.name} | {score(ev.score)} | {score(cv.score)} | {f'{score(b)} ({where})' if where else ''} | "
            f"{ratios[0]} | {ratios[1]} | {kept} | {cpu_ev:.1f} / {cpu_cv:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
