"""Checks shared by the batch, kill and helper tests: dataset consistency, the processes a job leaves alive, and
what a first run compiles."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

#: The slamobs command as a fresh interpreter runs it (as a cron job would).
#: The console script's own entry (what `slamobs` runs): it ends the process at once when the command is done. Through
#: ``main()`` the interpreter's teardown followed, in which Python has put SIGTERM back to its default: a batch
#: stopped just as it finished was killed by the signal (-15), a race of this harness, not of the command.
CLI = [sys.executable, "-c", "from slamobs.cli.main import entry; entry()"]


#: Run in the child: ``slamobs run ARGS...`` in-process (``kill`` as the first argument: the compile helper is killed
#: as soon as it is started), then what this process compiled, as JSON.
_COMPILING_RUN = """
import json, sys
from slamobs.pipeline import compile_ahead
from slamobs.pipeline.compile_clock import compiled_functions
from slamobs.cli.main import main
if sys.argv[1] == "kill":
    start = compile_ahead.start
    def killed(*args):
        helper = start(*args)
        helper.proc.kill()
        return helper
    compile_ahead.start = killed
main(["run", *sys.argv[2:]], standalone_mode=False)
print(json.dumps(sorted({c.function for c in compiled_functions()})))
"""


def first_run(args: list, cache: Path, kill: bool = False) -> list[str]:
    """``slamobs run ARGS...`` in a fresh process with the kernel cache ``cache`` (empty: a first run) and the
    compile helper on (killed at its start with ``kill``); the functions the run compiled itself."""
    from slamobs.pipeline import compile_ahead

    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), compile_ahead.ENV: "1"}
    argv = [sys.executable, "-c", _COMPILING_RUN, "kill" if kill else "-", *map(str, args)]
    out = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=600)  # a hang fails, never stalls
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def assert_compiles_none_of_the_helpers_kernels(compiled: list[str], estimator: str, its_own: str, the_helpers: str):
    """What a first run with the helper on compiled (:func:`first_run`): none of the helper's kernels, each compiled
    for the types the run calls it with; the kernel the run needs first after reading it compiles itself."""
    from slamobs.pipeline import compile_ahead

    assert f"slamobs.pipeline.{its_own}" in compiled
    assert f"slamobs.pipeline.{the_helpers}" not in compiled
    assert {f"{m}.{n}" for m, n, _ in compile_ahead.plan(estimator)}.isdisjoint(compiled)


def assert_consistent(out: Path) -> dict[str, dict]:
    """The dataset holds exactly the summary's finished runs (ok, or off by the estimator's own status), each
    (run_id, t_ns) once, each with its run directory, and nothing staged; returns the summary rows by run_id."""
    import pandas as pd

    from slamobs.pipeline.batch.ledger import finished, read_summary

    rows = read_summary(out)
    summary = pd.read_parquet(out / "summary.parquet")
    assert sorted(summary["run_id"]) == sorted(rows)  # the file is current once a batch has ended
    ok = {rid for rid, row in rows.items() if finished(row["status"])}
    ids: set[str] = set()
    if (out / "poses").is_dir():
        poses = pd.read_parquet(out / "poses", columns=["run_id", "t_ns"])
        assert not poses.duplicated(["run_id", "t_ns"]).any()
        ids = set(poses["run_id"].astype(str))
    assert ids == ok
    runs = {p.name for p in (out / "runs").iterdir()} if (out / "runs").exists() else set()
    assert runs == ok
    staging = out / "_slamobs" / "staging"
    assert not staging.exists() or not list(staging.iterdir())
    return rows


def _live_where(column: int, value: int) -> list[int]:
    """Live (not zombie) processes whose ``/proc/PID/stat`` field ``column`` (counted after the command name: 1
    parent, 2 process group, 3 session) is ``value``."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[column]) == value and fields[0] != "Z":
            found.append(int(entry))
    return found


def group_alive(pgid: int) -> list[int]:
    """Live processes of process group ``pgid``."""
    return _live_where(2, pgid)


def session_alive(sid: int) -> list[int]:
    """Live processes of session ``sid`` (a process may leave the group, not the session)."""
    return _live_where(3, sid)


def children(pid: int) -> list[int]:
    """Live children of ``pid``: the pipeline's own scan (``lifetime.children``)."""
    from slamobs.pipeline.lifetime import children as live_children

    return live_children(pid)


def descendants(pid: int) -> list[int]:
    """Live children of ``pid``, their children, and so on."""
    found, todo = [], [pid]
    while todo:
        kids = children(todo.pop())
        found += kids
        todo += kids
    return found


def alive(pid: int) -> bool:
    """``pid`` runs (exists and is not a zombie, which has ended and only waits to be reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def wait_gone(pgid: int, within: float = 20.0) -> list[int]:
    """Processes of ``pgid`` still alive after waiting up to ``within`` seconds for them to end (a bound,
    not a speed requirement: they are expected to be gone at once)."""
    end = time.monotonic() + within
    while (alive := group_alive(pgid)) and time.monotonic() < end:
        time.sleep(0.1)
    return alive


def wait_for(predicate, within: float, step: float = 0.1) -> bool:
    end = time.monotonic() + within
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(step)
    return predicate()


#: the Dask command of this interpreter's environment (an external cluster's scheduler and workers)
DASK = Path(sys.executable).with_name("dask")


def spawn(args: list, log: Path, env: dict | None = None) -> subprocess.Popen:
    """``args`` in a session of its own (a process group to kill whole), its output into ``log``."""
    with open(log, "w") as fh:
        return subprocess.Popen(
            [str(a) for a in args],
            stdout=fh,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env={**os.environ, **(env or {})},
        )


def stop(*procs: subprocess.Popen) -> None:
    """SIGKILL each still running process's group, and reap it."""
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        p.wait()


def start_scheduler(work: Path) -> tuple[subprocess.Popen, str]:
    """A Dask scheduler on a free local port (its log and scheduler file in ``work``): the process and its address;
    stopped and an AssertionError with its log when it has not written its file within 60 s."""
    info = work / "scheduler.json"
    info.unlink(missing_ok=True)
    log = work / "scheduler.log"
    proc = spawn(
        [DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--scheduler-file", info]
        + ["--dashboard-address", ":0"],
        log,
    )
    if not wait_for(info.is_file, 60):
        stop(proc)
        raise AssertionError(log.read_text())
    time.sleep(0.2)
    return proc, json.loads(info.read_text())["address"]
