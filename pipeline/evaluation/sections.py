"""The report's sections, one class each: APE, APE under each alignment, RPE, drift, clock offset, landmark map,
biases, convergence, uncertainty (NEES of the reference estimators' covariance).

Each is built with its options, computes from the data in :meth:`process_data` and gives its ``report.json``
section in :meth:`get_statistic` (the shape of evo's ``core/metrics.py`` metric classes); :attr:`notes` are
what it found worth saying in the report's notes, :attr:`METHOD` how its numbers are obtained. The sections
are pure: tables and the :class:`~.trajectory_evaluation.TrajectoryEvaluation` in, JSON-ready dicts out.
"""

from __future__ import annotations

import re
from dataclasses import replace
from collections.abc import Callable
from typing import Any

import numpy as np

from slamobs.pipeline.blocks import rms_sigmas, row_blocks
from slamobs.pipeline.evaluation import metrics, slam_metrics
from slamobs.pipeline.evaluation.align import (
    UPSIDE_DOWN_DEG,
    ATTITUDE,
    DESCRIPTIONS,
    SCALED_ALIGNMENTS,
    Alignment,
    apply_alignment,
    batch_sums,
    fit_alignment,
    gravity_tilt_deg,
    rotation_fix,
    translates,
)
from slamobs.pipeline.evaluation.drift import segment_drift, segment_errors
from slamobs.pipeline.evaluation.rpe import accumulated_distances
from slamobs.pipeline.evaluation.sync import NS_PER_S, PEAK_CORRELATION_MIN, TimeOffset, halves_agree, halves_owner
from slamobs.pipeline.evaluation.tables import (
    GYRO_COLUMNS,
    VEL_COLUMNS,
    Table,
    column,
    column_names,
    landmark_covariances,
    landmark_table,
    n_rows,
    require_columns,
    time_order,
)
from slamobs.pipeline.evaluation.trajectory_error import Paired, RpeOptions, AlignOptions, rpe
from slamobs.pipeline.evaluation.trajectory_evaluation import (
    GAUGE_SIGMA,
    axes_with_error,
    nees_values,
    paired_uncertainty,
    PLANAR_TILT_DEG,
    ReportOptions,
    TrajectoryEvaluation,
    turned_truth,
)
from slamobs.pipeline.lie import nearest_rotation, rots_to_quats, umeyama
from slamobs.pipeline.streams import PoseStream

#: evo's command-line flags of each alignment slamobs shares with it
EVO_ALIGN_FLAGS = {"se3": " -a", "sim3": " -as", "scale": " -s", "origin": " --align_origin", "none": ""}


def alignment_dict(al: Alignment) -> dict[str, Any]:
    """An alignment as the report states it."""
    return {
        "type": al.kind,
        "description": DESCRIPTIONS[al.kind],
        "n_points": int(al.n_points),
        "rotation_quat_xyzw": [float(v) for v in rots_to_quats(np.asarray(al.rot, dtype=np.float64)[None])[0]],
        "rotation_matrix": [[float(v) for v in row] for row in al.rot],
        "translation_m": [float(v) for v in al.trans],
        "scale": float(al.scale),
        "gravity_tilt_deg": gravity_tilt_deg(al.rot),
    } | ({"requested": al.requested, "why": al.why} if al.requested else {})


class Section:
    """One section of the report: :meth:`process_data` computes it, :meth:`get_statistic` gives it."""

    METHOD: dict[str, str] = {}  # its entries of the report's ``method``

    def __init__(self) -> None:
        self.notes: list[str] = []
        self.result: dict[str, Any] | None = None

    def get_statistic(self) -> dict[str, Any] | None:
        return self.result


class ApeSection(Section):
    """The APE (translation and rotation) after the report's alignment: the evaluation computed it already."""

    METHOD = {
        "ape_translation": "per pair ‖(s R p_est + t) − p_truth‖ in metres (evo APE translation_part)",
        "ape_rotation": "per pair angle of R_truthᵀ (R R_est) in degrees, in [0, 180] (evo APE rotation_angle_deg)",
        "statistics": (
            "rmse = sqrt(sse / n), sse = Σ e², std is the population std (ddof = 0), as evo; "
            "p90/p95/p99 are percentiles with linear interpolation"
        ),
    }

    def process_data(self, ev: TrajectoryEvaluation) -> None:
        self.result = {"translation_m": ev.translation.stats, "rotation_deg": ev.rotation.stats}
        if ev.alignment.why:  # the positions fix no rotation: the checks that fit one on them would fit noise
            self.result["truth_frame_turn"] = None
            self.result["gravity_tilt_deg"] = ev.gravity_tilt_deg
            self.notes += [attitude_note(ev.alignment)] + sparse_pairs_note(ev)
            return
        mirror = truth_mirror_note(ev)
        turn = None if mirror else truth_frame_turn(ev)  # a mirror is no turn: the turn would mislead
        self.result["truth_frame_turn"] = turn
        self.result["gravity_tilt_deg"] = ev.gravity_tilt_deg  # the tilt note's condition (tilt_note), as a flag
        self.notes += [ev.alignment.upright] if ev.alignment.upright else []
        self.notes += (mirror or truth_frame_note(ev, turn)) + truth_scale_note(ev) + sparse_pairs_note(ev)
        self.notes += still_stretch_note(ev)
        self.result["rotation_fix"] = fix = rotation_fix_section(ev)
        self.notes += rotation_fix_note(fix, ev.alignment.kind, self.result)


def rmse_standard_error(errors: np.ndarray) -> float | None:
    """The standard error (m) of the rmse of ``errors`` (time order) by batch means (:func:`~.align.batch_sums`
    of the squared errors): errors correlated along the path count as the batches they fill. None below 2
    batches."""
    e2 = np.square(np.asarray(errors, dtype=np.float64))
    sums, counts = batch_sums(e2[:, None])[:, 0], batch_sums(np.ones((e2.shape[0], 1)))[:, 0]
    if sums.shape[0] < 2 or not np.any(e2):
        return None
    se_ms = float(np.std(sums / counts, ddof=1) / np.sqrt(sums.shape[0]))
    return se_ms / (2.0 * float(np.sqrt(np.mean(e2))))


def rotation_fix_section(ev: TrajectoryEvaluation) -> dict[str, Any] | None:
    """report.json ``ape.rotation_fix``: :func:`~.align.rotation_fix` of the report's se3 or sim3 fit on all pairs,
    with ``ape_se_m`` and ``rotation_se_deg`` (:func:`rmse_standard_error` of the translation and rotation APE) and
    the APE after the weighed fit beside them (``weighed.translation_m``, ``rotation_deg``, ``alignment``); None
    for another alignment or one fitted on the first pairs only."""
    p, al = ev.paired, ev.alignment
    if al.n_points != len(p):
        return None  # fitted on the first pairs only: its spread is another question
    fix = rotation_fix(p.ref_pos, p.est_pos, al, p.ref_rot, p.est_rot, planar=ev.planar)
    if fix is None:
        return None
    fix["ape_se_m"] = rmse_standard_error(ev.translation.errors)
    fix["rotation_se_deg"] = rmse_standard_error(ev.rotation.errors)
    weighed = fix["weighed"]
    if weighed is not None:
        trans, rot = aligned_errors({"weighed": weighed["alignment"]}, p)["weighed"]
        fix["weighed"] = {
            "turn_deg": weighed["turn_deg"],
            "translation_m": metrics.statistics(trans),
            "rotation_deg": metrics.statistics(rot),
            "alignment": alignment_dict(weighed["alignment"]),
        }
    return fix


#: the principal axes as the notes name them (:func:`~.align.rotation_fix`'s order: largest spread first)
AXIS_NAMES = ("main axis", "second axis", "third axis")


def rotation_fix_note(fix: dict[str, Any] | None, kind: str, ape: dict[str, Any]) -> list[str]:
    """The note of an APE (``ape``: the section's ``translation_m`` and ``rotation_deg``, alignment ``kind``) whose
    fit's turn the positions fix less well than the attitudes do about some axis (``fix["weak_axes"]``), where
    weighing both moves the translation APE, the headline, by more than its own standard error
    (``fix["ape_se_m"]``): a number that turns on a fit the positions hardly make. A turn about an axis the
    positions hardly spread across moves them, and so that APE, little (TagSLAM test_22: 0.002 m for riekf's
    22 deg): the rotation APE moves with it, and is given beside it, but a rotation APE moves with any turn and
    its standard error (white attitude noise) can be far below the fit's; it does not call the note."""
    if not fix or not fix["weak_axes"] or fix["weighed"] is None or fix["ape_se_m"] is None:
        return []
    w = fix["weighed"]
    moved = [
        (w[key]["rmse"], ape[key]["rmse"], fix[se])
        for key, se in (("translation_m", "ape_se_m"), ("rotation_deg", "rotation_se_deg"))
    ]
    if abs(moved[0][0] - moved[0][1]) <= fix["ape_se_m"]:
        return []
    (t_w, t, t_se), (r_w, r, r_se) = moved
    axes = "; ".join(
        f"about the truth positions' {AXIS_NAMES[k]} (spread {fix['spread_m'][k]:.3g} m rms along it) "
        + (
            "not at all by the positions"
            if fix["positions_se_deg"][k] is None
            else f"±{fix['positions_se_deg'][k]:.3g} deg by the positions"
        )
        + f", ±{fix['turns_se_deg'][k]:.3g} deg by the attitudes' turns"
        for k in fix["weak_axes"]
    )
    se = lambda v, unit: "" if v is None else f" ± {v:.2g}{unit}"  # noqa: E731
    return [
        f"the {kind} alignment's rotation is weakly fixed: {axes} (standard errors over {fix['n_batches']} batches "
        f"of consecutive pairs). The fit that weighs the attitudes' turns too (ape.rotation_fix.weighed) turns the "
        f"estimate {w['turn_deg']:.3g} deg from it: translation APE {t_w:.4g} m against {t:.4g}{se(t_se, ' m')}, "
        f"rotation APE {r_w:.4g} deg against {r:.4g}{se(r_se, ' deg')}. The APE above is evo's fit, as the evo "
        "command reproduces it; where estimates differ by less than this, which is nearer the truth turns on "
        "the fit"
    ]


def attitude_note(al: Alignment) -> str:
    """The note of a report whose alignment asked for was not fitted because the truth positions fix no rotation
    (``al``: :data:`~.align.ATTITUDE`, with ``requested`` and ``why``)."""
    return (
        f"the {al.requested} alignment was not fitted: {al.why}; a rotation fitted to them would be fitted to their "
        "noise. The APE is after the attitude alignment instead (the rotation from the paired attitudes, the "
        "translation from the positions' means)"
    )


#: A translation APE above this share of the truth's RMS extent, or a rotation APE above TRUTH_FRAME_ROTATION_DEG, is
#: tried against a mirrored estimate; the mirror is named when an SE(3) fit of it leaves MIRROR_GAIN times less error
#: than the estimate as it is.
MIRROR_CHECK_SHARE = 0.1
MIRROR_GAIN = 4.0


def _rigid_fit_rmse(src: np.ndarray, dst: np.ndarray) -> float:
    rot, t, _ = umeyama(src, dst)
    return float(np.sqrt(np.mean(metrics.row_norms(apply_alignment(rot, t, 1.0, src), dst) ** 2)))


def truth_mirror_note(ev: TrajectoryEvaluation) -> list[str]:
    """The note naming a truth that is the estimate's mirror image (a left-handed frame, one axis of the wrong
    sign): no alignment the report fits can absorb a reflection, so its APE would be read as the estimator's
    error (a generated figure 8 with the truth's y negated: 0.674 m, the note "turned by a constant 179.2 deg":
    nearly level, the mirror is nearly a half turn about x, all but its height). Tried only when the translation
    APE is above ``MIRROR_CHECK_SHARE`` of the truth's extent or the rotation APE is implausible; a level
    trajectory's mirror is a rotation, which the fit absorbs, so it is never named."""
    trans, rot, extent = ev.translation.stats.get("rmse"), ev.rotation.stats.get("rmse"), ev.truth_extent_m
    ref, est = ev.paired.ref_pos, ev.paired.est_pos
    if trans is None or not extent > 0.0 or len(ref) < 3:
        return []
    if trans <= MIRROR_CHECK_SHARE * extent and not (rot is not None and rot > TRUTH_FRAME_ROTATION_DEG):
        return []
    try:
        as_is = _rigid_fit_rmse(est, ref)
        mirrored = _rigid_fit_rmse(est * np.array([-1.0, 1.0, 1.0]), ref)
    except ValueError:  # collinear pairs: no fit either way
        return []
    if not mirrored * MIRROR_GAIN < as_is:
        return []
    return [
        f"the truth looks like the estimate's mirror image: a rigid fit of the estimate with one axis negated leaves "
        f"{mirrored:.3g} m rmse against {as_is:.3g} m as it is ({as_is / max(mirrored, 1e-12):.3g}x less): a truth "
        "recorded in a left-handed frame, or an axis of the truth (or of a sensor) of the wrong sign; no alignment "
        "absorbs a mirror, so the APE here is mostly that"
    ]


#: Pairs fewer than this share of the shorter series' poses: most of its stamps lie further than t_max_diff from
#: the other's (TagSLAM test_22: 14 of the truth's 112 poses paired at 0.01 s, both series at 3.3 Hz on their own
#: stamps; APE 1.01 m over those, 0.75 m over 108 pairs at 0.16 s) and the report says so.
SPARSE_PAIRS = 0.5


def sparse_pairs_note(ev: TrajectoryEvaluation) -> list[str]:
    """The note for an APE over few of the poses it could pair: how far the shorter series' stamps lie from the
    other's nearest (the estimate's with the report's offset added), and a ``--t-max-diff`` that pairs 90 % of them."""
    p = ev.paired
    n, shorter = len(p.ref_pos), min(p.n_ref, p.n_est)
    if p.method == "index" or n >= SPARSE_PAIRS * shorter:
        return []
    t_truth = np.sort(np.asarray(ev.truth.t_ns, dtype=np.int64))
    t_est = np.sort(np.asarray(ev.estimate.t_ns, dtype=np.int64)) + int(round(ev.applied_offset_s * 1e9))
    side, t, other = ("truth", t_truth, t_est) if p.driving == "reference" else ("estimate", t_est, t_truth)
    j = np.clip(np.searchsorted(other, t), 1, other.size - 1) if other.size > 1 else np.zeros(t.size, np.int64)
    gap = np.minimum(np.abs(t - other[j]), np.abs(t - other[np.maximum(j - 1, 0)])) / 1e9
    wider = float(np.ceil(np.percentile(gap, 90.0) * 100.0) / 100.0)
    return [
        f"the APE is over {n} of the {side}'s {shorter} poses: the others have no "
        f"{'estimate' if side == 'truth' else 'truth'} pose within t_max_diff (their stamps lie a median "
        f"{float(np.median(gap)):.3g} s from the nearest); `slamobs report RUN --t-max-diff {wider:g}` pairs 90 % of "
        "them (the pairs then differ in time by up to that)"
    ]


#: A pair whose truth moves less than STILL_MOVE_M over STILL_SPAN_S either side of it stands still (a rig at rest:
#: 0 on a generated log; a motion-capture truth's jitter is millimetres). The APE weighs each place by the time spent
#: there: still pairs of STILL_SHARE or more of them, with an APE STILL_GAIN times the one fitted on the moving pairs
#: alone or more, get a note (seed=3657: 30 s still of 120, fast-adaptation 0.476 m against 0.289 m over the moving
#: poses: the place it stood 0.69 m off, the drift of the path after it; riekf and batch 0.08 and 0.03, no note).
STILL_SPAN_S = 0.5
STILL_MOVE_M = 0.01
STILL_SHARE = 0.1
STILL_GAIN = 1.25
#: Where the estimate's median speed over the truth's still pairs is this share of its median over the moving pairs
#: or more, the body did not stand still: the truth froze (a motion capture that lost track and repeats its last
#: pose). A margin, not tuned: seed=3965 (mocap frozen 10 s of 90) 0.9-1.1, seed=3657 and seed=3962 (30 s and 120 s
#: at rest) 0.01-0.1.
FROZEN_SPEED_SHARE = 0.5


def _span_ends(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The indices of the sorted stamps ``t`` (ns) nearest ``STILL_SPAN_S`` before and after each."""
    w = int(STILL_SPAN_S * NS_PER_S)
    return np.clip(np.searchsorted(t, t - w), 0, t.size - 1), np.clip(np.searchsorted(t, t + w), 0, t.size - 1)


def window_speeds(t_ns: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """The speed (m/s) of the time-ordered positions ``pos`` at ``t_ns`` over ``STILL_SPAN_S`` either side of each
    (the nearest poses): the displacement between the two over their time apart."""
    t = np.asarray(t_ns, dtype=np.int64)
    before, after = _span_ends(t)
    dt = np.maximum((t[after] - t[before]) / NS_PER_S, 1e-9)
    return metrics.row_norms(pos[after], pos[before]) / dt


def still_pairs(t_ns: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Which of the time-ordered poses ``pos`` at ``t_ns`` stand still: the position ``STILL_SPAN_S`` before and
    after each (the nearest pose) within ``STILL_MOVE_M`` of its own."""
    before, after = _span_ends(np.asarray(t_ns, dtype=np.int64))
    near = lambda j: metrics.row_norms(pos[j], pos) < STILL_MOVE_M  # noqa: E731
    return near(before) & near(after)


def still_stretch_note(ev: TrajectoryEvaluation) -> list[str]:
    """The note for an APE that a stretch of standing still weighs: the still pairs' share, their error, and the APE
    of the same alignment fitted on the moving pairs alone (seed=3657: fast-adaptation's 0.476 m was 0.289 m over the
    moving poses; the rig's 30 s at rest held the place it stood, 0.69 m off after the path's drift, for a quarter
    of the pairs). Only where the report's alignment is fitted on every pair (not evo's ``--n_to_align``, origin or
    none) and the pairs are stamped."""
    p, al = ev.paired, ev.alignment
    full = ev.translation.stats.get("rmse")
    if p.t_ref_ns is None or full is None or al.kind in ("origin", "none") or al.n_points != len(p) or len(p) < 10:
        return []
    order = np.argsort(p.t_ref_ns, kind="stable")
    still = np.empty(len(p), dtype=bool)
    still[order] = still_pairs(p.t_ref_ns[order], p.ref_pos[order])
    n_still = int(still.sum())
    if n_still < STILL_SHARE * len(p) or len(p) - n_still < max(STILL_SHARE * len(p), 3):
        return []
    moving = ~still
    try:
        fit = fit_alignment(al.kind, p.ref_pos[moving], p.est_pos[moving])
    except ValueError:  # collinear moving pairs: no fit
        return []
    err = metrics.row_norms(fit.positions(p.est_pos[moving]), p.ref_pos[moving])
    alone = float(np.sqrt(np.mean(err**2)))
    if full < STILL_GAIN * alone:
        return []
    speed = np.empty(len(p))
    speed[order] = window_speeds(p.t_ref_ns[order], p.est_pos[order])
    moving_speed, still_speed = float(np.median(speed[moving])), float(np.median(speed[still]))
    if moving_speed > 0.0 and still_speed >= FROZEN_SPEED_SHARE * moving_speed:
        return frozen_truth_note(ev, order, still, still_speed / moving_speed)
    at_still = float(np.mean(ev.translation.errors[still]))
    return [
        f"the truth stands still for {n_still / len(p):.0%} of the paired poses, and the APE weighs a place by the "
        f"time spent there: the estimate is {at_still:.3g} m off where it stood, and over the moving poses alone "
        f"(the {al.kind} alignment fitted on them) the APE is {alone:.3g} m against {full:.3g} m: the error of the "
        "place it stood (the path's drift since, or an estimate that moved while the body did not), not of the path"
    ]


def frozen_truth_note(ev: TrajectoryEvaluation, order: np.ndarray, still: np.ndarray, share: float) -> list[str]:
    """The note for a truth that stands still where the estimate moves on at ``share`` of its speed elsewhere (the
    estimate's speed is the body's measured velocity integrated, about 0 at rest whatever its error): a motion
    capture that lost track and repeats its last pose (seed=3965). The moving pairs leave out those within
    ``STILL_SPAN_S`` of a still one too: a frozen stretch's first and last half second are not still by
    :func:`still_pairs` but frozen all the same."""
    p, al, full = ev.paired, ev.alignment, ev.translation.stats["rmse"]
    t = p.t_ref_ns[order]
    before, after = _span_ends(t)
    near = np.cumsum(np.r_[0, still[order].astype(np.int64)])
    frozen = np.empty(len(p), dtype=bool)
    frozen[order] = near[after + 1] - near[before] > 0  # a still pair within the span either side
    try:
        fit = fit_alignment(al.kind, p.ref_pos[~frozen], p.est_pos[~frozen])
    except ValueError:  # collinear moving pairs: no fit
        return []
    alone = float(np.sqrt(np.mean(metrics.row_norms(fit.positions(p.est_pos[~frozen]), p.ref_pos[~frozen]) ** 2)))
    return [
        f"the truth stands still for {still.mean():.0%} of the paired poses while the estimate moves on there at "
        f"{share:.2g}x its speed where the truth moves: a truth that froze (a motion capture that lost track and "
        "repeats its last pose?) rather than a body at rest; the APE counts those poses "
        f"({float(np.mean(ev.translation.errors[still])):.3g} m off the frozen one, mean): over the "
        f"{int((~frozen).sum())} others alone (the {al.kind} alignment fitted on them) it is {alone:.3g} m against "
        f"{full:.3g} m"
    ]


#: The truth's extent over the estimate's (RMS distance of the paired positions from their centre) beyond this
#: factor either way is no estimation error but a unit (a truth in millimetres), or an estimate without metric
#: scale: the report says so.
TRUTH_SCALE_FACTOR = 10.0


def truth_scale_note(ev: TrajectoryEvaluation) -> list[str]:
    """The note for a truth ``TRUTH_SCALE_FACTOR`` times as large as the estimate or more (or as small): MR.CLAM's
    truth in millimetres gave an APE of 2374 m and no word why. Extents, not path lengths: an estimate's jitter
    lengthens its path."""
    if ev.alignment.kind in SCALED_ALIGNMENTS or len(ev.paired.ref_pos) < 2:
        return []
    truth_m, est_m = ev.truth_extent_m, slam_metrics.rms_extent(ev.paired.est_pos)
    if truth_m <= 0.0 or est_m <= 0.0 or 1.0 / TRUTH_SCALE_FACTOR < truth_m / est_m < TRUTH_SCALE_FACTOR:
        return []
    return [
        f"the truth is {truth_m / est_m:.4g}x as large as the estimate (RMS distance of the paired positions from "
        f"their centre: {truth_m:.4g} m against {est_m:.4g} m): a truth in other units (millimetres: 1000x)?, an "
        "estimate without metric scale, or one that diverged; the APE says nothing of the estimate then (report "
        "--align sim3 fits a scale)"
    ]


#: A rotation APE above this (deg) beside a translation APE below TRUTH_FRAME_TRANSLATION of the path length is
#: no estimation error but a truth recorded in another body convention: the report estimates the rotation.
TRUTH_FRAME_ROTATION_DEG = 20.0
TRUTH_FRAME_TRANSLATION = 0.05
#: the note names a turn only when the turn leaves at most this share of the rotation APE's rmse
TRUTH_FRAME_EXPLAINS = 0.5
#: the config key every note naming that turn offers
TRUTH_FRAME_KEY = "set frames.truth_rotation: ["
#: where that note turns from the numbers to what may explain them (:func:`camera_named_notes` keeps what is before)
TRUTH_FRAME_UNLESS = ", unless a sensor's extrinsic is wrong"
#: what that note says of the frames (the NEES notes repeat it; they and the body-frame note go by ape.truth_frame_turn)
TRUTH_FRAME_TURNED = "the truth's body frame looks turned against the estimate's"
#: what the note says instead when the run's detection pairs named the camera's extrinsic
CAMERA_NAMED_KEY = "the detection pairs name the camera's extrinsic"


def truth_body_rotation(ev: TrajectoryEvaluation) -> tuple[np.ndarray, np.ndarray]:
    """Hand–eye on the aligned pairs: the constant X with ``R_truth_i ≈ R_est_i X`` (closed form: the rotation
    nearest to ``Σ R_est_iᵀ R_truth_i``) and the per-pair angles (deg) it leaves."""
    est, ref = ev.rotation.est_rot_aligned, ev.paired.ref_rot
    n = len(ref)
    total = np.zeros((3, 3))
    for rows in row_blocks(n):
        total += np.einsum("nji,njk->ik", est[rows], ref[rows])
    x = nearest_rotation(total)
    left = np.empty(n)
    for rows in row_blocks(n):
        cos = (np.einsum("njk,njk->n", np.matmul(est[rows], x), ref[rows]) - 1.0) / 2.0
        left[rows] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return x, left


def truth_frame_turn(ev: TrajectoryEvaluation) -> dict[str, Any] | None:
    """The constant rotation between the truth's body frame and the estimate's (report.json ``ape.truth_frame_turn``:
    ``angle_deg``, ``axis``, ``quat_xyzw``, ``rotation_rmse_after_deg``, the rotation APE with it applied), when the
    rotation errors are implausible next to the translation errors and that turn explains them; else None. What the
    NEES notes, the body-frame note and the camera check go by (:func:`truth_frame_note` words it)."""
    rot, trans = ev.rotation.stats.get("rmse"), ev.translation.stats.get("rmse")
    ref = ev.paired.ref_pos
    path = float(metrics.row_norms(ref[1:], ref[:-1]).sum()) if len(ref) else 0.0
    if rot is None or trans is None or rot <= TRUTH_FRAME_ROTATION_DEG or trans >= TRUTH_FRAME_TRANSLATION * path:
        return None
    x, left = truth_body_rotation(ev)
    after = float(np.sqrt(np.mean(left**2)))
    if after > TRUTH_FRAME_EXPLAINS * rot:  # the errors are no constant turn (a lost estimate on MR.CLAM 7 r3:
        return None  # 57.3 deg, 53.0 with the turn): a key that changes nothing would be a false lead
    q = rots_to_quats(x[None])[0]
    q = q if q[3] >= 0 else -q
    axis = q[:3] / (np.linalg.norm(q[:3]) or 1.0)
    return {
        "angle_deg": float(np.degrees(2.0 * np.arctan2(np.linalg.norm(q[:3]), q[3]))),
        "axis": [float(v) for v in axis],
        "quat_xyzw": [float(v) for v in q],
        "rotation_rmse_after_deg": after,
        "path_m": path,
    }


def truth_frame_note(ev: TrajectoryEvaluation, turn: dict[str, Any] | None) -> list[str]:
    """The note naming :func:`truth_frame_turn`'s ``turn`` (None: no note), with the config key that applies it."""
    return [] if turn is None else [truth_frame_words(turn, ev.rotation.stats["rmse"], ev.translation.stats["rmse"])]


def truth_frame_words(turn: dict[str, Any], rot: float, trans: float) -> str:
    """:func:`truth_frame_note`'s words of ``turn`` beside the rotation and translation APE rmse (``rot`` deg,
    ``trans`` m); where the run's detection pairs named the camera (``turn["camera_named"]``:
    :func:`camera_named_notes`), that note's words instead. Public: a headline table says a report's note from its
    ``ape`` (:func:`.markdown.headline_caveats`), by the flag, not by finding the note's words."""
    path, axis, q = turn["path_m"], turn["axis"], turn["quat_xyzw"]
    plain = (
        f"rotation APE {rot:.1f} deg is implausible next to translation APE {trans:.3f} m "
        f"({100.0 * trans / path:.1f} % of the {path:.1f} m path): {TRUTH_FRAME_TURNED} by a constant "
        f"{turn['angle_deg']:.1f} deg about [{axis[0]:.3f}, {axis[1]:.3f}, {axis[2]:.3f}]; with it the "
        f"rotation APE would be {turn['rotation_rmse_after_deg']:.2f} deg rmse{TRUTH_FRAME_UNLESS} (a camera "
        "transform inverted or turned turns the estimate so: `slamobs info --noise LOG` checks it against the "
        f"motion); to apply it (evaluation only) {TRUTH_FRAME_KEY}"
        f"{q[0]:.6f}, {q[1]:.6f}, {q[2]:.6f}, {q[3]:.6f}]"
    )
    if not turn.get("camera_named"):
        return plain
    return (
        f"{plain.split(TRUTH_FRAME_UNLESS)[0]}; but {CAMERA_NAMED_KEY} (the warning below): a camera transform "
        "inverted or turned turns the estimate so; correct the extrinsic and run again (a rotation of the truth would "
        "only hide the error)"
    )


def body_frame_notes(report: dict[str, Any], run_input: dict[str, Any]) -> list[str]:
    """The note naming the body frame the run took and why (run.json's ``input``: ``body_frame``,
    ``body_frame_from``), when the report found the truth's body frame turned against the estimate's (``ape``'s
    ``truth_frame_turn``: :func:`truth_frame_turn`) and the run did not take it from ``frames.body``: a log whose
    odometry's child_frame_id is a sensor frame turned against the robot's base makes that sensor the body, and the
    truth, which tracks the base, looks turned. Empty otherwise, also when the camera's extrinsic is named instead
    (``truth_frame_turn.camera_named``: :func:`camera_named_notes`) or the run.json predates ``body_frame_from``.
    Where TF places a base frame against that body (``input.base_frame``) the run's note naming the key that makes it
    the body follows: report.md did not carry it, and its rotation note offers only ``frames.truth_rotation``, which
    turns the truth for the evaluation (TagSLAM test 22: rotation APE 124.5 deg, 12.3 deg with ``frames.body: rig``)."""
    turn = (report.get("ape") or {}).get("truth_frame_turn")
    origin, body = run_input.get("body_frame_from"), run_input.get("body_frame")
    from slamobs.pipeline.alignment import BODY_FROM_CONFIG, base_placed_note, body_frame_note

    if not turn or turn.get("camera_named") or not origin or origin == BODY_FROM_CONFIG:
        return []
    carried = run_input.get("truth_body")
    return [body_frame_note(body, origin, carried), *base_placed_note(body, run_input.get("base_frame"), carried)]


def detections_named_camera(metadata: dict[str, Any]) -> bool:
    """Whether a run's detection pairs named its camera's extrinsic turned or inverted (``time_offset.
    camera_turned``): riekf's and batch's own time-offset record (run.json ``observer.time_offset``; the observers'
    holds the decision alone since session 33, no check, so it names no camera) or the run's
    camera check (``observer.camera_check``: the observers', made when the report found the estimate turned).
    Public: the run's camera check reads it too (no second check where the estimator's own named the camera). A
    time-offset record written before the flag is judged by the same rule from its fields. An observer's run made
    before its camera check kept a record (session 27) has neither: its run.json notes (``metadata["notes"]``) are
    all it left of the check, read for the check's warning (``time_offset.CAMERA_ADVICE``); the reference
    estimators always record their own search, so their notes are never read so."""
    from slamobs.pipeline.estimators import ESTIMATORS
    from slamobs.pipeline.observers.time_offset import CAMERA_ADVICE, camera_turned

    observer = metadata.get("observer") or {}
    spec = ESTIMATORS.get(observer.get("name") or "")
    if not {"time_offset", "camera_check"} & observer.keys() and spec is not None and not spec.uses_noise:
        return any(n.startswith("warning: ") and CAMERA_ADVICE in n for n in metadata.get("notes") or [])
    records = [observer.get(k) or {} for k in ("time_offset", "camera_check")]
    return any(bool(r["camera_turned"]) if "camera_turned" in r else camera_turned(r) for r in records)


def camera_named_notes(report: dict[str, Any], metadata: dict[str, Any]) -> list[str]:
    """The report's notes once the run's detection pairs named a turned or inverted camera extrinsic
    (:func:`detections_named_camera`: the run's notes carry its warning) and the report found the truth's body
    frame turned (``ape.truth_frame_turn``, then marked ``camera_named``): such a camera turns the estimate as a
    truth recorded in another body frame would, so the truth-frame note (:func:`truth_frame_note`) keeps its
    numbers, sends the reader to that warning (a report's notes carry it: :func:`.report.add_run_context`) and no
    longer offers ``frames.truth_rotation``, which would hide the camera's error in the report, not mend the
    estimate. The notes as they are otherwise."""
    notes, ape = report.get("notes") or [], report.get("ape") or {}
    turn = ape.get("truth_frame_turn")
    if not turn or not detections_named_camera(metadata):
        return notes
    turn["camera_named"] = True
    rmse = [(ape.get(k) or {}).get("rmse") for k in ("rotation_deg", "translation_m")]
    if None in rmse:  # no APE: no truth-frame note to reword
        return notes
    plain = truth_frame_words({**turn, "camera_named": False}, *rmse)  # the note as its section wrote it
    return [truth_frame_words(turn, *rmse) if n == plain else n for n in notes]


class ApeByAlignmentSection(Section):
    """The same APE after each alignment fitted on the same pairs: what the report's alignment absorbs."""

    METHOD = {
        "ape_by_alignment": (
            "the same APE after each alignment fitted on the same pairs: what the primary "
            f"alignment absorbs; yaw (4-DoF) for runs with IMU directions and for planar runs (the estimate and "
            f"the truth both level: every paired pose tilted less than {PLANAR_TILT_DEG:g} deg from the z axis)"
        )
    }

    def __init__(self, options: ReportOptions) -> None:
        super().__init__()
        self.options = options

    def kinds(self, planar: bool = False) -> list[str]:
        """The report's alignment first; yaw (4-DoF) only for gravity-aligned or planar runs (or when it is the
        report's): only there do the estimate's and the truth's z axes agree, so that yaw is all to fit."""
        align = self.options.align
        kinds = [align] + [k for k in ("se3", "yaw", "origin", "none") if k != align]
        if not (self.options.gravity_aligned or planar):
            kinds = [k for k in kinds if k != "yaw" or k == align]
        return kinds

    def process_data(self, ev: TrajectoryEvaluation) -> None:
        p = ev.paired
        kinds = self.kinds(planar=ev.planar)
        fits: dict[str, Alignment] = {}
        for kind in kinds[1:]:
            try:
                fits[kind] = fit_alignment(kind, p.ref_pos, p.est_pos, p.ref_rot, p.est_rot)
            except ValueError as err:
                self.notes.append(f"APE with {kind} alignment not computed: {err}")
        errors = aligned_errors(fits, p)
        stats = {kind: tuple(metrics.statistics(e) for e in pair) for kind, pair in errors.items()}
        stats[self.options.align] = (dict(ev.translation.stats), dict(ev.rotation.stats))  # the same statistics
        fits[self.options.align] = ev.alignment
        self.result = {
            kind: {
                "translation_m": stats[kind][0],
                "rotation_deg": stats[kind][1],
                "alignment": alignment_dict(fits[kind]),
            }
            for kind in kinds
            if kind in fits
        }
        self.notes += tilt_note(self.options.align, ev.gravity_tilt_deg, self.result)


#: how every tilt note ends
TILT_NOTE_END = "(report --align yaw makes it the headline)"


def tilt_note(align: str, tilt: float | None, by_alignment: dict[str, Any]) -> list[str]:
    """The note for a run whose report alignment tilts the estimate's z axis off the truth's although both have a
    gravity axis: ``tilt`` is :attr:`~.trajectory_evaluation.TrajectoryEvaluation.gravity_tilt_deg`, the one rule
    (None: no such tilt). Such a fit no gravity-respecting alignment could give flatters its translation APE;
    turned upside down (positions in a plane fit as well flipped), its rotation APE reads ~180 deg whatever the
    heading. The note sets the 4-DoF APE beside it (none without that fit)."""
    yaw, primary = by_alignment.get("yaw"), by_alignment.get(align)
    if tilt is None or yaw is None or primary is None:
        return []
    if tilt > UPSIDE_DOWN_DEG:
        what = (
            f"the {align} alignment turned the estimate upside down (the positions lie in a plane, which fits as well "
            f"flipped), so its rotation APE ({primary['rotation_deg']['rmse']:.1f} deg rmse) says nothing of the "
            "heading"
        )
    else:
        what = (
            f"the {align} alignment tilted the estimate's z axis {tilt:.1f} deg off the truth's, though both have a "
            f"gravity axis: no gravity-respecting alignment could, and its APE ({primary['translation_m']['rmse']:.4f} "
            f"m, {primary['rotation_deg']['rmse']:.3f} deg rmse) looks better for it"
        )
    return [
        f"{what}; with the 4-DoF alignment (translation + yaw, ape_by_alignment.yaw) APE is "
        f"{yaw['translation_m']['rmse']:.4f} m, {yaw['rotation_deg']['rmse']:.3f} deg rmse {TILT_NOTE_END}"
    ]


def aligned_errors(fits: dict[str, Alignment], p: Paired) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """APE (translation, rotation in degrees) after each alignment, in one pass over blocks of pairs: the
    rotation matrices of a block serve every alignment, and no aligned estimate of all pairs is held."""
    n = len(p)
    out = {kind: (np.empty(n), np.empty(n)) for kind in fits}
    for rows in row_blocks(n):
        ref_pos, est_pos, ref_rot, est_rot = p.ref_pos[rows], p.est_pos[rows], p.ref_rot[rows], p.est_rot[rows]
        for kind, al in fits.items():
            none = al.kind == "none"  # the estimate as it is (as trajectory_error.align_paired takes it)
            pos = est_pos if none else al.positions(est_pos)
            out[kind][0][rows] = metrics.ape_errors("trans_part", ref_pos, None, pos, None)
            turned = est_rot if none else metrics.rotated(al.rot, est_rot)
            out[kind][1][rows] = metrics.ape_errors("angle_deg", ref_pos, ref_rot, pos, turned)
    return out


class RpeSection(Section):
    """evo's RPE over pose pairs ``rpe_delta_m`` of travelled path apart (None on a path too short)."""

    def __init__(self, options: ReportOptions) -> None:
        super().__init__()
        self.options = options

    def process_data(self, ev: TrajectoryEvaluation) -> None:
        options = self.options
        opts = RpeOptions(options.rpe_delta_m, "m", 0.1, False, False)
        al = AlignOptions(options.align)
        try:
            tr = rpe(ev.truth, ev.estimate, "trans_part", ev.sync, al, opts, paired=ev.paired, like=ev.translation)
            rr = rpe(ev.truth, ev.estimate, "angle_deg", ev.sync, al, opts, paired=ev.paired, like=ev.translation)
        except ValueError as err:
            self.notes.append(f"no RPE: {err}")
            return
        self.result = {
            "delta": float(options.rpe_delta_m),
            "delta_unit": "m",
            "n_pairs": int(tr.errors.shape[0]),
            "translation_m": tr.stats,
            "rotation_deg": rr.stats,
            "method": (
                f"evo_rpe definitions: consecutive pose pairs of the aligned estimate {options.rpe_delta_m:g} "
                "m of travelled path apart (a pair closes when its path reaches the delta); error pose "
                "E = (Q_i⁻¹Q_j)⁻¹(P_i⁻¹P_j); translation ‖t_E‖ in metres, rotation angle of R_E in degrees "
                f"(evo_rpe ... --delta {options.rpe_delta_m:g} --delta_unit m"
                f"{EVO_ALIGN_FLAGS.get(options.align, '')}"
                " -r trans_part / angle_deg)"
            ),
        }


class DriftSection(Section):
    """KITTI-style drift per segment length on the associated pairs (None without a segment)."""

    def __init__(self, options: ReportOptions) -> None:
        super().__init__()
        self.options = options

    def process_data(self, ev: TrajectoryEvaluation) -> None:
        p = ev.paired
        if len(p) < 3:
            return
        t = p.t_est_ns
        dt = metrics.median(np.diff(t)) / NS_PER_S if t is not None and t.shape[0] > 1 else 0.1
        step = max(1, int(round(1.0 / dt))) if dt > 0 else 10
        out = segment_drift(
            p.ref_pos,
            p.ref_rot,
            ev.translation.est_pos_aligned,
            ev.translation.est_rot_aligned,
            self.options.drift_lengths_m,
            step,
        )
        if out["n_segments"] == 0:
            return
        out["method"] = (
            "KITTI odometry devkit definition on the associated pairs: from every pair about 1 s apart "
            f"(every {step} pairs), for each segment length L the first pair whose truth path distance exceeds "
            "the start's by more than L; E = (P_i⁻¹P_j)⁻¹(Q_i⁻¹Q_j); translation_pct = mean ‖t_E‖/L × 100, "
            "rotation_deg_per_m = mean angle(R_E)/L; lengths are KITTI's 100–800 m for paths over 1.6 km, else "
            "10–50 % of the truth path; independent of the rigid alignment, sensitive to scale"
        )
        self.result = out


class SegmentErrorsSection(Section):
    """rpg_trajectory_evaluation's relative error per sub-trajectory length (None with fewer than 3 pairs); the
    error arrays per length stay in :attr:`arrays` for the box plots."""

    METHOD = {
        "segment_errors": (
            "rpg_trajectory_evaluation (compute_relative_error) on the associated pairs: lengths L = 10, 20, 30, "
            "40, 50 % of the truth path (truncated to cm); from every pair, the later pair whose truth path "
            "distance is nearest to the start's + L, within 0.2 L; E = (Q_i⁻¹Q_j)⁻¹(P_i⁻¹P_j) with the "
            "estimate's relative translation times the alignment's scale (so SE(3) and 4-DoF give the same, "
            "Sim(3) corrects the scale); translation ‖t_E‖ [m] and ‖t_E‖/L [%], rotation angle(R_E) [deg] and "
            "per metre, yaw and gravity (roll-pitch) parts of E rotated into the world by the estimate's attitude "
            "at j; a length with fewer than 2 segments has null errors"
        )
    }

    def __init__(self) -> None:
        super().__init__()
        self.arrays: dict[float, dict[str, np.ndarray]] = {}

    def process_data(self, ev: TrajectoryEvaluation) -> None:
        self.process_pairs(ev.paired, ev.truth, ev.alignment.kind, ev.alignment.scale)

    def process_pairs(self, p: Paired, truth: PoseStream, kind: str, scale: float) -> None:
        """The section from the pairs alone (all it needs of the evaluation besides the alignment's ``kind`` and
        ``scale``): the report starts it as soon as the trajectories are paired, before their APE."""
        if len(p) < 3:
            return
        path = accumulated_distances(np.asarray(truth.position))[-1]  # rpg: the whole truth's path
        out, self.arrays = segment_errors(p.ref_pos, p.ref_rot, p.est_pos, p.est_rot, path, scale)
        self.result = {**out, "alignment": kind}


class TimeOffsetSection(Section):
    """The estimated clock offset between estimate and truth, and the one applied."""

    def __init__(self, options: ReportOptions) -> None:
        super().__init__()
        self.options = options

    def unreliable_note(self, ev: TrajectoryEvaluation) -> None:
        """Note an applied (``t_offset auto``) offset that is not reliable; an offset not applied is still being
        searched for meanwhile and is not waited for here."""
        off = ev.time_offset if self.options.t_offset_s == "auto" else None
        if off is not None and not off.reliable:
            edge = ", at the search limit" if off.at_window_edge else ""
            edge += "" if off.consistent else f", {halves_owner(ev.offset_against)} {2 * off.uncertainty_s:.3f} s apart"
            self.notes.append(
                f"applied clock offset {ev.applied_offset_s:.6f} s is not reliable (peak correlation "
                f"{off.peak_correlation:.2f}{edge})"
            )

    def process_data(self, ev: TrajectoryEvaluation) -> None:
        self.result = offset_fields(ev.time_offset, ev.applied_offset_s, self.options.t_offset_s, ev.offset_against)

    @staticmethod
    def method(against: str) -> str:
        """The method text for an offset searched against the estimate or the log's velocity samples."""
        if against == "estimate":
            other = (
                "of estimate and truth (uncertainty_s: half the difference of the offsets the estimate's first and "
                "second half find, which must be at most a grid step or a quarter of the offset to be reliable)"
            )
            lag = (
                "A lag of the estimate behind the motion (an observer's filtering delay) shows as the same offset: "
                "a reliable offset is where the estimate matches the truth best, not proof that the clocks differ"
            )
        else:
            other = (
                "of the truth and of the log's own velocity samples (the trapezoid rule on their norms, less a "
                "constant bias fitted against the truth's rate at the lag found where that correlates better; the "
                "estimate's stamps are on their clock; uncertainty_s: half the difference of the offsets the log's "
                "first and second half find, which must be at most a grid step or a quarter of the offset to be "
                "reliable)"
            )
            lag = (
                "It is the offset between the truth's clock and the log's: an estimate lagging the motion (an "
                "observer's filtering delay) or lost does not move it, and the APE with it applied says whether the "
                "estimate agrees"
            )
        return (
            "Pearson cross-correlation of a motion signal that the unknown frame alignment does not change: "
            f"the angular rate magnitude |ω|, or the speed |v| when it varies clearly more (signal), {other}, "
            "resampled on one grid as mean rates per grid step; best lag within ±search_window_s, "
            "refined off the grid by golden-section search. Sign as evo --t_offset: t_estimate + offset is on "
            "the truth clock. Reliable: peak correlation >= 0.5, not on the window edge, and an offset more than "
            "one grid step from zero must not make the translation APE rmse larger (ape_rmse_with_m, with it "
            f"applied; ape_rmse_without_m, without; same association and alignment). {lag}. Applied to the "
            "association only when asked (t_offset auto)"
        )


def offset_fields(off: TimeOffset | None, applied_s: float, t_offset_s: float | str, against: str) -> dict[str, Any]:
    """report.json's ``time_offset`` of the search ``off`` (None: the motion told no offset), ``applied_s`` applied
    as ``t_offset_s`` asked (seconds, or ``auto``), the truth correlated with ``against`` (``estimate`` or ``velocity
    samples``). Public: ``slamobs evaluate --json`` states the same fields with the same definition."""
    return {
        "estimated_s": None if off is None else off.offset_s,
        "peak_correlation": None if off is None else off.peak_correlation,
        "signal": None if off is None else off.signal,
        "reliable": None if off is None else off.reliable,
        "ape_rmse_with_m": None if off is None else off.rmse_with_m,
        "ape_rmse_without_m": None if off is None else off.rmse_without_m,
        "search_window_s": None if off is None else off.search_window_s,
        "uncertainty_s": None if off is None else off.uncertainty_s,
        "grid_step_s": None if off is None else off.grid_step_s,
        "applied_s": float(applied_s),
        "applied_from": "estimate" if t_offset_s == "auto" else "option",
        "searched_against": against,
        "method": TimeOffsetSection.method(against),
    }


#: A map whose error after the trajectory's alignment is this many times its error after an alignment of its own (and
#: over MAP_PLACE_MIN_M) is named in the notes: its shape matches the landmark truth, its place does not.
MAP_PLACE_FACTOR = 10.0
MAP_PLACE_MIN_M = 1.0
#: A map whose error after the trajectory's alignment is this many times its error after the loose turn of that
#: alignment (:func:`slam_metrics.loose_turn`), and over MAP_TURN_MIN_M, is named in the notes: the error is the
#: alignment's freedom, not the map's.
MAP_TURN_FACTOR = 2.0
MAP_TURN_MIN_M = 0.1


#: a map σ check whose median ‖e‖/σ is at least this says the σ is that many times too small; below it, the mean
#: NEES may come from a few landmarks or from the covariance's shape, and the note names the worst landmark
MAP_SIGMA_FAR = 10.0


def map_only_mean(nees: np.ndarray, dof: int) -> tuple[float, int] | None:
    """The mean NEES of ``nees`` (finite, one per landmark over ``dof`` axes) measured after an alignment of the map
    alone: that alignment takes p = dof(dof + 1)/2 DoF out of the errors (6 in 3-D, 3 on a planar map), so the mean
    is the NEES sum over n − p/dof landmarks (a consistent map's sum is χ²(dof·n − p)); ``(mean, p)``, or None when
    dof·n ≤ p (nothing left to check). The one rule of :func:`confirm_after_map_only` and of the map-only
    :func:`sigma_check` of a run without trajectory truth."""
    removed = dof * (dof + 1) // 2
    if dof * nees.size <= removed:
        return None
    return float(np.sum(nees) / (nees.size - removed / dof)), removed


def sigma_check(
    ids: np.ndarray, errors: np.ndarray, cov: np.ndarray | None, method: str, map_only: bool = False
) -> dict[str, Any] | None:
    """The map's stated covariance against its error: per landmark NEES ``eᵀΣ⁻¹e`` (3 DoF), their mean against the
    two-sided 95 % χ² bounds of a mean of n independent values and against ``bound_any_correlation``
    (:func:`metrics.nees_bound_any_correlation`: the landmarks share the alignment's and the poses' errors, so they
    are not independent) with its verdict, how many lie above one NEES's upper bound, the worst landmark, and
    ``‖e‖ / σ`` (σ = ``sqrt(trace Σ / 3)``); None without a covariance (the observers). ``map_only``: ``errors``
    are after an alignment of the map alone, the mean and its bounds those of :func:`map_only_mean` (``dof_removed``);
    None when that leaves nothing."""
    if cov is None:
        return None
    axes = list(axes_with_error(errors))  # a planar map (MR.CLAM) has no error in z: its NEES is over x, y
    dof = len(axes)
    nees = slam_metrics.landmark_nees(errors[:, axes], cov[:, axes][:, :, axes])
    ok = np.flatnonzero(np.isfinite(nees))
    if not ok.size:
        return None
    sigma = rms_sigmas(cov[ok])
    norms = np.linalg.norm(errors[ok], axis=1)
    w = int(np.argmax(nees[ok]))
    mean, any_correlation = float(np.mean(nees[ok])), metrics.nees_bound_any_correlation(dof)
    bounds, removed = metrics.nees_bounds(dof, int(ok.size)), 0
    if map_only:
        if (found := map_only_mean(nees[ok], dof)) is None:
            return None
        (mean, removed), left = found, ok.size - found[1] / dof
        bounds = tuple(metrics.chi2_quantile(q, dof * ok.size - removed) / left for q in (0.025, 0.975))
    verdict = metrics.nees_verdict(mean, bounds, any_correlation)
    return {
        "n": int(ok.size),
        "dof": dof,
        **({"axes": ["xyz"[i] for i in axes]} if dof < NEES_DOF else {}),
        "mean_nees": mean,
        **({"dof_removed": removed} if map_only else {}),
        "bounds": [float(v) for v in bounds],
        "bound_any_correlation": any_correlation,
        "verdict": verdict,
        "sigma_factor": float(np.sqrt(mean / dof)),
        "n_above_single_bound": int(np.sum(nees[ok] > metrics.nees_bounds(dof, 1)[1])),
        "worst": {
            "id": int(ids[ok[w]]),
            "nees": float(nees[ok[w]]),
            "error_m": float(norms[w]),
            "sigma_m": float(sigma[w]),
        },
        "sigma_m": [float(np.min(sigma)), float(np.max(sigma))],
        "error_over_sigma_median": metrics.median(norms / sigma),
        "overconfident": verdict == "overconfident",
        "method": method,
    }


def confirm_after_map_only(check: dict[str, Any] | None, vectors: np.ndarray | None, cov: np.ndarray | None) -> None:
    """Keep an ``overconfident`` :func:`sigma_check` verdict (errors after the trajectory's alignment) only when the
    map is also above ``bound_any_correlation`` after an alignment of the map alone: ``vectors`` its errors and
    ``cov`` the covariances turned by its rotation (None: fewer than three landmarks not on one line, the verdict
    stays). That alignment takes the trajectory alignment's own error out, which Σ does not hold (7 of 70 consistent
    generated maps were called overconfident by it alone), and with it p = dof(dof + 1)/2 DoF (6 in 3-D, 3 on a
    planar map), so its mean NEES is the NEES sum over n − p/dof landmarks (``after_map_only``). Below that bound the
    verdict is ``inconclusive``, ``verdict_why`` says why."""
    if check is None or check["verdict"] != "overconfident":
        return
    dof, any_correlation = check["dof"], check["bound_any_correlation"]
    if vectors is None or cov is None:
        check["after_map_only"] = None
        return
    axes = ["xyz".index(a) for a in check.get("axes", "xyz")]
    nees = slam_metrics.landmark_nees(vectors[:, axes], cov[:, axes][:, :, axes])
    nees = nees[np.isfinite(nees)]
    if (found := map_only_mean(nees, dof)) is None:
        check["after_map_only"] = None
        return
    mean, removed = found
    check["after_map_only"] = {"mean_nees": mean, "n": int(nees.size), "dof_removed": removed}
    if mean > any_correlation:
        return
    check.update(verdict="inconclusive", overconfident=False)
    check["verdict_why"] = (
        f"above {any_correlation:.3g} after the trajectory's alignment, but {mean:.3g} after an alignment of the map "
        f"alone ({removed} DoF taken out): the excess is the trajectory alignment's own error, which the map's "
        "covariance does not hold"
    )


def confirm_in_gauge(
    check: dict[str, Any] | None,
    xyz: np.ndarray,
    truth: np.ndarray,
    cov: np.ndarray | None,
    gauge: tuple[np.ndarray, np.ndarray] | None,
) -> None:
    """Keep an ``overconfident`` :func:`sigma_check` verdict only when the map is also above
    ``bound_any_correlation`` in the estimator's gauge frame: the estimate ``xyz`` (matched rows, as written) moved
    by ``gauge`` (``(R, t)``, :func:`trajectory_evaluation.gauge_transform`: the transform that puts the gauge
    pose on the truth), ``cov`` turned by R, against ``truth``. Σ is relative to that pose; the trajectory's alignment
    places the map by its own error, and the map-only alignment moves the landmarks seen near the gauge, whose σ is
    a few mm (generated ground corner logs: 6 of 9 consistent maps overconfident after both, none in the gauge
    frame). The frame's mean NEES is ``in_gauge_frame``; at or below the bound the verdict is ``inconclusive``,
    ``verdict_why`` saying why. Nothing without a gauge (no trajectory truth or no covariance)."""
    if check is None or check["verdict"] != "overconfident" or gauge is None or cov is None:
        return
    rot, trans = gauge
    axes = ["xyz".index(a) for a in check.get("axes", "xyz")]
    errors = xyz @ rot.T + trans - truth
    nees = slam_metrics.landmark_nees(errors[:, axes], (rot @ cov @ rot.T)[:, axes][:, :, axes])
    nees = nees[np.isfinite(nees)]
    if not nees.size:
        return
    mean, any_correlation = float(np.mean(nees)), check["bound_any_correlation"]
    check["in_gauge_frame"] = {"mean_nees": mean, "n": int(nees.size)}
    if mean > any_correlation:
        return
    check.update(verdict="inconclusive", overconfident=False)
    after = check.get("after_map_only")
    also = f" ({after['mean_nees']:.3g} after the map-only alignment)" if after else ""
    check["verdict_why"] = (
        f"above {any_correlation:.3g} after the trajectory's alignment{also}, but {mean:.3g} in the estimator's gauge "
        "frame "
        "(its gauge pose put on the truth, the frame its covariance is defined in): the excess is the alignment's own "
        "error, which the map's covariance does not hold"
    )


def inconclusive_why(side: str, any_correlation: float) -> str:
    """Why a mean NEES ``side`` ("above" or "below") the bounds of independent values, and not above
    ``any_correlation``, decides nothing from one run: the pose's parts and the map say it alike."""
    if side == "above":
        return f"a mean of consistent values exceeds {any_correlation:.3g} with probability <= 2.5 % however correlated"
    return "no bound below holds for correlated values"


def map_sigma_note(check: dict[str, Any] | None, after: str) -> list[str]:
    """The note of a :func:`sigma_check` whose verdict is not within (errors measured ``after`` an alignment), else
    []: overconfident plainly (the σ's shortfall when the median ‖e‖/σ reaches ``MAP_SIGMA_FAR``, else how many
    landmarks and which one drive it); inconclusive as the pose's NEES says it (:func:`nees_note`)."""
    if not check or check["verdict"] == "within":
        return []
    lo, hi = check["sigma_m"]
    ratio, worst, mean = check["error_over_sigma_median"], check["worst"], check["mean_nees"]
    side = "above" if mean > check["bounds"][1] else "below"
    head = (
        f"mean landmark NEES {mean:.3g} {side} the 95 % bounds [{check['bounds'][0]:.3g}, {check['bounds'][1]:.3g}] "
        f"of {check['n']} independent landmarks"
    )
    if check.get("verdict_why"):  # above any correlation's bound, but not after the map-only alignment or the gauge
        field = "in_gauge_frame" if "in_gauge_frame" in check else "after_map_only"
        return [
            f"landmark map: {head}; its mean NEES is {check['verdict_why']}: not conclusive from one run "
            f"(landmarks.sigma_check.{field})"
        ]
    if check["verdict"] == "inconclusive":
        why = inconclusive_why(side, check["bound_any_correlation"])
        return [
            f"landmark map: {head}: the landmarks share the alignment's and the poses' errors, so one map strays "
            f"further than these bounds ({why}); not conclusive from one run (landmarks.sigma_check)"
        ]
    nees = (
        f"{head} and above {check['bound_any_correlation']:.3g}, which a mean of consistent values exceeds with "
        f"probability <= 2.5 % however correlated; {check['n_above_single_bound']} of them above one NEES's "
        f"{metrics.nees_bounds(check['dof'], 1)[1]:.3g}; worst landmark {worst['id']}: NEES {worst['nees']:.3g}, error "
        f"{worst['error_m']:.3g} m at σ {worst['sigma_m']:.2g} m"
    )
    if ratio >= MAP_SIGMA_FAR:
        head = f"its stated σ ({lo:.2g}-{hi:.2g} m) is {ratio:.3g}x below its error {after} (median error/σ)"
    else:
        head = f"its stated covariance does not cover its error {after} (median error/σ {ratio:.3g})"
    return [
        f"landmark map: {head}; {nees}: the map's covariance is overconfident (σ × {check['sigma_factor']:.2g} would "
        f"make the mean NEES its DoF {check['dof']}; landmarks.sigma_check)"
    ]


class LandmarkSection(Section):
    """The final map's error against the landmark truth: after the trajectory's alignment, and after an SE(3)
    alignment of the map alone (its shape error)."""

    METHOD = {
        "landmarks": (
            "final map moved by the same (s, R, t) as the trajectory (not re-fitted); "
            "error = ‖s R p̂_i + t − p_i‖ for ids present in both the estimate and the truth; "
            "map_aligned re-fits SE(3) on the landmarks alone; truth_never_estimated are true landmarks the "
            "run never saw, estimated_without_truth are estimated ids the truth does not know"
        )
    }
    MAP_ALIGNED_METHOD = (
        "SE(3) Umeyama fitted on the matched landmarks alone (map-only alignment); error = "
        "‖R_m p̂_i + t_m − p_i‖. The gap to error_m (trajectory alignment) is how far the map sits "
        "from where the trajectory puts it; error under this alignment is the map's shape error"
    )

    TURN_METHOD = (
        "the trajectory's alignment fixes a turn about the paired truth positions' main axis (their first principal "
        "direction, through their centre: axis, centre) only as far as turn_deg, the turn θ with 2(1 − cos θ)·across² "
        f"= ((1 + {slam_metrics.LOOSE_APE_SHARE:g})² − 1)·rmse² (raising the APE rmse by "
        f"{100 * slam_metrics.LOOSE_APE_SHARE:g} %; across_m the truth positions' RMS distance from the axis); "
        "best_turn_deg is the turn within ±turn_deg that brings the aligned map nearest its truth, error_turned_m the "
        "map error after it; per landmark alignment_slack_m is how far the turn by turn_deg moves it"
    )
    SIGMA_METHOD = (
        "per landmark NEES eᵀΣ⁻¹e of the error e after the trajectory's alignment and its loose turn "
        "(error_turned_m) against the landmark's covariance Σ turned likewise, over dof axes (3; on a planar map only "
        "the axes whose error is not zero on every landmark, named in axes: MR.CLAM's x, y); mean_nees against the "
        "two-sided 95 % χ² bounds of a mean of n independent values, χ²(dof·n)/n; error_over_sigma the error ‖e‖ "
        "over σ = sqrt(trace Σ / 3); n_above_single_bound the landmarks whose NEES is above one NEES's upper bound "
        "(χ²(dof) 97.5 %: 9.35 for 3), worst the landmark of the largest NEES; bound_any_correlation the level a mean "
        "of χ²(dof) values exceeds with probability <= 2.5 % however they are correlated, E[X | X > q] for one value "
        "X ~ χ²(dof) above its 97.5 % quantile q (11.5 for 3 DoF, 9.38 for 2: the mean lies below one value in "
        "convex order); the landmarks are correlated (they share the "
        "alignment's error and the poses' at their sightings), so the bounds of independent values do not hold for "
        "one map; verdict: overconfident above bound_any_correlation, inconclusive outside the bounds only, else "
        "within; sigma_factor = sqrt(mean_nees / dof), the factor the σ would need. The covariance is relative to the "
        "estimator's gauge (its start or anchor) and does not hold the alignment's own error, which a least-squares "
        "alignment adds to every landmark alike while absorbing part of the error Σ describes: a looser test than "
        "the trajectory's NEES, and a mean NEES hundreds of times the bound is no gauge effect"
    )
    #: the part of SIGMA_METHOD on :func:`confirm_after_map_only` (not in the map-only check, already after it)
    SIGMA_CONFIRM_METHOD = (
        "; an overconfident verdict stands only when the map is above bound_any_correlation after the map-only "
        "alignment too (after_map_only: the NEES sum over n − p/dof landmarks, p = dof(dof + 1)/2 the DoF that "
        "alignment takes out, 6 in 3-D, 3 on a planar map), which takes the trajectory alignment's own error out; "
        "else inconclusive, verdict_why saying so; with fewer than three landmarks not on one line (no such "
        "alignment: after_map_only null) it stands as it is; where the estimator's gauge pose has a truth "
        "(in_gauge_frame: the mean NEES of the map moved so that the gauge pose lies on the truth, the frame Σ is "
        "defined in, as the uncertainty section's), it stands only when above bound_any_correlation there too"
    )
    SIGMA_METHOD += SIGMA_CONFIRM_METHOD

    def __init__(self, landmark_truth: dict[int, np.ndarray] | None) -> None:
        super().__init__()
        self.landmark_truth = landmark_truth
        #: the matched landmarks' covariances in the estimate's frame, and their errors (vectors) after the map-only
        #: alignment with its rotation: what :meth:`map_only` checks the σ with
        self._map_cov: np.ndarray | None = None
        self._map_ids = np.empty(0, dtype=np.int64)
        self._map_only_fit: tuple[np.ndarray, np.ndarray] | None = None

    def process_data(
        self,
        landmarks: Table | None,
        al: Alignment,
        truth_xyz: np.ndarray | None = None,
        ape_rmse: float | None = None,
        gauge: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        """``truth_xyz``, ``ape_rmse``: the paired truth positions and the APE the alignment was fitted with (how
        loose it leaves the map's place: :meth:`_loose_turn`); without them the map is taken as the alignment puts
        it. ``gauge``: the transform that puts the estimator's gauge pose on the truth (:func:`confirm_in_gauge`)."""
        ids, xyz = landmark_table(landmarks)
        section: dict[str, Any] = {"n_estimated": int(ids.shape[0]), "truth_available": self.landmark_truth is not None}
        self.result = section
        if self.landmark_truth is None:
            section.update(
                n_truth=None,
                n_matched=0,
                error_m=None,
                per_landmark=[],
                estimated_without_truth=None,
                truth_never_estimated=None,
                map_aligned=None,
                alignment_turn=None,
                sigma_check=None,
            )
            return
        lm = metrics.landmark_errors(ids, xyz, self.landmark_truth, al.rot, al.trans, al.scale)
        row_of = {int(i): k for k, i in enumerate(ids)}
        raw = xyz[[row_of[int(i)] for i in lm.ids]] if lm.ids.size else np.empty((0, 3))
        map_err, map_aligned = self._map_only(raw, lm)
        turn, turned = self._loose_turn(lm, truth_xyz, ape_rmse)
        cov = landmark_covariances(landmarks)
        if cov is not None:  # the matched rows; into the truth frame by the alignment, then the loose turn
            self._map_cov, self._map_ids = cov[[row_of[int(i)] for i in lm.ids]], lm.ids
            cov = self._map_cov
            cov = al.scale**2 * (al.rot @ cov @ al.rot.T)
            cov = turned[1] @ cov @ turned[1].T
        sigmas = None if cov is None else rms_sigmas(cov)
        has_n_obs = landmarks is not None and "n_obs" in column_names(landmarks)
        n_obs = dict(zip(ids.tolist(), column(landmarks, "n_obs").tolist())) if has_n_obs else {}
        section.update(
            n_truth=len(self.landmark_truth),
            n_matched=int(lm.ids.shape[0]),
            error_m=metrics.statistics(lm.errors) if lm.ids.size else None,
            per_landmark=[
                {
                    "id": int(i),
                    "error_m": float(e),
                    "error_map_aligned_m": None if map_err is None else float(map_err[k]),
                    "error_turned_m": float(np.linalg.norm(turned[0][k] - q)) if turn else None,
                    "alignment_slack_m": float(turned[2][k]) if turn else None,
                    "sigma_m": None if sigmas is None or not np.isfinite(sigmas[k]) else float(sigmas[k]),
                    "estimate_aligned": [float(v) for v in p],
                    "truth": [float(v) for v in q],
                    "n_obs": int(n_obs[int(i)]) if int(i) in n_obs else None,
                }
                for k, (i, e, p, q) in enumerate(zip(lm.ids, lm.errors, lm.est_aligned, lm.truth))
            ],
            estimated_without_truth=[int(i) for i in lm.estimated_without_truth],
            truth_never_estimated=[int(i) for i in lm.truth_never_estimated],
            map_aligned=map_aligned,
            alignment_turn=turn,
            sigma_check=sigma_check(lm.ids, turned[0] - lm.truth, cov, self.SIGMA_METHOD) if lm.ids.size else None,
        )
        confirm_after_map_only(section["sigma_check"], *self._map_only_turned())
        confirm_in_gauge(section["sigma_check"], raw, lm.truth, self._map_cov if cov is not None else None, gauge)
        self.notes += self._map_place_note() + self._turn_note() + self._sigma_note() + self._unmatched_note(ids)

    def _loose_turn(
        self, lm: metrics.LandmarkErrors, truth_xyz: np.ndarray | None, ape_rmse: float | None
    ) -> tuple[dict | None, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The alignment's loose turn (:func:`slam_metrics.loose_turn`) with the map turned within it onto the
        landmark truth (:func:`slam_metrics.best_turn`): the section, and the turned map, the turn's rotation and
        each landmark's slack (how far the loosest turn moves it). The map unturned without a trajectory."""
        unturned = (lm.est_aligned, np.eye(3), np.zeros(lm.ids.shape[0]))
        if truth_xyz is None or ape_rmse is None or not lm.ids.size or len(truth_xyz) < 2:
            return None, unturned
        loose = slam_metrics.loose_turn(truth_xyz, ape_rmse)
        limit = np.radians(loose["turn_deg"])
        angle = slam_metrics.best_turn(lm.est_aligned, lm.truth, loose["axis"], loose["centre"], limit)
        rot, trans = slam_metrics.turn_about(loose["axis"], loose["centre"], angle)
        moved = lm.est_aligned @ rot.T + trans
        far = slam_metrics.turn_about(loose["axis"], loose["centre"], limit)
        slack = np.linalg.norm(lm.est_aligned @ far[0].T + far[1] - lm.est_aligned, axis=1)
        errors = np.linalg.norm(moved - lm.truth, axis=1)
        section = {**loose, "best_turn_deg": float(np.degrees(angle)), "error_turned_m": metrics.statistics(errors)}
        return section | {"method": self.TURN_METHOD}, (moved, rot, slack)

    def _turn_note(self) -> list[str]:
        """Say when the map error after the trajectory's alignment is mostly that alignment's freedom: a turn it
        holds loosely puts the map at least ``MAP_TURN_FACTOR`` times nearer its truth (TagSLAM test_22, batch: 1.92 m
        against a trajectory APE of 0.176 m, its trajectory a 1.8 m line with tags up to 2.4 m off it)."""
        turn, placed = self.result.get("alignment_turn"), self.result.get("error_m") or {}
        if not turn or placed.get("rmse") is None:
            return []
        rmse, turned = placed["rmse"], turn["error_turned_m"]["rmse"]
        if rmse <= max(MAP_TURN_MIN_M, MAP_TURN_FACTOR * turned):
            return []
        slack = max(row["alignment_slack_m"] for row in self.result["per_landmark"])
        return [
            f"landmark map: {rmse:.3g} m from its truth after the trajectory's alignment, {turned:.3g} m after a turn "
            f"of {turn['best_turn_deg']:.3g} deg about the truth trajectory's main axis, which that alignment does "
            f"not fix (the trajectory lies {turn['across_m']:.3g} m RMS off that axis: a turn of up to "
            f"{turn['turn_deg']:.3g} deg raises its APE by <= {100 * slam_metrics.LOOSE_APE_SHARE:g} % and moves the "
            f"landmarks by up to {slack:.3g} m): the {rmse:.3g} m is mostly the alignment's, not the map's "
            "(landmarks.alignment_turn)"
        ]

    def _sigma_note(self) -> list[str]:
        """Say when the map's stated σ is far below its error (TagSLAM test_22, riekf: σ 0.02-0.03 m against errors
        of 3.9-5.5 m, and no word), or when its mean NEES is outside the bounds of independent landmarks only
        (:func:`map_sigma_note`)."""
        turn = self.result.get("alignment_turn")
        at_limit = turn is not None and abs(turn["best_turn_deg"]) >= turn["turn_deg"] and turn["turn_deg"] < 180
        after = "after the trajectory's alignment and its loose turn" if turn else "after the trajectory's alignment"
        notes = map_sigma_note(self.result.get("sigma_check"), after)
        if notes and at_limit:  # the turn stopped at its limit: the error may still hold the alignment's freedom
            notes[0] += (
                f" (the turn stopped at its {turn['turn_deg']:.3g} deg limit: part of that error may be the "
                "alignment's)"
            )
        return notes

    def _unmatched_note(self, ids: np.ndarray) -> list[str]:
        """Say when most estimated landmarks have no truth by id: a map error over a few of them, or none at all
        (MR.CLAM with its landmark ids negated: no map error and no word why)."""
        matched, truth = self.result["n_matched"], sorted(self.landmark_truth or ())
        if not ids.size or not truth or 2 * matched >= ids.size:
            return []
        what = "no map error" if not matched else f"the map error covers those {matched} only"
        return [
            f"landmark map: {matched} of the {ids.size} estimated landmark ids are in the landmark truth "
            f"(estimated ids {int(ids.min())}..{int(ids.max())}, truth ids {truth[0]}..{truth[-1]}): {what} "
            "(the truth numbers the landmarks otherwise?)"
        ]

    def _map_only(self, raw: np.ndarray, lm: metrics.LandmarkErrors) -> tuple[np.ndarray | None, dict | None]:
        """Per-landmark error after an SE(3) alignment of the matched landmarks alone, and its section."""
        fit = slam_metrics.map_only_alignment(raw, lm.truth) if lm.ids.size else None
        if fit is None:
            return None, None
        rot_m, trans_m = fit
        vectors = metrics.apply_alignment(rot_m, trans_m, 1.0, raw) - lm.truth
        self._map_only_fit = rot_m, vectors
        map_err = np.linalg.norm(vectors, axis=1)
        return map_err, {
            "error_m": metrics.statistics(map_err),
            "alignment": alignment_dict(Alignment("se3", rot_m, trans_m, 1.0, int(lm.ids.size))),
            "method": self.MAP_ALIGNED_METHOD,
        }

    def _map_place_note(self) -> list[str]:
        """Say when the map's shape fits the landmark truth but its place does not: the landmark truth in another
        frame than the trajectory truth (a UTM truth file beside the log's landmark truth gave landmark errors of
        4,700 km and no word why), or a map that disagrees with its own trajectory."""
        mine = (self.result.get("map_aligned") or {}).get("error_m") or {}
        placed = self.result.get("error_m") or {}
        if mine.get("rmse") is None or placed.get("rmse") is None:
            return []
        if placed["rmse"] <= max(MAP_PLACE_MIN_M, MAP_PLACE_FACTOR * mine["rmse"]):
            return []
        return [
            f"landmark map: {placed['rmse']:.4g} m from its truth after the trajectory's alignment, "
            f"{mine['rmse']:.4g} m after an alignment of its own: its shape fits the landmark truth, its place "
            "does not (the landmark truth in another frame than the trajectory truth, or a map that disagrees "
            "with its trajectory)"
        ]

    def map_only(self) -> dict[str, Any] | None:
        """The map error of a run without trajectory truth (processed with no alignment): the landmarks after a
        map-only SE(3) alignment (needs three matched landmarks not on one line; None otherwise)."""
        section = self.result
        if section is None or section["map_aligned"] is None:
            return None
        return {
            "n_estimated": section["n_estimated"],
            "n_truth": section["n_truth"],
            "n_matched": section["n_matched"],
            "error_m": section["map_aligned"]["error_m"],
            "alignment": section["map_aligned"]["alignment"],
            "method": section["map_aligned"]["method"],
            "per_landmark": [
                {"id": row["id"], "error_m": row["error_map_aligned_m"], "n_obs": row["n_obs"]}
                for row in section["per_landmark"]
            ],
            "estimated_without_truth": section["estimated_without_truth"],
            "truth_never_estimated": section["truth_never_estimated"],
            "sigma_check": self.map_only_sigma_check(),
        }

    #: the σ check of :meth:`map_only`: the map-only alignment's error
    MAP_ONLY_SIGMA_METHOD = (
        SIGMA_METHOD.replace(SIGMA_CONFIRM_METHOD, "")
        .replace("after the trajectory's alignment and its loose turn (error_turned_m)", "after the map-only alignment")
        .replace(
            "mean_nees against the two-sided 95 % χ² bounds of a mean of n independent values, χ²(dof·n)/n",
            "mean_nees the NEES sum over n − p/dof landmarks, p = dof(dof + 1)/2 the DoF that alignment takes out "
            "(dof_removed: 6 in 3-D, 3 on a planar map), against the two-sided 95 % χ² bounds of such a mean of "
            "independent values, χ²(dof·n − p)/(n − p/dof)",
        )
    )

    def _map_only_turned(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The matched landmarks' errors after the map-only alignment and their covariances turned by its rotation
        (None, None without that alignment or a covariance)."""
        if self._map_cov is None or self._map_only_fit is None:
            return None, None
        rot, vectors = self._map_only_fit
        return vectors, rot @ self._map_cov @ rot.T

    def map_only_sigma_check(self) -> dict[str, Any] | None:
        """:func:`sigma_check` of the error after the map-only alignment (the covariance turned by its rotation)."""
        vectors, cov = self._map_only_turned()
        if vectors is None:
            return None
        return sigma_check(self._map_ids, vectors, cov, self.MAP_ONLY_SIGMA_METHOD, map_only=True)


def map_only_section(landmarks: Table | None, landmark_truth: dict[int, np.ndarray]) -> dict[str, Any] | None:
    """Map error of a run without trajectory truth: :meth:`LandmarkSection.map_only`, the same numbers as the
    report's ``map_aligned``."""
    section = LandmarkSection(landmark_truth)
    section.process_data(landmarks, Alignment("none", np.eye(3), np.zeros(3), 1.0, 0))
    if (found := section.map_only()) is not None:  # no trajectory alignment to name a gap to
        found["method"] = section.MAP_ALIGNED_METHOD.split(". The gap", 1)[0] + (
            ": the map's shape error (no trajectory truth to place it by)"
        )
        found["notes"] = map_sigma_note(found["sigma_check"], "after an alignment of its own")
        # each matched landmark's truth carried onto the estimate by the inverse of that alignment: the map figure
        # draws it beside the estimate, which stays as written (x = Rᵀ (p − t) of the fit x ↦ R x + t)
        rot = np.asarray(found["alignment"]["rotation_matrix"], dtype=np.float64)
        trans = np.asarray(found["alignment"]["translation_m"], dtype=np.float64)
        for row in found["per_landmark"]:
            row["truth_on_estimate_m"] = _vec(rot.T @ (np.asarray(landmark_truth[row["id"]], dtype=np.float64) - trans))
    return found


def _vec(v: Any) -> list[float]:
    return [float(x) for x in np.asarray(v, dtype=np.float64).reshape(3)]


class BiasSection(Section):
    """The final bias estimates against their truth, and how still they are over the last stretch of the run."""

    METHOD = {
        "biases": (
            "final = last row of the bias table; biases are body-frame quantities, unaffected by the "
            "alignment; error = truth − estimate, error_norm = its Euclidean norm; stability over the last "
            "window_fraction of the bias time span: per-axis mean, std, range and least-squares slope "
            "(drift_norm_per_s = ‖slope‖); window_error = truth − window mean"
        )
    }

    def __init__(self, bias_truth: dict[str, np.ndarray] | None, window_fraction: float) -> None:
        super().__init__()
        self.truth = (
            None if bias_truth is None else {"gyro": _vec(bias_truth["gyro"]), "velocity": _vec(bias_truth["velocity"])}
        )
        self.window_fraction = window_fraction

    def process_data(self, biases: Table | None) -> None:
        truth = self.truth
        section: dict[str, Any] = {
            "final": None,
            "truth": truth,
            "error": None,
            "error_norm": None,
            "stability": None,
            "window_error": None,
            "window_error_norm": None,
        }
        self.result = section
        if biases is None or n_rows(biases) == 0:
            return
        require_columns(biases, ("t_ns",) + GYRO_COLUMNS + VEL_COLUMNS, "biases")
        order = time_order(column(biases, "t_ns", np.int64))
        t_ns = column(biases, "t_ns", np.int64)[order]
        gyro = [column(biases, c, np.float64)[order] for c in GYRO_COLUMNS]  # columns: no (N, 3) copy
        vel = [column(biases, c, np.float64)[order] for c in VEL_COLUMNS]
        final = {"t_ns": int(t_ns[-1]), "gyro": _vec([c[-1] for c in gyro]), "velocity": _vec([c[-1] for c in vel])}
        section["final"] = final
        stab = {
            "window_fraction": float(self.window_fraction),
            "gyro": slam_metrics.window_stats(t_ns, gyro, self.window_fraction),
            "velocity": slam_metrics.window_stats(t_ns, vel, self.window_fraction),
        }
        section["stability"] = stab
        if truth is not None:
            err = {k: [t - e for t, e in zip(truth[k], final[k])] for k in ("gyro", "velocity")}
            section["error"] = err
            section["error_norm"] = {k: float(np.linalg.norm(err[k])) for k in err}
            werr = {k: [t - e for t, e in zip(truth[k], stab[k]["mean"])] for k in ("gyro", "velocity")}
            section["window_error"] = werr
            section["window_error_norm"] = {k: float(np.linalg.norm(werr[k])) for k in werr}


def truth_at_rest(ev: TrajectoryEvaluation) -> bool:
    """Whether the truth does not translate (a rig turning in place): its positions spread along no axis over
    their noise (:func:`.align.translates`), their RMS distance from their centre that noise. Asked only of a run
    the report aligned by the attitudes (:data:`ATTITUDE`), the one kind such a truth gets: a spreading truth's
    report pays for no spread check here."""
    return ev.alignment.kind == ATTITUDE and not translates(ev.paired.ref_pos)


def scene_extent(ev: TrajectoryEvaluation, scene: np.ndarray | None) -> float | None:
    """The scale the convergence verdict judges a truth at rest by (:func:`truth_at_rest`; beside its own extent,
    its noise, any estimate would be "lost"): the landmarks' ``scene`` (M, 3, truth frame) RMS distance from the
    truth's centre, how far off an estimate must be to have never found where it is among them; None without
    landmarks."""
    if scene is None or len(scene) == 0:
        return None
    return slam_metrics.rms_extent(scene, np.mean(ev.paired.ref_pos, axis=0))


class ConvergenceSection(Section):
    """When the aligned position error reaches the observer's own steady level (:func:`slam_metrics.convergence`)."""

    METHOD = {
        "convergence": (
            "the error level is the running median of the aligned position error over a centred window of "
            "window_fraction of the log's time span (window_s; evaluated at up to 2000 evenly spaced stamps, over "
            "an even stride of at most 2001 errors of the window); "
            "steady_level_m is its highest value over the last tail_fraction of the span, band_m = "
            "max(threshold_m, band_factor × steady_level_m); t_ns is the first stamp after which the level "
            "stays within band_m to the end (a stay outside shorter than window_s is no departure): when the observer "
            "reaches its own steady level, not when noise "
            "last crossed a fixed threshold; null if the last level is above the band, or if the error still "
            "grows (growing: tail_level_m, the median level over the last tail_fraction, is above growth_factor × "
            "earlier_level_m, the median level over the tail_fraction before it, or above growth_factor × "
            "before_tail_level_m, the median level over everything before it, and above threshold_m, and the rise "
            "above growth_standard_errors × growth_se_m, the standard error of the rise were the level before the "
            "tail one process (the scatter about a line of the medians over every tail-long stretch before the tail), "
            "unless it "
            "settled in the frame of the run's end: tail_frame, the report's alignment kind fitted on the last "
            "tail_fraction's pairs only, its level within max(threshold_m, band_factor × its highest level over "
            "that tail) from at least 2 × tail_fraction before the end, without an earlier as long stay in that "
            "band it left; t_ns is then that time, and lost and coarse judge that level: one fit over the whole run "
            "is pulled toward a long bad stretch, e.g. a first lap before its loop closed, and puts a right "
            "second lap off; a drift does not settle in that frame), or if "
            "steady_level_m is above both threshold_m and trajectory_extent_m, the truth's RMS distance from its "
            "centre (lost: the estimate never locked on to the motion; where the truth does not translate, a rig "
            "turning in place whose positions spread along no axis over their noise, the report's alignment then "
            "the attitude one, scene_extent_m instead, the RMS distance from the truth's centre of the landmarks "
            "the run mapped: their truth positions, else the estimate's through the alignment; no verdict of lost "
            "or coarse without either), "
            "or if the level was within band_m before, "
            "for at least as long as from that time to the end, and left it again for at least window_s (recurring_s: "
            "that stretch, s "
            "after the estimate start: an error that returns, e.g. once a lap); coarse: steady_level_m above "
            "coarse_share × "
            "trajectory_extent_m (or scene_extent_m) and threshold_m but not lost (the report states the level as a "
            "share of the "
            "extent beside the convergence time); "
            "steady_error_m is the "
            "median error over the last tail_fraction; t_since_start_s counts from the first estimate stamp"
        )
    }

    def __init__(self, threshold_m: float) -> None:
        super().__init__()
        self.threshold_m = threshold_m

    def process_data(self, ev: TrajectoryEvaluation, scene: np.ndarray | None = None) -> None:
        """``scene``: the landmarks (M, 3) in the truth frame, the scale a truth that does not translate is judged
        by (:func:`scene_extent`)."""
        t0 = int(ev.estimate.t_ns[0])
        extent = ev.truth_extent_m
        rest = truth_at_rest(ev)
        scene_m = scene_extent(ev, scene) if rest else None
        scale = scene_m if rest else extent
        c = slam_metrics.convergence(
            ev.pair_t_est_ns, ev.translation.errors, self.threshold_m, ev.error_level, scale, refit_errors(ev)
        )
        tail_frame = c["tail_frame"]
        self.result = {
            "threshold_m": float(self.threshold_m),
            "window_s": c["window_s"],
            "steady_error_m": c["steady_error"],
            "steady_level_m": c["steady_level"],
            "band_m": c["band"],
            "window_fraction": slam_metrics.WINDOW_FRACTION,
            "tail_fraction": slam_metrics.TAIL_FRACTION,
            "band_factor": slam_metrics.BAND_FACTOR,
            "tail_level_m": c["tail_level"],
            "earlier_level_m": c["earlier_level"],
            "before_tail_level_m": c["before_tail_level"],
            "growth_factor": slam_metrics.GROWTH_FACTOR,
            "growth_se_m": c["growth_se"],
            "growth_standard_errors": slam_metrics.GROWTH_SES,
            "growing": c["growing"],
            "trajectory_extent_m": extent,
            "scene_extent_m": scene_m,
            "lost": c["lost"],
            "coarse_share": slam_metrics.COARSE_SHARE,
            "steady_level_share": c["settled_level"] / scale if scale else None,
            "coarse": c["coarse"],
            "estimate_start_ns": t0,
            "recurring_s": None if c["recurring"] is None else [(x - t0) / 1e9 for x in c["recurring"]],
            "tail_frame": None
            if tail_frame is None
            else {"steady_level_m": tail_frame["steady_level"], "band_m": tail_frame["band"]},
            "t_ns": c["t_ns"],
            "t_since_start_s": None if c["t_ns"] is None else (c["t_ns"] - t0) / 1e9,
        }


def refit_errors(ev: TrajectoryEvaluation) -> Callable[[np.ndarray], np.ndarray] | None:
    """``mask -> errors``: the position errors of all pairs under ``ev``'s alignment kind fitted on the pairs of
    ``mask`` only (the convergence section's frame of the run's end, :func:`slam_metrics.settled_in_tail_frame`);
    None for the alignments that fit nothing to choose (origin, none)."""
    kind, ref, est = ev.alignment.kind, ev.paired.ref_pos, ev.paired.est_pos
    if kind in ("origin", "none", ATTITUDE):  # the attitude's rotation comes from all pairs' attitudes
        return None
    # the report's kind, which passed the spread check on all pairs, refitted on some as evo would
    return lambda mask: metrics.row_norms(
        fit_alignment(kind, ref[mask], est[mask], spread_check=False).positions(est), ref
    )


#: Degrees of freedom of the position and of the attitude NEES.
NEES_DOF = 3
#: Seconds of pairs each NEES window averages (the figure's points and the share of windows within bounds).
NEES_WINDOW_S = 1.0


class UncertaintySection(Section):
    """The estimator's own covariance against its error (riekf, batch): NEES with its χ² bounds and the share of
    errors within 3σ, as OpenVINS's ov_eval checks a filter's consistency. None for the observers."""

    METHOD = {
        "uncertainty": (
            "error (δθ, δp) of each pair, R_est = Exp(δθ) R_truth and p_est = p_truth + δp in the truth frame, the "
            "estimate moved rigidly so that its gauge pose (the pair with the smallest covariance: riekf's start, "
            "batch's anchor keyframe) lies on the truth (the covariance is relative to it; a least-squares alignment "
            "would absorb part of the error it describes), against the covariance turned likewise; NEES = eᵀ Σ⁻¹ e per "
            "part over its DoF axes (3 each; on a planar run only the axes whose error is not zero on every pair: "
            "the DoF column, the others' share within ±3σ null); bounds are two-sided 95 % χ² bounds of an average "
            f"of n independent NEES values, χ²(DoF·n)/n; windows of {NEES_WINDOW_S:g} s; pairs whose covariance "
            f"block is below {GAUGE_SIGMA:g} (the gauge) are left out; bound_any_correlation E[X | X > q] of one "
            "NEES value X ~ χ²(DoF) above its 97.5 % quantile q (11.5 for 3 DoF), which a mean of consistent values "
            "exceeds with probability at most 2.5 % however correlated (it is below one value in convex order); "
            "verdict: overconfident above it, inconclusive outside bounds only, else within; sigma_factor = "
            "sqrt(mean / DoF)"
        )
    }

    def process_data(self, ev: TrajectoryEvaluation) -> None:
        u = ev.uncertainty
        if u is None:
            return
        t_s = (u.t_ns - u.t_ns[0]) / NS_PER_S
        self.result = {
            "frame": "truth frame, the estimate's gauge pose put on the truth; R_est = Exp(δθ) R_truth, "
            "p_est = p_truth + δp",
            "gauge_t_ns": u.gauge_t_ns,
            "window_s": NEES_WINDOW_S,
            "position": nees_statistics(u.error[:, 3:], u.cov_position, u.nees_position, t_s, len(u.position_axes)),
            "attitude": nees_statistics(u.error[:, :3], u.cov_attitude, u.nees_attitude, t_s, len(u.attitude_axes)),
        }
        for part, axes in (("position", u.position_axes), ("attitude", u.attitude_axes)):
            if len(axes) < NEES_DOF:
                self.result[part]["axes"] = ["xyz"[i] for i in axes]
                if within := self.result[part]["within_3sigma"]:  # an axis with no error is "within" by nothing
                    self.result[part]["within_3sigma"] = [v if i in axes else None for i, v in enumerate(within)]
                off = ", ".join("xyz"[i] for i in range(3) if i not in axes)
                self.notes.append(
                    f"{part} NEES over {', '.join('xyz'[i] for i in axes)} only ({len(axes)} DoF, expected mean "
                    f"{len(axes)}): the {part} error about {off} is zero on every pair (a planar run), so the "
                    "covariance there is measured against nothing"
                )
        over = [part for part in ("position", "attitude") if self.result[part].get("verdict") == "overconfident"]
        turn = body_turn_nees(ev, self.result) if over and isinstance(ev, TrajectoryEvaluation) else None
        if turn is not None:
            self.result["body_turn"] = turn
        for part in ("position", "attitude"):
            if note := nees_note(part, self.result[part]):
                self.notes.append(note + (body_turn_words(turn) if part in over and turn else ""))


def body_turn_nees(ev: TrajectoryEvaluation, result: dict[str, Any]) -> dict[str, Any]:
    """report.json ``uncertainty.body_turn``: an overconfident verdict checked against a body-fixed systematic error,
    which no white-noise σ covers: the constant turn X between the estimate's body frame and the truth's (hand-eye on
    the aligned pairs, :func:`truth_body_rotation`, the fit ``ape.truth_frame_turn`` makes above 20 deg of rotation
    APE), and each part's mean NEES again with the truth's rotations turned by it (``R_truth Xᵀ``, the gauge put on that
    truth; positions unchanged; over the axes of the verdict). ``explains``: every overconfident part's mean is then at
    most its ``bound_any_correlation``, the bound its verdict was judged by (a stated rule, no threshold of its own). A
    camera's extrinsic stated 3 deg tilted on a hand-held log (seed=9993, batch given the true noise): position /
    attitude NEES 16.6 / 58.9 against the truth, 1.75 / 2.12 with its 2.8 deg turn out; a ground robot's floor
    (seed=9991, 22.2 / 10.1) has a turn of 0.45 deg that changes nothing (docs/benchmarks.md, "batch's stated σ on
    generated logs the truth finds converged, session 39")."""
    x, _ = truth_body_rotation(ev)
    q = rots_to_quats(x[None])[0]
    q = q if q[3] >= 0 else -q
    p = ev.paired
    ref = np.empty((len(p), 3, 3))
    for rows in row_blocks(len(p)):
        ref[rows] = np.matmul(p.ref_rot[rows], x.T)
    turned = replace(ev, truth=turned_truth(ev.truth, q), paired=replace(p, ref_rotation=ref))
    u, kept = paired_uncertainty(turned), ev.uncertainty
    means = {}
    for part, err, cov, axes in (
        ("position", u.error[:, 3:], u.cov_position, kept.position_axes),
        ("attitude", u.error[:, :3], u.cov_attitude, kept.attitude_axes),
    ):  # over the axes the verdict was over (a planar run's), whatever the turn leaves on the others
        a = list(axes)
        nees = nees_values(err[:, a], cov[:, a][:, :, a])
        ok = np.isfinite(nees)
        means[part] = float(np.mean(nees[ok])) if ok.any() else None
    over = [k for k in ("position", "attitude") if result[k].get("verdict") == "overconfident"]
    explains = all(means[k] is not None and means[k] <= result[k]["bound_any_correlation"] for k in over)
    axis = q[:3] / (np.linalg.norm(q[:3]) or 1.0)
    return {
        "angle_deg": float(np.degrees(2.0 * np.arctan2(np.linalg.norm(q[:3]), q[3]))),
        "axis": [float(v) for v in axis],
        "quat_xyzw": [float(v) for v in q],
        "position_mean": means["position"],
        "attitude_mean": means["attitude"],
        "explains": bool(explains),
    }


def body_turn_words(turn: dict[str, Any]) -> str:
    """The clause an overconfident NEES note gains from :func:`body_turn_nees`'s ``turn``: the turn that explains
    the excess, or that a constant turn does not."""
    pos, att = (f"{v:.3g}" if v is not None else "n/a" for v in (turn["position_mean"], turn["attitude_mean"]))
    if not turn["explains"]:
        return (
            f"; a constant turn between the estimate's body frame and the truth's does not explain it (the best, "
            f"{turn['angle_deg']:.2g} deg, leaves NEES {pos} / {att}, position / attitude: uncertainty.body_turn)"
        )
    axis = turn["axis"]
    return (
        f"; the excess is a constant {turn['angle_deg']:.2g} deg turn between the estimate's body frame and the "
        f"truth's, about [{axis[0]:.3f}, {axis[1]:.3f}, {axis[2]:.3f}] (with the truth turned by it the NEES is "
        f"{pos} / {att}, position / attitude: uncertainty.body_turn): a body-fixed systematic error, such as a "
        "sensor's stated extrinsic turned (a camera's tilt: `slamobs info --noise LOG` checks it against the motion) "
        "or a truth in another body frame; the written σ covers the stated white noise only, no such error"
    )


def nees_note(part: str, r: dict[str, Any]) -> str | None:
    """The note of a part's NEES outside its bounds (``verdict``), else None: plainly overconfident above the bound
    no correlation of the errors explains, else not conclusive from one run."""
    if not r["n"] or r["verdict"] == "within":
        return None
    side = "above" if r["mean"] > r["bounds"][1] else "below"
    head = (
        f"{part} NEES {r['mean']:.3g} (DoF {r.get('dof', NEES_DOF)}) is {side} the 95 % bounds [{r['bounds'][0]:.3g}, "
        f"{r['bounds'][1]:.3g}] of a mean of independent values"
    )
    if r["verdict"] == "inconclusive":
        return (
            f"{head}: consecutive errors are correlated, so one run strays further than these bounds "
            f"({inconclusive_why(side, r['bound_any_correlation'])}); not conclusive from one run (the test of "
            "consistency is the mean over runs)"
        )
    return (
        f"{head} and above {r['bound_any_correlation']:.3g}, which a mean of consistent values exceeds with "
        f"probability <= 2.5 % however correlated: the {part} covariance is overconfident, its σ "
        f"understates the error (σ × {r['sigma_factor']:.2g} would make the mean NEES its DoF); do not take the "
        f"written {part} σ at face value"
    )


#: what removes a turned truth where the run's frames say nothing more (:func:`turn_mend`)
TURN_MEND = (
    "frames.truth_rotation turns the truth for the report; frames.truth: FRAME, where the truth is of a frame TF "
    "places on the body, carries it, lever arm too"
)


def turn_mend(run_input: dict[str, Any]) -> str:
    """What removes a truth frame turned against the estimate's (``ape.truth_frame_turn``), from what the run knew of
    its frames (run.json ``input``: ``truth_body``, ``body_frame_from``, ``base_frame``; report.json
    ``truth_frame_turn.mend``, set by :func:`.report.add_run_context`). ``frames.body`` is offered nowhere: a truth
    whose child_frame_id names the body's frame is then carried from it to the new body, the turn the wrong way
    (TagSLAM test_21 against its reference with ``frames.body: rig``: rotation APE 178.7 deg, 1.96 with
    ``frames.truth: rig``); ``frames.truth`` carries the truth to whichever body the run has. Where the run carried
    the truth from its child_frame_id, that frame may not be its poses' (TagSLAM's reference names the odometry's
    frame and holds the rig's); where a base frame is placed on a body taken from an odometry, the truth is most
    likely the base's; where the truth was carried from the stated frame, only the report's turn is left (TagSLAM
    test_22 riekf with ``frames.truth: rig``: 42 deg left, 35 deg with ``frames.body: rig`` beside it)."""
    carried, base = run_input.get("truth_body") or {}, run_input.get("base_frame") or {}
    from slamobs.pipeline.alignment import BODY_FROM_CONFIG, TRUTH_FRAME_FROM_MESSAGE

    if carried.get("from") == TRUTH_FRAME_FROM_MESSAGE:
        return (
            f"frames.truth: FRAME, the frame the truth's poses are of (the run carried them from their "
            f"child_frame_id '{carried['frame']}', which may name another: the note on the truth's frame), or "
            "frames.truth_rotation for the report, removes it; frames.body does not (the truth is carried to the body)"
        )
    if carried:
        return (
            f"frames.truth_rotation for the report removes it; the truth was carried from frames.truth "
            f"'{carried['frame']}' already, so no frame key does"
        )
    if base and run_input.get("body_frame_from") not in (None, BODY_FROM_CONFIG):
        return (
            f"if the truth is the base's (the body-frame note), frames.truth: {base['frame']} carries it to the body "
            "and removes it; frames.truth_rotation turns it for the report"
        )
    return TURN_MEND


def relative_errors_turned(turn: dict[str, Any] | None) -> list[str]:
    """The sentence over report.md's relative errors (RPE, drift, segment errors) once the APE section found the
    truth's body frame turned against the estimate's (``turn``: ``ape.truth_frame_turn``, :func:`truth_frame_turn`).
    Those errors compare each trajectory's motion in its own body frame (evo's RPE, KITTI's drift, rpg's segment
    errors), so the turn is in them (TagSLAM test_22 riekf, truth turned 147.8 deg: segment errors 104-140 %, RPE
    1.5 m on 1 m); they are kept as defined, the numbers evo_rpe gives on the same two trajectories, and the sentence
    says the turn is in them and what removes it. Empty without a turn."""
    if not turn:
        return []
    mend = (
        "correct the camera's extrinsic (the note on the rotation APE names it) and run again"
        if turn.get("camera_named")
        else turn.get("mend") or TURN_MEND
    )
    return [
        f"Note: {TRUTH_FRAME_TURNED} by {turn['angle_deg']:.1f} deg (the note on the rotation APE); the relative "
        "errors below compare each trajectory's motion in its own body frame (evo's RPE, KITTI's drift, rpg's segment "
        f"errors), so that turn is in them, translation and rotation: {mend}."
    ]


#: a NEES note's start (:func:`nees_note`), not the planar note's ("position NEES over x, y only")
_NEES_NOTE = re.compile(r"^(position|attitude) NEES [-+.\deinf]+ \(DoF")


def nees_against_turned_truth(turn: dict[str, Any] | None, nees_notes: list[str]) -> list[str]:
    """The uncertainty section's notes once the APE section found the truth's body frame turned against the
    estimate's (``turn``: ``ape.truth_frame_turn``, :func:`truth_frame_turn`): each NEES verdict then says that it
    compares the estimate with a truth in another body frame (a position NEES of 2.6e6 on a log whose odometry's
    child frame is a sensor turned 90 deg, beside centimetres of translation APE), so the turn is in it. The notes
    as they are otherwise."""
    if not turn:
        return nees_notes
    why = (
        f"; but {TRUTH_FRAME_TURNED} (the note on the rotation APE): this NEES holds the estimate against a truth in "
        "another body frame, so that turn is in it: judge the covariance once the frames agree (report.md's note "
        "over the relative errors names the key)"
    )
    return [f"{n}{why}" if _NEES_NOTE.match(n) else n for n in nees_notes]


#: A reliable clock offset not applied whose APE with it applied is this share of the APE without or less: the truth's
#: clock is a visible part of the error the NEES holds against the covariance. A margin, not tuned: seed=3967 (truth
#: stamps 0.2 s late) riekf 0.073 m against 0.190 (0.39), NEES 799 "overconfident" as it was, 4.69 with it applied.
OFFSET_NEES_SHARE = 0.8


def nees_against_offset_truth(offset: dict[str, Any], nees_notes: list[str]) -> list[str]:
    """The uncertainty section's notes once the report found a clock offset between the truth and the estimate
    that it did not apply (``offset``: report.json's ``time_offset``) and that takes the APE to
    ``OFFSET_NEES_SHARE`` of itself or less: each NEES verdict then says that the truth's clock is in it. A reliable
    offset (seed=3967: "overconfident" at 799, 4.69 with the offset applied); or one with a clear peak that only the
    halves held back, their offsets apart (:func:`.sync.halves_agree`): a truth clock that drifts against the log's
    (seed=4119, drifting 1e-3: batch's NEES 331 "overconfident", its halves 0.058 s apart, the APE 0.044 m with the
    mean offset against 0.070 m). The notes as they are otherwise."""
    with_m, without_m = offset.get("ape_rmse_with_m"), offset.get("ape_rmse_without_m")
    if offset.get("applied_s") or with_m is None or not without_m or with_m > OFFSET_NEES_SHARE * without_m:
        return nees_notes
    if offset.get("reliable"):
        why = (
            f"; but the truth's clock looks {offset['estimated_s']:+.3g} s off the estimate's (the clock offset, "
            f"reliable, not applied: the APE {with_m:.3g} m with it against {without_m:.3g} m): this NEES holds the "
            "estimate against a truth that far off in time, so that is in it: judge the covariance with the offset "
            "applied (`slamobs report RUN_DIR --t-offset auto`)"
        )
    elif _halves_only(offset):
        why = (
            f"; but the truth's clock looks off the estimate's by an amount that varies over the log (the clock "
            f"offset {offset['estimated_s']:+.3g} s, peak correlation {offset['peak_correlation']:.2f}, not reliable: "
            f"{halves_owner(offset.get('searched_against'))} find offsets {2 * offset['uncertainty_s']:.3g} s apart: "
            f"a truth clock that drifts against the log's, or steps; the APE {with_m:.3g} m with that one offset "
            f"against {without_m:.3g} m): this NEES holds the estimate against a truth off in time, so that is in it: "
            "judge the covariance against a truth on the log's clock"
        )
    else:
        return nees_notes
    return [f"{n}{why}" if _NEES_NOTE.match(n) else n for n in nees_notes]


def _halves_only(offset: dict[str, Any]) -> bool:
    """report.json's ``time_offset`` ``offset`` has a clear peak (``PEAK_CORRELATION_MIN``) inside its window whose
    log halves disagree (:func:`.sync.halves_agree`): an offset that is not one value over the log."""
    unc, est, grid = offset.get("uncertainty_s"), offset.get("estimated_s"), offset.get("grid_step_s")
    if unc is None or est is None or grid is None or (offset.get("peak_correlation") or 0.0) < PEAK_CORRELATION_MIN:
        return False
    inside = abs(est) < (offset.get("search_window_s") or np.inf) - grid  # not on the search's edge
    return inside and not halves_agree(unc, grid, est)


def nees_windows(nees: np.ndarray, t_s: np.ndarray, window_s: float = NEES_WINDOW_S):
    """Average NEES over consecutive windows of ``window_s`` seconds: window mid times, averages, counts."""
    ok = np.isfinite(nees)
    k = np.floor(t_s[ok] / window_s).astype(np.int64)
    if k.size == 0:
        return np.empty(0), np.empty(0), np.empty(0, np.int64)
    ids, inv, counts = np.unique(k, return_inverse=True, return_counts=True)
    return (ids + 0.5) * window_s, np.bincount(inv, weights=nees[ok]) / counts, counts


def nees_statistics(
    error: np.ndarray, cov: np.ndarray, nees: np.ndarray, t_s: np.ndarray, dof: int = NEES_DOF
) -> dict[str, Any]:
    """One part's consistency: mean and median NEES with the bounds of the run's mean, the share of instants
    and of windows within their bounds, and the share of errors within ±3σ per axis."""
    ok = np.isfinite(nees)
    n = int(ok.sum())
    sd = np.sqrt(np.clip(np.einsum("nii->ni", cov), 0.0, None))
    inside = np.abs(error) <= 3.0 * sd
    out: dict[str, Any] = {
        "n": n,
        "gauge_excluded": int(error.shape[0] - n),
        "within_3sigma": [float(v) for v in np.mean(inside[ok], axis=0)] if n else None,
        "mean_sigma": [float(v) for v in np.mean(sd[ok], axis=0)] if n else None,
    }
    if not n:
        return {**out, "mean": None, "median": None, "bounds": None, "share_instants_within": None}
    lo1, hi1 = metrics.nees_bounds(dof, 1)
    _, means, counts = nees_windows(nees, t_s)
    bounds = np.array([metrics.nees_bounds(dof, int(c)) for c in np.unique(counts)])
    lo_w, hi_w = (bounds[np.searchsorted(np.unique(counts), counts), i] for i in (0, 1))
    mean, naive = float(np.mean(nees[ok])), metrics.nees_bounds(dof, n)
    any_correlation = metrics.nees_bound_any_correlation(dof)
    return {
        **out,
        "mean": mean,
        "median": metrics.median(nees[ok]),
        "dof": dof,
        "bounds": [float(v) for v in naive],
        "share_instants_within": float(np.mean((nees[ok] >= lo1) & (nees[ok] <= hi1))),
        "share_windows_within": float(np.mean((means >= lo_w) & (means <= hi_w))),
        "bound_any_correlation": any_correlation,
        "verdict": metrics.nees_verdict(mean, naive, any_correlation),
        # a negative mean: a covariance not positive definite somewhere (riekf at noise.gyro 1e6): no factor covers it
        "sigma_factor": float(np.sqrt(mean / dof)) if mean >= 0.0 else None,
    }
