"""The estimate against the truth, paired and aligned: what every trajectory section of the report and its
figures share, computed once (association, alignment, APE vectors, the clock offset).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from slamobs.pipeline.evaluation import slam_metrics
from slamobs.pipeline.blocks import row_blocks
from slamobs.pipeline.evaluation.align import KINDS, NAMES, Alignment, canonical, gravity_tilt_deg
from slamobs.pipeline.evaluation.metrics import row_norms
from slamobs.pipeline.evaluation.sync import TimeOffset
from slamobs.pipeline.evaluation.tables import (
    POSE_COLUMNS,
    Table,
    column,
    column_names,
    columns,
    n_rows,
    require_columns,
    time_order,
)
from slamobs.pipeline.evaluation.trajectory_error import (
    AlignOptions,
    ErrorResult,
    Paired,
    SyncOptions,
    ape,
    checked_time_offset,
    synchronize,
)
from slamobs.pipeline.evaluation.sync import (
    ReferenceMotion,
    halves_spread,
    interpolate_poses,
    rate_bias,
    step_angles,
    time_offset_of_steps,
    velocity_steps,
)
from slamobs.pipeline.errors import TruthUnusable
from slamobs.pipeline.lie import quat_to_rot, quats_to_rots, rots_to_quats
from slamobs.pipeline.streams import PoseStream

CONVERGENCE_THRESHOLD_M = 0.1
#: A covariance block with a standard deviation below this (m or rad) is the gauge (riekf's start, batch's anchor
#: keyframe): held fixed by definition, it has no NEES.
GAUGE_SIGMA = 1e-5
ALIGN_TYPES = KINDS


@dataclass(frozen=True)
class ReportOptions:
    """How the report compares the run with the truth.

    ``t_offset_s`` is added to the estimate stamps before association; ``"auto"`` applies the estimated clock
    offset (it is always estimated and reported, applied only when asked). ``gravity_aligned`` marks runs whose
    roll and pitch are observed (IMU directions): the report then adds the 4-DoF (translation + yaw) alignment.
    """

    t_max_diff_s: float = 0.01
    align: str = "se3"
    t_offset_s: float | str = 0.0
    convergence_threshold_m: float = CONVERGENCE_THRESHOLD_M
    gravity_aligned: bool = False
    rpe_delta_m: float = 1.0
    drift_lengths_m: tuple[float, ...] | None = None
    bias_window_fraction: float = 0.2
    max_time_offset_s: float = 1.0
    #: X (quaternion x, y, z, w) with R_truth = R_est X: the truth's body frame in the estimate's
    #: (``frames.truth_rotation``); the truth's rotations are turned by Xᵀ before anything is compared
    truth_rotation_xyzw: tuple[float, float, float, float] | None = None
    #: the truth's own frame in the estimate's body (translation x, y, z, quaternion x, y, z, w: ``x_body = R x + t``;
    #: :func:`truth_in_body` of run.json ``input.truth_body``): the truth is carried to the body first
    #: (:func:`turned_truth`)
    truth_in_body: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.align not in NAMES:
            raise ValueError(f"align must be one of {NAMES}, got {self.align!r}")
        object.__setattr__(self, "align", canonical(self.align))  # rpg's "posyaw" is "yaw"
        if not (self.t_offset_s == "auto" or isinstance(self.t_offset_s, (int, float))):
            raise ValueError(f"t_offset_s must be seconds or 'auto', got {self.t_offset_s!r}")
        if self.t_max_diff_s < 0 or self.convergence_threshold_m <= 0 or self.rpe_delta_m <= 0:
            raise ValueError("t_max_diff_s must be >= 0, convergence_threshold_m and rpe_delta_m > 0")
        if not 0 < self.bias_window_fraction <= 1:
            raise ValueError(f"bias_window_fraction must be in (0, 1], got {self.bias_window_fraction}")


#: The least truth a report judges a run by: this many associated pose pairs, spanning at least this fraction of the
#: estimate's time span. Less (3 poses over 40 ms of a 30 s run) and the APE is a number about a moment, fitted
#: on a few points, not about the run: the report says so instead of printing it.
MIN_TRUTH_PAIRS = 10
MIN_TRUTH_SPAN = 0.1


def check_truth_coverage(paired: Paired, est: PoseStream, truth: str = "truth") -> None:
    """:class:`~slamobs.pipeline.errors.TruthUnusable` (a ValueError) naming how little of the run the truth covers
    when it is less than :data:`MIN_TRUTH_PAIRS` pairs or spans less than :data:`MIN_TRUTH_SPAN` of the estimate's
    time span (poses paired by index: the count only)."""
    n = len(paired)
    run_s = float(est.t_ns[-1] - est.t_ns[0]) / 1e9
    span_s = None if paired.t_est_ns is None else float(np.ptp(paired.t_est_ns)) / 1e9
    if n >= MIN_TRUTH_PAIRS and (span_s is None or span_s >= MIN_TRUTH_SPAN * run_s):
        return
    over = "" if span_s is None else f" over {span_s:.3f} s of the estimate's {run_s:.3f} s"
    raise TruthUnusable(
        truth,
        f"the truth covers too little of the run to judge it: {n} pose pairs{over} (a report needs at least "
        f"{MIN_TRUTH_PAIRS} pairs spanning at least {MIN_TRUTH_SPAN:.0%} of the run); no APE",
    )


def estimate_stream(poses: Table) -> PoseStream:
    """The poses table as a PoseStream in time order."""
    require_columns(poses, POSE_COLUMNS, "poses")
    if n_rows(poses) == 0:
        raise ValueError("poses table is empty: nothing to evaluate")
    rows = time_order(column(poses, "t_ns", np.int64))
    t = column(poses, "t_ns", np.int64)[rows]
    return PoseStream(
        "estimate",
        "",
        "",
        t,
        t,
        columns(poses, ["x", "y", "z"], np.float64)[rows],
        columns(poses, ["qx", "qy", "qz", "qw"], np.float64)[rows],
    )


#: a run whose estimate and truth both stay this close to level (degrees of tilt) is planar: the report adds the
#: 4-DoF (translation + yaw) alignment, the right measure for a robot on a floor; an alignment that tilts the z axis
#: of such a run (or of one with IMU directions) by more than this is said so
PLANAR_TILT_DEG = 5.0


def level(rotations, n: int) -> bool:
    """Whether every one of ``n`` rotations keeps the body z axis within ``PLANAR_TILT_DEG`` of the frame's z
    axis (a planar robot's poses: roll and pitch fixed by the motion, yaw all that is free)."""
    cos_max = np.cos(np.radians(PLANAR_TILT_DEG))
    return all(bool(np.all(rotations[rows][:, 2, 2] >= cos_max)) for rows in row_blocks(n))


@dataclass(frozen=True)
class TrajectoryEvaluation:
    """Everything the report and its plots share: pairs, alignment, APE vectors, the aligned estimate."""

    estimate: PoseStream
    truth: PoseStream
    paired: Paired
    alignment: Alignment
    translation: ErrorResult  # APE trans_part (the evo result written to the zip)
    rotation: ErrorResult  # APE angle_deg
    offset: TimeOffset | Pending | None  # the estimated clock offset, perhaps still being computed
    applied_offset_s: float
    sync: SyncOptions
    #: the pose covariance at the paired estimate rows and its size at every row (``paired_covariance``), None
    #: without one
    covariance: PairedCovariance | None = None
    #: the estimate's roll and pitch are observed (IMU directions, gravity frame: ``ReportOptions.gravity_aligned``)
    gravity_aligned: bool = False
    #: what the clock-offset search correlated the truth with: the estimate, or the log's velocity samples (a run)
    offset_against: str = "estimate"

    @cached_property
    def planar(self) -> bool:
        """The estimate and the truth both stay level at every pair (:func:`level`): a robot on a floor."""
        p = self.paired
        return len(p) > 0 and level(p.ref_rot, len(p)) and level(p.est_rot, len(p))

    @property
    def gravity_tilt_deg(self) -> float | None:
        """How far the report's alignment tilts the estimate's z axis off the truth's when both have one (a planar
        run, or IMU directions) and that is more than ``PLANAR_TILT_DEG``: an alignment no gravity-respecting fit
        could give, which flatters the APE (:func:`~.sections.tilt_note`); else None."""
        if self.alignment.kind == "yaw" or not (self.gravity_aligned or self.planar):
            return None
        tilt = gravity_tilt_deg(self.alignment.rot)
        return tilt if tilt > PLANAR_TILT_DEG else None

    @cached_property
    def time_offset(self) -> TimeOffset | None:
        """The estimated clock offset (waits for it when it is computed beside the rest). Searched beside the
        rest, its APE without the offset is this evaluation's own (same pairs rule and alignment, no offset
        applied): it is filled in here rather than computed twice."""
        if not isinstance(self.offset, Pending):
            return self.offset
        off = self.offset.result()
        if off is not None and off.checked and off.rmse_without_m is None:
            off = replace(off, rmse_without_m=float(self.translation.stats["rmse"]))
        return off

    @property
    def est_positions_aligned(self) -> np.ndarray:
        """All estimate positions (not only the associated ones) in the truth frame."""
        return self.alignment.positions(self.estimate.position)

    @property
    def pair_t_est_ns(self) -> np.ndarray:
        return self.paired.t_est_ns

    @cached_property
    def gauge(self) -> tuple[int, np.ndarray, np.ndarray] | None:
        """:func:`gauge_transform`'s ``(row, R, t)``, once for the uncertainty section and the map σ check (None
        without a covariance)."""
        return None if self.covariance is None else gauge_transform(self)

    @cached_property
    def uncertainty(self) -> PairedUncertainty | None:
        """The paired errors beside the estimate's covariance, both in the truth frame (None without one)."""
        return None if self.covariance is None else paired_uncertainty(self)

    @cached_property
    def truth_extent_m(self) -> float:
        """The paired truth positions' :func:`slam_metrics.rms_extent`: the truth-scale note and the convergence
        section share it."""
        return slam_metrics.rms_extent(self.paired.ref_pos)

    @cached_property
    def error_level(self) -> tuple[np.ndarray, np.ndarray]:
        """The running median of the position error (:func:`slam_metrics.error_level`): the convergence figure
        and the errors plot share it."""
        return slam_metrics.error_level(self.pair_t_est_ns, self.translation.errors)


def evaluate_trajectory(
    poses: Table,
    truth: PoseStream,
    options: ReportOptions,
    *,
    estimate_offset: bool = True,
    checked: bool = False,
    judged: bool = False,
    on_pairs: Callable[[Paired, PoseStream], None] | None = None,
    found_offset: Callable[[], TimeOffset | None] | None = None,
) -> TrajectoryEvaluation:
    """Estimate the clock offset, associate, align and compute the APE vectors. ``checked``: ``truth`` is what
    :func:`valid_truth` and then :func:`truth_spikes` returned (not looked through again). ``judged``: the run is
    judged by this truth (the report), which must cover enough of it (:func:`check_truth_coverage`, before anything
    else is computed).
    ``on_pairs(paired, truth)`` is called as soon as the trajectories are paired (the truth in time order), before
    the alignment and the APE. ``found_offset()`` gives the clock offset searched another way (a run's:
    :func:`log_time_offset`), checked against the estimate instead of searching it."""
    if not checked:
        truth = truth_spikes(valid_truth(truth)[0])[0]
    if len(truth) == 0:
        raise ValueError("ground-truth stream is empty: nothing to compare the estimate with")
    est = estimate_stream(poses)
    truth_sorted = sorted_stream(turned_truth(truth, options.truth_rotation_xyzw, options.truth_in_body))
    offset = None
    search = (truth_sorted, est, SyncOptions(options.t_max_diff_s, 0.0, "nearest"), AlignOptions(options.align))
    beside = len(est) + len(truth_sorted) <= OFFSET_BESIDE_SAMPLES
    max_s = options.max_time_offset_s
    if options.t_offset_s == "auto" or (estimate_offset and not beside):  # first: needed, or too big to overlap
        offset = checked_time_offset(*search, max_offset_s=max_s, found=found_offset)
    elif estimate_offset:  # a diagnostic only: searched (or checked) on a thread (array code, mostly without the GIL)
        offset = Pending(checked_time_offset, *search, max_offset_s=max_s, without=False, found=found_offset)
    if options.t_offset_s == "auto":
        applied = offset.offset_s if offset is not None else 0.0
    else:
        applied = float(options.t_offset_s)
    sync = SyncOptions(options.t_max_diff_s, applied, "nearest")
    paired = synchronize(truth_sorted, est, sync, ref_label="truth")
    if judged:
        check_truth_coverage(paired, est, truth_sorted.topic or "truth")
    if on_pairs is not None:
        on_pairs(paired, truth_sorted)
    al_opts = AlignOptions(options.align)
    trans = ape(truth_sorted, est, "trans_part", sync, al_opts, paired=paired, ref_name="truth", est_name="estimate")
    rot = ape(
        truth_sorted, est, "angle_deg", sync, al_opts, paired=paired, ref_name="truth", est_name="estimate", like=trans
    )
    return TrajectoryEvaluation(
        est,
        truth_sorted,
        paired,
        trans.alignment,
        trans,
        rot,
        offset,
        applied,
        sync,
        paired_covariance(poses, est, paired),
        options.gravity_aligned,
        "estimate" if found_offset is None else "velocity samples",
    )


def _covariance_entries() -> tuple[list[tuple[int, int]], list[str]]:
    """The upper triangles of the 6×6 pose covariance's two diagonal blocks (attitude, then position; the
    cross terms are not needed): index pairs and the poses table's column names."""
    from slamobs.pipeline.writers import POSE_AXES

    pairs = [(i, j) for lo in (0, 3) for i in range(lo, lo + 3) for j in range(i, lo + 3)]
    return pairs, [f"cov_{POSE_AXES[i]}_{POSE_AXES[j]}" for i, j in pairs]


def report_pose_column(name: str) -> bool:
    """Whether the report reads column ``name`` of a poses table: not the standard deviations nor the
    covariance's cross terms (on batch's hour, 15 columns of 720,000 rows: 86 MB at the report's peak)."""
    return not name.startswith("sigma_") and (not name.startswith("cov_") or name in _covariance_entries()[1])


def pose_covariance(poses: Table) -> list[np.ndarray] | None:
    """The poses table's covariance columns of the attitude and position blocks (``cov_<a>_<b>``, written by
    the reference estimators), one array each in time order (views where the table is in time order), in the
    order of :func:`_covariance_entries` (:func:`expand_covariance` makes the matrices of the rows asked for; the
    9 cross terms are left in the table: on batch's hour they would add 52 MB to the report's peak); None when it
    has none (the observers' are null)."""
    _, names = _covariance_entries()
    if not set(names) <= set(column_names(poses)):
        return None
    order = time_order(column(poses, "t_ns", np.int64))
    values = [column(poses, name, np.float64)[order] for name in names]
    return values if any(np.isfinite(v).any() for v in values) else None


@dataclass(frozen=True)
class PairedCovariance:
    """What the uncertainty section needs of an estimate's pose covariance: the entries of :func:`pose_covariance`
    at the paired estimate rows, and the sum of the diagonal at every estimate row (where the gauge is). Not every
    row's entries: on batch's hour those (69 MB) and their copies were the report's peak."""

    entries: np.ndarray  # (n_pairs, 12)
    size: np.ndarray  # (N,)


def paired_covariance(poses: Table, est: PoseStream, paired: Paired) -> PairedCovariance | None:
    """The :class:`PairedCovariance` of ``poses`` (``est`` its time-ordered stream), None without a covariance.
    Taken a column at a time: an (N, 12) array of every row's entries and its diagonal's (N, 6) copy were 104 MB
    of batch's hour at the report's peak."""
    cov = pose_covariance(poses)
    if cov is None:
        return None
    idx = paired.idx_est if paired.idx_est is not None else np.searchsorted(est.t_ns, paired.t_est_ns)
    entries = np.empty((np.shape(idx)[0], len(cov)))
    size = None
    for k, ((i, j), values) in enumerate(zip(_covariance_entries()[0], cov, strict=True)):
        entries[:, k] = values[idx]
        if i == j:  # added left to right, as a row's sum over the six diagonal entries is
            size = values.copy() if size is None else np.add(size, values, out=size)
    return PairedCovariance(entries, size)


def expand_covariance(entries: np.ndarray, block: int) -> np.ndarray:
    """(N, 3, 3) symmetric matrices of the diagonal block from row and column ``block`` (0: attitude, 3:
    position) of (N, 12) entries of :func:`pose_covariance`."""
    pairs = np.array(_covariance_entries()[0])
    keep = np.flatnonzero((pairs >= block).all(axis=1) & (pairs < block + 3).all(axis=1))
    i, j = (pairs[keep] - block).T
    cov = np.empty((entries.shape[0], 3, 3))
    cov[:, i, j] = entries[:, keep]
    cov[:, j, i] = entries[:, keep]
    return cov


def nees_values(error: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``eᵀ Σ⁻¹ e`` per row (N, d) / (N, d, d); NaN where Σ is the gauge (a standard deviation below
    ``GAUGE_SIGMA``), not finite or singular."""
    ok = np.isfinite(cov).all(axis=(1, 2)) & np.isfinite(error).all(axis=1)
    ok &= np.where(ok[:, None], np.einsum("nii->ni", cov), 0.0).min(axis=1) > GAUGE_SIGMA**2
    out = np.full(error.shape[0], np.nan)
    if ok.any():
        try:  # every row: the matrices as they are, not a copy of them all (batch's hour: 49 MB)
            w = np.linalg.solve(cov if ok.all() else cov[ok], error[ok][:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:  # a singular block beyond the gauge: the positive definite ones only
            ok[ok] = np.linalg.eigvalsh(cov[ok])[:, 0] > 0.0
            w = np.linalg.solve(cov[ok], error[ok][:, :, None])[:, :, 0]
        out[ok] = np.einsum("ni,ni->n", error[ok], w)
    return out


@dataclass(frozen=True)
class PairedUncertainty:
    """Per associated pair: the estimate's error ``(δθ, δp)`` (``R_est = Exp(δθ) R_truth``, ``p_est = p_truth +
    δp``, in the truth frame, the estimate moved rigidly so that its gauge pose lies on the truth) and its
    covariance turned into that frame."""

    t_ns: np.ndarray  # (N,) estimate stamps of the pairs
    error: np.ndarray  # (N, 6) rad, m
    cov_attitude: np.ndarray  # (N, 3, 3) of δθ (the diagonal blocks only: all the report uses)
    cov_position: np.ndarray  # (N, 3, 3) of δp
    gauge_t_ns: int  # the estimate row whose pose was put on the truth
    nees_position: np.ndarray  # (N,) NaN at the gauge
    nees_attitude: np.ndarray
    #: the axes (0-2: x, y, z of δp / δθ) each NEES is over: all three but those whose error is zero on every pair
    #: (a planar run's z, roll and pitch: truth and estimate both hold them at zero, so their σ measures nothing)
    position_axes: tuple[int, ...] = (0, 1, 2)
    attitude_axes: tuple[int, ...] = (0, 1, 2)


def axes_with_error(error: np.ndarray) -> tuple[int, ...]:
    """The axes of an (N, 3) error that are not zero on every pair (all three when every axis is)."""
    moving = tuple(int(i) for i in np.flatnonzero(np.max(np.abs(error), axis=0, initial=0.0) > 1e-12))
    return moving or (0, 1, 2)


def _axes_of(cov: np.ndarray, axes: tuple[int, ...]) -> np.ndarray:
    """The (N, k, k) covariances of ``axes`` of (N, 3, 3) ``cov``: ``cov`` itself for all three (not two copies)."""
    return cov if axes == (0, 1, 2) else cov[:, axes][:, :, axes]


def gauge_transform(ev: TrajectoryEvaluation) -> tuple[int, np.ndarray, np.ndarray]:
    """The estimator's gauge (the estimate row with the smallest covariance inside the truth's span: riekf's start,
    batch's anchor keyframe) and the rigid transform ``x ↦ R x + t`` that puts its pose on the truth interpolated at
    its stamp: ``(row, R, t)``, the frame the estimator's covariance is defined in. Needs ``ev.covariance``. Held once
    per evaluation by ``TrajectoryEvaluation.gauge``: the uncertainty section and the report's map σ check
    (``sections.confirm_in_gauge``) both read it."""
    from slamobs.pipeline.evaluation.sync import interpolate_poses
    from slamobs.pipeline.lie import quats_to_rots

    est, truth = ev.estimate, ev.truth
    t_on_truth = np.asarray(est.t_ns, dtype=np.int64) + int(round(ev.applied_offset_s * 1e9))
    inside = (t_on_truth >= np.min(truth.t_ns)) & (t_on_truth <= np.max(truth.t_ns))
    g = int(np.nanargmin(np.where(inside, ev.covariance.size, np.inf)))
    ref_pos, ref_quat = interpolate_poses(truth.t_ns, truth.position, truth.quat_xyzw, t_on_truth[g : g + 1])
    est_rot = quats_to_rots(np.asarray(est.quat_xyzw[g : g + 1], dtype=np.float64))[0]
    rot = quats_to_rots(ref_quat)[0] @ est_rot.T
    return g, rot, ref_pos[0] - rot @ np.asarray(est.position[g], dtype=np.float64)


def paired_uncertainty(ev: TrajectoryEvaluation) -> PairedUncertainty:
    """The errors and covariances of the pairs. An estimator's covariance is relative to its gauge, the pose it
    holds fixed (riekf's start, batch's anchor keyframe: the estimate row with the smallest covariance inside
    the truth's span), so the estimate is moved by the rigid transform that puts that pose on the truth
    interpolated at its stamp (as evo's origin alignment does with the first pose): the report's least-squares
    alignment would absorb part of the error the covariance describes. The transform turns both error parts and
    the covariance by its rotation."""
    from slamobs.pipeline.blocks import row_blocks
    from slamobs.pipeline.lie import rotate_covariance, rots_to_rotvecs

    p, est = ev.paired, ev.estimate
    g, rot, trans = ev.gauge
    error = np.empty((len(p), 6))
    error[:, 3:] = p.est_pos @ rot.T + trans - p.ref_pos
    for rows in row_blocks(len(p)):
        rel = np.matmul(np.matmul(rot, p.est_rot[rows]), np.swapaxes(p.ref_rot[rows], 1, 2))
        error[rows, :3] = rots_to_rotvecs(rel)
    idx = p.idx_est if p.idx_est is not None else np.searchsorted(est.t_ns, p.t_est_ns)
    t_ns = np.asarray(est.t_ns[idx] if p.t_est_ns is None else p.t_est_ns, dtype=np.int64)
    # turned a block of rows at a time into the two kept (N, 3, 3) arrays: the whole arrays' expanded and half-turned
    # temporaries were ~150 MB of batch's hour at the report's peak
    entries = ev.covariance.entries
    att, pos = np.empty((entries.shape[0], 3, 3)), np.empty((entries.shape[0], 3, 3))
    for rows in row_blocks(entries.shape[0]):
        for block, out in ((0, att), (3, pos)):
            out[rows] = rotate_covariance(expand_covariance(entries[rows], block), rot)
    pa, aa = axes_with_error(error[:, 3:]), axes_with_error(error[:, :3])
    nees_position = nees_values(error[:, 3:][:, pa], _axes_of(pos, pa))
    nees_attitude = nees_values(error[:, :3][:, aa], _axes_of(att, aa))
    return PairedUncertainty(t_ns, error, att, pos, int(est.t_ns[g]), nees_position, nees_attitude, pa, aa)


#: The clock-offset search runs beside the association and the APE for up to this many estimate and truth
#: samples together. It holds ~200 bytes per sample (signals on its grid, their transforms); on a longer log
#: (four hours: 4.3 M samples, +0.6 GB) it would add that to the association's peak, so it runs first there.
OFFSET_BESIDE_SAMPLES = 2_000_000


class Pending:
    """``func(*args, **kwargs)`` computed on a thread of its own; :meth:`result` waits for it (and raises what
    it raised), or computes it in the caller's thread when the thread has not begun it yet (a loaded machine,
    where the thread got no core meanwhile: then no later than without a thread). The thread is a daemon: a run
    stopped meanwhile does not wait for it to end. The report computes the clock-offset search and its longest
    section (the segment errors) this way, beside the rest."""

    def __init__(self, func, *args, helper: bool = False, **kwargs) -> None:
        import threading

        from slamobs.pipeline.native import BLAS_START_MB, check_room

        # matrix products on two threads at once take a second OpenBLAS buffer, whose failure ends the process
        check_room("compute beside the report (a second OpenBLAS buffer)", BLAS_START_MB)
        self._value = self._error = None
        self._work = (func, args, kwargs)
        self._helper = helper  # the thread at a helper's priority (cores.lower_this_thread), beside an estimator
        self._claim = threading.Lock()  # held by whichever thread computes it
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="slamobs-report", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        if self._helper:
            from slamobs.pipeline.cores import lower_this_thread

            lower_this_thread()
        if self._claim.acquire(blocking=False):  # else the caller computes it itself
            self._compute()

    def _compute(self) -> None:
        (func, args, kwargs), self._work = self._work, None
        try:
            self._value = func(*args, **kwargs)
        except BaseException as err:  # noqa: BLE001 - raised by result()
            self._error = err
        finally:
            self._done.set()

    def result(self):
        from slamobs.pipeline import interrupts

        if self._claim.acquire(blocking=False):  # not begun: computed here, the thread then finds it taken
            self._compute()
        # a Ctrl-C/SIGTERM is not raised inside threading's wait (:mod:`.interrupts`): looked for between waits
        while not self._done.wait(interrupts.RETRY_S):
            interrupts.check()
        if self._error is not None:
            raise self._error
        return self._value


def valid_truth(truth: PoseStream) -> tuple[PoseStream, int]:
    """``truth`` without poses that are no rotation (a zero or non-finite quaternion, a non-finite position),
    and how many were dropped. A truth finite throughout (the usual) is checked for finite values as a whole,
    without the per-row reductions along the short axis and the masked copy: the same poses kept."""
    q = np.asarray(truth.quat_xyzw, dtype=np.float64)
    if np.isfinite(q).all() and np.isfinite(np.asarray(truth.position)).all():
        ok = row_norms(q) > 1e-6
    else:
        ok = np.isfinite(q).all(axis=1) & np.isfinite(np.asarray(truth.position)).all(axis=1)
        with np.errstate(invalid="ignore"):
            ok &= row_norms(np.where(ok[:, None], q, 0.0)) > 1e-6
    if ok.all():
        return truth, 0
    return PoseStream(
        truth.topic,
        truth.frame_id,
        truth.child_frame_id,
        np.asarray(truth.t_ns)[ok],
        np.asarray(truth.rec_ns)[ok],
        np.asarray(truth.position)[ok],
        q[ok],
    ), int((~ok).sum())


#: The chance, over a whole truth without a spike, that :func:`truth_spikes` calls one of its poses a spike: each
#: pose's deviation is tested at ``TRUTH_SPIKE_FALSE_ALARM / n`` (a Bonferroni count over the truth's poses).
TRUTH_SPIKE_FALSE_ALARM = 0.01
#: A truth with more than this share of its poses spikes is not one with a few glitches (a marker swap, a frame the
#: mocap lost) but a bad truth: the report says so and compares with it as it is, dropping none. A round rule: 1 in
#: 20 poses off is no longer a glitch to leave out but the truth's own quality.
TRUTH_SPIKES_MAX_FRACTION = 0.05
#: A spike is off its neighbours by more than this many times the deviation the truth's poses reach at
#: ``TRUTH_TAIL_PERCENTILE`` (one in ten): an order of magnitude. A motion capture's own jitter has tails far heavier
#: than a normal law's (MR.CLAM's Vicon: 0.3 mm at the median, 0.8 at the 90th percentile, 8 mm at most; TUM's
#: fr2_desk 3.4 mm, 1.4 deg): those stay, a marker swap's metres go.
TRUTH_SPIKE_TAIL_X = 10.0
TRUTH_TAIL_PERCENTILE = 90.0
#: A spike's steps from both neighbours are faster than this many times the truth's own motion at
#: ``TRUTH_MOTION_PERCENTILE`` (its steps' speeds and turn rates). The percentile is of the steps a truth within
#: ``TRUTH_SPIKES_MAX_FRACTION`` keeps clean (each spike makes two steps: at most 10 % of them); 3x the speed the
#: body exceeds a fifth of the time is a round bar (MR.CLAM's Vicon: steps 0.31 m/s at most, 0.12 at the 80th
#: percentile; its jitter of up to 8 mm off the neighbours at 60 Hz is no faster than the robots).
TRUTH_SPIKE_RATE_X = 3.0
TRUTH_MOTION_PERCENTILE = 80.0
#: Rounds of :func:`truth_spikes` (a spike beside another is found once the other is out); a round that finds
#: none ends it.
TRUTH_SPIKE_ROUNDS = 3


@dataclass(frozen=True)
class TruthSpikes:
    """The truth's spikes (:func:`truth_spikes`): poses off both neighbours, which agree with each other.
    ``count`` of ``n_poses``; the largest deviation from the neighbours' interpolation, in position and rotation;
    ``dropped``: left out of the comparison (none where they are more than ``TRUTH_SPIKES_MAX_FRACTION``)."""

    count: int
    n_poses: int
    largest_jump_m: float
    largest_turn_deg: float
    dropped: bool

    @property
    def fraction(self) -> float:
        return self.count / self.n_poses

    def record(self) -> dict:
        """report.json's ``truth_spikes``."""
        return {
            "count": self.count,
            "n_poses": self.n_poses,
            "fraction": self.fraction,
            "largest_jump_m": self.largest_jump_m,
            "largest_turn_deg": self.largest_turn_deg,
            "dropped": self.dropped,
        }

    def note(self) -> str:
        """The report's note of them."""
        share = f"{self.count} of {self.n_poses} ground-truth poses ({100 * self.fraction:.2g} %)"
        what = (
            f"are spikes, each off both its neighbours where those agree with each other (the largest "
            f"{self.largest_jump_m:.3g} m, {self.largest_turn_deg:.3g} deg off them: a marker swap or a frame the "
            "tracking lost)"
        )
        if self.dropped:
            return (
                f"truth: {share} {what}: dropped from the comparison, the APE, the verdicts and the NEES are "
                "computed without them (report.json truth_spikes)"
            )
        return (
            f"warning: truth: {share} {what}: more than {100 * TRUTH_SPIKES_MAX_FRACTION:.0f} % of it, the truth "
            "itself is bad, not dropped: the errors, the verdicts and the NEES are the truth's as much as the "
            "estimate's (report.json truth_spikes)"
        )


def _deviations(t: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, ...]:
    """For each inner pose (1..n-2): its position's and rotation's deviation from the interpolation of its two
    neighbours at its stamp (linear, slerp), and the neighbours' distance and angle to each other."""
    n = t.shape[0]
    at_pos, at_quat = np.empty((n, 3)), np.empty((n, 4))
    bridge_m, bridge_rad = np.empty(n), np.empty(n)
    for first in (0, 1):  # the odd poses between the even ones, and the even between the odd
        rows = np.arange(1 - first, n, 2)
        inner = rows[(rows > 0) & (rows < n - 1)]
        if inner.size == 0:
            continue
        xyz, q = interpolate_poses(t[first::2], pos[first::2], quat[first::2], t[inner])
        at_pos[inner], at_quat[inner] = xyz, q
        side = pos[first::2]
        bridge_m[inner] = np.linalg.norm(side[1:] - side[:-1], axis=1)[: inner.size]
        bridge_rad[inner] = step_angles(quat[first::2])[: inner.size]
    inner = slice(1, n - 1)
    off_m = np.linalg.norm(pos[inner] - at_pos[inner], axis=1)
    pairs = np.empty((2 * (n - 2), 4))
    pairs[0::2], pairs[1::2] = quat[inner], at_quat[inner]
    off_rad = step_angles(pairs)[0::2]
    return off_m, off_rad, bridge_m[inner], bridge_rad[inner]


def _outlying(off: np.ndarray, bridge: np.ndarray, rate: np.ndarray, n: int) -> np.ndarray:
    """The spikes among deviations (a 3-vector's length, one per inner pose): poses off their neighbours by more
    than those are apart (not on a sharp turn between them), reached by steps from both neighbours faster than
    ``TRUTH_SPIKE_RATE_X`` times the truth's own motion (``rate``: each step's length over its time; the motion at
    its ``TRUTH_MOTION_PERCENTILE``), and outliers of the truth's own deviations: beyond the χ²₃ quantile at
    ``TRUTH_SPIKE_FALSE_ALARM / n`` of their median scale and beyond ``TRUTH_SPIKE_TAIL_X`` times their
    ``TRUTH_TAIL_PERCENTILE`` (a motion capture's jitter has heavy tails). That scale is the poses' that are no
    candidate (off and fast) and beside none (a spike moves its neighbours' interpolation by half its size): the
    spikes, however many, do not set it."""
    from slamobs.pipeline.noise import chi2_quantile

    fast = TRUTH_SPIKE_RATE_X * float(np.percentile(rate, TRUTH_MOTION_PERCENTILE))
    candidate = (off > bridge) & (np.minimum(rate[:-1], rate[1:]) > fast)
    near = candidate.copy()
    near[1:] |= candidate[:-1]
    near[:-1] |= candidate[1:]
    own = off[~near] if (~near).any() else off
    scale2 = float(np.median(own * own)) / chi2_quantile(0.5, 3)
    bound2 = max(
        scale2 * chi2_quantile(1.0 - TRUTH_SPIKE_FALSE_ALARM / n, 3),
        (TRUTH_SPIKE_TAIL_X * float(np.percentile(own, TRUTH_TAIL_PERCENTILE))) ** 2,
    )
    return candidate & (off * off > bound2)


def truth_spikes(truth: PoseStream) -> tuple[PoseStream, TruthSpikes | None]:
    """``truth`` (in time order) without its spikes, and what they were (None: none). A spike is a pose off both
    its neighbours where they agree with each other: its deviation from their interpolation at its stamp (linear in
    position, slerp in rotation) is an outlier of the truth's own deviations (:func:`_outlying`: the χ²₃ quantile
    at ``TRUTH_SPIKE_FALSE_ALARM`` over the truth's poses, of their robust scale) and larger than the neighbours'
    distance to each other; in position or in rotation. Fast motion moves the neighbours apart with it: a pose
    on the way between them is none. Where the spikes are more than ``TRUTH_SPIKES_MAX_FRACTION`` of the poses the
    truth is returned whole (a bad truth, :meth:`TruthSpikes.note`)."""
    truth = sorted_stream(truth)
    t = np.asarray(truth.t_ns, dtype=np.int64)
    pos = np.asarray(truth.position, dtype=np.float64)
    quat = np.ascontiguousarray(truth.quat_xyzw, dtype=np.float64)
    n = t.shape[0]
    keep = np.ones(n, dtype=bool)
    jump_m = turn_rad = 0.0
    for _ in range(TRUTH_SPIKE_ROUNDS):
        rows = np.flatnonzero(keep)
        if rows.size < 5:
            break
        off_m, off_rad, bridge_m, bridge_rad = _deviations(t[rows], pos[rows], quat[rows])
        dt = np.maximum(np.diff(t[rows]), 1) * 1e-9  # two poses on one stamp: a step in a nanosecond
        speed = np.linalg.norm(np.diff(pos[rows], axis=0), axis=1) / dt
        spike = _outlying(off_m, bridge_m, speed, n) | _outlying(off_rad, bridge_rad, step_angles(quat[rows]) / dt, n)
        if not spike.any():
            break
        jump_m = max(jump_m, float(off_m[spike].max()))
        turn_rad = max(turn_rad, float(off_rad[spike].max()))
        keep[rows[1:-1][spike]] = False
    count = int(n - keep.sum())
    if count == 0:
        return truth, None
    dropped = count <= TRUTH_SPIKES_MAX_FRACTION * n
    spikes = TruthSpikes(count, n, jump_m, float(np.degrees(turn_rad)), dropped)
    if not dropped:
        return truth, spikes
    return pose_rows(truth, keep), spikes


def log_time_offset(
    truth: PoseStream,
    vel_t_ns: np.ndarray,
    omega: np.ndarray,
    velocity: np.ndarray,
    *,
    max_offset_s: float = ReportOptions.max_time_offset_s,
    truth_rotation_xyzw=None,
    truth_in_body=None,
) -> TimeOffset | None:
    """The clock offset of a log against its truth (``truth`` on the run's clock): the truth's angular rate (or
    speed) correlated with the log's own velocity samples (:func:`.sync.velocity_steps`), which the estimate
    shares the clock with. Known before the estimate is (a run searches it beside the observer); an estimate
    that lags the motion (filtering) or is lost does not move it. The truth as the report takes it (valid poses,
    its spikes out, ``frames.truth_rotation``, ``truth_in_body``, time order)."""
    truth = turned_truth(truth_spikes(valid_truth(truth)[0])[0], truth_rotation_xyzw, truth_in_body)
    if len(truth) == 0:
        return None

    reference = ReferenceMotion(truth.t_ns, truth.position, truth.quat_xyzw)  # the truth's side, once for all

    def motion(bias_omega, bias_velocity):
        return velocity_steps(vel_t_ns, np.subtract(omega, bias_omega), np.subtract(velocity, bias_velocity))

    def search(steps, part=slice(0, len(vel_t_ns))):
        # a part's steps are those between its samples: velocity_steps of the part's samples, the same bits
        at = slice(part.start, part.stop - 1)
        return time_offset_of_steps(reference, vel_t_ns[part], (steps[0][at], steps[1][at]), max_offset_s=max_offset_s)

    steps = motion(0.0, 0.0)
    off = search(steps)
    # a constant bias of the samples (a gyro's) distorts |ω|: fit it against the truth at the lag found and
    # search again, keeping the debiased search where it correlates better (docs/benchmarks.md, session 26)
    ref = reference.steps()
    for _ in range(BIAS_ROUNDS):
        if off is None:
            return None
        t = np.asarray(vel_t_ns, dtype=np.int64) + int(round(off.offset_s * 1e9))  # on the truth's clock
        bias_omega, bias_velocity = rate_bias(t, omega, truth.t_ns, ref[0]), rate_bias(t, velocity, truth.t_ns, ref[1])
        if not (bias_omega.any() or bias_velocity.any()):  # none found (MR.CLAM's): the same search again
            break
        debiased = motion(bias_omega, bias_velocity)
        again = search(debiased)
        if again is None or again.peak_correlation <= off.peak_correlation:
            break
        moved, off, steps = abs(again.offset_s - off.offset_s), again, debiased
        if moved < off.grid_step_s:  # settled
            break
    # the halves with the bias the whole log's search took (its steps: each half's are a slice of them)
    return replace(off, uncertainty_s=halves_spread(lambda part: search(steps, part), len(vel_t_ns)))


#: Rounds of :func:`log_time_offset`'s bias fit and search again (each starts from the last lag found: the
#: generated 10 s loop's lag went 0.368, 0.018, 0.008 s).
BIAS_ROUNDS = 3


#: The search's own fields of a :class:`.sync.TimeOffset` (not the check against the estimate): what run.json's
#: ``truth_clock_offset`` records of a run's :func:`log_time_offset`, for ``slamobs report`` to check again.
SEARCH_FIELDS = (
    "offset_s",
    "peak_correlation",
    "signal",
    "grid_step_s",
    "search_window_s",
    "at_window_edge",
    "uncertainty_s",
)


def offset_record(off: TimeOffset | None) -> dict | None:
    """:func:`log_time_offset`'s result as run.json records it (None: the motion told no offset)."""
    return None if off is None else {k: getattr(off, k) for k in SEARCH_FIELDS}


def recorded_offset(record: dict | None) -> TimeOffset | None:
    """The offset :func:`offset_record` recorded (the same bits: JSON keeps a float's shortest repr)."""
    # a run.json written before session 26 has no uncertainty_s: unknown, as the search of an estimate's
    return None if record is None else TimeOffset(**{k: record.get(k) for k in SEARCH_FIELDS})


#: the report options that are tuples (report.json keeps them as lists: read back, they are made tuples again)
TUPLE_OPTIONS = ("drift_lengths_m", "truth_rotation_xyzw", "truth_in_body")
#: the report options report.json records only where set (reports without them stay as they were)
SET_ONLY_OPTIONS = ("truth_rotation_xyzw", "truth_in_body")


def truth_in_body(record: dict | None) -> tuple[float, ...] | None:
    """:attr:`ReportOptions.truth_in_body` of run.json's ``input.truth_body`` (``alignment.truth_frame_in_body``:
    the truth's frame placed on the body by static TF), None without one."""
    return None if not record else (*record["translation"], *record["quat_xyzw"])


def turned_truth(truth: PoseStream, x_xyzw, in_body=None) -> PoseStream:
    """The truth in the estimate's body frame. ``in_body`` (:attr:`ReportOptions.truth_in_body`: the truth's frame F
    at ``t`` turned by ``R_bf`` in the body B) carries each pose to the body, ``T_world_B = T_world_F T_BFᵀ``:
    ``R_B = R_F R_bfᵀ``, ``p_B = p_F − R_B t`` (the estimate and its files stay the body's, and the truth written
    beside them for evo is this one). Then each rotation ``R_truth`` becomes ``R_truth Xᵀ`` (positions unchanged),
    ``X`` the quaternion of ``frames.truth_rotation``. The truth itself without either."""
    if x_xyzw is None and in_body is None:
        return truth
    rots = quats_to_rots(np.ascontiguousarray(truth.quat_xyzw, dtype=np.float64))
    position = np.asarray(truth.position, dtype=np.float64)
    if in_body is not None:
        r_bf = quat_to_rot(np.asarray(in_body[3:], dtype=np.float64))
        rots = np.matmul(rots, r_bf.T)
        position = position - np.matmul(rots, np.asarray(in_body[:3], dtype=np.float64))
    if x_xyzw is not None:
        rots = np.matmul(rots, quat_to_rot(np.asarray(x_xyzw, dtype=np.float64)).T)
    return replace(truth, position=position, quat_xyzw=rots_to_quats(np.ascontiguousarray(rots)))


def sorted_stream(stream: PoseStream) -> PoseStream:
    t = np.asarray(stream.t_ns, dtype=np.int64)
    if t.shape[0] < 2 or np.all(np.diff(t) >= 0):
        return stream
    return pose_rows(stream, np.argsort(t, kind="stable"))


def pose_rows(stream: PoseStream, rows: np.ndarray) -> PoseStream:
    """``stream``'s poses at ``rows`` (indices or a mask): a truth sorted, or without the poses it cannot use."""
    return replace(
        stream,
        t_ns=np.asarray(stream.t_ns, dtype=np.int64)[rows],
        rec_ns=np.asarray(stream.rec_ns)[rows],
        position=np.asarray(stream.position)[rows],
        quat_xyzw=np.asarray(stream.quat_xyzw)[rows],
    )
