"""Log simulator: analytic scenarios -> noisy sensor streams -> ROS1 bag / rosbag2 / MCAP with truth.

Typical use::

    sim = simulate("figure8", seed=1)
    write_log(sim, "out/figure8.mcap")
"""

from pipeline.simulate.logwriter import infer_container, make_typestore, write_log
from pipeline.simulate.scenarios import SCENARIOS, Scenario, Trajectory, get_scenario
from pipeline.simulate.sensors import NoiseModel, SimLog, expected_streams, simulate

__all__ = [
    "SCENARIOS",
    "NoiseModel",
    "Scenario",
    "SimLog",
    "Trajectory",
    "expected_streams",
    "get_scenario",
    "infer_container",
    "make_typestore",
    "simulate",
    "write_log",
]
