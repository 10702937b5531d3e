"""The report's figures planned: each as ``(plots function, file name, keyword arguments)``, the arrays it
draws prepared from the report's sections and the trajectory evaluation.

Drawing is :mod:`.plots` (in helper processes, :mod:`.plot_worker`, or in the run's own); a job needs only its
sections, so the report hands each one over as soon as they are known.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from slamobs.pipeline.evaluation.tables import (
    GYRO_COLUMNS,
    VEL_COLUMNS,
    Table,
    column,
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
        error_plot_job(report["convergence"], ev),
        bias_plot_job(report["biases"], biases, int(ev.estimate.t_ns[0])),
        *landmark_plot_jobs(report["landmarks"]),
        *segment_plot_jobs(segment_arrays(ev)),
        *uncertainty_plot_jobs(report.get("uncertainty"), ev),
    ]


def uncertainty_plot_jobs(section: dict[str, Any] | None, ev: TrajectoryEvaluation) -> list:
    """The 3σ figure and the NEES figure when the estimate has a covariance (riekf, batch; none otherwise)."""
    from slamobs.pipeline.evaluation import plots
    from slamobs.pipeline.evaluation.sections import nees_values, nees_windows

    u = ev.uncertainty
    if section is None or u is None:
        return []
    t_s = (u.t_ns - int(ev.estimate.t_ns[0])) / 1e9
    sigma = np.sqrt(np.clip(np.einsum("nii->ni", u.cov), 0.0, None))
    keep = plots.envelope(len(t_s), np.abs(u.error) - 3.0 * sigma)
    label = ALIGN_LABELS[ev.alignment.kind]
    nees = {}
    for part, sl in (("position", slice(3, 6)), ("attitude", slice(0, 3))):
        mid, mean, counts = nees_windows(nees_values(u.error[:, sl], u.cov[:, sl, sl]), t_s - t_s[0])
        nees[part] = (mid + t_s[0], mean, counts)
    return [
        (
            "plot_sigma_bounds",
            "uncertainty.png",
            dict(
                t_s=t_s[keep],
                error=u.error[keep],
                sigma=sigma[keep],
                title=f"Error and ±3σ of the estimate's covariance after {label} alignment (truth frame)",
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
            ),
        ),
    ]


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
            title=f"Top view (x-y): estimate after {ALIGN_LABELS[al.kind]} alignment vs truth, coloured by APE",
        ),
    )


def error_plot_job(convergence: dict[str, Any], ev: TrajectoryEvaluation):
    """The error figure: it needs the convergence section."""
    t0 = int(ev.estimate.t_ns[0])
    level_t, level = ev.error_level
    return (
        "plot_errors",
        "errors.png",
        dict(
            t_s=(ev.pair_t_est_ns - t0) / 1e9,
            position_error_m=ev.translation.errors,
            attitude_error_deg=ev.rotation.errors,
            band_m=convergence["band_m"],
            convergence_t_s=convergence["t_since_start_s"],
            title=f"Absolute pose error after {ALIGN_LABELS[ev.alignment.kind]} alignment",
            level=((level_t - t0) / 1e9, level),
        ),
    )


#: the box plots of the segment errors (rpg_trajectory_evaluation's relative error per sub-trajectory length)
SEGMENT_PLOT = "segment_errors.png"


def segment_arrays(ev: TrajectoryEvaluation) -> dict[float, dict[str, np.ndarray]]:
    """The segment error arrays per length, as the report's segment_errors section computed them."""
    from slamobs.pipeline.evaluation.sections import SegmentErrorsSection

    section = SegmentErrorsSection()
    section.process_data(ev)
    return section.arrays


def segment_plot_jobs(arrays: dict[float, dict[str, np.ndarray]]) -> list:
    """The segment errors' box plots when some length has segments (none otherwise)."""
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
            ),
        )
    ]


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
