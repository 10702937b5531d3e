"""batch evaluates each detection's σ(r) at the range its solution predicts, not the measured one (a measured
range carries the detection's own error: readings that came out short got more weight, and the map shrank).

A generated figure-8 whose detections' error grows with the range squared (the stereo / PnP law): at the measured
ranges the map comes out smaller than the truth (by 3.7 %); at the predicted ranges its scale is within
1 % and the trajectory closer to the truth. A law that does not grow with range is left alone.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import noisy_logs
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.noise import NoiseConfig, resolve_noise
from slamobs.pipeline.simulate import NoiseModel, expected_streams, get_scenario, simulate
from slamobs.pipeline.smoother import estimator
from slamobs.pipeline.smoother.settings import BatchSettings

SETTINGS = BatchSettings(noise_evidence="off", detection_correlation="off", detection_anisotropy="off")


@pytest.fixture(scope="module")
def range_squared():
    nm = replace(NoiseModel(), detection_base=0.01, detection_per_m=0.0, detection_per_m2=0.01)
    sim = simulate("figure8", duration=30.0, seed=5, noise=nm)
    noise = resolve_noise(NoiseConfig(detection=0.01, detection_per_m=0.0, detection_per_m2=0.01))
    return sim, align(expected_streams(sim), keep_directions=False), noise


def map_scale(smoother, stream) -> float:
    """The truth's size over the map's (the similarity fit's scale: 1 is unbiased)."""
    sc = get_scenario("figure8")
    where = {int(i): np.asarray(p) for i, p in zip(sc.landmark_ids, sc.landmarks)}
    est = smoother.result["solution"].landmarks
    truth = np.array([where[int(i)] for i in stream.landmark_ids])
    e, t = est - est.mean(axis=0), truth - truth.mean(axis=0)
    return float(np.linalg.svd(t.T @ e, compute_uv=False).sum() / (e**2).sum())


def test_the_range_law_is_evaluated_at_the_predicted_ranges(range_squared, monkeypatch):
    sim, stream, noise = range_squared
    predicted, ape_predicted = noisy_logs.smoothed(sim, stream, SETTINGS, noise=noise)
    monkeypatch.setattr(estimator, "RANGE_PASSES", 0)
    measured, ape_measured = noisy_logs.smoothed(sim, stream, SETTINGS, noise=noise)
    scale = {"predicted": map_scale(predicted, stream), "measured": map_scale(measured, stream)}
    assert scale["measured"] > 1.02, scale  # the map shrank
    assert abs(scale["predicted"] - 1.0) < 0.01, scale
    assert ape_predicted < 0.7 * ape_measured, (ape_predicted, ape_measured)
    assert predicted.det_range is not None
    assert any("range the solution predicts" in n for n in predicted.stats["notes"])


def test_a_law_without_range_growth_is_left_alone(range_squared):
    sim, stream, _ = range_squared
    flat = resolve_noise(NoiseConfig(detection=0.3, detection_per_m=0.0, detection_per_m2=0.0))
    smoother, _ = noisy_logs.smoothed(sim, stream, SETTINGS, noise=flat)
    assert smoother.det_range is None
    assert not any("range the solution predicts" in n for n in smoother.stats["notes"])
