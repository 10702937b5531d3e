"""The held-stream fit (``noise_estimation.held_motion_noise``) on generated held-command logs whose detections
carry a known error correlated in time (issue 23): how far the commands' estimated levels move from the truth
as the detections' slowly changing error grows. Prints a Markdown table.

    .venv/bin/python benchmarks/held_fit_sim.py [--seeds 3,4]

The log is ``tests/test_riekf_held.py``'s (figure8-wide, 40 s, commands held for 10 samples at 50 Hz): the truth
of each level is the command's error as a white-noise density over the hold (σ·√T). The correlated error is
added along each detection's line of sight (a range error, as MR.CLAM's camera makes): per landmark an
exponentially correlated sequence of standard deviation ``sd`` and correlation time ``tau`` over its detections.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import test_riekf_held as held  # noqa: E402

#: (sd m, tau s) of the detections' correlated range error; (0, 0): none
CASES = ((0.0, 0.0), (0.1, 3.0), (0.2, 5.0), (0.3, 10.0))


def correlated_range_error(stream, sd: float, tau: float, rng: np.random.Generator):
    """``stream`` with an exponentially correlated error (``sd``, ``tau``) per landmark along each detection's
    line of sight."""
    if sd <= 0:
        return stream
    t = np.repeat((stream.det_t_ns - stream.t0_ns) * 1e-9, np.diff(stream.det_offsets))
    err = np.zeros(t.size)
    for lm in np.unique(stream.det_idx):
        idx = np.flatnonzero(stream.det_idx == lm)
        idx = idx[np.argsort(t[idx], kind="stable")]
        rho = np.exp(-np.diff(t[idx], prepend=t[idx[0]]) / tau)
        x = 0.0
        for k, r, z in zip(idx, rho, rng.normal(0.0, sd, idx.size), strict=True):
            x = r * x + np.sqrt(1.0 - r * r) * z
            err[k] = x
    y = stream.det_y
    return replace(stream, det_y=y + y / np.linalg.norm(y, axis=1, keepdims=True) * err[:, None])


def main() -> None:
    from slamobs.pipeline.alignment import align
    from slamobs.pipeline.noise import estimate_log_noise, resolve_noise, stream_density
    from slamobs.pipeline.simulate import simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="3,4")
    args = ap.parse_args()
    hold = held.HOLD / held.RATE_HZ
    truth = held.SIGMA_OMEGA * np.sqrt(hold), held.SIGMA_V * np.sqrt(hold)
    print(f"truth: gyro {truth[0]:.4f} rad/sqrt(s), velocity {truth[1]:.4f} m/sqrt(s)")
    print("| seed | correlated range error | gyro / truth | velocity / truth | detection law factor |")
    print("| --- | --- | --- | --- | --- |")
    for seed in (int(s) for s in args.seeds.split(",")):
        sim = simulate("figure8-wide", duration=40.0, seed=seed, imu_rate=held.RATE_HZ, odom_rate=held.RATE_HZ)
        streams = held.commanded(sim, np.random.default_rng(seed))
        stream = align(streams, keep_directions=False)
        density = stream_density(streams.linear_velocity.t_ns, streams.linear_velocity.xyz)
        for sd, tau in CASES:
            noisy = correlated_range_error(stream, sd, tau, np.random.default_rng(seed + 100))
            found = estimate_log_noise(noisy, density)
            noise = resolve_noise(estimated=found)
            factor = next((n.split("scaled by ")[1].split(" ")[0] for n in found.notes if "scaled by" in n), "")
            case = f"sd {sd:g} m, tau {tau:g} s" if sd else "none (white)"
            ratios = np.max(noise.gyro) / truth[0], np.max(noise.velocity) / truth[1]
            print(f"| {seed} | {case} | {ratios[0]:.2f} | {ratios[1]:.2f} | {factor} |", flush=True)


if __name__ == "__main__":
    main()
