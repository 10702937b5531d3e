"""Inertial direction measurements (spec §4.1): gravity from the accelerometer, the magnetic field.

An accelerometer measures specific force ``f = Rᵀ(a − g)``; only when the body acceleration ``a`` is known
does it give the direction of gravity. The body acceleration is estimated from the velocity stream
(``a_B = dV/dt + Ω × V``) and removed; samples whose corrected magnitude is still far from ``‖g‖`` (hard
manoeuvres, impacts, odometry slip) get weight 0, with a smooth ramp in between, so an observer can
down-weight them rather than be pulled by them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Default inertial references: gravity (m/s²) and a mid-latitude magnetic field (Tesla), map frame.
DEFAULT_GRAVITY = (0.0, 0.0, -9.81)
DEFAULT_MAGNETIC_FIELD = (0.2e-4, 0.0, -0.45e-4)
#: Accelerometer trust ramp on |‖f − a_B‖ − ‖g‖| (m/s²): weight 1 up to ACCEL_TOL, 0 from ACCEL_GATE.
ACCEL_TOL = 0.3
ACCEL_GATE = 1.5


@dataclass(frozen=True)
class DirectionSet:
    """Unit body-frame measurements ``body (N, J, 3)`` of inertial unit directions ``inertial (J, 3)``.

    ``weight (N, J)`` in [0, 1] says how far each sample can be trusted (0 = unavailable).
    """

    names: tuple[str, ...]
    inertial: np.ndarray
    body: np.ndarray
    weight: np.ndarray


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = v / n[..., None]
    return u, n


#: Half-width (s) of the central difference that differentiates the velocity stream: odometry noise
#: differentiated over one sample would swamp the acceleration (0.02 m/s / 0.01 s = 2 m/s²).
DIFF_HALF_WIDTH = 0.1


def body_acceleration(t_s: np.ndarray, omega: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """``dV/dt + Ω × V`` in the body frame, dV/dt by a ±0.1 s central difference."""
    if t_s.shape[0] < 3 or t_s[-1] - t_s[0] <= 2 * DIFF_HALF_WIDTH:
        return np.cross(omega, velocity)
    lo = np.clip(t_s - DIFF_HALF_WIDTH, t_s[0], t_s[-1])
    hi = np.clip(t_s + DIFF_HALF_WIDTH, t_s[0], t_s[-1])
    dv = np.column_stack([(np.interp(hi, t_s, velocity[:, a]) - np.interp(lo, t_s, velocity[:, a])) / (hi - lo)
                          for a in range(3)])
    return dv + np.cross(omega, velocity)


def gravity_up(f_body: np.ndarray, acc_body: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit "up" direction (−g) in the body frame and a [0, 1] trust weight per sample."""
    up, norm = _unit(f_body - acc_body)
    err = np.abs(norm - g)
    weight = np.clip((ACCEL_GATE - err) / (ACCEL_GATE - ACCEL_TOL), 0.0, 1.0)
    weight[~np.isfinite(weight)] = 0.0
    return up, weight


def build_directions(t_s, omega, velocity, accel, magnetic, gravity=DEFAULT_GRAVITY,
                     magnetic_field=DEFAULT_MAGNETIC_FIELD) -> DirectionSet | None:
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
    return DirectionSet(tuple(names), np.array(inertial), np.stack(body, axis=1), np.stack(weight, axis=1))
