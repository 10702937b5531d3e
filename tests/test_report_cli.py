"""`slamobs report` and `slamobs evaluate` (click command objects, through CliRunner), and evo's own CLI as the
oracle of `evaluate`'s printed output (subprocess with SLAMOBS_EVO_PYTHON; skipped without it)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from slamobs.cli.evaluate_cmd import evaluate
from slamobs.cli.report_cmd import report
from slamobs.pipeline.config import OutputConfig, RunConfig
from slamobs.pipeline.evaluation.evo_zip import load_result_zip
from slamobs.pipeline.evaluation.figure_jobs import RUN_FIGURES
from slamobs.pipeline.evaluation.report import REPORT_FILES, validate_report
from slamobs.pipeline.evaluation.run_dir import replace_files
from slamobs.pipeline.run import run_log

SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs" / "circle.bag"
EVO_PYTHON = os.environ.get("SLAMOBS_EVO_PYTHON")


def invoke(cmd, *args, catch: bool = False):
    return CliRunner().invoke(cmd, [str(a) for a in args], catch_exceptions=catch)


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "circle"
    run_log(SAMPLE, out, RunConfig(output=OutputConfig(export=("tum", "evo"))))
    return out


@pytest.fixture
def run_dir(finished_run, tmp_path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(finished_run, copy)
    return copy


def load(path: Path) -> dict:
    return json.loads(path.read_text())


# ------------------------------------------------------------------------------------------ slamobs report


def test_report_recomputes_the_run_report(run_dir):
    before = load(run_dir / "report.json")
    res = invoke(report, run_dir)
    assert res.exit_code == 0, res.output
    after = load(run_dir / "report.json")
    validate_report(before)
    validate_report(after)
    assert before["truth_source"]["time_source"] == "header"  # the run's own report names the truth's clock too
    assert after["ape"] == before["ape"] and after["landmarks"] == before["landmarks"]
    assert after["truth_source"]["kind"] == "topic" and after["truth_source"]["name"] == "/mocap/pose"
    # every report file but the figures, and every figure the report lists (an observer has no covariance: no
    # uncertainty figures)
    assert "uncertainty.png" not in after["figures"] and set(after["figures"]) <= set(REPORT_FILES) | set(RUN_FIGURES)
    for name in [n for n in REPORT_FILES if not n.endswith(".png")] + after["figures"]:
        assert (run_dir / name).is_file(), name
    assert load(run_dir / "run.json")["report_truth"]["name"] == "/mocap/pose"
    assert "APE          translation rmse" in res.output and "pairs, SE(3)-aligned" in res.output
    assert "evo_ape tum truth_tum.txt estimate_tum.txt -a" in res.output
    conv = after["convergence"]  # the summary says that the error's level (a running median) stays in the band
    assert (
        f"median position error over {conv['window_s']:.3g} s within {conv['band_m']:.3g} m from then on" in res.output
    )
    assert not [p for p in run_dir.iterdir() if p.name.startswith(".report-")]


def test_report_against_a_trajectory_file(run_dir, tmp_path):
    truth_file = shutil.copy(run_dir / "truth_tum.txt", tmp_path / "gt.txt")
    before = load(run_dir / "report.json")
    res = invoke(report, run_dir, "--truth", truth_file)
    assert res.exit_code == 0, res.output
    after = load(run_dir / "report.json")
    assert after["truth_source"] == {
        "kind": "file",
        "format": "tum",
        "name": str(truth_file),
        "n_poses": 1500,
        "time_source": "file stamps",
    }
    assert after["ape"] == before["ape"]  # the exported truth is the log's truth, to the nanosecond
    assert after["landmarks"]["error_m"] == before["landmarks"]["error_m"]  # map truth still from the log


def test_report_of_a_run_whose_truth_was_a_file(finished_run, tmp_path):
    """A run with ``evaluation.truth_file`` is reported again from that file: `slamobs report RUN` took the file's
    path for a topic of the log ("topic for role truth is not in the log")."""
    from slamobs.pipeline.config import parse_config

    truth_file = shutil.copy(finished_run / "truth_tum.txt", tmp_path / "gt.txt")
    out = tmp_path / "run"
    run_log(SAMPLE, out, parse_config({"evaluation": {"truth_file": str(truth_file), "plots": False}}))
    assert load(out / "run.json")["input"]["truth_file"] == {"path": str(truth_file), "format": None, "times": None}
    before = load(out / "report.json")
    assert before["truth_source"]["time_source"] == "file stamps"  # as docs/outputs.md lists it
    res = invoke(report, out, "-q")
    assert res.exit_code == 0, res.output
    after = load(out / "report.json")
    assert after["truth_source"]["kind"] == "file" and after["truth_source"]["name"] == str(truth_file)
    assert after["ape"] == before["ape"]


def test_report_options_json_and_kept_options(run_dir):
    res = invoke(
        report,
        run_dir,
        "--align",
        "origin",
        "--t-offset",
        "auto",
        "--rpe-delta",
        "0.5",
        "--drift-lengths",
        "5,10",
        "--json",
    )
    assert res.exit_code == 0, res.output
    rep = json.loads(res.stdout)
    validate_report(rep)
    assert rep["method"]["alignment"]["type"] == "origin"
    assert rep["time_offset"]["applied_from"] == "estimate"
    assert rep["rpe"]["delta"] == 0.5 and rep["drift"]["lengths_m"] == [5.0, 10.0]
    assert "--align_origin" in rep["evo"]["ape"]
    again = invoke(report, run_dir, "-q")  # a re-report keeps the options of the report it replaces
    assert again.exit_code == 0 and again.output == ""
    assert load(run_dir / "report.json")["options"] == rep["options"]
    back = invoke(report, run_dir, "--align", "se3", "--t-offset", "0", "--json")
    assert json.loads(back.stdout)["method"]["alignment"]["type"] == "se3"


def test_tf_truth_on_a_log_without_tf_names_what_the_log_lacks(run_dir):
    """TF truth is supported: on this log (``/tf_static`` only, no ``/tf``) the one line names the log, the edge
    and the missing topic, and the previous report stays."""
    before = {f.name: f.read_bytes() for f in run_dir.iterdir()}
    res = invoke(report, run_dir, "--truth", "world->base_link")
    assert res.exit_code == 2
    assert res.stderr.splitlines() == [
        f"error: {SAMPLE}: truth TF edge world->base_link needs a /tf topic; the log has none"
    ]
    assert {f.name: f.read_bytes() for f in run_dir.iterdir()} == before


def test_report_errors_are_one_line(run_dir, tmp_path):
    res = invoke(report, tmp_path)
    assert res.exit_code == 2 and "not a run directory" in res.stderr
    res = invoke(report, run_dir, "--truth", "/no/such/topic")
    assert res.exit_code == 2 and "/no/such/topic" in res.stderr
    res = invoke(report, run_dir, "--t-offset", "soon")
    assert res.exit_code == 2 and "auto" in res.output
    meta = load(run_dir / "run.json")
    meta["input"]["path"] = str(tmp_path / "moved.bag")
    (run_dir / "run.json").write_text(json.dumps(meta))
    res = invoke(report, run_dir)
    assert res.exit_code == 2 and "input log is not there" in res.stderr


def test_a_directory_of_runs_given_as_a_run_names_them(finished_run, tmp_path):
    """Round 21: `slamobs export figure8_cmp -o e.mcap` (a compare output) and `slamobs report dataset` (a batch
    dataset) said only "not a run directory (no run.json)"; the line now names the run directories they hold."""
    import slamobs
    from slamobs.pipeline.errors import InputError

    cmp = tmp_path / "cmp"
    for name in ("riekf", "batch"):
        shutil.copytree(finished_run, cmp / name)
    res = invoke(report, cmp)
    assert res.exit_code == 2, res.output
    assert res.stderr.splitlines() == [
        f"error: {cmp}: not a run directory (no run.json); it holds run directories ({cmp / 'batch'}, "
        f"{cmp / 'riekf'}): give one of them"
    ]
    with pytest.raises(InputError, match=r"runs/one\): give one of them"):
        shutil.copytree(finished_run, tmp_path / "ds" / "runs" / "one")
        slamobs.load_run(tmp_path / "ds")
    res = invoke(report, tmp_path / "nothing")
    assert res.stderr.splitlines() == [f"error: {tmp_path / 'nothing'}: not a run directory (no run.json)"]


def test_failed_report_leaves_the_previous_one(run_dir, monkeypatch):
    import slamobs.pipeline.evaluation.run_dir as rd

    old = {name: (run_dir / name).read_bytes() for name in REPORT_FILES + ("run.json",) if (run_dir / name).is_file()}
    assert "report.json" in old and "errors.png" in old

    def half_written(report_, out, *args, **kwargs):
        (Path(out) / "report.json").write_text("{ half")
        raise OSError("disk full")

    monkeypatch.setattr(rd, "write_report", half_written)
    res = invoke(report, run_dir, "--align", "origin", catch=True)
    assert isinstance(res.exception, OSError)
    assert {name: (run_dir / name).read_bytes() for name in old} == old
    assert not [p for p in run_dir.iterdir() if p.name.startswith(".report")]


KILLED_REPORT = """
import os, signal, sys
from pathlib import Path
import slamobs.pipeline.evaluation.run_dir as rd

def killed(report_, out, *args, **kwargs):  # SIGKILLed with a table half-written in the staging
    (Path(out) / "poses_aligned.parquet").write_bytes(b"PAR1 half")
    os.kill(os.getpid(), signal.SIGKILL)

rd.write_report = killed
rd.report_run(sys.argv[1])
"""


def test_a_report_killed_while_staging_leaves_nothing_the_next_report_keeps(run_dir):
    """A ``slamobs report`` SIGKILLed while writing its staging left ``.report-*`` with a half-written Parquet file
    in the run for good (a recursive glob of the outputs read it: kill matrix seed 61); the next report removes it."""
    done = subprocess.run([sys.executable, "-c", KILLED_REPORT, str(run_dir)], timeout=300)
    assert done.returncode == -9
    left = [p for p in run_dir.iterdir() if p.name.startswith(".report")]
    assert len(left) == 1 and list(left[0].rglob("*.parquet")), left
    res = invoke(report, run_dir)
    assert res.exit_code == 0, res.output
    assert not [p for p in run_dir.iterdir() if p.name.startswith(".")], sorted(p.name for p in run_dir.iterdir())
    validate_report(load(run_dir / "report.json"))


def test_replace_files_renames_and_drops_stale_ones(tmp_path):
    run, staged = tmp_path / "run", tmp_path / "run" / ".staged"
    staged.mkdir(parents=True)
    (run / "report.json").write_text("old")
    (run / "landmarks.png").write_text("stale")
    (run / "poses.parquet").write_text("data")
    (staged / "report.json").write_text("new")
    moved = replace_files(run, staged, REPORT_FILES)
    assert [p.name for p in moved] == ["report.json"]
    assert (run / "report.json").read_text() == "new" and not (run / "landmarks.png").exists()
    assert (run / "poses.parquet").read_text() == "data"


# ------------------------------------------------------------------------------------------ slamobs evaluate


def test_evaluate_prints_like_evo_and_matches_the_report(finished_run, tmp_path):
    rep = load(finished_run / "report.json")
    truth, est = finished_run / "truth_tum.txt", finished_run / "estimate_tum.txt"
    res = invoke(evaluate, truth, est, "-a")
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    assert lines[:3] == ["APE w.r.t. translation part (m)", "(with SE(3) Umeyama alignment)", ""]
    stats = dict(line.split("\t") for line in lines[3:10])
    assert [k.strip() for k in stats] == ["max", "mean", "median", "min", "rmse", "sse", "std"]
    for k, v in stats.items():
        assert float(v) == pytest.approx(rep["ape"]["translation_m"][k.strip()], abs=5e-7)
    assert lines[11].split("\t") == ["     pairs", str(rep["ape"]["translation_m"]["n"])]
    # our poses.parquet is a valid estimate too, and --json carries every number with its method
    as_json = json.loads(invoke(evaluate, truth, finished_run / "poses.parquet", "-a", "--json").stdout)
    assert as_json["stats"] == rep["ape"]["translation_m"]
    assert as_json["method"]["association"]["n_pairs"] == rep["method"]["association"]["n_pairs"]


def test_evaluate_never_saves_results_over_its_inputs(finished_run, tmp_path):
    """``--save-results`` onto the truth or estimate file would replace it with a zip (it did, exit 0)."""
    for i in (0, 1):
        truth, est = tmp_path / "truth.txt", tmp_path / "est.txt"
        shutil.copy(finished_run / "truth_tum.txt", truth)
        shutil.copy(finished_run / "estimate_tum.txt", est)
        target = (truth, est)[i]
        before = target.read_bytes()
        res = invoke(evaluate, truth, est, "-a", "--save-results", target)
        assert res.exit_code == 2 and "is the input" in res.output and target.read_bytes() == before


def test_evaluate_rpe_options_zip_and_offset(finished_run, tmp_path):
    truth, est = finished_run / "truth_tum.txt", finished_run / "estimate_tum.txt"
    zip_path = tmp_path / "rpe.zip"
    res = invoke(
        evaluate,
        truth,
        est,
        "--metric",
        "rpe",
        "--delta",
        "1",
        "--delta_unit",
        "m",
        "-as",
        "-r",
        "angle_deg",
        "--save_results",
        zip_path,
        "--estimate-t-offset",
    )
    assert res.exit_code == 0, res.output
    assert res.stdout.startswith(
        "RPE w.r.t. rotation angle in degrees (deg)\nfor delta = 1.0 (m) using "
        "consecutive pairs\n(with Sim(3) Umeyama alignment)\n"
    )
    # circle.bag turns at a constant rate and speed: no clock information, and the output says so
    assert "t_offset\tnot estimated: the motion carries no clock information" in res.output
    info, stats, arrays = load_result_zip(zip_path)
    assert info["label"] == "RPE (deg)" and info["est_name"] == str(est)
    assert set(stats) == {"rmse", "mean", "median", "std", "min", "max", "sse"}
    assert arrays["error_array"].size == arrays["timestamps"].size > 0
    res = invoke(
        evaluate,
        truth,
        est,
        "--align_origin",
        "-r",
        "full",
        "--n_to_align",
        "10",
        "--t_offset",
        "auto",
        "--sync_method",
        "interpolation",
        "--json",
    )
    doc = json.loads(res.stdout)
    assert doc["method"]["association"]["method"] == "interpolation"
    off = doc["time_offset"]  # report.json's time_offset fields (sections.offset_fields)
    assert off["estimated_s"] is None and off["reliable"] is None and off["uncertainty_s"] is None
    assert off["applied_s"] == 0.0 and off["applied_from"] == "estimate" and off["searched_against"] == "estimate"
    # a turn rate that varies pins the offset, and auto applies it: the estimate's clock 0.25 s behind
    t = np.arange(6000) / 100.0
    yaw = np.sin(0.7 * t) + 0.3 * np.sin(2.1 * t)
    rows = np.column_stack(
        [t, t, np.zeros_like(t), np.zeros_like(t), np.zeros_like(t), np.zeros_like(t), np.sin(yaw / 2), np.cos(yaw / 2)]
    )
    np.savetxt(tmp_path / "truth.txt", rows, fmt="%.9f")
    rows[:, 0] -= 0.25
    np.savetxt(tmp_path / "late.txt", rows[::2], fmt="%.9f")
    doc = json.loads(
        invoke(evaluate, tmp_path / "truth.txt", tmp_path / "late.txt", "--t_offset", "auto", "--json").stdout
    )
    assert doc["time_offset"]["reliable"] and doc["time_offset"]["applied_s"] == pytest.approx(0.25, abs=0.002)
    # the estimate's halves agree (one `reliable` with a run's search of its log, session 27: no halves until then)
    assert doc["time_offset"]["uncertainty_s"] <= doc["time_offset"]["grid_step_s"]
    rows[len(rows) // 2 :, 0] += 0.25  # its second half on the truth's clock: the halves 0.25 s apart
    np.savetxt(tmp_path / "split.txt", rows[::2], fmt="%.9f")
    split = json.loads(
        invoke(evaluate, tmp_path / "truth.txt", tmp_path / "split.txt", "--estimate-t-offset", "--json").stdout
    )["time_offset"]
    assert split["uncertainty_s"] == pytest.approx(0.125, abs=0.01) and split["reliable"] is False, split
    # the printed line says why, as report.md does (markdown.offset_doubts), not a bare "NOT reliable"
    line = invoke(evaluate, tmp_path / "truth.txt", tmp_path / "split.txt", "--t_offset", "auto").stdout
    assert "NOT reliable: the estimate's halves find offsets 0.2" in line and " s apart)" in line, line


def test_evaluate_of_a_run_states_the_offset_its_report_states(tmp_path):
    """`slamobs evaluate TRUTH RUN/poses.parquet --t-offset auto` with the run's own truth: the search the run made
    against its log's velocity samples (gyro bias fitted, halves' uncertainty_s), not another one against the
    estimate, so evaluate and the run's report.json give the same offset, reliable flag and uncertainty (until
    session 27 evaluate searched the estimate, without uncertainty_s). A 20 s figure 8 whose truth is 0.1 s late."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import simulate
    from slamobs.pipeline.simulate.logwriter import write_log

    sim = simulate("figure8", seed=2, duration=20.0)
    late = 100_000_000
    sim = replace(sim, mocap=replace(sim.mocap, t_ns=sim.mocap.t_ns + late, rec_ns=sim.mocap.rec_ns + late))
    log = write_log(sim, tmp_path / "late_truth.mcap")
    out = tmp_path / "run"
    run_log(log, out, RunConfig(evaluation=replace(RunConfig().evaluation, plots=False)))
    meta, want = load(out / "run.json"), load(out / "report.json")["time_offset"]
    truth = f"{log}:{meta['input']['topics']['truth']}"
    res = invoke(evaluate, truth, out / "poses.parquet", "-a", "--t-offset", "auto", "--json")
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)["time_offset"]
    assert got["searched_against"] == want["searched_against"] == "velocity samples"
    for key in ("estimated_s", "reliable", "uncertainty_s", "peak_correlation", "grid_step_s", "method"):
        assert got[key] == want[key], key
    assert want["uncertainty_s"] is not None and abs(got["applied_s"] - 0.1) <= want["grid_step_s"]
    line = invoke(evaluate, truth, out / "poses.parquet", "-a", "--estimate-t-offset").stdout
    assert f"halves ±{want['uncertainty_s']:.6f} s" in line and "against the run's log" in line, line


def test_evaluate_usage_errors(finished_run, tmp_path):
    truth, est = finished_run / "truth_tum.txt", finished_run / "estimate_tum.txt"
    assert invoke(evaluate, truth, est, "-a", "--align_origin").exit_code == 2
    assert invoke(evaluate, truth, est, "-s", "--align-yaw").exit_code == 2
    res = invoke(evaluate, truth, tmp_path / "nope.txt")
    assert res.exit_code == 2 and "nope.txt: no such file" in res.stderr
    shifted = tmp_path / "late.txt"
    shifted.write_text(
        "".join(
            f"{float(line.split()[0]) + 3600:.9f} {line.split(' ', 1)[1]}\n" for line in est.read_text().splitlines()
        )
    )
    res = invoke(evaluate, truth, shifted)
    assert res.exit_code == 2 and "same clock" in res.stderr
    res = invoke(evaluate, truth, est, "--metric", "rpe", "--delta", "1000", "--delta_unit", "m")
    assert res.exit_code == 2 and "no pose pair" in res.stderr


def test_evaluate_kitti_pairs_by_index(tmp_path):
    rng = np.random.default_rng(3)
    rows = []
    for k in range(20):
        r = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        r *= np.sign(np.linalg.det(r))
        rows.append(np.column_stack([r, [k, 0.1 * k * k, 0.0]]).ravel())
    np.savetxt(tmp_path / "gt.txt", rows)
    np.savetxt(tmp_path / "est.txt", np.array(rows) + [0, 0, 0, 0.5, 0, 0, 0, 0, 0, 0, 0, 0])
    res = invoke(evaluate, tmp_path / "gt.txt", tmp_path / "est.txt", "--json")
    doc = json.loads(res.stdout)
    assert doc["method"]["association"]["method"] == "index" and doc["stats"]["n"] == 20
    assert doc["stats"]["max"] == pytest.approx(0.5)
    np.savetxt(tmp_path / "short.txt", rows[:5])
    res = invoke(evaluate, tmp_path / "gt.txt", tmp_path / "short.txt")
    assert res.exit_code == 2 and "paired by index" in res.stderr


def test_evaluate_states_the_poses_left_unpaired_and_warns_when_most_are(tmp_path):
    """ROS_example.bag's ORB-SLAM poses: `pairs 2550`, nothing saying that 5812 of the 8362 estimated poses found
    no truth stamp within --t_max_diff 0.01 s (h-user15). Here 200 of 300 estimate stamps fall between the truth's
    (20 Hz): the line and the warning say so; with a window that pairs them all, neither is printed."""
    t_truth = np.arange(400) * 0.05
    t_est = np.sort(np.r_[t_truth[:300:3], t_truth[1:300:3] + 0.025, t_truth[2:300:3] + 0.025])
    for name, t in (("gt.txt", t_truth), ("est.txt", t_est)):
        xyz = np.c_[np.cos(t), np.sin(t), 0.1 * t]
        np.savetxt(tmp_path / name, np.c_[t, xyz, np.zeros((t.size, 3)), np.ones(t.size)])
    res = invoke(evaluate, tmp_path / "gt.txt", tmp_path / "est.txt")
    assert res.exit_code == 0, res.output
    assert "  unpaired\t200 of 300 estimate poses (66.7%) found no truth stamp within 0.01 s" in res.stdout
    assert "warning: most estimate poses are unpaired" in res.stderr and "cover the 100 paired" in res.stderr
    doc = json.loads(invoke(evaluate, tmp_path / "gt.txt", tmp_path / "est.txt", "--json").stdout)
    assert doc["method"]["association"]["n_unpaired"] == 200 and doc["stats"]["n"] == 100
    res = invoke(evaluate, tmp_path / "gt.txt", tmp_path / "est.txt", "--t_max_diff", "0.03")
    assert res.exit_code == 0 and "unpaired" not in res.output, res.output


# ------------------------------------------------------------------------------------------ evo CLI as the oracle

CASES = [
    ("ape", ["-a"]),
    ("ape", ["-as", "-r", "angle_deg"]),
    ("ape", ["--align_origin", "-r", "full", "--t_max_diff", "0.02"]),
    ("ape", ["-s", "-r", "rot_part", "--n_to_align", "50"]),
    ("rpe", ["--delta", "1", "--delta_unit", "m", "-a", "-r", "trans_part"]),
    ("rpe", ["--delta", "10", "--delta_unit", "d", "-r", "angle_deg"]),
    ("rpe", ["--delta", "20", "--all_pairs", "-r", "point_distance"]),
]


EVO_CLI = """
import sys, json
from evo.cli import entry_points
for k, (metric, args) in enumerate(json.loads(sys.argv[1])):
    print(f"=== case {k}", flush=True)
    sys.argv = [f"evo_{metric}", *args]
    try:
        getattr(entry_points, metric)()
    except SystemExit:
        pass
    sys.stdout.flush()
"""


@pytest.mark.skipif(
    not EVO_PYTHON or not Path(EVO_PYTHON).exists(),
    reason="set SLAMOBS_EVO_PYTHON to a python with evo==1.38.1 to compare with evo's CLI",
)
def test_evaluate_output_equals_evo_cli(finished_run, tmp_path):
    """The printed block (title, alignment line, sorted statistics) is evo's, character for character."""
    truth, est = str(finished_run / "truth_tum.txt"), str(finished_run / "estimate_tum.txt")
    env = {**os.environ, "HOME": str(tmp_path), "MPLBACKEND": "Agg"}  # evo writes its settings under $HOME
    runs = [(metric, ["tum", truth, est, *flags]) for metric, flags in CASES]
    out = subprocess.run(
        [EVO_PYTHON, "-c", EVO_CLI, json.dumps(runs)], env=env, capture_output=True, text=True, timeout=300, check=True
    ).stdout
    blocks = out.split("=== case ")[1:]
    assert len(blocks) == len(CASES)
    for (metric, flags), block in zip(CASES, blocks):
        evo_block = block[block.index(f"{metric.upper()} w.r.t.") :].rstrip("\n").splitlines()
        ours = invoke(evaluate, truth, est, "--metric", metric, *flags)
        assert ours.exit_code == 0, ours.output
        assert ours.stdout.splitlines()[: len(evo_block)] == evo_block, (metric, flags)


def test_report_again_keeps_what_the_run_said_and_prints_each_note_once(tmp_path):
    """The noise levels riekf used (the run's ``noise:`` notes) are in the run's report and stay in it when
    ``slamobs report`` makes it again; the run's console names each note once."""
    from slamobs.cli.main import main

    out = tmp_path / "riekf"
    res = CliRunner().invoke(main, ["run", str(SAMPLE), "--observer", "riekf", "-o", str(out)])
    assert res.exit_code == 0, res.output
    noted = [line for line in res.output.splitlines() if line.startswith("note ")]
    assert len(noted) == len(set(noted)) and any("noise: gyro" in line for line in noted)
    before = load(out / "report.json")["notes"]
    assert [n for n in before if n.startswith("noise: ")], before
    res = invoke(report, out)
    assert res.exit_code == 0, res.output
    assert load(out / "report.json")["notes"] == before
    assert all(n in (out / "report.md").read_text() for n in before if n.startswith("noise: "))


def test_the_report_carries_the_noise_and_what_the_estimator_said_of_its_run():
    """The run's noise levels and the estimator's own notes (batch's evidence-scaled levels, the detections'
    correlation it weighed) reach the report; the run's other notes (samples dropped) and another estimator's
    do not; more than one segment is stated."""
    from slamobs.pipeline.evaluation.report import add_run_context

    notes = [
        "noise: gyro = 0.01 rad/s/sqrt(Hz) (estimated)",
        "batch: the detections' errors are correlated in time (share 0.7)",
        "5 angular-velocity samples outside the linear-velocity span dropped",
        "riekf: recovered",
    ]
    segments = [{"start_ns": 0, "end_ns": 1, "samples": 2}, {"start_ns": 3, "end_ns": 4, "samples": 2}]
    report = {"notes": ["APE note"]}
    add_run_context(report, notes, {"observer": {"name": "batch"}, "segments": segments})
    assert report["notes"][:3] == ["APE note", notes[0], notes[1]]
    assert "2 segments" in report["notes"][3] and report["segments"] == segments


def test_report_keeps_to_the_run_s_plots_false_unless_told(tmp_path):
    """A run made with evaluation.plots: false (a batch of thousands of logs) is reported again without figures, as
    the run was; ``--plots`` draws every one, ``--no-plots`` removes those an earlier report drew (before session
    30 `report` drew every figure whatever the run said, and its help said so)."""
    from dataclasses import replace

    out = tmp_path / "run"
    run_log(SAMPLE, out, RunConfig(evaluation=replace(RunConfig().evaluation, plots=False)))
    assert load(out / "run.json")["output"]["plots"] is False
    res = invoke(report, out, "-q")
    assert res.exit_code == 0, res.output
    assert not list(out.glob("*.png")) and not load(out / "run.json")["figures"]
    res = invoke(report, out, "-q", "--plots")
    assert res.exit_code == 0, res.output
    drawn = sorted(p.name for p in out.glob("*.png"))
    assert "trajectory_top.png" in drawn and "biases.png" in drawn and "map.png" in drawn, drawn
    assert sorted(load(out / "run.json")["figures"]) == drawn
    res = invoke(report, out, "-q", "--no-plots")  # biases.png, the run's figure and the report's, removed once
    assert res.exit_code == 0, res.output
    assert not list(out.glob("*.png")) and not load(out / "run.json")["figures"]
    assert set(json.loads((out / "slamobs-output.json").read_text())["files"]) == {p.name for p in out.iterdir()} - {
        "slamobs-output.json"
    }


def test_report_of_a_run_without_truth_keeps_to_its_plots_false(tmp_path):
    """Without truth the run's own figures follow the run's evaluation.plots too; --plots draws them."""
    from dataclasses import replace

    from slamobs.pipeline.config import with_truth

    out = tmp_path / "run"
    run_log(SAMPLE, out, with_truth(RunConfig(evaluation=replace(RunConfig().evaluation, plots=False)), "none"))
    res = invoke(report, out)
    assert res.exit_code == 0, res.output
    assert (out / "report.md").is_file() and not list(out.glob("*.png"))
    res = invoke(report, out, "-q", "--plots")
    assert res.exit_code == 0, res.output
    assert {"trajectory.png", "map.png"} <= {p.name for p in out.glob("*.png")}
