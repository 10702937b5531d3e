"""Which clock a run's stamps are on when a detection time offset is applied (issue 23): run.json
``output.clock``, and the report's truth-clock search consistent with it."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from slamobs.pipeline.api import run_log
from slamobs.pipeline.simulate import simulate
from slamobs.pipeline.simulate.logwriter import write_log

#: The detections (and the truth) stamped this late against the velocity samples (the simulator's option).
OFFSET_S = 0.1


@pytest.mark.parametrize("observer", ["riekf", "fast-adaptation"])
def test_run_json_says_which_clock_the_stamps_are_on(tmp_path, observer):
    """A generated log whose detections and truth are both stamped ``OFFSET_S`` late (a camera clock that the
    motion capture shares, the odometry's clock early): riekf moves the detections onto the velocity clock and
    run.json says by how much, the poses and biases staying on the velocity samples' stamps; the innovations
    carry the moved stamps, the landmarks' first sighting the recorded ones. The report's truth-clock search,
    made against the velocity samples, finds the truth that far off the poses' clock (for riekf: minus the
    detections' move). fast-adaptation moves them too, by the same rule (session 33: before, it moved nothing)."""
    sim = simulate("figure8", seed=2, duration=60.0, detection_offset=OFFSET_S)
    off_ns = int(round(OFFSET_S * 1e9))
    sim = replace(sim, mocap=replace(sim.mocap, t_ns=sim.mocap.t_ns + off_ns, rec_ns=sim.mocap.rec_ns + off_ns))
    log = write_log(sim, tmp_path / "late_camera.mcap")
    out = tmp_path / "out"
    run_log(log, out, config={"observer": observer, "evaluation": {"plots": False}})
    meta = json.loads((out / "run.json").read_text())
    clock = meta["output"]["clock"]
    assert clock["stamps"] == "velocity"
    assert clock["moved_tables"] == ["innovations", "landmark_tracks"]
    assert clock["recorded_tables"] == ["tag_detections", "landmarks"]
    moved = clock["detections_moved_s"]
    assert meta["observer"]["time_offset"]["applied"] and abs(moved + OFFSET_S) < 0.005
    import pyarrow.parquet as pq

    def stamps(name: str) -> np.ndarray:
        return pq.read_table(out / f"{name}.parquet", columns=["t_ns"]).column("t_ns").to_numpy()

    velocity = set(np.asarray(sim.odom.t_ns).tolist()) | set(np.asarray(sim.imu.t_ns).tolist())
    assert set(stamps("poses").tolist()) <= velocity and set(stamps("biases").tolist()) <= velocity
    recorded = set(np.asarray(sim.detections.t_ns).tolist())
    first_seen = pq.read_table(out / "landmarks.parquet", columns=["first_seen_ns"]).column(0).to_numpy()
    assert set(first_seen.tolist()) <= recorded
    back = stamps("innovations") - int(round(moved * 1e9))  # t_recorded = t - detections_moved_s
    assert set(back.tolist()) <= recorded
    # the truth is OFFSET_S behind the poses' clock (t_estimate + offset is on the truth clock)
    found = meta["truth_clock_offset"]["offset_s"]
    assert abs(found - OFFSET_S) < 0.01
    if moved:
        assert abs(found + moved) < 0.01
