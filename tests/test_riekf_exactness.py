"""riekf's speed work keeps its numbers: the one-pass frame (the propagation pending as low-rank terms, applied
with the Kalman downdate in one pass over the covariance) equals the propagation then the update in plain dense
matrix algebra, the time offset's batched grid equals its shift-by-shift evaluation, and why a compressed EKF
(Guivant & Nebot) cannot equal this filter: the landmarks out of view move at every update (docs/benchmarks.md,
riekf)."""

from __future__ import annotations

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.lie import skew, so3_exp, so3_left_jacobian
from slamobs.pipeline.observers import ObserverOptions, time_offset
from slamobs.pipeline.observers.riekf import (
    CONSISTENCY_WINDOWS,
    N_FIXED,
    N_SLOTS,
    PAD,
    WIN_SUM_ROWS,
    correlation_arrays,
    RiEKF,
    apply,
    propagation_terms,
    update,
    whitened_update,
)
from slamobs.pipeline.simulate import expected_streams, simulate


@pytest.mark.parametrize(("d", "k"), [(13, 6), (27, 9), (102, 30), (15, 33)])
def test_one_pass_sum_equals_the_matrix_product(d, k):
    """``apply``: ``Σ + Σ_(q<6) lt[q]ᵀ rt[q] − Σ_(q≥6) lt[q]ᵀ lt[q]`` with the position rows' ``dp`` added, over
    the upper triangle four rows at a time (and the rows left over), mirrored: the same matrix as NumPy's, exactly
    symmetric."""
    rng = np.random.default_rng(d + k)
    cov = rng.normal(size=(d, d))
    cov = cov + cov.T
    lt, rt, dp = rng.normal(size=(k, d)), rng.normal(size=(k, d)), rng.normal(size=(3, d))
    lt[:6, 3:6], rt[:6, 3:6] = 0.0, 0.0  # the position rows' change is in dp alone
    sym = lt[:6].T @ rt[:6] - lt[6:].T @ lt[6:]
    expect = cov + np.triu(sym) + np.triu(sym, 1).T
    for a in range(3):  # dp[a] is row 3 + a of the change (upper triangle: from the diagonal on, and rows 0..2)
        expect[3 + a, 3 + a :] += dp[a, 3 + a :]
        expect[:3, 3 + a] += dp[a, :3]
    expect = np.triu(expect) + np.triu(expect, 1).T
    got = cov.copy()
    apply(got, d, lt, rt, k, dp, np.zeros(0, np.int64), -1)  # the whole triangle mirrored
    assert np.array_equal(got, got.T)
    assert np.abs(got - expect).max() <= 1e-13 * np.abs(expect).max()


@pytest.mark.parametrize(("d", "k"), [(102, 30), (27, 6), (45, 33)])
def test_one_pass_tiles_give_the_bits_of_the_rows(d, k):
    """``apply`` on arrays padded to whole vectors (``PAD``: the eight-row tiles held in registers, ``pipeline.simd``)
    and on the same numbers unpadded (summed row by row): every entry of the upper triangle the same bits, each term
    added in its order as one fused multiply-add either way."""
    rng = np.random.default_rng(7 * d + k)
    dim = d + -d % PAD
    cov = np.zeros((dim, dim))
    cov[:d, :d] = rng.normal(size=(d, d))
    cov[:d, :d] += cov[:d, :d].T
    lt, rt, dp = np.zeros((k, dim)), np.zeros((6, dim)), np.zeros((3, dim))
    lt[:, :d], rt[:, :d], dp[:, :d] = rng.normal(size=(k, d)), rng.normal(size=(6, d)), rng.normal(size=(3, d))
    lt[:6, 3:6], rt[:, 3:6] = 0.0, 0.0
    padded, rows = cov.copy(), np.zeros(0, np.int64)
    apply(padded, d, lt, rt, k, dp, rows, -1)
    plain = np.ascontiguousarray(cov[:d, :d])
    apply(plain, d, lt[:, :d].copy(), rt[:, :d].copy(), k, dp[:, :d].copy(), rows, -1)
    assert np.array_equal(padded[:d, :d], plain)
    assert not padded[d:].any() and not padded[:, d:].any()  # zeros past d add zeros


def _dense_frame(cov, d, lm, slot_lm, acc, dt, walk_w, walk_v, h, z, noise):
    """One frame as the textbook writes it: ``Σ⁻ = Φ (Σ + walk) Φᵀ + Q`` with ``Φ = I + F`` from the running sums,
    then ``K = Σ⁻Hᵀ S⁻¹``, ``ξ̂ = K z``, ``Σ⁺ = Σ⁻ − K S Kᵀ`` (dense matrices, NumPy); ``noise(Σ⁻_RR)``: the
    detections' noise, which may depend on the propagated attitude block."""
    n = (d - N_FIXED) // 3
    f = np.zeros((d, 6))
    f[0:3, 0:3], f[3:6, 0:3], f[3:6, 3:6] = acc[0], acc[1], acc[0]
    q = np.zeros((d, d))
    q[0:3, 0:3], q[3:6, 0:3], q[0:3, 3:6], q[3:6, 3:6] = acc[2], acc[3], acc[3].T, acc[4]
    for s in range(n):
        rs, ls = slice(N_FIXED + 3 * s, N_FIXED + 3 + 3 * s), skew(lm[slot_lm[s]])
        f[rs, 0:3] = ls @ acc[0]
        q[rs, 0:3], q[rs, 3:6] = ls @ acc[2], ls @ acc[3].T
        q[0:3, rs], q[3:6, rs] = q[rs, 0:3].T, q[rs, 3:6].T
        for u in range(n):
            q[rs, N_FIXED + 3 * u : N_FIXED + 3 + 3 * u] = ls @ acc[2] @ skew(lm[slot_lm[u]]).T
    phi = np.eye(d)
    phi[:, 6:12] += f
    prior = cov[:d, :d].copy()
    prior[6:9, 6:9] += walk_w**2 * dt * np.eye(3)
    prior[9:12, 9:12] += walk_v**2 * dt * np.eye(3)
    prior = phi @ prior @ phi.T + q
    s_mat = h @ prior @ h.T + noise(prior[:3, :3])
    k = prior @ h.T @ np.linalg.inv(s_mat)
    return k @ z, prior - k @ s_mat @ k.T


def _random_frame_state():
    """A random filter state of six landmarks (seeded): the generator for what follows, n, d, the slots, a positive
    definite covariance, the map, the propagation sums (ΣR̂h, Σ[P̂]×R̂h; the noise sums from a positive definite W), the
    pose and the biases."""
    rng = np.random.default_rng(27)
    n = 6
    d = N_FIXED + 3 * n
    slot_of = rng.permutation(n)
    slot_lm = np.argsort(slot_of)
    a = rng.normal(size=(d, d))
    cov = (a @ a.T + d * np.eye(d)) * 1e-3
    lm = rng.normal(size=(n, 3)) * 5
    acc = rng.normal(size=(5, 3, 3)) * 0.1  # ΣR̂h, Σ[P̂]×R̂h; the noise sums from a positive definite W
    w = rng.normal(size=(6, 6)) * 0.1
    w = w @ w.T
    acc[2], acc[3], acc[4] = w[:3, :3], w[3:, :3], w[3:, 3:]
    r_hat, p_hat = so3_exp(rng.normal(size=3)), rng.normal(size=3)
    b_om, b_v = rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.01
    return rng, n, d, slot_of, slot_lm, cov, lm, acc, r_hat, p_hat, b_om, b_v


def test_one_pass_frame_equals_propagation_then_kalman_update():
    """A frame with propagation pending (``propagation_terms``) and three detections of known landmarks
    (``update``: gain from the rows of ``Σ⁻`` it needs, propagation and downdate in one pass) against the
    dense propagation then the dense Kalman update: covariance, state and map to 1e-12 of their magnitudes."""
    rng, n, d, slot_of, slot_lm, cov, lm, acc, r_hat, p_hat, b_om, b_v = _random_frame_state()
    det_idx = np.array([4, 1, 3])
    det_y = rng.normal(size=(3, 3)) * 3
    law = np.array([0.02, 0.004, 0.0, 1.0, 0.0])  # σ(r) = 0.02 + 0.004 r at the range the state predicts
    sigma2 = (law[0] + law[1] * np.linalg.norm(lm[det_idx] - p_hat, axis=1)) ** 2
    walk_w, walk_v, dt = 0.01, 0.02, 0.1
    h = np.zeros((9, d))
    z = np.zeros(9)
    for q, i in enumerate(det_idx):
        sl = N_FIXED + 3 * slot_of[i]
        h[3 * q : 3 * q + 3, 3:6] = np.eye(3)
        h[3 * q : 3 * q + 3, sl : sl + 3] = -np.eye(3)
        z[3 * q : 3 * q + 3] = r_hat @ det_y[q] + p_hat - lm[i]
    xi, cov_exp = _dense_frame(
        cov, d, lm, slot_lm, acc, dt, walk_w, walk_v, h, z, lambda srr: np.diag(np.repeat(sigma2, 3))
    )
    a_exp, jl = so3_exp(-xi[:3]), so3_left_jacobian(-xi[:3])
    lm_exp = np.array([a_exp @ lm[i] - jl @ xi[N_FIXED + 3 * slot_of[i] :][:3] for i in range(n)])
    r_exp, p_exp = a_exp @ r_hat, a_exp @ p_hat - jl @ xi[3:6]
    b_exp = np.r_[b_om, b_v] + xi[6:12]

    lt, rt, dp = np.zeros((15, d)), np.zeros((15, d)), np.zeros((3, d))
    assert propagation_terms(cov, d, lm, slot_lm, acc.copy(), dt, walk_w, walk_v, lt, rt, dp)
    ns = np.zeros(N_SLOTS, dtype=np.int64)
    innov, trk = np.zeros((3, 3)), np.zeros((3, 3))
    d_out = update(
        0, 3, det_idx, det_y, law, cov, d, r_hat, p_hat, b_om, b_v, lm, slot_of, slot_lm,
        np.zeros(3, np.int64), np.zeros(9), lt, rt, dp, np.zeros((9, 9)), innov, trk, 0, ns, 1e9, 1.0,
        np.zeros(9), np.zeros((9, 3)), np.zeros(9, np.int64), np.zeros(n, np.bool_), np.zeros(n, np.bool_),
        np.zeros((WIN_SUM_ROWS, CONSISTENCY_WINDOWS)), np.zeros(1), *correlation_arrays(n),
    )  # fmt: skip
    assert d_out == d and ns[9] == 1 and ns[8] == 0  # no new landmark, none gated; one update
    assert np.abs(cov - cov_exp).max() <= 1e-12 * np.abs(cov_exp).max() and np.array_equal(cov, cov.T)
    for got, want in ((r_hat, r_exp), (p_hat, p_exp), (lm, lm_exp), (np.r_[b_om, b_v], b_exp)):
        assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()


@pytest.mark.parametrize(
    ("n", "k", "bias_only"), [(1, 3, False), (4, 3, False), (4, 6, False), (3, 6, True), (4, 6, True)]
)
def test_a_pseudo_measurement_update_equals_the_dense_kalman_update(n, k, bias_only):
    """``whitened_update`` (the floor's three rows and a still window's six: ``_gain``'s whitening, the detection
    update's, then ``Σ − WᵀW``): the dense Kalman update, ``K = ΣHᵀS⁻¹``, ``ξ̂ = K z``, ``Σ⁺ = Σ − K S Kᵀ``, to 1e-12
    of the magnitudes (n = 4: d = 24, whole vectors, the padded path). With the bias rows only (the still window's
    Schmidt update while the heading is unknown) the bias rows and their correlations are the dense update's and
    every other entry of ``Σ``, the pose and the map are the bits they were. A d² over the gate changes nothing."""
    rng = np.random.default_rng(4420 + 10 * n + k)
    d = N_FIXED + 3 * n
    a = rng.normal(size=(d, d))
    cov = (a @ a.T + d * np.eye(d)) * 1e-3
    lm, slot_lm = rng.normal(size=(n, 3)) * 5, rng.permutation(n)
    r_hat, p_hat = so3_exp(rng.normal(size=3)), rng.normal(size=3)
    b_om, b_v = rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.01
    h = rng.normal(size=(k, d))
    z = rng.normal(size=k) * 0.05
    s_mat = h @ cov @ h.T + np.diag(rng.uniform(0.5, 2.0, size=k)) * 1e-3
    gain = cov @ h.T @ np.linalg.inv(s_mat)
    xi, cov_exp = gain @ z, cov - gain @ s_mat @ gain.T
    lo, hi = (6, N_FIXED) if bias_only else (0, d)
    keep = np.ones(d, bool)
    keep[lo:hi] = False
    if bias_only:  # a Schmidt update: the other rows' block as it was, their ξ̂ zero
        cov_exp[np.ix_(keep, keep)], xi[keep] = cov[np.ix_(keep, keep)], 0.0
    a_exp, jl = so3_exp(-xi[:3]), so3_left_jacobian(-xi[:3])
    lm_exp = lm @ a_exp.T - np.array([jl @ xi[N_FIXED + 3 * s : N_FIXED + 3 * s + 3] for s in np.argsort(slot_lm)])
    want = (a_exp @ r_hat, a_exp @ p_hat - jl @ xi[3:6], lm_exp, np.r_[b_om, b_v] + xi[6:12])
    before = (cov.copy(), r_hat.copy(), p_hat.copy(), lm.copy(), b_om.copy(), b_v.copy())

    args = (r_hat, p_hat, b_om, b_v, lm, slot_lm)
    chol = np.linalg.cholesky(s_mat)
    d2 = float(np.sum(np.linalg.solve(chol, z) ** 2))
    assert not whitened_update(cov, d, h @ cov, chol.copy(), z.copy(), k, 0.99 * d2, lo, hi, *args)
    for got, was in zip((cov, r_hat, p_hat, lm, b_om, b_v), before):
        assert np.array_equal(got, was)
    assert whitened_update(cov, d, h @ cov, chol, z.copy(), k, 1.01 * d2, lo, hi, *args)
    assert np.abs(cov - cov_exp).max() <= 1e-12 * np.abs(cov_exp).max()
    for got, exp in zip((r_hat, p_hat, lm, np.r_[b_om, b_v]), want):
        assert np.abs(got - exp).max() <= 1e-12 * np.abs(exp).max()
    if bias_only:
        assert np.array_equal(cov[np.ix_(keep, keep)], before[0][np.ix_(keep, keep)])
        for got, was in zip((r_hat, p_hat, lm), before[1:4]):
            assert np.array_equal(got, was)


def linearisation_noise(z: np.ndarray, srr: np.ndarray, sigma2: float, gate: float) -> np.ndarray:
    """A lone detection's noise in the update beyond ``σ²I``: ``[z]× Σ⁻_RR [z]×ᵀ`` (the covariance of the term
    ``−[z]× ξ_R`` the invariant model's constant ``H`` drops) when ``|z|² tr Σ⁻_RR`` exceeds ``gate σ²``, else none."""
    if z @ z * np.trace(srr) <= gate * sigma2:
        return np.zeros((3, 3))
    return skew(z) @ srr @ skew(z).T


def test_a_lone_detection_far_off_is_updated_with_the_linearisations_dropped_term():
    """A frame whose only detection is metres off while the attitude σ is about 15° (a return after a blind
    stretch): its noise in the update is ``σ²I + [z]× Σ⁻_RR [z]×ᵀ``, the covariance of the turn of the innovation the
    invariant ``H`` drops, since ``|z|² tr Σ⁻_RR`` is over the gate's ``σ²``; the frame still equals the dense
    propagation then the dense Kalman update with that noise. With two or more detections in a frame the noise is
    the law's alone (the test above)."""
    rng, n, d, slot_of, slot_lm, cov, lm, acc, r_hat, p_hat, b_om, b_v = _random_frame_state()
    i = 4
    det_y = rng.normal(size=(1, 3)) * 3
    law = np.array([0.02, 0.004, 0.0, 1.0, 0.0])
    sigma2 = (law[0] + law[1] * np.linalg.norm(lm[i] - p_hat)) ** 2
    gate, walk_w, walk_v, dt = 1000.0, 0.01, 0.02, 0.1
    sl = N_FIXED + 3 * slot_of[i]
    h = np.zeros((3, d))
    h[:, 3:6], h[:, sl : sl + 3] = np.eye(3), -np.eye(3)
    z = r_hat @ det_y[0] + p_hat - lm[i]

    def noise(srr):
        lin = linearisation_noise(z, srr, sigma2, gate)
        assert lin.any() and z @ z * np.trace(srr) > gate * sigma2
        return sigma2 * np.eye(3) + lin

    xi, cov_exp = _dense_frame(cov, d, lm, slot_lm, acc, dt, walk_w, walk_v, h, z, noise)
    xi_plain, _ = _dense_frame(cov, d, lm, slot_lm, acc, dt, walk_w, walk_v, h, z, lambda srr: sigma2 * np.eye(3))
    assert np.linalg.norm(xi[:6]) < 0.9 * np.linalg.norm(xi_plain[:6])  # the pose moved less than plainly
    a_exp, jl = so3_exp(-xi[:3]), so3_left_jacobian(-xi[:3])
    r_exp, p_exp = a_exp @ r_hat, a_exp @ p_hat - jl @ xi[3:6]

    lt, rt, dp = np.zeros((9, d)), np.zeros((9, d)), np.zeros((3, d))
    assert propagation_terms(cov, d, lm, slot_lm, acc.copy(), dt, walk_w, walk_v, lt, rt, dp)
    ns = np.zeros(N_SLOTS, dtype=np.int64)
    d_out = update(
        0, 1, np.array([i]), det_y, law, cov, d, r_hat, p_hat, b_om, b_v, lm, slot_of, slot_lm,
        np.zeros(1, np.int64), np.zeros(3), lt, rt, dp, np.zeros((3, 3)), np.zeros((1, 3)), np.zeros((1, 3)), 0, ns,
        gate, 1.0, np.zeros(9), np.zeros((9, 3)), np.zeros(9, np.int64), np.zeros(n, np.bool_),
        np.zeros(n, np.bool_), np.zeros((WIN_SUM_ROWS, CONSISTENCY_WINDOWS)), np.zeros(1), *correlation_arrays(n),
    )  # fmt: skip
    assert d_out == d and ns[9] == 1 and ns[8] == 0  # one update, not gated
    assert np.abs(cov - cov_exp).max() <= 1e-12 * np.abs(cov_exp).max()
    for got, want in ((r_hat, r_exp), (p_hat, p_exp)):
        assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()


def _two_frames(partial: bool):
    """Two frames through ``update``, propagation pending before each: the first detects landmarks 4, 1, 3 and a
    new one, 6 (augmented from the position's rows), and mirrors either the whole lower triangle or (``partial``)
    only what the second reads of it (the second detects 0, 1, 5 and 6); the covariance, state and map after each."""
    rng = np.random.default_rng(31)
    n, seen = 7, 6
    d = N_FIXED + 3 * seen
    slot_of = np.r_[rng.permutation(seen), -1]
    slot_lm = np.r_[np.argsort(slot_of[:seen]), 0]
    a = rng.normal(size=(d, d))
    cov = np.zeros((d + 4, d + 4))  # room for the new landmark, padded
    cov[:d, :d] = (a @ a.T + d * np.eye(d)) * 1e-3
    lm = rng.normal(size=(n, 3)) * 5
    r_hat, p_hat = so3_exp(rng.normal(size=3) * 0.3), rng.normal(size=3)
    b_om, b_v = np.zeros(3), np.zeros(3)
    det_idx = np.array([4, 1, 3, 6, 0, 1, 5, 6])
    det_y = np.array([r_hat.T @ (lm[i] - p_hat) for i in det_idx]) + rng.normal(size=(8, 3)) * 0.01
    law = np.array([0.02, 0.004, 0.0, 1.0, 0.0])
    width = cov.shape[0]
    lt, rt, dp = np.zeros((6 + 12, width)), np.zeros((6, width)), np.zeros((3, width))
    ns = np.zeros(N_SLOTS, dtype=np.int64)
    after = []
    for a0, nd, nxt in ((0, 4, 4 if partial else -1), (4, 4, -1)):
        acc = rng.normal(size=(5, 3, 3)) * 0.01
        w = rng.normal(size=(6, 6)) * 0.01
        acc[2], acc[3], acc[4] = (w @ w.T)[:3, :3], (w @ w.T)[3:, :3], (w @ w.T)[3:, 3:]
        propagation_terms(cov, d, lm, slot_lm, acc, 0.1, 0.01, 0.02, lt, rt, dp)
        d = update(
            a0, nd, det_idx, det_y, law, cov, d, r_hat, p_hat, b_om, b_v, lm, slot_of, slot_lm,
            np.zeros(4, np.int64), np.zeros(12), lt, rt, dp, np.zeros((12, 12)), np.zeros((8, 3)), np.zeros((8, 3)),
            0, ns, 1e9, 1.0, np.zeros(9), np.zeros((9, 3)), np.zeros(9, np.int64), np.zeros(n, np.bool_),
            np.zeros(n, np.bool_), np.zeros((WIN_SUM_ROWS, CONSISTENCY_WINDOWS)), np.zeros(1),
            *correlation_arrays(n), 4, nxt,
        )  # fmt: skip
        after.append((cov.copy(), r_hat.copy(), p_hat.copy(), np.r_[b_om, b_v], lm.copy()))
    assert ns[9] == 2 and ns[8] == 0 and d == N_FIXED + 3 * n  # two updates, none gated, landmark 6 augmented
    return after


def test_mirroring_what_the_next_frame_reads_gives_the_same_bits():
    """``update`` with the next frame's detections mirrors only the rows of ``Σ`` that frame reads below the
    diagonal (``_mirror_read``): the next frame gives the bits it gives after a whole mirror, though the first
    frame left other entries below the diagonal stale (and augmented a landmark from the position's rows)."""
    whole, partial = _two_frames(False), _two_frames(True)
    cov_w, cov_p = whole[0][0], partial[0][0]
    assert np.array_equal(np.triu(cov_w), np.triu(cov_p)) and not np.array_equal(cov_w, cov_p)
    for got, want in zip(partial[1], whole[1], strict=True):  # the second frame mirrors the whole triangle
        assert np.array_equal(got, want)


@pytest.fixture(scope="module")
def generated():
    sim = simulate("figure8", duration=12.0, seed=5)
    return align(expected_streams(sim), keep_directions=False)


def test_time_offset_grid_in_one_pass_equals_shift_by_shift(generated):
    """The residuals of many shifts in one pass (a pair at every shift, walking from the last shift's sample)
    equal each shift alone (a binary search), in any order of the shifts; so do the costs."""
    c = time_offset.Consistency(generated, np.zeros(6))
    shifts = np.array([0.3, -0.5, 0.02, 0.021, -0.2, 0.5, 0.0])
    together = c.residuals(shifts)
    for s, e in zip(shifts, together, strict=True):
        assert np.array_equal(e, c.residuals(s)[0])
    assert np.array_equal(c.costs(shifts), [c.costs(s)[0] for s in shifts])
    assert c.a.shape[0] >= time_offset.MIN_PAIRS


def test_time_offset_velocity_lags_in_one_pass_equal_a_dead_reckoning_per_lag(generated):
    """``velocity_lag``'s positions of all lags in one pass (the rotations shared, the positions linear in the
    velocity) equal the positions of one dead reckoning per lag of the velocity moved by it (``np.interp``), the
    21 of which were 0.14 of the estimate's CPU s on the one-hour log."""
    from slamobs.pipeline.lie import integrate_body_twists

    c = time_offset.Consistency(generated, np.zeros(6))
    t_s, rot_s, _, omega, vel = c.poses
    omega_steps, _, dt = c._steps
    lags = np.array([-0.2, -0.03, 0.0, 0.07, 0.2])
    keep = np.arange(0, t_s.shape[0], 7)
    out = np.empty((lags.shape[0], keep.shape[0], 3))
    time_offset.lagged_positions(t_s, rot_s, omega_steps, vel, dt, np.zeros(dt.shape[0], np.bool_), lags, keep, out)
    for k, lag in enumerate(lags):
        moved = np.column_stack([np.interp(t_s[:-1] + lag, t_s, vel[:, a]) for a in range(3)])
        _, ps = integrate_body_twists(np.eye(3), np.zeros(3), omega_steps, moved, dt)
        np.testing.assert_allclose(out[k], ps[keep], rtol=0, atol=1e-9)
    assert np.abs(out[0] - out[-1]).max() > 1e-3  # the lags move the positions


def test_landmarks_out_of_view_move_at_every_update(generated):
    """Why riekf keeps its dense covariance exact rather than a compressed EKF: an update moves every landmark
    through its correlation with the pose, in view or not, and the propagation of a landmark's covariance rows
    reads its estimate (``[p̂_s]×`` in the right-invariant error). A compressed EKF carries the passive
    landmarks' rows in accumulated matrices that must not depend on their estimates: it would differ from this
    filter by the passive landmarks' moves, far above the 1e-9 the outputs are held to."""
    f = RiEKF(generated, {}, ObserverOptions())
    s, moved = generated, []
    before = None
    for jf in range(5, 60):
        f.advance(int(np.searchsorted(f.vel_t, f.det_t[jf], side="right")))  # up to frame jf, the next not yet
        assert f.state.ns[1] == jf + 1
        seen = f.state.slot_of >= 0
        in_view = np.zeros(seen.shape[0], bool)
        in_view[s.det_idx[s.det_offsets[jf] : s.det_offsets[jf + 1]]] = True
        if before is not None:
            out = seen & before[1] & ~in_view
            if out.any():
                step = np.abs(f.lm[out] - before[0][out]).max() / np.abs(f.lm[seen]).max()
                moved.append(step)
        before = (f.lm.copy(), seen.copy())
    assert len(moved) > 20 and min(moved) > 1e-6, moved
    assert int(f.state.ns[7]) * 3 + N_FIXED <= f.state.cov.shape[0]
