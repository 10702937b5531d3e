"""`slamobs compare`: several observers on one log, one table, one overlay plot."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from slamobs.pipeline.estimators import ESTIMATORS
from slamobs.pipeline.evaluation.markdown import headline_caveats
from cli_checks import SAMPLES, invoke

SAMPLE = SAMPLES / "circle.bag"


#: APE (m) on circle.bag bounded at about twice what `slamobs compare` measured (README table: 0.010-0.029 m);
#: measured 2026-12-03: fast-adaptation 0.0131, hashim 0.0101, hashim-imu 0.0102, wang-tayebi 0.0290,
#: hybrid 0.0289, riekf 0.0096, batch 0.0050.
MAX_APE_M = {
    "fast-adaptation": 0.025,
    "hashim": 0.02,
    "hashim-imu": 0.02,
    "wang-tayebi": 0.05,
    "hybrid": 0.05,
    "riekf": 0.018,
    "batch": 0.009,
}


def test_compare_all_observers_side_by_side(tmp_path):
    out = tmp_path / "cmp"
    names = list(ESTIMATORS)
    assert set(MAX_APE_M) == set(names)  # a new observer gets its measured bound here
    res = invoke("compare", SAMPLE, "-o", out, "--observers", ",".join(names))
    assert res.exit_code == 0, res.output
    # without a terminal a line as each observer starts (on a terminal: a status line with every stage)
    assert [line for line in res.stderr.splitlines() if line.startswith("compare: ")][1:] == [
        f"compare: observer {k} of {len(names)}: {name}" for k, name in enumerate(names, 1)
    ]
    table = pd.read_parquet(out / "comparison.parquet")
    assert list(table["observer"]) == names
    # every observer runs on this log: a failed row is a broken observer, not a row to skip
    assert {row["observer"]: (row["status"], row["error"]) for row in table.to_dict("records")} == {
        name: ("ok", "") for name in names
    }
    for row in table.to_dict("records"):
        run = json.loads((out / row["observer"] / "run.json").read_text())
        report = json.loads((out / row["observer"] / "report.json").read_text())
        assert run["observer"]["name"] == row["observer"]
        # the accelerometer note only for observers that use the accelerometer
        uses_accel = ESTIMATORS[row["observer"]].min_directions > 0
        assert any(n.startswith("accelerometer: ") for n in run["notes"]) == uses_accel, row["observer"]
        assert row["ape_trans_rmse_m"] == pytest.approx(report["ape"]["translation_m"]["rmse"])
        assert row["ape_trans_rmse_m"] < MAX_APE_M[row["observer"]], row["observer"]
        conv = report["convergence"]
        assert row["convergence_s"] == conv["t_since_start_s"] and row["convergence_band_m"] == conv["band_m"]
        assert conv["band_m"] == pytest.approx(max(conv["threshold_m"], 1.5 * conv["steady_level_m"]))
    assert (out / "overlay.png").stat().st_size > 1000
    md = (out / "comparison.md").read_text()
    assert all(f"| {name} | ok |" in md for name in names)
    assert "convergence_band_m" in md and "last 20 % of the log" in md
    assert "gyro_bias_err in rad/s, vel_bias_err in m/s" in md  # the table's columns carry no unit
    # every caveat of the runs' reports stands under the table (none here but what the reports say)
    caveats = [f"{n}: {c}" for n in names for c in headline_caveats(json.loads((out / n / "report.json").read_text()))]
    assert all(f"- {c}\n" in md for c in caveats) and ("## Notes" in md) == bool(caveats)
    assert all(f"note: {c}" in res.stdout for c in caveats)
    # the closing line names every file the comparison wrote (docs/outputs.md: .parquet / .md / .json, overlay)
    wrote = res.stdout.splitlines()[-1]
    written = sorted(p.name for p in out.iterdir() if p.is_file() and p.name != "slamobs-output.json")
    assert written == ["comparison.json", "comparison.md", "comparison.parquet", "overlay.png"]
    assert all(name in wrote for name in written), wrote


def test_compare_no_plots_draws_no_figure_anywhere(tmp_path):
    """``--no-plots`` (and ``evaluation.plots: false``) is honoured by the comparison's own overlay.png too, with
    truth and without; the runs' directories have no figures either. Before session 30 overlay.png was drawn
    whatever the config said."""
    config = tmp_path / "run.yaml"
    config.write_text("evaluation:\n  plots: false\n")
    for name, args in {"truth": ["--config", config], "none": ["--no-plots", "--truth", "none"]}.items():
        out = tmp_path / name
        res = invoke("compare", SAMPLE, "-o", out, "--observers", "fast-adaptation,hashim", *args)
        assert res.exit_code == 0, res.output
        assert not list(out.rglob("*.png")), name
        assert (out / "comparison.md").is_file() and "overlay.png" not in (out / "comparison.md").read_text()
        assert "overlay.png" not in res.stdout.splitlines()[-1]


def test_unknown_observer_is_a_usage_error_and_writes_nothing(tmp_path):
    out = tmp_path / "cmp"
    res = invoke("compare", SAMPLE, "-o", out, "--observers", "fast-adaptation,nope")
    assert res.exit_code == 2 and "nope" in res.stderr
    assert not out.exists()


def test_a_run_time_that_includes_compiling_says_so(tmp_path, monkeypatch):
    """On a first run an observer's run_time_s holds the kernels' compile time (riekf 46.4 s beside batch 7.3 s on
    TagSLAM test_11, 46.1 s of it compiling): the table's note and the printed summary say which."""
    from dataclasses import replace

    from slamobs.pipeline import compare

    real = compare.run_prepared

    def first_run(prepared, out, config, **kw):  # as a first run records it in run.json
        summary = real(prepared, out, config, **kw)
        compiled = {"functions": 12, "seconds": 31.25} if config.observer == "hashim" else {"functions": 0}
        return replace(summary, metadata={**summary.metadata, "compiled": compiled})

    monkeypatch.setattr(compare, "run_prepared", first_run)
    out = tmp_path / "cmp"
    res = invoke("compare", SAMPLE, "-o", out, "--observers", "fast-adaptation,hashim")
    assert res.exit_code == 0, res.output
    note = "run time includes compiling numeric kernels (first run only): hashim's 31.2 s; run again for warm times."
    assert f"note: {note}" in res.stdout and f"The {note}" in (out / "comparison.md").read_text()
    assert "fast-adaptation's" not in res.stdout


def test_headline_caveats_explain_a_blank_convergence_and_a_180_degree_rotation():
    """MR.CLAM 6 robot 1, fast-adaptation: comparison.md showed convergence_s blank beside a band of 11.2 m and a
    rotation APE of 180 deg with no word; each report's verdicts now stand under the table."""
    from slamobs.pipeline.compare import comparison_markdown
    from slamobs.pipeline.evaluation.sections import tilt_note

    lost = {"t_since_start_s": None, "lost": True, "steady_level_m": 7.47, "tail_fraction": 0.2}
    lost["trajectory_extent_m"] = 2.38
    flip = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
    stats = {"rmse": 6.2, "translation_m": {"rmse": 6.2}, "rotation_deg": {"rmse": 180.0}}
    by = {
        "se3": {"alignment": {"rotation_matrix": flip}, **stats},
        "yaw": {"alignment": {"rotation_matrix": np.eye(3).tolist()}, **stats},
    }
    report = {"convergence": lost, "method": {"alignment": {"type": "se3"}}, "ape_by_alignment": by}
    report["ape"] = {"gravity_tilt_deg": 180.0}  # the flag the tilt note's section sets
    report["notes"] = ["other note"] + tilt_note("se3", 180.0, by)  # the report's own note, as its section wrote it
    caveats = headline_caveats(report)
    assert caveats[0] == (
        "convergence: no: the error level, 7.47 m at most over the last 20 % of the log, is above the trajectory's "
        "own extent, 2.38 m RMS about its centre: the estimate never locked on to the motion"
    )
    assert len(caveats) == 2 and caveats[1] == report["notes"][1]
    assert caveats[1].startswith("the se3 alignment turned the estimate upside down")
    plain = {"convergence": {"t_since_start_s": 1.0, "coarse": False}, "method": {"alignment": {"type": "se3"}}}
    assert headline_caveats(plain) == []
    table = pd.DataFrame([{"observer": "fast-adaptation", "status": "ok"}])
    md = comparison_markdown(table, Path("x.mcap"), notes=[f"fast-adaptation: {c}" for c in caveats])
    assert "\n## Notes\n\n- fast-adaptation: convergence: no: the error level" in md


def test_an_estimators_own_status_stands_beside_the_tables_ok():
    """riekf ``gated_at_end`` or ``lost`` (run.json ``observer.filter.status``) under a table whose ``status`` column
    says ``ok`` (the run finished): before, nothing did, with or without truth (TagSLAM test_22 cut at 31 s: riekf 4.7
    m off at its end, ``ok``); a ``converged`` riekf, a ``recovered`` one and a batch run add nothing."""
    from slamobs.pipeline.compare import caveats
    from slamobs.pipeline.observers.riekf import STATUSES
    from slamobs.pipeline.run import RunSummary

    def summary(filt=None):
        return RunSummary(Path("x"), {"observer": {"name": "riekf"} | ({"filter": filt} if filt else {})}, {})

    said = caveats(
        {
            "riekf": summary({"status": "gated_at_end", "status_checked": STATUSES["gated_at_end"]}),
            "old": summary({"status": "lost"}),  # a run.json from before status_checked
            "calm": summary({"status": "converged", "status_checked": STATUSES["converged"]}),
            "again": summary({"status": "recovered"}),
            "batch": summary(),
        }
    )
    assert said == [
        f"riekf: its own status is gated_at_end in run.json observer.filter.status: {STATUSES['gated_at_end']}",
        f"old: its own status is lost in run.json observer.filter.status: {STATUSES['lost']}",
    ]


def test_compare_prints_each_runs_hint_once_named_by_its_estimator(tmp_path):
    """Session 25: `compare m7r3.mcap --observers fast-adaptation,hashim,riekf` printed no `hint` line though each
    run directory's run.json had one. A log far noisier than fast-adaptation's defaults (the coarse run of
    test_never_mislead): its hint once, prefixed by its name, in the summary, comparison.md and comparison.json;
    riekf (weighing the log's noise) none."""
    log, config, out = tmp_path / "noisy.mcap", tmp_path / "run.yaml", tmp_path / "cmp"
    config.write_text("evaluation:\n  plots: false\n")
    args = ["--duration", 20, "--gyro-noise", 0.1, "--velocity-noise", 0.08, "--detection-noise", "0.02,0,0.009"]
    rates = ["--imu-rate", 20, "--odom-rate", 20, "--detection-rate", 10]
    assert invoke("simulate", "figure8", "-o", log, *args, *rates).exit_code == 0
    res = invoke("compare", log, "-o", out, "--observers", "fast-adaptation,riekf", "--config", config)
    assert res.exit_code == 0, res.output
    hint = json.loads((out / "fast-adaptation" / "run.json").read_text())["hints"][0]
    assert json.loads((out / "riekf" / "run.json").read_text())["hints"] == []
    printed = [line for line in res.output.splitlines() if line.startswith("hint: ")]
    assert printed == [f"hint: fast-adaptation: {hint}"], res.output
    assert f"## Hints\n\n- fast-adaptation: {hint}\n" in (out / "comparison.md").read_text()
    assert json.loads((out / "comparison.json").read_text())["hints"] == [f"fast-adaptation: {hint}"]


def test_headline_caveats_go_by_the_reports_flags_not_by_the_notes_words():
    """A headline table found a report's tilt and truth-frame caveats by their notes' words (``TILT_NOTE_END``,
    ``TRUTH_FRAME_KEY``, ``CAMERA_NAMED_KEY``): a reworded note dropped its caveat without a word. They are said
    from report.json's ``ape.gravity_tilt_deg`` and ``ape.truth_frame_turn`` now, whatever the notes say, in the
    words the report's own notes have; without the flags, none."""
    from slamobs.pipeline.evaluation.sections import CAMERA_NAMED_KEY, tilt_note, truth_frame_words

    stats = {"translation_m": {"rmse": 0.05}, "rotation_deg": {"rmse": 170.0}}
    by = {"se3": {"alignment": {}, **stats}, "yaw": {"alignment": {}, **stats}}
    turn = {"angle_deg": 170.0, "axis": [1.0, 0.0, 0.0], "quat_xyzw": [0.996, 0.0, 0.0, 0.087]}
    turn |= {"rotation_rmse_after_deg": 1.0, "path_m": 30.0}
    ape = {**stats, "gravity_tilt_deg": 175.0, "truth_frame_turn": turn}
    report = {"method": {"alignment": {"type": "se3"}}, "ape_by_alignment": by, "ape": ape, "notes": ["reworded"]}
    caveats = headline_caveats(report)
    assert caveats == tilt_note("se3", 175.0, by) + [truth_frame_words(turn, 170.0, 0.05)] and len(caveats) == 2
    assert "frames.truth_rotation" in caveats[1]
    turn["camera_named"] = True
    assert (
        CAMERA_NAMED_KEY in headline_caveats(report)[1] and "frames.truth_rotation" not in headline_caveats(report)[1]
    )
    flat = {**report, "ape": {**stats, "gravity_tilt_deg": None, "truth_frame_turn": None}}
    assert headline_caveats({**flat, "notes": caveats}) == []  # the notes' words alone say nothing


def test_a_run_its_own_check_calls_likely_lost_does_not_read_ok(tmp_path):
    """Round 20 (MR.CLAM 6 r3): `compare` printed `status ok` beside fast-adaptation's likely-lost note (the column
    said only that the run finished). The status column now carries the estimator's own status where its record says
    its estimate is off, the note says why, and `stats` still reads the run (not a failed row). The gains are those
    of test_tune's likely-lost tune (they wander on a generated 10 s figure 8); hashim on defaults stays ok."""
    from slamobs.pipeline.simulate import simulate, write_log
    from slamobs.pipeline.stats.inputs import read_comparison

    log, config, out = tmp_path / "f.mcap", tmp_path / "run.yaml", tmp_path / "cmp"
    write_log(simulate("figure8", duration=10.0, seed=70), log)
    gains = "{alpha: 1.014, gamma: 26.53, k_p: 0.1387, k_w: 0.01826}"
    config.write_text(f"evaluation:\n  plots: false\ngains:\n  fast-adaptation: {gains}\n")
    res = invoke("compare", log, "-o", out, "--observers", "fast-adaptation,hashim", "--config", config)
    assert res.exit_code == 0, res.output
    table = pd.read_parquet(out / "comparison.parquet").set_index("observer")
    assert table.loc["fast-adaptation", "status"] == "likely_lost" and table.loc["hashim", "status"] == "ok"
    md = (out / "comparison.md").read_text()
    assert "| fast-adaptation | likely_lost |" in md and "| hashim | ok |" in md and "likely_lost: an observer" in md
    # one wording of the own status (session 33): the status note and the convergence line say it alike
    words = "its own status is likely_lost in run.json observer."
    assert f"note: fast-adaptation: {words}" in res.stdout, res.stdout
    assert "fast-adaptation: convergence: " in res.stdout and res.stdout.count(words) == 2, res.stdout
    assert "likely lost in run.json" not in res.stdout and "(run.json observer." not in res.stdout, res.stdout
    # stats reads the run as the run it is: finished, its metrics counted, its own status in runs.csv
    runs = read_comparison(out).set_index("estimator")
    assert runs.loc["fast-adaptation", "status"] == "likely_lost" and runs.loc["hashim", "status"] == "ok"
    assert runs.loc["fast-adaptation", "ape_trans_rmse_m"] > 0
    from slamobs.pipeline.stats.compute import cell_stats

    cells = cell_stats(runs.reset_index()).set_index(["metric", "estimator", "log"])
    fa = cells.xs(("ape_trans_rmse_m", "fast-adaptation"), level=("metric", "estimator")).iloc[0]
    assert fa["n"] == 1 and fa["failed"] == 0, fa


def test_a_split_landmarks_warning_and_the_maps_size_stand_in_the_comparison(tmp_path, monkeypatch):
    """Round 20 (TagSLAM test_11, its example config, riekf and batch): comparison.md repeated none of the runs'
    landmark-jump warnings (each report.md has them) and its `landmarks` column, "the map size", read run.json
    `counts.landmarks` (20, the log's ids) where the map held 21 after a split. The sample figure 8 without truth,
    two landmarks' ids swapped from the middle on (test_robust_reference's swap): the run splits both; the table's
    `landmarks` is landmarks.parquet's rows (two more than the ids) and the notes hold the run's warning, its words."""
    from dataclasses import replace

    import pyarrow.parquet as pq

    from slamobs.pipeline import compare
    from slamobs.pipeline.config import NO_TRUTH, parse_config, with_truth
    from test_robust_reference import ids_swapped, second_half, swap_between_candidates

    real = compare.prepare_log

    def swapped(*args, **kw):
        prepared = real(*args, **kw)
        stream = prepared.aligned
        a, b = np.argsort(np.bincount(stream.det_idx[second_half(stream)]))[-2:]
        late, _ = swap_between_candidates(stream, (a, b))
        idx = ids_swapped(stream, late, a, b)
        prepared.aligned = replace(stream, det_idx=idx)
        return prepared

    monkeypatch.setattr(compare, "prepare_log", swapped)
    config = with_truth(parse_config({"evaluation": {"plots": False}}), NO_TRUTH)
    out = tmp_path / "cmp"
    table = compare.compare_log(SAMPLES / "figure8.mcap", out, config, ["riekf"])
    run = json.loads((out / "riekf" / "run.json").read_text())
    assert len(run["observer"]["landmark_jumps"]) == 2, run["observer"]["landmark_jumps"]
    rows = pq.read_metadata(out / "riekf" / "landmarks.parquet").num_rows
    assert table["landmarks"].tolist() == [rows] and rows == run["counts"]["landmarks"] + 2
    warned = [n.removeprefix("warning: ") for n in run["notes"] if n.startswith("warning: riekf: landmark ")]
    assert warned and all(n.startswith("riekf: landmark ") for n in warned)  # as the estimator's notes stand
    md = (out / "comparison.md").read_text()
    assert all(f"- {n}\n" in md for n in warned) and all(n in table.attrs["notes"] for n in warned)
    assert f"| riekf | ok |  | {rows} |" in md, md


def test_the_overlay_title_stays_inside_the_figure_and_says_what_the_bracketed_number_is(drawn_figures):
    """`slamobs compare` on TagSLAM test_21 without truth (fast-adaptation, hashim, wang-tayebi; round 25): the
    overlay's one-line title ran past the figure's right edge, cut at "(in brackets: disagreemen", so the legend's
    numbers had no definition in the figure. The title is two lines inside the figure, and the second says the
    number is a translation RMSE in m, against the others' mean or against the reference's estimate."""
    from slamobs.pipeline.compare import plot_estimates

    t = np.linspace(0.0, 6.0, 200)
    aligned = {
        name: np.column_stack([t, np.sin(t) + k * 0.01, 0 * t])
        for k, name in enumerate(("fast-adaptation", "hashim", "wang-tayebi"))
    }
    spread = {"fast-adaptation": 0.0176, "hashim": 0.014, "wang-tayebi": 0.0144}
    for reference, against in ((None, "each of the others (their mean)"), ("wang-tayebi", "wang-tayebi's estimate")):
        plot_estimates(io.BytesIO(), aligned, spread, reference)
        fig = drawn_figures[-1]
        renderer = fig.canvas.get_renderer()
        (ax,) = fig.axes
        box = ax.title.get_window_extent(renderer)
        assert 0.0 <= box.x0 and box.x1 <= fig.get_figwidth() * fig.dpi, ax.get_title()
        assert box.y1 <= fig.get_figheight() * fig.dpi
        assert ax.get_title().endswith(f"in brackets: disagreement, translation RMSE (m) against {against}")
