"""A batch under hostile conditions (issue 28): a full disk, a log replaced while it runs, a batch's own output
inside its inputs, a file name that is not UTF-8, a damaged compacted file, a Dask worker that stops answering.

As in test_batch_integrity, the workers run :func:`fake_pipeline` (milliseconds per log): what is under test is
the batch machinery. A full disk is the kernel's own ENOSPC (writes to ``/dev/full``), a stopped worker a real
SIGSTOP.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import pandas as pd
import pytest

from slamobs.pipeline.batch import BatchOptions, discover, run_batch
from slamobs.pipeline.batch.executor import run_task
from slamobs.pipeline.batch.ledger import read_summary
from slamobs.pipeline.errors import InputError, ResourceError

from batch_checks import CLI, alive, assert_consistent
from test_batch_integrity import batch, fake_pipeline, make_logs

FULL = Path("/dev/full")


def full_disk_pipeline(log: Path, out_dir: Path, config):
    """The run's output lands on a full disk: the kernel answers ENOSPC to the write."""
    from slamobs.pipeline.writers import atomic_directory

    with atomic_directory(out_dir) as tmp, open(FULL, "wb") as fh:
        (tmp / "run.json").write_text("{}")
        fh.write(b"\0" * 65536)
        fh.flush()
    raise AssertionError("unreachable: /dev/full accepted the write")


@pytest.mark.skipif(not FULL.exists(), reason="no /dev/full")
def test_a_full_disk_is_a_machine_failure_never_recorded_as_a_failed_log(tmp_path):
    make_logs(tmp_path / "in", ["a.mcap", "b.mcap", "c.mcap", "d.mcap"])
    out = tmp_path / "OUT"
    res = run_batch(
        discover([tmp_path / "in"]), BatchOptions(out=out, jobs=2), run=partial(run_task, pipeline=full_disk_pipeline)
    )
    assert [r["status"] for r in res.rows] == ["failed"] * 4
    assert all("No space left on device" in r["error"] and r["retry"] == "machine" for r in res.rows), res.rows
    assert res.exit_code == 3 and len(res.machine_failures) == 4
    assert read_summary(out) == {}  # nothing a later --skip-failed could skip

    # space freed: --skip-failed runs every log (it printed "0 ok, 4 skipped" with an empty dataset)
    res = batch([tmp_path / "in"], out, jobs=2, skip_failed=True)
    assert [r["status"] for r in res.rows] == ["ok"] * 4 and res.exit_code == 0
    assert len(assert_consistent(out)) == 4


def swapping_pipeline(log: Path, out_dir: Path, config):
    """While this log runs, someone replaces it (``cp other d/.new; mv d/.new log``) and the run reads the new one."""
    swap = Path(log).with_name(".replacement")
    if swap.exists():
        os.replace(swap, log)
    return fake_pipeline(log, out_dir, config)


def test_a_log_replaced_while_it_runs_is_not_stored_under_the_old_contents_run_id(tmp_path):
    make_logs(tmp_path / "in", ["f8.mcap", "keep.mcap"])
    make_logs(tmp_path / "other", ["new.mcap"], seed=7)
    original = tmp_path / "orig" / "f8.mcap"
    original.parent.mkdir()
    shutil.copy2(tmp_path / "in" / "f8.mcap", original)  # an untouched copy of the original content
    shutil.copy2(tmp_path / "other" / "new.mcap", tmp_path / "in" / ".replacement")
    out = tmp_path / "OUT"
    res = run_batch(
        discover([tmp_path / "in"]), BatchOptions(out=out, jobs=1), run=partial(run_task, pipeline=swapping_pipeline)
    )
    rows = {Path(r["log"]).name: r for r in res.rows}
    assert rows["keep.mcap"]["status"] == "ok"
    f8 = rows["f8.mcap"]
    assert f8["status"] == "failed" and "the log changed while it ran" in f8["error"] and res.exit_code == 1
    assert f8["run_id"] not in read_summary(out)  # not stored: neither as ok nor as a failure to skip

    # the untouched original is run (it was "skipped" with the new log's result, for good)
    res = batch([original], out)
    assert res.rows[0]["status"] == "ok" and res.rows[0]["run_id"] == f8["run_id"]
    # and the replaced log, now the new content, is a run of its own
    res = batch([tmp_path / "in" / "f8.mcap"], out)
    assert res.rows[0]["status"] == "ok" and res.rows[0]["run_id"] != f8["run_id"]
    assert len(assert_consistent(out)) == 3


def test_a_batch_never_takes_its_own_outputs_as_logs(tmp_path):
    make_logs(tmp_path / "d", ["a.mcap", "b.mcap"])
    out = tmp_path / "d" / "OUT"  # inside the input directory
    res = batch([tmp_path / "d"], out)
    assert res.count("ok") == 2
    for run in (out / "runs").iterdir():  # what `output.export: [mcap]` leaves in each run directory
        shutil.copy(tmp_path / "d" / "a.mcap", run / "results.mcap")
    for _ in range(2):  # every resume
        res = batch([tmp_path / "d"], out)
        assert sorted(Path(r["log"]).name for r in res.rows) == ["a.mcap", "b.mcap"]
        assert res.count("skipped") == 2 and res.exit_code == 0


def test_a_file_name_that_is_not_utf8_is_one_failed_row_never_a_crash(tmp_path):
    make_logs(tmp_path / "d", ["good.mcap"])
    bad = os.fsdecode(os.fsencode(tmp_path / "d") + b"/b\xffd.mcap")
    Path(bad).write_bytes(b"\x01" * 64)
    out = tmp_path / "OUT"
    res = batch([tmp_path / "d"], out)
    rows = {r["status"]: r for r in res.rows}
    assert rows["ok"]["log"].endswith("good.mcap")
    assert rows["failed"]["error"] == (
        f"{tmp_path / 'd'}/b\\xffd.mcap: the file name is not UTF-8 (byte 0xff): rename it to run this log"
    )
    assert res.exit_code == 1 and list(read_summary(out)) == [rows["ok"]["run_id"]]

    # the command: one line for that file, the rest of the batch runs (it aborted with a traceback)
    done = subprocess.run(
        [*CLI, "batch", os.fsencode(tmp_path / "d"), "-o", tmp_path / "OUT2", "-j", "1"],
        capture_output=True,
        timeout=300,
        check=False,
    )
    err = done.stderr.decode(errors="replace")
    assert "Traceback" not in err and done.returncode == 1, err
    assert "b\\xffd.mcap: the file name is not UTF-8" in err
    assert done.stdout.decode().startswith("batch: 2 logs, 0 ok, 0 skipped, 2 failed")


def test_a_damaged_compacted_file_is_named_in_one_line_and_its_runs_run_again(tmp_path):
    make_logs(tmp_path / "in", ["a.mcap", "b.mcap"])
    out = tmp_path / "OUT"
    batch([tmp_path / "in"], out)
    [damaged] = (out / "poses").glob("compacted-*.parquet")
    damaged.write_bytes(damaged.read_bytes()[: damaged.stat().st_size // 2])  # truncated

    with pytest.raises(InputError, match="damaged compacted file") as err:
        batch([tmp_path / "in"], out)
    assert err.value.path == str(damaged)
    for args in (["batch", "compact", out], ["batch", tmp_path / "in", "-o", out]):
        done = subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=300, check=False)
        assert done.returncode == 2 and done.stderr.splitlines() == [
            (
                f"error: {damaged}: damaged compacted file (Parquet magic bytes not found in footer. Either the "
                "file is corrupted or this is not a parquet file.): move it out of the dataset and run the batch "
                "again (the runs it held are run again)"
            )
        ], done.stderr

    damaged.rename(tmp_path / "damaged.parquet")  # as the message says
    res = batch([tmp_path / "in"], out)
    assert [r["status"] for r in res.rows] == ["ok", "ok"] and res.reconciled.dropped  # run again, not "skipped"
    assert len(assert_consistent(out)) == 2


@pytest.mark.skipif(not FULL.exists(), reason="no /dev/full")
def test_compaction_on_a_full_disk_names_its_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    from slamobs.pipeline.batch import compact

    make_logs(tmp_path / "in", ["a.mcap", "b.mcap", "c.mcap"])
    out = tmp_path / "OUT"
    real_open = compact.Writer._open

    def open_on_full_disk(self, schema):  # the compacted file's temporary lands on a full disk
        (self.base / f".{compact.COMPACTED}{self.gen:06d}-{len(self.done):04d}.parquet.tmp").symlink_to(FULL)
        real_open(self, schema)

    monkeypatch.setattr(compact.Writer, "_open", open_on_full_disk)
    with pytest.raises(ResourceError) as err:
        batch([tmp_path / "in"], out)
    first = out / "poses" / "compacted-000001-0000.parquet"  # tables are compacted in schemas.TABLES order
    assert err.value.path == str(first) and "No space left on device" in str(err.value)
    assert not [p for p in out.rglob(".*") if p.name.startswith(".compacted")]
    summary = pd.read_parquet(out / "summary.parquet")  # current: lists every stored run
    assert sorted(summary["run_id"]) == sorted(p.name for p in (out / "runs").iterdir()) and len(summary) == 3

    monkeypatch.setattr(compact.Writer, "_open", real_open)
    res = batch([tmp_path / "in"], out)  # room again: the runs are there, compaction completes
    assert res.count("skipped") == 3 and res.compaction
    assert len(assert_consistent(out)) == 3


def stalling_run(task, pid_file: str):
    """Dask task function: the ``a_stop`` log makes its staging directory, says which process it runs in and
    stalls there (the test SIGSTOPs that worker process); every other log runs normally."""
    if Path(task.log).name != "a_stop.mcap":
        return run_task(task, pipeline=fake_pipeline)
    Path(task.staged).mkdir()
    # whole or not at all: the test reads the file as soon as it exists (written in place, it could be read empty)
    Path(f"{pid_file}.part").write_text(str(os.getpid()))
    os.replace(f"{pid_file}.part", pid_file)
    time.sleep(600)
    raise AssertionError("unreachable: the worker was stopped, then restarted")


DASK_BATCH = """
import json, sys
from functools import partial
sys.path.insert(0, {tests!r})
from test_batch_hostile import stalling_run
from slamobs.pipeline.batch import BatchOptions, discover, run_batch
res = run_batch(discover([{logs!r}]), BatchOptions(out={out!r}, jobs=2, executor="dask", timeout=10.0),
                run=partial(stalling_run, pid_file={pid!r}))
print(json.dumps([[r["log"], r["status"], r.get("error")] for r in res.rows]))
"""


def test_a_stopped_dask_worker_times_out_and_its_queued_logs_go_to_another(tmp_path):
    """SIGSTOP on a real Dask worker process just as its run's staging directory appears: the log times out
    after --timeout, the logs queued on that worker run on the other one (progress stayed at 2/4, for good)."""
    pytest.importorskip("distributed")
    from batch_checks import descendants

    make_logs(tmp_path / "in", ["a_stop.mcap", "b.mcap", "c.mcap", "d.mcap"])
    pid_file, out = tmp_path / "worker.pid", tmp_path / "OUT"
    code = DASK_BATCH.format(
        tests=str(Path(__file__).parent), logs=str(tmp_path / "in"), out=str(out), pid=str(pid_file)
    )
    stdout, stderr = tmp_path / "stdout", tmp_path / "stderr"  # files: a full pipe would block the workers' logging
    with open(stdout, "w") as out_fh, open(stderr, "w") as err_fh:
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=out_fh, stderr=err_fh)
    stopped = None
    try:
        end = time.monotonic() + 240
        while not pid_file.exists() and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.1)  # a sign: the stalling log's staging directory is made, its worker named
        assert pid_file.exists(), stderr.read_text()
        stopped = int(pid_file.read_text())
        assert stopped in descendants(proc.pid)  # a worker process of this batch's local cluster
        os.kill(stopped, signal.SIGSTOP)
        proc.wait(timeout=180)  # it hung, progress at 2/4
    finally:
        proc.kill()
        if stopped is not None and alive(stopped):
            os.kill(stopped, signal.SIGKILL)
    assert proc.returncode == 0, stderr.read_text()
    rows = {Path(log).name: (status, error) for log, status, error in json.loads(stdout.read_text())}
    status, error = rows.pop("a_stop.mcap")
    assert status == "failed" and "timed out after 10 s (Dask worker tcp://" in error, error
    assert set(rows.values()) == {("ok", None)} and len(rows) == 3
    assert not alive(stopped)  # restarted through its nanny: the stopped process was killed
    assert sorted(r["status"] for r in assert_consistent(out).values()) == ["failed", "ok", "ok", "ok"]


def test_a_file_size_limit_is_a_machine_failure_never_recorded_as_a_failed_log(tmp_path):
    """A real batch under ``RLIMIT_FSIZE`` (a quota, ``ulimit -f`` of a cron job, a file system's largest file):
    the writers get EFBIG ("File too large"), the machine's refusal as much as ENOSPC. It was recorded as the
    log's failure (exit 1, a ``put`` row in the ledger), so ``--skip-failed`` skipped the log once there was room."""
    import resource

    from slamobs.pipeline.simulate import simulate, write_log

    write_log(simulate("circle", duration=3.0, seed=5), tmp_path / "in" / "c.mcap")
    cfg = tmp_path / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    out = tmp_path / "OUT"
    args = [*CLI, "batch", str(tmp_path / "in"), "-o", str(out), "--config", str(cfg), "--skip-failed"]

    def small_files():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of being killed (Python's own setting)
        resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))

    limited = subprocess.run(args, capture_output=True, text=True, preexec_fn=small_files, timeout=600)
    assert limited.returncode == 3, limited.stderr
    assert "File too large" in limited.stderr and "Traceback" not in limited.stderr, limited.stderr
    assert read_summary(out) == {}  # nothing a later --skip-failed could skip
    assert not list((out / "_slamobs" / "staging").glob("*/*")), "a staged run left"

    again = subprocess.run(args, capture_output=True, text=True, timeout=600)  # room again
    assert again.returncode == 0, again.stderr
    assert [r["status"] for r in assert_consistent(out).values()] == ["ok"]
