"""A broad, cheap sweep of generated logs nobody tuned on: every simulator scenario, the three containers, rates
10-400 Hz, gyro and velocity noise up to 300x the defaults, detection noise constant, growing with range and with
range squared, 3 or 200 landmarks, landmarks first seen late, a detection gap, detections ending, a detection time
offset, detections at 3 and 60 Hz. Each log (30 s by default) is run with ``fast-adaptation``, ``riekf`` and
``batch`` and no noise configuration, as ``slamobs run`` does; the velocity and gyro messages state no covariance
(zero), so the levels are estimated from the log, as on most real recordings. Prints a Markdown table and the flags.

    .venv/bin/python benchmarks/unseen_sweep.py [--cache DIR] [--only NAME ...] [--seed N] [--jobs 2]

Columns: APE translation RMSE (m, SE(3)-aligned) per estimator, riekf's and batch's over fast-adaptation's (batch
starts from it: its seed), map error RMSE (m) per estimator, the estimated noise against the simulated truth
(gyro and velocity white-noise densities, the detection law's sigma at 3 m), the warnings. Flags: an error; riekf
over 1.5x fast-adaptation; batch over 1.1x its seed; an estimated level more than 25 % off; a warning on a log
without defects (all of these are). Seeds are written as seed=N in the table.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import tempfile
import time
from dataclasses import dataclass, replace
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from slamobs.pipeline.api import run_log
from slamobs.pipeline.simulate import NoiseModel, simulate, write_log
from slamobs.pipeline.simulate.scenarios import SCENARIOS, customize, get_scenario

ESTIMATORS = ("fast-adaptation", "riekf", "batch")
SUFFIX = {"mcap": ".mcap", "bag": ".bag", "ros2": ""}
#: Range at which the detection law's sigma is compared with the simulated one, m.
AT_RANGE_M = 3.0


@dataclass(frozen=True)
class Case:
    name: str
    scenario: str = "figure8"
    container: str = "mcap"
    rate: float | None = None  # IMU and odometry rate, Hz (default: the simulator's 200 and 50)
    gyro_x: float = 1.0
    velocity_x: float = 1.0
    detection: tuple[float, float, float] = (0.01, 0.002, 0.0)  # S0, K, A of S0 + K r + A r^2
    landmarks: int | None = None
    gaps: tuple[tuple[float, float], ...] | None = None
    first_seen: tuple[tuple[int, float], ...] | None = None
    until: float | None = None
    offset_s: float = 0.0
    detection_rate: float | None = None  # Hz (default: the scenario's)


def cases() -> list[Case]:
    out = [Case(f"{sc}", scenario=sc) for sc in SCENARIOS]
    out += [Case(f"{sc}-{c}", scenario=sc, container=c) for sc in ("figure8", "ground") for c in ("bag", "ros2")]
    out += [Case(f"{sc}-{r:g}Hz", scenario=sc, rate=r) for sc in ("figure8", "ground") for r in (10.0, 25.0, 400.0)]
    for x in (10.0, 100.0, 300.0):
        out += [Case(f"figure8-gyro-x{x:g}", gyro_x=x), Case(f"figure8-velocity-x{x:g}", velocity_x=x)]
        out.append(Case(f"ground-both-x{x:g}", scenario="ground", gyro_x=x, velocity_x=x))
    out += [
        Case("figure8-det-constant", detection=(0.03, 0.0, 0.0)),
        Case("figure8-det-growing", detection=(0.005, 0.02, 0.0)),
        Case("figure8-det-r2", detection=(0.005, 0.0, 0.01)),
        Case("ground-det-r2", scenario="ground", detection=(0.005, 0.0, 0.02)),
        Case("figure8-3-landmarks", landmarks=3),
        Case("ground-3-landmarks", scenario="ground", landmarks=3),
        Case("loop-200-landmarks", scenario="loop", landmarks=200),
        Case("figure8-late", first_seen=((15, 15.0), (22, 20.0))),
        Case("figure8-gap", gaps=((8.0, 18.0),)),
        Case("figure8-until-15s", until=15.0),
        Case("figure8-offset-50ms", offset_s=0.05),
        Case("figure8-detections-3Hz", detection_rate=3.0),
        Case("figure8-detections-60Hz", detection_rate=60.0),
        Case("ground-detections-3Hz", scenario="ground", detection_rate=3.0),
    ]
    return out


def make_log(case: Case, seed: int, duration: float, cache: Path) -> tuple[Path, dict]:
    """The case's log (velocity and gyro covariances written as zero: unknown) and its true noise levels."""
    sc = customize(
        get_scenario(case.scenario),
        landmarks=case.landmarks,
        detections_until=case.until,
        detection_gaps=case.gaps,
        first_seen=case.first_seen,
    )
    nm = NoiseModel()
    s0, k, a = case.detection
    nm = replace(
        nm,
        gyro=nm.gyro * case.gyro_x,
        odom_linear=nm.odom_linear * case.velocity_x,
        detection_base=s0,
        detection_per_m=k,
        detection_per_m2=a,
    )
    rates = dict(imu_rate=case.rate, odom_rate=case.rate) if case.rate else {}
    sim = simulate(
        sc,
        duration=duration,
        seed=seed,
        noise=nm,
        detection_offset=case.offset_s,
        detection_rate=case.detection_rate,
        **rates,
    )
    truth = {
        "gyro": nm.gyro / np.sqrt(case.rate or 200.0),
        "velocity": nm.odom_linear / np.sqrt(case.rate or 50.0),
        "detection": s0 + k * AT_RANGE_M + a * AT_RANGE_M**2,
    }
    path = cache / f"{case.name}-seed{seed}{SUFFIX[case.container]}"
    # generated above: the covariances written are all the noise model still sets
    write_log(replace(sim, noise=replace(nm, gyro=0.0, odom_linear=0.0)), path, case.container, overwrite=True)
    return path, truth


LEVEL = re.compile(r"noise: (\w+) = (\[[^\]]*\]|\S+) ")


def levels(notes: list[str]) -> dict[str, float]:
    """The noise levels a run's notes give (the mean over axes), and the detection law's sigma at AT_RANGE_M."""
    found = {
        m.group(1): float(np.mean([float(v) for v in m.group(2).strip("[]").split(",")]))
        for n in notes
        if (m := LEVEL.match(n))
    }
    law = found.get("detection", 0.0) + found.get("detection_per_m", 0.0) * AT_RANGE_M
    found["detection"] = law + found.get("detection_per_m2", 0.0) * AT_RANGE_M**2
    return found


def run(log: Path, estimator: str, out: Path) -> dict:
    t0 = time.process_time()
    try:
        run_log(log, out, observer=estimator, config={"evaluation": {"plots": False}}, force=True)
    except Exception as exc:  # an error is a result of the sweep
        return {"error": f"{type(exc).__name__}: {str(exc)[:120]}"}
    meta = json.loads((out / "run.json").read_text())
    report = json.loads((out / "report.json").read_text())
    notes = meta.get("notes") or []
    shutil.rmtree(out, ignore_errors=True)
    return {
        "error": None,
        "cpu_s": time.process_time() - t0,
        "ape": report["ape"]["translation_m"]["rmse"],
        "map": ((report.get("landmarks") or {}).get("error_m") or {}).get("rmse", float("nan")),
        "levels": levels(notes),
        "warnings": [n for n in notes if n.startswith("warning")],
    }


def sweep_one(job: tuple[Case, int, float, Path]) -> tuple[Case, dict, dict]:
    case, seed, duration, cache = job
    log, truth = make_log(case, seed, duration, cache)
    res = {e: run(log, e, cache / "runs" / f"{log.stem}-{e}") for e in ESTIMATORS}
    shutil.rmtree(log, ignore_errors=True) if log.is_dir() else log.unlink()
    return case, truth, res


def flags(truth: dict, res: dict) -> list[str]:
    fa, rk, bt = (res[e] for e in ESTIMATORS)
    out = [f"{e}: {r['error']}" for e, r in res.items() if r["error"]]
    if not (fa["error"] or rk["error"]) and rk["ape"] > 1.5 * fa["ape"]:
        out.append(f"riekf {rk['ape'] / fa['ape']:.2f}x fast-adaptation")
    if not (fa["error"] or bt["error"]) and bt["ape"] > 1.1 * fa["ape"]:
        out.append(f"batch {bt['ape'] / fa['ape']:.2f}x its seed")
    if not rk["error"]:
        for key, true in truth.items():
            got = rk["levels"].get(key)
            if got is not None and abs(got / true - 1.0) > 0.25:
                out.append(f"{key} {got:.3g} vs {true:.3g}")
    out += sorted({w.split(":")[2].strip()[:60] for r in res.values() if not r["error"] for w in r["warnings"]})
    return out


def row(case: Case, seed: int, truth: dict, res: dict) -> str:
    ape = lambda r: r["error"] and "error" or f"{r['ape']:.3f}"  # noqa: E731
    fa, rk, bt = (res[e] for e in ESTIMATORS)
    ratio = (
        "" if fa["error"] else " / ".join(f"{r['ape'] / fa['ape']:.2f}" if not r["error"] else "-" for r in (rk, bt))
    )
    maps = " / ".join("-" if r["error"] else f"{r['map']:.3f}" for r in (fa, rk, bt))
    got = rk.get("levels", {})
    noise = " / ".join(f"{got.get(k, float('nan')) / truth[k]:.2f}" for k in ("gyro", "velocity", "detection"))
    cells = [f"{case.name} seed={seed}", " / ".join(ape(r) for r in (fa, rk, bt)), ratio, maps, noise]
    return "| " + " | ".join(cells + ["; ".join(flags(truth, res)) or "-"]) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-unseen-sweep")
    ap.add_argument("--only", nargs="+", help="cases whose name contains one of these")
    ap.add_argument("--seed", type=int, default=2101)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args()
    (args.cache / "runs").mkdir(parents=True, exist_ok=True)
    todo = [c for c in cases() if not args.only or any(s in c.name for s in args.only)]
    head = "| log | APE m: FA / riekf / batch | riekf / batch x FA | map m: FA / riekf / batch"
    print(head + " | estimated / true: gyro / velocity / detection at 3 m | flags |")
    print("|" + " --- |" * 6)
    jobs = [(c, args.seed, args.duration, args.cache) for c in todo]
    with Pool(args.jobs) as pool:
        for case, truth, res in pool.imap(sweep_one, jobs):
            print(row(case, args.seed, truth, res), flush=True)


if __name__ == "__main__":
    main()
