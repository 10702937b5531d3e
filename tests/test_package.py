"""The distribution installs one import package, ``slamobs``, and its small Python API works."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_has_only_the_slamobs_package(tmp_path):
    """No generic top-level names (``pipeline``, ``cli``, ``schemas``) in the wheel; the JSON schemas ship."""
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(ROOT),
        ],
        check=True,
        capture_output=True,
    )
    (wheel,) = tmp_path.glob("slamobs-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names}
    assert {t for t in top if not t.endswith(".dist-info")} == {"slamobs"}
    for sub in ("pipeline/run.py", "cli/main.py", "schemas/poses.json", "schemas/config.json", "__init__.py"):
        assert f"slamobs/{sub}" in names
    assert not [n for n in names if n.startswith("slamobs/tests/") or n.startswith("slamobs/benchmarks/")]


def test_local_folders_named_like_the_subpackages_do_not_shadow_them(tmp_path):
    """A user's own ``cli/`` or ``pipeline/`` folder on the path cannot break the command."""
    for name in ("cli", "pipeline", "schemas"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text("raise ImportError('shadowed')\n")
    out = subprocess.run(
        [sys.executable, "-c", "from slamobs.cli.main import main; main(['--version'])"],
        cwd=tmp_path,
        env={"PYTHONPATH": str(tmp_path)},
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert "slamobs, version" in out.stdout


def test_python_api_runs_a_log_and_loads_the_run(tmp_path):
    import slamobs

    summary = slamobs.run_log(
        ROOT / "sample_logs" / "circle.bag", tmp_path / "run", config={"evaluation": {"plots": False}}
    )
    run = slamobs.load_run(tmp_path / "run")
    assert run.meta["observer"]["name"] == "fast-adaptation"
    assert isinstance(run.poses, pd.DataFrame) and len(run.poses) == summary.metadata["counts"]["velocity_samples"]
    assert {"poses", "biases", "landmarks", "landmark_tracks", "innovations"} <= set(run.tables)
    assert run.report is not None and run.report["ape"]["translation_m"]["rmse"] < 0.1
    streams = slamobs.read_log(ROOT / "sample_logs" / "circle.bag")
    assert len(streams.angular_velocity.t_ns) > 100
