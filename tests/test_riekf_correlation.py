"""riekf's pose covariance widened by the detections' correlation in time (issue 23): the integrated autocorrelation
of the landmarks' whitened innovations, and the written pose covariance on a generated log whose detection errors
are correlated over seconds and on one whose errors are white."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.noise import estimate_log_noise, resolve_noise, stream_density
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.observers.riekf import CORRELATION_LAGS, RiEKF, correlation_factor
from slamobs.pipeline.simulate import expected_streams, get_scenario, simulate


def _lag_sums(series: list[np.ndarray]) -> tuple[np.ndarray, int]:
    """The lag sums the kernel pools (0: squares, k: products with the k-th last of the same series)."""
    sums = np.zeros(CORRELATION_LAGS + 1)
    for x in series:
        sums[0] += np.sum(x * x)
        for k in range(1, min(CORRELATION_LAGS, x.shape[0] - 1) + 1):
            sums[k] += np.sum(x[k:] * x[:-k])
    return sums, sum(x.shape[0] for x in series)


def _ar1(rng, n: int, rho: float) -> np.ndarray:
    x = np.empty((n, 3))
    x[0] = rng.normal(size=3)
    for i in range(1, n):
        x[i] = rho * x[i - 1] + np.sqrt(1.0 - rho * rho) * rng.normal(size=3)
    return x


def test_the_correlation_factor_is_the_integrated_autocorrelation_and_one_for_white_series():
    """An AR(1) series of coefficient ρ has ν = (1 + ρ) / (1 − ρ) (3 for ρ = 0.5): found within its standard error
    and applied; white series give 1 within theirs and are not applied; nothing counted: 1, not applied."""
    rng = np.random.default_rng(23)
    rec = correlation_factor(*_lag_sums([_ar1(rng, 400, 0.5) for _ in range(20)]))
    assert abs(rec["nu"] - 3.0) < 2.0 * rec["se"] and rec["se"] < 0.5 and rec["applied"]
    rec = correlation_factor(*_lag_sums([rng.normal(size=(400, 3)) for _ in range(20)]))
    assert abs(rec["nu"] - 1.0) < 2.0 * rec["se"] and not rec["applied"]
    assert correlation_factor(np.zeros(CORRELATION_LAGS + 1), 0) | {"se": 0} == {
        "nu": 1.0,
        "se": 0,
        "window": 0,
        "innovations": 0,
        "applied": False,
    }


def _correlated_run(tau: float | None, seed: int = 2140) -> tuple[dict, float, float, list[str]]:
    """riekf on 40 s of the generated figure8-wide log, started at the true pose with the log's own noise levels;
    with ``tau``, each landmark's detections carry an extra error (0.03 m per axis), an AR(1) over its own detections
    with correlation time ``tau`` s. The correlation record, the written pose covariance's mean position NEES (3 DoF)
    and what it would be unwidened (times the factor), and the notes."""
    sim = simulate("figure8-wide", duration=40.0, seed=seed)
    s = expected_streams(sim)
    d = s.detections
    xyz = d.xyz.copy()
    if tau is not None:
        t = np.repeat(d.t_ns, np.diff(d.offsets)) * 1e-9
        rng = np.random.default_rng(seed + 1000)
        for i in np.unique(d.ids):
            e, last = np.zeros(3), None
            for j in np.flatnonzero(d.ids == i):
                rho = 0.0 if last is None else np.exp(-(t[j] - last) / tau)
                e = rho * e + np.sqrt(1.0 - rho * rho) * 0.03 * rng.normal(size=3)
                xyz[j] += e
                last = t[j]
    s = replace(s, detections=replace(d, xyz=xyz))
    stream = align(s, keep_directions=False)
    noise = resolve_noise(
        estimated=estimate_log_noise(stream, stream_density(s.linear_velocity.t_ns, s.linear_velocity.xyz))
    )
    sc = get_scenario(sim.scenario)
    start = sc.sample(np.array([(stream.vel_t_ns[0] - sim.start_ns) * 1e-9]))
    filt = RiEKF(stream, {}, ObserverOptions(out_every=20), noise=noise, r0=start.R[0], p0=start.P[0])
    res = filt.advance(filt.n_vel)
    rec = res.stats["metadata"]["filter"]["correlation"]
    truth = sc.sample((res.t_ns - sim.start_ns) * 1e-9)
    dp = (res.position - truth.P)[1:]  # the written convention: p̂ = p + δp (the first row is the start)
    nees = np.einsum("ni,ni->n", dp, np.linalg.solve(res.pose_cov[1:, 3:, 3:], dp[..., None])[..., 0])
    return rec, float(nees.mean()), float(nees.mean()) * rec["factors"][-1], res.stats["notes"]


@pytest.mark.parametrize("tau", [1.0, 3.0])
def test_correlated_detection_errors_widen_the_written_pose_covariance_near_its_dof(tau):
    """Detection errors correlated over seconds: the levels estimated from the log do not see them (a slow error
    cancels in the short triplets), the filter's own pose covariance is far too small (position NEES above 15 for 3
    DoF), ν is well above 1 and the written covariance, widened by it, brings the NEES near 3, with a note."""
    rec, nees, unwidened, notes = _correlated_run(tau)
    assert rec["applied"] and rec["nu"] - 2.0 * rec["se"] > 1.0 and rec["factors"] == [rec["nu"]]
    assert unwidened > 15.0 and nees < 6.0, (unwidened, nees, rec)
    assert sum("pose σ is widened ×√ν" in n for n in notes) == 1


def test_white_detection_errors_leave_the_pose_covariance_as_the_filter_s():
    """The simulator's white detection errors: ν within its bound of 1, not applied, factor 1, no note."""
    rec, nees, unwidened, notes = _correlated_run(None)
    assert not rec["applied"] and rec["factors"] == [1.0] and nees == unwidened
    assert abs(rec["nu"] - 1.0) < 2.0 * rec["se"]
    assert not any("pose σ is widened" in n for n in notes)
