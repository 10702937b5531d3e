"""Algorithm E: the hybrid (synergistic) SLAM observer of Hashemi & Mattila as reconstructed in
docs/observers.md §8.2.

Landmarks alone carry no attitude information (docs/observers.md §1.1, §8.2), so the hybrid needs at least
two inertial directions: gravity from the accelerometer and the magnetic field (a third is their normalised cross
product). The flow is algorithm D plus the direction innovation (:mod:`pipeline.observers.wang_tayebi`,
one kernel for both); the direction inputs are algorithm C's (:mod:`pipeline.directions`: weights,
cross product, gravity re-compensated with the bias estimates, initial attitude by Wahba). This module
holds the switching design: the candidate rotations ``R_q = R_a(2π/3, u_q)`` about the eigen-axes ``u_q``
of ``A_v = Σ ρ_j a_j a_jᵀ``, the synergy gap Δ* and the hysteresis δ; the kernel jumps ``R̂ ← R_q*ᵀ R̂``
(pose and whole map) when ``μ = Φ(R̂) − min_q Φ(R_qᵀR̂) ≥ δ``, at most once per sample.

The measured directions change every sample but the design must not: A_v, the candidates and Δ* come
from the inertial reference directions with the nominal weight ρ (per-sample trust 1). A down-weighted
sample scales Φ and every ``Φ(R_qᵀR̂)`` alike, which only makes jumps rarer; a jump still lowers Φ by
at least δ.
"""

from __future__ import annotations

import math

import numpy as np

from slamobs.pipeline.directions import direction_arrays, first_attitude
from slamobs.pipeline.lie import so3_exp
from slamobs.pipeline.observers.base import GainError, GainSpec, ObserverOptions, ObserverSpec
from slamobs.pipeline.observers.wang_tayebi import FLOW_GAINS, Flow

NAME = "hybrid"
#: Rotation angle of the candidates (Wang–Tayebi's θ_q).
CANDIDATE_ANGLE = 2.0 * math.pi / 3.0
#: Eigenvalues closer than this (relative to tr A_v) span one eigenspace: its π-rotations form a continuum.
EIGEN_TOL = 1e-3
#: Grid resolution for degenerate eigenspaces: axes per half circle (a 3-D eigenspace gets GRID²/2 axes).
GRID = 360
#: Below this (relative to tr A_v) there is no usable gap: the switching would not be synergistic.
MIN_GAP = 1e-3


def _canonical_axes(a_v: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and eigen-axes of ``A_v`` with signs fixed by the reference directions.

    An eigenvector's sign is arbitrary but ``R_a(θ, −u) ≠ R_a(θ, u)``: each axis is turned towards the
    reference direction it is most aligned with, and one orthogonal to all of them completes a
    right-handed frame. The candidates then rotate with the inertial frame (frame invariance).
    """
    lam, vec = np.linalg.eigh(a_v)
    vec = vec.copy()
    free = []
    for q in range(3):
        proj = ref @ vec[:, q]
        j = int(np.argmax(np.abs(proj)))
        if abs(proj[j]) > 1e-9:
            vec[:, q] *= np.sign(proj[j])
        else:
            free.append(q)
    if len(free) == 1:
        q = free[0]
        if np.linalg.det(vec) < 0:
            vec[:, q] = -vec[:, q]
    return lam, vec


def candidates(a_v: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The candidate set ``R_q = R_a(2π/3, u_q)`` (3, 3, 3), ``u_q`` the eigen-axes of ``A_v``."""
    _, vec = _canonical_axes(a_v, ref)
    return np.array([so3_exp(CANDIDATE_ANGLE * vec[:, q]) for q in range(3)])  # R_a(θ, u), ‖u‖ = 1


def _potential(a_v: np.ndarray, r_err: np.ndarray) -> np.ndarray:
    """``Φ = tr(A_v (I − R̃))`` for a stack of attitude errors ``R̃ = R̂Rᵀ`` (exact measurements)."""
    return np.trace(a_v) - np.einsum("ij,...ji->...", a_v, r_err)


def _eigenspaces(lam: np.ndarray) -> list[list[int]]:
    tol = EIGEN_TOL * max(float(np.sum(np.abs(lam))), 1e-300)
    groups: list[list[int]] = [[0]]
    for q in (1, 2):
        (groups[-1].append(q) if lam[q] - lam[groups[-1][-1]] <= tol else groups.append([q]))
    return groups


def _grid_axes(basis: np.ndarray) -> np.ndarray:
    """Unit axes covering the span of ``basis`` (3, d) up to sign: a half circle or a hemisphere."""
    d = basis.shape[1]
    if d == 1:
        return basis.T
    if d == 2:
        a = np.linspace(0.0, math.pi, GRID, endpoint=False)
        return np.outer(np.cos(a), basis[:, 0]) + np.outer(np.sin(a), basis[:, 1])
    # Fibonacci points on the upper hemisphere (π-rotations about u and −u coincide).
    n = GRID * GRID // 2
    k = np.arange(n) + 0.5
    z = 1.0 - k / n
    r = np.sqrt(1.0 - z * z)
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    local = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    return local @ basis.T


def synergy_gap(a_v: np.ndarray, cand: np.ndarray) -> float:
    """Δ* (docs/observers.md §8.2): min over the undesired critical points ``R_a(π, u)`` of
    ``Φ − min_q Φ(R_qᵀ·)``.

    The critical points are π-rotations about eigen-axes of ``A_v``; where eigenvalues repeat they form
    a continuum, evaluated on a grid of axes of that eigenspace.
    """
    lam, vec = np.linalg.eigh(a_v)
    axes = np.vstack([_grid_axes(vec[:, g]) for g in _eigenspaces(lam)])
    r_pi = 2.0 * np.einsum("ki,kj->kij", axes, axes) - np.eye(3)  # R_a(π, u) = 2uuᵀ − I
    phi = _potential(a_v, r_pi)
    phi_q = np.min([_potential(a_v, np.einsum("ji,kjl->kil", c, r_pi)) for c in cand], axis=0)
    return float(np.min(phi - phi_q))


def switching_design(ref: np.ndarray, rho: float, delta_fraction: float) -> tuple[np.ndarray, float, float]:
    """Candidates, Δ* and δ = fraction × Δ* from the reference directions with nominal weights."""
    a_v = rho * np.einsum("ji,jk->ik", ref, ref)
    cand = candidates(a_v, ref)
    gap = synergy_gap(a_v, cand)
    if gap <= MIN_GAP * float(np.trace(a_v)):
        lam = np.linalg.eigvalsh(a_v)
        raise GainError(
            f"observer '{NAME}': the inertial directions give A_v eigenvalues "
            f"{', '.join(f'{x:.3g}' for x in lam)} and no synergy gap (Delta* = {gap:.2g}); "
            "repeated eigenvalues need directions that are not orthogonal with equal weights"
        )
    return cand, gap, delta_fraction * gap


def check_gains(gains: dict[str, float]) -> None:
    """δ must lie inside the gap: ``0 < delta_fraction < 1``."""
    frac = gains["delta_fraction"]
    if not 0.0 < frac < 1.0:  # the GainSpec's limit
        raise GainError(f"gain delta_fraction of observer '{NAME}' must be in (0, 1), got {frac!r}")


def start(stream, gains: dict[str, float], options: ObserverOptions) -> Flow:
    """Algorithm E on an aligned stream; every jump goes to ``extra_tables["jumps"]``.

    R̂(0) is the Wahba attitude of the first usable direction sample (as algorithm C): a log's initial
    heading is arbitrary, and correcting it later would rotate the map built so far about the vehicle.
    """
    check_gains(gains)
    if stream.directions is None or len(stream.directions.names) < 2:
        have = stream.directions.names if stream.directions is not None else ()
        raise ValueError(f"{NAME} needs 2 inertial directions, the stream has {len(have)}")
    ref, body, trust, gscale, make_cross = direction_arrays(stream.directions, {})
    dirs = (ref, body, gains["rho"] * trust, gscale, make_cross)
    cand, gap, delta = switching_design(ref, gains["rho"], gains["delta_fraction"])
    flow = Flow(stream, gains, options, dirs, first_attitude(*dirs), cand, delta, jumps=True)
    flow.stats.update({"jumps": 0, "synergy_gap": gap, "delta": delta})
    return flow


SPEC = ObserverSpec(
    name=NAME,
    algorithm="E",
    paper="Hashemi, Mattila: A Global Asymptotic Convergent Observer for SLAM (arXiv 2205.01953; switching "
    "after Wang, Tayebi, IEEE TAC 2019)",
    summary="D + inertial attitude innovation from gravity and magnetic field (map co-rotates) + synergistic "
    "jumps about the eigen-axes of A_v",
    gains=FLOW_GAINS
    + (
        GainSpec("rho", 1.0, "weight rho_j of each inertial direction (times its per-sample trust)", (0.1, 10.0)),
        GainSpec(
            "delta_fraction",
            0.5,
            "hysteresis delta as a fraction of the synergy gap Delta* (< 1)",
            (0.05, 0.95),
            limit=lambda _gains: 1.0,
        ),
    ),
    start=start,
    min_directions=2,
    check_gains=check_gains,
)
