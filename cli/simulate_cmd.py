"""``slamobs simulate``: write a simulated, seeded log with ground truth for testing the pipeline."""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path

import click

from slamobs.cli.options import SEED, AliasedOption, Finite, OutPath, quiet_option
from slamobs.cli.progress import Progress, compile_notice

#: Kept literal so ``slamobs --help`` need not import the simulator (numba, rosbags); a test checks it.
CONTAINERS = ("bag", "mcap", "ros2")

_RATE = Finite(min=0.0, min_open=True)
#: Horizontal field of view of the simulated image camera (--camera corners|images) when --fov is not given, deg.
IMAGE_FOV_DEG = 70.0


@click.command("simulate")
@click.argument("scenario")
@click.option(
    "-o",
    "--out",
    "--output",
    "output",
    required=True,
    type=OutPath(path_type=Path),
    cls=AliasedOption,
    hidden_aliases=("--output",),
    help="Log to write.",
)
@click.option(
    "--container",
    type=click.Choice(CONTAINERS),
    default=None,
    help="bag (ROS1), mcap (bare ROS2 MCAP) or ros2 (rosbag2 sqlite3 directory). Default: from the suffix.",
)
@click.option("--duration", type=_RATE, default=None, help="Seconds (default: the scenario's).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Noise and latency seed.")
@click.option("--no-noise", is_flag=True, help="Exact measurements (biases and latencies are kept).")
@click.option(
    "--gyro-noise",
    default=None,
    metavar="SIGMA[,SY,SZ]",
    help="Gyro noise per sample, rad/s: one value or x,y,z (default 0.005).",
)
@click.option(
    "--velocity-noise",
    default=None,
    metavar="SIGMA[,SY,SZ]",
    help="Odometry linear-velocity noise per sample, m/s: one value or x,y,z (default 0.02).",
)
@click.option(
    "--detection-noise",
    default=None,
    metavar="S0,K[,A]",
    help="Detection noise per axis at range r: S0 + K*r + A*r^2, m (default 0.01,0.002,0).",
)
@click.option("--imu-rate", type=_RATE, default=200.0, show_default=True, help="IMU rate, Hz.")
@click.option("--odom-rate", type=_RATE, default=50.0, show_default=True, help="Wheel odometry rate, Hz.")
@click.option("--mag-rate", type=_RATE, default=50.0, show_default=True, help="Magnetometer rate, Hz.")
@click.option("--mocap-rate", type=_RATE, default=100.0, show_default=True, help="Ground-truth pose rate, Hz.")
@click.option("--detection-rate", type=_RATE, default=None, help="Fiducial detection rate, Hz (default: scenario's).")
@click.option(
    "--camera",
    "camera_output",
    type=click.Choice(("fiducials", "corners", "images")),
    default="fiducials",
    show_default=True,
    help="What the camera reports: 3D fiducial poses, tag corners in pixels "
    "(apriltag_msgs) or rendered images (sensor_msgs), the last two with CameraInfo.",
)
@click.option("--image-size", default="640x480", show_default=True, help="Camera image size WxH (corners, images).")
@click.option(
    "--fov",
    type=Finite(10.0, 170.0),
    default=None,
    help="Horizontal field of view, deg: the scenario camera's (fiducials; default the scenario's, the "
    "vertical one scales with it) and the image camera's (corners, images; default 70).",
)
@click.option(
    "--distortion",
    type=click.Choice(("none", "radtan", "equidistant")),
    default="radtan",
    show_default=True,
    help="Lens distortion (corners, images).",
)
@click.option("--tag-size", type=_RATE, default=0.5, show_default=True, help="Tag size (black square), m.")
@click.option("--tag-family", default="36h11", show_default=True, help="Tag family of rendered images.")
@click.option(
    "--jpeg-quality",
    type=click.IntRange(0, 100),
    default=90,
    show_default=True,
    help="JPEG quality of images (sensor_msgs/CompressedImage); 0 writes raw mono8 sensor_msgs/Image.",
)
@click.option(
    "--image-noise", type=Finite(0.0), default=2.0, show_default=True, help="Pixel noise of images, grey levels."
)
@click.option("--blur", type=Finite(0.0), default=0.0, show_default=True, help="Image blur sigma, px.")
@click.option("--pixel-noise", type=Finite(0.0), default=0.3, show_default=True, help="Corner noise, px (corners).")
@click.option(
    "--landmarks",
    type=click.IntRange(min=3),
    default=None,
    help="Landmark count (loop: rebuilt with N tags; others: an evenly spaced subset of the map).",
)
@click.option(
    "--detections-until",
    type=Finite(min=0.0),
    default=None,
    help="Seconds after which no landmark is detected (they leave view for good).",
)
@click.option(
    "--imu-rpy",
    type=Finite(),
    nargs=3,
    default=None,
    metavar="ROLL PITCH YAW",
    help="IMU mounting, deg (imu_link -> body, published on /tf_static), e.g. 180 0 0 upside down.",
)
@click.option("--force", is_flag=True, help="Replace OUT if it exists.")
@quiet_option("Print nothing but errors.")
def simulate(
    scenario: str,
    output: Path,
    container: str | None,
    duration: float | None,
    seed: int,
    no_noise: bool,
    gyro_noise: str | None,
    velocity_noise: str | None,
    detection_noise: str | None,
    imu_rate: float,
    odom_rate: float,
    mag_rate: float,
    mocap_rate: float,
    detection_rate: float | None,
    camera_output: str,
    image_size: str,
    fov: float | None,
    distortion: str,
    tag_size: float,
    tag_family: str,
    jpeg_quality: int,
    image_noise: float,
    blur: float,
    pixel_noise: float,
    landmarks: int | None,
    detections_until: float | None,
    imu_rpy: tuple[float, float, float] | None,
    force: bool,
    quiet: bool,
) -> None:
    """Simulate SCENARIO (circle, figure8, figure8-wide, figure8-blind, figure8-imu-flipped, loop, ground,
    ground-hills) and write it to OUT with landmark and bias truth.

    With --camera corners or images the camera reports tags as a real one does (tag corners, or images rendered
    from the true camera pose; needs the vision extra: pip install 'slamobs[vision]'), with CameraInfo.
    """
    from slamobs.pipeline.simulate.logwriter import infer_container, log_size, why_kept, write_log
    from slamobs.pipeline.simulate.scenarios import SCENARIOS, customize, get_scenario
    from slamobs.pipeline.simulate.sensors import simulation

    if scenario not in SCENARIOS:
        raise click.BadParameter(
            f"unknown scenario {scenario!r}; choose from {', '.join(sorted(SCENARIOS))}", param_hint="SCENARIO"
        )
    try:
        rig = customize(
            get_scenario(scenario),
            landmarks=landmarks,
            fov_deg=fov,
            detections_until=detections_until,
            imu_rpy_deg=imu_rpy or None,
        )
    except ValueError as err:
        raise click.BadParameter(str(err)) from None
    container = container or infer_container(output)
    if os.path.lexists(output) and (why := why_kept(output, overwrite=force)) is not None:  # before the work
        from slamobs.cli.errors import exit_input_error
        from slamobs.pipeline.errors import OutputError

        exit_input_error(OutputError(output, why))
    camera = _camera(
        camera_output,
        image_size,
        IMAGE_FOV_DEG if fov is None else fov,
        distortion,
        tag_size,
        tag_family,
        jpeg_quality,
        image_noise,
        blur,
        pixel_noise,
    )
    sim = simulation(  # generated and written piece by piece: any duration fits in memory
        rig,
        duration=duration,
        seed=seed,
        noise=_noise_model(no_noise, gyro_noise, velocity_noise, detection_noise),
        imu_rate=imu_rate,
        odom_rate=odom_rate,
        mag_rate=mag_rate,
        detection_rate=detection_rate,
        mocap_rate=mocap_rate,
        camera=camera,
    )
    with Progress(quiet) as progress, compile_notice(progress.status, quiet=quiet, lines=progress):
        progress(f"simulate: writing {output}")
        path = write_log(sim, output, container, overwrite=force, progress=progress)
    if quiet:
        return
    counts = ", ".join(f"{topic} {n}" for topic, n in sim.topic_counts().items())
    click.echo(
        f"wrote {path} ({container}, {log_size(path) / 1e6:.2f} MB, {sim.scenario.name} {sim.duration:g} s, "
        f"seed {seed}{', no noise' if no_noise else ''}): {counts}"
    )


def _numbers(text: str, option: str, counts: tuple[int, ...]) -> tuple[float, ...]:
    """Comma-separated non-negative finite numbers, as many as one of ``counts``."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in counts or not all(math.isfinite(v) and v >= 0 for v in values):
        raise click.BadParameter(f"{text!r}: {' or '.join(map(str, counts))} non-negative numbers", param_hint=option)
    return values


def _noise_model(no_noise: bool, gyro: str | None, velocity: str | None, detection: str | None):
    """The simulator's noise: the default model (or none), with the levels given on the command line."""
    from slamobs.pipeline.simulate.sensors import NoiseModel

    if no_noise:
        if gyro or velocity or detection:
            raise click.BadParameter("noise levels given with --no-noise", param_hint="--no-noise")
        return False
    changes: dict = {}
    if gyro:
        g = _numbers(gyro, "--gyro-noise", (1, 3))
        changes["gyro"] = g[0] if len(g) == 1 else g
    if velocity:
        v = _numbers(velocity, "--velocity-noise", (1, 3))
        changes["odom_linear"] = v[0] if len(v) == 1 else v
    if detection:
        d = _numbers(detection, "--detection-noise", (2, 3))
        changes.update(detection_base=d[0], detection_per_m=d[1], detection_per_m2=d[2] if len(d) == 3 else 0.0)
    return replace(NoiseModel(), **changes) if changes else True


def _camera(
    output: str,
    image_size: str,
    fov: float,
    distortion: str,
    tag_size: float,
    family: str,
    jpeg_quality: int,
    image_noise: float,
    blur: float,
    pixel_noise: float,
):
    from slamobs.pipeline.simulate.camera import CameraSim

    try:
        width, height = (int(v) for v in image_size.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"{image_size!r} is not WxH (e.g. 640x480)", param_hint="--image-size") from None
    if output != "fiducials":
        from slamobs.pipeline.vision.detector import family_constant
        from slamobs.pipeline.errors import InputError

        try:
            family_constant(family)
        except InputError as err:
            raise click.BadParameter(err.problem, param_hint="--tag-family") from None
    try:
        return CameraSim(
            output,
            width,
            height,
            fov,
            distortion,
            tag_size,
            family,
            pixel_noise,
            image_noise,
            blur,
            jpeg_quality or None,
        )
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--image-size/--fov") from None
