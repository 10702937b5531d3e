"""Turn a scenario into the message arrays a robot would have recorded.

Stamps are true measurement times; record times add a random 1-5 ms latency (non-decreasing per topic),
so readers and the alignment stage get the same stamp/record split as on a real robot. Everything is
columnar; :mod:`pipeline.simulate.logwriter` turns rows into ROS messages.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from slamobs.pipeline.lie import integrate_body_twists, rots_to_quats, so3_exps
from slamobs.pipeline.simulate.camera import CameraSim, tag_views
from slamobs.pipeline.simulate.scenarios import (
    GRAVITY,
    MAGNETIC_FIELD,
    Camera,
    Scenario,
    get_scenario,
)
from slamobs.pipeline.streams import DetectionStream, LogStreams, PoseStream, Transform, Vec3Stream

EPOCH_NS = 1_700_000_000_000_000_000  # first stamp of every simulated log

TOPIC_IMU = "/imu/data"
TOPIC_ODOM = "/odom"
TOPIC_MAG = "/imu/mag"
TOPIC_DETECTIONS = "/fiducial_transforms"
TOPIC_TF_STATIC = "/tf_static"
TOPIC_MOCAP = "/mocap/pose"
TOPIC_TRUTH = "/slamobs/sim_truth"
TOPIC_TAGS = "/camera/tags"  # tag corners (camera output "corners")
TOPIC_IMAGE = "/camera/image_raw"  # raw images (camera output "images" without JPEG)
TOPIC_IMAGE_JPEG = "/camera/image_raw/compressed"
TOPIC_CAMERA_INFO = "/camera/camera_info"

FRAME_WORLD = "world"
FRAME_BODY = "base_link"
FRAME_IMU = "imu_link"
FRAME_CAMERA = "camera"
FRAME_ODOM = "odom"

# Fixed per-sensor phase (s) so no two sensors share stamps: the alignment stage must interpolate.
_PHASE = {"imu": 0.0, "odom": 0.0013, "mag": 0.0021, "detections": 0.007, "mocap": 0.0005}

# Tag model for the plausible detector quality fields.
_FOCAL_PX = 600.0
_TAG_SIZE_M = 0.16


@dataclass(frozen=True)
class NoiseModel:
    """Standard deviations of the additive white noises (all zero when simulating without noise).

    ``gyro`` and ``odom_linear`` are one value or one per axis (x, y, z); a detection's standard deviation per
    component is ``detection_base + detection_per_m * r + detection_per_m2 * r²`` at range r (the stereo / PnP
    law grows with r²). With ``stereo_pixel`` > 0 the detections are instead stereo triangulations
    (:func:`stereo_points`): a rectified pair of focal length ``stereo_focal`` px and baseline ``stereo_baseline``
    m sees each point with white pixel noise ``stereo_pixel`` px (depth error ~ z²/(f b), lateral ~ z/f); points
    behind the camera or whose noisy disparity is below twice the pixel noise are not detected."""

    gyro: float | tuple[float, float, float] = 0.005  # rad/s
    accel: float = 0.05  # m/s^2
    odom_linear: float | tuple[float, float, float] = 0.02  # m/s
    odom_angular: float = 0.01  # rad/s
    mag: float = 2e-7  # Tesla
    detection_base: float = 0.01  # m, per component
    detection_per_m: float = 0.002  # m per m of range, per component
    tag_rotation: float = 0.01  # rad
    detection_per_m2: float = 0.0  # m per m² of range, per component
    #: RMS (m/s, per axis) of a slowly varying error of the odometry's linear velocity beside the white one (slip,
    #: a robot lagging its commands), and its time scale (s): a sum of sinusoids of periods around
    #: ``2π odom_linear_drift_s`` (:func:`_drift`); 0 draws nothing (the random stream is unchanged)
    odom_linear_drift: float = 0.0
    odom_linear_drift_s: float = 10.0
    stereo_pixel: float = 0.0  # px, standard deviation of each image coordinate; 0: the additive law above
    stereo_focal: float = 450.0  # px
    stereo_baseline: float = 0.24  # m
    #: share of the detections that carry another landmark's ID (a tag decoding or stereo matching failure), and
    #: share placed at an absurd range (the point scaled 5-50x along its ray); drawn from their own generator, so
    #: 0 leaves every other draw unchanged
    wrong_id: float = 0.0
    absurd_range: float = 0.0

    @classmethod
    def zero(cls) -> NoiseModel:
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ImuData:
    t_ns: np.ndarray  # (N,) int64 stamps
    rec_ns: np.ndarray  # (N,) int64 record times
    gyro: np.ndarray  # (N, 3) rad/s, imu_link frame (biased)
    accel: np.ndarray  # (N, 3) specific force m/s^2


@dataclass(frozen=True)
class OdomData:
    t_ns: np.ndarray
    rec_ns: np.ndarray
    linear: np.ndarray  # (N, 3) body-frame velocity (biased)
    angular: np.ndarray  # (N, 3) body-frame angular velocity (unbiased)
    position: np.ndarray  # (N, 3) dead-reckoned, odom frame
    quat_xyzw: np.ndarray  # (N, 4)


@dataclass(frozen=True)
class MagData:
    t_ns: np.ndarray
    rec_ns: np.ndarray
    field: np.ndarray  # (N, 3) Tesla, imu_link frame


@dataclass(frozen=True)
class DetectionData:
    """One frame per message, CSR layout as :class:`pipeline.streams.DetectionStream`."""

    t_ns: np.ndarray  # (F,)
    rec_ns: np.ndarray  # (F,)
    offsets: np.ndarray  # (F + 1,) int64
    ids: np.ndarray  # (M,) int64
    xyz: np.ndarray  # (M, 3) camera frame
    quat_xyzw: np.ndarray  # (M, 4) tag orientation in the camera frame
    image_error: np.ndarray  # (M,) px
    object_error: np.ndarray  # (M,) m
    area: np.ndarray  # (M,) px^2


@dataclass(frozen=True)
class CameraData:
    """The simulated camera's frames (on the detection stamps): its pose, and the tags it sees with their corner
    pixels (noisy for the ``corners`` output, true for ``images``, which are rendered when written)."""

    t_ns: np.ndarray  # (F,)
    rec_ns: np.ndarray  # (F,)
    r_wc: np.ndarray  # (F, 3, 3) camera -> world
    t_wc: np.ndarray  # (F, 3)
    offsets: np.ndarray  # (F + 1,)
    ids: np.ndarray  # (M,)
    corners: np.ndarray  # (M, 4, 2) px, OpenCV order


@dataclass(frozen=True)
class PoseData:
    t_ns: np.ndarray
    rec_ns: np.ndarray
    position: np.ndarray  # (N, 3) world frame
    quat_xyzw: np.ndarray  # (N, 4)


@dataclass(frozen=True)
class SimLog:
    """Everything one simulated log contains, ready for :func:`pipeline.simulate.logwriter.write_log`."""

    scenario: str
    seed: int
    noise: NoiseModel
    duration: float
    start_ns: int  # stamp and record time of /tf_static and /slamobs/sim_truth
    imu: ImuData
    odom: OdomData
    mag: MagData
    detections: DetectionData
    mocap: PoseData
    static_tf: list[Transform]
    truth: dict = field(default_factory=dict)  # the /slamobs/sim_truth JSON document
    camera: CameraData | None = None  # tag corners / images instead of fiducial poses
    camera_sim: CameraSim = CameraSim()
    #: Index of the first sample of each stream in the whole log (a piece of a longer simulation; 0 otherwise).
    first: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STREAMS, 0))

    @property
    def truth_json(self) -> str:
        return json.dumps(self.truth, sort_keys=True)

    def topic_counts(self) -> dict[str, int]:
        """Messages per topic, as they will be written."""
        counts = {
            TOPIC_TF_STATIC: 1,
            TOPIC_TRUTH: 1,
            TOPIC_IMU: len(self.imu.t_ns),
            TOPIC_ODOM: len(self.odom.t_ns),
            TOPIC_MAG: len(self.mag.t_ns),
            TOPIC_DETECTIONS: len(self.detections.t_ns),
            TOPIC_MOCAP: len(self.mocap.t_ns),
        }
        return camera_topics(counts, self.camera_sim)


def body_points(R: np.ndarray, P: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Body-frame landmark positions ``R^T (p_i - P)``: (N, 3, 3), (N, 3), (L, 3) -> (N, L, 3)."""
    return np.einsum("nji,nlj->nli", R, landmarks[None, :, :] - P[:, None, :])


def camera_points(camera: Camera, y_body: np.ndarray) -> np.ndarray:
    """Body-frame points into the camera frame: ``R_bc^T (y - t_bc)``."""
    return (y_body - camera.t_bc) @ camera.R_bc


def visibility(camera: Camera, y_cam: np.ndarray) -> np.ndarray:
    """Which camera-frame points the camera detects (field-of-view cone and range limits)."""
    rng = np.linalg.norm(y_cam, axis=-1)
    vis = rng >= camera.min_range
    if camera.max_range is not None:
        vis &= rng <= camera.max_range
    if camera.fov_h_deg is not None or camera.fov_v_deg is not None:
        vis &= y_cam[..., 2] > 0.0
    if camera.fov_h_deg is not None:
        vis &= np.abs(np.arctan2(y_cam[..., 0], y_cam[..., 2])) <= np.deg2rad(camera.fov_h_deg) / 2
    if camera.fov_v_deg is not None:
        vis &= np.abs(np.arctan2(y_cam[..., 1], y_cam[..., 2])) <= np.deg2rad(camera.fov_v_deg) / 2
    return vis


def _count(duration: float, rate: float, phase: float) -> int:
    """Samples of a ``rate`` grid shifted by ``phase`` within ``[0, duration]``."""
    if rate <= 0:
        raise ValueError(f"rate must be positive, got {rate}")
    return max(int(np.floor((duration - phase) * rate + 1e-9)) + 1, 0)


def _stamps(first: int, stop: int, rate: float, phase: float, start_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (int64 ns) of grid samples ``first .. stop - 1``, and the exact times (s) they encode."""
    offs = np.round((phase + np.arange(first, stop) / rate) * 1e9).astype(np.int64)
    return start_ns + offs, offs.astype(float) * 1e-9


def _record_times(rng: np.random.Generator, t_ns: np.ndarray, after: int) -> np.ndarray:
    """Stamp + 1..5 ms latency, made non-decreasing like a recorder's queue (and not before ``after``)."""
    rec = t_ns + rng.integers(1_000_000, 5_000_001, size=t_ns.shape[0])
    if rec.size:
        rec[0] = max(rec[0], after)
    return np.maximum.accumulate(rec)


def _white(rng: np.random.Generator, sigma, shape: tuple[int, ...]) -> np.ndarray:
    """Gaussian noise (``sigma`` one value or one per last axis); still draws when ``sigma == 0`` so noisy and
    clean runs share one random stream."""
    return (sigma if np.isscalar(sigma) else np.asarray(sigma, dtype=float)) * rng.standard_normal(shape)


#: Seconds of log simulated at a time: bounds memory for logs of any length; logs up to this long are one
#: piece, drawn from ``default_rng(seed)`` as a whole (piece k > 0 of a longer log uses ``default_rng([seed, k])``).
PIECE_S = 300.0

STREAMS = ("imu", "odom", "mag", "detections", "mocap")


@dataclass(frozen=True)
class _Carry:
    """What a piece hands to the next: last record time per stream, the odometry dead-reckoning state."""

    rec: dict[str, int]
    odom: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float] | None  # R, P, angular, linear, t (s)


@dataclass(frozen=True)
class Simulation:
    """A seeded simulation, generated in pieces of ``PIECE_S`` seconds (:meth:`pieces`) so that a log of any
    length is written without holding it in memory; :meth:`whole` is the same data in one :class:`SimLog`."""

    scenario: Scenario
    duration: float
    seed: int
    noise: NoiseModel
    rates: dict[str, float]  # stream -> Hz
    start_ns: int = EPOCH_NS
    piece_s: float = PIECE_S
    camera: CameraSim = CameraSim()
    #: Added to the detections' stamps (and record times): a detection stream off the velocity clock.
    detection_offset_ns: int = 0
    #: What each IMU and odometry sample is (:data:`SAMPLINGS`, :func:`_motion`).
    sampling: str = "instant"

    @property
    def counts(self) -> dict[str, int]:
        """Samples per stream over the whole log."""
        return {k: _count(self.duration, self.rates[k], _PHASE[k]) for k in STREAMS}

    def topic_counts(self) -> dict[str, int]:
        """Messages per topic, as they will be written."""
        c = self.counts
        return camera_topics(
            {
                TOPIC_TF_STATIC: 1,
                TOPIC_TRUTH: 1,
                TOPIC_IMU: c["imu"],
                TOPIC_ODOM: c["odom"],
                TOPIC_MAG: c["mag"],
                TOPIC_DETECTIONS: c["detections"],
                TOPIC_MOCAP: c["mocap"],
            },
            self.camera,
        )

    def _bounds(self, stream: str) -> np.ndarray:
        """First sample index of every piece of ``stream`` (and the total count at the end)."""
        n = self.counts[stream]
        pieces = max(1, int(np.ceil(self.duration / self.piece_s - 1e-9)))
        rate, phase = self.rates[stream], _PHASE[stream]
        cuts = [min(n, max(0, int(np.ceil((k * self.piece_s - phase) * rate - 1e-9)))) for k in range(1, pieces)]
        return np.array([0, *cuts, n], dtype=np.int64)

    def pieces(self) -> Iterator[SimLog]:
        """The log in consecutive pieces (message indices continue across pieces: ``SimLog.first``)."""
        bounds = {k: self._bounds(k) for k in STREAMS}
        carry = _Carry(dict.fromkeys(STREAMS, np.iinfo(np.int64).min), None)
        for k in range(len(bounds["imu"]) - 1):
            rng = np.random.default_rng(self.seed if k == 0 else [self.seed, k])
            span = {name: (int(b[k]), int(b[k + 1])) for name, b in bounds.items()}
            piece, carry = _piece(self, rng, span, carry)
            yield piece

    def whole(self) -> SimLog:
        """Every piece joined into one SimLog."""
        parts = list(self.pieces())
        if len(parts) == 1:
            return parts[0]
        join = lambda name: _join([getattr(p, name) for p in parts])  # noqa: E731
        camera = _join_camera([p.camera for p in parts]) if parts[0].camera is not None else None
        return replace(
            parts[0],
            imu=join("imu"),
            odom=join("odom"),
            mag=join("mag"),
            detections=_join_detections([p.detections for p in parts]),
            mocap=join("mocap"),
            camera=camera,
        )


def _join(parts: list) -> object:
    """Stream data of consecutive pieces concatenated field by field."""
    return type(parts[0])(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(parts[0])))


def camera_topics(counts: dict[str, int], cam: CameraSim) -> dict[str, int]:
    """Per-topic message counts with the detection topic replaced by the camera's topics (corners or images)."""
    if cam.output == "fiducials":
        return counts
    n = counts.pop(TOPIC_DETECTIONS)
    out = {}
    for topic, count in counts.items():
        out[topic] = count
        if topic == TOPIC_MAG:  # camera topics where the detections were, in the same order every time
            out[camera_topic(cam)] = n
            out[TOPIC_CAMERA_INFO] = n
    return out


def camera_topic(cam: CameraSim) -> str:
    """The topic the simulated camera reports tags on."""
    if cam.output == "corners":
        return TOPIC_TAGS
    return TOPIC_IMAGE if cam.jpeg_quality is None else TOPIC_IMAGE_JPEG


def _join_detections(parts: list[DetectionData]) -> DetectionData:
    shifts = np.cumsum([0] + [int(p.offsets[-1]) for p in parts[:-1]])
    offsets = np.concatenate([[0]] + [p.offsets[1:] + s for p, s in zip(parts, shifts)])
    fields = {
        f.name: np.concatenate([getattr(p, f.name) for p in parts])
        for f in dataclasses.fields(DetectionData)
        if f.name != "offsets"
    }
    return DetectionData(**{**fields, "offsets": offsets.astype(np.int64)})


def _join_camera(parts: list[CameraData]) -> CameraData:
    shifts = np.cumsum([0] + [int(p.offsets[-1]) for p in parts[:-1]])
    offsets = np.concatenate([[0]] + [p.offsets[1:] + s for p, s in zip(parts, shifts)])
    fields = {
        f.name: np.concatenate([getattr(p, f.name) for p in parts])
        for f in dataclasses.fields(CameraData)
        if f.name != "offsets"
    }
    return CameraData(**{**fields, "offsets": offsets.astype(np.int64)})


def simulation(
    scenario: Scenario | str,
    *,
    duration: float | None = None,
    seed: int = 0,
    noise: bool | NoiseModel = True,
    imu_rate: float = 200.0,
    odom_rate: float = 50.0,
    mag_rate: float = 50.0,
    detection_rate: float | None = None,
    mocap_rate: float = 100.0,
    start_ns: int = EPOCH_NS,
    camera: CameraSim | None = None,
    detection_offset: float = 0.0,
    sampling: str = "instant",
) -> Simulation:
    """Every sensor stream of ``scenario`` (name or object) for ``duration`` seconds, to be generated.

    ``noise`` is ``True`` (default :class:`NoiseModel`), ``False`` (exact measurements, biases kept) or a
    custom model. ``detection_rate`` defaults to the scenario's. ``camera`` makes the camera report tag corners
    or images (with CameraInfo) instead of fiducial poses (:mod:`pipeline.simulate.camera`); without noise the
    corners are exact and the images clean (no pixel noise, blur or JPEG). ``detection_offset`` (seconds) is
    added to the detections' stamps: they are seen at the true time but stamped off the velocity clock.
    ``sampling`` is what each IMU and odometry sample is (:data:`SAMPLINGS`): ``"instant"`` the motion at its stamp,
    ``"mean"`` the mean over the sample interval before it (:func:`_motion`).
    """
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    duration = sc.duration if duration is None else float(duration)
    if duration <= 0:
        raise ValueError(f"duration must be positive, got {duration}")
    nm = noise if isinstance(noise, NoiseModel) else (NoiseModel() if noise else NoiseModel.zero())
    rates = {
        "imu": imu_rate,
        "odom": odom_rate,
        "mag": mag_rate,
        "mocap": mocap_rate,
        "detections": sc.detection_rate if detection_rate is None else detection_rate,
    }
    for rate in rates.values():
        if rate <= 0:
            raise ValueError(f"rate must be positive, got {rate}")
    cam = camera or CameraSim()
    if nm == NoiseModel.zero() and cam.output != "fiducials":
        cam = replace(cam, pixel_noise=0.0, image_noise=0.0, blur=0.0, jpeg_quality=None)
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {', '.join(SAMPLINGS)}, got {sampling!r}")
    offset_ns = int(round(detection_offset * 1e9))
    return Simulation(
        sc, duration, int(seed), nm, rates, start_ns, camera=cam, detection_offset_ns=offset_ns, sampling=sampling
    )


def simulate(scenario: Scenario | str, **kwargs) -> SimLog:
    """:func:`simulation` (same arguments) generated into one :class:`SimLog` (for logs that fit in memory)."""
    return simulation(scenario, **kwargs).whole()


def _piece(
    sim: Simulation, rng: np.random.Generator, span: dict[str, tuple[int, int]], carry: _Carry
) -> tuple[SimLog, _Carry]:
    """Samples ``span[stream]`` of every stream, drawn from ``rng``, continuing from ``carry``."""
    sc, nm, start_ns = sim.scenario, sim.noise, sim.start_ns

    def stamps(name: str) -> tuple[np.ndarray, np.ndarray]:
        return _stamps(*span[name], sim.rates[name], _PHASE[name], start_ns)

    # one generator: the streams draw in this order (imu, odom, mag, detections, mocap), or the noise changes
    imu = _imu(sc, rng, nm, *stamps("imu"), carry.rec["imu"], _period(sim, "imu"))
    odom, odom_carry = _odom(sc, rng, nm, *stamps("odom"), carry, sim.seed, _period(sim, "odom"))
    mag = _mag(sc, rng, nm, *stamps("mag"), carry.rec["mag"])
    detections = _detections(sc, rng, nm, *stamps("detections"), carry.rec["detections"])
    camera = _camera(sim, detections) if sim.camera.output != "fiducials" else None
    if sim.detection_offset_ns:
        off = sim.detection_offset_ns
        detections = replace(detections, t_ns=detections.t_ns + off, rec_ns=detections.rec_ns + off)
    mocap = _mocap(sc, rng, *stamps("mocap"), carry.rec["mocap"])
    piece = SimLog(
        sc.name,
        int(sim.seed),
        nm,
        sim.duration,
        start_ns,
        imu,
        odom,
        mag,
        detections,
        mocap,
        _static_tf(sc),
        _truth(sim, camera is not None),
        first={name: lo for name, (lo, _) in span.items()},
        camera=camera,
        camera_sim=sim.camera,
    )
    streams = {"imu": imu, "odom": odom, "mag": mag, "detections": detections, "mocap": mocap}
    rec = {name: int(d.rec_ns[-1]) if d.rec_ns.size else carry.rec[name] for name, d in streams.items()}
    return piece, _Carry(rec, odom_carry)


#: What a low-rate sample may be: the motion at its stamp (what a gyro or wheel encoder read at that instant
#: gives), or the mean over the sample interval before it (a downsampled or integrated stream: a VIO's twist may be
#: one). An odometry read as such is restamped to its intervals' midpoints (docs/benchmarks.md, h-meanoffset2).
SAMPLINGS = ("instant", "mean")
#: Points of the midpoint rule an interval mean is taken over.
MEAN_POINTS = 8


def _period(sim: Simulation, stream: str) -> float:
    """The interval a ``"mean"`` sample of ``stream`` averages over (s); 0 for instantaneous samples."""
    return 1.0 / sim.rates[stream] if sim.sampling == "mean" else 0.0


def _motion(sc: Scenario, t: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The body-frame angular velocity, linear velocity and specific force ``Rᵀ (a − g)`` (each (N, 3)) a sample
    stamped at ``t`` reads: at ``t`` (``period`` 0), or their mean over ``(t − period, t]`` (``MEAN_POINTS``
    midpoints)."""
    if period <= 0.0:
        tr = sc.sample(t)
        return tr.omega, tr.v, np.einsum("nji,nj->ni", tr.R, tr.accel - GRAVITY)
    parts = [_motion(sc, t - period * (j + 0.5) / MEAN_POINTS, 0.0) for j in range(MEAN_POINTS)]
    return tuple(sum(p[i] for p in parts) / MEAN_POINTS for i in range(3))


def _imu(
    sc: Scenario,
    rng: np.random.Generator,
    nm: NoiseModel,
    t_ns: np.ndarray,
    t: np.ndarray,
    rec_after: int,
    period: float = 0.0,
) -> ImuData:
    """IMU: biased gyro and specific force f = R^T (a - g), in the imu_link frame (each sample the motion at its
    stamp, or with ``period`` its mean over that interval before it: :func:`_motion`)."""
    omega, _, f_body = _motion(sc, t, period)
    n = t.shape[0]
    gyro = omega + sc.gyro_bias + _white(rng, nm.gyro, (n, 3))
    accel = f_body + _white(rng, nm.accel, (n, 3))
    if sc.imu_rotation is not None:  # body-frame quantities seen from the turned imu_link: R_biᵀ x
        gyro, accel = gyro @ sc.imu_rotation, accel @ sc.imu_rotation
    return ImuData(t_ns, _record_times(rng, t_ns, rec_after), gyro, accel)


def _odom(
    sc: Scenario,
    rng: np.random.Generator,
    nm: NoiseModel,
    t_ns: np.ndarray,
    t: np.ndarray,
    carry: _Carry,
    seed: int = 0,
    period: float = 0.0,
) -> tuple[OdomData, tuple | None]:
    """Wheel odometry: biased velocity, unbiased rate, pose dead-reckoned from the measured twist (continuing
    from the previous piece's last sample); the data and the dead-reckoning state for the next piece. Each twist
    is the motion at its stamp, held until the next in the dead reckoning, or with ``period`` its mean over that
    interval before the stamp (:func:`_motion`), which the dead reckoning holds over that interval (an integrating
    odometry: the twist is the increment it reports)."""
    omega, v, _ = _motion(sc, t, period)
    n = t.shape[0]
    lin = v + sc.velocity_bias + _white(rng, nm.odom_linear, (n, 3))
    if nm.odom_linear_drift > 0.0:
        lin += _drift(seed, nm.odom_linear_drift, nm.odom_linear_drift_s, t)
    ang = omega + _white(rng, nm.odom_angular, (n, 3))
    lead = 1 if period > 0.0 else 0  # the interval before each stamp, or after it
    if carry.odom is None:
        rs, ps = integrate_body_twists(
            np.eye(3), np.zeros(3), ang[lead : n - 1 + lead], lin[lead : n - 1 + lead], np.diff(t)
        )
    else:  # continue from the last sample of the previous piece
        r0, p0, ang0, lin0, t0 = carry.odom
        held_ang, held_lin = (ang, lin) if lead else (np.vstack([ang0, ang[:-1]]), np.vstack([lin0, lin[:-1]]))
        rs, ps = integrate_body_twists(r0, p0, held_ang, held_lin, np.diff(np.concatenate([[t0], t])))
        rs, ps = rs[1:], ps[1:]
    odom = OdomData(t_ns, _record_times(rng, t_ns, carry.rec["odom"]), lin, ang, ps, rots_to_quats(rs))
    odom_carry = (rs[-1].copy(), ps[-1].copy(), ang[-1:].copy(), lin[-1:].copy(), float(t[-1])) if n else carry.odom
    return odom, odom_carry


#: Sinusoids per axis of the slowly varying velocity error (:func:`_drift`).
DRIFT_TERMS = 12


def _drift(seed: int, rms: float, scale_s: float, t: np.ndarray) -> np.ndarray:
    """A slowly varying error (n, 3) at times ``t``: per axis ``DRIFT_TERMS`` sinusoids of random phase whose
    angular frequencies spread log-uniformly over a factor of 20 around ``1/scale_s``, RMS ``rms``. A function of
    time from its own generator (``seed``): the pieces of a long log join, and the noise stream is untouched."""
    g = np.random.default_rng([int(seed), 7919])
    freq = np.exp(g.uniform(np.log(0.22), np.log(4.5), (DRIFT_TERMS, 3))) / scale_s
    phase = g.uniform(0.0, 2.0 * np.pi, (DRIFT_TERMS, 3))
    waves = np.sin(t[:, None, None] * freq[None] + phase[None])  # (n, terms, 3)
    return rms * np.sqrt(2.0 / DRIFT_TERMS) * waves.sum(axis=1)


def _mag(
    sc: Scenario, rng: np.random.Generator, nm: NoiseModel, t_ns: np.ndarray, t: np.ndarray, rec_after: int
) -> MagData:
    """Magnetometer: the inertial field seen in the body frame (the imu_link's when it is turned)."""
    tr = sc.sample(t)
    fld = np.einsum("nji,j->ni", tr.R, MAGNETIC_FIELD) + _white(rng, nm.mag, (t.shape[0], 3))
    if sc.imu_rotation is not None:
        fld = fld @ sc.imu_rotation
    return MagData(t_ns, _record_times(rng, t_ns, rec_after), fld)


def _mocap(sc: Scenario, rng: np.random.Generator, t_ns: np.ndarray, t: np.ndarray, rec_after: int) -> PoseData:
    """Motion capture: the true body pose, noise-free (only the record times draw from ``rng``)."""
    tr = sc.sample(t)
    return PoseData(t_ns, _record_times(rng, t_ns, rec_after), tr.P.copy(), rots_to_quats(np.ascontiguousarray(tr.R)))


def _static_tf(sc: Scenario) -> list[Transform]:
    """The fixed extrinsics: body to camera, body to imu_link (identity unless the scenario turns the IMU)."""
    cam_q = rots_to_quats(np.ascontiguousarray(sc.camera.R_bc[None]))[0]
    return [
        Transform(FRAME_BODY, FRAME_CAMERA, sc.camera.t_bc.copy(), cam_q),
        Transform(
            FRAME_BODY,
            FRAME_IMU,
            np.zeros(3),
            np.array([0.0, 0.0, 0.0, 1.0])
            if sc.imu_rotation is None
            else rots_to_quats(np.ascontiguousarray(sc.imu_rotation[None], dtype=np.float64))[0],
        ),
    ]


def _truth(sim: Simulation, with_camera: bool) -> dict:
    """The ground truth written into the log (landmarks, biases, fields, odom origin, seed, tag geometry)."""
    sc = sim.scenario
    tr0 = sc.sample(np.zeros(1))
    truth = {
        "frame_id": FRAME_WORLD,
        "scenario": sc.name,
        "landmarks": {str(int(i)): [float(c) for c in p] for i, p in zip(sc.landmark_ids, sc.landmarks)},
        "gyro_bias": [float(c) for c in sc.gyro_bias],
        "velocity_bias": [float(c) for c in sc.velocity_bias],
        "gravity": [float(c) for c in GRAVITY],
        "magnetic_field": [float(c) for c in MAGNETIC_FIELD],
        "odom_origin": {  # pose of the odom frame in the world frame (the true start pose)
            "translation": [float(c) for c in tr0.P[0]],
            "quat_xyzw": [float(c) for c in rots_to_quats(np.ascontiguousarray(tr0.R))[0]],
        },
        "seed": int(sim.seed),
        "noise": sim.noise != NoiseModel.zero(),
        "duration_s": sim.duration,
    }
    if with_camera:
        truth["tag_size"] = sim.camera.tag_size
        truth["tag_family"] = sim.camera.family
    return truth


def _detections(
    sc: Scenario, rng: np.random.Generator, nm: NoiseModel, t_ns: np.ndarray, t: np.ndarray, rec_after: int
) -> DetectionData:
    """Fiducial detections: visible landmarks in the camera frame with range-dependent noise."""
    tr = sc.sample(t)
    y_cam = camera_points(sc.camera, body_points(tr.R, tr.P, sc.landmarks))  # (F, L, 3)
    vis = visibility(sc.camera, y_cam)
    if sc.detections_until is not None:  # the landmarks have left view: empty detection messages
        vis &= (t <= sc.detections_until)[:, None]
    for lo, hi in sc.detection_gaps:  # the camera sees nothing (dark, covered, its driver stalled)
        vis &= ((t < lo) | (t >= hi))[:, None]
    if sc.hidden_until:  # landmarks first seen late (behind a door, put up during the run)
        late = dict(sc.hidden_until)
        hide = np.array([late.get(int(i), -np.inf) for i in sc.landmark_ids])
        vis &= t[:, None] >= hide[None, :]
    frame_idx, lm_idx = np.nonzero(vis)  # row-major: frames in order, landmarks in map order
    m = frame_idx.shape[0]
    offsets = np.zeros(t.shape[0] + 1, dtype=np.int64)
    offsets[1:] = np.cumsum(vis.sum(axis=1))

    true_xyz = y_cam[frame_idx, lm_idx]
    rng_m = np.linalg.norm(true_xyz, axis=1)
    draws = rng.standard_normal((m, 3))
    if nm.stereo_pixel > 0.0:
        xyz, seen = stereo_points(true_xyz, draws, nm.stereo_pixel, nm.stereo_focal, nm.stereo_baseline)
    else:
        sigma = nm.detection_base + nm.detection_per_m * rng_m
        if nm.detection_per_m2:
            sigma = sigma + nm.detection_per_m2 * rng_m * rng_m
        xyz, seen = true_xyz + sigma[:, None] * draws, None

    # Tag orientation in the camera frame: R_bc^T R^T R_tag, perturbed by a small rotation.
    r_bt = np.einsum("mji,mjk->mik", tr.R[frame_idx], sc.landmark_rots[lm_idx])
    r_ct = np.einsum("ji,mjk->mik", sc.camera.R_bc, r_bt)
    rot_noise = _white(rng, nm.tag_rotation, (m, 3))
    if nm.tag_rotation > 0 and m:
        r_ct = np.einsum("mij,mjk->mik", r_ct, so3_exps(rot_noise))
    quats = rots_to_quats(np.ascontiguousarray(r_ct)) if m else np.zeros((0, 4))

    depth = np.maximum(true_xyz[:, 2], 0.1) if m else np.zeros(0)
    area = (_FOCAL_PX * _TAG_SIZE_M / depth) ** 2
    jitter = np.abs(1.0 + 0.3 * rng.standard_normal(m))
    if nm.detection_base == 0.0:
        jitter = np.ones(m)
    image_error = (0.05 + 0.02 * rng_m) * jitter
    object_error = 1e-3 * rng_m * rng_m * jitter
    ids = sc.landmark_ids[lm_idx].copy()
    rec_ns = _record_times(rng, t_ns, rec_after)
    if (nm.wrong_id > 0.0 or nm.absurd_range > 0.0) and m:
        ids, xyz = _outliers(nm, sc.landmark_ids, ids, xyz, int(t_ns[0]))
    if seen is not None:  # stereo points not triangulated: left out of their frames (every draw above is kept)
        offsets[1:] = np.cumsum(np.bincount(frame_idx[seen], minlength=t.shape[0]))
        ids, xyz, quats = ids[seen], xyz[seen], quats[seen]
        image_error, object_error, area = image_error[seen], object_error[seen], area[seen]
    return DetectionData(t_ns, rec_ns, offsets, ids, xyz, quats, image_error, object_error, area)


def _outliers(
    nm: NoiseModel, known: np.ndarray, ids: np.ndarray, xyz: np.ndarray, stamp: int
) -> tuple[np.ndarray, np.ndarray]:
    """``ids`` with a share ``nm.wrong_id`` swapped for another landmark's and ``xyz`` with a share
    ``nm.absurd_range`` scaled 5-50x along its ray, drawn from a generator of their own (keyed by the piece's first
    stamp) so the other draws stay as without them."""
    rng = np.random.default_rng([stamp & 0x7FFFFFFF, 23])
    ids, xyz = ids.copy(), xyz.copy()
    wrong = np.flatnonzero(rng.random(ids.size) < nm.wrong_id)
    if known.size > 1:
        shift = rng.integers(1, known.size, wrong.size)
        pos = np.searchsorted(np.sort(known), ids[wrong])
        ids[wrong] = np.sort(known)[(pos + shift) % known.size]
    far = np.flatnonzero(rng.random(ids.size) < nm.absurd_range)
    xyz[far] *= rng.uniform(5.0, 50.0, far.size)[:, None]
    return ids, xyz


def stereo_points(
    true_xyz: np.ndarray, draws: np.ndarray, pixel: float, focal: float, baseline: float
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (M, 3) triangulated from a rectified stereo pair that sees ``true_xyz`` with pixel noise
    ``pixel`` · ``draws`` (M, 3: left u, right u, v; v is the mean of the two images' rows, so its noise is
    ``pixel/√2``), and which points are triangulated at all (in front of the camera, noisy disparity above
    ``2 · pixel``). Depth ``z = f b / d`` from the disparity ``d``; the others scale the left pixel by ``z / f``."""
    x, y, z = true_xyz.T
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    ul = focal * x / zs + pixel * draws[:, 0]
    ur = focal * (x - baseline) / zs + pixel * draws[:, 1]
    v = focal * y / zs + pixel * draws[:, 2] / np.sqrt(2.0)
    disparity = ul - ur
    seen = front & (disparity > 2.0 * pixel)
    depth = focal * baseline / np.where(seen, disparity, 1.0)
    xyz = np.stack([ul * depth / focal, v * depth / focal, depth], axis=1)
    return np.where(seen[:, None], xyz, true_xyz), seen


def _camera(sim: Simulation, det: DetectionData) -> CameraData:
    """The camera frames on the detection stamps: pose, visible tags and their corners (noisy for ``corners``).

    Corner noise is drawn from a generator of its own (seeded by the seed and the first frame), so the other
    streams are the same whatever the camera reports.
    """
    sc, cam = sim.scenario, sim.camera
    t = (det.t_ns - sim.start_ns).astype(np.float64) * 1e-9
    tr = sc.sample(t)
    r_wc = np.einsum("fij,jk->fik", tr.R, sc.camera.R_bc)
    t_wc = tr.P + np.einsum("fij,j->fi", tr.R, sc.camera.t_bc)
    views = tag_views(cam, r_wc, t_wc, sc.landmarks, sc.landmark_rots, sc.camera.max_range)
    corners = views.corners
    if cam.output == "corners" and cam.pixel_noise > 0 and corners.size:
        first = int(np.round(t[0] * 1e3)) if t.size else 0
        noise = np.random.default_rng([sim.seed, 7, first]).normal(0.0, cam.pixel_noise, corners.shape)
        corners = corners + noise
    return CameraData(det.t_ns, det.rec_ns, r_wc, t_wc, views.offsets, sc.landmark_ids[views.lm_idx].copy(), corners)


def expected_streams(sim: SimLog, path: str = "") -> LogStreams:
    """What a reader should extract from a written simulated log (the natural role mapping).

    Angular velocity from the IMU gyro, linear velocity from the odometry twist, truth from motion capture,
    landmark and bias truth from ``/slamobs/sim_truth``. Meant for reader tests.
    """
    det, moc = sim.detections, sim.mocap
    return LogStreams(
        path=str(path),
        angular_velocity=Vec3Stream(TOPIC_IMU, FRAME_IMU, sim.imu.t_ns, sim.imu.rec_ns, sim.imu.gyro),
        linear_velocity=Vec3Stream(TOPIC_ODOM, FRAME_BODY, sim.odom.t_ns, sim.odom.rec_ns, sim.odom.linear),
        detections=DetectionStream(TOPIC_DETECTIONS, FRAME_CAMERA, det.t_ns, det.rec_ns, det.offsets, det.ids, det.xyz),
        truth=PoseStream(TOPIC_MOCAP, FRAME_WORLD, "", moc.t_ns, moc.rec_ns, moc.position, moc.quat_xyzw),
        accel=Vec3Stream(TOPIC_IMU, FRAME_IMU, sim.imu.t_ns, sim.imu.rec_ns, sim.imu.accel),
        magnetic=Vec3Stream(TOPIC_MAG, FRAME_IMU, sim.mag.t_ns, sim.mag.rec_ns, sim.mag.field),
        twist_angular=Vec3Stream(TOPIC_ODOM, FRAME_BODY, sim.odom.t_ns, sim.odom.rec_ns, sim.odom.angular),
        static_tf=list(sim.static_tf),
        landmark_truth={int(k): np.asarray(v, dtype=float) for k, v in sim.truth["landmarks"].items()},
        bias_truth={
            "gyro": np.asarray(sim.truth["gyro_bias"], dtype=float),
            "velocity": np.asarray(sim.truth["velocity_bias"], dtype=float),
        },
    )
