"""The run's error report: estimate vs ground truth, as a JSON document, a Markdown page and PNG plots.

``build_report`` is pure (tables in, dict out); ``write_report`` is the I/O edge. The report states how every
number was obtained (association, alignment) so that it can be reproduced with evo (see ``metrics``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline import __version__
from pipeline.evaluation import metrics
from pipeline.lie import quats_to_rots, rot_to_quat
from pipeline.streams import PoseStream

CONVERGENCE_THRESHOLD_M = 0.1
ALIGN_TYPES = ("se3", "none")
POSE_COLUMNS = ("t_ns", "x", "y", "z", "qx", "qy", "qz", "qw")
GYRO_COLUMNS = ("gyro_bias_x", "gyro_bias_y", "gyro_bias_z")
VEL_COLUMNS = ("vel_bias_x", "vel_bias_y", "vel_bias_z")
LANDMARK_COLUMNS = ("id", "x", "y", "z")


@dataclass(frozen=True)
class _Trajectory:
    """Associated, aligned trajectory arrays shared by the report and its plots."""

    t_ns: np.ndarray  # (N,) all estimate stamps, sorted
    position: np.ndarray  # (N, 3) all estimate positions, aligned to the truth frame
    idx_ref: np.ndarray  # (K,) into the truth stream
    idx_est: np.ndarray  # (K,) into t_ns / position, ascending in time
    position_error_m: np.ndarray  # (K,)
    attitude_error_deg: np.ndarray  # (K,)


def _require(df: pd.DataFrame, columns: tuple[str, ...], name: str) -> None:
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"{name} table lacks column(s) {missing}; has {list(df.columns)}")


def _sorted_poses(poses: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    _require(poses, POSE_COLUMNS, "poses")
    if len(poses) == 0:
        raise ValueError("poses table is empty: nothing to evaluate")
    order = np.argsort(poses["t_ns"].to_numpy(np.int64), kind="stable")
    t = poses["t_ns"].to_numpy(np.int64)[order]
    pos = poses[["x", "y", "z"]].to_numpy(np.float64)[order]
    quat = poses[["qx", "qy", "qz", "qw"]].to_numpy(np.float64)[order]
    return t, pos, quat


def _span(t_ns: np.ndarray) -> str:
    return f"[{t_ns.min() / 1e9:.9f}, {t_ns.max() / 1e9:.9f}] s ({t_ns.shape[0]} stamps)"


def _associate(truth: PoseStream, t_est: np.ndarray, t_max_diff_s: float) -> tuple[np.ndarray, np.ndarray]:
    if len(truth) == 0:
        raise ValueError("ground-truth stream is empty: nothing to compare the estimate with")
    idx_ref, idx_est = metrics.associate(truth.t_ns, t_est, t_max_diff_s)
    if idx_ref.size == 0:
        raise ValueError(
            f"no estimate stamp lies within {t_max_diff_s} s of a ground-truth stamp: estimate spans "
            f"{_span(t_est)}, truth spans {_span(np.asarray(truth.t_ns))}. Are both on the same clock "
            f"(header stamps vs. recording time, sim time vs. wall time)?"
        )
    order = np.argsort(idx_est, kind="stable")
    return idx_ref[order], idx_est[order]


def _trajectory(
    poses: pd.DataFrame, truth: PoseStream, t_max_diff_s: float, rot: np.ndarray | None, trans: np.ndarray
) -> tuple[_Trajectory, np.ndarray, np.ndarray]:
    """Associate, fit the alignment when ``rot`` is None (SE(3) Umeyama) and compute the APE vectors."""
    t, pos, quat = _sorted_poses(poses)
    idx_ref, idx_est = _associate(truth, t, t_max_diff_s)
    ref_pos = np.asarray(truth.position, dtype=np.float64)[idx_ref]
    if rot is None:
        rot, trans, _ = metrics.umeyama(pos[idx_est], ref_pos, with_scale=False)
    aligned = metrics.apply_alignment(rot, trans, 1.0, pos)
    ref_rot = quats_to_rots(np.ascontiguousarray(np.asarray(truth.quat_xyzw, dtype=np.float64)[idx_ref]))
    est_rot = np.einsum("ij,njk->nik", rot, quats_to_rots(np.ascontiguousarray(quat[idx_est])))
    traj = _Trajectory(
        t_ns=t,
        position=aligned,
        idx_ref=idx_ref,
        idx_est=idx_est,
        position_error_m=metrics.ape_translation(ref_pos, aligned[idx_est]),
        attitude_error_deg=metrics.ape_rotation_deg(ref_rot, est_rot),
    )
    return traj, rot, trans


def _convergence(traj: _Trajectory, threshold_m: float) -> dict[str, Any]:
    """First associated stamp from which the aligned position error stays below the threshold."""
    t0 = int(traj.t_ns[0])
    above = np.flatnonzero(traj.position_error_m >= threshold_m)
    if above.size == 0:
        k: int | None = 0
    elif above[-1] == traj.position_error_m.shape[0] - 1:
        k = None
    else:
        k = int(above[-1]) + 1
    t_conv = None if k is None else int(traj.t_ns[traj.idx_est[k]])
    return {
        "threshold_m": float(threshold_m),
        "estimate_start_ns": t0,
        "t_ns": t_conv,
        "t_since_start_s": None if t_conv is None else (t_conv - t0) / 1e9,
    }


def _landmark_table(landmarks: pd.DataFrame | None) -> tuple[np.ndarray, np.ndarray]:
    if landmarks is None:
        return np.empty(0, dtype=np.int64), np.empty((0, 3))
    _require(landmarks, LANDMARK_COLUMNS, "landmarks")
    return landmarks["id"].to_numpy(np.int64), landmarks[["x", "y", "z"]].to_numpy(np.float64)


def _landmark_section(
    landmarks: pd.DataFrame | None, landmark_truth: dict[int, np.ndarray] | None, rot: np.ndarray, trans: np.ndarray
) -> dict[str, Any]:
    ids, xyz = _landmark_table(landmarks)
    section: dict[str, Any] = {"n_estimated": int(ids.shape[0]), "truth_available": landmark_truth is not None}
    if landmark_truth is None:
        section.update(n_truth=None, n_matched=0, error_m=None, per_landmark=[], estimated_without_truth=None,
                       truth_never_estimated=None)
        return section
    lm = metrics.landmark_errors(ids, xyz, landmark_truth, rot, trans)
    has_n_obs = landmarks is not None and "n_obs" in landmarks.columns
    n_obs = dict(zip(ids.tolist(), landmarks["n_obs"].tolist())) if has_n_obs else {}
    section.update(
        n_truth=len(landmark_truth),
        n_matched=int(lm.ids.shape[0]),
        error_m=metrics.statistics(lm.errors) if lm.ids.size else None,
        per_landmark=[
            {
                "id": int(i),
                "error_m": float(e),
                "estimate_aligned": [float(v) for v in p],
                "truth": [float(v) for v in q],
                "n_obs": int(n_obs[int(i)]) if int(i) in n_obs else None,
            }
            for i, e, p, q in zip(lm.ids, lm.errors, lm.est_aligned, lm.truth)
        ],
        estimated_without_truth=[int(i) for i in lm.estimated_without_truth],
        truth_never_estimated=[int(i) for i in lm.truth_never_estimated],
    )
    return section


def _vec(v: Any) -> list[float]:
    return [float(x) for x in np.asarray(v, dtype=np.float64).reshape(3)]


def _bias_section(biases: pd.DataFrame | None, bias_truth: dict[str, np.ndarray] | None) -> dict[str, Any]:
    truth = None if bias_truth is None else {"gyro": _vec(bias_truth["gyro"]), "velocity": _vec(bias_truth["velocity"])}
    section: dict[str, Any] = {"final": None, "truth": truth, "error": None, "error_norm": None}
    if biases is None or len(biases) == 0:
        return section
    _require(biases, ("t_ns",) + GYRO_COLUMNS + VEL_COLUMNS, "biases")
    t_ns = biases["t_ns"].to_numpy(np.int64)
    k = int(np.argmax(t_ns))  # the row is read column-wise: a mixed row would turn the int64 stamp to float
    final = {
        "t_ns": int(t_ns[k]),
        "gyro": _vec(biases[list(GYRO_COLUMNS)].to_numpy(np.float64)[k]),
        "velocity": _vec(biases[list(VEL_COLUMNS)].to_numpy(np.float64)[k]),
    }
    section["final"] = final
    if truth is not None:
        err = {k: [t - e for t, e in zip(truth[k], final[k])] for k in ("gyro", "velocity")}
        section["error"] = err
        section["error_norm"] = {k: float(np.linalg.norm(err[k])) for k in err}
    return section


def build_report(
    poses: pd.DataFrame,
    biases: pd.DataFrame | None,
    landmarks: pd.DataFrame | None,
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    bias_truth: dict[str, np.ndarray] | None = None,
    *,
    t_max_diff_s: float = 0.01,
    align: str = "se3",
) -> dict[str, Any]:
    """Errors of one run against ground truth, JSON-ready (plain Python numbers, None for unknowns).

    SLAM without absolute references determines the pose only up to a constant rigid transform (spec §1.6),
    so with ``align="se3"`` the estimate is first mapped onto the truth frame by the least-squares SE(3)
    transform of the associated positions; ``align="none"`` compares the raw estimate.
    """
    if align not in ALIGN_TYPES:
        raise ValueError(f"align must be one of {ALIGN_TYPES}, got {align!r}")
    fixed = (np.eye(3), np.zeros(3)) if align == "none" else (None, np.zeros(3))
    traj, rot, trans = _trajectory(poses, truth, t_max_diff_s, *fixed)
    n_pairs = int(traj.idx_est.shape[0])
    n_est, n_ref = int(traj.t_ns.shape[0]), len(truth)
    alignment_desc = (
        "SE(3) Umeyama (least squares, no scale) fitted on the associated positions; maps the estimate onto the "
        "truth frame: p_truth ≈ R p_est + t, R_truth ≈ R R_est (evo_ape -a)"
        if align == "se3"
        else "none: the estimate is compared in its own frame (evo_ape without -a)"
    )
    return {
        "ape": {
            "translation_m": metrics.statistics(traj.position_error_m),
            "rotation_deg": metrics.statistics(traj.attitude_error_deg),
        },
        "landmarks": _landmark_section(landmarks, landmark_truth, rot, trans),
        "biases": _bias_section(biases, bias_truth),
        "convergence": _convergence(traj, CONVERGENCE_THRESHOLD_M),
        "time_span": {
            "estimate_ns": [int(traj.t_ns[0]), int(traj.t_ns[-1])],
            "truth_ns": [int(np.min(truth.t_ns)), int(np.max(truth.t_ns))],
        },
        "method": {
            "tool": f"slamobs {__version__}, pipeline.evaluation (definitions as evo 1.38.1 evo_ape)",
            "association": {
                "rule": (
                    "nearest timestamp: every stamp of the series with fewer samples (the estimate on a tie) "
                    "is paired with the nearest stamp of the other (earlier one on an exact tie); pairs more "
                    "than t_max_diff_s apart are dropped (evo sync.associate_trajectories, nearest_time)"
                ),
                "t_max_diff_s": float(t_max_diff_s),
                "t_offset_s": 0.0,
                "driving_series": "truth" if n_ref < n_est else "estimate",
                "n_pairs": n_pairs,
                "n_estimate": n_est,
                "n_truth": n_ref,
            },
            "alignment": {
                "type": align,
                "description": alignment_desc,
                "n_points": n_pairs if align == "se3" else 0,
                "rotation_quat_xyzw": [float(v) for v in rot_to_quat(np.ascontiguousarray(rot))],
                "rotation_matrix": [[float(v) for v in row] for row in rot],
                "translation_m": [float(v) for v in trans],
                "scale": 1.0,
            },
            "ape_translation": "per pair ‖(R p_est + t) − p_truth‖ in metres (evo APE translation_part)",
            "ape_rotation": (
                "per pair angle of R_truthᵀ (R R_est) in degrees, in [0, 180] (evo APE rotation_angle_deg)"
            ),
            "statistics": "rmse = sqrt(sse / n), sse = Σ e², std is the population std (ddof = 0), as evo",
            "landmarks": (
                "final map moved by the same (R, t) as the trajectory (not re-fitted); "
                "error = ‖R p̂_i + t − p_i‖ for ids present in both the estimate and the truth"
            ),
            "biases": (
                "last row of the bias table; biases are body-frame quantities, unaffected by the alignment; "
                "error = truth − estimate, error_norm = its Euclidean norm"
            ),
            "convergence": (
                f"first associated estimate stamp from which the aligned position error stays below "
                f"{CONVERGENCE_THRESHOLD_M} m until the end; null if the last error is above it; "
                "t_since_start_s counts from the first estimate stamp"
            ),
        },
    }


# ---------------------------------------------------------------------------------------------- writing


def _fmt(v: Any, digits: int = 6) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _stats_table(rows: list[tuple[str, dict[str, Any] | None]]) -> list[str]:
    keys = ("rmse", "mean", "median", "std", "min", "max", "sse", "n")
    out = ["| quantity | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
    for name, st in rows:
        cells = [_fmt(st[k]) if st is not None else "–" for k in keys]
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    return out


def _vec_str(v: list[float] | None) -> str:
    return "–" if v is None else "[" + ", ".join(f"{x:.6g}" for x in v) + "]"


def render_markdown(report: dict[str, Any]) -> str:
    """Human-readable version of the report (tables for APE, landmarks, biases and the method)."""
    ape, lm, bi, conv, m = (report[k] for k in ("ape", "landmarks", "biases", "convergence", "method"))
    lines = ["# slamobs error report", "", "## Absolute pose error (after alignment)", ""]
    lines += _stats_table([("translation [m]", ape["translation_m"]), ("rotation [deg]", ape["rotation_deg"])])
    conv_txt = (
        f"{conv['t_since_start_s']:.3f} s after the estimate start"
        if conv["t_ns"] is not None
        else "not converged (the last aligned position error is above the threshold)"
    )
    lines += ["", f"Convergence (position error stays below {conv['threshold_m']:g} m): {conv_txt}.", ""]
    lines += ["## Landmark map error", ""]
    if not lm["truth_available"]:
        lines += [f"{lm['n_estimated']} landmarks estimated; no landmark ground truth available.", ""]
    else:
        lines += [
            f"{lm['n_matched']} of {lm['n_estimated']} estimated landmarks have ground truth "
            f"({lm['n_truth']} true landmarks).",
            "",
        ]
        lines += _stats_table([("landmark error [m]", lm["error_m"])])
        lines += ["", "| id | error [m] | estimate (aligned) [m] | truth [m] | n_obs |", "|---|---|---|---|---|"]
        for row in lm["per_landmark"]:
            lines.append(
                f"| {row['id']} | {row['error_m']:.6g} | {_vec_str(row['estimate_aligned'])} | "
                f"{_vec_str(row['truth'])} | {_fmt(row['n_obs'])} |"
            )
        lines += [
            "",
            f"Estimated without truth: {lm['estimated_without_truth'] or 'none'}. "
            f"True landmarks never estimated: {lm['truth_never_estimated'] or 'none'}.",
            "",
        ]
    lines += ["## Biases (final estimate, body frame)", ""]
    if bi["final"] is None:
        lines += ["No bias estimates.", ""]
    else:
        lines += ["| bias | estimate | truth | error (truth − estimate) | ‖error‖ |", "|---|---|---|---|---|"]
        for key, label in (("gyro", "gyro [rad/s]"), ("velocity", "velocity [m/s]")):
            truth = bi["truth"][key] if bi["truth"] else None
            err = bi["error"][key] if bi["error"] else None
            norm = bi["error_norm"][key] if bi["error_norm"] else None
            lines.append(
                f"| {label} | {_vec_str(bi['final'][key])} | {_vec_str(truth)} | {_vec_str(err)} | {_fmt(norm)} |"
            )
        lines += ["", f"Final estimate at t_ns = {bi['final']['t_ns']}.", ""]
    assoc, al = m["association"], m["alignment"]
    lines += [
        "## Method",
        "",
        "| item | value |",
        "|---|---|",
        f"| tool | {m['tool']} |",
        f"| association | {assoc['rule']} |",
        f"| t_max_diff | {assoc['t_max_diff_s']:g} s |",
        f"| pairs | {assoc['n_pairs']} (estimate {assoc['n_estimate']} poses, truth {assoc['n_truth']} poses, "
        f"driven by the {assoc['driving_series']}) |",
        f"| alignment | {al['description']} |",
        f"| alignment rotation (quaternion x, y, z, w) | {_vec_str(al['rotation_quat_xyzw'])} |",
        f"| alignment translation [m] | {_vec_str(al['translation_m'])} |",
        f"| APE translation | {m['ape_translation']} |",
        f"| APE rotation | {m['ape_rotation']} |",
        f"| statistics | {m['statistics']} |",
        f"| landmarks | {m['landmarks']} |",
        f"| biases | {m['biases']} |",
        f"| convergence | {m['convergence']} |",
        "",
    ]
    return "\n".join(lines)


def write_report(
    report: dict[str, Any],
    out_dir: Path | str,
    poses: pd.DataFrame,
    biases: pd.DataFrame | None,
    landmarks: pd.DataFrame | None,
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
) -> list[Path]:
    """Write report.json, report.md and the PNG plots into ``out_dir``; returns the written paths.

    The plots re-use the association window and the alignment recorded in ``report["method"]`` so they show
    exactly the numbers of the report.
    """
    from pipeline.evaluation import plots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    json_path = out / "report.json"
    json_path.write_text(json.dumps(report, indent=2, sort_keys=True, allow_nan=False) + "\n", encoding="utf-8")
    written.append(json_path)
    md_path = out / "report.md"
    md_path.write_text(render_markdown(report), encoding="utf-8")
    written.append(md_path)

    al = report["method"]["alignment"]
    rot = np.asarray(al["rotation_matrix"], dtype=np.float64)
    trans = np.asarray(al["translation_m"], dtype=np.float64)
    traj, _, _ = _trajectory(poses, truth, report["method"]["association"]["t_max_diff_s"], rot, trans)
    t0 = traj.t_ns[0]

    ids, xyz = _landmark_table(landmarks)
    lm_truth_ids = lm_truth_xyz = None
    if landmark_truth:
        lm_truth_ids = np.array(sorted(int(k) for k in landmark_truth), dtype=np.int64)
        lm_truth_xyz = np.array([np.asarray(landmark_truth[int(i)], dtype=np.float64).reshape(3) for i in lm_truth_ids])
    written.append(
        plots.plot_trajectory_top(
            out / "trajectory_top.png",
            traj.position,
            np.asarray(truth.position, dtype=np.float64),
            ids,
            metrics.apply_alignment(rot, trans, 1.0, xyz) if len(ids) else np.empty((0, 3)),
            lm_truth_ids,
            lm_truth_xyz,
        )
    )
    conv = report["convergence"]
    written.append(
        plots.plot_errors(
            out / "errors.png",
            (traj.t_ns[traj.idx_est] - t0) / 1e9,
            traj.position_error_m,
            traj.attitude_error_deg,
            threshold_m=conv["threshold_m"],
            convergence_t_s=conv["t_since_start_s"],
        )
    )
    bt = report["biases"]["truth"]
    if biases is not None and len(biases):
        b = biases.sort_values("t_ns", kind="stable")
        bt_s = (b["t_ns"].to_numpy(np.int64) - t0) / 1e9
        gyro, vel = b[list(GYRO_COLUMNS)].to_numpy(np.float64), b[list(VEL_COLUMNS)].to_numpy(np.float64)
    else:
        bt_s, gyro, vel = np.empty(0), np.empty((0, 3)), np.empty((0, 3))
    written.append(
        plots.plot_biases(
            out / "biases.png",
            bt_s,
            gyro,
            vel,
            None if bt is None else np.asarray(bt["gyro"]),
            None if bt is None else np.asarray(bt["velocity"]),
        )
    )
    return written

