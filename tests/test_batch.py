"""`slamobs batch`: discovery, local and Dask execution, resume, failures, skip/--force, the dataset readers."""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import replace
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from slamobs.cli.batch_cmd import batch
from slamobs.pipeline.batch import BatchOptions, LogEntry, content_hash, discover, run_batch, run_id_for
from slamobs.pipeline.batch.dataset import SUMMARY_SCHEMA, partition_file, read_summary
from slamobs.pipeline.batch.executor import Task, failed_row, local_results
from slamobs.pipeline.batch.runner import _plan, _still_valid
from slamobs.pipeline.config import RunConfig, load_config
from slamobs.pipeline.errors import InputError

# pandas, the simulator and duckdb/polars are imported inside the tests: the crash test's worker processes
# import this module and should start fast

TABLES = ("poses", "biases", "landmarks", "landmark_tracks", "innovations")


def invoke(*args, **kwargs):
    group = click.Group()
    group.add_command(batch)
    return CliRunner().invoke(group, ["batch", *map(str, args)], catch_exceptions=False, **kwargs)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Three short simulated logs (one per container, nested) and a corrupt one in another directory."""
    from slamobs.pipeline.simulate import simulate, write_log

    base = tmp_path_factory.mktemp("batch_logs")
    good = {
        "circle": write_log(simulate("circle", duration=5.0, seed=11), base / "data" / "a" / "circle.mcap"),
        "f8": write_log(simulate("figure8", duration=5.0, seed=12), base / "data" / "a" / "f8.bag"),
        "ros2": write_log(simulate("figure8", duration=5.0, seed=13), base / "data" / "b" / "f8_ros2", "ros2"),
    }
    bad = base / "bad" / "broken.mcap"
    bad.parent.mkdir()
    bad.write_bytes(b"\x89MCAP0\r\n" + os.urandom(2000))  # right magic, garbage after it
    return {"base": base, "data": base / "data", "bad": bad, **good}


@pytest.fixture(scope="module")
def done(logs, tmp_path_factory):
    """One local batch over the good logs and the corrupt one; tests copy OUT before changing it."""
    out = tmp_path_factory.mktemp("batch_out") / "OUT"
    res = invoke(logs["data"], logs["bad"], "-o", out, "--jobs", 2)
    return res, out


def _copy(out: Path, tmp_path: Path) -> Path:
    dest = tmp_path / "OUT"
    shutil.copytree(out, dest)
    return dest


# --- discovery and identities (no runs) ------------------------------------------------------------------


def _fake_tree(root: Path) -> None:
    for f in ("x/one.bag", "x/y/two.mcap", "x/notes.txt", "x/.hidden/three.mcap", "x/docs/readme.txt",
              "x/crashed/rec_0.db3"):  # a rosbag2 recording that never wrote its metadata.yaml
        (root / f).parent.mkdir(parents=True, exist_ok=True)
        (root / f).write_bytes(b"data")
    ros2 = root / "x" / "y" / "r2"
    ros2.mkdir()
    (ros2 / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  storage_identifier: mcap\n")
    (ros2 / "r2_0.mcap").write_bytes(b"data")  # storage of the rosbag2 log, not a log of its own


def test_discover_directories_globs_and_rosbag2(tmp_path):
    _fake_tree(tmp_path)
    x = tmp_path / "x"
    found = [e.path for e in discover([x])]
    assert found == sorted([x / "one.bag", x / "crashed" / "rec_0.db3", x / "y" / "r2", x / "y" / "two.mcap"])
    # a glob reaching into the rosbag2 directory stands for that directory; duplicates collapse
    globbed = [e.path for e in discover([f"{x}/**/*.mcap", x / "one.bag", x / "y" / "r2"])]
    assert globbed == [x / "y" / "r2", x / "y" / "two.mcap", x / "one.bag"]
    assert [e.path for e in discover([x / "y" / "r2" / "metadata.yaml"])] == [x / "y" / "r2"]


def test_discover_manifests_resolve_relative_paths(tmp_path):
    _fake_tree(tmp_path)
    (tmp_path / "x" / "cfg.yaml").write_text("observer: fast-adaptation\n")
    csv = tmp_path / "x" / "list.csv"
    csv.write_text("log,config\none.bag,cfg.yaml\n# comment\ny/two.mcap,\n")
    assert discover([csv]) == [LogEntry(tmp_path / "x" / "one.bag", tmp_path / "x" / "cfg.yaml"),
                               LogEntry(tmp_path / "x" / "y" / "two.mcap", None)]
    yml = tmp_path / "x" / "list.yaml"
    yml.write_text("logs:\n  - y/r2\n  - {log: one.bag, config: cfg.yaml}\n")
    assert discover([yml]) == [LogEntry(tmp_path / "x" / "y" / "r2", None),
                               LogEntry(tmp_path / "x" / "one.bag", tmp_path / "x" / "cfg.yaml")]
    headerless = tmp_path / "x" / "plain.csv"
    headerless.write_text("missing.bag\n")  # not checked here: it becomes a failed run, not a batch error
    assert discover([headerless]) == [LogEntry(tmp_path / "x" / "missing.bag", None)]


@pytest.mark.parametrize("make,problem", [
    (lambda d: [d / "nope.bag"], "no such file"),
    (lambda d: [f"{d}/*.zzz"], "matches nothing"),
    (lambda d: [d / "x" / "notes.txt"], "not a log"),
    (lambda d: [d / "x" / "docs"], "no logs found"),
])
def test_discover_errors(tmp_path, make, problem):
    _fake_tree(tmp_path)
    with pytest.raises(InputError, match=problem):
        discover(make(tmp_path))


def test_run_id_is_readable_stable_and_unique_per_location(tmp_path):
    a, b = tmp_path / "a" / "flight 1.mcap", tmp_path / "b" / "flight 1.mcap"
    assert run_id_for(a) == run_id_for(a)
    assert run_id_for(a).startswith("flight_1-") and run_id_for(a) != run_id_for(b)
    assert run_id_for(tmp_path / "f8_ros2").startswith("f8_ros2-")


def test_content_hash_ignores_mtime_and_location_but_sees_changes(tmp_path):
    data = os.urandom(3 << 20)  # bigger than the two hashed MiB
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    a.write_bytes(data)
    b.write_bytes(data)
    os.utime(b, (1, 1))
    assert content_hash(a) == content_hash(b)
    b.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))  # last byte (MCAP footer / bag index end)
    assert content_hash(a) != content_hash(b)
    b.write_bytes(data + b"x")  # grown
    assert content_hash(a) != content_hash(b)
    # documented limit: a same-size edit in the middle of a big file is not seen (--force re-runs)
    mid = len(data) // 2
    b.write_bytes(data[:mid] + bytes([data[mid] ^ 1]) + data[mid + 1:])
    assert content_hash(a) == content_hash(b)


# --- a local batch with a corrupt log ---------------------------------------------------------------------


def test_local_batch_runs_good_logs_and_reports_the_corrupt_one(done, logs):
    import pandas as pd

    res, out = done
    assert res.exit_code == 1, res.output
    assert res.stdout.strip().splitlines()[-1].startswith("batch: 4 logs, 3 ok, 0 skipped, 1 failed")
    summary = pd.read_parquet(out / "summary.parquet")
    assert list(summary.columns) == SUMMARY_SCHEMA.names
    assert len(summary) == 4 and summary["run_id"].is_unique
    bad = summary.set_index("log").loc[str(logs["bad"].resolve())]
    assert bad["status"] == "failed" and str(logs["bad"].resolve()) in bad["error"] and "\n" not in bad["error"]
    assert not (out / "runs" / bad["run_id"]).exists()
    ok = summary[summary["status"] == "ok"]
    assert sorted(ok["log"]) == sorted(str(logs[k].resolve()) for k in ("circle", "f8", "ros2"))
    assert ok["content_hash"].str.startswith("v1:").all() and ok["config_hash"].nunique() == 1
    assert (ok["observer"] == "fast-adaptation").all() and ok["error"].isna().all()
    for col in ("read_s", "align_s", "observer_s", "write_s", "report_s", "dataset_s", "total_s"):
        assert (ok[col] > 0).all(), col
    assert (ok["velocity_samples"] > 900).all() and (ok["landmarks"] >= 4).all()
    assert (ok["ape_trans_rmse_m"] < 0.1).all() and (ok["landmark_rmse_m"] < 0.3).all()
    assert ok[["ape_rot_rmse_deg", "gyro_bias_err", "vel_bias_err", "convergence_s"]].notna().all().all()
    for rid in ok["run_id"]:
        run = json.loads((out / "runs" / rid / "run.json").read_text())
        assert run["observer"]["name"] == "fast-adaptation"
        assert (out / "runs" / rid / "report.json").is_file()
        for t in TABLES:
            assert partition_file(out, t, rid).is_file()
    assert not list(out.rglob(".*tmp*"))


def test_summary_has_every_headline_metric():
    from slamobs.pipeline.run import headline_metrics

    assert set(headline_metrics(None)) <= set(SUMMARY_SCHEMA.names)


def test_dataset_reads_in_pandas_duckdb_and_polars(done):
    import duckdb
    import pandas as pd
    import polars as pl

    _, out = done
    ok = pd.read_parquet(out / "summary.parquet").query("status == 'ok'")
    per_run = {rid: len(pd.read_parquet(out / "runs" / rid / "poses.parquet")) for rid in ok["run_id"]}
    for table in TABLES:
        df = pd.read_parquet(out / table)
        assert set(df["run_id"].astype(str)) == set(per_run)
    poses = pd.read_parquet(out / "poses")
    assert poses.groupby("run_id", observed=True).size().to_dict() == per_run
    inside = pd.read_parquet(partition_file(out, "poses", ok["run_id"].iloc[0]))  # the column is in the file
    assert set(inside["run_id"].astype(str)) == {ok["run_id"].iloc[0]}
    rows = duckdb.sql(f"SELECT run_id, count(*) FROM read_parquet('{out}/poses/*/*.parquet') GROUP BY run_id")
    assert dict(rows.fetchall()) == per_run
    pl_counts = pl.read_parquet(out / "poses").group_by("run_id").len().rows()
    assert {str(k): v for k, v in pl_counts} == per_run
    assert set(pl.scan_parquet(out / "landmarks").collect()["run_id"].cast(pl.String)) == set(per_run)


# --- re-runs: skip, --force, changed config, --json -------------------------------------------------------


def test_rerun_skips_finished_runs_and_force_reruns(done, logs, tmp_path):
    out = _copy(done[1], tmp_path)
    before = read_summary(out)
    res = invoke(logs["data"], "-o", out, "--json", "--jobs", 2)
    assert res.exit_code == 0
    lines = [json.loads(x) for x in res.stdout.strip().splitlines()]
    runs, final = lines[:-1], lines[-1]
    assert [r["status"] for r in runs] == ["skipped"] * 3 and all(r["event"] == "run" for r in runs)
    assert [r["done"] for r in runs] == [1, 2, 3] and all(r["total"] == 3 for r in runs)
    assert final == {**final, "event": "done", "ok": 0, "skipped": 3, "failed": 0, "exit_code": 0}
    after = read_summary(out)
    for rid, row in after.items():
        if row["status"] == "skipped":  # results and their provenance carried over unchanged
            assert row["finished_at"] == before[rid]["finished_at"]
            assert row["ape_trans_rmse_m"] == before[rid]["ape_trans_rmse_m"]

    res = invoke(logs["circle"], "-o", out, "--force", "--quiet")
    lines = res.output.strip().splitlines()
    assert res.exit_code == 0 and len(lines) == 1 and lines[0].startswith("batch: 1 logs, 1 ok, 0 skipped, 0 failed")
    rid = run_id_for(logs["circle"])
    assert read_summary(out)[rid]["finished_at"] > before[rid]["finished_at"]
    assert len(read_summary(out)) == 4  # rows of logs outside this invocation are kept

    # a changed config (or log content) is not "done": the plan sends that log to the workers again
    cfg = tmp_path / "rate.yaml"
    cfg.write_text("output:\n  rate_hz: 10\n")
    (task,) = _plan(discover([logs["circle"]]), BatchOptions(out=out, config=load_config(cfg)))
    assert task.run_id == rid and task.content_hash == read_summary(out)[rid]["content_hash"]
    assert not _still_valid(read_summary(out)[rid], task, out)
    (same,) = _plan(discover([logs["circle"]]), BatchOptions(out=out))
    assert _still_valid(read_summary(out)[rid], same, out)
    assert not _still_valid(read_summary(out)[rid], replace(same, content_hash="v1:other"), out)


# --- interruption and resume ------------------------------------------------------------------------------


class Interrupt(Exception):
    pass


def test_interrupted_batch_resumes_where_it_stopped(logs, tmp_path):
    import pandas as pd

    out = tmp_path / "OUT"
    entries = discover([logs["circle"], logs["f8"]])
    seen = []

    def stop_after_first(row, progress):
        seen.append(row["run_id"])
        raise Interrupt

    with pytest.raises(Interrupt):
        run_batch(entries, BatchOptions(out=out, jobs=1), on_row=stop_after_first)
    summary = read_summary(out)
    assert list(summary) == seen and summary[seen[0]]["status"] == "ok"  # consistent: just the recorded run
    # what a killed batch leaves behind: a half-written run directory and a partition temp file
    (out / "runs" / ".ghost-00000000.tmp-abcd").mkdir()
    (out / "runs" / ".ghost-00000000.tmp-abcd" / "poses.parquet").write_bytes(b"partial")
    stale_part = out / "poses" / f"run_id={seen[0]}" / ".part-0.parquet.tmp-999"
    stale_part.write_bytes(b"partial")

    result = run_batch(entries, BatchOptions(out=out, jobs=1))
    assert [r["status"] for r in result.rows] == ["skipped", "ok"] and result.exit_code == 0
    assert not (out / "runs" / ".ghost-00000000.tmp-abcd").exists() and not stale_part.exists()
    assert len(pd.read_parquet(out / "poses")["run_id"].unique()) == 2


# --- worker crashes, exit codes, arguments ----------------------------------------------------------------


def crash_on_circle(task: Task) -> dict:
    """Worker function for the crash test: dies like a segfault/OOM kill on one log."""
    if "circle" in task.run_id:
        os._exit(1)
    return {**failed_row(task, "not run"), "status": "ok"}


def test_a_log_that_kills_its_worker_fails_alone(logs, tmp_path):
    tasks = [Task.make(run_id_for(p), str(p), str(tmp_path), RunConfig())
             for p in (logs["f8"], logs["circle"], logs["ros2"])]
    rows = {r["run_id"]: r for r in local_results(tasks, 2, run=crash_on_circle)}
    assert len(rows) == 3
    assert rows[run_id_for(logs["circle"])]["status"] == "failed"
    assert "worker process died" in rows[run_id_for(logs["circle"])]["error"]
    assert rows[run_id_for(logs["f8"])]["status"] == rows[run_id_for(logs["ros2"])]["status"] == "ok"


def test_exit_code_2_when_nothing_succeeds_and_quiet_prints_one_line(logs, tmp_path):
    manifest = tmp_path / "list.csv"
    (tmp_path / "bad_gains.yaml").write_text("gains:\n  fast-adaptation: {k_p: -1}\n")
    manifest.write_text(f"log,config\nnot_there.mcap,\n{logs['circle']},bad_gains.yaml\n")
    res = invoke(logs["bad"], manifest, "-o", tmp_path / "OUT", "-q", "-j", 1)
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [res.stdout.strip()]
    rows = {Path(r["log"]).name: r for r in read_summary(tmp_path / "OUT").values()}
    assert {r["status"] for r in rows.values()} == {"failed"} and len(rows) == 3
    assert rows["not_there.mcap"]["error"].endswith("not_there.mcap: no such file or directory")
    assert rows["circle.mcap"]["error"].startswith(f"{tmp_path / 'bad_gains.yaml'}: gains.fast-adaptation: gain k_p")
    assert rows["circle.mcap"]["config_file"] == str(tmp_path / "bad_gains.yaml")


@pytest.mark.parametrize("args,message", [
    (["nowhere/*.mcap"], "matches nothing"),
    (["{data}", "--observer", "nope"], "unknown observer"),
    (["{data}", "--executor", "local", "--scheduler", "tcp://127.0.0.1:1"], "cannot be combined"),
])
def test_bad_arguments_exit_2_with_one_line(logs, tmp_path, args, message):
    res = invoke(*[a.format(data=logs["data"]) for a in args], "-o", tmp_path / "OUT")
    assert res.exit_code == 2
    assert len(res.output.strip().splitlines()) == 1 and message in res.output


def test_dask_missing_is_one_line(logs, tmp_path, monkeypatch):
    monkeypatch.setattr("slamobs.pipeline.batch.runner.dask_available", lambda: False)
    res = invoke(logs["circle"], "-o", tmp_path / "OUT", "--executor", "dask")
    assert res.exit_code == 2 and res.output.strip() == (
        "error: --executor dask needs Dask: pip install 'slamobs[dask]' (or: pip install \"dask[distributed]\")")


# --- Dask ---------------------------------------------------------------------------------------------------


def test_unreachable_scheduler_is_one_line(logs, tmp_path):
    dask = pytest.importorskip("dask")
    pytest.importorskip("distributed")
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        res = invoke(logs["circle"], "-o", tmp_path / "OUT", "--scheduler", "tcp://127.0.0.1:1")
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert res.output.strip().splitlines()[-1].startswith("error: tcp://127.0.0.1:1: cannot reach the Dask scheduler")


def test_dask_local_cluster(logs, tmp_path):
    import pandas as pd

    pytest.importorskip("distributed")
    out = tmp_path / "OUT"
    res = invoke(logs["f8"], logs["ros2"], "-o", out, "--executor", "dask", "--jobs", 2)
    assert res.exit_code == 0, res.output
    summary = pd.read_parquet(out / "summary.parquet")
    assert list(summary["status"]) == ["ok", "ok"]
    assert (summary["ape_trans_rmse_m"] < 0.1).all()
    assert sorted(pd.read_parquet(out / "poses")["run_id"].astype(str).unique()) == sorted(summary["run_id"])


def test_a_worker_with_another_version_fails_the_run_clearly(tmp_path):
    from slamobs.pipeline.batch.executor import run_task

    task = replace(Task.make("x-00000000", str(tmp_path / "x.mcap"), str(tmp_path), RunConfig()), version="0.0.1")
    row = run_task(task)
    assert row["status"] == "failed" and "the batch 0.0.1: install the same version" in row["error"]


def test_worker_warnings_go_to_the_summary_not_stderr(monkeypatch, tmp_path, capfd):
    import warnings

    from slamobs.pipeline.batch.executor import run_task

    def noisy_run_log(*_args, **_kwargs):
        warnings.warn("overflow encountered", RuntimeWarning, stacklevel=1)
        raise ValueError("diverged")

    monkeypatch.setattr("slamobs.pipeline.run.run_log", noisy_run_log)
    task = Task.make("x-00000000", str(tmp_path / "x.mcap"), str(tmp_path), RunConfig())
    row = run_task(task)
    assert row["status"] == "failed" and row["error"] == f"{tmp_path / 'x.mcap'}: ValueError: diverged"
    assert row["warnings"].startswith("RuntimeWarning: overflow encountered")
    assert capfd.readouterr().err == ""
