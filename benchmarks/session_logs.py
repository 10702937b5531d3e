"""fast-adaptation, ``riekf`` and ``batch`` with no configuration on generated logs whose seeds, scenarios and rates
no other benchmark uses (``unseen_logs.py`` and ``stereo_logs.py`` keep theirs), to compare two checkouts: run it
once with each checkout first on ``PYTHONPATH`` (``--json`` per checkout), then ``--compare`` the two files.

    .venv/bin/python benchmarks/session_logs.py --json now.json [--cache DIR]
    .venv/bin/python benchmarks/session_logs.py --compare base.json now.json

The logs (into the cache, once): stereo-like detections (``NoiseModel.stereo_*``, f = 1000 px, baseline 0.5 m) or
the simulator's additive law (isotropic, with an r² term on one), velocity and gyro at 10-400 Hz stating no
covariance, two logs from ``slamobs simulate`` as it writes them (one a rosbag2 directory), one with the IMU mounted
upside down and one in ROS1. The table: APE (m) / rotation error (deg) / median map error (m) of each checkout,
the notes the second run has and the first has not (first-run compile notes left out), and batch's
``detection_inverse_depth`` record.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from stereo_logs import fit_truth  # benchmarks/ is the script's directory

from slamobs.pipeline.api import run_log
from slamobs.pipeline.noise import DEFAULTS
from slamobs.pipeline.simulate import NoiseModel, simulate, write_log

ESTIMATORS = ("fast-adaptation", "riekf", "batch")
# name, scenario, seed, duration s, velocity and gyro Hz, detection Hz, stereo px (0: additive law), gyro and
# velocity densities over the defaults, additive law (b, per m, per m²) or None for the simulator's
SIMULATED = (
    ("circle-s41-100Hz-stereo5", "circle", 41, 90, 100, 15, 5, 50, 4, None),
    ("figure8-s42-200Hz-iso", "figure8", 42, 90, 200, 20, 0, 1, 1, None),
    ("loop-s43-10Hz-stereo7", "loop", 43, 150, 10, 10, 7, 100, 4, None),
    ("ground-s44-400Hz-stereo4", "ground", 44, 100, 400, 12, 4, 50, 4, None),
    ("figure8-wide-s45-50Hz-iso-r2", "figure8-wide", 45, 60, 50, 30, 0, 50, 4, (0.005, 0.0, 0.004)),
    ("ground-s46-30Hz-iso", "ground", 46, 100, 30, 12, 0, 20, 2, None),
)
# name, then `slamobs simulate` arguments
CLI = (
    ("figure8-s47-cli.mcap", ["figure8", "--seed", "47", "--imu-rate", "150", "--odom-rate", "25"]),
    ("loop-s48-ros2", ["loop", "--seed", "48", "--container", "ros2", "--duration", "80"]),
    ("figure8-imu-flipped-s49.mcap", ["figure8-imu-flipped", "--seed", "49", "--duration", "60", "--imu-rate", "120"]),
    ("figure8-blind-s50.bag", ["figure8-blind", "--seed", "50", "--duration", "60"]),
)


def make_logs(cache: Path) -> list[Path]:
    cache.mkdir(parents=True, exist_ok=True)
    logs = []
    for name, sc, seed, dur, rate, det, pixel, gx, vx, law in SIMULATED:
        path = cache / f"{name}.mcap"
        logs.append(path)
        if path.exists():
            continue
        nm = replace(
            NoiseModel(),
            gyro=gx * DEFAULTS["gyro"][0] / np.sqrt(1.0 / rate),
            odom_linear=vx * DEFAULTS["velocity"][0] / np.sqrt(1.0 / rate),
        )
        if pixel:
            nm = replace(nm, stereo_pixel=pixel, stereo_focal=1000.0, stereo_baseline=0.5)
        if law:
            nm = replace(nm, detection_base=law[0], detection_per_m=law[1], detection_per_m2=law[2])
        kw = dict(duration=dur, seed=seed, imu_rate=rate, odom_rate=rate, detection_rate=det)
        sim = simulate(sc, noise=nm, **kw)
        truth = fit_truth(sim.detections, simulate(sc, noise=False, **kw).detections)
        write_log(replace(sim, noise=replace(nm, gyro=0.0, odom_linear=0.0)), path, overwrite=True)
        (cache / f"{name}.truth.json").write_text(json.dumps(truth))
    for name, argv in CLI:
        path = cache / name
        logs.append(path)
        if not path.exists():
            code = "from slamobs.cli.main import entry; entry()"
            subprocess.run([sys.executable, "-c", code, "simulate", *argv, "-o", str(path)], check=True)
    return logs


def run(log: Path, estimator: str, out: Path) -> dict:
    t0 = time.process_time()
    try:
        run_log(log, out, observer=estimator, config={"evaluation": {"plots": False}}, force=True)
    except Exception as exc:  # an error is a result of the sweep
        return {"error": str(exc)[:200], "cpu": time.process_time() - t0}
    meta = json.loads((out / "run.json").read_text())
    rep = json.loads((out / "report.json").read_text())
    obs = meta.get("observer") or {}
    shutil.rmtree(out, ignore_errors=True)
    return {
        "ape": rep["ape"]["translation_m"]["rmse"],
        "rot": rep["ape"]["rotation_deg"]["rmse"],
        "map": ((rep.get("landmarks") or {}).get("error_m") or {}).get("median", float("nan")),
        "notes": [n for n in meta.get("notes") or [] if not n.startswith(("noise:", "first run: compiled"))],
        "inverse_depth": (obs.get("smoother") or {}).get("detection_inverse_depth"),
        "cpu": time.process_time() - t0,
    }


def compare(base: dict, now: dict) -> None:
    print("| log | estimator | base APE / rot / map | now APE / rot / map | notes now has, base not | inverse depth |")
    print("| --- | --- | --- | --- | --- | --- |")
    cell = lambda r: r.get("error") or f"{r['ape']:.4f} / {r['rot']:.2f} / {r['map']:.3f}"  # noqa: E731
    for key in sorted(set(base) & set(now)):
        b, n = base[key], now[key]
        new = [x[:160] for x in n.get("notes", []) if x not in b.get("notes", [])]
        inv = n.get("inverse_depth") or {}
        inv = inv.get("skipped") or (
            "applied, " + f"σ_u {inv['sigma_u']:.3g}, σ_w {inv['sigma_w_per_m']:.3g}/m" if inv else ""
        )
        print(f"| {' | '.join(key.split('|'))} | {cell(b)} | {cell(n)} | {'; '.join(new)} | {inv} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-session-logs")
    ap.add_argument("--json", type=Path, help="write this checkout's results here (resumed if present)")
    ap.add_argument("--compare", type=Path, nargs=2, metavar=("BASE", "NOW"))
    args = ap.parse_args()
    if args.compare:
        compare(*(json.loads(p.read_text()) for p in args.compare))
        return
    res = json.loads(args.json.read_text()) if args.json.is_file() else {}
    for log in make_logs(args.cache):
        for est in ESTIMATORS:
            key = f"{log.name}|{est}"
            if key not in res:
                res[key] = run(log, est, args.cache / "runs" / f"{log.name}-{est}")
                args.json.write_text(json.dumps(res, indent=1))
                print(key, {k: v for k, v in res[key].items() if k != "notes"}, flush=True)


if __name__ == "__main__":
    main()
