"""Known maps (``map:``) in the three file formats, ``fixed`` and ``prior`` modes, landmark truth from a file,
and odometry whose twist lacks the angular part or is given in the parent frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from slamobs.pipeline.config import parse_config
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.known_map import read_map
from slamobs.pipeline.readers import read_log
from slamobs.pipeline.readers.odometry import body_rates
from slamobs.pipeline.run import run_log
from slamobs.pipeline.simulate import make_typestore, simulate, write_log
from slamobs.pipeline.simulate.logwriter import write_raw_log
from slamobs.pipeline.simulate.scenarios import get_scenario
from slamobs.pipeline.lie import rots_to_quats

SC = get_scenario("figure8")


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    base = tmp_path_factory.mktemp("maplog")
    return write_log(simulate("figure8", duration=20.0, seed=11), base / "f8.mcap")


def _write_maps(base: Path, ids: np.ndarray, xyz: np.ndarray) -> dict[str, Path]:
    csv = base / "map.csv"
    csv.write_text("id,x,y,z\n# surveyed\n" + "".join(f"{i},{x},{y},{z}\n" for i, (x, y, z) in zip(ids, xyz)))
    pq = base / "landmarks.parquet"
    pd.DataFrame({"id": ids, "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}).to_parquet(pq)
    body = "\n".join(
        f"       - {{id: {i}, size: 0.2, pose: {{position: {{x: {x}, y: {y}, z: {z - 1.0}}}, "
        f"rotation: {{x: 0, y: 0, z: 0}}}}}}"
        for i, (x, y, z) in zip(ids, xyz)
    )
    yml = base / "tagslam.yaml"
    yml.write_text(
        "bodies:\n - lab:\n     is_static: true\n     pose: {position: {x: 0, y: 0, z: 1.0}, rotation: "
        f"{{x: 0, y: 0, z: 0}}}}\n     tags:\n{body}\n       - {{id: 999, size: 0.1}}\n"
    )
    return {"csv": csv, "parquet": pq, "yaml": yml}


def test_map_files_agree_and_bad_ones_are_named(tmp_path):
    files = _write_maps(tmp_path, SC.landmark_ids, SC.landmarks)
    maps = {k: read_map(p) for k, p in files.items()}
    for m in maps.values():  # tagslam: tag poses composed with their body's pose; a tag with only a size is none
        np.testing.assert_array_equal(m.ids, np.sort(SC.landmark_ids))
        np.testing.assert_allclose(m.xyz, SC.landmarks[np.argsort(SC.landmark_ids)], atol=1e-12)
    (tmp_path / "bad.csv").write_text("id,x,y,z\n1,2,3\n")
    with pytest.raises(InputError, match=r"bad.csv: line 2: expected 'id,x,y,z'"):
        read_map(tmp_path / "bad.csv")
    (tmp_path / "dup.csv").write_text("1,0,0,0\n1,1,1,1\n")
    with pytest.raises(InputError, match=r"more than once"):
        read_map(tmp_path / "dup.csv")
    with pytest.raises(InputError, match="map file not found"):
        read_map(tmp_path / "none.csv")
    (tmp_path / "folder").mkdir()  # it said 'map file not found' of a directory that is there
    with pytest.raises(InputError, match="folder: is a directory, not a map file$"):
        read_map(tmp_path / "folder")


def _run(log: Path, out: Path, **cfg) -> tuple[dict, dict | None]:
    run_log(log, out, parse_config({"evaluation": {"plots": False}, **cfg}))
    report = out / "report.json"
    return json.loads((out / "run.json").read_text()), json.loads(report.read_text()) if report.exists() else None


def test_fixed_map_localises_and_prior_map_is_updated(log, tmp_path):
    # the map holds all but three landmarks, and is shifted and turned: it fixes its own frame
    keep = np.arange(SC.landmark_ids.size) >= 3
    yaw = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    map_xyz = SC.landmarks @ yaw.T + [5.0, -2.0, 0.5]
    files = _write_maps(tmp_path, SC.landmark_ids[keep], map_xyz[keep])
    meta, report = _run(log, tmp_path / "fixed", map={"file": str(files["csv"]), "mode": "fixed"})
    lms = pd.read_parquet(tmp_path / "fixed" / "landmarks.parquet").set_index("id")
    assert set(lms.index) <= set(SC.landmark_ids[keep].tolist())  # unmapped tags dropped
    row = {int(i): k for k, i in enumerate(SC.landmark_ids)}
    np.testing.assert_array_equal(lms[["x", "y", "z"]].to_numpy(), map_xyz[[row[i] for i in lms.index]])
    assert any("not in the map dropped" in n for n in meta["notes"])
    assert any("start pose fitted" in n for n in meta["notes"]) and meta["input"]["map"]["mode"] == "fixed"
    assert meta["output"]["frame"]["name"] == "map"  # a known map's frame is the default output frame
    # the estimate lives in the map's frame: the trajectory is where the map says, no alignment needed
    poses = pd.read_parquet(tmp_path / "fixed" / "poses.parquet")
    truth = SC.sample((poses["t_ns"].to_numpy() - poses["t_ns"].iloc[0]) * 1e-9)
    err = np.linalg.norm(poses[["x", "y", "z"]].to_numpy() - (truth.P @ yaw.T + [5.0, -2.0, 0.5]), axis=1)
    assert np.median(err) < 0.1 and report["ape"]["translation_m"]["rmse"] < 0.1

    meta, report = _run(log, tmp_path / "prior", map={"file": str(files["parquet"]), "mode": "prior"})
    lms = pd.read_parquet(tmp_path / "prior" / "landmarks.parquet").set_index("id")
    assert set(SC.landmark_ids[~keep].tolist()) <= set(lms.index)  # new tags are mapped too
    moved = np.linalg.norm(
        lms.loc[SC.landmark_ids[keep & np.isin(SC.landmark_ids, lms.index)], ["x", "y", "z"]].to_numpy()
        - map_xyz[keep & np.isin(SC.landmark_ids, lms.index)],
        axis=1,
    )
    assert moved.max() > 1e-3 and np.median(moved) < 0.2  # updated, near the map it started from
    assert report["landmarks"]["map_aligned"]["error_m"]["rmse"] < 0.2


def test_fixed_map_refuses_observers_that_rotate_the_map(log, tmp_path):
    files = _write_maps(tmp_path, SC.landmark_ids, SC.landmarks)
    with pytest.raises(InputError, match="map mode 'fixed' does not work with observer 'hashim-imu'"):
        run_log(log, tmp_path / "x", parse_config({"observer": "hashim-imu", "map": str(files["csv"])}))
    assert not (tmp_path / "x").exists()


def test_map_truth_without_trajectory_truth(log, tmp_path):
    """Landmark truth from a file: the report's landmark section, or the map-only error in run.json."""
    files = _write_maps(tmp_path, SC.landmark_ids, SC.landmarks)
    meta, report = _run(log, tmp_path / "t", evaluation={"plots": False, "map_truth": str(files["yaml"])})
    assert report["landmarks"]["n_matched"] > 20
    meta, _ = _run(
        log, tmp_path / "n", topics={"truth": ""}, evaluation={"plots": False, "map_truth": str(files["yaml"])}
    )
    assert meta["map_error"]["n_matched"] == report["landmarks"]["n_matched"]
    assert meta["map_error"]["error_m"]["rmse"] == pytest.approx(report["landmarks"]["map_aligned"]["error_m"]["rmse"])

    # the summary report.md says what the run can be judged by and shows the map error with its definition
    meta, _ = _run(
        log, tmp_path / "md", topics={"truth": ""}, evaluation={"plots": True, "map_truth": str(files["yaml"])}
    )
    md = (tmp_path / "md" / "report.md").read_text()
    assert md.startswith("# Run summary (no trajectory truth; map error against the landmark truth)")
    row = next(line for line in md.splitlines() if line.startswith("| map_error_rmse |"))
    assert float(row.split(" | ")[1]) == pytest.approx(meta["map_error"]["error_m"]["rmse"], rel=1e-5)
    assert "SE(3) fit of the map alone" in row


# --------------------------------------------------------------------------- odometry twists


def test_body_rates_from_orientations():
    t = np.arange(0.0, 30.0, 0.05)
    tr = SC.sample(t)
    omega = body_rates((t * 1e9).astype(np.int64), rots_to_quats(np.ascontiguousarray(tr.R)))
    inner = slice(5, -5)
    err = np.linalg.norm(omega[inner] - tr.omega[inner], axis=1)
    assert np.percentile(err, 95) < 0.01 and np.abs(tr.omega).max() > 0.2


@pytest.mark.parametrize("nan", [False, True], ids=["clean", "nan-twists"])
def test_odometry_without_angular_twist_and_with_a_world_frame_twist(tmp_path, nan):
    """A VIO-like odometry: twist.angular zero, twist.linear in the parent frame; the readers derive the angular
    velocity from the orientations and rotate the linear velocity into the child frame, and say so. With some NaN
    twists (TagSLAM test_11 mutated: NaN in every 20th twist.angular) both rules held back and the run used the zero
    twist: a map error of 8.3 m instead of 0.16 m."""
    ts = make_typestore(ros1=True)
    t = np.arange(0.0, 20.0, 0.05)
    tr = SC.sample(t)
    q = rots_to_quats(np.ascontiguousarray(tr.R))
    v_world = np.einsum("nij,nj->ni", tr.R, tr.v)
    w_twist = np.zeros((t.size, 3))
    nan_lin = np.zeros(t.size, bool)
    if nan:
        w_twist[::20, 0] = np.nan
        nan_lin[7::25] = True
        v_world[nan_lin, 1] = np.nan
    T = ts.types
    msgs = []
    for k in range(t.size):
        ns = int(1_700_000_000e9 + t[k] * 1e9)
        vec = lambda a: T["geometry_msgs/msg/Vector3"](x=float(a[0]), y=float(a[1]), z=float(a[2]))  # noqa: E731
        msg = T["nav_msgs/msg/Odometry"](
            header=T["std_msgs/msg/Header"](
                seq=k, stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="world"
            ),
            child_frame_id="body",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](
                        x=float(tr.P[k, 0]), y=float(tr.P[k, 1]), z=float(tr.P[k, 2])
                    ),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=q[k, 0], y=q[k, 1], z=q[k, 2], w=q[k, 3]),
                ),
                covariance=np.zeros(36),
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=vec(v_world[k]), angular=vec(w_twist[k])),
                covariance=np.zeros(36),
            ),
        )
        msgs.append((ns, bytes(ts.serialize_ros1(msg, "nav_msgs/msg/Odometry"))))
    path = write_raw_log(tmp_path / "vio.bag", "bag", {"/vio/odom": msgs}, "nav_msgs/msg/Odometry", ts)
    s = read_log(path)
    assert "orientations of /vio/odom" in s.derived["angular_velocity"]
    assert "parent frame 'world'" in s.derived["linear_velocity"]
    inner = slice(5, -5)
    np.testing.assert_allclose(s.linear_velocity.xyz, tr.v[~nan_lin], atol=1e-9)
    assert (
        s.angular_velocity.xyz.shape[0] == t.size
        and np.percentile(np.linalg.norm(s.angular_velocity.xyz[inner] - tr.omega[inner], axis=1), 95) < 0.01
    )
    # a proper body-frame twist is left alone
    assert "linear_velocity" not in read_log(write_log(simulate("circle", duration=2.0), tmp_path / "c.bag")).derived


TAG = "{{id: {}, size: 0.2, pose: {{position: {{x: 7, y: 7, z: 0}}, rotation: {{x: 0, y: 0, z: 0}}}}}}"


@pytest.mark.parametrize(
    ("name", "text", "problem"),
    [
        (
            "m.csv",
            "id,x,y,z\n99999999999999999999,7,7,0\n2,-7,7,0\n",
            "line 2: landmark id 99999999999999999999 is out of range (64-bit integers)",
        ),
        ("m.csv", "id,x,y,z\n1.5,7,7,0\n", "line 2: landmark id 1.5 is not an integer"),
        (
            "t.yaml",
            "bodies:\n - world:\n     is_static: true\n     tags:\n       - " + TAG.format("one") + "\n",
            "body world: tag id 'one' is not an integer",
        ),
        (
            "t.yaml",
            "bodies:\n - world:\n     is_static: true\n     tags:\n       - " + TAG.format("1e30") + "\n",
            "body world: tag id 1e+30 is out of range (64-bit integers)",
        ),
        (
            "t.yaml",
            "bodies:\n - world:\n     is_static: true\n     tags: 5\n",
            "body world: tags must be a list of {id, size, pose}, got 5",
        ),
        ("t.yaml", "bodies: [world]\n", "bodies: expected {name: body} entries, got 'world'"),
        ("t.yaml", b"bodies: [\xff]\n", "not UTF-8 text (byte 0xff at offset 9): save the map as UTF-8"),
    ],
)
def test_bad_map_ids_and_structure_are_one_line(tmp_path, name, text, problem):
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(InputError) as err:
        read_map(path)
    assert str(err.value) == f"{path}: {problem}"


def test_map_csv_with_a_byte_order_mark(tmp_path):
    path = tmp_path / "m.csv"
    path.write_bytes(b"\xef\xbb\xbfid,x,y,z\r\n1,7,7,0\r\n2,-7,7,0\r\n")
    m = read_map(path)
    assert m.ids.tolist() == [1, 2] and m.xyz.tolist() == [[7, 7, 0], [-7, 7, 0]]
