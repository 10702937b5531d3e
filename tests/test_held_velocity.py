"""A held velocity's white level from the smoother's solution (issue 23; docs/noise.md "A held velocity's white
level from batch's solution"). The window density reads a known white density back from interval residuals; on a
generated log with white held commands whose velocity level starts 4x too high (as the detection pairs' level does
on MR.CLAM, where it holds the commands' slow drift), batch brings it back near the truth and its trajectory closer
to the truth than with ``batch.held_velocity: off``."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import test_riekf_held as held

from test_riekf_held import held_log  # noqa: F401  (the module's fixture)

from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.smoother import held_velocity as hv
from slamobs.pipeline.smoother.estimator import BatchSmoother
from slamobs.pipeline.smoother.settings import BatchSettings


def test_window_density_reads_a_white_density_back():
    """Interval residuals of a white density q (variance q² Δt per interval) over irregular keyframes: the
    window density is q on each axis, and a window across an open interval is left out."""
    rng = np.random.default_rng(0)
    kf_t = np.cumsum(rng.uniform(0.02, 0.2, 20_000))
    q = np.array([0.01, 0.004, 0.02])
    res = rng.normal(size=(kf_t.size - 1, 3)) * q * np.sqrt(np.diff(kf_t))[:, None]
    rot = np.tile(np.eye(3), (kf_t.size, 1, 1))
    closed = np.zeros(kf_t.size - 1, bool)
    found = hv.window_density(kf_t, rot, res, closed)
    assert np.allclose(found, q, rtol=0.05), found
    res[100] = 1e3  # an interval across a velocity gap: unconstrained, its residual anything
    gap = closed.copy()
    gap[100] = True
    assert np.allclose(hv.window_density(kf_t, rot, res, gap), q, rtol=0.05)
    forward = np.array([[0.3, 0.0, 0.0], [0.5, 0.01, 0.0]])  # a commanded forward speed
    assert hv.scale(np.array([0.02, 0.04, 0.0]), np.full(3, 0.05), forward) == pytest.approx(0.4)
    assert hv.scale(np.array([0.08, 0.01, 0.0]), np.full(3, 0.05), forward) == 1.0  # never raised


#: the held level batch starts from, over the white truth: as if the detection pairs had taken up a slow drift
#: (MR.CLAM: 4-10x, docs/benchmarks.md "The held streams against Vicon")
TOO_HIGH = 4.0


def _batch(held_log, mode: str):
    """batch on test_riekf_held's log (commands held for 0.2 s, white) starting from a held velocity level
    ``TOO_HIGH`` x the truth; the evidence off, so that only ``batch.held_velocity`` moves it."""
    sim, stream, noise = held_log
    white = held.SIGMA_V * np.sqrt(held.HOLD / held.RATE_HZ)
    noise = replace(noise, velocity=np.full(3, TOO_HIGH * white))
    settings = BatchSettings(held_velocity=mode, noise_evidence="off")
    b = BatchSmoother(stream, {}, replace(ObserverOptions(out_every=10), noise=noise), settings)
    res = b.advance(b.n_vel)
    return held.ape(sim, res.t_ns, res.position), b.noise.velocity[0] / white, b.stats["metadata"]["smoother"]


def test_batch_takes_a_held_velocity_to_its_white_level(held_log):
    off_ape, off_ratio, off = _batch(held_log, "off")
    on_ape, on_ratio, on = _batch(held_log, "auto")
    assert off["held_velocity"] == {"skipped": "batch.held_velocity is off"} and off_ratio == pytest.approx(TOO_HIGH)
    assert 0.75 < on_ratio < 1.25, (on_ratio, on["held_velocity"])
    assert on_ape < off_ape, (on_ape, off_ape)
