"""The figures planned: each as ``(plots function, file name, keyword arguments)``, the arrays it draws prepared
from the report's sections and the trajectory evaluation (the error report's), or from the run's own tables
(every run's, truth or not: the trajectory in top and 3D view, the map with landmark ids and how often each was
seen, the biases over time, detections per frame and innovation statistics over time; ``summary`` is what
``report.md`` and the CLI say about a run without truth).

Drawing is :mod:`.plots` (in helper processes, :mod:`.plot_worker`, or in the run's own); a job needs only its
sections, so the report hands each one over as soon as they are known.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from slamobs.pipeline.evaluation.align import UPSIDE_DOWN_DEG
from slamobs.pipeline.evaluation.markdown import extent_words
from slamobs.pipeline.evaluation.tables import (
    GYRO_COLUMNS,
    VEL_COLUMNS,
    Table,
    column,
    column_names,
    columns,
    landmark_table,
    n_rows,
    time_order,
)

if TYPE_CHECKING:
    from slamobs.pipeline.evaluation.trajectory_evaluation import TrajectoryEvaluation

ALIGN_LABELS = {
    "se3": "SE(3)",
    "sim3": "Sim(3)",
    "scale": "scale-only",
    "yaw": "4-DoF (yaw)",
    "origin": "origin",
    "none": "no",
    "attitude": "attitude",
}


def plot_jobs(
    report: dict[str, Any],
    ev: TrajectoryEvaluation,
    biases: Table | None,
    landmarks: Table | None,
    landmark_truth: dict[int, np.ndarray] | None,
) -> list:
    """The report's figures as ``(plots function, file name, keyword arguments)``, the costliest first."""
    return [
        top_view_job(report["landmarks"], ev, landmarks, landmark_truth),
        error_plot_job(report["convergence"], ev, (report.get("ape") or {}).get("truth_frame_turn")),
        bias_plot_job(report["biases"], biases, int(ev.estimate.t_ns[0])),
        *landmark_plot_jobs(report["landmarks"]),
        *segment_plot_jobs(segment_arrays(ev), (report.get("ape") or {}).get("truth_frame_turn")),
        *uncertainty_plot_jobs(report.get("uncertainty"), ev),
    ]


def unmeasured_axes(u) -> tuple[int, ...]:
    """The 3σ figure's axes (0-2 attitude, 3-5 position) the NEES leaves out: a planar run's, error zero on every
    pair (``PairedUncertainty.attitude_axes`` / ``position_axes``)."""
    return tuple(i for i in range(3) if i not in u.attitude_axes) + tuple(
        3 + i for i in range(3) if i not in u.position_axes
    )


def uncertainty_plot_jobs(section: dict[str, Any] | None, ev: TrajectoryEvaluation) -> list:
    """The 3σ figure and the NEES figure when the estimate has a covariance (riekf, batch; none otherwise)."""
    from slamobs.pipeline.evaluation import plots
    from slamobs.pipeline.evaluation.sections import nees_windows

    u = ev.uncertainty
    if section is None or u is None:
        return []
    t_s = (u.t_ns - int(ev.estimate.t_ns[0])) / 1e9
    variance = np.c_[np.einsum("nii->ni", u.cov_attitude), np.einsum("nii->ni", u.cov_position)]
    sigma = np.sqrt(np.clip(variance, 0.0, None))
    keep = plots.envelope(len(t_s), np.abs(u.error) - 3.0 * sigma)
    nees = {}
    for part, values in (("position", u.nees_position), ("attitude", u.nees_attitude)):
        mid, mean, counts = nees_windows(values, t_s - t_s[0])
        nees[part] = (mid + t_s[0], mean, counts)
    return [
        (
            "plot_sigma_bounds",
            "uncertainty.png",
            dict(
                t_s=t_s[keep],
                error=u.error[keep],
                sigma=sigma[keep],
                title="Error and ±3σ of the estimate's covariance (truth frame, the gauge pose put on the truth)",
                unmeasured=unmeasured_axes(u),
            ),
        ),
        (
            "plot_nees",
            "nees.png",
            dict(
                position=nees["position"],
                attitude=nees["attitude"],
                mean={k: section[k]["mean"] for k in ("position", "attitude")},
                window_s=section["window_s"],
                dof={k: section[k].get("dof", 3) for k in ("position", "attitude")},
            ),
        ),
    ]


def tilt_caveat(ev: TrajectoryEvaluation) -> str:
    """A second title line for a run the report's alignment tilts although it has a gravity axis (the report's
    note says more), else nothing."""
    return tilt_title_line(ev.gravity_tilt_deg)


def tilt_title_line(tilt: float | None, whose: str = "the estimate", wrap: bool = False) -> str:
    """The one sentence a figure's title gets for an alignment that tilts ``whose`` estimate although it has a
    gravity axis (``tilt``: :attr:`~.trajectory_evaluation.TrajectoryEvaluation.gravity_tilt_deg`, None: nothing):
    the report's figures and ``compare``'s overlay.png (public for the latter), on a line of its own; ``wrap``: on
    two (a long ``whose`` in an 8-inch figure; the report's figures leave room for one line only)."""
    if tilt is None:
        return ""
    what = f"turned {whose} upside down" if tilt > UPSIDE_DOWN_DEG else f"tilts {whose} {tilt:.0f} deg off level"
    return f"\n(this alignment {what}:{chr(10) if wrap else ' '}see the report's note and the 4-DoF APE)"


def top_view_job(
    landmark_section: dict[str, Any],
    ev: TrajectoryEvaluation,
    landmarks: Table | None,
    landmark_truth: dict[int, np.ndarray] | None,
):
    """The top view: it needs the alignment, the APE and the landmark errors only."""
    from slamobs.pipeline.evaluation import plots

    al = ev.alignment
    path = plots.thin(len(ev.estimate), plots.PATH_POINTS)  # only what is drawn is aligned
    ids, xyz = landmark_table(landmarks)
    lm_truth_ids = lm_truth_xyz = None
    if landmark_truth:
        lm_truth_ids = np.array(sorted(int(k) for k in landmark_truth), dtype=np.int64)
        lm_truth_xyz = np.array([np.asarray(landmark_truth[int(i)], dtype=np.float64).reshape(3) for i in lm_truth_ids])
    lm_err = {row["id"]: row["error_m"] for row in landmark_section["per_landmark"]}
    return (
        "plot_trajectory_top",
        "trajectory_top.png",
        dict(
            est_xyz=al.positions(ev.estimate.position[path]),
            truth_xyz=np.asarray(ev.truth.position, dtype=np.float64),
            lm_est_ids=ids,
            lm_est_xyz=al.positions(xyz) if len(ids) else np.empty((0, 3)),
            lm_truth_ids=lm_truth_ids,
            lm_truth_xyz=lm_truth_xyz,
            pair_xyz=ev.translation.est_pos_aligned,
            pair_error_m=ev.translation.errors,
            lm_error_m=np.array([lm_err.get(int(i), np.nan) for i in ids]),
            title=f"Top view (x-y): estimate after {ALIGN_LABELS[al.kind]} alignment vs truth, coloured by APE"
            + tilt_caveat(ev),
        ),
    )


def error_plot_job(convergence: dict[str, Any], ev: TrajectoryEvaluation, turn: dict[str, Any] | None = None):
    """The error figure: it needs the convergence section, and the APE section's ``truth_frame_turn`` (``turn``):
    where the truth's body frame is turned against the estimate's by a constant rotation (TagSLAM test_22: 148 deg
    of rotation APE, 9.7 deg without the turn) the attitude panel draws the error less that turn beside it, as
    report.md's note gives its rmse."""
    from slamobs.pipeline.evaluation.sections import truth_body_rotation

    t0 = int(ev.estimate.t_ns[0])
    level_t, level = ev.error_level
    turned = None
    if turn:
        turned = (truth_body_rotation(ev)[1], float(turn["angle_deg"]), float(turn["rotation_rmse_after_deg"]))
    return (
        "plot_errors",
        "errors.png",
        dict(
            t_s=(ev.pair_t_est_ns - t0) / 1e9,
            position_error_m=ev.translation.errors,
            attitude_error_deg=ev.rotation.errors,
            band_m=convergence["band_m"],
            convergence_t_s=convergence["t_since_start_s"],
            title=f"Absolute pose error after {ALIGN_LABELS[ev.alignment.kind]} alignment" + tilt_caveat(ev),
            level=((level_t - t0) / 1e9, level),
            verdict=convergence_verdict(convergence),
            band_label="this whole-run fit's band" if convergence.get("tail_frame") else "convergence band",
            extent_m=extent_words(convergence)[0] if convergence.get("lost") else None,
            extent_name=extent_words(convergence)[1],
            attitude_turned=turned,
        ),
    )


def convergence_verdict(conv: dict[str, Any]) -> str | None:
    """The error figure's words for the report's convergence section: why it has no convergence time (the band is
    still drawn), or that the level reached is coarse; None for a plain convergence."""
    if conv.get("t_since_start_s") is not None:
        coarse = f"coarse: level {100 * conv['steady_level_share']:.0f} % of the {extent_words(conv)[1]}"
        if tf := conv.get("tail_frame"):  # judged in the frame of the run's end: the band drawn is not its band
            tail = round(100 * conv["tail_fraction"])
            return (
                f"in the frame of its last {tail} %: level {tf['steady_level_m']:.3g} m, band {tf['band_m']:.3g} m"
                f"{'; ' + coarse if conv.get('coarse') else ''}; grows under this whole-run fit"
            )
        return coarse if conv.get("coarse") else None
    if conv.get("lost"):
        extent, name, _ = extent_words(conv)
        return f"not converged: level above the {name} ({extent:.3g} m RMS)"
    if conv.get("growing"):
        return "not converged: the error level keeps growing"
    if conv.get("recurring_s"):
        a, b = conv["recurring_s"]
        return f"not converged: the level left the band again after {b - a:.3g} s within it"
    return "not converged: the last error level is above the band"


#: the box plots of the segment errors (rpg_trajectory_evaluation's relative error per sub-trajectory length)
SEGMENT_PLOT = "segment_errors.png"


def segment_arrays(ev: TrajectoryEvaluation) -> dict[float, dict[str, np.ndarray]]:
    """The segment error arrays per length, as the report's segment_errors section computed them."""
    from slamobs.pipeline.evaluation.sections import SegmentErrorsSection

    section = SegmentErrorsSection()
    section.process_data(ev)
    return section.arrays


def segment_plot_jobs(arrays: dict[float, dict[str, np.ndarray]], turn: dict[str, Any] | None = None) -> list:
    """The segment errors' box plots when some length has segments (none otherwise); ``turn`` (report.json
    ``ape.truth_frame_turn``): the title says that turn is in them (:func:`turn_title_line`)."""
    if not arrays:
        return []
    lengths = sorted(arrays)
    return [
        (
            "plot_segment_errors",
            SEGMENT_PLOT,
            dict(
                lengths_m=np.array(lengths),
                translation_pct=[arrays[k]["translation_pct"] for k in lengths],
                rotation_deg_per_m=[arrays[k]["rotation_deg_per_m"] for k in lengths],
                caveat=turn_title_line(turn),
            ),
        )
    ]


def turn_title_line(turn: dict[str, Any] | None) -> str:
    """The title lines of a figure of relative errors (segment errors: motions in each trajectory's own body frame)
    where the report found the truth's body frame turned against the estimate's (``turn``: ``ape.truth_frame_turn``;
    None: nothing): TagSLAM test_21 against TagSLAM's rig trajectory drew 35-90 % boxes under a plain title beside a
    0.018 m APE. report.md's sentence over its relative errors says more (:func:`.sections.relative_errors_turned`)."""
    if not turn:
        return ""
    from slamobs.pipeline.evaluation.sections import TRUTH_FRAME_TURNED

    return (
        f"\n({TRUTH_FRAME_TURNED} by {turn['angle_deg']:.1f} deg:\nthat turn is in these errors; see the report's note)"
    )


def landmark_plot_jobs(landmark_section: dict[str, Any]) -> list:
    """The landmark error figure when the map has truth (none otherwise)."""
    rows = landmark_section["per_landmark"]
    if not rows:
        return []
    return [
        (
            "plot_landmark_errors",
            "landmarks.png",
            dict(
                ids=np.array([r["id"] for r in rows]),
                error_traj_m=np.array([r["error_m"] for r in rows]),
                error_map_m=None
                if rows[0].get("error_map_aligned_m") is None
                else np.array([r["error_map_aligned_m"] for r in rows]),
            ),
        )
    ]


def bias_plot_job(section: dict[str, Any], biases: Table | None, t0: int):
    """The bias figure: it needs the bias section and the estimate's first stamp ``t0`` (its time axis) only, so
    it can be drawn while the trajectory is still being evaluated."""
    bt = section["truth"]
    stab = section.get("stability")
    if biases is not None and n_rows(biases):
        drawn = bias_plot_rows(biases)
        bt_s = (column(drawn, "t_ns", np.int64) - t0) / 1e9
        gyro, vel = columns(drawn, list(GYRO_COLUMNS), np.float64), columns(drawn, list(VEL_COLUMNS), np.float64)
    else:
        bt_s, gyro, vel = np.empty(0), np.empty((0, 3)), np.empty((0, 3))
    return (
        "plot_biases",
        "biases.png",
        dict(
            t_s=bt_s,
            gyro=gyro,
            velocity=vel,
            gyro_truth=None if bt is None else np.asarray(bt["gyro"]),
            velocity_truth=None if bt is None else np.asarray(bt["velocity"]),
            window_start_s=None if not stab else (stab["gyro"]["t_start_ns"] - t0) / 1e9,
            window_fraction=None if not stab else stab.get("window_fraction"),
        ),
    )


def bias_plot_rows(biases: Table) -> Table:
    """The rows of the bias table the bias plot draws, in time order (:func:`plots.envelope`; a table that is
    already these rows comes back whole): all a caller must keep of a long table to draw its report."""
    from slamobs.pipeline.evaluation import plots

    rows = time_order(column(biases, "t_ns", np.int64))
    cols = [column(biases, c, np.float64)[rows] for c in GYRO_COLUMNS + VEL_COLUMNS]
    keep = plots.envelope(len(cols[0]), cols)
    take = np.arange(n_rows(biases))[rows][keep]
    if hasattr(biases, "columns"):
        return biases.iloc[take].reset_index(drop=True)
    return {c: np.asarray(v)[take] for c, v in biases.items()}


# ------------------------------------------------------------------------- the run's own figures, truth or not

TRAJECTORY_PNG = "trajectory.png"
MAP_PNG = "map.png"
MEASUREMENTS_PNG = "measurements.png"
BIASES_PNG = "biases.png"
#: every file a run's own figures may write (the bias figure is the report's one, drawn without truth too)
RUN_FIGURES = (TRAJECTORY_PNG, MAP_PNG, MEASUREMENTS_PNG, BIASES_PNG)
#: the figures a run draws by default (``evaluation.plots: true``): with truth the estimate over the truth from
#: above, the error over time and (riekf, batch: runs of tens of seconds) the 3σ and NEES figures, without truth
#: the estimate and its map; ``evaluation.plots: all`` draws every figure (each costs 0.3-0.5 s of matplotlib
#: whatever the log's length: most of a short log's run) and ``slamobs report RUN_DIR`` draws them all afterwards
MAIN_FIGURES = ("trajectory_top.png", "errors.png", "uncertainty.png", "nees.png")
MAIN_RUN_FIGURES = (TRAJECTORY_PNG, MAP_PNG)


def drawn(name: str, plots: bool | str, main: tuple[str, ...] = MAIN_FIGURES) -> bool:
    """Whether ``evaluation.plots`` asks for the figure ``name``: all with ``"all"``, none with False, else those
    of ``main``."""
    return plots == "all" or (bool(plots) and name in main)


def chosen(jobs: list, plots: bool | str, main: tuple[str, ...] = MAIN_FIGURES) -> list:
    """The ``jobs`` (figures) that ``evaluation.plots`` asks for (:func:`drawn`)."""
    return [job for job in jobs if drawn(job[1], plots, main)]


#: the innovation statistics are taken over this many time bins at most (about one per 2 pixels)
INNOVATION_BINS = 400


def run_figure_jobs(
    tables: dict[str, Table | None], *, with_biases: bool = True, map_error: dict[str, Any] | None = None
) -> list:
    """The run's figures from its ``tables`` (``poses`` needed; ``landmarks``, ``innovations``, ``biases``
    used when present). ``with_biases`` False leaves the bias figure to the report (it adds the truth);
    ``map_error`` (run.json's, a run without trajectory truth) adds the landmark truth to the map."""
    poses = tables.get("poses")
    if poses is None or not n_rows(poses):
        return []
    t_ns = column(poses, "t_ns", np.int64)
    t0 = int(np.min(t_ns))
    jobs = [trajectory_job(poses), map_job(poses, tables.get("landmarks"), map_error)]
    innovations = tables.get("innovations")
    if innovations is not None and n_rows(innovations):
        jobs.append(measurements_job(innovations, t0))
    if with_biases:
        from slamobs.pipeline.evaluation.sections import BiasSection
        from slamobs.pipeline.evaluation.trajectory_evaluation import ReportOptions

        section = BiasSection(None, ReportOptions().bias_window_fraction)
        section.process_data(tables.get("biases"))
        jobs.append(bias_plot_job(section.get_statistic(), tables.get("biases"), t0))
    return jobs


def _path_xyz(poses: Table) -> np.ndarray:
    """The estimate's positions in time order, thinned to what a figure draws."""
    from slamobs.pipeline.evaluation import plots

    order = time_order(column(poses, "t_ns", np.int64))
    xyz = columns(poses, ["x", "y", "z"], np.float64)[order]
    return xyz[plots.thin(len(xyz), plots.PATH_POINTS)]


def trajectory_job(poses: Table):
    """Top view and 3D view of the estimate as written (the output frame), coloured by time."""
    xyz = _path_xyz(poses)
    return ("plot_trajectory", TRAJECTORY_PNG, dict(xyz=xyz))


def _seen_counts(landmarks: Table | None) -> np.ndarray:
    if landmarks is None or "n_obs" not in (landmarks.columns if hasattr(landmarks, "columns") else landmarks):
        return np.zeros(0, dtype=np.int64)
    return column(landmarks, "n_obs", np.int64)


def map_truth_drawn(map_error: dict[str, Any] | None) -> dict[str, Any]:
    """The landmark truth a map without trajectory truth is drawn with: run.json ``map_error``'s matched landmarks
    carried onto the estimate by the inverse of the map-only alignment the map error is measured after, and the
    legend's words for it (empty: nothing to draw; a run.json written before has no such positions)."""
    rows = [r for r in (map_error or {}).get("per_landmark") or [] if r.get("truth_on_estimate_m") is not None]
    if not rows:
        return {}
    rmse = map_error["error_m"]["rmse"]
    return dict(
        truth_xyz=np.array([r["truth_on_estimate_m"] for r in rows], dtype=np.float64),
        truth_label=f"landmark truth ({len(rows)} matched), placed by a map-only SE(3) fit onto the estimate; "
        f"map error rmse {rmse:.3g} m",
    )


def map_job(poses: Table, landmarks: Table | None, map_error: dict[str, Any] | None = None):
    """The map: each landmark at its final estimate with its id and how often it was seen, over the path; with
    ``map_error`` the landmark truth beside it (:func:`map_truth_drawn`)."""
    ids, xyz = landmark_table(landmarks)
    seen = _seen_counts(landmarks)
    return (
        "plot_map",
        MAP_PNG,
        dict(
            ids=ids,
            xyz=xyz,
            seen=seen if len(seen) == len(ids) else np.zeros(len(ids)),
            path_xyz=_path_xyz(poses),
            **map_truth_drawn(map_error),
        ),
    )


def frame_counts(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Detection frames (distinct stamps) and the number of detections in each."""
    stamps, counts = np.unique(np.asarray(t_ns, dtype=np.int64), return_counts=True)
    return stamps, counts


def binned_stats(t_s: np.ndarray, values: np.ndarray, bins: int = INNOVATION_BINS) -> dict[str, np.ndarray]:
    """Median, 95th percentile and maximum of ``values`` in up to ``bins`` equal runs of time-ordered samples."""
    order = np.argsort(t_s, kind="stable")
    t_s, values = t_s[order], values[order]
    edges = np.unique(np.linspace(0, len(values), min(bins, len(values)) + 1).astype(np.int64))
    out = {k: np.empty(len(edges) - 1) for k in ("t_s", "median", "p95", "max")}
    for k, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        v = values[a:b]
        out["t_s"][k] = 0.5 * (t_s[a] + t_s[b - 1])
        out["median"][k], out["p95"][k] = np.percentile(v, (50, 95))
        out["max"][k] = np.max(v)
    return out


def measurements_job(innovations: Table, t0: int):
    """Detections per frame and the innovation (residual) norms over time, as statistics per time bin."""
    t_ns = column(innovations, "t_ns", np.int64)
    stamps, counts = frame_counts(t_ns)
    norms = column(innovations, "e_norm", np.float64)
    ok = np.isfinite(norms)
    stats = binned_stats((t_ns[ok] - t0) / 1e9, norms[ok]) if ok.any() else None
    return (
        "plot_measurements",
        MEASUREMENTS_PNG,
        dict(frame_t_s=(stamps - t0) / 1e9, per_frame=counts, innovation=stats),
    )


def summary(tables: dict[str, Table | None]) -> dict[str, Any]:
    """What a run without truth can say about itself: duration, path length, map size, detections."""
    poses, landmarks, innovations = (tables.get(k) for k in ("poses", "landmarks", "innovations"))
    out: dict[str, Any] = {"n_poses": n_rows(poses) if poses is not None else 0}
    if out["n_poses"]:
        t_ns = column(poses, "t_ns", np.int64)
        xyz = columns(poses, ["x", "y", "z"], np.float64)[time_order(t_ns)]
        out["duration_s"] = float((np.max(t_ns) - np.min(t_ns)) / 1e9)
        out["path_length_m"] = float(np.sum(np.linalg.norm(np.diff(xyz, axis=0), axis=1)))
        out["extent_m"] = [float(v) for v in np.ptp(xyz, axis=0)]
    out["landmarks"] = n_rows(landmarks) if landmarks is not None else 0
    if innovations is not None and n_rows(innovations):
        _, counts = frame_counts(column(innovations, "t_ns", np.int64))
        norms = column(innovations, "e_norm", np.float64)
        out["detection_frames"] = int(len(counts))
        out["detections_per_frame_mean"] = float(np.mean(counts))
        out["innovation_median"] = float(np.nanmedian(norms)) if np.isfinite(norms).any() else None
        out.update(map_residual(tables.get("landmark_tracks"), innovations, landmarks))
    return out


def map_residual(tracks: Table | None, innovations: Table, landmarks: Table | None) -> dict[str, float]:
    """Median and 95th percentile of :func:`.slam_metrics.map_residuals` (m) when the tables allow it (the tracks
    row for row with the innovations, as the run writes them), else {}."""
    from slamobs.pipeline.evaluation.slam_metrics import map_residuals

    if tracks is None or landmarks is None or n_rows(tracks) != n_rows(innovations) or not n_rows(landmarks):
        return {}
    t_ns, ids = column(tracks, "t_ns", np.int64), column(tracks, "id", np.int64)
    if not (
        np.array_equal(t_ns, column(innovations, "t_ns", np.int64))
        and np.array_equal(ids, column(innovations, "id", np.int64))
    ):
        return {}
    map_ids, map_xyz = landmark_table(landmarks)
    r = map_residuals(
        ids,
        columns(tracks, ["x", "y", "z"], np.float64),
        columns(innovations, ["ex", "ey", "ez"], np.float64),
        map_ids,
        map_xyz,
    )
    ok = np.isfinite(r)
    if not ok.any():
        return {}
    out = {"map_residual_median": float(np.median(r[ok])), "map_residual_p95": float(np.percentile(r[ok], 95))}
    if "sigma" not in column_names(landmarks):
        return out
    return out | residual_over_sigma(ids[ok], r[ok], map_ids, column(landmarks, "sigma", np.float64))


def residual_over_sigma(ids: np.ndarray, residuals: np.ndarray, map_ids: np.ndarray, sigma: np.ndarray) -> dict:
    """``map_residual_over_sigma``: the median over the landmarks with a stated σ of their detections' median
    residual over that σ; {} without σ (the observers)."""
    lm, inv = np.unique(ids, return_inverse=True)
    order = np.argsort(map_ids, kind="stable")
    row = order[np.clip(np.searchsorted(map_ids[order], lm), 0, len(map_ids) - 1)]
    med = np.array([np.median(residuals[inv == k]) for k in range(lm.size)])
    ratio = med / sigma[row]
    ratio = ratio[np.isfinite(ratio)]
    return {"map_residual_over_sigma": float(np.median(ratio))} if ratio.size else {}


#: What each number of :func:`summary` is, with its unit (report.md of a run without truth showed them bare).
SUMMARY_MEANING = {
    "n_poses": "rows of poses.parquet",
    "duration_s": "s from the first pose to the last",
    "path_length_m": "m travelled by the estimate (sum of the steps between poses)",
    "extent_m": "m, the estimate's range in x, y, z",
    "landmarks": "landmarks in the final map",
    "detection_frames": "detection frames with at least one landmark",
    "detections_per_frame_mean": "mean landmarks per detection frame",
    "innovation_median": "m, median over the detections of ‖e_i‖ = ‖p̂_i − R̂y_i − P̂‖ (innovations.parquet e_norm)",
    "map_residual_median": (
        "m, median over the detections of ‖p̂_i(final map) − (R̂y_i + P̂)‖: each detection made a point by the pose "
        "the run held at its time (landmark_tracks − innovations) against the final map; well above "
        "innovation_median when map and trajectory disagree (a filter's final map is refined by later frames, its "
        "earlier poses are not)"
    ),
    "map_residual_p95": "m, 95th percentile of the same",
    "map_residual_over_sigma": (
        "median over the landmarks of their detections' median map residual over the landmark's stated σ "
        "(sqrt(trace Σ / 3), landmarks.parquet sigma): the map against the run's own re-sightings, no truth needed. "
        "The residual also holds the detections' noise and the poses' errors, so it bounds the map's own error from "
        "above: a few is no verdict, tens say the σ is far too small (TagSLAM test_22 riekf 28, whose map is 3.9-5.5 "
        "m off its truth at σ 0.02-0.03 m; batch 0.22)"
    ),
    "map_error_rmse": (
        "m, RMS distance of the map's landmarks from their truth after an SE(3) fit of the map alone (no trajectory "
        "truth to align by; run.json map_error)"
    ),
    "map_error_max": "m, the largest of those distances",
    "map_error_landmarks": "landmarks matched to the truth by id (those the fit and the error are over)",
    "map_error_nees": (
        "mean over those landmarks of eᵀΣ⁻¹e, the error after that fit against the stated covariance turned likewise "
        "(about its DoF when the σ is right: 3, 2 on a planar map; run.json map_error.sigma_check has the DoF, the "
        "95 % bounds and the verdict)"
    ),
    "map_error_over_sigma": "median over those landmarks of ‖e‖ / σ, σ = sqrt(trace Σ / 3)",
}


#: The note of a run whose log has no truth at all (run.json ``notes``); report.md says it in its first lines.
NO_TRUTH_NOTE = "no ground truth in the log: no error report (report.md and the figures show the estimate)"


def summary_rows(info: dict[str, Any], map_error: dict[str, Any] | None = None) -> dict[str, Any]:
    """The numbers of a run without trajectory truth, as report.md's table shows them (each defined in
    :data:`SUMMARY_MEANING`): :func:`summary`'s, and with landmark truth the map error of ``run.json`` ``map_error``."""
    rows = {k: v for k, v in info.items() if k != "figures"}
    if map_error is not None:
        err = map_error["error_m"]
        rows.update(map_error_rmse=err["rmse"], map_error_max=err["max"], map_error_landmarks=map_error["n_matched"])
        if check := map_error.get("sigma_check"):
            rows.update(map_error_nees=check["mean_nees"], map_error_over_sigma=check["error_over_sigma_median"])
    return rows


def summary_json(
    info: dict[str, Any], figures: list[str], notes: list[str] = (), map_error: dict[str, Any] | None = None
) -> dict[str, Any]:
    """``slamobs report --json`` of a run without trajectory truth: every number report.md shows
    (:func:`summary_rows`), ``definitions`` saying what each is and its unit, the notes and figures, and with
    landmark truth run.json's ``map_error`` whole (its alignment, per-landmark errors, σ check)."""
    rows = summary_rows(info, map_error)
    return {
        **rows,
        "definitions": {k: SUMMARY_MEANING.get(k, "") for k in rows},
        "truth": "landmarks only" if map_error is not None else "none",
        "map_error": map_error,
        "notes": list(notes),
        "figures": list(figures),
    }


def summary_markdown(
    info: dict[str, Any], figures: list[str], notes: list[str] = (), map_error: dict[str, Any] | None = None
) -> str:
    """report.md of a run without trajectory truth: what the run did and its figures; with landmark truth the map
    error (``run.json`` ``map_error``: the one error number such a run has)."""
    if map_error is None and NO_TRUTH_NOTE in notes:  # said once, at the top, not again among the notes
        notes = [n for n in notes if n != NO_TRUTH_NOTE]
        lines = ["# Run summary (no ground truth)", ""]
        lines.append("There are no error numbers; the figures show the estimate.")
    elif map_error is None:
        lines = ["# Run summary (no ground truth)", ""]
        lines.append(
            "The run has no ground truth it can be judged by (none in the log, one too short or empty, or one set "
            "aside by `--truth none`: the notes say which), so there are no error numbers; the figures show the "
            "estimate."
        )
    else:
        lines = ["# Run summary (no trajectory truth; map error against the landmark truth)", ""]
        lines.append(
            "The run has landmark truth but no trajectory truth (none in the log, or one too short or empty: the "
            "notes say which): the map error below is its only error number; the figures show the estimate."
        )
    lines.append("Give truth with `slamobs report RUN --truth ...` for the error report.")
    lines += ["", "| quantity | value | meaning |", "|---|---|---|"]
    for key, value in summary_rows(info, map_error).items():
        shown = ", ".join(f"{v:.4g}" for v in value) if isinstance(value, list) else value
        shown = f"{shown:.6g}" if isinstance(shown, float) else "–" if shown is None else shown
        lines.append(f"| {key} | {shown} | {SUMMARY_MEANING.get(key, '')} |")
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    if figures:
        lines += ["", "## Figures", ""] + [f"![{name}]({name})" for name in figures]
    return "\n".join(lines) + "\n"


def run_tables(out) -> dict[str, Table | None]:
    """The tables of run directory ``out`` the run's figures draw (None where a table is missing)."""
    from slamobs.pipeline.writers import read_columns

    names = ("poses", "biases", "landmarks", "innovations", "landmark_tracks")
    paths = {k: Path(out) / f"{k}.parquet" for k in names}
    return {k: read_columns(p) if p.is_file() else None for k, p in paths.items()}


def write_run_figures(
    out,
    tables: dict[str, Table | None],
    notes: list[str] = (),
    plot_workers=None,
    plots: bool | str = "all",
    map_error: dict[str, Any] | None = None,
) -> list:
    """A run without truth: its figures (those ``plots`` chooses, :func:`chosen`; by ``plot_workers`` when given,
    else here) and ``report.md`` saying what the run did and showing them, into ``out``; the paths written."""
    jobs = chosen(run_figure_jobs(tables, map_error=map_error), plots, MAIN_RUN_FIGURES)
    if plot_workers is not None:
        plot_workers.submit(jobs)
        written = plot_workers.collect(Path(out))
    else:
        from slamobs.pipeline.evaluation.plot_worker import draw

        written = draw(jobs, lambda name: Path(out) / name)
    md = Path(out) / "report.md"
    md.write_text(
        summary_markdown(summary(tables), [p.name for p in written], list(notes), map_error), encoding="utf-8"
    )
    return [*written, md]
