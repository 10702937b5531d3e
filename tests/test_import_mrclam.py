"""``slamobs import mrclam``: a tiny MR.CLAM-format folder written here (the dataset's text layout, consistent made-up
motion), imported, read back message by message and run; plus one real robot when ../shared is present."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from cli_checks import invoke
from realdata import REALDATA
from slamobs.pipeline.readers import read_log
from slamobs.pipeline.simulate.logwriter import make_typestore

HEADER = "# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n# produced by a test\n# {what}\n"
BARCODES = {1: 5, 2: 14, 6: 63, 7: 81, 8: 7, 9: 70, 10: 45}  # subject -> barcode (robots 1-2, landmarks 6-10)
LANDMARKS = {6: (3.0, 0.5), 7: (0.0, 3.0), 8: (-3.0, 0.0), 9: (0.5, -3.0), 10: (2.0, 2.0)}
T0, SECONDS = 1248444175.103, 30.0
UNKNOWN_BARCODE = 99


def _write(path: Path, what: str, rows: list[str]) -> None:
    path.write_text(HEADER.format(what=what) + "".join(f"{r}\n" for r in rows))


def _robot(folder: Path, n: int, rng: np.random.Generator) -> dict:
    """Robot ``n`` drives a circle: Vicon at ~65 Hz, odometry at ~67 Hz, a measurement time every 0.5 s with
    each landmark nearer than 5 m, a sighting of the other robot and one of an unknown barcode."""
    v, w, phase = 0.3, 0.25, 0.7 * n
    t_gt = np.round(np.arange(0.0, SECONDS, 1 / 65), 3)
    th = phase + w * t_gt
    x, y = (v / w) * np.sin(th) - (v / w) * np.sin(phase), -(v / w) * np.cos(th) + (v / w) * np.cos(phase)
    _write(
        folder / f"Robot{n}_Groundtruth.dat",
        "Time [s]    x [m]    y [m]    orientation [rad]",
        [f"{T0 + t:.3f} \t {a:.8f} \t {b:.8f} \t {np.angle(np.exp(1j * c)):.4f}" for t, a, b, c in zip(t_gt, x, y, th)],
    )
    t_od = np.round(np.arange(0.2, SECONDS - 0.2, 1 / 67), 3)
    _write(folder / f"Robot{n}_Odometry.dat", "Time [s] v w", [f"{T0 + t:.3f} \t {v:.3f} \t {w:.3f}" for t in t_od])
    meas, kept, robots = [], 0, 0
    for t in np.arange(0.5, SECONDS - 0.5, 0.5):
        k = int(np.searchsorted(t_gt, t))
        for subject, (lx, ly) in LANDMARKS.items():
            dx, dy = lx - x[k], ly - y[k]
            rng_ = np.hypot(dx, dy)
            if rng_ < 5.0:
                bearing = np.angle(np.exp(1j * (np.arctan2(dy, dx) - th[k])))
                meas.append(f"{T0 + t_gt[k]:.3f} \t {BARCODES[subject]:3d} \t {rng_:.3f} \t {bearing:.3f}")
                kept += 1
        if int(t * 2) % 5 == 0:
            meas.append(f"{T0 + t_gt[k]:.3f} \t {BARCODES[3 - n]:3d} \t {rng.uniform(1, 4):.3f} \t 0.100")
            robots += 1
    meas.append(f"{T0 + SECONDS - 0.4:.3f} \t {UNKNOWN_BARCODE:3d} \t 2.000 \t 0.000")
    _write(folder / f"Robot{n}_Measurement.dat", "Time [s]    Subject #    range [m]    bearing [rad]", meas)
    return {"truth": t_gt.size, "odometry": t_od.size, "kept": kept, "robots": robots, "meas": meas}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> tuple[Path, dict]:
    folder = tmp_path_factory.mktemp("MRCLAM_Tiny")
    _write(folder / "Barcodes.dat", "Subject #    Barcode #", [f"{s:3d} \t {b:3d}" for s, b in BARCODES.items()])
    _write(
        folder / "Landmark_Groundtruth.dat",
        "Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]",
        [f"{s:3d} \t {x:.8f} \t {y:.8f} \t 0.0001 \t 0.0002" for s, (x, y) in LANDMARKS.items()],
    )
    rng = np.random.default_rng(3)
    return folder, {n: _robot(folder, n, rng) for n in (1, 2)}


@pytest.fixture(scope="module")
def imported(dataset, tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("imported") / "robot1.mcap"
    res = invoke("import", "mrclam", dataset[0], "-o", out, "--robot", "1")
    assert res.exit_code == 0, res.output
    return out, res.output


def _messages(path: Path) -> dict[str, list]:
    """Every message of the MCAP, deserialised, by topic."""
    ts = make_typestore(ros1=False)
    out: dict[str, list] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append((message.log_time, ts.deserialize_cdr(message.data, schema.name)))
    return out


def test_every_message_reads_back(dataset, imported):
    stats, (path, line) = dataset[1][1], imported
    msgs = _messages(path)
    assert {t: len(m) for t, m in msgs.items()} == {
        "/slamobs/sim_truth": 1,
        "/robot1/velocity": stats["odometry"],
        "/robot1/groundtruth": stats["truth"],
        "/robot1/landmarks": len({r.split()[0] for r in stats["meas"][:-1] if int(r.split()[1]) != BARCODES[2]}),
    }
    twists = [m.twist for _, m in msgs["/robot1/velocity"]]
    assert {(t.linear.x, t.angular.z, t.linear.y, t.angular.x) for t in twists} == {(0.3, 0.25, 0.0, 0.0)}
    points = [tr for _, m in msgs["/robot1/landmarks"] for tr in m.transforms]
    assert len(points) == stats["kept"] and {p.fiducial_id for p in points} <= set(LANDMARKS)
    first = stats["meas"][0].split()
    xyz = points[0].transform.translation
    r, b = float(first[2]), float(first[3])
    assert (xyz.x, xyz.y, xyz.z) == pytest.approx((r * np.cos(b), r * np.sin(b), 0.0))
    stamps = [t for topic in msgs.values() for t, _ in topic]
    assert min(stamps) >= int(T0 * 1e9) - 10**6
    survey = json.loads(msgs["/slamobs/sim_truth"][0][1].data)["landmarks"]
    assert sorted(map(int, survey)) == sorted(LANDMARKS)
    assert all(survey[str(k)] == pytest.approx([*xy, 0.0]) for k, xy in LANDMARKS.items())
    assert f"dropped {stats['robots']} of other robots and 1 of unlisted barcodes" in line


def test_readers_find_every_role_without_config(imported):
    streams = read_log(imported[0])
    assert streams.angular_velocity.topic == streams.linear_velocity.topic == "/robot1/velocity"
    assert streams.detections.topic == "/robot1/landmarks" and streams.truth.topic == "/robot1/groundtruth"
    assert sorted(streams.landmark_truth) == sorted(LANDMARKS)
    # the truth's heading is a rotation about z: the body x axis is (cos th, sin th, 0)
    first_heading = 0.7
    assert streams.truth.quat_xyzw[0] == pytest.approx([0, 0, np.sin(first_heading / 2), np.cos(first_heading / 2)])


def test_info_says_what_the_landmark_survey_is(imported):
    """`slamobs info` on an import listed the survey only as the role `sim_truth` (session 24): it now says it is
    the landmark truth, how many positions, and that runs report their map error against it, in the roles and as
    the readiness list's map truth; `info --json` carries the same words."""
    res = invoke("info", imported[0])
    assert res.exit_code == 0, res.output
    words = f"landmark truth: {len(LANDMARKS)} positions, surveyed or simulated; a run reports its map error against it"
    assert f"sim_truth         /slamobs/sim_truth  ({words})" in res.output, res.output
    assert f"map truth         found    /slamobs/sim_truth  ({words})" in res.output
    doc = json.loads(invoke("info", imported[0], "--json").output)
    assert doc["sim_truth"] == words


def test_run_on_the_imported_log_reports_ape_and_map_error(imported, tmp_path):
    (tmp_path / "run.yaml").write_text("evaluation:\n  plots: false\n")
    res = invoke("run", imported[0], "-o", tmp_path / "run", "--config", tmp_path / "run.yaml", "--quiet")
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    # exact odometry and measurements (to the file's 3 decimals): the estimate lies on the truth and the map on
    # the survey, which only holds if velocities, bearings and the survey's frame were all converted alike
    assert report["ape"]["translation_m"]["rmse"] < 0.02 and report["ape"]["rotation_deg"]["rmse"] < 0.5
    assert report["landmarks"]["error_m"]["n"] == len(LANDMARKS) and report["landmarks"]["error_m"]["rmse"] < 0.02


def test_all_robots_and_force_replaces_only_its_own_logs(dataset, tmp_path):
    out = tmp_path / "all"
    res = invoke("import", "mrclam", dataset[0], "-o", out, "--robot", "all")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["robot1.mcap", "robot2.mcap"]
    assert res.output.count("wrote ") == 2
    again = invoke("import", "mrclam", dataset[0], "-o", out / "robot2.mcap", "--robot", "2")
    assert again.exit_code == 2 and "exists already" in again.output
    assert invoke("import", "mrclam", dataset[0], "-o", out / "robot2.mcap", "--robot", "2", "--force").exit_code == 0
    foreign = tmp_path / "foreign.mcap"
    foreign.write_bytes(b"not ours")
    res = invoke("import", "mrclam", dataset[0], "-o", foreign, "--robot", "2", "--force")
    assert res.exit_code == 2 and foreign.read_bytes() == b"not ours"
    res = invoke("import", "mrclam", dataset[0], "-o", foreign, "--robot", "2")  # not "use --force" (refused too)
    assert res.exit_code == 2 and "--force replaces only" in res.output and "use --force" not in res.output


@pytest.mark.parametrize(
    "damage, named",
    [
        (lambda d: (d / "Barcodes.dat").unlink(), "Barcodes.dat"),
        (lambda d: (d / "Robot1_Odometry.dat").write_text("1248444175.1 0.3 zero\n"), "Robot1_Odometry.dat"),
        (lambda d: (d / "Robot1_Groundtruth.dat").write_text("1248444175.1 0.3 0.2\n"), "Robot1_Groundtruth.dat"),
        (lambda d: (d / "Robot1_Measurement.dat").write_text("5.0 63 2.0 0.1\n4.0 63 2.0 0.1\n"), "backwards"),
    ],
    ids=["no-barcodes", "not-a-number", "columns", "time-backwards"],
)
def test_a_malformed_folder_is_one_line_and_writes_nothing(dataset, tmp_path, damage, named):
    import shutil

    folder = tmp_path / "broken"
    shutil.copytree(dataset[0], folder)
    damage(folder)
    out = tmp_path / "out.mcap"
    res = invoke("import", "mrclam", folder, "-o", out, "--robot", "1")
    assert res.exit_code == 2, res.output
    assert res.output.startswith("error: ") and res.output.count("\n") == 1 and named in res.output
    assert not out.exists() and list(tmp_path.iterdir()) == [folder]


MRCLAM6 = REALDATA / "mrclam" / "MRCLAM_Dataset6"


@pytest.mark.skipif(not MRCLAM6.is_dir(), reason="MR.CLAM dataset 6 is not in ../shared/realdata")
def test_real_robot_imports_every_row(tmp_path):
    from slamobs.pipeline.importers.mrclam import read_dataset, read_robot

    def rows(name: str) -> int:
        return sum(1 for line in (MRCLAM6 / name).read_text().splitlines() if line and not line.startswith("#"))

    res = invoke("import", "mrclam", MRCLAM6, "-o", tmp_path / "r4.mcap", "--robot", "4")
    assert res.exit_code == 0, res.output
    msgs = _messages(tmp_path / "r4.mcap")
    log = read_robot(read_dataset(MRCLAM6), 4)
    assert len(msgs["/robot4/velocity"]) == rows("Robot4_Odometry.dat")
    assert len(msgs["/robot4/groundtruth"]) == rows("Robot4_Groundtruth.dat")
    observed = sum(len(m.transforms) for _, m in msgs["/robot4/landmarks"])
    assert observed + log.other_robots + log.unknown == rows("Robot4_Measurement.dat") and log.other_robots > 0
    assert len(json.loads(msgs["/slamobs/sim_truth"][0][1].data)["landmarks"]) == rows("Landmark_Groundtruth.dat")


def test_the_folder_of_the_datasets_names_them(dataset, tmp_path):
    """The downloaded layout is a folder of MRCLAM_Dataset1 ... 9: given that folder, the import said
    "<folder>/Barcodes.dat: missing: an MR.CLAM folder has Barcodes.dat", as if the dataset were broken; it now
    names the dataset folders in it and one to give."""
    import shutil

    parent = tmp_path / "mrclam"
    shutil.copytree(dataset[0], parent / "MRCLAM_Dataset6")
    out = tmp_path / "out.mcap"
    res = invoke("import", "mrclam", parent, "-o", out)
    assert res.exit_code == 2, res.output
    assert res.output.startswith("error: ") and res.output.count("\n") == 1, res.output
    assert "MRCLAM_Dataset6" in res.output and "give one" in res.output and "Barcodes.dat" not in res.output
    assert not out.exists()
