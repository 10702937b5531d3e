"""``slamobs view RUN_DIR...``: finished runs as a Rerun recording (``pipeline.viewer``; the ``view`` extra)."""

from __future__ import annotations

from pathlib import Path

import click

from slamobs.cli.options import OutPath, quiet_option
from slamobs.pipeline.errors import plural


@click.command("view")
@click.argument("run_dirs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    "out",
    type=OutPath(path_type=Path, dir_okay=False),
    default=None,
    help="the .rrd file to write (default: view.rrd in the first RUN_DIR; none with --spawn)",
)
@click.option("--spawn", is_flag=True, help="open the Rerun viewer now and stream the recording to it")
@click.option("--force", is_flag=True, help="replace an existing recording")
@quiet_option()
def view(run_dirs: tuple[Path, ...], out: Path | None, spawn: bool, force: bool, quiet: bool) -> None:
    """Show the runs RUN_DIR... in 3D over time with Rerun: estimate and truth (aligned as the report aligns
    them), landmarks with their 3-sigma covariance ellipsoids (when the run has them), detections as rays,
    errors and biases as time series. Several runs go into one recording, each under its estimator's name.

    Needs rerun-sdk: pip install 'slamobs[view]'. Open the file with `rerun FILE.rrd`.
    """
    from slamobs.pipeline.viewer import view_runs

    path, runs = view_runs(list(run_dirs), out, spawn=spawn, force=force)
    if quiet:
        return
    for run in runs:
        for note in run.notes:
            click.echo(f"view: {note}", err=True)
    if path is not None:
        click.echo(
            f"wrote {path} ({plural(len(runs), 'run')}, {path.stat().st_size / 1e6:.2f} MB); open it with: rerun {path}"
        )
