"""Algorithms B (hashim) and C (hashim-imu) against their reference runs (docs/observers.md §12.3) and their invariants.

The scenario is the circle (docs/observers.md §12.1): constant Ω, V, four landmarks, 100 Hz, noise-free, the
observer started at P̂ = 0, p̂_i = 0. Direction measurements are computed here as υ_B = Rᵀυ_I.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from slamobs.cli.main import main
from slamobs.pipeline.directions import DirectionSet, body_acceleration, gravity_up
from slamobs.pipeline.lie import quat_to_rot, rotation_angle, se3_exp, so3_exp
from slamobs.pipeline.observers import GainError, get_observer
from slamobs.pipeline.directions import direction_arrays, initial_attitude, load_directions
from slamobs.pipeline.observers.hashim import run_kernel
from cli_checks import SAMPLES

OMEGA = np.array([0.0, 0.0, 0.3])
VEL = np.array([2.5, 0.0, 0.0])
B_OM = np.array([0.09, -0.15, -0.1])
B_V = np.array([0.09, 0.06, -0.07])
LANDMARKS = np.array([[7, 7, 0], [-7, 7, 0], [7, -7, 0], [-7, -7, 0.0]])
DIRECTIONS = np.array([[1.0, -1.0, 1.0], [0.0, 0.0, 1.0]])  # docs/observers.md §12.3 (normalised below)
#: B's 100 Hz set (docs/observers.md §12.3, Γ = 0.3 I₆); C adds k_1 = k_2 = 1.
GAINS_B = dict(alpha=1.0, k_w=0.02, gamma_omega=0.3, gamma_v=0.3, k_p=1.0)
GAINS_C = dict(GAINS_B, k_1=1.0, k_2=1.0)
#: §12.3 names no axis for its 170° initial attitude error; this one reproduces every number there
#: (angles at 1/5/10 s, the no-IMU 167° and the final ‖P̃‖ ≈ 12.9 m). Other axes converge at other speeds.
AXIS_170 = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)


def scenario(duration=20.0, dt=0.01, landmarks=LANDMARKS, q=np.eye(3), visible_until=None):
    """Truth and measurements; ``q`` rotates the inertial frame (world, landmarks, directions).

    ``visible_until`` maps landmark index -> last time it is measured.
    """
    t = np.arange(0.0, duration + 1e-9, dt)
    rs = np.empty((t.size, 3, 3))
    ps = np.empty((t.size, 3))
    for k, tk in enumerate(t):
        r, p = se3_exp(OMEGA * tk, VEL * tk)
        rs[k] = q @ r
        ps[k] = q @ (p + np.array([0.0, 0.0, 6.0]))
    lms = landmarks @ q.T
    n = lms.shape[0]
    y = np.einsum("kji,kmj->kmi", rs, lms[None] - ps[:, None])
    keep = np.ones((t.size, n), bool)
    for i, t_last in (visible_until or {}).items():
        keep[t > t_last, i] = False
    vi = DIRECTIONS / np.linalg.norm(DIRECTIONS, axis=1, keepdims=True) @ q.T
    body = np.einsum("kji,mj->kmi", rs, vi)
    return dict(
        t=t,
        rs=rs,
        ps=ps,
        lms=lms,
        y=y[keep],
        idx=np.nonzero(keep)[1].astype(np.int64),
        offsets=np.r_[0, np.cumsum(keep.sum(1))].astype(np.int64),
        dirs=DirectionSet(("a", "b"), vi, body, np.ones(body.shape[:2])),
    )


def run(sc, gains, r0=np.eye(3), lm0=None, init=True, imu=True, map_frame=False):
    """The kernel on a scenario; returns (out_k, out_r, out_p, out_b, trk, innov, substeps), map, directions."""
    n = sc["t"].size
    n_lm = sc["lms"].shape[0]
    lm = np.zeros((n_lm, 3)) if lm0 is None else lm0.copy()
    dirs = (
        direction_arrays(sc["dirs"], gains)
        if imu
        else (np.zeros((0, 3)), np.zeros((n, 0, 3)), np.zeros((n, 0)), np.zeros(0), False)
    )
    out = run_kernel(
        sc["t"],
        np.tile(OMEGA + B_OM, (n, 1)),
        np.tile(VEL + B_V, (n, 1)),
        *dirs,
        sc["t"],
        sc["offsets"],
        sc["idx"],
        sc["y"],
        lm,
        np.full(n_lm, init),
        r0,
        np.zeros(3),
        np.zeros(3),
        np.zeros(3),
        gains["k_p"],
        gains["k_w"],
        gains["alpha"],
        gains["gamma_omega"],
        gains["gamma_v"],
        gains.get("k_1", 0.0),
        gains.get("k_2", 0.0),
        3,
        0.5,
        1,
        map_frame,
    )
    return out, lm, dirs[0]


def attitude_error_deg(out_r, sc):
    return np.degrees([rotation_angle(r_hat @ r.T) for r_hat, r in zip(out_r, sc["rs"])])


def e_max(innov, sc):
    return np.linalg.norm(innov.reshape(sc["t"].size, -1, 3), axis=2).max(axis=1)


def at(t):
    return int(round(t / 0.01))


R170 = so3_exp(np.radians(170.0) * AXIS_170)


@pytest.fixture(scope="module")
def spec_runs():
    """docs/observers.md §12.3: B from the identity, C and C with k_1 = k_2 = 0, from a 170° attitude error)."""
    sc = scenario(duration=30.0)
    return sc, {"B": run(sc, GAINS_B, imu=False), "C": run(sc, GAINS_C, r0=R170), "C0": run(sc, GAINS_B, r0=R170)}


def test_b_reproduces_spec_3_3(spec_runs):
    sc, runs = spec_runs
    (_, _, _, out_b, _, innov, steps), _, _ = runs["B"]
    e = e_max(innov, sc)
    # ±10 % at 10 s and ±25 % in the 1e-3 tail (as for algorithm A: the tail is integrator-sensitive; the
    # reference prototype is a plain 100 Hz Euler run, this one is sub-stepped with measurement prediction)
    assert e[at(10)] == pytest.approx(0.09, rel=0.10)
    assert e[at(20)] == pytest.approx(1.2e-3, rel=0.25)
    assert e[at(30)] < 1e-4
    # biases converge under the circle's excitation (constant Ω, V, four non-collinear landmarks)
    assert np.linalg.norm(out_b[at(30), :3] - B_OM) < 1e-5
    assert np.linalg.norm(out_b[at(30), 3:] - B_V) < 1e-4
    assert steps < 5 * sc["t"].size  # the 100 Hz-stable set needs only a few sub-steps


def test_c_reproduces_spec_4_3(spec_runs):
    sc, runs = spec_runs
    (_, out_r, out_p, out_b, _, innov, _), _, _ = runs["C"]
    ang = attitude_error_deg(out_r, sc)
    # Near 180° the IMU innovation is ∝ sin(angle), so the early phase is sensitive to the integrator:
    # ±3° at 1 s, ±10 % at 5 s, ±0.2° at 10 s.
    assert ang[at(1)] == pytest.approx(162.0, abs=3.0)
    assert ang[at(5)] == pytest.approx(32.6, rel=0.10)
    assert ang[at(10)] == pytest.approx(0.7, abs=0.2)
    assert ang[at(15) :].max() < 0.2
    assert e_max(innov, sc)[at(10)] == pytest.approx(0.087, rel=0.10)
    assert np.linalg.norm(out_b[at(20), :3] - B_OM) < 1e-4
    assert np.linalg.norm(out_b[at(20), 3:] - B_V) < 1e-3
    # P̃ = P̂ − R̃P settles at a large unobservable constant (spec ≈ 12.9 m): the map pivoted about the vehicle.
    r_err = np.einsum("kij,klj->kil", out_r, sc["rs"])
    p_tilde = out_p - np.einsum("kij,kj->ki", r_err, sc["ps"])
    assert np.linalg.norm(p_tilde[-1]) == pytest.approx(12.9, rel=0.10)
    assert np.linalg.norm(p_tilde[-1] - p_tilde[at(25)]) < 1e-3


def test_headline_attitude_converges_with_imu_only(spec_runs):
    """From 170°: below 1° within 10 s with the IMU; ≈ 167° for good without it (docs/observers.md §12.3)."""
    sc, runs = spec_runs
    with_imu = attitude_error_deg(runs["C"][0][1], sc)
    without = attitude_error_deg(runs["C0"][0][1], sc)
    assert with_imu[at(10) :].max() < 1.0
    assert without[at(5) :].min() > 160.0
    assert without[-1] == pytest.approx(167.0, abs=3.0)
    # ... while the landmark innovations converge the same way in both (co-rotation keeps ‖e_i‖)
    assert e_max(runs["C0"][0][5], sc)[at(20)] < 5e-3


@pytest.mark.parametrize("key", ["B", "C", "C0"])
def test_rotation_stays_on_so3(spec_runs, key):
    out_r = spec_runs[1][key][0][1]
    gram = np.einsum("kji,kjl->kil", out_r, out_r) - np.eye(3)
    assert np.abs(gram).max() < 1e-9
    assert np.allclose(np.linalg.det(out_r), 1.0, atol=1e-9)


def lyapunov(sc, out, gains, inertial):
    """L of docs/observers.md §5.2 (C; B without the attitude term): Σ‖e‖²/2α (+ 2k_2‖R̃M‖_I) + bias terms,
    at every sample."""
    _, out_r, _, out_b, _, innov, _ = out
    e2 = (innov.reshape(sc["t"].size, -1, 3) ** 2).sum(axis=(1, 2))
    val = (
        e2 / (2 * gains["alpha"])
        + 0.5 * ((out_b[:, :3] - B_OM) ** 2).sum(1) / gains["gamma_omega"]
        + 0.5 * ((out_b[:, 3:] - B_V) ** 2).sum(1) / gains["gamma_v"]
    )
    if gains.get("k_2", 0.0) > 0:
        u_true = np.einsum("kji,mj->kmi", sc["rs"], inertial)
        u_hat = np.einsum("kji,mj->kmi", out_r, inertial)
        val = val + 2 * gains["k_2"] * 0.25 * (1 - np.einsum("kmi,kmi->km", u_hat, u_true)).sum(1)  # s_j = 1
    return val


PAPER_C = dict(alpha=0.1, k_w=2.0, gamma_omega=30.0, gamma_v=30.0, k_p=1.0, k_1=1.0, k_2=0.5)
#: weak landmark weight: the gyro-bias law is driven mostly by the IMU term k_2 σ_R (k_w k_2 = 3 < 4 k_1)
IMU_BIAS_C = dict(alpha=100.0, k_w=1.0, gamma_omega=1.0, gamma_v=1.0, k_p=1.0, k_1=1.0, k_2=3.0)


@pytest.mark.parametrize(
    "gains,duration,final_ratio",
    [(GAINS_B, 10.0, 1e-3), (GAINS_C, 10.0, 1e-3), (PAPER_C, 10.0, 1e-3), (IMU_BIAS_C, 20.0, 1e-2)],
    ids=["B-100Hz", "C-100Hz", "C-paper", "C-imu-bias"],
)
def test_lyapunov_function_does_not_increase(gains, duration, final_ratio):
    sc = scenario(duration=duration)
    out, _, inertial = run(sc, gains, r0=R170, imu="k_1" in gains)
    val = lyapunov(sc, out, gains, inertial)
    # Slack: 1e-6 L per 10 ms sample. A sign or gain error raises L by O(Δt·rate) ~ 1e-2 L per sample; the
    # sub-stepped Euler/splitting error of a correct law is O(h²) per sub-step and, measured, never makes
    # L rise at all here (L falls by ≥ 0.02 % per sample); round-off on L is ~1e-15 L.
    assert np.all(np.diff(val) <= 1e-6 * val[:-1])
    assert val[-1] < final_ratio * val[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_noise_free_innovations_vanish_from_random_start(seed):
    rng = np.random.default_rng(seed)
    landmarks = rng.uniform(-10, 10, size=(6, 3)) * np.array([1, 1, 0.3])
    sc = scenario(duration=20.0, landmarks=landmarks)
    r0 = so3_exp(rng.normal(size=3))
    for gains in (GAINS_B, GAINS_C):
        out, _, _ = run(sc, gains, r0=r0, lm0=rng.normal(size=(6, 3)) * 3, imu="k_1" in gains)
        e = e_max(out[5], sc)
        assert e[-1] < 1e-2 * e[0]
        assert np.all(np.isfinite(out[3]))


@pytest.mark.parametrize("gains", [GAINS_B, GAINS_C], ids=["B", "C"])
def test_estimates_do_not_depend_on_the_inertial_frame(gains):
    """Rotating world, landmarks, inertial directions and the initial estimate by Q changes nothing in the body."""
    rng = np.random.default_rng(5)
    q = so3_exp(rng.normal(size=3))
    r0 = so3_exp(rng.normal(size=3))
    lm0 = rng.normal(size=(4, 3)) * 4
    imu = "k_1" in gains
    a, lm_a, _ = run(scenario(duration=8.0), gains, r0=r0, lm0=lm0, imu=imu)
    b, lm_b, _ = run(scenario(duration=8.0, q=q), gains, r0=q @ r0, lm0=lm0 @ q.T, imu=imu)
    assert a[6] == b[6]  # same sub-steps
    np.testing.assert_allclose(b[3], a[3], atol=1e-9)  # biases (body frame)
    np.testing.assert_allclose(np.linalg.norm(b[5], axis=1), np.linalg.norm(a[5], axis=1), atol=1e-9)
    np.testing.assert_allclose(
        np.einsum("kji,kj->ki", b[1], b[2]), np.einsum("kji,kj->ki", a[1], a[2]), atol=1e-8
    )  # R̂ᵀP̂
    np.testing.assert_allclose(b[1], np.einsum("ij,kjl->kil", q, a[1]), atol=1e-10)
    np.testing.assert_allclose(lm_b, lm_a @ q.T, atol=1e-8)


def test_first_sighting_initialisation_gives_zero_innovation():
    sc = scenario(duration=1.0)
    for gains in (GAINS_B, GAINS_C):
        (_, _, _, _, trk, innov, _), _, _ = run(sc, gains, init=False, imu="k_1" in gains)
        assert np.abs(innov[:4]).max() == 0.0
        assert np.allclose(trk[:4], sc["y"][:4])  # P̂ + R̂y with P̂ = 0, R̂ = I
        assert np.linalg.norm(innov, axis=1).max() < 0.5


def test_out_of_view_landmarks_frozen_in_b_and_turned_with_the_map_in_c_only_while_three_are_in_view():
    # Landmarks 2 and 3 are measured only during the first second.
    hidden = {2: 1.0, 3: 1.0}
    short, long_ = scenario(duration=2.0, visible_until=hidden), scenario(duration=4.0, visible_until=hidden)
    _, lm_s, _ = run(short, GAINS_B, init=False, imu=False)
    _, lm_l, _ = run(long_, GAINS_B, init=False, imu=False)
    assert np.array_equal(lm_s[2:], lm_l[2:])
    assert not np.array_equal(lm_s[0], lm_l[0])
    # C from a 170° error with only two landmarks left in view: nothing ties the vehicle to the map, so the
    # IMU corrects the vehicle alone (its own drift, as far as the map can tell) and the hidden map stays.
    out_s, lm_s, _ = run(short, GAINS_C, r0=R170, init=False)
    out_l, lm_l, _ = run(long_, GAINS_C, r0=R170, init=False)
    assert np.array_equal(lm_s[2:], lm_l[2:])
    assert attitude_error_deg(out_l[1], long_)[-1] < attitude_error_deg(out_s[1], short)[-1] - 5.0
    # With three in view the IMU turns the whole map about the vehicle (docs/observers.md §5.2), the hidden landmark
    # included, rigidly; in the map frame, where slamobs writes it, it stays where it was last seen.
    hidden = {3: 1.0}
    short, long_ = scenario(duration=2.0, visible_until=hidden), scenario(duration=4.0, visible_until=hidden)
    _, lm_s, _ = run(short, GAINS_C, r0=R170, init=False)
    _, lm_l, _ = run(long_, GAINS_C, r0=R170, init=False)
    assert np.linalg.norm(lm_l[3] - lm_s[3]) > 0.5
    framed = [run(sc, GAINS_C, r0=R170, init=False, map_frame=True) for sc in (short, long_)]
    _, lm_ms, _ = framed[0]
    np.testing.assert_allclose(framed[1][1][3], lm_ms[3], atol=1e-9)
    assert np.linalg.norm(lm_ms[3] - lm_s[3]) > 0.5  # the two frames differ by the turns so far
    # map frame and working frame differ by one rigid transform: distances between landmarks agree
    d = lambda m: np.linalg.norm(m[:, None] - m[None], axis=2)  # noqa: E731
    np.testing.assert_allclose(d(lm_ms), d(lm_s), atol=1e-9)


def test_bias_adaptation_frozen_below_three_landmarks_but_imu_still_corrects():
    sc = scenario(duration=4.0, visible_until={2: 1.0, 3: 1.0})
    for gains, r0 in ((GAINS_B, np.eye(3)), (GAINS_C, R170)):
        (_, out_r, _, out_b, _, _, _), _, _ = run(sc, gains, r0=r0, imu="k_1" in gains)
        frozen = out_b[at(1.02) :]
        assert np.array_equal(frozen, np.broadcast_to(frozen[0], frozen.shape))
        assert not np.array_equal(out_b[at(0.5)], out_b[at(1.0)])
    ang = attitude_error_deg(out_r, sc)
    assert ang[-1] < ang[at(1.02)] - 5.0


def test_paper_gains_are_stable_at_100_hz_by_sub_stepping():
    """A's paper gains with C (docs/observers.md §12.3: 0.6° at 10 s): explicit Euler would blow up."""
    sc = scenario(duration=12.0)
    (_, out_r, _, out_b, _, innov, steps), _, _ = run(sc, PAPER_C, r0=R170)
    ang = attitude_error_deg(out_r, sc)
    assert ang[at(10)] < 1.0
    assert np.linalg.norm(out_b[at(12), :3] - B_OM) < 3e-3
    assert e_max(innov, sc)[at(5)] < 0.15
    assert steps > 100 * sc["t"].size  # the rate bound of docs/observers.md §6.1 forced sub-steps


def test_direction_arrays_normalise_weight_and_complete_by_cross_product():
    rng = np.random.default_rng(2)
    vi = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, -1.0]])
    body = rng.normal(size=(5, 2, 3)) * 3
    weight = np.array([[1, 1], [0.5, 1], [0, 1], [1, np.nan], [1, 1.0]])
    body[4, 0] = np.nan
    ds = DirectionSet(("gravity", "magnetic"), vi, body, weight)
    inertial, b, w, gscale, make_cross = direction_arrays(ds, {"s_gravity": 2.0})
    assert make_cross and gscale[0] > 9 and gscale[1] == 0
    np.testing.assert_allclose(np.linalg.norm(inertial, axis=1), 1.0)
    np.testing.assert_allclose(
        inertial[2], np.cross(inertial[0], inertial[1]) / np.linalg.norm(np.cross(inertial[0], inertial[1]))
    )
    np.testing.assert_allclose(w, [[2, 1], [1, 1], [0, 1], [2, 0], [0, 1]])
    assert np.all(np.isfinite(b)) and np.all(b[w == 0] == 0)
    np.testing.assert_allclose(np.linalg.norm(b[w > 0], axis=1), 1.0)
    # per sample, the kernel builds the third body vector: normalised cross product, weakest weight
    out_b, out_w, zero = np.zeros((3, 3)), np.zeros(3), np.zeros(3)
    load_directions(b[1], w[1], np.zeros(2), True, zero, zero, zero, zero, out_b, out_w)
    c = np.cross(b[1, 0], b[1, 1])
    np.testing.assert_allclose(out_b[2], c / np.linalg.norm(c))
    assert out_w[2] == 1.0
    load_directions(b[2], w[2], np.zeros(2), True, zero, zero, zero, zero, out_b, out_w)
    assert out_w[2] == 0.0
    with pytest.raises(GainError, match="collinear"):
        direction_arrays(DirectionSet(("a", "b"), np.array([[0, 0, 1.0], [0, 0, -3.0]]), body, weight), {})


def test_gravity_direction_recompensated_with_bias_estimates():
    """``up`` built from biased odometry is tilted by b_Ω × V; with b̂ = b the kernel's correction removes it."""
    sc = scenario(duration=2.0)
    t = sc["t"]
    acc_inertial = np.cross(sc["rs"] @ OMEGA, sc["rs"] @ VEL)  # circle: a = R(Ω × V)
    f = np.einsum("kji,kj->ki", sc["rs"], acc_inertial - np.array([0, 0, -9.81]))
    om_m, v_m = np.tile(OMEGA + B_OM, (t.size, 1)), np.tile(VEL + B_V, (t.size, 1))
    up, w = gravity_up(f, body_acceleration(t, om_m, v_m), 9.81)
    true_up = sc["rs"][:, 2, :]  # Rᵀ e_z
    tilt = np.degrees(np.arccos(np.clip((up * true_up).sum(1), -1, 1)))
    assert tilt.min() > 1.0  # the paper's gyro bias tilts the raw "up" by > 1°
    out_b, out_w = np.zeros((1, 3)), np.zeros(1)
    for k in range(0, t.size, 50):
        load_directions(up[k : k + 1], np.ones(1), np.array([9.81]), False, om_m[k], v_m[k], B_OM, B_V, out_b, out_w)
        assert np.degrees(np.arccos(min(1.0, out_b[0] @ true_up[k]))) < 1e-6


def test_initial_attitude_solves_wahba():
    rng = np.random.default_rng(4)
    r = so3_exp(rng.normal(size=3))
    vi = rng.normal(size=(3, 3))
    vi /= np.linalg.norm(vi, axis=1, keepdims=True)
    np.testing.assert_allclose(initial_attitude(vi, vi @ r, np.array([1.0, 0.5, 2.0])), r, atol=1e-12)


def test_gain_coupling_constraint_is_a_gain_error(tmp_path):
    spec = get_observer("hashim-imu")
    assert spec.min_directions == 2
    spec.resolve_gains({"k_1": 1.0, "k_2": 3.9, "k_w": 1.0})
    with pytest.raises(GainError, match="k_w\\*k_2 < 4\\*k_1"):
        spec.resolve_gains({"k_1": 1.0, "k_2": 4.0, "k_w": 1.0})
    cfg = tmp_path / "run.yaml"
    cfg.write_text("gains:\n  hashim-imu: {k_1: 0.1, k_2: 1}\n")
    out = tmp_path / "out"
    res = CliRunner().invoke(
        main, ["run", str(SAMPLES / "figure8.mcap"), "-o", str(out), "--observer", "hashim-imu", "--config", str(cfg)]
    )
    assert res.exit_code == 2 and "k_w*k_2 < 4*k_1" in res.output
    assert not out.exists()


# Sample logs (noisy, 4-30 landmarks): APE after SE(3) alignment, map error, final bias errors; thresholds
# about twice the measured values (sample_logs/README.md describes the logs; circle.bag and circle_ros2 hold the
# same messages). Measured 2026-12-03 (ape, map, gyro, vel, attitude):
#   hashim      circle  0.0101 m, 0.0124 m, 0.0025 rad/s, 0.0038 m/s
#   hashim      figure8 0.0423 m, 0.0343 m, 0.0018 rad/s, 0.0075 m/s
#   hashim-imu  circle  0.0102 m, 0.0127 m, 0.0066 rad/s, 0.0038 m/s, 0.19 deg
#   hashim-imu  figure8 0.0379 m, 0.0320 m, 0.0106 rad/s, 0.0063 m/s, 0.25 deg
LIMITS = {  # observer: (ape_m, map_m, gyro_rad_s, vel_m_s, final absolute attitude error deg)
    "hashim": {"circle": (0.02, 0.025, 0.005, 0.0075, None), "figure8": (0.08, 0.07, 0.004, 0.015, None)},
    "hashim-imu": {"circle": (0.02, 0.025, 0.013, 0.0075, 0.4), "figure8": (0.075, 0.065, 0.02, 0.0125, 0.5)},
}


@pytest.mark.parametrize("observer", ["hashim", "hashim-imu"])
@pytest.mark.parametrize("log", ["circle.bag", "circle_ros2", "figure8.mcap"])
def test_cli_run_on_every_sample_log(tmp_path, log, observer):
    import pandas as pd

    out = tmp_path / "out"
    res = CliRunner().invoke(
        main, ["run", str(SAMPLES / log), "-o", str(out), "--observer", observer], catch_exceptions=False
    )
    assert res.exit_code == 0, res.output
    run_meta = json.loads((out / "run.json").read_text())
    assert run_meta["observer"]["name"] == observer
    report = json.loads((out / "report.json").read_text())
    ape, lm, gyro, vel, att = LIMITS[observer][log.split(".")[0].split("_")[0]]
    assert report["ape"]["translation_m"]["rmse"] < ape
    assert report["landmarks"]["error_m"]["rmse"] < lm
    assert report["biases"]["error_norm"]["gyro"] < gyro
    assert report["biases"]["error_norm"]["velocity"] < vel
    if att is not None:  # C estimates the absolute attitude (B only up to the unobservable R_c)
        assert run_meta["observer"]["directions"] == ["gravity", "magnetic"]
        from slamobs.pipeline.readers import read_log

        truth = read_log(SAMPLES / log).truth
        poses = pd.read_parquet(out / "poses.parquet")
        poses = poses[poses["t_ns"] > poses["t_ns"].iloc[-1] - 5 * 10**9]
        k = np.clip(np.searchsorted(truth.t_ns, poses["t_ns"].to_numpy()), 0, truth.t_ns.size - 1)
        same_time = np.abs(truth.t_ns[k] - poses["t_ns"].to_numpy()) < 10**6  # mocap and IMU stamps 0.5 ms apart
        q_hat = poses[["qx", "qy", "qz", "qw"]].to_numpy(float)[same_time]
        ang = [
            np.degrees(rotation_angle(quat_to_rot(q) @ quat_to_rot(truth.quat_xyzw[j]).T))
            for q, j in zip(q_hat, k[same_time])
        ]
        assert len(ang) > 100 and np.mean(ang) < att
