"""``slamobs info LOG``: containers, topics, types, counts, rates, time span and detected roles."""

from __future__ import annotations

import json
from pathlib import Path

import click

from slamobs.cli.errors import handled


@click.command("info")
@click.argument("logs", nargs=-1, required=True, metavar="LOG...", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.option(
    "--msg-dir",
    type=click.Path(path_type=Path),
    default=None,
    help="Directory of pkg/msg/Type.msg files for message types whose definitions the log lacks.",
)
def info(logs: tuple[Path, ...], *, as_json: bool, msg_dir: Path | None) -> None:
    """Summarise LOG (ROS1 .bag, rosbag2 directory, .mcap or .db3) and the roles its topics would play.

    A ROS1 recording split into NAME_0.bag, NAME_1.bag, ... is one LOG: its directory, or all its parts.
    """
    from slamobs.pipeline.readers import format_info, inspect_log
    from slamobs.pipeline.readers.container import recording_of

    with handled():  # as under the `slamobs` group, also when the command is used on its own
        summary = inspect_log(recording_of(logs), msg_dir=msg_dir)
    click.echo(json.dumps(summary.to_dict(), indent=2) if as_json else format_info(summary))
