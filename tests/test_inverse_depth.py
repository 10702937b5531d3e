"""batch weighs stereo-like detections in inverse depth (x/z, y/z, 1/z) in their camera's frame.

A generated figure-8 whose landmark points are triangulated from a rectified stereo pair with white pixel noise
(depth error ~ z², heavy-tailed and biased; lateral ~ z): with the law ``b + a·r²`` and a range/bearing ratio
above 1, batch's factors whiten to the inverse-depth residual and its trajectory is closer to the truth than with
range and bearing weighed apart in Cartesian terms. Points that are not a camera's (MR.CLAM's range-bearing
points in the body plane), a law linear in range or a ratio of 1 are left as they were.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import noisy_logs
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.noise import NoiseConfig, resolve_noise
from slamobs.pipeline.simulate import NoiseModel, expected_streams, simulate
from slamobs.pipeline.smoother import inverse_depth as idp
from slamobs.pipeline.smoother.settings import BatchSettings

PIXEL, FOCAL, BASELINE = 6.0, 1000.0, 0.5


def settings(mode: str) -> BatchSettings:
    return BatchSettings(noise_evidence="off", detection_correlation="off", detection_inverse_depth=mode)


@pytest.fixture(scope="module")
def stereo():
    nm = replace(NoiseModel(), stereo_pixel=PIXEL, stereo_focal=FOCAL, stereo_baseline=BASELINE)
    sim = simulate("figure8", duration=30.0, seed=5, noise=nm, detection_rate=10.0)
    stream = align(expected_streams(sim), keep_directions=False)
    per_axis = np.sqrt(2.0) * PIXEL / (FOCAL * BASELINE) / np.sqrt(3.0)  # the depth's z²·√2σ/(f b), over the axes
    law = resolve_noise(NoiseConfig(detection=1e-3, detection_per_m=0.0, detection_per_m2=per_axis))
    return sim, stream, replace(law, detection_ratio=30.0)  # as the triplets find it (not a configured ratio)


def test_the_factors_whiten_to_the_inverse_depth_residual():
    rng = np.random.default_rng(1)
    rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot *= np.sign(np.linalg.det(rot))
    sensor = (rot, np.array([0.1, -0.2, 0.3]))
    c = np.c_[rng.normal(0.0, 2.0, (20, 2)), rng.uniform(3.0, 15.0, 20)]
    at = c + rng.normal(0.0, 0.3, c.shape)
    y, sigma, shape = idp.factors(sensor, c @ rot.T + sensor[1], at @ rot.T + sensor[1], 0.006, 0.017)
    h = lambda p: np.c_[p[:, :2] / p[:, 2:], 1.0 / p[:, 2]]  # noqa: E731
    r_id = (h(at) - h(c)) / np.array([0.006, 0.006, 0.017])
    e = at @ rot.T + sensor[1] - y
    whitened = np.einsum("mi,mij,mj->m", e, shape, e) / sigma**2
    np.testing.assert_allclose(whitened, np.sum(r_id**2, axis=1), rtol=1e-9)
    np.testing.assert_allclose(np.linalg.det(shape), 1.0, rtol=1e-9)
    y0, _, _ = idp.factors(sensor, c @ rot.T + sensor[1], None, 0.006, 0.017)  # at the measurement: itself
    np.testing.assert_allclose(y0, c @ rot.T + sensor[1], atol=1e-12)


def test_stereo_like_detections_are_weighed_in_inverse_depth(stereo):
    sim, stream, noise = stereo
    assert stream.det_sensor is not None
    inverse, ape_inverse = noisy_logs.smoothed(sim, stream, settings("auto"), noise=noise)
    cartesian, ape_cartesian = noisy_logs.smoothed(sim, stream, settings("off"), noise=noise)
    record = inverse.stats["metadata"]["smoother"]["detection_inverse_depth"]
    assert record["applied"], record
    assert 0.8 * PIXEL / FOCAL < record["sigma_u"] < 1.25 * PIXEL / FOCAL, record
    assert any("inverse depth" in n for n in inverse.stats["notes"])
    assert cartesian.stats["metadata"]["smoother"]["detection_inverse_depth"] == {"skipped": "off"}
    assert ape_inverse < 0.75 * ape_cartesian, (ape_inverse, ape_cartesian)


def test_other_detections_are_left_alone(stereo):
    _, stream, noise = stereo
    sensor, y = stream.det_sensor, stream.det_y
    assert idp.why_not(noise, sensor, y, "auto") is None
    assert "not b + a·r²" in idp.why_not(replace(noise, detection_per_m=0.01), sensor, y, "auto")
    assert "ratio 1" in idp.why_not(replace(noise, detection_ratio=1.0), sensor, y, "auto")
    assert "one fixed sensor frame" in idp.why_not(noise, None, y, "auto")
    planar = np.c_[y[:, :2], np.zeros(y.shape[0])]  # range-bearing points in the body plane (MR.CLAM)
    assert "not a camera's" in idp.why_not(noise, (np.eye(3), np.zeros(3)), planar, "auto")
    behind = y.copy()
    behind[0] = 2.0 * sensor[1] - behind[0]  # one point mirrored through the camera's centre: z < 0
    assert "1 detections lie behind" in idp.why_not(noise, sensor, behind, "auto")
