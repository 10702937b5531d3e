"""Every estimator on the real logs with truth or a survey, with no noise configuration, beside the best result of
``riekf`` and ``batch`` over a grid of hand-set noise levels: how far the automatic choice is from the best hand
choice (issue 23). Prints a Markdown table.

    .venv/bin/python benchmarks/real_logs.py [--logs mrclam6,tagslam-11] [--quick] [--estimators riekf,batch]

Logs (``$SLAMOBS_REALDATA``, default ``../shared/realdata``; those absent are skipped):

* ``tagslam-11``, ``-16``, ``-21``, ``-22``: TagSLAM's tests (real AprilTag corners; VIO odometry in 11, 21, 22;
  16 has no velocities and is listed as skipped). Map error against the survey (11: ``tagslam.yaml``) or against
  TagSLAM's own optimised tag positions (21, 22: ``reference.bag``; not independent truth), after a rigid fit
  (22 has two tags, too few for a fit: the error of their distance instead; that metric's resolution is the
  standard error of the distance the detections measure directly, frame by frame, and two scores closer than it
  are printed as a tie). 22's APE is against TagSLAM's own optimised rig trajectory (``reference.bag``
  ``/tagslam/odom/body_rig``, paired within 0.08 s): TagSLAM's solution, not independent truth; the run's config
  says it is the rig's (``frames.truth: rig``), and the report carries it to the body, the odometry's frame.
* ``mrclam6-rN``, ``mrclam7-rN`` (N = 1..5): UTIAS MR.CLAM robots imported with ``slamobs import mrclam`` into the
  cache; APE against Vicon, map error against the landmark survey.

APE is after the 4-DoF (translation + yaw) alignment where the report computes it (planar runs such as MR.CLAM's,
and runs with IMU directions: ``ape_by_alignment["yaw"]``), else after SE(3); column ``align`` names it. The
noise levels of the default run are the ones run.json records (and their source). The grid scales the levels the
run with no configuration used (``auto``) for the motion keys (``gyro``, ``velocity``) by ``MOTION_SCALES`` and
for the detection law (``detection``, ``detection_per_m``, ``detection_per_m2``) by ``DETECTION_SCALES``: by
default a coordinate search (the motion scales at the auto detection law, then the detection scales at the best
motion scale: 5 points, the centre being the auto levels themselves), ``--full-grid`` their whole product;
``--motion-keys velocity`` scales the velocity alone (the gyro kept at its auto level).
"Best" is the lowest APE (map error without trajectory truth), the auto run included. ``vs seed`` is batch's
score over its seed's (``fast-adaptation``, the default ``batch.seed``) when that ran too.
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
#: scales of the hand-set noise grid, relative to the levels the run with no configuration used
MOTION_SCALES, DETECTION_SCALES = (0.1, 1.0, 10.0), (0.3, 1.0, 3.0)
MOTION_KEYS, DETECTION_KEYS = ("gyro", "velocity"), ("detection", "detection_per_m", "detection_per_m2")
SEED = "fast-adaptation"


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
    if test == "test_22":  # APE against TagSLAM's own optimised rig trajectory (3.3 Hz on other stamps: 0.08 s pairs)
        cfg["topics"] = {"truth": f"{d / 'reference.bag'}:/tagslam/odom/body_rig"}
        cfg["evaluation"]["t_max_diff"] = 0.08
        # its poses are the rig's (tagslam.yaml's body 'rig'), though its child_frame_id names the odometry's frame
        # (TagSLAM writes odom_frame_id there): the truth's frame stated, the report carries it to the body
        cfg["frames"] = {"truth": "rig"}
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
    levels: dict = field(default_factory=dict)
    error: str = ""
    #: run.json's observer.smoother (batch's record of its solve), {} for the others
    smoother: dict = field(default_factory=dict)
    #: the map score's resolution where it is the pairwise distance error (:func:`_pairwise_resolution`), else None
    resolution: float | None = None

    @property
    def score(self) -> float:
        value = self.ape if self.ape is not None else self.map_err
        return float("inf") if value is None or self.error else value


def run_noise(meta: dict) -> dict:
    """The noise section run.json records (riekf keeps it under ``filter``), or {}.
    Public: benchmarks/real_log_breakdown.py reads a run's levels with it."""
    observer = meta.get("observer") or {}
    return observer.get("noise") or (observer.get("filter") or {}).get("noise") or {}


def _noise_text(noise: dict) -> str:
    """The levels run.json records: gyro, velocity, detection (+ per metre, per metre²) and where each came from."""
    if not noise:
        return ""

    def level(key: str) -> str:
        v = noise.get(key)
        v = max(v) if isinstance(v, list) and v else v
        return f"{v:.2g}" if isinstance(v, (int, float)) else "?"

    sources = sorted({str(v) for v in (noise.get("sources") or {}).values()})
    return (
        f"g {level('gyro')}, v {level('velocity')}, d {level('detection')}+{level('detection_per_m')}r"
        f"+{level('detection_per_m2')}r² "
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
    noise_used = run_noise(meta)
    res.noise = _noise_text(noise_used)
    res.levels = {k: noise_used[k] for k in MOTION_KEYS + DETECTION_KEYS if k in noise_used}
    res.smoother = (meta.get("observer") or {}).get("smoother") or {}
    report_path = out / "report.json"
    report = json.loads(report_path.read_text()) if report_path.is_file() else {}
    by = report.get("ape_by_alignment") or {}
    ape = by.get("yaw") or report.get("ape")
    if ape and "translation_m" in ape:
        res.ape, res.rot = ape["translation_m"]["rmse"], ape["rotation_deg"]["rmse"]
        res.align = "yaw" if "yaw" in by else ape.get("alignment", {}).get("type", "se3")
    lm = report.get("landmarks") or {}
    if "error_m" in lm:
        res.map_err = lm["error_m"]["rmse"]
    elif meta.get("map_error"):
        res.map_err = meta["map_error"]["error_m"]["rmse"]
    # two tags (22): the pairwise distance error, also where its trajectory truth made the report fit the map with
    # the trajectory
    pairwise = log.config.get("evaluation", {}).get("map_truth", "").endswith(".csv")
    if pairwise and (res.map_err is None or "truth" in log.config.get("topics", {})):
        res.map_err = _pairwise_error(out / "landmarks.parquet", Path(log.config["evaluation"]["map_truth"]))
        res.resolution = _pairwise_resolution(out)
    shutil.rmtree(out, ignore_errors=True)
    return res


def run_batch_with(log: Log, key: str, value: str, out: Path) -> tuple[Result, float]:
    """One batch run of ``log`` with ``batch.<key>: value`` added to its configuration: its result and its CPU
    seconds (the noise-choice benchmarks compare settings with it)."""
    log = Log(log.name, log.path, json.loads(json.dumps(log.config)), log.skip)
    log.config.setdefault("batch", {})[key] = value
    c0 = time.process_time()
    res = run_one(log, "batch", out)
    return res, time.process_time() - c0


def score_text(v: float) -> str:
    """A score for a table: blank when there is none (``inf``)."""
    return "" if v == float("inf") else f"{v:.4g}"


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


def _pairwise_resolution(run_dir: Path) -> float | None:
    """The resolution of :func:`_pairwise_error`: the RMS over landmark pairs of the standard error of their
    distance as the detections measure it directly, in the frames that see both (the detection in the world
    frame at the solution, the landmark's estimate less the innovation ``R̂y + P̂``, so that two in one frame are
    ``|y_j − y_i|`` apart whatever the solution). The reference (TagSLAM's own optimisation, from the same
    detections) and every estimate of the distance carry about that much: scores closer than it are a tie. None
    when no pair is seen together in two frames."""
    import numpy as np
    import pandas as pd

    tracks, innov = run_dir / "landmark_tracks.parquet", run_dir / "innovations.parquet"
    if not (tracks.is_file() and innov.is_file()):
        return None
    tr, iv = pd.read_parquet(tracks), pd.read_parquet(innov)
    world = tr[["x", "y", "z"]].to_numpy() - iv[["ex", "ey", "ez"]].to_numpy()
    frames: dict[int, dict[int, np.ndarray]] = {}
    for t, i, w in zip(tr["t_ns"].to_numpy(), tr["id"].to_numpy(), world):
        frames.setdefault(int(t), {})[int(i)] = w
    dist: dict[tuple[int, int], list[float]] = {}
    for seen in frames.values():
        ids = sorted(seen)
        for a in range(len(ids)):
            for b in range(a + 1, len(ids)):
                dist.setdefault((ids[a], ids[b]), []).append(float(np.linalg.norm(seen[ids[a]] - seen[ids[b]])))
    se = [np.std(d, ddof=1) / np.sqrt(len(d)) for d in dist.values() if len(d) >= 2]
    return float(np.sqrt(np.mean(np.square(se)))) if se else None


def grid_noise(levels: dict, motion: float, detection: float, motion_keys: tuple[str, ...] = MOTION_KEYS) -> dict:
    """The auto run's levels, ``motion_keys`` scaled by ``motion`` (the other motion keys kept) and the detection
    law by ``detection``."""

    def scaled(v, f):
        return [x * f for x in v] if isinstance(v, list) else v * f

    def factor(k: str) -> float:
        return detection if k in DETECTION_KEYS else motion if k in motion_keys else 1.0

    return {k: scaled(v, factor(k)) for k, v in levels.items()}


def best_of_grid(
    log: Log, estimator: str, work: Path, auto: Result, full: bool, motion_keys: tuple[str, ...] = MOTION_KEYS
) -> tuple[Result, str]:
    """The lowest-scoring grid point around the auto run's levels (the auto run itself included, as the centre
    when nothing is better), and its scales; a coordinate search unless ``full``; the motion scales apply to
    ``motion_keys``."""
    if not auto.levels:
        return Result(error="the auto run recorded no noise levels"), ""
    tried: dict[tuple[float, float], Result] = {}

    def at(m: float, d: float) -> Result:
        if (m, d) not in tried:
            noise = grid_noise(auto.levels, m, d, motion_keys)
            tried[m, d] = run_one(log, estimator, work / f"{log.name}-{estimator}-grid", noise)
        return tried[m, d]

    points = [(m, d) for m in MOTION_SCALES for d in DETECTION_SCALES] if full else [(m, 1.0) for m in MOTION_SCALES]
    best = min(points, key=lambda p: at(*p).score)
    if not full:
        best = min([(best[0], d) for d in DETECTION_SCALES], key=lambda p: at(*p).score)
    best = min([best, "auto"], key=lambda p: auto.score if p == "auto" else tried[p].score)
    if best == "auto":
        return auto, "auto"
    moved = "motion" if set(motion_keys) == set(MOTION_KEYS) else "+".join(motion_keys)
    return tried[best], f"{moved} x{best[0]:g}, det x{best[1]:g}"


def _fmt(v: float | None, digits: int = 3) -> str:
    """``digits`` decimals, or two significant digits for a value that would print as 0.00… (test 22's mm)."""
    if v is None:
        return ""
    return f"{v:.2g}" if 0 < abs(v) < 10.0 ** (1 - digits) else f"{v:.{digits}f}"


def _tie(r: Result, b: Result) -> str:
    """The mark of a tie, when the two scores differ by less than their metric's resolution (else empty)."""
    res = max((x.resolution for x in (r, b) if x.resolution is not None), default=None)
    if res is None or b.score in (r.score, float("inf")) or abs(r.score - b.score) >= res:
        return ""
    return f" (a tie: Δ {_fmt(abs(r.score - b.score))} m < resolution {_fmt(res)} m)"


def row(log: Log, estimator: str, r: Result, best: tuple[Result, str] | None, seed: Result | None) -> str:
    if r.error:
        cells = ["", "", "", "", f"{r.seconds:.1f}", f"error: {r.error}"]
    else:
        cells = [_fmt(r.ape), _fmt(r.rot, 2), r.align, _fmt(r.map_err), f"{r.seconds:.1f}", r.noise]
    if best is not None:
        b, where = best
        ratio = r.score / b.score if b.score not in (0.0, float("inf")) else float("nan")
        cells += [f"{_fmt(b.ape if b.ape is not None else b.map_err)} ({where})", f"{ratio:.2f}{_tie(r, b)}"]
    else:
        cells += ["", ""]
    cells.append(f"{r.score / seed.score:.2f}" if seed is not None and 0.0 < seed.score < float("inf") else "")
    return f"| {log.name} | {estimator} | " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default=None, help="comma-separated log names or prefixes (mrclam6, tagslam-11, ...)")
    ap.add_argument("--estimators", default=",".join(ESTIMATORS), help="comma-separated estimators")
    ap.add_argument("--full-grid", action="store_true", help="every motion x detection scale, not a coordinate search")
    ap.add_argument("--no-grid", action="store_true", help="only the runs with no noise configuration")
    ap.add_argument(
        "--motion-keys", default=",".join(MOTION_KEYS), help="the motion keys the grid scales (e.g. velocity alone)"
    )
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-real-logs")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    wanted = args.logs.split(",") if args.logs else None
    estimators = args.estimators.split(",")
    search = "none" if args.no_grid else "full" if args.full_grid else "coordinate search"
    print(
        f"# real logs from {REALDATA}; grid ({search}): {args.motion_keys} x {MOTION_SCALES}, detection law x "
        f"{DETECTION_SCALES} of the auto levels"
    )
    print(
        "| log | estimator | APE m | rot deg | align | map m | time s | noise used (no config) "
        "| best hand-set grid | no-config / best | vs seed |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for log in all_logs(args.cache, wanted):
        if log.skip:
            print(f"| {log.name} | | | | | | | skipped: {log.skip} | | | |", flush=True)
            continue
        done: dict[str, Result] = {}
        for est in estimators:
            r = done[est] = run_one(log, est, args.cache / "runs" / f"{log.name}-{est}")
            grid = est in GRID_ESTIMATORS and not args.no_grid
            keys = tuple(args.motion_keys.split(","))
            best = best_of_grid(log, est, args.cache / "runs", r, args.full_grid, keys) if grid else None
            print(row(log, est, r, best, done.get(SEED) if est == "batch" else None), flush=True)


if __name__ == "__main__":
    sys.exit(main())
