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
without a detection, during it, after it) and the innovations' size in those stretches. Then what the truth is:
on which stamps it lies (the camera frames'?) and each detection against it (range and position residual by range,
the frames riekf gated), and riekf's attitude σ along the line through the two tags (the turn about it moves the
camera and leaves both tags where the camera sees them) against its other two axes. Last, where riekf loses
against fast-adaptation: the APE of tracks spliced from the two at a cut (one's poses before it, the other's after),
and riekf's first detection after the stretch updated as riekf does (one linear step) against the same update
iterated to its maximum a posteriori (Gauss-Newton on the pose alone, riekf's written pose covariance as the prior,
its own landmark held). Truth only to measure.
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


def _truth_poses(run_dir: Path, source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from slamobs.pipeline.evaluation.run_dir import resolve_truth
    from slamobs.pipeline.lie import quats_to_rots

    stream = resolve_truth(json.loads((run_dir / "run.json").read_text()), source).stream
    return stream.t_ns.astype(np.int64), np.asarray(stream.position), quats_to_rots(np.asarray(stream.quat_xyzw))


def _detection_table(run_dir: Path, source: str, tag_map: Path) -> None:
    """The truth's stamps against the detection frames' (recorded) ones, and each detection against the truth: the
    tag's map position seen from the truth's pose at the detection's frame (the rig is the camera: identity in
    ``camera_poses.yaml``)."""
    tt, tp, tr = _truth_poses(run_dir, source)
    det = pd.read_parquet(run_dir / "tag_detections.parquet")
    tags = pd.read_csv(tag_map).set_index("id")[["x", "y", "z"]]
    frames = np.unique(det["t_ns"].to_numpy())
    same = np.isin(frames, tt)
    print(
        f"\nThe truth's {len(tt)} stamps: {same.sum()} of the {len(frames)} frames with a detection lie on one exactly"
    )
    j = np.searchsorted(tt, det["t_ns"].to_numpy())
    on = (j < len(tt)) & (tt[np.minimum(j, len(tt) - 1)] == det["t_ns"].to_numpy())
    d, j = det[on], j[on]
    seen = np.einsum("nji,nj->ni", tr[j], tags.loc[d["id"]].to_numpy() - tp[j])  # R^T (tag - p)
    meas = d[["x", "y", "z"]].to_numpy()
    r_true, dr = np.linalg.norm(seen, axis=1), np.linalg.norm(meas, axis=1) - np.linalg.norm(seen, axis=1)
    dpos = np.linalg.norm(meas - seen, axis=1)
    print(
        "\nDetections against the truth on their frame (m): range measured − range seen from the truth; "
        "position residual\n"
    )
    print("| range m | detections | range residual median | range residual RMS | position residual median | p95 |")
    print("| --- | --- | --- | --- | --- | --- |")
    for a, b in ((0, 3.0), (3.0, 3.5), (3.5, 4.0), (4.0, 4.5), (4.5, 9.0)):
        m = (r_true >= a) & (r_true < b)
        if m.any():
            row = (np.median(dr[m]), _rms(dr[m]), np.median(dpos[m]), np.percentile(dpos[m], 95))
            print(
                f"| {a:g}-{b:g} | {m.sum()} | "
                + " | ".join(f"{v:+.3f}" if k == 0 else f"{v:.3f}" for k, v in enumerate(row))
                + " |"
            )
    t0 = tt[0]
    big = np.argsort(dpos)[::-1][:4]
    print(
        "\nlargest residuals: "
        + ", ".join(
            f"tag {int(d['id'].iloc[k])} at {(d['t_ns'].iloc[k] - t0) / 1e9:.2f} s, {r_true[k]:.2f} m: "
            f"range {dr[k]:+.3f}, "
            f"position {dpos[k]:.3f}, ambiguity {d['ambiguity'].iloc[k]:.2f}"
            for k in big
        )
    )


def _tag_line_sigma(run_dir: Path, spans: list[tuple[float, float]]) -> None:
    """riekf's attitude σ (deg, world frame) along the line through its two tags and its other two eigen-σ."""
    poses, lm = pd.read_parquet(run_dir / "poses.parquet"), pd.read_parquet(run_dir / "landmarks.parquet")
    if len(lm) != 2:
        return
    axis = np.diff(lm[["x", "y", "z"]].to_numpy(), axis=0)[0]
    axis /= np.linalg.norm(axis)
    c = ("rx", "ry", "rz")
    cov = np.stack([[poses[f"cov_{min(a, b)}_{max(a, b)}"].to_numpy() for b in c] for a in c], axis=-1).transpose(
        1, 0, 2
    )
    along = np.degrees(np.sqrt(np.einsum("i,nij,j->n", axis, cov, axis)))
    eig = np.degrees(np.sqrt(np.clip(np.linalg.eigvalsh(cov), 0, None)))
    t = (poses["t_ns"].to_numpy() - poses["t_ns"].iloc[0]) / 1e9
    print(
        "\nriekf's attitude σ deg: along the line through its two tags / its two smallest eigen-σ (median by stretch)\n"
    )
    print("| stretch s | along the tags' line | other two |\n| --- | --- | --- |")
    for a, b in spans:
        m = (t >= max(a, 0.5)) & (t < b)
        print(
            f"| {max(a, 0):.1f}-{min(b, t[-1]):.1f} | {np.median(along[m]):.2f} | "
            f"{np.median(eig[m, 0]):.2f}, {np.median(eig[m, 1]):.2f} |"
        )


def _splice_table(poses: dict, truth: tuple, spans: list[tuple[float, float]]) -> None:
    """APE (nearest pairing, shift 0) of riekf's poses before a cut and fast-adaptation's after it, and the other way;
    fast-adaptation's track moved onto riekf's by one fit over the first stretch (both start alike)."""
    from slamobs.pipeline.lie import umeyama

    r, f = poses["riekf"], poses["fast-adaptation"]
    if len(r) != len(f) or (r["t_ns"].to_numpy() != f["t_ns"].to_numpy()).any():
        return
    t = (r["t_ns"].to_numpy() - r["t_ns"].iloc[0]) / 1e9
    er, ef = r[["x", "y", "z"]].to_numpy(), f[["x", "y", "z"]].to_numpy()
    rot, trans, _ = umeyama(ef[t < spans[0][1]], er[t < spans[0][1]])
    ef = ef @ rot.T + trans
    ref, ok = _nearest(*truth, r["t_ns"].to_numpy())

    def ape(est: np.ndarray) -> float:
        rot, trans, _ = umeyama(est[ok], ref[ok])
        return _rms(np.linalg.norm(est[ok] @ rot.T + trans - ref[ok], axis=1))

    print(
        "\nAPE m of spliced tracks (nearest pairing, shift 0): one estimator's poses before the cut, "
        "the other's after\n"
    )
    print("| cut s | riekf, then fast-adaptation | fast-adaptation, then riekf |\n| --- | --- | --- |")
    print(f"| none | {ape(er):.3f} (riekf alone) | {ape(ef):.3f} (fast-adaptation alone) |")
    for cut in (spans[0][1], spans[1][1] - 0.1, spans[1][1] + 2.0, spans[1][1] + 4.5):
        before = (t < cut)[:, None]
        print(f"| {cut:.1f} | {ape(np.where(before, er, ef)):.3f} | {ape(np.where(before, ef, er)):.3f} |")


def _return_update(run_dir: Path, truth: tuple, spans: list[tuple[float, float]]) -> None:
    """riekf's first detection after the longest stretch without one: the pose before it (the last written pose, its
    covariance the prior), the linear update riekf makes (one Gauss-Newton step) and the same iterated to the
    maximum a posteriori; each one's position error against the truth after one fit over the poses before the
    return. The detection's camera axes are turned into the body's by a fit over the first stretch's detections,
    rounded to the axes' signed permutation it is near (the camera is mounted along the body's axes)."""
    from slamobs.pipeline.lie import quats_to_rots, so3_exp, umeyama

    poses = pd.read_parquet(run_dir / "poses.parquet")
    det, lm = pd.read_parquet(run_dir / "tag_detections.parquet"), pd.read_parquet(run_dir / "landmarks.parquet")
    lm = lm.set_index("id")[["x", "y", "z"]]
    rots = quats_to_rots(poses[["qx", "qy", "qz", "qw"]].to_numpy())
    est, t0 = poses[["x", "y", "z"]].to_numpy(), poses["t_ns"].iloc[0]
    t, td = (poses["t_ns"].to_numpy() - t0) / 1e9, (det["t_ns"].to_numpy() - t0) / 1e9
    ref, ok = _nearest(*truth, poses["t_ns"].to_numpy())
    back = ok & (t < spans[1][1])
    fit_r, fit_t, _ = umeyama(est[back], ref[back])
    meta = json.loads((run_dir / "run.json").read_text())["observer"]
    offset = meta["time_offset"]["estimate_s"] if meta.get("time_offset", {}).get("applied") else 0.0
    k_of = [int(np.argmin(np.abs(t - (s + offset)))) for s in td]  # each detection's nearest pose (velocity clock)
    first = td < spans[0][1]
    cam = det[["x", "y", "z"]].to_numpy(float)
    seen = np.stack([rots[k].T @ (lm.loc[i].to_numpy() - est[k]) for k, i in zip(k_of, det["id"])])
    body_cam, _, _ = umeyama(cam[first], seen[first])
    body_cam = np.round(body_cam)  # the camera is mounted along the body's axes (optical: z forward): exact axes
    if not np.allclose(body_cam @ body_cam.T, np.eye(3)) or np.linalg.det(body_cam) < 0:
        print("\nthe camera is not mounted along the body's axes: the return's update is not computed")
        return
    j = int(np.flatnonzero(td >= spans[1][1] - 1e-6)[0])  # spans are on the detections' recorded stamps
    y = body_cam @ cam[j]
    k = int(np.flatnonzero(t <= td[j] + offset)[-1])
    names = ("rx", "ry", "rz", "x", "y", "z")
    prior = np.array(
        [
            [poses[f"cov_{a}_{b}" if names.index(a) <= names.index(b) else f"cov_{b}_{a}"].iloc[k] for b in names]
            for a in names
        ]
    )
    law = meta["filter"]["noise"]
    r = float(np.linalg.norm(y))
    sigma = law["detection"] + law.get("detection_per_m", 0.0) * r + law.get("detection_per_m2", 0.0) * r * r
    landmark = lm.loc[det["id"].iloc[j]].to_numpy()

    def seen_from(x: np.ndarray) -> np.ndarray:
        return (so3_exp(x[:3]) @ rots[k]).T @ (landmark - est[k] - x[3:])

    def step(x: np.ndarray) -> np.ndarray:
        h = np.stack([(seen_from(x + 1e-6 * e) - seen_from(x - 1e-6 * e)) / 2e-6 for e in np.eye(6)], axis=1)
        gain = prior @ h.T @ np.linalg.inv(h @ prior @ h.T + sigma**2 * np.eye(3))
        return gain @ (y - seen_from(x) + h @ x)

    one, it = step(np.zeros(6)), np.zeros(6)
    for _ in range(20):
        it = step(it)
    print(
        f"\nriekf's first detection after the stretch (tag {det['id'].iloc[j]} at {td[j] + offset:.2f} s, {r:.2f} m, "
        f"σ {sigma:.3f} m; prior the pose at {t[k]:.2f} s, attitude σ "
        f"{np.degrees(np.sqrt(np.trace(prior[:3, :3]))):.1f}°, position σ {np.sqrt(np.trace(prior[3:, 3:])):.3f} m)\n"
    )
    print("| pose | turn ° | moved m | detection residual m | position error m |\n| --- | --- | --- | --- | --- |")
    for name, x in (("before (prior)", np.zeros(6)), ("one linear step (riekf's)", one), ("iterated (20 steps)", it)):
        err = np.linalg.norm((est[k] + x[3:]) @ fit_r.T + fit_t - ref[k])
        print(
            f"| {name} | {np.degrees(np.linalg.norm(x[:3])):.1f} | {np.linalg.norm(x[3:]):.3f} | "
            f"{np.linalg.norm(y - seen_from(x)):.3f} | {err:.3f} |"
        )
    err_next = np.linalg.norm(est[k + 1] @ fit_r.T + fit_t - ref[k + 1]) if ok[k + 1] else float("nan")
    print(f"\nriekf's own next pose ({t[k + 1]:.2f} s): position error {err_next:.3f} m")


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
        _detection_table(runs["riekf"], log.config["topics"]["truth"], Path(log.config["evaluation"]["map_truth"]))
        _tag_line_sigma(runs["riekf"], _stretches(runs["riekf"]))
        _splice_table(poses, truth, _stretches(runs["riekf"]))
        _return_update(runs["riekf"], truth, _stretches(runs["riekf"]))


if __name__ == "__main__":
    main()
