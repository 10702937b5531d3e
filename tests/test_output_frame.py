"""``output.frame`` (issue 12, item 3): the frame of the written tables, named in run.json and the Parquet
metadata, and the estimate aligned into the truth's frame (``poses_aligned``, ``landmarks_aligned``)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from slamobs.pipeline import output_frame
from slamobs.pipeline.alignment import align
from slamobs.pipeline.api import run_log
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.lie import quat_to_rot, quats_to_rots, rotation_angle, so3_exp
from slamobs.pipeline.observers import ObserverOptions, ObserverResult
from slamobs.pipeline.estimators import ESTIMATORS
from slamobs.pipeline.simulate import expected_streams, get_scenario, simulate, write_log
from slamobs.pipeline.simulate.sensors import EPOCH_NS
from slamobs.pipeline.writers import read_metadata

SECONDS = 15.0


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    """A noisy figure 8 whose world frame is z up with the magnetic field along x (the default references)."""
    return write_log(
        simulate("figure8", duration=SECONDS, seed=11, imu_rate=100.0), tmp_path_factory.mktemp("frame") / "f8.mcap"
    )


def run(log, out, observer, frame=None):
    cfg = {"observer": observer, "evaluation": {"plots": False}}
    if frame is not None:
        cfg["output"] = {"frame": frame}
    run_log(log, out, config=cfg)
    poses = pd.read_parquet(out / "poses.parquet")
    return poses, json.loads((out / "run.json").read_text())


def rotations(poses):
    return quats_to_rots(np.ascontiguousarray(poses[["qx", "qy", "qz", "qw"]].to_numpy(float)))


def true_rotations(poses):
    return get_scenario("figure8").sample((poses["t_ns"].to_numpy() - EPOCH_NS) * 1e-9).R


def tilt_deg(r_est, r_true):
    """Angle between the estimated and the true body-frame 'up' (roll and pitch, not yaw)."""
    up_est, up_true = r_est[:, 2, :], r_true[:, 2, :]  # rows: Rᵀ e_z
    return np.degrees(np.arccos(np.clip(np.einsum("ki,ki->k", up_est, up_true), -1.0, 1.0)))


def test_start_frame_is_the_default_without_directions(log, tmp_path):
    poses, meta = run(log, tmp_path / "a", "hashim")
    assert meta["output"]["frame"]["name"] == "start"
    assert np.allclose(poses[["x", "y", "z"]].to_numpy()[0], 0.0)
    assert np.allclose(rotations(poses)[0], np.eye(3), atol=1e-7)
    assert read_metadata(tmp_path / "a" / "landmarks.parquet")["output"]["frame"]["name"] == "start"


def test_gravity_frame_of_an_imu_observer_is_its_own_estimate(log, tmp_path):
    poses, meta = run(log, tmp_path / "g", "hashim-imu")
    assert meta["output"]["frame"]["name"] == "gravity" and "own estimate" in meta["output"]["frame"]["method"]
    late = poses["t_ns"] > poses["t_ns"].iloc[-1] - 5e9
    r_est, r_true = rotations(poses[late]), true_rotations(poses[late])
    assert np.median(tilt_deg(r_est, r_true)) < 1.0
    # the magnetometer fixes the heading too: the whole attitude, not only the tilt
    ang = np.degrees([rotation_angle(a @ b.T) for a, b in zip(r_est, r_true)])
    assert np.median(ang) < 1.5
    assert np.allclose(poses[["x", "y", "z"]].to_numpy()[0], 0.0)


def test_gravity_frame_from_the_accelerometer(log, tmp_path):
    poses, meta = run(log, tmp_path / "ga", "fast-adaptation", "gravity")
    assert "accelerometer" in meta["output"]["frame"]["method"]
    # one rotation for the whole run: the estimate's own attitude drifts a little without an IMU
    assert np.median(tilt_deg(rotations(poses), true_rotations(poses))) < 1.0


def test_accelerometer_up_undoes_a_tilted_estimate_frame():
    """An estimate whose frame is tilted by 20° comes out level (the simulated scenarios all start level)."""
    sim = simulate("figure8", duration=6.0, seed=2, imu_rate=100.0)
    aligned = align(expected_streams(sim))
    truth = get_scenario("figure8").sample(aligned.seconds(aligned.vel_t_ns) + (aligned.t0_ns - EPOCH_NS) * 1e-9)
    tilt = so3_exp(np.radians(20.0) * np.array([0.6, 0.8, 0.0]))
    first = ObserverResult(
        aligned.vel_t_ns,
        np.einsum("ij,kjl->kil", tilt, truth.R),
        truth.P @ tilt.T,
        *(np.zeros((aligned.vel_t_ns.size, 3)),) * 2,
        np.zeros(0, np.int64),
        np.zeros((0, 3)),
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        np.zeros((0, 3)),
        np.zeros((0, 3)),
    )
    frame = output_frame.resolve("gravity", first, aligned=aligned, log="x", gravity=(0.0, 0.0, -9.81))
    level = frame.apply(first).rotation
    assert np.median(tilt_deg(level, truth.R)) < 0.5 < 19.0 < np.median(tilt_deg(first.rotation, truth.R))
    assert np.allclose(frame.apply(first).position[0], 0.0)


def test_truth_and_explicit_initial_pose(log, tmp_path):
    poses, meta = run(log, tmp_path / "t", "fast-adaptation", "truth")
    assert meta["output"]["frame"]["name"] == "truth"
    truth = get_scenario("figure8").sample(np.array([(poses["t_ns"].iloc[0] - EPOCH_NS) * 1e-9]))
    np.testing.assert_allclose(poses[["x", "y", "z"]].to_numpy()[0], truth.P[0], atol=1e-6)
    np.testing.assert_allclose(rotations(poses)[0], truth.R[0], atol=1e-6)
    q = np.array([0.0, 0.0, np.sin(0.4), np.cos(0.4)])
    poses, meta = run(log, tmp_path / "p", "hashim-imu", {"position": [1.0, 2.0, 3.0], "orientation_xyzw": list(q)})
    assert meta["output"]["frame"]["name"] == "pose"
    np.testing.assert_allclose(poses[["x", "y", "z"]].to_numpy()[0], [1.0, 2.0, 3.0], atol=1e-6)
    np.testing.assert_allclose(rotations(poses)[0], quat_to_rot(q), atol=1e-6)


def test_frames_are_one_rigid_transform_apart(log, tmp_path):
    """Every frame moves poses and map together: the map relative to the trajectory does not change."""
    out = {}
    for frame in ("start", "truth"):
        run(log, tmp_path / frame, "hashim-imu", frame)
        out[frame] = (
            pd.read_parquet(tmp_path / frame / "poses.parquet"),
            pd.read_parquet(tmp_path / frame / "landmarks.parquet"),
        )
    (pa, la), (pb, lb) = out["start"], out["truth"]
    r = rotations(pb)[0] @ rotations(pa)[0].T
    t = pb[["x", "y", "z"]].to_numpy()[0] - r @ pa[["x", "y", "z"]].to_numpy()[0]
    np.testing.assert_allclose(pa[["x", "y", "z"]].to_numpy() @ r.T + t, pb[["x", "y", "z"]].to_numpy(), atol=1e-5)
    np.testing.assert_allclose(la[["x", "y", "z"]].to_numpy() @ r.T + t, lb[["x", "y", "z"]].to_numpy(), atol=1e-5)


def test_aligned_tables_use_the_reports_transform(log, tmp_path):
    run(log, tmp_path / "r", "hashim", "start")
    out = tmp_path / "r"
    report = json.loads((out / "report.json").read_text())
    al = report["method"]["alignment"]
    rot, trans = np.array(al["rotation_matrix"]), np.array(al["translation_m"])
    poses, aligned = pd.read_parquet(out / "poses.parquet"), pd.read_parquet(out / "poses_aligned.parquet")
    np.testing.assert_allclose(
        poses[["x", "y", "z"]].to_numpy() @ rot.T + trans, aligned[["x", "y", "z"]].to_numpy(), atol=1e-6
    )
    np.testing.assert_allclose(np.einsum("ij,kjl->kil", rot, rotations(poses)), rotations(aligned), atol=1e-6)
    lm, lm_al = pd.read_parquet(out / "landmarks.parquet"), pd.read_parquet(out / "landmarks_aligned.parquet")
    assert lm["id"].tolist() == lm_al["id"].tolist()
    err = np.linalg.norm(
        lm_al[["x", "y", "z"]].to_numpy()
        - np.array(
            [
                get_scenario("figure8").landmarks[list(get_scenario("figure8").landmark_ids).index(i)]
                for i in lm_al["id"]
            ]
        ),
        axis=1,
    )
    assert np.sqrt(np.mean(err**2)) == pytest.approx(report["landmarks"]["error_m"]["rmse"], rel=1e-5)
    meta = read_metadata(out / "poses_aligned.parquet")
    assert meta["aligned"]["alignment"]["type"] == "se3" and meta["output"]["frame"]["name"] == "start"


def test_bad_initial_pose_is_a_config_error(log, tmp_path):
    with pytest.raises(InputError, match="zero quaternion"):
        run(log, tmp_path / "bad", "hashim", {"position": [0, 0, 0], "orientation_xyzw": [0, 0, 0, 0]})
    assert not (tmp_path / "bad").exists()


# batch has no initial state of its own: its frame is its seed's (the seed observer's row), its gauge the seed's
@pytest.mark.parametrize("name", [n for n, s in ESTIMATORS.items() if not s.min_directions and n != "batch"])
def test_observers_without_directions_do_not_depend_on_their_initial_frame(name):
    """Why ``output.frame: truth`` may move their output instead of initialising them at the truth pose: started
    at any pose, their estimate is the identity start's estimate moved rigidly by that pose."""
    sim = simulate("figure8", duration=8.0, seed=5, imu_rate=100.0)
    aligned = align(expected_streams(sim))
    spec = ESTIMATORS[name]
    gains = spec.resolve_gains(None)
    r0, p0 = so3_exp(np.array([0.3, -1.1, 2.0])), np.array([4.0, -2.0, 1.5])
    plain = spec.run(aligned, gains, ObserverOptions())
    moved = spec.start(aligned, gains, ObserverOptions())
    moved.state.r_hat[:], moved.state.p_hat[:] = r0, p0
    res = moved.advance(moved.n_vel)
    np.testing.assert_allclose(res.position, plain.position @ r0.T + p0, atol=1e-6)
    np.testing.assert_allclose(res.rotation, np.einsum("ij,kjl->kil", r0, plain.rotation), atol=1e-8)
    np.testing.assert_allclose(res.landmark_xyz, plain.landmark_xyz @ r0.T + p0, atol=1e-6)
    np.testing.assert_allclose(res.gyro_bias, plain.gyro_bias, atol=1e-8)


def test_the_identity_frame_moves_nothing_and_copies_the_map():
    """``start`` from a first pose at the identity (riekf's, fast-adaptation's) and ``map`` write the rows as the
    estimator made them: no rotation of the hour's 131,072-row stretches on the writer's thread (~0.1 CPU s
    each), the same values; the map is copied (its live arrays move on while the stretch is written). A row
    with one non-finite component keeps its finite ones (the product with the identity made the whole row NaN)."""
    rng = np.random.default_rng(4)
    n = 50
    q = rng.normal(size=(n, 4))
    rot = quats_to_rots(q / np.linalg.norm(q, axis=1)[:, None])
    rot[0] = np.eye(3)
    position = rng.normal(size=(n, 3))
    position[0] = 0.0
    innovation = rng.normal(size=(4, 3))
    innovation[1, 2] = np.nan
    cov = rng.normal(size=(n, 6, 6))
    part = ObserverResult(
        np.arange(n, dtype=np.int64),
        rot,
        position,
        *(np.zeros((n, 3)),) * 2,
        np.arange(2, dtype=np.int64),
        rng.normal(size=(2, 3)),
        np.arange(4, dtype=np.int64),
        np.zeros(4, np.int64),
        rng.normal(size=(4, 3)),
        innovation,
        pose_cov=cov @ cov.transpose(0, 2, 1),
        landmark_cov=np.tile(np.eye(3), (2, 1, 1)),
    )
    for choice in ("start", "map"):
        frame = output_frame.resolve(choice, part, aligned=None, log="x", gravity=(0.0, 0.0, -9.81))
        assert frame.is_identity()
        moved = frame.apply(part)
        for name in ("rotation", "position", "track_xyz", "innovation", "pose_cov"):
            assert getattr(moved, name) is getattr(part, name), name
        assert np.array_equal(moved.innovation[1], [innovation[1, 0], innovation[1, 1], np.nan], equal_nan=True)
        for name in ("landmark_xyz", "landmark_cov"):
            assert np.array_equal(getattr(moved, name), getattr(part, name))
            assert not np.shares_memory(getattr(moved, name), getattr(part, name)), name
    turned = output_frame.OutputFrame("pose", so3_exp(np.array([0.0, 0.0, 0.3])), np.zeros(3), "a turn")
    assert not turned.is_identity()
    assert not np.array_equal(turned.apply(part).position, position)


def _near_exact(got, points, r, t):
    """Within two roundings of the exact ``points @ r.T + t`` (80-bit reference): OpenBLAS picks its kernel by CPU,
    so its last bit is not a portable oracle; on an FMA CPU the loops give its bits (docs/benchmarks.md, h-hour2)."""
    exact = points.astype(np.longdouble) @ r.T.astype(np.longdouble) + t.astype(np.longdouble)
    bound = 2 * np.finfo(float).eps * (np.abs(points) @ np.abs(r).T + np.abs(t))
    return bool(np.all(np.abs(got.astype(np.longdouble) - exact) <= bound))


def test_compiled_frame_moves_give_the_bits_of_einsum_and_matmul_rounding(monkeypatch):
    """A long stretch is moved into the output frame by compiled loops: the bits of ``np.einsum`` (rotations), signed
    zeros too, and the points (with and without a translation) within BLAS's rounding, at every length."""
    from slamobs.pipeline import output_frame

    rng = np.random.default_rng(21)
    monkeypatch.setattr(output_frame, "FRAME_KERNEL_ROWS", 1)
    for n in (1, 3, 7, 8, 17, 1000, 4097):
        m = rng.normal(size=(n, 3, 3))
        m[rng.random(m.shape) < 0.1] = 0.0
        m[rng.random(m.shape) < 0.1] = -0.0
        p = 10.0 * rng.normal(size=(n, 3))
        p[rng.random(p.shape) < 0.2] = -0.0
        for r, t in ((np.eye(3), np.zeros(3)), (rng.normal(size=(3, 3)), rng.normal(size=3))):
            assert output_frame.turned(r, m).tobytes() == np.einsum("ij,kjl->kil", r, m).tobytes(), n
            assert _near_exact(output_frame.moved(p, r, t), p, r, t), n
            assert _near_exact(output_frame.moved(p, r), p, r, np.zeros(3)), n
            assert not np.signbit(output_frame.moved(-np.zeros((1, 3)), r)).any()
    strided = p[::2]  # not C-contiguous: the array code
    assert output_frame.moved(strided, r, t).tobytes() == (strided @ r.T + t).tobytes()
