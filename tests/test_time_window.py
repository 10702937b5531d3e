"""A time window (issue 26, part 5): ``--start`` / ``--end`` and ``time.start`` / ``time.end`` run on a part of the
log; run.json and the report say which; a window outside the log is one line."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from cli_checks import SAMPLES, invoke
from slamobs.pipeline.alignment import ABSOLUTE_AFTER_S, time_window
from slamobs.pipeline.config import RunConfig, parse_config
from slamobs.pipeline.errors import InputError

LOG = SAMPLES / "circle.bag"


@pytest.fixture(scope="module")
def windowed_run(tmp_path_factory):
    where = tmp_path_factory.mktemp("window")
    config = where / "run.yaml"
    config.write_text("evaluation:\n  plots: false\n")  # the figures are most of a short run's time
    out = where / "run"
    res = invoke("run", LOG, "-o", out, "--config", config, "--start", "5", "--end", "20", "-q")
    assert res.exit_code == 0, res.output
    return out


def test_run_uses_only_the_window_and_says_so(windowed_run):
    meta = json.loads((windowed_run / "run.json").read_text())
    win = meta["time_window"]
    assert win["given"] == [5.0, 20.0] and (win["start_s"], win["end_s"]) == (5.0, 20.0)
    assert win["start_ns"] == win["log_start_ns"] + 5 * 10**9 and win["end_ns"] == win["log_start_ns"] + 20 * 10**9
    t = pd.read_parquet(windowed_run / "poses.parquet")["t_ns"].to_numpy()
    assert win["start_ns"] <= t.min() < win["start_ns"] + 10**8 and win["end_ns"] - 10**8 < t.max() <= win["end_ns"]
    report = json.loads((windowed_run / "report.json").read_text())
    assert report["time_window"] == win
    truth_span = report["time_span"]["truth_ns"]
    assert win["start_ns"] <= truth_span[0] and truth_span[1] <= win["end_ns"]  # the truth was cut too
    assert "Time window: 5.000 s to 20.000 s from the log's start" in (windowed_run / "report.md").read_text()


def test_report_again_keeps_the_window(windowed_run):
    from slamobs.pipeline.evaluation.run_dir import report_run

    report, _ = report_run(windowed_run)
    win = report["time_window"]
    assert win["start_s"] == 5.0 and win["start_ns"] <= report["time_span"]["truth_ns"][0]
    assert report["time_span"]["truth_ns"][1] <= win["end_ns"]


@pytest.mark.parametrize("args", [("--start", "100"), ("--end", "1500000000"), ("--start", "20", "--end", "10")])
def test_a_window_outside_the_log_is_one_line(tmp_path, args):
    out = tmp_path / "run"
    res = invoke("run", LOG, "-o", out, *args, catch_exceptions=True)
    assert res.exit_code == 2
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {LOG}") and "time window" in lines[0]
    assert not out.exists()


def test_relative_and_absolute_bounds():
    t0 = 1_700_000_000_010_000_000
    rel = time_window(5.0, None, t0)
    absolute = time_window(1_700_000_005.01, None, t0)
    assert rel.start_ns == absolute.start_ns == t0 + 5 * 10**9 and rel.end_ns is None
    assert time_window(None, None, t0) is None
    assert time_window(ABSOLUTE_AFTER_S, None, 0).start_ns == 10**18  # at the threshold: relative
    assert list(rel.keeps(np.array([t0, t0 + 5 * 10**9, t0 + 6 * 10**9]))) == [False, True, True]


def test_config_keys_and_command_options():
    config = parse_config({"time": {"start": 2, "end": 8.5}})
    assert (config.time.start, config.time.end) == (2.0, 8.5)
    assert RunConfig().with_window(None, 3.0).time.end == 3.0 and RunConfig().with_window().time.start is None
    with pytest.raises(InputError, match="end 1 is not after start 2"):
        parse_config({"time": {"start": 2, "end": 1}})
    for command in (("run",), ("compare",), ("batch", "run")):
        res = invoke(*command, "--help")
        assert "--start" in res.output and "--end" in res.output and "1e9" in res.output, command


def test_a_window_keeps_every_field_it_does_not_cut():
    """``alignment.windowed`` built a new AlignedStream from a list of its fields and left out those added later:
    under a time window run.json's ``input.body_frame_from`` was empty (the report's body-frame notes, which need it,
    were dropped), ``input.base_frame`` null and the detection pairs' ``gyro_turn`` / ``gyro_moved_s`` lost."""
    from dataclasses import fields

    from slamobs.pipeline.alignment import windowed
    from slamobs.pipeline.run import prepare_log

    aligned = prepare_log(LOG, parse_config({}), noise=False).aligned
    aligned = replace(aligned, base_frame={"frame": "base_link"}, gyro_turn={"turn": 1}, gyro_moved_s=0.1)
    cut = windowed(aligned, time_window(5.0, 20.0, aligned.t0_ns), LOG)
    assert cut.vel_t_ns.shape[0] < aligned.vel_t_ns.shape[0] and aligned.body_from
    moved = {"t0_ns", "vel_t_ns", "omega", "velocity", "det_t_ns", "det_offsets", "det_idx", "det_y", "landmark_ids"}
    moved |= {"notes", "directions", "segment_starts"}
    for f in fields(aligned):
        if f.name not in moved:
            assert getattr(cut, f.name) is getattr(aligned, f.name), f.name
