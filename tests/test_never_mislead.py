"""Never mislead: every metric computed is printed (the map error of a run with landmark truth only), the final
listings name only files that exist, and a truth in another body convention is named with the rotation that
explains it (hand–eye on the aligned trajectories) and the config key that applies it."""

from __future__ import annotations

import copy
import json
import re

import numpy as np
import pandas as pd
import pytest

from slamobs.pipeline.lie import quat_to_rot, quats_to_rots, rots_to_quats
from slamobs.pipeline.readers import read_truth
from slamobs.pipeline.readers.trajectory_files import write_tum
from slamobs.pipeline.simulate.logwriter import write_log
from slamobs.pipeline.simulate.sensors import simulate

from cli_checks import invoke, map_truth_only_config

#: The truth's body turned against the estimate's: 70 deg about a skew axis.
AXIS = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
ANGLE = np.radians(70.0)
X_XYZW = np.array([*(np.sin(ANGLE / 2) * AXIS), np.cos(ANGLE / 2)])


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A short circle log, a config without figures, and the log's truth turned by X as a TUM file."""
    root = tmp_path_factory.mktemp("mislead")
    log = write_log(simulate("circle", duration=8.0, seed=11), root / "circle.mcap")
    truth = read_truth(f"{log}:/mocap/pose").stream
    turned = np.matmul(quats_to_rots(np.ascontiguousarray(truth.quat_xyzw)), quat_to_rot(X_XYZW))  # R_truth X
    tum = write_tum(root / "turned_tum.txt", type(truth)(**{**truth.__dict__, "quat_xyzw": rots_to_quats(turned)}))
    config = root / "run.yaml"
    config.write_text("evaluation:\n  plots: false\n")
    return {"log": log, "root": root, "tum": tum, "config": config}


def _angle_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    return float(np.degrees(2.0 * np.arccos(min(1.0, abs(float(np.dot(q1, q2)))))))


def test_hand_eye_note_finds_the_truth_rotation_and_its_key_removes_it(sim, tmp_path):
    res = invoke("run", sim["log"], "-o", tmp_path / "turned", "--truth", sim["tum"], "--config", sim["config"])
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "turned" / "report.json").read_text())
    assert report["ape"]["rotation_deg"]["rmse"] > 60
    note = next(n for n in report["notes"] if "frames.truth_rotation" in n)
    assert note in res.output  # the run prints it
    # an inverted camera extrinsic turns an observer's estimate so too (h-silent12): the key would hide it
    assert "extrinsic" in note and "slamobs info --noise" in note
    found = np.array([float(v) for v in re.search(r"truth_rotation: \[([^\]]+)\]", note).group(1).split(",")])
    assert _angle_deg(found, X_XYZW) < 1.0
    left = float(re.search(r"would be ([0-9.]+) deg", note).group(1))
    assert left < 2.0

    fixed = tmp_path / "fixed.yaml"
    fixed.write_text(
        "evaluation:\n  plots: false\nframes:\n  truth_rotation: [" + ", ".join(f"{v:.6f}" for v in found) + "]\n"
    )
    res = invoke("run", sim["log"], "-o", tmp_path / "fixed", "--truth", sim["tum"], "--config", fixed)
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "fixed" / "report.json").read_text())
    assert report["ape"]["rotation_deg"]["rmse"] < 2.0
    assert not any("frames.truth_rotation" in n for n in report["notes"])
    again = invoke("report", tmp_path / "fixed", "--json")  # a re-report keeps the rotation
    assert json.loads(again.stdout)["ape"]["rotation_deg"]["rmse"] < 2.0


def test_the_report_summary_says_the_turn_is_in_its_rpe_and_drift_lines(sim, tmp_path):
    """`slamobs report` of TagSLAM test_21's run against TagSLAM's rig trajectory (round 25): the summary printed
    "RPE 1 m: translation rmse 0.7698 m" and "drift 57.585 % of distance" beside an APE of 0.0176 m, the truth's
    body frame turned 180 deg, with no word (report.md says it over its relative errors; the terminal's note named
    only the rotation APE). The sentence report.md has stands above the two lines."""
    res = invoke("run", sim["log"], "-o", tmp_path / "turned", "--truth", sim["tum"], "--config", sim["config"])
    assert res.exit_code == 0, res.output
    res = invoke("report", tmp_path / "turned")
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    first = next(k for k, line in enumerate(lines) if line.startswith(("RPE ", "drift ")))
    said = lines[first - 1]
    assert said.startswith("note         the truth's body frame looks turned against the estimate's by "), said
    assert said.endswith(
        "so that turn is in them, translation and rotation: frames.truth_rotation turns the truth for the report; "
        "frames.truth: FRAME, where the truth is of a frame TF places on the body, carries it, lever arm too."
    ), said
    res = invoke(
        "report", tmp_path / "turned", "--truth", f"{sim['log']}:/mocap/pose"
    )  # the log's own truth: not turned, no line
    assert res.exit_code == 0, res.output
    assert not [line for line in res.stdout.splitlines() if "so that turn is in them" in line]


def test_report_takes_the_truth_rotation_from_a_config(sim, tmp_path):
    """h-user9: `report` had no --config, so frames.truth_rotation (which the run's note names) applied only to a
    new `run`; a re-report of the turned run with the key removes the turn, the command line's options win."""
    res = invoke("run", sim["log"], "-o", tmp_path / "turned", "--truth", sim["tum"], "--config", sim["config"])
    assert res.exit_code == 0, res.output
    note = json.loads((tmp_path / "turned" / "report.json").read_text())["notes"]
    found = re.search(r"truth_rotation: \[([^\]]+)\]", next(n for n in note if "frames.truth_rotation" in n))
    fixed = tmp_path / "fixed.yaml"
    fixed.write_text(f"frames:\n  truth_rotation: [{found.group(1)}]\nevaluation:\n  t_max_diff: 0.02\n")
    res = invoke("report", tmp_path / "turned", "--config", fixed, "--json")
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert report["ape"]["rotation_deg"]["rmse"] < 2.0 and report["options"]["t_max_diff_s"] == 0.02
    assert not any("frames.truth_rotation" in n for n in report["notes"])
    res = invoke("report", tmp_path / "turned", "--config", fixed, "--t-max-diff", "0.03", "--json")
    assert json.loads(res.stdout)["options"]["t_max_diff_s"] == 0.03  # the option over the config
    bad = tmp_path / "bad.yaml"
    bad.write_text("frames:\n  truth_rotation: [0, 0, 0, 0]\n")
    res = invoke("report", tmp_path / "turned", "--config", bad)
    assert res.exit_code == 2 and "frames.truth_rotation" in res.output and "Traceback" not in res.output


def test_a_comparison_carries_the_truth_rotation_note_beside_its_rotation_column(sim, tmp_path):
    """TagSLAM test_21 against its rig trajectory: comparison.md's ape_rot_rmse_deg read 160-179 deg beside
    centimetres of translation with no word; each run's report named the turn and its key."""
    res = invoke("compare", sim["log"], "-o", tmp_path / "cmp", "--observers", "fast-adaptation,hashim")
    assert res.exit_code == 0, res.output  # the log's own truth: no note
    assert "frames.truth_rotation" not in (tmp_path / "cmp" / "comparison.md").read_text()
    res = invoke(
        "compare", sim["log"], "-o", tmp_path / "turned", "--observers", "fast-adaptation,hashim", "--truth", sim["tum"]
    )
    assert res.exit_code == 0, res.output
    md = (tmp_path / "turned" / "comparison.md").read_text()
    for name in ("fast-adaptation", "hashim"):
        report = json.loads((tmp_path / "turned" / name / "report.json").read_text())
        note = next(n for n in report["notes"] if "frames.truth_rotation" in n)
        assert f"- {name}: {note}\n" in md and f"note: {name}: {note}" in res.stdout


def test_a_comparison_without_landmark_truth_says_why_its_map_column_is_blank(sim, tmp_path):
    """TagSLAM test_21 against its rig trajectory: landmark_rmse_m blank for every estimator with no word (the
    bias columns had theirs), though the folder's tagslam.yaml would give it."""
    from slamobs.pipeline.compare import NO_MAP_TRUTH

    config = tmp_path / "run.yaml"
    config.write_text("topics:\n  sim_truth: ''\nevaluation:\n  plots: false\n")  # the log's poses, no map
    res = invoke("compare", sim["log"], "-o", tmp_path / "cmp", "--observers", "fast-adaptation", "--config", config)
    assert res.exit_code == 0, res.output
    assert pd.read_parquet(tmp_path / "cmp" / "comparison.parquet")["landmark_rmse_m"].isna().all()
    assert f"- {NO_MAP_TRUTH}\n" in (tmp_path / "cmp" / "comparison.md").read_text()
    assert f"note: {NO_MAP_TRUTH}" in res.stdout
    res = invoke("compare", sim["log"], "-o", tmp_path / "all", "--observers", "fast-adaptation")
    assert res.exit_code == 0 and "landmark_rmse_m is blank" not in res.stdout  # the simulator's map: no note


def test_no_truth_rotation_is_named_for_errors_a_constant_turn_does_not_explain():
    """MR.CLAM 7 robot 3, fast-adaptation (lost: 2.07 m APE on a 49 m path): the note named a 19.6 deg turn that
    left 53.0 of the 57.3 deg rotation APE, a key that changes nothing. A turn that explains the error is still
    named."""
    from types import SimpleNamespace

    from slamobs.pipeline.evaluation.sections import truth_frame_note, truth_frame_turn
    from slamobs.pipeline.lie import so3_exp

    rng = np.random.default_rng(3)
    n = 400
    pos = np.column_stack([np.linspace(0.0, 50.0, n), np.zeros(n), np.zeros(n)])
    est = np.array([so3_exp(v) for v in rng.normal(0.0, 0.02, (n, 3)).cumsum(axis=0)])  # a wandering attitude
    heading = 1.2 * np.sin(np.linspace(0.0, 6.0 * np.pi, n))  # a heading error swinging +-69 deg about none
    wander = np.array([so3_exp(np.array([0.0, 0.0, a])) for a in heading])

    def note(ref_rot):
        cos = (np.einsum("nij,nij->n", est, ref_rot) - 1.0) / 2.0
        rot = float(np.sqrt(np.mean(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) ** 2)))
        ev = SimpleNamespace(
            rotation=SimpleNamespace(stats={"rmse": rot}, est_rot_aligned=est),
            translation=SimpleNamespace(stats={"rmse": 0.5}),
            paired=SimpleNamespace(ref_pos=pos, ref_rot=ref_rot),
        )
        return rot, truth_frame_note(ev, truth_frame_turn(ev))

    rot, notes = note(np.matmul(est, wander))  # errors that wander: no constant turn explains them
    assert rot > 30.0 and notes == []
    rot, notes = note(np.matmul(est, quat_to_rot(X_XYZW)))  # a constant turn: named, with its key
    assert rot > 60.0 and len(notes) == 1 and "frames.truth_rotation" in notes[0]


def test_the_hints_of_a_turned_truth_go_by_the_reports_flag_not_by_a_notes_words():
    """The NEES notes' caveat, the body-frame note and the camera's reading of the turn went by the truth-frame
    note's words (``TRUTH_FRAME_TURNED``, ``TRUTH_FRAME_KEY`` found in the notes): a reworded note dropped them all
    without a word. They go by report.json's ``ape.truth_frame_turn`` now, whatever the notes say; the camera's reading
    of it by run.json's time-offset flag ``camera_turned``, not by ``CAMERA_ADVICE`` found in the run's notes."""
    from slamobs.pipeline.evaluation.report import add_run_context
    from slamobs.pipeline.evaluation.sections import nees_against_turned_truth
    from slamobs.pipeline.observers.time_offset import CAMERA_ADVICE

    turn = {"angle_deg": 90.0, "axis": [0.0, 0.0, 1.0], "quat_xyzw": [0.0, 0.0, 0.7071, 0.7071]}
    nees = ["position NEES 2.61e+06 (DoF 3) is above the 95 % bounds [2.92, 3.08] of a mean of independent values"]
    (said,) = nees_against_turned_truth(turn | {"rotation_rmse_after_deg": 0.1, "path_m": 30.0}, nees)
    assert said.startswith(nees[0]) and "this NEES holds the estimate against a truth in another body frame" in said
    assert nees_against_turned_truth(None, nees) == nees
    meta = {"observer": {"name": "riekf"}, "input": {"body_frame": "odom_sensor", "body_frame_from": "of /odom"}}
    for flagged in (True, False):
        report = {"ape": {"truth_frame_turn": dict(turn) if flagged else None}, "notes": ["rotation APE: reworded"]}
        add_run_context(report, [], meta)
        assert any("the run took 'odom_sensor' as the body frame" in n for n in report["notes"]) is flagged
    # the camera named by the run's time-offset record's flag (riekf's own, or the observers' camera check), whatever
    # the notes say: no body-frame note; the camera's advice in the notes without the flag names nothing
    for key in ("time_offset", "camera_check"):
        flagged = {**meta, "observer": {"name": "riekf", key: {"camera_turned": True}}}
        report = {"ape": {"truth_frame_turn": dict(turn)}, "notes": ["rotation APE: reworded"]}
        add_run_context(report, ["warning: the camera: reworded"], flagged)
        assert report["ape"]["truth_frame_turn"]["camera_named"] is True
        assert not any("as the body frame" in n for n in report["notes"])
    report = {"ape": {"truth_frame_turn": dict(turn)}, "notes": ["rotation APE: reworded"]}
    add_run_context(report, [f"warning: {CAMERA_ADVICE}"], meta)
    assert "camera_named" not in report["ape"]["truth_frame_turn"]
    # an observer's run made before its camera check kept a record: its run.json notes are all it left (`slamobs
    # report` of such a run lost the camera's reading of the turn and offered frames.truth_rotation again)
    for advice, named in (
        (f"warning: fast-adaptation: the detections fit ...: {CAMERA_ADVICE} ...", True),
        ("", False),
    ):
        legacy = {**meta, "observer": {"name": "fast-adaptation"}, "notes": [advice]}
        report = {"ape": {"truth_frame_turn": dict(turn)}, "notes": ["rotation APE: reworded"]}
        add_run_context(report, legacy["notes"], legacy)
        assert report["ape"]["truth_frame_turn"].get("camera_named", False) is named
    # a riekf record written before the flag: the same rule from its fields
    old = {**meta, "observer": {"name": "riekf", "time_offset": {"extrinsic_turn": {"gain": 5.5}, "gyro_misreads": {}}}}
    report = {"ape": {"truth_frame_turn": dict(turn)}, "notes": ["rotation APE: reworded"]}
    add_run_context(report, [], old)
    assert report["ape"]["truth_frame_turn"]["camera_named"] is True


def test_the_turned_truth_sentence_names_only_a_key_that_removes_the_turn():
    """Round 26 (h-newuser12): the sentence over the relative errors said "frames.body, or frames.truth_rotation for
    the report, removes it" whatever the run's frames. On TagSLAM test_21 against its reference (an Odometry naming
    the VIO frame 'basalt_pose_frame', holding the rig's poses) ``frames.body: rig`` carries the truth from that child
    frame to the rig, the wrong way: rotation APE 178.7 deg as before; ``frames.truth: rig`` gives 1.96. The sentence
    now goes by run.json's ``input`` (the run's frames): never ``frames.body``; ``frames.truth`` where the run carried
    the truth from its child_frame_id or a base is placed on an odometry's frame; ``frames.truth_rotation`` alone
    where the truth was carried from the stated frame (test_22 riekf with ``frames.truth: rig``: 42 deg left)."""
    from slamobs.pipeline.evaluation.report import add_run_context
    from slamobs.pipeline.evaluation.sections import relative_errors_turned

    turn = {"angle_deg": 179.8, "axis": [0.0, 0.0, -1.0], "quat_xyzw": [0.0, 0.0, -1.0, 0.002]}
    turn |= {"rotation_rmse_after_deg": 1.94, "path_m": 14.3}
    placed = "static, from /tf_static or the cameras: files: turned 179.9 deg, offset 0.011 m"
    odom = "the frame of /vio_node/odom's twist: an Odometry's child_frame_id or a TwistStamped's header frame"
    runs = {  # test_21's run.json inputs: frames.body: rig alone; no frames key; frames.truth: rig on test_22
        "body": {
            "body_frame": "rig",
            "body_frame_from": "frames.body",
            "base_frame": None,
            "truth_body": {"frame": "basalt_pose_frame", "from": "the truth's child_frame_id", "placed": placed},
        },
        "none": {
            "body_frame": "basalt_pose_frame",
            "body_frame_from": odom,
            "base_frame": {"frame": "rig", "placed": placed},
            "truth_body": None,
        },
        "truth": {
            "body_frame": "camera_pose_frame",
            "body_frame_from": odom,
            "base_frame": {"frame": "rig", "placed": placed},
            "truth_body": {"frame": "rig", "from": "frames.truth", "placed": placed},
        },
    }
    said = {}
    for name, run_input in runs.items():
        report = {"ape": {"truth_frame_turn": dict(turn)}, "notes": ["rotation APE: reworded"]}
        add_run_context(report, [], {"observer": {"name": "fast-adaptation"}, "input": run_input})
        (said[name],) = relative_errors_turned(report["ape"]["truth_frame_turn"])
        mend = said[name].split("translation and rotation: ", 1)[1]
        assert "frames.body" not in mend or "frames.body does not" in mend, (name, mend)
    assert "frames.truth: FRAME" in said["body"] and "'basalt_pose_frame'" in said["body"], said["body"]
    assert "frames.truth: rig carries it to the body" in said["none"], said["none"]
    assert said["truth"].endswith(
        "frames.truth_rotation for the report removes it; the truth was carried from "
        "frames.truth 'rig' already, so no frame key does."
    ), said["truth"]
    # the camera named: its own words, unchanged
    report = {"ape": {"truth_frame_turn": dict(turn, camera_named=True)}, "notes": []}
    assert "correct the camera's extrinsic" in relative_errors_turned(report["ape"]["truth_frame_turn"])[0]


def test_a_run_with_map_truth_only_prints_its_map_error(sim, tmp_path):
    config = map_truth_only_config(tmp_path)
    res = invoke("run", sim["log"], "-o", tmp_path / "out", "--config", config)
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "out" / "run.json").read_text())
    rmse = meta["map_error"]["error_m"]["rmse"]
    assert f"map error rmse {rmse:.4f} m" in res.output
    # the note report.md carries states the number and its alignment, not only that a map error exists
    assert any(f"rmse {rmse:.4f} m over" in n and "map-only SE(3)" in n for n in meta["notes"]), meta["notes"]
    assert "no ground truth in the log: no error report" not in res.output
    # and a comparison on that log tables each estimator's map error beside the disagreement
    res = invoke(
        "compare", sim["log"], "-o", tmp_path / "cmp", "--observers", "fast-adaptation,hashim", "--config", config
    )
    assert res.exit_code == 0, res.output
    table = pd.read_parquet(tmp_path / "cmp" / "comparison.parquet").set_index("observer")
    for name in ("fast-adaptation", "hashim"):
        run = json.loads((tmp_path / "cmp" / name / "run.json").read_text())
        assert table.loc[name, "map_error_m"] == pytest.approx(run["map_error"]["error_m"]["rmse"])
    assert "map_error_m" in res.output and "map-only SE(3)" in (tmp_path / "cmp" / "comparison.md").read_text()


def test_final_listings_name_only_files_that_exist(sim, tmp_path):
    res = invoke("run", sim["log"], "-o", tmp_path / "run", "--config", sim["config"])
    listed = res.output.split("wrote", 1)[1].split("(", 1)[1].rsplit(")", 1)[0].split(", ")
    assert "poses.parquet" in listed and "report.json" in listed
    assert all((tmp_path / "run" / name).is_file() for name in listed)
    assert not any(name.endswith(".png") for name in listed)  # plots: false draws none, none is claimed
    res = invoke(
        "compare", sim["log"], "-o", tmp_path / "cmp", "--observers", "fast-adaptation", "--config", sim["config"]
    )
    line = next(x for x in res.output.splitlines() if x.startswith("wrote"))
    for name in ("comparison.parquet", "comparison.md", "overlay.png"):
        assert (name in line) == (tmp_path / "cmp" / name).exists(), (name, line)


def test_a_coarse_observer_run_says_so_and_what_to_try(sim, tmp_path):
    """fast-adaptation on fixed gains over a log far noisier than its defaults (gyro 0.1 rad/s and velocity
    0.08 m/s at 20 Hz, detection error growing with range squared): it converges, but to a level that is a
    sizeable share of the motion itself; the summary says so beside the time and names the estimators that
    weigh the log's own noise and the tune that fits the gains. A well-fitting run (the sample log) says neither."""
    log = tmp_path / "noisy.mcap"
    args = ["--duration", 20, "--gyro-noise", 0.1, "--velocity-noise", 0.08, "--detection-noise", "0.02,0,0.009"]
    rates = ["--imu-rate", 20, "--odom-rate", 20, "--detection-rate", 10]
    assert invoke("simulate", "figure8", "-o", log, *args, *rates).exit_code == 0
    res = invoke("run", log, "-o", tmp_path / "out", "--config", sim["config"])
    assert res.exit_code == 0, res.output
    assert "a coarse estimate" in res.output and "--observer batch" in res.output, res.output
    assert f"slamobs tune {log} --observer fast-adaptation --target batch" in res.output
    conv = json.loads((tmp_path / "out" / "report.json").read_text())["convergence"]
    assert conv["coarse"] and conv["steady_level_share"] > conv["coarse_share"]
    # the hint is the run's (run.json) and the report's: report.md and `slamobs report`'s summary repeat it (session
    # 24: a user who read the report later never saw it)
    hints = [line.split(None, 1)[1] for line in res.output.splitlines() if line.startswith("hint ")]
    assert hints and json.loads((tmp_path / "out" / "run.json").read_text())["hints"] == hints
    assert f"Hint: {hints[0]}." in (tmp_path / "out" / "report.md").read_text()
    again = invoke("report", tmp_path / "out", "--align", "yaw")
    assert again.exit_code == 0 and f"\nhint         {hints[0]}\n" in again.output, again.output
    assert f"Hint: {hints[0]}." in (tmp_path / "out" / "report.md").read_text()
    assert json.loads((tmp_path / "out" / "report.json").read_text())["hints"] == hints
    from cli_checks import SAMPLES

    res = invoke("run", SAMPLES / "figure8.mcap", "-o", tmp_path / "fine", "--config", sim["config"])
    assert res.exit_code == 0 and "a coarse estimate" not in res.output and "\nhint " not in res.output, res.output


def test_the_hint_is_for_observers_on_fixed_gains_only():
    """The reference estimators (riekf, batch: not in the observers' registry) weigh the log's noise: a lost run
    of theirs gets the convergence line, no hint, and no lookup error (a lost batch run exited 2 on the lookup)."""
    from slamobs.pipeline.evaluation.report import loose_hint

    for name in ("batch", "riekf"):
        assert loose_hint(name, {"lost": True}, "log.mcap") is None
    assert loose_hint("hashim", {"coarse": False, "lost": False}, "log.mcap") is None
    assert "--target batch" in loose_hint("hashim", {"lost": True}, "log.mcap")


def test_the_hint_after_tuned_gains_does_not_send_the_user_to_tune_again():
    """`slamobs tune mr6.mcap --target batch` then `run --config gains.yaml` on MR.CLAM 6 robot 1 (APE 6.24 -> 1.14 m,
    still not converged) printed "`slamobs tune mr6.mcap --observer fast-adaptation --target batch -o DIR` fits
    fast-adaptation's gains to it": the command just run. Gains other than the defaults get a hint that says they
    came from the configuration; the defaults (also given explicitly) keep the tune command."""
    from slamobs.pipeline.evaluation.report import loose_hint
    from slamobs.pipeline.estimators import get_estimator

    defaults = {g.name: g.default for g in get_estimator("fast-adaptation").gains}
    tuned = defaults | {"k_p": 3.832}
    hint = loose_hint("fast-adaptation", {"lost": True}, "log.mcap", tuned)
    assert "set in the configuration" in hint and "--target batch -o DIR" not in hint and "--trials" in hint
    for gains in (None, defaults):
        assert "slamobs tune log.mcap --observer fast-adaptation --target batch" in loose_hint(
            "fast-adaptation", {"coarse": True}, "log.mcap", gains
        )


def test_an_inverted_camera_extrinsic_is_named_when_the_report_finds_the_estimate_turned(tmp_path):
    """/tf_static's base_link -> camera given as its inverse: fast-adaptation's run exited 0 at APE 0.73 m with one
    note, the truth's body frame turned (session 22). When the report finds that turn, the run now makes the detection
    pairs' checks (``run.camera_check``; a clean run does not): one warning naming the camera's extrinsic, the
    detection topic and the camera frame; the log as generated says nothing of it. The check is made before the
    report is written: report.md and report.json carry the warning, and their truth-frame note sends the reader to
    it instead of offering frames.truth_rotation (which would hide the camera's error); `slamobs report` again
    writes the same notes."""
    from dataclasses import replace

    from slamobs.pipeline.evaluation.markdown import headline_caveats

    sim = simulate("figure8", seed=5, duration=20.0)
    camera = sim.static_tf[0]
    rot = quats_to_rots(np.asarray(camera.quat_xyzw, dtype=float)[None])[0]
    inverse = replace(
        camera,
        translation=-rot.T @ np.asarray(camera.translation),
        quat_xyzw=rots_to_quats(np.ascontiguousarray(rot.T[None]))[0],
    )
    config = tmp_path / "run.yaml"
    config.write_text("evaluation:\n  plots: false\n")
    for name, s in (("clean", sim), ("inverted", replace(sim, static_tf=[inverse, *sim.static_tf[1:]]))):
        log = write_log(s, tmp_path / f"{name}.mcap")
        shown = invoke("run", log, "-o", tmp_path / name, "--observer", "fast-adaptation", "--config", config)
        assert shown.exit_code == 0, shown.output
        said = [line for line in shown.output.splitlines() if "check the camera's extrinsic" in line]
        notes = json.loads((tmp_path / name / "run.json").read_text())["notes"]
        assert len(said) == (name == "inverted") == len([n for n in notes if "check the camera's extrinsic" in n])
    assert "warning: fast-adaptation: the detections fit the odometry" in said[0], said
    assert "[detections /fiducial_transforms, camera frame camera]" in said[0], said
    out = tmp_path / "inverted"
    for again in (False, True):
        if again:  # the report made again from the run directory
            assert invoke("report", out).exit_code == 0
        page, report = (out / "report.md").read_text(), json.loads((out / "report.json").read_text())
        noted = report["notes"]
        assert any("name the camera's extrinsic" in c for c in headline_caveats(report))  # compare's table too
        assert "frames.truth_rotation" not in page and "the detection pairs name the camera's extrinsic" in page
        camera = [n for n in json.loads((out / "run.json").read_text())["notes"] if "camera's extrinsic" in n]
        assert [n for n in noted if "check the camera's extrinsic" in n] == camera
        assert page.count("check the camera's extrinsic") == 1, page


def test_a_failing_check_before_the_report_costs_a_warning_not_the_report(tmp_path, monkeypatch):
    """The camera check runs inside the report's step (so that report.md can name the camera); an unexpected error in
    it must not take the report with it (the report step's own errors end in "no report"): the report is written
    and one warning says the check failed."""
    from slamobs.pipeline import run as run_module

    def broken(*_args):
        raise RuntimeError("boom")

    monkeypatch.setattr(run_module, "camera_check", broken)
    log = write_log(simulate("figure8", seed=5, duration=10.0), tmp_path / "log.mcap")
    config = tmp_path / "run.yaml"
    config.write_text("evaluation:\n  plots: false\n")
    shown = invoke("run", log, "-o", tmp_path / "out", "--observer", "fast-adaptation", "--config", config)
    assert shown.exit_code == 0, shown.output
    assert (tmp_path / "out" / "report.json").exists() and (tmp_path / "out" / "report.md").exists()
    notes = json.loads((tmp_path / "out" / "run.json").read_text())["notes"]
    assert [n for n in notes if "check before the report failed (RuntimeError: boom)" in n], notes


def _odometry_in_a_turned_sensor_frame(src, dst, turn=np.pi / 2):
    """The simulated MCAP ``src`` with its odometry's child_frame_id a sensor frame turned ``turn`` (90 deg) about z
    from the body (the transform on /tf_static, the twist in that frame): a log whose odometry is the sensor's own."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from slamobs.pipeline.simulate.logwriter import make_typestore
    from slamobs.pipeline.simulate.sensors import TOPIC_ODOM, TOPIC_TF_STATIC

    ts, c, s = make_typestore(False), float(np.cos(turn / 2)), float(np.sin(turn / 2))  # the edge's quaternion
    cos, sin = float(np.cos(turn)), float(np.sin(turn))
    with src.open("rb") as fin, dst.open("wb") as fout:
        writer = Writer(fout)
        writer.start(profile="ros2", library="slamobs-tests")
        schemas, channels = {}, {}
        for schema, channel, msg in make_reader(fin).iter_messages():
            m = ts.deserialize_cdr(msg.data, schema.name)
            if channel.topic == TOPIC_TF_STATIC:
                edge = m.transforms[0]
                q = type(edge.transform.rotation)(x=0.0, y=0.0, z=s, w=c)
                origin = type(edge.transform.translation)(x=0.0, y=0.0, z=0.0)
                m.transforms = [
                    *m.transforms,
                    type(edge)(
                        header=edge.header, child_frame_id="odom_sensor", transform=type(edge.transform)(origin, q)
                    ),
                ]
            elif channel.topic == TOPIC_ODOM:
                m.child_frame_id = "odom_sensor"
                for v in (m.twist.twist.linear, m.twist.twist.angular):  # v_sensor = Rz(turn)ᵀ v_body
                    v.x, v.y = cos * v.x + sin * v.y, -sin * v.x + cos * v.y
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            data = bytes(ts.serialize_cdr(m, schema.name))
            writer.add_message(channels[channel.id], log_time=msg.log_time, data=data, publish_time=msg.publish_time)
        writer.finish()
    return dst


def test_a_truth_turned_by_the_odometrys_sensor_frame_says_which_body_the_run_took(sim, tmp_path):
    """Odometry whose child_frame_id is a sensor frame turned 90 deg about z makes that sensor the body: the report's
    note named a truth turned by 90 deg, but its position NEES of 2.6e6 read as an overconfident covariance, and
    nothing said which frame the run took as the body nor how to set another."""
    log = write_log(simulate("figure8", duration=8.0, seed=5), tmp_path / "clean.mcap")
    log = _odometry_in_a_turned_sensor_frame(log, tmp_path / "odom_sensor.mcap")
    res = invoke("run", log, "-o", tmp_path / "out", "--observer", "riekf", "--config", sim["config"])
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["ape"]["rotation_deg"]["rmse"] > 80
    assert report["uncertainty"]["position"]["mean"] > 100
    nees = [n for n in report["notes"] if n.startswith("position NEES ")]
    assert len(nees) == 1 and nees[0].endswith(
        "judge the covariance once the frames agree (report.md's note over the relative errors names the key)"
    ), report["notes"]
    body = [n for n in report["notes"] if n.startswith("the run took 'odom_sensor' as the body frame")]
    origin = "(the frame of /odom's twist: an Odometry's child_frame_id or a TwistStamped's header frame)"
    assert len(body) == 1 and origin in body[0]
    assert "frames.body: FRAME" in body[0] and res.output.count(body[0]) == 1  # the run's note and the report's
    # where TF places the base against that body, the key that makes the base the body follows in report.md too
    # (TagSLAM test 22's report offered only frames.truth_rotation, which turns the truth for the evaluation)
    placed = [n for n in report["notes"] if n.startswith("TF places the body frame 'odom_sensor' against 'base_link'")]
    assert len(placed) == 1 and placed[0].endswith("frames.body: base_link makes the base the body"), report["notes"]
    assert report["notes"].index(placed[0]) == report["notes"].index(body[0]) + 1
    assert res.output.count(placed[0]) == 1 and placed[0] in (tmp_path / "out" / "report.md").read_text()
    meta = json.loads((tmp_path / "out" / "run.json").read_text())
    assert meta["input"]["base_frame"]["frame"] == "base_link", meta["input"]
    # report.md's relative errors (RPE, drift, segment errors) compare motions in each one's body frame: the turn is
    # in them, and the sentence over them says so (it was said above the figures only)
    turn = report["ape"]["truth_frame_turn"]
    relative = (tmp_path / "out" / "report.md").read_text().split("## Relative error and drift\n\n", 1)[1]
    assert relative.startswith(
        f"Note: the truth's body frame looks turned against the estimate's by {turn['angle_deg']:.1f} deg (the note "
        "on the rotation APE); the relative errors below compare each trajectory's motion in its own body frame"
    ), relative[:300]
    assert relative.split("\n", 1)[0].endswith(
        "if the truth is the base's (the body-frame note), frames.truth: base_link carries it to the body and removes "
        "it; frames.truth_rotation turns it for the report."
    )
    turned_rpe = report["rpe"]["translation_m"]["rmse"]
    # the same log with the body set: the truth is in the body's frame, no note of a turn, nor of the body
    fixed = tmp_path / "body.yaml"
    fixed.write_text("frames:\n  body: base_link\nevaluation:\n  plots: false\n")
    res = invoke("run", log, "-o", tmp_path / "fixed", "--observer", "riekf", "--config", fixed)
    report = json.loads((tmp_path / "fixed" / "report.json").read_text())
    assert res.exit_code == 0 and report["ape"]["rotation_deg"]["rmse"] < 5
    assert not any("as the body frame" in n or "NEES" in n and "turn" in n for n in report["notes"])
    assert report["rpe"]["translation_m"]["rmse"] < turned_rpe / 3  # the turn was in the RPE
    assert "looks turned" not in (tmp_path / "fixed" / "report.md").read_text()


def test_a_comparison_whose_truth_looks_turned_names_the_body_and_the_base_once(sim, tmp_path):
    """`slamobs compare` of a log whose odometry's child frame is a sensor turned 90 deg against base_link (TF giving
    it) printed each estimator's turned-truth caveat with its own frames.truth_rotation (TagSLAM test 22: 124, 137
    and 112 deg for fast-adaptation, riekf and batch), and neither which frame the runs took as the body nor TF's
    base frame with the key that mends every run (frames.body: base_link). They now follow the caveats, once."""
    log = write_log(simulate("figure8", duration=8.0, seed=5), tmp_path / "clean.mcap")
    log = _odometry_in_a_turned_sensor_frame(log, tmp_path / "odom_sensor.mcap")
    res = invoke("compare", log, "-o", tmp_path / "cmp", "--observers", "fast-adaptation", "--config", sim["config"])
    assert res.exit_code == 0, res.output
    md = (tmp_path / "cmp" / "comparison.md").read_text()
    assert "fast-adaptation: rotation APE" in md and "frames.truth_rotation" in md, md
    body = "- the run took 'odom_sensor' as the body frame"
    placed = "- TF places the body frame 'odom_sensor' against 'base_link'"
    assert md.count(body) == 1 and md.count(placed) == 1, md
    assert "frames.body: base_link makes the base the body" in md
    assert res.output.count("note: TF places the body frame 'odom_sensor'") == 1, res.output


def test_a_body_taken_from_an_odometrys_sensor_frame_is_named_without_a_turned_truth(sim, tmp_path):
    """Session 25: the run named the body frame it took only when the truth looked turned; an odometry whose
    child_frame_id is a sensor frame (here on the base, not turned: the truth agrees) made that sensor the body
    silently, `info` alone saying so. The run's summary and run.json now name it once, and how to set another; the
    sample log, whose odometry's child frame is base_link, says nothing of it."""
    log = write_log(simulate("figure8", duration=8.0, seed=5), tmp_path / "clean.mcap")
    log = _odometry_in_a_turned_sensor_frame(log, tmp_path / "odom_sensor.mcap", turn=0.0)
    res = invoke("run", log, "-o", tmp_path / "out", "--observer", "fast-adaptation", "--config", sim["config"])
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["ape"]["rotation_deg"]["rmse"] < 5  # no turned truth: the report's own note does not fire
    body = [n for n in json.loads((tmp_path / "out" / "run.json").read_text())["notes"] if "as the body frame" in n]
    assert len(body) == 1 and body[0].startswith("the run took 'odom_sensor' as the body frame (the frame of /odom")
    assert "frames.body: FRAME" in body[0] and res.output.count(body[0]) == 1, res.output
    from cli_checks import SAMPLES

    res = invoke("run", SAMPLES / "figure8.mcap", "-o", tmp_path / "fine", "--config", sim["config"])
    assert res.exit_code == 0 and "as the body frame" not in res.output, res.output


def test_a_converged_figure_says_beside_it_that_the_runs_own_status_is_off(tmp_path):
    """A figure 8 (seed=3335) whose last 10 detections are 3 m off: riekf's last detections fail its gate, its own
    status is ``gated_at_end``, while its error against the truth settles at once (the last 10 detections are under
    the report's window): the report said "converged 0.00 s after start" and nothing of the status (session 32).
    Now report.json's ``convergence.own_status`` holds it (a field), the converged line and report.md say the
    verdict is the truth's only with the status beside it, and compare's notes carry that line."""
    from dataclasses import replace

    from slamobs.pipeline.compare import caveats
    from slamobs.pipeline.evaluation.report import validate_report
    from slamobs.pipeline.observers.riekf import STATUSES
    from slamobs.pipeline.run import RunSummary
    from slamobs.pipeline.simulate import NoiseModel

    sim = simulate("figure8", seed=3335, duration=40.0, noise=NoiseModel(detection_base=0.002, detection_per_m=0.0))
    xyz = sim.detections.xyz.copy()
    xyz[-10:] += 3.0
    log = write_log(replace(sim, detections=replace(sim.detections, xyz=xyz)), tmp_path / "off.mcap")
    config = tmp_path / "run.yaml"
    config.write_text("evaluation:\n  plots: false\nnoise:\n  detection: 0.002\n  detection_per_m: 0.0\n")
    res = invoke("run", log, "--observer", "riekf", "-o", tmp_path / "out", "--config", config)
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "out" / "run.json").read_text())
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    validate_report(report)
    conv = report["convergence"]
    assert meta["observer"]["filter"]["status"] == "gated_at_end", meta["observer"]["filter"]
    assert conv["t_since_start_s"] is not None, conv  # the truth's verdict stands: converged
    assert conv["own_status"] == {
        "status": "gated_at_end",
        "field": "observer.filter.status",
        "said": STATUSES["gated_at_end"],
    }
    said = "by the truth only (its own status is gated_at_end in run.json observer.filter.status): "
    (line,) = [x for x in res.output.splitlines() if x.startswith("converged ")]
    assert said in line, line
    md = (tmp_path / "out" / "report.md").read_text()
    assert f"Convergence: {said}" in md and "The run's own record: its own status is gated_at_end" in md, md
    notes = caveats({"riekf": RunSummary(tmp_path / "out", meta, {}, report=report)})
    assert [n for n in notes if n.startswith("riekf: convergence: ") and said in n], notes


def test_the_error_figure_draws_the_attitude_error_less_a_turn_of_the_truth_frame(drawn_figures):
    """TagSLAM test_22, riekf: errors.png drew an attitude error of 133-166 deg over the whole run and nothing on
    the figure said that report.md's note finds the truth's body frame turned 147.8 deg against the estimate's
    (9.7 deg rmse without it). The attitude panel now draws that error less the turn beside it, with the turn and
    the rmse in its legend; a report without a turn draws the one line."""
    import io
    from types import SimpleNamespace

    from slamobs.pipeline.evaluation import plots
    from slamobs.pipeline.evaluation.figure_jobs import error_plot_job
    from slamobs.pipeline.evaluation.sections import truth_frame_turn
    from slamobs.pipeline.lie import so3_exp

    rng = np.random.default_rng(5)
    n = 200
    t = np.arange(n) * 0.1
    est = np.array([so3_exp(v) for v in rng.normal(0.0, 0.02, (n, 3)).cumsum(axis=0)])
    ref_rot = np.matmul(est, quat_to_rot(X_XYZW))  # the truth's body frame turned by a constant rotation
    cos = (np.einsum("nij,nij->n", est, ref_rot) - 1.0) / 2.0
    errors = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    ev = SimpleNamespace(
        estimate=SimpleNamespace(t_ns=(t * 1e9).astype(np.int64)),
        error_level=((t * 1e9).astype(np.int64), np.full(n, 0.1)),
        pair_t_est_ns=(t * 1e9).astype(np.int64),
        translation=SimpleNamespace(errors=np.full(n, 0.1), stats={"rmse": 0.1}),
        rotation=SimpleNamespace(
            errors=errors, stats={"rmse": float(np.sqrt(np.mean(errors**2)))}, est_rot_aligned=est
        ),
        alignment=SimpleNamespace(kind="se3"),
        paired=SimpleNamespace(ref_pos=np.column_stack([t, np.zeros(n), np.zeros(n)]), ref_rot=ref_rot),
        gravity_tilt_deg=None,
    )
    turn = truth_frame_turn(ev)
    conv = {"band_m": 0.2, "t_since_start_s": None}
    for given in (turn, None):
        name, _, kwargs = error_plot_job(conv, ev, given)
        getattr(plots, name)(io.BytesIO(), **kwargs)
    (turned, plain) = ([line for line in fig.axes[1].get_lines()] for fig in drawn_figures)
    assert [line.get_label() for line in plain] == ["attitude error angle"]
    less = turned[1]
    assert less.get_label() == (
        f"less the truth frame's constant {turn['angle_deg']:.1f} deg turn (report.md's note): "
        f"{turn['rotation_rmse_after_deg']:.3g} deg rmse"
    )
    assert np.max(errors) > 60.0 and np.max(less.get_ydata()) < 1e-3  # a constant turn leaves nothing


def _riekf_reported_against(sim, tmp_path, wrong, truth) -> list[tuple[dict, dict]]:
    """The circle log's riekf run reported against the truth file ``wrong``, then again against its own ``truth``:
    each report.json and run.json as that report left them."""
    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.evaluation.run_dir import report_run

    right = write_tum(tmp_path / "right_tum.txt", truth)
    out = tmp_path / "riekf"
    run_log(sim["log"], out, observer="riekf", config=sim["config"], force=True)
    out_of = []
    for tum in (wrong, right):
        report_run(out, truth=str(tum), plots=False)
        out_of.append(tuple(json.loads((out / f).read_text()) for f in ("report.json", "run.json")))
    return out_of


def test_a_run_the_truth_finds_lost_says_so_in_a_warning_line(sim, tmp_path):
    """seed=4124 (session 37): riekf 13.6 m off with 2 landmarks over 5 min, its report's verdict "lost" (never
    locked on), and no ``warning:`` line among the run's notes: a user scanning them saw none. Now a verdict of lost
    is a warning of the run (run.json and report.json notes) with what to do; a report made again against a truth
    that finds it converged drops it. The lost verdict here: the log's truth with its positions scrambled in time
    (each 0.5 s stretch in another place), so no estimate can follow it."""
    from slamobs.pipeline.evaluation.report import LOST_BY_TRUTH

    truth = read_truth(f"{sim['log']}:/mocap/pose").stream
    n, block = len(truth), 50
    order = np.random.default_rng(4170).permutation(n // block)
    scrambled = np.concatenate(
        [np.arange(k * block, (k + 1) * block) for k in order] + [np.arange(n // block * block, n)]
    )
    far = write_tum(tmp_path / "far_tum.txt", type(truth)(**{**truth.__dict__, "position": truth.position[scrambled]}))
    said = f"warning: riekf: {LOST_BY_TRUTH}"
    (report, meta), (again, meta_again) = _riekf_reported_against(sim, tmp_path, far, truth)
    assert report["convergence"]["lost"]
    found = [n for n in meta["notes"] if n.startswith(said)]
    assert len(found) == 1 and "batch" in found[0], meta["notes"]
    assert found[0] in report["notes"]
    report, meta = again, meta_again  # reported again against the right truth: converged, the warning goes
    assert not report["convergence"]["lost"]
    assert not any(n.startswith(said) for n in meta["notes"] + report["notes"])


#: A motion-capture marker on the body: 120 deg about (1, -1, 1) (the turn of TagSLAM test 22's rig against the T265's
#: frame) and a lever arm, as static TF places it (``x_body = R x_marker + t``).
MARKER_XYZW = np.array([0.5, -0.5, 0.5, 0.5])
MARKER_AT = np.array([0.25, -0.15, 0.1])


def _truth_of_a_marker(src, dst):
    """The simulated MCAP ``src`` whose truth is a marker's, not the body's: /tf_static gains base_link -> marker
    (``MARKER_XYZW``, ``MARKER_AT``), /mocap/pose holds the marker's poses (``R_m = R_b R``, ``p_m = p_b + R_b t``)
    and /marker/odom the same poses as an Odometry whose child_frame_id names the marker."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from slamobs.pipeline.simulate.logwriter import make_typestore
    from slamobs.pipeline.simulate.sensors import TOPIC_MOCAP, TOPIC_TF_STATIC

    ts, r_bm = make_typestore(False), quat_to_rot(MARKER_XYZW)
    with src.open("rb") as fin, dst.open("wb") as fout:
        writer = Writer(fout)
        writer.start(profile="ros2", library="slamobs-tests")
        summary = make_reader(fin).get_summary()
        fin.seek(0)
        schemas, channels = {}, {}

        def channel(topic, schema):
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "cdr", schemas[schema.id])
            return channels[topic]

        odom_schema = next(s for s in summary.schemas.values() if s.name == "nav_msgs/msg/Odometry")
        for schema, ch, msg in make_reader(fin).iter_messages():
            m = ts.deserialize_cdr(msg.data, schema.name)
            if ch.topic == TOPIC_TF_STATIC:
                edge = m.transforms[0]
                q, t = MARKER_XYZW, MARKER_AT
                m.transforms = [
                    *m.transforms,
                    type(edge)(
                        header=type(edge.header)(stamp=edge.header.stamp, frame_id="base_link"),
                        child_frame_id="marker",
                        transform=type(edge.transform)(
                            type(edge.transform.translation)(x=t[0], y=t[1], z=t[2]),
                            type(edge.transform.rotation)(x=q[0], y=q[1], z=q[2], w=q[3]),
                        ),
                    ),
                ]
            elif ch.topic == TOPIC_MOCAP:
                p, o = m.pose.position, m.pose.orientation
                wrong = _as_odometry(ts, m, "marker")  # the body's poses under the marker's name (TagSLAM's mislabel)
                data = bytes(ts.serialize_cdr(wrong, "nav_msgs/msg/Odometry"))
                writer.add_message(
                    channel("/wrong/odom", odom_schema), log_time=msg.log_time, data=data, publish_time=msg.publish_time
                )
                r_b = quat_to_rot(np.array([o.x, o.y, o.z, o.w]))
                pm = np.array([p.x, p.y, p.z]) + r_b @ MARKER_AT
                qm = rots_to_quats((r_b @ r_bm)[None])[0]
                p.x, p.y, p.z = (float(v) for v in pm)
                o.x, o.y, o.z, o.w = (float(v) for v in qm)
                odom = _as_odometry(ts, m, "marker")
                data = bytes(ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
                writer.add_message(
                    channel("/marker/odom", odom_schema),
                    log_time=msg.log_time,
                    data=data,
                    publish_time=msg.publish_time,
                )
            data = bytes(ts.serialize_cdr(m, schema.name))
            writer.add_message(
                channel(ch.topic, schema), log_time=msg.log_time, data=data, publish_time=msg.publish_time
            )
        writer.finish()
    return dst


def _as_odometry(ts, pose_stamped, child: str):
    """``pose_stamped`` as a nav_msgs/Odometry naming ``child`` (no twist)."""
    t = ts.types
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t["nav_msgs/msg/Odometry"](
        header=pose_stamped.header,
        child_frame_id=child,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=copy.deepcopy(pose_stamped.pose), covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
        ),
    )


def test_a_truth_of_a_frame_static_tf_places_on_the_body_is_carried_to_the_body(tmp_path):
    """A truth of another frame than the body (a marker turned 120 deg and 0.3 m off it, static TF placing it) was
    compared with the body's poses as it was: its rotation APE was the marker's turn, its translation APE the lever
    arm swung by the rotation (TagSLAM test 22: 110-148 deg). Where the truth names its frame (an Odometry's
    child_frame_id) or the config does (``frames.truth``, a PoseStamped naming none), the report carries the truth
    to the body by TF's transform: the same APE as against the body's own truth, and the written truth_tum.txt is
    the carried truth (evo_ape on the files gives the report's number)."""
    clean = write_log(simulate("figure8", duration=8.0, seed=4340), tmp_path / "clean.mcap")
    log = _truth_of_a_marker(clean, tmp_path / "marker.mcap")
    topics = "topics:\n  linear_velocity: /odom\n  truth: "  # the marker's Odometry is no velocity
    runs = {
        "clean": (clean, f"{topics}/mocap/pose\n"),
        "odometry": (log, f"{topics}/marker/odom\n"),
        "stated": (log, f"{topics}/mocap/pose\nframes:\n  truth: marker\n"),
        "mislabelled": (log, f"{topics}/wrong/odom\n"),
        "mislabel_stated": (log, f"{topics}/wrong/odom\nframes:\n  truth: base_link\n"),
    }
    reports = {}
    for name, (path, cfg) in runs.items():
        (tmp_path / f"{name}.yaml").write_text(cfg + "evaluation:\n  plots: false\n")
        args = ("--observer", "fast-adaptation", "--export", "tum", "--config", tmp_path / f"{name}.yaml")
        res = invoke("run", path, "-o", tmp_path / name, *args)
        assert res.exit_code == 0, res.output
        reports[name] = json.loads((tmp_path / name / "report.json").read_text())
    base = reports["clean"]["ape"]
    assert base["rotation_deg"]["rmse"] < 10
    truth = np.loadtxt(tmp_path / "clean" / "truth_tum.txt")
    for name, origin in (("odometry", "the truth's child_frame_id"), ("stated", "frames.truth")):
        ape = reports[name]["ape"]
        for key in ("translation_m", "rotation_deg"):
            assert ape[key]["rmse"] == pytest.approx(base[key]["rmse"], rel=1e-6, abs=1e-9), (name, key, ape)
        assert ape["truth_frame_turn"] is None
        carried = np.loadtxt(tmp_path / name / "truth_tum.txt")
        assert np.abs(carried[:, 1:4] - truth[:, 1:4]).max() < 1e-6  # the file evo reads is the carried truth
        meta = json.loads((tmp_path / name / "run.json").read_text())
        record = meta["input"]["truth_body"]
        assert record["frame"] == "marker" and record["from"] == origin, record
        assert np.allclose(record["translation"], MARKER_AT) and _angle_deg(record["quat_xyzw"], MARKER_XYZW) < 1e-6
        assert reports[name]["options"]["truth_in_body"] == [*record["translation"], *record["quat_xyzw"]]
        note = [n for n in reports[name]["notes"] if n.startswith("the truth is of the frame 'marker'")]
        assert len(note) == 1 and note[0] in (tmp_path / name / "report.md").read_text(), reports[name]["notes"]
    # a child_frame_id that names another frame than its poses' (TagSLAM's) is carried the wrong way: said, with the key
    wrong = reports["mislabelled"]
    assert wrong["ape"]["truth_frame_turn"] is not None and wrong["ape"]["rotation_deg"]["rmse"] > 60
    note = [n for n in wrong["notes"] if n.startswith("the truth is of the frame 'marker'")]
    assert len(note) == 1 and "the child_frame_id may not name the frame its poses are of" in note[0], wrong["notes"]
    assert not any("may not name" in n for r in ("odometry", "stated") for n in reports[r]["notes"])
    # round 26: the sentence over the relative errors names frames.truth there, not frames.body (which carries the
    # truth from the same child frame to the new body), and frames.truth: base_link below removes the turn
    mend = wrong["ape"]["truth_frame_turn"]["mend"]
    assert mend.startswith("frames.truth: FRAME") and "'marker'" in mend and "frames.body does not" in mend, mend
    assert f"translation and rotation: {mend}." in (tmp_path / "mislabelled" / "report.md").read_text()
    stated = reports["mislabel_stated"]  # frames.truth: the body's own name compares it as it is
    assert stated["ape"]["translation_m"]["rmse"] == pytest.approx(base["translation_m"]["rmse"], rel=1e-6, abs=1e-9)
    assert stated["options"].get("truth_in_body") is None
    assert reports["clean"]["options"].get("truth_in_body") is None
    assert json.loads((tmp_path / "clean" / "run.json").read_text())["input"]["truth_body"] is None
    # a stated frame static TF does not place is an error, not a silent comparison
    (tmp_path / "wrong.yaml").write_text("topics:\n  truth: /mocap/pose\nframes:\n  truth: elsewhere\n")
    res = invoke(
        "run", log, "-o", tmp_path / "wrong", "--observer", "fast-adaptation", "--config", tmp_path / "wrong.yaml"
    )
    assert res.exit_code == 2 and "frames.truth: 'elsewhere' is not placed on the body frame" in res.output, res.output


def test_a_run_the_truth_finds_not_converged_says_so_in_a_warning_line(sim, tmp_path):
    """seed=4393 (session 38, a camera that sees 2.5 m only): riekf 1.24 m off, batch 0.26 m, both not converged by
    the truth, neither run with a ``warning:`` line (only a lost verdict was one). Now a verdict of not converged is
    a warning too, with what to do, and a report made again against a truth that finds it converged drops it. The
    verdict here: the log's truth moved by a random 0.2 x its extent in each 0.5 s stretch of its last 20 % (the
    error grows at the end, not lost)."""
    from slamobs.pipeline.evaluation.report import BY_TRUTH

    truth = read_truth(f"{sim['log']}:/mocap/pose").stream
    n, block = len(truth), 50
    p = truth.position.copy()
    extent = float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1))))
    tail = np.arange(n) >= int(0.8 * n)
    jumps = np.random.default_rng(4481).normal(0.0, 0.2 * extent, (n // block + 1, 3))
    p[tail] += jumps[np.arange(n)[tail] // block]
    moved = write_tum(tmp_path / "moved_tum.txt", type(truth)(**{**truth.__dict__, "position": p}))
    said = f"warning: riekf: {BY_TRUTH} its error never settled"
    (report, meta), (again, meta_again) = _riekf_reported_against(sim, tmp_path, moved, truth)
    conv = report["convergence"]
    assert conv["t_since_start_s"] is None and not conv["lost"], conv
    found = [n for n in meta["notes"] if n.startswith(said)]
    assert len(found) == 1 and "batch" in found[0], meta["notes"]
    assert found[0] in report["notes"]
    report, meta = again, meta_again  # reported again against the right truth: converged, the warning goes
    assert report["convergence"]["t_since_start_s"] is not None
    assert not any(n.startswith(f"warning: riekf: {BY_TRUTH}") for n in meta["notes"] + report["notes"])
