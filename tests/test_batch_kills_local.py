"""Kill tests with real processes, local workers: the batch CLI and its worker processes killed while a log runs,
and a signal during the compaction's switch; then no process is left and a rerun gives a consistent dataset."""

from __future__ import annotations

import json
import os
import signal
import subprocess
from pathlib import Path

import pytest

from batch_checks import CLI, alive, assert_consistent, children, wait_for, wait_gone
from kill_checks import EXPECTED_EXIT, N_LOGS, batch_args, rerun_and_check, staged_logs, start_batch, started_logs
from kill_checks import logs  # noqa: F401 - fixtures


@pytest.mark.parametrize(
    "target,sig",
    [
        ("parent", signal.SIGKILL),
        ("parent", signal.SIGTERM),
        ("parent", signal.SIGINT),  # sent to the process group, as a terminal's Ctrl-C is
        ("worker", signal.SIGKILL),
    ],
    ids=["parent-SIGKILL", "parent-SIGTERM", "group-SIGINT", "worker-SIGKILL"],
)
def test_killed_batch_leaves_no_process_and_resumes_consistently(logs, tmp_path, target, sig):
    """The signal lands while a worker runs a log (its ``started.json`` is there), never after a guessed delay:
    the batch of 4 short logs is over in about a second, a sleep of a few seconds signalled a finished batch."""
    out = tmp_path / "OUT"
    proc, err = start_batch(batch_args(logs, out, "-j", 2), tmp_path, "batch")
    try:
        assert wait_for(lambda: started_logs(out) or proc.poll() is not None, 120, step=0.005), err.read_text()
        started = started_logs(out)
        assert started and proc.poll() is None, err.read_text()  # a log is running: the batch has not ended
        if target == "worker":
            victim = started[0]["pid"]
            assert victim in children(proc.pid)  # a worker of this batch, running a log
            os.kill(victim, sig)
            code = proc.wait(timeout=300)
            assert code == 0, err.read_text()  # the log of the killed worker was run again
            assert not alive(victim)
        else:
            os.killpg(proc.pid, sig) if sig == signal.SIGINT else os.kill(proc.pid, sig)
            code = proc.wait(timeout=120)
            assert code == EXPECTED_EXIT[sig], err.read_text()
            if sig != signal.SIGKILL:
                assert f"{signal.Signals(sig).name}: batch stopped" in err.read_text()
                assert "Traceback" not in err.read_text()
        assert wait_gone(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    rerun_and_check(logs, out)
    if target == "worker":
        _moved_logs_are_not_run_again(logs, out, tmp_path)


def _moved_logs_are_not_run_again(logs, out: Path, tmp_path: Path) -> None:
    base, cfg = logs
    before = assert_consistent(out)
    moved = tmp_path / "moved"
    moved.mkdir()
    for p in base.glob("*.mcap"):
        os.link(p, moved / p.name.replace("k", "flight_"))  # same content, new place and name
    done = subprocess.run(
        [*CLI, *map(str, ["batch", moved, "-o", out, "--config", cfg, "--json"])],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    events = [json.loads(x) for x in done.stdout.splitlines()]
    assert [e["status"] for e in events[:-1]] == ["skipped"] * N_LOGS
    assert set(assert_consistent(out)) == set(before)


def test_a_worker_killed_twice_under_one_log_fails_that_log_only_and_a_rerun_runs_it(logs, tmp_path):
    """SIGKILL of the worker running a log, then of the fresh worker running it again (an OOM killer that keeps
    choosing it): that log fails naming the signal, the others run, the batch exits 1 with a consistent dataset,
    and the same command runs the failed log (kill_matrix kills a worker once: its log runs again)."""
    out = tmp_path / "OUT"
    proc, err = start_batch(batch_args(logs, out, "-j", 1), tmp_path, "batch")
    killed: list[int] = []
    victim_staged = None
    try:
        for _ in range(2):
            assert wait_for(
                lambda: [s for s in staged_logs(out) if s[1] not in killed] or proc.poll() is not None, 180, step=0.005
            ), err.read_text()
            running = [s for s in staged_logs(out) if s[1] not in killed]
            assert running and proc.poll() is None, err.read_text()
            staged, pid = running[0]
            assert victim_staged in (None, staged)  # the same log again, in a fresh worker
            victim_staged = staged
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
        assert proc.wait(timeout=300) == 1, err.read_text()
        assert wait_gone(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    rows = assert_consistent(out)
    failed = [r for r in rows.values() if r["status"] != "ok"]
    assert len(rows) == N_LOGS and len(failed) == 1, rows
    assert "worker process died twice while running this log (killed by SIGKILL)" in failed[0]["error"]
    rerun_and_check(logs, out)


def test_a_signal_during_the_compaction_switch_is_raised_after_it(tmp_path, monkeypatch):
    """SIGHUP while the compaction's journal was applied (kill_matrix seed 47, trial 5: exit 129): the renames were
    made, the replaced per-run files not deleted, so the stopped batch left every row of a run twice until the
    next batch finished the journal. The signal (a real one, to this process) now waits for the switch."""
    from slamobs.pipeline import interrupts
    from slamobs.pipeline.batch import dataset
    from slamobs.pipeline.batch.compact import compact_dataset
    from test_batch_integrity import batch, make_logs

    make_logs(tmp_path / "in", ["a.mcap", "b.mcap", "c.mcap"])
    out = tmp_path / "OUT"
    batch([tmp_path / "in"], out, compact=False)
    real = dataset.remove_path

    def hangup_then_remove(p):
        if "compaction" not in str(p) and not getattr(hangup_then_remove, "sent", False):
            hangup_then_remove.sent = True
            signal.raise_signal(signal.SIGHUP)  # between the renames and the deletions
        real(p)

    monkeypatch.setattr(dataset, "remove_path", hangup_then_remove)
    # as a terminal's job has it: a suite started under nohup inherits SIGHUP ignored, which raise_when_safe keeps
    hangup = signal.signal(signal.SIGHUP, signal.SIG_DFL)
    try:
        with pytest.raises(interrupts.Interrupted), interrupts.raise_when_safe():
            compact_dataset(out)
    finally:
        signal.signal(signal.SIGHUP, hangup)
    assert hangup_then_remove.sent
    assert not (out / "_slamobs" / dataset.JOURNAL).exists()
    assert len(assert_consistent(out)) == 3
