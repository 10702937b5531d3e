"""Every estimator on the real logs with truth or a survey, with no noise configuration, beside the best result of
``riekf`` and ``batch`` over a grid of hand-set noise levels: how far the automatic choice is from the best hand
choice (issue 23). Prints a Markdown table.

    .venv/bin/python benchmarks/real_logs.py [--logs mrclam6,tagslam-11] [--quick] [--estimators riekf,batch]

Logs (``$SLAMOBS_REALDATA``, default ``../shared/realdata``; those absent are skipped):

* ``tagslam-11``, ``-16``, ``-21``, ``-22``: TagSLAM's tests (real AprilTag corners; VIO odometry in 11, 21, 22;
  16 has no velocities and is listed as skipped). Map error against the survey (11: ``tagslam.yaml``) or against
  TagSLAM's own optimised tag positions (21, 22: ``reference.bag``; not independent truth), after a rigid fit
  (22 has two tags, too few for a fit: the error of their distance instead).
* ``mrclam6-rN``, ``mrclam7-rN`` (N = 1..5): UTIAS MR.CLAM robots imported with ``slamobs import mrclam`` into the
  cache; APE against Vicon, map error against the landmark survey.

APE is the report's (SE(3) alignment); a planar log is better measured with translation and yaw only, which the
report gives as ``ape_by_alignment["posyaw"]`` once that alignment exists: the table then uses it (column
``align``). The noise levels of the default run are the ones run.json records (and their source). The grid
scales the default levels of the motion keys (``gyro``, ``velocity``) and of the detection keys (``detection``,
``detection_per_m``) separately; "best" is the lowest APE (map error without trajectory truth).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

REALDATA = Path(os.environ.get("SLAMOBS_REALDATA") or Path(__file__).resolve().parents[2] / "shared" / "realdata")
ESTIMATORS = ("fast-adaptation", "hashim", "hashim-imu", "wang-tayebi", "hybrid", "riekf", "batch")
GRID_ESTIMATORS = ("riekf", "batch")
#: (motion scale, detection scale) of the hand-set noise grid, relative to the defaults.
GRID = [(m, d) for m in (0.1, 0.3, 1, 3, 10, 30, 100) for d in (0.1, 1, 10, 100)]
QUICK_GRID = [(0.1, 1), (1, 1), (10, 1), (100, 1), (10, 10), (100, 100)]
MOTION_KEYS, DETECTION_KEYS = ("gyro", "velocity"), ("detection", "detection_per_m")


@dataclass
class Log:
    name: str
    path: Path | None
    config: dict = field(default_factory=dict)
    skip: str = ""


def _tagslam(test: str, cache: Path) -> Log:
    d = REALDATA / "tagslam_test" / test
    name = f"tagslam-{test[5:]}"
    if not d.is_dir():
        return Log(name, None, skip="not in ../shared")
    tags = {"test_11": {"size": 0.15}, "test_21": {"size": 0.16, "sizes": {i: 0.1 for i in range(100, 109)}}}
    cfg = {
        "cameras": [str(d / f) for f in ("cameras.yaml", "camera_poses.yaml", "tagslam.yaml")],
        "tags": tags.get(test, {"size": 0.42}),
    }
    if test == "test_16":
        return Log(name, d / "tag_detections.bag", cfg, skip="no velocity stream (detections only)")
    survey = d / "tagslam.yaml" if test == "test_11" else _reference_map_csv(d, cache / f"{name}-reference.csv")
    cfg["evaluation"] = {"map_truth": str(survey)}
    return Log(name, d / "tag_detections.bag", cfg)


def _reference_map_csv(d: Path, out: Path) -> Path:
    """TagSLAM's optimised tag positions (reference.bag: map -> tag_N on /tf, last values) as a map CSV."""
    if out.is_file():
        return out
    from slamobs.pipeline.frames import TfBuffer
    from slamobs.pipeline.readers import read_log

    s = read_log(d / "reference.bag", {"tf": "/tf"})
    tf = TfBuffer(s.static_tf, s.tf)
    rows = [
        (int(e.child[4:]), *tf.lookup("map", e.child, e.t_ns[-1:]).trans[0]) for e in s.tf if e.child.startswith("tag_")
    ]
    out.write_text("id,x,y,z\n" + "".join(f"{i},{x:.6f},{y:.6f},{z:.6f}\n" for i, x, y, z in sorted(rows)))
    return out


def _mrclam(dataset: int, robot: int, cache: Path) -> Log:
    name = f"mrclam{dataset}-r{robot}"
    folder = REALDATA / "mrclam" / f"MRCLAM_Dataset{dataset}"
    if not folder.is_dir():
        return Log(name, None, skip="not in ../shared")
    out = cache / f"{name}.mcap"
    if not out.is_file():
        from slamobs.pipeline.importers.mrclam import import_robot, read_dataset

        import_robot(read_dataset(folder), robot, out)
    return Log(name, out)


def all_logs(cache: Path, wanted: list[str] | None) -> list[Log]:
    """The benchmark's logs whose name starts with one of ``wanted`` (all when None), prepared in ``cache``."""
    names = [f"tagslam-{t}" for t in (11, 16, 21, 22)] + [f"mrclam{d}-r{r}" for d in (6, 7) for r in range(1, 6)]
    chosen = [n for n in names if wanted is None or any(n.startswith(w) for w in wanted)]
    logs = []
    for n in chosen:
        if n.startswith("tagslam"):
            logs.append(_tagslam(f"test_{n[8:]}", cache))
        else:
            logs.append(_mrclam(int(n[6]), int(n[-1]), cache))
    return logs


@dataclass
class Result:
    ape: float | None = None
    rot: float | None = None
    align: str = ""
    map_err: float | None = None
    seconds: float = 0.0
    noise: str = ""
    error: str = ""

    @property
    def score(self) -> float:
        value = self.ape if self.ape is not None else self.map_err
        return float("inf") if value is None or self.error else value


def _noise_text(meta: dict) -> str:
    """The levels run.json records: gyro, velocity, detection (+ per metre) and where each came from."""
    observer = meta.get("observer") or {}
    noise = observer.get("noise") or (observer.get("filter") or {}).get("noise")
    if not noise:
        return ""

    def level(key: str) -> str:
        v = noise.get(key)
        v = max(v) if isinstance(v, list) and v else v
        return f"{v:.2g}" if isinstance(v, (int, float)) else "?"

    sources = sorted({str(v) for v in (noise.get("sources") or {}).values()})
    return (
        f"g {level('gyro')}, v {level('velocity')}, d {level('detection')}+{level('detection_per_m')}r "
        f"({'/'.join(sources)})"
    )


def run_one(log: Log, estimator: str, out: Path, noise: dict | None = None) -> Result:
    """One run through the public API; its APE, map error, time and noise levels, or its one-line error."""
    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.errors import SlamobsError, one_line

    cfg = json.loads(json.dumps(log.config))
    cfg.setdefault("evaluation", {})["plots"] = False
    if noise:
        cfg["noise"] = noise
    start = time.perf_counter()
    try:
        run_log(log.path, out, observer=estimator, config=cfg, force=True)
    except (SlamobsError, ValueError) as err:
        return Result(seconds=time.perf_counter() - start, error=one_line(getattr(err, "problem", err))[:90])
    res = Result(seconds=time.perf_counter() - start)
    meta = json.loads((out / "run.json").read_text())
    res.noise = _noise_text(meta)
    report_path = out / "report.json"
    report = json.loads(report_path.read_text()) if report_path.is_file() else {}
    by = report.get("ape_by_alignment") or {}
    ape = by.get("posyaw") or report.get("ape")
    if ape and "translation_m" in ape:
        res.ape, res.rot = ape["translation_m"]["rmse"], ape["rotation_deg"]["rmse"]
        res.align = "posyaw" if "posyaw" in by else ape.get("alignment", {}).get("type", "se3")
    lm = report.get("landmarks") or {}
    if "error_m" in lm:
        res.map_err = lm["error_m"]["rmse"]
    elif meta.get("map_error"):
        res.map_err = meta["map_error"]["error_m"]["rmse"]
    if res.map_err is None and log.config.get("evaluation", {}).get("map_truth", "").endswith(".csv"):
        res.map_err = _pairwise_error(out / "landmarks.parquet", Path(log.config["evaluation"]["map_truth"]))
    shutil.rmtree(out, ignore_errors=True)
    return res


def _pairwise_error(estimated: Path, reference: Path) -> float | None:
    """RMS error of the distances between every two matched landmarks (for maps too small for a rigid fit:
    TagSLAM test 22 has two tags); None when fewer than two match."""
    import numpy as np
    import pandas as pd

    if not estimated.is_file():
        return None
    est = pd.read_parquet(estimated).set_index("id")
    ref = pd.read_csv(reference).set_index("id")
    ids = sorted(set(est.index) & set(ref.index))
    if len(ids) < 2:
        return None
    a, b = (t.loc[ids, ["x", "y", "z"]].to_numpy() for t in (est, ref))
    i, j = np.triu_indices(len(ids), 1)
    diff = np.linalg.norm(a[i] - a[j], axis=1) - np.linalg.norm(b[i] - b[j], axis=1)
    return float(np.sqrt(np.mean(diff**2)))


def grid_noise(motion: float, detection: float) -> dict:
    from slamobs.pipeline.noise import DEFAULTS

    return {
        **{k: DEFAULTS[k][0] * motion for k in MOTION_KEYS},
        **{k: DEFAULTS[k][0] * detection for k in DETECTION_KEYS},
    }


def best_of_grid(log: Log, estimator: str, work: Path, grid: list[tuple[float, float]]) -> tuple[Result, str]:
    """The grid point with the lowest score, and its scales."""
    best, where = Result(error="no grid point ran"), ""
    for m, d in grid:
        r = run_one(log, estimator, work / f"{log.name}-{estimator}-grid", grid_noise(m, d))
        if r.score < best.score:
            best, where = r, f"motion x{m:g}, det x{d:g}"
    return best, where


def _fmt(v: float | None, digits: int = 3) -> str:
    return "" if v is None else f"{v:.{digits}f}"


def row(log: Log, estimator: str, r: Result, best: tuple[Result, str] | None) -> str:
    if r.error:
        cells = ["", "", "", "", f"{r.seconds:.1f}", f"error: {r.error}"]
    else:
        cells = [_fmt(r.ape), _fmt(r.rot, 2), r.align, _fmt(r.map_err), f"{r.seconds:.1f}", r.noise]
    if best is not None:
        b, where = best
        ratio = r.score / b.score if b.score not in (0.0, float("inf")) else float("nan")
        cells += [f"{_fmt(b.ape if b.ape is not None else b.map_err)} ({where})", f"{ratio:.2f}"]
    else:
        cells += ["", ""]
    return f"| {log.name} | {estimator} | " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default=None, help="comma-separated log names or prefixes (mrclam6, tagslam-11, ...)")
    ap.add_argument("--estimators", default=",".join(ESTIMATORS), help="comma-separated estimators")
    ap.add_argument("--quick", action="store_true", help=f"grid of {len(QUICK_GRID)} points instead of {len(GRID)}")
    ap.add_argument("--no-grid", action="store_true", help="only the runs with no noise configuration")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-real-logs")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    wanted = args.logs.split(",") if args.logs else None
    estimators = args.estimators.split(",")
    grid = [] if args.no_grid else (QUICK_GRID if args.quick else GRID)
    print(f"# real logs from {REALDATA}; grid {len(grid)} points (motion x det scales of the default noise)")
    print(
        "| log | estimator | APE m | rot deg | align | map m | time s | noise used (no config) "
        "| best hand-set grid | no-config / best |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for log in all_logs(args.cache, wanted):
        if log.skip:
            print(f"| {log.name} | | | | | | | skipped: {log.skip} | | |", flush=True)
            continue
        for est in estimators:
            r = run_one(log, est, args.cache / "runs" / f"{log.name}-{est}")
            best = best_of_grid(log, est, args.cache / "runs", grid) if est in GRID_ESTIMATORS and grid else None
            print(row(log, est, r, best), flush=True)


if __name__ == "__main__":
    sys.exit(main())
