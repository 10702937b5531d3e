"""Inertial direction measurements (docs/observers.md §7): gravity from the accelerometer, the magnetic field.

An accelerometer measures specific force ``f = Rᵀ(a − g)``; only when the body acceleration ``a`` is known
does it give the direction of gravity. The body acceleration is estimated from the velocity stream
(``a_B = dV/dt + Ω × V``) and removed; samples whose corrected magnitude is still far from ``‖g‖`` (hard
manoeuvres, impacts, odometry slip) get weight 0, with a smooth ramp in between, so an observer can
down-weight them rather than be pulled by them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from slamobs.pipeline.kernel_cache import njit

from slamobs.pipeline.blocks import interp_sorted
from slamobs.pipeline.errors import GainError
from slamobs.pipeline.lie import nearest_rotation

#: Default inertial references: gravity (m/s²) and a mid-latitude magnetic field (Tesla), map frame.
DEFAULT_GRAVITY = (0.0, 0.0, -9.81)
DEFAULT_MAGNETIC_FIELD = (0.2e-4, 0.0, -0.45e-4)
#: Accelerometer trust ramp on |‖f − a_B‖ − ‖g‖| (m/s²): weight 1 up to ACCEL_TOL, 0 from ACCEL_GATE.
ACCEL_TOL = 0.3
ACCEL_GATE = 1.5
#: Two directions whose cross product is shorter than this are collinear: no attitude from them.
MIN_CROSS = 1e-6


@dataclass(frozen=True)
class DirectionSet:
    """Unit body-frame measurements ``body (N, J, 3)`` of inertial unit directions ``inertial (J, 3)``.

    ``weight (N, J)`` in [0, 1] says how far each sample can be trusted (0 = unavailable).
    """

    names: tuple[str, ...]
    inertial: np.ndarray
    body: np.ndarray
    weight: np.ndarray
    gravity_norm: float = float(np.linalg.norm(DEFAULT_GRAVITY))  # ‖g‖ used for the compensation


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = v / n[..., None]
    return u, n


#: Half-width (s) of the central difference that differentiates the velocity stream: odometry noise
#: differentiated over one sample would swamp the acceleration (0.02 m/s / 0.01 s = 2 m/s²).
DIFF_HALF_WIDTH = 0.1


def body_acceleration(
    t_s: np.ndarray, omega: np.ndarray, velocity: np.ndarray, rows: slice = slice(None)
) -> np.ndarray:
    """``dV/dt + Ω × V`` in the body frame (at ``rows``), dV/dt by a ±0.1 s central difference."""
    if t_s.shape[0] < 3 or t_s[-1] - t_s[0] <= 2 * DIFF_HALF_WIDTH:
        return np.cross(omega[rows], velocity[rows])
    lo = np.clip(t_s[rows] - DIFF_HALF_WIDTH, t_s[0], t_s[-1])
    hi = np.clip(t_s[rows] + DIFF_HALF_WIDTH, t_s[0], t_s[-1])
    interp = np.interp if rows == slice(None) else interp_sorted
    dv = np.column_stack(
        [(interp(hi, t_s, velocity[:, a]) - interp(lo, t_s, velocity[:, a])) / (hi - lo) for a in range(3)]
    )
    return dv + np.cross(omega[rows], velocity[rows])


def gravity_up(f_body: np.ndarray, acc_body: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit "up" direction (−g) in the body frame and a [0, 1] trust weight per sample."""
    up, norm = _unit(f_body - acc_body)
    err = np.abs(norm - g)
    weight = np.clip((ACCEL_GATE - err) / (ACCEL_GATE - ACCEL_TOL), 0.0, 1.0)
    weight[~np.isfinite(weight)] = 0.0
    return up, weight


def build_directions(
    t_s, omega, velocity, accel, magnetic, gravity=DEFAULT_GRAVITY, magnetic_field=DEFAULT_MAGNETIC_FIELD
) -> DirectionSet | None:
    """Direction measurements available on the velocity time base (accel/magnetic may be None)."""
    names, inertial, body, weight = [], [], [], []
    if accel is not None:
        g = np.asarray(gravity, float)
        up, w = gravity_up(accel, body_acceleration(t_s, omega, velocity), float(np.linalg.norm(g)))
        names.append("gravity")
        inertial.append(-g / np.linalg.norm(g))
        body.append(up)
        weight.append(w)
    if magnetic is not None:
        m = np.asarray(magnetic_field, float)
        u, n = _unit(magnetic)
        ok = np.isfinite(n) & (n > 0)
        names.append("magnetic")
        inertial.append(m / np.linalg.norm(m))
        body.append(np.where(ok[:, None], u, 0.0))
        weight.append(ok.astype(float))
    if not names:
        return None
    return DirectionSet(
        tuple(names),
        np.array(inertial),
        np.stack(body, axis=1),
        np.stack(weight, axis=1),
        float(np.linalg.norm(gravity)),
    )


# Observer-side preparation (shared by algorithms C and E): kernel arrays, per-sample loading with the
# bias-corrected gravity compensation and the cross-product third vector, and the initial attitude.


def direction_arrays(directions: DirectionSet, gains: dict[str, float]):
    """Kernel inputs ``(inertial (J,3), body (N,J0,3), weight (N,J0), gscale (J0,), make_cross)``.

    Both sides are normalised (docs/observers.md §7); the weight is the gain ``s_<name>`` (default 1) times
    the per-sample trust, and unusable samples (weight 0 or not finite) are zeroed so that no NaN reaches
    the kernel. With exactly two directions the inertial third vector is their normalised cross product
    and ``make_cross`` asks the kernel to build the body one per sample (after its gravity correction).
    """
    inertial = np.asarray(directions.inertial, float)
    inertial = inertial / np.linalg.norm(inertial, axis=1, keepdims=True)
    body = np.asarray(directions.body, float)
    norm = np.linalg.norm(body, axis=2)
    s = np.array([gains.get(f"s_{name}", 1.0) for name in directions.names])
    weight = np.asarray(directions.weight, float) * s
    ok = np.isfinite(norm) & (norm > 0) & np.isfinite(weight) & (weight > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        body = np.where(ok[..., None], body / norm[..., None], 0.0)
    weight = np.where(ok, weight, 0.0)
    gscale = np.array([directions.gravity_norm if name == "gravity" else 0.0 for name in directions.names])
    make_cross = inertial.shape[0] == 2
    if make_cross:
        ci = np.cross(inertial[0], inertial[1])
        if np.linalg.norm(ci) < MIN_CROSS:
            raise GainError(
                f"inertial directions {', '.join(directions.names)} are collinear: attitude is not observable from them"
            )
        inertial = np.vstack([inertial, ci / np.linalg.norm(ci)])
    return (
        np.ascontiguousarray(inertial),
        np.ascontiguousarray(body),
        np.ascontiguousarray(weight),
        gscale,
        make_cross,
    )


def initial_attitude(inertial: np.ndarray, body: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Weighted least-squares attitude (Wahba, by SVD) from one sample's unit direction pairs.

    Algorithm 2 of the paper allows R̂(0) from an attitude-determination method; starting there avoids
    a long co-rotation transient of the map on real logs (the initial yaw of a log is arbitrary).
    """
    return nearest_rotation((inertial * weight[:, None]).T @ body)  # Σ w υ_I υ_Bᵀ, maximise tr(Rᵀ b)


@njit(cache=True)
def load_directions(body, weight, gscale, make_cross, om_m, v_m, b_om, b_v, dir_b, dir_w):
    """Direction measurements of one velocity sample into ``dir_b``/``dir_w``, ready for the kernel.

    Gravity from the accelerometer was compensated for the odometry acceleration with the *measured*
    twist (``Ω_m × V_m``, :func:`pipeline.directions.body_acceleration`); with the paper's gyro bias
    that tilts "up" by 1-2°. Here the term is redone with the bias-corrected twist:
    ``up ∝ a up_m + c``, ``c = Ω_m × V_m − (Ω_m − b̂_Ω) × (V_m − b̂_V)``, where the lost length ``a`` of
    ``f − a_B,m`` follows from ``‖a up_m + c‖ = ‖g‖`` (exact when b̂ is). Then, with two directions, the
    third is their normalised cross product (docs/observers.md §7), weighted like the weaker of the two.
    """
    n0 = body.shape[0]
    for j in range(n0):
        w = weight[j]
        dir_w[j] = w
        x0, x1, x2 = body[j, 0], body[j, 1], body[j, 2]
        g = gscale[j]
        if g > 0.0 and w > 0.0:
            o0, o1, o2 = om_m[0] - b_om[0], om_m[1] - b_om[1], om_m[2] - b_om[2]
            u0, u1, u2 = v_m[0] - b_v[0], v_m[1] - b_v[1], v_m[2] - b_v[2]
            c0 = (om_m[1] * v_m[2] - om_m[2] * v_m[1]) - (o1 * u2 - o2 * u1)
            c1 = (om_m[2] * v_m[0] - om_m[0] * v_m[2]) - (o2 * u0 - o0 * u2)
            c2 = (om_m[0] * v_m[1] - om_m[1] * v_m[0]) - (o0 * u1 - o1 * u0)
            # length a of the un-normalised f − a_B,m such that ‖a up_m + c‖ = ‖g‖
            uc = x0 * c0 + x1 * c1 + x2 * c2
            disc = uc * uc - (c0 * c0 + c1 * c1 + c2 * c2) + g * g
            a = -uc + math.sqrt(disc) if disc > 0.0 else g
            x0 = a * x0 + c0
            x1 = a * x1 + c1
            x2 = a * x2 + c2
            n = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            x0 /= n
            x1 /= n
            x2 /= n
        dir_b[j, 0] = x0
        dir_b[j, 1] = x1
        dir_b[j, 2] = x2
    if make_cross:
        c0 = dir_b[0, 1] * dir_b[1, 2] - dir_b[0, 2] * dir_b[1, 1]
        c1 = dir_b[0, 2] * dir_b[1, 0] - dir_b[0, 0] * dir_b[1, 2]
        c2 = dir_b[0, 0] * dir_b[1, 1] - dir_b[0, 1] * dir_b[1, 0]
        n = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        if n > MIN_CROSS and dir_w[0] > 0.0 and dir_w[1] > 0.0:
            dir_b[2, 0] = c0 / n
            dir_b[2, 1] = c1 / n
            dir_b[2, 2] = c2 / n
            dir_w[2] = min(dir_w[0], dir_w[1])
        else:
            dir_w[2] = 0.0


def first_attitude(inertial, body, weight, gscale, make_cross) -> np.ndarray | None:
    """:func:`initial_attitude` at the first sample where every direction is usable (None if there is none)."""
    usable = np.flatnonzero((weight > 0).all(axis=1))
    if not usable.size:
        return None
    dir_b = np.zeros((inertial.shape[0], 3))
    dir_w = np.zeros(inertial.shape[0])
    zero = np.zeros(3)  # no odometry or bias correction yet: b̂(0) = 0
    load_directions(body[usable[0]], weight[usable[0]], gscale, make_cross, zero, zero, zero, zero, dir_b, dir_w)
    return initial_attitude(inertial, dir_b, dir_w)
