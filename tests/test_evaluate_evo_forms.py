"""Issue 25, item 6: `slamobs evaluate` as a drop-in for evo_ape / evo_rpe: evo's positional forms (`tum|kitti|euroc
TRUTH EST`, `bag|bag2|mcap LOG TOPIC TOPIC`) and its common flags give the numbers of the two-argument form, and,
where the evo venv is there (SLAMOBS_EVO_PYTHON, see tests/test_evaluation.py), evo's own numbers; `-p` and
`--save_plot` draw.

evo (GPL-3.0) runs only as a subprocess of its own interpreter; without it only the comparison with evo skips.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from cli_checks import SAMPLES, invoke

EVO_PYTHON = os.environ.get("SLAMOBS_EVO_PYTHON")
PNG = b"\x89PNG\r\n\x1a\n"
STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def _poses(n: int = 200, seed: int = 3):
    """A 20 s helix as truth and an estimate rotated, moved, scaled by 1.1 and noisy, 10 Hz, stamps 0.002 s
    apart."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    xyz = np.column_stack([5 * np.cos(0.3 * t), 5 * np.sin(0.3 * t), 0.05 * t])
    yaw = 0.3 * t + np.pi / 2
    quat = np.column_stack([np.zeros(n), np.zeros(n), np.sin(yaw / 2), np.cos(yaw / 2)])  # x y z w
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    est = 1.1 * xyz @ rot.T + [1.0, -2.0, 0.5] + rng.normal(0, 0.05, (n, 3))
    est_yaw = yaw + 0.4 + rng.normal(0, 0.01, n)
    est_quat = np.column_stack([np.zeros(n), np.zeros(n), np.sin(est_yaw / 2), np.cos(est_yaw / 2)])
    return t, xyz, quat, t + 0.002, est, est_quat


def _matrices(xyz, quat):
    x, y, z, w = quat.T
    rows = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w), xyz[:, 0]],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w), xyz[:, 1]],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y), xyz[:, 2]],
        ]
    )  # (3, 4, n)
    return rows.transpose(2, 0, 1).reshape(len(xyz), 12)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("traj")
    t, xyz, quat, t_est, est, est_quat = _poses()
    np.savetxt(d / "truth.txt", np.column_stack([t, xyz, quat]), fmt="%.9f")
    np.savetxt(d / "est.txt", np.column_stack([t_est, est, est_quat]), fmt="%.9f")
    np.savetxt(d / "truth.kitti", _matrices(xyz, quat), fmt="%.9f")
    np.savetxt(d / "est.kitti", _matrices(est, est_quat), fmt="%.9f")
    w_first = np.column_stack([quat[:, 3], quat[:, :3]])
    euroc = np.column_stack([(t * 1e9).astype(np.int64), xyz, w_first, np.zeros((len(t), 9))])
    header = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"
    np.savetxt(d / "truth.csv", euroc, fmt=["%d"] + ["%.9f"] * 16, delimiter=",", header=header, comments="")
    return d


def _ours(*args) -> dict:
    res = invoke("evaluate", *args, "--json")
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)["stats"]


def _evo(tool: str, *args) -> dict:
    """evo's statistics for the same arguments (its own interpreter, never imported here)."""
    if not EVO_PYTHON:
        pytest.skip("set SLAMOBS_EVO_PYTHON to a python with evo==1.38.1 to compare with evo")
    exe = Path(EVO_PYTHON).with_name(tool)
    done = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    stats = {}
    for line in done.stdout.splitlines():
        key, _, value = line.strip().partition("\t")
        if key in STATS:
            stats[key] = float(value)
    assert set(stats) == set(STATS), done.stdout
    return stats


def _same(ours: dict, evo: dict) -> None:
    for key in STATS:
        assert ours[key] == pytest.approx(evo[key], rel=1e-5, abs=2e-6), key  # evo prints 6 decimals


FORMS = [
    # evo's positional form, the same in slamobs' two-argument form with the formats spelled out
    (("tum", "truth.txt", "est.txt"), ("truth.txt", "est.txt", "--truth-format", "tum", "--est-format", "tum")),
    (("kitti", "truth.kitti", "est.kitti"), ("truth.kitti", "est.kitti", "--truth-format", "kitti")),
    (("euroc", "truth.csv", "est.txt"), ("truth.csv", "est.txt", "--truth-format", "euroc", "--est-format", "tum")),
]


@pytest.mark.parametrize("form, plain", FORMS, ids=[f[0][0] for f in FORMS])
def test_evo_positional_forms(files, monkeypatch, form, plain):
    monkeypatch.chdir(files)
    flags = ("-a",) if form[0] == "kitti" else ("-a", "--t_max_diff", "0.01")  # KITTI: paired by index
    ours = _ours(*form, *flags)
    assert ours == _ours(*plain, *flags)
    assert 0.01 < ours["rmse"] < 1.0  # aligned but not scale-corrected: the 1.1 scale remains
    _same(ours, _evo("evo_ape", *form, *flags))


@pytest.mark.parametrize("form, log", [("bag", "circle.bag"), ("mcap", "figure8.mcap")])
def test_evo_log_forms(form, log):
    log = SAMPLES / log
    ours = _ours(form, log, "/mocap/pose", "/odom", "-a")
    assert ours == _ours(f"{log}:/mocap/pose", f"{log}:/odom", "-a") and ours["rmse"] > 0
    _same(ours, _evo("evo_ape", form, log, "/mocap/pose", "/odom", "-a"))


FLAGS = [
    ("evo_ape", ("-a", "-s")),
    ("evo_ape", ("-a", "-r", "angle_deg")),
    ("evo_ape", ("-as", "--t_max_diff", "0.001", "--t_offset", "-0.002")),
    ("evo_rpe", ("-a", "--delta", "2", "--delta_unit", "m", "-r", "trans_part")),
    ("evo_rpe", ("--delta", "5", "--delta_unit", "f", "-r", "angle_deg")),
]


@pytest.mark.parametrize("tool, flags", FLAGS, ids=[" ".join(f) for _, f in FLAGS])
def test_evo_flags(files, monkeypatch, tool, flags):
    monkeypatch.chdir(files)
    metric = ("--metric", "rpe") if tool == "evo_rpe" else ()
    ours = _ours(*metric, "tum", "truth.txt", "est.txt", *flags)
    assert ours["n"] > 10
    _same(ours, _evo(tool, "tum", "truth.txt", "est.txt", *flags))


def test_flags_change_the_numbers_as_they_should(files, monkeypatch):
    monkeypatch.chdir(files)
    raw = _ours("tum", "truth.txt", "est.txt")
    se3 = _ours("tum", "truth.txt", "est.txt", "-a")
    sim3 = _ours("tum", "truth.txt", "est.txt", "-a", "-s")
    assert raw["rmse"] > se3["rmse"] > sim3["rmse"] and sim3["rmse"] < 0.1  # the noise is 0.05 m per axis
    # the estimate's stamps are 2 ms late: 1 ms apart, nothing pairs; shifted back, everything does
    assert invoke("evaluate", "tum", "truth.txt", "est.txt", "--t_max_diff", "0.001").exit_code == 2
    shifted = _ours("tum", "truth.txt", "est.txt", "--t_max_diff", "0.001", "--t_offset", "-0.002")
    assert shifted["n"] == raw["n"]


def test_save_results_and_plots(files, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    truth, est = files / "truth.txt", files / "est.txt"
    res = invoke("evaluate", "tum", truth, est, "-a", "-p", "--save_results", "res.zip")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "ape_plot.png").read_bytes()[:8] == PNG and (tmp_path / "res.zip").stat().st_size > 0
    res = invoke(
        "evaluate", "--metric", "rpe", "tum", truth, est, "--plot_mode", "xy", "--save_plot", tmp_path / "r.png"
    )
    assert res.exit_code == 0 and (tmp_path / "r.png").read_bytes()[:8] == PNG and "r.png" in res.output
    (tmp_path / "notes.png").write_text("mine")  # a file that is not a plot is never replaced
    res = invoke("evaluate", "tum", truth, est, "--save_plot", tmp_path / "notes.png")
    assert res.exit_code == 2 and (tmp_path / "notes.png").read_text() == "mine"


def test_an_evo_result_archive_given_as_a_log_or_a_trajectory_says_what_it_holds(files, tmp_path, monkeypatch):
    """evo's `res_files/orb_ape.zip` (round 24): `info` said "zip-compressed: decompress it first", which gives no
    log, and `evaluate` "unknown trajectory format"; both now say it is an evo result archive, of which pair, its
    rmse, and what reads it. Another zip still says to decompress it."""
    monkeypatch.chdir(tmp_path)
    res = invoke("evaluate", "tum", files / "truth.txt", files / "est.txt", "-a", "-q", "--save_results", "res.zip")
    assert res.exit_code == 0, res.output
    rmse = json.loads(invoke("evaluate", "tum", files / "truth.txt", files / "est.txt", "-a", "--json").stdout)
    said = f"an evo result archive: APE w.r.t. translation part (m) of {files / 'est.txt'} against "
    for args in (("info", "res.zip"), ("evaluate", files / "truth.txt", "res.zip"), ("run", "res.zip", "-o", "o")):
        res = invoke(*args)
        assert res.exit_code == 2 and said in res.stderr, res.stderr
        assert f"rmse {rmse['stats']['rmse']:.6g}; it holds an evaluation's errors" in res.stderr
        assert "decompress" not in res.stderr and len(res.stderr.splitlines()) == 1
    import zipfile

    with zipfile.ZipFile("other.zip", "w") as archive:
        archive.writestr("notes.txt", "x")
    res = invoke("info", "other.zip")
    assert res.exit_code == 2 and "zip-compressed: decompress it first" in res.stderr


def test_a_kitti_times_file_given_as_a_trajectory_says_what_it_is(files, tmp_path):
    """evo's `KITTI_00_gt_times.txt` beside `KITTI_00_gt.txt` (round 24): `evaluate GT TIMES` said "unknown
    trajectory format"; a file of one number a line is named as KITTI's times.txt, with how KITTI poses pair and
    where a run takes such stamps."""
    times = tmp_path / "times.txt"
    np.savetxt(times, np.arange(200) * 0.1, fmt="%.6e")
    res = invoke("evaluate", files / "truth.kitti", times)
    assert res.exit_code == 2 and "one number a line: KITTI's times.txt, not poses?" in res.stderr, res.stderr
    assert "evaluation.truth_times" in res.stderr and len(res.stderr.splitlines()) == 1


def test_a_kitti_plot_s_x_axis_is_the_pose_index_not_seconds(files, tmp_path, drawn_figures):
    """evo's KITTI 00 files (no stamps, paired by index) with `-p` (round 24): the error was drawn over the pose
    index 0-4540 under the label "t [s]"; a stamped pair keeps its seconds."""
    res = invoke(
        "evaluate", "kitti", files / "truth.kitti", files / "est.kitti", "-a", "--save_plot", tmp_path / "k.png"
    )
    assert res.exit_code == 0, res.output
    res = invoke("evaluate", "tum", files / "truth.txt", files / "est.txt", "-a", "--save_plot", tmp_path / "t.png")
    assert res.exit_code == 0, res.output
    kitti, tum = drawn_figures
    assert kitti.axes[0].get_xlabel() == "index (poses without stamps, paired by index)"
    assert tum.axes[0].get_xlabel() == "t [s]"


def test_a_wrong_positional_form_is_one_usage_line():
    res = invoke("evaluate", "euroc", "a", "b", "c")
    assert res.exit_code == 2 and "LOG TOPIC TOPIC" in res.stderr


def test_an_unaligned_ape_names_the_aligned_one_when_the_frames_differ(files, monkeypatch):
    """rpg_trajectory_evaluation's EuRoC MH_04 estimate against its truth, as a user types it: `evaluate GT EST`
    printed rmse 18.90 m "(not aligned)" and nothing else; the same pairs after SE(3) alignment are 0.168 m. A note
    on stderr names the aligned rmse where it is under half the unaligned one (evo's stdout stays as it was); not
    with -a, not for an estimate in the truth's own frame."""
    monkeypatch.chdir(files)
    t, xyz, quat, *_ = _poses()
    noisy = xyz + np.random.default_rng(3180).normal(0, 0.05, xyz.shape)
    np.savetxt("same_frame.txt", np.column_stack([t, noisy, quat]), fmt="%.9f")
    res = invoke("evaluate", "tum", "truth.txt", "est.txt")
    assert res.exit_code == 0
    note = next(line for line in res.stderr.splitlines() if line.startswith("note: not aligned"))
    se3 = _ours("tum", "truth.txt", "est.txt", "-a")
    assert f"after SE(3) alignment (-a) {se3['rmse']:.6g} m" in note
    assert "note:" not in res.stdout
    assert "note: not aligned" not in invoke("evaluate", "tum", "truth.txt", "est.txt", "-a").stderr
    assert "note: not aligned" not in invoke("evaluate", "tum", "truth.txt", "same_frame.txt").stderr


@pytest.mark.parametrize("flags, said", [((), "estimate (not aligned)"), (("-a",), "estimate (aligned)")])
def test_the_plot_s_legend_says_whether_the_estimate_is_aligned(files, tmp_path, monkeypatch, flags, said):
    """`evaluate GT EST -p` without -a drew the estimate labelled "estimate (aligned)" under the title "(not
    aligned)" (rpg_trajectory_evaluation's MH_04: an 18.9 m offset shown as if aligned)."""
    from matplotlib.figure import Figure

    drawn = []
    savefig = Figure.savefig

    def legends_then_save(fig, *args, **kwargs):
        drawn.append([t.get_text() for a in fig.axes if a.get_legend() for t in a.get_legend().get_texts()])
        return savefig(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", legends_then_save)
    monkeypatch.chdir(tmp_path)
    assert invoke("evaluate", "tum", files / "truth.txt", files / "est.txt", "-p", *flags).exit_code == 0
    assert said in drawn[0] and ({"estimate (aligned)", "estimate (not aligned)"} - {said}).isdisjoint(drawn[0])
