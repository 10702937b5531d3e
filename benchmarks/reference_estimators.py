"""The reference estimators on the one-hour benchmark log: riekf's filter stage against real time, batch's
smoother stage (CPU seconds: one core) and peak memory, beside fast-adaptation.

    .venv/bin/python benchmarks/reference_estimators.py [--hours 1] [--container mcap] [--cache DIR]

The log is ``benchmarks/end_to_end.py``'s (figure8-wide, generated once into the cache); each estimator runs in
its own ``slamobs run`` process after a warm-up on a short log (numba cache filled). Floors (issue 27, in
``end_to_end.py``), on the one-hour log: riekf's filter stage <= 1.8 s; batch's smoother stage <= 8 CPU s and peak
RSS <= 1 GB. Each is printed on its own line ending in met or MISSED, after the load and the machine's speed.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from end_to_end import (  # noqa: E402
    MAX_RIEKF_FILTER_1H_S,
    MAX_RSS_BATCH_1H_MB,
    MAX_SMOOTHER_1H_S,
    SUFFIX,
    cpu_model,
    load,
    make_log,
    met,
    run,
)

OBSERVERS = ("fast-adaptation", "riekf", "batch")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--container", default="mcap", choices=sorted(SUFFIX))
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-bench")
    ap.add_argument("--estimators", nargs="+", default=list(OBSERVERS), choices=OBSERVERS)
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    short, log = make_log(args.cache, 60.0, args.container), make_log(args.cache, args.hours * 3600, args.container)
    for name in args.estimators:
        run(short, args.cache / "runs" / "warmup", extra=("--observer", name))
    print(f"# {log.name}, {cpu_model()}, {load()}")
    print(
        "| estimator | wall s | CPU s | estimator stage s | x real time | µs per velocity sample | seed s | "
        "smoother s (CPU s) | peak RSS MB |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    res = {}
    for name in args.estimators:
        r = res[name] = run(log, args.cache / "runs" / f"{log.stem}-{name}", extra=("--observer", name))
        t = r["timings"]
        n = json.loads((args.cache / "runs" / f"{log.stem}-{name}" / "run.json").read_text())["counts"][
            "velocity_samples"
        ]
        smoother = f"{t['smoother_s']:.1f} ({t['smoother_cpu_s']:.1f})" if "smoother_s" in t else ""
        print(
            f"| {name} | {r['wall']:.1f} | {r['cpu']:.1f} | {t['observer_s']:.1f} | "
            f"{r['span_s'] / t['observer_s']:.0f}x | {1e6 * t['observer_s'] / n:.1f} | "
            f"{t.get('seed_s', float('nan')):.1f} | {smoother} | {r['rss']:.0f} |"
        )
    print(f"# floors (issue 27, {args.hours:g} h log; the floors are for 1 h); {load()}")
    if "batch" in res:
        b = res["batch"]
        t = b["timings"]
        cov, cov_cpu = t["pose_landmark_covariance_s"], t["pose_landmark_covariance_cpu_s"]
        print(f"batch: pose and landmark covariances {cov_cpu:.1f} CPU s ({cov:.1f} s)")
        cpu = t["smoother_cpu_s"]
        print(
            f"batch: smoother stage {cpu:.1f} CPU s ({t['smoother_s']:.1f} s wall) (<= {MAX_SMOOTHER_1H_S:g}): "
            f"{met(cpu <= MAX_SMOOTHER_1H_S)}"
        )
        print(f"batch: peak RSS {b['rss']:.0f} MB (<= {MAX_RSS_BATCH_1H_MB:g}): {met(b['rss'] <= MAX_RSS_BATCH_1H_MB)}")
    if "riekf" in res:
        f = res["riekf"]
        filt = f["timings"]["observer_s"]
        print(
            f"riekf: filter stage {filt:.2f} s = {f['span_s'] / filt:.0f}x real time (<= {MAX_RIEKF_FILTER_1H_S:g} s): "
            f"{met(filt <= MAX_RIEKF_FILTER_1H_S)}"
        )


if __name__ == "__main__":
    main()
