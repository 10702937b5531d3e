"""The detections' sensor position on the body fitted with batch's solution (``smoother.extrinsic`` in run.json).

A camera whose stated position on the body (its extrinsic's translation ``t``) is off by ``δ`` puts every
detection ``δ`` off in the body frame: the measured point is ``y + δ``, not ``y``. Batch cannot see it with its poses
held (each pose moves by ``R δ`` and the map with it); the odometry between poses disagrees with that move as the body
turns (docs/benchmarks.md, "A camera extrinsic stated 5 cm off, silent", session 38). So ``δ`` is a variable of the
graph, one body-frame translation shared by every detection, its residual ``Rᵀ(ℓ − P) − (y + δ)``, with a prior
``N(0, PRIOR_SIGMA_M² I)`` about the stated position, and estimated jointly with the poses, map and biases: at batch's
solution one Gauss–Newton step in ``(x, δ)`` with the poses, landmarks and biases ``x`` eliminated,

    (H_δδ − H_xδᵀ H_xx⁻¹ H_xδ + I/σ_p²) Δδ = −g_δ + H_xδᵀ H_xx⁻¹ g_x,

the three columns ``H_xx⁻¹ H_xδ`` from the smoother's own factorization (:meth:`graph.Normal.solve_normal`), the
matrix on the left the inverse of ``δ``'s marginal covariance.

An eigen-direction of that covariance is observable where its variance is at most ``OBSERVABLE_SHARE`` of the
prior's (the detections and the odometry carry at least nine times the prior's information there). The fit is
applied (the solution solved again with the shifted detections, the step taken once more from there and reported)
and noted only where (1) every axis is observable and (2) the shift is beyond χ²(``LEVEL``, 3): the data determine
the position in full and reject the stated one. (2) keeps a stated position the data agree with: applying a shift
within its standard errors cost the generated loop of ``tests/test_smoother.py`` twice its APE (a steady turn's
velocity bias and the offset read alike). (1) keeps a planar robot's: its height is the prior's, and what the yaw
excites in the plane is confounded with the heading error of a commanded yaw rate (MR.CLAM 6 r1 / r2 fitted 6-13 cm
along one direction, their sensor at the body's origin; docs/benchmarks.md, session 39). Where not applied the record
still says what the data fit.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from slamobs.pipeline.noise import chi2_quantile

#: Standard deviation (m, per axis) of the prior on the sensor's position about the stated one: a round 5 cm, what a
#: position measured by hand on the mount (a tape, a CAD drawing of another revision) gets wrong; session 38 measured
#: 5 cm doubling batch's error.
PRIOR_SIGMA_M = 0.05
#: A direction is observable where the data leave at most this share of the prior's variance (their information at
#: least 9x the prior's: the fit there is the data's, not the prior's).
OBSERVABLE_SHARE = 0.1
#: The level at which the data reject the stated position: the shift along the observable directions beyond
#: χ²(0.99, their number).
LEVEL = 0.99


def step(problem, sol, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The Gauss–Newton step ``Δδ`` of the sensor's position and its marginal covariance (3 × 3) at ``sol``, the
    detections of ``problem`` already shifted by ``offset`` from the stated position (the prior's residual); None
    where the normal matrix is singular."""
    from slamobs.pipeline.smoother.graph import Guess, Normal

    ne = Normal(problem, Guess(sol.rot, sol.pos, sol.landmarks, sol.bias))
    ne.linearize(tuple(np.ascontiguousarray(a, float) for a in (sol.rot, sol.pos, sol.landmarks, sol.bias)))
    rot = sol.rot[ne.kf]
    q = np.einsum("mji,mj->mi", rot, sol.landmarks[ne.idx] - sol.pos[ne.kf])
    d = q - ne.y
    w = np.broadcast_to(np.eye(3), (ne.kf.shape[0], 3, 3)) if ne.shape.shape[0] == 0 else ne.shape
    w = w * ne.weight[:, None, None]  # each detection's information a·S
    g = -np.einsum("mij,mj->i", w, d) + offset / PRIOR_SIGMA_M**2  # J_δ = −I
    h = w.sum(axis=0) + np.eye(3) / PRIOR_SIGMA_M**2
    k = ne.ad.shape[0]
    pose = np.zeros((k, 6, 3))  # J_poseᵀ W J_δ = [[q]× W; W]
    qw = np.cross(q[:, None, :], np.swapaxes(w, 1, 2)).swapaxes(1, 2)  # [q]× W, a column at a time
    np.add.at(pose, ne.kf, np.concatenate([qw, w], axis=1))
    border = np.zeros((ne.gb.shape[0], 3))
    lm = np.zeros((ne.n_lm, 3, 3))  # J_ℓᵀ W J_δ = −R W
    np.add.at(lm, ne.idx, -(rot @ w))
    border[: 3 * ne.n_lm] = lm.reshape(-1, 3)
    xp, xb = np.zeros_like(pose), np.zeros_like(border)
    for c in range(3):
        out = ne.solve_normal(pose[:, :, c], border[:, c])
        if out is None:
            return None
        xp[:, :, c], xb[:, c] = out
    info = h - np.einsum("kpi,kpj->ij", pose, xp) - border.T @ xb
    info = 0.5 * (info + info.T)
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None
    rhs = -g + np.einsum("kpi,kp->i", xp, ne.ga) + xb.T @ ne.gb
    return cov @ rhs, cov


def observable(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The observable eigen-directions of ``cov`` (columns) and their variances (``OBSERVABLE_SHARE``)."""
    lam, vec = np.linalg.eigh(cov)
    keep = lam <= OBSERVABLE_SHARE * PRIOR_SIGMA_M**2
    return vec[:, keep], lam[keep]


def judged(shift: np.ndarray, cov: np.ndarray) -> tuple[int, float, float | None, bool]:
    """The shift from the stated position along the observable directions of ``cov``: their number, its χ² over
    their variances, the bound χ²(``LEVEL``, their number) (None without any) and whether it is beyond it."""
    vec, lam = observable(cov)
    along = vec.T @ shift
    chi2 = float(np.sum(along * along / lam)) if lam.size else 0.0
    bound = chi2_quantile(LEVEL, int(lam.size)) if lam.size else None
    return int(lam.size), chi2, bound, bool(bound is not None and chi2 > bound)


def record(stated: np.ndarray, shift: np.ndarray, cov: np.ndarray, judge: tuple, applied: np.ndarray, cpu_s: float):
    """run.json ``smoother.extrinsic``: the fitted position, its marginal σ, the shift from the stated, the first
    step's observable directions, χ² and bound (the decision, :func:`judged`), what was applied."""
    n, chi2, bound, beyond = judge
    return {
        "stated_m": [round(float(v), 5) for v in stated],
        "fitted_m": [round(float(v), 5) for v in stated + shift],
        "shift_m": [round(float(v), 5) for v in shift],
        "sigma_m": [round(float(v), 5) for v in np.sqrt(np.clip(np.diagonal(cov), 0.0, None))],
        "prior_sigma_m": PRIOR_SIGMA_M,
        "observable_axes": n,
        "chi2": round(chi2, 3),
        "bound_chi2": None if bound is None else round(bound, 3),
        "beyond": beyond,
        "applied": bool(np.any(applied != 0.0)),
        "applied_shift_m": [round(float(v), 5) for v in applied],
        "cpu_s": round(cpu_s, 3),
    }


def fitted(problem, sol, solve_again) -> tuple | None:
    """The step from batch's solution ``sol`` of ``problem`` and its judgement (:func:`judged`); where every axis is
    observable and the shift beyond its bound, the shift applied, the problem solved again by ``solve_again(problem,
    start)`` from ``sol`` and the step taken once more from there (what is left, reported, not applied). The last
    problem and solution, the total shift fitted (3,), its marginal covariance, the judgement and the shift applied;
    None where a step is singular."""
    out = step(problem, sol, np.zeros(3))
    if out is None:
        return None
    shift, cov = out
    judge = judged(shift, cov)
    if not (judge[0] == 3 and judge[3]):
        return problem, sol, shift, cov, judge, np.zeros(3)
    problem = replace(problem, det_y=problem.det_y + shift)
    sol = solve_again(problem, sol)
    out = step(problem, sol, shift)
    if out is None:
        return None
    return problem, sol, shift + out[0], out[1], judge, shift


def note(rec: dict) -> list[str]:
    """The note of a fitted position the estimate used (none otherwise)."""
    if not rec.get("applied"):
        return []
    s, f, st, sig = rec["shift_m"], rec["fitted_m"], rec["stated_m"], rec["sigma_m"]
    return [
        f"batch: the detections' sensor sits ({f[0]:+.3f}, {f[1]:+.3f}, {f[2]:+.3f}) m in the body frame by "
        f"the data, ({s[0]:+.3f}, {s[1]:+.3f}, {s[2]:+.3f}) ± ({sig[0]:.3f}, {sig[1]:.3f}, {sig[2]:.3f}) m from the "
        f"stated ({st[0]:+.3f}, {st[1]:+.3f}, {st[2]:+.3f}): χ² {rec['chi2']:.3g} > {rec['bound_chi2']:.3g} "
        f"(χ²({LEVEL:g}, 3)); the estimate uses the fitted position: is the camera's extrinsic (its TF translation) "
        "right? (run.json smoother.extrinsic)"
    ]


def timed(problem, sol, stated: np.ndarray, solve_again):
    """:func:`fitted` and its record: (problem, solution, record, the shift applied)."""
    c0 = time.process_time()
    out = fitted(problem, sol, solve_again)
    if out is None:
        return problem, sol, {"skipped": "the normal matrix is singular at the solution"}, np.zeros(3)
    problem, sol, total, cov, judge, applied = out
    return problem, sol, record(stated, total, cov, judge, applied, time.process_time() - c0), applied
