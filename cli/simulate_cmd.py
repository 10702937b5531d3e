"""``slamobs simulate``: write a simulated, seeded log with ground truth for testing the pipeline."""

from __future__ import annotations

from pathlib import Path

import click

from slamobs.cli.options import AliasedOption, quiet_option
from slamobs.cli.progress import compile_notice

#: Kept literal so ``slamobs --help`` need not import the simulator (numba, rosbags); a test checks it.
CONTAINERS = ("bag", "mcap", "ros2")

_RATE = click.FloatRange(min=0.0, min_open=True)


@click.command("simulate")
@click.argument("scenario")
@click.option("-o", "--out", "--output", "output", required=True, type=click.Path(path_type=Path), cls=AliasedOption,
              hidden_aliases=("--output",), help="Log to write.")
@click.option(
    "--container",
    type=click.Choice(CONTAINERS),
    default=None,
    help="bag (ROS1), mcap (bare ROS2 MCAP) or ros2 (rosbag2 sqlite3 directory). Default: from the suffix.",
)
@click.option("--duration", type=_RATE, default=None, help="Seconds (default: the scenario's).")
@click.option("--seed", type=int, default=0, show_default=True, help="Noise and latency seed.")
@click.option("--no-noise", is_flag=True, help="Exact measurements (biases and latencies are kept).")
@click.option("--imu-rate", type=_RATE, default=200.0, show_default=True, help="IMU rate, Hz.")
@click.option("--odom-rate", type=_RATE, default=50.0, show_default=True, help="Wheel odometry rate, Hz.")
@click.option("--mag-rate", type=_RATE, default=50.0, show_default=True, help="Magnetometer rate, Hz.")
@click.option("--mocap-rate", type=_RATE, default=100.0, show_default=True, help="Ground-truth pose rate, Hz.")
@click.option("--detection-rate", type=_RATE, default=None, help="Fiducial detection rate, Hz (default: scenario's).")
@click.option("--landmarks", type=click.IntRange(min=3), default=None,
              help="Landmark count (loop: rebuilt with N tags; others: an evenly spaced subset of the map).")
@click.option("--fov", type=click.FloatRange(0.0, 180.0, min_open=True, max_open=True), default=None,
              help="Camera horizontal field of view, deg (the vertical one scales with it).")
@click.option("--detections-until", type=click.FloatRange(min=0.0), default=None,
              help="Seconds after which no landmark is detected (they leave view for good).")
@click.option("--imu-rpy", type=float, nargs=3, default=None, metavar="ROLL PITCH YAW",
              help="IMU mounting, deg (imu_link -> body, published on /tf_static), e.g. 180 0 0 upside down.")
@click.option("--force", is_flag=True, help="Replace OUT if it exists.")
@quiet_option("Print nothing but errors.")
def simulate(
    scenario: str,
    output: Path,
    container: str | None,
    duration: float | None,
    seed: int,
    no_noise: bool,
    imu_rate: float,
    odom_rate: float,
    mag_rate: float,
    mocap_rate: float,
    detection_rate: float | None,
    landmarks: int | None,
    fov: float | None,
    detections_until: float | None,
    imu_rpy: tuple[float, float, float] | None,
    force: bool,
    quiet: bool,
) -> None:
    """Simulate SCENARIO (circle, figure8, figure8-wide, figure8-blind, figure8-imu-flipped, loop) and write it
    to OUT with landmark and bias truth."""
    from slamobs.pipeline.simulate.logwriter import infer_container, log_size, write_log
    from slamobs.pipeline.simulate.scenarios import SCENARIOS, customize, get_scenario
    from slamobs.pipeline.simulate.sensors import simulation

    if scenario not in SCENARIOS:
        raise click.BadParameter(
            f"unknown scenario {scenario!r}; choose from {', '.join(sorted(SCENARIOS))}", param_hint="SCENARIO"
        )
    try:
        rig = customize(get_scenario(scenario), landmarks=landmarks, fov_deg=fov, detections_until=detections_until,
                        imu_rpy_deg=imu_rpy or None)
    except ValueError as err:
        raise click.BadParameter(str(err)) from None
    container = container or infer_container(output)
    if (output.exists() or output.is_symlink()) and not force:
        raise click.ClickException(f"{output} exists already (use --force to replace it)")
    sim = simulation(  # generated and written piece by piece: any duration fits in memory
        rig,
        duration=duration,
        seed=seed,
        noise=not no_noise,
        imu_rate=imu_rate,
        odom_rate=odom_rate,
        mag_rate=mag_rate,
        detection_rate=detection_rate,
        mocap_rate=mocap_rate,
    )
    with compile_notice(quiet=quiet):
        path = write_log(sim, output, container, overwrite=force)
    if quiet:
        return
    counts = ", ".join(f"{topic} {n}" for topic, n in sim.topic_counts().items())
    click.echo(
        f"wrote {path} ({container}, {log_size(path) / 1e6:.2f} MB, {sim.scenario.name} {sim.duration:g} s, "
        f"seed {seed}{', no noise' if no_noise else ''}): {counts}"
    )
