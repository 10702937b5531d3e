"""``slamobs export RUN_DIR --mcap OUT.mcap``: a finished run's results in another format (today: MCAP)."""

from __future__ import annotations

from pathlib import Path

import click

from slamobs.cli.errors import exit_input_error
from slamobs.cli.options import Finite, OutPath, quiet_option

DEFAULT_RATE_HZ = 50.0  # pipeline.results_mcap.DEFAULT_RATE_HZ, literal so `slamobs --help` imports no numpy

_RATE = Finite(min=0.0)


@click.command("export")
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--out",
    "--mcap",
    "mcap_path",
    required=True,
    type=OutPath(path_type=Path, dir_okay=False),
    help="MCAP file to write: pose, TF, path, landmark map, biases and innovations as ROS 2 messages "
    "(--mcap, the older name, works too)",
)
@click.option(
    "--rate",
    "rate_hz",
    type=_RATE,
    default=DEFAULT_RATE_HZ,
    show_default=True,
    help="at most this many pose, TF and bias messages per second; 0: one per table row",
)
@click.option("--force", is_flag=True, help="replace an existing file")
@quiet_option()
def export(run_dir: Path, mcap_path: Path, rate_hz: float | None, force: bool, quiet: bool) -> None:
    """Write the results of the run directory RUN_DIR as an MCAP file to open beside the log in Foxglove."""
    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.results_mcap import write_results_mcap

    try:
        path = write_results_mcap(run_dir, mcap_path, rate_hz=rate_hz, force=force)
    except (InputError, ValueError) as err:
        exit_input_error(str(err))
    if not quiet:
        click.echo(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
