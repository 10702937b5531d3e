"""``slamobs stats INPUTS... -o OUT``: statistics across runs of batch datasets, compare outputs and run
directories (``pipeline.stats``)."""

from __future__ import annotations

from pathlib import Path

import click

from slamobs.cli.options import OutPath, quiet_option
from slamobs.pipeline.errors import plural

STYLES = ("table", "rpg")  # pipeline.stats.render.STYLES, literal so `slamobs --help` imports no pandas
#: The repeated runs' notes printed (stats.md has them all).
REPEAT_NOTES = 5


@click.command("stats")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o", "--out", "out_dir", required=True, type=OutPath(path_type=Path, file_okay=False), help="directory to write"
)
@click.option(
    "--style",
    type=click.Choice(STYLES),
    default=STYLES[0],
    show_default=True,
    help="table: a row per log and estimator with n, mean, median, min, max, std; rpg: a column per estimator, "
    "cells 'mean, median (min, max)' (rpg_trajectory_evaluation's tables)",
)
@click.option("--no-plots", is_flag=True, help="write the tables only (no box and violin figures)")
@click.option("--force", is_flag=True, help="replace an earlier stats output")
@quiet_option()
def stats(inputs: tuple[Path, ...], out_dir: Path, style: str, no_plots: bool, force: bool, quiet: bool) -> None:
    """Statistics across runs: estimators × logs, mean / median / min / max / std of APE, RPE, map, bias errors
    and run time, with box and violin plots and a ranking of how often each estimator wins.

    INPUTS are batch dataset directories (summary.parquet), `slamobs compare` output directories and run
    directories, mixed as needed. OUT gets stats.md, stats.tex, stats.csv, ranking.csv, runs.csv and figures/.
    A metric a run lacks (no truth, no map) is shown as missing, never as zero.
    """
    from slamobs.cli.progress import Progress
    from slamobs.pipeline.stats import write_stats

    with Progress(quiet) as progress:
        progress(f"stats: {len(inputs)} inputs into {out_dir}")
        result = write_stats(list(inputs), out_dir, style=style, figures=not no_plots, force=force)
    if quiet:
        return
    runs = result.runs
    said = runs["status"].value_counts().to_dict()  # ok, failed, or a finished run's own status (likely_lost, ...)
    counts = ", ".join(f"{said[s]} {s}" for s in sorted(said, key=lambda s: (s != "ok", s)))
    click.echo(
        f"stats: {plural(len(runs), 'run')} ({counts}) of {plural(runs['estimator'].nunique(), 'estimator')} on "
        f"{plural(runs['log'].nunique(), 'log')}; wrote {out_dir}/ (stats.md, stats.tex, stats.csv, ranking.csv, "
        f"runs.csv, {plural(len(result.figures), 'figure')})"
    )
    for note in result.notes[:REPEAT_NOTES]:
        click.echo(f"note: {note}")
    if len(result.notes) > REPEAT_NOTES:
        click.echo(
            f"note: {len(result.notes) - REPEAT_NOTES} more estimator and log pairs run more than once alike: "
            "stats.md lists them"
        )
