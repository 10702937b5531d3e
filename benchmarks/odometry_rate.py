"""riekf against fast-adaptation over the velocity stream's rate (issue 23 on slow odometry): generated logs of the
ground robot (180 s), the drone's figure 8 and the hand-held rig of ``handheld_logs.py`` (60 s each) with their
odometry at each rate, the IMU at 100 Hz or (``--slow-gyro``) at the odometry's own rate, as a log whose angular
velocity comes from its slow odometry. Each log is run with ``fast-adaptation`` (no configuration), ``riekf`` given
the true levels and ``riekf`` with none; prints a Markdown table of APE (m, SE(3)-aligned).

    .venv/bin/python benchmarks/odometry_rate.py [--cache DIR] [--rates 4 50] [--seeds 3322 3323] [--slow-gyro]

docs/benchmarks.md, "riekf on slow odometry", session 32.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from handheld_logs import Case, make_log, run  # noqa: E402

#: Seeds per scenario (docs/benchmarks.md: seed=3322 to seed=3329; the hand-held rig also seed=3305 to seed=3310)
#: and the scenario's duration (s).
SCENARIOS = {
    "ground": ((3322, 3323, 3324, 3325), 180.0),
    "figure8": ((3326, 3327), 60.0),
    "handheld": ((3328, 3329, 3305, 3306, 3307, 3308, 3309, 3310), 60.0),
}
RUNS = (("fast-adaptation", "auto"), ("riekf", "true"), ("riekf", "auto"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-odometry-rate")
    ap.add_argument("--rates", type=float, nargs="+", default=[4.0, 50.0], help="the odometry's rates (Hz)")
    ap.add_argument("--seeds", type=int, nargs="+", help="the logs' seeds (default: all)")
    ap.add_argument("--slow-gyro", action="store_true", help="the IMU at the odometry's rate, not at 100 Hz")
    args = ap.parse_args()
    head = "| log | scenario | s | IMU/odom Hz | FA | riekf true | riekf auto | riekf true / FA |"
    print(head + "\n|" + " --- |" * (head.count("|") - 1))
    for name, (seeds, seconds) in SCENARIOS.items():
        for seed in seeds:
            if args.seeds and seed not in args.seeds:
                continue
            for hz in args.rates:
                imu = hz if args.slow_gyro else 100.0
                case = Case(seed, name, seconds, name, imu_hz=imu, odom_hz=hz)
                cache = args.cache / f"imu{imu:g}-odom{hz:g}"
                cache.mkdir(parents=True, exist_ok=True)
                log, truth = make_log(case, cache)
                ape = {}
                for est, mode in RUNS:
                    res = run(log, est, cache / "runs" / f"s{seed}-{est}-{mode}", truth if mode == "true" else None)
                    ape[est, mode] = res.get("ape")
                cells = [f"{ape[k]:.3f}" if ape[k] is not None else "error" for k in RUNS]
                fa, rt = ape[RUNS[0]], ape[RUNS[1]]
                ratio = f"{rt / fa:.2f}" if fa and rt is not None else "-"
                print(f"| seed={seed} | {name} | {seconds:g} | {imu:g}/{hz:g} | " + " | ".join(cells) + f" | {ratio} |")


if __name__ == "__main__":
    main()
