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

A camera whose stated *rotation* is a few degrees off moves each detection by ``φ × (y − t)``, which a translation
fits in part (2 and 5 deg of pitch were fitted as 3 cm and applied: docs/benchmarks.md, session 39 (h-extrinsic12)).
So the step is of the six-vector ``(δ, φ)``, ``φ`` a turn of the detections about the stated sensor position (prior
``PRIOR_TURN_RAD``); the shift judged is the position's with the turn held (as before), and no shift is applied
where the turn explains the detections beyond the position (:func:`turned`) or the detection pairs' check names the
camera turned (``time_offset.camera_named``): one cause, one message. Every χ² is divided by the detections'
a-posteriori variance factor where above 1 and by the variance gain of their time correlation (:func:`calibration`):
TagSLAM 21's residuals correlate 0.63 from one detection to the next, and its χ² of 32 and 47 named an 8 mm shift
and a half-degree turn.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from slamobs.pipeline.noise import chi2_quantile
from slamobs.pipeline.observers.time_offset import CAMERA_ADVICE, turn_phrase

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
#: Standard deviation (rad, per axis) of the prior on the sensor's rotation about the stated one: a round 5 deg, what
#: a mount's angle set by eye or a CAD drawing of another revision gets wrong (session 38's tilted logs: 2-5 deg).
PRIOR_TURN_RAD = np.radians(5.0)


def step(problem, sol, offset: np.ndarray, origin: np.ndarray | None = None) -> tuple | None:
    """The Gauss–Newton step of the sensor's position ``Δδ`` and its marginal covariance (3 × 3) at ``sol``, the
    detections of ``problem`` already shifted by ``offset`` from the stated position (the prior's residual); with the
    sensor's stated ``origin`` (body frame) the step and covariance of the six-vector ``(δ, φ)``, ``φ`` a turn of the
    detections about ``origin`` (the stated extrinsic's rotation off, prior ``PRIOR_TURN_RAD``), and the detections'
    whitened residuals' variance factor (:func:`variance_factor`); None where the normal matrix is singular."""
    from slamobs.pipeline.smoother.graph import Guess, Normal

    ne = Normal(problem, Guess(sol.rot, sol.pos, sol.landmarks, sol.bias))
    ne.linearize(tuple(np.ascontiguousarray(a, float) for a in (sol.rot, sol.pos, sol.landmarks, sol.bias)))
    rot = sol.rot[ne.kf]
    q = np.einsum("mji,mj->mi", rot, sol.landmarks[ne.idx] - sol.pos[ne.kf])
    d = q - ne.y
    w = np.broadcast_to(np.eye(3), (ne.kf.shape[0], 3, 3)) if ne.shape.shape[0] == 0 else ne.shape
    w = w * ne.weight[:, None, None]  # each detection's information a·S
    cols = [-np.broadcast_to(np.eye(3), w.shape)]  # J_δ = −I
    prior = [np.full(3, PRIOR_SIGMA_M)]
    if origin is not None:
        arm = ne.y - origin  # J_φ = [y − t]× (d(exp(φ)(y − t))/dφ = −[y − t]×), its column j (y − t) × e_j
        cols.append(np.cross(arm[:, None, :], np.eye(3)[None]).swapaxes(1, 2))
        prior.append(np.full(3, PRIOR_TURN_RAD))
    jac = np.concatenate(cols, axis=2)  # (m, 3, n)
    n = jac.shape[2]
    sig = np.concatenate(prior)
    wj = w @ jac
    g = np.einsum("mji,mj->i", wj, d) + np.concatenate([offset, np.zeros(n - 3)]) / sig**2
    h = np.einsum("mji,mjk->ik", jac, wj) + np.diag(1.0 / sig**2)
    k = ne.ad.shape[0]
    pose = np.zeros((k, 6, n))  # J_poseᵀ W J = −[[q]×; I] W J
    np.add.at(pose, ne.kf, -np.concatenate([np.cross(q[:, None, :], np.swapaxes(wj, 1, 2)).swapaxes(1, 2), wj], axis=1))
    border = np.zeros((ne.gb.shape[0], n))
    lm = np.zeros((ne.n_lm, 3, n))  # J_ℓᵀ W J = R W J
    np.add.at(lm, ne.idx, rot @ wj)
    border[: 3 * ne.n_lm] = lm.reshape(-1, n)
    xp, xb = np.zeros_like(pose), np.zeros_like(border)
    for c in range(n):
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
    if origin is None:
        return cov @ rhs, cov
    return cov @ rhs, cov, rhs, variance_factor(ne, d, w)


def variance_factor(ne, d: np.ndarray, w: np.ndarray) -> dict:
    """The detections' whitened residuals at the solution: their a-posteriori variance factor ``Σ dᵀ W d / (3m − p)``
    (``p`` the landmarks' unknowns ``3 n_lm``: the keyframes' poses are the odometry's as much, and counting them
    took 3612 of a 60 s hand-held log's 4431 degrees of freedom, σ̂₀² 5.4-5.8 against 0.93-0.96; so a lower bound,
    which never divides by more than the residuals show) and the lag-1 correlation ``ρ`` of each landmark's
    whitened residuals from one of its detections to the next (in time), with the variance a mean of such errors
    gains, ``(1 + ρ) / (1 − ρ)``."""
    m = d.shape[0]
    r = float(np.einsum("mi,mij,mj->", d, w, d))
    dof = max(3 * m - 3 * ne.n_lm, 1)
    e = d * np.sqrt(ne.weight)[:, None]
    order = np.lexsort((ne.kf, ne.idx))
    same = ne.idx[order][1:] == ne.idx[order][:-1]
    a, b = e[order][:-1][same], e[order][1:][same]
    rho = float(np.sum(a * b) / max(np.sum(e * e), 1e-300)) if same.any() else 0.0
    return {"s0": r / dof, "rho": rho, "ar1": (1.0 + max(rho, 0.0)) / (1.0 - min(max(rho, 0.0), 0.99))}


def observable(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The observable eigen-directions of ``cov`` (columns) and their variances (``OBSERVABLE_SHARE``)."""
    lam, vec = np.linalg.eigh(cov)
    keep = lam <= OBSERVABLE_SHARE * PRIOR_SIGMA_M**2
    return vec[:, keep], lam[keep]


def judged(shift: np.ndarray, cov: np.ndarray, factor: float = 1.0) -> tuple[int, float, float | None, bool]:
    """The shift from the stated position along the observable directions of ``cov``: their number, its χ² over
    their variances times ``factor`` (:func:`calibration`), the bound χ²(``LEVEL``, their number) (None without any)
    and whether it is beyond it."""
    vec, lam = observable(cov)
    along = vec.T @ shift
    chi2 = float(np.sum(along * along / lam)) / factor if lam.size else 0.0
    bound = chi2_quantile(LEVEL, int(lam.size)) if lam.size else None
    return int(lam.size), chi2, bound, bool(bound is not None and chi2 > bound)


def calibration(vf: dict) -> float:
    """The factor the data's χ² are divided by (their covariance multiplied by): the detections' a-posteriori
    variance factor ``σ̂₀²`` (:func:`variance_factor`, a lower bound) where above 1, else 1 (the stated noise taken
    where the residuals are within it), times ``(1 + ρ) / (1 − ρ)`` for a positive lag-1 correlation ``ρ`` of a
    landmark's residuals from one detection to the next: the variance an AR(1) series' mean gains over independent
    values, the effective number of independent detections ``n (1 − ρ) / (1 + ρ)`` (TagSLAM 21: ρ 0.63, its χ² of
    32 and 47 named an 8 mm shift and a half-degree turn; the generated logs' ρ is −0.1 to 0.01)."""
    return max(1.0, float(vf["s0"])) * float(vf["ar1"])


def turned(rhs: np.ndarray, cov6: np.ndarray, factor: float) -> dict:
    """Whether a turn of the detections explains them beyond the position: the six-vector's deviance (the cost the
    step takes off, ``rhsᵀ C rhs``) less the position's alone, over ``factor``, against χ²(``LEVEL``, 3), and the turn
    alone explaining more than the position alone (three unknowns each); the turn (deg) the six-vector fits, its σ."""
    info = np.linalg.inv(cov6)
    dev = float(rhs @ cov6 @ rhs)
    dev_t = float(rhs[:3] @ np.linalg.solve(info[:3, :3], rhs[:3]))
    dev_r = float(rhs[3:] @ np.linalg.solve(info[3:, 3:], rhs[3:]))
    chi2 = (dev - dev_t) / factor
    bound = chi2_quantile(LEVEL, 3)
    turn = cov6 @ rhs
    return {
        "turn_deg": np.degrees(turn[3:]),
        "turn_sigma_deg": np.degrees(np.sqrt(np.clip(np.diagonal(cov6)[3:] * factor, 0.0, None))),
        "chi2": chi2,
        "bound": bound,
        "position_chi2": dev_t / factor,
        "turn_alone_chi2": dev_r / factor,
        "beyond": bool(chi2 > bound and dev_r > dev_t),
    }


def record(stated, shift, cov, judge: tuple, applied, turn: dict | None = None, vf: dict | None = None):
    """run.json ``smoother.extrinsic``: the fitted position, its marginal σ, the shift from the stated, the first
    step's observable directions, χ² and bound (the decision, :func:`judged`), what was applied; the turn's test
    (:func:`turned`) and the calibration (:func:`calibration`)."""
    n, chi2, bound, beyond = judge
    out = {
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
    }
    if vf is not None:
        out["variance_factor"] = round(vf["s0"], 4)
        out["residual_lag1_correlation"] = round(vf["rho"], 4)
        out["calibration"] = round(calibration(vf), 4)
    if turn is not None:
        out["turn"] = {
            "turn_deg": [round(float(v), 3) for v in turn["turn_deg"]],
            "sigma_deg": [round(float(v), 3) for v in turn["turn_sigma_deg"]],
            "prior_sigma_deg": round(float(np.degrees(PRIOR_TURN_RAD)), 3),
            "chi2": round(turn["chi2"], 3),
            "bound_chi2": round(turn["bound"], 3),
            "position_chi2": round(turn["position_chi2"], 3),
            "turn_alone_chi2": round(turn["turn_alone_chi2"], 3),
            "beyond": turn["beyond"],
            "named_by_pairs": turn["named"],
        }
    return out


def fitted(problem, sol, solve_again, origin: np.ndarray, named: bool = False) -> tuple | None:
    """The step from batch's solution ``sol`` of ``problem`` and its judgement (:func:`judged`); where every axis is
    observable, the shift beyond its bound and no turn explains the detections better (:func:`turned`, or the
    detection pairs' check, ``named``: ``time_offset.camera_named``), the shift
    applied, the problem solved again by ``solve_again(problem, start)`` from ``sol`` and the step taken once more
    from there (what is left, reported, not applied). The last problem and solution, the total shift fitted (3,), its
    marginal covariance, the judgement, the shift applied, the turn's test and the residuals' factors; None where a
    step is singular."""
    out = step(problem, sol, np.zeros(3), origin)
    if out is None:
        return None
    _, cov6, rhs, vf = out
    factor = calibration(vf)
    cov = np.linalg.inv(np.linalg.inv(cov6)[:3, :3])  # the position's with the turn held at the stated
    shift = cov @ rhs[:3]
    judge = judged(shift, cov, factor)
    turn = turned(rhs, cov6, factor)
    turn["named"] = named
    if not (judge[0] == 3 and judge[3]) or turn["beyond"] or named:
        return problem, sol, shift, cov * factor, judge, np.zeros(3), turn, vf
    problem = replace(problem, det_y=problem.det_y + shift)
    sol = solve_again(problem, sol)
    out = step(problem, sol, shift)
    if out is None:
        return None
    return problem, sol, shift + out[0], out[1] * factor, judge, shift, turn, vf


def note(rec: dict) -> list[str]:
    """The note of a fitted position the estimate used, or of a turn the detections show (none otherwise)."""
    turn = rec.get("turn") or {}
    if turn.get("beyond") and not turn.get("named_by_pairs"):  # named by the pairs: their warning is the one
        t, sig = turn["turn_deg"], turn["sigma_deg"]
        return [
            f"batch: the detections fit better turned {turn_phrase(t)} (({t[0]:+.1f}, {t[1]:+.1f}, {t[2]:+.1f}) ± "
            f"({sig[0]:.1f}, {sig[1]:.1f}, {sig[2]:.1f}) deg) than with their sensor's position shifted: χ² "
            f"{turn['chi2']:.3g} > {turn['bound_chi2']:.3g} (χ²({LEVEL:g}, 3)); {CAMERA_ADVICE} (its stated rotation "
            "a few degrees off); no shift applied (run.json smoother.extrinsic)"
        ]
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


def timed(problem, sol, stated: np.ndarray, solve_again, named: bool = False):
    """:func:`fitted` and its record: (problem, solution, record, the shift applied, its CPU seconds). The seconds
    stay out of the record (run.json's timings take them): a record of the data is the same on every run."""
    c0 = time.process_time()
    out = fitted(problem, sol, solve_again, stated, named)
    if out is None:
        rec = {"skipped": "the normal matrix is singular at the solution"}
        return problem, sol, rec, np.zeros(3), time.process_time() - c0
    problem, sol, total, cov, judge, applied, turn, vf = out
    return problem, sol, record(stated, total, cov, judge, applied, turn, vf), applied, time.process_time() - c0
