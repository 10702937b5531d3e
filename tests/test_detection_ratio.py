"""A detection's range error apart from its bearing's in ``noise: auto`` and riekf (issue 23; docs/noise.md
"Range and bearing in riekf"): the triplets' residuals along the middle detection's line of sight against those
across it give the ratio of the two standard deviations (the law stays their mean over the axes); a log whose
detections are alike on every axis keeps 1, said in a note, and riekf's outputs do not change; a log whose range
error is 5 times the across one gets that ratio within 25 %, and riekf given it follows the truth more closely
than with the same σ on every axis; a ``noise: detection_ratio`` key overrides the estimate."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.lie import umeyama
from slamobs.pipeline.noise import NoiseConfig, estimate_log_noise, resolve_noise, stream_density
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.observers.riekf import RiEKF
from slamobs.pipeline.simulate import NoiseModel, expected_streams, get_scenario, simulate

RATIO = 5.0


@pytest.fixture(scope="module")
def logs():
    """A 30 s figure-8 (the default noise: the same σ(r) on every axis), and the same log whose detections carry
    an extra error along their line of sight making the range's σ ``RATIO`` times the across one."""
    nm = NoiseModel()
    sim = simulate("figure8", duration=30.0, seed=5, noise=nm)
    stream = align(expected_streams(sim), keep_directions=False)
    y = stream.det_y
    r = np.linalg.norm(y, axis=1)
    sigma = nm.detection_base + nm.detection_per_m * r
    extra = np.sqrt(RATIO**2 - 1) * sigma * np.random.default_rng(6).normal(size=r.size)
    sharp = replace(stream, det_y=y + y / r[:, None] * extra[:, None])
    velocity = stream_density(sim.odom.t_ns, sim.odom.linear)
    return sim, stream, sharp, velocity


def riekf_ape(sim, stream, noise) -> float:
    filt = RiEKF(stream, {}, ObserverOptions(out_every=10), noise=noise)
    res = filt.advance(filt.n_vel)
    truth = get_scenario(sim.scenario).sample((res.t_ns - sim.start_ns) * 1e-9)
    rot, t, _ = umeyama(res.position, truth.P)
    return float(np.sqrt(np.mean(np.sum((res.position @ rot.T + t - truth.P) ** 2, axis=1))))


def test_alike_axes_keep_one_and_say_so(logs):
    _, stream, _, velocity = logs
    found = estimate_log_noise(stream, velocity)
    assert found.ratio is None
    assert any("line of sight is not told" in n for n in found.notes), found.notes
    nz = resolve_noise(estimated=found)
    assert nz.detection_ratio == 1.0 and nz.sources["detection_ratio"] == "default"
    across, along = nz.ratio_split()  # the factors of σ(r)²: the law itself on every axis
    assert across == along == 1.0


def test_a_range_error_five_times_the_across_one_is_found_and_riekf_follows_it(logs):
    sim, _, sharp, velocity = logs
    found = estimate_log_noise(sharp, velocity)
    assert found.ratio is not None and abs(found.ratio.value / RATIO - 1) <= 0.25, found.ratio
    assert 0 < found.ratio.uncertainty < 0.1 * found.ratio.value
    nz = resolve_noise(estimated=found)
    assert nz.sources["detection_ratio"] == "estimated" and nz.detection_ratio == found.ratio.value
    across, along = nz.ratio_split()  # the factors of σ(r)² across the line of sight and along it
    np.testing.assert_allclose(along, nz.detection_ratio**2 * across)  # the range's variance
    np.testing.assert_allclose((2 * across + along) / 3, 1.0)  # trace kept: σ(r) the mean over the axes
    alike = riekf_ape(sim, sharp, replace(nz, detection_ratio=1.0))
    apart = riekf_ape(sim, sharp, nz)
    assert apart < alike, (apart, alike)


def test_a_configured_ratio_overrides_the_estimate(logs):
    _, _, sharp, velocity = logs
    nz = resolve_noise(NoiseConfig(detection_ratio=2.0), estimated=estimate_log_noise(sharp, velocity))
    assert nz.detection_ratio == 2.0 and nz.sources["detection_ratio"] == "config"
    assert nz.sources["detection"] == "estimated"
