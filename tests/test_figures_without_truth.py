"""Issue 25, items 2 and 5: every run draws its figures, truth or not; `report` and `compare` work without truth;
commands show progress; a simulated log carries what a run needs to read it."""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pandas as pd
import pytest

from cli_checks import invoke

PNG = b"\x89PNG\r\n\x1a\n"
NO_TRUTH = 'topics:\n  truth: ""\n'  # the log's truth topic left unread: a log without truth


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    """A short simulated log (its truth is ignored through the config)."""
    path = tmp_path_factory.mktemp("log") / "circle.mcap"
    res = invoke("simulate", "circle", "-o", path, "--duration", "8", "-q")
    assert res.exit_code == 0, res.output
    config = path.with_name("no_truth.yaml")
    config.write_text(NO_TRUTH + "evaluation:\n  plots: all\n")  # every figure; the default draws the main ones
    return path, config


@pytest.fixture(scope="module")
def run_dir(log, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "out"
    res = invoke("run", log[0], "-o", out, "--config", log[1])
    assert res.exit_code == 0, res.output
    return out, res


def _pngs(out, names):
    for name in names:
        data = (out / name).read_bytes()
        assert data[:8] == PNG and len(data) > 5000, name


def test_a_run_without_truth_draws_and_lists_its_figures(run_dir):
    out, res = run_dir
    run = json.loads((out / "run.json").read_text())
    assert run["report"] is None and not (out / "report.json").exists()
    figures = run["figures"]
    assert {"trajectory.png", "map.png", "measurements.png", "biases.png"} <= set(figures)
    _pngs(out, figures)
    md = (out / "report.md").read_text()
    assert all(f"({name})" in md for name in figures)
    # the simulated log's landmark truth stays: the page says it has no trajectory truth (it said "no ground truth")
    # and shows the map error run.json holds
    assert md.startswith("# Run summary (no trajectory truth; map error against the landmark truth)")
    assert f"| map_error_rmse | {run['map_error']['error_m']['rmse']:.6g} |" in md
    # the summary's numbers are the run's: as many landmarks as the map table holds
    n_landmarks = len(pd.read_parquet(out / "landmarks.parquet"))
    assert f"| landmarks | {n_landmarks} |" in md
    assert "figures      trajectory.png" in res.output
    # every number says what it is and its unit (innovation_median was a bare 0.0229)
    rows = [line.split(" | ") for line in md.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert rows and all(len(r) == 3 and r[2].strip(" |") for r in rows), rows
    assert any(r[0] == "| innovation_median" and r[2].startswith("m, median") for r in rows)
    # the map against the run's own poses: each detection placed by its pose (track − innovation) vs the final map
    tracks, innov = pd.read_parquet(out / "landmark_tracks.parquet"), pd.read_parquet(out / "innovations.parquet")
    final = pd.read_parquet(out / "landmarks.parquet").set_index("id").loc[tracks["id"], ["x", "y", "z"]].to_numpy()
    placed = tracks[["x", "y", "z"]].to_numpy() - innov[["ex", "ey", "ez"]].to_numpy()
    residual = float(np.median(np.linalg.norm(final - placed, axis=1)))
    row = next(r for r in rows if r[0] == "| map_residual_median")
    assert float(row[1]) == pytest.approx(residual, rel=1e-5) and row[2].startswith("m, median")


def test_the_map_without_trajectory_truth_draws_the_landmark_truth_it_is_measured_against(run_dir):
    """h-user9, TagSLAM test_11: with landmark truth but no trajectory truth, map.png drew the estimate only, not the
    survey its map error was measured against. The truth is drawn, carried onto the estimate by the inverse of the
    map-only fit the map error is after, and the legend says so."""
    from slamobs.pipeline.evaluation.figure_jobs import MAP_PNG, run_figure_jobs, run_tables
    from slamobs.pipeline.simulate.scenarios import get_scenario

    out, _ = run_dir
    map_error = json.loads((out / "run.json").read_text())["map_error"]
    fit = map_error["alignment"]
    rot, trans = np.array(fit["rotation_matrix"]), np.array(fit["translation_m"])
    sc = get_scenario("circle")
    truth = dict(zip(sc.landmark_ids, sc.landmarks))
    estimate = pd.read_parquet(out / "landmarks.parquet").set_index("id")
    for row in map_error["per_landmark"]:
        placed = np.array(row["truth_on_estimate_m"])
        assert rot @ placed + trans == pytest.approx(truth[row["id"]], abs=1e-9)  # the fit's inverse
        gap = np.linalg.norm(placed - estimate.loc[row["id"], ["x", "y", "z"]].to_numpy(float))
        assert gap == pytest.approx(row["error_m"], abs=1e-6)  # as far from its estimate as its map error says
    (job,) = [j for j in run_figure_jobs(run_tables(out), map_error=map_error) if j[1] == MAP_PNG]
    assert len(job[2]["truth_xyz"]) == map_error["n_matched"] > 0
    assert "map-only SE(3) fit onto the estimate" in job[2]["truth_label"]


def test_report_without_truth_draws_the_figures_again(run_dir):
    out, _ = run_dir
    (out / "map.png").unlink()
    res = invoke("report", out)
    assert res.exit_code == 0, res.output
    assert "truth        none" in res.output and "map.png" in res.output
    rmse = json.loads((out / "run.json").read_text())["map_error"]["error_m"]["rmse"]
    assert f"landmarks    map error rmse {rmse:.4f} m over" in res.output  # as `run` printed it (report said nothing)
    assert (
        f"map          {len(pd.read_parquet(out / 'landmarks.parquet'))} landmarks; the detections placed" in res.output
    )
    assert re.search(r"median innovation [0-9.e-]+ m\n", res.output), res.output
    _pngs(out, json.loads((out / "run.json").read_text())["figures"])
    as_json = json.loads(invoke("report", out, "--json").stdout)
    assert as_json["landmarks"] == len(pd.read_parquet(out / "landmarks.parquet"))
    assert as_json["path_length_m"] > 1.0


def test_report_json_without_trajectory_truth_carries_every_number_of_report_md(run_dir):
    """h-user11: with landmark truth and no trajectory truth, `report --json` lacked the map error report.md shows
    (its one error number), and said what none of its numbers were."""
    out, _ = run_dir
    as_json = json.loads(invoke("report", out, "--json").stdout)
    md = (out / "report.md").read_text()
    rows = [line.split(" | ") for line in md.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert {r[0].removeprefix("| ") for r in rows} >= {"map_error_rmse", "map_error_max", "map_error_landmarks"}
    for key, shown, meaning in rows:
        key = key.removeprefix("| ")
        value = as_json[key]
        assert shown == (
            "–"
            if value is None
            else ", ".join(f"{v:.4g}" for v in value)
            if isinstance(value, list)
            else f"{value:.6g}"
            if isinstance(value, float)
            else str(value)
        ), key
        assert as_json["definitions"][key] == meaning.removesuffix(" |") != "", key
    run = json.loads((out / "run.json").read_text())
    assert as_json["map_error_rmse"] == run["map_error"]["error_m"]["rmse"]
    assert as_json["map_error"] == run["map_error"] and as_json["truth"] == "landmarks only"
    assert as_json["notes"] == run["notes"] and as_json["figures"] == run["figures"]


def test_a_run_with_truth_adds_its_own_figures_to_the_report(log, tmp_path):
    out, config = tmp_path / "out", tmp_path / "all.yaml"
    config.write_text("evaluation:\n  plots: all\n")
    res = invoke("run", log[0], "-o", out, "--config", config)
    assert res.exit_code == 0, res.output
    report = json.loads((out / "report.json").read_text())
    assert {"trajectory.png", "map.png", "measurements.png", "trajectory_top.png", "errors.png"} <= set(
        report["figures"]
    )
    _pngs(out, report["figures"])
    assert json.loads((out / "run.json").read_text())["figures"] == report["figures"]


def test_the_default_figures_are_the_main_ones(log, tmp_path):
    """``evaluation.plots: true`` (the default) draws the main figures only: with truth the top view and the
    error over time, without truth the estimate and its map (each figure costs 0.3-0.5 s of matplotlib)."""
    for name, text, main in (
        ("truth", "", ["trajectory_top.png", "errors.png"]),
        ("none", NO_TRUTH, ["trajectory.png", "map.png"]),
    ):
        out, config = tmp_path / name, tmp_path / f"{name}.yaml"
        config.write_text(text or "{}\n")
        assert invoke("run", log[0], "-o", out, "--config", config, "-q").exit_code == 0
        figures = json.loads((out / "run.json").read_text())["figures"]
        assert figures == main
        assert sorted(p.name for p in out.glob("*.png")) == sorted(main)
        _pngs(out, figures)


def test_compare_without_truth_measures_disagreement(log, tmp_path):
    from slamobs.pipeline.compare import disagreement
    from slamobs.pipeline.writers import read_columns

    out, names = tmp_path / "cmp", ("fast-adaptation", "hashim", "batch")
    config = tmp_path / "c.yaml"
    config.write_text(NO_TRUTH + "evaluation:\n  plots: false\n")  # the runs' own figures are tested above
    # --plots: overlay.png follows evaluation.plots (session 30), the runs then draw their main figures
    res = invoke("compare", log[0], "-o", out, "--observers", ",".join(names), "--config", config, "--plots")
    assert res.exit_code == 0, res.output
    table = pd.read_parquet(out / "comparison.parquet").set_index("observer")
    assert list(table["status"]) == ["ok"] * 3
    spread = table["disagreement_m"]  # against the batch smoother's estimate, in the list
    assert spread["batch"] == 0.0 and spread["fast-adaptation"] > 0 and spread["hashim"] > 0
    assert (table["landmarks"] > 0).all() and (table["path_length_m"] > 1.0).all()
    assert (out / "overlay.png").read_bytes()[:8] == PNG
    assert "no ground truth" in (out / "comparison.md").read_text()
    assert "overlay.png" in res.output
    poses = {n: read_columns(out / n / "poses.parquet") for n in names[:2]}
    again, aligned = disagreement({**poses, "batch": read_columns(out / "batch" / "poses.parquet")}, "batch")
    assert again["hashim"] == pytest.approx(spread["hashim"]) and set(aligned) == set(names)
    # without batch each is measured against the others: two estimates, one APE (rigid alignment: symmetric)
    pair, _ = disagreement(poses, None)
    assert pair["fast-adaptation"] > 0 and pair["fast-adaptation"] == pytest.approx(pair["hashim"], rel=1e-6)


# ------------------------------------------------------------------------------------------------- progress


def test_progress_without_a_terminal_prints_a_line_now_and_then(capsys):
    from slamobs.cli.progress import Progress

    lines: list[str] = []
    with Progress(every_s=0.1) as progress:
        progress("step one")
        # one long step: the heartbeat repeats its line. Waited for, not slept: a loaded machine may not wake the
        # heartbeat within a fixed sleep (0.45 s, 4 intervals); the bound only turns a silent heartbeat into a failure
        deadline = time.monotonic() + 60.0
        while len(lines) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
            lines += capsys.readouterr().err.splitlines()
    lines += capsys.readouterr().err.splitlines()
    assert len(lines) >= 2 and all(line.startswith("[") and line.endswith(" s] step one") for line in lines)
    with Progress(every_s=600.0) as progress:  # done sooner than a line is due: nothing
        progress("quick")
    with Progress(quiet=True, every_s=0.01) as progress:
        progress("quiet")
        time.sleep(0.05)
    assert capsys.readouterr().err == ""


def test_simulate_shows_progress_without_a_terminal(tmp_path, monkeypatch):
    # What simulate tells its progress is counted, not timed (CI once wrote the 20 s log within two 0.05 s lines):
    # several "s written" messages, moving forward; the printed line then needs only the run to outlast 10 ms.
    from slamobs.cli.progress import Progress

    heard: list[str] = []
    tell = Progress.__call__

    def recording(self, message: str) -> None:
        heard.append(message)
        tell(self, message)

    monkeypatch.setattr(Progress, "__call__", recording)
    monkeypatch.setenv("SLAMOBS_PROGRESS_EVERY", "0.01")
    res = invoke("simulate", "circle", "-o", tmp_path / "c.mcap", "--duration", "20")
    assert res.exit_code == 0, res.output
    written = [float(m.split()[1]) for m in heard if m.endswith("s written")]
    assert len(written) >= 2 and written == sorted(written) and written[-1] > written[0], heard
    lines = [line for line in res.stderr.splitlines() if line.startswith("[")]
    assert lines and any("simulate:" in line for line in lines), res.stderr


# -------------------------------------------------------------------------------- self-describing simulated logs


@pytest.fixture(scope="module")
def corners_log(tmp_path_factory):
    """A simulated log of tag corners and its run without a config."""
    path = tmp_path_factory.mktemp("corners") / "corners.mcap"
    res = invoke("simulate", "circle", "-o", path, "--duration", "6", "--camera", "corners", "--tag-size", "0.6", "-q")
    assert res.exit_code == 0, res.output
    res = invoke("run", path, "-o", path.with_name("own"), "-q")
    assert res.exit_code == 0, res.output
    return path


def test_a_simulated_camera_log_runs_without_config(corners_log):
    from slamobs.pipeline.readers import read_log

    assert read_log(corners_log).recorded == {"tag_size": 0.6, "tag_family": "36h11"}
    notes = json.loads((corners_log.with_name("own") / "run.json").read_text())["notes"]
    assert any("tag size 0.6 m and family 36h11 as the simulated log records them" in n for n in notes)


def test_the_config_overrides_what_the_log_records(corners_log, tmp_path):
    config = tmp_path / "run.yaml"
    config.write_text("tags:\n  size: 0.3\nevaluation:\n  plots: false\n")
    res = invoke("run", corners_log, "-o", tmp_path / "half", "-q", "--config", config)
    assert res.exit_code == 0, res.output
    notes = json.loads((tmp_path / "half" / "run.json").read_text())["notes"]
    assert not any("as the simulated log records them" in n for n in notes)
    # another tag size puts every tag at another distance: other tag poses from the same corners
    half = pd.read_parquet(tmp_path / "half" / "tag_detections.parquet")
    own = pd.read_parquet(corners_log.with_name("own") / "tag_detections.parquet")
    assert len(half) == len(own) and not half.equals(own)


def test_a_figure_that_fails_is_a_note_not_a_failed_run(log, tmp_path, monkeypatch):
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.evaluation import plots
    from slamobs.pipeline.run import run_log

    def broken(*_args, **_kwargs):
        raise ValueError("no room for the map")

    monkeypatch.setattr(plots, "plot_map", broken)
    summary = run_log(log[0], tmp_path / "out", load_config(log[1]))  # figures drawn in this process
    assert "no figures: no room for the map" in summary.notes
    assert summary.metadata["figures"] == [] and not list((tmp_path / "out").glob("*.png"))
    assert (tmp_path / "out" / "poses.parquet").is_file()


def test_report_with_truth_on_a_run_without_it_is_kept(log, tmp_path):
    """`report RUN --truth T` on a run without truth makes its error report; `report RUN` later reuses T instead
    of replacing that report with the summary."""
    out = tmp_path / "out"
    config = tmp_path / "c.yaml"
    config.write_text(NO_TRUTH + "evaluation:\n  plots: false\n")
    assert invoke("run", log[0], "-o", out, "--config", config, "-q").exit_code == 0
    first = invoke("report", out, "--truth", "/mocap/pose", "--json")
    assert first.exit_code == 0, first.output
    again = invoke("report", out, "--json", "--plots")  # the run's plots: false kept without --plots (session 30)
    assert again.exit_code == 0, again.output
    assert json.loads(again.stdout)["ape"] == json.loads(first.stdout)["ape"]
    assert (out / "report.json").is_file() and (out / "trajectory_top.png").is_file()


def test_innovation_lines_break_where_no_detection_was_made():
    """Time bins with innovations on both sides of a 40 s stretch without detections: the line stops there (a NaN
    after the gap) instead of drawing values nobody measured across it."""
    import numpy as np

    from slamobs.pipeline.evaluation.plots import break_at_gaps

    t = np.r_[np.arange(0.0, 10.0, 0.5), np.arange(50.0, 60.0, 0.5)]
    y = np.ones_like(t)
    tb, yb = break_at_gaps(t, y)
    assert tb.size == t.size + 1 and np.isnan(tb[20]) and np.isnan(yb[20])
    assert np.array_equal(tb[~np.isnan(tb)], t)
    tb, yb = break_at_gaps(np.arange(5.0), np.arange(5.0))  # evenly spaced: untouched
    assert not np.isnan(tb).any()


def test_report_md_of_a_log_without_any_truth_says_so_once(log, tmp_path):
    """No trajectory and no landmark truth: report.md said "no ground truth" in its title, its first sentence and
    again in its notes; now in the title alone (run.json's notes keep the note: it has no title)."""
    config = tmp_path / "none.yaml"
    config.write_text(NO_TRUTH + '  sim_truth: ""\n')
    res = invoke("run", log[0], "-o", tmp_path / "out", "--config", config)
    assert res.exit_code == 0, res.output
    md = (tmp_path / "out" / "report.md").read_text()
    assert md.startswith("# Run summary (no ground truth)") and md.count("ground truth") == 1, md
    notes = json.loads((tmp_path / "out" / "run.json").read_text())["notes"]
    assert any(n.startswith("no ground truth in the log") for n in notes)


def test_the_3d_view_is_drawn_to_one_scale_and_says_when_its_height_is_stretched():
    """matplotlib fills the 3D box on every axis, so 1 m of height drew as long as 40 m of path; the view keeps
    one scale, and a nearly level path's height, stretched to be seen, is stated in the title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from slamobs.pipeline.evaluation.plots import MIN_Z_SHARE, one_scale_3d

    s = np.linspace(0.0, 1.0, 200)
    level = np.column_stack([40.0 * s, 20.0 * s, 1.0 * np.sin(6 * s)])  # 40 m x 20 m, ~1 m of height
    ax = plt.figure().add_subplot(projection="3d")
    note = one_scale_3d(ax, level)
    x, y, z = ax.get_box_aspect()
    assert x / y == pytest.approx(2.0, rel=1e-6) and z / x == pytest.approx(MIN_Z_SHARE, rel=1e-6)
    assert note == f" (z stretched {MIN_Z_SHARE * 40.0 / np.ptp(level[:, 2]):.3g}x)"
    steep = np.column_stack([10.0 * s, 10.0 * s, 8.0 * s])  # a climb: its own height, no stretch
    ax = plt.figure().add_subplot(projection="3d")
    assert one_scale_3d(ax, steep) == " (one scale)"
    x, y, z = ax.get_box_aspect()
    assert z / x == pytest.approx(0.8, rel=1e-6)
    plt.close("all")


def test_a_path_at_one_height_is_said_level_not_stretched_by_a_billion():
    """evo's tf_example (odom -> base_footprint, planar) with `evaluate ... -p`: z is 0 everywhere and the title
    said "z stretched 7.11e+08x" (the height's floor of 1e-9 m). A path whose height varies by less than the
    step lengths are written at has no height to stretch: " (z constant)"; a path 1 mm high is still stretched."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from slamobs.pipeline.evaluation.plots import MIN_Z_SHARE, one_scale_3d

    s = np.linspace(0.0, 1.0, 200)
    flat = np.column_stack([1.2 * s, -3.0 * s, np.zeros_like(s)])
    ax = plt.figure().add_subplot(projection="3d")
    assert one_scale_3d(ax, flat) == " (z constant)"
    assert one_scale_3d(ax, flat + [0.0, 0.0, 5.0]) == " (z constant)"
    low = flat + np.column_stack([0 * s, 0 * s, 0.001 * s])
    assert one_scale_3d(ax, low) == f" (z stretched {MIN_Z_SHARE * 3.0 / 0.001:.3g}x)"
    plt.close("all")


def test_the_3d_view_s_short_side_gets_fewer_ticks():
    """TagSLAM test 11's trajectory: 18 m in x, 5 m in y, 16 m in z; drawn to one scale the y side is short, and its
    six tick labels (-4 to 1) drew over one another. A side gets tick intervals in proportion to its length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from slamobs.pipeline.evaluation.plots import one_scale_3d

    s = np.linspace(0.0, 1.0, 200)
    path = np.column_stack([18.0 * s - 10.0, 5.0 * np.sin(7 * s) - 2.0, 16.0 * s])
    ax = plt.figure().add_subplot(projection="3d")
    ax.plot(*path.T)
    one_scale_3d(ax, path)

    def shown(ticks, lim):
        return [t for t in ticks if lim[0] - 1e-9 <= t <= lim[1] + 1e-9]

    y = shown(ax.get_yticks(), ax.get_ylim())
    x = shown(ax.get_xticks(), ax.get_xlim())
    assert 2 <= len(y) <= 3, y  # 5 m of 18: 2 intervals
    assert 4 <= len(x) <= 7, x  # the longest side: at most 6 intervals
    plt.close("all")


def test_a_log_axis_over_less_than_a_decade_is_labelled_in_plain_numbers():
    """nees.png's attitude panel (NEES 0.2 to 4) was labelled 2×10⁰, 3×10⁰, 4×10⁰ by matplotlib's minor ticks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from slamobs.pipeline.evaluation.plots import plain_log_axis

    fig, ax = plt.subplots()
    ax.plot([0, 1, 2], [0.2, 1.0, 4.0])
    ax.set_yscale("log")
    plain_log_axis(ax.yaxis)
    fig.canvas.draw()
    lo, hi = ax.get_ylim()
    shown = [t.get_text() for t in ax.get_yticklabels() if lo <= t.get_position()[1] <= hi and t.get_text()]
    minor = [t.get_text() for t in ax.yaxis.get_minorticklabels() if t.get_text()]
    plt.close(fig)
    assert shown == ["0.2", "0.5", "1", "2"] and not minor, (shown, minor)


def test_map_labels_clear_each_other_and_the_markers():
    """TagSLAM test_11's map.png: "6 (506)" over "36 (19)" and "35 (24)" over "11 (22)", every label drawn 4 pt
    above right of its landmark. Two landmarks 6 pt apart and a third under the first's usual spot: their label
    boxes now share no area and reach into no marker; the fixed spot overlapped both."""
    from slamobs.pipeline.evaluation.plots import MAP_MARKER_RADIUS_PT, box_overlap, disc_overlap, label_offsets

    anchors = np.array([[100.0, 100.0], [106.0, 101.0], [115.0, 110.0]])
    sizes = np.array([[31.5, 8.5], [31.5, 8.5], [36.0, 8.5]])

    def clashes(offsets):
        boxes = [np.r_[a + o, a + o + s] for a, o, s in zip(anchors, offsets, sizes)]
        shared = sum(box_overlap(b[:2], b[2:], boxes[:k]) for k, b in enumerate(boxes))
        return shared, sum(disc_overlap(b[:2], b[2:], anchors, MAP_MARKER_RADIUS_PT) for b in boxes)

    assert all(c > 0 for c in clashes(np.full((3, 2), 4.0)))
    assert clashes(label_offsets(anchors, sizes, MAP_MARKER_RADIUS_PT)) == (0.0, 0.0)


def test_the_map_names_its_frame(monkeypatch, tmp_path):
    """MR.CLAM 6 robot 3, riekf, `report`: map.png drew landmarks 16-18 at (-0.8, 0.5) m, trajectory_top.png beside
    it at (4, 3.2) m (aligned onto the truth), neither title saying which frame: the map's now names its own, as
    trajectory.png's does."""
    from slamobs.pipeline.evaluation import plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    xyz = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.0]])
    plots.plot_map(tmp_path / "map.png", np.array([1, 2]), xyz, np.array([3, 4]), xyz)
    (fig,) = figures
    assert fig.axes[0].get_title().startswith("Landmark map, output frame: 2 landmarks")


def test_a_bias_figure_s_y_labels_stay_inside_the_figure(drawn_figures):
    """MR.CLAM 6 robot 3's batch biases.png: velocity biases of a few mm/s tick as 0.0025 and -0.0005, and the
    label "velocity bias b_V [m/s]" beside them was cut off at the figure's left edge (fixed margins in inches).
    The grid moves right by what the labels reach past the edge; a figure whose labels fit is drawn as before."""
    import io

    from slamobs.pipeline.evaluation import plots

    t = np.linspace(0.0, 900.0, 500)
    gyro = np.tile([0.0, 0.0, 0.005], (len(t), 1))
    velocity = np.tile([0.00245, -0.00063, 0.0], (len(t), 1))
    plots.plot_biases(io.BytesIO(), t, gyro, velocity, window_start_s=700.0)
    plots.plot_biases(io.BytesIO(), t, 10.0 * gyro, 100.0 * velocity)  # ticks 0.05, 0.25: they fit
    (small, plain) = drawn_figures
    renderer = small.canvas.get_renderer()
    for ax in small.axes:
        box = ax.yaxis.get_tightbbox(renderer)
        assert box.x0 >= 0.0 and ax.yaxis.label.get_window_extent(renderer).x0 >= 0.0, ax.get_ylabel()
    assert plain.subplotpars.left == pytest.approx(0.85 / 10.0)  # _figure's margin, not moved
    assert small.subplotpars.left > plain.subplotpars.left


def test_an_rpe_plot_s_three_line_title_stays_inside_the_figure(drawn_figures):
    """`slamobs evaluate --metric rpe -p` (round 24, evo's EuRoC V1_01 OpenVINS files): the title is evo's three
    lines, "RPE w.r.t. rotation angle in degrees (deg)" / "for delta = 1.0 (m) using consecutive pairs" / "(not
    aligned)", and the first, the one that says what is plotted, was drawn above the figure's top edge (fixed
    margins in inches). The grid moves down by what a title reaches past the top; the gap between the rows is
    kept."""
    import io

    from slamobs.pipeline.evaluation import plots

    t = np.linspace(0.0, 130.0, 60)
    xyz = np.column_stack([np.cos(t / 20.0), np.sin(t / 20.0), 0.01 * t])
    errors = 0.2 + 0.1 * np.sin(t)
    stats = {"rmse": 0.25, "median": 0.2, "mean": 0.21, "std": 0.07}
    title = "RPE w.r.t. rotation angle in degrees (deg)\nfor delta = 1.0 (m) using consecutive pairs\n(not aligned)"
    plots.plot_error_result(io.BytesIO(), t, errors, stats, xyz, xyz, xyz, title=title, label="RPE (deg)")
    (fig,) = drawn_figures
    renderer = fig.canvas.get_renderer()
    top = fig.get_figheight() * fig.dpi
    for ax in fig.axes:
        assert ax.title.get_window_extent(renderer).y1 <= top, ax.get_title()
    upper, trajectory = fig.axes[:2]  # the error over time; the trajectory panel below it
    assert upper.get_title() == title
    assert upper.xaxis.get_tightbbox(renderer).y0 > trajectory.title.get_window_extent(renderer).y1  # no overlap


def test_an_evaluate_plot_draws_no_line_across_a_stretch_without_pairs(drawn_figures):
    """evo's TUM fr2_desk ORB-SLAM estimate (`evaluate tum ... -as -p`, round 24): 719 of its 2893 poses have no
    truth stamp, and the error over time and the reference path were drawn as straight lines across the 14 s
    without pairs, errors and a path nobody measured. Both break there (``break_at_gaps``, as the innovation
    figure does); the pairs' values are drawn as before."""
    import io

    from slamobs.pipeline.evaluation import plots

    t = np.concatenate([np.arange(0.0, 30.0, 0.1), np.arange(45.0, 100.0, 0.1)])
    xyz = np.column_stack([np.cos(t / 10.0), np.sin(t / 10.0), np.zeros_like(t)])
    errors = 0.005 + 0.001 * np.sin(t)
    stats = {"rmse": 0.006, "median": 0.005, "mean": 0.005, "std": 0.001}
    plots.plot_error_result(io.BytesIO(), t, errors, stats, xyz, xyz, xyz, plot_mode="xy", label="APE (m)")
    (fig,) = drawn_figures
    upper, trajectory = fig.axes[:2]
    (line,) = [ln for ln in upper.get_lines() if ln.get_label() == "APE (m)"]
    x, y = (np.asarray(v, dtype=np.float64) for v in line.get_data())
    gap = np.flatnonzero(np.isnan(y))
    assert len(gap) == 1 and x[gap[0] - 1] < 30.0 and x[gap[0] + 1] == pytest.approx(45.0)
    assert np.array_equal(y[np.isfinite(y)], errors)
    (reference,) = [ln for ln in trajectory.get_lines() if ln.get_label() == "reference"]
    assert np.isnan(np.asarray(reference.get_xdata(), dtype=np.float64)).sum() == 1


def test_the_innovation_median_is_drawn_over_the_percentile_and_maximum(drawn_figures):
    """TagSLAM test_22's measurements.png: one or two detections per time bin, so median, 95th percentile and
    maximum are one value; the median, drawn first, lay under the other two and its blue line was nowhere."""
    import io

    from slamobs.pipeline.evaluation import plots

    t = np.arange(0.0, 10.0, 0.25)
    one = {"t_s": t, "median": np.ones_like(t), "p95": np.ones_like(t), "max": np.ones_like(t)}
    plots.plot_measurements(io.BytesIO(), t, np.ones_like(t), one)
    lines = {line.get_label(): line.get_zorder() for line in drawn_figures[0].axes[1].get_lines()}
    assert lines["median"] > lines["95th percentile"] > lines["maximum"], lines


def test_a_bias_figure_says_what_its_shaded_stability_window_is(drawn_figures):
    """Round 26 (h-newuser12): biases.png shades the report's stability window and named it "stability window" in
    the legend, defined only in report.md's Method table. The top title says what it is, its share of the bias
    time span where known, inside the figure; a figure without the window says nothing of it."""
    import io

    from slamobs.pipeline.evaluation import plots

    t = np.linspace(0.0, 900.0, 500)
    gyro, velocity = np.tile([0.0, 0.0, 0.005], (len(t), 1)), np.tile([0.00245, -0.00063, 0.0], (len(t), 1))
    plots.plot_biases(io.BytesIO(), t, gyro, velocity, window_start_s=720.0)
    plots.plot_biases(io.BytesIO(), t, gyro, velocity, window_start_s=720.0, window_fraction=0.2)
    plots.plot_biases(io.BytesIO(), t, gyro, velocity)
    (unknown, known, plain) = drawn_figures
    said = unknown.axes[0].get_title()
    assert "shaded: the stability window" in said and "report.md's mean, std, range and drift" in said, said
    assert "the last 20 % of the bias time span" in known.axes[0].get_title()
    renderer = known.canvas.get_renderer()
    box = known.axes[0].title.get_window_extent(renderer)
    width, height = known.bbox.width, known.bbox.height
    assert box.x0 >= 0.0 and box.x1 <= width and box.y1 <= height, (box, width, height)
    assert "stability" not in plain.axes[0].get_title()
