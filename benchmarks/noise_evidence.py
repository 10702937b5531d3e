"""``batch`` with and without the velocity level chosen by its evidence (``batch.noise_evidence``), on the real
logs of ``real_logs.py``, side by side in one process: APE (or map error), the scale that won, every tried
scale's log evidence, and the CPU seconds of each run. Prints a Markdown table.

    .venv/bin/python benchmarks/noise_evidence.py --logs mrclam6,mrclam7 --cache /tmp/rl [--mode always]

Truth is used only to measure; the choice reads none.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import real_logs  # noqa: E402  (the benchmark's logs and scoring, one place)

score = real_logs.score_text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default="mrclam6,mrclam7", help="comma-separated log names or prefixes")
    ap.add_argument("--mode", default="always", choices=("held", "always"), help="batch.noise_evidence to compare")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-real-logs")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    print("| log | score off | score evidence | ratio | scale chosen | log Z by scale (last pass) | CPU s off / on |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for log in real_logs.all_logs(args.cache, args.logs.split(",")):
        if log.skip or log.path is None:
            continue
        off, cpu_off = real_logs.run_batch_with(
            log, "noise_evidence", "off", args.cache / "runs" / f"{log.name}-evidence-off"
        )
        on, cpu_on = real_logs.run_batch_with(
            log, "noise_evidence", args.mode, args.cache / "runs" / f"{log.name}-evidence-on"
        )
        ratio = on.score / off.score if 0.0 < off.score < float("inf") else float("nan")
        records = on.smoother.get("noise_scale") or {}
        chosen = ", ".join(f"{k} {r.get('scale', r.get('skipped', ''))}" for k, r in records.items())
        scores = "; ".join(
            f"{k}: " + ", ".join(f"x{s} {z}" for s, z in r.get("log_evidence", {}).items()) for k, r in records.items()
        )
        print(
            f"| {log.name} | {score(off.score)} | {score(on.score)} | {ratio:.3f} | {chosen or on.error} | {scores} | "
            f"{cpu_off:.1f} / {cpu_on:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
