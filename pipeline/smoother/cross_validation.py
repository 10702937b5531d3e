"""Choosing the smoother's noise scales by blocked cross-validation: how well it predicts detections it did not
see (``batch.noise_selection: cross_validation``; docs/noise.md).

The evidence (:mod:`pipeline.smoother.evidence`) is an in-sample criterion under a white-noise model: where the
detections' errors are correlated in time (MR.CLAM: a range error that decorrelates over 8-32 s) it rewards
levels that let the trajectory follow that slow error. Held-out prediction does not assume the model is right.
For each candidate pair of scales (``motion`` on the gyro and velocity levels together, ``detection`` on the
detection law) the detections are split into ``FOLDS`` folds of interleaved time blocks of ``BLOCK_S`` seconds
(longer than the errors' correlation, so a held-out block is not predicted by its own slow error seen next to
it); fold ``k`` drops its detections (those of a landmark seen only there are kept with their standard
deviation multiplied by ``HELD_OUT``, so that it stays determined; they are not scored), is solved
warm-started from the full solution (at most ``MAX_ITERATIONS``), and its held-out detections are predicted
from the fold's trajectory and map. The score of a candidate is the Huber-robust sum over every held-out
detection of its prediction error whitened by the FIXED reference law (the run's law before any scale): a
candidate's own law does not enter its score, so a wider law cannot buy a lower score. Of the candidates
within ``MIN_GAIN`` (relative) of the lowest score, the one nearest (x1, x1) wins.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from slamobs.pipeline.noise import DETECTION_LAW_KEYS

#: Candidate scales of the motion levels (gyro and velocity together) and of the detection law: the hand-set
#: grid of ``benchmarks/real_logs.py`` (so the choice can be scored against that grid's best).
MOTION_SCALES = (0.1, 1.0, 10.0)
DETECTION_SCALES = (0.3, 1.0, 3.0)
#: Folds and the length of their interleaved blocks, s: block ``b`` (from the first detection) is in fold
#: ``b mod FOLDS``.
FOLDS, BLOCK_S = 4, 60.0
#: The standard deviation of a held-out detection whose landmark has no other one in the fold is multiplied by
#: this (weight 1e-8 of a kept one). Every held-out detection kept so (before dropping them) leaked: on
#: TagSLAM 11 (mm detections, hundreds a second) at motion x10, detection x0.3 the held-out errors fell 35-fold.
HELD_OUT = 1e4
#: Levenberg–Marquardt iterations per fold solve (warm-started from the full solution).
MAX_ITERATIONS = 20
#: Scores within this fraction of the lowest are ties (the folds' scores are noisy at about a per cent): of them,
#: the pair nearest x1, x1 wins.
MIN_GAIN = 0.01
#: What the choice minimises, for run.json.
CRITERION = (
    f"blocked cross-validation: {FOLDS} folds of interleaved {BLOCK_S:g} s blocks of detections held out, each "
    "fold solved without them; Huber-robust sum of the held-out detections' prediction errors whitened by the "
    "run's detection law before any scale"
)
MOTION_KEYS = ("gyro", "velocity")


def fold_of(t_det: np.ndarray, n_folds: int | None = None, block_s: float | None = None) -> np.ndarray:
    """The fold of each detection (stamps ``t_det``, s): blocks of ``block_s`` (``BLOCK_S``) from the first,
    interleaved over ``n_folds`` (``FOLDS``); on a log too short for two blocks per fold, blocks of an eighth
    of its span (for four folds)."""
    n_folds, block_s = n_folds or FOLDS, block_s or BLOCK_S
    if t_det.size == 0:
        return np.zeros(0, np.int64)
    block_s = min(block_s, max(float(np.ptp(t_det)), 1e-9) / (2 * n_folds))
    return ((t_det - t_det.min()) // block_s).astype(np.int64) % n_folds


def subset(problem, keep: np.ndarray, det_sigma: np.ndarray | None = None):
    """``problem`` with only the detections ``keep`` (a mask or indices), their standard deviations
    ``det_sigma`` (all the problem's detections) if given."""
    sigma = problem.det_sigma if det_sigma is None else det_sigma
    return replace(
        problem,
        kf_of_det=problem.kf_of_det[keep],
        det_idx=problem.det_idx[keep],
        det_y=problem.det_y[keep],
        det_sigma=sigma[keep],
        det_shape=None if problem.det_shape is None else problem.det_shape[keep],
    )


def holding_out(problem, held: np.ndarray, seen: np.ndarray):
    """``problem`` without the detections ``held`` (a mask), except those of landmarks with no other detection
    (``seen[landmark]`` False): kept with their standard deviation x ``HELD_OUT``, they keep the landmark
    determined, and pull on nothing else (their landmark follows them)."""
    keep = ~held | ~seen[problem.det_idx]
    return subset(problem, keep, np.where(held, problem.det_sigma * HELD_OUT, problem.det_sigma))


def prediction_errors(problem, sol) -> np.ndarray:
    """The body-frame prediction error ``Rᵀ(ℓ − P) − y`` of every detection of ``problem`` at ``sol``."""
    kf, lm = problem.kf_of_det, problem.det_idx
    pred = np.einsum("mji,mj->mi", sol.rot[kf], sol.landmarks[lm] - sol.pos[kf])
    return pred - problem.det_y


def candidate_problem(problem, motion_data, motion: float, detection: float):
    """``problem`` at the scales (``motion_data(scale)``: the relative-motion factors' data at that scale)."""
    data = problem.data if motion == 1.0 else motion_data(motion)
    return replace(problem, data=data, det_sigma=problem.det_sigma * detection)


def cross_validate(problem, start, folds: np.ndarray, motion_data, solve, scales) -> dict:
    """Per candidate ``(motion, detection)`` of ``scales``: the score (module docstring) summed over the folds,
    its per-fold parts and the linear solves taken. ``problem`` and ``start`` (a graph.Guess) are the full
    solution's; ``solve(problem, guess)`` solves a fold; a detection whose landmark has no kept detection in its
    fold is not scored (nothing predicts it)."""
    from slamobs.pipeline.smoother.candidates import detection_cost
    from slamobs.pipeline.smoother.graph import Guess

    out = {}
    for motion, detection in scales:
        cand = candidate_problem(problem, motion_data, motion, detection)
        parts, sse, solves = [], 0.0, 0
        for k in np.unique(folds):
            held = folds == k
            seen = np.zeros(start.landmarks.shape[0], bool)
            seen[problem.det_idx[~held]] = True
            which = np.flatnonzero(held & seen[problem.det_idx])
            sol = solve(holding_out(cand, held, seen), Guess(start.rot, start.pos, start.landmarks, start.bias))
            solves += int(sol.summary.get("linear_solves", 0))
            scored = subset(problem, which)  # at the run's own law: the fixed reference
            parts.append(detection_cost(scored, sol.rot, sol.pos, sol.landmarks))
            sse += float(np.sum(prediction_errors(scored, sol) ** 2))
        out[motion, detection] = {"score": float(np.sum(parts)), "folds": parts, "sse": sse, "solves": solves}
    return out


def candidates(motion_free: bool, detection_free: bool) -> list[tuple[float, float]]:
    """The scale pairs tried: a level set in the configuration is not scaled (its scales are x1 only)."""
    ms = MOTION_SCALES if motion_free else (1.0,)
    ds = DETECTION_SCALES if detection_free else (1.0,)
    return [(m, d) for m in ms for d in ds]


def winner(scores: dict) -> tuple[float, float]:
    """Of the pairs whose score is within ``MIN_GAIN`` (relative) of the lowest, the one nearest (1, 1) (in
    ``|log m| + |log d|``): the folds' scores are noisy at about a per cent, and near-ties are no evidence
    to move; (1, 1) when none could be scored."""
    valid = {p: v["score"] for p, v in scores.items() if np.isfinite(v["score"])}
    if not valid:
        return 1.0, 1.0
    top = min(valid.values())
    near = [p for p, v in valid.items() if v <= top * (1.0 + MIN_GAIN)]
    return min(near, key=lambda p: abs(np.log(p[0])) + abs(np.log(p[1])))


def scaled_noise(noise, motion: float, detection: float, motion_keys=MOTION_KEYS):
    """``noise`` with the motion levels ``motion_keys`` scaled by ``motion`` and the detection law by
    ``detection``, the methods saying so."""
    factors = {**dict.fromkeys(motion_keys, motion), **dict.fromkeys(DETECTION_LAW_KEYS, detection)}
    return noise.scaled(factors, "the smoother's cross-validation")


def record(scores: dict, chosen: tuple[float, float], n_det: int) -> tuple[dict, str]:
    """The choice for run.json (observer.smoother.noise_scale.cross_validation) and its note."""
    table = {f"motion x{m:g}, detection x{d:g}": round(v["score"], 3) for (m, d), v in sorted(scores.items())}
    said = ", ".join(f"{k} {v}" for k, v in table.items())
    note = (
        f"batch: noise scales chosen by blocked cross-validation ({FOLDS} folds of {BLOCK_S:g} s blocks, "
        f"{n_det} detections; held-out score, lower is better): {said}; kept motion x{chosen[0]:g}, detection "
        f"x{chosen[1]:g}"
    )
    out = {
        "criterion": CRITERION,
        "scores": table,
        "folds": {k: [round(x, 3) for x in v["folds"]] for k, v in zip(table, (scores[p] for p in sorted(scores)))},
        "squared_error_m2": {k: round(scores[p]["sse"], 4) for k, p in zip(table, sorted(scores))},
        "winner": {"motion": chosen[0], "detection": chosen[1]},
        "linear_solves": int(sum(v["solves"] for v in scores.values())),
    }
    return out, note
