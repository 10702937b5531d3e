"""Uncertainty out (issue 26, part 2): riekf and batch write pose and landmark covariances in the documented convention
(``R̂ = Exp(δθ) R``, ``p̂ = p + δp``, map/output frame), the observers leave those columns null, and the report
checks the covariance against the error (NEES with χ² bounds, 3σ figures)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pyarrow.parquet as pq
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.evaluation.metrics import chi2_quantile, nees_bounds
from slamobs.pipeline.evaluation.trajectory_evaluation import nees_values
from slamobs.pipeline.lie import rots_to_quats, rots_to_rotvecs, skew
from slamobs.pipeline.noise import DEFAULTS, NoiseConfig, resolve_noise
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.observers.base import output_rows
from slamobs.pipeline.observers.riekf import RiEKF
from slamobs.pipeline.simulate import expected_streams, get_scenario, simulate, write_log
from slamobs.pipeline.writers import POSE_AXES

SIGMA_B = 0.05
RUNS, SECONDS, EVERY = 8, 15.0, 20


@pytest.fixture(scope="module")
def filter_runs():
    """Noisy figure-8 runs whose biases are drawn from the filter's prior, the filter given the simulator's noise
    and started at the true pose (the gauge); bias walks off, so the test mechanism's covariance rows (flushed at
    each row) equal what the filter writes."""
    noise = resolve_noise(
        NoiseConfig(gyro_bias=SIGMA_B, velocity_bias=SIGMA_B, gyro_bias_walk=0.0, velocity_bias_walk=0.0)
    )
    rng = np.random.default_rng(26)
    runs = []
    for run in range(RUNS):
        b = rng.normal(0.0, SIGMA_B, 6)
        sc = replace(get_scenario("figure8"), gyro_bias=b[:3], velocity_bias=b[3:])
        sim = simulate(sc, duration=SECONDS, seed=300 + run)
        stream = align(expected_streams(sim), keep_directions=False)
        start = sc.sample(np.array([(stream.vel_t_ns[0] - sim.start_ns) * 1e-9]))
        filt = RiEKF(stream, {}, ObserverOptions(out_every=EVERY), noise=noise, r0=start.R[0], p0=start.P[0])
        filt.cov_rows = np.zeros((output_rows(filt.n_vel, EVERY, 0, filt.n_vel), 12, 12))
        res = filt.advance(filt.n_vel)
        truth = sc.sample((res.t_ns - sim.start_ns) * 1e-9)
        lm_truth = sc.landmarks[np.searchsorted(sc.landmark_ids, res.landmark_ids)]
        runs.append((res, truth, filt.cov_rows, lm_truth))
    return runs


def test_riekf_pose_covariance_is_the_filters_in_the_written_convention(filter_runs):
    """The written 6×6 is the filter's (ξ_R, ξ_P) block turned by δθ = ξ_R, δp = ξ_P − [P̂]×ξ_R, symmetric and
    positive definite after the start (the gauge: zero there)."""
    res, _, cov12, _ = filter_runs[0]
    for k in range(1, len(res.t_ns), 7):
        j = np.eye(6)
        j[3:, :3] = -skew(res.position[k])
        expect = j @ cov12[k, :6, :6] @ j.T
        assert np.allclose(res.pose_cov[k], expect, rtol=1e-9, atol=1e-15)
    assert np.allclose(res.pose_cov[0], 0.0)
    assert np.allclose(res.pose_cov, np.swapaxes(res.pose_cov, 1, 2))
    assert np.linalg.eigvalsh(res.pose_cov[1:])[:, 0].min() > 0.0


def test_riekf_nees_is_within_chi2_bounds(filter_runs):
    """Position and attitude NEES of the written covariance against the true error in the written convention,
    averaged over the runs at each instant (ov_eval's check): within the two-sided 95 % χ²(3R)/R bounds at most
    instants and on average over the run."""
    pos, att = [], []
    for res, truth, _, _ in filter_runs:
        d_theta = rots_to_rotvecs(np.matmul(res.rotation, np.swapaxes(truth.R, 1, 2)))
        d_p = res.position - truth.P
        pos.append(nees_values(d_p[1:], res.pose_cov[1:, 3:, 3:]))
        att.append(nees_values(d_theta[1:], res.pose_cov[1:, :3, :3]))
    lo, hi = nees_bounds(3, RUNS)
    for name, nees in (("position", pos), ("attitude", att)):
        n = min(len(r) for r in nees)
        mean = np.mean([r[:n] for r in nees], axis=0)
        assert np.isfinite(mean).all()
        assert np.mean((mean >= lo) & (mean <= hi)) >= 0.9, (name, lo, hi, mean.round(1))
        assert lo < mean.mean() < hi, (name, mean.mean())


def test_riekf_landmark_covariance_is_consistent(filter_runs):
    """Each landmark's 3×3 (map frame) is positive definite, and the NEES of the final map against the truth,
    pooled over landmarks and runs, lies within its two-sided 95 % bounds (twice as wide: landmarks seen
    together share their errors)."""
    nees = []
    for res, _, _, lm_truth in filter_runs:
        seen = np.isfinite(res.landmark_cov).all(axis=(1, 2))
        assert seen.sum() >= 10
        assert np.linalg.eigvalsh(res.landmark_cov[seen])[:, 0].min() > 0.0
        nees.append(nees_values(res.landmark_xyz[seen] - lm_truth[seen], res.landmark_cov[seen]))
    nees = np.concatenate(nees)
    lo, hi = nees_bounds(3, nees.size)
    mid = 3.0
    assert mid - 2 * (mid - lo) < nees.mean() < mid + 2 * (hi - mid), nees.mean()


def test_chi2_quantiles_match_the_tables():
    """χ² quantiles the NEES bounds come from: the tabulated values (3 and 30 DoF, and a large count)."""
    assert chi2_quantile(0.025, 3) == pytest.approx(0.2158, abs=1e-4)
    assert chi2_quantile(0.975, 3) == pytest.approx(9.3484, abs=1e-4)
    assert chi2_quantile(0.975, 30) == pytest.approx(46.979, rel=1e-3)
    assert chi2_quantile(0.025, 29) == pytest.approx(16.047, rel=1e-3)
    lo, hi = nees_bounds(3, 1000)
    assert lo < 3.0 < hi and hi - lo == pytest.approx(2 * 1.96 * np.sqrt(6 / 1000), rel=0.02)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A 12 s simulated figure-8 log run by riekf and batch with the simulator's noise (the ``noise:`` config) and
    by an observer; their run directories."""
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import run_log

    base = tmp_path_factory.mktemp("uncertainty")
    log = write_log(simulate("figure8", duration=12.0, seed=5), base / "f8.mcap")
    out = {}
    noise = {k: float(DEFAULTS[k][0]) for k in ("gyro", "velocity", "detection", "detection_per_m")}
    for name in ("riekf", "batch", "fast-adaptation"):
        if name == "batch":
            pytest.importorskip("gtsam")
        out[name] = base / name
        run_log(log, out[name], parse_config({"observer": name, "noise": noise}))
    return out


def _covariances(table, names, n):
    tri = [(i, j) for i in range(n) for j in range(i, n)]
    cov = np.empty((table.num_rows, n, n))
    for (i, j), name in zip(tri, names):
        cov[:, i, j] = cov[:, j, i] = table.column(name).to_numpy()
    return cov


POSE_COV = [f"cov_{POSE_AXES[i]}_{POSE_AXES[j]}" for i in range(6) for j in range(i, 6)]
LM_COV = ["cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz"]


@pytest.mark.parametrize("name", ["riekf", "batch"])
def test_reference_estimators_write_positive_definite_covariances(runs, name):
    """poses.parquet: 6 standard deviations that are the covariance's diagonal, the covariance positive definite
    (apart from the gauge); landmarks.parquet: a positive definite 3×3 and its RMS standard deviation."""
    poses = pq.read_table(runs[name] / "poses.parquet")
    cov = _covariances(poses, POSE_COV, 6)
    sd = np.stack([poses.column(f"sigma_{a}").to_numpy() for a in ("rx", "ry", "rz", "x", "y", "z")], axis=1)
    assert np.allclose(sd, np.sqrt(np.einsum("nii->ni", cov)), rtol=3e-5)  # both stored on 16 bits (schema float_bits)
    eig = np.linalg.eigvalsh(cov)[:, 0]
    assert np.mean(eig > 0) > 0.99 and eig.min() > -1e-12  # the gauge (start or anchor) is (nearly) zero
    lms = pq.read_table(runs[name] / "landmarks.parquet")
    lcov = _covariances(lms, LM_COV, 3)
    assert np.linalg.eigvalsh(lcov)[:, 0].min() > 0.0
    assert np.allclose(lms.column("sigma").to_numpy(), np.sqrt(np.einsum("nii->n", lcov) / 3), rtol=3e-5)


def test_observers_leave_the_uncertainty_columns_null(runs):
    """The observers keep no covariance: the columns are there, all null, and the report has no uncertainty."""
    poses = pq.read_table(runs["fast-adaptation"] / "poses.parquet")
    lms = pq.read_table(runs["fast-adaptation"] / "landmarks.parquet")
    for table, names in ((poses, [*POSE_COV, "sigma_x", "sigma_rz"]), (lms, [*LM_COV, "sigma"])):
        for name in names:
            assert table.column(name).null_count == table.num_rows > 0, name
    report = json.loads((runs["fast-adaptation"] / "report.json").read_text())
    assert report["uncertainty"] is None
    assert not (runs["fast-adaptation"] / "nees.png").exists()


@pytest.mark.parametrize("name", ["riekf", "batch"])
def test_report_has_nees_and_its_figures(runs, name):
    """report.json: NEES (position, attitude) with bounds around 3 and counts; report.md the table; the 3σ and
    NEES figures written."""
    from slamobs.pipeline.evaluation.report import validate_report

    report = json.loads((runs[name] / "report.json").read_text())
    validate_report(report)
    u = report["uncertainty"]
    for part in ("position", "attitude"):
        r = u[part]
        assert r["n"] > 100 and r["mean"] > 0 and r["bounds"][0] < 3.0 < r["bounds"][1]
        assert all(0.0 <= v <= 1.0 for v in r["within_3sigma"])
    assert "## Uncertainty (NEES)" in (runs[name] / "report.md").read_text()
    for figure in ("uncertainty.png", "nees.png"):
        assert (runs[name] / figure).stat().st_size > 10_000


def test_output_frame_turns_covariances_with_the_estimate(filter_runs):
    """A rigid output frame turns the error (δθ, δp) by its rotation: the written covariance turns with it, so the
    NEES of the turned error is the same."""
    from slamobs.pipeline.lie import so3_exp
    from slamobs.pipeline.output_frame import OutputFrame

    res, truth, _, _ = filter_runs[1]
    r = so3_exp(np.array([0.4, -1.1, 2.0]))
    out = OutputFrame("test", r, np.array([3.0, -2.0, 1.0]), "test").apply(res)
    error = np.c_[rots_to_rotvecs(np.matmul(res.rotation, np.swapaxes(truth.R, 1, 2))), res.position - truth.P][1:]
    turned = error @ np.kron(np.eye(2), r).T
    assert np.allclose(nees_values(turned, out.pose_cov[1:]), nees_values(error, res.pose_cov[1:]), rtol=1e-6)
    seen = np.isfinite(res.landmark_cov).all(axis=(1, 2))
    assert np.allclose(out.landmark_cov[seen], r @ res.landmark_cov[seen] @ r.T)


def test_batch_covariance_between_marginal_keyframes_is_interpolated():
    """The smoother computes marginals at one keyframe per second (and the last); rows between are linear in
    time: exact at those keyframes, the mean half-way, positive definite throughout."""
    from slamobs.pipeline.smoother.estimator import (
        COVARIANCE_MARGINALS,
        COVARIANCE_ROW_BLOCK,
        covariance_keyframes,
        interpolate_covariance,
    )

    kf_t = np.arange(100) / 20.0  # 0 .. 4.95 s
    picked = covariance_keyframes(kf_t)
    assert np.allclose(kf_t[picked], [0.0, 1.0, 2.0, 3.0, 4.0, 4.95])
    rng = np.random.default_rng(3)
    a = rng.normal(size=(picked.size, 6, 6))
    cov = a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(6)
    t = kf_t[picked]
    assert np.allclose(interpolate_covariance(t, cov, t), cov)
    assert np.allclose(interpolate_covariance(t, cov, np.array([1.5]))[0], 0.5 * (cov[1] + cov[2]))
    rows = interpolate_covariance(t, cov, np.linspace(-1.0, 6.0, 50))
    assert np.linalg.eigvalsh(rows)[:, 0].min() > 0.0
    # a block at a time into ``out``: the same bits as the whole-array formula, across block boundaries
    many = np.sort(rng.uniform(-1.0, 6.0, 3 * COVARIANCE_ROW_BLOCK + 100))
    out = np.full((many.size, 6, 6), np.nan)
    assert interpolate_covariance(t, cov, many, out) is out
    j = np.clip(np.searchsorted(t, many, side="right"), 1, t.size - 1)
    w = np.clip((many - t[j - 1]) / (t[j] - t[j - 1]), 0.0, 1.0)[:, None, None]
    assert np.array_equal(out, (1.0 - w) * cov[j - 1] + w * cov[j])
    hour = covariance_keyframes(np.arange(72_000) / 20.0)  # an hour at 20 Hz: the count is capped, spread evenly
    assert hour.size <= COVARIANCE_MARGINALS + 2 and np.ptp(np.diff(hour)) <= 1


def test_a_planar_run_counts_only_the_axes_with_error():
    """MR.CLAM (planar): truth and riekf's estimate both hold z, roll and pitch at zero, so those axes' large σ
    measured nothing and the NEES was compared with 3 (attitude 3.2 'just above' [2.98, 3.02]); it is over the axes
    with error, with χ²(dof) bounds (attitude: yaw alone, 1 DoF, 3.2 times its expectation)."""
    from slamobs.pipeline.evaluation.sections import nees_statistics
    from slamobs.pipeline.evaluation.trajectory_evaluation import axes_with_error

    rng = np.random.default_rng(5)
    n = 4000
    err = np.c_[rng.normal(0.0, 0.1, (n, 2)), np.zeros(n)]  # x, y consistent with σ 0.1, z zero by construction
    cov = np.tile(np.diag([0.01, 0.01, 1.0]), (n, 1, 1))  # a 1 m σ on z that nothing tests
    assert axes_with_error(err) == (0, 1) and axes_with_error(np.zeros((3, 3))) == (0, 1, 2)
    full = nees_statistics(err, cov, nees_values(err, cov), np.arange(n) * 0.01)
    assert full["dof"] == 3 and full["mean"] < full["bounds"][0]  # the zero axis drags a consistent NEES below 3
    planar = nees_statistics(err, cov, nees_values(err[:, :2], cov[:, :2, :2]), np.arange(n) * 0.01, 2)
    lo, hi = nees_bounds(2, n)
    assert planar["dof"] == 2 and planar["bounds"] == pytest.approx([lo, hi]) and lo < planar["mean"] < hi


def test_a_planar_runs_unmeasured_axes_are_not_called_within_3_sigma():
    """MR.CLAM 7 robot 1, riekf: the report's table said 1 (every pair within ±3σ) for position z and attitude x, y,
    the axes the NEES leaves out because their error is zero on every pair, and the Method row said "3 DoF each,
    χ²(3n)/n" beside a DoF column of 2 and 1. Those shares are null ("–"), the Method says the DoF column's bounds."""
    from types import SimpleNamespace

    from slamobs.pipeline.evaluation.markdown import md_uncertainty
    from slamobs.pipeline.evaluation.sections import UncertaintySection

    rng = np.random.default_rng(7)
    n = 500
    err = np.zeros((n, 6))
    err[:, 2] = rng.normal(0.0, 0.01, n)  # yaw
    err[:, 3:5] = rng.normal(0.0, 0.1, (n, 2))  # x, y
    cov = np.tile(np.diag([0.01, 0.01, 1e-4, 0.01, 0.01, 1.0]), (n, 1, 1))
    u = SimpleNamespace(
        t_ns=np.arange(n) * 10_000_000,
        gauge_t_ns=0,
        error=err,
        cov_position=cov[:, 3:, 3:],
        cov_attitude=cov[:, :3, :3],
        nees_position=nees_values(err[:, 3:5], cov[:, 3:5, 3:5]),
        nees_attitude=nees_values(err[:, 2:3], cov[:, 2:3, 2:3]),
        position_axes=(0, 1),
        attitude_axes=(2,),
    )
    section = UncertaintySection()
    section.process_data(SimpleNamespace(uncertainty=u))
    pos, att = section.result["position"], section.result["attitude"]
    assert pos["within_3sigma"][2] is None and pos["within_3sigma"][0] > 0.9
    assert att["within_3sigma"][:2] == [None, None] and att["within_3sigma"][2] > 0.9
    rows = "\n".join(md_uncertainty(section.result))
    assert "| position | 2 (x, y) |" in rows and ", –]" in rows and "[–, –, " in rows
    method = UncertaintySection.METHOD["uncertainty"]
    assert "χ²(DoF·n)/n" in method and "(3 DoF each)" not in method


def test_the_3_sigma_figure_draws_a_planar_runs_unmeasured_axes_empty(monkeypatch, tmp_path):
    """MR.CLAM 7 robot 1, riekf: uncertainty.png showed δθ x, δθ y and δp z as a zero error inside ±3σ bands of up to
    45° and 4 m (the covariance riekf keeps open on the axes a planar run holds): a consistent-looking estimate on
    axes nothing measured. Those panels are drawn empty with a word; the others keep their error and band."""
    from types import SimpleNamespace

    from slamobs.pipeline.evaluation import plots
    from slamobs.pipeline.evaluation.figure_jobs import unmeasured_axes

    u = SimpleNamespace(position_axes=(0, 1), attitude_axes=(2,))
    held = unmeasured_axes(u)
    assert held == (0, 1, 5)
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    n = 50
    t = np.linspace(0.0, 5.0, n)
    plots.plot_sigma_bounds(tmp_path / "u.png", t, np.zeros((n, 6)), np.ones((n, 6)), unmeasured=held)
    (fig,) = figures
    panels = fig.axes[:6]  # rows of (attitude, position): axes[k, col] in row-major order
    for k in range(3):
        for col in range(2):
            ax = panels[2 * k + col]
            empty = 3 * col + k in held
            assert (len(ax.lines) == 0) == empty and (len(ax.collections) == 0) == empty, (k, col)
            assert any("not measured" in x.get_text() for x in ax.texts) == empty, (k, col)
            # an empty panel shows no scale: its default 0-1 ticks read as degrees, metres and seconds of nothing
            assert (len(ax.get_xticks()) == 0 and len(ax.get_yticks()) == 0) == empty, (k, col)


def test_a_nees_no_correlation_explains_says_plainly_the_sigma_is_not_to_be_trusted():
    """MR.CLAM 7 robot 1, riekf: position NEES 13.8 for 2 DoF (attitude 8.1 for 1) against Vicon, and the report's
    note said the covariance "looks optimistic here (consecutive errors are correlated, so one run strays further
    than these bounds ...)": a reader could take the σ at face value. A mean above E[X | X > q] of one NEES value
    above its 97.5 % quantile q (11.5 for 3 DoF), which a mean of consistent values exceeds with probability at most
    2.5 % however correlated, is called overconfident with the factor the σ would need; a mean outside the
    independent values' bounds only stays not conclusive, and so does one between q (9.35) and that bound: q itself
    holds for no correlation (the first version of this check used it)."""
    from types import SimpleNamespace

    from slamobs.pipeline.evaluation.markdown import md_uncertainty
    from slamobs.pipeline.evaluation.sections import UncertaintySection, nees_statistics

    rng = np.random.default_rng(11)
    n = 3000
    drift = np.cumsum(rng.normal(0.0, 0.01, (n, 6)), axis=0)  # a slow error, correlated over the whole run
    rms = np.sqrt(np.mean(drift**2, axis=0) * 3)  # each part's error scaled to an RMS norm of 0.1 √3 times ...
    err = drift / rms * 0.1 * np.sqrt(3) * np.r_[[np.sqrt(1.3)] * 3, [3.5] * 3]  # ... √1.3 (attitude), 3.5 (position)
    cov = np.tile(np.eye(3) * 0.01, (n, 1, 1))
    u = SimpleNamespace(
        t_ns=np.arange(n) * 10_000_000,
        gauge_t_ns=0,
        error=err,
        cov_position=cov,
        cov_attitude=cov,
        nees_position=nees_values(err[:, 3:], cov),
        nees_attitude=nees_values(err[:, :3], cov),
        position_axes=(0, 1, 2),
        attitude_axes=(0, 1, 2),
    )
    section = UncertaintySection()
    section.process_data(SimpleNamespace(uncertainty=u))
    pos, att = section.result["position"], section.result["attitude"]
    assert pos["mean"] > pos["bound_any_correlation"] == pytest.approx(11.51, abs=0.01)
    assert pos["verdict"] == "overconfident" and pos["sigma_factor"] == pytest.approx(3.5, rel=0.05)
    assert att["bounds"][1] < att["mean"] < att["bound_any_correlation"] and att["verdict"] == "inconclusive"
    (p_note,) = [x for x in section.notes if x.startswith("position NEES")]
    (a_note,) = [x for x in section.notes if x.startswith("attitude NEES")]
    assert "overconfident" in p_note and "do not take the written position σ at face value" in p_note
    assert "σ × 3.5" in p_note and "not conclusive from one run" in a_note and "face value" not in a_note
    rows = "\n".join(md_uncertainty(section.result))
    assert "| overconfident (3.5) |" in rows and "| inconclusive (1" in rows
    between = nees_statistics(err[:, 3:], cov, np.full(n, 10.4), u.t_ns / 1e9)  # above q = 9.35, below 11.5
    assert between["verdict"] == "inconclusive"


def test_a_negative_mean_nees_has_no_sigma_factor():
    """riekf at noise.gyro 1e6 (tests/test_riekf.py) wrote covariances whose NEES mean came out negative (not
    positive definite somewhere): the report's σ factor was sqrt of a negative number, NaN with a RuntimeWarning,
    written into report.json. It is null there, and the verdict is not 'overconfident'."""
    import warnings

    from slamobs.pipeline.evaluation.sections import nees_statistics

    n = 200
    err = np.full((n, 3), 0.1)
    cov = np.tile(np.eye(3) * 0.01, (n, 1, 1))
    nees = np.full(n, -4.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stats = nees_statistics(err, cov, nees, np.arange(n) * 0.01)
    assert stats["mean"] < 0.0 and stats["sigma_factor"] is None and stats["verdict"] != "overconfident"


def test_a_generated_maps_sigma_verdict_and_the_same_map_at_a_tenth_of_its_sigma(runs, tmp_path):
    """The report's map σ check on a generated log: riekf's and batch's maps, with the simulator's noise, are not
    called overconfident (their landmarks share the alignment's and the poses' errors: the verdict allows for
    that); riekf's map written with a tenth of its σ is, with the factor the σ would need and a plain note."""
    import shutil

    import pyarrow.compute as pc

    from slamobs.pipeline.evaluation.run_dir import report_run

    for name in ("riekf", "batch"):
        check = json.loads((runs[name] / "report.json").read_text())["landmarks"]["sigma_check"]
        assert check["n"] >= 10 and check["verdict"] != "overconfident" and not check["overconfident"]
    run = tmp_path / "riekf"
    shutil.copytree(runs["riekf"], run)
    table = pq.read_table(run / "landmarks.parquet")
    for name in LM_COV:
        table = table.set_column(table.schema.get_field_index(name), name, pc.divide(table.column(name), 100.0))
    pq.write_table(table, run / "landmarks.parquet")
    before = json.loads((runs["riekf"] / "report.json").read_text())["landmarks"]["sigma_check"]
    report, _ = report_run(run)
    check = report["landmarks"]["sigma_check"]
    assert check["mean_nees"] == pytest.approx(100 * before["mean_nees"], rel=1e-6)
    assert check["verdict"] == "overconfident" and check["mean_nees"] > check["bound_any_correlation"]
    assert check["sigma_factor"] == pytest.approx(10 * before["sigma_factor"], rel=1e-6)
    assert [n for n in report["notes"] if "the map's covariance is overconfident" in n]


def test_riekfs_map_on_a_generated_corner_log_is_not_called_overconfident_for_the_alignments_error(tmp_path):
    """A ground robot nobody tuned for, its tags seen as corners through a lens (the brief of session 29: gyro
    0.01 rad/s, velocity 0.03,0.03,0.005 m/s per sample, IMU 100 Hz, odometry 15 Hz, corners at 10 Hz): riekf's map
    is consistent where its covariance is defined (the gauge frame: mean NEES near 3), but the trajectory's alignment
    places it centimetres off and the map-only alignment moves its landmarks of mm σ, so the check called it
    overconfident (x3.2, NEES 83 and 62 after the two alignments). It now confirms in the gauge frame. The bias
    priors are given (the defaults' values): riekf's start from the detection pairs (session 29) leaves this log's
    map within the bound after the alignment too (6.2), where the check has nothing to confirm."""
    pytest.importorskip("cv2")
    from cli_checks import invoke

    log, out, config = tmp_path / "ground.mcap", tmp_path / "run", tmp_path / "run.yaml"
    config.write_text("noise:\n  gyro_bias: 0.2\n  velocity_bias: 0.2\n")
    noise = ["--gyro-noise", "0.01", "--velocity-noise", "0.03,0.03,0.005", "--imu-rate", "100", "--odom-rate", "15"]
    camera = ["--detection-rate", "10", "--camera", "corners", "--distortion", "radtan"]
    res = invoke("simulate", "ground", "-o", log, "--seed", 2121, "--duration", 40, *noise, *camera, "-q")
    assert res.exit_code == 0, res.output
    res = invoke("run", log, "-o", out, "--observer", "riekf", "--config", config, "-q")
    assert res.exit_code == 0, res.output
    report = json.loads((out / "report.json").read_text())
    check = report["landmarks"]["sigma_check"]
    assert check["mean_nees"] > check["bound_any_correlation"]  # after the trajectory's alignment
    assert check["after_map_only"]["mean_nees"] > check["bound_any_correlation"]  # and after the map's own
    assert check["in_gauge_frame"]["mean_nees"] < check["bounds"][1] * 1.5  # near its DoF where Σ is defined
    assert check["verdict"] == "inconclusive" and not check["overconfident"]
    assert not [n for n in report["notes"] if "the map's covariance is overconfident" in n]
    assert [n for n in report["notes"] if "landmarks.sigma_check.in_gauge_frame" in n]


def test_paired_covariance_takes_the_rows_of_the_whole_matrix_bit_for_bit():
    """The report's covariance entries at the paired rows and the diagonal's sum at every row, taken a column at a
    time (not an (N, 12) array of every row, batch's hour's report peak), are those of the whole matrix in time
    order, bit for bit: a table out of time order, rows without a covariance (NaN), an unused cross term."""
    from types import SimpleNamespace

    from slamobs.pipeline.evaluation.trajectory_evaluation import paired_covariance

    rng = np.random.default_rng(7)
    n = 5000
    # the attitude and position blocks' upper triangles, in the order of the report's entries
    pairs = [(i, j) for lo in (0, 3) for i in range(lo, lo + 3) for j in range(i, lo + 3)]
    names = [f"cov_{POSE_AXES[i]}_{POSE_AXES[j]}" for i, j in pairs]
    t_ns = rng.permutation(n).astype(np.int64) * 1_000_000
    table = {"t_ns": t_ns, "cov_x_roll": rng.standard_normal(n)}
    table |= {c: np.abs(rng.standard_normal(n)) * 10.0 ** rng.integers(-9, 2, n) for c in names}
    table[names[0]][:7] = np.nan
    order = np.argsort(t_ns, kind="stable")
    whole = np.stack([table[c] for c in names], axis=1)[order]
    idx = np.sort(rng.choice(n, 1200, replace=False))
    got = paired_covariance(table, SimpleNamespace(t_ns=t_ns[order]), SimpleNamespace(idx_est=idx))
    diagonal = [k for k, (i, j) in enumerate(pairs) if i == j]
    assert np.array_equal(got.entries, whole[idx], equal_nan=True)
    assert np.array_equal(got.size, whole[:, diagonal].sum(axis=1), equal_nan=True)
    # by stamps when the pairs have no row index
    got = paired_covariance(
        table, SimpleNamespace(t_ns=t_ns[order]), SimpleNamespace(idx_est=None, t_est_ns=t_ns[order][idx])
    )
    assert np.array_equal(got.entries, whole[idx], equal_nan=True)
    nothing = {"t_ns": t_ns} | {c: np.full(n, np.nan) for c in names}
    assert paired_covariance(nothing, SimpleNamespace(t_ns=t_ns[order]), SimpleNamespace(idx_est=idx)) is None


def _turned_body_evaluation(turn_deg: float, error_scale: float = 1.0):
    """A hand-held path (yaw about the circle, roll and pitch wobbling) and an estimate of it whose body frame is
    turned ``turn_deg`` about body x (a camera's extrinsic stated tilted) with white errors ``error_scale`` times the
    σ its covariance states (0.002 rad, 0.005 m; the first row its gauge, covariance 0); the trajectory evaluation."""
    from slamobs.pipeline.evaluation.trajectory_evaluation import ReportOptions, evaluate_trajectory
    from slamobs.pipeline.lie import so3_exp
    from slamobs.pipeline.streams import PoseStream

    rng = np.random.default_rng(39)
    n = 3000
    t = np.arange(n) * 0.02
    yaw, roll, pitch = 0.25 * t, 0.15 * np.sin(0.9 * t), 0.1 * np.sin(1.3 * t)
    rot = np.stack(
        [
            so3_exp(np.array([0.0, 0.0, a])) @ so3_exp(np.array([0.0, b, 0.0])) @ so3_exp(np.array([c, 0.0, 0.0]))
            for a, b, c in zip(yaw, pitch, roll, strict=True)
        ]
    )
    pos = np.c_[3.0 * np.cos(0.25 * t), 3.0 * np.sin(0.25 * t), 1.5 + 0.1 * np.sin(2.0 * t)]
    t_ns = 1_700_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    truth = PoseStream("truth", "world", "body", t_ns, t_ns, pos, rots_to_quats(rot))
    sa, sp = 0.002, 0.005
    c = so3_exp(np.array([np.radians(turn_deg), 0.0, 0.0]))
    est_rot = np.stack([so3_exp(error_scale * rng.normal(0.0, sa, 3)) @ r @ c for r in rot])
    est_pos = pos + error_scale * rng.normal(0.0, sp, (n, 3))
    est_rot[0], est_pos[0] = rot[0] @ c, pos[0]
    q = rots_to_quats(est_rot)
    cols = {"t_ns": t_ns, "x": est_pos[:, 0], "y": est_pos[:, 1], "z": est_pos[:, 2]}
    cols |= {k: q[:, i] for i, k in enumerate(("qx", "qy", "qz", "qw"))}
    for block, s in ((0, sa), (3, sp)):
        for i in range(block, block + 3):
            for j in range(i, block + 3):
                var = np.full(n, s * s if i == j else 0.0)
                var[0] = 0.0
                cols[f"cov_{POSE_AXES[i]}_{POSE_AXES[j]}"] = var
    return evaluate_trajectory(cols, truth, ReportOptions(), estimate_offset=False)


def test_an_overconfident_nees_names_a_constant_body_turn_that_explains_it():
    """seed=9993 (the lead's unseen check, session 38): a hand-held log whose camera is stated 3 deg tilted; batch,
    given the true noise, 0.034 m APE, position / attitude NEES 16.6 / 58.9, called overconfident with no word of
    why. The estimate's body frame is turned 2.8 deg against the truth's, a body-fixed systematic error no σ of white
    noise covers: with the truth turned by it the NEES is 1.75 / 2.12. The report now fits that turn (hand-eye on the
    aligned pairs) when a verdict is overconfident, gives each part's NEES with it out (``uncertainty.body_turn``),
    and the note names it where it explains the excess; where it does not (errors 6x their σ, no turn), it says so."""
    from slamobs.pipeline.evaluation.sections import UncertaintySection

    section = UncertaintySection()
    section.process_data(_turned_body_evaluation(3.0))
    r = section.result
    assert r["attitude"]["verdict"] == "overconfident" and r["position"]["verdict"] == "overconfident"
    turn = r["body_turn"]
    assert turn["angle_deg"] == pytest.approx(3.0, abs=0.1) and abs(turn["axis"][0]) > 0.99
    assert turn["explains"] and turn["attitude_mean"] < r["attitude"]["bound_any_correlation"]
    assert turn["position_mean"] < r["position"]["bound_any_correlation"]
    (a_note,) = [x for x in section.notes if x.startswith("attitude NEES")]
    assert "constant 3 deg turn between the estimate's body frame and the truth's" in a_note
    assert "covers the stated white noise only" in a_note

    plain = UncertaintySection()
    plain.process_data(_turned_body_evaluation(0.0))
    assert plain.result["attitude"]["verdict"] != "overconfident" and "body_turn" not in plain.result

    noisy = UncertaintySection()
    noisy.process_data(_turned_body_evaluation(0.0, error_scale=6.0))
    assert noisy.result["attitude"]["verdict"] == "overconfident" and not noisy.result["body_turn"]["explains"]
    (n_note,) = [x for x in noisy.notes if x.startswith("attitude NEES")]
    assert "does not explain it" in n_note
