"""Log simulator: analytic scenarios -> noisy sensor streams -> ROS1 bag / rosbag2 / MCAP with truth.

Typical use::

    sim = simulate("figure8", seed=1)          # one SimLog in memory
    write_log(sim, "out/figure8.mcap")
    write_log(simulation("figure8-wide", duration=4 * 3600), "out/long.mcap")  # generated piece by piece
"""

from slamobs.pipeline.simulate.logwriter import infer_container, make_typestore, write_log
from slamobs.pipeline.simulate.scenarios import SCENARIOS, Scenario, Trajectory, get_scenario
from slamobs.pipeline.simulate.sensors import NoiseModel, SimLog, Simulation, expected_streams, simulate, simulation

__all__ = [
    "SCENARIOS",
    "NoiseModel",
    "Scenario",
    "SimLog",
    "Simulation",
    "Trajectory",
    "expected_streams",
    "get_scenario",
    "infer_container",
    "make_typestore",
    "simulate",
    "simulation",
    "write_log",
]
