"""Error metrics with the definitions evo 1.38.1 uses, written from the mathematics.

A SLAM observer without absolute references recovers the pose only up to a constant rigid transform
(docs/observers.md §1.1), so every comparison with ground truth goes: associate stamps (:mod:`.sync`) ->
alignment of the estimate onto the truth (:mod:`.align`) -> absolute or relative pose error (here). The
definitions are chosen so that numbers are comparable with ``evo_ape`` / ``evo_rpe`` (every ``-r`` pose
relation, statistics).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from slamobs.pipeline.blocks import blockwise, row_norms3
from slamobs.pipeline.evaluation.align import apply_alignment
from slamobs.pipeline.evaluation.sync import NS_PER_S, associate
from slamobs.pipeline import kernel_cache
from slamobs.pipeline.kernel_cache import KERNEL_ROWS, njit
from slamobs.pipeline.lie import quat_angles, quats_to_rots, umeyama
from slamobs.pipeline.noise import chi2_quantile, nees_bounds  # noqa: F401 (the report's bounds, defined with riekf's)
from slamobs.pipeline.simd import fma

__all__ = [
    "NS_PER_S",
    "POSE_RELATIONS",
    "LandmarkErrors",
    "RotationRows",
    "ape_errors",
    "ape_rotation_deg",
    "ape_translation",
    "apply_alignment",
    "associate",
    "landmark_errors",
    "relative_angles",
    "rpe_errors",
    "statistics",
    "umeyama",
]


def chi2_sf(x: float, dof: int) -> float:
    """``P(χ² > x)`` for ``dof`` (a positive integer) degrees of freedom: the regularised upper incomplete gamma
    ``Q(dof/2, x/2)`` by its recursion ``Q(a + 1, y) = Q(a, y) + yᵃ e⁻ʸ / Γ(a + 1)`` from ``Q(1/2, y) = erfc(√y)``
    or ``Q(1, y) = e⁻ʸ``."""
    y = max(float(x), 0.0) / 2.0
    a, total = (0.5, math.erfc(math.sqrt(y))) if dof % 2 else (1.0, math.exp(-y))
    while a < dof / 2.0:
        total += math.exp(a * math.log(y) - y - math.lgamma(a + 1.0)) if y > 0 else 0.0
        a += 1.0
    return total


def nees_bound_any_correlation(dof: int, tail: float = 0.025) -> float:
    """The level a mean of NEES values, each χ²(``dof``) but correlated in any way, exceeds with probability at
    most ``tail``: ``E[X | X > q]`` of one value X ~ χ²(dof) above its ``1 − tail`` quantile q, ``dof · P(χ²(dof
    + 2) > q) / tail``. The mean Y lies below X in convex order (f(mean) ≤ mean of f for convex f), so
    ``P(Y ≥ t) ≤ E(X − c)₊ / (t − c)`` for every c < t, which is ``tail`` at t = that expectation and c = q
    (11.5 for 3 DoF, where q is 9.35; the bound holds for any correlation, q itself does not)."""
    q = chi2_quantile(1.0 - tail, dof)
    return dof * chi2_sf(q, dof + 2) / tail


def nees_verdict(mean: float, bounds, any_correlation: float) -> str:
    """A run's mean NEES against the bounds of a mean of independent values and the level no correlation explains
    (:func:`nees_bound_any_correlation`): ``overconfident`` above that level, ``inconclusive`` outside the
    independent bounds only (one run's correlated errors can do that), else ``within``. One rule for the pose's
    parts and the map."""
    if mean > any_correlation:
        return "overconfident"
    return "within" if bounds[0] <= mean <= bounds[1] else "inconclusive"


def row_norms(x: np.ndarray, minus: np.ndarray | None = None) -> np.ndarray:
    """``np.linalg.norm(x - minus, axis=1)`` (``x`` alone without ``minus``) of (N, k) rows: where
    :func:`compiled_for`, a compiled loop with the same operations in the same order (each difference, its
    square, the squares summed left to right as NumPy's reduction of a short axis does, one ``sqrt``): the same
    bits, without NumPy's temporaries and its slow reduction along a short axis (~1 ms per 100 k rows)."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or not compiled_for(x.shape[0], row_norms_into):
        return row_norms3(x if minus is None else x - minus)
    out = np.empty(x.shape[0])
    row_norms_into(
        np.ascontiguousarray(x), None if minus is None else np.ascontiguousarray(minus, dtype=np.float64), out
    )
    return out


@njit(cache=True, nogil=True)
def row_norms_into(x, minus, out):  # pragma: no cover - compiled
    """:func:`row_norms` into ``out``.
    Public: tests/test_kernel_cache.py compiles it again to check the cache."""
    for n in range(x.shape[0]):
        s = 0.0
        for c in range(x.shape[1]):
            d = x[n, c] if minus is None else x[n, c] - minus[n, c]
            s += d * d
        out[n] = math.sqrt(s)


def ape_translation(ref_pos: np.ndarray, est_pos: np.ndarray) -> np.ndarray:
    """Per-pair ``‖p_est − p_ref‖`` (evo APE, translation part), metres."""
    ref = np.asarray(ref_pos, dtype=np.float64)
    est = np.asarray(est_pos, dtype=np.float64)
    if ref.shape != est.shape or ref.ndim != 2 or ref.shape[1] != 3:
        raise ValueError(f"ape_translation: expected two (N, 3) arrays, got {ref.shape} and {est.shape}")
    return row_norms(est, ref)


#: evo ``-r`` choices -> (evo's PoseRelation text used in titles, unit of the error)
POSE_RELATIONS: dict[str, tuple[str, str]] = {
    "trans_part": ("translation part", "m"),
    "angle_deg": ("rotation angle in degrees", "deg"),
    "angle_rad": ("rotation angle in radians", "rad"),
    "full": ("full transformation", "unit-less"),
    "rot_part": ("rotation part", "unit-less"),
    "point_distance": ("point distance", "m"),
}

RELATION_DEFINITIONS = {
    "trans_part": "‖t_E‖ of the error pose E: the distance of the positions, metres",
    "angle_deg": "rotation angle of R_E in degrees, in [0, 180]",
    "angle_rad": "rotation angle of R_E in radians, in [0, π]",
    "full": "Frobenius norm ‖E − I₄‖ of the 4x4 error pose (unit-less, mixes metres and radians)",
    "rot_part": "Frobenius norm ‖R_E − I₃‖ (unit-less; 2√2 sin(θ/2) for an angle θ)",
    "point_distance": "APE: as trans_part; RPE: | ‖Δp_ref‖ − ‖Δp_est‖ |, difference of travelled straight-line "
    "distances, metres",
}


def _check_relation(relation: str) -> None:
    if relation not in POSE_RELATIONS:
        raise ValueError(f"pose relation must be one of {tuple(POSE_RELATIONS)}, got {relation!r}")


def _orthogonal_factor(m: np.ndarray) -> np.ndarray:
    """Orthogonal polar factors ``U Vᵀ`` of nonsingular 3x3 matrices ``(N, 3, 3)`` (the nearest rotations), by
    the Newton iteration ``X ← (X + X⁻ᵀ) / 2`` (quadratic convergence), each row until it moves by less than
    1e-16 or 20 times."""
    x = m.copy()
    active = np.arange(x.shape[0])
    for _ in range(20):
        if not active.size:
            break
        a = x[active]
        c = np.empty_like(a)  # cofactor matrix: X⁻ᵀ = cofactors / det
        c[:, 0, 0] = a[:, 1, 1] * a[:, 2, 2] - a[:, 1, 2] * a[:, 2, 1]
        c[:, 0, 1] = a[:, 1, 2] * a[:, 2, 0] - a[:, 1, 0] * a[:, 2, 2]
        c[:, 0, 2] = a[:, 1, 0] * a[:, 2, 1] - a[:, 1, 1] * a[:, 2, 0]
        c[:, 1, 0] = a[:, 0, 2] * a[:, 2, 1] - a[:, 0, 1] * a[:, 2, 2]
        c[:, 1, 1] = a[:, 0, 0] * a[:, 2, 2] - a[:, 0, 2] * a[:, 2, 0]
        c[:, 1, 2] = a[:, 0, 1] * a[:, 2, 0] - a[:, 0, 0] * a[:, 2, 1]
        c[:, 2, 0] = a[:, 0, 1] * a[:, 1, 2] - a[:, 0, 2] * a[:, 1, 1]
        c[:, 2, 1] = a[:, 0, 2] * a[:, 1, 0] - a[:, 0, 0] * a[:, 1, 2]
        c[:, 2, 2] = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
        det = a[:, 0, 0] * c[:, 0, 0] + a[:, 0, 1] * c[:, 0, 1] + a[:, 0, 2] * c[:, 0, 2]
        nxt = 0.5 * (a + c / det[:, None, None])
        moved = np.abs(nxt - a).max(axis=(1, 2))
        x[active] = nxt
        active = active[~(moved < 1e-16)]
    return x


def _is_orthogonal(m: np.ndarray) -> np.ndarray:
    """Per row, SciPy 1.17's test before it orthogonalises: m mᵀ close to I (|Δ| <= 1e-12 + 1e-5 |I|, numpy
    isclose)."""
    ok = np.ones(m.shape[0], dtype=bool)
    for i in range(3):
        for j in range(3):
            g = m[:, i, 0] * m[:, j, 0] + m[:, i, 1] * m[:, j, 1] + m[:, i, 2] * m[:, j, 2]
            e = 1.0 if i == j else 0.0
            ok &= ~(np.abs(g - e) > 1e-12 + 1e-5 * e)
    return ok


def matrix_quats(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) of rotation matrices ``(N, 3, 3)`` as SciPy's ``Rotation.from_matrix`` (hence
    evo) computes them: a matrix that is not orthogonal to 1e-12 is replaced by its orthogonal polar factor, then
    Markley's method (the branch of the largest of the diagonal and the trace). Rotations read from files are
    orthonormal only to their printed digits (KITTI), and this gives evo's angles for them, not just close ones."""
    m = np.asarray(r, dtype=np.float64)
    bad = ~_is_orthogonal(m)
    if bad.any():
        m = m.copy()
        m[bad] = _orthogonal_factor(m[bad])
    n = m.shape[0]
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    c = np.zeros(n, dtype=np.int64)  # argmax of (m00, m11, m22, tr), first on ties
    best = m[:, 0, 0].copy()
    for k in (1, 2):
        up = m[:, k, k] > best
        c[up], best[up] = k, m[up, k, k]
    c[tr > best] = 3
    q = np.empty((n, 4))
    rows = c == 3
    q[rows, 0] = m[rows, 2, 1] - m[rows, 1, 2]
    q[rows, 1] = m[rows, 0, 2] - m[rows, 2, 0]
    q[rows, 2] = m[rows, 1, 0] - m[rows, 0, 1]
    q[rows, 3] = 1.0 + tr[rows]
    for i in range(3):
        rows = np.flatnonzero(c == i)
        j, k = (i + 1) % 3, (i + 2) % 3
        q[rows, i] = 1.0 - tr[rows] + 2.0 * m[rows, i, i]
        q[rows, j] = m[rows, j, i] + m[rows, i, j]
        q[rows, k] = m[rows, k, i] + m[rows, i, k]
        q[rows, 3] = m[rows, k, j] - m[rows, j, k]
    return q / np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2] + q[:, 3] * q[:, 3])[:, None]


def compiled_for(n: int, kernel) -> bool:
    """Whether ``n`` rows take the compiled ``kernel`` (:func:`.kernel_cache.compiled_for`, from this module's
    ``KERNEL_ROWS``)."""
    return kernel_cache.compiled_for(n, kernel, KERNEL_ROWS)


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle of ``a_kᵀ b_k`` per row, through its quaternion (see :func:`matrix_quats`); ``arccos`` of
    the trace would lose ~1e-8 rad at small angles. The products that are orthogonal to 1e-12 (all but
    rotations read from files with few digits) take :func:`_relative_quats`, the others :func:`matrix_quats`;
    the numbers are the same, bit for bit. Rows not :func:`compiled_for` take the array code."""
    a, b = np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64)
    if not compiled_for(a.shape[0], _relative_quats):
        return quat_angles(matrix_quats(relative_rotations(a, b)))
    q = np.empty((a.shape[0], 4))
    bad = np.zeros(a.shape[0], dtype=np.bool_)
    _relative_quats(a, b, q, bad)
    if bad.any():
        q[bad] = matrix_quats(relative_rotations(a[bad], b[bad]))
    return quat_angles(q)


def relative_rotations(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a_kᵀ b_k`` per row.
    Public: tests/test_evaluation.py builds its reference angles from it."""
    m = np.empty((a.shape[0], 3, 3))
    for i in range(3):
        for j in range(3):
            m[:, i, j] = a[:, 0, i] * b[:, 0, j] + a[:, 1, i] * b[:, 1, j] + a[:, 2, i] * b[:, 2, j]
    return m


@njit(cache=True, nogil=True)
def _relative_quats(a, b, q, bad):  # pragma: no cover - compiled
    """:func:`matrix_quats` of ``a_kᵀ b_k`` (the same operations in the same order, one row at a time: on an
    hour of pairs the array version took 0.8 s of a report) into ``q``; rows whose product is not orthogonal
    to 1e-12 (:func:`_is_orthogonal`) are only marked in ``bad``."""
    m = np.empty((3, 3))
    t = np.empty(4)
    for n in range(a.shape[0]):
        for i in range(3):
            for j in range(3):
                m[i, j] = a[n, 0, i] * b[n, 0, j] + a[n, 1, i] * b[n, 1, j] + a[n, 2, i] * b[n, 2, j]
        for i in range(3):
            for j in range(3):
                g = m[i, 0] * m[j, 0] + m[i, 1] * m[j, 1] + m[i, 2] * m[j, 2]
                e = 1.0 if i == j else 0.0
                if abs(g - e) > 1e-12 + 1e-5 * e:
                    bad[n] = True
        if bad[n]:
            continue
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        c = 0  # argmax of (m00, m11, m22, tr), first on ties
        best = m[0, 0]
        for k in (1, 2):
            if m[k, k] > best:
                c, best = k, m[k, k]
        if tr > best:
            t[0] = m[2, 1] - m[1, 2]
            t[1] = m[0, 2] - m[2, 0]
            t[2] = m[1, 0] - m[0, 1]
            t[3] = 1.0 + tr
        else:
            i, j, k = c, (c + 1) % 3, (c + 2) % 3
            t[i] = 1.0 - tr + 2.0 * m[i, i]
            t[j] = m[j, i] + m[i, j]
            t[k] = m[k, i] + m[i, k]
            t[3] = m[k, j] - m[j, k]
        norm = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2] + t[3] * t[3])
        for k in range(4):
            q[n, k] = t[k] / norm


@njit(cache=True, nogil=True)
def _left_products(left, m, out):  # pragma: no cover - compiled
    """``out_k = left @ m_k`` with :func:`fma`'s rounding."""
    for s in range(m.shape[0]):
        for r in range(3):
            for c in range(3):
                out[s, r, c] = fma(left[r, 2], m[s, 2, c], fma(left[r, 1], m[s, 1, c], left[r, 0] * m[s, 0, c]))


def rotated(left: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``left @ m_k`` for each of the ``(N, 3, 3)`` matrices ``m``: ``np.matmul``, where :func:`compiled_for` a
    compiled loop with its rounding (:func:`fma`; NumPy calls BLAS once per 3×3 matrix, ~1 µs each)."""
    m = np.ascontiguousarray(m, dtype=np.float64)
    if m.ndim != 3 or not compiled_for(m.shape[0], _left_products):
        return np.matmul(left, m)
    out = np.empty_like(m)
    _left_products(np.ascontiguousarray(left, dtype=np.float64), m, out)
    return out


#: :class:`RotationRows` keeps the matrices of up to this many rows (72 MB; ~1.5 h of 200 Hz pairs): beyond, a
#: log's report would hold 72 bytes more per pose and pair, and the four-hour log's peak memory grows with it.
MATRICES_KEPT_ROWS = 1 << 20


class RotationRows:
    """Rotation matrices of N poses: ``left @ R_k`` with ``R_k`` from the quaternions ``(x, y, z, w)`` (or the
    matrices as given), for the rows asked for. The matrices of quaternions are built once, for all N rows, at
    the first use, and shared with the :meth:`turned` copies (an hour of pairs is ~26 MB; the report's sections
    asked for them ~16 times over, block by block); the turned rows are built for the rows asked for. The
    arithmetic per row is the same either way, so the numbers are those of the full arrays.
    """

    def __init__(
        self,
        rotation: np.ndarray,
        left: np.ndarray | None = None,
        index: np.ndarray | None = None,
        _built=None,
        _lock=None,
    ) -> None:
        self.rotation = np.asarray(rotation, dtype=np.float64)
        self.left = None if left is None else np.asarray(left, dtype=np.float64)
        self.index = index  # the rows of ``rotation`` these are (pairs refer to their streams' rows)
        self._built = [] if _built is None else _built  # the quaternions' matrices, shared with turned copies
        # the report's threads ask for the same rows at once (segment errors and APE): the matrices built once
        self._lock = threading.Lock() if _lock is None else _lock

    def turned(self, left: np.ndarray) -> RotationRows:
        """The same rows rotated: ``left @ R_k``."""
        return RotationRows(self.rotation, left, self.index, self._built, self._lock)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (len(self), 3, 3)

    def __len__(self) -> int:
        return int((self.rotation if self.index is None else self.index).shape[0])

    def _matrices(self, rows) -> np.ndarray:
        """``R_k`` of ``rows`` (not turned)."""
        if self.rotation.ndim == 3:  # matrices as given: only the rows asked for are gathered
            return self.rotation[rows if self.index is None else self.index[rows]]
        if len(self) > MATRICES_KEPT_ROWS:  # a longer log converts the rows asked for, each time
            q = self.rotation[rows if self.index is None else self.index[rows]]
            return quats_to_rots(np.ascontiguousarray(q[None] if q.ndim == 1 else q))[0 if q.ndim == 1 else slice(None)]
        if not self._built:
            with self._lock:
                if not self._built:
                    q = self.rotation if self.index is None else self.rotation[self.index]
                    self._built.append(quats_to_rots(np.ascontiguousarray(q)))
        return self._built[0][rows]

    def __getitem__(self, rows) -> np.ndarray:
        m = self._matrices(rows)
        single = m.ndim == 2
        m = np.ascontiguousarray(m[None] if single else m)
        if self.left is not None:
            m = rotated(self.left, m)
        return m[0] if single else m

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = self[:]
        return out if dtype is None else out.astype(dtype, copy=False)


def _rotations(r: np.ndarray, name: str) -> np.ndarray:
    out = np.ascontiguousarray(r, dtype=np.float64)
    if out.ndim != 3 or out.shape[1:] != (3, 3):
        raise ValueError(f"{name}: expected an (N, 3, 3) array, got {out.shape}")
    return out


def relative_angles(ref_R: np.ndarray, est_R: np.ndarray) -> np.ndarray:
    """Per-pair rotation angle of ``R_refᵀ R_est`` in radians, in [0, π]."""
    ref, est = _rotations(ref_R, "ref_R"), _rotations(est_R, "est_R")
    if ref.shape != est.shape:
        raise ValueError(f"relative_angles: shapes differ, {ref.shape} and {est.shape}")
    return _angles(ref, est) if ref.shape[0] else np.empty(0)


def ape_rotation_deg(ref_R: np.ndarray, est_R: np.ndarray) -> np.ndarray:
    """Per-pair angle of ``R_refᵀ R_est`` in degrees, in [0, 180] (evo APE, rotation_angle_deg)."""
    return np.degrees(relative_angles(ref_R, est_R))


def _error_pose_norms(relation: str, r_a: np.ndarray, r_b: np.ndarray, t_err: np.ndarray) -> np.ndarray:
    """Error of the pose E with ``R_E = R_aᵀ R_b`` and translation ``t_E = t_err`` under ``relation``."""
    if relation in ("trans_part", "point_distance"):
        return row_norms(t_err)
    if relation in ("angle_deg", "angle_rad"):
        ang = relative_angles(r_a, r_b)
        return np.degrees(ang) if relation == "angle_deg" else ang
    # ‖R_aᵀ R_b − I‖_F = ‖R_b − R_a‖_F for orthogonal R_a; evo forms the product, and so do we
    m = np.einsum("nji,njk->nik", r_a, r_b) - np.eye(3)
    rot_sq = np.einsum("nij,nij->n", m, m)
    if relation == "rot_part":
        return np.sqrt(rot_sq)
    return np.sqrt(rot_sq + np.einsum("ni,ni->n", t_err, t_err))  # full


def ape_errors(
    relation: str, ref_pos: np.ndarray, ref_R: np.ndarray, est_pos: np.ndarray, est_R: np.ndarray
) -> np.ndarray:
    """Absolute pose error per pair (evo APE): ``E = X_est⁻¹ X_ref``, reduced by ``relation`` (one of
    ``POSE_RELATIONS``); positions and rotations are already aligned."""
    _check_relation(relation)
    ref_p, est_p = np.asarray(ref_pos, dtype=np.float64), np.asarray(est_pos, dtype=np.float64)
    if ref_p.shape != est_p.shape or ref_p.ndim != 2 or ref_p.shape[1] != 3:
        raise ValueError(f"ape_errors: expected two (N, 3) position arrays, got {ref_p.shape} and {est_p.shape}")
    if relation in ("trans_part", "point_distance"):
        return row_norms(est_p, ref_p)
    if isinstance(ref_R, RotationRows) or isinstance(est_R, RotationRows):  # block by block, never all at once
        return blockwise(
            lambda rp, rr, ep, er: ape_errors(relation, rp, rr, ep, er), ref_p.shape[0], ref_p, ref_R, est_p, est_R
        )
    est_r = _rotations(est_R, "est_R")
    if relation in ("angle_deg", "angle_rad"):  # the rotation alone
        return _error_pose_norms(relation, est_r, _rotations(ref_R, "ref_R"), np.empty((0, 3)))
    # t_E = R_estᵀ (t_ref − t_est), formed explicitly: rotations read from files (KITTI) are orthonormal only
    # to their printed digits, and evo uses them as they are
    t_err = np.einsum("nji,nj->ni", est_r, ref_p) - np.einsum("nji,nj->ni", est_r, est_p)
    return _error_pose_norms(relation, est_r, _rotations(ref_R, "ref_R"), t_err)


def rpe_errors(
    relation: str,
    ref_pos: np.ndarray,
    ref_R: np.ndarray | None,
    est_pos: np.ndarray,
    est_R: np.ndarray | None,
    i: np.ndarray,
    j: np.ndarray,
) -> np.ndarray:
    """Relative pose error of the pairs ``(i_k, j_k)`` (evo RPE, TUM RGB-D notation): with the relative motions
    ``Q = Q_i⁻¹ Q_j`` (reference) and ``P = P_i⁻¹ P_j`` (estimate), ``E = Q⁻¹ P``, reduced by ``relation``
    (``point_distance`` needs no rotations)."""
    _check_relation(relation)
    i = np.asarray(i, dtype=np.int64)
    j = np.asarray(j, dtype=np.int64)
    rp, ep = np.asarray(ref_pos, dtype=np.float64), np.asarray(est_pos, dtype=np.float64)
    if relation == "point_distance":
        return np.abs(row_norms(rp[i], rp[j]) - row_norms(ep[i], ep[j]))
    if not isinstance(ref_R, RotationRows):
        ref_R = _rotations(ref_R, "ref_R")
    if not isinstance(est_R, RotationRows):
        est_R = _rotations(est_R, "est_R")
    rr_i, rr_j, er_i, er_j = ref_R[i], ref_R[j], est_R[i], est_R[j]  # only the rows of the pairs
    q_rot = np.einsum("nji,njk->nik", rr_i, rr_j)
    p_rot = np.einsum("nji,njk->nik", er_i, er_j)
    q_t = np.einsum("nji,nj->ni", rr_i, rp[j]) - np.einsum("nji,nj->ni", rr_i, rp[i])
    p_t = np.einsum("nji,nj->ni", er_i, ep[j]) - np.einsum("nji,nj->ni", er_i, ep[i])
    # t_E = R_Qᵀ t_P − R_Qᵀ t_Q, formed explicitly (not ‖t_P − t_Q‖): file rotations are orthonormal only to
    # their printed digits, and evo uses them as they are
    t_err = np.einsum("nji,nj->ni", q_rot, p_t) - np.einsum("nji,nj->ni", q_rot, q_t)
    return _error_pose_norms(relation, q_rot, p_rot, t_err)


#: evo's statistics, in the order evo computes them
EVO_STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")
PERCENTILES = (90, 95, 99)


def statistics(errors: np.ndarray, part: np.ndarray | None = None) -> dict[str, float | int]:
    """Summary of an error vector as evo reports it: rmse, mean, median, std (population, ddof=0),
    min, max, sse (sum of squares); plus the count n and the 90/95/99th percentiles (linear interpolation,
    NumPy's default) as p90, p95, p99. Plain Python numbers (JSON-ready). ``part``: the errors' values at
    :func:`statistic_ranks` where the caller has them (:func:`monotone_part`), else put in order here."""
    e = np.asarray(errors, dtype=np.float64).ravel()
    if e.size == 0:
        raise ValueError("statistics: empty error vector")
    # evo's sum of squares; NumPy's pairwise sum, not ``np.dot``: OpenBLAS's ddot sums in another order with two
    # threads than with one, so a report's last digits depended on what ran beside it
    sse = float(np.sum(e * e))
    mean = np.mean(e, keepdims=True)  # np.std's own mean (the same sum and division): handed to it, not summed again
    out: dict[str, float | int] = {
        "rmse": float(np.sqrt(sse / e.size)),
        "mean": float(mean[0]),
        "median": None,
        "std": float(np.std(e, mean=mean)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": sse,
        "n": int(e.size),
    }
    median, percentiles = order_statistics(e, part)
    out["median"] = median
    for p, v in zip(PERCENTILES, percentiles):
        out[f"p{p}"] = float(v)
    return out


def _percentile_ranks(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """NumPy's linear percentile of ``n`` values at ``PERCENTILES``: the virtual index, the ranks below and above
    it (-1 at the last value), and the middle rank(s) of the median."""
    virtual = (n - 1) * np.true_divide(np.asarray(PERCENTILES), 100)
    below = np.floor(virtual)
    below[virtual >= n - 1] = -1
    below = below.astype(np.intp)
    above = np.where(below < 0, -1, below + 1)
    return virtual, below, above, [n // 2 - 1, n // 2] if n % 2 == 0 else [n // 2]


def statistic_ranks(n: int) -> np.ndarray:
    """The rising ranks :func:`order_statistics` needs in order among ``n`` values (first, last: NaN's place,
    the percentiles' neighbours, the median's middle)."""
    _, below, above, middle = _percentile_ranks(n)
    return np.unique(np.concatenate(([0, n - 1], below % n, above % n, middle)))


def monotone_part(part: np.ndarray, f: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """The values at :func:`statistic_ranks` of ``f(e)`` from those of ``e`` (``part``, as :func:`ranked` left
    them), for an elementwise ``f`` that never decreases (a positive scale: rounding keeps the order), so the
    ``k``-th smallest of ``f(e)`` is ``f`` of the ``k``-th smallest of ``e``, bit for bit: no second partition of
    ``f(e)`` (the segment errors' % and per-metre kinds). The other places are left unset."""
    ranks = statistic_ranks(part.shape[0])
    out = np.empty_like(part)
    out[ranks] = f(part[ranks])
    return out


def order_statistics(e: np.ndarray, part: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """``np.median(e)`` and ``np.percentile(e, PERCENTILES)`` (linear) from one copy of ``e`` put in order at the
    ranks they need (:func:`ranked`; or ``part``, its values at those ranks, from :func:`monotone_part`) instead of
    one partition each: NumPy's order statistics are the values at the same ranks, the median the mean of the
    middle one or two, the percentiles NumPy's interpolation (``_lerp``) between the same neighbours with the same
    weights, so the same bits (tested against both). With a NaN, NumPy's own calls."""
    n = e.shape[0]
    virtual, below, above, middle = _percentile_ranks(n)
    if part is None:
        part = ranked(e, statistic_ranks(n))
    if np.isnan(part[-1]):
        return float(np.median(e)), np.percentile(e, PERCENTILES)
    a, b = part[below], part[above]
    gamma = virtual - below
    diff = b - a
    lerp = np.where(gamma >= 0.5, b - diff * (1 - gamma), a + diff * gamma)
    return float(np.mean(part[middle[0] : middle[-1] + 1])), lerp


def median(e: np.ndarray) -> float:
    """``float(np.median(e))`` of a 1-D array of floats or integers, the same bits: from ``RANKED_ROWS`` values
    the middle one or two and the last (NaN's place) put in order by :func:`ranked`, where ``np.median``
    partitions at those two or three ranks at once (an even count of integers or any count of floats, whose last
    rank it adds for NaN; 720,000 floats: ~2 against 8.3 ms). Integers keep their type, as ``np.median`` takes
    their mean."""
    e = np.asarray(e)
    n = e.shape[0] if e.ndim == 1 else 0
    nans = e.dtype.kind == "f"
    if n < RANKED_ROWS or e.dtype.kind not in "fiu" or (n % 2 == 1 and not nans):  # odd integers: one rank
        return float(np.median(e))
    middle = [n // 2 - 1, n // 2] if n % 2 == 0 else [n // 2]
    part = ranked(e, np.asarray([*middle, n - 1] if nans else middle))
    if nans and np.isnan(part[-1]):
        return math.nan
    return float(np.mean(part[middle[0] : middle[-1] + 1]))


#: values from which :func:`ranked` partitions one rank at a time (1,000 values: 0.012 against 0.006 ms at once)
RANKED_ROWS = 4096


def ranked(e: np.ndarray, ranks: np.ndarray) -> np.ndarray:
    """A copy of ``e`` (its type kept) with the values of rising ``ranks`` in place, as ``np.partition(e, ranks)``
    puts them (NaN last), partitioned at one rank at a time over what lies above the rank before: NumPy partitions at a
    single rank with its vectorised selection and at several with its scalar one (360,000 errors, the report's
    nine ranks: ~1.6 against 4.4-6.5 ms; ``benchmarks/order_statistics.py``). Below ``RANKED_ROWS`` values, where
    the loop costs more than it saves, ``np.partition`` itself."""
    if e.shape[0] < RANKED_ROWS:
        return np.partition(e, ranks)
    part = np.array(e, copy=True)
    lo = 0
    for r in ranks:
        rest = part[lo:]  # a view: every value from rank lo on
        rest.partition(int(r) - lo)
        lo = int(r) + 1
    return part


@dataclass(frozen=True)
class LandmarkErrors:
    """Map error after alignment: distances for ids known to both sides, and the ids known to one only."""

    ids: np.ndarray  # (K,) int64, ids with an estimate and a truth, ascending
    errors: np.ndarray  # (K,) metres, ‖s R p̂_i + t − p_i‖
    est_aligned: np.ndarray  # (K, 3) aligned estimates of those ids
    truth: np.ndarray  # (K, 3)
    estimated_without_truth: list[int]
    truth_never_estimated: list[int]


def landmark_errors(
    est_ids: np.ndarray,
    est_xyz: np.ndarray,
    truth: dict[int, np.ndarray],
    rot: np.ndarray,
    trans: np.ndarray,
    scale: float = 1.0,
) -> LandmarkErrors:
    """Distance of each aligned landmark estimate to its true position.

    The estimated map lives in the observer's frame, like the trajectory, so it is moved by the same
    alignment that was fitted on the trajectory (the map is not re-fitted: that would hide map errors).
    """
    ids = np.asarray(est_ids, dtype=np.int64).ravel()
    xyz = np.asarray(est_xyz, dtype=np.float64).reshape(-1, 3)
    if ids.shape[0] != xyz.shape[0]:
        raise ValueError(f"landmark_errors: {ids.shape[0]} ids but {xyz.shape[0]} positions")
    truth_ids = {int(k) for k in truth}
    est_set = {int(i) for i in ids}
    common = np.array(sorted(est_set & truth_ids), dtype=np.int64)
    row_of = {int(i): k for k, i in enumerate(ids)}
    rows = np.array([row_of[int(i)] for i in common], dtype=np.int64)
    aligned = apply_alignment(rot, trans, scale, xyz[rows]) if rows.size else np.empty((0, 3))
    true_xyz = (
        np.array([np.asarray(truth[int(i)], dtype=np.float64).reshape(3) for i in common])
        if common.size
        else np.empty((0, 3))
    )
    return LandmarkErrors(
        ids=common,
        errors=np.linalg.norm(aligned - true_xyz, axis=1) if common.size else np.empty(0),
        est_aligned=aligned,
        truth=true_xyz,
        estimated_without_truth=sorted(est_set - truth_ids),
        truth_never_estimated=sorted(truth_ids - est_set),
    )
