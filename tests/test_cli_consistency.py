"""One way to spell things across the commands: -o/--out, -q/--quiet, underscore aliases, --msg-dir, no
internal names in what a user reads, and the compile notice on stderr."""

from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner

from slamobs.cli.main import main

COMMANDS = ("run", "compare", "report", "evaluate", "export", "simulate", "batch", "tune", "info", "observers")
INTERNAL = re.compile(r"spec/|spec §|§|seed \d{3}|paper-[A-Z]|100 Hz set|shared/")


def invoke(*args, **kwargs):
    return CliRunner().invoke(main, [str(a) for a in args], **kwargs)


def help_text(command: str) -> str:
    res = invoke(command, "--help")
    assert res.exit_code == 0, res.output
    return res.output


def test_help_spells_options_one_way_and_names_nothing_internal():
    texts = {c: help_text(c) for c in COMMANDS}
    for c in ("run", "compare", "simulate", "batch", "tune"):
        assert "-o, --out" in texts[c], c
    for c in ("run", "compare", "report", "evaluate", "export", "simulate", "batch", "tune"):
        assert "-q, --quiet" in texts[c], c
    for c in ("run", "compare", "batch", "info"):
        assert "--msg-dir" in texts[c], c
    assert "--align-seconds, --align_seconds" in texts["evaluate"]
    everything = "\n".join(texts.values()) + invoke("--help").output + invoke("observers").output
    assert "--silent" not in everything and "--output" not in everything  # old spellings hidden
    assert not INTERNAL.findall(everything)
    assert "se3-aligned" not in everything.lower()


def test_every_two_word_option_takes_the_underscore_spelling(tmp_path):
    missing = tmp_path / "missing.mcap"
    (tmp_path / "msgs").mkdir()
    for args in (
        ("batch", "--wait_workers", "1", "--skip_failed", "--no_compact", missing, "-o", tmp_path / "b"),
        ("tune", missing, "--observer", "fast-adaptation", "-o", tmp_path / "t", "--wait_workers", "1"),
        ("run", missing, "-o", tmp_path / "r", "--msg_dir", tmp_path / "msgs"),
    ):
        res = invoke(*args)
        assert "No such option" not in res.output and "missing.mcap" in res.output, (args, res.output)


def test_old_spellings_still_work(tmp_path):
    out = tmp_path / "short.mcap"
    res = invoke("simulate", "circle", "--output", out, "--duration", "1", "--quiet")
    assert res.exit_code == 0 and res.output == "" and out.is_file()
    t = np.arange(50) * 0.1
    rows = np.column_stack([t, np.cos(t), np.sin(t), np.zeros((50, 4)), np.ones(50)])  # t x y z qx qy qz qw
    np.savetxt(tmp_path / "a.txt", rows, fmt="%.9f")
    np.savetxt(tmp_path / "b.txt", rows + [0, 1, 0, 0, 0, 0, 0, 0], fmt="%.9f")
    loud = invoke("evaluate", tmp_path / "a.txt", tmp_path / "b.txt", "-a", "--align_seconds", "2")
    assert loud.exit_code == 0 and "rmse" in loud.output
    for flag in ("--silent", "-q"):
        res = invoke("evaluate", tmp_path / "a.txt", tmp_path / "b.txt", "-a", flag)
        assert res.exit_code == 0 and res.output == ""


def test_batch_hands_msg_dir_to_the_runs(tmp_path, monkeypatch):
    import slamobs.pipeline.batch as batch

    seen = {}

    def fake_run_batch(entries, options, **kwargs):
        seen["msg_dir"] = options.config.msg_dir
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "run_batch", fake_run_batch)
    log = tmp_path / "a.mcap"
    log.write_bytes(b"")
    msgs = tmp_path / "msgs"
    msgs.mkdir()
    res = invoke("batch", log, "-o", tmp_path / "out", "--msg-dir", msgs)
    assert res.exit_code == 130 and seen["msg_dir"] == str(msgs.resolve())


def test_compile_notice_with_and_without_a_terminal(capsys):
    from numba import njit

    from slamobs.cli.progress import COMPILING, compile_notice

    def fresh():  # a kernel nobody has compiled: this process compiles it now
        @njit(cache=False)
        def twice(x):
            return 2.0 * x

        return twice

    with compile_notice():
        assert fresh()(2.0) == 4.0
    assert capsys.readouterr().err == f"{COMPILING} ...\n"  # stderr is no terminal here: one plain line

    class Line:
        def __init__(self):
            self.calls = []

        def compiling(self, seconds, active):
            self.calls.append((seconds, active))

    line = Line()
    with compile_notice(line):
        fresh()(1.0)
    assert line.calls and line.calls[0][1] is True and line.calls[-1][1] is False
    assert all(s >= 0 for s, _ in line.calls) and capsys.readouterr().err == ""
    with compile_notice(quiet=True):
        fresh()(1.0)
    with compile_notice():
        pass  # nothing compiled: nothing said
    assert capsys.readouterr().err == ""


def test_progress_lines_say_while_the_kernels_compile(capsys):
    """Without a terminal (a log file, CI) a first riekf run printed `[ 30.1 s] ... riekf: 0 of 11996 samples` every
    10 s for a minute and a half after one `compiling numeric kernels` line: a count stuck at 0 reads as a hang.
    Each progress line says so while numba compiles, and stops saying it when it is done."""
    from numba import njit

    from slamobs.cli.progress import COMPILING, Progress, compile_notice

    @njit(cache=False)
    def thrice(x):
        return 3.0 * x

    with Progress(every_s=0.0) as progress, compile_notice(progress.status, lines=progress):
        events = []
        original = progress.compiling

        def compiling(seconds, active=True):  # a progress line in the middle of the compile
            original(seconds, active)
            if active and not events:
                events.append(seconds)
                progress("riekf: 0 of 100 samples")

        progress.compiling = compiling
        assert thrice(2.0) == 6.0
        progress("riekf: 100 of 100 samples")
    err = capsys.readouterr().err.splitlines()
    during = next(line for line in err if "0 of 100" in line and "100 of 100" not in line)
    assert f"riekf: 0 of 100 samples | {COMPILING}: " in during
    after = next(line for line in err if "100 of 100" in line)
    assert COMPILING not in after


@pytest.mark.parametrize("kinds", ["tum,evo,mcap", "none"])
def test_export_option_parses_lists(kinds, tmp_path):
    res = invoke("run", tmp_path / "missing.mcap", "-o", tmp_path / "out", "--export", kinds)
    assert res.exit_code == 2 and "missing.mcap" in res.stderr  # parsed: the log is the problem
    res = invoke("run", tmp_path / "missing.mcap", "-o", tmp_path / "out", "--export", "tum,ply")
    assert res.exit_code == 2 and "ply" in res.output


BAD_NUMBERS = [  # each was a traceback (OverflowError, ValueError) or went through to a wrong result
    ("evaluate", "{a}", "{a}", "--t-max-diff", "inf"),
    ("evaluate", "{a}", "{a}", "--t-offset", "1e300"),
    ("evaluate", "{a}", "{a}", "--delta", "nan"),
    ("report", "{d}", "--t-offset", "nan"),
    ("report", "{d}", "--rpe-delta", "nan"),
    ("report", "{d}", "--drift-lengths", "5,nan"),
    ("simulate", "circle", "-o", "{d}/s.mcap", "--duration", "nan"),
    ("simulate", "circle", "-o", "{d}/s.mcap", "--imu-rpy", "inf", "0", "0"),
    ("simulate", "circle", "-o", "{d}/s.mcap", "--seed", "-1"),
    ("tune", "{a}", "--observer", "hashim", "-o", "{d}/t", "--seed", "-1"),
    ("export", "{d}", "--mcap", "{d}/x.mcap", "--rate", "nan"),
    ("batch", "{a}", "-o", "{d}/b", "--jobs", "0"),
    ("batch", "{a}", "-o", "{d}/b", "--msg-dir", "{d}/none"),  # was exit 1, the log recorded as failed
]


@pytest.mark.parametrize("args", BAD_NUMBERS, ids=lambda a: " ".join(a[:1] + a[-2:]))
def test_a_bad_option_value_is_one_line_and_nothing_is_written(tmp_path, args):
    """NaN, infinite, overflowing or negative option values: one ``error:`` line naming the option, exit 2 (click's
    own four lines of usage text included), and nothing written (tune left tune.journal for a bad seed)."""
    (tmp_path / "a.txt").write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n")
    res = CliRunner().invoke(main, [a.format(a=tmp_path / "a.txt", d=tmp_path) for a in args])
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    option = [a for a in args if a.startswith("--")][-1]
    assert option in lines[0] and "Usage:" not in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


@pytest.mark.parametrize(
    "args",
    [
        ("run", "{a}"),
        ("compare", "{a}", "--observers", "hashim"),
        ("batch", "{a}"),
        ("tune", "{a}", "--observer", "hashim"),
        ("stats", "{a}"),
        ("simulate", "circle"),
        ("export", "{d}"),
        ("import", "mrclam", "{d}"),
        ("view", "{d}"),
    ],
    ids=lambda a: a[0],
)
@pytest.mark.parametrize("empty", ["", " "])
def test_an_empty_output_path_is_a_usage_error(tmp_path, monkeypatch, args, empty):
    """``-o ""`` is ``.``: a batch wrote its dataset into the current directory, run named "." in its refusal."""
    (tmp_path / "a.mcap").write_bytes(b"")
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, [a.format(a=tmp_path / "a.mcap", d=tmp_path) for a in args] + ["-o", empty])
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2 and len(lines) == 1 and "'-o'" in lines[0] and "is empty" in lines[0], res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap"]
