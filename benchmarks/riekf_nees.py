"""riekf consistency: run-averaged NEES of pose and biases (12 DoF) over noisy simulated runs, against the
two-sided 95 % χ² bounds of that average.

    .venv/bin/python benchmarks/riekf_nees.py [--runs 20] [--duration 20] [--scenario figure8 loop]
        [--detection-rate 0.5]

Each run draws its biases from the filter's prior (σ = 0.05) and starts the filter at the true pose (the
gauge); the NEES is taken at 10 Hz. Prints, per scenario, the mean NEES over the run, the share of instants
whose run-average lies within the bounds, and the propagation cost per velocity sample; then the final map's
landmark NEES (3 DoF: ``RiEKF.landmark_covariance`` against the simulator's landmarks; the filter starts at the
true pose, so its map frame is the truth's) pooled over the landmarks and runs, the median and largest of the runs'
means, and the runs whose mean exceeds χ²(3) 97.5 % (landmarks seen together share their errors: a run's mean is
no χ² average). ``--detection-rate`` (Hz) thins the detections (the scenario's rate otherwise): sparse maps.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import align
from slamobs.pipeline.evaluation.metrics import nees_bounds
from slamobs.pipeline.lie import so3_log
from slamobs.pipeline.noise import NoiseConfig, resolve_noise
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.observers.base import output_rows
from slamobs.pipeline.observers.riekf import RiEKF
from slamobs.pipeline.simulate import expected_streams, get_scenario, simulate


def landmark_nees(filt: RiEKF, sc) -> np.ndarray:
    """Each landmark in the state: NEES (3 DoF) of its estimate against the truth under its written covariance."""
    cov = filt.landmark_covariance()
    seen = np.isfinite(cov).all(axis=(1, 2))
    err = filt.lm[seen, :3] - sc.landmarks[np.searchsorted(sc.landmark_ids, filt.stream.landmark_ids[seen])]
    return np.einsum("ni,ni->n", err, np.linalg.solve(cov[seen], err[..., None])[..., 0])


def nees_runs(scenario: str, runs: int, duration: float, sigma_b: float = 0.05, every: int = 20, rate=None):
    noise = resolve_noise(
        NoiseConfig(gyro_bias=sigma_b, velocity_bias=sigma_b, gyro_bias_walk=0.0, velocity_bias_walk=0.0)
    )
    rng = np.random.default_rng(2015)
    nees, lm_nees, seconds, samples = [], [], 0.0, 0
    for run in range(runs):
        b = rng.normal(0.0, sigma_b, 6)
        sc = replace(get_scenario(scenario), gyro_bias=b[:3], velocity_bias=b[3:])
        sim = simulate(sc, duration=duration, seed=100 + run, detection_rate=rate)
        stream = align(expected_streams(sim), keep_directions=False)
        start = sc.sample(np.array([(stream.vel_t_ns[0] - sim.start_ns) * 1e-9]))
        filt = RiEKF(stream, {}, ObserverOptions(out_every=every), noise=noise, r0=start.R[0], p0=start.P[0])
        filt.cov_rows = np.zeros((output_rows(filt.n_vel, every, 0, filt.n_vel), 12, 12))
        _ = filt.time_offset  # waited for (it is estimated on another core meanwhile): the filter alone is timed
        t = time.perf_counter()
        res = filt.advance(filt.n_vel)
        if run:  # the first run compiles
            seconds += time.perf_counter() - t
            samples += filt.n_vel
        truth = sc.sample((res.t_ns - sim.start_ns) * 1e-9)
        row = []
        for k in range(1, res.t_ns.shape[0]):
            eta = res.rotation[k] @ truth.R[k].T
            err = np.r_[
                so3_log(eta), res.position[k] - eta @ truth.P[k], b[:3] - res.gyro_bias[k], b[3:] - res.vel_bias[k]
            ]
            row.append(err @ np.linalg.solve(filt.cov_rows[k], err))
        nees.append(row)
        lm_nees.append(landmark_nees(filt, sc))
    n = min(len(r) for r in nees)
    mean = np.mean([r[:n] for r in nees], axis=0)
    lo, hi = nees_bounds(12, runs)
    return mean, lo, hi, seconds / max(samples, 1), lm_nees


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--scenario", nargs="+", default=["figure8", "loop"])
    ap.add_argument("--detection-rate", type=float, help="detections per second (the scenario's otherwise)")
    args = ap.parse_args()
    lm_rows = []
    print(
        "| scenario | runs x s | mean NEES (12 DoF) | 95 % bounds of the run average | instants inside | "
        "median / max of the run average | µs per velocity sample |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for name in args.scenario:
        mean, lo, hi, per_sample, lm = nees_runs(name, args.runs, args.duration, rate=args.detection_rate)
        lm_rows.append((name, lm))
        inside = np.mean((mean >= lo) & (mean <= hi))
        print(
            f"| {name} | {args.runs} x {args.duration:g} | {mean.mean():.2f} | {lo:.2f} - {hi:.2f} | "
            f"{100 * inside:.0f} % | {np.median(mean):.2f} / {mean.max():.2f} | {1e6 * per_sample:.1f} |"
        )
    print(
        "\n| scenario | landmarks (runs) | landmark NEES (3 DoF), pooled | median / max of the runs' means | "
        "runs > 9.35 |"
    )
    print("| --- | --- | --- | --- | --- |")
    for name, lm in lm_rows:
        means = np.array([r.mean() for r in lm])
        print(
            f"| {name} | {sum(r.size for r in lm)} ({len(lm)}) | {np.concatenate(lm).mean():.2f} | "
            f"{np.median(means):.2f} / {means.max():.2f} | {int(np.sum(means > 9.35))} |"
        )


if __name__ == "__main__":
    main()
