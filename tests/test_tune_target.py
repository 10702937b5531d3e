"""``slamobs tune --target batch``: gains tuned against the batch smoother's solution on the same logs, so logs
without ground truth can be tuned; the --holdout logs are still scored against their truth."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

pytest.importorskip("optuna")
pytest.importorskip("gtsam")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    from slamobs.pipeline.simulate import simulate, write_log

    base = tmp_path_factory.mktemp("target_logs")
    return [write_log(simulate("figure8", duration=8.0, seed=90 + i), base / f"f{i}.mcap") for i in range(2)]


def _scores(log, target: str) -> dict:
    """The defaults of fast-adaptation scored on ``log`` in this process, as a tune's worker does."""
    from slamobs.pipeline.config import RunConfig
    from slamobs.pipeline.tune.worker import prepared_log, score

    config = replace(RunConfig(), observer="fast-adaptation")
    prepared, _ = prepared_log(str(log), config, directions=False)
    return score(prepared, config, target)


def test_batch_target_measures_against_the_smoother_and_the_holdout_against_truth(logs, tmp_path):
    from slamobs.pipeline.tune.study import TuneOptions, run_tune

    out = tmp_path / "tune"
    options = TuneOptions(
        out=out, observer="fast-adaptation", trials=2, jobs=1, seed=3, target="batch", holdout=(logs[1],)
    )
    run_tune([logs[0]], options)
    summary = json.loads((out / "tune.json").read_text())
    assert "batch smoother" in summary["objective"]["against"] and summary["setup"]["target"] == "batch"
    assert "against the batch smoother" in (out / "tune.md").read_text()
    defaults = summary["defaults"]["per_log"][str(logs[0].resolve())]
    vs_batch, vs_truth = _scores(logs[0], "batch"), _scores(logs[0], "truth")
    # trial 0 (the defaults) is scored against batch's trajectory, which is not the truth
    assert defaults == pytest.approx(vs_batch["ape_trans_rmse_m"], rel=1e-6)
    assert abs(vs_batch["ape_trans_rmse_m"] - vs_truth["ape_trans_rmse_m"]) > 1e-4
    held = summary["holdout"]["rows"][0]
    assert held["defaults"] == pytest.approx(_scores(logs[1], "truth")["ape_trans_rmse_m"], rel=1e-6)


def test_logs_without_truth_tune_against_batch(logs, tmp_path):
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.tune.study import TuneOptions, run_tune

    cfg = tmp_path / "no_truth.yaml"
    cfg.write_text("topics:\n  truth: ''\n")  # the truth role switched off: only the smoother to compare with
    options = TuneOptions(
        out=tmp_path / "t", observer="fast-adaptation", trials=2, jobs=1, config=load_config(cfg), target="batch"
    )
    result = run_tune(logs, options)
    best = result.summary["best"]
    assert result.ran == 2 and best is not None and 0 < best["objective"] < 1.0
    assert (tmp_path / "t" / "gains.yaml").is_file()
