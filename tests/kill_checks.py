"""What the kill tests with real processes share (tests/test_batch_kills_*.py, tests/test_tune.py): the batch CLI
started as cron or systemd runs it, its logs, the signs that a worker runs a log, and a real Dask scheduler and
real Dask workers. After every kill: no process of the batch is alive, and once the same command has run again
the dataset holds exactly the summary's ok runs, each (run_id, t_ns) once.

Each kill lands while a worker runs a log (the sign: its ``started.json``); ``benchmarks/batch_kills.py`` runs a
larger matrix of kill points."""

from __future__ import annotations

import json
import os
import signal
import subprocess
from pathlib import Path

import pytest

from batch_checks import CLI, DASK, assert_consistent, children, spawn, start_scheduler, stop, wait_for
from slamobs.pipeline.batch.executor import STARTED


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


@pytest.fixture(scope="module")
def six_logs(tmp_path_factory):
    from slamobs.pipeline.simulate import simulate, write_log

    base = tmp_path_factory.mktemp("six_logs")
    for i in range(6):
        write_log(simulate(("circle", "figure8")[i % 2], duration=3.0, seed=50 + i), base / f"k{i}.mcap")
    cfg = base / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    return base, cfg


def start_batch(args: list, tmp_path: Path, name: str) -> tuple[subprocess.Popen, Path]:
    err = tmp_path / f"{name}.err"
    with open(err, "w") as fh:
        proc = subprocess.Popen([*CLI, *map(str, args)], stdout=subprocess.DEVNULL, stderr=fh, start_new_session=True)
    return proc, err


def batch_args(logs, out: Path, *extra) -> list:
    base, cfg = logs
    return ["batch", base, "-o", out, "--config", cfg, *extra]


def rerun_and_check(logs, out: Path) -> None:
    done = subprocess.run(
        [*CLI, *map(str, batch_args(logs, out, "-j", 1))], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    rows = assert_consistent(out)
    assert sorted(r["status"] for r in rows.values()) == ["ok"] * N_LOGS


def started_logs(out: Path) -> list[dict]:
    """What the workers wrote as they began a log (``started.json`` in its staging directory): the sign that the
    batch is running a log, with the pid of the worker running it."""
    found = []
    for marker in (out / "_slamobs" / "staging").glob(f"*/*/{STARTED}"):
        try:
            found.append(json.loads(marker.read_text()))
        except (OSError, ValueError):  # removed as its run was committed, or not written out yet
            pass
    return found


def staged_logs(out: Path) -> list[tuple[Path, int]]:
    """(staging directory, worker pid) of each log a worker has begun."""
    found = []
    for marker in (out / "_slamobs" / "staging").glob(f"*/*/{STARTED}"):
        try:
            found.append((marker.parent, json.loads(marker.read_text())["pid"]))
        except (OSError, ValueError, KeyError):
            pass
    return found


# --- Dask: real scheduler and worker processes --------------------------------------------------------------

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


@pytest.fixture
def scheduler(tmp_path):
    pytest.importorskip("distributed")
    if not DASK.is_file():
        pytest.skip("no dask command next to the interpreter")
    proc, address = start_scheduler(tmp_path)
    try:
        yield proc, address
    finally:
        stop(proc)


def dask_worker(address: str, tmp_path: Path, name: str, env: dict | None = None) -> subprocess.Popen:
    return spawn(
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


def batch_with_its_cluster_starting(logs, tmp_path):
    """A ``batch --executor dask`` process, returned once its local cluster has a worker process and before the
    batch says where it runs (the cluster is starting), with its stderr file."""
    pytest.importorskip("distributed")
    args = batch_args(logs, tmp_path / "OUT", "--executor", "dask", "-j", 2, "--wait-workers", 60)
    proc, err = start_batch(args, tmp_path, "b")
    try:
        assert wait_for(lambda: children(proc.pid) or proc.poll() is not None, 120, step=0.005), err.read_text()
        assert proc.poll() is None and "to run on" not in err.read_text()
    except BaseException:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    return proc, err


def children_running(pid: int, marker: bytes) -> list[int]:
    """The children of ``pid`` whose command line holds ``marker`` (a child forked but not yet exec'd still shows its
    parent's command line and environment, so it matches none)."""
    found = []
    for child in children(pid):
        try:
            with open(f"/proc/{child}/cmdline", "rb") as fh:
                if marker in fh.read():
                    found.append(child)
        except OSError:
            pass
    return found


def spawned_workers(pid: int) -> list[int]:
    """The worker processes a local Dask cluster's nannies spawned under the batch ``pid``."""
    return children_running(pid, b"spawn_main")


def resource_trackers(pid: int) -> list[int]:
    """multiprocessing's resource tracker under the batch ``pid`` (``from multiprocessing.resource_tracker import
    main``)."""
    return children_running(pid, b"resource_tracker")


def blocked_signals(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return next(int(line.split()[1], 16) for line in fh if line.startswith("SigBlk:"))
