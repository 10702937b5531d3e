"""What an odometry topic's twist should have said, from its poses: VIO and SLAM odometry often leave
``twist.angular`` zero and some publish ``twist.linear`` in the parent (world) frame instead of the child frame
``nav_msgs/Odometry`` defines.

* Angular velocity from orientations: the body-frame increments ``log(R_kᵀ R_k+1)`` (unchanged by any rotation
  of the world frame) over their time steps, as a central difference at each sample, then a centred moving
  average over ``SMOOTH_S``.
* The frame of ``twist.linear``: compared with the position derivative in the parent frame and rotated into the
  child frame; whichever fits is used, and a twist that fits the parent frame is rotated into the child frame.

Both are reported (``LogStreams.derived``, written to ``run.json``).
"""

from __future__ import annotations

import numpy as np
from slamobs.pipeline.blocks import row_norms3
from slamobs.pipeline.kernel_cache import njit

from slamobs.pipeline.lie import mat3_mul, quats_to_rots, so3_exps, so3_log
from slamobs.pipeline.streams import PoseStream, Vec3Stream

#: Centred moving-average window of the differentiated angular velocity, seconds.
SMOOTH_S = 0.1
#: The twist is taken to be in the parent frame when that fits this much better than the child frame.
FRAME_MARGIN = 2.0


@njit(cache=True)
def _increments(rots):  # noqa: ANN001, ANN202
    """``log(R_kᵀ R_k+1)`` for consecutive rotations (K, 3, 3) -> (K - 1, 3)."""
    out = np.empty((max(rots.shape[0] - 1, 0), 3))
    for k in range(out.shape[0]):
        out[k] = so3_log(mat3_mul(rots[k].T.copy(), rots[k + 1]))
    return out


def body_rates(t_ns: np.ndarray, quat_xyzw: np.ndarray, smooth_s: float = SMOOTH_S) -> np.ndarray:
    """Body-frame angular velocity (N, 3) at the stamps of an orientation series (strictly increasing stamps)."""
    n = t_ns.shape[0]
    out = np.zeros((n, 3))
    if n < 2:
        return out
    q = np.asarray(quat_xyzw, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    inc = _increments(quats_to_rots(np.ascontiguousarray(q)))
    dt = np.diff(t_ns).astype(np.float64) * 1e-9
    # central difference: the two increments around a sample over the time they span (one-sided at the ends)
    total = np.zeros((n, 3))
    span = np.zeros(n)
    total[:-1] += inc
    total[1:] += inc
    span[:-1] += dt
    span[1:] += dt
    out = total / np.maximum(span, 1e-12)[:, None]
    period = float(np.median(dt))
    half = int(round(0.5 * smooth_s / period)) if period > 0 else 0
    if half >= 1:
        kernel = np.ones(2 * half + 1)
        weight = np.convolve(np.ones(n), kernel, mode="same")
        out = np.column_stack([np.convolve(out[:, a], kernel, mode="same") / weight for a in range(3)])
    return out


def angular_from_poses(poses: PoseStream, frame: str) -> Vec3Stream:
    """The angular-velocity stream of an odometry topic differentiated from its orientations."""
    omega = body_rates(poses.t_ns, poses.quat_xyzw)
    return Vec3Stream(poses.topic, frame, poses.t_ns, poses.rec_ns, omega)


def twist_in_parent(poses: PoseStream, linear: Vec3Stream) -> tuple[bool, float, float]:
    """Whether ``linear`` (on the stamps of ``poses``) matches the position derivative in the parent frame rather
    than in the child frame; with the median misfit (m/s) of each."""
    if len(poses) < 3 or len(linear) != len(poses) or not np.array_equal(poses.t_ns, linear.t_ns):
        return False, np.nan, np.nan
    # a repeated stamp has no derivative (numpy warns dividing by its zero step): the first sample of each stamp
    rows = np.flatnonzero(np.diff(poses.t_ns, prepend=np.iinfo(np.int64).min) > 0)
    if rows.size < 3 or not bool(np.all(np.diff(poses.t_ns[rows]) > 0)):
        return False, np.nan, np.nan
    t = poses.t_ns[rows].astype(np.float64) * 1e-9
    d_p = np.gradient(poses.position[rows], t, axis=0)
    quat = poses.quat_xyzw[rows]
    rots = quats_to_rots(np.ascontiguousarray(quat / np.linalg.norm(quat, axis=1, keepdims=True)))
    in_child = np.einsum("nji,nj->ni", rots, d_p)
    moving = row_norms3(d_p) > 1e-3  # np.linalg.norm's bits
    if np.count_nonzero(moving) < 3:
        return False, np.nan, np.nan
    lin = linear.xyz[rows]
    parent_fit = float(np.median(row_norms3(lin[moving] - d_p[moving])))
    child_fit = float(np.median(row_norms3(lin[moving] - in_child[moving])))
    return parent_fit * FRAME_MARGIN < child_fit, parent_fit, child_fit


def rotate_into_child(poses: PoseStream, linear: Vec3Stream) -> Vec3Stream:
    """``twist.linear`` given in the parent frame, expressed in the child frame with each sample's orientation."""
    q = poses.quat_xyzw / np.linalg.norm(poses.quat_xyzw, axis=1, keepdims=True)
    rots = quats_to_rots(np.ascontiguousarray(q))
    return Vec3Stream(
        linear.topic, linear.frame_id, linear.t_ns, linear.rec_ns, np.einsum("nji,nj->ni", rots, linear.xyz)
    )


#: What a twist sample can be against its own topic's poses (:func:`twist_sampling`): the mean over the interval
#: before its stamp (a downsampled or integrating odometry), the motion at its stamp (central difference), or the
#: increment over the interval after it (poses dead-reckoned by holding each twist until the next: the twist made
#: them, so they say nothing about how it was sampled).
SAMPLING_CANDIDATES = ("mean", "instant", "held")
#: Standard errors by which the best candidate's mean misfit must beat each other's (paired over the samples) to be
#: read (the detection offset's ``MIN_SIGMAS``, by the same reasoning: a model read wrong moves the offset search's
#: zero by half an interval).
SAMPLING_SIGMAS = 5.0
#: Intervals longer than this many median intervals (gaps) give no candidate to the samples beside them.
SAMPLING_GAP = 3.0


def _interval_twists(t: np.ndarray, quat_xyzw: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per interval between consecutive poses, the constant body twist that joins them (K - 1, 3) each: the
    rotation increment's log over the step, and the position increment in the body frame at the interval's middle
    orientation over the step (second order in the turn)."""
    q = quat_xyzw / np.linalg.norm(quat_xyzw, axis=1, keepdims=True)
    rots = quats_to_rots(np.ascontiguousarray(q))
    dt = np.diff(t)[:, None]
    turn = _increments(rots)
    mid = np.einsum("nij,njk->nik", rots[:-1], so3_exps(0.5 * turn))
    return turn / dt, np.einsum("nji,nj->ni", mid, np.diff(position, axis=0)) / dt


def _read_candidate(measured: np.ndarray, rates: np.ndarray, dt: np.ndarray, ok: np.ndarray) -> dict:
    """Which of ``SAMPLING_CANDIDATES`` the samples ``measured`` (interior ones, ``ok``) fit: the mean misfit of each
    (the norm of the difference), and the standard errors by which the best beats the runner-up (paired). The
    instantaneous candidate is the two intervals' rates (each at its middle) interpolated to the stamp."""
    before, after = rates[:-1][ok], rates[1:][ok]
    w = (dt[:-1][ok] / (dt[:-1][ok] + dt[1:][ok]))[:, None]  # the weight of the interval after the stamp
    m = measured[1:-1][ok]
    cands = {"mean": before, "instant": (1.0 - w) * before + w * after, "held": after}
    err = {k: row_norms3(m - v) for k, v in cands.items()}
    means = {k: float(np.mean(e)) for k, e in err.items()}
    best = min(means, key=means.get)
    z = np.inf
    for k in cands:
        if k != best:
            d = err[k] - err[best]
            se = float(np.std(d, ddof=1)) / np.sqrt(d.shape[0])
            z = min(z, float(np.mean(d)) / se if se > 0 else np.inf)
    return {"best": best, "sigmas": z, "misfit": {k: round(v, 6) for k, v in means.items()}}


def twist_sampling(poses: PoseStream, angular: Vec3Stream, linear: Vec3Stream) -> dict | None:
    """What each sample of an odometry's twist is (``SAMPLING_CANDIDATES``), read from the topic's own poses on
    the same stamps: against the body twist joining consecutive poses (:func:`_interval_twists`), the twist at a
    stamp equals the interval's before it where it is that interval's mean, the two intervals' mean (a central
    difference) where it is the motion at the stamp, the interval's after it where the poses were dead-reckoned by
    holding it. Read for the angular and the linear velocity apart; ``model`` is a candidate both read alike (or one
    reads and the other is not told), each best by ``SAMPLING_SIGMAS`` standard errors, else None. None when the
    poses are not on the twist's stamps or too few (fewer than 3 interior samples)."""
    n = len(poses)
    if n < 5 or len(angular) != n or len(linear) != n:
        return None
    if not (np.array_equal(poses.t_ns, angular.t_ns) and np.array_equal(poses.t_ns, linear.t_ns)):
        return None
    t = poses.t_ns.astype(np.float64) * 1e-9
    dt = np.diff(t)
    if not bool(np.all(dt > 0)):
        return None
    good = dt <= SAMPLING_GAP * float(np.median(dt))
    ok = good[:-1] & good[1:]
    if np.count_nonzero(ok) < 3:
        return None
    omega, vel = _interval_twists(t, poses.quat_xyzw, poses.position)
    read = {k: _read_candidate(s.xyz, r, dt, ok) for k, s, r in (("angular", angular, omega), ("linear", linear, vel))}
    told = {r["best"] for r in read.values() if r["sigmas"] >= SAMPLING_SIGMAS}
    return {
        "model": next(iter(told)) if len(told) == 1 else None,
        "samples": int(np.count_nonzero(ok)),
        **{k: {**r, "sigmas": round(float(min(r["sigmas"], 1e6)), 2)} for k, r in read.items()},  # no inf in run.json
    }


#: What the record says of a twist read as interval means (:func:`midpoint_restamped`).
RESTAMPED = "restamped to interval midpoints"


def interval_spans(stream: Vec3Stream) -> np.ndarray:
    """The interval (ns) each sample of a twist of interval means averages, ending at its stamp: the time since the
    sample before; the first sample's, and one's after a gap (an interval over ``SAMPLING_GAP`` median intervals: a
    dropped message, not a longer mean), the median interval. At least 2 samples."""
    dt = np.diff(stream.t_ns)
    med = int(np.median(dt))
    return np.concatenate([[med], np.where(dt > SAMPLING_GAP * med, med, dt)])


def midpoint_restamped(stream: Vec3Stream) -> Vec3Stream:
    """A twist of interval means (:func:`twist_sampling` reads ``mean``) restamped to the midpoint of the interval
    each sample covers (:func:`interval_spans`), ``t_k − (t_k − t_{k−1})/2``, where it is the motion to second order:
    a consumer that takes the twist linear between samples, or as the motion at its stamp, takes it so. Both clocks
    move alike. (One that holds each sample until the next takes it at its interval's start:
    ``alignment.held_stamps``.)"""
    if len(stream) < 2:
        return stream
    back = interval_spans(stream) // 2
    return Vec3Stream(stream.topic, stream.frame_id, stream.t_ns - back, stream.rec_ns - back, stream.xyz)
