"""TagSLAM test_22's APE row read two ways, against a truth on an unknown clock (issue 23: riekf against
fast-adaptation). Prints Markdown tables.

    SLAMOBS_REALDATA=... .venv/bin/python benchmarks/tagslam22_clock.py --cache /tmp/rl

Runs fast-adaptation, riekf and batch on tagslam-22 as ``real_logs.py`` builds it (no noise configuration), then
scores each run's poses against TagSLAM's optimised rig trajectory (3.3 Hz, on other stamps than the poses'
4.3 Hz) with one SE(3) fit (Umeyama, no scale) per estimator, two ways: the benchmark's pairing (the truth pose
nearest each pose, kept within 0.08 s: which poses pair changes with a shift of a few hundredths of a second) and
the truth's position interpolated linearly at every pose stamp (between truth poses less than 0.5 s apart). Both
with the poses' stamps moved by a common shift of −0.4 to +0.5 s (the truth's clock is not known: the report's
own search is not reliable on this log), then the interpolated error by stretch (before the longest stretch
without a detection, during it, after it) and the innovations' size in those stretches. Truth only to measure.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_logs as rl  # noqa: E402  (the benchmark's logs)

ESTIMATORS = ("riekf", "fast-adaptation", "batch")
NEAREST_S, TRUTH_GAP_S = 0.08, 0.5
SHIFTS = np.round(np.arange(-0.4, 0.501, 0.05), 2)


def _truth(run_dir: Path, source: str) -> tuple[np.ndarray, np.ndarray]:
    from slamobs.pipeline.evaluation.run_dir import resolve_truth

    stream = resolve_truth(json.loads((run_dir / "run.json").read_text()), source).stream
    return stream.t_ns.astype(np.int64), np.asarray(stream.position)


def _nearest(tt: np.ndarray, tp: np.ndarray, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    i = np.clip(np.searchsorted(tt, ts), 1, len(tt) - 1)
    j = np.where(np.abs(tt[i] - ts) < np.abs(tt[i - 1] - ts), i, i - 1)
    return tp[j], np.abs(tt[j] - ts) <= NEAREST_S * 1e9


def _interpolated(tt: np.ndarray, tp: np.ndarray, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    i = np.clip(np.searchsorted(tt, ts), 1, len(tt) - 1)
    ok = (ts >= tt[0]) & (ts <= tt[-1]) & (tt[i] - tt[i - 1] < TRUTH_GAP_S * 1e9)
    w = ((ts - tt[i - 1]) / (tt[i] - tt[i - 1]))[:, None]
    return (1 - w) * tp[i - 1] + w * tp[i], ok


def _errors(poses: pd.DataFrame, truth: tuple, pairing, shift_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Each paired pose's position error after the SE(3) fit, and the paired poses' mask."""
    from slamobs.pipeline.lie import umeyama

    ts = poses["t_ns"].to_numpy() + int(round(shift_s * 1e9))
    ref, ok = pairing(*truth, ts)
    est, ref = poses[["x", "y", "z"]].to_numpy()[ok], ref[ok]
    rot, trans, _ = umeyama(est, ref)
    return np.linalg.norm(est @ rot.T + trans - ref, axis=1), ok


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")


def _shift_table(poses: dict, truth: tuple) -> None:
    for name, pairing in (("nearest within 0.08 s", _nearest), ("interpolated", _interpolated)):
        print(f"\nAPE m (poses paired) with the poses' stamps moved by the shift; truth {name}\n")
        print("| shift s | " + " | ".join(ESTIMATORS) + " |\n| --- |" + " --- |" * len(ESTIMATORS))
        curves = {e: [] for e in ESTIMATORS}
        for s in SHIFTS:
            cells = []
            for e in ESTIMATORS:
                err, ok = _errors(poses[e], truth, pairing, s)
                curves[e].append(_rms(err))
                cells.append(f"{_rms(err):.3f} ({ok.sum()})")
            print(f"| {s:+.2f} | " + " | ".join(cells) + " |")
        for e in ESTIMATORS:
            c = np.array(curves[e])
            print(f"\n{e}: {c.min():.3f} at {SHIFTS[c.argmin()]:+.2f} s, largest {c.max():.3f}", end="")
        print()


def _stretches(run_dir: Path) -> list[tuple[float, float]]:
    """Log seconds before, during and after the longest stretch without a detection frame."""
    det = np.unique(pd.read_parquet(run_dir / "tag_detections.parquet")["t_ns"].to_numpy())
    t0 = pd.read_parquet(run_dir / "poses.parquet")["t_ns"].iloc[0]
    k = int(np.argmax(np.diff(det)))
    a, b = (det[k] - t0) / 1e9, (det[k + 1] - t0) / 1e9
    return [(-1.0, a), (a, b), (b, 1e9)]


def _stretch_table(poses: dict, truth: tuple, runs: dict[str, Path]) -> None:
    spans = _stretches(runs["riekf"])
    heads = ["to {1:.1f} s", "{0:.1f}-{1:.1f} s (no detection)", "from {0:.1f} s"]
    print("\nAPE m by stretch (interpolated truth, shift 0, one fit over the whole run); innovation |e| median m\n")
    print("| estimator | all | " + " | ".join(h.format(*s) for h, s in zip(heads, spans)) + " | innovations before |")
    print("| --- " * 4 + "| --- | --- |")
    for e in ESTIMATORS:
        err, ok = _errors(poses[e], truth, _interpolated, 0.0)
        t = (poses[e]["t_ns"].to_numpy()[ok] - poses[e]["t_ns"].iloc[0]) / 1e9
        iv = pd.read_parquet(runs[e] / "innovations.parquet")
        ti = (iv["t_ns"].to_numpy() - poses[e]["t_ns"].iloc[0]) / 1e9
        med = [float(np.median(iv["e_norm"][(ti >= a - 0.5) & (ti < b) & (iv["e_norm"] > 0)])) for a, b in spans]
        cells = [f"{_rms(err[(t >= a) & (t < b)]):.3f}" for a, b in spans]
        print(f"| {e} | {_rms(err):.3f} | " + " | ".join(cells) + f" | {med[0]:.3f}, after {med[2]:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-real-logs")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    (log,) = rl.all_logs(args.cache, ["tagslam-22"])
    if log.path is None:
        print(f"tagslam-22: {log.skip}")
        return
    from slamobs.pipeline.api import run_log

    with tempfile.TemporaryDirectory() as tmp:
        runs = {e: Path(tmp) / e for e in ESTIMATORS}
        for e in ESTIMATORS:
            cfg = json.loads(json.dumps(log.config))
            cfg["evaluation"]["plots"] = False
            run_log(log.path, runs[e], observer=e, config=cfg, force=True)
        truth = _truth(runs["riekf"], log.config["topics"]["truth"])
        poses = {e: pd.read_parquet(runs[e] / "poses.parquet") for e in ESTIMATORS}
        _shift_table(poses, truth)
        _stretch_table(poses, truth, runs)


if __name__ == "__main__":
    main()
