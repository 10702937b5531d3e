"""A first run's kernels compiled ahead in a helper process (pipeline/compile_ahead.py): the run then compiles
only its readers' kernels (and on a long log the alignment's), writes the same tables, compiles everything itself
when the helper is gone, and a killed run leaves no helper behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from batch_checks import CLI, alive, assert_compiles_none_of_the_helpers_kernels, children, first_run
from tests.cli_checks import SAMPLES

from slamobs.pipeline import compile_ahead

LOG = SAMPLES / "figure8.mcap"

PLANNED = {f"{m}.{n}" for m, n, _ in compile_ahead.plan("fast-adaptation")}


def _first_run(tmp, name: str, kill: bool = False, observer: str = "fast-adaptation") -> list[str]:
    """A run of the sample log with an empty kernel cache and the helper on; the functions it compiled."""
    return first_run([LOG, "-o", tmp / name, "-q", "--observer", observer], tmp / f"numba-{name}", kill)


@pytest.fixture(scope="module")
def first_runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ahead")
    return tmp, _first_run(tmp, "ahead"), _first_run(tmp, "alone", kill=True)


def test_with_the_helper_a_first_run_compiles_only_its_readers(first_runs):
    """The alignment's rotations are array code on a log this short (``lie.ROTATION_KERNEL_ROWS``); a long log's
    run compiles their kernel itself, as the helper does not take it (``compile_ahead.PLANS``)."""
    _, ahead, _ = first_runs
    ours = [f for f in ahead if f.startswith("slamobs.")]
    assert ours, "a first run compiles its readers' kernels itself"
    assert [f for f in ours if not f.startswith("slamobs.pipeline.readers.")] == []
    assert PLANNED.isdisjoint(ahead)


def test_a_first_batch_run_compiles_none_of_the_helpers_kernels(tmp_path):
    """riekf's first run: test_interrupts_compile.py, whose reference run is one (a first riekf compile each
    module pays once)."""
    compiled = _first_run(tmp_path, "batch", observer="batch")
    assert_compiles_none_of_the_helpers_kernels(compiled, "batch", "smoother.solver.factor", "observers.riekf._advance")


def test_without_its_helper_a_run_compiles_everything_and_writes_the_same_tables(first_runs):
    tmp, _, alone = first_runs
    assert PLANNED <= set(alone)  # the killed helper compiled nothing the run could use
    tables = sorted(p.name for p in (tmp / "ahead").glob("*.parquet"))
    assert "poses.parquet" in tables
    assert tables == sorted(p.name for p in (tmp / "alone").glob("*.parquet"))
    for name in tables:
        assert (tmp / "ahead" / name).read_bytes() == (tmp / "alone" / name).read_bytes(), name


def test_a_warm_run_starts_no_helper(first_runs, monkeypatch):
    tmp, _, _ = first_runs
    monkeypatch.setenv(compile_ahead.ENV, "1")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp / "numba-ahead"))
    code = (
        "from slamobs.pipeline import compile_ahead\n"
        "print(compile_ahead.missing(compile_ahead.plan('fast-adaptation')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ))
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_the_choice(monkeypatch):
    monkeypatch.delenv(compile_ahead.ENV, raising=False)
    assert compile_ahead.wanted(1) and not compile_ahead.wanted(0)
    assert compile_ahead.plan("hashim") == compile_ahead.PLANS["report"]


def _helper_of(run: subprocess.Popen, within: float = 30.0) -> int:
    """The pid of the run's compile helper, once it has started."""
    deadline = time.monotonic() + within
    while time.monotonic() < deadline and run.poll() is None:
        for pid in children(run.pid):
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as fh:
                    if b"compile_ahead" in fh.read():
                        return pid
            except OSError:
                continue
        time.sleep(0.05)
    raise AssertionError("the run started no compile helper")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_a_killed_run_leaves_no_helper(tmp_path, sig):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"), compile_ahead.ENV: "1"}
    run = subprocess.Popen(
        [*CLI, "run", str(LOG), "-o", str(tmp_path / "run"), "-q"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    helper = _helper_of(run)
    time.sleep(0.5)  # the helper is importing or compiling
    run.send_signal(sig)
    run.wait(timeout=120)
    expected = -sig if sig == signal.SIGKILL else 128 + sig
    assert run.returncode == expected, run.stderr.read()
    run.stderr.close()
    deadline = time.monotonic() + 5.0  # far less than its compilation would take
    while alive(helper):
        assert time.monotonic() < deadline, f"compile helper {helper} runs on after its run ended ({sig.name})"
        time.sleep(0.05)
    assert not (tmp_path / "run").exists()


def test_a_helper_that_cannot_start_leaves_the_run_to_compile(monkeypatch):
    """No process or descriptor to spare for the helper: no helper, no error (the run compiles in process)."""

    def no_process(*args, **kwargs):
        raise OSError(24, "Too many open files")

    monkeypatch.setenv(compile_ahead.ENV, "1")
    monkeypatch.setattr("slamobs.pipeline.kernel_cache.cached", lambda module, name: False)
    monkeypatch.setattr(compile_ahead.subprocess, "Popen", no_process)
    assert compile_ahead.start_early(1) is None
    assert compile_ahead.start("fast-adaptation", 1) is None
