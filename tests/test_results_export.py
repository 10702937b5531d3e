"""Small run directories (TUM and evo files only on request) and the results MCAP, read back with the mcap
library and with rosbags and checked against the run's Parquet tables."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from slamobs.cli.main import main
from slamobs.pipeline.config import parse_config
from slamobs.pipeline.errors import OutputError
from slamobs.pipeline.run import run_log
from cli_checks import SAMPLES, invoke

SAMPLE = SAMPLES / "figure8.mcap"
TABLES = ("poses", "biases", "landmarks", "landmark_tracks", "innovations")
EXPORT_FILES = {"estimate_tum.txt", "truth_tum.txt", "ape_evo.zip"}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A run with ``output.mcap: true`` in its config and nothing else asked for."""
    out = tmp_path_factory.mktemp("runs") / "figure8"
    run_log(SAMPLE, out, parse_config({"output": {"mcap": True}, "evaluation": {"plots": False}}))
    return out


def _messages(path: Path) -> dict[str, list[tuple[int, object]]]:
    """Every message of an MCAP file, decoded by rosbags from the definitions stored in the file."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([path]) as reader:
        for conn, t_ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype)))
    return out


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_run_directory_holds_no_exports_unless_asked(run_dir):
    names = {p.name for p in run_dir.iterdir()}
    assert not names & EXPORT_FILES
    assert {f"{t}.parquet" for t in TABLES} | {"run.json", "report.json", "report.md", "results.mcap"} <= names
    meta = json.loads((run_dir / "run.json").read_text())
    assert meta["output"]["export"] == ["mcap"] and meta["input"]["truth_frame"] == "world"
    assert not [p for p in run_dir.parent.iterdir() if p.name.startswith(".")]  # no temporary left behind


def test_results_mcap_matches_the_tables(run_dir):
    from mcap.reader import make_reader

    path = run_dir / "results.mcap"
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert reader.get_header().profile == "ros2"
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        pose_schema = next(s for s in summary.schemas.values() if s.name == "geometry_msgs/msg/PoseStamped")
        assert b"MSG: geometry_msgs/Pose" in pose_schema.data  # nested definitions embedded
        log_times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
    assert log_times == sorted(log_times)  # written in time order

    msgs = _messages(path)
    poses = pd.read_parquet(run_dir / "poses.parquet")
    row_of = {int(t): k for k, t in enumerate(poses["t_ns"])}
    stamped = msgs["/slamobs/pose"]
    rows = np.array([row_of[_stamp(m)] for _, m in stamped])
    span_s = (poses["t_ns"].iloc[-1] - poses["t_ns"].iloc[0]) / 1e9
    assert rows[0] == 0 and rows[-1] == len(poses) - 1 and np.all(np.diff(rows) > 0)
    assert len(rows) <= 50 * span_s + 2 < len(poses)  # default cap: 50 per second of the 200 Hz rows
    got = np.array(
        [
            [
                m.pose.position.x,
                m.pose.position.y,
                m.pose.position.z,
                m.pose.orientation.x,
                m.pose.orientation.y,
                m.pose.orientation.z,
                m.pose.orientation.w,
            ]
            for _, m in stamped
        ]
    )
    want = poses[["x", "y", "z", "qx", "qy", "qz", "qw"]].to_numpy()[rows]
    assert np.array_equal(got, want)
    assert all(t == _stamp(m) and m.header.frame_id == "slamobs/map" for t, m in stamped)
    tf = [m.transforms[0] for _, m in msgs["/tf"]]
    assert {(x.header.frame_id, x.child_frame_id) for x in tf} == {("slamobs/map", "slamobs/base_link")}
    assert np.array_equal(
        [
            [x.transform.translation.x, x.transform.translation.y, x.transform.translation.z, x.transform.rotation.w]
            for x in tf
        ],
        want[:, [0, 1, 2, 6]],
    )

    biases = pd.read_parquet(run_dir / "biases.parquet")
    for topic, prefix in (("/slamobs/gyro_bias", "gyro_bias_"), ("/slamobs/velocity_bias", "vel_bias_")):
        vec = np.array([[m.vector.x, m.vector.y, m.vector.z] for _, m in msgs[topic]])
        assert np.array_equal(vec, biases[[prefix + a for a in "xyz"]].to_numpy()[rows])

    innov = pd.read_parquet(run_dir / "innovations.parquet")
    for lid, group in innov.groupby("id"):
        got = msgs[f"/slamobs/innovation/landmark_{lid}"]
        assert [_stamp(m) for _, m in got] == group["t_ns"].tolist()
        assert np.array_equal([[m.vector.x, m.vector.y, m.vector.z] for _, m in got], group[["ex", "ey", "ez"]])

    landmarks = pd.read_parquet(run_dir / "landmarks.parquet")
    maps = [m for _, m in msgs["/slamobs/landmarks"]]
    assert len(maps) > 10  # the map as it grows, then the final one
    final = maps[-1].markers
    assert np.array_equal([[p.x, p.y, p.z] for p in final[0].points], landmarks[["x", "y", "z"]].to_numpy())
    assert [m.text for m in final[1:]] == [str(i) for i in landmarks["id"]]
    first_ids = {int(m.text) for m in maps[0].markers[1:]}
    assert first_ids < set(landmarks["id"])  # landmarks appear as they are first seen

    (path_msg,) = [m for _, m in msgs["/slamobs/path"]]
    path_xyz = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in path_msg.poses])
    path_rows = [row_of[_stamp(p)] for p in path_msg.poses]
    assert np.array_equal(path_xyz, poses[["x", "y", "z"]].to_numpy()[path_rows])

    # the report's alignment puts the map frame into the truth frame
    al = json.loads((run_dir / "report.json").read_text())["method"]["alignment"]
    (static,) = [m.transforms[0] for _, m in msgs["/tf_static"]]
    assert (static.header.frame_id, static.child_frame_id) == ("world", "slamobs/map")
    t = static.transform
    assert [t.translation.x, t.translation.y, t.translation.z] == al["translation_m"]
    assert [t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w] == al["rotation_quat_xyzw"]


def test_export_command_every_row_atomic_and_no_overwrite(run_dir, tmp_path, monkeypatch):
    import slamobs.pipeline.results_mcap as rm

    out = tmp_path / "res.mcap"
    res = invoke("export", run_dir, "--mcap", out, "--rate", "0")
    assert res.exit_code == 0 and "wrote" in res.output
    n_poses = len(pd.read_parquet(run_dir / "poses.parquet", columns=["t_ns"]))
    from mcap.reader import make_reader

    with out.open("rb") as f:
        summary = make_reader(f).get_summary()
    counts = {c.topic: summary.statistics.channel_message_counts[c.id] for c in summary.channels.values()}
    assert counts["/slamobs/pose"] == counts["/tf"] == n_poses
    before = out.read_bytes()
    res = CliRunner().invoke(main, ["export", str(run_dir), "--mcap", str(out)])
    assert res.exit_code == 2 and "--force" in res.stderr and out.read_bytes() == before

    def broken(stream, *args):
        stream.write(b"half")
        raise OSError("disk full")

    monkeypatch.setattr(rm, "_write", broken)
    with pytest.raises(OutputError, match="res.mcap: cannot write the output: disk full"):  # names the file
        rm.write_results_mcap(run_dir, out, force=True)
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["res.mcap"]
    res = CliRunner().invoke(main, ["export", str(tmp_path), "--mcap", str(tmp_path / "x.mcap")])
    assert res.exit_code == 2 and "no run.json" in res.stderr
    monkeypatch.undo()
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    table = (copy / "poses.parquet").read_bytes()  # a file of the run is an input, --force or not
    res = CliRunner().invoke(main, ["export", str(copy), "--mcap", str(copy / "poses.parquet"), "--force"])
    assert res.exit_code == 2 and "is the input" in res.stderr and (copy / "poses.parquet").read_bytes() == table
    for bad, why in (("", "is empty: name the output"), (copy / "run.json" / "x.mcap", "is a file, not a directory")):
        res = CliRunner().invoke(main, ["export", str(copy), "--mcap", str(bad), "--force"])
        assert res.exit_code == 2 and why in res.stderr, res.stderr
    res = CliRunner().invoke(main, ["export", str(copy), "--mcap", str(copy / "results.mcap"), "--force", "-q"])
    assert res.exit_code == 0, res.output  # a results MCAP beside the tables, as `--export mcap` writes it
    notes = tmp_path / "notes.mcap"
    notes.write_bytes(b"mine")
    for force in ([], ["--force"]):  # a file slamobs did not write: refused, never "use --force" (refused too)
        res = CliRunner().invoke(main, ["export", str(copy), "-o", str(notes), *force])
        assert res.exit_code == 2 and "not a results MCAP" in res.stderr and "use --force" not in res.stderr
        assert "choose another -o" in res.stderr and notes.read_bytes() == b"mine"


def test_report_writes_tum_and_evo_on_request(run_dir, tmp_path):
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    assert invoke("report", copy, "--export", "tum,evo", "-q").exit_code == 0
    assert EXPORT_FILES <= {p.name for p in copy.iterdir()}
    assert json.loads((copy / "run.json").read_text())["output"]["export"] == ["mcap", "tum", "evo"]
    est = pd.read_csv(copy / "estimate_tum.txt", sep=" ", header=None)
    assert len(est) == len(pd.read_parquet(copy / "poses.parquet", columns=["t_ns"]))
    assert invoke("report", copy, "--export", "none", "-q").exit_code == 0
    assert not EXPORT_FILES & {p.name for p in copy.iterdir()}
    res = CliRunner().invoke(main, ["report", str(copy), "--export", "tum,pdf"])
    assert res.exit_code == 2 and "pdf" in res.output


def test_export_of_a_damaged_run_is_one_line_naming_the_file(run_dir, tmp_path):
    """A run.json or report.json that is not UTF-8 and a damaged table are named (the line said only "'utf-8'
    codec can't decode byte 0xff" or "Parquet file size is 5 bytes")."""
    for name, data, why in (
        ("run.json", b"\xff\xfe{}", "unreadable run.json"),
        ("report.json", b"\xff\xfe", "unreadable report.json"),
        ("poses.parquet", b"junk\n", "unreadable table"),
    ):
        copy = tmp_path / name
        shutil.copytree(run_dir, copy)
        (copy / name).write_bytes(data)
        res = CliRunner().invoke(main, ["export", str(copy), "--mcap", str(tmp_path / f"{name}.mcap")])
        lines = res.stderr.strip().splitlines()
        assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {copy / name}: {why}"), lines
        assert not (tmp_path / f"{name}.mcap").exists()
