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
from slamobs.pipeline.batch.executor import Task
from slamobs.pipeline.batch.ledger import SUMMARY_SCHEMA, read_summary
from slamobs.pipeline.batch.runner import config_hash
from slamobs.pipeline.config import RunConfig
from slamobs.pipeline.errors import InputError

from batch_checks import assert_consistent
from cli_checks import map_truth_only_config

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
    for f in (
        "x/one.bag",
        "x/y/two.mcap",
        "x/notes.txt",
        "x/.hidden/three.mcap",
        "x/docs/readme.txt",
        "x/crashed/rec_0.db3",
    ):  # a rosbag2 recording that never wrote its metadata.yaml
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


def test_discover_takes_a_split_recording_as_one_log_as_run_does(tmp_path):
    """A directory holding the NAME_N parts of one recording and no metadata.yaml (a split rosbag2 recording that was
    not closed, or a split ROS1 recording) is one log to ``run``: batch took each part as a log of its own."""
    heads = {".db3": b"SQLite format 3\x00", ".mcap": b"\x89MCAP0\r\n", ".bag": b"#ROSBAG V2.0\n"}
    x = tmp_path / "x"
    for folder, names in {"crashed": ("crashed_0.db3", "crashed_1.db3"), "m": ("m_0.mcap", "m_1.mcap", "m_2.mcap"),
                          "split": ("split_1.bag", "split_0.bag"), "mixed": ("a_0.db3", "b_0.db3"),
                          "flights": ("flight_0.mcap", "flight_1.mcap")}.items():  # fmt: skip
        (x / folder).mkdir(parents=True)
        for name in names:
            (x / folder / name).write_bytes(heads[Path(name).suffix] + b"data")
    found = [e.path for e in discover([x])]
    # two recordings' parts in one directory are not one log, nor logs that are not named after their directory (a
    # directory of whole logs flight_0, flight_1): each file stays a log of its own
    flights, mixed = [x / "flights" / f"flight_{k}.mcap" for k in (0, 1)], [x / "mixed" / f"{n}_0.db3" for n in "ab"]
    assert found == [x / "crashed", *flights, x / "m", *mixed, x / "split"]
    assert [e.path for e in discover([x / "crashed"])] == [x / "crashed"]  # given itself, not searched
    # a glob reaching into it stands for the recording; a part named by itself is that file (as ``run`` reads it)
    assert [e.path for e in discover([f"{x}/m/*.mcap", f"{x}/s*/*_0.bag"])] == [x / "m", x / "split"]
    assert [e.path for e in discover([x / "split" / "split_0.bag"])] == [x / "split" / "split_0.bag"]
    assert [e.path for e in discover([x / "flights"])] == flights


def test_discover_manifests_resolve_relative_paths(tmp_path):
    _fake_tree(tmp_path)
    (tmp_path / "x" / "cfg.yaml").write_text("observer: fast-adaptation\n")
    csv = tmp_path / "x" / "list.csv"
    csv.write_text("log,config\none.bag,cfg.yaml\n# comment\ny/two.mcap,\n")
    assert discover([csv]) == [
        LogEntry(tmp_path / "x" / "one.bag", tmp_path / "x" / "cfg.yaml"),
        LogEntry(tmp_path / "x" / "y" / "two.mcap", None),
    ]
    yml = tmp_path / "x" / "list.yaml"
    yml.write_text("logs:\n  - y/r2\n  - {log: one.bag, config: cfg.yaml}\n")
    assert discover([yml]) == [
        LogEntry(tmp_path / "x" / "y" / "r2", None),
        LogEntry(tmp_path / "x" / "one.bag", tmp_path / "x" / "cfg.yaml"),
    ]
    headerless = tmp_path / "x" / "plain.csv"
    headerless.write_text("missing.bag\n")  # not checked here: it becomes a failed run, not a batch error
    assert discover([headerless]) == [LogEntry(tmp_path / "x" / "missing.bag", None)]


@pytest.mark.parametrize(
    "make,problem",
    [
        (lambda d: [d / "nope.bag"], "no such file"),
        (lambda d: [f"{d}/*.zzz"], "matches nothing"),
        (lambda d: [d / "x" / "notes.txt"], "not a log"),
        (lambda d: [d / "x" / "docs"], "no logs found"),
    ],
)
def test_discover_errors(tmp_path, make, problem):
    _fake_tree(tmp_path)
    with pytest.raises(InputError, match=problem):
        discover(make(tmp_path))


def test_a_symbolic_link_to_a_directory_is_named_not_silently_skipped(logs, tmp_path):
    """A night's folder of links (``ln -s /data/flights_0501 nightly/``) ran only the logs linked one by one, and
    neither the batch's lines nor its error for a folder of directory links only said why the rest were missing."""
    night = tmp_path / "nightly"
    night.mkdir()
    os.symlink(logs["data"] / "a", night / "flights_a")  # a directory of logs: not followed
    os.symlink(logs["data"] / "b" / "f8_ros2", night / "f8_ros2")  # a rosbag2 directory: that log
    links: list[Path] = []
    assert discover([night], links) == [LogEntry(night / "f8_ros2", None)] and links == [night / "flights_a"]
    os.unlink(night / "f8_ros2")
    with pytest.raises(InputError, match=f"symbolic links to directories are not searched \\({night / 'flights_a'}\\)"):
        discover([night])
    os.symlink(logs["bad"], night / "broken.mcap")
    res = invoke(night, "-o", tmp_path / "OUT", "-j", 1)
    assert f"note: {night / 'flights_a'}: a symbolic link to a directory, not searched" in res.output


def test_a_log_listed_with_and_without_a_config_says_no_config_not_none(tmp_path):
    (tmp_path / "a.mcap").write_bytes(b"x")
    (tmp_path / "list.csv").write_text("log,config\na.mcap,run.yaml\n")
    with pytest.raises(InputError, match=r"different configs \(no config and "):
        discover([tmp_path / "a.mcap", tmp_path / "list.csv"])


def test_run_id_is_readable_and_from_content_and_config():
    from slamobs.pipeline.batch import run_key

    key = run_key("v1:abc", config_hash(RunConfig()))
    assert run_id_for(Path("/a/flight 1.mcap"), key) == f"flight_1-{key}"
    assert run_id_for(Path("/elsewhere/f8_ros2"), key) == f"f8_ros2-{key}"
    assert (
        run_key("v1:abc", config_hash(RunConfig(observer="hashim")))
        != key
        != run_key("v1:abd", config_hash(RunConfig()))
    )


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
    b.write_bytes(data[:mid] + bytes([data[mid] ^ 1]) + data[mid + 1 :])
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
    assert (
        ok[
            [
                "ape_rot_rmse_deg",
                "rpe_trans_rmse_m",
                "rpe_rot_rmse_deg",
                "gyro_bias_err",
                "vel_bias_err",
                "convergence_s",
            ]
        ]
        .notna()
        .all()
        .all()
    )
    assert (ok["warning_count"] == 0).all()
    # each run's line names its log (TagSLAM's tests all call theirs tag_detections.bag: two lines alike)
    lines = [line for line in res.stderr.splitlines() if "] ok " in line]
    assert sorted(line.rsplit("  ", 1)[1] for line in lines) == sorted(ok["log"]) and all(" APE " in x for x in lines)
    assert all(set(TABLES) <= set(t.split(",")) for t in ok["tables"])  # and the aligned tables (truth)
    for rid in ok["run_id"]:
        run = json.loads((out / "runs" / rid / "run.json").read_text())
        assert run["observer"]["name"] == "fast-adaptation"
        assert (out / "runs" / rid / "report.json").is_file()
        assert not list((out / "runs" / rid).glob("*.parquet"))  # one copy of each table: in the dataset
    for t in TABLES:  # compacted at the end: one file per table, every ok run in it
        assert [p.name for p in (out / t).iterdir()] == ["compacted-000001-0000.parquet"]
    assert not list(out.rglob(".*tmp*")) and not list((out / "_slamobs" / "staging").iterdir())


def test_summary_has_every_headline_metric():
    from slamobs.pipeline.run import headline_metrics

    assert set(headline_metrics(None)) <= set(SUMMARY_SCHEMA.names)


def test_a_log_with_map_truth_only_has_its_map_error_in_the_summary_and_its_line(logs, tmp_path):
    """A TagSLAM-style log (a landmark survey, no trajectory truth): the run measures its map error, so the batch
    summary has it (``map_error_m``, as a comparison's) and its line says it, not "no truth"."""
    import pandas as pd

    config = map_truth_only_config(tmp_path)
    res = invoke(logs["circle"], "-o", tmp_path / "OUT", "-j", 1, "--config", config)
    assert res.exit_code == 0, res.output
    row = pd.read_parquet(tmp_path / "OUT" / "summary.parquet").iloc[0]
    run = json.loads((tmp_path / "OUT" / "runs" / row["run_id"] / "run.json").read_text())
    rmse = run["map_error"]["error_m"]["rmse"]
    assert row["map_error_m"] == pytest.approx(rmse) and pd.isna(row["ape_trans_rmse_m"])
    assert f"map error {rmse:.4f} m (map-only alignment; no trajectory truth)" in res.output, res.output
    assert "no truth" not in res.output.replace("no trajectory truth", "")
    # a new report of that run (it rewrites the run's map error) keeps the row's (it read batch.json, which has none)
    from slamobs.cli.main import main

    res = CliRunner().invoke(main, ["report", str(tmp_path / "OUT" / "runs" / row["run_id"])], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    again = pd.read_parquet(tmp_path / "OUT" / "summary.parquet").iloc[0]
    assert again["map_error_m"] == pytest.approx(rmse)


def test_dataset_reads_in_pandas_duckdb_and_polars(done):
    import duckdb
    import pandas as pd
    import polars as pl

    import slamobs

    _, out = done
    ok = pd.read_parquet(out / "summary.parquet").query("status == 'ok'")
    per_run = {
        rid: json.loads((out / "runs" / rid / "batch.json").read_text())["tables"]["poses"] for rid in ok["run_id"]
    }
    for table in TABLES:
        df = pd.read_parquet(out / table)
        assert set(df["run_id"].astype(str)) == set(per_run)
    poses = pd.read_parquet(out / "poses")
    assert poses.groupby("run_id", observed=True).size().to_dict() == per_run
    assert not poses.duplicated(["run_id", "t_ns"]).any()
    # a batch run directory loads like any run directory: its tables come from the dataset
    rid = ok["run_id"].iloc[0]
    run = slamobs.load_run(out / "runs" / rid)
    assert len(run.poses) == per_run[rid] and "run_id" not in run.poses
    assert run.poses["t_ns"].tolist() == poses[poses["run_id"] == rid]["t_ns"].tolist()
    from slamobs.cli.main import main  # and the commands that read a run directory work on it

    res = CliRunner().invoke(main, ["report", str(out / "runs" / rid), "-q"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(main, ["export", str(out / "runs" / rid), "--mcap", str(out.parent / "r.mcap"), "-q"])
    assert res.exit_code == 0 and (out.parent / "r.mcap").stat().st_size > 0, res.output
    rows = duckdb.sql(f"SELECT run_id, count(*) FROM read_parquet('{out}/poses/**/*.parquet') GROUP BY run_id")
    assert dict(rows.fetchall()) == per_run
    pl_counts = pl.read_parquet(out / "poses").group_by("run_id").len().rows()
    assert {str(k): v for k, v in pl_counts} == per_run
    assert set(pl.scan_parquet(out / "landmarks").collect()["run_id"].cast(pl.String)) == set(per_run)


# --- re-runs: skip, --force, changed config, --json -------------------------------------------------------


def _rid(out: Path, log: Path) -> str:
    (rid,) = [r for r, row in read_summary(out).items() if row["log"] == str(log.resolve())]
    return rid


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
    assert read_summary(out) == before  # nothing re-recorded: results and provenance unchanged

    rid = _rid(out, logs["circle"])
    res = invoke(logs["circle"], "-o", out, "--force", "--quiet")
    lines = res.output.strip().splitlines()
    assert res.exit_code == 0 and len(lines) == 1 and lines[0].startswith("batch: 1 log, 1 ok, 0 skipped, 0 failed")
    assert read_summary(out)[rid]["finished_at"] > before[rid]["finished_at"]
    assert len(read_summary(out)) == 4  # rows of logs outside this invocation are kept

    # another config is another run (side by side), not "done"
    cfg = tmp_path / "rate.yaml"
    cfg.write_text("output:\n  rate_hz: 10\n")
    res = invoke(logs["circle"], "-o", out, "--config", cfg, "--json")
    (row,) = [json.loads(x) for x in res.stdout.strip().splitlines()[:-1]]
    assert row["status"] == "ok" and row["run_id"] != rid
    assert row["content_hash"] == before[rid]["content_hash"] and row["config_hash"] != before[rid]["config_hash"]
    import pandas as pd

    poses = pd.read_parquet(out / "poses")
    assert set(poses["run_id"].astype(str)) == {r for r, x in read_summary(out).items() if x["status"] == "ok"}
    assert not poses.duplicated(["run_id", "t_ns"]).any()


def test_force_and_reconciliation_never_delete_what_slamobs_did_not_write(done, logs, tmp_path):
    # --force replaced OUT/runs/<id>/ whole and a start's reconciliation deleted any directory of runs/ it had no
    # record of: a user's notes in a run directory, or a directory -o named that was no batch dataset, were lost;
    # then one such file stopped the whole batch (exit 2) before any other log ran: now only that run is kept
    out = _copy(done[1], tmp_path)
    rid, other = _rid(out, logs["circle"]), _rid(out, logs["f8"])
    before = read_summary(out)
    notes = out / "runs" / rid / "notes.txt"
    notes.write_text("mine")
    res = invoke(logs["circle"], logs["f8"], "-o", out, "--force", "--json")
    *rows, done_event = [json.loads(x) for x in res.stdout.strip().splitlines()]
    by_id = {r["run_id"]: r for r in rows}
    assert res.exit_code == 4 and done_event["exit_code"] == 4 and list(done_event["kept"]) == [rid]
    assert by_id[rid]["status"] == "skipped" and by_id[rid]["error"].startswith(f"{notes}: not written by slamobs; ")
    assert f"move it out of {out}" in by_id[rid]["error"]
    assert by_id[other]["status"] == "ok"  # the other log of the batch ran
    after = read_summary(out)
    assert notes.read_text() == "mine" and after[rid] == before[rid]  # nothing deleted, nothing re-run
    assert after[other]["finished_at"] > before[other]["finished_at"]
    assert_consistent(out)
    res = invoke(logs["circle"], "-o", out, "--force", "--quiet")
    assert res.exit_code == 4 and f"{notes}: not written by slamobs; " in res.output  # --quiet still names it
    notes.unlink()
    # a report of this run killed before its switch leaves its hidden temporaries: slamobs's, no obstacle
    (out / "runs" / rid / ".batch.json.report-tmp").write_text("{}")
    assert invoke(logs["circle"], "-o", out, "--force", "--quiet").exit_code == 0  # what slamobs wrote is replaced
    assert not (out / "runs" / rid / ".batch.json.report-tmp").exists()
    assert read_summary(out)[rid]["finished_at"] > before[rid]["finished_at"]
    # a directory of the user's in runs/ (no record: a start's reconciliation would remove it as partial)
    mine = out / "runs" / "mine"
    mine.mkdir()
    (mine / "plot.png").write_text("mine")
    res = invoke(logs["circle"], "-o", out, "--force", "--quiet")
    assert res.exit_code == 4 and f"batch: {mine / 'plot.png'}: not written by slamobs; run mine kept" in res.output
    assert (mine / "plot.png").read_text() == "mine" and read_summary(out)[rid]["status"] == "ok"
    # a directory that is no batch dataset but holds names a batch writes and deletes
    foreign = tmp_path / "foreign"
    (foreign / "runs" / "x").mkdir(parents=True)
    (foreign / "runs" / "x" / "f.txt").write_text("mine")
    res = invoke(logs["circle"], "-o", foreign, "--quiet")
    assert res.exit_code == 2 and res.output == (
        f"error: {foreign}: not a slamobs batch dataset (no _slamobs/) but holds runs/, which a batch writes and "
        "deletes: write the batch to a new or empty directory\n"
    )
    assert sorted(p.name for p in foreign.rglob("*")) == ["f.txt", "runs", "x"]


# --- slamobs report on a batch run: the dataset follows the new report -------------------------------------


def _aligned_rows(out: Path, rid: str | None = None):
    import pandas as pd

    df = pd.read_parquet(out / "poses_aligned")
    df["run_id"] = df["run_id"].astype(str)
    assert not df.duplicated(["run_id", "t_ns"]).any()  # never a run twice, whatever state the switch is in
    df = df.sort_values(["run_id", "t_ns"], ignore_index=True)
    return df if rid is None else df[df["run_id"] == rid].drop(columns="run_id").reset_index(drop=True)


def _report_row(out: Path, rid: str) -> dict:
    import pandas as pd

    from slamobs.pipeline.run import headline_metrics

    rep = json.loads((out / "runs" / rid / "report.json").read_text())
    row = pd.read_parquet(out / "summary.parquet").set_index("run_id").loc[rid]
    return {k: (row[k], v) for k, v in headline_metrics(rep).items() if v is not None}


def test_report_of_a_batch_run_updates_its_rows_in_the_dataset(done, logs, tmp_path):
    import pandas as pd

    from slamobs.cli.main import main
    from slamobs.pipeline.batch.rereport import dataset_report
    from slamobs.pipeline.evaluation.run_dir import report_run

    out = _copy(done[1], tmp_path)
    rid = _rid(out, logs["f8"])
    before = read_summary(out)
    others = _aligned_rows(out).query("run_id != @rid")
    with pytest.raises(KeyboardInterrupt), dataset_report(out / "runs" / rid):  # what `slamobs report` does
        report_run(out / "runs" / rid, align="sim3")
        expected = pd.read_parquet(out / "runs" / rid / "poses_aligned.parquet")  # the new report's aligned poses
        raise KeyboardInterrupt  # Ctrl-C or SIGTERM once the report's files are replaced: the dataset follows still
    pairs = _report_row(out, rid)
    assert pairs["ape_trans_rmse_m"][0] != before[rid]["ape_trans_rmse_m"]  # Sim(3) fits better than SE(3)
    assert all(a == b for a, b in pairs.values()), pairs  # summary.parquet == the run's report.json
    pd.testing.assert_frame_equal(_aligned_rows(out, rid), expected, check_dtype=False)
    assert not (out / "runs" / rid / "poses_aligned.parquet").exists()  # stored once, in the dataset
    pd.testing.assert_frame_equal(_aligned_rows(out).query("run_id != @rid"), others)
    assert {r: x for r, x in read_summary(out).items() if r != rid} == {r: x for r, x in before.items() if r != rid}
    assert (
        json.loads((out / "runs" / rid / "batch.json").read_text())["row"]["ape_trans_rmse_m"]
        == pairs["ape_trans_rmse_m"][0]
    )
    assert_consistent(out)

    # again with the batch's alignment (the run's rows are now a partition): the batch's numbers come back
    res = CliRunner().invoke(main, ["report", str(out / "runs" / rid), "--align", "se3", "-q"])
    assert res.exit_code == 0, res.output
    pairs = _report_row(out, rid)
    assert all(a == b for a, b in pairs.values()), pairs
    assert pairs["ape_trans_rmse_m"][0] == pytest.approx(before[rid]["ape_trans_rmse_m"], rel=1e-9)
    assert (out / "poses_aligned" / f"run_id={rid}").is_dir()
    res = invoke(logs["data"], "-o", out, "--quiet")  # a batch afterwards: nothing to run, compacts, consistent
    assert res.exit_code == 0 and "0 ok, 3 skipped" in res.output
    assert not (out / "poses_aligned" / f"run_id={rid}").exists()
    assert _report_row(out, rid) == pairs
    assert_consistent(out)


def test_report_of_a_batch_run_is_refused_while_a_batch_writes(done, logs, tmp_path):
    from slamobs.cli.main import main
    from slamobs.pipeline.batch.dataset import batch_lock

    out = _copy(done[1], tmp_path)
    rid = _rid(out, logs["circle"])
    report = (out / "runs" / rid / "report.json").read_bytes()
    with batch_lock(out):  # a batch is writing to OUT
        res = CliRunner().invoke(main, ["report", str(out / "runs" / rid), "--align", "sim3"])
    assert res.exit_code == 2 and "a batch (or another report) is writing to this directory" in res.output
    assert (out / "runs" / rid / "report.json").read_bytes() == report  # nothing replaced


#: A child process that brings the dataset in line with run RID's report and SIGKILLs itself at the rename onto NAME.
_KILLED_SYNC = """
import os, signal, sys
from pathlib import Path
from slamobs.pipeline.batch.dataset import batch_lock
from slamobs.pipeline.batch.ledger import Ledger
from slamobs.pipeline.batch.rereport import sync_run
out, rid, name = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
real = os.replace
def replace(src, dest, *args, **kwargs):
    if Path(dest).name == name:
        os.kill(os.getpid(), signal.SIGKILL)
    return real(src, dest, *args, **kwargs)
os.replace = replace
with batch_lock(out):
    sync_run(out, rid, Ledger(out))
"""


def test_a_killed_report_leaves_old_or_new_rows_and_the_next_writer_completes_it(done, logs, tmp_path):
    """A real SIGKILL in the middle of the switch, on real runs (every rename: test_batch_integrity)."""
    at = "part-0.parquet"
    import subprocess
    import sys

    import pandas as pd

    from slamobs.pipeline.batch import compact_batch
    from slamobs.pipeline.evaluation.run_dir import report_run

    out = _copy(done[1], tmp_path)
    rid = _rid(out, logs["circle"])
    old_row, old_rows = read_summary(out)[rid], _aligned_rows(out, rid)
    report_run(out / "runs" / rid, align="sim3")  # a report killed after its files: the run directory is new ...
    (out / "_slamobs" / "reports").mkdir(exist_ok=True)
    (out / "_slamobs" / "reports" / rid).touch()  # ... and marked, as `slamobs report` marks it before it starts
    expected = pd.read_parquet(out / "runs" / rid / "poses_aligned.parquet")
    proc = subprocess.run([sys.executable, "-c", _KILLED_SYNC, str(out), rid, at], capture_output=True)
    assert proc.returncode == -9, proc.stderr.decode()[-2000:]
    rows = _aligned_rows(out, rid)  # readable, never twice; old rows, or (between renames) none, or new ones
    assert len(rows) == 0 or rows.equals(old_rows) or rows.equals(expected.astype(rows.dtypes))
    summary = pd.read_parquet(out / "summary.parquet").set_index("run_id")
    assert summary.loc[rid, "ape_trans_rmse_m"] == old_row["ape_trans_rmse_m"]  # the summary: old until the end
    compact_batch(out)  # `slamobs batch compact OUT`, or a batch, or a report: completes it
    pairs = _report_row(out, rid)
    assert all(a == b for a, b in pairs.values()), pairs
    assert pairs["ape_trans_rmse_m"][0] != old_row["ape_trans_rmse_m"]
    pd.testing.assert_frame_equal(_aligned_rows(out, rid), expected, check_dtype=False)
    assert not list((out / "_slamobs" / "reports").iterdir()) and not (out / "_slamobs" / "report.json").exists()
    assert not [p for p in out.rglob(".*") if p.is_file()]  # no hidden temporaries left
    assert_consistent(out)


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
    summary = pd.read_parquet(out / "summary.parquet")  # written on the way out
    assert list(summary["run_id"]) == seen and list(summary["status"]) == ["ok"]
    assert set(pd.read_parquet(out / "poses")["run_id"].astype(str)) == set(seen)
    assert not list((out / "_slamobs" / "staging").iterdir())  # the abandoned run left nothing

    result = run_batch(entries, BatchOptions(out=out, jobs=1))
    assert [r["status"] for r in result.rows] == ["skipped", "ok"] and result.exit_code == 0
    assert len(pd.read_parquet(out / "poses")["run_id"].unique()) == 2


# --- worker crashes, exit codes, arguments ----------------------------------------------------------------


def crash_on_circle(task: Task) -> dict:
    """Worker function for the crash test: dies like a segfault/OOM kill on one log."""
    from slamobs.pipeline.batch.executor import base_row

    if "circle" in task.run_id:
        os._exit(1)
    return {**base_row(task), "status": "ok"}


def test_a_log_that_kills_its_worker_fails_alone(tmp_path):
    from slamobs.pipeline.batch.local import LocalPool

    tasks = [
        Task.make(f"{name}-0", str(tmp_path / name), str(tmp_path), RunConfig()) for name in ("f8", "circle", "r2")
    ]
    rows = {r["run_id"]: r for _, r in LocalPool(2, run=crash_on_circle).results(tasks)}
    assert len(rows) == 3
    assert rows["circle-0"]["status"] == "failed"
    assert "worker process died twice while running this log (exit status 1)" in rows["circle-0"]["error"]
    assert rows["f8-0"]["status"] == rows["r2-0"]["status"] == "ok"


def test_exit_code_1_when_nothing_succeeds_and_quiet_prints_one_line(logs, tmp_path):
    manifest = tmp_path / "list.csv"
    (tmp_path / "bad_gains.yaml").write_text("gains:\n  fast-adaptation: {k_p: -1}\n")
    manifest.write_text(f"log,config\nnot_there.mcap,\n{logs['circle']},bad_gains.yaml\n")
    res = invoke(logs["bad"], manifest, "-o", tmp_path / "OUT", "-q", "-j", 1)
    assert res.exit_code == 1
    assert res.output.strip().splitlines() == [res.stdout.strip()]
    rows = {Path(r["log"]).name: r for r in read_summary(tmp_path / "OUT").values()}
    assert {r["status"] for r in rows.values()} == {"failed"} and len(rows) == 3
    assert rows["not_there.mcap"]["error"].endswith("not_there.mcap: no such file or directory")
    assert rows["circle.mcap"]["error"].startswith(f"{tmp_path / 'bad_gains.yaml'}: gains.fast-adaptation: gain k_p")
    assert rows["circle.mcap"]["config_file"] == str(tmp_path / "bad_gains.yaml")


def test_a_skipped_log_s_line_names_the_log_and_why_it_was_not_run(logs, tmp_path):
    """A nightly ``--skip-failed`` batch printed ``[1/1] skipped broken-<key>`` for a log that had failed: neither
    the log nor that it had failed (the run id of a copy of another log read the same); now both are on the line."""
    out = tmp_path / "OUT"
    assert invoke(logs["bad"], "-o", out, "-j", 1).exit_code == 1
    res = invoke(logs["bad"], "-o", out, "-j", 1, "--skip-failed")
    assert res.exit_code == 0
    (line,) = [ln for ln in res.output.splitlines() if ln.startswith("[1/1]")]
    assert line.split()[1] == "skipped" and f"  {logs['bad']}  (not retried (--skip-failed): " in line


def test_no_plots_overrides_every_config_and_report_keeps_to_it(logs, tmp_path):
    """``batch run --no-plots`` (thousands of logs): no figure in any run, a per-log config asking for every figure
    included, and ``slamobs report OUT/runs/<id>`` of such a run draws none either unless given ``--plots``."""
    from slamobs.cli.report_cmd import report

    (tmp_path / "all.yaml").write_text("evaluation:\n  plots: all\n")
    manifest = tmp_path / "list.csv"
    manifest.write_text(f"log,config\n{logs['circle']},all.yaml\n{logs['f8']},\n")
    out = tmp_path / "OUT"
    res = invoke(manifest, "-o", out, "-q", "-j", 1, "--no-plots")
    assert res.exit_code == 0, res.output
    runs = sorted((out / "runs").iterdir())
    assert len(runs) == 2 and not list(out.rglob("*.png"))
    assert all(json.loads((r / "run.json").read_text())["output"]["plots"] is False for r in runs)
    assert CliRunner().invoke(report, [str(runs[0]), "-q"]).exit_code == 0
    assert not list(runs[0].glob("*.png"))
    assert CliRunner().invoke(report, [str(runs[0]), "-q", "--plots"]).exit_code == 0
    assert "trajectory_top.png" in {p.name for p in runs[0].glob("*.png")}


def test_counts_are_spelled_for_one(logs, tmp_path):
    from slamobs.pipeline.errors import plural

    assert [plural(n, "log") for n in (0, 1, 2)] == ["0 logs", "1 log", "2 logs"]
    assert plural(1, "process", "processes") == "1 process" and plural(3, "process", "processes") == "3 processes"
    res = invoke(logs["bad"], "-o", tmp_path / "OUT", "-j", 1)
    lines = res.output.strip().splitlines()
    assert lines[0] == "batch: 1 log, 1 to run on 1 local worker process", lines
    assert lines[-1].startswith("batch: 1 log, 0 ok, 0 skipped, 1 failed"), lines


@pytest.mark.parametrize(
    "args,message",
    [
        (["nowhere/*.mcap"], "matches nothing"),
        (["{data}", "--observer", "nope"], "unknown observer"),
        (["{data}", "--executor", "local", "--scheduler", "tcp://127.0.0.1:1"], "cannot be combined"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(logs, tmp_path, args, message):
    res = invoke(*[a.format(data=logs["data"]) for a in args], "-o", tmp_path / "OUT")
    assert res.exit_code == 2
    assert len(res.output.strip().splitlines()) == 1 and message in res.output


def test_dask_missing_is_one_line(logs, tmp_path, monkeypatch):
    monkeypatch.setattr("slamobs.pipeline.batch.runner.dask_available", lambda: False)
    res = invoke(logs["circle"], "-o", tmp_path / "OUT", "--executor", "dask")
    assert res.exit_code == 2 and res.output.strip() == (
        "error: --executor dask needs Dask: pip install 'slamobs[dask]' (or: pip install \"dask[distributed]\")"
    )


# --- Dask ---------------------------------------------------------------------------------------------------


def test_unreachable_scheduler_is_one_line_and_exit_3(logs, tmp_path):
    dask = pytest.importorskip("dask")
    pytest.importorskip("distributed")
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        res = invoke(logs["circle"], "-o", tmp_path / "OUT", "--scheduler", "tcp://127.0.0.1:1", "--wait-workers", 1)
    assert res.exit_code == 3 and "Traceback" not in res.output
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
    assert (summary["worker"].str.startswith("tcp://")).all()  # ran on the Dask workers


def test_a_worker_with_other_slamobs_code_refuses_the_task(tmp_path):
    from slamobs.pipeline.batch.executor import EnvironmentMismatch, run_task

    task = Task.make("x-00000000", str(tmp_path / "x.mcap"), str(tmp_path), RunConfig())
    with pytest.raises(EnvironmentMismatch, match="the batch 0.0.1 .*install the same version"):
        run_task(replace(task, version="0.0.1"))
    with pytest.raises(EnvironmentMismatch, match="code 0123"):
        run_task(replace(task, code="0123"))


def test_warnings_are_counted_in_the_summary_not_printed(tmp_path, capfd):
    import warnings

    from slamobs.pipeline.batch.executor import run_task

    def noisy_pipeline(log, out_dir, config):
        warnings.warn("overflow encountered", RuntimeWarning, stacklevel=1)
        raise ValueError("diverged")

    (tmp_path / "stage").mkdir()
    task = replace(
        Task.make("x-00000000", str(tmp_path / "x.mcap"), str(tmp_path), RunConfig()),
        staged=str(tmp_path / "stage" / "x"),
    )
    row = run_task(task, pipeline=noisy_pipeline)
    assert row["status"] == "failed" and row["error"] == f"{tmp_path / 'x.mcap'}: ValueError: diverged"
    assert row["warnings"].startswith("RuntimeWarning: overflow encountered") and row["warning_count"] == 1
    assert capfd.readouterr().err == ""
    assert not (tmp_path / "stage" / "x").exists()


def test_a_riekf_run_whose_own_status_says_it_is_off_reads_that_status_with_a_warning(tmp_path, monkeypatch):
    """A riekf run that finished with its last detections failing the gate (run.json ``observer.filter.status``
    ``gated_at_end``) was a clean ``ok`` row; then (session 32) ``ok`` with the status among its warnings; now
    (session 33) its row's ``status`` is ``gated_at_end``, as compare's column, with the same words among its
    warnings; its tables are in the dataset all the same."""
    from slamobs.pipeline import run
    from slamobs.pipeline.batch.executor import run_task
    from slamobs.pipeline.observers.riekf import STATUSES

    def finished(log, out_dir, config, status="gated_at_end"):
        out_dir.mkdir(parents=True)
        filt = {"status": status, "status_checked": STATUSES[status]}
        return run.RunSummary(out_dir, {"observer": {"name": "riekf", "filter": filt}, "counts": {}}, {})

    (tmp_path / "stage").mkdir()
    task = replace(
        Task.make("x-00000000", str(tmp_path / "x.mcap"), str(tmp_path), RunConfig()),
        staged=str(tmp_path / "stage" / "x"),
    )
    (tmp_path / "x.mcap").write_bytes(b"x")
    monkeypatch.setattr(run, "run_log", finished)
    row = run_task(task)
    assert row["status"] == "gated_at_end" and row["warning_count"] == 1 and "tables" in row, row
    assert row["warnings"].startswith("riekf: its own status is gated_at_end in run.json observer.filter.status:"), row
    monkeypatch.setattr(run, "run_log", lambda log, out_dir, config: finished(log, out_dir, config, "converged"))
    task = replace(task, run_id="y-00000000", staged=str(tmp_path / "stage" / "y"))
    row = run_task(task)
    assert row["status"] == "ok" and row["warning_count"] == 0 and row["warnings"] is None, row


def test_a_batch_run_its_own_check_calls_likely_lost_reads_likely_lost_and_resumes_as_finished(tmp_path):
    """Session 33: a batch's summary.parquet read ``ok`` beside a run whose own check says likely lost (compare's
    column said ``likely_lost``): a user filtering ``status == "ok"`` kept it. test_compare's likely-lost run (a
    generated 10 s figure 8, the gains test_tune's likely-lost tune picked) in a batch: the summary, the progress
    line and the final counts say ``likely_lost``; its tables are in the dataset; a second batch skips it as
    finished, ``--force`` runs it again; ``stats`` counts its metrics, not a failure."""
    import pandas as pd

    from slamobs.pipeline.simulate import simulate, write_log
    from slamobs.pipeline.stats.compute import cell_stats
    from slamobs.pipeline.stats.inputs import read_dataset

    log, config, out = tmp_path / "logs" / "f.mcap", tmp_path / "run.yaml", tmp_path / "OUT"
    write_log(simulate("figure8", duration=10.0, seed=70), log)
    gains = "{alpha: 1.014, gamma: 26.53, k_p: 0.1387, k_w: 0.01826}"
    config.write_text(f"evaluation:\n  plots: false\ngains:\n  fast-adaptation: {gains}\n")
    args = (log, "-o", out, "--observer", "fast-adaptation", "--config", config, "--jobs", 1)
    res = invoke(*args)
    assert res.exit_code == 0, res.output
    assert "batch: 1 log, 0 ok, 1 likely_lost, 0 skipped, 0 failed" in res.stdout, res.output
    assert "] likely_lost " in res.output, res.output
    (rid,) = read_summary(out)
    summary = pd.read_parquet(out / "summary.parquet")
    assert summary["status"].tolist() == ["likely_lost"] and summary["warning_count"].tolist() == [1], summary
    assert summary["warnings"][0].startswith("fast-adaptation: its own status is likely_lost in run.json observer.")
    assert assert_consistent(out).keys() == {rid}  # its results are in the dataset, its run directory kept
    before = read_summary(out)[rid]

    res = invoke(*args, "--json")
    lines = [json.loads(x) for x in res.stdout.strip().splitlines()]
    assert res.exit_code == 0 and [r["status"] for r in lines[:-1]] == ["skipped"], res.output
    assert lines[-1] == {**lines[-1], "ok": 0, "off": {}, "skipped": 1, "failed": 0}, lines[-1]
    assert read_summary(out)[rid] == before  # not run again

    res = invoke(*args, "--force", "--json")
    lines = [json.loads(x) for x in res.stdout.strip().splitlines()]
    assert res.exit_code == 0 and [r["status"] for r in lines[:-1]] == ["likely_lost"], res.output
    assert lines[-1] == {**lines[-1], "ok": 0, "off": {"likely_lost": 1}, "skipped": 0}, lines[-1]
    assert read_summary(out)[rid]["finished_at"] > before["finished_at"]

    runs = read_dataset(out)
    assert runs["status"].tolist() == ["likely_lost"] and runs["ape_trans_rmse_m"][0] > 0, runs
    cells = cell_stats(runs).set_index(["metric", "log"])
    ape = cells.loc[("ape_trans_rmse_m", "all logs")]
    assert ape["n"] == 1 and ape["failed"] == 0, ape


def test_a_dask_log_fails_for_dying_workers_only_once_they_began_it_that_often(tmp_path):
    """Dask counts a worker's death against the logs queued on it too (``KilledWorker`` for a log that never ran):
    such a log is submitted again, and fails only once workers began it ``allowed-failures`` + 1 times; the task
    refuses a start past that. The kill itself: test_batch_kills_local.py (a real worker, kill -9)."""
    from slamobs.pipeline.batch.dask_exec import DaskPool
    from slamobs.pipeline.batch.executor import DIED, RETRY, run_task, starts

    (tmp_path / "stage").mkdir()
    task = replace(
        Task.make("x-00000000", str(tmp_path / "x.mcap"), str(tmp_path), RunConfig()),
        staged=str(tmp_path / "stage" / "x"),
    )
    pool = DaskPool(2)
    pool.allowed = 1
    assert pool._killed(task) is None and pool._killed(task) is None  # never began: again, twice
    row = pool._killed(task)
    assert row[RETRY] == "machine" and "died 6 times while they held this log, before it could run" in row["error"]
    ran = []
    run_task(task, pipeline=lambda log, out, cfg: ran.append(log) or 1 / 0)  # began once (and failed)
    run_task(replace(task, starts_limit=2), pipeline=lambda log, out, cfg: ran.append(log) or 1 / 0)
    assert starts(task) == 2 and len(ran) == 2
    refused = run_task(replace(task, starts_limit=2), pipeline=lambda log, out, cfg: ran.append(log))
    assert refused["status"] == "failed" and refused["error"] == f"{task.log}: {DIED}" and len(ran) == 2
    assert pool._killed(task)["error"] == f"{task.log}: {DIED}" and RETRY not in pool._killed(task)
    assert pool._killed(replace(task, staged=""))["error"] == f"{task.log}: {DIED}"  # a tune's trial: as Dask says


def test_manifest_not_utf8_is_one_line(tmp_path):
    manifest = tmp_path / "m.csv"
    manifest.write_bytes(b"log,config\n\xff\xfe,ok.yaml\n")
    with pytest.raises(
        InputError, match=r"not UTF-8 text \(byte 0xff at offset 11\): save the manifest as UTF-8"
    ) as err:
        discover([manifest])
    assert err.value.path == str(manifest) and "\n" not in str(err.value)
    res = invoke(manifest, "-o", tmp_path / "OUT", "-j", 1)
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert res.output.strip().splitlines() == [f"error: {err.value}"]


def test_manifest_saved_by_excel_with_bom_and_crlf(tmp_path):
    _fake_tree(tmp_path)
    (tmp_path / "x" / "cfg.yaml").write_text("observer: fast-adaptation\n")
    csv = tmp_path / "x" / "excel.csv"
    csv.write_bytes(b"\xef\xbb\xbflog,config\r\none.bag,cfg.yaml\r\ny/two.mcap,\r\n")
    assert discover([csv]) == [
        LogEntry(tmp_path / "x" / "one.bag", tmp_path / "x" / "cfg.yaml"),
        LogEntry(tmp_path / "x" / "y" / "two.mcap", None),
    ]
    yml = tmp_path / "x" / "excel.yaml"
    yml.write_bytes(b"\xef\xbb\xbf- y/r2\r\n")
    assert discover([yml]) == [LogEntry(tmp_path / "x" / "y" / "r2", None)]
