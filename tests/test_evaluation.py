"""Error report: metric definitions, report building/writing, and evo 1.38.1 as an oracle.

evo (GPL-3.0) is never imported by the package; here it is only an optional oracle (importorskip).
"""

from __future__ import annotations

import json
import re
from decimal import Decimal
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation import (
    ape_rotation_deg,
    ape_translation,
    apply_alignment,
    associate,
    build_report,
    landmark_errors,
    statistics,
    umeyama,
    write_report,
)
from pipeline.lie import quats_to_rots, rots_to_quats, so3_exp
from pipeline.streams import PoseStream

SHARED = Path(__file__).resolve().parents[2] / "shared"
EVO_DATA = SHARED / "realdata" / "evo"
RPG_DATA = SHARED / "realdata" / "rpg_traj_eval"
T0_NS = 1_700_000_000_000_000_000


# ------------------------------------------------------------------------------------------ helpers


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return so3_exp(rng.uniform(-np.pi, np.pi, 3) * 0.55)


def make_truth(n: int = 1500, dt_ns: int = 10_000_000) -> PoseStream:
    """A 3-D figure-eight with turning attitude (positions far from collinear)."""
    t = np.arange(n, dtype=np.int64) * dt_ns + T0_NS
    s = (t - T0_NS) / 1e9
    pos = np.stack([3.0 * np.sin(0.4 * s), 2.0 * np.sin(0.8 * s), 1.0 + 0.5 * np.cos(0.3 * s)], axis=1)
    rots = np.array([so3_exp(np.array([0.1 * np.sin(0.5 * x), 0.2 * np.cos(0.3 * x), 0.4 * x])) for x in s])
    return PoseStream("/mocap", "world", "body", t, t.copy(), pos, rots_to_quats(rots))


def moved(truth: PoseStream, rot_c: np.ndarray, p_c: np.ndarray, noise_m: float = 0.0, seed: int = 0,
          jitter_ns: int = 0) -> pd.DataFrame:
    """The truth seen in another frame: p = R_c p_true + p_c (+ noise), R = R_c R_true."""
    rng = np.random.default_rng(seed)
    pos = truth.position @ rot_c.T + p_c + noise_m * rng.standard_normal(truth.position.shape)
    rots = np.einsum("ij,njk->nik", rot_c, quats_to_rots(truth.quat_xyzw))
    q = rots_to_quats(rots)
    t = truth.t_ns + (rng.integers(-jitter_ns, jitter_ns + 1, len(truth)) if jitter_ns else 0)
    return pd.DataFrame({"t_ns": t, "x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2],
                         "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2], "qw": q[:, 3]})


def make_landmarks(n: int = 8, seed: int = 1) -> dict[int, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {100 + i: rng.uniform(-5, 5, 3) for i in range(n)}


def landmark_table(truth_lm: dict[int, np.ndarray], rot_c, p_c, noise_m=0.0, seed=2, extra_ids=()) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    ids = list(truth_lm) + list(extra_ids)
    xyz = np.array([rot_c @ truth_lm[i] + p_c if i in truth_lm else rng.uniform(-5, 5, 3) for i in ids])
    xyz = xyz + noise_m * rng.standard_normal(xyz.shape)
    return pd.DataFrame({"id": np.array(ids, dtype=np.int64), "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                         "first_seen_ns": T0_NS, "last_seen_ns": T0_NS + 10**9, "n_obs": 50})


def bias_table(t_ns: np.ndarray, gyro_final, vel_final) -> pd.DataFrame:
    decay = np.exp(-(t_ns - t_ns[0]) / 2e9)[:, None]
    g = np.asarray(gyro_final) * (1 - decay)
    v = np.asarray(vel_final) * (1 - decay)
    return pd.DataFrame({"t_ns": t_ns, "gyro_bias_x": g[:, 0], "gyro_bias_y": g[:, 1], "gyro_bias_z": g[:, 2],
                         "vel_bias_x": v[:, 0], "vel_bias_y": v[:, 1], "vel_bias_z": v[:, 2]})


# ------------------------------------------------------------------------------------------ metrics


def test_umeyama_recovers_rigid_transform():
    rng = np.random.default_rng(0)
    for _ in range(20):
        src = rng.normal(size=(50, 3)) * 4
        rot, t = random_rotation(rng), rng.normal(size=3) * 10
        r_hat, t_hat, s_hat = umeyama(src, src @ rot.T + t)
        assert np.allclose(r_hat, rot, atol=1e-10) and np.allclose(t_hat, t, atol=1e-9) and s_hat == 1.0


def test_umeyama_with_scale_and_noise():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(400, 3)) * 3
    rot, t, s = random_rotation(rng), np.array([1.0, -2.0, 0.5]), 2.5
    dst = s * src @ rot.T + t
    r_hat, t_hat, s_hat = umeyama(src, dst, with_scale=True)
    assert np.allclose(r_hat, rot, atol=1e-10) and np.allclose(t_hat, t, atol=1e-9) and s_hat == pytest.approx(s)
    noisy = dst + 0.01 * rng.normal(size=dst.shape)
    r_n, t_n, s_n = umeyama(src, noisy, with_scale=True)
    assert np.degrees(np.arccos((np.trace(r_n.T @ rot) - 1) / 2)) < 0.05 and abs(s_n - s) < 1e-3


def test_umeyama_reflection_case_returns_a_rotation():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(30, 3))
    mirror = np.diag([1.0, 1.0, -1.0])
    r_hat, _, _ = umeyama(src, src @ mirror.T)
    assert np.linalg.det(r_hat) == pytest.approx(1.0) and np.allclose(r_hat @ r_hat.T, np.eye(3), atol=1e-12)


def test_umeyama_planar_points_are_fine():
    rng = np.random.default_rng(3)
    src = np.column_stack([rng.normal(size=(20, 2)), np.zeros(20)])
    rot = random_rotation(rng)
    r_hat, _, _ = umeyama(src, src @ rot.T)
    assert np.allclose(r_hat, rot, atol=1e-10)


@pytest.mark.parametrize(
    "src, match",
    [
        (np.zeros((2, 3)), "at least 3"),
        (np.outer(np.linspace(0, 1, 10), [1.0, 2.0, 3.0]) + 1.0, "collinear"),
        (np.ones((5, 3)), "collinear"),
    ],
)
def test_umeyama_degenerate_input_raises(src, match):
    with pytest.raises(ValueError, match=match):
        umeyama(src, src + 1.0)


def test_associate_nearest_within_window_with_gaps_and_offset():
    ref = T0_NS + np.arange(0, 1000, 10, dtype=np.int64) * 1_000_000  # 100 Hz, 100 stamps
    ref = np.delete(ref, np.arange(40, 60))  # a 0.2 s gap in the truth
    est = T0_NS + np.array([3, 14, 25, 395, 455, 612, 2000], dtype=np.int64) * 1_000_000
    i_ref, i_est = associate(ref, est, t_max_diff_s=0.01)
    # 25 ms is equidistant from 20 and 30 ms: the earlier stamp wins; 455 ms lies in the gap (nearest truth
    # 390 ms / 600 ms), 2000 ms is after the end.
    assert i_est.tolist() == [0, 1, 2, 3, 5]
    assert ((ref[i_ref] - T0_NS) // 1_000_000).tolist() == [0, 10, 20, 390, 610]
    # +5 ms on the estimate: 395 -> 400 is exactly 10 ms from 390 (the window is inclusive), 612 -> 617 -> 620
    i_ref, i_est = associate(ref, est, t_max_diff_s=0.01, t_offset_s=0.005)
    assert i_est.tolist() == [0, 1, 2, 3, 5]
    assert ((ref[i_ref] - T0_NS) // 1_000_000).tolist() == [10, 20, 30, 390, 620]
    assert associate(ref, est, t_max_diff_s=0.01, t_offset_s=0.0051)[1].tolist() == [0, 1, 2, 5]
    # tighter windows drop the pairs further apart
    assert associate(ref, est, t_max_diff_s=0.004)[1].tolist() == [0, 1, 5]
    assert associate(ref, est, t_max_diff_s=0.002)[1].tolist() == [5]


def test_associate_shorter_series_drives():
    """Like evo, the series with fewer samples keeps all its stamps; unique, sorted pairs."""
    ref = T0_NS + np.array([0, 100, 200], dtype=np.int64) * 1_000_000
    est = T0_NS + np.arange(0, 250, 3, dtype=np.int64) * 1_000_000
    i_ref, i_est = associate(ref, est, t_max_diff_s=0.01)
    assert i_ref.tolist() == [0, 1, 2]
    assert ((est[i_est] - T0_NS) // 1_000_000).tolist() == [0, 99, 201]
    assert len(set(zip(i_ref.tolist(), i_est.tolist()))) == 3
    assert associate(ref, est[:0])[0].size == 0
    with pytest.raises(ValueError, match="integer"):
        associate(ref / 1e9, est)


def test_associate_unsorted_input():
    ref = T0_NS + np.array([30, 0, 20, 10], dtype=np.int64) * 1_000_000
    est = T0_NS + np.array([11, 29], dtype=np.int64) * 1_000_000
    i_ref, i_est = associate(ref, est, t_max_diff_s=0.005)
    assert i_ref.tolist() == [3, 0] and i_est.tolist() == [0, 1]


def test_statistics_hand_checked():
    st = statistics(np.array([1.0, 2.0, 3.0, 4.0]))
    assert st == {
        "rmse": pytest.approx(np.sqrt(7.5)),
        "mean": 2.5,
        "median": 2.5,
        "std": pytest.approx(np.sqrt(1.25)),  # population std, not sqrt(5/3)
        "min": 1.0,
        "max": 4.0,
        "sse": 30.0,
        "n": 4,
    }
    assert all(type(v) is float for k, v in st.items() if k != "n") and type(st["n"]) is int
    with pytest.raises(ValueError):
        statistics(np.array([]))


def test_ape_definitions():
    ref = np.zeros((2, 3))
    assert ape_translation(ref, np.array([[3.0, 4.0, 0.0], [0.0, 0.0, -2.0]])).tolist() == [5.0, 2.0]
    ref_r = np.stack([np.eye(3), so3_exp(np.array([0.0, 0.0, 1.0]))])
    est_r = np.stack([so3_exp(np.array([0.0, np.radians(30.0), 0.0])), so3_exp(np.array([0.0, 0.0, 1.0 - np.pi]))])
    assert ape_rotation_deg(ref_r, est_r) == pytest.approx([30.0, 180.0])


def test_landmark_errors_uses_given_alignment_and_lists_unmatched():
    truth = {1: np.array([1.0, 0, 0]), 2: np.array([0, 2.0, 0]), 3: np.array([0, 0, 3.0])}
    rot = so3_exp(np.array([0.0, 0.0, np.pi / 2]))
    trans = np.array([1.0, 1.0, 1.0])
    # estimates in the observer frame: p_est = rotᵀ (p - t); id 2 off by 0.5 m, id 9 unknown to the truth
    est = {1: truth[1], 2: truth[2] + np.array([0.5, 0, 0]), 9: np.zeros(3)}
    ids = np.array(list(est))
    xyz = np.array([rot.T @ (p - trans) for p in est.values()])
    lm = landmark_errors(ids, xyz, truth, rot, trans)
    assert lm.ids.tolist() == [1, 2]
    assert lm.errors == pytest.approx([0.0, 0.5], abs=1e-12)
    assert lm.estimated_without_truth == [9] and lm.truth_never_estimated == [3]


# ------------------------------------------------------------------------------------------ report

ROT_C = so3_exp(np.array([0.3, -0.2, 1.1]))
P_C = np.array([4.0, -3.0, 0.7])


def synthetic_run(noise_m=0.0, lm_noise_m=0.0, jitter_ns=0):
    truth = make_truth()
    poses = moved(truth, ROT_C, P_C, noise_m=noise_m, jitter_ns=jitter_ns)
    lm_truth = make_landmarks()
    landmarks = landmark_table(lm_truth, ROT_C, P_C, noise_m=lm_noise_m, extra_ids=(7,))
    biases = bias_table(poses["t_ns"].to_numpy(), [0.01, -0.02, 0.005], [0.1, 0.0, -0.05])
    bias_truth = {"gyro": np.array([0.01, -0.02, 0.0]), "velocity": np.array([0.1, 0.0, -0.05])}
    return poses, biases, landmarks, truth, lm_truth, bias_truth


def test_unobservable_rigid_offset_gives_zero_error():
    poses, biases, landmarks, truth, lm_truth, bias_truth = synthetic_run()
    rep = build_report(poses, biases, landmarks, truth, lm_truth, bias_truth)
    assert rep["ape"]["translation_m"]["max"] < 1e-9
    assert rep["ape"]["rotation_deg"]["max"] < 1e-5
    assert rep["ape"]["translation_m"]["n"] == len(truth)
    assert rep["landmarks"]["error_m"]["max"] < 1e-9
    al = rep["method"]["alignment"]
    assert np.allclose(np.array(al["rotation_matrix"]), ROT_C.T, atol=1e-10)
    assert np.allclose(al["translation_m"], -ROT_C.T @ P_C, atol=1e-9)
    # without alignment the offset is all there is
    raw = build_report(poses, biases, landmarks, truth, lm_truth, bias_truth, align="none")
    assert raw["ape"]["translation_m"]["min"] > 1.0 and raw["convergence"]["t_ns"] is None


def test_report_on_noisy_estimate():
    noise = 0.01
    poses, biases, landmarks, truth, lm_truth, bias_truth = synthetic_run(noise, 0.02, jitter_ns=2_000_000)
    rep = build_report(poses, biases, landmarks, truth, lm_truth, bias_truth)
    json.dumps(rep, allow_nan=False)
    tr = rep["ape"]["translation_m"]
    # 3-D isotropic noise of std σ: rmse ≈ σ√3
    assert tr["rmse"] == pytest.approx(noise * np.sqrt(3), rel=0.1)
    assert rep["ape"]["rotation_deg"]["max"] < 0.05
    lm = rep["landmarks"]
    assert lm["n_matched"] == 8 and lm["error_m"]["max"] < 0.15
    assert lm["estimated_without_truth"] == [7] and lm["truth_never_estimated"] == []
    assert [row["id"] for row in lm["per_landmark"]] == sorted(lm_truth)
    bi = rep["biases"]
    assert bi["final"]["t_ns"] == int(poses["t_ns"].max())
    assert bi["error_norm"]["gyro"] == pytest.approx(np.linalg.norm([0, 0, -0.005]) , abs=1e-3)
    assert bi["error_norm"]["velocity"] < 1e-3
    assert rep["convergence"]["t_since_start_s"] == 0.0
    m = rep["method"]["association"]
    assert m["n_pairs"] == len(truth) and m["t_max_diff_s"] == 0.01


def test_convergence_time():
    truth = make_truth()
    poses = moved(truth, np.eye(3), np.zeros(3))
    t_s = (poses["t_ns"].to_numpy() - T0_NS) / 1e9
    bump = np.where(t_s < 4.0, 1.0 - t_s / 4.0, 0.0)  # error 1 m decaying linearly to 0 at 4 s
    poses["z"] = poses["z"] + bump * (t_s < 4.0)
    empty = pd.DataFrame({"id": np.array([], dtype=np.int64), "x": [], "y": [], "z": []})
    rep = build_report(poses, None, empty, truth, align="none")
    assert rep["convergence"]["t_since_start_s"] == pytest.approx(3.6, abs=0.011)
    assert rep["landmarks"]["n_estimated"] == 0 and rep["biases"]["final"] is None


def test_no_time_overlap_raises_with_both_spans():
    poses, biases, landmarks, truth, *_ = synthetic_run()
    poses["t_ns"] = poses["t_ns"] - 3_600 * 10**9  # estimate stamped on another clock
    with pytest.raises(ValueError, match=r"(?s)estimate spans \[.*truth spans \["):
        build_report(poses, biases, landmarks, truth)


def test_bad_align_option():
    poses, biases, landmarks, truth, *_ = synthetic_run()
    with pytest.raises(ValueError, match="align"):
        build_report(poses, biases, landmarks, truth, align="sim3")


def test_write_report_files(tmp_path):
    poses, biases, landmarks, truth, lm_truth, bias_truth = synthetic_run(0.01, 0.02)
    rep = build_report(poses, biases, landmarks, truth, lm_truth, bias_truth)
    paths = write_report(rep, tmp_path / "out", poses, biases, landmarks, truth, lm_truth)
    names = sorted(p.name for p in paths)
    assert names == ["biases.png", "errors.png", "report.json", "report.md", "trajectory_top.png"]
    for p in paths:
        assert p.is_file() and p.stat().st_size > 0
        if p.suffix == ".png":
            assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    loaded = json.loads((tmp_path / "out" / "report.json").read_text())
    assert loaded == json.loads(json.dumps(rep))
    md = (tmp_path / "out" / "report.md").read_text()
    for needle in ("Absolute pose error", "Landmark map error", "Biases", "Method", "| 100 |"):
        assert needle in md


def test_write_report_without_map_biases_or_truth_extras(tmp_path):
    poses, _, _, truth, *_ = synthetic_run(0.01)
    rep = build_report(poses, None, None, truth)
    assert rep["landmarks"]["truth_available"] is False and rep["biases"]["final"] is None
    paths = write_report(rep, tmp_path, poses, None, None, truth)
    assert len(paths) == 5 and all(p.is_file() for p in paths)
    assert "no landmark ground truth" in (tmp_path / "report.md").read_text()


# ------------------------------------------------------------------------------------------ evo oracle: stored numbers


def load_tum(path: Path) -> PoseStream:
    """TUM trajectory file (``t x y z qx qy qz qw``, '#' comments); stamps parsed exactly to int64 ns."""
    t, vals = [], []
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.replace(",", " ").split()
        t.append(int((Decimal(tok[0]) * 1_000_000_000).to_integral_value()))
        vals.append([float(v) for v in tok[1:8]])
    t_ns, v = np.array(t, dtype=np.int64), np.array(vals)
    return PoseStream(path.name, "", "", t_ns, t_ns.copy(), v[:, :3], v[:, 3:7])


def load_euroc_csv(path: Path) -> PoseStream:
    """EuRoC ``state_groundtruth_estimate0/data.csv``: t [ns], p xyz, q wxyz, ..."""
    m = np.loadtxt(path, delimiter=",", comments="#")
    t_ns = np.array([int(line.split(",")[0]) for line in path.read_text().splitlines() if line[:1].isdigit()])
    return PoseStream(path.name, "", "", t_ns, t_ns.copy(), m[:, 1:4], m[:, [5, 6, 7, 4]])


def kitti_positions(path: Path) -> np.ndarray:
    return np.loadtxt(path)[:, [3, 7, 11]]


def reference_rows() -> dict[str, dict[str, float | None]]:
    """rmse/mean/max of each row of REFERENCE_NUMBERS.md, by pair name (first number when 'a / b')."""
    rows, previous = {}, ""
    for line in (EVO_DATA / "REFERENCE_NUMBERS.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 5 or not re.match(r"^\d", cells[2]):
            continue
        num = [None if c in ("–", "-") else float(c.split("/")[0]) for c in cells[2:]]
        command = previous if cells[1].startswith("same") else cells[1]  # "same" repeats the row above
        rows[cells[0]] = {"command": command, "rmse": num[0], "mean": num[1], "max": num[2]}
        previous = command
    return rows


# (pair name in REFERENCE_NUMBERS.md, loader, reference file, estimate file); all APE, translation part, `-a`
SUPPORTED_ROWS = [
    ("TUM fr1_xyz rgbdslam", "tum", EVO_DATA / "freiburg1_xyz-groundtruth.txt",
     EVO_DATA / "freiburg1_xyz-rgbdslam.txt"),
    ("EuRoC V1_01 OpenVINS", "tum", EVO_DATA / "V101_gt.txt", EVO_DATA / "V101_openvins.txt"),
    ("rpg MH_04 run 0", "tum", RPG_DATA / "MH_04" / "stamped_groundtruth.txt",
     RPG_DATA / "MH_04" / "stamped_traj_estimate0.txt"),
    ("rpg V1_02 run 0", "tum", RPG_DATA / "V1_02" / "stamped_groundtruth.txt",
     RPG_DATA / "V1_02" / "stamped_traj_estimate0.txt"),
    ("EuRoC V1_02", "euroc", EVO_DATA / "V102_groundtruth.csv", EVO_DATA / "V102.txt"),
    ("KITTI_00 ORB", "kitti", EVO_DATA / "KITTI_00_gt.txt", EVO_DATA / "KITTI_00_ORB.txt"),
    ("KITTI_00 S-PTAM", "kitti", EVO_DATA / "KITTI_00_gt.txt", EVO_DATA / "KITTI_00_SPTAM.txt"),
]


@pytest.mark.skipif(not (EVO_DATA / "REFERENCE_NUMBERS.md").is_file(), reason="shared/realdata/evo not present")
@pytest.mark.parametrize("name, kind, ref_path, est_path", SUPPORTED_ROWS, ids=[r[0] for r in SUPPORTED_ROWS])
def test_reference_numbers_from_evo(name, kind, ref_path, est_path):
    row = reference_rows()[name]
    assert "evo_ape" in row["command"] and " -a" in row["command"] and "-as" not in row["command"].split("/")[0]
    if kind == "kitti":  # no stamps: poses are paired by index
        ref_pos, est_pos = kitti_positions(ref_path), kitti_positions(est_path)
        errors = ape_translation(ref_pos, apply_alignment(*umeyama(est_pos, ref_pos), est_pos))
    else:
        ref = load_euroc_csv(ref_path) if kind == "euroc" else load_tum(ref_path)
        est = load_tum(est_path)
        i_ref, i_est = associate(ref.t_ns, est.t_ns)
        ref_pos, est_pos = ref.position[i_ref], est.position[i_est]
        errors = ape_translation(ref_pos, apply_alignment(*umeyama(est_pos, ref_pos), est_pos))
    st = statistics(errors)
    for key in ("rmse", "mean", "max"):
        if row[key] is not None:
            assert st[key] == pytest.approx(row[key], abs=1e-6), key


@pytest.mark.skipif(not (EVO_DATA / "REFERENCE_NUMBERS.md").is_file(), reason="shared/realdata/evo not present")
def test_build_report_reproduces_evo_reference_row():
    """The whole report path (DataFrame in, dict out) gives the evo number for a TUM row."""
    ref, est = load_tum(EVO_DATA / "V101_gt.txt"), load_tum(EVO_DATA / "V101_openvins.txt")
    poses = pd.DataFrame({"t_ns": est.t_ns, **{c: est.position[:, k] for k, c in enumerate("xyz")},
                          **{c: est.quat_xyzw[:, k] for k, c in enumerate(("qx", "qy", "qz", "qw"))}})
    rep = build_report(poses, None, None, ref)
    row = reference_rows()["EuRoC V1_01 OpenVINS"]
    for key in ("rmse", "mean", "max"):
        assert rep["ape"]["translation_m"][key] == pytest.approx(row[key], abs=1e-6)


# ------------------------------------------------------------------------------------------ evo oracle: live API


def _evo_traj(t_ns, pos, quat_xyzw):
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(positions_xyz=np.array(pos, dtype=float),
                            orientations_quat_wxyz=np.asarray(quat_xyzw)[:, [3, 0, 1, 2]],
                            timestamps=np.asarray(t_ns) / 1e9)


@pytest.mark.parametrize("truth_longer", [True, False])
def test_against_evo_api(truth_longer):
    pytest.importorskip("evo")
    import copy

    from evo.core import metrics as evo_metrics
    from evo.core import sync
    from evo.core.geometry import umeyama_alignment

    rng = np.random.default_rng(7)
    truth = make_truth(n=1200)
    rot_c, p_c = random_rotation(rng), rng.normal(size=3) * 5
    poses = moved(truth, rot_c, p_c, noise_m=0.05, seed=3)
    # perturb attitudes too, and make the stamps irregular (jitter, gaps) without exact ties
    q = poses[["qx", "qy", "qz", "qw"]].to_numpy() + 0.02 * rng.normal(size=(len(poses), 4))
    poses[["qx", "qy", "qz", "qw"]] = q / np.linalg.norm(q, axis=1, keepdims=True)
    poses["t_ns"] = poses["t_ns"] + rng.integers(-12_000_000, 12_000_000, len(poses)) + 1
    keep = rng.random(len(poses)) < (0.3 if truth_longer else 1.0)
    poses = poses[keep].sort_values("t_ns").reset_index(drop=True)
    if not truth_longer:
        sub = np.sort(rng.choice(len(truth), 300, replace=False))
        truth = PoseStream("/mocap", "world", "body", truth.t_ns[sub], truth.rec_ns[sub], truth.position[sub],
                           truth.quat_xyzw[sub])

    est_pos = poses[["x", "y", "z"]].to_numpy()
    est_q = poses[["qx", "qy", "qz", "qw"]].to_numpy()
    traj_ref = _evo_traj(truth.t_ns, truth.position, truth.quat_xyzw)
    traj_est = _evo_traj(poses["t_ns"].to_numpy(), est_pos, est_q)
    ref_sync, est_sync = sync.associate_trajectories(traj_ref, traj_est, max_diff=0.01)

    i_ref, i_est = associate(truth.t_ns, poses["t_ns"].to_numpy(), 0.01)
    assert np.allclose(truth.t_ns[i_ref] / 1e9, ref_sync.timestamps, rtol=0, atol=1e-6)
    assert np.allclose(poses["t_ns"].to_numpy()[i_est] / 1e9, est_sync.timestamps, rtol=0, atol=1e-6)

    for with_scale in (False, True):
        r_e, t_e, s_e = umeyama_alignment(est_sync.positions_xyz.T, ref_sync.positions_xyz.T, with_scale)
        r, t, s = umeyama(est_pos[i_est], truth.position[i_ref], with_scale=with_scale)
        assert np.allclose(r, r_e, atol=1e-12) and np.allclose(t, t_e, atol=1e-10) and s == pytest.approx(s_e)

    aligned = copy.deepcopy(est_sync)
    aligned.align(ref_sync)
    rep = build_report(poses, None, pd.DataFrame({"id": np.array([], dtype=np.int64), "x": [], "y": [], "z": []}),
                       truth)
    for relation, key in ((evo_metrics.PoseRelation.translation_part, "translation_m"),
                          (evo_metrics.PoseRelation.rotation_angle_deg, "rotation_deg")):
        ape = evo_metrics.APE(relation)
        ape.process_data((ref_sync, aligned))
        expected = ape.get_all_statistics()
        ours = rep["ape"][key]
        for stat in ("rmse", "mean", "median", "std", "min", "max", "sse"):
            assert ours[stat] == pytest.approx(expected[stat], rel=1e-9, abs=1e-9), (key, stat)
