"""How every command reports bad input: one line ``error: FILE [TOPIC]: problem`` on stderr, exit code 2."""

from __future__ import annotations

import sys
from typing import NoReturn

import click

#: Exit code of bad input (missing or unreadable file, bad config); 1 is left to partial failures (batch).
INPUT_ERROR_EXIT = 2


def exit_input_error(err: Exception | str) -> NoReturn:
    click.echo(f"error: {err}", err=True)
    sys.exit(INPUT_ERROR_EXIT)
