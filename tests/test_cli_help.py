"""Help texts say what an option takes: no ``[x<=None]`` for an unbounded number, and every default shown as one
of the choices the help lists (``trans-part``, not ``trans_part``), for every command."""

from __future__ import annotations

import re

import click
import pytest

from cli_checks import invoke
from slamobs.cli.main import main


def _commands(group: click.Group, prefix: tuple[str, ...] = ()):
    for name, cmd in sorted(group.commands.items()):
        yield (*prefix, name), cmd
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, (*prefix, name))


COMMANDS = list(_commands(main))


@pytest.mark.parametrize("path, cmd", COMMANDS, ids=[" ".join(p) for p, _ in COMMANDS])
def test_help_shows_ranges_and_defaults_as_they_are_typed(path, cmd):
    res = invoke(*path, "--help")
    assert res.exit_code == 0, res.output
    assert "None]" not in " ".join(res.output.split())
    parent = click.Context(main, info_name="slamobs", **main.context_settings)  # dashes for underscores, as run
    ctx = click.Context(cmd, info_name=path[-1], parent=parent)
    checked = 0
    for param in cmd.params:
        record = param.get_help_record(ctx) if isinstance(param, click.Option) else None
        if record is None or not isinstance(param.type, click.Choice):
            continue
        choices = re.search(r"\[([^\]]+)\]", record[0])
        default = re.search(r"\[default: ([^;\]]+)", record[1])
        if choices and default and "|" in choices.group(1):
            assert default.group(1) in choices.group(1).split("|"), (path, record)
            checked += 1
    if path == ("evaluate",):
        assert checked >= 3  # --metric, --pose-relation, --sync-method at least: the check must see them


#: the commands that write a file or directory of their own (report and evaluate write beside their inputs)
WRITERS = ("run", "compare", "simulate", "export", "batch", "tune")


@pytest.mark.parametrize("name", WRITERS)
def test_every_command_that_writes_takes_o_and_out(name):
    cmd = main.commands[name]
    commands = [cmd, *getattr(cmd, "commands", {}).values()]  # a group (batch): the subcommand that writes
    assert any({"-o", "--out"} <= {o for p in c.params for o in getattr(p, "opts", [])} for c in commands), name


def test_export_takes_o_and_still_mcap(tmp_path):
    for flag in ("-o", "--mcap"):
        res = invoke("export", tmp_path / "no-run", flag, tmp_path / "x.mcap")
        assert res.exit_code == 2 and "not a run directory" in res.stderr and "No such option" not in res.output


def test_python_dash_m_runs_the_command():
    """``python -m slamobs.cli.main`` is the same command as ``slamobs`` (it printed nothing and exited 0)."""
    import subprocess
    import sys

    res = subprocess.run(
        [sys.executable, "-m", "slamobs.cli.main", "observers"], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr
    assert "riekf" in res.stdout and "batch" in res.stdout
    bad = subprocess.run([sys.executable, "-m", "slamobs.cli.main", "no-such-command"], capture_output=True, text=True)
    assert bad.returncode == 2 and "no-such-command" in bad.stderr


def test_report_and_batch_help_say_what_their_defaults_and_exit_codes_are():
    """Round 21 read the help as a stranger: `report --help` gave `association tolerance [s] (0.01)`, `(0.1)`, ...
    where a re-report keeps the run's report's options (`report --t-max-diff 0.05`, then `report`: 0.05), numbers
    written a second time beside the report's own defaults; `batch --help` said exit 0 is "every log ok or
    skipped" where a finished run off by its estimator's own status (likely_lost, ...) exits 0 too."""
    text = " ".join(invoke("report", "--help").output.split())
    assert "keep what the run's report used: its report.json options lists them" in text, text
    assert not [d for d in ("(0.01)", "(0.1)", "(1)", "(0.2)", "(se3;") if d in text], text
    text = " ".join(invoke("batch", "--help").output.split())
    assert "0 every log finished (ok, or off by its estimator's own status: likely_lost, lost, gated_at_end)" in text
