"""The batch smoother's solver against the same graph built from GTSAM's stock factors in Python (issue 27).

    .venv/bin/python benchmarks/batch_gtsam.py [--seconds 60] [--cache DIR]

On ``benchmarks/end_to_end.py``'s figure8-wide log of ``--seconds`` (generated once into the cache), the
smoother's problem is built as ``slamobs run --observer batch`` builds it (seed, keyframes, preintegrated
odometry), then solved twice from the seed: by the package's solver (``solve`` in
``pipeline/smoother/graph.py``, compiled normal equations over the block tridiagonal structure) and by GTSAM's
``LevenbergMarquardtOptimizer`` on a graph
of stock factors made in Python: ``BetweenFactorPose3`` per keyframe interval (the preintegrated motion at the
seed's bias and its covariance: stock factors have no bias correction, so the biases stay at the seed's),
``BearingRangeFactor3D`` per detection with the same Huber kernel, and a ``PriorFactorPose3`` gauge. Printed:
CPU seconds of each (GTSAM's including building its graph, ours including its linearizations), their ratio,
and how far the two solutions' keyframe positions are apart. The kernels are compiled by a warm-up first.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from end_to_end import cpu_model, load, make_log  # noqa: E402


def problem_of(log: Path):
    """The smoother's problem and seed guess for ``log``, as a run builds them."""
    from slamobs.pipeline import run as R
    from slamobs.pipeline.config import parse_config

    cfg = parse_config({"observer": "batch"})
    prep = R.prepare_log(log, cfg)
    est = R.estimator_input(prep, cfg)
    return est.spec.start(prep.aligned, est.gains, est.options).first_problem()


def stock_graph(problem, guess):
    """GTSAM's stock factors for the same problem (module docstring) and the initial values."""
    import gtsam

    from slamobs.pipeline.smoother.graph import GAUGE_SIGMA
    from slamobs.pipeline.smoother.preintegration import D_P, D_R, D_W

    k = problem.data.shape[0] + 1
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i in range(k):
        values.insert(i, gtsam.Pose3(gtsam.Rot3(guess.rot[i]), guess.pos[i]))
    for key, p in enumerate(guess.landmarks):
        values.insert(k + key, np.asarray(p, float))
    for j in range(k - 1):
        w = problem.data[j, D_W : D_W + 36].reshape(6, 6)
        rel = gtsam.Pose3(gtsam.Rot3(problem.data[j, D_R : D_R + 9].reshape(3, 3)), problem.data[j, D_P : D_P + 3])
        noise = gtsam.noiseModel.Gaussian.Covariance(np.linalg.inv(w.T @ w))
        graph.add(gtsam.BetweenFactorPose3(j, j + 1, rel, noise))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(problem.huber)
    ranges = np.linalg.norm(problem.det_y, axis=1)
    for m in range(problem.det_y.shape[0]):
        s = float(problem.det_sigma[m])
        model = gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Diagonal.Sigmas(np.r_[s, s, s] / [ranges[m], ranges[m], 1.0])
        )
        graph.add(
            gtsam.BearingRangeFactor3D(
                int(problem.kf_of_det[m]),
                k + int(problem.det_idx[m]),
                gtsam.Unit3(problem.det_y[m] / ranges[m]),
                float(ranges[m]),
                model,
            )
        )
    a = problem.anchor
    graph.add(
        gtsam.PriorFactorPose3(
            a, gtsam.Pose3(gtsam.Rot3(guess.rot[a]), guess.pos[a]), gtsam.noiseModel.Isotropic.Sigma(6, GAUGE_SIGMA)
        )
    )
    return graph, values


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="log length (GTSAM needs ~1 GB per 10 minutes)")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-bench")
    args = ap.parse_args()
    import gtsam

    from slamobs.pipeline.smoother import graph as g

    args.cache.mkdir(parents=True, exist_ok=True)
    warm, guess = problem_of(make_log(args.cache, 60.0, "mcap"))
    g.solve(warm, guess, max_iterations=1)
    problem, guess = problem_of(make_log(args.cache, args.seconds, "mcap"))
    c = time.process_time()
    ours = g.solve(problem, guess)
    c_ours = time.process_time() - c
    c = time.process_time()
    graph, values = stock_graph(problem, guess)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-5)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    c_gtsam = time.process_time() - c
    pos = gtsam.utilities.extractPose3(result)[:, 9:]
    apart = np.sqrt(np.mean(np.sum((pos - ours.pos) ** 2, axis=1)))
    n = problem.data.shape[0] + 1
    print(f"# {args.seconds:g} s log: {n} keyframes, {problem.det_idx.size} detections; {cpu_model()}, {load()}")
    print("| solver | CPU s | iterations |")
    print("| --- | --- | --- |")
    print(f"| slamobs (graph.solve) | {c_ours:.2f} | {ours.summary['iterations']} |")
    print(f"| GTSAM stock factors, LevenbergMarquardtOptimizer | {c_gtsam:.2f} | |")
    print(f"ratio GTSAM / slamobs: {c_gtsam / c_ours:.1f}x; keyframe positions apart (RMS): {apart:.2e} m")


if __name__ == "__main__":
    main()
