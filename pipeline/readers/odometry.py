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

from slamobs.pipeline.lie import mat3_mul, quats_to_rots, so3_log
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
