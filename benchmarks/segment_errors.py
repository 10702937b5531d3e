"""Segment errors (rpg_trajectory_evaluation's relative error per sub-trajectory length) on long trajectories:
slamobs' compiled version against its former NumPy formulation (stacked matmuls) and rpg's own loop (vendored in
tests/oracles), and what they add to a report.

    PYTHONPATH=... .venv/bin/python benchmarks/segment_errors.py [--poses 1000 10000 100000 1000000] [--rpg-max 3000]

For each size, a generated trajectory (a 3-D loop at 20 Hz with 1 % scale error and a slow yaw drift) is
evaluated at rpg's five lengths (10-50 % of the path); best of ``--repeat`` runs. rpg's segment search is
quadratic Python: it runs only up to ``--rpg-max`` poses (its time there is the reason the report does not use it).
Prints one table row per size: poses, segments found, slamobs seconds, the same with the NumPy products, whether
the two give the same bits, rpg seconds, and the largest difference to rpg (where it ran).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from slamobs.pipeline.evaluation import drift  # noqa: E402
from slamobs.pipeline.evaluation.drift import SEGMENT_ERROR_KINDS, rpg_lengths, segment_errors  # noqa: E402
from slamobs.pipeline.lie import rots_to_quats, so3_exp  # noqa: E402


def trajectory(n: int) -> tuple[np.ndarray, ...]:
    """Truth and estimate positions and rotations of ``n`` poses."""
    s = np.arange(n) * 0.05
    pos = np.stack([40 * np.sin(0.01 * s), 25 * np.sin(0.02 * s), 2 + np.cos(0.005 * s)], axis=1)
    yaw = 0.01 * s
    rot = np.zeros((n, 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = (
        np.cos(yaw),
        -np.sin(yaw),
        np.sin(yaw),
        np.cos(yaw),
        1.0,
    )
    drift = np.array([so3_exp(np.array([0.0, 0.0, 1e-4 * x])) for x in np.linspace(0, 500, 200)])
    est_rot = np.einsum("nij,njk->nik", drift[np.minimum((np.arange(n) * 200) // n, 199)], rot)
    return pos, rot, 1.01 * pos, est_rot


def best(fn, repeat: int) -> tuple[float, object]:
    out, times = None, []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, nargs="+", default=[1000, 10000, 100000, 1000000])
    ap.add_argument("--rpg-max", type=int, default=3000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    from oracles import rpg_relative_error as rpg

    print("| poses | segments | slamobs [s] | NumPy products [s] | same bits | rpg [s] | max abs difference to rpg |")
    print("|---:|---:|---:|---:|---|---:|---:|")
    segment_errors(*trajectory(100), 10.0)  # the kernels loaded (or compiled) before the clock runs
    for n in args.poses:
        rp, rr, ep, er = trajectory(n)
        path = float(np.sum(np.linalg.norm(np.diff(rp, axis=0), axis=1)))
        ours_s, (ours, arrays) = best(lambda: segment_errors(rp, rr, ep, er, path), args.repeat)
        segments = sum(row["n_segments"] for row in ours["per_length"])
        compiled = drift.relative_errors
        drift.relative_errors = drift.relative_errors_numpy
        try:
            numpy_s, (_, numpy_arrays) = best(lambda: segment_errors(rp, rr, ep, er, path), args.repeat)
        finally:
            drift.relative_errors = compiled
        same = (
            all(np.array_equal(arrays[L][k], numpy_arrays[L][k]) for L in arrays for k in SEGMENT_ERROR_KINDS)
            and arrays.keys() == numpy_arrays.keys()
        )
        rpg_s, diff = "–", "–"
        if n <= args.rpg_max:
            qg, qe = rots_to_quats(rr), rots_to_quats(er)
            t = time.perf_counter()
            d = rpg.get_distance_from_start(rp)
            theirs = {
                L: rpg.compute_relative_error(ep, qe, rp, qg, np.eye(4), L, 0.2 * L, d) for L in rpg_lengths(path)
            }
            rpg_s = f"{time.perf_counter() - t:.3f}"
            order = ("translation_m", "translation_pct", "yaw_deg", "gravity_deg", "rotation_deg", "rotation_deg_per_m")
            diff = max(
                float(np.max(np.abs(arrays[L][k] - dict(zip(order, res[1:]))[k])))
                for L, res in theirs.items()
                for k in SEGMENT_ERROR_KINDS
            )
            diff = f"{diff:.1e}"
        print(f"| {n} | {segments} | {ours_s:.4f} | {numpy_s:.4f} | {'yes' if same else 'no'} | {rpg_s} | {diff} |")


if __name__ == "__main__":
    main()
