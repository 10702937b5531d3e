"""Do the written maps sit where the written trajectories put them? Per observer and simulated scenario.

    .venv/bin/python benchmarks/map_consistency.py [--seeds 0 1] [--scenarios loop figure8-blind ...]
                                                   [--observers hashim-imu hybrid ...]

Each scenario is simulated (``slamobs simulate``), written as MCAP and run through ``slamobs run`` (report
without plots) with every registered observer. Printed per run, from report.json: landmark map error (median
over the landmarks) after the SE(3) alignment fitted on the trajectory, after an SE(3) alignment fitted on the
map alone, their ratio, and the APE (translation RMSE). A map consistent with its trajectory has the first
close to the second (the property test asks trajectory <= 1.5 x map-only + 5 cm).

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

from slamobs.pipeline.config import RunConfig
from slamobs.pipeline.observers import OBSERVERS
from slamobs.pipeline.run import prepare_log, run_prepared
from slamobs.pipeline.simulate import simulation, write_log

SCENARIOS = ("loop", "figure8-blind", "figure8-imu-flipped", "figure8")


def measure(log: Path, out: Path, observers: list[str]) -> dict[str, dict]:
    rows = {}
    for name in observers:
        cfg = RunConfig(observer=name, plots=False)
        prepared = prepare_log(log, cfg, directions=OBSERVERS[name].min_directions > 0)
        summary = run_prepared(prepared, out / name, cfg, force=True, release=True)
        rep = summary.report
        lm = rep["landmarks"]
        rows[name] = {
            "traj": lm["error_m"]["median"],
            "map": lm["map_aligned"]["error_m"]["median"] if lm["map_aligned"] else float("nan"),
            "ape": rep["ape"]["translation_m"]["rmse"],
        }
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--observers", nargs="+", default=list(OBSERVERS))
    args = ap.parse_args()
    print("| scenario | seed | observer | map err, trajectory alignment [m] | map err, map-only alignment [m] | "
          "ratio | APE rmse [m] |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for scenario in args.scenarios:
            for seed in args.seeds:
                log = write_log(simulation(scenario, seed=seed), root / f"{scenario}-{seed}.mcap")
                for name, r in measure(log, root / f"{scenario}-{seed}", args.observers).items():
                    print(f"| {scenario} | {seed} | {name} | {r['traj']:.3f} | {r['map']:.3f} | "
                          f"{r['traj'] / r['map']:.1f} | {r['ape']:.3f} |", flush=True)


if __name__ == "__main__":
    main()
