"""A held velocity stream's white level from the smoother's own solution (issue 23).

A commanded (held) velocity has no samples to measure its noise on, so ``noise: auto`` takes its level from
pairs of detections over lags of 0.5-32 s (``noise_estimation.held_motion_noise``). Its error is coloured: on
MR.CLAM the commanded speed misses Vicon's by 0.004-0.009 m/√s over windows under a second but 0.02-0.03 over
8-32 s (a slowly varying error: slip, the robot lagging its commands), and the detection pairs see the slow part
(0.04-0.06 m/√s). The smoother's between factors weigh each keyframe interval (at most ``keyframe_dt``, 0.2 s)
by the white level, so the held level makes it trust the odometry 5-10x too little over the short intervals it
weighs, and the trajectory follows the detections' own slow range error.

The solution itself shows the short-window level once the detections' time correlation is fitted (weighed as
independent, the detections pull the first solution about: 0.028 m/√s on MR.CLAM 6-r1, 0.0085 after): its
keyframe poses against the odometry preintegrated between them, summed over windows of ``WINDOW_S`` (each
interval's position residual ``R_iᵀ(P_j − P_i) − Δp_ij``, turned into the window's first keyframe frame), as a
white-noise density per body axis

    q_a² = mean over windows of e_a² / T        (T the window's length, from each keyframe to the first at or
                                                 after ``WINDOW_S`` later; windows across a velocity gap left out)

On MR.CLAM that solution's forward density over 0.4 s is 0.006-0.014 m/√s (Vicon's over the same windows
0.009-0.011), and over 25 s it grows to 0.024-0.045 as Vicon's does: the solution's residuals have Vicon's
shape. The level adopted is that density on the axis the stream moves along, as a scale of the whole level
(never above 1: the white part cannot exceed the whole). Pure numerics, no I/O.
"""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.smoother.preintegration import D_JPV, D_JPW, D_P

#: Length (s) of the windows the residuals are summed over: two keyframe intervals of the default
#: ``keyframe_dt`` (0.2 s), short against the odometry's slow error (which grows over seconds) and long enough
#: that a window holds more than one detection frame's correction.
WINDOW_S = 0.4


def interval_residuals(data: np.ndarray, b_bar: np.ndarray, rot, pos, bias, seg_of) -> np.ndarray:
    """Per keyframe interval ``j``: the position residual ``R_jᵀ(P_{j+1} − P_j) − (Δp + J_pΩ δb_Ω + J_pV δb_V)``
    (m, body frame of keyframe ``j``), the bias that of the interval's segment."""
    db = bias[seg_of] - b_bar
    jpw = data[:, D_JPW : D_JPW + 9].reshape(-1, 3, 3)
    jpv = data[:, D_JPV : D_JPV + 9].reshape(-1, 3, 3)
    predicted = data[:, D_P : D_P + 3] + np.einsum("kij,kj->ki", jpw, db[:, :3])
    predicted += np.einsum("kij,kj->ki", jpv, db[:, 3:])
    moved = np.einsum("kji,kj->ki", rot[:-1], pos[1:] - pos[:-1])
    return moved - predicted


def window_density(kf_t: np.ndarray, rot: np.ndarray, residual: np.ndarray, open_interval: np.ndarray) -> np.ndarray:
    """Per body axis, the white-noise density (m/√s) of the interval residuals ``residual`` (K−1, 3) summed over
    windows of :data:`WINDOW_S` (module docstring); ``open_interval`` (K−1,) marks the intervals across a gap,
    whose windows are left out. NaN when no window fits."""
    k = kf_t.shape[0]
    world = np.einsum("kij,kj->ki", rot[:-1], residual)
    total = np.vstack([np.zeros((1, 3)), np.cumsum(world, axis=0)])
    gaps = np.r_[0, np.cumsum(open_interval.astype(np.int64))]
    i = np.arange(k)
    j = np.searchsorted(kf_t, kf_t + WINDOW_S * (1.0 - 1e-9))
    ok = j < k
    i, j = i[ok], j[ok]
    ok = gaps[j] == gaps[i]
    i, j = i[ok], j[ok]
    if i.shape[0] == 0:
        return np.full(3, np.nan)
    e = np.einsum("kji,kj->ki", rot[i], total[j] - total[i])
    return np.sqrt(np.mean(e * e / (kf_t[j] - kf_t[i])[:, None], axis=0))


def scale(density: np.ndarray, level: np.ndarray, velocity: np.ndarray) -> float:
    """The scale of the velocity level ``level`` (3,) that puts it at the residual density on the axis the
    stream moves along most (the largest RMS of its samples ``velocity`` (N, 3): a commanded forward speed; across
    it the residuals carry the heading's error times the distance, the gyro's part). At most 1; 1 when the
    density is not finite."""
    axis = int(np.argmax(np.sqrt(np.mean(velocity * velocity, axis=0))))
    s = float(density[axis] / level[axis]) if level[axis] > 0 else 1.0
    return min(s, 1.0) if np.isfinite(s) and s > 0 else 1.0


def skipped(mode: str, noise, fixed_bias: bool) -> str | None:
    """Why batch does not take the velocity level from its solution's short-window residuals, or None when it
    does: ``mode`` its ``batch.held_velocity`` setting, ``noise`` the levels it starts from
    (``pipeline.noise.NoiseSettings``), ``fixed_bias`` a reference run. Public: ``slamobs info --noise`` says by it
    that batch's run re-estimates the level it prints."""
    if mode == "off":
        return "batch.held_velocity is off"
    if "velocity" not in noise.held:
        return "the velocity stream's samples move (its level is measured from them)"
    if noise.sources.get("velocity") == "config":
        return "noise: velocity is set in the configuration"
    if fixed_bias:
        return "the biases are fixed (a reference run)"
    return None


def record(density: np.ndarray, level: np.ndarray, s: float) -> dict:
    """run.json's ``observer.smoother.held_velocity``: the densities per axis, the level before, the scale."""
    return {
        "window_s": WINDOW_S,
        "residual_density": [round(float(x), 6) for x in density],
        "held_level": [round(float(x), 6) for x in level],
        "scale": round(s, 6),
    }


def note(level: np.ndarray, s: float) -> str:
    """The report's note when the level moved."""
    return (
        f"batch: the held velocity's level {float(np.max(level)):.3g} -> {float(np.max(level)) * s:.3g} m/s/sqrt(Hz) "
        f"(x{s:.3g}): its first solution's residuals over {WINDOW_S:g} s windows (the detection pairs' level is the "
        "commands' slow drift; batch.held_velocity)"
    )
