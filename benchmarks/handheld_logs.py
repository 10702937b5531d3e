"""Generated logs of a hand-held / VIO rig, which the earlier unseen sweeps (ground robots, circles, figure 8s) did
not imitate: a walker's figure 8 (8 x 4 m, 0.6-1.3 m/s, 1.5 m high) with a 1.8 Hz step bob of 4 cm, a 12 deg roll and
pitch, a yaw wobble of 0.3 rad at 0.6 Hz, among the ``figure8-wide`` landmarks, seen by a camera beside the body
(8 cm, yawed 10 deg) to 8 m; the odometry's twist at 3-5 Hz (one instant's sample of the motion, as the simulator
writes it), and per case what a VIO rig adds: detection stamps 0.2-0.4 s off, message covariances stated at
0.05-0.2x the truth, blind stretches, few landmarks, a file cut short, 30-600 s, the three containers; and the
figure 8, loop and ground robot at 3-4 Hz as controls. Each log is run with ``fast-adaptation``, ``riekf`` and
``batch`` and no noise configuration, and riekf and batch given the true levels. Prints a Markdown table.

    .venv/bin/python benchmarks/handheld_logs.py [--cache DIR] [--seeds 3345 3348] [--no-true]
    .venv/bin/python benchmarks/handheld_logs.py --set round5 [--notes FILE]

``--set round5``: session 33's cases (``ROUND5``): a quadrotor's flight, a 200-400 Hz IMU beside 10 Hz odometry, a
drifting gyro bias, silent streams, jittered stamps, 60-200 landmarks, a camera turned 90 deg, covariances stated
3-10x above the samples (docs/benchmarks.md, "Logs nobody has run yet, round 5").

Columns: APE (m, SE(3)-aligned) per estimator, auto over true for riekf and batch, each over fast-adaptation,
the convergence verdicts, the report's mean position NEES ("OC": called overconfident), the velocity level auto
used against the truth, and the warnings (lines starting ``warning:``). docs/benchmarks.md, "Hand-held rigs with
a slow VIO twist", session 32.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from slamobs.pipeline.api import run_log
from slamobs.pipeline.noise import DEFAULTS
from slamobs.pipeline.simulate import NoiseModel, simulate, write_log
from slamobs.pipeline.simulate.scenarios import customize, flight_trajectory, get_scenario, handheld, rot_z

SUFFIX = {"mcap": ".mcap", "bag": ".bag", "ros2": ""}


@dataclass(frozen=True)
class Case:
    seed: int
    scenario: str
    duration: float
    note: str
    container: str = "mcap"
    imu_hz: float = 200.0
    odom_hz: float = 4.0
    gyro_x: float = 30.0  # the gyro's density over the default
    velocity_x: float = 10.0
    law: tuple[float, float] = (0.03, 0.006)  # sigma0 (m), k (m per m of range)
    detection_hz: float = 15.0
    offset_s: float = 0.0  # added to the detection stamps
    stated: float = 0.0  # the messages' covariance at this many times the truth (0: unknown)
    gaps: tuple[tuple[float, float], ...] = ()
    tilt_deg: float = 12.0
    wobble: float = 0.3  # yaw wobble amplitude (rad) at 0.6 Hz
    truncate: float = 0.0  # the file cut to this share of its bytes
    landmarks: int | None = None
    bias_walk: float = 0.0  # the gyro bias's random walk, rad/s per sqrt(s)
    dropouts: tuple[tuple[str, float, float], ...] = ()  # (stream: imu, odom or mag; start s; stop s) silent
    jitter_s: float = 0.0  # odometry and detection stamps moved by uniform +-jitter_s
    cam_yaw_deg: float = 0.0  # the camera turned this much more about the body's z axis


CASES = (
    Case(3345, "handheld", 60, "hand-held, 4 Hz twist"),
    Case(3346, "handheld", 120, "3 Hz odometry", container="bag", odom_hz=3),
    Case(3347, "handheld", 90, "stated 0.1x", container="ros2", odom_hz=5, stated=0.1),
    Case(3348, "handheld", 90, "stated 0.2x", stated=0.2),
    Case(3349, "handheld", 90, "stated 0.05x", container="bag", stated=0.05),
    Case(3350, "handheld", 90, "detection stamps +0.3 s", offset_s=0.3),
    Case(3351, "handheld", 90, "detection stamps -0.2 s", container="ros2", offset_s=-0.2),
    Case(3352, "handheld", 90, "detection stamps +0.4 s", container="bag", offset_s=0.4),
    Case(3353, "handheld", 120, "blind 20/16/21 s, 4 s returns", gaps=((20, 40), (44, 60), (64, 85))),
    Case(3354, "handheld", 120, "blind 25 s, 6 landmarks", container="ros2", gaps=((30, 55),), landmarks=6),
    Case(3355, "handheld", 60, "tilt 15 deg, yaw wobble 0.6 rad", tilt_deg=15, wobble=0.6),
    Case(3356, "handheld", 90, "MCAP cut at 80 %", truncate=0.8),
    Case(3357, "handheld", 90, "bag cut at 70 %", container="bag", truncate=0.7),
    Case(3358, "handheld", 30, "30 s, g100 v30", odom_hz=5, gyro_x=100, velocity_x=30),
    Case(3359, "handheld", 600, "600 s", gyro_x=10, velocity_x=5, law=(0.02, 0.004), detection_hz=10),
    Case(3360, "handheld", 120, "+0.25 s, stated 0.1x, blind 15 s", offset_s=0.25, stated=0.1, gaps=((50, 65),)),
    Case(3361, "figure8", 90, "drone figure 8, 4 Hz odometry"),
    Case(3362, "loop", 120, "loop, 3 Hz odometry", container="ros2", odom_hz=3, law=(0.05, 0.01)),
    Case(3363, "handheld", 90, "g30 v50, sigma (0.1, 0.02)", velocity_x=50, law=(0.1, 0.02)),
    Case(3364, "handheld", 90, "stated 0.1x, +0.3 s", container="bag", imu_hz=100, stated=0.1, offset_s=0.3),
    Case(3365, "ground", 180, "ground robot, 4 Hz odometry", imu_hz=100),
)


#: round 5 (session 33, docs/benchmarks.md "Logs nobody has run yet, round 5"): a quadrotor's 3D flight, a fast IMU
#: with 10 Hz odometry, a drifting gyro bias, silent streams, jittered stamps, 50-200 landmarks seen briefly and
#: re-seen a lap later, a camera turned 90 deg, stated covariances 3-10x above the samples
ROUND5 = (
    Case(3445, "flight", 90, "quadrotor flight, 400/10 Hz", imu_hz=400, odom_hz=10),
    Case(3446, "flight", 120, "flight, stated 5x", container="bag", imu_hz=400, odom_hz=10, stated=5.0),
    Case(
        3447,
        "flight",
        90,
        "flight, imu silent 3 s twice",
        container="ros2",
        imu_hz=300,
        odom_hz=10,
        dropouts=(("imu", 30, 33), ("imu", 60, 64)),
    ),
    Case(
        3448,
        "flight",
        90,
        "flight, odom silent 4 s twice",
        imu_hz=400,
        odom_hz=10,
        dropouts=(("odom", 25, 29), ("odom", 55, 60)),
    ),
    Case(3449, "flight", 120, "flight, stamps +-20 ms", container="bag", imu_hz=200, odom_hz=10, jitter_s=0.02),
    Case(
        3450,
        "flight",
        600,
        "flight 10 min, bias walk 3e-4",
        imu_hz=200,
        odom_hz=10,
        bias_walk=3e-4,
        gyro_x=10,
        velocity_x=5,
        detection_hz=10,
    ),
    Case(
        3451,
        "handheld",
        600,
        "hand-held 10 min, bias walk 5e-4",
        container="ros2",
        imu_hz=200,
        odom_hz=10,
        bias_walk=5e-4,
        gyro_x=10,
        velocity_x=5,
        detection_hz=10,
    ),
    Case(3452, "handheld", 90, "camera turned 90 deg", imu_hz=400, odom_hz=10, cam_yaw_deg=90),
    Case(3453, "flight", 90, "flight, camera turned 90 deg", container="ros2", imu_hz=400, odom_hz=10, cam_yaw_deg=90),
    Case(3454, "loop", 270, "loop, 150 landmarks, 3 laps", imu_hz=400, odom_hz=10, landmarks=150),
    Case(
        3455,
        "loop",
        270,
        "loop, 200 landmarks, stated 3x",
        container="bag",
        imu_hz=200,
        odom_hz=10,
        landmarks=200,
        stated=3.0,
    ),
    Case(
        3456,
        "loop",
        180,
        "loop, 60 landmarks, jitter 20 ms",
        container="ros2",
        imu_hz=300,
        odom_hz=10,
        landmarks=60,
        jitter_s=0.02,
    ),
    Case(3457, "handheld", 90, "stated 10x", imu_hz=400, odom_hz=10, stated=10.0),
    Case(3458, "handheld", 90, "stated 3x, 4 Hz odom", container="bag", stated=3.0),
    Case(
        3459,
        "handheld",
        120,
        "odom silent 5 s twice, mag silent 2 s",
        imu_hz=400,
        odom_hz=10,
        dropouts=(("odom", 30, 35), ("odom", 80, 85), ("mag", 50, 52)),
    ),
    Case(
        3460,
        "flight",
        120,
        "flight, jitter, odom silent, stated 5x",
        imu_hz=400,
        odom_hz=10,
        jitter_s=0.02,
        stated=5.0,
        dropouts=(("odom", 40, 44), ("odom", 90, 93)),
    ),
    Case(
        3461,
        "loop",
        270,
        "loop, 100 landmarks, bias walk 5e-4",
        container="ros2",
        imu_hz=200,
        odom_hz=10,
        landmarks=100,
        bias_walk=5e-4,
    ),
    Case(
        3462,
        "flight",
        90,
        "flight, g100 v30, law (0.05, 0.01)",
        container="bag",
        imu_hz=400,
        odom_hz=10,
        gyro_x=100,
        velocity_x=30,
        law=(0.05, 0.01),
    ),
    Case(3463, "ground", 180, "ground robot, 400/10 Hz, stated 5x", imu_hz=400, odom_hz=10, stated=5.0),
    Case(
        3464, "flight", 90, "flight, camera 90 deg, stamps +0.2 s", imu_hz=400, odom_hz=10, cam_yaw_deg=90, offset_s=0.2
    ),
)
SETS = {"round4": CASES, "round5": ROUND5}


def scenario(case: Case):
    if case.scenario == "flight":
        sc = replace(get_scenario("figure8-wide"), name="flight", trajectory=flight_trajectory())
    elif case.scenario != "handheld":
        sc = get_scenario(case.scenario)
    else:
        sc = handheld(case.tilt_deg, case.wobble)
    if case.cam_yaw_deg:
        turn = rot_z(np.array([np.deg2rad(case.cam_yaw_deg)]))[0]
        sc = replace(sc, camera=replace(sc.camera, R_bc=turn @ sc.camera.R_bc))
    return customize(sc, landmarks=case.landmarks, detection_gaps=case.gaps or None)


def perturb(sim, case: Case):
    """What the simulator does not draw: the gyro bias's random walk, silent streams, jittered stamps (from their
    own generator, so the simulator's draws are those of the plain case)."""
    rng = np.random.default_rng(case.seed + 7)
    imu = sim.imu
    if case.bias_walk:
        dt = np.diff(imu.t_ns, prepend=imu.t_ns[0]) * 1e-9
        walk = np.cumsum(rng.standard_normal((len(dt), 3)) * case.bias_walk * np.sqrt(dt)[:, None], axis=0)
        imu = replace(imu, gyro=imu.gyro + walk)
    streams = {"imu": imu, "odom": sim.odom, "mag": sim.mag}
    for name, lo, hi in case.dropouts:
        d = streams[name]
        t = (d.t_ns - sim.start_ns) * 1e-9
        keep = (t < lo) | (t >= hi)
        streams[name] = replace(d, **{f: getattr(d, f)[keep] for f in d.__dataclass_fields__})
    det = sim.detections
    if case.jitter_s:
        j = lambda n: np.round(rng.uniform(-case.jitter_s, case.jitter_s, n) * 1e9).astype(np.int64)  # noqa: E731
        odom = streams["odom"]
        streams["odom"] = replace(odom, t_ns=odom.t_ns + j(len(odom.t_ns)))
        det = replace(det, t_ns=det.t_ns + j(len(det.t_ns)))
    return replace(sim, detections=det, **streams)


def make_log(case: Case, cache: Path) -> tuple[Path, dict]:
    """The case's log in ``cache`` (written once) and its true noise as a ``noise:`` section."""
    path, truth_path = cache / f"s{case.seed}{SUFFIX[case.container]}", cache / f"s{case.seed}.truth.json"
    if path.exists() and truth_path.is_file():
        return path, json.loads(truth_path.read_text())
    gyro, velocity = case.gyro_x * DEFAULTS["gyro"][0], case.velocity_x * DEFAULTS["velocity"][0]
    nm = replace(
        NoiseModel(),
        gyro=gyro * np.sqrt(case.imu_hz),  # per-sample sigma at the stream's rate
        odom_linear=velocity * np.sqrt(case.odom_hz),
        detection_base=case.law[0],
        detection_per_m=case.law[1],
    )
    kw = dict(duration=case.duration, seed=case.seed, imu_rate=case.imu_hz, odom_rate=case.odom_hz)
    sim = simulate(scenario(case), noise=nm, detection_rate=case.detection_hz, detection_offset=case.offset_s, **kw)
    sim = perturb(sim, case)
    stated = replace(nm, gyro=case.stated * nm.gyro, odom_linear=case.stated * nm.odom_linear)
    write_log(replace(sim, noise=stated), path, container=case.container, overwrite=True)
    if case.truncate:
        with open(path, "r+b") as f:
            f.truncate(int(path.stat().st_size * case.truncate))
    truth = {"gyro": gyro, "velocity": velocity, "detection": case.law[0], "detection_per_m": case.law[1]}
    truth |= {"detection_per_m2": 0.0, "detection_ratio": 1.0}
    truth_path.write_text(json.dumps(truth))
    return path, truth


def run(log: Path, estimator: str, out: Path, noise: dict | None) -> dict:
    cfg: dict = {"evaluation": {"plots": False}, **({"noise": noise} if noise else {})}
    try:
        run_log(log, out, observer=estimator, config=cfg, force=True)
    except Exception as exc:  # an error is a result of the sweep
        return {"error": str(exc)[:120]}
    meta, report = json.loads((out / "run.json").read_text()), json.loads((out / "report.json").read_text())
    shutil.rmtree(out, ignore_errors=True)
    conv, nees = report.get("convergence") or {}, (report.get("uncertainty") or {}).get("position") or {}
    verdict = "lost" if conv.get("lost") else "coarse" if conv.get("coarse") else "no" if conv.get("growing") else None
    velocity = next((n for n in meta.get("notes") or [] if n.startswith("noise: velocity =")), "")
    return {
        "ape": report["ape"]["translation_m"]["rmse"],
        "converged": verdict or ("yes" if conv.get("t_ns") is not None else "no"),
        "nees": f"{nees['mean']:.3g}{' OC' if 'over' in nees.get('verdict', '') else ''}" if "mean" in nees else "-",
        "velocity": velocity.split("[", 1)[-1].split("]", 1)[0] if "[" in velocity else "",
        "warnings": [n for n in meta.get("notes") or [] if n.startswith("warning")],
        "notes": meta.get("notes") or [],
        "status": meta.get("status"),
    }


def row(case: Case, truth: dict, res: dict) -> str:
    ape = lambda k: None if "error" in res[k] else res[k]["ape"]  # noqa: E731
    cell = lambda k: res[k].get("error") or f"{res[k]['ape']:.3f}"  # noqa: E731
    ratio = lambda a, b: "-" if ape(a) is None or b not in res or ape(b) is None else f"{ape(a) / ape(b):.2f}"  # noqa: E731
    fa, rk, bt = ("fast-adaptation", "auto"), ("riekf", "auto"), ("batch", "auto")
    true = lambda e: f" / {cell((e, 'true'))} ({ratio((e, 'auto'), (e, 'true'))})" if (e, "true") in res else ""  # noqa: E731
    ok = [res[k] for k in (fa, rk, bt) if "error" not in res[k]]
    cells = [
        f"seed={case.seed}",
        case.note,
        case.container,
        f"{case.duration:g}",
        f"{case.imu_hz:g}/{case.odom_hz:g}",
        cell(fa),
        cell(rk) + true("riekf"),
        cell(bt) + true("batch"),
        f"{ratio(rk, fa)}, {ratio(bt, fa)}",
        "/".join(res[k].get("converged", "err") for k in (fa, rk, bt)),
        "; ".join(res[k].get("nees", "err") for k in (rk, bt)),
        f"{res[rk].get('velocity', '')} ({truth['velocity']:.4f})",
        str(sum(len(r["warnings"]) for r in ok)),
    ]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-handheld-logs")
    ap.add_argument("--seeds", type=int, nargs="+", help="the cases' seeds (default: all)")
    ap.add_argument("--no-true", action="store_true", help="skip the runs given the true noise")
    ap.add_argument("--set", choices=SETS, default="round4", help="which cases (default: round4, session 32's)")
    ap.add_argument("--notes", type=Path, help="append every run's notes to this JSON-lines file")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    head = "| log | case | container | s | IMU/odom Hz | FA | riekf auto / true (x) | batch auto / true (x) "
    head += "| riekf, batch / FA | converged FA/riekf/batch | NEES riekf; batch | velocity auto (true) | warnings |"
    print(head + "\n|" + " --- |" * (head.count("|") - 1))
    for case in SETS[args.set]:
        if args.seeds and case.seed not in args.seeds:
            continue
        log, truth = make_log(case, args.cache)
        res = {}
        for est in ("fast-adaptation", "riekf", "batch"):
            for mode in ("auto",) if est == "fast-adaptation" or args.no_true else ("auto", "true"):
                out = args.cache / "runs" / f"s{case.seed}-{est}-{mode}"
                res[est, mode] = run(log, est, out, truth if mode == "true" else None)
        print(row(case, truth, res), flush=True)
        if args.notes:
            with args.notes.open("a") as f:
                for (est, mode), r in res.items():
                    f.write(json.dumps({"seed": case.seed, "estimator": est, "mode": mode, **r}) + "\n")


if __name__ == "__main__":
    main()
