"""The smoother's evidence: which scale of a noise level the log itself supports, without ground truth.

For a scale ``s`` of a motion white-noise level (velocity, then gyro) the smoother is solved (warm-started from
the neighbouring scale's solution) and the Laplace approximation of the marginal likelihood of the measurements
given ``s`` (the trajectory, map and biases integrated out) is

    log Z(s) = −F(x*; s) − ½ log det H(x*; s) − ½ Σᵢ log det Σᵢ(s) + const,

with ``F`` the objective at the optimum (half the whitened squares, Huber-robust detections as solved), ``H`` the
Gauss–Newton normal matrix there (:func:`pipeline.smoother.graph.evidence_terms`: the log determinant comes from
the Cholesky factors the solver computes anyway) and ``Σᵢ`` each factor's covariance (only the relative-motion
factors' change with ``s``; their log determinants come from the whitening matrices, ``Σ⁻¹ = WᵀW``). A level
too low makes the odometry fight the detections (``F`` grows); one too high lets the trajectory float (the
Occam terms ``½ log det H − ½ Σ log det Σ`` grow): the scale with the highest ``log Z`` is kept. The constant
is the same for every scale: the same detections (the first solution's, after its χ² gate) and variables.
"""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.smoother.preintegration import D_END, D_W

#: The levels whose scale is chosen, one after the other (each at the scales already chosen before it).
KEYS = ("velocity", "gyro")
#: The velocity's axes across the heading (body y and z), scanned apart after ``KEYS`` when the velocity stream
#: holds its values (commanded): the held streams' fit gives one level for every axis (the detection pairs
#: cannot tell the forward drift from the sideways one), while a ground robot's command is a forward speed whose
#: sideways and vertical parts are zero by its kinematics. On MR.CLAM the evidence takes them x0.3 and batch's
#: APE falls (docs/benchmarks.md, "The velocity across the heading apart (MR.CLAM)").
ACROSS = "velocity_across"
#: Passes over ``KEYS`` go on while a scale moved (the levels trade off against each other, and a pass moves a
#: level by x3 up or x10 down at most), until the scans' linear solves exceed this many times those of the first
#: solution (the solver's work, counted rather than timed so that a run's result does not depend on the
#: machine's load), and at least ``SOLVE_FLOOR`` linear solves: on a small log the first solution takes few
#: (TagSLAM 22: 9, while one scan of the velocity took 93), and 20x of them stopped it after two passes.
SOLVE_BUDGET, SOLVE_FLOOR = 20.0, 600
#: Scales of each level tried, from the level the run would otherwise use (``noise: auto``, estimated
#: or defaulted); searched downwards from 1 while the evidence rises, else upwards.
SCALES = (0.1, 0.3, 1.0, 3.0)
#: The lowest overall scale of a level measured from its own stream's samples (``noise: auto``, a stream whose
#: samples move; not a held one's, nor a stated covariance): the samples' high-frequency content is a lower
#: bound of the stream's noise (coloured noise adds to it, docs/noise.md), so the evidence may raise such a level
#: but not take it below that bound by more than half a step of the ladder (x3: 1/√3; a pass that moved it x3 up
#: may still come back to x0.9). On stereo-like logs (depth error ~ r², benchmarks/stereo_logs.py) the evidence
#: took the measured velocity to x0.3 of its true level, and batch's APE 1.3-2x above the run at x1.
SAMPLE_FLOOR = float(1.0 / np.sqrt(3.0))
#: Above this many keyframes the choice is skipped (and the notes say so): on the one-hour benchmark log (72,002
#: keyframes) it took the smoother from 7.5 to 29.6 CPU s (the scales tried cost a solve each) and kept x1.
MAX_KEYFRAMES = 30_000
#: A scale replaces the current one only when it raises the log evidence by more than this: a Bayes factor above
#: 100, "decisive" on Jeffreys' scale. With a margin of 1 ``figure8_camera`` (267 detections) took its gyro to
#: x0.3 on a gain of 4.3 and batch got worse by 9 % (APE) and 15 % (map); where the detections cannot tell a level
#: the evidence is that flat, on the real logs it moved by tens to thousands.
MIN_GAIN = float(np.log(100.0))
#: A pass that moved no level but where a scale gained more than this (a Bayes factor above 10, "substantial" on
#: Jeffreys' scale) yet not ``MIN_GAIN`` takes that scale for one more pass: kept when that pass moves a level by
#: ``MIN_GAIN`` (the step was the first of a move the levels make together), else the search goes back to where it
#: was. On TagSLAM 22 with batch's gap factor the gyro's x3 gained 4.25 in pass 2 (5.66 without the factor) and
#: the search stopped at log evidence 522.5 where the velocity's x0.1 after it reached 576.9: a search whose result
#: flips with one step's gain a little under or over a fixed threshold (docs/benchmarks.md, "batch's level search
#: one pass past a near step").
NEAR_GAIN = float(np.log(10.0))
#: What the choice maximises, for run.json.
CRITERION = (
    "Laplace approximation of the marginal likelihood of the log's measurements given the noise level (the "
    "smoother's trajectory, map and biases integrated out)"
)


def motion_log_det(problem) -> float:
    """``Σᵢ log det Σᵢ`` of the relative-motion factors, from their whitening matrices (``W = L⁻¹``, lower
    triangular: ``log det Σ = −2 Σ log |diag W|``)."""
    w = problem.data[:, D_W:D_END].reshape(-1, 6, 6)
    return -2.0 * float(np.sum(np.log(np.abs(np.diagonal(w, axis1=1, axis2=2)))))


def detection_log_det(problem) -> float:
    """``Σ log det Σ`` of the detections: three axes of ``σ`` each, times ``S⁻¹`` when range and bearing are
    weighed apart (``det_shape``, :mod:`pipeline.smoother.anisotropy`): 0 for the scan's own shape (its volume
    kept), not for a ratio set in the configuration (its trace kept), so shapes of either kind compare."""
    isotropic = 6.0 * float(np.sum(np.log(np.maximum(problem.det_sigma, 1e-12))))
    if problem.det_shape is None:
        return isotropic
    return isotropic - float(np.sum(np.linalg.slogdet(problem.det_shape)[1]))


def walk_log_det(problem, n_segments: int) -> float:
    """``Σ log det Σ`` of the random-walk factors between the ``n_segments`` bias segments (diagonal, 6 axes
    each; 0 for one constant bias). With them the evidence compares bias models and walk levels: a segment adds
    six variables and one six-dimensional factor, so the ``2π`` terms cancel."""
    if problem.walk_sigma is None or n_segments < 2:
        return 0.0
    return 2.0 * (n_segments - 1) * float(np.sum(np.log(problem.walk_sigma)))


def log_evidence(problem, sol) -> float | None:
    """``log Z`` at the solution ``sol`` of ``problem`` (module docstring), up to a constant; None when the normal
    matrix there is not positive definite."""
    from slamobs.pipeline.smoother.graph import evidence_terms

    terms = evidence_terms(problem, sol)
    if terms is None:
        return None
    error, log_det_h = terms
    dets = motion_log_det(problem) + detection_log_det(problem) + walk_log_det(problem, sol.bias.shape[0])
    return -error - 0.5 * log_det_h - 0.5 * dets


def search_order(scales: tuple[float, ...] = SCALES) -> tuple[list[float], list[float]]:
    """The scales below 1 (nearest first) and above it: tried downwards while the evidence rises, else upwards."""
    return sorted((s for s in scales if s < 1.0), reverse=True), sorted(s for s in scales if s > 1.0)


def better(new: float | None, old: float | None) -> bool:
    """``new`` beats ``old`` by more than ``MIN_GAIN`` (None: not evaluated, never better)."""
    return new is not None and np.isfinite(new) and (old is None or not np.isfinite(old) or new > old + MIN_GAIN)


def climb(ladder, problem_at, solve, sols: dict, scores: dict) -> float:
    """Along ``ladder`` (scales moving away from 1) while the evidence rises: each scale's problem
    (``problem_at(scale)``) solved from the solution of the scale before (``solve(problem, start)``), its solution
    and log evidence put into ``sols`` and ``scores`` (which hold scale 1's); the last scale that rose (1: none)."""
    prev = 1.0
    for scale in ladder:
        problem = problem_at(scale)
        sols[scale] = solve(problem, sols[prev])
        scores[scale] = log_evidence(problem, sols[scale])
        if not better(scores[scale], scores[prev]):
            break
        prev = scale
    return prev


def best_scale(scores: dict[float, float | None]) -> float:
    """Of the scales whose evidence is within ``MIN_GAIN`` of the highest, the one nearest 1 (1 when none could be
    evaluated)."""
    valid = {s: z for s, z in scores.items() if z is not None and np.isfinite(z)}
    if not valid:
        return 1.0
    top = max(valid.values())
    return min((s for s, z in valid.items() if z >= top - MIN_GAIN), key=lambda s: abs(np.log(s)))


def near_step(scores: dict[float, float | None], winner: float) -> tuple[float, float] | None:
    """The scale of a scan that kept x1 (``winner``) whose evidence beat x1's by more than ``NEAR_GAIN`` (the
    highest such), and its gain; None when there is none (or the scan moved)."""
    if winner != 1.0 or scores.get(1.0) is None or not np.isfinite(scores[1.0]):
        return None
    gains = {s: z - scores[1.0] for s, z in scores.items() if s != 1.0 and z is not None and np.isfinite(z)}
    if not gains or max(gains.values()) <= NEAR_GAIN:
        return None
    scale = max(gains, key=gains.get)
    return scale, float(gains[scale])


def search(run_pass, take, undo, budget: float) -> tuple[list[list[str]], int, bool]:
    """Passes over the levels while one moves and the linear solves spent stay within ``budget``:
    ``run_pass(notes)`` makes one (its notes appended to ``notes``) and gives whether a level moved, the pass's near
    step (``(key, scale, gain, ...)``, :func:`near_step`) or None, and the solves it took. A pass that moved nothing
    but has a near step takes it (``take(near)``: the state before it, for ``undo``, and the solves) for one more
    pass: kept when that pass moves a level (the step was the first of a move the levels make together), else
    undone (``undo(state)``), so the search never ends below the evidence it had before the step. The notes of
    each pass, the solves spent, and whether the search stopped at its budget while a level still moved."""
    passes, spent, held, moved = [], 0, None, True
    while spent <= budget:
        passes.append([])
        moved, near, solves = run_pass(passes[-1])
        spent += solves
        if moved:
            held = None  # the step taken (if one was) led to a decisive one: kept
            continue
        if held is not None or near is None:
            break
        key, scale, gain = near[:3]
        passes[-1].append(
            f"batch: the evidence's {key} x{scale:g} gained {gain:.2f} (over {NEAR_GAIN:.2f}, under {MIN_GAIN:.2f}): "
            "taken for one more pass, kept if that pass moves a level"
        )
        held, solves = take(near)
        spent, moved = spent + solves, True
    if held is not None:
        undo(held)
        passes[-1].append(
            f"batch: the evidence's {key} x{scale:g} not kept: no pass after it moved a level by {MIN_GAIN:.2f} "
            "(the levels and the solution before it restored)"
        )
        moved = False
    return passes, spent, moved


def in_passes(passes: list[list[str]], again: bool = False) -> list[str]:
    """The choices' notes (:func:`record`) of each pass over the levels, each saying which pass it is when there
    were several, or when the scan was made again after range and bearing were weighed apart (``again``): the
    same level's note two or three times with other numbers read as a repetition."""
    if len(passes) == 1 and not again:
        return list(passes[0])

    def label(k: int) -> str:
        said = [f"pass {k} of {len(passes)}"] * (len(passes) > 1) + [
            "again after range and bearing were weighed apart"
        ] * again
        return "; ".join(said)

    return [
        note.replace("chosen by the evidence", f"chosen by the evidence ({label(k)})", 1)
        for k, notes in enumerate(passes, 1)
        for note in notes
    ]


def record(key: str, level: np.ndarray, scores: dict[float, float | None], winner: float) -> tuple[dict, str]:
    """The choice for run.json (observer.smoother.noise_scale.<key>) and its note."""
    table = {f"{s:g}": (None if z is None else round(float(z), 3)) for s, z in sorted(scores.items())}
    said = ", ".join(f"x{s} {z if z is not None else 'n/a'}" for s, z in table.items())
    kept = level * winner
    note = (
        f"batch: {key} noise level chosen by the evidence (log marginal likelihood): {said}; kept x{winner:g} "
        f"({', '.join(f'{v:.3g}' for v in np.atleast_1d(kept))})"
    )
    out = {"criterion": CRITERION, "log_evidence": table, "winner": winner, "level": kept.tolist()}
    return out, note
