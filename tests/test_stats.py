"""`slamobs stats`: statistics across runs of batch datasets, compare outputs and run directories."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from cli_checks import invoke

from slamobs.pipeline.batch.ledger import Ledger
from slamobs.pipeline.stats import METRICS, cell_stats, gather_runs, ranking
from slamobs.pipeline.stats.compute import ALL_LOGS

ESTIMATORS = ("riekf", "hashim", "batch")
LOGS = ("/data/a/circle.mcap", "/data/b/figure8.bag", "/data/c/notruth.mcap")
SUMMARY_METRICS = [m for m in METRICS if m != "run_time_s"]


def _row(k: int, est: str, log: str, rng: np.random.Generator, status: str = "ok") -> dict:
    """A summary row as a batch records it; the log without truth has no APE, RPE or bias errors."""
    truth = "notruth" not in log
    metrics = {m: (float(rng.uniform(0.01, 1.0)) if truth or m == "landmark_rmse_m" else None) for m in SUMMARY_METRICS}
    if status != "ok":
        metrics = dict.fromkeys(SUMMARY_METRICS)
    return {"run_id": f"r{k:03d}", "log": log, "observer": est, "status": status, "observer_s": 0.1 + k, **metrics}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A batch dataset written by the batch's own ledger: 3 estimators × 3 logs × 3 runs, one failed run, and
    one log where only riekf ran."""
    out = tmp_path_factory.mktemp("stats") / "ds"
    rng = np.random.default_rng(7)
    ledger = Ledger(out)
    k = 0
    for est in ESTIMATORS:
        for log in LOGS:
            for _ in range(3):
                ledger.put(_row(k := k + 1, est, log, rng))
    ledger.put(_row(k := k + 1, "hashim", LOGS[0], rng, status="failed"))
    ledger.put(_row(k := k + 1, "riekf", "/data/d/only.mcap", rng))
    ledger.compact()
    ledger.close()
    return out


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    """`slamobs compare` of two observers on a short simulated log (real run directories and reports)."""
    from slamobs.pipeline.simulate import simulate, write_log

    base = tmp_path_factory.mktemp("stats_cmp")
    log = write_log(simulate("circle", duration=3.0, seed=3), base / "circle4.mcap")
    (base / "run.yaml").write_text("evaluation:\n  plots: false\n")
    res = invoke("compare", log, "-o", base / "cmp", "--observers", "riekf,hashim", "--config", base / "run.yaml")
    assert res.exit_code == 0, res.output
    return base / "cmp"


def _direct(out) -> pd.DataFrame:
    """The same statistics straight from summary.parquet with pandas."""
    s = pd.read_parquet(out / "summary.parquet")
    s = s[s["status"] == "ok"].rename(columns={"observer": "estimator", "observer_s": "run_time_s"})
    s["log"] = s["log"].map(lambda p: p.rsplit("/", 1)[1])
    long = s.melt(id_vars=["estimator", "log"], value_vars=list(METRICS), var_name="metric").dropna()
    g = long.groupby(["metric", "estimator", "log"])["value"]
    return pd.DataFrame(
        {"n": g.size(), "mean": g.mean(), "median": g.median(), "min": g.min(), "max": g.max(), "std": g.std(ddof=0)}
    )


def test_numbers_match_a_direct_computation(dataset, tmp_path):
    res = invoke("stats", dataset, "-o", tmp_path / "st", "--no-plots")
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "st" / "figures").exists()
    # the closing line names every table it wrote (docs/stats_and_viewer.md lists runs.csv beside the others)
    tables = sorted(p.name for p in (tmp_path / "st").iterdir() if p.suffix in (".md", ".tex", ".csv"))
    assert tables == ["ranking.csv", "runs.csv", "stats.csv", "stats.md", "stats.tex"]
    assert all(name in res.stdout.splitlines()[-1] for name in tables), res.stdout
    got = pd.read_csv(tmp_path / "st" / "stats.csv")
    expected = _direct(dataset)
    per_log = got[got["log"] != ALL_LOGS].set_index(["metric", "estimator", "log"])
    with_values = per_log[per_log["n"] > 0]
    assert set(with_values.index) == set(expected.index)
    pd.testing.assert_frame_equal(
        with_values.loc[expected.index, list(expected.columns)], expected, check_dtype=False, rtol=1e-9
    )
    # over all logs: every run of the estimator pooled
    s = pd.read_parquet(dataset / "summary.parquet")
    riekf = s[(s["observer"] == "riekf") & (s["status"] == "ok")]["ape_trans_rmse_m"].dropna()
    pooled = got[(got["metric"] == "ape_trans_rmse_m") & (got["estimator"] == "riekf") & (got["log"] == ALL_LOGS)]
    assert pooled["n"].item() == len(riekf) and pooled["mean"].item() == pytest.approx(riekf.mean())
    assert pooled["std"].item() == pytest.approx(riekf.std(ddof=0))
    # the failed run is counted as failed, not in the statistics
    cell = per_log.loc[("ape_trans_rmse_m", "hashim", "circle.mcap")]
    assert (cell["runs"], cell["failed"], cell["n"]) == (4, 1, 3)


def test_missing_metrics_stay_missing(dataset, tmp_path):
    res = invoke("stats", dataset, "-o", tmp_path / "st", "--no-plots")
    assert res.exit_code == 0, res.output
    got = pd.read_csv(tmp_path / "st" / "stats.csv", keep_default_na=False)
    notruth = got[(got["log"] == "notruth.mcap") & (got["metric"] == "ape_trans_rmse_m")]
    assert len(notruth) == len(ESTIMATORS) and (notruth["n"] == 0).all()
    assert (notruth[["mean", "median", "min", "max", "std"]] == "").all().all()  # empty, not 0
    mapped = got[(got["log"] == "notruth.mcap") & (got["metric"] == "landmark_rmse_m")]
    assert (mapped["n"] == 3).all()
    md = (tmp_path / "st" / "stats.md").read_text()
    assert "| notruth.mcap | riekf | 3 | 0 | – | – | – | – | – |" in md
    # `runs` counts failed runs too (a log no estimator could run: runs 1, n 0): the key says so, and that a –
    # may be a failed run's, not a log without truth (`batch` over a folder of logs that cannot run, session 28)
    assert "runs read (failed ones among them: stats.csv `failed`" in md and "or every run failed" in md
    tex = (tmp_path / "st" / "stats.tex").read_text()
    assert r"notruth.mcap & riekf & 3 & 0 & -- & -- & -- & -- & -- \\" in tex
    assert r"\begin{tabular}" in tex and tex.count(r"\begin{table}") == len(METRICS) + 1


def test_ranking_counts_wins_per_metric(dataset):
    runs = gather_runs([dataset])
    stats = cell_stats(runs)
    rank = ranking(stats)
    direct = _direct(dataset).reset_index()
    for metric in METRICS:
        part = direct[direct["metric"] == metric]
        contested = part.groupby("log").filter(lambda g: len(g) >= 2)
        best = contested.loc[contested.groupby("log")["mean"].idxmin(), "estimator"]
        for est in ESTIMATORS:
            assert rank.loc[est, metric] == (best == est).sum(), (metric, est)
        assert rank.loc["contested", metric] == contested["log"].nunique()
    # only.mcap has riekf alone: never contested; notruth.mcap is contested on the map error only
    assert rank.loc["contested", "ape_trans_rmse_m"] == 2 and rank.loc["contested", "landmark_rmse_m"] == 3


def test_rpg_style(dataset, tmp_path):
    res = invoke("stats", dataset, "-o", tmp_path / "st", "--style", "rpg", "--no-plots")
    assert res.exit_code == 0, res.output
    stats = pd.read_csv(tmp_path / "st" / "stats.csv").set_index(["metric", "estimator", "log"])
    c = stats.loc[("ape_trans_rmse_m", "batch", "figure8.bag")]
    cell = f"{c['mean']:.4g}, {c['median']:.4g} ({c['min']:.4g}, {c['max']:.4g})"
    md = (tmp_path / "st" / "stats.md").read_text()
    assert cell in md and "| log | batch | hashim | riekf |" in md
    # the lowest mean of a row in bold, in both formats
    row = stats.xs(("ape_trans_rmse_m", "figure8.bag"), level=("metric", "log"))
    best = row["mean"].idxmin()
    b = row.loc[best]
    assert f"**{b['mean']:.4g}, {b['median']:.4g} (" in md
    assert rf"\textbf{{{b['mean']:.4g}, " in (tmp_path / "st" / "stats.tex").read_text()


def test_box_and_violin_figures_only_for_metrics_with_values(dataset, tmp_path):
    from slamobs.pipeline.stats import write_figures

    runs = gather_runs([dataset])
    drawn = ["ape_trans_rmse_m"]
    runs[[m for m in METRICS if m not in drawn]] = np.nan  # drawing every metric takes seconds: one suffices
    written = write_figures(runs, tmp_path / "figures")
    assert sorted(p.name for p in written) == sorted(f"{m}_{k}.png" for m in drawn for k in ("box", "violin"))
    assert all(p.stat().st_size > 5000 for p in written)


@pytest.mark.parametrize("seed", [0, 1])
def test_boxes_and_violins_are_matplotlibs_statistics(seed):
    """The figures draw their own boxes and violins (a few collections, not matplotlib's artists per group): the
    quartiles, whiskers, outliers and violin outline are those matplotlib's boxplot and violinplot compute."""
    from matplotlib import cbook, mlab

    from slamobs.pipeline.evaluation.plots import VIOLIN_POINTS, box_stats, violin_outline

    rng = np.random.default_rng(seed)
    values = np.concatenate([rng.gamma(2.0, 0.05, 300), [2.0, 3.5]])  # two far outliers
    ref = cbook.boxplot_stats(values)[0]
    q1, med, q3, low, high, out = box_stats(values)
    assert np.allclose([q1, med, q3, low, high], [ref["q1"], ref["med"], ref["q3"], ref["whislo"], ref["whishi"]])
    assert np.array_equal(np.sort(out), np.sort(ref["fliers"])) and {2.0, 3.5} <= set(out.tolist())
    outline = violin_outline(values, 4.0, 0.6)
    heights = np.linspace(values.min(), values.max(), VIOLIN_POINTS)
    density = mlab.GaussianKDE(values, "scott").evaluate(heights)
    left = outline[:VIOLIN_POINTS]
    assert np.allclose(left[:, 1], heights)
    assert np.allclose(4.0 - left[:, 0], 0.3 * density / density.max())
    assert np.allclose(outline[VIOLIN_POINTS:, 0] - 4.0, (4.0 - left[:, 0])[::-1])


def test_stats_command_does_not_import_numba(dataset, tmp_path):
    """numba (0.5-15 s to import on a loaded machine) is for runs: ``stats`` writes its tables without it."""
    import subprocess
    import sys

    code = (
        "import sys; from slamobs.cli.main import main; "
        "main(['stats', sys.argv[1], '-o', sys.argv[2], '--no-plots', '-q'], standalone_mode=False); "
        "print(sorted(m for m in sys.modules if m == 'numba' or m.startswith('numba.')))"
    )
    args = [sys.executable, "-c", code, str(dataset), str(tmp_path / "st")]
    out = subprocess.run(args, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]" and (tmp_path / "st" / "stats.md").is_file()


def test_records_newer_than_the_summary_are_read(dataset, tmp_path):
    import shutil

    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    ledger = Ledger(copy)
    ledger.put(_row(999, "newcomer", LOGS[0], np.random.default_rng(1)))  # recorded, summary not rewritten
    ledger.close()
    runs = gather_runs([copy])
    assert (runs["estimator"] == "newcomer").sum() == 1 and len(runs) == len(gather_runs([dataset])) + 1


def test_compare_outputs_and_run_directories_mixed(compared, dataset, tmp_path):
    # the compare output and one of its run directories again: that run counts once
    res = invoke("stats", compared, compared / "riekf", dataset, "-o", tmp_path / "st", "--no-plots")
    assert res.exit_code == 0, res.output
    runs = pd.read_csv(tmp_path / "st" / "runs.csv")
    mine = runs[runs["log"] == "circle4.mcap"].set_index("estimator")
    assert sorted(mine.index) == ["hashim", "riekf"]
    for est in ("riekf", "hashim"):
        report = json.loads((compared / est / "report.json").read_text())
        meta = json.loads((compared / est / "run.json").read_text())
        assert mine.loc[est, "ape_trans_rmse_m"] == pytest.approx(report["ape"]["translation_m"]["rmse"])
        assert mine.loc[est, "rpe_rot_rmse_deg"] == pytest.approx(report["rpe"]["rotation_deg"]["rmse"])
        assert mine.loc[est, "run_time_s"] == pytest.approx(meta["timings_s"]["observer_s"])
    assert len(runs) == 2 + len(gather_runs([dataset]))


def test_bad_inputs_are_one_line_and_write_nothing(dataset, tmp_path):
    (tmp_path / "empty").mkdir()
    for bad, problem in ((tmp_path / "nowhere", "does not exist"), (tmp_path / "empty", "is not a batch dataset")):
        res = invoke("stats", dataset, bad, "-o", tmp_path / "st")
        assert res.exit_code == 2
        assert res.stderr.strip().splitlines() == [res.stderr.strip()]
        assert problem in res.stderr and str(bad) in res.stderr
        assert not (tmp_path / "st").exists()
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "summary.parquet").write_bytes(b"not parquet")
    res = invoke("stats", broken, "-o", tmp_path / "st")
    assert res.exit_code == 2 and "unreadable batch summary" in res.stderr and not (tmp_path / "st").exists()


def test_cli_styles_are_the_renderers():
    from slamobs.cli.stats_cmd import STYLES as CLI_STYLES
    from slamobs.pipeline.stats.render import STYLES

    assert CLI_STYLES == STYLES


def test_a_run_with_landmark_truth_only_has_its_map_error_in_the_stats(tmp_path):
    """TagSLAM test_11 (a tag survey, no trajectory truth) in a batch dataset or as a run directory: its map error,
    0.1629 m after a map-only alignment, was "–" under "no truth, no map"; it is a metric of its own now (run.json
    map_error, the batch summary's map_error_m), beside landmark_rmse_m (after the trajectory's alignment)."""
    run = tmp_path / "run"
    run.mkdir()
    meta = {"observer": {"name": "riekf"}, "input": {"path": "/logs/tag_detections.bag"}, "tables": {}}
    meta |= {"timings_s": {"observer_s": 1.0}, "map_error": {"error_m": {"rmse": 0.1629}}}
    (run / "run.json").write_text(json.dumps(meta))
    runs = gather_runs([run])
    assert runs.loc[0, "map_error_m"] == pytest.approx(0.1629) and pd.isna(runs.loc[0, "landmark_rmse_m"])
    assert "map_error_m" in METRICS


def test_the_same_log_and_settings_run_twice_is_said_to_count_twice(compared, dataset, tmp_path):
    """A compare output and a separate `run` of the same log with the same estimator and config (as a user's batch
    over a log they had compared): two run directories, so both count, and riekf's `all logs` rows pooled that log
    twice with nothing said (MR.CLAM 6 r3 in a batch and a compare: `riekf | 2 runs`, std 0). Now a note names the
    two; the dataset's runs (each its own values) and the other estimator get none."""
    base = compared.parent
    res = invoke(
        "run", base / "circle4.mcap", "-o", tmp_path / "again", "--observer", "riekf", "--config", base / "run.yaml"
    )
    assert res.exit_code == 0, res.output
    res = invoke("stats", compared, tmp_path / "again", dataset, "-o", tmp_path / "st", "--no-plots")
    assert res.exit_code == 0, res.output
    said = [line for line in res.output.splitlines() if line.startswith("note:")]
    assert len(said) == 1 and said[0].startswith("note: riekf on circle4.mcap: 2 runs with the same value"), said
    assert str(tmp_path / "again") in said[0] and str(compared / "riekf") in said[0]
    assert f"- {said[0]}" in (tmp_path / "st" / "stats.md").read_text()
    res = invoke("stats", compared, dataset, "-o", tmp_path / "st1", "--no-plots")
    assert res.exit_code == 0 and "note:" not in res.output, res.output
