"""A signal while a first riekf run compiles its event loop: numba's compiler holds the main thread for ~25 s of CPU
in one piece (one LLVM call alone runs several seconds without a Python handler), and the run used to end only
when it returned. Now the run's watching thread ends it within a second or so (``interrupts._end_in_compiler``):
exit 128 + n, one line, no output or temporary, no process of its session left, and the kernel cache it leaves
gives the next run the outputs of a run whose cache nobody killed.

"Compiling" is observed, not guessed from a delay: with ``NUMBA_DEBUG_CACHE`` numba prints each kernel it saves,
and riekf's event loop compiles its callees (kernels of their own, saved one by one) before itself, so the first
saved riekf kernel means the loop's compilation is under way (its own index appears only at its end: the test
checks it is absent after the kill). The time bound only turns a hang into a failure (the old ~25 s wait).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from batch_checks import CLI, alive, assert_compiles_none_of_the_helpers_kernels, descendants, first_run

from slamobs.pipeline.simulate import simulate, write_log

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

#: a first run, or a killed one, not done after this long counts as hung: a bound for a hang only. 300 s was crossed by
#: the cold riekf run after the kill (it compiles the rest) at load 16-20 on 2 cores, both parametrizations (session 30)
HANG = 1200.0
STOPS_WITHIN_S = 10.0  # a stop this much after the signal is no hang (the old wait was the whole compilation)


#: A process in numba's compiler for a minute (a frame of a ``numba`` module in a call that runs no Python, as LLVM's
#: optimisation), with a temporary directory registered for removal and a child process, when SIGTERM arrives.
IN_COMPILER = r"""
import os, signal, subprocess, sys
from pathlib import Path
from slamobs.pipeline import interrupts
temp = Path(sys.argv[1])
temp.mkdir()
sleep = [sys.executable, "-c", "import time; time.sleep(600)"]
child = subprocess.Popen(sleep, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
print(child.pid, flush=True)
ns = {"__name__": "numba.core.fake"}
exec(
    "import os, signal, time\n"
    "def optimise():\n"
    "    print(time.monotonic(), flush=True)\n"  # when the signal is sent, on the machine's monotonic clock
    "    os.kill(os.getpid(), signal.SIGTERM)\n"
    "    time.sleep(60)\n",
    ns,
)
with interrupts.raise_when_safe(lambda signum: f"stopped by {signum}\n"), interrupts.undone_at_end(temp.rmdir):
    ns["optimise"]()
print("the compiler returned", flush=True)
"""


def test_a_process_in_the_compiler_ends_from_the_watching_thread(tmp_path):
    """Its children killed, its temporaries removed, the farewell line printed, exit 143: within seconds of the
    signal (counted from the signal, not from the start: a loaded machine's start-up and imports took seconds)."""
    done = subprocess.run(
        [sys.executable, "-c", IN_COMPILER, str(tmp_path / "temp")], capture_output=True, text=True, timeout=HANG
    )
    ended = time.monotonic()
    assert done.returncode == 143, done.stderr
    assert done.stderr == "stopped by 15\n"
    child, sent = int(done.stdout.split()[0]), float(done.stdout.split()[1])
    assert ended - sent < STOPS_WITHIN_S  # the compiler's 60 s not waited out
    assert "returned" not in done.stdout and not alive(child)
    assert not (tmp_path / "temp").exists()


def _default_sigint() -> None:  # as from a shell (a pytest-xdist worker may ignore SIGINT)
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A short generated log, a config without figures, the tables of a run with a kernel cache of its own, empty
    at its start, and the functions that run compiled: riekf's kernels compiled as a first run (with the compile
    helper) compiles them. (Not the session's cache, which other tests filled in other orders: riekf's outputs from
    kernels compiled in another context differ in the last bits of the run metadata's floats, e.g. final_bias_sigma
    at 6e-15 relative, the written columns' 28-bit values equal.)"""
    base = tmp_path_factory.mktemp("compile-sig")
    log = write_log(simulate("figure8", duration=12.0, seed=6), base / "short.mcap")
    cfg = base / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    ref = base / "ref"
    compiled = first_run([log, "-o", ref, "-q", "--observer", "riekf", "--config", cfg], base / "numba-ref")
    return log, cfg, ref, compiled


def test_a_first_riekf_run_compiles_none_of_the_helpers_kernels(inputs):
    """test_compile_ahead.py's check for riekf, on the reference run (one first riekf compile, not two)."""
    compiled = inputs[3]
    assert_compiles_none_of_the_helpers_kernels(
        compiled, "riekf", "observers.riekf._advance", "observers.time_offset._trimmed_costs"
    )


def _run(inputs, out: Path, env: dict, **kw) -> subprocess.Popen:
    log, cfg, _, _ = inputs
    argv = [*CLI, "run", str(log), "-o", str(out), "-q", "--observer", "riekf", "--config", str(cfg)]
    return subprocess.Popen(argv, env=env, **kw)


@pytest.mark.parametrize(("sig", "ahead"), [(signal.SIGTERM, "1"), (signal.SIGINT, "0")], ids=["TERM-ahead", "INT"])
def test_a_signal_while_riekfs_event_loop_compiles_ends_the_run_at_once(inputs, tmp_path, sig, ahead):
    cache = tmp_path / "numba"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "SLAMOBS_COMPILE_AHEAD": ahead}
    out = tmp_path / "out"
    run = _run(
        inputs,
        out,
        {**env, "NUMBA_DEBUG_CACHE": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        process_group=0,  # its own group (a Ctrl-C's), in this session
        preexec_fn=_default_sigint,
    )
    for line in run.stdout:
        if b"index saved to" in line and b"observers/riekf." in line:  # the event loop's callees are compiling
            break
    else:
        pytest.fail(f"the run ended before riekf compiled: {run.wait()} {run.stderr.read()[-300:]!r}")
    helpers = descendants(run.pid)  # the compile helper, when on
    sent = time.monotonic()
    if sig == signal.SIGINT:
        os.killpg(run.pid, sig)  # Ctrl-C: the whole process group, compile helper included
    else:
        run.send_signal(sig)
    try:
        _, err = run.communicate(timeout=HANG)
    except subprocess.TimeoutExpired:
        os.killpg(run.pid, signal.SIGKILL)
        pytest.fail("the run hung after the signal")
    took = time.monotonic() - sent
    assert run.returncode == 128 + sig, err
    assert err.decode().strip().splitlines()[-1] == (
        f"interrupted ({sig.name}): stopped; nothing was written and an existing output is unchanged"
    )
    assert took < STOPS_WITHIN_S, f"ended {took:.1f} s after {sig.name}: it waited for the compiler"
    assert not [p for p in helpers if alive(p)], "a child process outlived the run"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["numba"]  # no output, no temporary
    assert not list(cache.rglob("riekf._advance-*.nbi")), "the signal came after the event loop had compiled"
    # the cache as the killed run left it: the next run compiles the rest and writes the same tables
    again = _run(inputs, out, env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, err = again.communicate(timeout=HANG)
    assert again.returncode == 0, err
    ref = inputs[2]
    tables = sorted(p.name for p in ref.glob("*.parquet"))
    assert "poses.parquet" in tables and tables == sorted(p.name for p in out.glob("*.parquet"))
    for name in tables:
        assert (out / name).read_bytes() == (ref / name).read_bytes(), name
