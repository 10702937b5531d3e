"""Time-correlated detection errors in ``batch`` (issue 23; docs/noise.md "Detections whose errors are correlated
in time"). The variogram fit (:mod:`pipeline.smoother.correlation`) finds no correlation in white residuals, so
every factor is exactly 1 and the smoother's solution is the one without the model; on residuals with a known
exponential correlation it finds the share and time scale, and its per-detection factors count a track's
detections as the exact correlation does. On a generated log whose detections carry a slowly varying range error
(the detector's error along the line of sight, as on MR.CLAM) the smoother models it and its trajectory gets
closer to the truth than with the detections taken as independent."""

from __future__ import annotations

import numpy as np
import noisy_logs
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.simulate import expected_streams, simulate
from slamobs.pipeline.smoother import correlation as dc
from slamobs.pipeline.smoother.estimator import BatchSmoother
from slamobs.pipeline.smoother.settings import BatchSettings

#: generated residual tracks: landmarks, detections per track at RATE Hz, tracks per landmark
LANDMARKS, PER_TRACK, RATE, TRACKS = 12, 40, 4.0, 5
#: the correlated residuals' share of the variance and time constant (s)
SHARE, TAU = 0.7, 3.0
#: the generated log's slow range error: sd (m) and correlation time (s)
RANGE_SD, RANGE_TAU = 0.15, 5.0


def tracks(share: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Detection times, landmark ids and whitened 3-D residuals: per track a correlated part (``share`` of the
    variance, time constant ``TAU``) plus a white one."""
    rng = np.random.default_rng(seed)
    t, lm, w = [], [], []
    for j in range(LANDMARKS):
        for k in range(TRACKS):
            tt = 60.0 * k + j + np.arange(PER_TRACK) / RATE + rng.uniform(0, 0.05, PER_TRACK)
            slow = np.stack([noisy_logs.exponential(tt, TAU, rng) for _ in range(3)], axis=1)
            t.append(tt)
            lm.append(np.full(PER_TRACK, j))
            w.append(np.sqrt(share) * slow + np.sqrt(1.0 - share) * rng.normal(size=(PER_TRACK, 3)))
    return np.concatenate(t), np.concatenate(lm), np.concatenate(w)


def test_white_residuals_give_every_detection_a_factor_of_exactly_one():
    t, lm, w = tracks(0.0)
    corr = dc.fit(t, lm, w)
    assert not corr.significant, corr
    assert np.array_equal(dc.inflation(t, lm, corr), np.ones(t.size))


def test_correlated_residuals_give_their_share_and_time_scale():
    t, lm, w = tracks(SHARE)
    corr = dc.fit(t, lm, w)
    assert corr.significant, corr
    assert abs(corr.share - SHARE) < 0.15, corr
    assert TAU / 2 < corr.tau < 2 * TAU, corr


def test_the_factors_count_a_track_as_its_correlation_does():
    """The information of a track's mean with the inflated diagonal weights, ``Σ 1/fᵢ``, against the exact one
    under the fitted correlation, ``1ᵀC⁻¹1``: the same within a fifth, where the detections as independent
    would count ``n``."""
    t = np.arange(PER_TRACK) / RATE
    lm = np.zeros(PER_TRACK, int)
    corr = dc.Correlation(SHARE, TAU, 0.0, 1, {})
    c = corr.rho(t[:, None] - t[None, :])
    np.fill_diagonal(c, 1.0)
    exact = float(np.ones(PER_TRACK) @ np.linalg.solve(c, np.ones(PER_TRACK)))
    approx = float(np.sum(1.0 / dc.inflation(t, lm, corr)))
    assert abs(approx / exact - 1.0) < 0.2, (approx, exact)
    assert exact < PER_TRACK / 3


def test_factors_of_tracks_that_start_before_the_last_one_ended_give_no_warning():
    """Tracks taken landmark by landmark step back in time from one landmark's last detection to the next one's
    first: no link is computed there (it overflowed ``exp`` and printed a RuntimeWarning on real logs), and the
    factors are those of each track alone."""
    t = np.r_[np.arange(50) * 10.0 + 5000.0, np.arange(40) / RATE]  # landmark 0 seen long after landmark 1
    lm = np.r_[np.zeros(50, int), np.ones(40, int)]
    corr = dc.Correlation(SHARE, 0.5, 0.0, 1, {})
    with np.errstate(all="raise"):
        got = dc.inflation(t, lm, corr)
    alone = np.r_[dc.inflation(t[:50], lm[:50], corr), dc.inflation(t[50:], lm[50:], corr)]
    assert np.array_equal(got, alone)
    assert got[50:].min() > 1.5 and np.all(got[:50] < 1.0 + 1e-6)


@pytest.fixture(scope="module")
def generated():
    sim = simulate("figure8", duration=30.0, seed=3)
    return sim, align(expected_streams(sim), keep_directions=False)


def smoothed(sim, stream, mode: str):
    """The smoother (noise: auto's defaults, no evidence scan) and its keyframes' APE against the truth."""
    return noisy_logs.smoothed(sim, stream, BatchSettings(noise_evidence="off", detection_correlation=mode))


def test_a_white_log_keeps_the_independent_detections(generated):
    sim, stream = generated
    auto, ape_auto = smoothed(sim, stream, "auto")
    _, ape_off = smoothed(sim, stream, "off")
    record = auto.stats["metadata"]["smoother"]["detection_correlation"]
    assert record["applied"] is False, record
    assert auto.det_factor is None
    assert ape_auto == ape_off


def test_a_slow_range_error_is_modelled_and_the_trajectory_follows(generated):
    sim, stream = generated
    noisy = noisy_logs.with_slow_range_error(stream, RANGE_SD, RANGE_TAU, seed=4)
    auto, ape_auto = smoothed(sim, noisy, "auto")
    _, ape_off = smoothed(sim, noisy, "off")
    record = auto.stats["metadata"]["smoother"]["detection_correlation"]
    assert record["applied"] is True, record
    assert record["variance_factor"]["median"] > 2.0, record
    assert ape_auto < ape_off, (ape_auto, ape_off)


def test_batch_leaves_the_held_fits_factor_out_of_the_law_where_it_models_the_correlation():
    """On held (commanded) streams the detection law carries a factor for the detections' slow error, fitted with
    the streams' levels (MR.CLAM: 1.2-1.6); batch, which weighs that error by the detections' correlation in time,
    takes the triplets' law without it (and says so), unless the correlation is off or the law is configured."""
    from dataclasses import replace as swap

    from slamobs.pipeline.noise import LogNoise, NoiseConfig, resolve_noise
    from slamobs.pipeline.noise_estimation import DetectionLaw, Estimate

    sim = simulate("figure8", duration=10.0, seed=2)
    stream = align(expected_streams(sim), keep_directions=False)
    law = DetectionLaw("sigma0 + k*r", Estimate(0.03, 0.001, "m", 100), Estimate(0.006, 0.001, "m", 100), 1, (1, 5), -1)
    estimated = LogNoise(None, None, swap(law, held_scale=1.5))
    nz = resolve_noise(estimated=estimated)
    assert nz.detection_held_scale == 1.5 and nz.detection == 0.03
    auto = BatchSmoother(stream, {}, ObserverOptions(), settings=BatchSettings(), noise=nz)
    assert auto.noise.detection == pytest.approx(0.02) and auto.noise.detection_per_m == pytest.approx(0.004)
    assert any("held streams' fit's factor 1.5" in n for n in auto.law_notes), auto.law_notes
    assert auto.noise.detection_held_scale == 1.0  # the law it keeps carries no factor any more
    off = BatchSmoother(stream, {}, ObserverOptions(), settings=BatchSettings(detection_correlation="off"), noise=nz)
    assert off.noise.detection == 0.03 and not off.law_notes
    configured = resolve_noise(NoiseConfig(detection=0.03), estimated=estimated)
    assert configured.detection_held_scale == 1.0


def _fit(share: float, stderr: float, applied: bool = True) -> dict:
    return {"share": share, "stderr": stderr, "tau_s": 8.0, "applied": applied}


def test_the_detection_model_at_the_held_level_is_kept_only_where_the_share_held():
    """batch's detection model chosen again at the held velocity's level is kept when the correlated share did not
    fall by more than ``SIGNIFICANCE`` of its standard errors (MR.CLAM 7-r4's fits: 0.4414 +- 0.00885, then 0.4457:
    kept; 6-r1's: 0.427 +- 0.00792, then 0.2747: not, its ratio 32 took over the slow error); never when either fit
    is not applied (white detections)."""
    assert dc.share_held(_fit(0.4414, 0.00885), _fit(0.4457, 0.00981))
    assert not dc.share_held(_fit(0.427, 0.00792), _fit(0.2747, 0.00794))
    edge = 0.5 - dc.SIGNIFICANCE * 0.01
    assert dc.share_held(_fit(0.5, 0.01), _fit(edge + 1e-6, 0.01))
    assert not dc.share_held(_fit(0.5, 0.01), _fit(edge - 1e-3, 0.01))
    assert not dc.share_held(_fit(0.5, 0.01), _fit(0.5, 0.01, applied=False))
    assert not dc.share_held(_fit(0.5, 0.01, applied=False), _fit(0.5, 0.01))
    kept = {"ratio": 32.0, "share": 0.4457, "tau_s": 6.034, "share_before": 0.4414, "stderr_before": 0.00885}
    assert "and kept" in dc.again_note(kept | {"kept": True})
    assert "not kept" in dc.again_note(kept | {"kept": False})
