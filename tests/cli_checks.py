"""What the CLI tests share: the sample logs the project ships, and running a command in this process."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from slamobs.cli.main import main

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"


def invoke(*args, catch_exceptions: bool = False, **kwargs):
    """``slamobs ARGS...`` through click's runner; an unexpected exception fails the test unless caught."""
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=catch_exceptions, **kwargs)


def map_truth_only_config(tmp_path: Path) -> Path:
    """A run config with the circle scenario's landmarks as map truth and the trajectory truth switched off
    (a log with a survey and no trajectory truth)."""
    from slamobs.pipeline.simulate import get_scenario

    sc = get_scenario("circle")
    truth_map = tmp_path / "map.csv"
    truth_map.write_text(
        "id,x,y,z\n" + "".join(f"{i},{x},{y},{z}\n" for i, (x, y, z) in zip(sc.landmark_ids, sc.landmarks))
    )
    config = tmp_path / "run.yaml"
    config.write_text(f"topics:\n  truth: ''\nevaluation:\n  plots: false\n  map_truth: {json.dumps(str(truth_map))}\n")
    return config
