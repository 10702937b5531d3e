"""What the CLI tests share: the sample logs the project ships, and running a command in this process."""

from __future__ import annotations

import re
from pathlib import Path

from click.testing import CliRunner

from slamobs.cli.main import main

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"


def invoke(*args, catch_exceptions: bool = False, **kwargs):
    """``slamobs ARGS...`` through click's runner; an unexpected exception fails the test unless caught."""
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=catch_exceptions, **kwargs)


#: A plain progress line (`cli.progress`: printed every 10 s by a command that takes longer, e.g. on a loaded VM)
PROGRESS_LINE = re.compile(r"^\[\s*\d+\.\d s\] ")


def message_lines(res) -> list[str]:
    """What a command printed (stdout and stderr), line by line, less its progress lines: a check for 'one error
    line' must not depend on how long the command took."""
    return [line for line in res.output.strip().splitlines() if not PROGRESS_LINE.match(line)]
