"""Initial guesses of the batch smoother: an observer's run, or dead reckoning.

An observer's trajectory at the keyframes, its final map and its final biases start the smoother (the
observers converge from almost any start, docs/observers.md §4-§8, which the smoother cannot promise). Dead reckoning
(odometry integrated without bias correction from the identity, landmarks placed at their first sighting)
is the start a smoother would have without an observer.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from slamobs.pipeline.alignment import AlignedStream
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.smoother.preintegration import advance_poses, dead_reckon

#: Velocity samples per stretch of the seed observer (its histories are never held whole).
STRETCH = 131_072


@dataclass
class Seed:
    name: str
    rot: np.ndarray  # (K, 3, 3) at the keyframes
    pos: np.ndarray  # (K, 3)
    landmarks: np.ndarray  # (L, 3) in the stream's landmark order
    bias: np.ndarray  # (6,) [b_Ω, b_V]
    seconds: float
    #: landmarks whose detections jump in the run of a seed with a gate (riekf: :func:`.landmark_jumps`)
    landmark_jumps: list = field(default_factory=list)


def first_sightings(stream: AlignedStream, kf_of_det: np.ndarray, rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Each landmark placed at ``P + R y`` from its first detection (keyframe poses ``rot``, ``pos``)."""
    n_lm = stream.landmark_ids.shape[0]
    _, first = np.unique(stream.det_idx, return_index=True)
    out = np.zeros((n_lm, 3))
    k = kf_of_det[first]
    out[stream.det_idx[first]] = pos[k] + np.einsum("mij,mj->mi", rot[k], stream.det_y[first])
    return out


def dead_reckoning_seed(stream: AlignedStream, kf_t: np.ndarray, kf_of_det: np.ndarray) -> Seed:
    t = time.perf_counter()
    k = kf_t.shape[0]
    rot, pos = np.empty((k, 3, 3)), np.empty((k, 3))
    vel_t = stream.seconds(stream.vel_t_ns)
    dead_reckon(vel_t, stream.omega, stream.velocity, kf_t, np.zeros(6), np.eye(3), np.zeros(3), rot, pos)
    lms = first_sightings(stream, kf_of_det, rot, pos)
    return Seed("dead-reckoning", rot, pos, lms, np.zeros(6), time.perf_counter() - t)


def observer_seed(name: str, stream: AlignedStream, gains: dict, options, kf_t: np.ndarray, stepper=None) -> Seed:
    """Run observer ``name`` over the stream a stretch at a time, keeping its pose at each keyframe (``stepper``:
    an already started run of it, e.g. from another initial state)."""
    from slamobs.pipeline.observers import get_observer

    t = time.perf_counter()
    if stepper is None:
        stepper = get_observer(name).start(stream, gains, replace(options, out_every=1))
    vel_t = stream.seconds(stream.vel_t_ns)
    # the sample each keyframe falls in (a keyframe before the first sample: the first, carried back to it)
    s_of_kf = np.maximum(np.searchsorted(vel_t, kf_t, side="right") - 1, 0)
    k = kf_t.shape[0]
    rot, pos, bias = np.empty((k, 3, 3)), np.empty((k, 3)), np.empty((k, 6))
    from slamobs.pipeline.observers.base import InnovationRecord, ObserverDiverged, landmark_jumps

    # riekf's innovations show a reused landmark id where batch's own may not (MR.CLAM 6 r1, id 6 given to
    # landmark 16: batch kept riekf's start, weighed the range 32x down and took 3.75 m with no jump in its own)
    record = InnovationRecord() if get_observer(name).uses_noise else None
    part = None
    first = 0
    for stop in range(STRETCH, stepper.n_vel + STRETCH, STRETCH):
        try:
            part = stepper.advance(stop)
        except ObserverDiverged:
            part = None
            break
        n = part.t_ns.shape[0]
        sel = np.flatnonzero((s_of_kf >= first) & (s_of_kf < first + n))
        rows = s_of_kf[sel] - first
        rot[sel], pos[sel] = part.rotation[rows], part.position[rows]
        bias[sel, :3], bias[sel, 3:] = part.gyro_bias[rows], part.vel_bias[rows]
        first += n
        if record is not None:
            record.add(part)
    if part is None or not (np.isfinite(pos).all() and np.isfinite(part.landmark_xyz).all()):
        raise InputError(
            "<stream>", f"the seed observer '{name}' diverged (non-finite state); choose another batch.seed"
        )
    advance_poses(rot, pos, stream.omega[s_of_kf], stream.velocity[s_of_kf], bias, kf_t - vel_t[s_of_kf])
    return Seed(
        name,
        rot,
        pos,
        np.array(part.landmark_xyz, dtype=float),
        np.r_[part.gyro_bias[-1], part.vel_bias[-1]],
        time.perf_counter() - t,
        landmark_jumps(*record.arrays()) if record is not None else [],
    )
