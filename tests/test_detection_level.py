"""The detection law's level again from batch's own residuals (issue 23; docs/noise.md "The detection law's level
from batch's residuals"). The median's scale reads a known level back from whitened residuals with a heavy tail
that the mean square would take for noise; batch applies it only where it models the detections' correlation in
time, and on a generated log whose detections carry a slowly varying range error (the triplets' law sees only the
white part) it raises the law towards the detections' whole standard deviation."""

from __future__ import annotations

import numpy as np
import noisy_logs
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.simulate import expected_streams, simulate
from slamobs.pipeline.smoother import detection_level as dl
from slamobs.pipeline.smoother.settings import BatchSettings


def test_the_median_reads_the_level_back_through_a_heavy_tail():
    rng = np.random.default_rng(0)
    w = 0.5 * rng.normal(size=(20_000, 3))
    w[:2_000] *= 20.0  # a tenth far out: mis-associations, a turn between a detection and its stamp
    assert dl.scale(w) == pytest.approx(0.5 * 1.06, rel=0.04)  # the tail's tenth shifts the median a little
    record = dl.record(w, dl.scale(w))
    assert record["rms_scale"] > 3.0 and record["applied"] is True
    assert dl.scale(rng.normal(size=(20_000, 3))) == pytest.approx(1.0, rel=0.03)
    assert not dl.moved(1.0 + dl.MIN_CHANGE / 2) and dl.moved(1.0 - 2 * dl.MIN_CHANGE)


def test_the_level_is_taken_again_only_where_the_correlation_is_modelled():
    applied, white = {"applied": True}, {"applied": False}
    assert dl.skipped("auto", False, False, applied, False) is None
    assert "white" in dl.skipped("auto", False, False, white, False)
    assert "configuration" in dl.skipped("auto", True, False, applied, False)
    assert "off" in dl.skipped("off", False, False, applied, False)
    assert "inverse depth" in dl.skipped("auto", False, False, applied, True)


@pytest.fixture(scope="module")
def generated():
    sim = simulate("figure8", duration=30.0, seed=3)
    return sim, align(expected_streams(sim), keep_directions=False)


def test_a_white_log_keeps_its_law(generated):
    sim, stream = generated
    smoother, _ = noisy_logs.smoothed(sim, stream, BatchSettings(noise_evidence="off"))
    record = smoother.stats["metadata"]["smoother"]["detection_level"]
    assert "white" in record["skipped"], record


def test_a_slow_range_error_raises_the_law_towards_the_whole_error(generated):
    """The slow error (0.15 m along the line of sight, 5 s) is most of a detection's error and the triplets' law
    misses it: the law's geometric mean over the axes at the chosen shape is then about 2.2x the white one (0.15 m
    along against 0.015 across). The median of the solution's residuals raises the law, by less (the solution
    absorbs part of a slow error)."""
    sim, stream = generated
    noisy = noisy_logs.with_slow_range_error(stream, 0.15, 5.0, seed=4)
    auto, _ = noisy_logs.smoothed(sim, noisy, BatchSettings(noise_evidence="off"))
    off, _ = noisy_logs.smoothed(sim, noisy, BatchSettings(noise_evidence="off", detection_level="off"))
    record = auto.stats["metadata"]["smoother"]["detection_level"]
    assert record["applied"] is True and 1.2 < record["scale"] < 2.2, record
    assert auto.noise.detection == pytest.approx(record["scale"] * off.noise.detection, rel=1e-3)
    assert any("batch: the detection law x" in n for n in auto.stats["notes"]), auto.stats["notes"]
