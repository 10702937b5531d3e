"""``slamobs import``: public datasets converted to logs that every command reads (``import mrclam``)."""

from __future__ import annotations

from pathlib import Path

import click

from slamobs.cli.options import OutPath, quiet_option
from slamobs.cli.progress import Progress


@click.group("import")
def import_group() -> None:
    """Convert a public dataset to an MCAP log with its ground truth (see the subcommands)."""


@import_group.command("mrclam")
@click.argument("folder", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    "out",
    required=True,
    type=OutPath(path_type=Path),
    help="MCAP log to write; with --robot all a directory that gets robot1.mcap ... robot5.mcap.",
)
@click.option("--robot", default="1", show_default=True, help="Robot number 1-5, or 'all'.")
@click.option("--force", is_flag=True, help="Replace logs slamobs import wrote before.")
@quiet_option("Print nothing but errors.")
def mrclam(folder: Path, out: Path, robot: str, force: bool, quiet: bool) -> None:
    """Convert one robot of a UTIAS MR.CLAM dataset FOLDER (e.g. MRCLAM_Dataset6) to an MCAP log.

    The log has the odometry as body velocities (TwistStamped: v along x, omega about z), the range-bearing
    measurements of landmarks as body-frame points (FiducialTransformArray, ids = subject numbers), the Vicon
    poses as ground truth and the landmark survey as landmark truth: `slamobs run OUT.mcap -o RUN` needs no
    config. Measurements of other robots are dropped and counted.
    """
    from slamobs.pipeline.importers.mrclam import import_robot, read_dataset, robot_number

    try:
        number = robot_number(robot)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--robot") from None
    ds = read_dataset(folder)
    targets = [(number, out)] if number is not None else [(n, out / f"robot{n}.mcap") for n in ds.robots]
    with Progress(quiet) as progress:  # a status line on a terminal, a line now and then otherwise
        for n, path in targets:
            done = import_robot(ds, n, path, overwrite=force, progress=progress)
            if progress.status is not None:
                progress.status.clear()
            if not quiet:
                click.echo(done.line())
