"""Kill tests with a real Dask scheduler and real Dask workers (an external cluster): a lost scheduler, workers that
cannot run the batch or die during its environment check, results lost with the scheduler (the client a
stand-in where the race is one of milliseconds): exit 3 with one line, and a consistent dataset."""

from __future__ import annotations

import subprocess
import time
from contextlib import contextmanager

import pytest

from batch_checks import CLI, assert_consistent, wait_for, wait_gone
from slamobs.pipeline.batch.ledger import read_summary
from kill_checks import NO_SLAMOBS, batch_args, dask_worker, rerun_and_check, start_batch, started_logs, stop
from kill_checks import logs, scheduler  # noqa: F401 - fixtures


@contextmanager
def _batch_on_one_worker(logs, out, address: str, tmp_path):
    """A batch of ``logs`` into ``out`` on the scheduler at ``address`` with one worker (w1) of its own, which is
    stopped on leaving: the batch process and its stderr file."""
    worker = dask_worker(address, tmp_path, "w1")
    try:
        yield start_batch(batch_args(logs, out, "--scheduler", address, "--wait-workers", "30"), tmp_path, "batch")
    finally:
        stop(worker)


def test_dask_without_usable_workers_exits_3_with_one_line(logs, tmp_path, scheduler):
    _, address = scheduler
    args = [*CLI, *map(str, batch_args(logs, tmp_path / "OUT", "--scheduler", address))]
    done = subprocess.run([*args, "--wait-workers", "2"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 3 and done.stderr.strip().splitlines()[-1] == (
        f"error: {address}: no Dask workers after 2 s (--wait-workers)"
    )

    site = tmp_path / "no_slamobs"
    site.mkdir()
    (site / "sitecustomize.py").write_text(NO_SLAMOBS)
    worker = dask_worker(address, tmp_path, "bare", {"PYTHONPATH": str(site)})
    try:
        t0 = time.monotonic()
        done = subprocess.run(args, capture_output=True, text=True, timeout=60)  # never waits forever
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 3, done.stderr
        assert len(lines) == 1 and lines[0].startswith("error: Dask worker tcp://127.0.0.1:")
        assert "cannot import slamobs (ModuleNotFoundError: No module named 'slamobs')" in lines[0]
        assert time.monotonic() - t0 < 60
    finally:
        stop(worker)
    rows = assert_consistent(tmp_path / "OUT")
    assert rows == {}  # nothing was run, nothing recorded


def test_lost_dask_scheduler_exits_3_and_a_rerun_is_consistent(logs, tmp_path, scheduler):
    sched, address = scheduler
    out = tmp_path / "OUT"
    with _batch_on_one_worker(logs, out, address, tmp_path) as (proc, err):
        # a run recorded (its line may already be in summary.parquet: rewritten every second or so)
        assert wait_for(lambda: len(read_summary(out)) >= 1 or proc.poll() is not None, 180), err.read_text()
        sched.kill()
        code = proc.wait(timeout=120)
        assert code == 3, err.read_text()
        assert "lost the Dask scheduler" in err.read_text().strip().splitlines()[-1]
        assert wait_gone(proc.pid) == []
    rerun_and_check(logs, out)


def test_a_scheduler_killed_while_a_task_runs_leaves_nothing_staged(logs, tmp_path, scheduler):
    """The worker outlives the killed scheduler and its task goes on: its run's writer made the staging directory
    again after the batch had removed it (kill_matrix seed 35: two staged runs left after exit 3). The batch now
    removes what such tasks write until they have seen its lease gone and ended."""
    from slamobs.pipeline.batch.executor import LEASE_POLL_S

    sched, address = scheduler
    out = tmp_path / "OUT"
    with _batch_on_one_worker(logs, out, address, tmp_path) as (proc, err):
        assert wait_for(lambda: started_logs(out) or proc.poll() is not None, 180, step=0.01), err.read_text()
        sched.kill()
        assert proc.wait(timeout=120) == 3, err.read_text()
        time.sleep(LEASE_POLL_S + 3)  # the orphaned task has seen the lease gone and ended its worker process
        staged = sorted(str(p.relative_to(out)) for p in (out / "_slamobs" / "staging").rglob("*"))
        assert staged == [], staged
        assert_consistent(out)
    rerun_and_check(logs, out)


def test_a_scheduler_killed_before_the_batch_connects_is_exit_3_at_once_naming_it(logs, tmp_path, scheduler):
    """Nothing listens at the address any more: one line naming it, exit 3, without waiting out Dask's connect
    timeout (min(--wait-workers, 30) s: 25 s measured with --wait-workers 20)."""
    sched, address = scheduler
    sched.kill()
    sched.wait()
    t0 = time.monotonic()
    args = [*CLI, *map(str, batch_args(logs, tmp_path / "OUT", "--scheduler", address, "--wait-workers", "60"))]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert done.returncode == 3, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"error: {address}: cannot reach the Dask scheduler "
        "(connection refused for 3 s: is it running at this address?)"
    ]
    assert time.monotonic() - t0 < 30  # not Dask's connect timeout


def test_a_result_lost_with_the_scheduler_is_exit_3_not_a_failed_log(monkeypatch, tmp_path):
    """The scheduler lost between a task finishing and its result being fetched (the connection refused or closed
    while gathering: CI saw it once) is the lost scheduler, not an error line for the batch (exit 2)."""
    pytest.importorskip("distributed")
    from distributed import Future
    from distributed.comm.core import CommClosedError

    from slamobs.pipeline.batch.dask_exec import DaskPool
    from slamobs.pipeline.batch.executor import InfrastructureError, Task

    def closed(self, timeout=None):
        raise CommClosedError("in <TCP (closed) ConnectionPool.gather>: Stream is closed")

    task = Task.make("r0", str(tmp_path / "a.mcap"), str(tmp_path / "OUT"), {})
    pool = DaskPool(1, run=repr, wait_workers=30)
    try:
        monkeypatch.setattr(Future, "result", closed)
        with pytest.raises(InfrastructureError, match=r"lost the Dask scheduler \(CommClosedError: .*Stream is closed"):
            list(pool.results([task]))
    finally:
        pool.close()


def test_a_result_cancelled_with_the_lost_scheduler_is_exit_3_not_an_internal_error(monkeypatch, tmp_path):
    """The other side of the same race: the client, giving the lost scheduler up, cancels every future, so the
    fetch of a result already seen finished raises distributed's FutureCancelledError (a
    concurrent.futures.CancelledError, not asyncio's): it escaped the batch as an internal error."""
    pytest.importorskip("distributed")
    from distributed import Future
    from distributed.client import FutureCancelledError

    from slamobs.pipeline.batch.dask_exec import DaskPool
    from slamobs.pipeline.batch.executor import InfrastructureError, Task

    def cancelled(self, timeout=None):
        raise FutureCancelledError(self.key, "scheduler-connection-lost")

    task = Task.make("r0", str(tmp_path / "a.mcap"), str(tmp_path / "OUT"), {})
    pool = DaskPool(1, run=repr, wait_workers=30)
    try:
        monkeypatch.setattr(Future, "result", cancelled)
        with pytest.raises(
            InfrastructureError, match=r"lost the Dask scheduler \(FutureCancelledError: .*connection-lost"
        ):
            list(pool.results([task]))
    finally:
        pool.close()


def test_a_scheduler_lost_before_submitting_or_while_waiting_for_workers_is_exit_3(monkeypatch, tmp_path):
    """A tune's next round submitted after its client gave the lost scheduler up (ClosedClientError), and the
    scheduler lost while the batch waits for workers (the identity call's connection closed), are the lost
    scheduler (InfrastructureError, exit 3), not a traceback (exit 1) or an error line (exit 2)."""
    pytest.importorskip("distributed")
    import distributed
    from distributed.client import ClosedClientError
    from distributed.comm.core import CommClosedError

    from slamobs.pipeline.batch import dask_exec
    from slamobs.pipeline.batch.dask_exec import DaskPool
    from slamobs.pipeline.batch.executor import InfrastructureError, Task

    class Gone:
        status = "closed"

        def __init__(self, *args, **kwargs):
            pass

        def submit(self, *args, **kwargs):
            raise ClosedClientError("Client is closed. Can't send update-graph message.")

        def wait_for_workers(self, n, timeout=None):
            raise CommClosedError("in <TCP (closed) ConnectionPool.identity>: Stream is closed")

        def close(self, timeout=None):
            pass

    task = Task.make("r0", str(tmp_path / "a.mcap"), str(tmp_path / "OUT"), {})
    pool = DaskPool(1, scheduler="tcp://127.0.0.1:8786", run=repr)
    pool.client = Gone()
    with pytest.raises(InfrastructureError, match=r"lost the Dask scheduler \(ClosedClientError: Client is closed"):
        list(pool.results([task]))
    monkeypatch.setattr(distributed, "Client", Gone)
    monkeypatch.setattr(dask_exec, "_refused", lambda _address: False)  # nothing listens: the client is a stand-in
    with pytest.raises(InfrastructureError, match=r"lost the Dask scheduler \(CommClosedError: .*Stream is closed"):
        pool.connect()


def test_a_worker_that_dies_during_the_environment_check_is_left_out_unless_none_answered():
    """An external cluster's worker SIGKILLed while the batch asked every worker for its environment ended the batch:
    exit 3, "Dask worker tcp://...: cannot run the environment check (CommClosedError: ... Stream is closed)"
    (kill_matrix seed 75, trial 5). A worker whose connection closed is left out while another answered; all gone,
    or any other error, still stops the batch. (The client stands in for the cluster: the race is one of ms.)"""
    pytest.importorskip("distributed")
    from distributed.comm.core import CommClosedError

    from slamobs.pipeline.batch import dask_exec
    from slamobs.pipeline.batch.executor import InfrastructureError
    from slamobs.pipeline.batch.identity import code_hash
    from slamobs.pipeline.version import __version__

    ok = {"ok": True, "version": __version__, "code": code_hash(), "host": "h", "python": "p"}

    class Client:
        def __init__(self, answers):
            self.answers = answers

        def run(self, _function, on_error):
            return self.answers

    closed = CommClosedError("in <TCP (closed) Scheduler Broadcast>: Stream is closed")
    both = {"tcp://a:1": ok, "tcp://b:2": closed}
    assert dask_exec.check_workers(Client(both), "S", __version__, code_hash(), 10) == 1
    with pytest.raises(InfrastructureError, match="cannot run the environment check"):
        dask_exec.check_workers(Client({"tcp://b:2": closed}), "S", __version__, code_hash(), 10)
    with pytest.raises(InfrastructureError, match="cannot run the environment check"):
        dask_exec.check_workers(
            Client({"tcp://a:1": ok, "tcp://b:2": ValueError("x")}), "S", __version__, code_hash(), 10
        )
