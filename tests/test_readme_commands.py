"""The README's promises: every `slamobs` command line it shows names a command that exists and only options that
command takes, and its worked example (a corners bag -> info -> run with the shipped config -> compare) runs and
writes what the README says it writes."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import click
import pytest

from cli_checks import invoke
from slamobs.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
#: `slamobs ...` as a line of a shell block or inside a table cell's backticks
SHELL_LINE = re.compile(r"^(?:\.venv/bin/)?slamobs (.+?)(?:\s+#.*)?$", re.M)
CELL = re.compile(r"`slamobs ([^`]+)`")


def _command_lines() -> list[str]:
    lines = []
    for block in re.findall(r"```sh\n(.*?)```", README, re.S):
        block = block.replace("\\\n", " ")
        lines += [m.group(1) for m in SHELL_LINE.finditer(block)]
    lines += [m.group(1).replace("\\|", "|") for m in CELL.finditer(README)]
    return lines


def _options(words: list[str]) -> list[str]:
    """The option names of a README line: `-o`, `--observer`, also inside `[...]` and `a|b` alternatives."""
    found = []
    for word in words:
        for part in re.split(r"[\[\]|]", word):
            if re.fullmatch(r"--?[A-Za-z][\w-]*", part):
                found.append(part)
    return found


def _names(command: click.Command) -> set[str]:
    return {name for p in command.params for name in (*p.opts, *p.secondary_opts)} | {"-h", "--help"}


LINES = _command_lines()


def test_the_readme_shows_every_command():
    shown = {shlex.split(line)[0] for line in LINES}
    assert set(main.commands) <= shown, f"commands the README does not show: {sorted(set(main.commands) - shown)}"


@pytest.mark.parametrize("line", LINES)
def test_each_readme_command_line_parses(line):
    words = shlex.split(line)
    command = main.commands.get(words[0])
    assert command is not None, f"README shows `slamobs {words[0]}`, which does not exist"
    if isinstance(command, click.Group):  # a subcommand, else the one the group implies (`batch INPUTS` = `batch run`)
        sub = words[1] if len(words) > 1 and words[1] in command.commands else "run"
        command, words = command.commands[sub], words[1:] if sub == words[1] else words
    unknown = [o for o in _options(words[1:]) if o not in _names(command)]
    assert not unknown, f"`slamobs {line}`: {words[0]} takes no {unknown}"


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    """The worked example, shortened to 20 s of log."""
    d = tmp_path_factory.mktemp("readme")
    invoke("simulate", "figure8", "--camera", "corners", "--duration", 20, "-o", d / "figure8_corners.bag")
    return d


def test_worked_example_info_names_the_roles(example):
    out = invoke("info", example / "figure8_corners.bag").output
    for role in ("angular_velocity", "linear_velocity", "detections", "camera_info", "truth"):
        assert role in out


def test_worked_example_runs_with_the_shipped_config(example):
    run = example / "figure8_run"
    result = invoke("run", example / "figure8_corners.bag", "-o", run, "--config", ROOT / "examples" / "corners.yaml")
    assert result.exit_code == 0, result.output
    for name in ("poses.parquet", "landmarks.parquet", "biases.parquet", "run.json", "report.md", "trajectory_top.png"):
        assert (run / name).stat().st_size > 0, name
    meta = json.loads((run / "run.json").read_text())
    assert meta["counts"]["landmarks"] >= 10
    report = json.loads((run / "report.json").read_text())
    assert report["ape"]["translation_m"]["rmse"] < 1.0  # metres on a 20 s figure 8 whose tags span ~20 m


def test_worked_example_compare_runs(example):
    out = example / "figure8_cmp"
    config = ROOT / "examples" / "corners.yaml"
    result = invoke("compare", example / "figure8_corners.bag", "-o", out, "--config", config, "--observers",
                    "fast-adaptation,hashim")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (out / "comparison.md").stat().st_size > 0
