"""Alignment of an estimated trajectory onto the reference frame before its error is measured.

(Not to be confused with :mod:`pipeline.alignment`, which puts sensor streams on one time base.) A SLAM
estimate is defined only up to the transformations its sensors cannot observe: a rigid transform without
absolute references (docs/observers.md §1.1), a similarity for monocular vision, translation and yaw when
gravity is observed. Each alignment here removes exactly one such group, fitted by least squares on associated
positions, as evo 1.38.1 does for ``-a``, ``-as``, ``-s`` and ``--align_origin``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamobs.pipeline.lie import umeyama

KINDS = ("se3", "sim3", "scale", "yaw", "origin", "none")
#: Other names of the same alignments: rpg_trajectory_evaluation's ``align_type`` (its eval_cfg.yaml) calls the
#: 4-DoF one ``posyaw``. Accepted wherever an alignment is chosen; reports name the kind as in ``KINDS``.
ALIASES = {"posyaw": "yaw"}
NAMES = KINDS + tuple(ALIASES)
#: the alignments that fit a scale (the others' is 1)
SCALED_ALIGNMENTS = ("sim3", "scale")

DESCRIPTIONS = {
    "se3": "SE(3) Umeyama (least squares rotation + translation, no scale) on the associated positions (evo -a)",
    "sim3": "Sim(3) Umeyama (least squares rotation + translation + scale) on the associated positions (evo -as)",
    "scale": "scale only, the Umeyama Sim(3) scale applied to the estimate positions (evo -s without -a)",
    "yaw": "4-DoF: translation + rotation about the z (gravity) axis, least squares on the associated positions "
    "(rpg_trajectory_evaluation posyaw); for estimates whose roll and pitch are observed (IMU directions)",
    "origin": "origin: the first associated estimate pose is moved onto the first reference pose (evo --align_origin)",
    "none": "none: the estimate is compared in its own frame (evo without -a)",
}


@dataclass(frozen=True)
class Alignment:
    """``p_ref ≈ scale · rot · p_est + trans`` and ``R_ref ≈ rot · R_est``."""

    kind: str
    rot: np.ndarray  # (3, 3)
    trans: np.ndarray  # (3,)
    scale: float
    n_points: int  # associated pairs the fit used (0 for "none")
    #: the 4x4 matrix evo stores as ``alignment_transformation_sim3`` (for "scale" evo stores the whole Umeyama
    #: fit although it applies only the scale)
    evo_matrix: np.ndarray | None = None

    def positions(self, p: np.ndarray) -> np.ndarray:
        return apply_alignment(self.rot, self.trans, self.scale, p)

    def rotations(self, r: np.ndarray) -> np.ndarray:
        return np.matmul(self.rot, np.asarray(r, dtype=np.float64))

    @property
    def matrix(self) -> np.ndarray:
        """The applied transform as a 4x4 Sim(3) matrix ``[[s R, t], [0, 1]]``."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rot
        m[:3, 3] = self.trans
        return m


#: a tilt (:func:`gravity_tilt_deg`) over this is an alignment that turned the estimate upside down, as the report's
#: note and the figures' titles say
UPSIDE_DOWN_DEG = 90.0


def gravity_tilt_deg(rot: np.ndarray) -> float:
    """How far (degrees) the rotation ``rot`` turns the z (gravity) axis: 0 for a rotation about z only (the 4-DoF
    alignment's), 180 for one that turns the estimate upside down."""
    return float(np.degrees(np.arccos(np.clip(np.asarray(rot, dtype=np.float64)[2, 2], -1.0, 1.0))))


def yaw_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``dst ≈ R_z(θ) src + t`` (rotation about z only): with centred points,
    ``θ = atan2(Σ (x_s y_d − y_s x_d), Σ (x_s x_d + y_s y_d))`` and ``t = μ_dst − R_z μ_src``."""
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape != y.shape or x.shape[0] < 2:
        raise ValueError(f"yaw alignment: need two (N >= 2, 3) arrays, got {x.shape} and {y.shape}")
    mu_x, mu_y = x.mean(axis=0), y.mean(axis=0)  # each mean once (a pass over all pairs each)
    x0, x1 = x[:, 0] - mu_x[0], x[:, 1] - mu_x[1]  # the centred horizontal columns only: z is not used
    y0, y1 = y[:, 0] - mu_y[0], y[:, 1] - mu_y[1]
    s = float(np.sum(x0 * y1 - x1 * y0))
    c = float(np.sum(x0 * y0 + x1 * y1))
    if abs(s) + abs(c) <= 1e-300:
        raise ValueError("yaw alignment: the horizontal positions do not vary, the yaw is undetermined")
    th = np.arctan2(s, c)
    rot = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    return rot, mu_y - rot @ mu_x


def yaw_fit_first(ref_pos0, est_pos0, ref_rot0, est_rot0) -> tuple[np.ndarray, np.ndarray]:
    """The 4-DoF alignment from one pose pair (rpg_trajectory_evaluation ``alignPositionYawSingle``): the yaw
    maximising ``trace(R_z(θ) R_est R_refᵀ)``, then the translation that puts the first positions together."""
    c = np.asarray(est_rot0, dtype=np.float64) @ np.asarray(ref_rot0, dtype=np.float64).T
    th = np.arctan2(c[0, 1] - c[1, 0], c[0, 0] + c[1, 1])
    rot = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    return rot, np.asarray(ref_pos0, dtype=np.float64) - rot @ np.asarray(est_pos0, dtype=np.float64)


def canonical(kind: str) -> str:
    """The alignment ``kind`` (any of ``NAMES``) as ``KINDS`` spells it."""
    name = ALIASES.get(kind, kind)
    if name not in KINDS:
        raise ValueError(f"alignment must be one of {NAMES}, got {kind!r}")
    return name


def apply_alignment(rot: np.ndarray, trans: np.ndarray, scale: float, points: np.ndarray) -> np.ndarray:
    """``s R p + t`` for each row ``p`` of an ``(N, 3)`` array. A scale of 1 multiplies nothing (``1.0 · x`` is
    ``x``, bit for bit) and the translation is added in place: the same numbers with two passes fewer over the
    rows (the report moves all pairs by each alignment, block by block)."""
    p = np.asarray(points, dtype=np.float64)
    out = (p if scale == 1.0 else scale * p) @ np.asarray(rot).T
    if out.ndim and np.ndim(trans) <= 1:  # one translation for all rows
        out += trans
        return out
    return out + trans


def _sim3(rot: np.ndarray, trans: np.ndarray, scale: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = scale * rot
    m[:3, 3] = trans
    return m


def fit_alignment(
    kind: str,
    ref_pos: np.ndarray,
    est_pos: np.ndarray,
    ref_rot: np.ndarray | None = None,
    est_rot: np.ndarray | None = None,
    n: int | None = None,
) -> Alignment:
    """Fit ``kind`` (one of ``KINDS``) on associated pairs; ``n`` limits the fit to the first ``n`` pairs
    (evo ``--n_to_align``). ``origin`` needs the rotations of the first pair, and so does ``yaw`` fitted on one
    pair (as rpg_trajectory_evaluation's posyaw with ``align_num_frames: 1``)."""
    kind = canonical(kind)
    ref = np.asarray(ref_pos, dtype=np.float64)
    est = np.asarray(est_pos, dtype=np.float64)
    m = ref.shape[0] if n is None or n < 0 else min(int(n), ref.shape[0])
    if kind == "none":
        return Alignment(kind, np.eye(3), np.zeros(3), 1.0, 0, None)
    if m == 0:
        raise ValueError("alignment: no associated poses")
    if kind == "origin":
        if ref_rot is None or est_rot is None:
            raise ValueError("origin alignment needs the rotations")
        rot = np.asarray(ref_rot[0]) @ np.asarray(est_rot[0]).T
        trans = ref[0] - rot @ est[0]
        return Alignment(kind, rot, trans, 1.0, 1, _sim3(rot, trans, 1.0))
    if kind == "yaw" and m == 1 and ref_rot is not None and est_rot is not None:
        rot, trans = yaw_fit_first(ref[0], est[0], ref_rot[0], est_rot[0])
        return Alignment(kind, rot, trans, 1.0, 1, _sim3(rot, trans, 1.0))
    if kind == "yaw":
        rot, trans = yaw_fit(est[:m], ref[:m])
        return Alignment(kind, rot, trans, 1.0, m, _sim3(rot, trans, 1.0))
    rot, trans, scale = umeyama(est[:m], ref[:m], with_scale=kind in SCALED_ALIGNMENTS)
    evo = _sim3(rot, trans, scale)
    if kind == "scale":
        return Alignment(kind, np.eye(3), np.zeros(3), scale, m, evo)
    return Alignment(kind, rot, trans, scale, m, evo)
