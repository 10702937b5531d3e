"""The factor graph of the batch smoother, solved with GTSAM (used here only; ``estimator.require_gtsam`` imports
it to check that it is installed).

Variables: one ``Pose3`` per keyframe (keys ``0 .. K−1``), one ``Point3`` per landmark (``K .. K+L−1``) and the
bias ``[b_Ω; b_V]`` as a 6-vector, one per segment (``K+L ..``). Factors:

* each detection: GTSAM's ``BearingRangeFactor3D`` (the body-frame point as bearing and range, standard
  deviations ``σ/r`` and ``σ`` for an isotropic ``σ`` per axis, to first order the same model) with a Huber
  kernel on the norm of the whitened residual;
* a prior on the biases (zero mean, the prior standard deviations of the noise settings), a random walk
  between segment biases when the bias model asks for it, and the gauge: the anchor keyframe held at the
  seed's pose (the problem is invariant to one rigid transform, docs/observers.md §1.1);
* relative motion between consecutive keyframes, from the compiled preintegration
  (:mod:`pipeline.smoother.preintegration`): GTSAM has no preintegrated factor for body-velocity odometry.
  Its whitened residuals and analytic Jacobians are computed for all intervals in one compiled call and
  enter GTSAM's linear system as ``JacobianFactor`` s at each linearization.

Levenberg–Marquardt runs here (GTSAM linearizes its own factors, eliminates and retracts): GTSAM's optimizers
copy the whole ``Values`` into Python for every ``CustomFactor`` call (measured: 1.8 ms per call at 2,400
keyframes, growing with the log), so a Python-side factor cannot live inside them. The damping ``λI`` of
each keyframe rides in its relative-motion factor's extra rows.

Elimination order: the keyframes of each block of ``BLOCK`` consecutive keyframes, then the block
boundaries, then landmarks and biases: a block's keyframes only share the landmarks seen inside it, which
keeps the dense fronts small (for 9,000 keyframes and 30 landmarks, 3x faster than the time order and 4x
faster than COLAMD).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

#: Keyframes per elimination block (see the module docstring).
BLOCK = 100
#: Relative resolution at which landmark noise models are shared (one model per 1 % of standard deviation).
SIGMA_STEP = 0.01
#: Standard deviation of the gauge prior on the anchor keyframe (rad and m: effectively a constraint).
GAUGE_SIGMA = 1e-6


@dataclass
class Problem:
    """Everything the graph is built from (arrays, seconds and metres)."""

    data: np.ndarray  # (K−1, 75) preintegrated intervals (pipeline.smoother.preintegration layout)
    b_bar: np.ndarray  # (6,) bias the intervals were preintegrated at
    seg_of: np.ndarray  # (K−1,) bias segment of each interval
    kf_of_det: np.ndarray  # (M,) keyframe of each detection
    det_idx: np.ndarray  # (M,) landmark of each detection
    det_y: np.ndarray  # (M, 3) body-frame landmark positions
    det_sigma: np.ndarray  # (M,) per-axis standard deviation of each detection
    bias_prior_sigma: np.ndarray  # (6,)
    bias_prior_mean: np.ndarray  # (6,)
    walk_sigma: np.ndarray | None  # (6,) per segment step, None for one constant bias
    huber: float
    anchor: int  # keyframe held fixed (gauge)


@dataclass
class Guess:
    rot: np.ndarray  # (K, 3, 3)
    pos: np.ndarray  # (K, 3)
    landmarks: np.ndarray  # (L, 3)
    bias: np.ndarray  # (S, 6)


@dataclass
class Solution:
    rot: np.ndarray
    pos: np.ndarray
    landmarks: np.ndarray
    bias: np.ndarray  # (S, 6)
    bias_cov: np.ndarray  # (S, 6, 6) marginal covariance of each segment's bias
    summary: dict = field(default_factory=dict)


def _keys(problem: Problem, guess: Guess):
    """Keyframe count, landmark keys and bias keys (one per segment)."""
    k = problem.data.shape[0] + 1
    n_lm, n_seg = guess.landmarks.shape[0], guess.bias.shape[0]
    return k, np.arange(k, k + n_lm), np.arange(k + n_lm, k + n_lm + n_seg)


def build(problem: Problem, guess: Guess):
    """GTSAM's part of the graph (every factor but the relative motion) and the initial values."""
    import gtsam

    k, lm_keys, bias_keys = _keys(problem, guess)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i in range(k):
        values.insert(i, gtsam.Pose3(gtsam.Rot3(guess.rot[i]), guess.pos[i]))
    for key, p in zip(lm_keys, guess.landmarks):
        values.insert(int(key), np.asarray(p, dtype=float))
    for key, b in zip(bias_keys, guess.bias):
        values.insert(int(key), np.asarray(b, dtype=float))

    huber = gtsam.noiseModel.mEstimator.Huber.Create(problem.huber)
    models: dict[tuple[int, int], object] = {}
    ranges = np.linalg.norm(problem.det_y, axis=1)
    step = np.log1p(SIGMA_STEP)
    sig = np.maximum(problem.det_sigma, 1e-9)
    q_range = np.round(np.log(sig) / step).astype(np.int64)
    q_bear = np.round(np.log(sig / np.maximum(ranges, 1e-9)) / step).astype(np.int64)
    for m in range(problem.det_y.shape[0]):
        if ranges[m] <= 0.0:
            continue
        key = (int(q_bear[m]), int(q_range[m]))
        model = models.get(key)
        if model is None:
            sb, sr = np.exp(key[0] * step), np.exp(key[1] * step)
            model = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Diagonal.Sigmas(np.array([sb, sb, sr])))
            models[key] = model
        y = problem.det_y[m]
        graph.add(
            gtsam.BearingRangeFactor3D(
                int(problem.kf_of_det[m]),
                int(lm_keys[problem.det_idx[m]]),
                gtsam.Unit3(y / ranges[m]),
                float(ranges[m]),
                model,
            )
        )

    graph.add(
        gtsam.PriorFactorVector(
            int(bias_keys[0]),
            np.asarray(problem.bias_prior_mean, dtype=float),
            gtsam.noiseModel.Diagonal.Sigmas(problem.bias_prior_sigma),
        )
    )
    if problem.walk_sigma is not None:
        walk = gtsam.noiseModel.Diagonal.Sigmas(problem.walk_sigma)
        for a, b in zip(bias_keys[:-1], bias_keys[1:]):
            graph.add(gtsam.BetweenFactorVector(int(a), int(b), np.zeros(6), walk))
    a = problem.anchor
    graph.add(
        gtsam.PriorFactorPose3(
            a, gtsam.Pose3(gtsam.Rot3(guess.rot[a]), guess.pos[a]), gtsam.noiseModel.Isotropic.Sigma(6, GAUGE_SIGMA)
        )
    )
    return graph, values


def ordering(k: int, lm_keys: np.ndarray, bias_keys: np.ndarray):
    """Block-wise elimination order (module docstring)."""
    import gtsam

    order = gtsam.Ordering()
    bounds = set(range(0, k, BLOCK)) | {k - 1}
    for i in range(k):
        if i not in bounds:
            order.push_back(i)
    for i in sorted(bounds):
        order.push_back(i)
    for key in (*lm_keys, *bias_keys):
        order.push_back(int(key))
    return order


def _stats(x: np.ndarray) -> dict:
    if x.size == 0:
        return {"n": 0}
    return {
        "n": int(x.size),
        "rms": float(np.sqrt(np.mean(x * x))),
        "mean": float(np.mean(x)),
        "p95": float(np.percentile(x, 95)),
        "max": float(np.max(x)),
    }


class _Motion:
    """The relative-motion factors: their error, and their linearization as GTSAM ``JacobianFactor`` s."""

    CHUNK = 8192

    def __init__(self, problem: Problem, bias_keys: np.ndarray) -> None:
        import gtsam

        self.p = problem
        n = min(problem.data.shape[0], self.CHUNK)
        self.r = np.empty((n, 12))
        self.h = np.empty((n, 3, 12, 6))
        self.kb = [int(bias_keys[s]) for s in problem.seg_of]
        self.unit12 = gtsam.noiseModel.Unit.Create(12)

    def error(self, rot, pos, bias) -> float:
        from slamobs.pipeline.smoother.preintegration import motion_error

        p = self.p
        return 0.5 * motion_error(p.data, p.b_bar, rot, pos, bias, p.seg_of)

    def linearize(self, rot, pos, bias, damping: float, graph) -> None:
        import gtsam

        from slamobs.pipeline.smoother.preintegration import motion_linearize

        p, r, h, kb, unit = self.p, self.r, self.h, self.kb, self.unit12
        k = p.data.shape[0]
        for a in range(0, k, self.CHUNK):  # a chunk at a time: the Jacobians of a long log are 1.7 KB each
            b = min(k, a + self.CHUNK)
            motion_linearize(p.data[a:b], p.b_bar, rot[a : b + 1], pos[a : b + 1], bias, p.seg_of[a:b], damping, r, h)
            np.negative(r, out=r)  # JacobianFactor error is ‖A δ − b‖²: b = −residual
            for i in range(b - a):
                j = a + i
                graph.push_back(gtsam.JacobianFactor(j, h[i, 0], j + 1, h[i, 1], kb[j], h[i, 2], r[i], unit))


def _arrays(values, k: int, bias_keys: np.ndarray):
    import gtsam

    poses = gtsam.utilities.extractPose3(values)
    return (
        np.ascontiguousarray(poses[:, :9].reshape(-1, 3, 3)),
        np.ascontiguousarray(poses[:, 9:]),
        np.array([values.atVector(int(key)) for key in bias_keys]).reshape(-1, 6),
    )


def _damping(graph, keys_dims: list[tuple[int, int]], sqrt_lam: float) -> None:
    """``√λ I`` on the variables the relative-motion factors do not damp (last keyframe, landmarks, biases)."""
    import gtsam

    for key, dim in keys_dims:
        graph.push_back(
            gtsam.JacobianFactor(key, sqrt_lam * np.eye(dim), np.zeros(dim), gtsam.noiseModel.Unit.Create(dim))
        )


class _Steps:
    """One Levenberg–Marquardt problem: GTSAM's factors plus the compiled relative-motion factors, one
    elimination order, and the variables the motion factors do not damp."""

    def __init__(self, graph, motion: _Motion, order, k: int, lm_keys: np.ndarray, bias_keys: np.ndarray) -> None:
        self.graph, self.motion, self.order, self.k, self.bias_keys = graph, motion, order, k, bias_keys
        self.others = [(k - 1, 6), *((int(key), 3) for key in lm_keys), *((int(key), 6) for key in bias_keys)]

    def error(self, values, arrays) -> float:
        """The total error: GTSAM's factors and the relative-motion factors."""
        return self.graph.error(values) + self.motion.error(*arrays)

    def step(self, values, arrays, error: float, lam: float, lam_max: float = 1e10):
        """The first damped step (``λ`` raised tenfold until one is found) that lowers ``error``: the new values,
        arrays, error and (bias marginal, its ``λ``), or None; the ``λ`` reached and the linear solves made."""
        import gtsam

        base = self.graph.linearize(values)
        trials = 0
        while lam <= lam_max:
            trials += 1
            lin = gtsam.GaussianFactorGraph()
            lin.push_back(base)
            self.motion.linearize(*arrays, np.sqrt(lam), lin)
            _damping(lin, self.others, np.sqrt(lam))
            tree = lin.eliminateMultifrontal(self.order)
            del lin
            delta = tree.optimize()
            step_cov = (self._marginals(tree), lam)
            del tree
            new_values = values.retract(delta)
            del delta
            new_arrays = _arrays(new_values, self.k, self.bias_keys)
            new_error = self.error(new_values, new_arrays)
            if np.isfinite(new_error) and new_error < error:
                return (new_values, new_arrays, new_error, step_cov), lam, trials
            del new_values, new_arrays
            lam *= 10.0
        return None, lam, trials

    def bias_covariance(self, values, arrays) -> np.ndarray:
        """The biases' marginal covariance from an undamped factorization at ``values``."""
        lin = self.graph.linearize(values)
        self.motion.linearize(*arrays, 0.0, lin)
        tree = lin.eliminateMultifrontal(self.order)
        del lin
        return self._marginals(tree)

    def _marginals(self, tree) -> np.ndarray:
        """The biases' marginal covariances (segments × 6 × 6) from an eliminated Bayes tree."""
        return np.array([tree.marginalCovariance(int(key)) for key in self.bias_keys]).reshape(-1, 6, 6)


def solve(
    problem: Problem, guess: Guess, *, max_iterations: int = 50, relative_tolerance: float = 1e-5, progress=None
) -> Solution:
    """Levenberg–Marquardt from ``guess``; the solution, the biases' marginal covariance and a summary."""
    t0 = time.perf_counter()
    k = problem.data.shape[0] + 1
    _, lm_keys, bias_keys = _keys(problem, guess)
    graph, values = build(problem, guess)
    motion = _Motion(problem, bias_keys)
    t_build = time.perf_counter() - t0
    lm = _Steps(graph, motion, ordering(k, lm_keys, bias_keys), k, lm_keys, bias_keys)
    arrays = _arrays(values, k, bias_keys)
    errors = [lm.error(values, arrays)]
    lam = 1e-5
    iterations, converged, trials = 0, False, 0
    bias_cov, cov_lam = None, np.inf
    while iterations < max_iterations:
        step, lam, n = lm.step(values, arrays, errors[-1], lam)
        trials += n
        if step is None:
            converged = True  # no step decreases the error any more: a (local) minimum
            break
        # the marginal at the last point linearized (one small step before the solution)
        values, arrays, error, (bias_cov, cov_lam) = step
        del step
        iterations += 1
        errors.append(error)
        lam = max(lam / 10.0, 1e-12)
        if progress is not None:
            progress(f"batch: iteration {iterations}, error {error:.6g}")
        if errors[-2] - error <= relative_tolerance * errors[-2]:
            converged = True
            break
    t_solve = time.perf_counter() - t0 - t_build
    rot, pos, bias = arrays
    lms = np.array([values.atVector(int(key)) for key in lm_keys]).reshape(-1, 3)
    t = time.perf_counter()
    if bias_cov is None or cov_lam > 1e-3:  # no undamped factorization near the solution: one more
        bias_cov = lm.bias_covariance(values, arrays)
    t_marg = time.perf_counter() - t
    summary = {
        "iterations": iterations,
        "linear_solves": trials,
        "converged": converged,
        "initial_error": float(errors[0]),
        "final_error": float(errors[-1]),
        "error_per_iteration": [float(e) for e in errors],
        "variables": {"keyframes": int(k), "landmarks": int(lm_keys.size), "bias_segments": int(bias_keys.size)},
        "factors": int(graph.size()) + k - 1,
        "seconds": {"build": round(t_build, 3), "optimize": round(t_solve, 3), "covariance": round(t_marg, 3)},
    }
    return Solution(rot, pos, lms, bias, bias_cov, summary)


def cost(problem: Problem, guess: Guess) -> float:
    """The smoother's objective at ``guess``: every factor of ``problem`` (Huber-robust landmark factors, relative
    motion, bias priors; the gauge prior sits at the guess's own anchor pose and adds nothing), as GTSAM sums it
    (half the squared whitened residuals). Solutions from different seeds are compared by it."""
    _, _, bias_keys = _keys(problem, guess)
    graph, values = build(problem, guess)
    return float(graph.error(values)) + _Motion(problem, bias_keys).error(guess.rot, guess.pos, guess.bias)


def covariances(problem: Problem, sol: Solution, keyframes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Marginal covariances at the solution, from one undamped factorization: of the poses at ``keyframes``
    (K', 6, 6) and of every landmark (L, 3, 3), both in the map frame. GTSAM's pose marginal is that of the body
    twist ``ξ = (ω, v)`` in ``T̂ = T Exp(ξ)``; the written error ``(δθ, δp)``, ``R̂ = Exp(δθ) R``, ``p̂ = p + δp``
    is ``(R ω, R v)`` to first order. Both are conditioned on the gauge (the anchor keyframe held fixed)."""
    k, lm_keys, bias_keys = _keys(problem, Guess(sol.rot, sol.pos, sol.landmarks, sol.bias))
    graph, values = build(problem, Guess(sol.rot, sol.pos, sol.landmarks, sol.bias))
    lin = graph.linearize(values)
    del graph, values  # the nonlinear graph is not needed any more: memory for the factorization
    _Motion(problem, bias_keys).linearize(sol.rot, sol.pos, sol.bias, 0.0, lin)
    tree = lin.eliminateMultifrontal(ordering(k, lm_keys, bias_keys))
    del lin
    body = np.array([tree.marginalCovariance(int(i)) for i in keyframes]).reshape(-1, 6, 6)
    turn = np.zeros((keyframes.shape[0], 6, 6))
    turn[:, :3, :3] = turn[:, 3:, 3:] = sol.rot[keyframes]
    pose = np.einsum("nij,njk,nlk->nil", turn, body, turn)
    landmarks = np.array([tree.marginalCovariance(int(key)) for key in lm_keys]).reshape(-1, 3, 3)
    return pose, landmarks


def merge_summaries(first: dict, second: dict) -> dict:
    """The summary of a solve continued by a second one (after gating): counts added, errors joined."""
    out = dict(second)
    out["iterations"] = first["iterations"] + second["iterations"]
    out["linear_solves"] = first["linear_solves"] + second["linear_solves"]
    out["initial_error"] = first["initial_error"]
    out["error_per_iteration"] = first["error_per_iteration"] + second["error_per_iteration"]
    out["error_before_gating"] = first["final_error"]
    out["seconds"] = {k: round(first["seconds"][k] + second["seconds"][k], 3) for k in second["seconds"]}
    return out


def residual_statistics(problem: Problem, sol: Solution) -> dict:
    """Per factor type: residual sizes at the solution (metric and whitened), and how many detections the
    Huber kernel down-weights."""
    from slamobs.pipeline.smoother.preintegration import motion_residuals

    motion = motion_residuals(problem.data, problem.b_bar, sol.rot, sol.pos, sol.bias, problem.seg_of)
    kf = problem.kf_of_det
    pred = np.einsum("mji,mj->mi", sol.rot[kf], sol.landmarks[problem.det_idx] - sol.pos[kf])
    err = np.linalg.norm(pred - problem.det_y, axis=1)
    whitened = err / np.maximum(problem.det_sigma, 1e-12)
    bias_prior = (sol.bias[0] - problem.bias_prior_mean) / problem.bias_prior_sigma
    return {
        "relative_motion": {
            "rotation_deg": _stats(np.degrees(motion[:, 0])),
            "position_m": _stats(motion[:, 1]),
            "whitened": _stats(motion[:, 2]),
        },
        "landmark": {
            "error_m": _stats(err),
            "whitened": _stats(whitened),
            "huber_downweighted": int(np.count_nonzero(whitened > problem.huber)),
        },
        "bias_prior": {"whitened": _stats(np.abs(bias_prior))},
    }
