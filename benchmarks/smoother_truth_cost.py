"""``batch``'s graph cost at the truth against its cost at its own solution, on one of ``stereo_logs.py``'s generated
logs given the true noise: "model" (the truth costs more than the solution: the graph's minimum is where the data
put it) or "solver" (the truth, or a start near it, reaches a lower cost than the solution found).

    PYTHONPATH=... .venv/bin/python benchmarks/smoother_truth_cost.py --sweep unseen --case 2 [--reseed K]

Prints the run's APE, the cost of the final graph at the solution and at the truth (poses of the noise-free
simulation at the keyframes, the scenario's landmarks; the solution's bias), split into motion (relative motion
and bias prior) and detections, beside half the graph's residual dimensions (what a calibrated model costs at
the truth), then the graph solved from the truth to convergence (its cost and APE), and riekf given the same
noise with its floor held and not (``noise.floor``). The graph's gauge prior sits at each guess's own anchor
pose, so the truth's frame does not matter.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import stereo_logs  # noqa: E402

from slamobs.pipeline.api import run_log  # noqa: E402
from slamobs.pipeline.lie import quats_to_rots  # noqa: E402
from slamobs.pipeline.simulate import simulate  # noqa: E402
from slamobs.pipeline.simulate.scenarios import customize, get_scenario  # noqa: E402
from slamobs.pipeline.smoother import estimator, graph  # noqa: E402


def ape(p: np.ndarray, truth: np.ndarray) -> float:
    """RMS position error after the SE(3) alignment of ``p`` on ``truth`` (least squares, no scale)."""
    a, b = p - p.mean(0), truth - truth.mean(0)
    u, _, vt = np.linalg.svd(b.T @ a)
    r = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    return float(np.sqrt(((a @ r.T - b) ** 2).sum(1).mean()))


def final_graph(log: Path, out: Path, config: dict):
    """One batch run; the smoother, the graph it solved last and its solution (kept as the run passes them to
    ``graph.residual_statistics``)."""
    kept: dict = {}
    statistics, solve = graph.residual_statistics, estimator.BatchSmoother.solve

    def statistics_kept(problem, sol):
        kept["problem"], kept["solution"] = problem, sol
        return statistics(problem, sol)

    def solve_kept(self, progress=None):
        kept["smoother"] = self
        return solve(self, progress)

    graph.residual_statistics, estimator.BatchSmoother.solve = statistics_kept, solve_kept
    try:
        run_log(log, out, observer="batch", config=config, force=True)
    finally:
        graph.residual_statistics, estimator.BatchSmoother.solve = statistics, solve
    return kept["smoother"], kept["problem"], kept["solution"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-stereo-logs")
    ap.add_argument("--sweep", choices=("issue", "unseen"), default="unseen")
    ap.add_argument("--case", type=int, default=2, help="index into the sweep's cases")
    ap.add_argument("--reseed", type=int, default=0)
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    case = (stereo_logs.UNSEEN if args.sweep == "unseen" else stereo_logs.CASES)[args.case]
    case = replace(case, seed=case.seed + args.reseed)
    log, truth = stereo_logs.make_log(case, args.cache)
    noise = {k: v for k, v in truth.items() if k not in ("median_range_m", "detections")}
    config = {"evaluation": {"plots": False}, "noise": noise}
    out = args.cache / "runs" / f"{case.name}-truth-cost"
    smoother, problem, sol = final_graph(log, out, config)
    report = json.loads((out / "report.json").read_text())
    print(f"{case.name}: batch APE {report['ape']['translation_m']['rmse']:.3f} m (true noise)")

    sc = customize(get_scenario(case.scenario), landmarks=case.landmarks, detection_gaps=case.gaps)
    kw = dict(duration=case.duration, seed=case.seed, imu_rate=case.rate, odom_rate=case.rate)
    exact = simulate(sc, noise=False, detection_rate=case.detection_hz, **kw)
    kf_t, stream = smoother.result["kf_t"], smoother.stream
    t = stream.seconds(exact.mocap.t_ns)
    pos = np.stack([np.interp(kf_t, t, exact.mocap.position[:, i]) for i in range(3)], axis=-1)
    near = np.clip(np.searchsorted(t, kf_t), 0, t.size - 1)
    rot = quats_to_rots(exact.mocap.quat_xyzw[near])
    landmarks = {int(k): v for k, v in exact.truth["landmarks"].items()}
    lms = np.array([landmarks[int(i)] for i in stream.landmark_ids], float)
    at_truth = graph.Guess(rot, pos, lms, sol.bias)
    at_sol = graph.Guess(sol.rot, sol.pos, sol.landmarks, sol.bias)
    empty = np.zeros(0, int)
    motion_only = replace(
        problem,
        kf_of_det=empty,
        det_idx=empty,
        det_y=problem.det_y[:0],
        det_sigma=problem.det_sigma[:0],
        det_shape=None if problem.det_shape is None else problem.det_shape[:0],
    )
    dims = 6 * problem.data.shape[0], 3 * problem.det_idx.shape[0]
    print(f"half the residual dimensions: motion {dims[0] / 2:.0f}, detections {dims[1] / 2:.0f}")
    for name, guess in (("solution", at_sol), ("truth", at_truth)):
        total, motion = graph.cost(problem, guess), graph.cost(motion_only, guess)
        where = ape(guess.pos, pos)
        print(f"cost at the {name}: {total:.1f} (motion {motion:.1f}, detections {total - motion:.1f}); {where:.3f} m")
    back = graph.solve(problem, at_truth, max_iterations=400, relative_tolerance=0.0)
    s = back.summary
    print(
        f"solved from the truth: cost {s['final_error']:.4f} after {s['iterations']} iterations "
        f"(converged {s['converged']}), {ape(back.pos, pos):.3f} m"
    )
    for floor in ("auto", False):
        res = stereo_logs.run(log, "riekf", args.cache / "runs" / f"{case.name}-riekf", {**noise, "floor": floor})
        print(f"riekf, noise.floor {floor}: APE {res['ape']:.3f} m")


if __name__ == "__main__":
    main()
