"""Generated logs whose odometry goes silent while the gyro records (a VIO reset), and the error just after the
silence: the bridged-gap tests of the observers and riekf (docs/observers.md, "Gaps")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from slamobs.pipeline.lie import umeyama


def silence_odometry(streams, start_ns: int, lo: float, hi: float):
    """``streams`` (``simulate.expected_streams``) with the odometry's linear and angular twist silent from ``lo`` to
    ``hi`` s after ``start_ns``; the IMU and the detections as recorded."""
    silent = {}
    for role in ("linear_velocity", "twist_angular"):
        s = getattr(streams, role)
        t = (s.t_ns - start_ns) * 1e-9
        keep = (t < lo) | (t > hi)
        silent[role] = replace(s, t_ns=s.t_ns[keep], rec_ns=s.rec_ns[keep], xyz=s.xyz[keep])
    return replace(streams, **silent)


def rms_after(res, truth, start_ns: int, lo: float, hi: float = np.inf) -> float:
    """RMS position error (m) of ``res`` (an ``ObserverResult``) from ``lo`` to ``hi`` s after ``start_ns``, after one
    rigid alignment of the whole run to ``truth`` (its nearest truth sample at or after each pose)."""
    t = truth.t_ns
    ref = truth.position[np.clip(np.searchsorted(t, res.t_ns), 0, t.size - 1)]
    r, shift, _ = umeyama(res.position, ref)
    err = np.linalg.norm(res.position @ r.T + shift - ref, axis=1)
    s = (res.t_ns - start_ns) * 1e-9
    return float(np.sqrt(np.mean(err[(s > lo) & (s < hi)] ** 2)))
