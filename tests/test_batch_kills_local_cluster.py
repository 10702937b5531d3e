"""Kill tests on a local Dask cluster (``--executor dask``): its worker processes killed under a log or as the cluster
starts, the batch stopped while the cluster starts, runs or closes: one line, no process left, a consistent
dataset."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest

from batch_checks import CLI, alive, assert_consistent, wait_for, wait_gone
from slamobs.pipeline.batch.dask_exec import TRACKER_WARNINGS
from slamobs.pipeline.batch.executor import STARTED
from kill_checks import (
    N_LOGS,
    batch_args,
    batch_with_its_cluster_starting,
    blocked_signals,
    resource_trackers,
    spawned_workers,
    staged_logs,
    start_batch,
    started_logs,
)
from kill_checks import logs, six_logs  # noqa: F401 - fixtures


def test_a_stopped_batch_kills_its_local_clusters_running_logs_instead_of_waiting_for_them(tmp_path):
    """A signal stops a batch on a local Dask cluster with logs running: their worker processes are killed, as
    local workers are, not closed gracefully (each waited for its running log: exit 11 s after a SIGTERM in
    benchmarks/kill_matrix.py). The log here would finish 60 s after starting (a 2 s log finished within a slow
    close on a loaded machine): its worker process is gone once the pool is closed, and the log never finished."""
    pytest.importorskip("distributed")
    from slamobs.pipeline.batch.dask_exec import DaskPool
    from slamobs.pipeline.batch.executor import Task

    marks = str(tmp_path)

    def slow(task):
        import os
        import pathlib
        import time

        (pathlib.Path(marks) / "pid").write_text(str(os.getpid()))
        (pathlib.Path(marks) / "started").touch()
        time.sleep(60.0)
        (pathlib.Path(marks) / "finished").touch()
        return {}

    def stopped_once_running():
        if (tmp_path / "started").exists():
            raise KeyboardInterrupt
        return 1

    pool = DaskPool(1, run=slow, wait_workers=30)
    try:
        pool._workers = stopped_once_running  # the batch's SIGTERM, once the log runs
        with pytest.raises(KeyboardInterrupt):
            list(pool.results([Task.make("r0", str(tmp_path / "a.mcap"), str(tmp_path / "OUT"), {})]))
    finally:
        pool.close()
    worker = int((tmp_path / "pid").read_text())
    # killed with the pool (a graceful close waited the log's 60 s out); the bound only catches a worker left running
    assert wait_for(lambda: not alive(worker), 30) and not (tmp_path / "finished").exists()


def test_a_stop_signal_while_the_local_cluster_closes_is_raised_after_the_close_and_the_staging_clean_up(
    logs, tmp_path, monkeypatch
):
    """A first SIGTERM while a batch closes its local Dask cluster (its normal end): batch's own handler raised at
    once, inside ``DaskPool.close``, which only ``interrupts``' handler deferred (``critical()``): the close was cut
    (the cluster's worker processes left to the exit) and the staging clean-up after it skipped, so the stopped batch
    left its staging directory (and what its last tasks staged). Now the stop is raised after both."""
    pytest.importorskip("distributed")
    from slamobs.cli.jobs import EXIT_SIGNAL, Stopped, on_signal
    from slamobs.pipeline.batch import BatchOptions, discover, run_batch
    from slamobs.pipeline.batch import dask_exec
    from slamobs.pipeline.config import load_config

    kill, seen, whole = dask_exec.kill_workers, [], []

    def signalled_first(cluster):
        first = not seen
        if first:
            seen.extend(nanny.pid for nanny in cluster.workers.values())
            os.kill(os.getpid(), signal.SIGTERM)  # the handler runs in this frame, right after the kill
        kill(cluster)
        whole.append(first)  # not reached when the signal cut the close here

    monkeypatch.setattr(dask_exec, "kill_workers", signalled_first)
    base, cfg = logs
    out = tmp_path / "OUT"
    options = BatchOptions(out=out, config=load_config(cfg), executor="dask", jobs=1, compact=False, wait_workers=60)
    handlers = {sig: signal.signal(sig, on_signal) for sig in EXIT_SIGNAL}
    try:
        with pytest.raises(Stopped):
            run_batch(discover([base]), options)
    finally:
        for sig, old in handlers.items():
            signal.signal(sig, old)
    assert seen and whole[:1] == [True], whole  # the close the signal hit ran to its end
    assert wait_for(lambda: not any(alive(pid) for pid in seen), 20), seen
    staging = out / "_slamobs" / "staging"
    assert not staging.exists() or not list(staging.iterdir()), list(staging.rglob("*"))
    assert_consistent(out)


def test_a_local_cluster_starts_without_a_warning_when_port_8787_is_taken():
    """A second batch (or any Dask dashboard) holding port 8787 made every local-cluster batch print "Port 8787
    is already in use. Perhaps you already have a cluster running?" above its own lines."""
    pytest.importorskip("distributed")
    import socket
    import warnings

    from slamobs.pipeline.batch.dask_exec import DaskPool

    taken = socket.socket()
    try:
        taken.bind(("", 8787))
        taken.listen()
    except OSError:
        taken.close()
        taken = None  # someone else holds it: the same situation
    pool = DaskPool(1, run=repr, wait_workers=30)
    try:
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            pool.connect()
        assert not [w for w in seen if "already in use" in str(w.message)]
    finally:
        pool.close()
        if taken is not None:
            taken.close()


def test_a_local_cluster_that_cannot_start_is_exit_3(monkeypatch):
    """A local Dask cluster that cannot start (no free port, no processes) is the machine's failure (exit 3 with
    one line), not an error line about the batch (exit 2)."""
    pytest.importorskip("distributed")
    import distributed

    from slamobs.pipeline.batch.dask_exec import DaskPool
    from slamobs.pipeline.batch.executor import InfrastructureError

    class NoPorts:
        def __init__(self, *args, **kwargs):
            raise OSError(98, "Address already in use")

    monkeypatch.setattr(distributed, "LocalCluster", NoPorts)
    with pytest.raises(InfrastructureError, match=r"local Dask cluster: cannot start \(OSError: .*Address already"):
        DaskPool(1).connect()


def test_a_dask_worker_killed_under_a_log_until_dask_gives_up_fails_that_log_with_one_line(logs, tmp_path):
    """SIGKILL of the local Dask worker running a log (an OOM kill), as many times as Dask allows
    (``allowed-failures`` 0 here, 3 by default: kill6's loop killed the same log 4 times): that log fails naming the
    dying workers, the others run, exit 1, a consistent dataset, no process left, and the batch's own lines only:
    the scheduler running in the batch printed its ERROR lines between them ("Task ... marked as failed because 1
    workers died while trying to run it", "Couldn't gather keys")."""
    pytest.importorskip("distributed")
    out = tmp_path / "OUT"
    env = {**os.environ, "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "0"}
    err = tmp_path / "b.err"
    with open(err, "w") as fh:
        args = batch_args(logs, out, "--executor", "dask", "-j", 2)
        proc = subprocess.Popen(
            [*CLI, *map(str, args)], stdout=subprocess.DEVNULL, stderr=fh, env=env, start_new_session=True
        )
    try:
        assert wait_for(lambda: staged_logs(out) or proc.poll() is not None, 180, step=0.005), err.read_text()
        os.kill(staged_logs(out)[0][1], signal.SIGKILL)
        assert proc.wait(timeout=300) == 1, err.read_text()
        assert wait_gone(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    lines = err.read_text().strip().splitlines()
    assert lines[0].startswith("batch: ") and all(line.startswith("[") for line in lines[1:]), lines
    rows = assert_consistent(out)
    failed = [r for r in rows.values() if r["status"] != "ok"]
    # the tasks Dask had handed to that worker (queued behind the log) count as its victims too
    assert len(rows) == N_LOGS and 1 <= len(failed) < N_LOGS, rows
    assert all("Dask workers died while running this log" in r["error"] for r in failed), failed


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_batch_stopped_while_its_local_cluster_starts_says_one_line_and_leaves_no_process(logs, tmp_path, sig):
    """A signal while ``LocalCluster`` starts its worker processes cut the constructor in two: the batch printed
    its one line, then distributed's exit hook closed the half-built cluster and printed a traceback
    (``AssertionError: Status.init``, kill4's loop: SIGTERM at 6.0 s under load). The signal lands once the first
    worker process exists and before the batch says where it runs. A worker process still being spawned as the
    batch ends may print its own traceback (its semaphore gone): theirs, left open, not checked here."""
    proc, err = batch_with_its_cluster_starting(logs, tmp_path)
    try:
        os.kill(proc.pid, sig)
        code = proc.wait(timeout=60)
        text = err.read_text()
        assert code == 128 + sig, text
        assert "Exception ignored" not in text and "Status.init" not in text, text
        assert text.strip().splitlines()[0] == (
            f"{signal.Signals(sig).name}: batch stopped, its workers killed; finished runs are recorded; run the "
            "same command again to resume"
        ), text
        assert wait_gone(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def read_environ(pid: int) -> list[bytes]:
    """A process's environment as its ``NAME=value`` entries."""
    with open(f"/proc/{pid}/environ", "rb") as fh:
        return fh.read().split(b"\0")


def test_ctrl_c_while_the_local_cluster_starts_prints_the_batch_s_line_only(logs, tmp_path):
    """Ctrl-C (SIGINT to the group; SIGHUP, a closed terminal, the same) reached the local cluster's worker
    processes as they imported: each printed its KeyboardInterrupt traceback under the batch's line (8 of 10 trials
    at load 15-20). They now start with SIGINT and SIGHUP blocked (the batch kills them; SIGTERM still ends them):
    the batch's line is the only output."""
    proc, err = batch_with_its_cluster_starting(logs, tmp_path)
    try:
        assert wait_for(lambda: spawned_workers(proc.pid) or proc.poll() is not None, 60, step=0.005)
        workers = spawned_workers(proc.pid)
        masks = {pid: blocked_signals(pid) for pid in workers}
        # by its command line: the children but the workers also held a worker forked and not yet exec'd, with
        # the batch's own environment (one fresh-clone suite run, session 25)
        tracker = {pid: blocked_signals(pid) for pid in resource_trackers(proc.pid)}
        environ = {pid: read_environ(pid) for pid in tracker}
        time.sleep(0.3)  # they import
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=60)
        text = err.read_text()
        assert code == 130, text
        assert wait_gone(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    both = 1 << (signal.SIGINT - 1) | 1 << (signal.SIGHUP - 1)
    assert masks and all(mask & both == both for mask in masks.values()), masks
    # multiprocessing's resource tracker, killed by a SIGHUP to the group, was relaunched and printed a KeyError
    # traceback per semaphore (kill_matrix seed 75): it ignores SIGINT itself, SIGHUP is blocked
    assert tracker and all(mask & 1 << (signal.SIGHUP - 1) for mask in tracker.values()), tracker
    # ... and its own shutdown warnings ignored: "1 leaked semaphore objects" and "[Errno 2]" of a semaphore whose
    # unlink raced the exit's printed under the batch's line (one fresh-clone suite run, session 24)
    want = f"PYTHONWARNINGS={TRACKER_WARNINGS}".encode()
    assert all(want in env for env in environ.values()), environ
    assert text.strip().splitlines() == [
        "SIGINT: batch stopped, its workers killed; finished runs are recorded; run the same command again to resume"
    ], text


def test_a_dask_worker_killed_under_a_log_fails_that_log_only_not_the_ones_queued_on_it(
    six_logs, tmp_path, monkeypatch
):
    """Dask counts a worker's death against every log the worker held, the one queued behind the running one too
    (two per single-threaded worker): with ``allowed-failures`` 0, one kill -9 of a worker running a log failed
    two logs of 6 ("Dask workers died while running this log, every retry"), one of which never started. A log
    that never began on a dying worker is now submitted again; only the log it was running fails."""
    pytest.importorskip("distributed")
    monkeypatch.setenv("DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES", "0")
    out = tmp_path / "OUT"
    proc, err = start_batch(batch_args(six_logs, out, "--executor", "dask", "-j", 2), tmp_path, "b")
    try:
        assert wait_for(lambda: started_logs(out) or proc.poll() is not None, 300, step=0.005), err.read_text()
        markers = list((out / "_slamobs" / "staging").glob(f"*/*/{STARTED}"))
        victim = json.loads(markers[0].read_text())["pid"]
        os.kill(victim, signal.SIGKILL)
        code = proc.wait(timeout=600)
        text = err.read_text()
        assert wait_gone(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert code == 1, text
    rows = assert_consistent(out)
    failed = {rid: row["error"] for rid, row in rows.items() if row["status"] != "ok"}
    assert failed == {
        markers[0].parent.name: f"{six_logs[0] / markers[0].parent.name.rsplit('-', 1)[0]}.mcap: "
        "Dask workers died while running this log, every retry (crash or out of memory)"
    }, text
    assert len(rows) == 6, text


def test_a_worker_killed_while_the_local_cluster_starts_is_started_again_and_the_batch_runs(logs, tmp_path):
    """SIGKILL of one worker process as the local cluster starts (as it imports, before it registers) failed the
    cluster's whole start: exit 3, "local Dask cluster: cannot start (RuntimeError: Nanny failed to start.)"
    (kill_matrix seed 72, trial 3). Its nanny is now started again: one line says so, every log runs, exit 0."""
    proc, err = batch_with_its_cluster_starting(logs, tmp_path)
    out = tmp_path / "OUT"
    try:
        assert wait_for(lambda: spawned_workers(proc.pid) or proc.poll() is not None, 60, step=0.005)
        os.kill(spawned_workers(proc.pid)[0], signal.SIGKILL)
        code = proc.wait(timeout=300)
        text = err.read_text()
        assert code == 0, text
        notes = [line for line in text.splitlines() if line.startswith("note: ")]
        assert notes == [
            "note: local Dask cluster: a worker process died as it started (RuntimeError: Nanny failed to start "
            "worker process); started it again"
        ], text
        assert "Traceback" not in text, text
        assert wait_gone(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    rows = assert_consistent(out)
    assert sorted(r["status"] for r in rows.values()) == ["ok"] * N_LOGS


def test_ctrl_c_while_the_local_cluster_starts_leaves_no_half_built_cluster_to_the_exit_hook(logs, tmp_path):
    """Ctrl-C (SIGINT to the whole group) while the local cluster starts also ends its worker processes as they
    import: the constructor then raised, its half-built cluster was left to distributed's exit hook, which printed
    ``AssertionError: Status.init`` (kill_matrix seed 45, trial 4). The workers' own KeyboardInterrupt at import is
    their output, not the batch's, and is not checked here."""
    proc, err = batch_with_its_cluster_starting(logs, tmp_path)
    try:
        time.sleep(0.3)  # its worker processes are importing
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=60)
        text = err.read_text()
        assert code in (130, 3), text  # stopped, or the cluster could not start (its workers died): one line
        # the fixed fault; left open (seen once in the lead's CI): the batch's own import cut by the group's SIGINT
        # ("Exception ignored in: <function _get_module_lock...>") and a nanny's "failed to start" task beside it
        assert "Status.init" not in text, text
        assert wait_gone(proc.pid) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
