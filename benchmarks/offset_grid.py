"""riekf and batch with the detection time offset forced to each of a grid, on real logs and a generated figure 8.

Issue 23: which detection time offset do the estimators want, beside what the search
(``pipeline/observers/time_offset.py``) estimates? ``time_offset.estimate`` is replaced in-process by one that
returns the search's own record with ``estimate_s`` set to the grid's offset and ``applied`` true (a 0.0 offset
moves nothing); ``none`` in ``--grid`` is the search as it is. The search's estimate is printed once per log. Real
logs through ``real_logs.py``'s ``all_logs`` / ``run_one`` (``SLAMOBS_REALDATA``), generated ones through
``unseen_sweep.py``'s ``make_log`` / ``run`` (``--generated``: odometry and IMU rates in Hz, a figure 8 each).
Prints one row per log and estimator: APE / map error (m) at each offset. Accuracy only, no timings.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import real_logs  # noqa: E402
import unseen_sweep  # noqa: E402

from slamobs.pipeline.observers import time_offset  # noqa: E402

SEARCH = time_offset.estimate
#: the log being run, the offset forced (None: the search's own) and each log's search record
STATE: dict = {"log": None, "forced": None, "found": {}}


def forced(stream, bias=None, decided=None) -> dict:
    """``time_offset.estimate``'s record with the offset forced to ``STATE["forced"]`` (the search run once a log)."""
    found = STATE["found"]
    if STATE["log"] not in found:
        found[STATE["log"]] = SEARCH(stream, bias)
    out = dict(found[STATE["log"]])
    if STATE["forced"] is not None:
        out.pop("why_not_applied", None)
        out.update({"estimate_s": float(STATE["forced"]), "applied": True})
    if decided is not None:
        decided({"applied": out["applied"], "estimate_s": out["estimate_s"]})
    return out


def search_text(rec: dict) -> str:
    why = rec.get("why_not_applied")
    return f"{rec.get('estimate_s')} s, " + ("applied" if rec.get("applied") else f"not applied ({why})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default="", help="real logs whose name starts with one of these (comma-separated)")
    ap.add_argument("--generated", default="", help="generated figure 8s at these rates, Hz (comma-separated)")
    ap.add_argument("--seed", type=int, default=2101)
    ap.add_argument("--estimators", default="riekf,batch")
    ap.add_argument("--grid", default="none,-0.6,-0.5,-0.4,-0.3,-0.2,-0.1,0.0,0.1")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-offset-grid")
    args = ap.parse_args()
    grid = [None if g == "none" else float(g) for g in args.grid.split(",")]
    (args.cache / "runs").mkdir(parents=True, exist_ok=True)
    time_offset.estimate = forced
    print("| log | estimator | " + " | ".join("search" if g is None else f"{g:+.3f} s" for g in grid) + " |")
    print("|" + " --- |" * (len(grid) + 2))
    runs = []
    for log in real_logs.all_logs(args.cache, args.logs.split(",")) if args.logs else []:
        if log.path is not None and not log.skip:
            runs.append((log.name, lambda e, out, log=log: _real(log, e, out)))
    for rate in (float(r) for r in args.generated.split(",") if r):
        case = unseen_sweep.Case(f"figure8-{rate:g}Hz", rate=rate)
        path, _ = unseen_sweep.make_log(case, args.seed, 30.0, args.cache)
        runs.append((f"{case.name} seed={args.seed}", lambda e, out, path=path: _generated(path, e, out)))
    for name, run in runs:
        for estimator in args.estimators.split(","):
            cells = []
            for g in grid:
                STATE["log"], STATE["forced"] = name, g
                ape, map_err = run(estimator, args.cache / "runs" / f"{estimator}")
                cells.append(f"{_fmt(ape)} / {_fmt(map_err)}")
            print(f"| {name} | {estimator} | " + " | ".join(cells) + " |", flush=True)
        print(f"search on {name}: {search_text(STATE['found'][name])}", flush=True)


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.3f}" if v >= 0.01 else f"{v:.2g}"


def _real(log, estimator: str, out: Path) -> tuple:
    r = real_logs.run_one(log, estimator, out)
    return r.ape, r.map_err


def _generated(path: Path, estimator: str, out: Path) -> tuple:
    r = unseen_sweep.run(path, estimator, out)
    return r.get("ape"), r.get("map")


if __name__ == "__main__":
    main()
