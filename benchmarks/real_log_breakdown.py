"""Where batch's error on one real log with trajectory truth comes from, beside chosen points of the hand-set grid
(issue 23: why a grid point beats the run with no noise configuration). Prints Markdown tables.

    SLAMOBS_REALDATA=... .venv/bin/python benchmarks/real_log_breakdown.py --log mrclam7-r4 \
        --points 1:1,0.3:1,0.1:0.3 [--set '{"noise": {"velocity": 0.006}}'] --cache /tmp/rl

Runs ``batch`` with no noise configuration, then at each ``motion:detection`` point (scales of the levels the first
run used, as ``real_logs.py``'s grid sets them) and with each ``--set`` configuration added. For each run: the APE
(translation + yaw alignment, the report's), the APE of the poses within 2 s of a detection frame and of those 10 s
or more from one (the dead-reckoned stretches), the APE in 100 s windows, what batch chose (range/bearing ratio,
the detections' correlated share, the motion levels' scales by the evidence, detections gated) and each
landmark's map error after the trajectory's alignment. Then each landmark's detections against the truth (range
and bearing errors, their means: a constant error per landmark shows there; bearings more than 0.2 rad off count
as mis-associations). Truth only to measure; the logs are ``real_logs.py``'s.
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
import real_logs as rl  # noqa: E402  (the benchmark's logs and grid)

NEAR_S, FAR_S, WINDOW_S, MISASSOCIATED_RAD = 2.0, 10.0, 100.0, 0.2


def _yaw(q: np.ndarray) -> np.ndarray:
    return np.arctan2(2 * (q[:, 3] * q[:, 2] + q[:, 0] * q[:, 1]), 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2))


def _yaw_fit(est: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation about z and translation taking ``est`` onto ``truth`` in the least-squares sense (4-DoF)."""
    a, b = est[:, :2] - est[:, :2].mean(0), truth[:, :2] - truth[:, :2].mean(0)
    h = a.T @ b
    th = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    rot = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    return rot, truth.mean(0) - rot @ est.mean(0)


def breakdown(run: Path, streams) -> dict:
    """The run's errors by time and landmark (module docstring) against the log's truth."""
    tt, tp = streams.truth.t_ns.astype(np.int64), streams.truth.position
    poses = pd.read_parquet(run / "poses.parquet")
    t = poses["t_ns"].to_numpy().astype(np.int64)
    inside = (t >= tt[0]) & (t <= tt[-1])
    t, p = t[inside], poses[["x", "y", "z"]].to_numpy()[inside]
    truth = np.stack([np.interp(t, tt, tp[:, i]) for i in range(3)], 1)
    rot, trans = _yaw_fit(p, truth)
    err = np.linalg.norm(p @ rot.T + trans - truth, axis=1)
    frames = np.unique(streams.detections.t_ns.astype(np.int64))
    j = np.searchsorted(frames, t)
    gap = np.minimum(np.abs(t - frames[np.clip(j - 1, 0, None)]), np.abs(frames[np.clip(j, None, frames.size - 1)] - t))
    gap = gap / 1e9
    window = ((t - t[0]) / 1e9 // WINDOW_S).astype(int)

    def rms(m: np.ndarray) -> float:
        return float(np.sqrt(np.mean(err[m] ** 2))) if m.any() else float("nan")

    lm = pd.read_parquet(run / "landmarks.parquet")
    at = lm[["x", "y", "z"]].to_numpy() @ rot.T + trans
    truth_lm = streams.landmark_truth or {}
    lm_err = {
        int(i): float(np.linalg.norm((at[k] - np.asarray(truth_lm[int(i)]))[:2]))
        for k, i in enumerate(lm["id"])
        if int(i) in truth_lm
    }
    meta = json.loads((run / "run.json").read_text())
    sm = (meta.get("observer") or {}).get("smoother") or {}
    report = json.loads((run / "report.json").read_text())
    ape = (report.get("ape_by_alignment") or {}).get("yaw") or report.get("ape") or {}
    return {
        "ape": (ape.get("translation_m") or {}).get("rmse"),
        "near": rms(gap < NEAR_S),
        "far": rms(gap >= FAR_S),
        "far_share": float(np.mean(gap >= FAR_S)),
        "windows": [rms(window == w) for w in range(window.max() + 1)],
        "ratio": (sm.get("detection_anisotropy") or {}).get("ratio", 1.0),
        "share": (sm.get("detection_correlation") or {}).get("share"),
        "scales": {k: r.get("scale") for k, r in (sm.get("noise_scale") or {}).items() if "scale" in r},
        "gated": ((sm.get("residuals") or {}).get("landmark") or {}).get("gated"),
        "landmarks": lm_err,
    }


def detection_errors(streams) -> pd.DataFrame:
    """Each landmark's detections against the truth (planar range and bearing in the body frame)."""
    tt, tp, tq = streams.truth.t_ns.astype(np.int64), streams.truth.position, streams.truth.quat_xyzw
    d = streams.detections
    t = np.repeat(d.t_ns.astype(np.int64), np.diff(d.offsets))
    q = np.stack([np.interp(t, tt, tq[:, i]) for i in range(4)], 1)
    yaw = _yaw(q / np.linalg.norm(q, axis=1)[:, None])
    pos = np.stack([np.interp(t, tt, tp[:, i]) for i in range(3)], 1)
    truth = streams.landmark_truth or {}
    known = np.array([int(i) in truth for i in d.ids])
    rel = np.array([truth[int(i)] if int(i) in truth else (np.nan,) * 3 for i in d.ids]) - pos
    bx = np.cos(yaw) * rel[:, 0] + np.sin(yaw) * rel[:, 1]
    by = -np.sin(yaw) * rel[:, 0] + np.cos(yaw) * rel[:, 1]
    r_true = np.hypot(bx, by)
    frame = pd.DataFrame(
        {
            "id": d.ids.astype(int),
            "range_m": r_true,
            "range_err": np.hypot(d.xyz[:, 0], d.xyz[:, 1]) - r_true,
            "bearing_err": np.angle(np.exp(1j * (np.arctan2(d.xyz[:, 1], d.xyz[:, 0]) - np.arctan2(by, bx)))),
        }
    )[known]
    return frame.groupby("id").agg(
        n=("range_err", "size"),
        range_m=("range_m", "mean"),
        range_err_mean=("range_err", "mean"),
        range_err_sd=("range_err", "std"),
        bearing_err_mean=("bearing_err", "mean"),
        bearing_err_sd=("bearing_err", "std"),
        misassociated=("bearing_err", lambda e: int(np.sum(np.abs(e) > MISASSOCIATED_RAD))),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", required=True, help="one of real_logs.py's logs with trajectory truth (mrclam7-r4)")
    ap.add_argument("--points", default="", help="motion:detection scales of the auto levels, comma-separated")
    ap.add_argument("--set", action="append", default=[], help="a configuration (JSON) added to a run of its own")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-real-logs")
    args = ap.parse_args()
    from slamobs.pipeline.api import read_log, run_log

    args.cache.mkdir(parents=True, exist_ok=True)
    log = next((g for g in rl.all_logs(args.cache, [args.log]) if g.name == args.log), None)
    if log is None or log.skip:
        sys.exit(f"{args.log}: not available ({log.skip if log else 'no such log'})")
    streams = read_log(log.path)
    if streams.truth is None:
        sys.exit(f"{args.log}: no trajectory truth")
    base = json.loads(json.dumps(log.config))
    base.setdefault("evaluation", {})["plots"] = False
    work = args.cache / "runs" / f"{log.name}-breakdown"
    out = work / "auto"
    run_log(log.path, out, observer="batch", config=base, force=True)
    rows = [("no config", breakdown(out, streams))]
    levels = rl.run_noise(json.loads((out / "run.json").read_text()))
    levels = {k: levels[k] for k in rl.MOTION_KEYS + rl.DETECTION_KEYS if k in levels}
    extra = []
    for point in filter(None, args.points.split(",")):
        m, d = (float(x) for x in point.split(":"))
        extra.append((f"motion x{m:g}, det x{d:g}", base | {"noise": rl.grid_noise(levels, m, d)}))
    for text in args.set:
        cfg = json.loads(json.dumps(base))
        for section, values in json.loads(text).items():
            cfg.setdefault(section, {}).update(values)
        extra.append((text, cfg))
    for k, (name, cfg) in enumerate(extra):
        out = work / f"point-{k}"
        run_log(log.path, out, observer="batch", config=cfg, force=True)
        rows.append((name, breakdown(out, streams)))
    ids = sorted({i for _, r in rows for i in r["landmarks"]})
    print(
        f"# {log.name}: batch, APE m (translation + yaw alignment); poses near (< {NEAR_S:g} s) and far "
        f"(>= {FAR_S:g} s) from a detection frame"
    )
    print("| run | APE | near | far (share) | per 100 s | ratio | corr share | evidence scales | gated |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, r in rows:
        windows = " ".join(f"{w:.2f}" for w in r["windows"])
        print(
            f"| {name} | {r['ape']:.3f} | {r['near']:.3f} | {r['far']:.3f} ({r['far_share']:.2f}) | {windows} | "
            f"{r['ratio']:g} | {r['share']} | {r['scales']} | {r['gated']} |"
        )
    print("\nEach landmark's map error m (after the trajectory's alignment):\n")
    print("| run | " + " | ".join(str(i) for i in ids) + " |")
    print("| --- |" + " --- |" * len(ids))
    for name, r in rows:
        print(f"| {name} | " + " | ".join(f"{r['landmarks'].get(i, float('nan')):.2f}" for i in ids) + " |")
    print("\nEach landmark's detections against the truth (m, rad):\n")
    table = detection_errors(streams)
    print("| landmark | " + " | ".join(table.columns) + " |")
    print("| --- |" + " --- |" * len(table.columns))
    for i, r in table.iterrows():
        print(f"| {i} | " + " | ".join(f"{v:.4g}" for v in r) + " |")


if __name__ == "__main__":
    sys.exit(main())
