"""Kill tests with real processes: the batch CLI (as cron or systemd runs it), its workers, a real Dask scheduler
and real Dask workers. After every kill: no process of the batch is alive, and once the same command has run
again the dataset holds exactly the summary's ok runs, each (run_id, t_ns) once.

Each kill lands while a worker runs a log (the sign: its ``started.json``); ``benchmarks/batch_kills.py`` runs a
larger matrix of kill points.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from batch_checks import CLI, alive, assert_consistent, children, wait_for, wait_gone
from slamobs.pipeline.batch.executor import STARTED
from slamobs.pipeline.batch.ledger import read_summary

N_LOGS = 4
EXPECTED_EXIT = {signal.SIGKILL: -9, signal.SIGTERM: 143, signal.SIGINT: 130}


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    from slamobs.pipeline.simulate import simulate, write_log

    base = tmp_path_factory.mktemp("kill_logs")
    for i in range(N_LOGS):
        write_log(simulate(("circle", "figure8")[i % 2], duration=3.0, seed=40 + i), base / f"k{i}.mcap")
    cfg = base / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    return base, cfg


def _start(args: list, tmp_path: Path, name: str) -> tuple[subprocess.Popen, Path]:
    err = tmp_path / f"{name}.err"
    with open(err, "w") as fh:
        proc = subprocess.Popen([*CLI, *map(str, args)], stdout=subprocess.DEVNULL, stderr=fh, start_new_session=True)
    return proc, err


def _batch_args(logs, out: Path, *extra) -> list:
    base, cfg = logs
    return ["batch", base, "-o", out, "--config", cfg, *extra]


def _rerun_and_check(logs, out: Path) -> None:
    done = subprocess.run(
        [*CLI, *map(str, _batch_args(logs, out, "-j", 1))], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    rows = assert_consistent(out)
    assert sorted(r["status"] for r in rows.values()) == ["ok"] * N_LOGS


def _started(out: Path) -> list[dict]:
    """What the workers wrote as they began a log (``started.json`` in its staging directory): the sign that the
    batch is running a log, with the pid of the worker running it."""
    found = []
    for marker in (out / "_slamobs" / "staging").glob(f"*/*/{STARTED}"):
        try:
            found.append(json.loads(marker.read_text()))
        except (OSError, ValueError):  # removed as its run was committed, or not written out yet
            pass
    return found


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
    proc, err = _start(_batch_args(logs, out, "-j", 2), tmp_path, "batch")
    try:
        assert wait_for(lambda: _started(out) or proc.poll() is not None, 120, step=0.005), err.read_text()
        started = _started(out)
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
    _rerun_and_check(logs, out)
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


# --- Dask: real scheduler and worker processes --------------------------------------------------------------

DASK = Path(sys.executable).with_name("dask")
# A worker environment without slamobs, made without a second venv: `import slamobs` fails in that process.
NO_SLAMOBS = """
import sys
class _NoSlamobs:
    def find_spec(self, name, path=None, target=None):
        if name == "slamobs" or name.startswith("slamobs."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None
sys.meta_path.insert(0, _NoSlamobs())
"""


def _spawn(args: list, log: Path, env: dict | None = None) -> subprocess.Popen:
    with open(log, "w") as fh:
        return subprocess.Popen(
            [str(a) for a in args],
            stdout=fh,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env={**os.environ, **(env or {})},
        )


def _stop(*procs: subprocess.Popen) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        p.wait()


@pytest.fixture
def scheduler(tmp_path):
    pytest.importorskip("distributed")
    if not DASK.is_file():
        pytest.skip("no dask command next to the interpreter")
    info = tmp_path / "scheduler.json"
    proc = _spawn(
        [
            DASK,
            "scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--scheduler-file",
            info,
            "--dashboard-address",
            ":0",
        ],
        tmp_path / "scheduler.log",
    )
    try:
        assert wait_for(info.is_file, 60), (tmp_path / "scheduler.log").read_text()
        time.sleep(0.2)
        yield proc, json.loads(info.read_text())["address"]
    finally:
        _stop(proc)


def _worker(address: str, tmp_path: Path, name: str, env: dict | None = None) -> subprocess.Popen:
    return _spawn(
        [
            DASK,
            "worker",
            address,
            "--nthreads",
            "1",
            "--no-dashboard",
            "--name",
            name,
            "--local-directory",
            tmp_path / name,
        ],
        tmp_path / f"{name}.log",
        env,
    )


def test_dask_without_usable_workers_exits_3_with_one_line(logs, tmp_path, scheduler):
    _, address = scheduler
    args = [*CLI, *map(str, _batch_args(logs, tmp_path / "OUT", "--scheduler", address))]
    done = subprocess.run([*args, "--wait-workers", "2"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 3 and done.stderr.strip().splitlines()[-1] == (
        f"error: {address}: no Dask workers after 2 s (--wait-workers)"
    )

    site = tmp_path / "no_slamobs"
    site.mkdir()
    (site / "sitecustomize.py").write_text(NO_SLAMOBS)
    worker = _worker(address, tmp_path, "bare", {"PYTHONPATH": str(site)})
    try:
        t0 = time.monotonic()
        done = subprocess.run(args, capture_output=True, text=True, timeout=60)  # never waits forever
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 3, done.stderr
        assert len(lines) == 1 and lines[0].startswith("error: Dask worker tcp://127.0.0.1:")
        assert "cannot import slamobs (ModuleNotFoundError: No module named 'slamobs')" in lines[0]
        assert time.monotonic() - t0 < 60
    finally:
        _stop(worker)
    rows = assert_consistent(tmp_path / "OUT")
    assert rows == {}  # nothing was run, nothing recorded


def test_lost_dask_scheduler_exits_3_and_a_rerun_is_consistent(logs, tmp_path, scheduler):
    sched, address = scheduler
    worker = _worker(address, tmp_path, "w1")
    out = tmp_path / "OUT"
    try:
        proc, err = _start(_batch_args(logs, out, "--scheduler", address, "--wait-workers", "30"), tmp_path, "batch")
        # a run recorded (its line may already be in summary.parquet: rewritten every second or so)
        assert wait_for(lambda: len(read_summary(out)) >= 1 or proc.poll() is not None, 180), err.read_text()
        sched.kill()
        code = proc.wait(timeout=120)
        assert code == 3, err.read_text()
        assert "lost the Dask scheduler" in err.read_text().strip().splitlines()[-1]
        assert wait_gone(proc.pid) == []
    finally:
        _stop(worker)
    _rerun_and_check(logs, out)


def test_a_scheduler_killed_while_a_task_runs_leaves_nothing_staged(logs, tmp_path, scheduler):
    """The worker outlives the killed scheduler and its task goes on: its run's writer made the staging directory
    again after the batch had removed it (kill_matrix seed 35: two staged runs left after exit 3). The batch now
    removes what such tasks write until they have seen its lease gone and ended."""
    from slamobs.pipeline.batch.executor import LEASE_POLL_S

    sched, address = scheduler
    worker = _worker(address, tmp_path, "w1")
    out = tmp_path / "OUT"
    try:
        proc, err = _start(_batch_args(logs, out, "--scheduler", address, "--wait-workers", "30"), tmp_path, "batch")
        assert wait_for(lambda: _started(out) or proc.poll() is not None, 180, step=0.01), err.read_text()
        sched.kill()
        assert proc.wait(timeout=120) == 3, err.read_text()
        time.sleep(LEASE_POLL_S + 3)  # the orphaned task has seen the lease gone and ended its worker process
        staged = sorted(str(p.relative_to(out)) for p in (out / "_slamobs" / "staging").rglob("*"))
        assert staged == [], staged
        assert_consistent(out)
    finally:
        _stop(worker)
    _rerun_and_check(logs, out)


def test_a_scheduler_killed_before_the_batch_connects_is_exit_3_at_once_naming_it(logs, tmp_path, scheduler):
    """Nothing listens at the address any more: one line naming it, exit 3, without waiting out Dask's connect
    timeout (min(--wait-workers, 30) s: 25 s measured with --wait-workers 20)."""
    sched, address = scheduler
    sched.kill()
    sched.wait()
    t0 = time.monotonic()
    args = [*CLI, *map(str, _batch_args(logs, tmp_path / "OUT", "--scheduler", address, "--wait-workers", "60"))]
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


def test_a_stopped_batch_kills_its_local_clusters_running_logs_instead_of_waiting_for_them(tmp_path):
    """A signal stops a batch on a local Dask cluster with logs running: their worker processes are killed, as
    local workers are, not closed gracefully (each waited for its running log: exit 11 s after a SIGTERM in
    benchmarks/kill_matrix.py). The log here would finish 2 s after starting; it must not."""
    pytest.importorskip("distributed")
    from slamobs.pipeline.batch.dask_exec import DaskPool
    from slamobs.pipeline.batch.executor import Task

    marks = str(tmp_path)

    def slow(task):
        import pathlib
        import time

        (pathlib.Path(marks) / "started").touch()
        time.sleep(2.0)
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
    time.sleep(3.0)  # longer than the log had left to run
    assert (tmp_path / "started").exists() and not (tmp_path / "finished").exists()


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


def test_a_worker_killed_twice_under_one_log_fails_that_log_only_and_a_rerun_runs_it(logs, tmp_path):
    """SIGKILL of the worker running a log, then of the fresh worker running it again (an OOM killer that keeps
    choosing it): that log fails naming the signal, the others run, the batch exits 1 with a consistent dataset,
    and the same command runs the failed log (kill_matrix kills a worker once: its log runs again)."""
    out = tmp_path / "OUT"
    proc, err = _start(_batch_args(logs, out, "-j", 1), tmp_path, "batch")
    killed: list[int] = []
    victim_staged = None
    try:
        for _ in range(2):
            assert wait_for(
                lambda: [s for s in _staged(out) if s[1] not in killed] or proc.poll() is not None, 180, step=0.005
            ), err.read_text()
            running = [s for s in _staged(out) if s[1] not in killed]
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
    _rerun_and_check(logs, out)


def _staged(out: Path) -> list[tuple[Path, int]]:
    """(staging directory, worker pid) of each log a worker has begun."""
    found = []
    for marker in (out / "_slamobs" / "staging").glob(f"*/*/{STARTED}"):
        try:
            found.append((marker.parent, json.loads(marker.read_text())["pid"]))
        except (OSError, ValueError, KeyError):
            pass
    return found


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
        args = _batch_args(logs, out, "--executor", "dask", "-j", 2)
        proc = subprocess.Popen(
            [*CLI, *map(str, args)], stdout=subprocess.DEVNULL, stderr=fh, env=env, start_new_session=True
        )
    try:
        assert wait_for(lambda: _staged(out) or proc.poll() is not None, 180, step=0.005), err.read_text()
        os.kill(_staged(out)[0][1], signal.SIGKILL)
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


def _batch_with_its_cluster_starting(logs, tmp_path):
    """A ``batch --executor dask`` process, returned once its local cluster has a worker process and before the
    batch says where it runs (the cluster is starting), with its stderr file."""
    pytest.importorskip("distributed")
    args = _batch_args(logs, tmp_path / "OUT", "--executor", "dask", "-j", 2, "--wait-workers", 60)
    proc, err = _start(args, tmp_path, "b")
    try:
        assert wait_for(lambda: children(proc.pid) or proc.poll() is not None, 120, step=0.005), err.read_text()
        assert proc.poll() is None and "to run on" not in err.read_text()
    except BaseException:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    return proc, err


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_batch_stopped_while_its_local_cluster_starts_says_one_line_and_leaves_no_process(logs, tmp_path, sig):
    """A signal while ``LocalCluster`` starts its worker processes cut the constructor in two: the batch printed
    its one line, then distributed's exit hook closed the half-built cluster and printed a traceback
    (``AssertionError: Status.init``, kill4's loop: SIGTERM at 6.0 s under load). The signal lands once the first
    worker process exists and before the batch says where it runs. A worker process still being spawned as the
    batch ends may print its own traceback (its semaphore gone): theirs, left open, not checked here."""
    proc, err = _batch_with_its_cluster_starting(logs, tmp_path)
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


def _spawned_workers(pid: int) -> list[int]:
    """The worker processes a local Dask cluster's nannies spawned under the batch ``pid`` (not multiprocessing's
    resource tracker)."""
    found = []
    for child in children(pid):
        try:
            with open(f"/proc/{child}/cmdline", "rb") as fh:
                if b"spawn_main" in fh.read():
                    found.append(child)
        except OSError:
            pass
    return found


def _blocked(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return next(int(line.split()[1], 16) for line in fh if line.startswith("SigBlk:"))


def test_ctrl_c_while_the_local_cluster_starts_prints_the_batch_s_line_only(logs, tmp_path):
    """Ctrl-C (SIGINT to the group; SIGHUP, a closed terminal, the same) reached the local cluster's worker
    processes as they imported: each printed its KeyboardInterrupt traceback under the batch's line (8 of 10 trials
    at load 15-20). They now start with SIGINT and SIGHUP blocked (the batch kills them; SIGTERM still ends them):
    the batch's line is the only output."""
    proc, err = _batch_with_its_cluster_starting(logs, tmp_path)
    try:
        assert wait_for(lambda: _spawned_workers(proc.pid) or proc.poll() is not None, 60, step=0.005)
        workers = _spawned_workers(proc.pid)
        masks = {pid: _blocked(pid) for pid in workers}
        tracker = {pid: _blocked(pid) for pid in set(children(proc.pid)) - set(workers)}  # resource tracker
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
    assert text.strip().splitlines() == [
        "SIGINT: batch stopped, its workers killed; finished runs are recorded; run the same command again to resume"
    ], text


@pytest.fixture(scope="module")
def six_logs(tmp_path_factory):
    from slamobs.pipeline.simulate import simulate, write_log

    base = tmp_path_factory.mktemp("six_logs")
    for i in range(6):
        write_log(simulate(("circle", "figure8")[i % 2], duration=3.0, seed=50 + i), base / f"k{i}.mcap")
    cfg = base / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    return base, cfg


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
    proc, err = _start(_batch_args(six_logs, out, "--executor", "dask", "-j", 2), tmp_path, "b")
    try:
        assert wait_for(lambda: _started(out) or proc.poll() is not None, 300, step=0.005), err.read_text()
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
    proc, err = _batch_with_its_cluster_starting(logs, tmp_path)
    out = tmp_path / "OUT"
    try:
        assert wait_for(lambda: _spawned_workers(proc.pid) or proc.poll() is not None, 60, step=0.005)
        os.kill(_spawned_workers(proc.pid)[0], signal.SIGKILL)
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
    proc, err = _batch_with_its_cluster_starting(logs, tmp_path)
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


_ENDS_WHILE_A_CHILD_STARTS = """
import multiprocessing, os, sys, threading, time
from multiprocessing import resource_tracker, util

from slamobs.pipeline.batch.dask_exec import spawns_settled

resource_tracker.ensure_running()  # started by a first spawn, through the same call: not the child slowed below
launch = util.spawnv_passfds


def slow(*args):  # the child exists, its start data not yet written (a nanny's start as the batch ends)
    pid = launch(*args)
    time.sleep(1.5)
    return pid


util.spawnv_passfds = slow
child = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(60,), daemon=True)
threading.Thread(target=child.start, daemon=True).start()
time.sleep(0.5)
if sys.argv[1] == "settle":
    spawns_settled()
for proc in multiprocessing.active_children():  # what the exit does (cli.errors.exit_at_once)
    proc.kill()
    proc.join(5)
os._exit(0)
"""


def test_a_process_that_ends_while_a_child_process_starts_waits_for_the_start_so_the_child_prints_nothing():
    """A batch that ended while a local Dask nanny started its worker process (a thread between fork-exec and
    writing the child's start data) left the child to read a closed pipe: ``EOFError: Ran out of input`` and a
    traceback under the batch's line (1 of 5 Ctrl-C trials, kill5). ``spawns_settled`` (the cluster's close and
    a failed start) waits for the start; then the exit kills the child. Both ways here, the child's start slowed."""
    seen = {}
    for how in ("settle", "no"):
        done = subprocess.run(
            [sys.executable, "-c", _ENDS_WHILE_A_CHILD_STARTS, how], capture_output=True, text=True, timeout=120
        )
        seen[how] = (done.returncode, done.stderr)
    assert seen["no"][0] == 0 and "EOFError" in seen["no"][1], seen  # the fault, reproduced without the wait
    assert seen["settle"] == (0, ""), seen


_ENDS_WHILE_A_THREAD_RELEASES_A_SEMAPHORE = """
import multiprocessing, os, sys, threading, time
from multiprocessing import resource_tracker, util

from slamobs.cli import errors

resource_tracker.ensure_running()
unregister, telling = resource_tracker.unregister, threading.Event()


def slow(name, rtype):  # unlinked, the tracker not yet told (a loaded machine: 5 ms in the kill test)
    telling.set()
    time.sleep(1.0)
    unregister(name, rtype)


resource_tracker.unregister = slow


def release():  # the local cluster's event loop collecting a closed nanny's queue
    lock = multiprocessing.get_context("spawn").Lock()
    del lock


threading.Thread(target=release, daemon=True).start()
telling.wait(30)
if sys.argv[1] == "exit":
    errors.EXIT_AT_ONCE = True
    errors.exit_at_once(130)
util._run_finalizers(0)  # the exit before: its own finalizers only
os._exit(130)
"""


def test_an_exit_while_another_thread_releases_a_semaphore_waits_so_the_resource_tracker_prints_nothing():
    """A batch stopped as its local cluster started ended (``os._exit``) while the cluster's event loop thread
    released a nanny's queue semaphore, between its unlink and telling the resource tracker: the tracker printed
    "There appear to be 1 leaked semaphore objects" and "[Errno 2] No such file or directory" under the batch's
    line (2 of 10 Ctrl-C trials, the kill test above; 1 in 5 full-suite runs). The exit now waits for the release.
    Both ways here, the release slowed; stderr read to its end, so the tracker's shutdown is in it."""
    seen = {}
    for how in ("exit", "no"):
        done = subprocess.run(
            [sys.executable, "-c", _ENDS_WHILE_A_THREAD_RELEASES_A_SEMAPHORE, how],
            capture_output=True,
            text=True,
            timeout=120,
        )
        seen[how] = (done.returncode, done.stderr)
    assert seen["no"][0] == 130 and "leaked semaphore" in seen["no"][1], seen  # the fault, without the wait
    assert seen["exit"] == (130, ""), seen


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


def test_a_process_started_after_the_stop_still_ends_on_sigterm():
    """Once stopped, the batch ignored further signals with ``SIG_IGN``, which survives exec: the worker processes a
    starting local Dask cluster spawned after a SIGHUP ignored SIGTERM, and the batch's exit (multiprocessing's
    SIGTERM, then its wait) took 11-50 s after the batch's line under load 20. A process started after the stop
    must end on SIGTERM."""
    from slamobs.cli.jobs import EXIT_SIGNAL, Stopped, on_signal

    previous = {sig: signal.signal(sig, on_signal) for sig in EXIT_SIGNAL}
    try:
        with pytest.raises(Stopped):
            os.kill(os.getpid(), signal.SIGHUP)
            for _ in range(400):  # the handler runs at a bytecode boundary
                time.sleep(0.005)
        os.kill(os.getpid(), signal.SIGTERM)  # a second signal during the clean-up: nothing
        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(300)"])
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
    try:
        child.terminate()
        assert child.wait(timeout=60) == -signal.SIGTERM
    finally:
        child.kill()
        child.wait()


EXIT_WITH_A_DAEMONIC_CHILD = """
import multiprocessing, sys, time
from slamobs.cli import errors
if __name__ == "__main__":
    child = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(300,), daemon=True)
    child.start()
    print(child.pid, flush=True)
    errors.EXIT_AT_ONCE = True
    errors.exit_at_once(7)
    print("the interpreter's teardown", flush=True)
"""


def test_a_command_ends_at_once_with_its_daemonic_children_killed():
    """A daemonic multiprocessing child alive at the end (the worker processes a starting local Dask cluster spawned
    after the stop) sent the command through the interpreter's teardown: SIGTERM to the child, a wait without bound,
    then garbage collection (3-6 s after a stopped batch's line at load 10-20, and "Task exception was never
    retrieved" tracebacks of its nannies as they were collected). The exit kills the child and ends at once."""
    done = subprocess.run(
        [sys.executable, "-c", EXIT_WITH_A_DAEMONIC_CHILD], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 7, done.stderr
    assert "teardown" not in done.stdout and "leaked" not in done.stderr, done.stdout + done.stderr
    assert not alive(int(done.stdout.split()[0]))


SIGNAL_TO_ANOTHER_THREAD = """
import signal, threading, time
from slamobs.cli.jobs import EXIT_SIGNAL, Stopped, on_signal, signals_to_the_main_thread
for sig in EXIT_SIGNAL:
    signal.signal(sig, on_signal)
go = threading.Event()
def other():
    go.wait()
    time.sleep(0.5)
    signal.pthread_kill(threading.get_ident(), signal.SIGHUP)  # the kernel's choice: not the main thread
    time.sleep(600)
threading.Thread(target=other, daemon=True).start()
try:
    with signals_to_the_main_thread():
        go.set()
        threading.Event().wait(600)  # a lock wait, as distributed's sync() while a local cluster starts
    print("the wait ended")
except Stopped as stop:
    print("stopped by", stop.signum, flush=True)
"""


def test_a_signal_handed_to_another_thread_stops_a_main_thread_waiting_on_a_lock():
    """SIGHUP while a local Dask cluster starts: the main thread waits on a lock in distributed's ``sync()``, and the
    kernel may hand the signal to one of Dask's threads; Python then ran the batch's handler only when that wait
    returned (the batch's line 2-8 s after the signal at load 8-20). The signal is sent on to the main thread."""
    done = subprocess.run([sys.executable, "-c", SIGNAL_TO_ANOTHER_THREAD], capture_output=True, text=True, timeout=60)
    assert done.stdout.strip() == f"stopped by {int(signal.SIGHUP)}", done.stdout + done.stderr
