"""``slamobs evaluate TRUTH EST``: APE / RPE of any two trajectories, a drop-in for common evo_ape / evo_rpe uses.

Options carry evo's names (``--t_max_diff`` and ``--t-max-diff`` both work, ``-a``, ``-as``, ``-r``, ...) and
the printed block is evo's. Heavy modules are imported inside the command (``slamobs --help`` stays fast).
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from slamobs.cli.errors import exit_input_error
from slamobs.cli.options import Finite, Seconds, Spelled, offset_seconds, quiet_option
from slamobs.cli.progress import compile_notice

RELATIONS = ("trans_part", "angle_deg", "angle_rad", "full", "rot_part", "point_distance")
FORMATS = ("tum", "euroc", "kitti", "parquet")


#: evo's first positional argument: the format of both files (``euroc``: a EuRoC truth and a TUM estimate), or
#: ``bag``/``bag2``/``mcap``: topics of one log
EVO_FORMS = {"tum": ("tum", "tum"), "kitti": ("kitti", "kitti"), "euroc": ("euroc", "tum")}
BAG_FORMS = ("bag", "bag2", "mcap")
#: evo's ``--plot_mode``: the axes of the trajectory panel (``xyz``: a 3D view)
PLOT_MODES = ("xy", "xz", "yx", "yz", "zx", "zy", "xyz")


@click.command("evaluate")
@click.argument("inputs", nargs=-1, required=True, metavar="[tum|kitti|euroc] TRUTH EST | bag|mcap LOG TOPIC TOPIC")
@click.option(
    "--metric",
    type=click.Choice(["ape", "rpe"]),
    default="ape",
    show_default=True,
    help="absolute (evo_ape) or relative (evo_rpe) pose error",
)
@click.option(
    "-r",
    "--pose-relation",
    "--pose_relation",
    "relation",
    type=Spelled(RELATIONS),
    default="trans-part",
    show_default=True,
    help="pose relation the error is based on (evo -r)",
)
@click.option("-a", "--align", is_flag=True, help="SE(3) Umeyama alignment (with -s: Sim(3))")
@click.option("-s", "--correct-scale", "--correct_scale", is_flag=True, help="correct the scale (Umeyama)")
@click.option("--align-origin", "--align_origin", is_flag=True, help="align the first poses")
@click.option(
    "--align-yaw",
    "--align_yaw",
    "--align-posyaw",
    "align_yaw",
    is_flag=True,
    help="4-DoF alignment: translation + yaw about z (for estimates with observed gravity; rpg's posyaw)",
)
@click.option(
    "--n-to-align",
    "--n_to_align",
    type=int,
    default=-1,
    show_default=True,
    help="fit the alignment on the first N associated poses (-1: all)",
)
@click.option(
    "--align-seconds",
    "--align_seconds",
    type=Seconds(),
    default=None,
    help="fit the alignment on the associated poses of the first SECONDS only",
)
@click.option(
    "--t-max-diff",
    "--t_max_diff",
    type=Seconds(),
    default=0.01,
    show_default=True,
    help="maximum timestamp difference for data association [s]",
)
@click.option(
    "--t-offset",
    "--t_offset",
    default="0.0",
    show_default=True,
    help="seconds added to the estimate stamps for the association, or 'auto' (estimated)",
)
@click.option(
    "--sync-method",
    "--sync_method",
    type=Spelled(["nearest_time", "interpolation"]),
    default="nearest-time",
    show_default=True,
    help="nearest stamps, or the denser trajectory interpolated at the sparser one's stamps",
)
@click.option("--estimate-t-offset", is_flag=True, help="estimate the clock offset of EST and print it")
@click.option("--delta", type=Finite(), default=1.0, show_default=True, help="RPE: delta between pose pairs")
@click.option(
    "-u",
    "--delta-unit",
    "--delta_unit",
    type=click.Choice(["f", "m", "d", "r"]),
    default="f",
    show_default=True,
    help="RPE: delta in frames, metres, degrees or radians",
)
@click.option(
    "-t",
    "--delta-tol",
    "--delta_tol",
    type=Finite(),
    default=0.1,
    show_default=True,
    help="RPE: relative delta tolerance for all pairs",
)
@click.option("--all-pairs", "--all_pairs", is_flag=True, help="RPE: all pairs instead of consecutive pairs")
@click.option(
    "--pairs-from-reference",
    "--pairs_from_reference",
    is_flag=True,
    help="RPE: choose the pairs on TRUTH instead of EST",
)
@click.option("--truth-format", type=click.Choice(FORMATS), default=None, help="format of TRUTH (default: detect)")
@click.option("--est-format", type=click.Choice(FORMATS), default=None, help="format of EST (default: detect)")
@click.option(
    "--save-results",
    "--save_results",
    type=click.Path(path_type=Path),
    default=None,
    help=".zip with the result in evo's layout (evo_res reads it)",
)
@click.option("-p", "--plot", is_flag=True, help="draw the error over time and on the trajectory (evo -p) into a PNG")
@click.option(
    "--plot-mode",
    "--plot_mode",
    type=click.Choice(PLOT_MODES),
    default="xyz",
    show_default=True,
    help="axes of the trajectory panel (xyz: 3D)",
)
@click.option(
    "--save-plot",
    "--save_plot",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="PNG file of the plot (implies -p; -p alone writes ape_plot.png or rpe_plot.png here)",
)
@click.option("--json", "as_json", is_flag=True, help="print the result as JSON instead of evo's text")
@quiet_option("print nothing but errors")
def evaluate(
    inputs: tuple[str, ...],
    metric: str,
    relation: str,
    align: bool,
    correct_scale: bool,
    align_origin: bool,
    align_yaw: bool,
    n_to_align: int,
    align_seconds: float | None,
    t_max_diff: float,
    t_offset: str,
    sync_method: str,
    estimate_t_offset: bool,
    delta: float,
    delta_unit: str,
    delta_tol: float,
    all_pairs: bool,
    pairs_from_reference: bool,
    truth_format: str | None,
    est_format: str | None,
    save_results: Path | None,
    plot: bool,
    plot_mode: str,
    save_plot: Path | None,
    as_json: bool,
    quiet: bool,
) -> None:
    """Error of trajectory EST against TRUTH (APE by default; --metric rpe).

    TRUTH and EST are TUM, EuRoC CSV (truth) or KITTI files, a run's poses.parquet, or LOG:TOPIC for a
    PoseStamped / Odometry topic of a ROS bag or MCAP, or LOG:parent->child, a TF edge of the log. KITTI
    files without stamps are paired by index.
    evo's own forms work too: `evaluate tum|kitti|euroc TRUTH EST` and `evaluate bag|bag2|mcap LOG TOPIC TOPIC`
    (a TOPIC also as evo's /tf:parent.child).
    """
    from slamobs.pipeline.errors import InputError

    truth, est, truth_format, est_format = _inputs(inputs, truth_format, est_format)
    kind = _alignment_kind(align, correct_scale, align_origin, align_yaw)
    offset = offset_seconds(t_offset)
    if plot and save_plot is None:
        save_plot = Path(f"{metric}_plot.png")
    try:
        if save_plot is not None:
            from slamobs.pipeline.paths import check_output_file

            check_output_file(save_plot, (truth, est))
        if save_results is not None:
            from slamobs.pipeline.paths import check_output_file

            check_output_file(save_results, (truth, est))
            from slamobs.pipeline.errors import OutputError
            from slamobs.pipeline.evaluation.evo_zip import why_kept

            if save_results.exists() and (why := why_kept(save_results)) is not None:  # refused before the work
                raise OutputError(save_results, why)
        with compile_notice(quiet=quiet):
            out = _run(
                truth,
                est,
                metric,
                relation,
                kind,
                n_to_align,
                align_seconds,
                t_max_diff,
                offset,
                sync_method,
                estimate_t_offset,
                delta,
                delta_unit,
                delta_tol,
                all_pairs,
                pairs_from_reference,
                truth_format,
                est_format,
                save_results,
            )
        if save_plot is not None:
            _save_plot(save_plot, out[0], plot_mode)
    except InputError as err:
        exit_input_error(str(err))
    except ValueError as err:
        exit_input_error(str(err))
    if quiet:
        return
    result, extra = out
    if as_json:
        click.echo(json.dumps(extra["json"], indent=2, sort_keys=True))
        return
    click.echo(result.pretty())
    st = result.stats
    click.echo(f"{'pairs':>10}\t{st['n']}")
    if (line := _unpaired_line(result.paired, t_max_diff)) is not None:
        click.echo(line)
    for p in ("p90", "p95", "p99"):
        click.echo(f"{p:>10}\t{st[p]:.6f}")
    if extra.get("time_offset_line"):
        click.echo(extra["time_offset_line"])
    if extra.get("unaligned_note"):
        click.echo(extra["unaligned_note"], err=True)
    if save_plot is not None:
        click.echo(f"{'plot':>10}\t{save_plot}")


def _inputs(
    inputs: tuple[str, ...], truth_format: str | None, est_format: str | None
) -> tuple[str, str, str | None, str | None]:
    """TRUTH, EST and their formats from the positional arguments: ``TRUTH EST``, evo's ``FORMAT TRUTH EST``
    (the format of both unless --truth-format/--est-format say otherwise) or ``bag LOG TOPIC TOPIC``."""
    if len(inputs) == 2:
        return inputs[0], inputs[1], truth_format, est_format
    if len(inputs) == 3 and inputs[0] in EVO_FORMS:
        ref_fmt, est_fmt = EVO_FORMS[inputs[0]]
        return inputs[1], inputs[2], truth_format or ref_fmt, est_format or est_fmt
    if len(inputs) == 4 and inputs[0] in BAG_FORMS:
        ref, est = (_evo_tf_edge(t) for t in inputs[2:])
        return f"{inputs[1]}:{ref}", f"{inputs[1]}:{est}", truth_format, est_format
    if len(inputs) == 3 and inputs[0] in BAG_FORMS:  # two LOG:TOPIC specifications
        return inputs[1], inputs[2], truth_format, est_format
    raise click.UsageError(
        f"expected TRUTH EST, {'|'.join(EVO_FORMS)} TRUTH EST, or {'|'.join(BAG_FORMS)} LOG TOPIC TOPIC; got "
        f"{len(inputs)} "
        f"argument{'s' if len(inputs) != 1 else ''}: {' '.join(inputs)}"
    )


def _is_tf_edge(source: str) -> bool:
    """``LOG:parent->child``: a TF edge of an existing log (an estimate published as TF, as evo reads one)."""
    from slamobs.pipeline.readers.roles import EDGE_ARROW
    from slamobs.pipeline.readers.trajectory_files import split_topic_source

    found = split_topic_source(str(source))
    return found is not None and EDGE_ARROW in found[1]


def _evo_tf_edge(topic: str) -> str:
    """evo's TF form of a bag's topic, ``/tf:parent.child`` (evo's own example: ``tf_example.bag
    /tf:odom.base_footprint``), as slamobs's ``parent->child``; any other topic unchanged. slamobs reads a TF edge
    from the log's ``/tf`` and ``/tf_static``: another TF topic named there is an error, not read silently."""
    tf_topic, sep, frames = topic.partition(":")
    if not sep:
        return topic
    parent, dot, child = frames.partition(".")
    if tf_topic.strip("/") != "tf" or not dot or not parent or not child or "." in child:
        raise click.BadParameter(
            f"{topic!r}: evo's TF form is /tf:parent.child (slamobs reads TF edges from /tf and /tf_static; "
            "a frame name with a '.' is written LOG:parent->child)",
            param_hint="TOPIC",
        )
    return f"{parent}->{child}"


def _save_plot(path: Path, result, plot_mode: str) -> None:
    """evo's -p figure of ``result`` into the PNG ``path`` (written under a temporary name, then renamed); an
    existing file is replaced only when it is a PNG."""
    import numpy as np

    from slamobs.pipeline.evaluation.plots import plot_error_result
    from slamobs.pipeline.writers import atomic_file, kept_unless

    errors = np.asarray(result.errors, dtype=np.float64)
    t_s = np.asarray(result.arrays.get("seconds_from_start", ()), dtype=np.float64)
    x_label = "t [s]"
    if len(t_s) != len(errors):  # poses without stamps (KITTI), paired by index: the x axis is no time
        t_s, x_label = np.arange(len(errors), dtype=np.float64), "index"
        if "seconds_from_start" not in result.arrays:
            x_label = "index (poses without stamps, paired by index)"
    est = np.asarray(result.est_pos_aligned, dtype=np.float64)
    at = est if result.pair_i is None else est[np.asarray(result.pair_i)]
    why_kept = kept_unless(
        lambda head: head.startswith(b"\x89PNG\r\n\x1a\n"),
        "exists and is not a PNG plot: it is kept; remove it or choose another --save_plot",
    )
    with atomic_file(path, why_kept=why_kept) as tmp:
        plot_error_result(
            tmp,
            t_s,
            errors,
            result.stats,
            np.asarray(result.paired.ref_pos, dtype=np.float64),
            est,
            at,
            plot_mode=plot_mode,
            title=result.title,
            label=result.label,
            aligned=result.alignment.kind != "none",
            x_label=x_label,
        )


def _alignment_kind(align: bool, scale: bool, origin: bool, yaw: bool) -> str:
    if sum((align, origin, yaw)) > 1:
        raise click.UsageError("-a/--align, --align-origin and --align-yaw exclude each other")
    if scale and (origin or yaw):
        raise click.UsageError("-s/--correct-scale combines with -a only")
    if align:
        return "sim3" if scale else "se3"
    if scale:
        return "scale"
    return "origin" if origin else "yaw" if yaw else "none"


def _run(
    truth,
    est,
    metric,
    relation,
    kind,
    n_to_align,
    align_seconds,
    t_max_diff,
    offset,
    sync_method,
    estimate_t_offset,
    delta,
    delta_unit,
    delta_tol,
    all_pairs,
    pairs_from_reference,
    truth_format,
    est_format,
    save_results,
):
    from slamobs.pipeline.evaluation.evo_zip import save_result_zip
    from slamobs.pipeline.evaluation.run_dir import recorded_run_offset
    from slamobs.pipeline.evaluation.sections import offset_fields
    from slamobs.pipeline.evaluation.trajectory_error import (
        AlignOptions,
        RpeOptions,
        SyncOptions,
        ape,
        checked_time_offset,
        describe,
        rpe,
    )
    from slamobs.pipeline.readers import read_truth
    from slamobs.pipeline.readers.trajectory_files import read_trajectory

    ref = read_truth(truth, fmt=truth_format)  # the truth grammar of every command (LOG:parent->child too)
    est_t = read_trajectory(est, est_format) if est_format or not _is_tf_edge(est) else read_truth(est)
    timed = ref.timed and est_t.timed
    method = "nearest" if sync_method == "nearest_time" else "interpolation"
    al = AlignOptions(kind, n_to_align if n_to_align >= 0 else None, align_seconds)
    found, against, asked = None, "estimate", estimate_t_offset or offset == "auto"
    if timed and asked:
        # a run's poses against its own truth: the search the run made and its report states (one search)
        recorded = recorded_run_offset(est, ref.stream)
        against = "estimate" if recorded is None else "velocity samples"
        found = checked_time_offset(ref.stream, est_t.stream, SyncOptions(t_max_diff, 0.0, method), al, found=recorded)
    applied = (found.offset_s if found is not None else 0.0) if offset == "auto" else float(offset)
    sync = SyncOptions(t_max_diff, applied, method)
    rpe_opts = RpeOptions(delta, delta_unit, delta_tol, all_pairs, pairs_from_reference) if metric == "rpe" else None
    if metric == "ape":
        result = ape(ref, est_t, relation, sync, al, ref_name=ref.name, est_name=est_t.name)
    else:
        result = rpe(ref, est_t, relation, sync, al, rpe_opts, ref_name=ref.name, est_name=est_t.name)
    if save_results is not None:
        save_result_zip(save_results, result)
    offset_json = offset_fields(found, applied, offset, against) if timed and asked else None
    return result, {
        "json": _doc(result, describe(result, sync, al, rpe_opts), offset_json),
        "time_offset_line": _offset_line(found, timed, asked, applied, against, offset_json),
        "unaligned_note": _unaligned_note(result, al) if metric == "ape" else None,
    }


#: Below this share of the unaligned APE rmse, the SE(3)-aligned one is named beside it (a note on stderr).
UNALIGNED_NOTE_SHARE = 0.5


def _unaligned_note(result, al) -> str | None:
    """An unaligned translation APE (evo's default) whose SE(3)-aligned rmse on the same pairs is under
    ``UNALIGNED_NOTE_SHARE`` of it, both named: the unaligned number measures the frames as well as the estimate
    (rpg_trajectory_evaluation's EuRoC MH_04 VIO estimate, in its own frame: 18.90 m unaligned, 0.168 m after
    SE(3); evo's KITTI 00 ORB estimate, which starts in the truth's frame: 7.79 m, 1.30 m). None otherwise."""
    from slamobs.pipeline.evaluation.trajectory_error import AlignOptions, ape

    if al.kind != "none" or result.relation not in ("trans_part", "point_distance") or len(result.paired) < 3:
        return None
    unaligned = float(result.stats["rmse"])
    try:
        aligned = ape(None, None, result.relation, align=AlignOptions("se3"), paired=result.paired).stats["rmse"]
    except ValueError:  # collinear positions: the rotation about their line is undetermined, nothing to compare
        return None
    if not float(aligned) < UNALIGNED_NOTE_SHARE * unaligned:
        return None
    return (
        f"note: not aligned (evo's default): rmse {unaligned:.6g} m; the same pairs after SE(3) alignment (-a) "
        f"{aligned:.6g} m. An unaligned error measures the frames as well as the estimate: it is the estimate's "
        "only where it starts in the truth's frame; else -a (or --align-posyaw: translation and yaw, for an "
        "estimate that observes gravity)"
    )


#: Above this share of the driving series' poses unpaired, ``evaluate`` warns: its statistics cover the minority.
UNPAIRED_WARN_SHARE = 0.5


def _unpaired_line(paired, t_max_diff: float) -> str | None:
    """The poses of the driving (shorter) series that found no stamp of the other within ``t_max_diff``: a line
    under ``pairs`` (none when every pose was paired), and a warning on stderr when most were not."""
    if paired.unpaired == 0:
        return None
    series, other = ("truth", "estimate") if paired.driving == "reference" else ("estimate", "truth")
    of = paired.n_ref if paired.driving == "reference" else paired.n_est
    share = paired.unpaired / of
    said = f"{paired.unpaired} of {of} {series} poses ({share:.1%}) found no {other} stamp within {t_max_diff:g} s"
    if share > UNPAIRED_WARN_SHARE:
        click.echo(
            f"warning: most {series} poses are unpaired: {said} (--t_max_diff); the statistics cover the "
            f"{len(paired)} paired; a wider --t_max_diff pairs more of them.",
            err=True,
        )
    return f"{'unpaired':>10}\t{said}"


def _offset_line(found, timed: bool, asked: bool, applied: float, against: str, fields: dict | None) -> str | None:
    """The printed clock-offset line: the offset found, how sure (its correlation, the halves' spread where the
    search has halves, and why it is not reliable as report.md says it: ``markdown.offset_doubts`` of ``fields``,
    the ``--json`` document's ``time_offset``), and what was applied."""
    from slamobs.pipeline.evaluation.markdown import offset_doubts

    if not asked:
        return None
    if not timed:
        return f"{'t_offset':>10}\tnot estimated: poses without stamps are paired by index"
    if found is None:
        return (
            f"{'t_offset':>10}\tnot estimated: the motion carries no clock information (turn rate and speed "
            f"constant) or the trajectories overlap too little; {applied:.6f} s applied"
        )
    halves = "" if found.uncertainty_s is None else f", halves ±{found.uncertainty_s:.6f} s"
    of = "the run's log (its velocity samples)" if against != "estimate" else "the estimate"
    return (
        f"{'t_offset':>10}\t{found.offset_s:.6f} s estimated against {of} (peak correlation "
        f"{found.peak_correlation:.2f}{halves}{'' if found.reliable else ', NOT reliable' + offset_doubts(fields)}), "
        f"{applied:.6f} s applied"
    )


def _doc(result, method: str, offset_json: dict | None) -> dict:
    """``--json``'s document: evo's result fields, the method, and report.json's ``time_offset`` fields."""
    return {
        "title": result.title,
        "label": result.label,
        "ref_name": result.ref_name,
        "est_name": result.est_name,
        "stats": result.stats,
        "method": method,
        "time_offset": offset_json,
    }
