"""Lie-group helpers: identities of docs/observers.md §1 and agreement between the allocation-free and plain forms."""

from __future__ import annotations

import numpy as np
import pytest

from slamobs.pipeline import lie
from slamobs.pipeline.evaluation import metrics


def expm(a, terms=40):
    """Matrix exponential by its series (small test matrices only)."""
    out = np.eye(a.shape[0])
    term = np.eye(a.shape[0])
    for k in range(1, terms):
        term = term @ a / k
        out = out + term
    return out


def _twist_and_exponential(scale: float, seed: int):
    """A random twist ``(w, v)`` with ``|w| = scale`` and its SE(3) exponential by ``scipy.linalg.expm``."""
    rng = np.random.default_rng(seed)
    w = rng.normal(size=3)
    w = w / np.linalg.norm(w) * scale
    v = rng.normal(size=3)
    a = np.zeros((4, 4))
    a[:3, :3] = lie.skew(w)
    a[:3, 3] = v
    return w, v, expm(a)


@pytest.mark.parametrize("scale", [0.0, 1e-10, 1e-3, 0.5, 2.0, 3.1])
def test_se3_exp_matches_matrix_exponential(scale):
    w, v, ref = _twist_and_exponential(scale, int(scale * 1000))
    r, p = lie.se3_exp(w, v)
    assert np.allclose(r, ref[:3, :3], atol=1e-12)
    assert np.allclose(p, ref[:3, 3], atol=1e-12)
    r2, p2 = np.empty((3, 3)), np.empty(3)
    lie.se3_exp_into(*w, *v, r2, p2)
    assert np.allclose(r2, r, atol=1e-14) and np.allclose(p2, p, atol=1e-14)


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-6, 1e-4, 1e-3, 0.03, 0.0999, 0.1001, 0.5])
def test_se3_exp_into_is_the_exponential_to_rounding(scale):
    """The exponential's coefficients from their series (below 0.1 rad) are the matrix exponential to rounding, also at
    the angles of an integration step where the closed form's ``1 − cos θ`` and ``θ − sin θ`` lose digits (its p was
    4e-13 off at 1e-4); above, the closed form. ``so3_left_jacobian_apply`` (riekf's correction) takes the same."""
    w, v, ref = _twist_and_exponential(scale, int(scale * 1e6) + 7)
    r, p = np.empty((3, 3)), np.empty(3)
    lie.se3_exp_into(*w, *v, r, p)
    assert np.abs(r - ref[:3, :3]).max() <= 4e-16
    assert np.abs(p - ref[:3, 3]).max() <= 4e-15 * max(1.0, scale)
    assert np.abs(np.array(lie.so3_left_jacobian_apply(*w, *v)) - ref[:3, 3]).max() <= 4e-15 * max(1.0, scale)


def test_log_inverts_exp_including_near_pi():
    rng = np.random.default_rng(3)
    for angle in [1e-9, 1e-3, 1.0, np.pi - 1e-3, np.pi - 1e-7]:
        axis = rng.normal(size=3)
        w = axis / np.linalg.norm(axis) * angle
        assert np.allclose(lie.so3_log(lie.so3_exp(w)), w, atol=1e-6)
        assert lie.rotation_angle(lie.so3_exp(w)) == pytest.approx(angle, abs=1e-6)


def test_quaternion_round_trip_and_sign():
    rng = np.random.default_rng(4)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rots = lie.quats_to_rots(q)
    back = lie.rots_to_quats(rots)
    assert np.all(back[:, 3] >= 0)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", back, q)), 1.0)
    assert np.allclose(np.einsum("kji,kjl->kil", rots, rots), np.eye(3), atol=1e-12)


def test_rots_to_quats_is_rot_to_quat_row_by_row():
    """Every branch of Shepperd's method (trace, then the largest diagonal entry), scaled and NaN matrices: the
    array version gives exactly the scalar one's numbers."""
    rng = np.random.default_rng(6)
    q = rng.normal(size=(400, 4))
    rots = lie.quats_to_rots(q / np.linalg.norm(q, axis=1, keepdims=True))
    rots[:4] = [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])]
    rots[4] *= 1.01
    rots[5] = np.nan
    got = lie.rots_to_quats(rots[::-1][::-1])  # a strided view, as callers may pass
    want = np.array([lie.rot_to_quat(np.ascontiguousarray(r)) for r in rots])
    assert np.array_equal(got, want, equal_nan=True)
    assert np.isnan(got[5]).all() and got[1].tolist() == [1.0, 0.0, 0.0, 0.0]


def test_quats_to_rots_is_quat_to_rot_row_by_row():
    rng = np.random.default_rng(7)
    q = rng.normal(size=(300, 4)) * rng.uniform(0.1, 10.0, size=(300, 1))  # not normalised
    q[3] = 0.0
    q[4] = np.nan
    got = lie.quats_to_rots(q[:, [0, 1, 2, 3]])  # a copy with its own strides
    assert np.array_equal(got[5:], np.array([lie.quat_to_rot(row) for row in q[5:]]))
    assert np.isnan(got[3]).all() and np.isnan(got[4]).all()  # a zero quaternion is no rotation: NaN


def test_short_and_long_arrays_of_rotations_give_the_same_bits(monkeypatch):
    """Short arrays take array code, long ones the compiled kernel (``lie.ROTATION_KERNEL_ROWS``): both directions
    give the same bits for every case of Shepperd's method, near-ties between diagonal entries, tiny, zero and NaN
    quaternions, matrices that are not rotations."""
    rng = np.random.default_rng(8)
    q = rng.normal(size=(6000, 4))
    q[:100] *= 1e-200
    q[100:200] = 0.0
    q[200:300, :3] = 0.0
    q[300, 1] = np.nan
    q[400:500] = np.round(q[400:500])  # exact multiples of pi / 2 and ties
    m = np.empty((6000, 3, 3))
    lie.rots_quats_into(m, q, False)
    m[500:1000] += rng.normal(scale=1e-3, size=(500, 3, 3))
    m[1000:1100] = rng.normal(size=(100, 3, 3))
    m[1100:1200] = np.diag([-1.0, -1.0, 1.0])
    m[1200] = np.nan
    got = {}
    for rows in (1, 1 << 62):
        monkeypatch.setattr(lie, "ROTATION_KERNEL_ROWS", rows)
        got[rows] = (lie.quats_to_rots(q), lie.rots_to_quats(m))
    for a, b in zip(got[1], got[1 << 62]):
        assert np.array_equal(a.view(np.int64), b.view(np.int64))


def test_skew_vex_and_identities():
    rng = np.random.default_rng(5)
    x, y = rng.normal(size=3), rng.normal(size=3)
    r = lie.so3_exp(rng.normal(size=3))
    assert np.allclose(lie.skew(x) @ y, np.cross(x, y))
    assert np.allclose(lie.vex(lie.skew(x)), x)
    assert np.allclose(lie.skew(r @ x), r @ lie.skew(x) @ r.T)
    assert np.trace(lie.skew(x) @ lie.skew(y)) == pytest.approx(-2 * x @ y)
    drift = r + 1e-7 * rng.normal(size=(3, 3))
    fixed = lie.project_so3(drift)
    assert np.allclose(fixed.T @ fixed, np.eye(3), atol=1e-12)
    assert np.abs(fixed - r).max() < 1e-6


def test_three_velocity_columns_in_one_dead_reckoning_equal_three():
    """``integrate_body_twists_at_columns`` (the time offset's velocity-bias Jacobian): the rotations shared, each
    column's positions the same bits as :func:`lie.integrate_body_twists_at` on the velocities with that column
    replaced, and the rotations those of every call."""
    rng = np.random.default_rng(11)
    k = 500
    omega, v, cols = rng.normal(size=(k, 3)), rng.normal(size=(k, 3)), rng.normal(size=(k, 3))
    omega[::50] = 0.0  # small angles take the series branch
    dt = rng.uniform(0.001, 0.02, k)
    keep = np.sort(rng.choice(k + 1, 40, replace=False))
    r0, p0 = lie.so3_exp(rng.normal(size=3)), rng.normal(size=3)
    rs, ps = lie.integrate_body_twists_at_columns(r0, p0, omega, v, cols, dt, keep)
    for c in range(3):
        vc = v.copy()
        vc[:, c] = cols[:, c]
        r_one, p_one = lie.integrate_body_twists_at(r0, p0, omega, vc, dt, keep)
        assert np.array_equal(rs, r_one) and np.array_equal(ps[c], p_one)
    assert not np.array_equal(ps[0], ps[1])


def test_three_gyro_columns_in_one_pass_equal_three_dead_reckonings():
    """``integrate_body_twists_at_rotation_columns`` (the time offset's gyro-bias Jacobian): each column's rotations
    and positions the same bits as :func:`lie.integrate_body_twists_at` on the angular velocities with that column
    replaced."""
    rng = np.random.default_rng(12)
    k = 500
    omega, v, cols = rng.normal(size=(k, 3)), rng.normal(size=(k, 3)), rng.normal(size=(k, 3))
    omega[::50], cols[::70] = 0.0, 0.0  # small angles take the series branch
    dt = rng.uniform(0.001, 0.02, k)
    keep = np.sort(rng.choice(k + 1, 40, replace=False))
    r0, p0 = lie.so3_exp(rng.normal(size=3)), rng.normal(size=3)
    rs, ps = lie.integrate_body_twists_at_rotation_columns(r0, p0, omega, v, cols, dt, keep)
    for c in range(3):
        oc = omega.copy()
        oc[:, c] = cols[:, c]
        r_one, p_one = lie.integrate_body_twists_at(r0, p0, oc, v, dt, keep)
        assert np.array_equal(rs[c], r_one) and np.array_equal(ps[c], p_one)
    assert not np.array_equal(rs[0], rs[1])


def test_quat_angles_to_is_the_angle_between_rotations_near_zero_and_pi_too():
    """One quaternion angle for the report and the readers (``readers.decode.static_change_text`` took
    2 arccos(|q·q_last|) of its own until session 27, which reads 0 below ~1e-8 rad): against the matrices' angle,
    unnormalised quaternions and either sign, and to the rounding where arccos loses it."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(50, 4)) * rng.uniform(0.5, 3.0, size=(50, 1))
    ref = rng.normal(size=4)
    want = [lie.rotation_angle(lie.quat_to_rot(ref).T @ lie.quat_to_rot(row)) for row in q]
    np.testing.assert_allclose(lie.quat_angles_to(q, ref), want, atol=1e-7)
    np.testing.assert_allclose(lie.quat_angles_to(-q, ref), want, atol=1e-7)  # q and -q: one rotation
    tiny = np.array(
        [[np.sin(5e-10), 0.0, 0.0, np.cos(5e-10)], [np.sin(0.5 * (np.pi - 1e-9)), 0, 0, np.cos(0.5 * (np.pi - 1e-9))]]
    )
    np.testing.assert_allclose(
        lie.quat_angles_to(tiny, np.array([0.0, 0.0, 0.0, 1.0])), [1e-9, np.pi - 1e-9], rtol=1e-6
    )
    assert lie.quat_angles is metrics.quat_angles  # the report's rotation errors take the same function
