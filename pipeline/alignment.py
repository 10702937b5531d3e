"""Put the multi-rate streams on one time base and in the body frame: one ordered stream for an observer.

Angular velocity sets the time base (usually the fastest stream); body linear velocity is interpolated
linearly onto it. Landmark detections are moved from the camera frame into the body frame with the
static extrinsic and their ids mapped to dense indices. Everything an observer needs is here, as arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.directions import ACCEL_GATE, ACCEL_TOL, DEFAULT_GRAVITY, DEFAULT_MAGNETIC_FIELD, DirectionSet, build_directions
from pipeline.errors import InputError
from pipeline.frames import static_transform
from pipeline.streams import DetectionStream, LogStreams, Vec3Stream

#: Velocity gaps longer than this (seconds) are reported: the observer holds the last sample across them.
GAP_WARN_S = 0.5


@dataclass(frozen=True)
class AlignedStream:
    """Observer input. Times in int64 ns; ``t0_ns`` is the origin of the seconds the kernels use."""

    t0_ns: int
    vel_t_ns: np.ndarray  # (N,)
    omega: np.ndarray  # (N, 3) body angular velocity, measured (biased)
    velocity: np.ndarray  # (N, 3) body linear velocity, measured (biased)
    det_t_ns: np.ndarray  # (F,)
    det_offsets: np.ndarray  # (F + 1,)
    det_idx: np.ndarray  # (M,) index into landmark_ids
    det_y: np.ndarray  # (M, 3) landmark positions in the body frame
    landmark_ids: np.ndarray  # (L,) sorted unique ids
    body_frame: str
    notes: list[str] = field(default_factory=list)
    directions: DirectionSet | None = None  # inertial direction measurements on the velocity time base

    def seconds(self, t_ns: np.ndarray) -> np.ndarray:
        """Times relative to ``t0_ns`` in float64 seconds (exact to well below a microsecond)."""
        return (t_ns - self.t0_ns).astype(np.float64) * 1e-9

    @property
    def det_ids(self) -> np.ndarray:
        return self.landmark_ids[self.det_idx]


def _times(stream, time_source: str) -> np.ndarray:
    return stream.rec_ns if time_source == "record" else stream.t_ns


def _extrinsic(streams: LogStreams, body: str, frame: str, topic: str, identity_frames: set[str]):
    """Transform ``frame`` -> body, or a one-line error saying which transform is missing."""
    if not frame or frame.lstrip("/") in identity_frames:
        return np.eye(3), np.zeros(3)
    found = static_transform(streams.static_tf, body, frame)
    if found is None:
        raise InputError(
            streams.path,
            f"no /tf_static transform from frame '{frame}' to body frame '{body}' "
            f"(set frames.body, or list '{frame}' in frames.assume_identity)",
            topic,
        )
    return found


def _require(streams: LogStreams, name: str, what: str):
    stream = getattr(streams, name)
    if stream is None or len(stream) == 0:
        raise InputError(streams.path, f"no {what} found ({name}); set topics.{name} in the config")
    return stream


def _sorted(t: np.ndarray, *arrays: np.ndarray):
    if t.shape[0] > 1 and np.any(np.diff(t) < 0):
        order = np.argsort(t, kind="stable")
        return (t[order], *(a[order] for a in arrays))
    return (t, *arrays)


def _gaps(t_ns: np.ndarray, topic: str) -> list[str]:
    if t_ns.shape[0] < 2:
        return []
    d = np.diff(t_ns) * 1e-9
    big = d > GAP_WARN_S
    if not np.any(big):
        return []
    return [f"{topic}: {int(big.sum())} gap(s) longer than {GAP_WARN_S} s (largest {d.max():.2f} s)"]


def _resample(streams: LogStreams, stream: Vec3Stream | None, t_base: np.ndarray, body: str,
              time_source: str, ident: set[str]) -> np.ndarray | None:
    """A vector stream rotated into the body frame and interpolated onto ``t_base`` (NaN outside its span)."""
    if stream is None or len(stream) < 2:
        return None
    t, xyz = _sorted(_times(stream, time_source), stream.xyz)
    r, _ = _extrinsic(streams, body, stream.frame_id, stream.topic, ident)
    rel = (t - t[0]).astype(np.float64)
    q = (t_base - t[0]).astype(np.float64)
    out = np.column_stack([np.interp(q, rel, xyz[:, a], left=np.nan, right=np.nan) for a in range(3)])
    return out @ r.T


def align(
    streams: LogStreams,
    *,
    body_frame: str | None = None,
    time_source: str = "header",
    identity_frames: tuple[str, ...] = (),
    gravity=DEFAULT_GRAVITY,
    magnetic_field=DEFAULT_MAGNETIC_FIELD,
) -> AlignedStream:
    """Build the observer's ordered input from the decoded streams of one log."""
    om: Vec3Stream = _require(streams, "angular_velocity", "angular velocity (sensor_msgs/Imu or odometry twist)")
    lv: Vec3Stream = _require(streams, "linear_velocity", "body linear velocity (nav_msgs/Odometry or TwistStamped)")
    det: DetectionStream = _require(streams, "detections", "landmark detections (fiducial_msgs/FiducialTransformArray)")
    body = (body_frame or lv.frame_id or "base_link").lstrip("/")
    ident = {f.lstrip("/") for f in identity_frames}
    notes: list[str] = []

    t_om, w = _sorted(_times(om, time_source), om.xyz)
    t_lv, v = _sorted(_times(lv, time_source), lv.xyz)
    lo, hi = max(t_om[0], t_lv[0]), min(t_om[-1], t_lv[-1])
    if hi <= lo:
        raise InputError(
            streams.path,
            f"angular velocity ({om.topic}) and linear velocity ({lv.topic}) do not overlap in time",
        )
    keep = (t_om >= lo) & (t_om <= hi)
    if not np.all(keep):
        notes.append(f"{int((~keep).sum())} angular-velocity samples outside the linear-velocity span dropped")
    t_om, w = t_om[keep], w[keep]

    r_bi, _ = _extrinsic(streams, body, om.frame_id, om.topic, ident)
    omega = w @ r_bi.T
    # Linear velocity of the body origin from the velocity of the odometry frame (lever arm t_bc).
    rel = (t_lv - lo).astype(np.float64)
    rel_q = (t_om - lo).astype(np.float64)
    v_interp = np.column_stack([np.interp(rel_q, rel, v[:, a]) for a in range(3)])
    r_bc, t_bc = _extrinsic(streams, body, lv.frame_id, lv.topic, ident)
    velocity = v_interp @ r_bc.T - np.cross(omega, t_bc)
    notes += _gaps(t_om, om.topic) + _gaps(t_lv, lv.topic)

    # Detections: camera frame -> body frame, inside the velocity span.
    t_det = _times(det, time_source)
    counts = np.diff(det.offsets)
    frame_of = np.repeat(np.arange(len(det)), counts)
    order = np.argsort(t_det, kind="stable")
    in_span = (t_det >= lo) & (t_det <= hi)
    frames = order[in_span[order]]
    if frames.shape[0] < len(det):
        notes.append(f"{len(det) - frames.shape[0]} detection frames outside the velocity span dropped")
    sel = np.flatnonzero(in_span[frame_of]).astype(np.int64)
    # One detection per id and frame: repeated ids in one frame are ambiguous; keep the first.
    if sel.size:
        key = frame_of[sel] * (np.int64(1) << 32) + (det.ids[sel] & 0xFFFFFFFF)
        _, first = np.unique(key, return_index=True)
        if first.size < sel.size:
            notes.append(f"{det.topic}: {sel.size - first.size} repeated ids within a frame dropped")
            mask = np.zeros(sel.size, bool)
            mask[first] = True
            sel = sel[mask]
    r_bc, t_bc = _extrinsic(streams, body, det.frame_id, det.topic, ident)
    det_y = det.xyz[sel] @ r_bc.T + t_bc
    # ``frames`` is in time order; rebuild CSR offsets in that order.
    rank = np.empty(len(det), np.int64)
    rank[frames] = np.arange(frames.size)
    frame_rank = rank[frame_of[sel]]
    order_det = np.argsort(frame_rank, kind="stable")
    det_y = det_y[order_det]
    ids = det.ids[sel][order_det]
    per_frame = np.bincount(frame_rank, minlength=frames.size)
    offsets = np.concatenate([[0], np.cumsum(per_frame)]).astype(np.int64)
    landmark_ids, det_idx = np.unique(ids, return_inverse=True)
    if landmark_ids.size == 0:
        raise InputError(streams.path, "no landmark detections inside the velocity time span", det.topic)

    t_s = (t_om - t_om[0]).astype(np.float64) * 1e-9
    directions = build_directions(
        t_s, omega, velocity,
        _resample(streams, streams.accel, t_om, body, time_source, ident),
        _resample(streams, streams.magnetic, t_om, body, time_source, ident),
        gravity, magnetic_field,
    )
    if directions is not None and "gravity" in directions.names:
        w = directions.weight[:, directions.names.index("gravity")]
        notes.append(f"accelerometer: {100.0 * float(np.mean(w < 1.0)):.1f} % of samples down-weighted and "
                     f"{100.0 * float(np.mean(w == 0.0)):.1f} % skipped as accelerating "
                     f"(| |f - a_body| - |g| | above {ACCEL_TOL} / {ACCEL_GATE} m/s^2)")

    return AlignedStream(
        t0_ns=int(t_om[0]),
        vel_t_ns=t_om.astype(np.int64),
        omega=np.ascontiguousarray(omega),
        velocity=np.ascontiguousarray(velocity),
        det_t_ns=t_det[frames].astype(np.int64),
        det_offsets=offsets,
        det_idx=det_idx.astype(np.int64),
        det_y=np.ascontiguousarray(det_y, dtype=np.float64),
        landmark_ids=landmark_ids.astype(np.int64),
        body_frame=body,
        notes=notes,
        directions=directions,
    )
