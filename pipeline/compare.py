"""Several observers on one log: read and align once, one run directory each, a side-by-side table."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from slamobs.pipeline.config import RunConfig
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.estimators import get_estimator
from slamobs.pipeline.evaluation.figure_jobs import tilt_title_line
from slamobs.pipeline.evaluation.markdown import MAP_TRUTH_HINT
from slamobs.pipeline.evaluation.sections import tilt_note
from slamobs.pipeline.run import (
    MAP_ERROR,
    Progress,
    RunSummary,
    map_error_rmse,
    silent,
    prepare_log,
    run_inputs,
    run_prepared,
)
from slamobs.pipeline.streams import PoseStream

#: Each estimate's APE against the others' (or batch's) when the log has no truth.
DISAGREEMENT = "disagreement_m"
COLUMNS_NO_TRUTH = ("observer", "status", DISAGREEMENT, "landmarks", "path_length_m", "run_time_s", "error")
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
#: What comparison.md says of the ``status`` column (:meth:`.run.RunSummary.status`).
STATUS_WORDS = (
    "status is failed when the estimator could not run (error says why), its own status when its run's record says "
    "its estimate is off (lost or gated_at_end: riekf's filter; likely_lost: an observer's resightings or velocity "
    "bias; gyro_clipped: an observer that integrated a saturating gyro's rates; the Notes say why), else ok"
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
    status "failed" and its one-line reason; the others still run. A finished run's status is its estimator's own
    where that says its estimate is off (:meth:`.run.RunSummary.status`: lost, gated_at_end, likely_lost), else
    "ok". Returns the table as a DataFrame.
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
    prepared = prepare_log(log, config, progress=progress, estimator=", ".join(observers))
    rows, summaries, compiled = [], {}, {}
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
            if seconds := (summary.metadata.get("compiled") or {}).get("seconds"):
                compiled[name] = float(seconds)  # inside its run time: a first run only
            band = ((summary.report or {}).get("convergence") or {}).get("band_m")
            rows.append(
                {
                    "observer": name,
                    "status": summary.status(),
                    "error": "",
                    **summary.headline(),
                    "convergence_band_m": band,
                    "run_time_s": summary.timings.get("observer_s", float("nan")),
                }
            )
        if not has_truth(prepared.streams):
            table = _without_truth(tmp, rows, summaries, log, compiled, bool(config.evaluation.plots))
            table.attrs["compile_note"] = compile_note(compiled)
            return table
        columns = list(COLUMNS)
        if "batch" in observers:
            columns.insert(columns.index("ape_trans_rmse_m") + 1, VS_BATCH)
            ref = next(
                (r.get("ape_trans_rmse_m") for r in rows if r["observer"] == "batch" and r["status"] != "failed"), None
            )
            for r in rows:
                ape = r.get("ape_trans_rmse_m")
                r[VS_BATCH] = ape / ref if ape is not None and ref else None
        table = pd.DataFrame(rows).reindex(columns=columns)
        table.to_parquet(tmp / "comparison.parquet", compression="zstd", index=False)
        notes, tips = caveats(summaries), hints(summaries)
        if table["gyro_bias_err"].isna().all() and table["vel_bias_err"].isna().all():
            notes.append("gyro_bias_err and vel_bias_err are blank: the log has no bias truth")
        if table["landmark_rmse_m"].isna().all():
            notes.append(NO_MAP_TRUTH)
        (tmp / "comparison.md").write_text(comparison_markdown(table, log, compiled=compiled, notes=notes, hints=tips))
        doc = {"log": str(Path(log).resolve()), "rows": table.to_dict("records"), "hints": tips}
        write_json(tmp / "comparison.json", doc)
        if prepared.streams.truth is not None and summaries and config.evaluation.plots:
            plot_overlay(tmp / "overlay.png", prepared.streams.truth, summaries)
    table.attrs["compile_note"] = compile_note(compiled)
    table.attrs["notes"] = notes
    table.attrs["hints"] = tips
    return table


#: the note of a comparison with trajectory truth but no landmark truth (TagSLAM test_21: a blank column, no word)
NO_MAP_TRUTH = f"landmark_rmse_m is blank: no landmark truth; {MAP_TRUTH_HINT}"


def caveats(summaries: dict[str, RunSummary]) -> list[str]:
    """Per observer, why its own status stands in the table's ``status`` (:meth:`.run.RunSummary.status_caveats`:
    riekf lost, or its last detections failing the gate, an observer without a gate likely lost), its run's
    landmark-jump warnings in the words of its run.json ``notes`` (:func:`.observers.base.jump_warnings`: a landmark
    split in two, or one id seen at two places; its report.md has them) and what its report
    says beside its headline numbers (:func:`.evaluation.markdown.headline_caveats`: no or a coarse convergence, or
    one the run's own status contradicts, an upside-down alignment, a truth turned against the estimate), so a blank
    or 180-degree cell is explained; then, once for the log, the body frame
    the runs took and the base frame TF places against it where a truth looked turned
    (:func:`.evaluation.sections.body_frame_notes`: the key that mends the runs, where the turned-truth caveats offer
    only frames.truth_rotation, for the evaluation, one angle per estimator)."""
    from slamobs.pipeline.evaluation.markdown import headline_caveats
    from slamobs.pipeline.evaluation.sections import body_frame_notes
    from slamobs.pipeline.observers.base import jump_warnings

    out = [
        f"{name}: {c}"
        for name, s in summaries.items()
        for c in [*s.status_caveats(), *jump_warnings(name, s.notes), *headline_caveats(s.report or {})]
    ]
    frames = (n for s in summaries.values() for n in body_frame_notes(s.report or {}, s.metadata.get("input") or {}))
    return out + list(dict.fromkeys(frames))


def hints(summaries: dict[str, RunSummary]) -> list[str]:
    """Per estimator, what its run's report suggests trying next (report.json ``hints``), each once and prefixed
    by the estimator's name: compare's summary, comparison.md's Hints and comparison.json's ``hints``."""
    said = (f"{name}: {h}" for name, s in summaries.items() for h in (s.report or {}).get("hints") or [])
    return list(dict.fromkeys(said))


def has_truth(streams) -> bool:
    return streams.truth is not None and len(streams.truth) > 0


def compile_note(compiled: dict[str, float]) -> str:
    """Which run times include compiling the numeric kernels (a first run only), so that one is not read as the
    estimator's speed (riekf 46.4 s beside batch 7.3 s on TagSLAM test_11, 46.1 s of it compiling)."""
    if not compiled:
        return ""
    parts = ", ".join(f"{name}'s {seconds:.1f} s" for name, seconds in compiled.items())
    return f"run time includes compiling numeric kernels (first run only): {parts}; run again for warm times."


def _without_truth(
    tmp: Path,
    rows: list[dict],
    summaries: dict[str, RunSummary],
    log: Path,
    compiled: dict[str, float],
    plots: bool = True,
):
    """The comparison of a log without truth: run time, map size, path length and each estimate's disagreement
    with the others (APE of one estimate against another after SE(3) alignment; against ``batch`` when it
    ran), the table files and (``plots``) an overlay of the estimates aligned onto the reference."""
    import pandas as pd

    from slamobs.pipeline.writers import read_columns, write_json

    poses = {name: read_columns(Path(s.out_dir) / "poses.parquet") for name, s in summaries.items()}
    reference = "batch" if "batch" in poses else None
    spread, aligned = disagreement(poses, reference)
    for r in rows:
        s = summaries.get(r["observer"])
        r[DISAGREEMENT] = spread.get(r["observer"])
        r["landmarks"] = map_size(Path(s.out_dir)) if s is not None else None
        r["path_length_m"] = path_length(poses[r["observer"]]) if r["observer"] in poses else None
        r[MAP_ERROR] = map_error_rmse(s.metadata if s is not None else None)
    columns = list(COLUMNS_NO_TRUTH)
    if any(r[MAP_ERROR] is not None for r in rows):
        columns.insert(columns.index("landmarks") + 1, MAP_ERROR)
    table = pd.DataFrame(rows).reindex(columns=columns)
    table.to_parquet(tmp / "comparison.parquet", compression="zstd", index=False)
    against = "the batch smoother's estimate" if reference else "each of the other estimates (their mean)"
    table.attrs["notes"] = notes = caveats(summaries)  # no truth: each estimator's own status, its frames' notes
    (tmp / "comparison.md").write_text(comparison_markdown(table, log, against, compiled, notes, overlay=plots))
    doc = {"log": str(Path(log).resolve()), "truth": None, "disagreement_against": reference or "others"}
    write_json(tmp / "comparison.json", {**doc, "rows": table.to_dict("records")})
    if aligned and plots:
        plot_estimates(tmp / "overlay.png", aligned, spread, reference)
    return table


def map_size(run_dir: Path) -> int | None:
    """The landmarks of the map a run wrote (landmarks.parquet's rows), None without one: a landmark split in two
    counts twice, where run.json ``counts.landmarks`` counts the log's ids (TagSLAM test_11 with its example config:
    21 in the map, 20 ids; comparison.md's ``landmarks`` read 20 before session 33)."""
    from slamobs.pipeline.writers import read_columns

    path = run_dir / "landmarks.parquet"
    return int(read_columns(path, wanted=lambda c: c == "id")["id"].size) if path.is_file() else None


def path_length(poses) -> float:
    xyz = np.column_stack([np.asarray(poses[c], dtype=np.float64) for c in "xyz"])
    return float(np.sum(np.linalg.norm(np.diff(xyz, axis=0), axis=1)))


def _as_stream(name: str, poses) -> PoseStream:
    """An estimate as the stream another one is measured against."""
    xyz = np.column_stack([np.asarray(poses[c], dtype=np.float64) for c in "xyz"])
    quat = np.column_stack([np.asarray(poses[c], dtype=np.float64) for c in ("qx", "qy", "qz", "qw")])
    t_ns = np.asarray(poses["t_ns"], dtype=np.int64)
    return PoseStream(name, name, "", t_ns, t_ns, xyz, quat)


def disagreement(poses: dict, reference: str | None) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Each estimate's APE translation RMSE (m, after SE(3) alignment) against ``reference``'s estimate, or the
    mean of those against every other estimate; and each estimate's positions aligned onto the reference (the
    first estimate without one)."""
    from slamobs.pipeline.evaluation.trajectory_evaluation import ReportOptions, evaluate_trajectory

    names = list(poses)
    if not names:
        return {}, {}
    anchor = reference or names[0]

    def against(a: str, b: str):
        ev = evaluate_trajectory(poses[a], _as_stream(b, poses[b]), ReportOptions(), estimate_offset=False)
        return float(np.sqrt(np.mean(ev.translation.errors**2))), ev.alignment

    spread: dict[str, float] = {}
    aligned: dict[str, np.ndarray] = {}
    for a in names:
        xyz = _as_stream(a, poses[a]).position
        if a == anchor:
            aligned[a] = xyz
            continue
        rmse, alignment = against(a, anchor)
        aligned[a] = alignment.positions(xyz)
        if reference is not None:
            spread[a] = rmse
    if reference is None and len(names) > 1:
        pair = {(a, b): against(a, b)[0] for a in names for b in names if a < b}
        for a in names:
            spread[a] = float(np.mean([pair[tuple(sorted((a, b)))] for b in names if b != a]))
    elif reference is not None:
        spread[reference] = 0.0
    return spread, aligned


def plot_estimates(path: Path, aligned: dict[str, np.ndarray], spread: dict[str, float], reference) -> Path:
    """Top view of every estimate, aligned onto the reference (or the first), labelled with its disagreement."""
    from slamobs.pipeline.evaluation.plots import PATH_POINTS, import_matplotlib, thin

    import_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 8.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for name, xyz in aligned.items():
        xy = xyz[thin(len(xyz), PATH_POINTS)]
        d = spread.get(name)
        label = name + (" (reference)" if name == reference else f" ({d:.3f} m)" if d is not None else "")
        ref = name == reference
        style = dict(lw=3.0, color="0.6", zorder=1) if ref else dict(lw=1.0, zorder=2)
        ax.plot(xy[:, 0], xy[:, 1], "-", label=label, **style)
    anchor = reference or next(iter(aligned))
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    # two lines: in one, the words that define the legend's numbers ran past the right edge ("... (in brackets:
    # disagreemen", test_21's compare); the second says what the number is, as comparison.md's disagreement_m does
    against = f"{reference}'s estimate" if reference else "each of the others (their mean)"
    ax.set_title(
        f"Top view, no truth: estimates SE(3)-aligned onto {anchor}'s\n"
        f"in brackets: disagreement, translation RMSE (m) against {against}",
        fontsize=10,
    )
    ax.grid(True, alpha=0.3)
    fig.legend(loc="outside lower center", ncols=3, fontsize=8)
    fig.savefig(path, dpi=110)
    return path


def comparison_markdown(
    table,
    log: Path,
    against: str | None = None,
    compiled: dict[str, float] | None = None,
    notes: list[str] = (),
    hints: list[str] = (),
    overlay: bool = True,
) -> str:
    """comparison.md: the table of the estimators' metrics on ``log``, each report's caveats and hints under it
    (``overlay``: the comparison drew overlay.png). Public: tests/test_compare.py reads the caveats from made-up
    reports."""
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
    if note := compile_note(compiled or {}):
        body += f"\nThe {note}\n"
    if notes:
        body += "\n## Notes\n\n" + "".join(f"- {n}\n" for n in notes)
    if hints:  # what each run's report suggests trying next (its report.md's "Hint:" lines)
        body += "\n## Hints\n\n" + "".join(f"- {h}\n" for h in hints)
    if against is not None:
        map_words = (
            f"{MAP_ERROR} the map's RMS error against the landmark truth after a map-only SE(3) alignment "
            "(run.json map_error), "
            if MAP_ERROR in columns
            else ""
        )
        return (
            f"# Observer comparison (no ground truth)\n\nLog: `{log}`\n\nThe log has no trajectory truth, so "
            f"there are no trajectory errors: disagreement_m is each estimate's APE translation RMSE against "
            f"{against} after SE(3) alignment (a spread among the estimators, not an error); landmarks is the map "
            f"size (the landmarks each run's map holds: landmarks.parquet's rows, a landmark split in two counted "
            f"twice), {map_words}path_length_m the estimated path's length; run time is the observer stage; "
            f"{STATUS_WORDS}. "
            + ("overlay.png shows the estimates aligned onto one another." if overlay else "")
            + f"\n\n{head}{body}"
        )
    return (
        f"# Observer comparison\n\nLog: `{log}`\n\nAPE and landmark errors after SE(3) alignment to the "
        "truth; bias errors are final-sample norms (gyro_bias_err in rad/s, vel_bias_err in m/s); convergence_s is "
        "the first time after which the aligned "
        f"position error's level (running median over 5 % of the log) stays within convergence_band_m = "
        f"max(threshold, 1.5 × the observer's highest level over the last 20 % of the log), so each observer is "
        f"measured against its own steady level; run time is the observer stage; {STATUS_WORDS}.{vs}\n\n{head}{body}"
    )


def overlay_title(reports: dict[str, dict]) -> str:
    """overlay.png's title: a line for each estimate whose report notes that its alignment tilted it (turned it
    upside down), the sentence the report's own figures give."""
    lines = ["Top view: SE(3)-aligned estimates vs truth"]
    for name, report in reports.items():
        if tilt_note(
            report["method"]["alignment"]["type"],
            (report.get("ape") or {}).get("gravity_tilt_deg"),
            report.get("ape_by_alignment") or {},
        ):
            tilt = report["method"]["alignment"]["gravity_tilt_deg"]
            lines.append(tilt_title_line(tilt, f"{name}'s estimate", wrap=True))
    return "".join(lines)


def plot_overlay(path: Path, truth, summaries: dict[str, RunSummary]) -> Path:
    """Top view: truth and every observer's trajectory after its own SE(3) alignment."""
    import pandas as pd

    from slamobs.pipeline.evaluation.plots import import_matplotlib

    import_matplotlib()
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
    ax.set_title(overlay_title({name: s.report or {} for name, s in summaries.items()}))
    ax.grid(True, alpha=0.3)
    fig.legend(loc="outside lower center", ncols=3, fontsize=8)  # below the axes: never over the data
    fig.savefig(path, dpi=110)
    return path
