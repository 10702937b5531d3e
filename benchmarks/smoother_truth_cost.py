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

``--tilt DEG``: also the graph with what a floor would add to it, the body's up axis the same at every keyframe
to DEG (a virtual landmark ``UP_M`` straight above the body, seen from each keyframe with σ = ``UP_M``·tan DEG per
axis: tilt only, no height), solved from the solution and from the truth to convergence; their APE. With
``--height M`` also the body's height above one plane to M (a second virtual landmark ``UP_M`` below the body,
weighed along the body's up axis; ``SLACK``: σ across it ~100x larger, 5 m at M = 0.05, so a weak pull of every
keyframe towards one vertical line comes with it). An experiment of what a floor would give, not a factor of the
smoother.
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

#: m, the virtual landmark of ``--tilt`` above the body
UP_M = 1000.0
#: ``--height``: how much less the landmark below weighs across the body's up axis than along it (σ ratio)
SLACK = 100.0


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


def with_up_axis(problem, n_landmarks: int, sigma: float, height: float | None = None):
    """``problem`` with one more landmark seen ``UP_M`` straight above the body from every keyframe (σ per axis);
    with ``height`` (m) one more seen ``UP_M`` below it too, weighed along the body's up axis only (σ ``height``
    there, ``SLACK`` times larger across): the body's height above one plane."""
    k, lm = problem.data.shape[0] + 1, n_landmarks
    n = 1 + (height is not None)
    kfs = np.tile(np.arange(k), n)
    shape = np.tile(np.eye(3), (n * k, 1, 1))
    y, sig = np.tile([0.0, 0.0, UP_M], (n * k, 1)), np.full(n * k, sigma)
    if height is not None:
        a = SLACK ** (-2.0 / 3.0)  # information a, a, 1/a² (determinant 1): σ_z = σ·a, σ across = σ/√a
        shape[k:] = np.diag([a, a, 1.0 / a**2])
        y[k:, 2], sig[k:] = -UP_M, height / a
    return replace(
        problem,
        kf_of_det=np.concatenate([problem.kf_of_det, kfs]),
        det_idx=np.concatenate([problem.det_idx, np.repeat(lm + np.arange(n), k)]),
        det_y=np.concatenate([problem.det_y, y]),
        det_sigma=np.concatenate([problem.det_sigma, sig]),
        det_shape=np.concatenate([np.tile(np.eye(3), (problem.det_idx.size, 1, 1)), shape])
        if problem.det_shape is None
        else np.concatenate([problem.det_shape, shape]),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-stereo-logs")
    ap.add_argument("--sweep", choices=("issue", "unseen"), default="unseen")
    ap.add_argument("--case", type=int, default=2, help="index into the sweep's cases")
    ap.add_argument("--reseed", type=int, default=0)
    ap.add_argument("--tilt", type=float, nargs="*", default=[], help="degrees: the graph with a common up axis")
    ap.add_argument("--height", type=float, default=None, help="m: with --tilt, the height above one plane too")
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
    wobble = np.degrees(np.arccos(np.clip(rot[:, 2, 2], -1.0, 1.0)))
    print(f"the truth's body up axis from the vertical: {wobble.mean():.2f} deg mean, {wobble.max():.2f} at most")
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
    height = f" and height to {args.height:g} m" if args.height is not None else ""
    for deg in args.tilt:
        up = with_up_axis(problem, sol.landmarks.shape[0], UP_M * np.tan(np.radians(deg)), args.height)
        for name, g in (("the solution", at_sol), ("the truth", at_truth)):
            above = [g.pos[problem.anchor] + s * UP_M * g.rot[problem.anchor][:, 2] for s in (1.0, -1.0)]
            lms_up = np.vstack([g.landmarks, *above[: 1 + (args.height is not None)]])
            tilted = graph.solve(
                up, graph.Guess(g.rot, g.pos, lms_up, g.bias), max_iterations=600, relative_tolerance=0.0
            )
            t = tilted.summary
            print(
                f"with a common up axis to {deg:g} deg{height}, from {name}: {ape(tilted.pos, pos):.3f} m (cost "
                f"{t['final_error']:.1f}, {t['iterations']} iterations, converged {t['converged']})"
            )
    for floor in ("auto", False):
        res = stereo_logs.run(log, "riekf", args.cache / "runs" / f"{case.name}-riekf", {**noise, "floor": floor})
        print(f"riekf, noise.floor {floor}: APE {res['ape']:.3f} m")


if __name__ == "__main__":
    main()
