"""The run's error report: estimate vs ground truth, as a JSON document, a Markdown page, plots and evo files.

``build_report`` is pure (tables in, dict out); ``write_report`` is the I/O edge. The trajectory numbers come
from :mod:`.trajectory_error`, the one evo-compatible path, and the report states how every number was obtained
(association, alignment, definitions). On request (``exports``) it also writes the estimate and the truth as TUM
files and the APE as an evo result zip, so an evo user can reproduce the headline with ``evo_ape`` and compare
with ``evo_res``.
Beyond evo: APE under several alignments, landmark map error after the trajectory alignment and after a
map-only alignment, bias error and stability, convergence time, clock offset estimate, KITTI-style drift.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Union

import numpy as np

from slamobs.pipeline.version import __version__
from slamobs.pipeline.blocks import row_blocks
from slamobs.pipeline.evaluation import metrics, slam_metrics
from slamobs.pipeline.evaluation.align import DESCRIPTIONS, KINDS, Alignment, fit_alignment
from slamobs.pipeline.evaluation.drift import segment_drift
from slamobs.pipeline.evaluation.sync import NS_PER_S, TimeOffset
from slamobs.pipeline.evaluation.trajectory_error import (
    AlignOptions,
    ErrorResult,
    Paired,
    RpeOptions,
    SyncOptions,
    ape,
    checked_time_offset,
    rpe,
    synchronize,
)
from slamobs.pipeline.lie import quats_to_rots, rot_to_quat, rots_to_quats
from slamobs.pipeline.streams import PoseStream

if TYPE_CHECKING:
    import pandas as pd

#: A run table: a pandas DataFrame, or its columns as NumPy arrays (what a run reads back without pandas,
#: :func:`slamobs.pipeline.writers.read_columns`; importing pandas is ~0.8 s of a short run).
Table = Union["pd.DataFrame", Mapping[str, np.ndarray]]

SCHEMA_VERSION = 1
CONVERGENCE_THRESHOLD_M = 0.1
ALIGN_TYPES = KINDS
POSE_COLUMNS = ("t_ns", "x", "y", "z", "qx", "qy", "qz", "qw")
GYRO_COLUMNS = ("gyro_bias_x", "gyro_bias_y", "gyro_bias_z")
VEL_COLUMNS = ("vel_bias_x", "vel_bias_y", "vel_bias_z")
LANDMARK_COLUMNS = ("id", "x", "y", "z")

#: files ``write_report`` may write into a run directory (all of them belong to the report)
TRUTH_TUM = "truth_tum.txt"
ESTIMATE_TUM = "estimate_tum.txt"
EVO_ZIP = "ape_evo.zip"
PLOTS = ("trajectory_top.png", "errors.png", "biases.png", "landmarks.png")
#: the estimate moved into the truth's frame by the report's alignment (schemas/poses_aligned.json, ...)
ALIGNED_TABLES = ("poses_aligned.parquet", "landmarks_aligned.parquet")
REPORT_FILES = ("report.json", "report.md", *PLOTS, EVO_ZIP, ESTIMATE_TUM, TRUTH_TUM, *ALIGNED_TABLES)

_EVO_ALIGN_FLAGS = {"se3": " -a", "sim3": " -as", "scale": " -s", "origin": " --align_origin", "none": ""}
_ALIGN_LABELS = {"se3": "SE(3)", "sim3": "Sim(3)", "scale": "scale-only", "yaw": "4-DoF (yaw)", "origin": "origin",
                 "none": "no"}


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

    def __post_init__(self) -> None:
        if self.align not in ALIGN_TYPES:
            raise ValueError(f"align must be one of {ALIGN_TYPES}, got {self.align!r}")
        if not (self.t_offset_s == "auto" or isinstance(self.t_offset_s, (int, float))):
            raise ValueError(f"t_offset_s must be seconds or 'auto', got {self.t_offset_s!r}")
        if self.t_max_diff_s < 0 or self.convergence_threshold_m <= 0 or self.rpe_delta_m <= 0:
            raise ValueError("t_max_diff_s must be >= 0, convergence_threshold_m and rpe_delta_m > 0")
        if not 0 < self.bias_window_fraction <= 1:
            raise ValueError(f"bias_window_fraction must be in (0, 1], got {self.bias_window_fraction}")


def _names(table: Table) -> list[str]:
    return list(table.columns) if hasattr(table, "columns") else list(table)


def _col(table: Table, name: str, dtype=None) -> np.ndarray:
    column = table[name]
    return column.to_numpy(dtype) if hasattr(column, "to_numpy") else np.asarray(column, dtype=dtype)


def _cols(table: Table, names: list[str], dtype) -> np.ndarray:
    """Columns ``names`` as one ``(N, k)`` array (as ``DataFrame[names].to_numpy(dtype)``)."""
    if hasattr(table, "columns"):
        return table[list(names)].to_numpy(dtype)
    return np.stack([np.asarray(table[c], dtype=dtype) for c in names], axis=1)


def _nrows(table: Table) -> int:
    return len(table) if hasattr(table, "columns") else (len(next(iter(table.values()))) if len(table) else 0)


def _require(df: Table, columns: tuple[str, ...], name: str) -> None:
    missing = [c for c in columns if c not in _names(df)]
    if missing:
        raise ValueError(f"{name} table lacks column(s) {missing}; has {_names(df)}")


def estimate_stream(poses: Table) -> PoseStream:
    """The poses table as a PoseStream in time order."""
    _require(poses, POSE_COLUMNS, "poses")
    if _nrows(poses) == 0:
        raise ValueError("poses table is empty: nothing to evaluate")
    rows = _time_order(_col(poses, "t_ns", np.int64))
    t = _col(poses, "t_ns", np.int64)[rows]
    return PoseStream("estimate", "", "", t, t, _cols(poses, ["x", "y", "z"], np.float64)[rows],
                      _cols(poses, ["qx", "qy", "qz", "qw"], np.float64)[rows])


def _time_order(t_ns: np.ndarray) -> np.ndarray | slice:
    """Rows in time order (stable): all of them as they are when already sorted (no copy), else an index."""
    if t_ns.shape[0] < 2 or bool(np.all(t_ns[1:] >= t_ns[:-1])):
        return slice(None)
    return np.argsort(t_ns, kind="stable")


@dataclass(frozen=True)
class TrajectoryEvaluation:
    """Everything the report and its plots share: pairs, alignment, APE vectors, the aligned estimate."""

    estimate: PoseStream
    truth: PoseStream
    paired: Paired
    alignment: Alignment
    translation: ErrorResult  # APE trans_part (the evo result written to the zip)
    rotation: ErrorResult  # APE angle_deg
    offset: TimeOffset | _Pending | None  # the estimated clock offset, perhaps still being computed
    applied_offset_s: float
    sync: SyncOptions

    @cached_property
    def time_offset(self) -> TimeOffset | None:
        """The estimated clock offset (waits for it when it is computed beside the rest). Searched beside the
        rest, its APE without the offset is this evaluation's own (same pairs rule and alignment, no offset
        applied): it is filled in here rather than computed twice."""
        if not isinstance(self.offset, _Pending):
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
    def error_level(self) -> tuple[np.ndarray, np.ndarray]:
        """The running median of the position error (:func:`slam_metrics.error_level`): the convergence figure
        and the errors plot share it."""
        return slam_metrics.error_level(self.pair_t_est_ns, self.translation.errors)


def evaluate_trajectory(poses: Table, truth: PoseStream, options: ReportOptions, *,
                        estimate_offset: bool = True) -> TrajectoryEvaluation:
    """Estimate the clock offset, associate, align and compute the APE vectors."""
    truth, _ = valid_truth(truth)
    if len(truth) == 0:
        raise ValueError("ground-truth stream is empty: nothing to compare the estimate with")
    est = estimate_stream(poses)
    truth_sorted = _sorted(truth)
    offset = None
    search = (truth_sorted, est, SyncOptions(options.t_max_diff_s, 0.0, "nearest"), AlignOptions(options.align))
    beside = len(est) + len(truth_sorted) <= OFFSET_BESIDE_SAMPLES
    if options.t_offset_s == "auto" or (estimate_offset and not beside):  # first: needed, or too big to overlap
        offset = checked_time_offset(*search, max_offset_s=options.max_time_offset_s)
    elif estimate_offset:  # a diagnostic only: searched on a thread (array code, mostly without the GIL)
        offset = _Pending(checked_time_offset, *search, max_offset_s=options.max_time_offset_s, without=False)
    if options.t_offset_s == "auto":
        applied = offset.offset_s if offset is not None else 0.0
    else:
        applied = float(options.t_offset_s)
    sync = SyncOptions(options.t_max_diff_s, applied, "nearest")
    paired = synchronize(truth_sorted, est, sync, ref_label="truth")
    al_opts = AlignOptions(options.align)
    trans = ape(truth_sorted, est, "trans_part", sync, al_opts, paired=paired, ref_name="truth",
                est_name="estimate")
    rot = ape(truth_sorted, est, "angle_deg", sync, al_opts, paired=paired, ref_name="truth", est_name="estimate",
              like=trans)
    return TrajectoryEvaluation(est, truth_sorted, paired, trans.alignment, trans, rot, offset, applied, sync)


#: The clock-offset search runs beside the association and the APE for up to this many estimate and truth
#: samples together. It holds ~200 bytes per sample (signals on its grid, their transforms); on a longer log
#: (four hours: 4.3 M samples, +0.6 GB) it would add that to the association's peak, so it runs first there.
OFFSET_BESIDE_SAMPLES = 2_000_000


class _Pending:
    """``func(*args, **kwargs)`` computed on a thread of its own; :meth:`result` waits for it (and raises what
    it raised). The thread is a daemon: a run stopped meanwhile does not wait for it to end."""

    def __init__(self, func, *args, **kwargs) -> None:
        import threading

        from slamobs.pipeline.native import BLAS_START_MB, check_room

        # matrix products on two threads at once take a second OpenBLAS buffer, whose failure ends the process
        check_room("compute beside the report (a second OpenBLAS buffer)", BLAS_START_MB)
        self._value = self._error = None
        self._thread = threading.Thread(target=self._run, args=(func, args, kwargs), name="slamobs-report",
                                        daemon=True)
        self._thread.start()

    def _run(self, func, args, kwargs) -> None:
        try:
            self._value = func(*args, **kwargs)
        except BaseException as err:  # noqa: BLE001 - raised by result()
            self._error = err

    def result(self):
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value


def valid_truth(truth: PoseStream) -> tuple[PoseStream, int]:
    """``truth`` without poses that are no rotation (a zero or non-finite quaternion, a non-finite position),
    and how many were dropped."""
    q = np.asarray(truth.quat_xyzw, dtype=np.float64)
    ok = np.isfinite(q).all(axis=1) & np.isfinite(np.asarray(truth.position)).all(axis=1)
    with np.errstate(invalid="ignore"):
        ok &= np.linalg.norm(np.where(ok[:, None], q, 0.0), axis=1) > 1e-6
    if ok.all():
        return truth, 0
    return PoseStream(truth.topic, truth.frame_id, truth.child_frame_id, np.asarray(truth.t_ns)[ok],
                      np.asarray(truth.rec_ns)[ok], np.asarray(truth.position)[ok], q[ok]), int((~ok).sum())


def _sorted(stream: PoseStream) -> PoseStream:
    t = np.asarray(stream.t_ns, dtype=np.int64)
    if t.shape[0] < 2 or np.all(np.diff(t) >= 0):
        return stream
    order = np.argsort(t, kind="stable")
    return PoseStream(stream.topic, stream.frame_id, stream.child_frame_id, t[order],
                      np.asarray(stream.rec_ns)[order], np.asarray(stream.position)[order],
                      np.asarray(stream.quat_xyzw)[order])


# ---------------------------------------------------------------------------------------------- sections


def _alignment_dict(al: Alignment) -> dict[str, Any]:
    return {
        "type": al.kind,
        "description": DESCRIPTIONS[al.kind],
        "n_points": int(al.n_points),
        "rotation_quat_xyzw": [float(v) for v in rots_to_quats(np.asarray(al.rot, dtype=np.float64)[None])[0]],
        "rotation_matrix": [[float(v) for v in row] for row in al.rot],
        "translation_m": [float(v) for v in al.trans],
        "scale": float(al.scale),
    }


def _ape_by_alignment(ev: TrajectoryEvaluation, options: ReportOptions, notes: list[str]) -> dict[str, Any]:
    kinds = [options.align] + [k for k in ("se3", "yaw", "origin", "none") if k != options.align]
    if not options.gravity_aligned:
        kinds = [k for k in kinds if k != "yaw" or k == options.align]
    p = ev.paired
    fits: dict[str, Alignment] = {}
    for kind in kinds[1:]:
        try:
            fits[kind] = fit_alignment(kind, p.ref_pos, p.est_pos, p.ref_rot, p.est_rot)
        except ValueError as err:
            notes.append(f"APE with {kind} alignment not computed: {err}")
    errors = _aligned_errors(fits, p)
    errors[options.align] = (ev.translation.errors, ev.rotation.errors)
    fits[options.align] = ev.alignment
    return {kind: {"translation_m": metrics.statistics(errors[kind][0]),
                   "rotation_deg": metrics.statistics(errors[kind][1]), "alignment": _alignment_dict(fits[kind])}
            for kind in kinds if kind in fits}


def _aligned_errors(fits: dict[str, Alignment], p: Paired) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """APE (translation, rotation in degrees) after each alignment, in one pass over blocks of pairs: the
    rotation matrices of a block serve every alignment, and no aligned estimate of all pairs is held."""
    n = len(p)
    out = {kind: (np.empty(n), np.empty(n)) for kind in fits}
    for rows in row_blocks(n):
        ref_pos, est_pos, ref_rot, est_rot = p.ref_pos[rows], p.est_pos[rows], p.ref_rot[rows], p.est_rot[rows]
        for kind, al in fits.items():
            pos = al.positions(est_pos)
            out[kind][0][rows] = metrics.ape_errors("trans_part", ref_pos, None, pos, None)
            out[kind][1][rows] = metrics.ape_errors("angle_deg", ref_pos, ref_rot, pos, np.matmul(al.rot, est_rot))
    return out


def _rpe_section(ev: TrajectoryEvaluation, options: ReportOptions, notes: list[str]) -> dict[str, Any] | None:
    opts = RpeOptions(options.rpe_delta_m, "m", 0.1, False, False)
    al = AlignOptions(options.align)
    try:
        tr = rpe(ev.truth, ev.estimate, "trans_part", ev.sync, al, opts, paired=ev.paired, like=ev.translation)
        rr = rpe(ev.truth, ev.estimate, "angle_deg", ev.sync, al, opts, paired=ev.paired, like=ev.translation)
    except ValueError as err:
        notes.append(f"no RPE: {err}")
        return None
    return {
        "delta": float(options.rpe_delta_m),
        "delta_unit": "m",
        "n_pairs": int(tr.errors.shape[0]),
        "translation_m": tr.stats,
        "rotation_deg": rr.stats,
        "method": (f"evo_rpe definitions: consecutive pose pairs of the aligned estimate {options.rpe_delta_m:g} m "
                   "of travelled path apart (a pair closes when its path reaches the delta); error pose "
                   "E = (Q_i⁻¹Q_j)⁻¹(P_i⁻¹P_j); translation ‖t_E‖ in metres, rotation angle of R_E in degrees "
                   f"(evo_rpe ... --delta {options.rpe_delta_m:g} --delta_unit m"
                   f"{_EVO_ALIGN_FLAGS.get(options.align, '')}"
                   " -r trans_part / angle_deg)"),
    }


def _drift_section(ev: TrajectoryEvaluation, options: ReportOptions) -> dict[str, Any] | None:
    p = ev.paired
    if len(p) < 3:
        return None
    t = p.t_est_ns
    dt = float(np.median(np.diff(t))) / NS_PER_S if t is not None and t.shape[0] > 1 else 0.1
    step = max(1, int(round(1.0 / dt))) if dt > 0 else 10
    out = segment_drift(p.ref_pos, p.ref_rot, ev.translation.est_pos_aligned, ev.translation.est_rot_aligned,
                        options.drift_lengths_m, step)
    if out["n_segments"] == 0:
        return None
    out["method"] = (
        "KITTI odometry devkit definition on the associated pairs: from every pair about 1 s apart "
        f"(every {step} pairs), for each segment length L the first pair whose truth path distance exceeds "
        "the start's by more than L; E = (P_i⁻¹P_j)⁻¹(Q_i⁻¹Q_j); translation_pct = mean ‖t_E‖/L × 100, "
        "rotation_deg_per_m = mean angle(R_E)/L; lengths are KITTI's 100–800 m for paths over 1.6 km, else "
        "10–50 % of the truth path; independent of the rigid alignment, sensitive to scale"
    )
    return out


def _time_offset_section(ev: TrajectoryEvaluation, options: ReportOptions) -> dict[str, Any]:
    off = ev.time_offset
    return {
        "estimated_s": None if off is None else off.offset_s,
        "peak_correlation": None if off is None else off.peak_correlation,
        "signal": None if off is None else off.signal,
        "reliable": None if off is None else off.reliable,
        "ape_rmse_with_m": None if off is None else off.rmse_with_m,
        "ape_rmse_without_m": None if off is None else off.rmse_without_m,
        "search_window_s": None if off is None else off.search_window_s,
        "grid_step_s": None if off is None else off.grid_step_s,
        "applied_s": float(ev.applied_offset_s),
        "applied_from": "estimate" if options.t_offset_s == "auto" else "option",
        "method": (
            "Pearson cross-correlation of a motion signal that the unknown frame alignment does not change: the "
            "angular rate magnitude |ω|, or the speed |v| when it varies clearly more (signal), of estimate and "
            "truth, resampled on one grid as mean rates per grid step; best lag within ±search_window_s, refined "
            "off the grid by golden-section search. Sign as evo --t_offset: t_estimate + offset is on the truth "
            "clock. Reliable: peak correlation >= 0.5, not on the window edge, and an offset more than one grid "
            "step from zero must not make the translation APE rmse larger (ape_rmse_with_m, with it applied; "
            "ape_rmse_without_m, without; same association and alignment). A lag of the estimate behind the "
            "motion (an observer's filtering delay) shows as the same offset: a reliable offset is where the estimate "
            "matches the truth best, not proof that the clocks differ. Applied to the association only when asked "
            "(t_offset auto)"
        ),
    }


def _landmark_table(landmarks: Table | None) -> tuple[np.ndarray, np.ndarray]:
    if landmarks is None:
        return np.empty(0, dtype=np.int64), np.empty((0, 3))
    _require(landmarks, LANDMARK_COLUMNS, "landmarks")
    return _col(landmarks, "id", np.int64), _cols(landmarks, ["x", "y", "z"], np.float64)


#: A map whose error after the trajectory's alignment is this many times its error after an alignment of its own (and
#: over MAP_PLACE_MIN_M) is named in the notes: its shape matches the landmark truth, its place does not.
MAP_PLACE_FACTOR = 10.0
MAP_PLACE_MIN_M = 1.0


def _map_place_note(section: dict[str, Any]) -> list[str]:
    """Say when the map's shape fits the landmark truth but its place does not: the landmark truth in another frame
    than the trajectory truth (a UTM truth file beside the log's landmark truth gave landmark errors of 4,700 km and
    no word why), or a map that disagrees with its own trajectory."""
    mine = (section.get("map_aligned") or {}).get("error_m") or {}
    placed = section.get("error_m") or {}
    if mine.get("rmse") is None or placed.get("rmse") is None:
        return []
    if placed["rmse"] <= max(MAP_PLACE_MIN_M, MAP_PLACE_FACTOR * mine["rmse"]):
        return []
    return [f"landmark map: {placed['rmse']:.4g} m from its truth after the trajectory's alignment, "
            f"{mine['rmse']:.4g} m after an alignment of its own: its shape fits the landmark truth, its place "
            "does not (the landmark truth in another frame than the trajectory truth, or a map that disagrees "
            "with its trajectory)"]


def _landmark_section(landmarks: Table | None, landmark_truth: dict[int, np.ndarray] | None,
                      al: Alignment) -> dict[str, Any]:
    ids, xyz = _landmark_table(landmarks)
    section: dict[str, Any] = {"n_estimated": int(ids.shape[0]), "truth_available": landmark_truth is not None}
    if landmark_truth is None:
        section.update(n_truth=None, n_matched=0, error_m=None, per_landmark=[], estimated_without_truth=None,
                       truth_never_estimated=None, map_aligned=None)
        return section
    lm = metrics.landmark_errors(ids, xyz, landmark_truth, al.rot, al.trans, al.scale)
    row_of = {int(i): k for k, i in enumerate(ids)}
    raw = xyz[[row_of[int(i)] for i in lm.ids]] if lm.ids.size else np.empty((0, 3))
    fit = slam_metrics.map_only_alignment(raw, lm.truth) if lm.ids.size else None
    map_err = None
    map_aligned = None
    if fit is not None:
        rot_m, trans_m = fit
        map_err = np.linalg.norm(metrics.apply_alignment(rot_m, trans_m, 1.0, raw) - lm.truth, axis=1)
        map_aligned = {
            "error_m": metrics.statistics(map_err),
            "alignment": _alignment_dict(Alignment("se3", rot_m, trans_m, 1.0, int(lm.ids.size))),
            "method": ("SE(3) Umeyama fitted on the matched landmarks alone (map-only alignment); error = "
                       "‖R_m p̂_i + t_m − p_i‖. The gap to error_m (trajectory alignment) is how far the map sits "
                       "from where the trajectory puts it; error under this alignment is the map's shape error"),
        }
    has_n_obs = landmarks is not None and "n_obs" in _names(landmarks)
    n_obs = dict(zip(ids.tolist(), _col(landmarks, "n_obs").tolist())) if has_n_obs else {}
    section.update(
        n_truth=len(landmark_truth),
        n_matched=int(lm.ids.shape[0]),
        error_m=metrics.statistics(lm.errors) if lm.ids.size else None,
        per_landmark=[
            {
                "id": int(i),
                "error_m": float(e),
                "error_map_aligned_m": None if map_err is None else float(map_err[k]),
                "estimate_aligned": [float(v) for v in p],
                "truth": [float(v) for v in q],
                "n_obs": int(n_obs[int(i)]) if int(i) in n_obs else None,
            }
            for k, (i, e, p, q) in enumerate(zip(lm.ids, lm.errors, lm.est_aligned, lm.truth))
        ],
        estimated_without_truth=[int(i) for i in lm.estimated_without_truth],
        truth_never_estimated=[int(i) for i in lm.truth_never_estimated],
        map_aligned=map_aligned,
    )
    return section


def map_only_section(landmarks: Table | None, landmark_truth: dict[int, np.ndarray]) -> dict[str, Any] | None:
    """Map error of a run without trajectory truth: the landmarks after a map-only SE(3) alignment (needs three
    matched landmarks not on one line; None otherwise). Same numbers as the report's ``map_aligned``."""
    identity = Alignment("none", np.eye(3), np.zeros(3), 1.0, 0)
    section = _landmark_section(landmarks, landmark_truth, identity)
    if section["map_aligned"] is None:
        return None
    return {
        "n_estimated": section["n_estimated"],
        "n_truth": section["n_truth"],
        "n_matched": section["n_matched"],
        "error_m": section["map_aligned"]["error_m"],
        "alignment": section["map_aligned"]["alignment"],
        "method": section["map_aligned"]["method"],
        "per_landmark": [{"id": row["id"], "error_m": row["error_map_aligned_m"], "n_obs": row["n_obs"]}
                         for row in section["per_landmark"]],
        "estimated_without_truth": section["estimated_without_truth"],
        "truth_never_estimated": section["truth_never_estimated"],
    }


def _vec(v: Any) -> list[float]:
    return [float(x) for x in np.asarray(v, dtype=np.float64).reshape(3)]


def bias_plot_rows(biases: Table) -> Table:
    """The rows of the bias table the bias plot draws, in time order (:func:`plots.envelope`; a table that is
    already these rows comes back whole): all a caller must keep of a long table to draw its report."""
    from slamobs.pipeline.evaluation import plots

    rows = _time_order(_col(biases, "t_ns", np.int64))
    cols = [_col(biases, c, np.float64)[rows] for c in GYRO_COLUMNS + VEL_COLUMNS]
    keep = plots.envelope(len(cols[0]), cols)
    take = np.arange(_nrows(biases))[rows][keep]
    if hasattr(biases, "columns"):
        return biases.iloc[take].reset_index(drop=True)
    return {c: np.asarray(v)[take] for c, v in biases.items()}


def _bias_section(biases: Table | None, bias_truth: dict[str, np.ndarray] | None,
                  window_fraction: float) -> dict[str, Any]:
    truth = None if bias_truth is None else {"gyro": _vec(bias_truth["gyro"]), "velocity": _vec(bias_truth["velocity"])}
    section: dict[str, Any] = {"final": None, "truth": truth, "error": None, "error_norm": None, "stability": None,
                               "window_error": None, "window_error_norm": None}
    if biases is None or _nrows(biases) == 0:
        return section
    _require(biases, ("t_ns",) + GYRO_COLUMNS + VEL_COLUMNS, "biases")
    order = _time_order(_col(biases, "t_ns", np.int64))
    t_ns = _col(biases, "t_ns", np.int64)[order]
    gyro = [_col(biases, c, np.float64)[order] for c in GYRO_COLUMNS]  # columns: no (N, 3) copy
    vel = [_col(biases, c, np.float64)[order] for c in VEL_COLUMNS]
    final = {"t_ns": int(t_ns[-1]), "gyro": _vec([c[-1] for c in gyro]), "velocity": _vec([c[-1] for c in vel])}
    section["final"] = final
    stab = {"window_fraction": float(window_fraction),
            "gyro": slam_metrics.window_stats(t_ns, gyro, window_fraction),
            "velocity": slam_metrics.window_stats(t_ns, vel, window_fraction)}
    section["stability"] = stab
    if truth is not None:
        err = {k: [t - e for t, e in zip(truth[k], final[k])] for k in ("gyro", "velocity")}
        section["error"] = err
        section["error_norm"] = {k: float(np.linalg.norm(err[k])) for k in err}
        werr = {k: [t - e for t, e in zip(truth[k], stab[k]["mean"])] for k in ("gyro", "velocity")}
        section["window_error"] = werr
        section["window_error_norm"] = {k: float(np.linalg.norm(werr[k])) for k in werr}
    return section


def _convergence(ev: TrajectoryEvaluation, threshold_m: float) -> dict[str, Any]:
    """When the aligned position error reaches the observer's own steady level (:func:`slam_metrics.convergence`)."""
    t0 = int(ev.estimate.t_ns[0])
    c = slam_metrics.convergence(ev.pair_t_est_ns, ev.translation.errors, threshold_m, ev.error_level)
    return {
        "threshold_m": float(threshold_m),
        "window_s": c["window_s"],
        "steady_error_m": c["steady_error"],
        "steady_level_m": c["steady_level"],
        "band_m": c["band"],
        "window_fraction": slam_metrics.WINDOW_FRACTION,
        "tail_fraction": slam_metrics.TAIL_FRACTION,
        "band_factor": slam_metrics.BAND_FACTOR,
        "estimate_start_ns": t0,
        "t_ns": c["t_ns"],
        "t_since_start_s": None if c["t_ns"] is None else (c["t_ns"] - t0) / 1e9,
    }


def convergence_definition(conv: dict[str, Any]) -> str:
    """The convergence figure's definition, with its numbers (report.md)."""
    return (f"first time after which the error level (median aligned position error over a {conv['window_s']:.3g} s "
            f"window, {100 * conv['window_fraction']:g} % of the log) stays within max(threshold "
            f"{conv['threshold_m']:g} m, {conv['band_factor']:g} × {conv['steady_level_m']:.4g} m, the highest level "
            f"over the last {100 * conv['tail_fraction']:g} % of the log) = {conv['band_m']:.4g} m")


def convergence_line(conv: dict[str, Any]) -> str | None:
    """The convergence figure for a one-line summary: what stays within the band is the error *level* (a running
    median), not every error, which may still exceed the band now and then."""
    if conv.get("t_since_start_s") is None:
        return None
    return (f"{conv['t_since_start_s']:.2f} s after start (median position error over {conv['window_s']:.3g} s "
            f"within {conv['band_m']:.3g} m from then on)")


def _evo_commands(options: ReportOptions, applied_offset_s: float) -> dict[str, str | None]:
    flags = _EVO_ALIGN_FLAGS.get(options.align)
    if flags is None:
        return {"ape": None, "note": f"evo has no {options.align} alignment"}
    off = f" --t_offset {applied_offset_s!r}" if applied_offset_s else ""
    base = f"evo_ape tum {TRUTH_TUM} {ESTIMATE_TUM}{flags} --t_max_diff {options.t_max_diff_s!r}{off}"
    return {"ape": base, "ape_rotation": base + " -r angle_deg",
            "note": f"run in the run directory; the TUM files are written with --export tum, {EVO_ZIP} (the "
                    f"translation result, evo_res {EVO_ZIP}) with --export evo"}


def build_report(
    poses: Table,
    biases: Table | None,
    landmarks: Table | None,
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    bias_truth: dict[str, np.ndarray] | None = None,
    *,
    options: ReportOptions | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    """Errors of one run against ground truth, JSON-ready (plain Python numbers, None for unknowns).

    SLAM without absolute references determines the pose only up to a constant rigid transform
    (docs/observers.md §1.1), so with ``align="se3"`` the estimate is first mapped onto the truth frame by the
    least-squares SE(3) transform of the associated positions; ``align="none"`` compares the raw estimate. ``overrides`` are
    :class:`ReportOptions` fields (e.g. ``t_max_diff_s``, ``align``) on top of ``options``.
    """
    return evaluate_report(poses, biases, landmarks, truth, landmark_truth, bias_truth, options=options,
                           **overrides)[0]


def evaluate_report(
    poses: Table,
    biases: Table | None,
    landmarks: Table | None,
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    bias_truth: dict[str, np.ndarray] | None = None,
    *,
    options: ReportOptions | None = None,
    **overrides: Any,
) -> tuple[dict[str, Any], TrajectoryEvaluation]:
    """:func:`build_report` and the trajectory evaluation behind it (hand it to :func:`write_report`, which
    otherwise associates and aligns the trajectories again: seconds on a long log)."""
    return evaluate_tables({"poses": poses, "biases": biases, "landmarks": landmarks}, truth, landmark_truth,
                           bias_truth, options=options, **overrides)


def evaluate_tables(
    tables: dict[str, Table | None],
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    bias_truth: dict[str, np.ndarray] | None = None,
    *,
    options: ReportOptions | None = None,
    figures: Callable[[list], None] | None = None,
    drawn_biases: Table | None = None,
    **overrides: Any,
) -> tuple[dict[str, Any], TrajectoryEvaluation]:
    """:func:`evaluate_report` of the ``poses``, ``biases`` and ``landmarks`` tables in ``tables``, each removed
    from the dict once it has been used: a caller that hands the dict over (keeps no other reference) has the
    bias table of a long run freed before the trajectory is evaluated.

    ``figures`` (e.g. :meth:`.plot_worker.PlotWorkers.submit`) is handed the report's figure jobs as soon as
    their sections are known (the bias figure, drawn from ``drawn_biases``, first), so that helper processes
    draw them while the rest of the report is computed."""
    options = replace(options or ReportOptions(), **overrides)
    notes: list[str] = []
    truth, invalid = valid_truth(truth)
    if invalid:
        notes.append(f"{invalid} ground-truth poses with a zero or non-finite quaternion (no rotation) dropped")
    bias_section = _bias_section(tables.pop("biases", None), bias_truth, options.bias_window_fraction)
    poses = tables.pop("poses")
    if figures is not None and _nrows(poses):  # the estimate's first stamp is the figures' time origin
        figures([bias_plot_job(bias_section, drawn_biases, int(np.min(_col(poses, "t_ns", np.int64))))])
    ev = evaluate_trajectory(poses, truth, options)  # ``ev.estimate`` holds what is needed
    del poses
    landmarks = tables.pop("landmarks", None)
    landmark_section = _landmark_section(landmarks, landmark_truth, ev.alignment)
    notes += _map_place_note(landmark_section)
    if figures is not None:  # the top view and the landmark errors need no more than the landmark section
        figures([top_view_job(landmark_section, ev, landmarks, landmark_truth),
                 *landmark_plot_jobs(landmark_section)])
    convergence = _convergence(ev, options.convergence_threshold_m)
    if figures is not None:
        figures([error_plot_job(convergence, ev)])
    p = ev.paired
    off = ev.time_offset if options.t_offset_s == "auto" else None  # else still being searched for
    if off is not None and not off.reliable:
        edge = ", at the search limit" if off.at_window_edge else ""
        notes.append(f"applied clock offset {ev.applied_offset_s:.6f} s is not reliable (peak correlation "
                     f"{off.peak_correlation:.2f}{edge})")
    n_pairs, n_est, n_ref = len(p), len(ev.estimate), len(ev.truth)
    report = {
        "schema_version": SCHEMA_VERSION,
        "ape": {"translation_m": ev.translation.stats, "rotation_deg": ev.rotation.stats},
        "ape_by_alignment": _ape_by_alignment(ev, options, notes),
        "rpe": _rpe_section(ev, options, notes),
        "drift": _drift_section(ev, options),
        "time_offset": _time_offset_section(ev, options),
        "landmarks": landmark_section,
        "biases": bias_section,
        "convergence": convergence,
        "time_span": {
            "estimate_ns": [int(ev.estimate.t_ns[0]), int(ev.estimate.t_ns[-1])],
            "truth_ns": [int(np.min(ev.truth.t_ns)), int(np.max(ev.truth.t_ns))],
        },
        "truth_source": {"kind": "stream", "name": truth.topic, "n_poses": len(truth)},
        "evo": _evo_commands(options, ev.applied_offset_s),
        "notes": notes,
        "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(options).items()},
        "method": {
            "tool": f"slamobs {__version__}, pipeline.evaluation (definitions as evo 1.38.1 evo_ape/evo_rpe)",
            "association": {
                "rule": (
                    "nearest timestamp: every stamp of the series with fewer samples (the estimate on a tie) "
                    "is paired with the nearest stamp of the other (earlier one on an exact tie); pairs more "
                    "than t_max_diff_s apart are dropped (evo sync.associate_trajectories, nearest_time); "
                    "t_offset_s is added to the estimate stamps first"
                ),
                "t_max_diff_s": float(options.t_max_diff_s),
                "t_offset_s": float(ev.applied_offset_s),
                "driving_series": "truth" if n_ref < n_est else "estimate",
                "n_pairs": n_pairs,
                "n_estimate": n_est,
                "n_truth": n_ref,
            },
            "alignment": _alignment_dict(ev.alignment),
            "ape_translation": "per pair ‖(s R p_est + t) − p_truth‖ in metres (evo APE translation_part)",
            "ape_rotation": (
                "per pair angle of R_truthᵀ (R R_est) in degrees, in [0, 180] (evo APE rotation_angle_deg)"
            ),
            "ape_by_alignment": ("the same APE after each alignment fitted on the same pairs: what the primary "
                                 "alignment absorbs; yaw (4-DoF) only for runs with IMU directions"),
            "statistics": ("rmse = sqrt(sse / n), sse = Σ e², std is the population std (ddof = 0), as evo; "
                           "p90/p95/p99 are percentiles with linear interpolation"),
            "landmarks": (
                "final map moved by the same (s, R, t) as the trajectory (not re-fitted); "
                "error = ‖s R p̂_i + t − p_i‖ for ids present in both the estimate and the truth; "
                "map_aligned re-fits SE(3) on the landmarks alone; truth_never_estimated are true landmarks the "
                "run never saw, estimated_without_truth are estimated ids the truth does not know"
            ),
            "biases": (
                "final = last row of the bias table; biases are body-frame quantities, unaffected by the "
                "alignment; error = truth − estimate, error_norm = its Euclidean norm; stability over the last "
                "window_fraction of the bias time span: per-axis mean, std, range and least-squares slope "
                "(drift_norm_per_s = ‖slope‖); window_error = truth − window mean"
            ),
            "convergence": (
                "the error level is the running median of the aligned position error over a centred window of "
                "window_fraction of the log's time span (window_s; evaluated at up to 2000 evenly spaced stamps, over "
                "an even stride of at most 2001 errors of the window); "
                "steady_level_m is its highest value over the last tail_fraction of the span, band_m = "
                "max(threshold_m, band_factor × steady_level_m); t_ns is the first stamp after which the level "
                "stays within band_m to the end: when the observer reaches its own steady level, not when noise "
                "last crossed a fixed threshold; null if the last level is above the band; steady_error_m is the "
                "median error over the last tail_fraction; t_since_start_s counts from the first estimate stamp"
            ),
        },
    }
    return report, ev


def report_schema() -> dict:
    """JSON Schema of report.json (``schemas/report.json``)."""
    from slamobs.schemas import HERE

    return json.loads((HERE / "report.json").read_text(encoding="utf-8"))


def validate_report(report: dict[str, Any]) -> None:
    """Raise ``jsonschema.ValidationError`` if ``report`` does not follow ``schemas/report.json``."""
    import jsonschema

    jsonschema.validate(report, report_schema(), cls=jsonschema.Draft202012Validator)


# ---------------------------------------------------------------------------------------------- writing


def _fmt(v: Any, digits: int = 6) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max", "sse", "n", "p95")


def _stats_table(rows: list[tuple[str, dict[str, Any] | None]]) -> list[str]:
    out = ["| quantity | " + " | ".join(STAT_KEYS) + " |", "|---|" + "---|" * len(STAT_KEYS)]
    for name, st in rows:
        cells = [_fmt(st.get(k)) if st is not None else "–" for k in STAT_KEYS]
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    return out


def _vec_str(v: list[float] | None) -> str:
    return "–" if v is None else "[" + ", ".join(_fmt(x) for x in v) + "]"


def _md_trajectory(report: dict[str, Any]) -> list[str]:
    ape, conv, m = report["ape"], report["convergence"], report["method"]
    lines = ["## Absolute pose error (after alignment)", ""]
    lines += _stats_table([("translation [m]", ape["translation_m"]), ("rotation [deg]", ape["rotation_deg"])])
    conv_txt = (
        f"{conv['t_since_start_s']:.3f} s after the estimate start"
        if conv["t_ns"] is not None
        else "not converged (the last aligned position error is above the band)"
    )
    lines += ["", f"Convergence: {conv_txt}; defined as the {convergence_definition(conv)}.", ""]
    if report["evo"].get("ape"):
        lines += [f"Reproduce with evo (TUM files written with `--export tum`): `{report['evo']['ape']}`.", ""]
    by = report.get("ape_by_alignment") or {}
    if by:
        lines += ["### APE under each alignment (same pairs)", ""]
        lines += _stats_table([(f"{k}: translation [m]", v["translation_m"]) for k, v in by.items()]
                              + [(f"{k}: rotation [deg]", v["rotation_deg"]) for k, v in by.items()])
        lines.append("")
    rpe_s, drift, off = report.get("rpe"), report.get("drift"), report["time_offset"]
    lines += ["## Relative error and drift", ""]
    if rpe_s:
        lines += [f"RPE, delta {rpe_s['delta']:g} {rpe_s['delta_unit']} ({rpe_s['n_pairs']} pairs):", ""]
        lines += _stats_table([("translation [m]", rpe_s["translation_m"]), ("rotation [deg]", rpe_s["rotation_deg"])])
        lines.append("")
    if drift:
        lines += ["| segment [m] | segments | translation [%] | rotation [deg/m] |", "|---|---|---|---|"]
        for row in drift["per_length"]:
            lines.append(f"| {row['length_m']:g} | {row['n_segments']} | {_fmt(row['translation_pct'], 4)} | "
                         f"{_fmt(row['rotation_deg_per_m'], 4)} |")
        lines += [f"| all | {drift['n_segments']} | {_fmt(drift['translation_pct'], 4)} | "
                  f"{_fmt(drift['rotation_deg_per_m'], 4)} |", ""]
    if not rpe_s and not drift:
        lines += ["Path too short for RPE and drift.", ""]
    est = "not estimated" if off["estimated_s"] is None else (
        f"{off['estimated_s']:.4f} s (peak correlation {off['peak_correlation']:.2f}, "
        f"{'reliable' + LAG_CAVEAT if off['reliable'] else 'NOT reliable' + _offset_doubts(off)})")
    lines += [f"Clock offset of the estimate: {est}; applied: {off['applied_s']:g} s ({off['applied_from']}).", ""]
    del m
    return lines


#: What a reliable offset is and is not: the estimate's lag behind the truth (a filter's delay) looks the same.
LAG_CAVEAT = (": the estimate matches the truth best when shifted by this much, from the clocks or from the "
              "estimate lagging behind the motion; the trajectories cannot tell the two apart")


def _offset_doubts(off: dict[str, Any]) -> str:
    """Why a clock offset of the report's ``time_offset`` section is not reliable, as ``": reason; reason"``."""
    why = []
    if off["peak_correlation"] < 0.5:
        why.append("correlation below 0.5")
    if abs(off["estimated_s"]) >= off["search_window_s"] - off["grid_step_s"]:
        why.append("at the search limit")
    with_m, without_m = off.get("ape_rmse_with_m"), off.get("ape_rmse_without_m")
    if with_m is not None and without_m is not None and with_m > without_m:
        why.append(f"applied, it raises the APE rmse from {without_m:.4g} to {with_m:.4g} m")
    return ": " + "; ".join(why) if why else ""


def _md_landmarks(lm: dict[str, Any]) -> list[str]:
    lines = ["## Landmark map error", ""]
    if not lm["truth_available"]:
        return lines + [f"{lm['n_estimated']} landmarks estimated; no landmark ground truth available.", ""]
    lines += [f"{lm['n_matched']} of {lm['n_estimated']} estimated landmarks have ground truth "
              f"({lm['n_truth']} true landmarks).", ""]
    rows = [("after trajectory alignment [m]", lm["error_m"])]
    if lm.get("map_aligned"):
        rows.append(("after map-only alignment [m]", lm["map_aligned"]["error_m"]))
    lines += _stats_table(rows)
    lines += ["", "| id | error [m] | error, map-only alignment [m] | estimate (aligned) [m] | truth [m] | n_obs |",
              "|---|---|---|---|---|---|"]
    for row in lm["per_landmark"]:
        lines.append(f"| {row['id']} | {row['error_m']:.6g} | {_fmt(row.get('error_map_aligned_m'))} | "
                     f"{_vec_str(row['estimate_aligned'])} | {_vec_str(row['truth'])} | {_fmt(row['n_obs'])} |")
    return lines + ["", f"Estimated without truth: {lm['estimated_without_truth'] or 'none'}. "
                        f"True landmarks never estimated: {lm['truth_never_estimated'] or 'none'}.", ""]


def _md_biases(bi: dict[str, Any]) -> list[str]:
    lines = ["## Biases (body frame)", ""]
    if bi["final"] is None:
        return lines + ["No bias estimates.", ""]
    lines += ["| bias | final estimate | truth | error (truth − estimate) | ‖error‖ | ‖error‖ of window mean | "
              "drift [/s] |", "|---|---|---|---|---|---|---|"]
    for key, label in (("gyro", "gyro [rad/s]"), ("velocity", "velocity [m/s]")):
        truth = bi["truth"][key] if bi["truth"] else None
        err = bi["error"][key] if bi["error"] else None
        norm = bi["error_norm"][key] if bi["error_norm"] else None
        wnorm = bi["window_error_norm"][key] if bi.get("window_error_norm") else None
        drift = bi["stability"][key]["drift_norm_per_s"] if bi.get("stability") else None
        lines.append(f"| {label} | {_vec_str(bi['final'][key])} | {_vec_str(truth)} | {_vec_str(err)} | "
                     f"{_fmt(norm)} | {_fmt(wnorm)} | {_fmt(drift)} |")
    st = bi.get("stability") or {}
    frac = st.get("window_fraction")
    return lines + ["", f"Final estimate at t_ns = {bi['final']['t_ns']}; stability window: last "
                        f"{_fmt(frac)} of the bias time span.", ""]


def render_markdown(report: dict[str, Any]) -> str:
    """Human-readable version of the report (tables for APE, RPE/drift, landmarks, biases and the method)."""
    m = report["method"]
    lines = ["# slamobs error report", ""]
    lines += _md_trajectory(report)
    lines += _md_landmarks(report["landmarks"])
    lines += _md_biases(report["biases"])
    if report.get("notes"):
        lines += ["## Notes", ""] + [f"- {n}" for n in report["notes"]] + [""]
    assoc, al = m["association"], m["alignment"]
    lines += [
        "## Method",
        "",
        "| item | value |",
        "|---|---|",
        f"| tool | {m['tool']} |",
        f"| association | {assoc['rule']} |",
        f"| t_max_diff | {assoc['t_max_diff_s']:g} s |",
        f"| t_offset | {assoc['t_offset_s']:g} s |",
        f"| pairs | {assoc['n_pairs']} (estimate {assoc['n_estimate']} poses, truth {assoc['n_truth']} poses, "
        f"driven by the {assoc['driving_series']}) |",
        f"| alignment | {al['description']} |",
        f"| alignment rotation (quaternion x, y, z, w) | {_vec_str(al['rotation_quat_xyzw'])} |",
        f"| alignment translation [m] | {_vec_str(al['translation_m'])} |",
        f"| alignment scale | {al['scale']:.9g} |",
        f"| APE translation | {m['ape_translation']} |",
        f"| APE rotation | {m['ape_rotation']} |",
        f"| APE by alignment | {m['ape_by_alignment']} |",
        f"| statistics | {m['statistics']} |",
    ]
    if report.get("rpe"):
        lines.append(f"| RPE | {report['rpe']['method']} |")
    if report.get("drift"):
        lines.append(f"| drift | {report['drift']['method']} |")
    lines += [
        f"| clock offset | {report['time_offset']['method']} |",
        f"| landmarks | {m['landmarks']} |",
    ]
    if report["landmarks"].get("map_aligned"):
        lines.append(f"| map-only alignment | {report['landmarks']['map_aligned']['method']} |")
    lines += [f"| biases | {m['biases']} |", f"| convergence | {m['convergence']} |", ""]
    return "\n".join(lines)


def _options_of(report: dict[str, Any]) -> ReportOptions:
    """The options a report was built with, the applied clock offset fixed (plots show the report's pairs)."""
    opts = dict(report.get("options") or {})
    opts["t_offset_s"] = report["method"]["association"]["t_offset_s"]
    opts["t_max_diff_s"] = report["method"]["association"]["t_max_diff_s"]
    opts["align"] = report["method"]["alignment"]["type"]
    if opts.get("drift_lengths_m") is not None:
        opts["drift_lengths_m"] = tuple(opts["drift_lengths_m"])
    fields = set(ReportOptions.__dataclass_fields__)
    return ReportOptions(**{k: v for k, v in opts.items() if k in fields})


def write_report(
    report: dict[str, Any],
    out_dir: Path | str,
    poses: Table | None,
    biases: Table | None,
    landmarks: Table | None,
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    *,
    evaluation: TrajectoryEvaluation | None = None,
    plots: bool = True,
    metadata: dict[str, Any] | None = None,
    exports: tuple[str, ...] = (),
    plot_workers=None,
) -> list[Path]:
    """Write report.json, report.md, the PNG plots (unless ``plots`` is False: they are most of the report's
    time on short logs), the estimate aligned into the truth's frame (``poses_aligned.parquet``,
    ``landmarks_aligned.parquet``, with the run ``metadata``) and, as ``exports`` asks, the TUM files ("tum")
    and the evo result zip ("evo") into ``out_dir``; returns the written paths.

    The plots and the zip re-use the association window, clock offset and alignment recorded in the report, so
    they show exactly the numbers of the report; ``evaluation`` is the one :func:`evaluate_report` returned with
    this report (same pairs and alignment; ``poses`` may then be None), else it is computed again from
    ``poses``. With ``plot_workers`` (started :class:`~.plot_worker.PlotWorkers`) the figures are drawn by
    those helper processes while the aligned tables are written. The writes are plain: callers that
    replace an existing report write into a temporary directory first (see :mod:`.run_dir`).
    """
    from slamobs.pipeline.evaluation.evo_zip import save_result_zip
    from slamobs.pipeline.readers.trajectory_files import write_tum

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    json_path = out / "report.json"
    json_path.write_text(json.dumps(report, indent=2, sort_keys=True, allow_nan=False) + "\n", encoding="utf-8")
    written.append(json_path)
    md_path = out / "report.md"
    md_path.write_text(render_markdown(report), encoding="utf-8")
    written.append(md_path)

    options = _options_of(report)  # the applied offset is fixed there: no need to estimate it again
    if evaluation is None and poses is None:
        raise ValueError("write_report needs the poses table or the report's evaluation")
    ev = evaluation or evaluate_trajectory(poses, truth, options, estimate_offset=False)
    if "evo" in exports:
        written.append(save_result_zip(out / EVO_ZIP, ev.translation))
    if "tum" in exports:
        written.append(write_tum(out / ESTIMATE_TUM, ev.estimate))
        written.append(write_tum(out / TRUTH_TUM, ev.truth))
    submitted = plot_workers is not None and plot_workers.submitted  # by evaluate_tables, as it went
    jobs = plot_jobs(report, ev, biases, landmarks, landmark_truth) if plots and not submitted else []
    if jobs and plot_workers is not None:
        plot_workers.submit(jobs)  # drawn by the helper processes while the aligned tables are written
    written += write_aligned_tables(out, report, ev, landmarks, metadata or {})
    if plot_workers is not None and plot_workers.submitted:
        written += plot_workers.collect(out)
    elif jobs:
        from slamobs.pipeline.evaluation.plot_worker import draw

        written += draw(jobs, lambda name: out / name)
    return written


def write_aligned_tables(out: Path, report: dict[str, Any], ev: TrajectoryEvaluation, landmarks: Table | None,
                         metadata: dict[str, Any]) -> list[Path]:
    """``poses_aligned.parquet`` and ``landmarks_aligned.parquet``: every pose and the map moved by the report's
    alignment into the truth's frame (a stretch of poses at a time), with the run metadata and the alignment."""
    from slamobs.pipeline.writers import FLOAT_BITS, TableWriter

    al = ev.alignment
    meta = {**metadata, "aligned": {"frame": "ground truth", "alignment": report["method"]["alignment"],
                                    "truth_source": report.get("truth_source")}}
    bits = int((metadata.get("output") or {}).get("float_bits", FLOAT_BITS))
    sink = TableWriter(out, bits)
    try:
        est = ev.estimate
        for rows in row_blocks(len(est)):
            pos = al.positions(np.asarray(est.position[rows], dtype=np.float64))
            rot = al.rotations(quats_to_rots(np.ascontiguousarray(est.quat_xyzw[rows], dtype=np.float64)))
            q = rots_to_quats(np.ascontiguousarray(rot))
            sink.write({"poses_aligned": {"t_ns": np.asarray(est.t_ns[rows]), "x": pos[:, 0], "y": pos[:, 1],
                                          "z": pos[:, 2], "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2], "qw": q[:, 3]}})
        if landmarks is not None:
            xyz = al.positions(_cols(landmarks, ["x", "y", "z"], np.float64))
            sink.write({"landmarks_aligned": {**{c: _col(landmarks, c) for c in _names(landmarks)},
                                              "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}})
        return sink.close(meta)
    except BaseException:
        sink.abort()
        raise


def plot_jobs(report: dict[str, Any], ev: TrajectoryEvaluation, biases: Table | None,
              landmarks: Table | None, landmark_truth: dict[int, np.ndarray] | None) -> list:
    """The report's figures as ``(plots function, file name, keyword arguments)``, the costliest first."""
    return [top_view_job(report["landmarks"], ev, landmarks, landmark_truth), error_plot_job(report["convergence"], ev),
            bias_plot_job(report["biases"], biases, int(ev.estimate.t_ns[0])), *landmark_plot_jobs(report["landmarks"])]


def top_view_job(landmark_section: dict[str, Any], ev: TrajectoryEvaluation, landmarks: Table | None,
                 landmark_truth: dict[int, np.ndarray] | None):
    """The top view: it needs the alignment, the APE and the landmark errors only."""
    from slamobs.pipeline.evaluation import plots

    al = ev.alignment
    path = plots.thin(len(ev.estimate), plots.PATH_POINTS)  # only what is drawn is aligned
    ids, xyz = _landmark_table(landmarks)
    lm_truth_ids = lm_truth_xyz = None
    if landmark_truth:
        lm_truth_ids = np.array(sorted(int(k) for k in landmark_truth), dtype=np.int64)
        lm_truth_xyz = np.array([np.asarray(landmark_truth[int(i)], dtype=np.float64).reshape(3) for i in lm_truth_ids])
    lm_err = {row["id"]: row["error_m"] for row in landmark_section["per_landmark"]}
    return ("plot_trajectory_top", "trajectory_top.png", dict(
        est_xyz=al.positions(ev.estimate.position[path]),
        truth_xyz=np.asarray(ev.truth.position, dtype=np.float64),
        lm_est_ids=ids,
        lm_est_xyz=al.positions(xyz) if len(ids) else np.empty((0, 3)),
        lm_truth_ids=lm_truth_ids,
        lm_truth_xyz=lm_truth_xyz,
        pair_xyz=ev.translation.est_pos_aligned,
        pair_error_m=ev.translation.errors,
        lm_error_m=np.array([lm_err.get(int(i), np.nan) for i in ids]),
        title=f"Top view (x-y): estimate after {_ALIGN_LABELS[al.kind]} alignment vs truth, coloured by APE",
    ))


def error_plot_job(convergence: dict[str, Any], ev: TrajectoryEvaluation):
    """The error figure: it needs the convergence section."""
    t0 = int(ev.estimate.t_ns[0])
    level_t, level = ev.error_level
    return ("plot_errors", "errors.png", dict(
        t_s=(ev.pair_t_est_ns - t0) / 1e9,
        position_error_m=ev.translation.errors,
        attitude_error_deg=ev.rotation.errors,
        band_m=convergence["band_m"],
        convergence_t_s=convergence["t_since_start_s"],
        title=f"Absolute pose error after {_ALIGN_LABELS[ev.alignment.kind]} alignment",
        level=((level_t - t0) / 1e9, level),
    ))


def landmark_plot_jobs(landmark_section: dict[str, Any]) -> list:
    """The landmark error figure when the map has truth (none otherwise)."""
    rows = landmark_section["per_landmark"]
    if not rows:
        return []
    return [("plot_landmark_errors", "landmarks.png", dict(
        ids=np.array([r["id"] for r in rows]),
        error_traj_m=np.array([r["error_m"] for r in rows]),
        error_map_m=None if rows[0].get("error_map_aligned_m") is None
        else np.array([r["error_map_aligned_m"] for r in rows]),
    ))]


def bias_plot_job(section: dict[str, Any], biases: Table | None, t0: int):
    """The bias figure: it needs the bias section and the estimate's first stamp ``t0`` (its time axis) only, so
    it can be drawn while the trajectory is still being evaluated."""
    bt = section["truth"]
    stab = section.get("stability")
    if biases is not None and _nrows(biases):
        drawn = bias_plot_rows(biases)
        bt_s = (_col(drawn, "t_ns", np.int64) - t0) / 1e9
        gyro, vel = _cols(drawn, list(GYRO_COLUMNS), np.float64), _cols(drawn, list(VEL_COLUMNS), np.float64)
    else:
        bt_s, gyro, vel = np.empty(0), np.empty((0, 3)), np.empty((0, 3))
    return ("plot_biases", "biases.png", dict(
        t_s=bt_s,
        gyro=gyro,
        velocity=vel,
        gyro_truth=None if bt is None else np.asarray(bt["gyro"]),
        velocity_truth=None if bt is None else np.asarray(bt["velocity"]),
        window_start_s=None if not stab else (stab["gyro"]["t_start_ns"] - t0) / 1e9,
    ))
