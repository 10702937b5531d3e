"""Do the written maps sit where the written trajectories put them? Per observer and simulated scenario.

    .venv/bin/python benchmarks/map_consistency.py [--seeds 0 1] [--scenarios loop figure8-blind ...]
                                                   [--observers hashim-imu hybrid ...]

Each scenario is simulated (``slamobs simulate``), written as MCAP and run through ``slamobs run`` (report
without plots) with every registered observer. Printed per run, from report.json: landmark map error (median
over the landmarks) after the SE(3) alignment fitted on the trajectory, after an SE(3) alignment fitted on the
map alone, their ratio, and the APE (translation RMSE). A map consistent with its trajectory has the first
close to the second (the property test asks trajectory <= 1.5 x map-only + 5 cm). The last column fits the
trajectory alignment only on the poses of the time span in which landmarks were seen: where it is small but
the first is not, the trajectory drifted after the landmarks left view (dead reckoning), not the map.

Scenarios (simulator names and options):
  loop                 3 min, two laps past 60 landmarks, 50 deg camera
  figure8-blind        90 s figure 8 whose landmarks leave view after 40 s
  figure8-imu-flipped  60 s figure 8, IMU mounted upside down with its own /tf_static entry
  figure8              60 s figure 8 (the sample log's scenario)
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from slamobs.pipeline.config import EvaluationConfig, RunConfig
from slamobs.pipeline.lie import umeyama
from slamobs.pipeline.estimators import ESTIMATORS
from slamobs.pipeline.run import prepare_log, run_prepared
from slamobs.pipeline.simulate import get_scenario, simulation, write_log

SCENARIOS = ("loop", "figure8-blind", "figure8-imu-flipped", "figure8")


def seen_span_error(run: Path, scenario: str, start_ns: int) -> float:
    """Median map error after an SE(3) alignment fitted on the poses between the first and last sighting."""
    poses, lms = pd.read_parquet(run / "poses.parquet"), pd.read_parquet(run / "landmarks.parquet")
    sc = get_scenario(scenario)
    seen = poses[(poses["t_ns"] >= lms["first_seen_ns"].min()) & (poses["t_ns"] <= lms["last_seen_ns"].max())]
    truth = sc.sample((seen["t_ns"].to_numpy() - start_ns) * 1e-9).P
    rot, trans, _ = umeyama(seen[["x", "y", "z"]].to_numpy(), truth)
    true_xyz = sc.landmarks[np.searchsorted(sc.landmark_ids, lms["id"].to_numpy())]
    return float(np.median(np.linalg.norm(lms[["x", "y", "z"]].to_numpy() @ rot.T + trans - true_xyz, axis=1)))


def measure(log: Path, out: Path, observers: list[str], scenario: str, start_ns: int) -> dict[str, dict]:
    rows = {}
    for name in observers:
        cfg = RunConfig(observer=name, evaluation=EvaluationConfig(plots=False))
        prepared = prepare_log(log, cfg, directions=ESTIMATORS[name].min_directions > 0)
        summary = run_prepared(prepared, out / name, cfg, force=True, release=True)
        rep = summary.report
        lm = rep["landmarks"]
        rows[name] = {
            "traj": lm["error_m"]["median"],
            "map": lm["map_aligned"]["error_m"]["median"] if lm["map_aligned"] else float("nan"),
            "ape": rep["ape"]["translation_m"]["rmse"],
            "seen": seen_span_error(out / name, scenario, start_ns),
        }
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--observers", nargs="+", default=list(ESTIMATORS))
    args = ap.parse_args()
    print(
        "| scenario | seed | observer | map err, trajectory alignment [m] | map err, map-only alignment [m] | "
        "ratio | APE rmse [m] | map err, alignment on the poses while landmarks were seen [m] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for scenario in args.scenarios:
            for seed in args.seeds:
                sim = simulation(scenario, seed=seed)
                log = write_log(sim, root / f"{scenario}-{seed}.mcap")
                rows = measure(log, root / f"{scenario}-{seed}", args.observers, scenario, sim.start_ns)
                for name, r in rows.items():
                    print(
                        f"| {scenario} | {seed} | {name} | {r['traj']:.3f} | {r['map']:.3f} | "
                        f"{r['traj'] / r['map']:.1f} | {r['ape']:.3f} | {r['seen']:.3f} |",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
