"""Algorithm A against the paper scenario (docs/observers.md §12.1, §12.2) and its invariants."""

from __future__ import annotations

import numpy as np
import pytest

from slamobs.pipeline.lie import rotation_angle, se3_exp
from slamobs.pipeline.observers.fast_adaptation import run_kernel

OMEGA = np.array([0.0, 0.0, 0.3])
VEL = np.array([2.5, 0.0, 0.0])
B_OM = np.array([0.09, -0.15, -0.1])
B_V = np.array([0.09, 0.06, -0.07])
LANDMARKS = np.array([[7, 7, 0], [-7, 7, 0], [7, -7, 0], [-7, -7, 0.0]])
PAPER_GAINS = dict(k_p=1.0, k_w=2.0, alpha=0.1, gamma=30.0)

# docs/observers.md §12.2: max_i |e_i| of the continuous-time solution
REFERENCE = {
    0.0: 11.58,
    0.1: 4.0,
    0.5: 1.83,
    1.0: 1.22,
    2.0: 0.756,
    3.0: 0.532,
    5.0: 0.297,
    10.0: 0.082,
    20.0: 6.7e-3,
    30.0: 5.5e-4,
}


def paper_scenario(duration=30.0, dt=0.01, landmarks=LANDMARKS):
    t = np.arange(0.0, duration + 1e-9, dt)
    rs = np.empty((t.size, 3, 3))
    ps = np.empty((t.size, 3))
    for k, tk in enumerate(t):
        r, p = se3_exp(OMEGA * tk, VEL * tk)
        rs[k] = r
        ps[k] = p + np.array([0.0, 0.0, 6.0])
    n = landmarks.shape[0]
    y = np.einsum("kji,kmj->kmi", rs, landmarks[None] - ps[:, None]).reshape(-1, 3)
    return dict(
        t=t,
        rs=rs,
        ps=ps,
        y=y,
        offsets=np.arange(0, n * t.size + 1, n, dtype=np.int64),
        idx=np.tile(np.arange(n), t.size).astype(np.int64),
    )


def run(sc, gains=PAPER_GAINS, lm0=None, init=True, r0=np.eye(3)):
    n = sc["idx"].max() + 1
    lm = np.zeros((n, 3)) if lm0 is None else lm0.copy()
    lm_init = np.full(n, init)
    size = sc["t"].size
    out = run_kernel(
        sc["t"],
        np.tile(OMEGA + B_OM, (size, 1)),
        np.tile(VEL + B_V, (size, 1)),
        sc["t"],
        sc["offsets"],
        sc["idx"],
        sc["y"],
        lm,
        lm_init,
        r0,
        np.zeros(3),
        np.zeros(3),
        np.zeros(3),
        gains["k_p"],
        gains["k_w"],
        gains["alpha"],
        gains["gamma"],
        3,
        0.5,
        1,
    )
    return out, lm


@pytest.fixture(scope="module")
def paper_run():
    sc = paper_scenario()
    out, lm = run(sc)
    return sc, out, lm


def test_reproduces_spec_reference_table(paper_run):
    sc, (out_k, out_r, out_p, out_b, trk, innov, steps), _ = paper_run
    e_max = np.linalg.norm(innov.reshape(sc["t"].size, 4, 3), axis=2).max(axis=1)
    for t, ref in REFERENCE.items():
        got = e_max[int(round(t / 0.01))]
        tol = 0.10 if t <= 10 else 0.25  # spec: ±10 % for t <= 10 s; the tail is integrator-sensitive
        assert got == pytest.approx(ref, rel=tol), f"max|e| at {t} s"
    # substeps per 10 ms sample in the range docs/observers.md §12.2 gives (216-661)
    assert 216 * 0.8 <= steps / sc["t"].size <= 661 * 1.2


def test_biases_converge_as_in_spec(paper_run):
    sc, (out_k, out_r, out_p, out_b, *_), _ = paper_run
    k = lambda t: int(round(t / 0.01))  # noqa: E731
    assert np.linalg.norm(out_b[k(0.5), :3] - B_OM) < 1e-3
    assert np.linalg.norm(out_b[k(1.0), :3] - B_OM) < 1e-6
    assert np.linalg.norm(out_b[k(1.0), 3:] - B_V) < 1e-4
    assert np.abs(out_b[k(2.0) :] - np.r_[B_OM, B_V]).max() < 1e-3


def test_rotation_stays_on_so3_and_errors_settle_to_constants(paper_run):
    sc, (out_k, out_r, out_p, *_), lm = paper_run
    gram = np.einsum("kji,kjl->kil", out_r, out_r) - np.eye(3)
    assert np.abs(gram).max() < 1e-9
    assert np.allclose(np.linalg.det(out_r), 1.0, atol=1e-9)
    # R̃ = R̂ Rᵀ converges to a small constant (spec: ≈ 0.09-0.10 deg), P̃ = P̂ - R̃P to a constant.
    r_err = np.einsum("kij,klj->kil", out_r, sc["rs"])
    ang = np.degrees([rotation_angle(r) for r in r_err])
    assert ang[-1] < 0.5
    assert abs(ang[-1] - ang[-500]) < 0.01
    p_err = out_p - np.einsum("kij,kj->ki", r_err, sc["ps"])
    assert np.linalg.norm(p_err[-1] - p_err[-500]) < 1e-3
    assert 0.5 < np.linalg.norm(p_err[-1]) < 1.2  # the unobservable constant (docs/observers.md §12.2: ≈ 0.8 m)


def test_first_sighting_initialisation_gives_zero_innovation():
    sc = paper_scenario(duration=1.0)
    (out_k, out_r, out_p, out_b, trk, innov, _), lm = run(sc, init=False)
    assert np.abs(innov[:4]).max() == 0.0
    # Initialised at P̂ + R̂ y with P̂ = 0, R̂ = I: the body-frame measurement itself.
    assert np.allclose(trk[:4], sc["y"][:4])
    # Everything stays consistent afterwards: innovations remain small (only the bias drives them).
    assert np.linalg.norm(innov, axis=1).max() < 0.5


def _drop_landmark_after(sc, index, t_last):
    keep = np.ones(sc["idx"].size, bool)
    keep[(sc["idx"] == index) & (np.repeat(sc["t"], 4) > t_last)] = False
    counts = np.add.reduceat(keep.astype(np.int64), np.arange(0, keep.size, 4))
    return dict(sc, y=sc["y"][keep], idx=sc["idx"][keep], offsets=np.r_[0, np.cumsum(counts)].astype(np.int64))


def test_landmarks_out_of_view_keep_their_estimate():
    # Landmark index 3 is visible only during the first second; its estimate must not move afterwards,
    # whether the run stops at 2 s or at 4 s, while the visible ones keep being corrected.
    _, lm_short = run(_drop_landmark_after(paper_scenario(duration=2.0), 3, 1.0), init=False)
    _, lm_long = run(_drop_landmark_after(paper_scenario(duration=4.0), 3, 1.0), init=False)
    assert np.array_equal(lm_short[3], lm_long[3])
    assert not np.array_equal(lm_short[0], lm_long[0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_free_innovations_vanish_from_random_start(seed):
    rng = np.random.default_rng(seed)
    landmarks = rng.uniform(-10, 10, size=(6, 3)) * np.array([1, 1, 0.3])
    sc = paper_scenario(duration=20.0, landmarks=landmarks)
    from slamobs.pipeline.lie import so3_exp

    r0 = so3_exp(rng.normal(size=3) * 0.5)
    (_, out_r, _, out_b, _, innov, _), _ = run(sc, lm0=rng.normal(size=(6, 3)), r0=r0)
    e = np.linalg.norm(innov.reshape(sc["t"].size, 6, 3), axis=2).max(axis=1)
    assert e[-1] < 1e-2 * e[0]
    assert np.all(np.isfinite(out_b))


@pytest.mark.parametrize("wrong_id", [0.0, 0.02])
def test_gross_detections_into_an_observer_without_a_gate_are_noted(tmp_path, wrong_id):
    """2 % of the detections carry another landmark's ID and 0.5 % sit 5-50x too far: fast-adaptation takes them
    in (it has no gate) and says so in run.json instead of a quiet 1.5 m trajectory (a ground-robot log of
    benchmarks/unseen_logs.py); the clean log gets no such note."""
    import json
    from dataclasses import replace

    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.simulate import NoiseModel, simulate, write_log

    nm = replace(NoiseModel(), wrong_id=wrong_id, absurd_range=wrong_id / 4)
    log = tmp_path / "log.mcap"
    write_log(simulate("figure8", duration=30.0, seed=3, noise=nm), log)
    run_log(log, tmp_path / "out", observer="fast-adaptation", config={"evaluation": {"plots": False}})
    notes = json.loads((tmp_path / "out" / "run.json").read_text())["notes"]
    gross = [n for n in notes if "mis-identified landmarks" in n]
    assert bool(gross) == (wrong_id > 0), notes


@pytest.mark.parametrize("lost", [False, True])
def test_a_lost_estimate_is_noted_from_landmarks_seen_again(tmp_path, lost):
    """Two laps of the loop scenario: with velocity and gyro at 10 Hz, the gyro 100x and the velocity 4x noisier
    than the defaults and stereo-like detections (7 px), fast-adaptation's velocity bias takes up most of the
    motion and the estimate ends 16.9 m from the truth (APE, benchmarks/session_logs.py's loop s43) while its
    innovations stay near their median; the landmarks seen again on the second lap arrive 7x that far from its map,
    and run.json and the report say the estimate is likely lost. At the simulator's default noise and rates
    (APE 0.2-0.5 m on seeds 0 and 1) as many landmarks come back, near where the map has them, and it does not."""
    import json
    from dataclasses import replace

    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import NoiseModel, simulate, write_log

    kw: dict = dict(duration=150.0, seed=43)
    nm = NoiseModel()
    if lost:
        rate = 10.0
        kw |= dict(imu_rate=rate, odom_rate=rate, detection_rate=10.0)
        nm = replace(
            nm,
            gyro=100 * DEFAULTS["gyro"][0] / np.sqrt(1.0 / rate),
            odom_linear=4 * DEFAULTS["velocity"][0] / np.sqrt(1.0 / rate),
            stereo_pixel=7.0,
            stereo_focal=1000.0,
            stereo_baseline=0.5,
        )
    sim = simulate("loop", noise=nm, **kw)
    log = tmp_path / "log.mcap"
    write_log(replace(sim, noise=replace(nm, gyro=0.0, odom_linear=0.0)), log)
    run_log(log, tmp_path / "out", observer="fast-adaptation", config={"evaluation": {"plots": False}})
    meta = json.loads((tmp_path / "out" / "run.json").read_text())
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    ape = report["ape"]["translation_m"]["rmse"]
    said = [n for n in meta["notes"] if n.startswith("warning: fast-adaptation: its estimate is likely lost")]
    assert [n for n in report["notes"] if n in said] == said  # the report says it too
    check = meta["observer"]["resightings"]
    assert (ape > 5.0) == lost, ape
    assert check["detections"] >= 20, check  # the check had its evidence either way
    assert (check["ratio"] > 3.0) == lost, check
    assert bool(said) == lost, meta["notes"]
    assert (meta["observer"]["velocity_bias"]["share"] > 0.3) == lost, meta["observer"]["velocity_bias"]
    # beside the report's convergence verdict, the run's own (session 32), from the same fields as the warning
    own = report["convergence"]["own_status"]
    assert (own is not None and (own["status"], own["field"]) == ("likely_lost", "observer.resightings")) == lost, own
    assert own is None or f"is likely lost: {own['said']}; do not trust it" in said[0], (own, said)  # its words


def test_a_lost_estimate_is_noted_without_landmarks_seen_again(tmp_path):
    """The lost loop above cut to 60 s, under one lap: no landmark comes back, so the map cannot be tested against
    the trajectory, and fast-adaptation ended 15.8 m from the truth with no word (TagSLAM 11 likewise: map 2.56 m,
    riekf 0.18 m, 3 re-sightings). Its velocity bias estimate is 0.67x the velocity's rms: it took up the motion."""
    import json
    from dataclasses import replace

    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import NoiseModel, simulate, write_log

    rate = 10.0
    nm = replace(
        NoiseModel(),
        gyro=100 * DEFAULTS["gyro"][0] / np.sqrt(1.0 / rate),
        odom_linear=4 * DEFAULTS["velocity"][0] / np.sqrt(1.0 / rate),
        stereo_pixel=7.0,
        stereo_focal=1000.0,
        stereo_baseline=0.5,
    )
    sim = simulate("loop", noise=nm, duration=60.0, seed=43, imu_rate=rate, odom_rate=rate, detection_rate=10.0)
    log = tmp_path / "log.mcap"
    write_log(replace(sim, noise=replace(nm, gyro=0.0, odom_linear=0.0)), log)
    run_log(log, tmp_path / "out", observer="fast-adaptation", config={"evaluation": {"plots": False}})
    meta = json.loads((tmp_path / "out" / "run.json").read_text())
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["ape"]["translation_m"]["rmse"] > 5.0
    assert meta["observer"]["resightings"]["detections"] < 20  # the re-sighting check has no evidence
    said = [n for n in meta["notes"] if n.startswith("warning: fast-adaptation: its estimate is likely lost")]
    assert len(said) == 1 and "its velocity bias estimate wanders by" in said[0], meta["notes"]
    assert meta["observer"]["velocity_bias"]["share"] > 0.3, meta["observer"]["velocity_bias"]
    assert [n for n in report["notes"] if n in said] == said
    # the run's own status beside the convergence verdict (session 32), and a batch's or compare's table's ``ok``
    # with it (before: a batch counted no warning for it)
    from slamobs.pipeline.run import RunSummary

    own = report["convergence"]["own_status"]
    assert own["status"] == "likely_lost" and own["field"] == "observer.velocity_bias", own
    assert RunSummary(tmp_path / "out", meta, {}).status_caveats() == [
        f"its own status is likely_lost in run.json observer.velocity_bias: {own['said']}"
    ]
    assert f"is likely lost: {own['said']}; do not trust it" in said[0], (own, said)  # the warning's words


def test_a_slow_vehicle_whose_constant_velocity_bias_is_learned_is_not_called_lost(tmp_path, monkeypatch):
    """A circle flown at 0.25 m/s whose odometry carries the scenario's constant 0.13 m/s bias: fast-adaptation learns
    it (APE ~1 cm), so its bias estimate is ~0.36x the velocity's rms, which the first form of the check (the bias's
    size) called "likely lost". The check looks at how the settled estimate wanders instead: a few mm/s here."""
    import json

    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.simulate import scenarios, simulate, write_log

    monkeypatch.setattr(scenarios, "CIRCLE_OMEGA", np.array([0.0, 0.0, 0.03]))
    monkeypatch.setattr(scenarios, "CIRCLE_V", np.array([0.25, 0.0, 0.0]))
    log = tmp_path / "slow.mcap"
    write_log(simulate("circle", duration=90.0, seed=9), log)
    run_log(log, tmp_path / "out", observer="fast-adaptation", config={"evaluation": {"plots": False}})
    meta = json.loads((tmp_path / "out" / "run.json").read_text())
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["ape"]["translation_m"]["rmse"] < 0.05
    vb = meta["observer"]["velocity_bias"]
    assert vb["rms_m_s"] / vb["velocity_rms_m_s"] > 0.3, vb  # its size alone would say lost
    assert vb["share"] < 0.1, vb
    assert not [n for n in meta["notes"] if "likely lost" in n], meta["notes"]


@pytest.mark.parametrize("n_landmarks", [2, None])
def test_biases_held_at_their_start_for_want_of_landmarks_are_said(tmp_path, n_landmarks):
    """A figure 8 whose map keeps two of its tags (seed=3393): no frame sees the three landmarks fast-adaptation
    needs before it adapts its biases, so biases.parquet holds [0, 0, 0] from start to end, and the report's bias
    table printed that as the final estimate with nothing to say it was never estimated (TagSLAM test 22: two tags).
    The run and the report say so; with the whole map the biases move and nothing is said."""
    import json
    from dataclasses import replace

    import pandas as pd

    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.simulate import get_scenario, simulate, write_log

    sc = get_scenario("figure8")
    keep = np.arange(n_landmarks or sc.landmark_ids.shape[0])
    sc = replace(
        sc, landmark_ids=sc.landmark_ids[keep], landmarks=sc.landmarks[keep], landmark_rots=sc.landmark_rots[keep]
    )
    log = tmp_path / "few.mcap"
    write_log(simulate(sc, duration=20.0, seed=3393), log)
    run_log(log, tmp_path / "out", observer="fast-adaptation", config={"evaluation": {"plots": False}})
    meta = json.loads((tmp_path / "out" / "run.json").read_text())
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    biases = pd.read_parquet(tmp_path / "out" / "biases.parquet").drop(columns="t_ns")
    held = meta["observer"]["bias_held"]
    said = [n for n in meta["notes"] if n.startswith("fast-adaptation: its gyro and velocity bias estimates stayed")]
    assert bool((biases == biases.iloc[0]).all().all()) == (n_landmarks == 2)
    if n_landmarks == 2:
        assert held == {"start": [0.0] * 6, "max_landmarks_per_frame": 2, "min_landmarks_bias": 3}, held
        assert len(said) == 1 and "only while 3 or more landmarks are in view" in said[0], meta["notes"]
        assert "no detection frame of this log holds more than 2" in said[0]
    else:
        assert held is None and not said, (held, said)
    assert [n for n in report["notes"] if n in said] == said  # the report says it too
