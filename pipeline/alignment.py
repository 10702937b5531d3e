"""Put the multi-rate streams on one time base and in the body frame: one ordered stream for an observer.

Angular velocity sets the time base (usually the fastest stream); body linear velocity is interpolated
linearly onto it. Landmark detections are moved from the camera frame into the body frame and their ids
mapped to dense indices. Everything an observer needs is here, as arrays.

Frames: the body frame is ``body_frame`` if given, else the frame of the linear velocity (the odometry child
frame). Each sensor frame is brought into it through ``/tf_static`` when a static chain exists (one constant
transform). Otherwise, as logs often publish fixed extrinsics on ``/tf`` (ROS1 static_transform_publisher,
robot_state_publisher) and moving ones (gimbals, TF tag frames under a world frame) only there, the chain
through ``/tf`` is interpolated at every sample: velocity and direction samples outside the ``/tf`` span hold
the nearest transform (an extrinsic that drifts little), detection frames outside it are dropped (a moving
camera must not be guessed). Which edges were used is reported in the notes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.directions import ACCEL_GATE, ACCEL_TOL, DEFAULT_GRAVITY, DEFAULT_MAGNETIC_FIELD, DirectionSet, build_directions
from pipeline.errors import InputError
from pipeline.frames import TfBuffer
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


@dataclass(frozen=True)
class _Extrinsic:
    """``x_body = rot x_frame + trans``: one constant transform, or one per sample (``(N, 3, 3)``, ``(N, 3)``)."""

    rot: np.ndarray
    trans: np.ndarray
    valid: np.ndarray | None = None  # per-sample lookups: inside the /tf span

    def rotate(self, x: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        if self.rot.ndim == 2:
            return x @ self.rot.T
        return np.einsum("nij,nj->ni", self.rot[rows], x)

    def apply(self, x: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        return self.rotate(x, rows) + (self.trans if self.trans.ndim == 1 else self.trans[rows])


_IDENTITY = _Extrinsic(np.eye(3), np.zeros(3))
_VARYING_RAD = 1e-3  # a /tf extrinsic turning more than this over the log is reported as time-varying


def _to_body(tf: TfBuffer, body: str, frame: str, topic: str, ident: set[str], t_ns: np.ndarray,
             notes: list[str]) -> _Extrinsic:
    """Transform ``frame`` -> body: the /tf_static chain, else the /tf chain at ``t_ns``, else a one-line error."""
    frame = frame.lstrip("/")
    if not frame or frame in ident or frame == body:
        return _IDENTITY
    found = tf.static_lookup(body, frame)
    if found is not None:
        return _Extrinsic(*found)
    if tf.chain(body, frame) is None:
        raise InputError(
            tf.path,
            f"no transform from frame '{frame}' to body frame '{body}' in /tf_static or /tf "
            f"({tf.explain(body, frame)}; set frames.body, or list '{frame}' in frames.assume_identity)",
            topic,
        )
    res = tf.lookup(body, frame, t_ns, topic)
    note = f"{topic}: frame '{frame}' -> body '{body}' through /tf ({', '.join(res.dynamic)}), at each sample"
    if res.rot.shape[0] > 1:
        cos = (np.einsum("ij,nij->n", res.rot[0], res.rot) - 1.0) / 2.0
        turn = float(np.arccos(np.clip(cos, -1.0, 1.0)).max())
        if turn > _VARYING_RAD:
            note += f"; time-varying (turns up to {np.degrees(turn):.2f} deg)"
    notes.append(note)
    return _Extrinsic(res.rot, res.trans, res.valid)


def _held(ext: _Extrinsic, topic: str, notes: list[str]) -> None:
    """Velocity and direction samples outside the /tf span keep the nearest transform: say how many."""
    if ext.valid is not None and (n := int(np.count_nonzero(~ext.valid))):
        notes.append(f"{topic}: {n} samples outside the /tf span use the nearest transform")


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


def _resample(tf: TfBuffer, stream: Vec3Stream | None, t_base: np.ndarray, body: str,
              time_source: str, ident: set[str], notes: list[str]) -> np.ndarray | None:
    """A vector stream interpolated onto ``t_base`` (NaN outside its span) and rotated into the body frame."""
    if stream is None or len(stream) < 2:
        return None
    t, xyz = _sorted(_times(stream, time_source), stream.xyz)
    rel = (t - t[0]).astype(np.float64)
    q = (t_base - t[0]).astype(np.float64)
    out = np.column_stack([np.interp(q, rel, xyz[:, a], left=np.nan, right=np.nan) for a in range(3)])
    ext = _to_body(tf, body, stream.frame_id, stream.topic, ident, t_base, notes)
    _held(ext, stream.topic, notes)
    return ext.rotate(out)


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
    tf = TfBuffer(streams.static_tf, streams.tf, path=streams.path, time_source=time_source)

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

    gyro_ext = _to_body(tf, body, om.frame_id, om.topic, ident, t_om, notes)
    _held(gyro_ext, om.topic, notes)
    omega = gyro_ext.rotate(w)
    # Linear velocity of the body origin from the velocity of the odometry frame (lever arm t_bc).
    rel = (t_lv - lo).astype(np.float64)
    rel_q = (t_om - lo).astype(np.float64)
    v_interp = np.column_stack([np.interp(rel_q, rel, v[:, a]) for a in range(3)])
    vel_ext = _to_body(tf, body, lv.frame_id, lv.topic, ident, t_om, notes)
    _held(vel_ext, lv.topic, notes)
    velocity = vel_ext.rotate(v_interp) - np.cross(omega, vel_ext.trans)
    notes += _gaps(t_om, om.topic) + _gaps(t_lv, lv.topic)

    # Detections: camera frame -> body frame, inside the velocity span.
    t_det = _times(det, time_source)
    counts = np.diff(det.offsets)
    frame_of = np.repeat(np.arange(len(det)), counts)
    order = np.argsort(t_det, kind="stable")
    in_span = (t_det >= lo) & (t_det <= hi)
    if n_out := len(det) - int(np.count_nonzero(in_span)):
        notes.append(f"{n_out} detection frames outside the velocity span dropped")
    cam_ext = _to_body(tf, body, det.frame_id, det.topic, ident, t_det, notes)
    if cam_ext.valid is not None and (n_tf := int(np.count_nonzero(in_span & ~cam_ext.valid))):
        notes.append(f"{det.topic}: {n_tf} detection frames outside the /tf span dropped")
        in_span &= cam_ext.valid
    frames = order[in_span[order]]
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
    det_y = cam_ext.apply(det.xyz[sel], frame_of[sel])
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
        _resample(tf, streams.accel, t_om, body, time_source, ident, notes),
        _resample(tf, streams.magnetic, t_om, body, time_source, ident, notes),
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
