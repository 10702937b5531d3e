"""End to end through the ``slamobs`` command, as a user or a cron job runs it (a fresh process each time): the
features tested elsewhere only below the CLI. ``time.source: auto`` on a log whose truth is stamped on another
clock, ``run --export mcap``, and ``batch --prune`` after a log was deleted."""

from __future__ import annotations

import json
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from batch_checks import CLI, assert_consistent

#: A quiet run: the figures are not what these tests check, and drawing them is most of a short run's time.
NO_PLOTS = "evaluation:\n  plots: false\n"


def slamobs(*args, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def _config(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def late_truth(tmp_path_factory) -> Path:
    """A 15 s figure-8 whose motion-capture header stamps run 0.5 s ahead of every other clock (a mocap PC with
    its own clock); its record times are right. On a figure-8 the SE(3) alignment cannot hide the lag (on a
    circle flown at constant speed it is a rotation)."""
    from slamobs.pipeline.simulate import simulate, write_log

    sim = simulate("figure8", duration=15.0, seed=3)
    mocap = replace(sim.mocap, t_ns=sim.mocap.t_ns + 500_000_000)
    return write_log(replace(sim, mocap=mocap), tmp_path_factory.mktemp("clock") / "late_mocap.mcap")


def test_time_source_auto_takes_record_time_for_the_topic_on_another_clock(late_truth, tmp_path):
    """Measured: APE 0.092 m with ``auto`` (the same log with correct stamps: 0.091 m), 0.44 m with header stamps;
    the bound sits at about 1.5x the first and a third of the last."""
    out = tmp_path / "auto"
    done = slamobs(
        "run", late_truth, "-o", out, "--config", _config(tmp_path / "auto.yaml", "time:\n  source: auto\n" + NO_PLOTS)
    )
    assert done.returncode == 0, done.stderr
    meta = json.loads((out / "run.json").read_text())
    assert meta["input"]["clocks"] == {"/mocap/pose": "record"}  # only the topic on the other clock
    note = "/mocap/pose: header clock is +0.500 s off /imu/data's (wall clock), use record time for it"
    assert note in meta["notes"] and note in done.stdout
    ape = json.loads((out / "report.json").read_text())["ape"]["translation_m"]["rmse"]
    assert ape < 0.14
    # `slamobs report` reads the truth again the same way (run.json's clocks): the same numbers
    again = slamobs("report", out)
    assert again.returncode == 0, again.stderr
    assert json.loads((out / "report.json").read_text())["ape"]["translation_m"]["rmse"] == ape


def test_time_source_header_keeps_the_stamps_of_the_same_log(late_truth, tmp_path):
    """The other side of the test above: without ``auto`` the same log is evaluated on its header stamps (the
    lag shows in the APE), so the log does carry the problem ``auto`` solves."""
    out = tmp_path / "header"
    done = slamobs("run", late_truth, "-o", out, "--config", _config(tmp_path / "header.yaml", NO_PLOTS))
    assert done.returncode == 0, done.stderr
    assert json.loads((out / "run.json").read_text())["input"]["clocks"] == {}
    assert json.loads((out / "report.json").read_text())["ape"]["translation_m"]["rmse"] > 0.3


SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs" / "circle.bag"


def test_run_export_mcap_writes_the_results_mcap(tmp_path):
    """``slamobs run --export mcap``: results.mcap beside the tables, and only it of the optional exports; its pose
    messages are rows of poses.parquet."""
    from mcap.reader import make_reader

    out = tmp_path / "out"
    done = slamobs("run", SAMPLE, "-o", out, "--export", "mcap", "--config", _config(tmp_path / "r.yaml", NO_PLOTS))
    assert done.returncode == 0, done.stderr
    names = {p.name for p in out.iterdir()}
    assert "results.mcap" in names and not names & {"estimate_tum.txt", "truth_tum.txt", "ape_evo.zip"}
    assert json.loads((out / "run.json").read_text())["output"]["export"] == ["mcap"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # nothing temporary left
    poses = pd.read_parquet(out / "poses.parquet")
    with (out / "results.mcap").open("rb") as f:
        reader = make_reader(f)
        topics = {c.topic for c in reader.get_summary().channels.values()}
        stamps = [m.log_time for _, c, m in reader.iter_messages(topics=["/slamobs/pose"])]
    assert {"/slamobs/pose", "/tf", "/slamobs/landmarks"} <= topics
    assert len(stamps) > 100 and np.isin(stamps, poses["t_ns"]).all()
    assert stamps[0] == poses["t_ns"].iloc[0] and stamps[-1] == poses["t_ns"].iloc[-1]


def test_batch_prune_drops_the_runs_of_deleted_logs(tmp_path):
    """``slamobs batch --prune`` after a log was deleted: without ``--prune`` its run stays; with it the run leaves
    the summary, the tables and runs/, the other runs stay untouched and nothing is run again."""
    from slamobs.pipeline.batch.ledger import read_summary
    from slamobs.pipeline.simulate import simulate, write_log

    logs = tmp_path / "logs"
    logs.mkdir()
    paths = [write_log(simulate("circle", duration=3.0, seed=60 + i), logs / f"p{i}.mcap") for i in range(3)]
    out, cfg = tmp_path / "OUT", _config(tmp_path / "run.yaml", NO_PLOTS)
    first = slamobs("batch", logs, "-o", out, "--config", cfg, "-j", "1")
    assert first.returncode == 0, first.stderr
    runs = {row["log"]: rid for rid, row in assert_consistent(out).items()}
    assert sorted(runs) == sorted(map(str, paths))

    paths[1].unlink()
    kept = slamobs("batch", logs, "-o", out, "--config", cfg, "-j", "1", "--json")
    assert kept.returncode == 0, kept.stderr
    assert json.loads(kept.stdout.splitlines()[-1])["pruned"] == 0  # not asked for: the run of p1 stays
    assert set(assert_consistent(out)) == set(runs.values())

    before = read_summary(out)
    pruned = slamobs("batch", logs, "-o", out, "--config", cfg, "-j", "1", "--prune")
    assert pruned.returncode == 0, pruned.stderr
    assert "batch: pruned 1 run whose logs are gone" in pruned.stderr
    assert "batch: 2 logs, 0 ok, 2 skipped, 0 failed" in pruned.stdout  # nothing run again
    rows = assert_consistent(out)
    assert set(rows) == {runs[str(paths[0])], runs[str(paths[2])]}
    assert {rid: rows[rid]["finished_at"] for rid in rows} == {rid: before[rid]["finished_at"] for rid in rows}
