"""What a velocity stream a few percent off in scale costs, and what the detection pairs' fit says of it: generated
ground robots, flights, a loop and a hand-held rig (``handheld_logs.Case``, seeds 3940-3947: 60-300 s, 3 landmarks or
the scene's all, a drifting gyro bias and jittered stamps on one), each written with its twist's forward axis or all
its axes times 0.95, 0.98, 1.02, 1.05 and 1.10 beside the log as drawn (the same draws: only the scale differs), run
with ``fast-adaptation``, ``riekf`` and ``batch`` and no noise configuration. Prints a Markdown table.

    .venv/bin/python benchmarks/velocity_scale_logs.py [--cache DIR] [--seeds 3940 3942] [--scales 1 1.05]

Columns: APE and map error (m) per estimator, each over the log as drawn in brackets, the report's mean position
NEES, the pairs' velocity scale on x (``run.json`` ``observer.time_offset.velocity_scale``: with the dilution taken
off, as fitted in brackets, ± its standard error; the detections say the body moved this many times as far as the
velocity says: 1/x expected), the warnings. docs/benchmarks.md, "A velocity a few percent off in scale", session 36.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from slamobs.pipeline.api import run_log

sys.path.insert(0, str(Path(__file__).resolve().parent))
from handheld_logs import R6, Case, make_log  # noqa: E402

ESTIMATORS = ("fast-adaptation", "riekf", "batch")
CASES = (
    Case(3940, "ground", 150, "ground, bias walk, +-10 ms", "ros2", bias_walk=0.001, jitter_s=0.01, **R6),
    Case(3941, "ground", 300, "ground, 3 landmarks", landmarks=3, **R6),
    Case(3942, "flight", 90, "flight", "bag", **R6),
    Case(3943, "flight", 60, "flight, 3 landmarks", landmarks=3, **R6),
    Case(3944, "ground", 60, "ground", **R6),
    Case(3945, "flight", 180, "flight", "ros2", **R6),
    Case(3946, "loop", 120, "loop", **R6),
    Case(3947, "handheld", 90, "hand-held", **R6),
)
SCALES = (1.0, 0.95, 0.98, 1.02, 1.05, 1.1)


def run(log: Path, estimator: str, out: Path) -> dict:
    """One run: APE, map error, mean position NEES, the pairs' velocity scale and the warnings (or its error)."""
    try:
        run_log(log, out, observer=estimator, config={"evaluation": {"plots": False}}, force=True)
    except Exception as exc:  # an error is a result of the sweep
        return {"error": str(exc)[:120]}
    meta = json.loads((out / "run.json").read_text())
    report = json.loads((out / "report.json").read_text()) if (out / "report.json").is_file() else {}
    shutil.rmtree(out, ignore_errors=True)
    nees = ((report.get("uncertainty") or {}).get("position") or {}).get("mean")
    return {
        "ape": ((report.get("ape") or {}).get("translation_m") or {}).get("rmse"),
        "map": (((report.get("landmarks") or {}).get("error_m")) or {}).get("rmse"),
        "nees": nees,
        "scale": ((meta.get("observer") or {}).get("time_offset") or {}).get("velocity_scale"),
        "warnings": [n for n in meta.get("notes") or [] if n.startswith("warning")],
    }


def _ratio(value: float | None, base: float | None, scaled: bool) -> str:
    if value is None:
        return "-"
    return f"{value:.3f}" + (f" ({value / base:.2f})" if scaled and base else "")


def row(case: Case, axes: str, g: float, res: dict, base: dict) -> str:
    """One Markdown row: ``res`` the runs at this scale, ``base`` those of the log as drawn."""
    ok = {e: r for e, r in res.items() if "error" not in r}
    cell = lambda e, k: res[e].get("error") or _ratio(res[e][k], base.get(e, {}).get(k), g != 1.0)  # noqa: E731
    vs = (ok.get("riekf") or {}).get("scale") or {}
    x = (vs.get("scale") or [None])[0]
    fitted = f"{x:.3f} ({vs['fitted'][0]:.3f}) ± {vs['sigma'][0]:.3f}" if x is not None else "-"
    nees = "; ".join(f"{ok[e]['nees']:.2f}" if e in ok and ok[e]["nees"] else "-" for e in ("riekf", "batch"))
    cells = [f"seed={case.seed}", case.note, axes, f"{g:g}"]
    cells += [cell(e, "ape") for e in ESTIMATORS] + [cell(e, "map") for e in ESTIMATORS[1:]]
    cells += [nees, f"{fitted}; {1.0 / g:.3f}", str(sum(len(r["warnings"]) for r in ok.values()))]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-velocity-scale-logs")
    ap.add_argument("--seeds", type=int, nargs="+", help="the cases' seeds (default: all)")
    ap.add_argument("--scales", type=float, nargs="+", default=SCALES, help="the twist's factors (1: as drawn)")
    args = ap.parse_args()
    head = "| log | case | axes | x | FA APE | riekf APE | batch APE | riekf map | batch map | NEES riekf; batch "
    head += "| pairs' scale x (fitted) ± σ; 1/x | warnings |"
    print(head + "\n|" + " --- |" * (head.count("|") - 1))
    for case in CASES:
        if args.seeds and case.seed not in args.seeds:
            continue
        base: dict = {}
        for g in sorted(args.scales, key=lambda v: v != 1.0):  # the log as drawn first: the others' brackets
            for axes, factor in (("x", (g, 1.0, 1.0)), ("all", (g, g, g)))[: 1 if g == 1.0 else 2]:
                cache = args.cache / f"s{case.seed}-{axes}-{g:g}"
                cache.mkdir(parents=True, exist_ok=True)
                log, _ = make_log(replace(case, velocity_scale=factor), cache)
                res = {e: run(log, e, cache / f"run-{e}") for e in ESTIMATORS}
                if g == 1.0:
                    base = {e: r for e, r in res.items() if "error" not in r}
                print(row(case, axes, g, res, base), flush=True)


if __name__ == "__main__":
    main()
