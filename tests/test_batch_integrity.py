"""Batch dataset integrity: records, commit and reconciliation, compaction, identity by content, pruning,
timeouts and dying workers, hostile inputs (FIFO, symbolic link loop).

Most tests run the batch machinery with :func:`fake_pipeline` in the workers (a run directory with tables
derived from the log's bytes, in milliseconds): what is under test is staging, commit, records and
compaction, which are the same whatever the observer computes. One test salvages a real truncated log.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from slamobs.pipeline.batch import BatchOptions, discover, run_batch
from slamobs.pipeline.batch.executor import Task, base_row, run_task
from slamobs.pipeline.batch.ledger import Ledger, read_summary
from slamobs.pipeline.config import EvaluationConfig, RunConfig

from batch_checks import alive, assert_consistent

TABLES = ("poses", "biases")


def fake_pipeline(log: Path, out_dir: Path, config):
    """Worker-side stand-in for the observer pipeline: ``poses`` and ``biases`` with a row count and values
    that depend on the log's bytes; logs named ``bad*`` fail, ``salvaged*`` ones carry a reader warning."""
    from types import SimpleNamespace

    from slamobs.pipeline.writers import atomic_directory, write_json, write_tables
    from slamobs.schemas import arrow_schema

    data = Path(log).read_bytes()
    if Path(log).name.startswith("bad"):
        raise ValueError("cannot decode")
    n = 20 + data[0] % 17
    rng = np.random.default_rng(int.from_bytes(data[:4], "little"))
    tables = {
        name: {
            f.name: (np.arange(n, dtype=np.int64) * 5_000_000 if f.name == "t_ns" else rng.normal(size=n))
            for f in arrow_schema(name)
        }
        for name in TABLES
    }
    meta = {
        "counts": {"velocity_samples": n, "detection_frames": 0, "detections": 0, "landmarks": 0, "internal_steps": n}
    }
    with atomic_directory(out_dir) as tmp:
        write_tables(tmp, tables, meta)
        write_json(tmp / "run.json", meta)
    warnings = (
        [f"{log}: incomplete (truncated): recovered {n} messages"] if Path(log).name.startswith("salvaged") else []
    )
    # a RunSummary's fields; its own status says nothing against the estimate
    summary = SimpleNamespace(metadata=meta, timings={"read_s": 0.001}, headline=dict, status=lambda: "ok")
    return summary, warnings


FAKE = partial(run_task, pipeline=fake_pipeline)


def make_logs(root: Path, names, seed: int = 0) -> list[Path]:
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in names:
        p = root / name
        p.write_bytes(rng.bytes(64))
        paths.append(p)
    return paths


def batch(inputs, out: Path, jobs: int = 1, **kwargs):
    return run_batch(discover(inputs), BatchOptions(out=out, jobs=jobs, **kwargs), run=FAKE)


def raced_pipeline(log: Path, out_dir: Path, config):
    """:func:`fake_pipeline`, but while a log named ``raced*`` runs a user's file appears in its run directory of
    the dataset (``out_dir`` is ``OUT/_slamobs/staging/<batch>/<run_id>/run``)."""
    run_id = out_dir.parent.name
    if Path(log).name.startswith("raced"):
        final = out_dir.parents[4] / "runs" / run_id
        final.mkdir(parents=True, exist_ok=True)
        (final / "notes.txt").write_text("mine")
    return fake_pipeline(log, out_dir, config)


# --- records ------------------------------------------------------------------------------------------------


def test_records_append_survive_a_torn_line_and_compact(tmp_path):
    led = Ledger(tmp_path)
    led.put({"run_id": "a", "status": "ok", "total_s": 1.0})
    led.put({"run_id": "b", "status": "failed", "error": "x: bad"})
    led.drop("a")
    led.put({"run_id": "c", "status": "ok", "total_s": float("nan")})
    assert set(read_summary(tmp_path)) == {"b", "c"}  # readable mid-batch, before any summary.parquet
    led.close()
    (rec,) = (tmp_path / "_slamobs").glob("records-*.jsonl")
    with open(rec, "ab") as fh:
        fh.write(b'{"op": "put", "row": {"run_id": "torn"')  # a writer killed mid-line
    led = Ledger(tmp_path)
    assert set(led.rows) == {"b", "c"} and led.rows["c"]["total_s"] is None
    led.put({"run_id": "d", "status": "ok"})  # appended after the cut-off torn line, readable
    assert set(read_summary(tmp_path)) == {"b", "c", "d"}
    led.compact()
    led.put({"run_id": "e", "status": "ok"})
    led.close()
    assert [p.name for p in (tmp_path / "_slamobs").glob("records-*.jsonl")] == ["records-000001.jsonl"]
    assert set(Ledger(tmp_path).rows) == set(read_summary(tmp_path)) == {"b", "c", "d", "e"}


def test_summary_is_rewritten_every_second_or_at_most_a_twentieth_of_the_time(tmp_path):
    """A batch killed by SIGKILL left a summary up to 30 s behind its tables (7 runs in the tables, none in the
    summary); now the wait between rewrites follows what a rewrite costs, from 1 s up to 30 s."""
    from slamobs.pipeline.batch.ledger import REFRESH_COST, REFRESH_MIN_S, REFRESH_S

    led = Ledger(tmp_path)
    assert led.refresh_every() == REFRESH_MIN_S == 1.0
    for i in range(3):
        led.put({"run_id": f"r{i}", "status": "ok"})
        led.compact()
    assert led.rewrites == 3 and 0 < led.compact_s < 1  # measured from the second rewrite on
    led.compact_s = 0.2  # a large summary
    assert led.refresh_every() == pytest.approx(REFRESH_COST * 0.2) and REFRESH_COST * 0.2 > REFRESH_MIN_S
    led.compact_s = 10.0
    assert led.refresh_every() == REFRESH_S
    led.close()


# --- identity: moved, copied, changed logs; hash cache; prune ----------------------------------------------


def test_moved_log_is_neither_rerun_nor_duplicated_and_hashes_are_cached(tmp_path, monkeypatch):
    import slamobs.pipeline.batch.identity as identity

    a, b, c = make_logs(tmp_path / "in", ["a.mcap", "b.mcap", "c.mcap"])
    out = tmp_path / "OUT"
    first = batch([tmp_path / "in"], out)
    assert [r["status"] for r in first.rows] == ["ok"] * 3
    before = assert_consistent(out)

    hashed = []
    real = identity.content_hash
    monkeypatch.setattr(identity, "content_hash", lambda p: hashed.append(p) or real(p))
    moved = tmp_path / "elsewhere" / "renamed.mcap"
    moved.parent.mkdir()
    os.replace(a, moved)  # same file system: same inode, recognised without reading it
    again = batch([tmp_path / "in", moved], out)
    assert [r["status"] for r in again.rows] == ["skipped"] * 3 and hashed == []
    after = assert_consistent(out)
    assert set(after) == set(before)  # same run_ids: nothing re-run, nothing added
    rid = next(r for r, row in before.items() if row["log"] == str(a))
    assert after[rid]["log"] == str(moved) and after[rid]["finished_at"] == before[rid]["finished_at"]

    shutil.copy(b, tmp_path / "copy_of_b.mcap")  # a copy: hashed (new inode), same content -> same run
    again = batch([tmp_path / "copy_of_b.mcap"], out)
    assert [r["status"] for r in again.rows] == ["skipped"] and len(hashed) == 1
    assert set(assert_consistent(out)) == set(before)

    # a new recording where the moved one was: a new run; the moved one stays, recorded at its new place
    a.write_bytes(b"new recording" * 10)
    again = batch([a, moved], out)
    assert [r["status"] for r in again.rows] == ["ok", "skipped"] and again.rows[1]["run_id"] == rid
    rows = assert_consistent(out)
    assert len(rows) == 4 and rows[rid]["log"] == str(moved) and rows[again.rows[0]["run_id"]]["log"] == str(a)


def test_a_copy_under_another_name_in_the_same_first_batch_is_run_and_stored_once(tmp_path):
    # a night's folder held fig8-3991.mcap and a copy of it named unreadable.mcap: the first batch ran both and
    # stored the same run twice (unreadable-<key> and fig8-3991-<key>, the same poses); docs/batch.md: never twice
    (a,) = make_logs(tmp_path / "in", ["fig8.mcap"])
    shutil.copy(a, tmp_path / "in" / "zz_copy.mcap")
    out = tmp_path / "OUT"
    res = batch([tmp_path / "in"], out)
    assert [r["status"] for r in res.rows] == ["ok", "skipped"]
    assert res.rows[1]["run_id"] == res.rows[0]["run_id"] and str(a) in res.rows[1]["error"]
    assert list(assert_consistent(out)) == [res.rows[0]["run_id"]]


def test_changed_log_replaces_its_run_and_prune_drops_runs_of_gone_logs(tmp_path):
    a, b, c = make_logs(tmp_path / "in", ["a.mcap", "b.mcap", "c.mcap"])
    out = tmp_path / "OUT"
    batch([tmp_path / "in"], out)
    old = {row["log"]: rid for rid, row in read_summary(out).items()}
    a.write_bytes(b"re-recorded" + a.read_bytes())
    res = batch([a], out)
    (row,) = res.rows
    assert row["status"] == "ok" and row["run_id"] != old[str(a)]
    rows = assert_consistent(out)
    assert old[str(a)] not in rows and len(rows) == 3

    c.unlink()
    res = batch([a], out)  # without --prune, runs of logs outside the batch are kept
    assert len(assert_consistent(out)) == 3 and res.pruned == []
    res = batch([a], out, prune=True)
    assert res.pruned == [old[str(c)]]
    assert set(assert_consistent(out)) == {row["run_id"], old[str(b)]}


def test_skip_failed_does_not_retry_a_failed_log(tmp_path):
    make_logs(tmp_path / "in", ["bad.mcap", "good.mcap"])
    out = tmp_path / "OUT"
    res = batch([tmp_path / "in"], out)
    assert [r["status"] for r in res.rows] == ["failed", "ok"] and res.exit_code == 1
    assert "ValueError: cannot decode" in res.rows[0]["error"]
    res = batch([tmp_path / "in"], out, skip_failed=True)
    assert [r["status"] for r in res.rows] == ["skipped", "skipped"] and res.exit_code == 0
    assert res.rows[0]["error"].startswith("not retried (--skip-failed)")
    res = batch([tmp_path / "in"], out)
    assert [r["status"] for r in res.rows] == ["failed", "skipped"] and res.exit_code == 1
    rows = assert_consistent(out)
    assert sorted(r["status"] for r in rows.values()) == ["failed", "ok"]


def test_salvaged_log_is_ok_with_its_warnings_counted(tmp_path):
    make_logs(tmp_path / "in", ["salvaged.mcap", "clean.mcap"])
    out = tmp_path / "OUT"
    res = batch([tmp_path / "in"], out)
    clean, salvaged = res.rows
    assert salvaged["status"] == clean["status"] == "ok" and res.warned == 1
    assert salvaged["warning_count"] == 1 and "incomplete (truncated)" in salvaged["warnings"]
    assert clean["warning_count"] == 0 and clean["warnings"] is None
    assert read_summary(out)[salvaged["run_id"]]["warning_count"] == 1


def test_truncated_real_log_is_salvaged_with_a_warning(tmp_path):
    from slamobs.pipeline.simulate import simulate, write_log

    log = write_log(simulate("circle", duration=4.0, seed=3), tmp_path / "full.mcap")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: log.stat().st_size * 2 // 3])
    (tmp_path / "stage").mkdir()
    task = Task.make(
        "cut-0",
        str(cut),
        str(tmp_path),
        RunConfig(evaluation=EvaluationConfig(plots=False)),
        staged=str(tmp_path / "stage" / "cut-0"),
    )
    row = run_task(task)
    assert row["status"] == "ok" and row["warning_count"] >= 1
    assert "incomplete" in row["warnings"] and "recovered" in row["warnings"]


# --- commit, reconciliation, compaction ---------------------------------------------------------------------


def _stage(out: Path, log: Path, rid: str) -> tuple[Path, dict]:
    """A run staged by a worker, as a batch killed before its commit would leave it."""
    staged = out / "_slamobs" / "staging" / "dead-batch" / rid
    staged.parent.mkdir(parents=True, exist_ok=True)
    from slamobs.pipeline.batch import content_hash
    from slamobs.pipeline.batch.runner import config_hash

    task = Task.make(
        rid,
        str(log),
        str(out),
        RunConfig(),
        staged=str(staged),
        content_hash=content_hash(log),
        config_hash=config_hash(RunConfig()),
    )
    return staged, FAKE(task)


def test_reconcile_adopts_complete_runs_and_removes_partial_ones(tmp_path):
    from slamobs.pipeline.batch.dataset import commit_run
    from slamobs.pipeline.stored_runs import partition_file, run_dir

    logs = make_logs(tmp_path / "in", [f"l{i}.mcap" for i in range(4)])
    out = tmp_path / "OUT"
    batch(logs[:2], out, compact=False)
    recorded = assert_consistent(out)
    # 1. committed but not recorded (killed between the renames and the record): adopted
    staged, row = _stage(out, logs[2], "adopt-me")
    commit_run(out, staged, "adopt-me", ["poses", "biases"])
    # 2. killed in the middle of a commit: one table renamed, no run directory: removed
    staged, _ = _stage(out, logs[3], "half")
    os.makedirs(partition_file(out, "poses", "half").parent)
    os.replace(staged / "poses.parquet", partition_file(out, "poses", "half"))
    # 3. a run directory without its batch.json, 4. a staged run never committed, 5. a recorded run whose
    # partition someone deleted: removed, dropped from the record, and run again by the next batch
    (run_dir(out, "orphan-dir")).mkdir()
    _stage(out, logs[3], "never-committed")
    victim = sorted(recorded)[0]
    partition_file(out, "biases", victim).unlink()

    res = batch(logs, out, compact=False)
    assert res.reconciled.adopted == ["adopt-me"] and res.reconciled.dropped == [victim]
    assert set(res.reconciled.removed) >= {"half", "orphan-dir", victim} - {victim}
    statuses = {r["run_id"]: r["status"] for r in res.rows}
    assert statuses[victim] == "ok" and statuses["adopt-me"] == "skipped"  # run again / adopted as done
    rows = assert_consistent(out)
    assert "adopt-me" in rows and rows["adopt-me"]["status"] == "ok"
    assert not any(n in rows for n in ("half", "orphan-dir", "never-committed"))


def test_compaction_keeps_every_row_and_run_id_and_survives_a_kill(tmp_path):
    import pandas as pd

    from slamobs.pipeline.batch.compact import JOURNAL, compact_dataset, finish_compaction
    from slamobs.pipeline.batch.dataset import DatasetIndex, batch_lock

    logs = make_logs(tmp_path / "in", [f"l{i:02d}.mcap" for i in range(12)])
    out = tmp_path / "OUT"
    batch(logs, out, compact=False)
    before = pd.read_parquet(out / "poses").sort_values(["run_id", "t_ns"], ignore_index=True)
    assert len(list((out / "poses").iterdir())) == 12

    def frame():
        df = pd.read_parquet(out / "poses").sort_values(["run_id", "t_ns"], ignore_index=True)
        df["run_id"] = df["run_id"].astype(str)
        return df

    # a compaction killed after its journal and one rename: rolled back, the partitions intact
    with batch_lock(out):
        compact_dataset(out, file_rows=150, group_rows=64)
    files = sorted(p.name for p in (out / "poses").iterdir())
    assert all(f.startswith("compacted-") for f in files) and 2 <= len(files) < 12
    pd.testing.assert_frame_equal(frame(), before.assign(run_id=before["run_id"].astype(str)))
    index = DatasetIndex.scan(out)
    assert set().union(*index.compacted["poses"].values()) == set(read_summary(out))

    # --force of a run inside a compacted file: its rows leave that file, the new ones come in once
    res = batch(logs[:1], out, force=True, compact=False)
    assert res.rows[0]["status"] == "ok"
    assert_consistent(out)

    # a killed compaction: journal written, renames half done -> rolled back; all done -> completed
    more = make_logs(tmp_path / "more", ["m1.mcap", "m2.mcap"], seed=5)
    batch(more, out, compact=False)
    snapshot = frame()
    from slamobs.pipeline.batch import compact as compact_mod

    real_apply = compact_mod.apply_journal
    compact_mod.apply_journal = lambda o: (_ for _ in ()).throw(KeyboardInterrupt)  # journal written, nothing renamed
    try:
        with pytest.raises(KeyboardInterrupt), batch_lock(out):
            compact_dataset(out, file_rows=150, group_rows=64)
    finally:
        compact_mod.apply_journal = real_apply
    assert (out / "_slamobs" / JOURNAL).is_file()
    finish_compaction(out)
    assert not (out / "_slamobs" / JOURNAL).exists()
    pd.testing.assert_frame_equal(frame(), snapshot)
    res = batch(logs + more, out)  # compacts at its end
    assert {r["status"] for r in res.rows} == {"skipped"}
    assert all(p.name.startswith("compacted-") for p in (out / "poses").iterdir())
    pd.testing.assert_frame_equal(frame(), snapshot)
    assert_consistent(out)


def _as_reported(out: Path, rid: str, rmse: float) -> None:
    """What `slamobs report` leaves in a batch run directory before the dataset follows: report.json and an
    aligned table (here the run's poses, shifted by ``rmse``), and the run's marker."""
    import json

    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    from slamobs.pipeline.stored_runs import run_tables

    poses = run_tables(out / "runs" / rid)["poses"]
    poses = poses.set_column(1, poses.field(1), pc.add(poses.column("x"), rmse))  # x shifted by rmse
    pq.write_table(poses, out / "runs" / rid / "poses_aligned.parquet")
    (out / "runs" / rid / "report.json").write_text(json.dumps({"ape": {"translation_m": {"rmse": rmse}}}))
    (out / "_slamobs" / "reports").mkdir(exist_ok=True)
    (out / "_slamobs" / "reports" / rid).touch()


def test_a_report_switch_killed_at_any_rename_never_shows_a_run_twice(tmp_path, monkeypatch):
    """The rows of a re-reported batch run, in a compacted file alone (deleted) or with others (rewritten):
    killed at each rename of the switch, readers see the run once or not at all; the next writer completes it."""
    import pandas as pd

    from slamobs.pipeline.batch import compact_batch, compact_dataset
    from slamobs.pipeline.batch.dataset import batch_lock
    from slamobs.pipeline.batch.rereport import sync_run

    class Killed(BaseException):
        pass

    base = tmp_path / "base"
    batch(make_logs(tmp_path / "in", ["a.mcap", "b.mcap"]), base)
    a, b = sorted(read_summary(base))
    for rid, rmse in ((a, 1.0), (b, 2.0)):  # both runs get aligned rows, compacted into one file
        _as_reported(base, rid, rmse)
        with batch_lock(base):
            sync_run(base, rid, Ledger(base))
    with batch_lock(base):
        compact_dataset(base, file_rows=1)  # one run per file: the kill matrix covers a file that is deleted
    assert len(list((base / "poses_aligned").glob("compacted-*"))) == 2

    def aligned(out):
        df = pd.read_parquet(out / "poses_aligned")
        df["run_id"] = df["run_id"].astype(str)
        assert not df.duplicated(["run_id", "t_ns"]).any()
        return df

    before = aligned(base).sort_values(["run_id", "t_ns"], ignore_index=True)
    old_a, old_b = before[before["run_id"] == a], before[before["run_id"] == b]
    new_a = old_a.assign(x=old_a["x"] + 2.0)  # reported again with 3.0 instead of 1.0
    real = os.replace
    for kill_at in range(4):  # the journal, the new partition, batch.json, the summary
        out = tmp_path / f"k{kill_at}"
        shutil.copytree(base, out)
        _as_reported(out, a, 3.0)
        calls = []

        def replace(src, dst, *args, **kwargs):
            calls.append(dst)
            if len(calls) > kill_at:
                raise Killed  # like SIGKILL: nothing after it runs (no clean-up code catches a BaseException here)
            return real(src, dst, *args, **kwargs)

        monkeypatch.setattr(os, "replace", replace)
        with pytest.raises(Killed), batch_lock(out):
            sync_run(out, a, Ledger(out))
        monkeypatch.setattr(os, "replace", real)
        rows = aligned(out).sort_values(["run_id", "t_ns"], ignore_index=True)  # never a run twice (in aligned)
        pd.testing.assert_frame_equal(rows[rows["run_id"] == b].reset_index(drop=True), old_b.reset_index(drop=True))
        got_a = rows[rows["run_id"] == a].reset_index(drop=True)
        assert got_a.empty or got_a.equals(old_a.reset_index(drop=True)) or got_a.equals(new_a.reset_index(drop=True))
        compact_batch(out)  # the next writer completes the switch
        rows = aligned(out).sort_values(["run_id", "t_ns"], ignore_index=True)
        pd.testing.assert_frame_equal(rows[rows["run_id"] == a].reset_index(drop=True), new_a.reset_index(drop=True))
        assert read_summary(out)[a]["ape_trans_rmse_m"] == 3.0 and read_summary(out)[b]["ape_trans_rmse_m"] == 2.0
        assert not (out / "runs" / a / "poses_aligned.parquet").exists()
        assert_consistent(out)
    assert [Path(c).name for c in calls[:3]] == ["report.json", "part-0.parquet", "batch.json"]  # what was killed


# --- workers: timeout, death, hostile inputs ---------------------------------------------------------------


def hang_on_slow(task: Task) -> dict:
    """Worker function: hangs on logs named slow* (like an observer spinning on a 1e9 m detection)."""
    if "slow" in task.run_id:
        while True:
            time.sleep(1)
    return {**base_row(task), "status": "ok"}


def nap(task: Task) -> dict:
    time.sleep(1.5)
    return {**base_row(task), "status": "ok", "worker_pid": os.getpid()}


def test_a_hanging_log_is_killed_at_its_timeout_and_fails_alone(tmp_path):
    from slamobs.pipeline.batch.local import LocalPool

    tasks = [Task.make(f"{n}-0", str(tmp_path / n), str(tmp_path), RunConfig()) for n in ("slow", "a", "b")]
    pool = LocalPool(2, run=hang_on_slow, timeout=2.0)
    gen = pool.results(tasks)
    rows = {}
    for task, row in gen:
        rows[task.run_id] = row
        pids = pool.pids()
    assert rows["a-0"]["status"] == rows["b-0"]["status"] == "ok"
    assert rows["slow-0"]["status"] == "failed" and "timed out after 2 s (worker killed" in rows["slow-0"]["error"]
    assert pool.pids() == [] and not any(alive(p) for p in pids)


def test_a_worker_killed_from_outside_is_replaced_and_its_log_retried(tmp_path):
    from slamobs.pipeline.batch.local import LocalPool

    tasks = [Task.make(f"t{i}-0", str(tmp_path / f"t{i}"), str(tmp_path), RunConfig()) for i in range(3)]
    pool = LocalPool(2, run=nap)
    killed = []

    def kill_one():
        while not pool.pids():
            time.sleep(0.05)
        time.sleep(0.5)
        killed.append(pool.pids()[0])
        os.kill(killed[0], signal.SIGKILL)

    threading.Thread(target=kill_one, daemon=True).start()
    rows = [row for _, row in pool.results(tasks)]
    assert sorted(r["run_id"] for r in rows) == ["t0-0", "t1-0", "t2-0"]
    assert {r["status"] for r in rows} == {"ok"} and killed and killed[0] not in {r["worker_pid"] for r in rows}
    assert not alive(killed[0])


def test_fifo_and_symlink_loop_are_one_line_failures_never_a_hang(tmp_path):
    make_logs(tmp_path / "in", ["good.mcap"])
    os.mkfifo(tmp_path / "in" / "pipe.mcap")
    os.symlink("loop_b.mcap", tmp_path / "in" / "loop_a.mcap")
    os.symlink("loop_a.mcap", tmp_path / "in" / "loop_b.mcap")
    (tmp_path / "in" / "up").symlink_to("..")  # a directory loop: not followed
    res = batch([tmp_path / "in"], tmp_path / "OUT")
    rows = {Path(r["log"]).name: r for r in res.rows}
    assert rows["good.mcap"]["status"] == "ok"
    assert rows["pipe.mcap"]["error"] == f"{tmp_path / 'in' / 'pipe.mcap'}: a FIFO, not a log file or directory"
    assert rows["loop_a.mcap"]["error"] == f"{tmp_path / 'in' / 'loop_a.mcap'}: symbolic link loop"
    assert res.exit_code == 1 and len(res.rows) == 4

    # given directly on the command line: exit 2 and one line, no traceback (a subprocess: a hang would show)
    cmd = [sys.executable, "-c", "from slamobs.cli.main import main; main()", "batch", "-o", str(tmp_path / "O2")]
    for name, problem in (("pipe.mcap", "a FIFO"), ("loop_a.mcap", "symbolic link loop")):
        done = subprocess.run([*cmd, str(tmp_path / "in" / name)], capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and done.stderr.strip().splitlines() == [
            f"error: {tmp_path / 'in' / name}: input: {problem}"
            + (", not a log file or directory" if name == "pipe.mcap" else "")
        ]


def test_a_dask_task_whose_batch_is_gone_ends_its_worker_process(tmp_path):
    """The lease watchdog of a Dask task (in a child process: it ends the process it runs in)."""
    lease = tmp_path / "LEASE"
    lease.touch()
    code = (
        "import sys, time, threading; import slamobs.pipeline.batch.executor as ex; "
        "ex.LEASE_STALE_S, ex.LEASE_POLL_S = 5.0, 0.1; "
        f"ex._watch_lease(__import__('pathlib').Path({str(lease)!r}), threading.Event()); "
        "print('watching', flush=True); time.sleep(120)"
    )
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "watching"
        # a live batch touches its lease: the task carries on (touched every 0.2 s, stale after 5 s: a loaded
        # machine that stalls this loop for a second no longer reads as a batch gone)
        for _ in range(30):
            os.utime(lease)
            time.sleep(0.2)
        assert child.poll() is None
        assert child.wait(timeout=60) == 70  # untouched for 5 s: the worker process ends (ORPHANED)
    finally:
        child.kill()


def sleepy_pipeline(log: Path, out_dir: Path, config):
    if "slow" in Path(log).name:
        time.sleep(600)
    return fake_pipeline(log, out_dir, config)


def test_dask_timeout_fails_the_log_and_restarts_its_worker(tmp_path):
    pytest.importorskip("distributed")
    make_logs(tmp_path / "in", ["a_slow.mcap", "b_fine.mcap"])  # submitted in this order to the one worker
    # a 10 s timeout: the fine log runs on a freshly restarted worker, which took over 3 s under load (-n 2)
    out = tmp_path / "OUT"
    res = run_batch(
        discover([tmp_path / "in"]),
        BatchOptions(out=out, jobs=1, executor="dask", timeout=10.0),
        run=partial(run_task, pipeline=sleepy_pipeline),
    )
    rows = {Path(r["log"]).name: r for r in res.rows}
    slow = rows["a_slow.mcap"]
    assert slow["status"] == "failed" and "timed out after 10 s (Dask worker tcp://" in slow["error"]
    assert rows["b_fine.mcap"]["status"] == "ok", rows  # ran once the hung worker was restarted
    assert_consistent(out)


class _DiesWhenUnpickled:
    """Pickled into a worker's start-up arguments: the worker process dies before it can take a log."""

    def __reduce__(self):
        return (os._exit, (3,))


def test_workers_that_die_while_starting_are_an_infrastructure_error(tmp_path):
    from slamobs.pipeline.batch.executor import InfrastructureError
    from slamobs.pipeline.batch.local import STARTUP_FAILURES, LocalPool

    tasks = [Task.make("a-0", str(tmp_path / "a"), str(tmp_path), RunConfig())]
    pool = LocalPool(1, run=partial(run_task, pipeline=_DiesWhenUnpickled()))
    with pytest.raises(InfrastructureError, match=f"die while starting \\(exit status 3, {STARTUP_FAILURES} times"):
        list(pool.results(tasks))
    assert pool.pids() == []


def test_a_file_of_the_users_appearing_in_a_run_directory_during_the_run_keeps_it_and_the_batch_goes_on(tmp_path):
    # commit_run moved the run's tables into the dataset and then raised InputError on the user's file in its run
    # directory: the batch stopped (exit 2) with the tables of a run without record or run directory in place
    logs = make_logs(tmp_path / "logs", ["raced.bag", "a.bag", "b.bag"])
    out = tmp_path / "OUT"
    res = run_batch(discover(logs), BatchOptions(out=out, jobs=1), run=partial(run_task, pipeline=raced_pipeline))
    rows = {Path(r["log"]).name: r for r in res.rows}
    raced = rows["raced.bag"]
    assert raced["status"] == "skipped" and "notes.txt: not written by slamobs" in raced["error"]
    assert res.kept == {raced["run_id"]: raced["error"]} and res.exit_code == 4
    assert rows["a.bag"]["status"] == rows["b.bag"]["status"] == "ok"
    assert (out / "runs" / raced["run_id"] / "notes.txt").read_text() == "mine"
    assert raced["run_id"] not in read_summary(out)  # not recorded: the next batch runs it
    assert not list((out / "poses").glob(f"run_id={raced['run_id']}"))  # nothing of it moved in


def test_the_summary_keeps_every_stage_a_run_timed_and_total_s_is_their_sum_and_more(tmp_path):
    """A run without trajectory truth times its figures apart (``figures_s``), a run with tags ``tags_s``: the
    summary kept neither, so its ``total_s`` was not the sum of the stages it listed (h-user9's TagSLAM batch:
    348.8 s against 55.9 s of listed stages, 170.4 s of figures)."""
    import json

    from slamobs.pipeline.batch.ledger import SUMMARY_SCHEMA, encode_row
    from slamobs.pipeline.simulate import simulate, write_log

    log = write_log(simulate("circle", duration=4.0, seed=3), tmp_path / "circle.mcap")
    (tmp_path / "stage").mkdir()
    config = RunConfig.from_dict({"topics": {"truth": ""}})  # no trajectory truth: the figures are their own stage
    task = Task.make("c-0", str(log), str(tmp_path), config, staged=str(tmp_path / "stage" / "c-0"))
    row = encode_row(run_task(task))
    assert row["status"] == "ok", row["error"]
    timings = json.loads(next((tmp_path / "stage" / "c-0").rglob("run.json")).read_text())["timings_s"]
    assert "figures_s" in timings and set(timings) <= set(SUMMARY_SCHEMA.names)
    assert all(row[k] == pytest.approx(v) for k, v in timings.items())
    stages = sum(v for k, v in timings.items() if k != "write_s")  # the writer's time overlaps observer_s
    assert row["total_s"] >= stages + row["dataset_s"]


def test_a_symbolic_link_s_run_id_takes_the_name_the_user_gave(tmp_path):
    # `batch mix/t22.bag` (a link to .../tag_detections.bag) gave the run id `tag_detections-...`, the target's name
    (tmp_path / "in").mkdir()
    os.mkfifo(tmp_path / "target.mcap")  # fails before any worker starts: its row and run id only
    os.symlink("../target.mcap", tmp_path / "in" / "t22.mcap")
    res = batch([tmp_path / "in"], tmp_path / "OUT")
    assert [r["run_id"].rsplit("-", 1)[0] for r in res.rows] == ["t22"]
