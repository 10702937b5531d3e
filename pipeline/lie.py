"""SO(3)/SE(3) helpers shared by every observer, the simulator and the evaluation.

Conventions (docs/observers.md §1): ``R`` maps body-frame vectors to the inertial frame, twists are ordered
``[omega; v]``, quaternions are stored ``(x, y, z, w)`` as in ROS messages. The per-pose functions are
numba-compiled so the observer kernels can call them (they also work from plain Python on NumPy arrays); the
ones over arrays of poses (:func:`quats_to_rots`, :func:`rots_to_quats`) run the same per-row arithmetic, in array
code on a short log's arrays (no compile on its first run) and in one kernel for both directions
(``rots_quats_into``) on long ones, with the same bits.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import types
from slamobs.pipeline.kernel_cache import njit, subroutine
from slamobs.pipeline.kernel_cache import compiled_for

SMALL_ANGLE = 1e-8


@njit(cache=True)
def mat3_mul(a, b):
    """3x3 product without BLAS (numba's ``@`` needs scipy; loops are faster at this size)."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@njit(cache=True)
def mat3_vec(a, v):
    """``a @ v`` for a 3x3 matrix and a 3-vector."""
    out = np.empty(3)
    for i in range(3):
        out[i] = a[i, 0] * v[0] + a[i, 1] * v[1] + a[i, 2] * v[2]
    return out


@njit(cache=True)
def mat3t_vec(a, v):
    """``a.T @ v`` for a 3x3 matrix and a 3-vector."""
    out = np.empty(3)
    for i in range(3):
        out[i] = a[0, i] * v[0] + a[1, i] * v[1] + a[2, i] * v[2]
    return out


@njit(cache=True)
def skew(w):
    """``[w]x`` such that ``skew(w) @ z == cross(w, z)``."""
    out = np.zeros((3, 3))
    out[0, 1] = -w[2]
    out[0, 2] = w[1]
    out[1, 0] = w[2]
    out[1, 2] = -w[0]
    out[2, 0] = -w[1]
    out[2, 1] = w[0]
    return out


@njit(cache=True)
def vex(m):
    """Inverse of :func:`skew` applied to the anti-symmetric part of ``m``."""
    out = np.empty(3)
    out[0] = 0.5 * (m[2, 1] - m[1, 2])
    out[1] = 0.5 * (m[0, 2] - m[2, 0])
    out[2] = 0.5 * (m[1, 0] - m[0, 1])
    return out


@njit(cache=True)
def so3_exp(w):
    """Rodrigues' formula with the small-angle branch of docs/observers.md §1."""
    theta = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    k = skew(w)
    k2 = mat3_mul(k, k)
    if theta < SMALL_ANGLE:
        return np.eye(3) + k + 0.5 * k2
    return np.eye(3) + (np.sin(theta) / theta) * k + ((1.0 - np.cos(theta)) / (theta * theta)) * k2


@njit(cache=True)
def so3_left_jacobian(w):
    """Left Jacobian ``J(w)`` of SO(3); translation part of the SE(3) exponential."""
    theta = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    k = skew(w)
    k2 = mat3_mul(k, k)
    if theta < SMALL_ANGLE:
        return np.eye(3) + 0.5 * k + (1.0 / 6.0) * k2
    t2 = theta * theta
    return np.eye(3) + ((1.0 - np.cos(theta)) / t2) * k + ((theta - np.sin(theta)) / (t2 * theta)) * k2


@njit(cache=True)
def skew_into(v0, v1, v2, out):
    """``out = [v]×`` (allocation-free :func:`skew` for kernels)."""
    out[0, 0] = 0.0
    out[0, 1] = -v2
    out[0, 2] = v1
    out[1, 0] = v2
    out[1, 1] = 0.0
    out[1, 2] = -v0
    out[2, 0] = -v1
    out[2, 1] = v0
    out[2, 2] = 0.0


@njit(cache=True)
def so3_jacobians_into(w0, w1, w2, jl, jr):
    """Left and right Jacobians of SO(3) at ``w`` (``J_r(w) = J_l(−w)``)."""
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    theta = math.sqrt(t2)
    if theta < SMALL_ANGLE:
        b, c = 0.5, 1.0 / 6.0
    else:
        b = (1.0 - math.cos(theta)) / t2
        c = (theta - math.sin(theta)) / (t2 * theta)
    w = (w0, w1, w2)
    for i in range(3):
        for j in range(3):
            k2 = w[i] * w[j] - (t2 if i == j else 0.0)  # [w]×² = w wᵀ − θ² I
            eye = 1.0 if i == j else 0.0
            jl[i, j] = eye + c * k2
            jr[i, j] = eye + c * k2
    # the [w]× term: +b for the left, −b for the right Jacobian
    jl[0, 1] -= b * w2
    jl[0, 2] += b * w1
    jl[1, 0] += b * w2
    jl[1, 2] -= b * w0
    jl[2, 0] -= b * w1
    jl[2, 1] += b * w0
    jr[0, 1] += b * w2
    jr[0, 2] -= b * w1
    jr[1, 0] -= b * w2
    jr[1, 2] += b * w0
    jr[2, 0] += b * w1
    jr[2, 1] -= b * w0


@njit(cache=True)
def so3_left_jacobian_apply(w0, w1, w2, v0, v1, v2):
    """``J(w) v`` (:func:`so3_left_jacobian` applied, allocation-free) as three scalars, its coefficients those of
    :func:`se3_exp_into` (the series for small ``w``)."""
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    _, cb, cc = _exp_coefficients(t2)
    x0 = w1 * v2 - w2 * v1
    x1 = w2 * v0 - w0 * v2
    x2 = w0 * v1 - w1 * v0
    return (
        v0 + cb * x0 + cc * (w1 * x2 - w2 * x1),
        v1 + cb * x1 + cc * (w2 * x0 - w0 * x2),
        v2 + cb * x2 + cc * (w0 * x1 - w1 * x0),
    )


@njit(cache=True)
def so3_exps(w):
    """:func:`so3_exp` of every row of an ``(N, 3)`` array: ``(N, 3, 3)``."""
    out = np.empty((w.shape[0], 3, 3))
    for k in range(w.shape[0]):
        out[k] = so3_exp(w[k])
    return out


@njit(cache=True)
def se3_exp(w, v):
    """Closed-form SE(3) exponential of the twist ``[w; v]``: returns ``(R, p)``."""
    return so3_exp(w), mat3_vec(so3_left_jacobian(w), v)


#: Largest θ² up to which :func:`se3_exp_into` takes its coefficients from their series (θ < 0.1 rad).
SERIES_T2 = 1e-2
#: Taylor coefficients in θ² of ``a = sin θ/θ``, ``b = (1 − cos θ)/θ²``, ``c = (θ − sin θ)/θ³``, from the θ⁰ term on
#: (six terms: the first left out is below 3e-18 relative for θ² < SERIES_T2).
_A = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(6))
_B = tuple((-1.0) ** k / math.factorial(2 * k + 2) for k in range(6))
_C = tuple((-1.0) ** k / math.factorial(2 * k + 3) for k in range(6))


@subroutine(types.none)
def se3_exp_into(w0, w1, w2, v0, v1, v2, r_out, p_out):
    """:func:`se3_exp` written into ``r_out``/``p_out`` without temporaries (for the hot loops).

    ``R = I + a K + b K²``, ``p = v + b (w x v) + c w x (w x v)`` with ``K = [w]x``,
    ``a = sin θ/θ``, ``b = (1 − cos θ)/θ²``, ``c = (θ − sin θ)/θ³`` (:func:`_exp_coefficients`: exact to rounding at
    the small angles of an integration step too).
    """
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    a, b, c = _exp_coefficients(t2)
    _se3_of_coefficients(a, b, c, t2, w0, w1, w2, v0, v1, v2, r_out, p_out)


@njit(cache=True, inline="always")
def _exp_coefficients(t2):
    """``(a, b, c)`` of :func:`se3_exp_into` at ``θ² = t2``: for ``θ² < SERIES_T2`` from their Taylor series in ``θ²``
    (:data:`_A`, :data:`_B`, :data:`_C` by Horner: no square root, sine, cosine or division, and none of the closed
    form's cancellation in ``1 − cos θ`` and ``θ − sin θ``, whose rounding is ~ε/θ² relative and put up to ~ε/(2θ)
    relative into ``p``: 2,000 ε at θ = 1e-4..1e-3, benchmarks/se3_exp_precision.py), else in closed form."""
    if t2 < SERIES_T2:
        a = _A[0] + t2 * (_A[1] + t2 * (_A[2] + t2 * (_A[3] + t2 * (_A[4] + t2 * _A[5]))))
        b = _B[0] + t2 * (_B[1] + t2 * (_B[2] + t2 * (_B[3] + t2 * (_B[4] + t2 * _B[5]))))
        c = _C[0] + t2 * (_C[1] + t2 * (_C[2] + t2 * (_C[3] + t2 * (_C[4] + t2 * _C[5]))))
        return a, b, c
    theta = math.sqrt(t2)
    st = math.sin(theta)
    return st / theta, (1.0 - math.cos(theta)) / t2, (theta - st) / (t2 * theta)


@njit(cache=True, inline="always")
def _se3_of_coefficients(a, b, c, t2, w0, w1, w2, v0, v1, v2, r_out, p_out):
    """``R = I + a K + b K²`` and ``p = v + b (w x v) + c w x (w x v)`` into ``r_out``/``p_out``."""
    # K² = w wᵀ − θ² I
    r_out[0, 0] = 1.0 + b * (w0 * w0 - t2)
    r_out[1, 1] = 1.0 + b * (w1 * w1 - t2)
    r_out[2, 2] = 1.0 + b * (w2 * w2 - t2)
    r_out[0, 1] = -a * w2 + b * w0 * w1
    r_out[1, 0] = a * w2 + b * w0 * w1
    r_out[0, 2] = a * w1 + b * w0 * w2
    r_out[2, 0] = -a * w1 + b * w0 * w2
    r_out[1, 2] = -a * w0 + b * w1 * w2
    r_out[2, 1] = a * w0 + b * w1 * w2
    x0 = w1 * v2 - w2 * v1
    x1 = w2 * v0 - w0 * v2
    x2 = w0 * v1 - w1 * v0
    xx0 = w1 * x2 - w2 * x1
    xx1 = w2 * x0 - w0 * x2
    xx2 = w0 * x1 - w1 * x0
    p_out[0] = v0 + b * x0 + c * xx0
    p_out[1] = v1 + b * x1 + c * xx1
    p_out[2] = v2 + b * x2 + c * xx2


@njit(cache=True)
def so3_log(r):
    """Rotation vector of ``r`` (inverse of :func:`so3_exp`), robust near 0 and pi."""
    c = 0.5 * (r[0, 0] + r[1, 1] + r[2, 2] - 1.0)
    c = min(1.0, max(-1.0, c))
    theta = np.arccos(c)
    if theta < 1e-6:
        return vex(r)
    if np.pi - theta < 1e-4:
        # Near pi the antisymmetric part vanishes; use the symmetric part for the axis.
        b = 0.5 * (r + r.T) - c * np.eye(3)
        i = 0
        if b[1, 1] > b[i, i]:
            i = 1
        if b[2, 2] > b[i, i]:
            i = 2
        axis = b[:, i] / np.sqrt(max(b[i, i], 1e-300))
        axis = axis / np.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)
        s = vex(r)
        if axis[0] * s[0] + axis[1] * s[1] + axis[2] * s[2] < 0.0:
            axis = -axis
        return theta * axis
    return (theta / np.sin(theta)) * vex(r)


@njit(cache=True)
def rotation_angle(r):
    """Rotation angle in [0, pi] (docs/observers.md §1)."""
    c = 0.5 * (r[0, 0] + r[1, 1] + r[2, 2] - 1.0)
    return np.arccos(min(1.0, max(-1.0, c)))


@njit(cache=True)
def project_so3(r):
    """Re-orthonormalise a rotation that drifted by round-off (through its quaternion; exact to O(drift))."""
    out = np.empty((3, 3))
    x, y, z, w = _quat_of_rot(r)
    _rot_of_quat(x, y, z, w, out)
    return out


@subroutine(types.none)
def project_so3_into(r):
    """:func:`project_so3` in place (for the observer kernels: no temporary, no array assignment)."""
    x, y, z, w = _quat_of_rot(r)
    _rot_of_quat(x, y, z, w, r)


def nearest_rotation(m: np.ndarray) -> np.ndarray:
    """The rotation closest to ``m`` in the Frobenius norm (polar factor by SVD, reflection excluded): of a sum of
    rotations, their chordal mean."""
    u, _, vt = np.linalg.svd(np.asarray(m, dtype=np.float64))
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    return u @ np.diag([1.0, 1.0, d]) @ vt


@njit(cache=True)
def quat_to_rot(q):
    """``(x, y, z, w)`` quaternion (normalised here) to a rotation matrix."""
    out = np.empty((3, 3))
    _rot_of_quat(q[0], q[1], q[2], q[3], out)
    return out


@subroutine(types.none, error_model="numpy")
def _rot_of_quat(qx, qy, qz, qw, out):
    """:func:`quat_to_rot` of the four scalars, written into ``out`` (a zero quaternion gives NaN)."""
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    x, y, z, w = qx / n, qy / n, qz / n, qw / n
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - z * w)
    out[0, 2] = 2.0 * (x * z + y * w)
    out[1, 0] = 2.0 * (x * y + z * w)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - x * w)
    out[2, 0] = 2.0 * (x * z - y * w)
    out[2, 1] = 2.0 * (y * z + x * w)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def rot_to_quat(r):
    """Rotation matrix to a unit ``(x, y, z, w)`` quaternion with ``w >= 0`` (Shepperd's method)."""
    q = np.empty(4)
    q[0], q[1], q[2], q[3] = _quat_of_rot(r)
    return q


@subroutine(types.UniTuple(types.float64, 4), error_model="numpy")
def _quat_of_rot(r):
    """:func:`rot_to_quat` as four scalars (no temporaries: the kernels re-orthonormalise with it). The nine
    elements are read once: numba lowers every element read of an array with a copy of the array's struct and its
    reference count, so reading each once makes a third of the code to compile, with the same arithmetic."""
    r00, r01, r02 = r[0, 0], r[0, 1], r[0, 2]
    r10, r11, r12 = r[1, 0], r[1, 1], r[1, 2]
    r20, r21, r22 = r[2, 0], r[2, 1], r[2, 2]
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        w = 0.25 * s
        x = (r21 - r12) / s
        y = (r02 - r20) / s
        z = (r10 - r01) / s
    elif r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        w = (r21 - r12) / s
        x = 0.25 * s
        y = (r01 + r10) / s
        z = (r02 + r20) / s
    elif r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        w = (r02 - r20) / s
        x = (r01 + r10) / s
        y = 0.25 * s
        z = (r12 + r21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        w = (r10 - r01) / s
        x = (r02 + r20) / s
        y = (r12 + r21) / s
        z = 0.25 * s
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    n = math.sqrt(x * x + y * y + z * z + w * w)
    return x / n, y / n, z / n, w / n


#: Rows from which :func:`quats_to_rots` and :func:`rots_to_quats` take their compiled kernel (and from a 64th of it
#: once this process has it); shorter arrays take the array code, whose numbers are the same bit for bit: the
#: kernel's first compilation (~0.3 s of CPU) would cost a short log's first run more than it saves (a 3-minute
#: log's 36 000 poses compile nothing here; an hour's 720 000 take the kernel).
ROTATION_KERNEL_ROWS = 65_536


def _kernel_for(n: int) -> bool:
    return compiled_for(n, rots_quats_into, ROTATION_KERNEL_ROWS)


def quats_to_rots(q):
    """Vectorised :func:`quat_to_rot` over an ``(N, 4)`` array: the same arithmetic row by row (compiled for long
    arrays, :data:`ROTATION_KERNEL_ROWS`); a zero quaternion gives NaN."""
    q = np.ascontiguousarray(q, dtype=np.float64)
    out = np.empty((q.shape[0], 3, 3))
    if _kernel_for(q.shape[0]):
        rots_quats_into(out, q, False)
    else:
        _rots_of_quats(q, out)
    return out


def rots_to_quats(r):
    """Vectorised :func:`rot_to_quat` over an ``(N, 3, 3)`` array: the same arithmetic row by row (compiled for long
    arrays, :data:`ROTATION_KERNEL_ROWS`); NaN rows give NaN."""
    r = np.ascontiguousarray(r, dtype=np.float64)
    q = np.empty((r.shape[0], 4))
    if _kernel_for(r.shape[0]):
        rots_quats_into(r, q, True)
    else:
        _quats_of_rots(r, q)
    return q


def _rots_of_quats(q: np.ndarray, out: np.ndarray) -> None:
    """:func:`_rot_of_quat` of every row of ``q`` into ``out`` in array code: its operations in its order."""
    qx, qy, qz, qw = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        x, y, z, w = qx / n, qy / n, qz / n, qw / n
        out[:, 0, 0] = 1.0 - 2.0 * (y * y + z * z)
        out[:, 0, 1] = 2.0 * (x * y - z * w)
        out[:, 0, 2] = 2.0 * (x * z + y * w)
        out[:, 1, 0] = 2.0 * (x * y + z * w)
        out[:, 1, 1] = 1.0 - 2.0 * (x * x + z * z)
        out[:, 1, 2] = 2.0 * (y * z - x * w)
        out[:, 2, 0] = 2.0 * (x * z - y * w)
        out[:, 2, 1] = 2.0 * (y * z + x * w)
        out[:, 2, 2] = 1.0 - 2.0 * (x * x + y * y)


def _quats_of_rots(r: np.ndarray, q: np.ndarray) -> None:
    """:func:`_quat_of_rot` of every matrix of ``r`` into ``q`` in array code: each of its four cases on the rows
    that take it, its operations in its order."""
    n = r.shape[0]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r.reshape(n, 9).T.copy()  # each element contiguous over the rows
    xyzw = np.empty((4, n))
    with np.errstate(invalid="ignore", divide="ignore"):
        tr = r00 + r11 + r22
        s = 2.0 * np.sqrt(tr + 1.0)  # the first case on every row (nearly all take it); the others' rows redone
        xyzw[:] = (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s, 0.25 * s
        rest = ~(tr > 0.0)
        second = rest & (r00 > r11) & (r00 > r22)
        third = rest & ~second & (r11 > r22)
        fourth = rest & ~second & ~third
        for rows, k in ((second, 0), (third, 1), (fourth, 2)):  # the diagonal element k is the largest
            _quats_case(k, np.flatnonzero(rows), (r00, r01, r02, r10, r11, r12, r20, r21, r22), xyzw)
        flip = np.flatnonzero(xyzw[3] < 0.0)
        xyzw[:, flip] = -xyzw[:, flip]
        x, y, z, w = xyzw
        norm = np.sqrt(x * x + y * y + z * z + w * w)
        for c in range(4):
            q[:, c] = xyzw[c] / norm


def _quats_case(k: int, i: np.ndarray, e: tuple, xyzw: np.ndarray) -> None:
    """Rows ``i`` of :func:`_quats_of_rots` in :func:`_quat_of_rot`'s case of the diagonal element ``k`` (0, 1, 2:
    x, y, z is the component found first), from the matrices' elements ``e`` (row-major, each over the rows)."""
    if not i.size:
        return
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = (c[i] for c in e)
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + r00 - r11 - r22)
        x, y, z, w = 0.25 * s, (r01 + r10) / s, (r02 + r20) / s, (r21 - r12) / s
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + r11 - r00 - r22)
        x, y, z, w = (r01 + r10) / s, 0.25 * s, (r12 + r21) / s, (r02 - r20) / s
    else:
        s = 2.0 * np.sqrt(1.0 + r22 - r00 - r11)
        x, y, z, w = (r02 + r20) / s, (r12 + r21) / s, 0.25 * s, (r10 - r01) / s
    for c, v in enumerate((x, y, z, w)):
        xyzw[c, i] = v


@njit(cache=True, nogil=True, nrt=False)
def rots_quats_into(r, q, to_quats):
    """Rotations ``r`` (N, 3, 3) to quaternions ``q`` (N, 4), or back when ``to_quats`` is False: both directions
    in one kernel, so a first run compiles one (the alignment's) where it compiled two (the report's too).
    Public: tests/test_lie.py checks it bit for bit."""
    if to_quats:
        for n in range(r.shape[0]):
            q[n, 0], q[n, 1], q[n, 2], q[n, 3] = _quat_of_rot(r[n])
    else:
        for n in range(q.shape[0]):
            _rot_of_quat(q[n, 0], q[n, 1], q[n, 2], q[n, 3], r[n])


@njit(cache=True, nogil=True)
def integrate_body_twists(r0, p0, omega, v, dt):
    """Dead-reckon ``(R, P)`` through steps ``(R, P) <- (R, P) exp(dt_k [omega_k; v_k])``.

    ``omega``, ``v`` are (K, 3) per-step body twists, ``dt`` (K,) step lengths; returns the K + 1 poses.
    Used both for wheel-odometry poses and to check the scenarios' kinematic consistency. Each step is
    :func:`se3_exp` with the same operations in the same order, written without temporaries (the same numbers,
    bit for bit, a tenth of the time on long logs).
    """
    k = dt.shape[0]
    rs = np.empty((k + 1, 3, 3))
    ps = np.empty((k + 1, 3))
    rs[0] = r0
    ps[0] = p0
    scratch = np.empty((3, 3, 3))
    for i in range(k):
        _twist_step(rs[i], ps[i], omega[i], v[i], dt[i], scratch, rs[i + 1], ps[i + 1])
    return rs, ps


@njit(cache=True, nogil=True)
def integrate_body_twists_at(r0, p0, omega, v, dt, keep):
    """:func:`integrate_body_twists`'s poses ``keep`` (sorted indices into its K + 1), the same numbers, without
    storing the others (a long log's poses are read at a few places)."""
    m = keep.shape[0]
    rs = np.empty((m, 3, 3))
    ps = np.empty((m, 3))
    cur_r, cur_p = r0.copy(), p0.copy()
    nxt_r, nxt_p = np.empty((3, 3)), np.empty(3)
    scratch = np.empty((3, 3, 3))
    j = 0
    for i in range(dt.shape[0] + 1):
        while j < m and keep[j] == i:
            rs[j] = cur_r
            ps[j] = cur_p
            j += 1
        if j == m or i == dt.shape[0]:
            break
        _twist_step(cur_r, cur_p, omega[i], v[i], dt[i], scratch, nxt_r, nxt_p)
        cur_r, nxt_r = nxt_r, cur_r
        cur_p, nxt_p = nxt_p, cur_p
    return rs, ps


@njit(cache=True, nogil=True)
def integrate_body_twists_at_columns(r0, p0, omega, v, cols, dt, keep):
    """:func:`integrate_body_twists_at` for ``v`` with its column ``c`` replaced by ``cols[:, c]``, for each
    ``c`` of 0..2 (three dead reckonings that share ``omega``): the rotations (the same for all three) once, the
    positions of each; the same numbers as three calls. Returns ``rs`` (m, 3, 3) and ``ps`` (3, m, 3)."""
    m = keep.shape[0]
    rs = np.empty((m, 3, 3))
    ps = np.empty((3, m, 3))
    cur_r, nxt_r = r0.copy(), np.empty((3, 3))
    cur_p, nxt_p = np.empty((3, 3)), np.empty((3, 3))
    for c in range(3):
        cur_p[c] = p0
    vc = np.empty(3)
    scratch = np.empty((3, 3, 3))
    j = 0
    for i in range(dt.shape[0] + 1):
        while j < m and keep[j] == i:
            rs[j] = cur_r
            for c in range(3):
                ps[c, j] = cur_p[c]
            j += 1
        if j == m or i == dt.shape[0]:
            break
        cj, cl = _twist_rotation(omega[i], dt[i], scratch)
        for c in range(3):
            vc[0], vc[1], vc[2] = v[i, 0], v[i, 1], v[i, 2]
            vc[c] = cols[i, c]
            _twist_position(cur_r, cur_p[c], vc, dt[i], cj, cl, scratch, nxt_p[c])
        dr = scratch[2]
        for a in range(3):
            for b in range(3):
                nxt_r[a, b] = cur_r[a, 0] * dr[0, b] + cur_r[a, 1] * dr[1, b] + cur_r[a, 2] * dr[2, b]
        cur_r, nxt_r = nxt_r, cur_r
        cur_p, nxt_p = nxt_p, cur_p
    return rs, ps


@njit(cache=True, nogil=True)
def integrate_body_twists_at_rotation_columns(r0, p0, omega, v, cols, dt, keep):
    """:func:`integrate_body_twists_at` for ``omega`` with its column ``c`` replaced by ``cols[:, c]``, for each ``c``
    of 0..2: three dead reckonings in one pass over the steps (each step's three chains independent: the core
    overlaps them), the same numbers as three calls. Returns ``rs`` (3, m, 3, 3) and ``ps`` (3, m, 3)."""
    m = keep.shape[0]
    rs = np.empty((3, m, 3, 3))
    ps = np.empty((3, m, 3))
    cur_r, nxt_r = np.empty((3, 3, 3)), np.empty((3, 3, 3))
    cur_p, nxt_p = np.empty((3, 3)), np.empty((3, 3))
    for c in range(3):
        cur_r[c] = r0
        cur_p[c] = p0
    wc = np.empty(3)
    scratch = np.empty((3, 3, 3))
    j = 0
    for i in range(dt.shape[0] + 1):
        while j < m and keep[j] == i:
            for c in range(3):
                rs[c, j] = cur_r[c]
                ps[c, j] = cur_p[c]
            j += 1
        if j == m or i == dt.shape[0]:
            break
        for c in range(3):
            wc[0], wc[1], wc[2] = omega[i, 0], omega[i, 1], omega[i, 2]
            wc[c] = cols[i, c]
            _twist_step(cur_r[c], cur_p[c], wc, v[i], dt[i], scratch, nxt_r[c], nxt_p[c])
        cur_r, nxt_r = nxt_r, cur_r
        cur_p, nxt_p = nxt_p, cur_p
    return rs, ps


@njit(cache=True, inline="always")
def _twist_step(r, p, omega, v, dt, scratch, r_out, p_out):
    """``(r_out, p_out) = (r, p) exp(dt [omega; v])`` as :func:`se3_exp`, :func:`mat3_vec` and :func:`mat3_mul`
    compute it (``scratch``: (3, 3, 3))."""
    cj, cl = _twist_rotation(omega, dt, scratch)
    _twist_position(r, p, v, dt, cj, cl, scratch, p_out)
    dr = scratch[2]
    for a in range(3):
        for b in range(3):
            r_out[a, b] = r[a, 0] * dr[0, b] + r[a, 1] * dr[1, b] + r[a, 2] * dr[2, b]


@njit(cache=True, inline="always")
def _twist_rotation(omega, dt, scratch):
    """The rotation part of :func:`_twist_step`: ``K``, ``K²`` and ``Exp(dt omega)`` into ``scratch``; returns
    the left Jacobian's coefficients ``(cj, cl)``."""
    kk, k2, dr = scratch[0], scratch[1], scratch[2]
    w0, w1, w2 = omega[0] * dt, omega[1] * dt, omega[2] * dt
    theta = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    skew_into(w0, w1, w2, kk)
    for a in range(3):
        for b in range(3):
            k2[a, b] = kk[a, 0] * kk[0, b] + kk[a, 1] * kk[1, b] + kk[a, 2] * kk[2, b]
    # so3_exp and so3_left_jacobian: I + ca K + cb K² and I + cj K + cl K²
    if theta < SMALL_ANGLE:
        ca, cb, cj, cl = 1.0, 0.5, 0.5, 1.0 / 6.0
    else:
        t2, st, ct = theta * theta, np.sin(theta), np.cos(theta)
        ca, cb = st / theta, (1.0 - ct) / t2
        cj, cl = cb, (theta - st) / (t2 * theta)
    for a in range(3):
        for b in range(3):
            eye = 1.0 if a == b else 0.0
            dr[a, b] = (eye + ca * kk[a, b]) + cb * k2[a, b]
    return cj, cl


@njit(cache=True, inline="always")
def _twist_position(r, p, v, dt, cj, cl, scratch, p_out):
    """The position part of :func:`_twist_step` (after :func:`_twist_rotation` filled ``scratch``)."""
    kk, k2 = scratch[0], scratch[1]
    v0, v1, v2 = v[0] * dt, v[1] * dt, v[2] * dt
    dp0 = _jl_row(0, cj, cl, kk, k2, v0, v1, v2)
    dp1 = _jl_row(1, cj, cl, kk, k2, v0, v1, v2)
    dp2 = _jl_row(2, cj, cl, kk, k2, v0, v1, v2)
    for a in range(3):
        p_out[a] = p[a] + (r[a, 0] * dp0 + r[a, 1] * dp1 + r[a, 2] * dp2)


@njit(cache=True, inline="always")
def _jl_row(a, cj, cl, kk, k2, v0, v1, v2):
    """Row ``a`` of ``(I + cj K + cl K²) v`` as :func:`so3_left_jacobian` and :func:`mat3_vec` compute it."""
    j0 = ((1.0 if a == 0 else 0.0) + cj * kk[a, 0]) + cl * k2[a, 0]
    j1 = ((1.0 if a == 1 else 0.0) + cj * kk[a, 1]) + cl * k2[a, 1]
    j2 = ((1.0 if a == 2 else 0.0) + cj * kk[a, 2]) + cl * k2[a, 2]
    return j0 * v0 + j1 * v1 + j2 * v2


@subroutine(types.UniTuple(types.float64, 3))
def floor_tilt_row(u, t, n):
    """A floor's tilt row: the Jacobian ``u × t`` of ``tᵀu`` (the up axis ``u`` along the floor's tangent ``t``)
    in a rotation step ``ξ`` with ``δu = ξ × u``, less its part along the floor's normal ``n`` (turning about the
    normal tilts the up axis no less: no heading in the tilt rows); ``u``, ``t``, ``n`` 3-vectors in the step's
    frame. riekf's floor pseudo-measurements (``observers.riekf._planar_update``: the world frame, ``u = R̂e3``) and
    the smoother's floor terms (``smoother.graph.floor_terms``: the body frame, ``u = e3``, ``Rᵀt``, ``Rᵀn``)."""
    a0 = u[1] * t[2] - u[2] * t[1]
    a1 = u[2] * t[0] - u[0] * t[2]
    a2 = u[0] * t[1] - u[1] * t[0]
    d = a0 * n[0] + a1 * n[1] + a2 * n[2]
    return a0 - d * n[0], a1 - d * n[1], a2 - d * n[2]


@njit(cache=True)
def floor_tilt_rows(u, t, n):
    """:func:`floor_tilt_row` of each row of ``(K, 3)`` arrays ``u``, ``t``, ``n``: ``(K, 3)``."""
    out = np.empty((u.shape[0], 3))
    for k in range(u.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = floor_tilt_row(u[k], t[k], n[k])
    return out


class CrossCovariance(NamedTuple):
    """What :func:`umeyama_fit` decomposed: the cross-covariance ``1/n Σ (dst_i − μ_dst)(src_i − μ_src)ᵀ = U D Vᵀ``
    (``u``, ``d``, ``vt`` as ``np.linalg.svd`` gives them), the means, and ``σ²_src`` (None unless the fit was
    scaled)."""

    u: np.ndarray
    d: np.ndarray
    vt: np.ndarray
    mu_src: np.ndarray
    mu_dst: np.ndarray
    var_src: float | None


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`umeyama_fit`'s ``(R, t, s)``."""
    return umeyama_fit(src, dst, with_scale)[:3]


def umeyama_fit(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, float, CrossCovariance]:
    """Least-squares similarity ``dst ≈ s R src + t`` (Umeyama 1991, "Least-squares estimation of
    transformation parameters between two point patterns"), with ``s = 1`` unless ``with_scale``.

    With the cross-covariance ``Σ = 1/n Σ (dst_i − μ_dst)(src_i − μ_src)ᵀ = U D Vᵀ``, the optimum is
    ``R = U S Vᵀ`` with ``S = diag(1, 1, −1)`` when ``det U det V < 0`` (otherwise the best orthogonal
    matrix would be a reflection), ``s = tr(D S) / σ²_src`` and ``t = μ_dst − s R μ_src``. The solution
    is unique iff ``rank Σ ≥ 2``, i.e. the points are not all collinear. Returns ``(R, t, s)`` and the
    decomposition (:class:`CrossCovariance`: a caller that needs it again, ``evaluation.align.upright_fit``, reads
    it, not a second SVD).
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape != y.shape:
        raise ValueError(f"umeyama: src and dst must both be (N, 3), got {x.shape} and {y.shape}")
    n = x.shape[0]
    if n < 3:
        raise ValueError(f"umeyama: need at least 3 point pairs for a unique rigid alignment, got {n}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("umeyama: input contains NaN or infinite coordinates")
    mu_x = x.mean(axis=0)
    mu_y = y.mean(axis=0)
    xc = x - mu_x
    yc = y - mu_y
    cov = yc.T @ xc / n
    u, d, vt = np.linalg.svd(cov)
    if d[0] <= 0.0 or d[1] <= 1e-12 * d[0]:
        raise ValueError(
            f"umeyama: degenerate input ({n} points are all collinear or coincident; cross-covariance "
            f"singular values {d.tolist()}), the rotation about the common line is undetermined"
        )
    s_diag = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        s_diag[2] = -1.0
    rot = (u * s_diag) @ vt
    scale, var_x = 1.0, None
    if with_scale:
        var_x = float(np.mean(np.sum(xc * xc, axis=1)))
        scale = float(np.sum(d * s_diag) / var_x)
    trans = mu_y - scale * rot @ mu_x
    return rot, trans, scale, CrossCovariance(u, d, vt, mu_x, mu_y, var_x)


def rotate_covariance(cov: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Covariances (N, d, d) of error vectors that turn by ``r`` (d × d; a pose error ``(δθ, δp)`` turns by
    ``diag(R, R)``): ``r Σ rᵀ`` each."""
    return np.matmul(np.matmul(r, cov), r.T)


def quat_angles(q: np.ndarray) -> np.ndarray:
    """Rotation angles in [0, π] of unit quaternions ``(N, 4)``: 2 atan2(‖v‖, |w|), accurate near 0 and near π.
    The one quaternion angle of the report's rotation errors (:mod:`.evaluation.metrics`) and of the readers'
    ``/tf_static`` changes (:func:`quat_angles_to`)."""
    return 2.0 * np.arctan2(np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2]), np.abs(q[:, 3]))


def quat_angles_to(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Rotation angle in [0, π] from the quaternion ``ref`` (4,) to each row of ``q`` (N, 4), all normalised here:
    :func:`quat_angles` of ``ref⁻¹ q_k`` (``/tf_static`` values published again, against the last one)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1)[:, None]
    r = np.asarray(ref, dtype=np.float64) / np.linalg.norm(ref)
    rel = np.empty_like(q)  # conj(r) * q, w last
    rel[:, :3] = r[3] * q[:, :3] - q[:, 3:] * r[:3] - np.cross(r[:3], q[:, :3])
    rel[:, 3] = q[:, 3] * r[3] + q[:, :3] @ r[:3]
    return quat_angles(rel)


def rots_to_rotvecs(r: np.ndarray) -> np.ndarray:
    """Rotation vectors (N, 3) of rotation matrices (N, 3, 3) (:func:`so3_log` row by row, through the
    quaternion: angle in [0, π])."""
    q = rots_to_quats(r)
    q = np.where(q[:, 3:] < 0.0, -q, q)
    s = np.linalg.norm(q[:, :3], axis=1)
    angle = 2.0 * np.arctan2(s, q[:, 3])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 2.0)  # sin(θ/2) ≈ θ/2 near 0
    return q[:, :3] * scale[:, None]
