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
