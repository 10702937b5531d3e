"""The batch smoother's own normal equations and their structured solution (pipeline/smoother/solver.py) against
dense linear algebra: the gradient against finite differences of the cost, the information matrix against
finite differences of the gradient, the damped step against a dense solve and the marginal covariances against
the dense inverse, on a small generated problem with two bias segments (a random walk between them)."""

from __future__ import annotations

import numpy as np
import pytest
from smoother_checks import preintegrated

from slamobs.pipeline.smoother import graph as g
from slamobs.pipeline.smoother.preintegration import D_W, dead_reckon, whitening
from slamobs.pipeline.smoother.solver import border_row, pose_marginals, retract

K, N_LM, N_SEG = 30, 4, 2


@pytest.fixture(scope="module")
def case():
    """A problem whose residuals all vanish at ``guess`` (poses dead-reckoned from the odometry, detections
    exact), so that its Gauss–Newton information is the cost's Hessian there."""
    rng = np.random.default_rng(7)
    vel_t = np.arange(10 * (K - 1) + 1) * 0.01
    omega = rng.normal(size=(vel_t.size, 3)) * 0.3
    vel = rng.normal(size=(vel_t.size, 3)) * 0.2 + [1.0, 0.0, 0.0]
    kf_t = vel_t[::10]
    b_bar = rng.normal(size=6) * 0.01
    data, cov = preintegrated(vel_t, omega, vel, kf_t, b_bar, 1e-5, 1e-3)
    data[:, D_W:] = whitening(cov).reshape(-1, 36)
    rot, pos = np.empty((K, 3, 3)), np.empty((K, 3))
    dead_reckon(vel_t, omega, vel, kf_t, b_bar, np.eye(3), np.zeros(3), rot, pos)
    lms = rng.uniform(-3.0, 3.0, size=(N_LM, 3)) + [1.5, 0.0, 0.0]
    kf_of_det = np.repeat(np.arange(K), 2)
    det_idx = np.array([rng.choice(N_LM, 2, replace=False) for _ in range(K)]).ravel()
    det_y = np.einsum("mji,mj->mi", rot[kf_of_det], lms[det_idx] - pos[kf_of_det])
    problem = g.Problem(
        data=data,
        b_bar=b_bar,
        seg_of=np.arange(K - 1) * N_SEG // (K - 1),
        kf_of_det=kf_of_det,
        det_idx=det_idx,
        det_y=det_y,
        det_sigma=np.full(det_idx.size, 0.01),
        bias_prior_sigma=np.full(6, 0.1),
        bias_prior_mean=b_bar,
        walk_sigma=np.full(6, 0.01),
        huber=3.0,
        anchor=K - 1,
    )
    guess = g.Guess(rot, pos, lms, np.tile(b_bar, (N_SEG, 1)))
    return problem, guess, (rot, pos, lms, guess.bias)


def moved(pt, x, xb):
    """``pt`` retracted by the pose steps ``x`` (K, 6) and the border steps ``xb``."""
    out = tuple(np.empty_like(a) for a in pt)
    retract(*pt, x, xb, N_LM, *out)
    return out


def gradient(ne, pt):
    ne.linearize(pt)
    return np.r_[ne.ga.ravel(), ne.gb]


def dense_information(ne) -> np.ndarray:
    """``JᵀJ`` assembled densely from the solver's blocks."""
    nb = ne.c.shape[0]
    h = np.zeros((6 * K + nb, 6 * K + nb))
    brow = np.empty((6, nb))
    for i in range(K):
        h[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = ne.ad[i]
        if i < K - 1:
            h[6 * i : 6 * i + 6, 6 * i + 6 : 6 * i + 12] = ne.ao[i]
            h[6 * i + 6 : 6 * i + 12, 6 * i : 6 * i + 6] = ne.ao[i].T
        border_row(i, *ne._geo()[:3], ne.det_start[i], ne.det_start[i + 1], *ne._geo()[4:], brow)
        h[6 * i : 6 * i + 6, 6 * K :] = brow
        h[6 * K :, 6 * i : 6 * i + 6] = brow.T
    h[6 * K :, 6 * K :] = ne.c
    return h


def split(v):
    return v[: 6 * K].reshape(K, 6), v[6 * K :]


def test_gradient_is_the_cost_derivative_away_from_the_minimum(case):
    problem, guess, pt = case
    rng = np.random.default_rng(1)
    ne = g.Normal(problem, guess)
    away = rng.normal(size=6 * K + 3 * N_LM + 6 * N_SEG) * 1e-3
    away[6 * (K - 1) : 6 * K] = 0.0  # the anchor stays at its gauge (its prior is linearized as the identity)
    here = moved(pt, *split(away))
    grad = gradient(ne, here)
    for _ in range(3):
        d = rng.normal(size=grad.size)
        d[6 * (K - 1) : 6 * K] = 0.0
        eps = 1e-6
        fd = (ne.error(moved(here, *split(eps * d))) - ne.error(moved(here, *split(-eps * d)))) / (2 * eps)
        assert fd == pytest.approx(grad @ d, rel=1e-4)


def test_information_step_and_marginals_match_dense_linear_algebra(case):
    problem, guess, pt = case
    rng = np.random.default_rng(2)
    ne = g.Normal(problem, guess)
    ne.linearize(pt)
    h = dense_information(ne)
    g0 = np.r_[ne.ga.ravel(), ne.gb]
    d = rng.normal(size=h.shape[0])
    d[6 * (K - 1) : 6 * K] = 0.0  # the anchor: its gauge prior's 1e12 would dwarf every other entry
    eps = 1e-6
    fd = (gradient(ne, moved(pt, *split(eps * d))) - gradient(ne, moved(pt, *split(-eps * d)))) / (2 * eps)
    rows = np.r_[0 : 6 * (K - 1), 6 * K : h.shape[0]]
    assert np.allclose(fd[rows], (h @ d)[rows], rtol=1e-4, atol=1e-5 * np.abs(h @ d)[rows].max())
    ne.linearize(pt)
    lam = 1e-3
    out = ne.step(lam)
    assert out is not None
    expect = np.linalg.solve(h + lam * np.eye(h.shape[0]), -g0)
    x_exp, xb_exp = split(expect)
    assert np.allclose(out[0][2], pt[2] + xb_exp[: 3 * N_LM].reshape(-1, 3), rtol=0, atol=1e-9)
    assert np.allclose(out[0][1], pt[1] + np.einsum("kij,kj->ki", pt[0], x_exp[:, 3:]), rtol=0, atol=1e-9)
    assert np.allclose(out[0][3], pt[3] + xb_exp[3 * N_LM :].reshape(-1, 6), rtol=0, atol=1e-9)
    cov = np.linalg.inv(h)
    f = ne.factor(0.0)
    body = np.zeros((K, 6, 6))
    pose_marginals(ne._geo(), ne.dd, ne.ee, np.linalg.inv(f[0]), np.arange(K), body)
    dense = np.array([cov[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i in range(K)])
    assert np.allclose(body, dense, rtol=1e-6, atol=1e-9 * np.abs(dense).max())
    nb0 = 6 * K + 3 * N_LM
    assert np.allclose(ne.bias_covariance(f[0])[1], cov[nb0 + 6 : nb0 + 12, nb0 + 6 : nb0 + 12], rtol=1e-6)


def test_the_floor_s_gradient_is_its_cost_s_derivative_and_its_information_has_no_heading(case):
    """The floor's rows (graph.floor_terms) in the normal equations: their gradient is their cost's derivative (the
    tilt's cost is the same whatever the heading about the floor's normal); their information says nothing of that
    heading (the tilt rows, each of which reads it when tilted, without it: riekf's rows), away from a level pose."""
    from dataclasses import replace

    problem, guess, pt = case
    rng = np.random.default_rng(3)
    floor = np.stack([np.full(K, 1.0 / 0.02**2), np.full(K, 1.0 / 0.05**2)], axis=1)
    with_floor, without = g.Normal(replace(problem, floor=floor), guess), g.Normal(problem, guess)
    away = rng.normal(size=6 * K + 3 * N_LM + 6 * N_SEG) * 1e-3
    away[6 * (K - 1) : 6 * K] = 0.0
    here = moved(pt, *split(away))
    grad = gradient(with_floor, here) - gradient(without, here)
    info = with_floor.ad - without.ad

    def cost(at):
        return with_floor.error(at) - without.error(at)

    eps = 1e-6
    for _ in range(3):
        d = rng.normal(size=grad.size)
        d[6 * (K - 1) : 6 * K] = 0.0
        fd = (cost(moved(here, *split(eps * d))) - cost(moved(here, *split(-eps * d)))) / (2 * eps)
        assert fd == pytest.approx(grad @ d, rel=1e-5)
    r, jac = g.floor_terms(with_floor.plane, *here[:2])
    normal = np.einsum("kji,j->ki", here[0], with_floor.plane[1:4])  # Rᵀn: the turn about the floor's normal
    tilted = np.linalg.norm(r[:, :2], axis=1) > 0.05
    assert tilted[:-1].sum() > K // 3
    rows = info[:-1, :3, :3]  # the anchor's block holds the gauge too (test below)
    assert np.abs(np.einsum("kij,kj->ki", rows, normal[:-1])[tilted[:-1]]).max() < 1e-9 * np.abs(info).max()
    floor_info = np.einsum("kri,kr,krj->kij", jac, floor[:, [0, 0, 1]], jac)
    assert np.allclose(info[:-1], floor_info[:-1])


def test_with_the_floor_the_gauge_holds_the_anchor_s_position_and_heading_and_the_floor_its_tilt(case):
    """The floor's plane (graph.floor_at) has the keyframes' mean up axis for its normal, not the anchor's: a start
    whose anchor is tilted off the rest (a blind stretch's gyro drift) is not held at that tilt; the gauge keeps
    only the anchor's position and its heading about the normal, and the solve levels it with the others."""
    from dataclasses import replace

    from slamobs.pipeline.lie import so3_exp, so3_log

    problem, guess, _ = case
    up = guess.rot[:, :, 2].mean(axis=0)
    plane = g.floor_at(guess.rot, guess.pos, K - 1)
    assert np.allclose(plane[1:4], up / np.linalg.norm(up))
    floor = np.stack([np.full(K, 1.0 / 0.02**2), np.full(K, 1.0 / 0.05**2)], axis=1)
    tilted = guess.rot.copy()
    tilted[K - 1] = tilted[K - 1] @ so3_exp(np.array([0.2, 0.0, 0.0]))
    start = replace(guess, rot=tilted)
    ne = g.Normal(replace(problem, floor=floor), start)
    sol = g.solve(replace(problem, floor=floor), start)
    a = K - 1
    assert np.allclose(sol.pos[a], start.pos[a], atol=1e-6)
    turned = so3_log(tilted[a].T @ sol.rot[a])
    assert abs(turned @ ne.gauge_axis) < 1e-4  # the heading about the normal held
    assert np.linalg.norm(turned) > 0.05  # the tilt not: levelled toward the rest


def test_the_biases_covariance_leaves_out_a_landmark_the_gate_left_with_no_detection(case):
    """The χ² gate may drop every detection of one landmark (unseen sweep seed=2134 with the floor): its rows in the
    border's Schur complement are zero, undamped it is singular; the biases' covariance is the same as without it."""
    from dataclasses import replace

    problem, guess, pt = case
    kept = np.flatnonzero(problem.det_idx != 0)
    ne = g.Normal(g.with_detections(problem, kept), guess)
    ne.linearize(pt)
    s = ne.factor(0.0)[0]
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.inv(s)
    others = g.with_detections(problem, kept)
    others = replace(others, det_idx=others.det_idx - 1)  # the same problem without landmark 0
    ref = g.Normal(others, g.Guess(guess.rot, guess.pos, guess.landmarks[1:], guess.bias))
    ref.linearize((pt[0], pt[1], pt[2][1:], pt[3]))
    assert np.allclose(ne.bias_covariance(s), ref.bias_covariance(ref.factor(0.0)[0]), rtol=1e-9)


def test_the_marginal_covariances_leave_out_a_landmark_the_gate_left_with_no_detection(case):
    """The same for the poses' and landmarks' marginal covariances (seed=3973, a clock set back 5 s mid-log: a
    landmark's detections all gated, the run failed on numpy's ``Singular matrix``): the poses' and the other
    landmarks' are those of the problem without it, its own NaN (no detection constrains it)."""
    from dataclasses import replace

    problem, guess, pt = case
    kept = np.flatnonzero(problem.det_idx != 0)
    sol = g.Solution(*pt, bias_cov=np.zeros((N_SEG, 6, 6)))
    keyframes = np.array([0, K // 2, K - 1])
    pose, landmarks = g.covariances(g.with_detections(problem, kept), sol, keyframes)
    others = g.with_detections(problem, kept)
    others = replace(others, det_idx=others.det_idx - 1)  # the same problem without landmark 0
    ref = g.Solution(pt[0], pt[1], pt[2][1:], pt[3], bias_cov=sol.bias_cov)
    ref_pose, ref_landmarks = g.covariances(others, ref, keyframes)
    assert np.isnan(landmarks[0]).all() and np.isfinite(pose).all()
    assert np.allclose(pose, ref_pose, rtol=1e-8, atol=1e-14)
    assert np.allclose(landmarks[1:], ref_landmarks, rtol=1e-8, atol=1e-14)


def test_the_evidence_leaves_out_a_landmark_the_gate_left_with_no_detection(case):
    """The same for the evidence's ``log det H`` (seed=3973: the levels' evidence after range and bearing were
    weighed apart read "n/a" there and the level choice kept x1): the objective and the log determinant are those
    of the problem without the landmark, not None."""
    from dataclasses import replace

    problem, guess, pt = case
    kept = np.flatnonzero(problem.det_idx != 0)
    sol = g.Solution(*pt, bias_cov=np.zeros((N_SEG, 6, 6)))
    terms = g.evidence_terms(g.with_detections(problem, kept), sol)
    others = replace(g.with_detections(problem, kept), det_idx=problem.det_idx[kept] - 1)  # without landmark 0
    ref = g.evidence_terms(others, g.Solution(pt[0], pt[1], pt[2][1:], pt[3], bias_cov=sol.bias_cov))
    assert terms is not None and ref is not None
    assert np.allclose(terms, ref, rtol=1e-10, atol=1e-12)
    assert g.evidence_terms(problem, sol)[1] > terms[1]  # landmark 0's detections add information
