"""riekf's speed work keeps its numbers: the blocked dense loops sum each entry in the textbook order (bit for bit),
the time offset's batched grid equals its shift-by-shift evaluation, and why a compressed EKF (Guivant & Nebot)
cannot equal this filter: the landmarks out of view move at every update (docs/benchmarks.md, riekf)."""

from __future__ import annotations

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.observers import ObserverOptions, time_offset
from slamobs.pipeline.observers.riekf import N_FIXED, RiEKF, _add_bias_terms, _gain_and_downdate
from slamobs.pipeline.simulate import expected_streams, simulate


def _textbook_gain_and_downdate(cov, d, hp, chol, z, k3):
    """The loops as first written: one term a pass, each entry summed in order (plain Python)."""
    for c in range(k3):
        for r in range(d):
            v = hp[c, r]
            for k in range(c):
                v -= hp[k, r] * chol[c, k]
            hp[c, r] = v / chol[c, c]
    w = np.zeros(k3)
    for c in range(k3):
        v = z[c]
        for k in range(c):
            v -= chol[c, k] * w[k]
        w[c] = v / chol[c, c]
    xi = np.zeros(d)
    for c in range(k3):
        for r in range(d):
            xi[r] += hp[c, r] * w[c]
    for r in range(d):
        for c in range(r, d):
            acc = 0.0
            for k in range(k3):
                acc += hp[k, r] * hp[k, c]
            cov[r, c] -= acc
            cov[c, r] = cov[r, c]
    return xi


def _textbook_bias_terms(cov, d, f, pb, g):
    for i in range(d):
        for j in range(i, d):
            acc = 0.0
            for e in range(6):
                acc += f[e, i] * pb[e, j] + pb[e, i] * f[e, j] + g[e, i] * f[e, j]
            cov[i, j] += acc
            cov[j, i] = cov[i, j]


@pytest.mark.parametrize("k3", [3, 9, 24])
def test_blocked_downdate_is_bit_for_bit_the_textbook_loop(k3):
    """Four terms a pass (and the remainder one at a time) add each entry's terms in the same order."""
    rng = np.random.default_rng(k3)
    d = N_FIXED + 3 * 5
    a = rng.normal(size=(d, d))
    cov = a @ a.T + d * np.eye(d)
    hp = rng.normal(size=(k3, d))
    s = rng.normal(size=(k3, k3))
    chol = np.linalg.cholesky(s @ s.T + k3 * np.eye(k3))
    z = rng.normal(size=k3)
    c1, h1, c2, h2 = cov.copy(), hp.copy(), cov.copy(), hp.copy()
    x1 = _gain_and_downdate(c1, d, h1, chol, z, k3)
    x2 = _textbook_gain_and_downdate(c2, d, h2, chol, z, k3)
    assert np.array_equal(h1, h2) and np.array_equal(x1, x2) and np.array_equal(c1, c2)


def test_bias_terms_in_one_pass_are_bit_for_bit_the_textbook_loop():
    """The landmark rows' three b̃_Ω terms in one pass: the same sums as over all six bias columns (F is zero in
    the b̃_V columns off the position rows, as the filter builds it)."""
    rng = np.random.default_rng(3)
    d = N_FIXED + 3 * 4
    cov = rng.normal(size=(d, d))
    cov = cov + cov.T
    f, pb, g = rng.normal(size=(3, 6, d))
    f[3:, :3] = 0.0  # Fᵀ: b̃_V reaches ξ_P (columns 3..5) only
    f[3:, 6:] = 0.0
    c1, c2 = cov.copy(), cov.copy()
    _add_bias_terms(c1, d, f, pb, g)
    _textbook_bias_terms(c2, d, f, pb, g)
    assert np.array_equal(c1, c2)


@pytest.fixture(scope="module")
def generated():
    sim = simulate("figure8", duration=12.0, seed=5)
    return align(expected_streams(sim), keep_directions=False)


def test_time_offset_grid_in_one_pass_equals_shift_by_shift(generated):
    """The residuals of many shifts in one pass (a pair at every shift, walking from the last shift's sample)
    equal each shift alone (a binary search), in any order of the shifts; so do the costs."""
    c = time_offset._Consistency(generated, np.zeros(6))
    shifts = np.array([0.3, -0.5, 0.02, 0.021, -0.2, 0.5, 0.0])
    together = c.residuals(shifts)
    for s, e in zip(shifts, together, strict=True):
        assert np.array_equal(e, c.residuals(s)[0])
    assert np.array_equal(c.costs(shifts), [c.costs(s)[0] for s in shifts])
    assert c.a.shape[0] >= time_offset.MIN_PAIRS


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
