"""riekf's biases held while the map holds fewer than ``min_landmarks_bias`` landmarks (module docstring, "Biases
held"): the detections then update the pose and the map, not the bias states."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import align
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.observers.riekf import RiEKF
from slamobs.pipeline.simulate import expected_streams, simulate


def _two_landmarks_first(stream, until_s: float):
    """``stream`` with the detections of all but its first two landmarks dropped before ``until_s`` s."""
    t = (stream.det_t_ns - stream.det_t_ns[0]) * 1e-9
    frame = np.repeat(np.arange(t.shape[0]), np.diff(stream.det_offsets))
    first = np.unique(stream.det_idx[: stream.det_offsets[1]])[:2]
    keep = (t[frame] >= until_s) | np.isin(stream.det_idx, first)
    counts = np.bincount(frame[keep], minlength=t.shape[0])
    return replace(
        stream,
        det_idx=stream.det_idx[keep],
        det_y=stream.det_y[keep],
        det_offsets=np.r_[0, np.cumsum(counts)].astype(stream.det_offsets.dtype),
    )


def test_the_biases_are_held_until_the_map_holds_three_landmarks_then_learned():
    """Two landmarks for the first 8 s: the bias rows stay at their start (exactly) until the third landmark's first
    frame, which run.json's ``bias_release`` names; after it they move. ``min_landmarks_bias`` 0 updates them from
    the first frame (the plain update)."""
    sim = simulate("figure8", duration=20.0, seed=4720)
    stream = _two_landmarks_first(align(expected_streams(sim), keep_directions=False), 8.0)
    filt = RiEKF(stream, {}, ObserverOptions())
    out = filt.advance(filt.n_vel)
    rec = filt._recovery()["bias_release"]
    assert rec["landmarks"] == 3
    released = rec["released_at_s"]
    assert released is not None and 7.5 <= released <= 9.0, rec  # the third landmark's first frame after 8 s
    t = (out.t_ns - stream.vel_t_ns[0]) * 1e-9
    bias = np.c_[out.gyro_bias, out.vel_bias]
    before, after = t < released - 1e-6, t > released + 0.5
    assert before.sum() > 10 and after.sum() > 10
    assert np.all(bias[before] == bias[:1]), "a bias moved while held"
    assert np.any(np.abs(bias[after] - bias[:1]) > 1e-3), "the biases never learned after the release"
    free = RiEKF(stream, {}, ObserverOptions(min_landmarks_bias=0))
    fo = free.advance(free.n_vel)
    assert free._recovery()["bias_release"]["released_at_s"] is None
    fb = np.c_[fo.gyro_bias, fo.vel_bias]
    assert np.any(np.abs(fb[before] - fb[:1]) > 1e-3), "min_landmarks_bias 0: the plain update from the start"
