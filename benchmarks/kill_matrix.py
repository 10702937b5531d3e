"""Randomized kill harness over every command: start the real CLI in its own session on generated logs, send
SIGTERM / SIGINT (to the group, as Ctrl-C does) / SIGKILL at a random delay drawn over ``--span`` (0.9) of the
command's median unkilled duration (the reference run, then every rerun and every trial that ended before its
signal: such a trial is drawn again, up to ``--retries`` times, so that the trials hit a live process), then
check what docs/reliability.md promises.

    .venv/bin/python benchmarks/kill_matrix.py [--trials N] [--seed S] [--only run-fa,batch,...] [--cache DIR]
        [--signals TERM,INT,KILL,HUP] [--span 0.9] [--retries 2] [--dask] [--dask-cluster]

SIGHUP (``--signals ...,HUP``) goes to the group, as a closed terminal's shell sends it to its jobs. ``--dask`` adds
``batch --executor dask`` (a LocalCluster in the batch's session), ``--dask-cluster`` a batch on a ``dask scheduler``
and two ``dask worker`` processes the harness starts in their own sessions (a fresh cluster per trial; the rerun
uses the same one unless its scheduler was killed). On both, a trial may instead SIGKILL one Dask worker process
(the batch then exits 0: its log runs again) or the external scheduler (exit 3, a lost cluster); on the local
``batch`` case one of its worker processes, mid-log. ``--group`` (0.3) of the SIGTERM / SIGKILL trials send it to
the whole process group (workers and helpers get it beside their parent) instead of the command alone.
Cases without a signal from the harness: ``batch-timeout`` runs under ``timeout -s TERM -k K DELAY`` (a cron
job's limit, K 0.05-1 s; plots on, so its runs have figure helpers): exit 124, or -9 when the KILL was needed
(timeout sends it to its own group, itself included: 137 in a shell), or 0 if it finished;
``run-memory-limit`` under ``prlimit --as`` at a limit drawn from 250-1400 MB: it fits (0) or ends with one line
naming the memory (2), never a traceback or a hang; ``batch-fsize`` under ``prlimit --fsize`` at 4-600 KB (a quota,
``ulimit -f``: the writers get EFBIG as on a full disk): it fits (0) or the machine failed its runs (3), nothing
recorded as a failed log, the rerun with room equal to the unkilled batch. Also ``export``, ``stats`` and ``info`` of
the 600 s log, ``report`` and ``evaluate`` of its run, ``tune --target batch`` (the smoother as the target) and
``compare`` of three estimators (its figure helpers drawing). ``run-riekf-cold`` and ``run-batch-cold`` are first
runs (an empty kernel cache of the trial's own, the compile helper on), so most signals land inside numba's compiler;
the rerun uses the cache the killed run left. Any trial whose stderr holds a traceback is a violation.

Per trial: the process exits within a bound with 143 / 130 / 129 (-9 after SIGKILL; 0 only if it ended before the
signal), no process of its session is alive a few seconds later (checked by session id: a LocalCluster's nannies
and workers too), a batch that ended by itself (not SIGKILL) left a consistent dataset, nothing is visible
under a final name unless complete (the manifest's files with their sizes, JSON parses, Parquet reads, PNG
decodes, the MCAP / zip equals the unkilled one's), no hidden temporary is left after SIGTERM / SIGINT / SIGHUP
(after SIGKILL they are
documented: the next run removes them), and the same command run again (``--force`` where the output exists;
``batch`` and ``tune`` without: resume) exits 0 with the same tables as the unkilled run. Prints a line per
trial (with its seed, to replay it: ``--seed S --only CASE --trials 1``), a table per case and the violations;
exits 1 if there are any.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from batch_checks import CLI, assert_consistent, children, descendants, session_alive, wait_for  # noqa: E402

HANG_S = 60.0  # a process not gone this long after SIGTERM / SIGINT counts as hung
LOST_S = 120.0  # ... and this long after its Dask worker or scheduler was killed (--wait-workers 20 in the cases)
LINGER_S = 5.0  # processes of the session still alive this long after the main one exited are violations
GROUP_SIGNALS = (signal.SIGINT, signal.SIGHUP)  # sent to the process group: Ctrl-C, a closed terminal
DASK = Path(sys.executable).with_name("dask")
# columns that legitimately differ between two runs of the same command (wall-clock times, paths of the trial)
VOLATILE = ("time", "seconds", "wall", "duration", "started", "finished", "host", "pid", "path", "dir", "worker")


def _stable(columns) -> list[str]:
    return [c for c in columns if not c.endswith("_s") and not any(v in c.split("_") for v in VOLATILE)]


@dataclass
class Case:
    name: str
    argv: list  # OUT stands for the trial's output, IN for the case's input directory
    out: str  # the output's name inside the trial directory
    kind: str  # dir (manifest), file (compared whole), batch, tune
    force: bool = True  # a rerun over an existing output adds --force
    prepare: str | None = None  # a reference output copied into the trial first (report)
    ref: dict = field(default_factory=dict)
    durations: list = field(default_factory=list)  # unkilled runs' seconds: the reference, reruns, trials ended first
    needs: tuple = ()  # the cases whose unkilled outputs it reads (IN/ref-NAME)
    wrap: str = ""  # "timeout": under timeout -s TERM -k 1 DELAY; "memory" / "fsize": under prlimit (no signal)
    victims: tuple = ()  # besides the command itself: "worker" (a Dask worker process), "scheduler" (external)
    cold: bool = False  # each trial a first run: an empty kernel cache of its own (kept for its rerun), helper on

    def env(self, tdir: Path) -> dict | None:
        """A cold case's environment for trial directory ``tdir`` (its kernel cache beside it); None: inherited."""
        if not self.cold:
            return None
        cache = tdir.parent / f"{tdir.name}.numba"
        return {**os.environ, "NUMBA_CACHE_DIR": str(cache), "SLAMOBS_COMPILE_AHEAD": "1"}

    @property
    def duration(self) -> float:
        """The median unkilled duration so far: one measurement under one load was too long or too short for the
        trials run under another (about 40 % of them ended before their signal)."""
        d = sorted(self.durations)
        return (d[(len(d) - 1) // 2] + d[len(d) // 2]) / 2 if d else 0.0

    def observe(self, seconds: float) -> None:
        self.durations.append(seconds)


def _evaluate_case(name: str, log: str, ref: str) -> Case:
    """``slamobs evaluate`` of case ``ref``'s unkilled poses against ``log``'s mocap, saving results and a plot."""
    argv = ["evaluate", f"{log}:/mocap/pose", f"IN/ref-{ref}/out/poses.parquet", "-a", "-q", "--save-results", "OUT"]
    return Case(name, [*argv, "--save-plot", "OUT.png"], "ape.zip", "file", False, needs=(ref,))


def make_cases(inp: Path, realdata: Path | None, dask: bool, dask_cluster: bool = False) -> list[Case]:
    log, long_log = str(inp / "f180.mcap"), str(inp / "f600.mcap")
    cfg = str(inp / "noplots.yaml")
    cases = [
        Case("run-fa", ["run", log, "-o", "OUT", "-q"], "out", "dir"),
        Case("run-fa-600s", ["run", long_log, "-o", "OUT", "-q"], "out", "dir"),
        Case("run-riekf", ["run", log, "-o", "OUT", "-q", "--observer", "riekf"], "out", "dir"),
        Case("run-batch", ["run", log, "-o", "OUT", "-q", "--observer", "batch"], "out", "dir"),
        # first runs: killed mostly while they compile (riekf's event loop, ~25 s of CPU in one piece), then run again
        # on the kernel cache the killed run left
        Case("run-riekf-cold", ["run", log, "-o", "OUT", "-q", "--observer", "riekf"], "out", "dir", cold=True),
        Case("run-batch-cold", ["run", log, "-o", "OUT", "-q", "--observer", "batch"], "out", "dir", cold=True),
        Case("compare", ["compare", log, "-o", "OUT", "-q", "--observers", "fast-adaptation,riekf"], "out", "dir"),
        Case("batch", ["batch", str(inp / "many"), "-o", "OUT", "-j", "2", "--config", cfg], "out", "batch", False),
        Case(
            "tune",
            ["tune", str(inp / "many" / "m0.mcap"), "--observer", "fast-adaptation", "-o", "OUT", "--trials", "3"],
            "out",
            "tune",
            False,
        ),
        Case("report", ["report", "OUT"], "out", "dir", False, prepare="run-fa", needs=("run-fa",)),
        Case("simulate", ["simulate", "figure8-wide", "-o", "OUT", "--duration", "180"], "sim.mcap", "file"),
        _evaluate_case("evaluate", log, "run-fa"),
    ]
    cases += [
        Case("export", ["export", "IN/ref-run-fa/out", "-o", "OUT", "-q"], "res.mcap", "file", needs=("run-fa",)),
        Case(
            "stats",
            ["stats", "IN/ref-run-fa/out", "IN/ref-compare/out", "-o", "OUT", "-q"],
            "out",
            "dir",
            needs=("run-fa", "compare"),
        ),
        Case("info-600s", ["info", long_log], "none", "none"),
        Case("run-memory-limit", ["run", log, "-o", "OUT", "-q"], "out", "dir", wrap="memory"),
        # a cron job's timeout: TERM, then KILL soon after, to a batch whose runs draw figures in helper processes
        Case("batch-timeout", ["batch", str(inp / "many"), "-o", "OUT", "-j", "2"], "out", "batch", False),
    ]
    cases[-1].wrap = "timeout"
    cases += [  # part 4: the smoother as a tune's target, three estimators' figures, big runs, a file size limit
        Case(
            "tune-batch",
            ["tune", str(inp / "many" / "m0.mcap"), "--observer", "fast-adaptation", "--target", "batch"]
            + ["-o", "OUT", "--trials", "3"],
            "out",
            "tune",
            False,
        ),
        Case(
            "compare-3",
            ["compare", log, "-o", "OUT", "-q", "--observers", "fast-adaptation,riekf,batch"],
            "out",
            "dir",
        ),
        Case("report-600s", ["report", "OUT"], "out", "dir", False, prepare="run-fa-600s", needs=("run-fa-600s",)),
        _evaluate_case("evaluate-600s", long_log, "run-fa-600s"),
        Case(
            "batch-fsize",
            ["batch", str(inp / "many"), "-o", "OUT", "-j", "2", "--config", cfg],
            "out",
            "batch",
            False,
            wrap="fsize",
        ),
    ]
    cases[7].victims = ("worker",)  # batch (-j 2): a local worker SIGKILLed mid-log, its log runs again
    assert cases[7].name == "batch"
    many = ["batch", str(inp / "many"), "-o", "OUT", "--config", cfg, "--wait-workers", "20"]
    if dask:
        cases.append(Case("batch-dask", [*many, "--executor", "dask", "-j", "2"], "out", "batch", False))
        cases[-1].victims = ("worker",)
    if dask_cluster:
        cases.append(Case("batch-dask-cluster", [*many, "--scheduler", "SCHED"], "out", "batch", False))
        cases[-1].victims = ("worker", "scheduler")
    if realdata is not None:
        folder = str(realdata / "mrclam" / "MRCLAM_Dataset6")
        cases.append(Case("import-mrclam", ["import", "mrclam", folder, "-o", "OUT", "-q"], "r1.mcap", "file"))
    return cases


def argv_for(case: Case, tdir: Path, inp: Path, rerun: bool = False, sched: str = "", wrap=()) -> list[str]:
    out = str(tdir / case.out)
    args = [a.replace("OUT", out).replace("IN/", f"{inp}/").replace("SCHED", sched) for a in case.argv]
    if rerun and case.force and (tdir / case.out).exists():
        args.append("--force")
    return [*wrap, *CLI, *args]


#: The memory limits drawn for a run under ``prlimit --as`` (MB): from too small to start to enough for the run.
MEMORY_MB = (250, 1400)
#: A command under ``timeout -s TERM -k K DELAY`` that has not ended K seconds after the TERM gets SIGKILL (timeout
#: sends both to its process group: the batch, its workers and their figure helpers); K is drawn from this range
#: (from the delay, so that a trial's seed and delay replay it): short enough that some batches get the KILL.
KILL_AFTER_S = (0.05, 1.0)
#: The file size limits drawn for a batch under ``prlimit --fsize`` (KB, log-uniform): from too small for any run's
#: table to enough for the compacted ones (300 KB): a quota or ``ulimit -f``, as a full disk, on the whole output.
FSIZE_KB = (4, 600)


def wrapper(victim: str, sig: int, delay: float) -> list[str]:
    if victim == "timeout":
        kill_after = random.Random(delay).uniform(*KILL_AFTER_S)
        return ["timeout", "-s", signal.Signals(sig).name[3:], "-k", f"{kill_after:.2f}", f"{delay:.3f}"]
    if victim == "memory":  # delay: the limit in MB
        return ["prlimit", f"--as={int(delay) << 20}", "--"]
    if victim == "fsize":  # delay: the limit in KB
        return ["prlimit", f"--fsize={int(delay * 1024)}", "--"]
    return []


# --------------------------------------------------------------------------- what "complete" means


def _check_file(path: Path) -> str | None:
    try:
        if path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix == ".parquet":
            import pyarrow.parquet as pq

            pq.read_table(path)
        elif path.suffix == ".png":
            from PIL import Image

            with Image.open(path) as im:
                im.load()
        elif path.suffix == ".zip":
            with zipfile.ZipFile(path) as z:
                if z.testzip() is not None:
                    return f"{path.name}: bad zip member"
    except Exception as exc:  # noqa: BLE001 - any failure to open is an incomplete file
        return f"{path.name}: {type(exc).__name__}: {str(exc)[:80]}"
    return None


def check_dir(out: Path) -> list[str]:
    """A visible output directory: its manifest lists every file with its size, and each file opens."""
    bad = []
    manifest = out / "slamobs-output.json"
    if not manifest.is_file():
        return [f"{out.name}: visible without slamobs-output.json: {sorted(p.name for p in out.iterdir())[:6]}"]
    try:
        listed = json.loads(manifest.read_text())
    except ValueError as exc:
        return [f"{out.name}/slamobs-output.json: {exc}"]
    for rel, size in listed.get("files", {}).items():
        p = out / rel
        if not p.is_file() or p.stat().st_size != size:
            bad.append(f"{out.name}/{rel}: missing or size differs from the manifest")
        elif (err := _check_file(p)) is not None:
            bad.append(f"{out.name}/{err}")
    for d in listed.get("directories", []):
        if f"{d}/slamobs-output.json" in listed.get("files", {}):  # a run of a compare (stats' figures/: files)
            bad.extend(check_dir(out / d))
    return bad


def visible_violations(case: Case, tdir: Path, killed_by: int | None) -> list[str]:
    bad = []
    for p in sorted(tdir.rglob("*")):
        rel = p.relative_to(tdir)
        hidden = any(part.startswith(".") for part in rel.parts)
        in_batch_state = case.kind == "batch" and "_slamobs" in rel.parts
        if (
            hidden
            and not in_batch_state
            and killed_by in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
            and p.parent == tdir
        ):
            bad.append(f"hidden temporary left after {signal.Signals(killed_by).name}: {rel}")
    out = tdir / case.out
    if not out.exists():
        return bad
    if case.kind == "dir":
        bad.extend(check_dir(out))
    elif case.kind == "file":
        for p in [out, *tdir.glob("*.png")]:
            if (err := _check_file(p)) is not None:
                bad.append(err)
        if case.name != "evaluate" and digest_file(out) != case.ref["file"]:
            bad.append(f"{case.out}: visible but differs from the unkilled output")
    elif case.kind == "tune":
        for p in out.iterdir():
            if not p.name.startswith(".") and p.is_file() and (err := _check_file(p)) is not None:
                bad.append(f"tune/{err}")
    return bad


# --------------------------------------------------------------------------- same outputs as an unkilled run


def digest_file(path: Path) -> str:
    if path.suffix == ".zip":  # the members' contents: their stored dates are the time of writing
        with zipfile.ZipFile(path) as z:
            return hashlib.sha256(b"".join(n.encode() + z.read(n) for n in sorted(z.namelist()))).hexdigest()
    return hashlib.sha256(path.read_bytes()).hexdigest()


def digest_table(path: Path, sort: tuple[str, ...] = ()) -> str:
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    keep = _stable(table.column_names)
    df = table.select(keep).to_pandas()
    if sort:
        df = df.sort_values([c for c in sort if c in df.columns], kind="stable").reset_index(drop=True)
    df = df.drop(columns=[c for c in ("run_id",) if c in df.columns and "run_id" not in sort])
    return hashlib.sha256(df.to_csv(index=False).encode()).hexdigest()


def digest(case: Case, out: Path) -> dict[str, str]:
    if case.kind == "file":
        return {"file": digest_file(out)}
    if case.kind == "batch":
        rows = assert_consistent(out)
        d = {"ok": str(sorted(r["status"] for r in rows.values()))}
        for table in ("poses", "landmarks", "biases"):
            if (out / table).is_dir():
                d[table] = digest_table_dir(out / table)
        return d
    if case.kind == "none":
        return {}
    if case.kind == "tune":
        # a trial cut by the kill is recorded FAIL and run again with the same gains under a new number, and a
        # resumed tune draws new gains: as many complete trials, the defaults scored alike, no gains run twice
        import pandas as pd

        df = pd.read_parquet(out / "trials.parquet")
        done = df[df["state"] == "COMPLETE"]
        gains = done.drop_duplicates("trial")[[c for c in done.columns if c.startswith("gain_")]]
        return {
            "complete": str(len(gains)),
            "defaults": str(sorted(done[done["is_default"]]["objective"].round(12))),
            "distinct gains": str(not gains.duplicated().any()),
        }
    return {str(p.relative_to(out)): digest_table(p) for p in sorted(out.rglob("*.parquet"))}


def digest_table_dir(path: Path) -> str:
    import pandas as pd

    df = pd.read_parquet(path)
    df = df[_stable(df.columns)]
    df = df.sort_values([c for c in df.columns if df[c].dtype != object or c == "run_id"]).reset_index(drop=True)
    return hashlib.sha256(df.to_csv(index=False).encode()).hexdigest()


# --------------------------------------------------------------------------- one trial


def _sigint() -> None:
    # as from a terminal: a harness started in the background by a script inherits SIGINT ignored, and under
    # nohup SIGHUP ignored; an ignored signal stays ignored through exec (a SIGHUP trial then saw exit 0)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    if AUTOGROUP_NICE is not None:  # the command's new session is a scheduler autogroup of its own (Linux, as root)
        try:
            with open("/proc/self/autogroup", "w") as f:
                f.write(str(AUTOGROUP_NICE))
        except OSError:
            pass


#: ``--autogroup-nice``: the nice value of each trial's session (on a shared 2-core VM, -20 keeps its timings apart
#: from other work; docs/benchmarks.md "the hour's two cores"); None: left as it is.
AUTOGROUP_NICE: int | None = None


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")[:120]
    except OSError:
        return "?"


class Cluster:
    """A ``dask scheduler`` and two single-threaded ``dask worker`` processes (nanny and worker), each in its own
    session as on a real cluster; their logs under ``work``."""

    def __init__(self, work: Path) -> None:
        work.mkdir(parents=True, exist_ok=True)
        self.work, self.procs = work, []
        info = work / "scheduler.json"
        info.unlink(missing_ok=True)
        self.scheduler = self._spawn(
            ["scheduler", "--host", "127.0.0.1", "--port", "0", "--scheduler-file", info, "--dashboard-address", ":0"],
            "scheduler",
        )
        if not wait_for(info.is_file, 60):
            self.stop()
            raise SystemExit(f"dask scheduler did not start: {(work / 'scheduler.log').read_text()[-400:]}")
        time.sleep(0.2)
        self.address = json.loads(info.read_text())["address"]
        for i in range(2):
            self._spawn(["worker", self.address, "--nthreads", "1", "--no-dashboard", "--local-directory", work], i)

    def _spawn(self, args, tag) -> subprocess.Popen:
        with open(self.work / f"{tag}.log", "w") as fh:
            p = subprocess.Popen(
                [str(a) for a in [DASK, *args]], stdout=fh, stderr=subprocess.STDOUT, start_new_session=True
            )
        self.procs.append(p)
        return p

    def workers(self) -> list[int]:
        return [w for p in self.procs[1:] for w in children(p.pid)]

    def stop(self) -> None:
        for p in self.procs:
            for q in [*descendants(p.pid), p.pid]:
                try:
                    os.kill(q, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            p.wait()


def send(p: subprocess.Popen, victim: str, sig: int, cluster: Cluster | None) -> str:
    """Send ``sig`` to the command (its group for SIGINT/SIGHUP) or a Dask worker process or the scheduler; returns
    what was hit."""
    if victim == "scheduler":
        cluster.scheduler.send_signal(sig)
        return "scheduler"
    if victim == "worker":
        workers = cluster.workers() if cluster else [w for n in children(p.pid) for w in [n, *children(n)]]
        workers = [w for w in workers if "spawn_main" in _cmdline(w)]  # not multiprocessing's resource tracker
        if workers:
            w = random.Random(p.pid).choice(workers)
            os.kill(w, sig)
            return f"worker {w}"
        return "no worker yet"
    if victim == "group":  # a job control kill %1, systemd's KillMode=control-group, a cluster's job killer
        os.killpg(p.pid, sig)
        return "group"
    (os.killpg if sig in GROUP_SIGNALS else os.kill)(p.pid, sig)
    return "command"


#: A signal this early may reach the interpreter before Python installs any handler: the kernel's default action
#: ends it (``-sig`` here, ``128 + sig`` in a shell), before any work; what is visible is checked as always.
INTERPRETER_START_S = 0.1


def _expected(victim: str, sig: int, starting: bool, delay: float = 1.0) -> set:
    if victim == "timeout":  # the command ended on the TERM (124) or needed the KILL, which timeout also sends its
        return {0, 124, 128 + signal.SIGKILL, -signal.SIGKILL}  # own group: itself killed (-9, 137 in a shell)
    if victim == "memory":  # it fits, or one line with exit 2
        return {0, 2}
    if victim == "fsize":  # it fits, or the machine failed its runs or summary: not recorded, exit 3
        return {0, 3}
    if victim in ("command", "group") and delay < INTERPRETER_START_S:
        return {-signal.SIGKILL} if sig == signal.SIGKILL else {128 + sig, -sig}
    if victim == "worker":  # its log runs again; a LocalCluster whose worker is killed as it starts starts it
        return {0}  # again (kill6: was exit 3, "cannot start"); an external cluster's other worker runs the logs
    if victim == "scheduler":
        return {3}  # a lost cluster
    return {-signal.SIGKILL} if sig == signal.SIGKILL else {128 + sig}


def _hit(res: dict) -> bool:
    """The signal reached a live process (not: the command had ended, or had no Dask / local worker yet)."""
    return res["signalled"] and res.get("hit") != "no worker yet"


def trial(
    case: Case, sig: int, delay: float, tdir: Path, inp: Path, victim: str = "command", retry: bool = False
) -> dict:
    """One kill and the rerun after it; with ``retry``, a command that ended before its signal is not run again
    (the trial is drawn again with a new delay)."""
    tdir.mkdir(parents=True)
    if case.prepare:
        shutil.copytree(inp / f"ref-{case.prepare}" / "out", tdir / case.out)
    cluster = Cluster(tdir.parent / f"{tdir.name}.dask") if "SCHED" in case.argv else None
    res = {"rc": None, "signalled": False, "violations": [], "victim": victim}
    try:
        _run_killed(case, sig, delay, tdir, inp, victim, cluster, res)
        if retry and not _hit(res):
            return res
        if victim == "scheduler" and res["signalled"]:  # the rerun needs a cluster again
            cluster.stop()
            cluster = Cluster(tdir.parent / f"{tdir.name}.dask2")
        _rerun(case, tdir, inp, cluster, res)
    finally:
        if cluster:
            cluster.stop()
            shutil.rmtree(cluster.work, ignore_errors=True)
    return res


def _run_killed(case, sig, delay, tdir, inp, victim, cluster, res) -> None:
    err = tdir.parent / f"{tdir.name}.err"
    sched = cluster.address if cluster else ""
    wrap = wrapper(victim, sig, delay)
    with open(err, "w") as fh:
        p = subprocess.Popen(
            argv_for(case, tdir, inp, sched=sched, wrap=wrap),
            stdout=subprocess.DEVNULL,
            stderr=fh,
            start_new_session=True,
            preexec_fn=_sigint,
            env=case.env(tdir),
        )
    t0 = time.monotonic()
    bound = HANG_S if victim in ("command", "group") else LOST_S
    if wrap:  # the wrapper sends the signal (or sets the limit): its exit code says what happened
        bound = delay + HANG_S if victim == "timeout" else HANG_S * 10
    else:
        try:
            p.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            res["signalled"] = True
            res["starting"] = "to run on" not in err.read_text()  # the batch's first line: its cluster is up
            res["hit"] = send(p, victim, sig, cluster)
    try:
        res["rc"] = p.wait(timeout=bound)
    except subprocess.TimeoutExpired:
        res["violations"].append(f"hung: alive {bound:.0f} s after {signal.Signals(sig).name} of the {victim}")
        os.killpg(p.pid, signal.SIGKILL)
        res["rc"] = p.wait()
    if wrap:
        res["signalled"] = victim in ("memory", "fsize") or res["rc"] != 0
        res["starting"], res["hit"] = False, victim
        delay = delay if victim == "timeout" else 0.0  # no signal sent
    res["exit_s"] = time.monotonic() - t0 - delay if res["signalled"] else 0.0
    res["ran_s"] = time.monotonic() - t0  # unkilled duration when it ended before the signal
    deadline = time.monotonic() + LINGER_S
    while (left := session_alive(p.pid)) and time.monotonic() < deadline:
        time.sleep(0.05)
    if left:
        res["violations"].append(
            f"{len(left)} processes of the session alive {LINGER_S:g} s later: "
            + "; ".join(_cmdline(q) for q in left[:3])
        )
        for q in left:
            try:
                os.kill(q, signal.SIGKILL)
            except ProcessLookupError:
                pass
    tail = err.read_text().strip().splitlines()[-1:] if err.exists() else []
    res["tail"] = tail
    if err.exists() and any(t in err.read_text() for t in ("Traceback", "Exception ignored")):
        text = err.read_text()  # a user-facing error is one line (a batch: its rows and one line), never a traceback
        res["violations"].append(f"a traceback on stderr: {text[text.find('Traceback') :][:160]!r}")
    if res["signalled"] and res.get("hit") != "no worker yet":
        if res["rc"] not in _expected(victim, sig, res["starting"], delay):
            res["violations"].append(f"exit code {res['rc']} after {signal.Signals(sig).name} of the {victim}: {tail}")
    elif res["rc"] != 0:
        res["violations"].append(f"exit code {res['rc']} without a signal: {err.read_text()[-200:]}")
    if victim == "memory" and res["rc"] == 2:  # one line, naming the machine's failure: not a traceback
        lines = err.read_text().strip().splitlines()
        if len(lines) != 1 or not lines[0].startswith("error:") or not ("memory" in lines[0] or "thread" in lines[0]):
            res["violations"].append(f"not one line naming the memory limit: {lines[-3:]}")
    killed_by = signal.SIGKILL if res["rc"] in (-signal.SIGKILL, 128 + signal.SIGKILL) else sig
    res["violations"].extend(visible_violations(case, tdir, killed_by if res["signalled"] else None))
    if case.kind == "batch" and res["rc"] != -signal.SIGKILL and (tdir / case.out / "summary.parquet").exists():
        try:  # a batch that ended by itself (signal handled, lost cluster) leaves its dataset consistent
            assert_consistent(tdir / case.out)
        except Exception as exc:  # noqa: BLE001 - shown as a violation
            res["violations"].append(f"inconsistent after rc {res['rc']}: {type(exc).__name__}: {str(exc)[:120]}")
            shutil.copytree(tdir / case.out, tdir.parent / f"{tdir.name}.inconsistent")  # before the rerun mends it


def _rerun(case, tdir, inp, cluster, res) -> None:
    argv = argv_for(case, tdir, inp, rerun=True, sched=cluster.address if cluster else "")
    t0 = time.monotonic()
    rerun = subprocess.run(argv, capture_output=True, text=True, timeout=900, env=case.env(tdir))
    if rerun.returncode == 0 and case.kind in ("dir", "file") and not case.cold:  # a whole run again (batch, tune:
        # a resume; a cold case's rerun loads what the killed run compiled)
        case.observe(time.monotonic() - t0)
    if rerun.returncode != 0:
        res["violations"].append(f"rerun exit {rerun.returncode}: {rerun.stderr.strip().splitlines()[-1:]}")
        return
    try:
        got = digest(case, tdir / case.out)
        diff = sorted(k for k in case.ref if got.get(k) != case.ref[k])
        if diff:
            res["violations"].append(f"rerun differs from the unkilled run in {diff[:4]}")
    except Exception as exc:  # noqa: BLE001 - a failed check is a violation, shown
        res["violations"].append(f"rerun inconsistent: {type(exc).__name__}: {str(exc)[:120]}")


# --------------------------------------------------------------------------- set-up and main


def make_inputs(inp: Path) -> None:
    def sim(scenario: str, duration: int, out: Path, seed: int = 0) -> None:
        if not out.exists():
            cmd = [*CLI, "simulate", scenario, "-o", str(out), "--duration", str(duration), "--seed", str(seed)]
            subprocess.run(cmd, check=True, capture_output=True)

    inp.mkdir(parents=True, exist_ok=True)
    sim("figure8-wide", 180, inp / "f180.mcap")
    sim("figure8-wide", 600, inp / "f600.mcap")
    for i in range(3):
        sim(("circle", "figure8")[i % 2], 20, inp / "many" / f"m{i}.mcap", seed=70 + i)
    (inp / "noplots.yaml").write_text("evaluation:\n  plots: false\n")


def measure(case: Case, inp: Path) -> None:
    """The unkilled run: its duration (the delays are drawn over it) and its outputs (the reference)."""
    cluster = Cluster(inp / "measure.dask") if "SCHED" in case.argv else None
    try:
        for tag in ("warm", "ref"):  # the first compiles or loads the kernels and reads the log into the page cache
            tdir = inp / f"{tag}-{case.name}"
            shutil.rmtree(tdir, ignore_errors=True)
            tdir.mkdir()
            if case.prepare:
                shutil.copytree(inp / f"ref-{case.prepare}" / "out", tdir / case.out)
            t = time.monotonic()
            shutil.rmtree(tdir.parent / f"{tdir.name}.numba", ignore_errors=True)  # a cold case: a first run
            r = subprocess.run(
                argv_for(case, tdir, inp, sched=cluster.address if cluster else ""),
                capture_output=True,
                text=True,
                env=case.env(tdir),
            )
            took = time.monotonic() - t
            if r.returncode != 0:
                raise SystemExit(f"{case.name}: the unkilled run failed: {r.stderr[-400:]}")
    finally:
        if cluster:
            cluster.stop()
    case.durations = [took]
    case.ref = digest(case, tdir / case.out)


def drawn_trial(case: Case, rng: random.Random, signals, args, tdir: Path, inp: Path) -> tuple[int, float, dict]:
    """A trial at a delay drawn over ``--span`` of the case's median unkilled duration; a command that ended
    before its signal (a loaded VM's durations vary) adds its duration to the median and is tried again at a new
    delay, up to ``--retries`` times: the trials test a live process."""
    sig = rng.choice(signals)
    victim = "command"
    if case.victims and rng.random() < 0.5:  # half of a Dask case's trials kill a worker or the scheduler
        victim, sig = rng.choice(case.victims), signal.SIGKILL
    elif sig in (signal.SIGTERM, signal.SIGKILL) and rng.random() < args.group:
        victim = "group"  # the whole process group at once: workers and helpers get it beside their parent
    if case.wrap:
        victim, sig = case.wrap, signal.SIGTERM
    for attempt in range(args.retries + 1):
        delay = rng.uniform(0.0, case.duration * args.span)
        if victim == "memory":
            delay = rng.uniform(*MEMORY_MB)
        if victim == "fsize":
            delay = math.exp(rng.uniform(*map(math.log, FSIZE_KB)))
        r = trial(case, sig, delay, tdir, inp, victim, retry=attempt < args.retries)
        r["attempts"] = attempt + 1
        if _hit(r) or r["violations"]:
            break
        if r["rc"] == 0:  # it ran to its end: an unkilled duration
            case.observe(r["ran_s"])
        if attempt < args.retries:
            shutil.rmtree(tdir, ignore_errors=True)
            shutil.rmtree(tdir.parent / f"{tdir.name}.numba", ignore_errors=True)  # a cold case starts cold again
    return sig, delay, r


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=None, help="trials in total, spread over the cases (one each)")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--only", default=None, help="comma-separated case names")
    ap.add_argument("--dask", action="store_true", help="also batch --executor dask (a LocalCluster)")
    ap.add_argument("--dask-cluster", action="store_true", help="also batch on a dask scheduler + 2 workers")
    ap.add_argument(
        "--span",
        type=float,
        default=0.9,
        help="delays drawn over this fraction of the median unkilled duration (the reference run, the reruns and "
        "the trials that ended before their signal)",
    )
    ap.add_argument(
        "--group",
        type=float,
        default=0.3,
        help="this fraction of the SIGTERM / SIGKILL trials send it to the whole process group, not only the command",
    )
    ap.add_argument(
        "--retries",
        type=int,
        default=2,
        help="a trial whose command ended before its signal is drawn again at most this many times",
    )
    ap.add_argument("--signals", default="TERM,INT,KILL", help="drawn from for the command: TERM,INT,KILL,HUP")
    ap.add_argument("--cache", type=Path, default=None, help="keep the generated logs and references here")
    ap.add_argument("--autogroup-nice", type=int, default=None, help="nice value of each trial's session (root)")
    args = ap.parse_args()
    global AUTOGROUP_NICE
    AUTOGROUP_NICE = args.autogroup_nice
    seed = args.seed if args.seed is not None else random.randrange(2**32)
    realdata = Path(os.environ["SLAMOBS_REALDATA"]) if os.environ.get("SLAMOBS_REALDATA") else None
    with tempfile.TemporaryDirectory(prefix="kill_matrix-") as tmp:
        inp = args.cache or Path(tmp) / "in"
        make_inputs(inp)
        cases = make_cases(inp, realdata, args.dask, args.dask_cluster)
        signals = [signal.Signals["SIG" + name.strip().upper()] for name in args.signals.split(",")]
        if args.only:
            chosen = [c for c in cases if c.name in args.only.split(",")]
            needed = {n for c in chosen for n in c.needs}
            for c in cases:  # the references a chosen case reads, made if missing
                if c.name in needed and c not in chosen and not (inp / f"ref-{c.name}").is_dir():
                    measure(c, inp)
            cases = chosen
        for c in cases:
            measure(c, inp)
            print(f"{c.name}: {c.duration:.1f} s unkilled", flush=True)
        print(f"seed {seed}; load average {os.getloadavg()[0]:.2f} (2 cores)", flush=True)
        results: dict[str, list] = {c.name: [] for c in cases}
        for k in range(args.trials or len(cases)):
            case = cases[k % len(cases)]
            rng = random.Random(f"{seed}-{k // len(cases)}-{case.name}")
            tdir = Path(tmp) / "t" / f"{k}"
            sig, delay, r = drawn_trial(case, rng, signals, args, tdir, inp)
            results[case.name].append((sig, r))
            mark = "OK" if not r["violations"] else "VIOLATION"
            what = (
                f"{delay:.0f} MB address space"
                if r["victim"] == "memory"
                else f"{delay:.0f} KB file size limit"
                if r["victim"] == "fsize"
                else f"{signal.Signals(sig).name}@{delay:.2f}s"
            )
            print(
                f"trial {k} {case.name} {what} of the {r.get('hit', r['victim'])} "
                + (f"(draw {r['attempts']}, median {case.duration:.1f} s) " if r["attempts"] > 1 else "")
                + f"rc={r['rc']} "
                f"exit+{r['exit_s']:.2f}s {mark} {'; '.join(r['violations'])}"
                + (f" ({' '.join(r['tail'])[:100]})" if r["victim"] != "command" and r["signalled"] else ""),
                flush=True,
            )
            if r["violations"] and args.cache:  # kept for a look: the trial's output and the command's stderr
                keep = args.cache.parent / f"violation-{seed}-{k}"
                shutil.copytree(tdir, keep, dirs_exist_ok=True)
                shutil.copy(tdir.parent / f"{k}.err", keep / "stderr.txt")
                if (tdir.parent / f"{k}.inconsistent").is_dir():
                    shutil.copytree(tdir.parent / f"{k}.inconsistent", keep / "as-left")
                print(f"  kept in {keep}", flush=True)
            shutil.rmtree(tdir, ignore_errors=True)
            shutil.rmtree(tdir.parent / f"{tdir.name}.numba", ignore_errors=True)
        report(results, seed, signals)


#: Who got the signal besides the command alone, in the table's column (a wrapper's trials: the memory limit drawn
#: for ``prlimit``, the ``timeout`` command's TERM and KILL).
OTHER_VICTIMS = ("group", "worker", "scheduler", "timeout", "memory", "fsize")


def report(results: dict[str, list], seed: int, signals) -> None:
    print(f"\nseed {seed}; load average {os.getloadavg()[0]:.2f}\n")
    names = " / ".join(s.name for s in signals)
    print(
        f"| command | trials | {names} of the command | to the group; Dask worker / scheduler; timeout; memory / file "
        "size limit "
        "| hit a live process | drawn again | ended first | exit codes | slowest exit after signal | violations |\n"
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    )
    total = 0
    for name, rs in results.items():
        n = [sum(1 for s, r in rs if s == sig and r["victim"] in ("command", "group")) for sig in signals]
        other = ", ".join(f"{v} {k}" for v in OTHER_VICTIMS if (k := sum(1 for _, r in rs if r["victim"] == v)))
        codes = ", ".join(sorted({str(r["rc"]) for _, r in rs}))
        timed = [(s, r) for s, r in rs if r["signalled"] and r["victim"] not in ("memory", "fsize")]  # no signal
        slow = max((r["exit_s"] for s, r in timed if s != signal.SIGKILL or r["victim"] == "scheduler"), default=0.0)
        bad = sum(1 for _, r in rs if r["violations"])
        total += bad
        first = sum(1 for _, r in rs if not r["signalled"])
        hit = sum(1 for _, r in rs if _hit(r))
        again = sum(r["attempts"] - 1 for _, r in rs)
        counts = " / ".join(map(str, n))
        print(
            f"| {name} | {len(rs)} | {counts} | {other or '–'} | {hit} | {again} | {first} | {codes} "
            f"| {slow:.2f} s | {bad} |"
        )
    print(f"\n{total} trials with violations")
    sys.exit(1 if total else 0)


if __name__ == "__main__":
    main()
