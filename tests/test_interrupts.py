"""Real signals: Ctrl-C and SIGTERM stop a run whose observer would spin for a long time (an absurd detection,
an absurd gain), and a SIGKILL at any point of a ``--force`` replacement leaves the old or the new run.

How fast a run stops is measured by ``benchmarks/interrupt_latency.py`` (no timed assertions here; the
timeouts below only turn a hang into a failure).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from batch_checks import alive, descendants

from slamobs.pipeline import writers
from slamobs.pipeline.simulate import simulate, write_log

SLAMOBS = Path(sys.executable).with_name("slamobs")
HANG = 120.0  # seconds after which a process that has not stopped counts as hung


def _default_sigint() -> None:
    # as from a shell: a test process (a pytest-xdist worker) may ignore SIGINT, and an ignored SIGINT is
    # inherited through exec (Python then keeps it ignored, as a background job started by a script should)
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(log: Path, out: Path, cfg: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [str(SLAMOBS), "run", str(log), "-o", str(out), "--config", str(cfg), "-q", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_default_sigint,
    )


def _wait_for_observer(proc: subprocess.Popen, parent: Path, name: str) -> None:
    """Until the run writes its temporary output (the observer stage has begun)."""
    deadline = time.monotonic() + HANG
    while not any(p.name.startswith(f".{name}.tmp-") for p in parent.iterdir()):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run never reached the observer stage"
        time.sleep(0.02)


@pytest.fixture(scope="module")
def long_log(tmp_path_factory):
    sim = simulate("figure8", duration=20.0, seed=4, imu_rate=200.0)
    base = tmp_path_factory.mktemp("sig")
    det = sim.detections
    xyz = det.xyz.copy()
    first = det.ids[0]
    later = np.flatnonzero(det.ids == first)[1]  # the second sighting of the first landmark, early in the log
    xyz[later] = [1e9, 0.0, 0.0]
    return {
        "plain": write_log(sim, base / "plain.bag"),
        "far": write_log(replace(sim, detections=replace(det, xyz=xyz)), base / "far.bag"),
    }


@pytest.mark.parametrize(("case", "signum"), [("far", signal.SIGINT), ("stiff", signal.SIGTERM)])
def test_signal_stops_a_spinning_observer(long_log, tmp_path, case, signum):
    cfg = tmp_path / "run.yaml"
    if case == "far":  # a detection at 1e9 m with the range gate off
        log, text = long_log["far"], "limits:\n  max_range: null\n"
    else:  # a gain of 1e12
        log, text = long_log["plain"], "gains:\n  fast-adaptation: {k_w: 1.0e12}\n"
    cfg.write_text(text + "evaluation:\n  plots: false\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "run.json").write_text('{"earlier": true}')  # an earlier run that --force would replace
    proc = _start(log, out, cfg, "--force")
    _wait_for_observer(proc, tmp_path, "out")
    time.sleep(0.5)  # well inside the stiff part of the run
    proc.send_signal(signum)
    try:
        _, err = proc.communicate(timeout=HANG)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the run ignored the signal")
    assert proc.returncode == 128 + signum, err
    assert err.strip().splitlines() == [
        f"interrupted ({signal.Signals(signum).name}): stopped; nothing was written and an existing output is unchanged"
    ]
    assert json.loads((out / "run.json").read_text()) == {"earlier": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "run.yaml"]


# --------------------------------------------------------------------------- SIGKILL during a --force swap

FS_OPS = ("rename", "replace", "rmtree", "exchange", "touch")


def _killed_at(step: int, parent: Path, exchange: bool) -> bool:
    """Replace ``parent/out`` (old run) by a new one in a forked child that SIGKILLs itself at file system
    operation number ``step``; True if it was killed (False: it finished before that step)."""
    pid = os.fork()
    if pid == 0:  # the child: only file system calls, then a real SIGKILL
        try:
            count = [0]

            def counted(fn):
                def call(*a, **k):
                    count[0] += 1
                    if count[0] == step:
                        os.kill(os.getpid(), signal.SIGKILL)
                    return fn(*a, **k)

                return call

            os.rename, os.replace, shutil.rmtree = counted(os.rename), counted(os.replace), counted(shutil.rmtree)
            writers.exchange = counted(writers.exchange if exchange else lambda a, b: False)
            Path.touch = counted(Path.touch)
            with writers.atomic_directory(parent / "out", force=True) as tmp:
                (tmp / "run.json").write_text('"new"')
                (tmp / "poses.parquet").write_bytes(b"n" * 4096)
        finally:
            os._exit(0)
    _, status = os.waitpid(pid, 0)
    return os.WIFSIGNALED(status)


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2-exchange", "two-renames"])
def test_sigkill_at_any_point_of_a_force_swap_leaves_old_or_new(tmp_path, exchange):
    """After a SIGKILL at each file system operation of the swap, ``out`` holds the complete old or new run, and
    the next run on the same parent finishes the swap or cleans up (no hidden directory stays)."""
    if exchange and writers.RENAMEAT2 is None:
        pytest.skip("no renameat2 on this system")
    seen = set()
    for step in range(1, 30):
        parent = tmp_path / f"s{step}"
        (parent / "out").mkdir(parents=True)
        (parent / "out" / "run.json").write_text('"old"')
        (parent / "out" / "poses.parquet").write_bytes(b"o" * 4096)
        killed = _killed_at(step, parent, exchange)
        state = None
        if exchange:  # the name holds a complete run at every instant
            state = json.loads((parent / "out" / "run.json").read_text())
            assert state in ("old", "new") and (parent / "out" / "poses.parquet").stat().st_size == 4096, step
        writers.remove_stale_temporaries(parent)  # what the next run on this parent does first
        assert sorted(p.name for p in parent.iterdir()) == ["out"], (step, list(parent.iterdir()))
        final = json.loads((parent / "out" / "run.json").read_text())
        assert final in ("old", "new") and (parent / "out" / "poses.parquet").stat().st_size == 4096, step
        assert state in (None, final), (step, state, final)
        seen.add(final)
        if not killed:
            assert final == "new"
            break
    else:
        pytest.fail("the swap never completed")
    assert seen == {"old", "new"}


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_after_the_command_ends_the_process_with_its_code(sig):
    """Once a command is done (outputs complete), a SIGTERM or SIGINT during the exit gives 143/130 at once: left at
    the default, a batch stopped just as it finished was killed by the signal (-15) and a SIGINT printed a
    traceback from the interpreter's teardown."""
    code = (
        "import os, signal, time\n"
        "from slamobs.cli import errors\n"
        "errors.end_signals_at_once()\n"
        f"os.kill(os.getpid(), {int(sig)})\n"
        "time.sleep(30)\n"
    )
    # as from a shell: a job started in the background (CI under nohup) inherits SIGINT ignored, and keeps it so
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, preexec_fn=_default_sigint
    )
    assert proc.returncode == 128 + int(sig) and "Traceback" not in proc.stderr


def _busy_in(module: str):
    """A function that signals this process and then keeps running for 0.2 s as code of ``module``."""
    ns = {"__name__": module}
    exec(
        "import os, signal, time\n"
        "def busy():\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    t = time.monotonic()\n"
        "    while time.monotonic() - t < 0.2:\n"
        "        pass\n"
        "    return 'finished'\n",
        ns,
    )
    return ns["busy"]


@pytest.mark.parametrize("module", ["numba.core.fake", "llvmlite.binding.fake", "threading", "queue"])
def test_a_signal_inside_library_locks_is_raised_after_them(module):
    """A SIGTERM that arrives inside numba's compiler, llvmlite, a thread start or a queue is raised once the
    main thread is back in other code: unwinding through them left a lock held (a SIGTERM while a cached kernel
    loaded hung a run forever) or a thread running."""
    from slamobs.pipeline.interrupts import Interrupted, raise_when_safe

    reached = []
    with pytest.raises(Interrupted) as info, raise_when_safe():
        reached.append(_busy_in(module)())
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:  # the retry raises here
            time.sleep(0.005)
    assert reached == ["finished"] and info.value.signum == signal.SIGTERM


def test_a_signal_in_our_code_is_raised_at_once():
    from slamobs.pipeline.interrupts import Interrupted, raise_when_safe

    reached = []
    with pytest.raises(Interrupted), raise_when_safe():
        _busy_in(__name__)()
        reached.append("after")
    assert reached == []


def test_a_dropped_signal_still_stops_the_output(tmp_path):
    """Python prints and drops an exception raised inside a finalizer: the pending request still keeps the
    output from being published."""
    from slamobs.pipeline import interrupts

    with interrupts.raise_when_safe():
        interrupts.requested = signal.SIGTERM  # as the handler records it
        with pytest.raises(interrupts.Interrupted):
            with writers.atomic_directory(tmp_path / "out") as tmp:
                (tmp / "poses.parquet").write_bytes(b"x")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    assert interrupts.requested is None  # nothing pending after the block


def test_an_error_raised_by_the_signals_unwinding_is_the_interruption(tmp_path, monkeypatch):
    """A signal inside a compiled call comes back as a SystemError, and a writer closed half way raises its own
    error: such an error exits 143 'interrupted', not 2 'error' or a traceback, and no report note is made of it."""
    from click.testing import CliRunner

    from slamobs.cli import main as cli_main
    from slamobs.pipeline import run as run_mod
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.interrupts import Interrupted

    def compiled_call(*_a, **_k):
        try:
            raise Interrupted(signal.SIGTERM)
        except KeyboardInterrupt as err:
            raise SystemError("CPUDispatcher(<function f>) returned a result with an exception set") from err

    sim = simulate("figure8", duration=6.0, seed=2)
    log = write_log(sim, tmp_path / "short.mcap")
    monkeypatch.setattr("slamobs.pipeline.evaluation.evaluate_tables", compiled_call)
    with pytest.raises(KeyboardInterrupt):  # not a run without its report
        run_mod.run_log(log, tmp_path / "api", load_config(None))
    assert not (tmp_path / "api").exists()
    result = CliRunner().invoke(cli_main.main, ["run", str(log), "-o", str(tmp_path / "cli"), "-q"])
    assert result.exit_code == 143, result.output
    assert "interrupted (SIGTERM)" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "cli").exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigterm_at_any_moment_of_a_run_stops_it_cleanly(tmp_path):
    """SIGTERM at moments spread over a whole run (imports, reading, kernels loading, observer, writer thread,
    report, figure helpers): every run ends 143 with one 'interrupted' line and nothing under the output name
    (or, signalled once the output was published, its complete output and a line saying so), or had finished (0,
    complete output); none hangs, crashes or leaves a process. Before the safe-point
    handler such sweeps gave a run hung forever, a segmentation fault, a SystemError traceback, exit 2 'cannot
    write the output' and a SIGTERM swallowed with exit 0."""
    sim = simulate("figure8", duration=40.0, seed=5)
    log = write_log(sim, tmp_path / "sweep.mcap")
    cfg = tmp_path / "run.yaml"
    cfg.write_text("{}\n")
    started = time.monotonic()
    first = _start(log, tmp_path / "whole", cfg)
    assert first.wait(timeout=HANG) == 0, first.communicate()
    whole = time.monotonic() - started
    outcomes = []
    for k in range(14):
        out = tmp_path / f"out{k}"
        proc = _start(log, out, cfg)
        time.sleep(whole * (0.15 + 0.07 * k))
        helpers = descendants(proc.pid)
        proc.send_signal(signal.SIGTERM)
        try:
            _, err = proc.communicate(timeout=HANG)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"run {k} hung after SIGTERM")
        outcomes.append(proc.returncode)
        if proc.returncode == 0:
            assert (out / "report.json").is_file()
        else:
            assert proc.returncode == 143, err
            last = err.strip().splitlines()[-1]
            assert last.startswith("interrupted (SIGTERM)"), err
            if out.exists():  # the signal came after the output was published (while the summary printed)
                assert last.startswith("interrupted (SIGTERM) after the output was complete"), err
                assert (out / "report.json").is_file()
        deadline = time.monotonic() + 5.0
        while (left := [p for p in helpers if alive(p)]) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not left, f"run {k}: processes {left} outlived it"
    assert 143 in outcomes
    assert not [p for p in tmp_path.iterdir() if ".tmp-" in p.name]


def test_a_signal_still_pending_when_the_command_ends_is_raised():
    """A signal that came while the command's last steps ran in unsafe code was dropped with the block (evaluate
    exited 0 after a SIGTERM): it is raised when the block ends."""
    from slamobs.pipeline.interrupts import Interrupted, raise_when_safe

    with pytest.raises(Interrupted), raise_when_safe():
        _busy_in("numba.core.fake")()  # the retry timer always finds it in unsafe code


def test_a_command_with_its_own_handlers_takes_over_a_pending_signal():
    """batch and tune install their own handlers: a signal that arrived before is handed to them, and the
    shared retry raises nothing of its own any more (it did: batch reported SIGINT/130 for a SIGTERM)."""
    from slamobs.pipeline import interrupts

    caught = []
    with interrupts.raise_when_safe():
        _busy_in("numba.core.fake")()
        old = signal.signal(signal.SIGTERM, lambda *_: caught.append("own"))
        try:
            assert interrupts.take_pending() == signal.SIGTERM
            time.sleep(5 * interrupts.RETRY_S)  # a retry would raise here
            assert interrupts.take_pending() is None
        finally:
            signal.signal(signal.SIGTERM, old)


def test_an_ignored_sigint_stays_ignored():
    """A background job inherits SIGINT ignored; the command must not start answering it."""
    from slamobs.pipeline.interrupts import raise_when_safe

    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with raise_when_safe():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, old)


def test_no_gap_between_the_commands_handlers_and_the_end_handlers():
    """The console entry installs the end handlers before the command: when the command's handlers are put back,
    a SIGTERM still ends with 143 (in that moment it killed the process by the signal, -15)."""
    from slamobs.cli import errors
    from slamobs.pipeline.interrupts import raise_when_safe

    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        errors.end_signals_at_once()
        with raise_when_safe():
            pass
        assert signal.getsignal(signal.SIGTERM) is errors.end_by_signal
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def test_the_message_after_a_complete_output_says_so(capsys, tmp_path):
    """It names the outputs published that are still there; one published inside a temporary output the
    interruption removed (a compare's runs) is not "complete": then nothing was written."""
    from slamobs.cli import errors
    from slamobs.pipeline import interrupts

    run1 = tmp_path / "run1"
    run1.mkdir()
    for published, said in (
        ([str(run1), str(tmp_path / "gone")], f"interrupted (SIGTERM) after the output was complete: {run1}"),
        ([str(tmp_path / ".cmp.tmp-x" / "run" / "fast-adaptation")], "interrupted (SIGTERM): stopped; nothing was"),
    ):
        interrupts.published[:] = published
        try:
            with pytest.raises(SystemExit) as done:
                errors.exit_interrupted(interrupts.Interrupted(signal.SIGTERM))
        finally:
            interrupts.published.clear()
        assert done.value.code == 143
        assert capsys.readouterr().err.strip().startswith(said)


def test_an_interrupted_run_does_not_wait_for_riekfs_time_offset_thread(tmp_path):
    """riekf estimates the time offset on a thread of its own while its filter starts (``time_offset.Background``):
    a run interrupted meanwhile (the CLI's handler unwinds it to an exit) ends at once, the thread with it (a
    daemon: it writes nothing), however long the estimate still has to go (here: blocked for an hour)."""
    script = tmp_path / "stop.py"
    script.write_text(
        "import os, sys, time\n"
        "from slamobs.pipeline.observers import time_offset\n"
        "time_offset.estimate = lambda stream, decided=None: time.sleep(3600)\n"
        "job = time_offset.Background(None)\n"
        "assert job._thread is not None and job._thread.is_alive() and job._thread.daemon\n"
        "sys.exit(143)\n"
    )
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("one core: the estimate runs in the caller's thread")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=HANG)
    assert proc.returncode == 143, proc.stderr


def test_a_signal_while_a_batch_commits_waits_for_the_commit_with_other_threads_running():
    """``signals_deferred`` blocked the signals for the main thread only: with another thread running (Dask's
    client loop, any helper thread), the kernel hands the signal to that thread and Python runs the handler in
    the main thread all the same, inside the commit. A batch on a Dask cluster stopped by SIGINT then left its
    dataset inconsistent (benchmarks/kill_matrix.py --dask-cluster, seed 15)."""
    import threading

    from slamobs.cli.jobs import Stopped, on_signal
    from slamobs.pipeline.batch.dataset import signals_deferred

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    done = threading.Event()
    other = threading.Thread(target=done.wait, daemon=True)  # started before the block: signals not blocked
    other.start()
    steps = []
    try:
        with pytest.raises(Stopped):
            with signals_deferred():
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(200):  # the handler would run here, at a bytecode boundary
                    time.sleep(0.005)
                steps.append("committed")
            steps.append("after the block")
    finally:
        done.set()
        for sig, old in previous.items():
            signal.signal(sig, old)
    assert steps == ["committed"]
