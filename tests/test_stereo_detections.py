"""The simulator's stereo detection model (``NoiseModel.stereo_pixel``: each landmark point triangulated from two
noisy pixels, the detection law of issue 23's unseen stereo dataset; benchmarks/stereo_logs.py): the depth error
grows with the square of the range and the lateral one linearly, points behind the camera or with too small a
disparity are not detected, the other streams draw exactly what the additive law's log draws, and ``noise: auto``
finds the r² law and a range error far above the bearing's on such a log."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import align
from slamobs.pipeline.noise import estimate_log_noise, stream_density
from slamobs.pipeline.simulate import NoiseModel, expected_streams, simulate
from slamobs.pipeline.simulate.sensors import stereo_points

F, B, PX = 1000.0, 0.5, 4.0


def test_depth_error_grows_with_the_square_of_the_range_and_lateral_with_the_range():
    rng = np.random.default_rng(0)
    n = 20_000
    errors = {}
    for z in (4.0, 8.0):
        pts = np.tile([0.5, -0.3, z], (n, 1))
        xyz, seen = stereo_points(pts, rng.standard_normal((n, 3)), PX, F, B)
        assert seen.all()
        errors[z] = (xyz - pts).std(axis=0)
    depth = errors[8.0][2] / errors[4.0][2]
    lateral = errors[8.0][0] / errors[4.0][0]
    assert 3.5 < depth < 4.6, depth  # (8/4)² = 4
    assert 1.7 < lateral < 2.4, lateral  # 8/4 = 2 (plus the depth error's share of x = u z / f)
    # first order: σ_z = z² √2 σ / (f b)
    np.testing.assert_allclose(errors[4.0][2], 16.0 * np.sqrt(2.0) * PX / (F * B), rtol=0.1)


def test_exact_pixels_give_the_points_and_unseen_points_are_left_out():
    pts = np.array([[1.0, 0.5, 5.0], [0.0, 0.0, -2.0], [0.0, 0.0, 200.0]])  # in front, behind, too far
    xyz, seen = stereo_points(pts, np.zeros((3, 3)), PX, F, B)
    assert seen.tolist() == [True, False, False]  # disparity at 200 m: 2.5 px < 2 · 4 px
    np.testing.assert_allclose(xyz[0], pts[0], atol=1e-12)


def test_a_stereo_log_shares_every_other_draw_and_keeps_its_frames():
    stereo = replace(NoiseModel(), stereo_pixel=8.0, stereo_focal=F, stereo_baseline=0.2)
    a = simulate("figure8-wide", duration=10.0, seed=3, noise=stereo)
    b = simulate("figure8-wide", duration=10.0, seed=3)
    assert np.array_equal(a.imu.gyro, b.imu.gyro) and np.array_equal(a.mocap.position, b.mocap.position)
    da, db = a.detections, b.detections
    assert np.array_equal(da.t_ns, db.t_ns) and da.offsets[-1] == da.ids.size
    assert 0 < da.ids.size < db.ids.size  # the far points' disparity is below 2 σ: not detected
    per_frame_a, per_frame_b = np.diff(da.offsets), np.diff(db.offsets)
    assert (per_frame_a <= per_frame_b).all()


def test_noise_auto_finds_the_square_law_and_a_steep_range_error():
    stereo = replace(NoiseModel(), stereo_pixel=PX, stereo_focal=F, stereo_baseline=B)
    sim = simulate("figure8-wide", duration=20.0, seed=88, noise=stereo, detection_rate=20.0)
    stream = align(expected_streams(sim), keep_directions=False)
    found = estimate_log_noise(stream, stream_density(sim.odom.t_ns, sim.odom.linear))
    assert found.detection.law == "b + a*r^2", found.detection.law
    # along the line of sight / across: √2 z / b at the ranges seen (4-14 m) is 11-40
    assert found.ratio is not None and 10.0 < found.ratio.value < 60.0, found.ratio


def test_riekf_on_a_stereo_log_with_learned_noise_is_within_1_5x_of_the_truth_and_gates_little():
    """Issue 23's riekf criterion on a stereo-like log (gyro 100x the default density, velocity 4x, 6 px): with
    the levels learned from the log, riekf is within 1.5x of riekf given the truth (the densities drawn, the
    first-order stereo law σ̄(r) = √(2/3)·σ r²/(f b) with the ratio √2·r/b at the median range) and gates
    fewer than 5 % of the detections."""
    from slamobs.pipeline.lie import umeyama
    from slamobs.pipeline.noise import DEFAULTS, NoiseConfig, resolve_noise
    from slamobs.pipeline.observers import ObserverOptions
    from slamobs.pipeline.observers.riekf import RiEKF
    from slamobs.pipeline.simulate import get_scenario

    rate, px = 50.0, 6.0
    gyro, velocity = 100 * DEFAULTS["gyro"][0], 4 * DEFAULTS["velocity"][0]  # densities
    nm = replace(
        NoiseModel(),
        gyro=gyro * np.sqrt(rate),
        odom_linear=velocity * np.sqrt(rate),
        stereo_pixel=px,
        stereo_focal=F,
        stereo_baseline=B,
    )
    sim = simulate("figure8-wide", duration=30.0, seed=88, noise=nm, imu_rate=rate, odom_rate=rate, detection_rate=20)
    stream = align(expected_streams(sim), keep_directions=False)  # no message covariances: all estimated
    auto = resolve_noise(estimated=estimate_log_noise(stream, stream_density(sim.odom.t_ns, sim.odom.linear)))
    r_med = float(np.median(np.linalg.norm(stream.det_y, axis=1)))
    truth = resolve_noise(
        NoiseConfig(
            gyro=gyro,
            velocity=velocity,
            detection=0.0,
            detection_per_m=0.0,
            detection_per_m2=np.sqrt(2.0 / 3.0) * px / (F * B),
            detection_ratio=np.sqrt(2.0) * r_med / B,
        )
    )
    errors, gated = {}, {}
    for name, nz in (("auto", auto), ("truth", truth)):
        filt = RiEKF(stream, {}, ObserverOptions(out_every=10), noise=nz)
        res = filt.advance(filt.n_vel)
        true_p = get_scenario(sim.scenario).sample((res.t_ns - sim.start_ns) * 1e-9).P
        rot, t, _ = umeyama(res.position, true_p)
        errors[name] = float(np.sqrt(np.mean(np.sum((res.position @ rot.T + t - true_p) ** 2, axis=1))))
        gated[name] = filt.stats["metadata"]["filter"]["gated_detections"] / stream.det_idx.shape[0]
    assert errors["auto"] <= 1.5 * errors["truth"], errors
    assert gated["auto"] < 0.05, gated


def test_a_steep_range_error_is_not_trimmed_at_the_bearings_spread():
    """Triplet residuals drawn from the law σ(r) = b + a·r² with the range's σ 20x the bearing's, lines of sight
    near one axis (a camera's): judged every component alike, the 4 σ outlier test cuts the along-the-line part
    (nearly all of the variance) at ~2.3 of its σ and the law comes out 5 % low; judged along and across the
    line of sight at the ratio, within 2 %."""
    from slamobs.pipeline.noise_estimation import Triplets, detection_law

    rng = np.random.default_rng(7)
    k, ratio, b, a = 5_000, 20.0, 0.01, 0.005
    r = np.repeat(rng.uniform(3.0, 12.0, k)[:, None], 3, axis=1)
    c2 = np.tile([0.25, 1.0, 0.25], (k, 1))  # the middle detection minus the mean of its neighbours
    law_var = np.sum(c2 * (b + a * r * r) ** 2, axis=1)
    u = np.c_[0.3 * rng.normal(size=(k, 2)), np.ones(k)]  # lines of sight near the optical axis, as a camera's
    u /= np.linalg.norm(u, axis=1)[:, None]
    across = rng.normal(size=(k, 3))
    across -= np.sum(across * u, axis=1)[:, None] * u  # two axes across, each of unit variance
    r2 = ratio * ratio
    e = np.sqrt(law_var)[:, None] * (
        np.sqrt(3.0 * r2 / (r2 + 2.0)) * rng.normal(size=k)[:, None] * u + np.sqrt(3.0 / (r2 + 2.0)) * across
    )
    tri = Triplets(e, c2, r, np.zeros(k), u)
    mid = np.array([7.5])
    truth = b + a * mid * mid
    alike = detection_law(tri).sigma(mid)[0] / truth
    apart = detection_law(tri, ratio=ratio).sigma(mid)[0] / truth
    assert alike < 0.97, alike  # 0.95
    assert abs(apart - 1.0) < 0.02, apart  # 1.004
