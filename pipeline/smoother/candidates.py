"""Several starts for the batch smoother, and the rule that keeps one (docs/observers.md, batch: "Never worse
than its seed"). On a log of at most ``ALWAYS_MAX_KEYFRAMES`` keyframes every start is tried; on a longer one
only when the first solution is doubtful:

the smoother's first solution, from the configured seed, is doubtful when more than ``estimator.MAX_GATED`` of
the detections fail the χ² gate at it, or when its seed explains the detections better than it does (the
Huber-robust cost of the landmark factors alone is lower at the seed's trajectory and map than at the
solution: the smoother gave up detection fit for odometry fit, which a wrong noise model does), or when its
solution fails the global model test (``GLOBAL_CHI2_DOUBT``). The other starts (``extra_seeds``: dead
reckoning, and riekf where its dense covariance is cheap) are each moved rigidly onto the first seed's gauge
(its anchor keyframe) and solved like the first. Every candidate
(each start as it is, and each smoother solution) is scored by one criterion, evaluated identically for all:
the smoother's own objective (:func:`pipeline.smoother.graph.cost`) over every detection, before any gating,
with the odometry preintegrated about the candidate's own (mean) bias, so that the first-order bias correction
of the preintegration does not favour the candidate whose bias it was computed at. The lowest wins.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from slamobs.pipeline.lie import umeyama
from slamobs.pipeline.smoother.settings import DEAD_RECKONING

CRITERION = (
    "the smoother's robust graph cost over every detection (before gating), odometry preintegrated at each "
    "candidate's bias"
)
#: What the final check against the starts scores (the estimator's ``_against_seeds``).
SEED_CHECK_CRITERION = (
    "the smoother's robust graph cost over every detection (before gating) under the final noise model, odometry "
    "preintegrated about the kept candidate's seed's bias (another seed's: about its own)"
)
#: The first solution is doubtful too when it fails the global model test: its χ² (whitened squares of every
#: detection and relative-motion factor) over the redundancy ``d·(M − L)`` (``M`` detections of ``L`` landmarks,
#: ``d`` measured axes) above this (1 expected; the sample logs 1.00). With noise levels that fit the log the gate
#: no longer flags a smoother stopped near a poor seed (MR.CLAM seeded by fast-adaptation: 3.4 to 13; from dead
#: reckoning or riekf 1.05 to 1.75); with levels far too small it is always above (MR.CLAM on the defaults: 70-280).
GLOBAL_CHI2_DOUBT = 2.5
#: A candidate replaces the first solution only when it lowers the objective (half the whitened squares) by more
#: than this: a likelihood ratio above e. Starts that reach the same minimum differ by the solver's tolerance
#: (figure8_camera: 637.518 against 637.487), and the configured seed's solution then stays.
TIE_COST = 1.0
#: riekf is tried as a start only up to this many landmarks (its covariance is dense: (12 + 3n)² per frame).
RIEKF_SEED_MAX_LANDMARKS = 200
#: Up to this many keyframes the other starts are tried on every log, doubtful or not: a solution can pass every
#: check above and still sit in a wrong minimum, the noise model loose enough to hold it (a generated stereo-like
#: loop, 10 Hz, ~30 % range error: from fast-adaptation's start χ² 1.4 at an APE of 12.5 m, 18.3 m after the
#: evidence; from riekf's 1.3 m at a lower cost). Longer logs try them only when doubtful (each start is a solve).
ALWAYS_MAX_KEYFRAMES = 30_000


@dataclass
class Candidate:
    """One start and what the smoother made of it (``sol`` None: the start itself, as a candidate)."""

    seed: object  # seed.Seed
    problem: object | None = None  # graph.Problem solved last (after gating)
    sol: object | None = None  # graph.Solution
    notes: list[str] | None = None
    cost: float = float("nan")

    @property
    def name(self) -> str:
        return self.seed.name if self.sol is not None else f"{self.seed.name} (unsmoothed)"

    def guess(self, n_segments: int):
        """The candidate's trajectory, map and biases as a graph guess of ``n_segments`` bias segments (a start's one
        bias in each: the graph reads segment ``seg_of[j]``'s row for interval ``j``, and a single row for several
        segments was read past its end, a random-walk log's starts then scored from whatever memory followed)."""
        from slamobs.pipeline.smoother.graph import Guess

        if self.sol is not None:
            return Guess(self.sol.rot, self.sol.pos, self.sol.landmarks, self.sol.bias)
        return Guess(self.seed.rot, self.seed.pos, self.seed.landmarks, np.tile(self.seed.bias, (n_segments, 1)))


def detection_cost(problem, rot: np.ndarray, pos: np.ndarray, landmarks: np.ndarray) -> float:
    """Huber-robust cost of the landmark factors alone (threshold ``problem.huber``, whitened residual norms: the
    range and bearing weighed apart, or in inverse depth, by their shape as the solver weighs them)."""
    from slamobs.pipeline.smoother.graph import whiten_detections

    kf = problem.kf_of_det
    pred = np.einsum("mji,mj->mi", rot[kf], landmarks[problem.det_idx] - pos[kf])
    r = np.linalg.norm(whiten_detections(problem, pred - problem.det_y), axis=1)
    k = problem.huber
    return float(np.sum(np.where(r <= k, 0.5 * r * r, k * (r - 0.5 * k))))


def doubt(problem, first: Candidate) -> str | None:
    """Why the first solution is doubtful (module docstring), or None. ``problem`` has every detection."""
    if first.notes:
        return "many detections fail the χ² gate at the solution"
    at_seed = detection_cost(problem, first.seed.rot, first.seed.pos, first.seed.landmarks)
    at_sol = detection_cost(problem, first.sol.rot, first.sol.pos, first.sol.landmarks)
    if at_seed < at_sol:
        return f"the seed explains the detections better than the solution (robust cost {at_seed:.4g} < {at_sol:.4g})"
    ratio = global_chi2(problem, first.sol)
    if ratio > GLOBAL_CHI2_DOUBT:
        return f"the solution fails the global model test (chi-square over redundancy {ratio:.3g})"
    return None


def why_other_starts(problem, first: Candidate, keyframes: int) -> str | None:
    """Why the other starts are tried (the first solution's doubt, or a log short enough to try them always:
    ``ALWAYS_MAX_KEYFRAMES``), or None."""
    if (reason := doubt(problem, first)) is not None:
        return f"first solution doubtful ({reason})"
    if keyframes <= ALWAYS_MAX_KEYFRAMES:
        return f"every start tried on a log of {keyframes} keyframes (at most {ALWAYS_MAX_KEYFRAMES})"
    return None


def global_chi2(problem, sol) -> float:
    """χ² of the detection and relative-motion factors at ``sol`` over the redundancy (``GLOBAL_CHI2_DOUBT``);
    0 without redundancy."""
    from slamobs.pipeline.smoother.graph import whitened_residuals
    from slamobs.pipeline.smoother.preintegration import motion_residuals

    det = np.sum(whitened_residuals(problem, sol) ** 2)  # the shape too (range/bearing apart, inverse depth)
    motion = motion_residuals(problem.data, problem.b_bar, sol.rot, sol.pos, sol.bias, problem.seg_of)[:, 2]
    axes = int(np.count_nonzero(np.any(problem.det_y != 0.0, axis=0)))
    redundancy = axes * (problem.det_idx.shape[0] - np.unique(problem.det_idx).shape[0])
    return float((det + np.sum(motion**2)) / redundancy) if redundancy > 0 else 0.0


def extra_seeds(configured: str, n_landmarks: int) -> list[str]:
    """The other starts to try when the first solution is doubtful."""
    names = [DEAD_RECKONING]
    if n_landmarks <= RIEKF_SEED_MAX_LANDMARKS:
        names.append("riekf")
    return [n for n in names if n != configured]


def align_to(seed, ref, anchor: int):
    """``seed`` moved rigidly so that its pose at keyframe ``anchor`` is ``ref``'s (the smoother's gauge)."""
    rot = ref.rot[anchor] @ seed.rot[anchor].T
    trans = ref.pos[anchor] - rot @ seed.pos[anchor]
    return replace(
        seed,
        rot=np.einsum("ij,kjl->kil", rot, seed.rot),
        pos=seed.pos @ rot.T + trans,
        landmarks=seed.landmarks @ rot.T + trans,
    )


def disagreement(a, b) -> float:
    """APE between two starts: RMSE of their keyframe positions after a rigid alignment (m)."""
    if a.pos.shape[0] < 3:
        return float(np.sqrt(np.mean(np.sum((a.pos - b.pos) ** 2, axis=1))))
    rot, trans, _ = umeyama(b.pos, a.pos)
    return float(np.sqrt(np.mean(np.sum((b.pos @ rot.T + trans - a.pos) ** 2, axis=1))))


def choose(candidates: list[Candidate]) -> Candidate:
    """The lowest-cost candidate, unless it beats the first (the configured seed's solution) by no more than
    ``TIE_COST``: then the first."""
    best = min(candidates, key=lambda c: c.cost)
    first = candidates[0]
    return first if first.cost - best.cost <= TIE_COST else best


def record(reason: str, candidates: list[Candidate], best: Candidate, first_seed) -> tuple[dict, str]:
    """The choice for run.json (observer.smoother.candidates) and its note. ``solution_ape_m``: each candidate's
    trajectory (its solution, or the start as it is) against the winner's; near 0 where two starts reached one
    minimum (their costs then differ by the solver's tolerance, MR.CLAM 6 robot 1: dead reckoning and riekf,
    5.6 m apart as starts, 0.4 mm as solutions)."""
    trajectory = {c.name: c.sol if c.sol is not None else c.seed for c in candidates}
    table = {
        c.name: {
            "cost": c.cost,
            "gate_failed": bool(c.notes),
            "seed_ape_m": round(disagreement(first_seed, c.seed), 6),
            "solution_ape_m": round(disagreement(trajectory[best.name], trajectory[c.name]), 6),
        }
        for c in candidates
    }
    spread = max(v["seed_ape_m"] for v in table.values())
    costs = ", ".join(f"{name} {v['cost']:.6g}" for name, v in table.items())
    tied = best.cost > min(c.cost for c in candidates)
    tie = f" (no start lowers the cost by more than {TIE_COST:g}: a tie)" if tied else ""
    reached = ", ".join(
        f"{c.name} {table[c.name]['solution_ape_m']:.3g} m" for c in candidates if c.sol is not None and c is not best
    )
    note = (
        f"batch: {reason}; tried {len(candidates)} candidates, robust graph cost: "
        f"{costs}; kept '{best.name}'{tie}; the starts disagreed by up to {spread:.3g} m (APE against "
        f"'{first_seed.name}'); the other solutions against the kept one: {reached or 'none'}"
    )
    return {"reason": reason, "criterion": CRITERION, "winner": best.name, "candidates": table}, note


def seed_check(found: list[Candidate], kept: Candidate) -> dict:
    """The final check against the starts (the estimator's ``_against_seeds``) for run.json
    (observer.smoother.seed_check): the criterion, each one's cost under the final noise model, the one kept."""
    costs = {c.name if c.sol is None else "solution": round(float(c.cost), 6) for c in found}
    kept_name = "solution" if kept.sol is not None and kept is found[0] else kept.name
    return {"criterion": SEED_CHECK_CRITERION, "cost": costs, "kept": kept_name}


def seed_check_note(record: dict) -> str:
    """The note when a start as it is beat the final solution."""
    costs = ", ".join(f"{name} {cost:.6g}" for name, cost in record["cost"].items())
    return (
        f"batch: the final solution (after the noise levels, range/bearing and correlation steps) scored worse "
        f"than a start as it is under the final noise model ({costs}): kept '{record['kept']}'"
    )
