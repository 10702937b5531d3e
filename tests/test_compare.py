"""`slamobs compare`: several observers on one log, one table, one overlay plot."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from slamobs.cli.main import main
from slamobs.pipeline.estimators import ESTIMATORS

SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs" / "circle.bag"


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_compare_all_observers_side_by_side(tmp_path):
    out = tmp_path / "cmp"
    names = list(ESTIMATORS)
    res = invoke("compare", SAMPLE, "-o", out, "--observers", ",".join(names))
    assert res.exit_code == 0, res.output
    # without a terminal a line as each observer starts (on a terminal: a status line with every stage)
    assert [line for line in res.stderr.splitlines() if line.startswith("compare: ")][1:] == [
        f"compare: observer {k} of {len(names)}: {name}" for k, name in enumerate(names, 1)]
    table = pd.read_parquet(out / "comparison.parquet")
    assert list(table["observer"]) == names
    for row in table.to_dict("records"):
        if row["status"] == "ok":
            run = json.loads((out / row["observer"] / "run.json").read_text())
            report = json.loads((out / row["observer"] / "report.json").read_text())
            assert run["observer"]["name"] == row["observer"]
            # the accelerometer note only for observers that use the accelerometer
            uses_accel = ESTIMATORS[row["observer"]].min_directions > 0
            assert any(n.startswith("accelerometer: ") for n in run["notes"]) == uses_accel, row["observer"]
            assert row["ape_trans_rmse_m"] == pytest.approx(report["ape"]["translation_m"]["rmse"])
            assert row["ape_trans_rmse_m"] < 0.5
            conv = report["convergence"]
            assert row["convergence_s"] == conv["t_since_start_s"] and row["convergence_band_m"] == conv["band_m"]
            assert conv["band_m"] == pytest.approx(max(conv["threshold_m"], 1.5 * conv["steady_level_m"]))
        else:
            assert row["error"]
    assert (table["status"] == "ok").any()
    assert (out / "overlay.png").stat().st_size > 1000
    md = (out / "comparison.md").read_text()
    assert "| fast-adaptation | ok |" in md and "convergence_band_m" in md and "last 20 % of the log" in md


def test_unknown_observer_is_a_usage_error_and_writes_nothing(tmp_path):
    out = tmp_path / "cmp"
    res = invoke("compare", SAMPLE, "-o", out, "--observers", "fast-adaptation,nope")
    assert res.exit_code == 2 and "nope" in res.stderr
    assert not out.exists()
