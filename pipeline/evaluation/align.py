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

from slamobs.pipeline.blocks import row_blocks
from slamobs.pipeline.lie import CrossCovariance, nearest_rotation, rots_to_rotvecs, umeyama_fit

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
    "attitude": "attitude: the rotation is the chordal mean of the paired truth and estimate attitudes (R_truth "
    "R_estᵀ), the translation puts the positions' means together; chosen in place of a least-squares fit on the "
    "positions when the truth positions' spread cannot fix a rotation (a rig turning in place, or moving along a line)",
}
#: the alignment :func:`fit_alignment` falls back to when the truth positions cannot fix the rotation of the one
#: asked for (not a kind to ask for: it is chosen, and the report says why)
ATTITUDE = "attitude"
#: the truth positions fix the rotation about an axis when their rms spread across it is over this many times their
#: own noise (:func:`position_noise`): white noise alone spreads ~1x its σ along every axis. Low, because that noise
#: estimate takes in the motion's acceleration · dt² on a sparse truth (TagSLAM test_22's 3.3 Hz reference: 9 mm,
#: its 3.3 cm across its 0.6 m path then 3.6x); a round number, not fitted to a log
SPREAD_OVER_NOISE = 2.0
#: :func:`position_noise` takes the median of at most this many second differences
NOISE_ROWS = 20_000


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
    #: the kind asked for when another was fitted (:data:`ATTITUDE`), and why (None: the kind asked for)
    requested: str | None = None
    why: str | None = None
    #: why the fit is not evo's Umeyama rotation although its kind is (:func:`upright_fit`: a flat truth's fit
    #: that evo turns upside down), None where it is evo's
    upright: str | None = None
    #: evo's own Umeyama fit on the same pairs, an :class:`Alignment` of the same kind, where ``upright`` departs
    #: from it, None elsewhere: what ``evo_ape`` fits (report.json ``evo.departs`` reads its APE through the
    #: report's own path, ``sections.aligned_errors``)
    umeyama: Alignment | None = None

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


def position_noise(p: np.ndarray) -> float:
    """The noise (m, one coordinate's σ) of positions ``p`` (N, 3) in time order: the second differences' median
    absolute coordinate, 1.4826 · median / √6 (white noise of σ gives second differences of σ√6; a smooth motion's
    are its acceleration · dt², small beside it at a dense truth's rate). 0 for fewer than 5 rows. The median of
    at most ``NOISE_ROWS`` second differences, evenly spread (an hour's pairs: ~1 ms, not ~15)."""
    x = np.asarray(p, dtype=np.float64)
    if x.shape[0] < 5:
        return 0.0
    i = np.arange(0, x.shape[0] - 2, max(1, (x.shape[0] - 2) // NOISE_ROWS))
    d2 = x[i + 2] - 2.0 * x[i + 1] + x[i]
    return float(1.4826 * np.median(np.abs(d2)) / np.sqrt(6.0))


def position_spread(p: np.ndarray) -> np.ndarray:
    """The rms spread (m) of positions ``p`` (N, 3) along their three principal axes, largest first: the centred
    positions' singular values over √N, from their covariance's eigenvalues (one pass over the rows)."""
    x = np.asarray(p, dtype=np.float64)
    xc = x - x.mean(axis=0)
    ev = np.linalg.eigvalsh(xc.T @ xc / max(x.shape[0], 1))[::-1]
    return np.sqrt(np.clip(ev, 0.0, None))


def spread_axes(ref_pos: np.ndarray, noise: float | None = None, yaw: bool = False) -> tuple[np.ndarray, float, int]:
    """``(spread, noise, axes)`` of the truth positions ``ref_pos`` (N, 3, time order): their rms spread along their
    principal axes (:func:`position_spread`; the horizontal ones only with ``yaw``), the noise they are judged
    against (``noise``, else :func:`position_noise`, at least 1e-9 of the coordinates' size, for a truth without
    noise) and how many axes spread over ``SPREAD_OVER_NOISE`` times it: 0 for a rig that does not translate."""
    ref = np.asarray(ref_pos, dtype=np.float64)
    spread = position_spread(ref[:, :2] if yaw else ref)
    if noise is None:
        noise = max(position_noise(ref), 1e-9 * (1.0 + float(np.max(np.abs(ref)))))
    return spread, noise, int(np.count_nonzero(spread > SPREAD_OVER_NOISE * noise))


def truth_spread(ref_pos: np.ndarray, yaw: bool = False) -> tuple[np.ndarray, float, int] | None:
    """:func:`spread_axes` of the truth positions ``ref_pos`` (N, 3, time order) against their noise, or None where
    no spread judges them (fewer than 3 rows or a coordinate not finite: the fit's own checks say what is wrong)."""
    ref = np.asarray(ref_pos, dtype=np.float64)
    if ref.shape[0] < 3 or not np.all(np.isfinite(ref)):
        return None
    return spread_axes(ref, yaw=yaw)


def translates(ref_pos: np.ndarray) -> bool:
    """Whether the truth positions ``ref_pos`` (N, 3, time order) spread over their noise along some axis
    (:func:`spread_axes`): False for a rig turning in place, whose positions are one point and its noise."""
    spread = truth_spread(ref_pos)
    return spread is None or spread[2] > 0


def rotation_undetermined(
    ref_pos: np.ndarray, yaw: bool = False, error_m: float | None = None, spread: tuple | None = None
) -> str | None:
    """Why the truth positions ``ref_pos`` (N, 3, time order) cannot fix a rotation, or None when they can. A
    least-squares fit on positions fixes the rotation about an axis only where the positions spread across it: a
    plane or a volume fixes all three axes, a line two (not the turn about itself), a point none. An axis counts
    when the rms spread along it is over ``SPREAD_OVER_NOISE`` times the positions' own noise
    (:func:`position_noise`; at least 1e-9 of the coordinates' size, for a truth without noise). ``yaw``: the
    rotation about z only, which the horizontal positions fix if they spread along one axis (a line). ``error_m``:
    the fit's residual (one coordinate's rms), the scale instead where it is below that noise. ``spread``:
    :func:`truth_spread` of ``ref_pos`` where the caller has it (:func:`fit_alignment`, once for this and
    :func:`upright_fit`)."""
    ref = np.asarray(ref_pos, dtype=np.float64)
    judged = spread if spread is not None else truth_spread(ref, yaw)
    if judged is None:
        return None  # the fit's own checks say what is wrong
    axes_needed = 1 if yaw else 2
    spread, noise, axes = judged
    what = "their noise"
    if error_m is not None and error_m < noise:
        spread, noise, axes = spread_axes(ref, error_m, yaw)
        what = "the fit's residual"
    if axes >= axes_needed:
        return None
    shape = "along a line: they fix no turn about it" if axes == 1 else "about one point: they fix no rotation"
    return (
        f"the truth {'horizontal ' if yaw else ''}positions spread {', '.join(f'{v:.3g}' for v in spread)} m rms "
        "along their principal axes, "
        f"against {what} of {noise:.2g} m (over {SPREAD_OVER_NOISE:g}x it needed along {axes_needed} "
        f"{'axes' if axes_needed > 1 else 'axis'}): they lie {shape}"
    )


def undetermined_fit(ref, est, rot, trans, scale, yaw: bool = False, spread: tuple | None = None) -> str | None:
    """Why a rotation fitted on positions (``rot``, ``trans``, ``scale``: ``ref ≈ s R est + t``; ``rot`` None where
    the fit found the positions degenerate) is not fixed by them: :func:`rotation_undetermined` against the truth
    positions' noise and, only where that says so (seldom: nothing more to compute for a spreading truth), again
    against the fit's residual rms, the estimate's own error. Both must say so: a spread of unordered points
    (second differences as large as the spread) is fixed by an estimate that matches it, and a truth at rest by none.
    ``spread``: :func:`truth_spread` of ``ref`` where the caller has it."""
    why = rotation_undetermined(ref, yaw=yaw, spread=spread)
    if why is None or rot is None:
        return why
    residual = float(np.sqrt(np.mean(np.sum((apply_alignment(rot, trans, scale, est) - ref) ** 2, axis=1) / 3.0)))
    return rotation_undetermined(ref, yaw=yaw, error_m=residual)


def attitude_fit(ref_pos, est_pos, ref_rot, est_rot) -> tuple[np.ndarray, np.ndarray]:
    """``R = argmin Σ ‖R R_est,i − R_ref,i‖²_F``, the chordal mean of ``R_ref,i R_est,iᵀ``, and ``t = μ_ref − R
    μ_est`` (the positions' least-squares translation for that rotation)."""
    r_ref = np.asarray(ref_rot, dtype=np.float64)
    r_est = np.asarray(est_rot, dtype=np.float64)
    rot = nearest_rotation(np.einsum("nij,nkj->ik", r_ref, r_est))
    ref = np.asarray(ref_pos, dtype=np.float64)
    est = np.asarray(est_pos, dtype=np.float64)
    return rot, ref.mean(axis=0) - rot @ est.mean(axis=0)


def world_turns(rots: np.ndarray) -> np.ndarray:
    """The turns between consecutive attitudes ``rots`` (N, 3, 3) in the world frame, the rotation vectors of
    ``R_{i+1} R_iᵀ`` (N − 1, 3): a rig's body frame convention does not change them (``R B`` for ``R``)."""
    return rots_to_rotvecs(np.einsum("nij,nkj->nik", rots[1:], rots[:-1]))


def upright_fit(
    ref, est, rot, scaled, ref_rot, est_rot, axes: int, cc: CrossCovariance
) -> tuple[np.ndarray, np.ndarray, float, str] | None:
    """The least-squares fit of ``ref ≈ s R est + t`` that keeps the estimate's up side up on a flat truth, where
    Umeyama's ``rot`` turns it over: ``(R, t, s, why)``, or None where ``rot`` stands. Truth positions in a plane
    (:func:`spread_axes`: two axes over their noise) give a cross-covariance ``U D Vᵀ`` of rank 2, and two
    rotations fit them: Umeyama's ``U S Vᵀ``, ``S = diag(1, 1, ±1)`` (trace d₁ + d₂), and ``U diag(1, −1, ∓1) Vᵀ``
    (trace d₁ − d₂), the half turn about the plane's first axis away. They map the estimate's out-of-plane axis
    ``V₃`` to the plane's normal ``U₃`` with opposite signs, the second being the first composed with an in-plane
    mirror: Umeyama's wins whenever the estimate's in-plane path is nearer the truth's mirror image than the truth
    (det of the in-plane cross-covariance below 0), a question of the estimate's error, not of its frame. A
    rigid estimate has no mirror, so the side is the attitudes' to say: the one on which the estimate turns about
    ``V₃`` as the truth turns about ``U₃`` (the sign of ``Σ (U₃ · ω_ref,i)(V₃ · ω_est,i)`` over
    :func:`world_turns`, which a body frame convention does not change); where they say the other, the second
    rotation is the fit (scale ``(d₁ − d₂ ∓ d₃)/σ²_est``). ``axes``: the truth's :func:`spread_axes` count, ``cc``:
    the decomposition Umeyama's fit made (:func:`~slamobs.pipeline.lie.umeyama_fit`; its ``σ²_est`` when
    ``scaled``), both as :func:`fit_alignment` computed them."""
    if ref_rot is None or est_rot is None or len(ref_rot) < len(ref) or len(est_rot) < len(ref) or len(ref) < 3:
        return None
    if axes != 2:
        return None
    u, d, vt = cc.u, cc.d, cc.vt
    turns = float(np.sum((world_turns(ref_rot[: len(ref)]) @ u[:, 2]) * (world_turns(est_rot[: len(ref)]) @ vt[2])))
    if turns * float(u[:, 2] @ rot @ vt[2]) >= 0.0:
        return None  # Umeyama's side is the turns' (or neither side turns)
    sign = np.sign(np.linalg.det(u) * np.linalg.det(vt)) or 1.0
    flip = np.array([1.0, -1.0, -sign])
    turned = u @ np.diag(flip) @ vt
    scale = float(d @ flip / cc.var_src) if scaled else 1.0
    why = (
        f"the truth positions lie in a plane, which the estimate's positions fit as well turned over (a half turn "
        f"about an in-plane axis and a mirror within the plane); evo's Umeyama rotation turns the estimate's z axis "
        f"{gravity_tilt_deg(rot):.1f} deg off the truth's, the estimate then turning against the truth's turns, so "
        f"the fit is the least-squares one on the side where it turns with them (its z axis "
        f"{gravity_tilt_deg(turned):.1f} deg off; alignment_transformation_sim3 is this fit, not evo's)"
    )
    return turned, cc.mu_dst - scale * turned @ cc.mu_src, scale, why


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
    spread_check: bool = True,
) -> Alignment:
    """Fit ``kind`` (one of ``KINDS``) on associated pairs; ``n`` limits the fit to the first ``n`` pairs
    (evo ``--n_to_align``). ``origin`` needs the rotations of the first pair, and so does ``yaw`` fitted on one
    pair (as rpg_trajectory_evaluation's posyaw with ``align_num_frames: 1``). Where the truth positions cannot fix
    the rotation of ``se3`` or ``sim3`` (:func:`rotation_undetermined`), the fit is :data:`ATTITUDE` with the
    rotations of all pairs given, else a ``ValueError`` saying why (a rotation fitted to the noise is no measure);
    ``spread_check=False`` fits as evo does whatever the spread (a refit of a fit that passed the check)."""
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
    checked = spread_check and kind in ("se3", "sim3", "yaw")
    spread = truth_spread(ref[:m], yaw=kind == "yaw") if checked else None  # once: the checks' and upright_fit's
    cc = None
    try:
        if kind == "yaw":
            rot, trans, scale = (*yaw_fit(est[:m], ref[:m]), 1.0)
        else:
            rot, trans, scale, cc = umeyama_fit(est[:m], ref[:m], with_scale=kind in SCALED_ALIGNMENTS)
    except ValueError:  # degenerate positions: said as the spread says it, where it does
        if not checked or rotation_undetermined(ref[:m], yaw=kind == "yaw", spread=spread) is None:
            raise
        rot, trans, scale = None, None, 1.0
    why = undetermined_fit(ref[:m], est[:m], rot, trans, scale, kind == "yaw", spread) if checked else None
    if why and kind == "yaw":
        raise ValueError(f"yaw alignment: {why}")
    if why:
        if ref_rot is None or est_rot is None or len(ref_rot) < m or len(est_rot) < m:
            raise ValueError(f"{kind} alignment: {why}")
        rot, trans = attitude_fit(ref[:m], est[:m], ref_rot[:m], est_rot[:m])
        return Alignment(ATTITUDE, rot, trans, 1.0, m, _sim3(rot, trans, 1.0), kind, why)
    up = None
    if checked and kind != "yaw" and spread is not None:
        up = upright_fit(ref[:m], est[:m], rot, kind == "sim3", ref_rot, est_rot, spread[2], cc)
    if up is not None:
        evo_fit = Alignment(kind, rot, trans, scale, m, _sim3(rot, trans, scale))
        rot, trans, scale, upright = up
        return Alignment(kind, rot, trans, scale, m, _sim3(rot, trans, scale), upright=upright, umeyama=evo_fit)
    evo = _sim3(rot, trans, scale)
    if kind == "yaw":
        return Alignment(kind, rot, trans, 1.0, m, evo)
    if kind == "scale":
        return Alignment(kind, np.eye(3), np.zeros(3), scale, m, evo)
    return Alignment(kind, rot, trans, scale, m, evo)


def batch_sums(x: np.ndarray) -> np.ndarray:
    """The sums of the rows of ``x`` (N, k, time order) over ⌊√N⌋ runs of consecutive rows of near-equal length
    (batch means' usual count: batches grow with the log, so that an error correlated along the path falls
    mostly within one, and their number grows too, so that their spread is an estimate)."""
    n = x.shape[0]
    b = max(int(np.sqrt(n)), 1)
    return np.add.reduceat(x, np.linspace(0, n, b + 1).astype(np.intp)[:-1], axis=0)


def turn_normal(q: np.ndarray) -> np.ndarray:
    """``Σ (|q|² I − q qᵀ)`` of the points ``q`` (N, 3, centred on the turn's centre): the normal matrix of the
    small turn ``δ`` in a least-squares fit of ``q`` (``r + δ × q``); zero about an axis they do not spread
    across."""
    q = np.asarray(q, dtype=np.float64)
    return float(np.sum(q * q)) * np.eye(3) - q.T @ q


def fit_weight(q: np.ndarray, r: np.ndarray) -> float:
    """The weight (per m² of squared residual) of a least-squares fit of the points ``q`` (N, 3, time order, the
    fitted side centred on the turn's centre) with residuals ``r`` (fitted − target): ``1 / (σ² f)``, so that
    ``weight · turn_normal(q)`` is the inverse covariance (rad⁻²) of the turn it fixes. ``σ²`` is the residuals'
    variance per coordinate, ``f`` (at least 1) how much more the gradient ``Σ q × r`` varies than that of
    independent residuals (``σ² tr H``): the trace of its covariance from :func:`batch_sums` over it (residuals
    correlated along the path count as the batches they fill, not as their rows). One scalar, not a 3x3
    covariance of the batches: a short log's few batches fix one number, not six."""
    q = np.asarray(q, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    var = max(float(np.mean(r * r)), 1e-300)
    g = batch_sums(np.cross(q, r))
    b, trace = g.shape[0], 2.0 * float(np.sum(q * q))
    f = 1.0
    if b >= 2 and trace > 0.0:
        g = g - g.mean(axis=0)  # the fit's gradient sums to 0 at its optimum: the batches' spread about it
        f = max(1.0, float(np.sum(g * g)) * b / (b - 1.0) / (var * trace))
    return 1.0 / (var * f)


def _standard_errors_deg(info: np.ndarray, axes: np.ndarray) -> list[float | None]:
    """The standard error (deg) of the turn about each of ``axes`` (rows) under the inverse covariance ``info``
    (None about an axis it does not fix: information under 1e-12 of its largest)."""
    cov = np.linalg.pinv(info, rcond=1e-12)
    top = max(float(np.max(np.linalg.eigvalsh(info))), 0.0)
    out: list[float | None] = []
    for a in axes:
        fixed = float(a @ info @ a) > 1e-12 * top
        out.append(float(np.degrees(np.sqrt(max(float(a @ cov @ a), 0.0)))) if fixed else None)
    return out


def rotation_fix(ref, est, al: Alignment, ref_rot=None, est_rot=None, planar: bool = False) -> dict | None:
    """How well the positions fix the rotation of the least-squares fit ``al`` (se3 or sim3 of ``ref ≈ s R est +
    t``, N pairs in time order), and the fit that weighs the attitudes too; None for another kind or < 9 pairs.

    ``axes`` are the truth positions' principal axes (rows, largest spread first, ``spread_m`` the rms along each),
    ``positions_se_deg`` the standard error of the fit's turn about each (:func:`fit_weight` · :func:`turn_normal`
    of the aligned estimate's positions about their centre). The attitudes fix the same rotation through the
    world turns (:func:`world_turns`, which a body frame convention does not change; taken a block of rows at a
    time, no (N, 3, 3) array held): ``ω_ref,i ≈ R ω_est,i``, the
    least-squares (Procrustes) fit of these vectors, whose turn about each axis has ``turns_se_deg``.
    ``weak_axes``: the axes about which the positions fix the turn less well than the turns do, of those the estimate
    has freedom in: on a ``planar`` run (estimate and truth level, ``TrajectoryEvaluation.planar``) only the principal
    axis nearest the estimate's vertical as aligned (``al.rot``'s z column). A level estimate holds its roll and pitch
    at zero, unestimated: its world turns are all about its vertical, and their fit fixes a tilt only by that level,
    as exactly as it holds, while a flat path's positions fix it by their spread: every planar run read "weak" about
    both horizontal axes (28 of MR.CLAM's 30), which the 4-DoF alignment a planar run gets already answers.
    ``weighed``: the least-squares fit of both at once, each term weighted by its :func:`fit_weight` (``R`` the
    rotation nearest ``w_p s Σ (p_ref − μ_ref)(p_est − μ_est)ᵀ + w_t Σ ω_ref ω_estᵀ``, the translation putting the
    means together, the scale kept), with ``turn_deg``, how far it turns the estimate from ``al``. Without
    rotations: the positions' part alone."""
    if al.kind not in ("se3", "sim3"):
        return None
    ref = np.asarray(ref, dtype=np.float64)
    est = np.asarray(est, dtype=np.float64)
    if ref.shape[0] < 9:
        return None
    centred = ref - ref.mean(axis=0)
    values, vectors = np.linalg.eigh(centred.T @ centred / ref.shape[0])
    axes = vectors[:, ::-1].T  # largest spread first
    aligned = al.positions(est)
    q = aligned - aligned.mean(axis=0)
    weight_p = fit_weight(q, aligned - ref)
    info_p = weight_p * turn_normal(q)
    out: dict = {
        "axes": [[float(v) for v in a] for a in axes],
        "spread_m": [float(np.sqrt(max(v, 0.0))) for v in values[::-1]],
        "n_batches": int(batch_sums(ref[:, :1]).shape[0]),
        "positions_se_deg": _standard_errors_deg(info_p, axes),
        "turns_se_deg": None,
        "weak_axes": [],
        "weighed": None,
    }
    if ref_rot is None or est_rot is None or len(ref_rot) < len(ref) or len(est_rot) < len(ref):
        return out
    w_ref, w_est = (
        np.concatenate([world_turns(r[b.start : b.stop + 1]) for b in row_blocks(len(ref))]) for r in (ref_rot, est_rot)
    )
    turns = w_est @ nearest_rotation(w_ref.T @ w_est).T
    weight_t = fit_weight(turns, turns - w_ref)
    info_t = weight_t * turn_normal(turns)
    se_t, se_p = _standard_errors_deg(info_t, axes), out["positions_se_deg"]
    out["turns_se_deg"] = se_t
    free = range(3) if not planar else [int(np.argmax(np.abs(axes @ np.asarray(al.rot)[:, 2])))]
    out["weak_axes"] = [k for k in free if se_t[k] is not None and (se_p[k] is None or se_p[k] > se_t[k])]
    m = weight_p * al.scale * (centred.T @ (est - est.mean(axis=0))) + weight_t * (w_ref.T @ w_est)
    weighed = nearest_rotation(m)
    trans = ref.mean(axis=0) - al.scale * weighed @ est.mean(axis=0)
    out["weighed"] = {
        "alignment": Alignment(al.kind, weighed, trans, al.scale, al.n_points, _sim3(weighed, trans, al.scale)),
        "turn_deg": float(np.degrees(np.linalg.norm(rots_to_rotvecs((weighed @ np.asarray(al.rot).T)[None])[0]))),
    }
    return out
