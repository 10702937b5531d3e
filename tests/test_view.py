"""`slamobs view`: runs as a Rerun recording, read back with rerun's own reader (skipped without rerun-sdk)."""

from __future__ import annotations

import json
import shutil
from collections import defaultdict

import numpy as np
import pandas as pd
import pytest

from cli_checks import invoke

chunk = pytest.importorskip("rerun.chunk", reason="rerun-sdk (the view extra) is not installed")

from slamobs.pipeline.evaluation.tables import LANDMARK_COV
from slamobs.pipeline.viewer import SIGMAS


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A riekf run on a short simulated log (no report figures: not needed here) and a copy of it."""
    from slamobs.pipeline.simulate import simulate, write_log

    base = tmp_path_factory.mktemp("view")
    log = write_log(simulate("circle", duration=3.0, seed=5), base / "circle.mcap")
    (base / "run.yaml").write_text("evaluation:\n  plots: false\n")
    res = invoke("run", log, "-o", base / "runs" / "riekf", "--observer", "riekf", "--config", base / "run.yaml")
    assert res.exit_code == 0, res.output
    shutil.copytree(base / "runs" / "riekf", base / "runs" / "copy")
    return base / "runs"


def read_rrd(path) -> dict[str, dict]:
    """Per entity path: rows (time points or static logs) and the Arrow columns' values, concatenated."""
    found: dict[str, dict] = defaultdict(lambda: {"rows": 0, "static": False, "columns": defaultdict(list)})
    for c in chunk.RrdReader(str(path)).stream():
        entity = found[c.entity_path]
        entity["rows"] += c.num_rows
        entity["static"] |= c.is_static
        batch = c.to_record_batch()
        for name in batch.schema.names:
            entity["columns"][name] += batch.column(name).to_pylist()
    return found


def _instances(entity: dict, column: str) -> int:
    """Instances logged in ``column`` over all rows (a row holds a list of them)."""
    return sum(len(v) for v in entity["columns"][column])


def test_one_run_entities_and_counts(runs, tmp_path):
    out = tmp_path / "riekf.rrd"
    res = invoke("view", runs / "riekf", "-o", out)
    assert res.exit_code == 0, res.output
    rec = read_rrd(out)
    poses = pd.read_parquet(runs / "riekf" / "poses.parquet")
    landmarks = pd.read_parquet(runs / "riekf" / "landmarks.parquet")
    innovations = pd.read_parquet(runs / "riekf" / "innovations.parquet")
    biases = pd.read_parquet(runs / "riekf" / "biases.parquet")
    report = json.loads((runs / "riekf" / "report.json").read_text())
    base = "/world/riekf"
    assert rec[f"{base}/pose"]["rows"] == len(poses) and not rec[f"{base}/pose"]["static"]
    assert rec[f"{base}/truth"]["static"] and rec[f"{base}/trajectory"]["static"]
    assert _instances(rec[f"{base}/landmarks"], "Points3D:positions") == len(landmarks)
    assert sorted(rec[f"{base}/landmarks"]["columns"]["Points3D:labels"][0]) == sorted(map(str, landmarks["id"]))
    # a ray per detection, grouped by detection time
    assert _instances(rec[f"{base}/detections"], "LineStrips3D:strips") == len(innovations)
    assert rec[f"{base}/detections"]["rows"] == innovations["t_ns"].nunique()
    # errors: one value per associated pose pair, the report's APE
    position = np.array([v[0] for v in rec["/errors/riekf/position_m"]["columns"]["Scalars:scalars"]])
    assert len(position) == report["ape"]["translation_m"]["n"]
    assert np.sqrt(np.mean(position**2)) == pytest.approx(report["ape"]["translation_m"]["rmse"], rel=1e-9)
    for axis in "xyz":
        gyro = [v[0] for v in rec[f"/biases/riekf/gyro/{axis}"]["columns"]["Scalars:scalars"]]
        np.testing.assert_allclose(gyro, biases[f"gyro_bias_{axis}"].to_numpy())
        assert rec[f"/biases/riekf/velocity/{axis}"]["rows"] == len(biases)
    # riekf writes each landmark's covariance: one 3-sigma ellipsoid per landmark, axes from its eigenvalues
    cov = landmarks[list(LANDMARK_COV)].to_numpy()
    assert np.isfinite(cov).all()
    xx, xy, xz, yy, yz, zz = cov.T
    mats = np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], 1)
    half = np.array(rec[f"{base}/landmarks/covariance"]["columns"]["Ellipsoids3D:half_sizes"][0])
    scale = report["method"]["alignment"].get("scale", 1.0)
    expected = SIGMAS * scale * np.sqrt(np.clip(np.linalg.eigvalsh(mats), 0, None))
    np.testing.assert_allclose(np.sort(half, axis=1), expected, rtol=1e-5, atol=1e-9)  # rerun stores float32


def test_several_runs_in_one_recording_and_the_default_file(runs):
    res = invoke("view", runs / "riekf", runs / "copy")
    assert res.exit_code == 0, res.output
    out = runs / "riekf" / "view.rrd"
    entities = set(read_rrd(out))
    for label in ("riekf", "riekf-2"):  # one label per run, numbered when an estimator comes twice
        assert {f"/world/{label}/pose", f"/world/{label}/trajectory", f"/errors/{label}/position_m"} <= entities
    manifest = json.loads((runs / "riekf" / "slamobs-output.json").read_text())
    assert "view.rrd" in manifest["files"]  # still slamobs's own output directory
    res = invoke("view", runs / "copy", "-o", out)
    assert res.exit_code == 2 and "exists already" in res.stderr
    res = invoke("view", runs / "copy", "-o", out, "--force")
    assert res.exit_code == 0 and "/world/riekf-2/pose" not in read_rrd(out)


def test_landmark_covariance_becomes_ellipsoids(runs, tmp_path):
    run = tmp_path / "with_cov"
    shutil.copytree(runs / "copy", run)
    landmarks = pd.read_parquet(run / "landmarks.parquet")
    variances = np.array([0.01, 0.04, 0.09])
    cov = {c: 0.0 for c in LANDMARK_COV} | {"cov_xx": variances[0], "cov_yy": variances[1], "cov_zz": variances[2]}
    for name, value in cov.items():
        landmarks[name] = value
    landmarks.loc[0, list(LANDMARK_COV)] = np.nan  # a landmark without covariance (an observer's) gets none
    landmarks.to_parquet(run / "landmarks.parquet")
    res = invoke("view", run, "-o", tmp_path / "cov.rrd")
    assert res.exit_code == 0, res.output
    ellipsoids = read_rrd(tmp_path / "cov.rrd")["/world/riekf/landmarks/covariance"]["columns"]
    half = np.array(ellipsoids["Ellipsoids3D:half_sizes"][0])
    assert half.shape == (len(landmarks) - 1, 3)
    # the alignment rotates the axes but keeps their lengths: 3 sigma of each variance
    expected = np.tile(SIGMAS * np.sqrt(variances), (len(half), 1))
    np.testing.assert_allclose(np.sort(half, axis=1), expected, rtol=1e-6)  # rerun stores float32


def test_bad_run_directory_is_one_line_and_writes_nothing(tmp_path):
    (tmp_path / "empty").mkdir()
    res = invoke("view", tmp_path / "empty", "-o", tmp_path / "x.rrd")
    assert res.exit_code == 2 and "not a run directory" in res.stderr and str(tmp_path / "empty") in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "x.rrd").exists()


def test_without_truth_the_estimate_is_shown_alone(runs, tmp_path):
    run = tmp_path / "moved"
    shutil.copytree(runs / "copy", run)
    meta = json.loads((run / "run.json").read_text())
    meta["input"]["path"] = str(tmp_path / "gone.mcap")  # the log moved away: no truth to read
    (run / "run.json").write_text(json.dumps(meta))
    res = invoke("view", run, "-o", tmp_path / "alone.rrd")
    assert res.exit_code == 0, res.output
    assert "no truth shown" in res.stderr and "gone.mcap" in res.stderr
    rec = read_rrd(tmp_path / "alone.rrd")
    assert "/world/riekf/pose" in rec and "/world/riekf/landmarks" in rec
    assert not any(e.startswith("/errors/") or e.endswith("/truth") for e in rec)
    poses = pd.read_parquet(run / "poses.parquet")
    shown = np.array([p[0] for p in rec["/world/riekf/pose"]["columns"]["Points3D:positions"]])
    np.testing.assert_allclose(shown, poses[["x", "y", "z"]].to_numpy(), rtol=1e-6, atol=1e-6)  # unaligned


def test_a_run_without_covariance_columns_has_no_ellipsoids(runs, tmp_path):
    run = tmp_path / "older"
    shutil.copytree(runs / "copy", run)
    landmarks = pd.read_parquet(run / "landmarks.parquet")
    landmarks.drop(columns=[c for c in landmarks.columns if c.startswith("cov_")]).to_parquet(run / "landmarks.parquet")
    res = invoke("view", run, "-o", tmp_path / "older.rrd")
    assert res.exit_code == 0, res.output
    rec = read_rrd(tmp_path / "older.rrd")
    assert "/world/riekf/landmarks" in rec and "/world/riekf/landmarks/covariance" not in rec
