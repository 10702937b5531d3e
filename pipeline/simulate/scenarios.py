"""True trajectories, landmark maps and camera placements of the simulated scenarios.

Everything here is noise-free and analytic: a scenario is a pure function of time, so sensors can sample
it at any rate and the kinematics (``dR/dt = R [Omega]x``, ``dP/dt = R V``) hold exactly, which is what
the observers' convergence claims are checked against. Body frame: x forward, y left, z up; camera frame:
ROS optical convention (z along the optical axis, x right, y down).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

GRAVITY = np.array([0.0, 0.0, -9.81])  # inertial-frame gravity, m/s^2
MAGNETIC_FIELD = np.array([0.2, 0.0, -0.45]) * 1e-4  # inertial-frame Earth field, Tesla


@dataclass(frozen=True)
class Trajectory:
    """Body pose and its exact derivatives at times ``t`` (seconds from the scenario start)."""

    t: np.ndarray  # (N,)
    R: np.ndarray  # (N, 3, 3) body -> inertial
    P: np.ndarray  # (N, 3) body origin in the inertial frame
    omega: np.ndarray  # (N, 3) body-frame angular velocity
    v: np.ndarray  # (N, 3) body-frame linear velocity
    accel: np.ndarray  # (N, 3) inertial-frame acceleration d^2P/dt^2


@dataclass(frozen=True)
class Camera:
    """Camera extrinsic (camera -> body: ``y_body = R_bc y_cam + t_bc``) and field of view.

    ``fov_h_deg``/``fov_v_deg``/``max_range`` of ``None`` mean unlimited (the paper's all-seeing camera).
    """

    R_bc: np.ndarray  # (3, 3)
    t_bc: np.ndarray  # (3,)
    fov_h_deg: float | None = None
    fov_v_deg: float | None = None
    min_range: float = 0.0
    max_range: float | None = None


@dataclass(frozen=True)
class Scenario:
    """A named trajectory with its landmark map, sensor biases and camera."""

    name: str
    duration: float  # default duration, s
    trajectory: Callable[[np.ndarray], Trajectory]
    landmark_ids: np.ndarray  # (L,) int64, not necessarily contiguous
    landmarks: np.ndarray  # (L, 3) inertial positions
    landmark_rots: np.ndarray  # (L, 3, 3) tag orientation (tag -> inertial), z = tag normal
    gyro_bias: np.ndarray  # (3,) body frame, rad/s
    velocity_bias: np.ndarray  # (3,) body frame, m/s
    camera: Camera
    detection_rate: float  # default fiducial detection rate, Hz
    #: Seconds after which the camera detects nothing (landmarks leave view for good); None = never.
    detections_until: float | None = None
    #: IMU mounting (imu_link -> body rotation, published on /tf_static); None = aligned with the body.
    imu_rotation: np.ndarray | None = None
    #: (start, stop) s spans in which the camera detects nothing; empty = none.
    detection_gaps: tuple[tuple[float, float], ...] = ()
    #: (landmark id, seconds before which it is never detected): landmarks first seen late; empty = none.
    hidden_until: tuple[tuple[int, float], ...] = ()

    def sample(self, t: np.ndarray) -> Trajectory:
        """True state at times ``t`` (s since start)."""
        return self.trajectory(np.asarray(t, dtype=float))


def rot_x(a: np.ndarray) -> np.ndarray:
    """Stack of rotations about x by angles ``a`` (N,) -> (N, 3, 3)."""
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(a: np.ndarray) -> np.ndarray:
    """Stack of rotations about y by angles ``a`` (N,) -> (N, 3, 3)."""
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(a: np.ndarray) -> np.ndarray:
    """Stack of rotations about z by angles ``a`` (N,) -> (N, 3, 3)."""
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


# ------------------------------------------------- circle (the fast-adaptation paper's simulation scenario)

CIRCLE_OMEGA = np.array([0.0, 0.0, 0.3])
CIRCLE_V = np.array([2.5, 0.0, 0.0])
CIRCLE_P0 = np.array([0.0, 0.0, 6.0])


def circle_trajectory(t: np.ndarray) -> Trajectory:
    """Constant twist: R = Rz(0.3 t), a horizontal circle of radius 2.5/0.3 m at height 6 m."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    wz, speed = CIRCLE_OMEGA[2], CIRCLE_V[0]
    psi = wz * t
    radius = speed / wz
    P = np.stack([radius * np.sin(psi), radius * (1.0 - np.cos(psi)), np.zeros_like(t)], -1) + CIRCLE_P0
    accel = speed * wz * np.stack([-np.sin(psi), np.cos(psi), np.zeros_like(t)], -1)
    n = t.shape[0]
    return Trajectory(t, rot_z(psi), P, np.tile(CIRCLE_OMEGA, (n, 1)), np.tile(CIRCLE_V, (n, 1)), accel)


def circle() -> Scenario:
    """The paper scenario: four ground landmarks, camera looking straight down, sees everything."""
    ids = np.array([1, 2, 3, 4], dtype=np.int64)
    lms = np.array([[7.0, 7.0, 0.0], [-7.0, 7.0, 0.0], [7.0, -7.0, 0.0], [-7.0, -7.0, 0.0]])
    # Optical axis = -z_body, image x (right) = -y_body, image y (down) = -x_body.
    r_bc = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    cam = Camera(R_bc=r_bc, t_bc=np.array([0.1, 0.0, -0.05]))
    return Scenario(
        name="circle",
        duration=30.0,
        trajectory=circle_trajectory,
        landmark_ids=ids,
        landmarks=lms,
        landmark_rots=np.tile(np.eye(3), (4, 1, 1)),
        gyro_bias=np.array([0.09, -0.15, -0.1]),
        velocity_bias=np.array([0.09, 0.06, -0.07]),
        camera=cam,
        detection_rate=30.0,
    )


# --------------------------------------------------------------------------- figure 8

F8_A = 10.0  # x amplitude, m (y amplitude is A/2)
F8_W = 2.0 * np.pi / 30.0  # one figure 8 every 30 s: speed 1.4 .. 3.0 m/s
F8_H = 4.0  # mean height, m
F8_HZ = 0.5  # height oscillation amplitude, m
F8_ROLL = 0.06  # rad
F8_PITCH = 0.04  # rad

# Landmark table: id, x, y, z, kind (0 = on the ground facing up, 1 = on a wall facing the path centre).
_F8_LANDMARKS = np.array(
    [
        # ground, scattered around and inside both lobes
        [10, 4.0, 0.0, 0.0, 0],
        [11, -4.0, 0.5, 0.0, 0],
        [15, 9.0, 4.5, 0.0, 0],
        [17, 12.0, -2.0, 0.0, 0],
        [18, 6.0, -6.5, 0.0, 0],
        [21, -7.0, 6.0, 0.0, 0],
        [22, -12.5, 1.0, 0.0, 0],
        [23, -8.0, -5.0, 0.0, 0],
        [26, 0.5, -3.0, 0.0, 0],
        [27, -1.0, 3.5, 0.0, 0],
        [31, 6.5, 2.5, 0.0, 0],
        [33, -6.0, -1.5, 0.0, 0],
        [34, 13.5, 3.0, 0.0, 0],
        [36, -14.0, -3.5, 0.0, 0],
        [37, 11.0, -7.0, 0.0, 0],
        [38, -6.5, -8.0, 0.0, 0],
        # walls around the arena (x = +/-17, y = +/-10)
        [40, 17.0, -4.0, 1.5, 1],
        [41, 17.0, 1.0, 3.0, 1],
        [42, 17.0, 6.0, 2.0, 1],
        [44, -17.0, 4.0, 2.5, 1],
        [45, -17.0, -1.0, 1.0, 1],
        [47, -17.0, -6.0, 3.5, 1],
        [50, 8.0, 10.0, 2.0, 1],
        [52, 0.0, 10.0, 3.0, 1],
        [53, -9.0, 10.0, 1.5, 1],
        [55, 9.0, -10.0, 3.0, 1],
        [57, -1.0, -10.0, 2.0, 1],
        [58, -8.0, -10.0, 2.5, 1],
        [59, 14.0, -10.0, 1.0, 1],
        # a pillar in the middle of the arena
        [60, 0.0, 0.0, 2.0, 1],
    ]
)


def _wall_rotation(p: np.ndarray) -> np.ndarray:
    """Tag orientation on a vertical wall: normal (z) horizontal, pointing towards the arena centre."""
    n = -np.array([p[0], p[1], 0.0])
    if np.linalg.norm(n) < 1e-9:
        n = np.array([1.0, 0.0, 0.0])
    z = n / np.linalg.norm(n)
    x = np.cross(np.array([0.0, 0.0, 1.0]), z)
    y = np.cross(z, x)
    return np.stack([x, y, z], -1)


def figure8_trajectory(t: np.ndarray) -> Trajectory:
    """Lissajous figure 8 with heading along the path plus small roll/pitch and height oscillations.

    R = Rz(psi) Ry(pitch) Rx(roll); body Omega from the exact ZYX Euler-rate relation.
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    a, b, w, th = F8_A, 0.5 * F8_A, F8_W, F8_W * t
    x, xd, xdd = a * np.sin(th), a * w * np.cos(th), -a * w * w * np.sin(th)
    y, yd, ydd = b * np.sin(2 * th), 2 * b * w * np.cos(2 * th), -4 * b * w * w * np.sin(2 * th)
    z = F8_H + F8_HZ * np.sin(3 * th)
    zd = 3 * w * F8_HZ * np.cos(3 * th)
    zdd = -9 * w * w * F8_HZ * np.sin(3 * th)
    phi, phid = F8_ROLL * np.sin(2 * th), 2 * w * F8_ROLL * np.cos(2 * th)
    the, thed = F8_PITCH * np.sin(4 * th), 4 * w * F8_PITCH * np.cos(4 * th)
    return heading_along_path(t, (x, xd, xdd), (y, yd, ydd), (z, zd, zdd), (phi, phid), (the, thed))


def heading_along_path(t, xs, ys, zs, roll, pitch, yaw_off=None) -> Trajectory:
    """A path given by positions and their first two derivatives, yaw along the horizontal velocity (plus
    ``yaw_off``, an (angle, rate) wobble about it, when given) and the given roll and pitch (angle, rate):
    R = Rz(psi) Ry(pitch) Rx(roll), Omega from the exact ZYX Euler rates."""
    (x, xd, xdd), (y, yd, ydd), (z, zd, zdd) = xs, ys, zs
    (phi, phid), (the, thed) = roll, pitch
    psi = np.arctan2(yd, xd)
    psid = (xd * ydd - yd * xdd) / (xd * xd + yd * yd)
    if yaw_off is not None:
        psi, psid = psi + yaw_off[0], psid + yaw_off[1]

    R = rot_z(psi) @ rot_y(the) @ rot_x(phi)
    omega = np.stack(
        [
            phid - psid * np.sin(the),
            thed * np.cos(phi) + psid * np.cos(the) * np.sin(phi),
            -thed * np.sin(phi) + psid * np.cos(the) * np.cos(phi),
        ],
        -1,
    )
    pdot = np.stack([xd, yd, zd], -1)
    v = np.einsum("nji,nj->ni", R, pdot)
    return Trajectory(t, R, np.stack([x, y, z], -1), omega, v, np.stack([xdd, ydd, zdd], -1))


def figure8() -> Scenario:
    """Figure 8 among ground and wall tags; forward-down camera with a limited field of view."""
    ids = _F8_LANDMARKS[:, 0].astype(np.int64)
    lms = _F8_LANDMARKS[:, 1:4].copy()
    rots = np.stack([_wall_rotation(p) if k else np.eye(3) for p, k in zip(lms, _F8_LANDMARKS[:, 4])])
    # Forward-looking optical frame (z = x_body, x = -y_body, y = -z_body) pitched 30 deg down.
    tilt = np.deg2rad(30.0)
    z_c = np.array([np.cos(tilt), 0.0, -np.sin(tilt)])
    x_c = np.array([0.0, -1.0, 0.0])
    r_bc = np.stack([x_c, np.cross(z_c, x_c), z_c], -1)
    cam = Camera(
        R_bc=r_bc, t_bc=np.array([0.1, 0.0, -0.05]), fov_h_deg=100.0, fov_v_deg=75.0, min_range=0.5, max_range=15.0
    )
    return Scenario(
        name="figure8",
        duration=60.0,
        trajectory=figure8_trajectory,
        landmark_ids=ids,
        landmarks=lms,
        landmark_rots=rots,
        gyro_bias=np.array([0.02, -0.03, 0.05]),
        velocity_bias=np.array([0.05, -0.04, 0.02]),
        camera=cam,
        detection_rate=20.0,
    )


def figure8_wide() -> Scenario:
    """figure8 seen by a wider camera (120 x 90 deg, up to 18 m): about 8 of the 30 landmarks in view (4-13),
    the load of a typical fiducial log; used by the end-to-end benchmark."""
    sc = figure8()
    cam = replace(sc.camera, fov_h_deg=120.0, fov_v_deg=90.0, max_range=18.0)
    return replace(sc, name="figure8-wide", camera=cam)


def figure8_blind() -> Scenario:
    """figure8 for 90 s whose landmarks leave view after 40 s: 50 s of dead reckoning (IMU directions still
    there) with a map that is no longer observed."""
    return replace(figure8(), name="figure8-blind", duration=90.0, detections_until=40.0)


#: An IMU mounted upside down: imu_link is the body frame turned 180 deg about x (published on /tf_static).
IMU_FLIPPED = np.diag([1.0, -1.0, -1.0])


def figure8_imu_flipped() -> Scenario:
    """figure8 with the IMU mounted upside down (its own /tf_static entry): gyro, accelerometer and
    magnetometer are measured in the turned imu_link frame."""
    return replace(figure8(), name="figure8-imu-flipped", imu_rotation=IMU_FLIPPED)


# --------------------------------------------------------------------------- loop

LOOP_PERIOD = 90.0  # s per lap: two laps in the default 3 minutes
LOOP_A = 24.0  # m, x semi-axis
LOOP_B = 14.0  # m, y semi-axis
LOOP_WIGGLE = 2.0  # m, lateral weave (three per lap) so the turn rate varies
LOOP_H = 2.0  # m, mean height
LOOP_HZ = 0.3  # m, height oscillation
LOOP_ROLL = 0.05  # rad
LOOP_PITCH = 0.03  # rad
LOOP_LANDMARKS = 60
LOOP_FOV_DEG = 50.0


def loop_trajectory(t: np.ndarray) -> Trajectory:
    """An ellipse with a lateral weave, heading along the path, small roll/pitch and height oscillations."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    w = 2.0 * np.pi / LOOP_PERIOD
    th = w * t
    a, b, c = LOOP_A, LOOP_B, LOOP_WIGGLE
    x = a * np.sin(th) + c * np.sin(3 * th)
    xd = a * w * np.cos(th) + 3 * c * w * np.cos(3 * th)
    xdd = -a * w * w * np.sin(th) - 9 * c * w * w * np.sin(3 * th)
    y = b * (1.0 - np.cos(th))
    yd = b * w * np.sin(th)
    ydd = b * w * w * np.cos(th)
    z = LOOP_H + LOOP_HZ * np.sin(5 * th)
    zd = 5 * w * LOOP_HZ * np.cos(5 * th)
    zdd = -25 * w * w * LOOP_HZ * np.sin(5 * th)
    roll = (LOOP_ROLL * np.sin(4 * th), 4 * w * LOOP_ROLL * np.cos(4 * th))
    pitch = (LOOP_PITCH * np.sin(7 * th), 7 * w * LOOP_PITCH * np.cos(7 * th))
    return heading_along_path(t, (x, xd, xdd), (y, yd, ydd), (z, zd, zdd), roll, pitch)


def _forward_camera(tilt_deg: float, fov_h_deg: float, fov_v_deg: float, max_range: float) -> Camera:
    """Forward-looking optical frame (z = x_body, x = -y_body, y = -z_body) pitched ``tilt_deg`` down."""
    tilt = np.deg2rad(tilt_deg)
    z_c = np.array([np.cos(tilt), 0.0, -np.sin(tilt)])
    x_c = np.array([0.0, -1.0, 0.0])
    r_bc = np.stack([x_c, np.cross(z_c, x_c), z_c], -1)
    return Camera(
        R_bc=r_bc,
        t_bc=np.array([0.1, 0.0, -0.05]),
        fov_h_deg=fov_h_deg,
        fov_v_deg=fov_v_deg,
        min_range=0.5,
        max_range=max_range,
    )


def loop(n_landmarks: int = LOOP_LANDMARKS) -> Scenario:
    """Two 90 s laps of a weaving ellipse (semi-axes 24 m and 14 m) past ``n_landmarks`` tags set 1.5-5 m
    outside the path (heights 0-3 m, fixed layout), seen by a forward camera with a 50 deg field of view: 3-10
    landmarks in view at a time (about 6), each seen once per lap."""
    if n_landmarks < 3:
        raise ValueError(f"the loop needs at least 3 landmarks, got {n_landmarks}")
    rng = np.random.default_rng(20240612)  # the layout is part of the scenario, not of the noise seed
    th = 2.0 * np.pi * (np.arange(n_landmarks) + rng.uniform(-0.3, 0.3, n_landmarks)) / n_landmarks
    path = loop_trajectory(th / (2.0 * np.pi / LOOP_PERIOD))
    vel = np.einsum("nij,nj->ni", path.R, path.v)[:, :2]  # horizontal path direction
    vel /= np.linalg.norm(vel, axis=1, keepdims=True)
    normal = np.column_stack([-vel[:, 1], vel[:, 0], np.zeros(n_landmarks)])  # to the left of the path
    side = -rng.uniform(1.5, 5.0, n_landmarks)  # outside the loop: a narrow camera loses the inside of a turn
    lms = path.P + side[:, None] * normal
    lms[:, 2] = rng.uniform(0.0, 3.0, n_landmarks)
    cam = _forward_camera(10.0, LOOP_FOV_DEG, 0.8 * LOOP_FOV_DEG, 20.0)
    return Scenario(
        name="loop",
        duration=2.0 * LOOP_PERIOD,
        trajectory=loop_trajectory,
        landmark_ids=np.arange(100, 100 + n_landmarks, dtype=np.int64),
        landmarks=lms,
        landmark_rots=np.tile(np.eye(3), (n_landmarks, 1, 1)),
        gyro_bias=np.array([0.015, -0.02, 0.03]),
        velocity_bias=np.array([0.04, -0.03, 0.02]),
        camera=cam,
        detection_rate=20.0,
    )


# --------------------------------------------------------------------------- ground robot

GROUND_PERIOD = 80.0  # s per figure 8: 0.2-0.6 m/s
GROUND_A = 4.0  # m, x amplitude (y amplitude is A/2)
GROUND_H = 0.3  # m, body height above the floor
GROUND_WOBBLE = 0.015  # rad, roll and pitch on an uneven floor


def _ground_figure8(t) -> tuple:
    """The ground robot's figure 8 in the plane (ground, ground-hills): the times as an array, the phase's rate and
    the phase, and x and y with their first two derivatives."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    w = 2.0 * np.pi / GROUND_PERIOD
    th = w * t
    a, b = GROUND_A, 0.5 * GROUND_A
    xs = (a * np.sin(th), a * w * np.cos(th), -a * w * w * np.sin(th))
    ys = (b * np.sin(2 * th), 2 * b * w * np.cos(2 * th), -4 * b * w * w * np.sin(2 * th))
    return t, w, th, xs, ys


def ground_trajectory(t: np.ndarray) -> Trajectory:
    """A wheeled robot's figure 8 on a flat floor (fixed height) with a small roll/pitch wobble."""
    t, w, th, xs, ys = _ground_figure8(t)
    zero = np.zeros_like(t)
    zs = (zero + GROUND_H, zero, zero)
    roll = (GROUND_WOBBLE * np.sin(7.3 * th), 7.3 * w * GROUND_WOBBLE * np.cos(7.3 * th))
    pitch = (GROUND_WOBBLE * np.sin(11.1 * th), 11.1 * w * GROUND_WOBBLE * np.cos(11.1 * th))
    return heading_along_path(t, xs, ys, zs, roll, pitch)


def ground() -> Scenario:
    """A ground robot driving a 8 m x 4 m figure 8 at 0.2-0.6 m/s in a 12 m x 8 m room with 16 landmarks on its
    walls (0.4-2.2 m high), seen by a forward camera (tilted 10 deg up, 60 deg field of view, up to 5 m): 0-4
    landmarks in view, none for stretches of tens of seconds."""
    rng = np.random.default_rng(20261204)  # the layout is part of the scenario, not of the noise seed
    walls = [(np.array([x, -4.0]), np.array([x, 4.0])) for x in (-4.5, -1.5, 1.5, 4.5)]
    walls += [(np.array([-6.0, y]), np.array([6.0, y])) for y in (-2.0, 2.0)]
    lms = np.array([[*p, 0.0] for pair in walls for p in pair])
    lms[:, 2] = rng.uniform(0.4, 2.2, lms.shape[0])
    lms[:, :2] += rng.uniform(-0.3, 0.3, (lms.shape[0], 2))
    rots = np.stack([_wall_rotation(p) for p in lms])
    return Scenario(
        name="ground",
        duration=GROUND_PERIOD,
        trajectory=ground_trajectory,
        landmark_ids=np.arange(1, lms.shape[0] + 1, dtype=np.int64),
        landmarks=lms,
        landmark_rots=rots,
        gyro_bias=np.array([0.004, -0.006, 0.01]),
        velocity_bias=np.array([0.02, -0.01, 0.0]),
        camera=_forward_camera(-10.0, 60.0, 45.0, 5.0),
        detection_rate=15.0,
    )


GROUND_HILL = 0.25  # m, the hills' height on either side of the floor's (ground-hills)


def ground_hills_trajectory(t: np.ndarray) -> Trajectory:
    """The ground robot's figure 8 over hills, a floor that is no plane: its height ``GROUND_HILL`` times the sine of
    three times the figure's phase, the body pitched along the slope it drives on beside its roll wobble."""
    t, w, th, xs, ys = _ground_figure8(t)
    h = GROUND_HILL  # three hills a lap: no plane through the path (one would be, under a figure 8's x or y)
    zs = (GROUND_H + h * np.sin(3 * th), 3 * w * h * np.cos(3 * th), -9 * w * w * h * np.sin(3 * th))
    sh = np.hypot(xs[1], ys[1])  # the horizontal speed, and the slope u along the path
    u = zs[1] / sh
    ud = (zs[2] * sh - zs[1] * (xs[1] * xs[2] + ys[1] * ys[2]) / sh) / sh**2
    roll = (GROUND_WOBBLE * np.sin(7.3 * th), 7.3 * w * GROUND_WOBBLE * np.cos(7.3 * th))
    pitch = (-np.arctan(u), -ud / (1.0 + u * u))  # nose up while climbing
    return heading_along_path(t, xs, ys, zs, roll, pitch)


def ground_hills() -> Scenario:
    """The ground robot's room and camera (:func:`ground`), its figure 8 over hills (:func:`ground_hills_trajectory`):
    the floor batch and riekf hold on a ground robot is wrong here."""
    return replace(ground(), name="ground-hills", trajectory=ground_hills_trajectory)


def handheld_trajectory(tilt_deg: float, wobble: float, period: float = 60.0, a: float = 8.0, h: float = 1.5):
    """A walker's figure 8 (a x a/2 m at h m in ``period`` s) with a 1.8 Hz step bob of 4 cm, roll and pitch up to
    ``tilt_deg`` and 0.8 of it, and a yaw wobble of ``wobble`` rad at 0.6 Hz about the path (turn rates to 1.5
    rad/s): the motion a 3-5 Hz VIO twist does not resolve (docs/benchmarks.md, "Hand-held rigs with a slow VIO
    twist", session 32)."""
    w, tilt = 2 * np.pi / period, np.deg2rad(tilt_deg)
    fw, fr, fp, fb = 2 * np.pi * np.array([0.6, 0.23, 0.31, 1.8])

    def trajectory(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        th, b = w * t, a / 2
        x, xd, xdd = a * np.sin(th), a * w * np.cos(th), -a * w * w * np.sin(th)
        y, yd, ydd = b * np.sin(2 * th), 2 * b * w * np.cos(2 * th), -4 * b * w * w * np.sin(2 * th)
        z, zd, zdd = h + 0.04 * np.sin(fb * t), 0.04 * fb * np.cos(fb * t), -0.04 * fb * fb * np.sin(fb * t)
        phi, phid = tilt * np.sin(fr * t), tilt * fr * np.cos(fr * t)
        the, thed = 0.8 * tilt * np.sin(fp * t), 0.8 * tilt * fp * np.cos(fp * t)
        wob = (wobble * np.sin(fw * t), wobble * fw * np.cos(fw * t))
        return heading_along_path(t, (x, xd, xdd), (y, yd, ydd), (z, zd, zdd), (phi, phid), (the, thed), wob)

    return trajectory


def handheld(tilt_deg: float = 12.0, wobble: float = 0.3) -> Scenario:
    """figure8-wide's room walked by hand (:func:`handheld_trajectory`), the camera turned 10 deg, 9 cm off the
    body's origin and seeing to 8 m."""
    sc = figure8_wide()
    turn = rot_z(np.array([np.deg2rad(10.0)]))[0]
    cam = replace(sc.camera, R_bc=turn @ sc.camera.R_bc, t_bc=np.array([0.05, -0.08, 0.03]), max_range=8.0)
    return replace(sc, name="handheld", trajectory=handheld_trajectory(tilt_deg, wobble), camera=cam)


def flight_trajectory(period: float = 30.0, a: float = 10.0, h: float = 4.0):
    """A quadrotor's 3D figure 8 (a x a/2 m, 1.4-3 m/s) climbing and sinking 2 m (2.0-6.0 m high, 1.3 m/s
    vertical), banked up to 25 deg and pitched up to 15 deg, its yaw swinging 0.8 rad about the path at 0.2 Hz."""
    w, roll, pitch = 2 * np.pi / period, np.deg2rad(25.0), np.deg2rad(15.0)
    fy = 2 * np.pi * 0.2

    def trajectory(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        th, b = w * t, a / 2
        x, xd, xdd = a * np.sin(th), a * w * np.cos(th), -a * w * w * np.sin(th)
        y, yd, ydd = b * np.sin(2 * th), 2 * b * w * np.cos(2 * th), -4 * b * w * w * np.sin(2 * th)
        z, zd, zdd = h + 2.0 * np.sin(3 * th), 6.0 * w * np.cos(3 * th), -18.0 * w * w * np.sin(3 * th)
        phi, phid = roll * np.sin(2 * th), 2 * w * roll * np.cos(2 * th)
        the, thed = pitch * np.sin(5 * th), 5 * w * pitch * np.cos(5 * th)
        wob = (0.8 * np.sin(fy * t), 0.8 * fy * np.cos(fy * t))
        return heading_along_path(t, (x, xd, xdd), (y, yd, ydd), (z, zd, zdd), (phi, phid), (the, thed), wob)

    return trajectory


SCENARIOS: dict[str, Callable[[], Scenario]] = {
    "ground": ground,
    "ground-hills": ground_hills,
    "circle": circle,
    "figure8": figure8,
    "figure8-wide": figure8_wide,
    "figure8-blind": figure8_blind,
    "figure8-imu-flipped": figure8_imu_flipped,
    "loop": loop,
}


def get_scenario(name: str) -> Scenario:
    """Scenario by name; ``KeyError`` listing the known names otherwise."""
    try:
        return SCENARIOS[name]()
    except KeyError:
        raise KeyError(f"unknown scenario {name!r}; known: {', '.join(sorted(SCENARIOS))}") from None


def customize(
    sc: Scenario,
    *,
    landmarks: int | None = None,
    fov_deg: float | None = None,
    detections_until: float | None = None,
    imu_rpy_deg: tuple[float, float, float] | None = None,
    detection_gaps: tuple[tuple[float, float], ...] | None = None,
    first_seen: tuple[tuple[int, float], ...] | None = None,
) -> Scenario:
    """``sc`` with some of its rig changed (each option left at None keeps the scenario's value).

    ``landmarks``: the loop is rebuilt with that many tags; other scenarios keep an evenly spaced subset of
    their map. ``fov_deg``: horizontal field of view, the vertical one scaled in proportion (an unlimited
    camera gets a vertical field of view of 0.75 times it). ``detections_until``: nothing is detected after
    that many seconds. ``imu_rpy_deg``: IMU mounting as roll, pitch, yaw (imu_link -> body,
    R = Rz(yaw) Ry(pitch) Rx(roll)), published on /tf_static. ``detection_gaps``: (start, stop) s spans with no
    detections. ``first_seen``: (landmark id, s) pairs, each landmark never detected before that time.
    """
    if landmarks is not None:
        if sc.name.startswith("loop"):
            sc = replace(
                loop(landmarks),
                name=sc.name,
                duration=sc.duration,
                camera=sc.camera,
                detections_until=sc.detections_until,
                imu_rotation=sc.imu_rotation,
            )
        else:
            n = sc.landmark_ids.shape[0]
            if not 3 <= landmarks <= n:
                raise ValueError(f"scenario {sc.name!r} has {n} landmarks; choose 3 to {n}")
            keep = np.unique(np.round(np.linspace(0, n - 1, landmarks)).astype(int))
            sc = replace(
                sc,
                landmark_ids=sc.landmark_ids[keep],
                landmarks=sc.landmarks[keep],
                landmark_rots=sc.landmark_rots[keep],
            )
    if fov_deg is not None:
        if not 0.0 < fov_deg < 180.0:
            raise ValueError(f"field of view must be in (0, 180) deg, got {fov_deg}")
        cam = sc.camera
        ratio = cam.fov_v_deg / cam.fov_h_deg if cam.fov_h_deg and cam.fov_v_deg else 0.75
        sc = replace(sc, camera=replace(cam, fov_h_deg=float(fov_deg), fov_v_deg=float(fov_deg) * ratio))
    if detections_until is not None:
        sc = replace(sc, detections_until=float(detections_until))
    if imu_rpy_deg is not None:
        r, p, y = np.deg2rad(np.asarray(imu_rpy_deg, dtype=float))
        rot = (rot_z(np.array([y])) @ rot_y(np.array([p])) @ rot_x(np.array([r])))[0]
        sc = replace(sc, imu_rotation=rot)
    if detection_gaps is not None:
        gaps = tuple((float(lo), float(hi)) for lo, hi in detection_gaps)
        if any(hi <= lo for lo, hi in gaps):
            raise ValueError(f"each detection gap must end after it starts, got {gaps}")
        sc = replace(sc, detection_gaps=gaps)
    if first_seen is not None:
        unknown = sorted({int(i) for i, _ in first_seen} - set(sc.landmark_ids.tolist()))
        if unknown:
            raise ValueError(f"scenario {sc.name!r} has no landmarks {unknown}")
        sc = replace(sc, hidden_until=tuple((int(i), float(s)) for i, s in first_seen))
    return sc
