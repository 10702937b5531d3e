"""Several observers on one log: read and align once, one run directory each, a side-by-side table."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from slamobs.pipeline.config import RunConfig
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.estimators import get_estimator
from slamobs.pipeline.run import Progress, RunSummary, silent, prepare_log, run_inputs, run_prepared

COLUMNS = (
    "observer",
    "status",
    "ape_trans_rmse_m",
    "ape_rot_rmse_deg",
    "landmark_rmse_m",
    "gyro_bias_err",
    "vel_bias_err",
    "convergence_s",
    "convergence_band_m",
    "run_time_s",
    "error",
)
#: Added after the APE when the batch smoother is compared: each estimator's APE over the smoother's.
VS_BATCH = "ape_vs_batch"
LABELS = {VS_BATCH: "APE / batch APE"}


def compare_log(
    log: Path,
    out_dir: Path,
    config: RunConfig,
    observers: list[str],
    *,
    force: bool = False,
    progress: Progress = silent,
    on_observer: Progress = silent,
):
    """Run every observer in ``observers`` on ``log``; write ``OUT/<observer>/``, the table and an overlay plot.

    An observer that cannot run on this log (e.g. it needs IMU directions the log lacks) gets a row with
    status "failed" and its one-line reason; the others still run. Returns the table as a DataFrame.
    ``progress`` gets every stage line of the runs, ``on_observer`` one line as each observer starts.
    """
    import pandas as pd

    from slamobs.pipeline.paths import check_output
    from slamobs.pipeline.writers import atomic_directory, write_json

    for name in observers:
        spec = get_estimator(name)
        spec.resolve_gains(config.gains.get(name))  # unknown names or bad gains: fail early
        spec.directions_needed(replace(config, observer=name))  # and bad estimator settings
    inputs = run_inputs(Path(log), config)
    check_output(out_dir, inputs, force=force)  # before reading the log: nothing touched
    on_observer(f"reading {log}")
    prepared = prepare_log(log, config, progress=progress)
    rows, summaries = [], {}
    with atomic_directory(out_dir, force=force, inputs=inputs) as tmp:
        for k, name in enumerate(observers, 1):
            t = time.perf_counter()
            step = f"observer {k} of {len(observers)}"
            on_observer(f"{step}: {name}")
            try:
                summary = run_prepared(
                    prepared,
                    tmp / name,
                    replace(config, observer=name),
                    progress=lambda m, step=step: progress(f"{step}: {m}"),
                )
            except InputError as err:
                rows.append(
                    {"observer": name, "status": "failed", "error": err.problem, "run_time_s": time.perf_counter() - t}
                )
                continue
            summaries[name] = summary
            band = ((summary.report or {}).get("convergence") or {}).get("band_m")
            rows.append(
                {
                    "observer": name,
                    "status": "ok",
                    "error": "",
                    **summary.headline(),
                    "convergence_band_m": band,
                    "run_time_s": summary.timings.get("observer_s", float("nan")),
                }
            )
        columns = list(COLUMNS)
        if "batch" in observers:
            columns.insert(columns.index("ape_trans_rmse_m") + 1, VS_BATCH)
            ref = next(
                (r.get("ape_trans_rmse_m") for r in rows if r["observer"] == "batch" and r["status"] == "ok"), None
            )
            for r in rows:
                ape = r.get("ape_trans_rmse_m")
                r[VS_BATCH] = ape / ref if ape is not None and ref else None
        table = pd.DataFrame(rows).reindex(columns=columns)
        table.to_parquet(tmp / "comparison.parquet", compression="zstd", index=False)
        (tmp / "comparison.md").write_text(_markdown(table, log))
        write_json(tmp / "comparison.json", {"log": str(Path(log).resolve()), "rows": table.to_dict("records")})
        if prepared.streams.truth is not None and summaries:
            plot_overlay(tmp / "overlay.png", prepared.streams.truth, summaries)
    return table


def _markdown(table, log: Path) -> str:
    columns = list(table.columns)
    head = "| " + " | ".join(LABELS.get(c, c) for c in columns) + " |\n|" + "---|" * len(columns) + "\n"
    body = ""
    for row in table.to_dict("records"):
        cells = []
        for c in columns:
            v = row.get(c)
            cells.append(
                ""
                if v is None or (isinstance(v, float) and np.isnan(v))
                else (f"{v:.4g}" if isinstance(v, float) else str(v))
            )
        body += "| " + " | ".join(cells) + " |\n"
    vs = (
        " APE / batch APE is each estimator's APE over the batch smoother's on the same inputs."
        if VS_BATCH in columns
        else ""
    )
    return (
        f"# Observer comparison\n\nLog: `{log}`\n\nAPE and landmark errors after SE(3) alignment to the "
        f"truth; bias errors are final-sample norms; convergence_s is the first time after which the aligned "
        f"position error's level (running median over 5 % of the log) stays within convergence_band_m = "
        f"max(threshold, 1.5 × the observer's highest level over the last 20 % of the log), so each observer is "
        f"measured against its own steady level; run time is the observer stage.{vs}\n\n{head}{body}"
    )


def plot_overlay(path: Path, truth, summaries: dict[str, RunSummary]) -> Path:
    """Top view: truth and every observer's trajectory after its own SE(3) alignment."""
    import pandas as pd
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 8.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    from slamobs.pipeline.evaluation.plots import PATH_POINTS, thin

    truth_xy = truth.position[thin(len(truth.position), PATH_POINTS)]
    ax.plot(truth_xy[:, 0], truth_xy[:, 1], "-", color="0.2", lw=2.0, label="truth")
    for name, s in summaries.items():
        poses = pd.read_parquet(Path(s.out_dir) / "poses.parquet", columns=["x", "y", "z"]).to_numpy()
        poses = poses[thin(len(poses), PATH_POINTS)]  # a figure's worth of vertices (long logs: millions)
        align = ((s.report or {}).get("method") or {}).get("alignment") or {}
        rot = np.asarray(align.get("rotation_matrix", np.eye(3)))
        trans = np.asarray(align.get("translation_m", np.zeros(3)))
        xy = poses @ rot.T + trans
        rmse = s.headline()["ape_trans_rmse_m"]
        label = name + (f" (APE {rmse:.3f} m)" if rmse is not None else "")
        ax.plot(xy[:, 0], xy[:, 1], "-", lw=1.0, label=label)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("Top view: SE(3)-aligned estimates vs truth")
    ax.grid(True, alpha=0.3)
    fig.legend(loc="outside lower center", ncols=3, fontsize=8)  # below the axes: never over the data
    fig.savefig(path, dpi=110)
    return path
