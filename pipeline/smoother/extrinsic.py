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
matrix on the left the inverse of ``δ``'s marginal covariance. Where it is applied, the solution is solved again
with the shifted detections and the step taken once more from there (``PASSES``).

Applied only along directions the data observe: an eigen-direction of the marginal covariance is observable where
its variance is at most ``OBSERVABLE_SHARE`` of the prior's (the detections and the odometry carry at least nine
times the prior's information there); a planar robot's height offset, which no yaw can reveal, keeps the stated
value. A note only where the shift along the observable directions is beyond their χ²(``NOTE_LEVEL``) quantile.
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
#: The note's level: the shift along the observable directions beyond χ²(0.99, their number).
NOTE_LEVEL = 0.99
#: Gauss–Newton steps in the sensor's position (the second from the solution solved again with the first).
PASSES = 2


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


def record(stated: np.ndarray, shift: np.ndarray, cov: np.ndarray, applied: np.ndarray, cpu_s: float) -> dict:
    """run.json ``smoother.extrinsic``: the fitted position, its marginal σ, the shift from the stated, the
    observable directions' χ² and its bound, what was applied."""
    vec, lam = observable(cov)
    along = vec.T @ shift
    chi2 = float(np.sum(along * along / lam)) if lam.size else 0.0
    bound = chi2_quantile(NOTE_LEVEL, int(lam.size)) if lam.size else None
    return {
        "stated_m": [round(float(v), 5) for v in stated],
        "fitted_m": [round(float(v), 5) for v in stated + shift],
        "shift_m": [round(float(v), 5) for v in shift],
        "sigma_m": [round(float(v), 5) for v in np.sqrt(np.clip(np.diagonal(cov), 0.0, None))],
        "prior_sigma_m": PRIOR_SIGMA_M,
        "observable_axes": int(lam.size),
        "chi2": round(chi2, 3),
        "bound_chi2": None if bound is None else round(bound, 3),
        "beyond": bool(bound is not None and chi2 > bound),
        "applied": bool(np.any(applied != 0.0)),
        "applied_shift_m": [round(float(v), 5) for v in applied],
        "cpu_s": round(cpu_s, 3),
    }


def fitted(problem, sol, solve_again) -> tuple[object, object, np.ndarray, np.ndarray, np.ndarray] | None:
    """``PASSES`` steps from batch's solution ``sol`` of ``problem``, each but the last applied along its observable
    directions and the problem solved again by ``solve_again(problem, start)`` from the last solution (the last step
    measures what is left). The last problem and solution, the total shift fitted (3,), its marginal covariance and
    the shift applied; None where a step is singular."""
    offset = np.zeros(3)
    total = cov = None
    for n in range(PASSES):
        out = step(problem, sol, offset)
        if out is None:
            return None
        delta, cov = out
        total = offset + delta
        vec, _ = observable(cov)
        move = vec @ (vec.T @ total) - offset
        if n == PASSES - 1 or vec.shape[1] == 0 or not np.any(move):
            break
        problem = replace(problem, det_y=problem.det_y + move)
        sol = solve_again(problem, sol)
        offset = offset + move
    return problem, sol, total, cov, offset


def note(rec: dict) -> list[str]:
    """The note of a shift beyond its bound (none otherwise)."""
    if not rec.get("beyond"):
        return []
    s, f, st = rec["shift_m"], rec["fitted_m"], rec["stated_m"]
    sig = rec["sigma_m"]
    done = (
        "the estimate uses the fitted position"
        if rec["applied"]
        else "not applied (no direction observable beyond the prior)"
    )
    return [
        f"warning: batch: the detections' sensor sits ({f[0]:+.3f}, {f[1]:+.3f}, {f[2]:+.3f}) m in the body frame by "
        f"the data, ({s[0]:+.3f}, {s[1]:+.3f}, {s[2]:+.3f}) ± ({sig[0]:.3f}, {sig[1]:.3f}, {sig[2]:.3f}) m from the "
        f"stated ({st[0]:+.3f}, {st[1]:+.3f}, {st[2]:+.3f}): χ² {rec['chi2']:.3g} over {rec['observable_axes']} "
        f"observable axes > {rec['bound_chi2']:.3g} (χ²({NOTE_LEVEL:g})); is the camera's extrinsic (its TF "
        f"translation) right? {done} (run.json smoother.extrinsic)"
    ]


def timed(problem, sol, stated: np.ndarray, solve_again):
    """:func:`fitted` and its record: (problem, solution, record, the shift applied)."""
    c0 = time.process_time()
    out = fitted(problem, sol, solve_again)
    if out is None:
        return problem, sol, {"skipped": "the normal matrix is singular at the solution"}, np.zeros(3)
    problem, sol, total, cov, applied = out
    return problem, sol, record(stated, total, cov, applied, time.process_time() - c0), applied
