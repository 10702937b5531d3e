"""``noise: auto`` against the truth: the levels learned from simulated logs over a sweep of rates, levels and
seeds, next to the levels the simulator drew them with.

    .venv/bin/python benchmarks/noise_sweep.py [--rates 10 50 200 400] [--seeds 0 1 2] [--duration 30]

Gyro and odometry run at the rate of the row, with per-axis noises (the simulator's defaults on the x axis,
twice that on y, half on z), the gyro's scaled by the row's level (100: a real gyro); the detections follow
σ0 + k·r (``linear``) or b + a·r² (``square``). Prints, per row, estimated / true for each velocity axis and
for the detection σ at the 5th, 50th and 95th percentile of the ranges seen, the law chosen, and the
estimation time.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import align
from slamobs.pipeline.noise import estimate_log_noise, stream_density
from slamobs.pipeline.simulate import NoiseModel, expected_streams, simulate

AXES = np.array([1.0, 2.0, 0.5])
LAWS = {
    "linear": {"detection_base": 0.008, "detection_per_m": 0.003, "detection_per_m2": 0.0},
    "square": {"detection_base": 0.004, "detection_per_m": 0.0, "detection_per_m2": 0.0008},
}


def row(rate: float, level: float, law: str, seed: int, duration: float) -> list[str]:
    """One simulated log: the ratios estimated / true, formatted."""
    base = NoiseModel()
    nm = replace(base, gyro=tuple(level * base.gyro * AXES), odom_linear=tuple(base.odom_linear * AXES))
    nm = replace(nm, **LAWS[law])
    sim = simulate("figure8", duration=duration, seed=seed, noise=nm, imu_rate=rate, odom_rate=rate)
    stream = align(expected_streams(sim), keep_directions=False)
    t = time.perf_counter()
    found = estimate_log_noise(stream, stream_density(sim.odom.t_ns, sim.odom.linear))
    seconds = time.perf_counter() - t
    period = 1.0 / rate
    gyro = found.gyro.value / (np.array(nm.gyro) * np.sqrt(period))
    vel = found.velocity.value / (np.array(nm.odom_linear) * np.sqrt(period))
    det = found.detection
    r = np.linspace(*det.ranges, 3)
    truth = nm.detection_base + nm.detection_per_m * r + nm.detection_per_m2 * r * r
    ratio = det.sigma(r) / truth
    cells = [f"{rate:g}", f"{level:g}", law, str(seed)]
    cells += [" ".join(f"{x:.2f}" for x in v) for v in (gyro, vel, ratio)]
    worst = float(np.max(np.abs(np.r_[gyro, vel, ratio] - 1.0)))
    return cells + [det.law, f"{100 * worst:.0f} %", f"{seconds:.2f}"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[10, 50, 200, 400])
    ap.add_argument("--levels", type=float, nargs="+", default=[1, 100])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of log (60 below 50 Hz)")
    args = ap.parse_args()
    head = ["Hz", "gyro level", "law", "seed", "gyro x y z", "velocity x y z", "σ(r) p5 p50 p95"]
    head += ["chosen", "worst", "s"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    worst = []
    for rate in args.rates:
        for level in args.levels:
            for law in LAWS:
                for seed in args.seeds:
                    cells = row(rate, level, law, seed, args.duration if rate >= 50 else 2 * args.duration)
                    worst.append(float(cells[-2].rstrip(" %")))
                    print("| " + " | ".join(cells) + " |", flush=True)
    print(f"\nratios estimated / true; worst error over {len(worst)} logs: {max(worst):.0f} %")


if __name__ == "__main__":
    main()
