"""batch chooses its noise scales by blocked cross-validation (issue 23; ``batch.noise_selection:
cross_validation``, pipeline/smoother/cross_validation.py): how well the smoother predicts detections it did not
see, no truth read. On a generated log with white noise at known levels, started from motion levels 10x too low,
it must pick the scale that brings them back to the truth, keep the truth when started there, and end no worse
than the evidence's choice (docs/noise.md)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from noisy_logs import noisy_figure8, smoothed
from slamobs.pipeline.noise import DETECTION_LAW_KEYS
from slamobs.pipeline.smoother import cross_validation as cv
from slamobs.pipeline.smoother.settings import BatchSettings


@pytest.fixture(scope="module")
def log():
    sim, stream, truth = noisy_figure8(40.0, 2)
    return sim, stream, truth


def estimated(truth, motion: float):
    """The true levels with gyro and velocity scaled by ``motion``, every level marked as estimated (so that the
    choice may scale it)."""
    sources = {k: "estimated" for k in (*cv.MOTION_KEYS, *DETECTION_LAW_KEYS)}
    return replace(truth, gyro=truth.gyro * motion, velocity=truth.velocity * motion, sources=sources)


def run(log, noise, selection: str):
    """The smoother with ``batch.noise_selection: selection``: itself and its APE at the keyframes (m)."""
    sim, stream, _ = log
    return smoothed(sim, stream, BatchSettings(noise_selection=selection), noise)


@pytest.fixture(scope="module")
def runs(log):
    """Started from the truth and from motion levels 10x too low, by cross-validation and by the evidence."""
    ways = ("cross_validation", "evidence")
    return {(m, how): run(log, estimated(log[2], m), how) for m in (1.0, 0.1) for how in ways}


def test_folds_are_interleaved_blocks():
    """Blocks of ``BLOCK_S`` from the first detection, fold = block mod ``FOLDS``; a short log gets shorter blocks so
    that every fold holds two."""
    t = np.arange(0.0, 9 * cv.BLOCK_S, 1.0)
    folds = cv.fold_of(t)
    assert np.array_equal(folds, (t // cv.BLOCK_S).astype(int) % cv.FOLDS)
    short = cv.fold_of(np.linspace(0.0, 40.0, 401))
    assert set(short.tolist()) == set(range(cv.FOLDS))
    assert np.count_nonzero(np.diff(short)) >= 2 * cv.FOLDS - 1


@pytest.mark.parametrize(("start", "expected"), [(1.0, 1.0), (0.1, 10.0)])
def test_cross_validation_finds_the_true_motion_level(log, runs, start, expected):
    """From the truth it keeps x1; from levels 10x too low it takes motion x10. run.json states every candidate's
    score and the winner, the winner is within the margin of the lowest score, and the levels used follow."""
    s, _ = runs[start, "cross_validation"]
    record = s.stats["metadata"]["smoother"]["noise_scale"]["cross_validation"]
    assert record["winner"]["motion"] == expected, record
    assert len(record["scores"]) == len(cv.MOTION_SCALES) * len(cv.DETECTION_SCALES), record
    won = record["scores"][f"motion x{record['winner']['motion']:g}, detection x{record['winner']['detection']:g}"]
    assert won <= min(record["scores"].values()) * (1.0 + cv.MIN_GAIN), record
    used = np.asarray(s.stats["metadata"]["noise"]["velocity"])
    np.testing.assert_allclose(used, log[2].velocity * start * expected)
    assert any("blocked cross-validation" in n for n in s.stats["notes"]), s.stats["notes"]


@pytest.mark.parametrize("start", [1.0, 0.1])
def test_cross_validation_is_not_worse_than_the_evidence_on_white_noise(runs, start):
    """Where the white-noise model is right, the evidence is the reference: cross-validation ends within 10 % of its
    APE."""
    _, ape_cv = runs[start, "cross_validation"]
    _, ape_ev = runs[start, "evidence"]
    assert ape_cv <= 1.1 * ape_ev, (ape_cv, ape_ev)


def test_configured_levels_are_not_cross_validated(log):
    """Every level set in the configuration: nothing to choose, the record says why and no fold is solved."""
    s, _ = run(log, log[2], "cross_validation")
    record = s.stats["metadata"]["smoother"]["noise_scale"]["cross_validation"]
    assert "configuration" in record["skipped"], record
