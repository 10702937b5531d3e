"""``slamobs info LOG``: containers, topics, types, counts, rates, time span, detected roles, and whether the log
can run (per estimator, with what would give each missing input and a ``run.yaml`` for what was found)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from slamobs.cli.errors import handled
from slamobs.cli.options import config_option


@click.command("info")
@click.argument("logs", nargs=-1, required=True, metavar="LOG...", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.option(
    "--msg-dir",
    type=click.Path(path_type=Path),
    default=None,
    help="Directory of pkg/msg/Type.msg files for message types whose definitions the log lacks.",
)
@click.option(
    "--noise",
    is_flag=True,
    help="Read and align LOG and print the noise levels riekf would use and batch would start from (docs/noise.md); "
    "no estimator runs. "
    "On a log they cannot run on (e.g. IMU only): each sensor stream's own white-noise density, and why not the rest.",
)
@config_option("run.yaml: the settings it gives (tags.size, cameras) are not asked for; with --noise its noise levels.")
def info(logs: tuple[Path, ...], *, as_json: bool, msg_dir: Path | None, noise: bool, config_path: Path | None) -> None:
    """Summarise LOG (ROS1 .bag, rosbag2 directory, .mcap or .db3), the roles its topics would play, and whether
    each estimator can run on it; with --noise, the noise levels learned from it.

    A ROS1 recording split into NAME_0.bag, NAME_1.bag, ... is one LOG: its directory, or all its parts.
    """
    from slamobs.pipeline.readers import format_info, inspect_log
    from slamobs.pipeline.readers.container import recording_of
    from slamobs.pipeline.readiness import readiness

    with handled():  # as under the `slamobs` group, also when the command is used on its own
        log = recording_of(logs)
        if noise:
            _noise(log, msg_dir, config_path, as_json)
            return
        config = _config(config_path)
        clocks = None if config is None else config.reader_options()["clocks"]
        summary = inspect_log(log, msg_dir=msg_dir, frames=_frames(config), clocks=clocks)
        ready = readiness(summary, config)
    if as_json:
        click.echo(json.dumps({**summary.to_dict(), "readiness": ready.to_dict()}, indent=2))
    else:
        click.echo(format_info(summary) + "\n\n" + format_readiness(ready))


def _config(config_path: Path | None):
    """The run.yaml given to info, or None."""
    from slamobs.pipeline.config import load_config

    return None if config_path is None else load_config(config_path)


def _frames(config) -> dict | None:
    """What the config says of frames that ``info``'s TF section needs (the body, the frames taken as it, cameras)."""
    if config is None:
        return None
    return {
        "body_frame": config.frames.body,
        "identity": config.frames.assume_identity,
        "override": config.frames.override_identity,
        "cameras_given": bool(config.cameras),
    }


def _noise(log: Path, msg_dir: Path | None, config_path: Path | None, as_json: bool) -> None:
    """The noise levels of the reference estimators on LOG: the config's, else plausible covariances, else
    estimated from the samples (the detection law from the log's own static landmarks: no estimator needed)."""
    from dataclasses import replace

    from slamobs.cli.progress import compile_notice, status_line
    from slamobs.pipeline.run import silent
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.run import detection_checks, log_noise, prepare_log

    from slamobs.pipeline.errors import InputError

    config = load_config(config_path)
    if msg_dir:
        config = replace(config, msg_dir=str(msg_dir))
    status = status_line(quiet=False)
    try:
        with compile_notice(status):
            prepared = prepare_log(log, config, directions=False, progress=status or silent)
            settings = log_noise(prepared, config)
            checks = [] if as_json else detection_checks(prepared)
    except InputError as err:  # e.g. an IMU-only log: its sensors' own levels, and why not the rest
        if status is not None:
            status.clear()
        _sensor_noise(log, config, err, as_json)
        return
    if status is not None:
        status.clear()
    if as_json:
        click.echo(json.dumps(settings.as_dict(), indent=2))
        return
    click.echo(
        f"noise levels of {log} (riekf uses them, batch starts from them; key: value unit (source, ± standard "
        "error: method)):"
    )
    for line in settings.lines() + _batch_lines(settings, config) + list(settings.notes) + checks:
        click.echo(f"  {line}")


def _batch_lines(settings, config) -> list[str]:
    """What batch's run will use in place of a level printed: the held velocity's level re-estimated from its own
    solution (``pipeline.smoother.held_velocity``), which on MR.CLAM is a third of the detection pairs' level."""
    from slamobs.pipeline.smoother.held_velocity import WINDOW_S, skipped

    if skipped(config.batch.held_velocity, settings, fixed_bias=False) is not None:
        return []
    return [
        "velocity (batch): not the level above: batch re-estimates it from its own solution's residuals over "
        f"{WINDOW_S:g} s windows, at most the level above (batch.held_velocity; its run.json "
        "observer.smoother.held_velocity, its note)"
    ]


def _sensor_noise(log: Path, config, err, as_json: bool) -> None:
    """What ``--noise`` can show of a log the reference estimators cannot run on (``err``, the input error that
    stopped them: e.g. an IMU-only log, no velocity or detections): each sensor stream's own white-noise density
    (``noise.sensor_levels``; no estimator's level: those weigh the streams together), and what cannot be
    estimated and why. ``err`` is raised again when the log has no such stream, or cannot be read at all."""
    from slamobs.pipeline.alignment import accel_up_unaligned, gyro_axes_unaligned
    from slamobs.pipeline.errors import SlamobsError
    from slamobs.pipeline.noise import format_level, sensor_levels
    from slamobs.pipeline.readers import read_log

    try:
        streams = read_log(log, config.topics or None, **config.reader_options())
    except SlamobsError:
        raise err from None
    levels = sensor_levels(streams)
    # a turned IMU frame, before a config takes it as the body: by the odometry's turn, by gravity
    checks = gyro_axes_unaligned(streams, config.frames.body) + accel_up_unaligned(streams, config.frames.body)
    if not any("value" in v for v in levels.values()):
        raise err
    why = f"{err.problem}{''.join(f'; {d}' for d in err.details)}"
    cannot = (
        "the detection levels, the biases' and the levels batch and riekf would use (they weigh the streams together)"
    )
    if as_json:
        doc = {"sensors": levels, "checks": checks, "not_estimated": cannot, "why": why}
        click.echo(json.dumps(doc, indent=2))  # one string
        return
    click.echo(f"noise of {log}'s sensor streams, each on its own (key: value unit (topic, ± standard error: method)):")
    for name, v in levels.items():
        if "value" in v:
            value, spread = format_level(v["value"], 4, False), format_level(v["uncertainty"], 4, False)
            click.echo(f"  {name} = {value} {v['unit']} ({v['topic']}, ± {spread}: {v['method']})")
            if (st := v.get("stated")) is not None:
                click.echo(f"    {_stated_line(st, v['unit'], name)}")
        else:
            click.echo(f"  {name}: not estimated ({v['why']})")
    for line in checks:
        click.echo(f"  {line}")
    click.echo(f"  not estimated: {cannot}: {err.problem}")
    for line in err.details:
        click.echo(f"    {line}")


def _stated_line(st: dict, unit: str, key: str) -> str:
    """What a stream's messages state of its noise (``noise.sensor_levels``' ``stated``) and whether a run uses it."""
    from slamobs.pipeline.noise import format_level

    head = f"its messages state {st['topic']} covariance ({st['rate']})"
    if st["value"] is not None:
        head += f" = {format_level(st['value'], 4, False)} {unit}"
    if st["used"] and st.get("above") is not None:
        return (
            f"{head}: {st['above']:.3g}x above the level above, its own samples': riekf and batch would use it in "
            "place of that level (a coloured noise is louder than its samples show; if this sensor's is white, "
            f"noise.{key} in run.yaml at that level weighs it as it is)"
        )
    if st["used"]:
        return f"{head}: riekf and batch would use it in place of the level above (plausible against the samples)"
    return f"{head}: riekf and batch would not use it ({st['why']})"


def format_readiness(ready) -> str:
    """The readiness section: each role found or missing, each estimator ready or what it lacks, the run.yaml."""
    ready_names = [e.name for e in ready.estimators if e.ready]
    verdict = f"{len(ready_names)} of {len(ready.estimators)} estimators can run" if ready_names else "cannot run"
    needs = {e.needs for e in ready.estimators if e.ready}
    if ready_names and () not in needs:  # `run` with no config stops on these: the verdict says so
        verdict += " once the config gives " + " and ".join(
            dict.fromkeys(n.split(" (")[0] for x in needs for n in x)
        ).replace(":", "")
    lines = [f"  readiness: {verdict}"]
    width = max(len(r.role) for r in ready.roles)
    for r in ready.roles:
        if r.found:
            rate = f"{r.rate_hz:.1f} Hz" if r.rate_hz is not None else "-"
            lines.append(f"    {r.role:<{width}}  found    {r.topic}  ({r.msgtype}, {rate})")
        else:
            lines.append(f"    {r.role:<{width}}  MISSING")
    if ready.map_truth:
        lines.append(f"    {'map truth':<{width}}  found    {ready.map_truth}")
    groups: dict[tuple, list[str]] = {}
    for e in ready.estimators:
        groups.setdefault((e.missing, e.unavailable, e.needs), []).append(e.name)
    lines.append("")
    for (missing, unavailable, needs), names in groups.items():
        if unavailable:
            state = f"cannot run: {unavailable}"
        elif missing:
            state = f"cannot run, missing {', '.join(missing)}"
        else:
            state = f"ready once the config gives {' and '.join(needs)}" if needs else "ready"
        lines.append(f"    {', '.join(names)}: {state}")
    if ready.trajectory:
        lines.append(f"    {ready.trajectory}")
    needed = {m for e in ready.estimators for m in e.missing} | {"truth"}
    for role, ways in ready.satisfy.items():
        if role in needed:
            what = "" if role != "truth" else " (optional: the error report)"
            lines += ["", f"    to give {role}{what}:", *(f"      {w}" for w in ways)]
    lines += ["", "  run.yaml for what was found:", *(f"    {x}" for x in ready.run_yaml.splitlines())]
    return "\n".join(lines)
