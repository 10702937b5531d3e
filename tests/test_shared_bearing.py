"""A bearing error shared by the detections of one frame and slow in time, in ``batch`` (issue 23; docs/noise.md
"A bearing error shared across landmarks"). The fit (:mod:`pipeline.smoother.shared_bearing`) finds no shared
part in independent bearings, so every factor is exactly 1 and the solution is the one without the model; on
bearings that share a yaw error it finds the share, and on a generated log whose sensor carries a slow yaw error
the smoother models it and its trajectory gets closer to the truth than with the bearings taken as
independent."""

from __future__ import annotations

import numpy as np
import noisy_logs
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.simulate import expected_streams, simulate
from slamobs.pipeline.smoother import shared_bearing as sb
from slamobs.pipeline.smoother.settings import BatchSettings

#: generated frames: count, rate (Hz), landmarks in view per frame
FRAMES, RATE, IN_VIEW = 600, 5.0, 3
#: the shared yaw error's share of the bearing variance and its time constant (s)
SHARE, TAU = 0.6, 2.0
#: the generated log's shared yaw error: sd (rad) and correlation time (s)
YAW_SD, YAW_TAU = 0.02, 3.0


def frames(share: float, seed: int = 0):
    """Detection times, landmark ids, body-frame points and residuals whose bearing carries a yaw shared by each
    frame's detections (``share`` of its variance, time constant ``TAU``) plus each detection's own."""
    rng = np.random.default_rng(seed)
    ft = np.arange(FRAMES) / RATE
    shared = np.repeat(noisy_logs.exponential(ft, TAU, rng), IN_VIEW)
    t = np.repeat(ft, IN_VIEW)
    lm = (np.arange(t.size) % IN_VIEW + 3 * (np.repeat(np.arange(FRAMES), IN_VIEW) // 50)) % 20
    ang = rng.uniform(-np.pi, np.pi, t.size)
    rng_m = rng.uniform(1.0, 4.0, t.size)
    y = np.stack([rng_m * np.cos(ang), rng_m * np.sin(ang), np.zeros(t.size)], axis=1)
    beta = np.sqrt(share) * shared + np.sqrt(1.0 - share) * rng.normal(size=t.size)
    r = 0.01 * beta[:, None] * np.stack([-y[:, 1], y[:, 0], np.zeros(t.size)], axis=1)
    return t, lm, y, r


def test_independent_bearings_give_every_detection_a_factor_of_exactly_one():
    t, lm, y, r = frames(0.0)
    corr = sb.fit(t, lm, y, r)
    assert not corr.significant, corr
    assert np.array_equal(sb.factor(t, lm, corr), np.ones(t.size))


def test_shared_bearings_give_their_share_and_time_scale():
    t, lm, y, r = frames(SHARE)
    corr = sb.fit(t, lm, y, r)
    assert corr.significant, corr
    assert abs(corr.share - SHARE) < 0.15, corr
    assert TAU / 2 < corr.tau < 2 * TAU, corr
    g = sb.factor(t, lm, corr)
    assert np.median(g) > 3.0, np.median(g)


def test_the_shape_scales_only_the_bearing_about_the_vertical():
    y = np.array([[2.0, 0.0, 0.5], [0.0, -3.0, 0.0]])
    base = np.array([np.diag([0.5, 2.0, 2.0]), np.diag([2.0, 0.5, 2.0])])
    s = sb.shape(y, base, np.array([4.0, 9.0]))
    cov, before = np.linalg.inv(s), np.linalg.inv(base)
    assert cov[0, 1, 1] == pytest.approx(4.0 * before[0, 1, 1]) and cov[1, 0, 0] == pytest.approx(9.0 * before[1, 0, 0])
    for m, (along, vertical) in enumerate(((0, 2), (1, 2))):
        assert cov[m, along, along] == pytest.approx(before[m, along, along])
        assert cov[m, vertical, vertical] == pytest.approx(before[m, vertical, vertical])


@pytest.fixture(scope="module")
def generated():
    sim = simulate("figure8", duration=30.0, seed=3)
    return sim, align(expected_streams(sim), keep_directions=False)


def smoothed(sim, stream, mode: str):
    """The smoother (noise: auto's defaults, no evidence scan, no time correlation) and its APE against truth."""
    settings = BatchSettings(noise_evidence="off", detection_correlation="off", detection_shared_bearing=mode)
    return noisy_logs.smoothed(sim, stream, settings)


def test_a_log_of_independent_bearings_is_solved_as_before(generated):
    sim, stream = generated
    auto, ape_auto = smoothed(sim, stream, "auto")
    _, ape_off = smoothed(sim, stream, "off")
    record = auto.stats["metadata"]["smoother"]["detection_shared_bearing"]
    assert record["applied"] is False, record
    assert auto.det_bearing is None
    assert ape_auto == ape_off


def test_a_shared_slow_yaw_error_is_modelled_and_the_trajectory_follows(generated):
    sim, stream = generated
    noisy = noisy_logs.with_shared_bearing_error(stream, YAW_SD, YAW_TAU, seed=4)
    auto, ape_auto = smoothed(sim, noisy, "auto")
    _, ape_off = smoothed(sim, noisy, "off")
    record = auto.stats["metadata"]["smoother"]["detection_shared_bearing"]
    assert record["applied"] is True, record
    assert record["bearing_variance_factor"]["median"] > 2.0, record
    assert ape_auto < ape_off, (ape_auto, ape_off)
