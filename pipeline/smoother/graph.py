"""The batch smoother's least-squares problem and its Levenberg–Marquardt solution.

Variables: one pose per keyframe, one point per landmark and the bias ``[b_Ω; b_V]`` as a 6-vector, one per
segment. Factors:

* each detection: the body-frame point ``Rᵀ(ℓ − P) − y``, a standard deviation ``σ`` per axis, or its
  range apart from its bearing (``det_shape``, :mod:`pipeline.smoother.anisotropy`), with a Huber kernel on the
  norm of the whitened residual (the model of the χ² gate, the candidates' detection
  cost and the residual statistics);
* a prior on the biases (zero mean, the prior standard deviations of the noise settings), a random walk
  between segment biases when the bias model asks for it, and the gauge: the anchor keyframe held at the
  seed's pose by a prior of ``GAUGE_SIGMA`` (the problem is invariant to one rigid transform,
  docs/observers.md §1.1);
* relative motion between consecutive keyframes, from the compiled preintegration
  (:mod:`pipeline.smoother.preintegration`; GTSAM has no preintegrated factor for body-velocity odometry);
* on a ground robot whose floor is held (riekf's decision, ``noise.floor``: :func:`pipeline.observers.riekf.
  floor_decision`), the floor at each keyframe (:func:`floor_terms`): the body's up axis normal to one plane (two
  rows, without the heading about the normal) and the position's height on it, the plane through the anchor's
  position with the keyframes' mean up axis its normal (:func:`floor_at`); the gauge then holds the anchor's
  position and heading, its tilt left to the floor.

The normal equations are formed and solved by compiled code over their structure (block tridiagonal in the
poses with a border of landmark and bias columns, :mod:`pipeline.smoother.solver`): on the one-hour benchmark
log (72,000 keyframes, 577,200 detections) one linearization and solve takes about a second and the marginal
covariances one more, where GTSAM's general elimination of the same graph (with a Python object per factor)
took tens of seconds and 1.7 GB. ``benchmarks/batch_gtsam.py`` solves the same graph with GTSAM's stock
factors for comparison.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from slamobs.pipeline.lie import floor_tilt_rows

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
    #: (M, 3, 3) each detection's body-frame information relative to ``1/σ²`` (range and bearing weighed apart,
    #: :mod:`pipeline.smoother.anisotropy`; determinant 1), or None: isotropic, ``σ`` on every axis
    det_shape: np.ndarray | None = None
    #: (K, 2) each keyframe's floor information (the tilt rows' and the height row's ``1/σ²``), or None: no floor
    floor: np.ndarray | None = None


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


class Normal:
    """The normal equations of ``problem`` at one point, the factors that solve them, and the total error.
    Public: the smoother's tests solve with it directly."""

    def __init__(self, problem: Problem, guess: Guess) -> None:
        p = self.p = problem
        k, self.n_lm, self.n_seg = p.data.shape[0] + 1, guess.landmarks.shape[0], guess.bias.shape[0]
        order = np.argsort(p.kf_of_det, kind="stable")  # the detections of each keyframe together
        self.kf, self.idx = p.kf_of_det[order], p.det_idx[order]
        self.y, self.sigma = np.ascontiguousarray(p.det_y[order], float), p.det_sigma[order].astype(float)
        self.shape = np.zeros((0, 3, 3)) if p.det_shape is None else np.ascontiguousarray(p.det_shape[order], float)
        self.det_start = np.searchsorted(self.kf, np.arange(k + 1))
        self.gauge = (guess.rot[p.anchor].copy(), guess.pos[p.anchor].copy())
        #: the floor's plane (:func:`floor_at`), fixed for this solve from the guess; its normal in the anchor's
        #: body frame, the one rotation the gauge holds with the floor (the floor holds the tilt)
        self.plane = None if p.floor is None else floor_at(guess.rot, guess.pos, p.anchor)
        self.gauge_axis = None if self.plane is None else self.gauge[0].T @ self.plane[1:4]
        nb = 3 * self.n_lm + 6 * self.n_seg
        self.ad, self.ao, self.mb = np.zeros((k, 6, 6)), np.zeros((k - 1, 6, 6)), np.zeros((k - 1, 2, 6, 6))
        self.ga, self.c, self.gb = np.zeros((k, 6)), np.zeros((nb, nb)), np.zeros(nb)
        self.weight, self.scratch = np.zeros(self.kf.shape[0]), np.zeros(self.kf.shape[0])
        self.dd, self.ee = np.zeros((k, 6, 6)), np.zeros((k, 6, 6))
        self.at = None

    def error(self, pt: tuple) -> float:
        """Half the squared whitened residuals (Huber-robust for the detections) at ``pt`` (rot, pos, lms, bias)."""
        from slamobs.pipeline.smoother.preintegration import motion_error
        from slamobs.pipeline.smoother.solver import detection_terms

        p, (rot, pos, lms, bias) = self.p, pt
        total = detection_terms(rot, pos, lms, self.kf, self.idx, self.y, self.sigma, self.shape, p.huber, self.scratch)
        total += 0.5 * motion_error(p.data, p.b_bar, rot, pos, bias, p.seg_of)
        total += 0.5 * np.sum(((bias[0] - p.bias_prior_mean) / p.bias_prior_sigma) ** 2)
        if p.walk_sigma is not None:
            total += 0.5 * np.sum((np.diff(bias, axis=0) / p.walk_sigma) ** 2)
        dev = self._gauge_deviation(rot, pos) / GAUGE_SIGMA
        if p.floor is not None:
            r, _ = floor_terms(self.plane, rot, pos)
            total += 0.5 * float(np.sum(r * r * p.floor[:, [0, 0, 1]]))
        return float(total + 0.5 * dev @ dev)

    def _gauge_deviation(self, rot, pos) -> np.ndarray:
        """The gauge prior's residual at the anchor: its pose's deviation from the guess's
        (:func:`pipeline.smoother.solver.pose_deviation`); with the floor, of its rotation only the part about
        the floor's normal (its heading), the tilt left to the floor."""
        from slamobs.pipeline.smoother.solver import pose_deviation

        dev = pose_deviation(*self.gauge, rot[self.p.anchor], pos[self.p.anchor])
        if self.gauge_axis is not None:
            dev[:3] = self.gauge_axis * (self.gauge_axis @ dev[:3])
        return dev

    def linearize(self, pt: tuple) -> None:
        """The normal equations ``JᵀJ``, ``Jᵀr`` at ``pt`` (with the detections' Huber weights there)."""
        from slamobs.pipeline.smoother.solver import detection_normal, detection_terms, motion_terms

        p, (rot, pos, lms, bias) = self.p, pt
        detection_terms(rot, pos, lms, self.kf, self.idx, self.y, self.sigma, self.shape, p.huber, self.weight)
        for a in (self.ad, self.ao, self.ga, self.c, self.gb):
            a[:] = 0.0
        detection_normal(
            rot, pos, lms, self.kf, self.idx, self.y, self.weight, self.shape, self.ad, self.ga, self.c, self.gb
        )
        b0 = 3 * self.n_lm
        motion_terms(p.data, p.b_bar, rot, pos, bias, p.seg_of, self.ad, self.ao, self.mb, self.ga, self.c, self.gb, b0)
        prior = 1.0 / p.bias_prior_sigma**2
        self.c[b0 : b0 + 6, b0 : b0 + 6] += np.diag(prior)
        self.gb[b0 : b0 + 6] += prior * (bias[0] - p.bias_prior_mean)
        if p.walk_sigma is not None:
            w = 1.0 / p.walk_sigma**2
            for s in range(self.n_seg - 1):
                d = w * (bias[s + 1] - bias[s])
                i, j = b0 + 6 * s, b0 + 6 * s + 6
                self.c[i : i + 6, i : i + 6] += np.diag(w)
                self.c[j : j + 6, j : j + 6] += np.diag(w)
                self.c[i : i + 6, j : j + 6] -= np.diag(w)
                self.c[j : j + 6, i : i + 6] -= np.diag(w)
                self.gb[i : i + 6] -= d
                self.gb[j : j + 6] += d
        if p.floor is not None:
            r, jac = floor_terms(self.plane, rot, pos)
            wj = jac * p.floor[:, [0, 0, 1], None]
            self.ad += np.einsum("kri,krj->kij", wj, jac)
            self.ga += np.einsum("kri,kr->ki", wj, r)
        info = np.eye(6)
        if self.gauge_axis is not None:
            info[:3, :3] = np.outer(self.gauge_axis, self.gauge_axis)
        self.ad[p.anchor] += info / GAUGE_SIGMA**2
        self.ga[p.anchor] += self._gauge_deviation(rot, pos) / GAUGE_SIGMA**2
        self.at = pt

    def _geo(self) -> tuple:
        rot, pos, lms, _ = self.at
        return (rot, pos, lms, self.det_start, self.idx, self.weight, self.shape, self.mb, self.p.seg_of, 3 * self.n_lm)

    def factor(self, lam: float) -> tuple | None:
        """``A + λI`` factored and the border's Schur complement ``S`` (None: not positive definite), with
        ``z = L⁻¹(−Jᵀr)_a`` and the border's right side."""
        from slamobs.pipeline.smoother.solver import factor

        s, rb, z = self.c + lam * np.eye(self.c.shape[0]), -self.gb, -self.ga
        if not factor(self.ad, self.ao, lam, z, self._geo(), self.dd, self.ee, s, rb):
            return None
        upper = np.triu(s)
        return upper + np.triu(s, 1).T, rb, z

    def step(self, lam: float) -> tuple | None:
        """The damped Gauss–Newton step from the linearization point: the new point and ``S`` (None: singular)."""
        from slamobs.pipeline.smoother.solver import back_substitute, retract

        f = self.factor(lam)
        if f is None:
            return None
        s, rb, z = f
        try:
            xb = np.linalg.solve(s, rb)
        except np.linalg.LinAlgError:
            return None
        x = np.empty_like(self.ga)
        back_substitute(z, xb, self._geo(), self.dd, self.ee, x)
        rot, pos, lms, bias = self.at
        new = (np.empty_like(rot), np.empty_like(pos), np.empty_like(lms), np.empty_like(bias))
        retract(rot, pos, lms, bias, x, xb, self.n_lm, *new)
        return new, s

    def solve_normal(self, ra: np.ndarray, rb: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``x`` (poses K × 6, border n_b) with ``H x = [ra; rb]`` for the undamped normal matrix ``H`` of the last
        linearization (None: not positive definite); a landmark left with no detection gets 0
        (:func:`border_rows`). Public: :mod:`pipeline.smoother.extrinsic` solves its coupling columns with it."""
        from slamobs.pipeline.smoother.solver import back_substitute, factor

        s, rb, z = self.c.copy(), np.array(rb, float), np.array(ra, float)
        if not factor(self.ad, self.ao, 0.0, z, self._geo(), self.dd, self.ee, s, rb):
            return None
        s = np.triu(s) + np.triu(s, 1).T
        keep = border_rows(s, self.n_lm)
        xb = np.zeros_like(rb)
        try:
            xb[keep] = np.linalg.solve(s[np.ix_(keep, keep)], rb[keep])
        except np.linalg.LinAlgError:
            return None
        x = np.empty_like(z)
        back_substitute(z, xb, self._geo(), self.dd, self.ee, x)
        return x, xb

    def bias_covariance(self, s: np.ndarray) -> np.ndarray:
        """The biases' marginal covariances (segments × 6 × 6) from the border's Schur complement; a landmark
        left with no detection (the χ² gate dropped them all) has no rows there and is left out."""
        cov = border_inverse(s, self.n_lm)[3 * self.n_lm :, 3 * self.n_lm :]
        return np.array([cov[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i in range(self.n_seg)]).reshape(-1, 6, 6)


def floor_at(rot: np.ndarray, pos: np.ndarray, anchor: int) -> np.ndarray:
    """The floor's plane for keyframes at ``rot``, ``pos``: riekf's (:func:`pipeline.observers.riekf.floor_plane`)
    with the keyframes' mean up axis its normal, through the anchor's position. Any plane is a gauge (the graph is
    invariant to one rigid transform); the mean up axis is the one the keyframes are nearest, where the anchor's
    own (riekf's choice, its start pose) may be off the rest by what a blind stretch's gyro drift tilted it."""
    from slamobs.pipeline.observers.riekf import floor_plane

    up = rot[:, :, 2].mean(axis=0)
    frame = np.eye(3)
    frame[:, 2] = up / np.linalg.norm(up)
    return floor_plane(frame, pos[anchor], np.zeros((0, 3)))


def floor_terms(plane: np.ndarray, rot: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The floor's residuals (K, 3) at every keyframe and their Jacobians (K, 3, 6) in the step ``(θ, ρ)`` of
    ``R Exp(θ)``, ``P + Rρ``: ``t_kᵀ R e3`` (the up axis along the plane's tangents ``t1``, ``t2``) and
    ``nᵀP − h``: the plane ``plane`` (:func:`floor_at`). ``∂(tᵀR e3)/∂θ = e3 × Rᵀt``, less its part along
    ``Rᵀn`` (turning about the normal tilts the up axis no less: no heading, as riekf's rows); ``∂(nᵀP)/∂ρ = Rᵀn``."""
    n, tangents = plane[1:4], plane[5:11].reshape(2, 3)
    k = rot.shape[0]
    r, jac = np.empty((k, 3)), np.zeros((k, 3, 6))
    r[:, :2] = rot[:, :, 2] @ tangents.T
    r[:, 2] = pos @ n - plane[4]
    nb = np.einsum("kji,j->ki", rot, n)  # Rᵀn
    up = np.zeros((k, 3))
    up[:, 2] = 1.0
    for row in range(2):  # e3 × Rᵀt less its heading about Rᵀn: riekf's rows in the body frame
        jac[:, row, :3] = floor_tilt_rows(up, np.einsum("kji,j->ki", rot, tangents[row]), nb)
    jac[:, 2, 3:] = nb  # no rotation part: P + Rρ moves with ρ alone (riekf's invariant error adds P̂ × n)
    return r, jac


def floor_test(problem: Problem, held: Solution, free: Solution) -> tuple[float, float, float]:
    """The nested test of the floor (``problem.floor``): ``Δχ²``, twice the rise of every other factor's cost from
    ``free`` (the minimum of ``problem`` without the floor) to ``held`` (with it); the detections' part of it; and
    the floor's effective degrees of freedom ``tr(H_f Σ)`` at ``held`` (``H_f`` its rows' information, ``Σ`` the
    poses' marginal covariance with it: per row its share of the pose the data leave to it, a soft prior per keyframe
    pins less than its 3 rows). Where the floor holds (its rows measurements within their σ), ``Δχ²`` has that mean
    and at most twice it as variance; a floor the data hold the keyframes off raises it far above."""
    free_problem = replace(problem, floor=None)
    no_detections = with_detections(free_problem, np.zeros(0, dtype=np.int64))
    as_guess = lambda s: Guess(s.rot, s.pos, s.landmarks, s.bias)  # noqa: E731
    rise = [cost(p, as_guess(held)) - cost(p, as_guess(free)) for p in (free_problem, no_detections)]
    k = problem.floor.shape[0]
    pose, _ = covariances(problem, held, np.arange(k))
    turn = np.zeros((k, 6, 6))
    turn[:, :3, :3] = turn[:, 3:, 3:] = held.rot
    body = np.einsum("kji,kjl,klm->kim", turn, pose, turn)  # back to the body twist the rows' Jacobians are in
    _, jac = floor_terms(floor_at(held.rot, held.pos, problem.anchor), held.rot, held.pos)
    dof = float(np.sum(np.einsum("kri,kij,krj->kr", jac, body, jac) * problem.floor[:, [0, 0, 1]]))
    return 2.0 * rise[0], 2.0 * (rise[0] - rise[1]), dof


def solve(
    problem: Problem, guess: Guess, *, max_iterations: int = 50, relative_tolerance: float = 1e-5, progress=None
) -> Solution:
    """Levenberg–Marquardt from ``guess``; the solution, the biases' marginal covariance and a summary."""
    t0 = time.perf_counter()
    k = problem.data.shape[0] + 1
    ne = Normal(problem, guess)
    pt = tuple(np.ascontiguousarray(a, float) for a in (guess.rot, guess.pos, guess.landmarks, guess.bias))
    errors = [ne.error(pt)]
    t_build = time.perf_counter() - t0
    lam, iterations, converged, trials = 1e-5, 0, False, 0
    bias_cov, cov_lam = None, np.inf
    while iterations < max_iterations:
        step, lam, n = _step(ne, pt, errors[-1], lam)
        trials += n
        if step is None:
            converged = True  # no step decreases the error any more: a (local) minimum
            break
        pt, error, s = step
        bias_cov, cov_lam = ne.bias_covariance(s), lam  # at the last point linearized, one small step before
        iterations += 1
        errors.append(error)
        lam = max(lam / 10.0, 1e-12)
        if progress is not None:
            progress(f"batch: iteration {iterations}, error {error:.6g}")
        if errors[-2] - error <= relative_tolerance * errors[-2]:
            converged = True
            break
    t_solve = time.perf_counter() - t0 - t_build
    t = time.perf_counter()
    if bias_cov is None or cov_lam > 1e-3:  # no undamped factorization near the solution: one more
        ne.linearize(pt)
        f = ne.factor(0.0)
        bias_cov = ne.bias_covariance(f[0]) if f is not None else np.full((ne.n_seg, 6, 6), np.nan)
    t_marg = time.perf_counter() - t
    summary = {
        "iterations": iterations,
        "linear_solves": trials,
        "converged": converged,
        "initial_error": float(errors[0]),
        "final_error": float(errors[-1]),
        "error_per_iteration": [float(e) for e in errors],
        "variables": {"keyframes": int(k), "landmarks": ne.n_lm, "bias_segments": ne.n_seg},
        "factors": _factor_count(problem, ne.n_seg),
        "seconds": {"build": round(t_build, 3), "optimize": round(t_solve, 3), "bias_covariance": round(t_marg, 3)},
    }
    rot, pos, lms, bias = pt
    return Solution(rot, pos, lms, bias, bias_cov, summary)


def _factor_count(problem: Problem, n_seg: int) -> int:
    """Detections, relative motions, the bias prior, the walk steps, the gauge and the floor's keyframes."""
    walk = n_seg - 1 if problem.walk_sigma is not None else 0
    floor = 0 if problem.floor is None else int(problem.floor.shape[0])
    return int(problem.det_idx.shape[0]) + int(problem.data.shape[0]) + 1 + walk + 1 + floor


def _step(ne: Normal, pt: tuple, error: float, lam: float, lam_max: float = 1e10):
    """The first damped step (``λ`` raised tenfold until one is found) that lowers ``error``: (the new point, its
    error, the border's Schur complement) or None; the ``λ`` reached and the linear solves made."""
    ne.linearize(pt)
    trials = 0
    while lam <= lam_max:
        trials += 1
        out = ne.step(lam)
        if out is not None:
            new, s = out
            new_error = ne.error(new)
            if np.isfinite(new_error) and new_error < error:
                return (new, new_error, s), lam, trials
        lam *= 10.0
    return None, lam, trials


def cost(problem: Problem, guess: Guess) -> float:
    """The smoother's objective at ``guess``: every factor of ``problem`` (Huber-robust landmark factors, relative
    motion, bias priors; the gauge prior sits at the guess's own anchor pose and adds nothing), half the squared
    whitened residuals. Solutions from different seeds are compared by it."""
    pt = tuple(np.ascontiguousarray(a, float) for a in (guess.rot, guess.pos, guess.landmarks, guess.bias))
    return Normal(problem, guess).error(pt)


def covariances(problem: Problem, sol: Solution, keyframes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Marginal covariances at the solution, from one undamped factorization: of the poses at ``keyframes``
    (K', 6, 6; sorted) and of every landmark (L, 3, 3), both in the map frame. The pose marginal is that of the
    body twist ``ξ = (ω, v)`` in ``T̂ = T Exp(ξ)``; the written error ``(δθ, δp)``, ``R̂ = Exp(δθ) R``,
    ``p̂ = p + δp`` is ``(R ω, R v)`` to first order. Both are conditioned on the gauge (the anchor keyframe
    held fixed)."""
    from slamobs.pipeline.smoother.solver import pose_marginals

    ne = Normal(problem, Guess(sol.rot, sol.pos, sol.landmarks, sol.bias))
    pt = tuple(np.ascontiguousarray(a, float) for a in (sol.rot, sol.pos, sol.landmarks, sol.bias))
    ne.linearize(pt)
    f = ne.factor(0.0)
    n = keyframes.shape[0]
    if f is None:
        return np.full((n, 6, 6), np.nan), np.full((ne.n_lm, 3, 3), np.nan)
    s_inv = border_inverse(f[0], ne.n_lm)
    unseen = np.isnan(np.diagonal(s_inv)[: 3 * ne.n_lm : 3])
    s_inv[np.isnan(s_inv)] = 0.0  # no detection couples the poses to them (their ee blocks are 0)
    body = np.zeros((n, 6, 6))
    pose_marginals(ne._geo(), ne.dd, ne.ee, s_inv, np.asarray(keyframes, np.int64), body)
    turn = np.zeros((n, 6, 6))
    turn[:, :3, :3] = turn[:, 3:, 3:] = sol.rot[keyframes]
    pose = np.einsum("nij,njk,nlk->nil", turn, body, turn)
    landmarks = np.array([s_inv[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] for i in range(ne.n_lm)]).reshape(-1, 3, 3)
    landmarks[unseen] = np.nan
    return pose, landmarks


def border_rows(s: np.ndarray, n_lm: int) -> np.ndarray:
    """The rows of the border's Schur complement ``s`` (the ``n_lm`` landmarks' 3 rows each, then the biases')
    the solve constrains: all but those of a landmark left with no detection (the χ² gate dropped them all), whose
    rows are 0. :func:`border_inverse` and :func:`evidence_terms` leave the others out."""
    b0 = 3 * n_lm
    return np.r_[np.flatnonzero(np.any(s[:b0] != 0.0, axis=1)), np.arange(b0, s.shape[0])]


def border_inverse(s: np.ndarray, n_lm: int) -> np.ndarray:
    """The inverse of the border's Schur complement ``s`` (the ``n_lm`` landmarks' 3 rows each, then the biases');
    a landmark left with no detection (the χ² gate dropped them all) has rows of 0 there: its block is NaN and
    the rest the inverse of ``s`` without it (seed=3973, a clock set back 5 s mid-log: the run's covariances failed
    on ``Singular matrix`` where the bias's had this)."""
    try:
        return np.linalg.inv(s)
    except np.linalg.LinAlgError:
        keep = border_rows(s, n_lm)
        out = np.full_like(s, np.nan)
        out[np.ix_(keep, keep)] = np.linalg.inv(s[np.ix_(keep, keep)])
        return out


def evidence_terms(problem: Problem, sol: Solution) -> tuple[float, float] | None:
    """The two terms of the Laplace approximation of the evidence that need the solver: the objective ``F`` at the
    solution (half the whitened squares, Huber-robust) and ``log det H`` of the undamped Gauss–Newton normal
    matrix there, ``2 Σ log diag`` of the poses' Cholesky blocks plus the border's Schur complement's log
    determinant (None: not positive definite). A landmark left with no detection (the χ² gate dropped them all)
    is left out of it (:func:`border_rows`): nothing in the problem depends on it, and its rows of 0 made the
    determinant 0 (seed=3973, a clock set back 5 s mid-log: the later passes' evidence read "n/a")."""
    ne = Normal(problem, Guess(sol.rot, sol.pos, sol.landmarks, sol.bias))
    pt = tuple(np.ascontiguousarray(a, float) for a in (sol.rot, sol.pos, sol.landmarks, sol.bias))
    error = ne.error(pt)
    ne.linearize(pt)
    f = ne.factor(0.0)
    if f is None:
        return None
    keep = border_rows(f[0], ne.n_lm)
    sign, border = np.linalg.slogdet(f[0][np.ix_(keep, keep)])
    if sign <= 0:
        return None
    chain = 2.0 * float(np.sum(np.log(np.diagonal(ne.dd, axis1=1, axis2=2))))
    return error, chain + float(border)


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


def with_detections(problem: Problem, kept: np.ndarray) -> Problem:
    """``problem`` with only the detections ``kept`` (indices into its detections)."""
    return replace(
        problem,
        kf_of_det=problem.kf_of_det[kept],
        det_idx=problem.det_idx[kept],
        det_y=problem.det_y[kept],
        det_sigma=problem.det_sigma[kept],
        det_shape=None if problem.det_shape is None else problem.det_shape[kept],
    )


def predicted_detections(kf_of_det: np.ndarray, det_idx: np.ndarray, sol: Solution) -> np.ndarray:
    """Each detection as the solution predicts it, ``Rᵀ(ℓ − P)`` (M, 3, body frame, m)."""
    return np.einsum("mji,mj->mi", sol.rot[kf_of_det], sol.landmarks[det_idx] - sol.pos[kf_of_det])


def detection_residuals(problem: Problem, sol: Solution) -> np.ndarray:
    """Each detection's residual ``Rᵀ(ℓ − P) − y`` (M, 3, body frame, m) at the solution."""
    return predicted_detections(problem.kf_of_det, problem.det_idx, sol) - problem.det_y


def whitened_residuals(problem: Problem, sol: Solution) -> np.ndarray:
    """Each detection's residual whitened by its covariance ``σ² S⁻¹`` (M, 3; ``Lᵀr/σ`` with ``S = LLᵀ``, ``r/σ``
    for isotropic ones): its squared norm is the χ² the gate and the Huber kernel read."""
    return whiten_detections(problem, detection_residuals(problem, sol))


def whiten_detections(problem: Problem, r: np.ndarray) -> np.ndarray:
    """Detection residuals ``r`` (M, 3, body frame, m) whitened by their covariance ``σ² S⁻¹`` (``Lᵀr/σ``)."""
    r = r / np.maximum(problem.det_sigma, 1e-12)[:, None]
    if problem.det_shape is None:
        return r
    return np.einsum("mji,mj->mi", np.linalg.cholesky(problem.det_shape), r)


def residual_statistics(problem: Problem, sol: Solution) -> dict:
    """Per factor type: residual sizes at the solution (metric and whitened), and how many detections the
    Huber kernel down-weights."""
    from slamobs.pipeline.smoother.preintegration import motion_residuals

    motion = motion_residuals(problem.data, problem.b_bar, sol.rot, sol.pos, sol.bias, problem.seg_of)
    err = np.linalg.norm(detection_residuals(problem, sol), axis=1)
    whitened = np.linalg.norm(whitened_residuals(problem, sol), axis=1)
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
