"""What the CLI tests share: the sample logs the project ships, and running a command in this process."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from slamobs.cli.main import main

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"


def invoke(*args, catch_exceptions: bool = False, **kwargs):
    """``slamobs ARGS...`` through click's runner; an unexpected exception fails the test unless caught."""
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=catch_exceptions, **kwargs)
