"""``slamobs report RUN_DIR``: (re)compute the error report of a finished run, optionally against another truth.

Heavy modules are imported inside the command (``slamobs --help`` stays fast).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import click

from slamobs.cli.errors import exit_input_error
from slamobs.cli.options import (
    Finite,
    Seconds,
    config_option,
    export_option,
    offset_seconds,
    plots_option,
    quiet_option,
)
from slamobs.cli.progress import Progress, compile_notice

ALIGNMENTS = ("se3", "sim3", "scale", "yaw", "origin", "none")
#: How the summary names each alignment (one spelling in every command: "SE(3)-aligned").
ALIGNED = {
    "se3": "SE(3)-aligned",
    "sim3": "Sim(3)-aligned",
    "scale": "scale-aligned",
    "yaw": "4-DoF (yaw)-aligned",
    "origin": "origin-aligned",
    "none": "not aligned",
    "attitude": "aligned by the attitudes (the truth positions fix no rotation)",
}


def _lengths(text: str | None) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        out = tuple(float(x) for x in text.split(",") if x.strip())
        if not all(math.isfinite(x) for x in out):
            raise ValueError(text)
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected comma-separated metres", param_hint="--drift-lengths") from None
    if not out or min(out) <= 0:
        raise click.BadParameter("segment lengths must be positive", param_hint="--drift-lengths")
    return out


def _previous_options(run_dir: Path) -> dict:
    """Options of the report already in the run directory (a re-report keeps them unless told otherwise)."""
    try:
        options = json.loads((run_dir / "report.json").read_text()).get("options")
    except (OSError, ValueError, AttributeError, RecursionError):  # damaged or edited: the new report replaces it
        return {}
    return dict(options) if isinstance(options, dict) else {}


@click.command("report")
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option(
    "--truth",
    default=None,
    help="a topic of the run's log, a TF edge parent->child, a TUM / EuRoC CSV / KITTI (with stamps) file, or "
    "LOG:TOPIC of another log; 'none': the run's figures and summary without its truth [default: the run's truth]",
)
@click.option("--t-max-diff", "--t_max_diff", type=Seconds(), default=None, help="association tolerance [s]")
@click.option(
    "--t-offset",
    "--t_offset",
    default=None,
    help="seconds added to the estimate stamps, or 'auto' to apply the estimated clock offset",
)
@click.option(
    "--align",
    type=click.Choice(ALIGNMENTS + ("posyaw",)),
    default=None,
    help="alignment of the estimate onto the truth (yaw = 4-DoF translation + yaw, rpg's posyaw)",
)
@click.option("--convergence-threshold", type=Finite(), default=None, help="position error threshold [m]")
@click.option("--rpe-delta", type=Finite(), default=None, help="RPE pair distance [m]")
@click.option("--drift-lengths", default=None, help="KITTI drift segment lengths, comma-separated metres")
@click.option(
    "--bias-window", type=Finite(), default=None, help="fraction of the run at its end used for bias stability"
)
@config_option(
    "run.yaml, read as `slamobs run` reads it: its truth (topics.truth, evaluation.truth_file), evaluation.t_max_diff, "
    "convergence_threshold, align and frames.truth_rotation, where set, replace the run's; the options above replace "
    "those"
)
@export_option(("tum", "evo"), default="what the run wrote")
@plots_option("every figure, none where the run had evaluation.plots: false")
@click.option("--json", "as_json", is_flag=True, help="print report.json instead of the summary")
@quiet_option()
def report(
    run_dir: Path,
    truth: str | None,
    t_max_diff: float | None,
    t_offset: str | None,
    align: str | None,
    convergence_threshold: float | None,
    rpe_delta: float | None,
    drift_lengths: str | None,
    bias_window: float | None,
    config_path: Path | None,
    export: tuple[str, ...] | None,
    plots: bool | None,
    as_json: bool,
    quiet: bool,
) -> None:
    """(Re)compute the error report of the finished run RUN_DIR; report files are replaced atomically.
    Without truth (the run had none and no --truth), or when the run's own truth cannot judge it (no poses, too
    short: as ``slamobs run`` reported): the run's figures and a summary in report.md. It draws every figure
    (evaluation.plots: true spares a run its figures' time: docs/outputs.md, which figures), none where the run
    was made with evaluation.plots: false (or --no-plots); --plots draws them all there too. The options from
    --t-max-diff to --bias-window, where not given, keep what the run's report used: its report.json options
    lists them (a run's first report takes them from its config's evaluation: section, else its defaults)."""
    from slamobs.pipeline.config import NO_TRUTH
    from slamobs.pipeline.errors import TruthUnusable

    from_config, config_truth = _from_config(config_path)
    truth = config_truth if truth is None else truth
    given = {
        "t_max_diff_s": t_max_diff,
        "align": align,
        "convergence_threshold_m": convergence_threshold,
        "rpe_delta_m": rpe_delta,
        "drift_lengths_m": _lengths(drift_lengths),
        "bias_window_fraction": bias_window,
    }
    if t_offset is not None:
        given["t_offset_s"] = offset_seconds(t_offset)
    given = {**from_config, **{k: v for k, v in given.items() if v is not None}}
    if truth is not None and truth.strip() == NO_TRUTH:  # asked for none: as a run without truth
        _summarised(run_dir, as_json, quiet, plots, told=True)
        return
    if truth is None and not _summarised(run_dir, as_json, quiet, plots):  # a run without truth: its figures
        return
    try:
        rep, written = _reported(run_dir, truth, export, given, quiet, plots)
    except TruthUnusable as err:
        if truth is not None:  # a truth asked for by name that cannot judge the run: that is the answer
            exit_input_error(str(err))
        _summarised(run_dir, as_json, quiet, plots, unusable=str(err))  # the run's own truth: as `slamobs run` did
        return
    if quiet:
        return
    if as_json:
        click.echo(json.dumps(rep, indent=2, sort_keys=True))
        return
    _summary(rep, written, run_dir)


def _from_config(path: Path | None) -> tuple[dict, str | None]:
    """The report options and the truth a run.yaml sets (each only where it differs from the default: a key the
    file leaves out keeps the run's report as it was); a config that cannot be read ends the command (exit 2)."""
    if path is None:
        return {}, None
    from slamobs.pipeline.config import RunConfig, load_config
    from slamobs.pipeline.errors import InputError

    try:
        config = load_config(path)
    except InputError as err:
        exit_input_error(str(err))
    ev, default = config.evaluation, RunConfig().evaluation
    options = {
        "t_max_diff_s": ev.t_max_diff if ev.t_max_diff != default.t_max_diff else None,
        "convergence_threshold_m": (
            ev.convergence_threshold if ev.convergence_threshold != default.convergence_threshold else None
        ),
        "align": ev.align,
        "truth_rotation_xyzw": config.frames.truth_rotation,
    }
    truth = config.topics.get("truth") or ev.truth_file
    return {k: v for k, v in options.items() if v is not None}, truth if isinstance(truth, str) and truth else None


def _reported(
    run_dir: Path, truth: str | None, export, given: dict, quiet: bool, plots: bool | None
) -> tuple[dict, list[Path]]:
    """The run's report against ``truth`` (None: the run's own) with the options given over the run's, its figures
    as ``plots`` says (``run_dir.report_plots``); a truth that cannot judge the run raises TruthUnusable, every
    other input error ends the command (exit 2)."""
    from slamobs.pipeline.batch.rereport import dataset_report
    from slamobs.pipeline.errors import InputError, TruthUnusable
    from slamobs.pipeline.evaluation.trajectory_evaluation import TUPLE_OPTIONS, ReportOptions
    from slamobs.pipeline.evaluation.run_dir import options_for_run, report_plots, report_run, run_meta

    try:
        meta = run_meta(run_dir)
        base = {k: v for k, v in _previous_options(run_dir).items() if k in ReportOptions.__dataclass_fields__}
        for key in TUPLE_OPTIONS:
            if base.get(key) is not None:
                base[key] = tuple(base[key])
        base.pop("gravity_aligned", None)
        options = options_for_run(meta, **{**base, **{k: v for k, v in given.items() if v is not None}})
        if truth is not None:  # another truth than the run's: the frame run.json names is its truth's, not this one's
            options = replace(options, truth_in_body=None)
        with Progress(quiet) as progress, compile_notice(progress.status, quiet=quiet, lines=progress):
            drawing = " and drawing the figures" if report_plots(meta, plots) else ""
            progress(f"report: evaluating{drawing}")
            with dataset_report(run_dir):  # a batch run: its rows in the dataset follow the new report
                return report_run(run_dir, truth, options, exports=export, plots=plots)
    except TruthUnusable:
        raise
    except (InputError, ValueError) as err:
        exit_input_error(str(err))


def _summarised(
    run_dir: Path, as_json: bool, quiet: bool, plots: bool | None, unusable: str | None = None, told: bool = False
) -> bool:
    """A run without truth is summarised and drawn as ``plots`` says (False: done); True when the run has truth to
    report on.
    ``unusable``: why the run's truth cannot judge it (no poses, too short): summarised as without truth; ``told``:
    ``--truth none``, summarised as without truth."""
    from slamobs.pipeline.batch.rereport import dataset_report
    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.evaluation.run_dir import has_truth, report_plots, run_meta, summarise_run

    try:
        meta = run_meta(run_dir)
        if unusable is None and not told and has_truth(meta):
            return True
        with Progress(quiet) as progress, dataset_report(run_dir):
            what = "drawing the run's figures" if report_plots(meta, plots) else "summarising the run"
            progress(f"report: {what} (no truth: no error report)")
            info, written = summarise_run(run_dir, plots, set_aside=told and has_truth(meta))
    except InputError as err:
        exit_input_error(str(err))
    if as_json:
        click.echo(json.dumps(info, indent=2, sort_keys=True))
    elif not quiet:
        click.echo(
            f"truth        unusable ({unusable}): the run's figures and summary only"
            if unusable
            else "truth        none (--truth none): the run's figures and summary only"
            if told
            else "truth        none: the run's figures and summary only (give --truth for the error report)"
        )
        extent = " x ".join(f"{v:.3g}" for v in info.get("extent_m", []))
        click.echo(
            f"estimate     {info['n_poses']} poses over {info.get('duration_s', 0):.1f} s, path "
            f"{info.get('path_length_m', 0):.2f} m, extent {extent} m"
        )
        residual = (
            f"; the detections placed by the run's own poses lie {info['map_residual_median']:.4g} m from it "
            f"(median; p95 {info['map_residual_p95']:.3g} m)"
            if info.get("map_residual_median") is not None
            else ""
        )
        click.echo(f"map          {info['landmarks']} landmarks{residual}")
        if map_error := run_meta(run_dir).get("map_error"):
            click.echo(map_error_line(map_error))
        if info.get("detection_frames"):
            click.echo(
                f"detections   {info['detection_frames']} frames, {info['detections_per_frame_mean']:.2f} per frame, "
                "median innovation "
                + ("–" if info["innovation_median"] is None else f"{info['innovation_median']:.4g} m")
            )
        click.echo(f"wrote        {', '.join(sorted(p.name for p in written))}")
    return False


def map_error_line(map_error: dict) -> str:
    """The map error of a run with landmark truth and no trajectory truth, as ``run`` and ``report`` print it (the
    one error number such a run has; ``report`` said nothing of it)."""
    err = map_error["error_m"]
    return (
        f"landmarks    map error rmse {err['rmse']:.4f} m over {map_error['n_matched']} landmarks "
        "(map-only SE(3) alignment)"
    )


def clock_offset_line(off: dict, run_dir: Path) -> str | None:
    """The summary's clock-offset line (``off``: a report's ``time_offset``; None: none estimated). A reliable
    offset left unapplied names the command that applies it (public: the test reads the line itself)."""
    if off.get("estimated_s") is None:
        return None
    quality = "reliable" if off["reliable"] else "not reliable"
    line = f"{off['estimated_s']:.4f} s estimated ({quality}), {off['applied_s']:g} s applied"
    if off["reliable"] and off["applied_s"] == 0.0 and off["estimated_s"] != 0.0:
        line += f": `slamobs report {run_dir} --t-offset auto` applies it"
    return line


def clock_offset_matters(off: dict) -> bool:
    """Whether ``slamobs run``'s summary shows the clock-offset line (``report`` always does): a reliable offset,
    not applied, more than the search's grid step from zero (where applying it can change the APE; the sample
    logs' 0.004 s is not worth a line on every run)."""
    est = off.get("estimated_s")
    return (
        est is not None
        and bool(off.get("reliable"))
        and off.get("applied_s") == 0.0
        and abs(est) > off.get("grid_step_s", 0.0)
    )


def echo_biases_and_convergence(r: dict) -> None:
    """The report's final bias error and when the estimate converged (``r``: report.json), one line each when
    the report has them, as ``run`` and ``report`` print them."""
    err = (r.get("biases") or {}).get("error_norm")
    if err:
        click.echo(f"biases       final error gyro {err['gyro']:.4g} rad/s, velocity {err['velocity']:.4g} m/s")
    from slamobs.pipeline.evaluation.markdown import convergence_line

    conv = convergence_line(r.get("convergence") or {})
    if conv is not None:
        click.echo(f"converged    {conv}")


def _summary(r: dict, written: list[Path], run_dir: Path) -> None:
    src = r.get("truth_source") or {}
    where = f" of {src['log']}" if src.get("log") else ""  # the log it was read from (LOG:TOPIC: another log)
    click.echo(f"truth        {src.get('kind', '?')} {src.get('name', '?')}{where} ({src.get('n_poses', '?')} poses)")
    ape_t, ape_r = r["ape"]["translation_m"], r["ape"]["rotation_deg"]
    kind = r["method"]["alignment"]["type"]
    click.echo(
        f"APE          translation rmse {ape_t['rmse']:.4f} m (max {ape_t['max']:.4f} m), rotation rmse "
        f"{ape_r['rmse']:.3f} deg, {ape_t['n']} pairs, {ALIGNED[kind]}"
    )
    from slamobs.pipeline.evaluation.sections import relative_errors_turned

    # a turned truth's frame is in the relative errors (test_21 against TagSLAM's rig: RPE 0.77 m on 1 m, drift 58 %
    # beside 0.018 m APE): said above them, as report.md says it over its section
    turned = relative_errors_turned((r.get("ape") or {}).get("truth_frame_turn"))
    if turned and (r.get("rpe") or r.get("drift")):
        click.echo(f"note         {turned[0].removeprefix('Note: ')}")
    if r.get("rpe"):
        click.echo(
            f"RPE          {r['rpe']['delta']:g} m: translation rmse {r['rpe']['translation_m']['rmse']:.4f} m, "
            f"rotation rmse {r['rpe']['rotation_deg']['rmse']:.3f} deg"
        )
    if r.get("drift"):
        d = r["drift"]
        click.echo(
            f"drift        {d['translation_pct']:.3f} % of distance, {d['rotation_deg_per_m']:.4f} deg/m "
            f"({d['n_segments']} segments)"
        )
    lm = r.get("landmarks") or {}
    if lm.get("error_m"):
        extra = f", map-only alignment {lm['map_aligned']['error_m']['rmse']:.4f} m" if lm.get("map_aligned") else ""
        click.echo(
            f"landmarks    map error rmse {lm['error_m']['rmse']:.4f} m over {lm['error_m']['n']} landmarks{extra}"
        )
    echo_biases_and_convergence(r)
    if (line := clock_offset_line(r.get("time_offset") or {}, run_dir)) is not None:
        click.echo(f"clock offset {line}")
    for hint in r.get("hints") or []:  # the run's, as `slamobs run` printed them (run.json's `hints`)
        click.echo(f"hint         {hint}")
    for note in r.get("notes") or []:
        click.echo(f"note         {note}")
    if r.get("evo", {}).get("ape") and any(p.name == "estimate_tum.txt" for p in written):
        click.echo(f"evo          {r['evo']['ape']}")
    click.echo(f"wrote        {', '.join(sorted(p.name for p in written))}")
