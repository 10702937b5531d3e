"""What Vicon truth says about MR.CLAM's noise, beside what ``noise: auto`` estimates without it (issue 23): a
measuring tool for the held-stream fit, never an input to it. Prints two Markdown tables.

    .venv/bin/python benchmarks/mrclam_truth_noise.py [--logs mrclam6,mrclam7-r3] [--cache DIR]

Per robot (imported into the cache as ``benchmarks/real_logs.py`` does):

* motion: the commanded yaw rate and speed integrated over windows of T s against Vicon's heading change and
  path length along the heading, as a white-noise density (RMS error / sqrt(T), with the robust 1.4826 MAD in
  brackets); a density that grows with T is an error correlated in time (a bias). Beside it the levels
  ``noise: auto`` estimates from the detections (``pipeline.noise.estimate_log_noise``).
* detections: each detection against the truth (robot pose from Vicon, landmark from the survey) as range and
  bearing errors: their whole spread, the spread of the per-landmark means, and the variance of the difference
  of two detections of one landmark ``lag`` s apart over two (the structure function: flat for a white error,
  reaching the whole variance for one that decorrelates within the lag).
* ``--speed``: a third table, what the commanded speed's error is made of: the speed density over the same windows
  raw, after one scale, lag and bias fitted to Vicon over 2 s windows (a constant scale, a lag and a bias are what
  a calibration would remove), and after an oracle scale or bias per segment of 60, 30 or 15 s (what a slowly
  varying scale or velocity-bias state could at best absorb).
* ``--shared``: a fourth table, whether the detections' error is shared by the landmarks seen together: the
  correlation of two different landmarks' range (bearing) errors in one frame, per-landmark means removed and
  mis-associations (bearing error above ``MISASSOCIATED_RAD``) left out, beside one landmark's own at 0.5-1.5 s;
  then the detections' stamp offset that best explains the bearing error by Vicon's yaw rate (``e = −ω·δ``), the
  share of its variance that explains, and the same-frame bearing correlation left after it.
* ``--law``: a fifth table, the detection law ``noise: auto`` gives riekf beside the truth's, per range bin
  (:data:`LAW_BINS_M`): each detection's error against the truth as a vector in the body frame, in the law's
  convention (``|d|²/3`` per axis, as the triplets' three components), its RMS within 4 σ of the bin's robust scale
  and that over the robust scale (a heavy tail within the range is over 1), against the law's σ at the bin's median
  range (docs/noise.md, "Wild detections"). With it, every table's levels are estimated as a run estimates them
  (the velocity density from the samples as recorded, not as aligned).
* ``--ratio``: a sixth table, the range's error against the error across the line of sight (bearing error times the
  detection's range), mis-associations left out as in ``--shared``: their RMS and ratio, beside the ratio ``noise:
  auto`` gives riekf (``detection_ratio``, 1 where kept at 1), and the correlation of two detections of one landmark
  at most ``MAX_TRIPLET_S`` apart (per-landmark means kept), along and across: the share of each error a triplet's
  second difference cancels (docs/benchmarks.md, "riekf's range-against-bearing ratio on MR.CLAM from the log
  alone").
* ``--offset``: a seventh table, the detections' offset against the commands by the truth, beside the one the
  detection pairs find (``time_offset.decide``, no truth): the lag of the commands behind Vicon's motion (the turn
  and the distance along the heading over :data:`OFFSET_WINDOW_S` windows, one scale fitted, on a
  :data:`OFFSET_STEP_S` grid), the lag of the detections' stamps behind Vicon's pose (the bearings, per-landmark means
  removed, mis-associations out, the best 90 %), and the offset they make together (detection lag minus the turn's
  lag: what to add to the detection stamps to put them on the commands' clock, the search's sign), over the whole
  log and over each half (split at the detections' median time) (docs/benchmarks.md, "The detection offsets the
  halves hold back, on MR.CLAM's truth").
* ``--visits``: an eighth table, what a static landmark's detections look like over a log (docs/benchmarks.md,
  "What makes MR.CLAM 7 r3's landmark 20 look moved"): each landmark's visits (its detections no more than
  :data:`VISIT_GAP_S` apart; those of :data:`MIN_VISIT` or more), the robust spread of the range error within a
  visit, the spread of the visits' median range errors (the spread within divided by the root of each visit's
  count would be all of it if the error were white) and the largest, the same across the line of sight (bearing
  error times range); then the mis-associations (bearing error above ``MISASSOCIATED_RAD``), at seconds from the
  robot's first detection (the clock of batch's ``landmark_moves`` record): where each puts its landmark, the
  surveyed landmark or the other robot (of the logs given) nearest that place.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_logs import all_logs  # noqa: E402

WINDOWS_S = (0.5, 2.0, 8.0, 32.0)
LAGS_S = (0.5, 2.0, 8.0, 32.0)
#: The commands' lags tried (s) and the segments (s) of the oracle scale and bias of ``--speed``.
SPEED_LAGS_S = tuple(np.round(np.arange(0.0, 0.61, 0.05), 2))
SPEED_SEGMENTS_S = (60.0, 30.0, 15.0)
#: ``--shared``: a bearing error above this (rad) is a mis-association, left out; two detections less than
#: ``SAME_FRAME_S`` apart are one frame's.
MISASSOCIATED_RAD, SAME_FRAME_S = 0.1, 0.05
#: ``--law``: the range bins (m) the truth's detection error and the law are compared in.
LAW_BINS_M = (0.0, 1.5, 2.5, 3.5, 5.0)
#: ``--offset``: the lags tried (s, a grid refined by a parabola through the best three) and the windows (s) the
#: commands' increments are compared with Vicon's over.
OFFSET_STEP_S = 0.005
OFFSET_LAGS_S = np.round(np.arange(-0.6, 0.8 + OFFSET_STEP_S / 2, OFFSET_STEP_S), 4)
OFFSET_WINDOW_S = 1.0
#: ``--visits``: detections of one landmark no more than this far apart (s) are one visit; visits of fewer than
#: ``MIN_VISIT`` detections are left out of the spreads.
VISIT_GAP_S, MIN_VISIT = 2.0, 5


def _robust(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def _truth_yaw(streams, t: np.ndarray, t0_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Vicon's (unwrapped) yaw and planar position interpolated at ``t`` (s from ``t0_ns``)."""
    tr = streams.truth
    tt = (tr.t_ns - t0_ns) * 1e-9
    q = tr.quat_xyzw
    yaw = np.unwrap(2 * np.arctan2(q[:, 2], q[:, 3]))
    pos = np.stack([np.interp(t, tt, tr.position[:, k]) for k in range(2)], axis=1)
    return np.interp(t, tt, yaw), pos


def motion_cells(streams, aligned) -> list[str]:
    """Per window: the gyro and speed densities the commands' errors against Vicon amount to."""
    t0 = aligned.t0_ns
    tt = (streams.truth.t_ns - t0) * 1e-9
    vt = (aligned.vel_t_ns - t0) * 1e-9
    yaw, pos = _truth_yaw(streams, tt, t0)
    heading = 0.5 * (yaw[1:] + yaw[:-1])
    step = np.diff(pos, axis=0)
    path = np.r_[0.0, np.cumsum(step[:, 0] * np.cos(heading) + step[:, 1] * np.sin(heading))]
    h = np.diff(vt)
    cmd_yaw = np.r_[0.0, np.cumsum(aligned.omega[:-1, 2] * h)]
    cmd_path = np.r_[0.0, np.cumsum(aligned.velocity[:-1, 0] * h)]
    lo, hi = max(vt[0], tt[0]), min(vt[-1], tt[-1])
    cells = []
    for w in WINDOWS_S:
        start = np.arange(lo, hi - w, w / 2)

        def change(t, c, start=start, w=w):
            return np.interp(start + w, t, c) - np.interp(start, t, c)

        for err in (change(vt, cmd_yaw) - change(tt, yaw), change(vt, cmd_path) - change(tt, path)):
            cells.append(f"{np.sqrt(np.mean(err**2) / w):.3f} ({_robust(err) / np.sqrt(w):.3f})")
    return cells


def _truth_path(streams, t0_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Vicon's stamps (s from ``t0_ns``) and its path length along the heading there."""
    tt = (streams.truth.t_ns - t0_ns) * 1e-9
    yaw, pos = _truth_yaw(streams, tt, t0_ns)
    heading = 0.5 * (yaw[1:] + yaw[:-1])
    step = np.diff(pos, axis=0)
    return tt, np.r_[0.0, np.cumsum(step[:, 0] * np.cos(heading) + step[:, 1] * np.sin(heading))]


def _densities(vt: np.ndarray, speed: np.ndarray, tt: np.ndarray, path: np.ndarray, lo: float, hi: float) -> list:
    """The error of ``speed`` (on stamps ``vt``) integrated over each of :data:`WINDOWS_S` against Vicon's path,
    as a white-noise density (RMS / sqrt(T), m/sqrt(s))."""
    cmd = np.r_[0.0, np.cumsum(speed[:-1] * np.diff(vt))]
    out = []
    for w in WINDOWS_S:
        s = np.arange(lo, hi - w, w / 2)
        err = np.interp(s + w, vt, cmd) - np.interp(s, vt, cmd) - (np.interp(s + w, tt, path) - np.interp(s, tt, path))
        out.append(float(np.sqrt(np.mean(err**2) / w)))
    return out


def _calibration(vt, v, tt, path, lo, hi) -> tuple[float, float, float]:
    """The lag (s, of :data:`SPEED_LAGS_S`), scale and bias (m/s) that best map the commanded speed onto Vicon's
    over 2 s windows (least squares)."""
    start = np.arange(lo, hi - 2.0, 1.0)
    truth = np.interp(start + 2.0, tt, path) - np.interp(start, tt, path)
    cmd = np.r_[0.0, np.cumsum(v[:-1] * np.diff(vt))]
    best = None
    for lag in SPEED_LAGS_S:
        a = np.interp(start + 2.0 - lag, vt, cmd) - np.interp(start - lag, vt, cmd)
        design = np.stack([a, np.full_like(a, 2.0)], axis=1)
        (k, b), *_ = np.linalg.lstsq(design, truth, rcond=None)
        rms = float(np.sqrt(np.mean((design @ (k, b) - truth) ** 2)))
        if best is None or rms < best[0]:
            best = (rms, float(lag), float(k), float(b))
    return best[1:]


def _per_segment(vt, v, v_true, lo, hi, seg_s: float, kind: str) -> np.ndarray:
    """The commanded speed with Vicon's least-squares scale (``kind`` "scale") or its mean error while moving
    ("bias") put in per segment of ``seg_s``: an oracle, what a state varying at that pace could absorb."""
    out = v.copy()
    for a in np.arange(lo, hi, seg_s):
        m = (vt >= a) & (vt < min(a + seg_s, hi))
        if kind == "scale" and np.sum(v[m] ** 2) > 1e-9:
            out[m] = v[m] * np.sum(v[m] * v_true[m]) / np.sum(v[m] ** 2)
        elif kind == "bias" and (moving := m & (np.abs(v) > 1e-9)).any():
            out[moving] = v[moving] + np.mean(v_true[moving] - v[moving])
    return out


def speed_rows(name: str, streams, aligned) -> list[str]:
    """``--speed``'s rows of one robot (module docstring)."""
    tt, path = _truth_path(streams, aligned.t0_ns)
    vt = (aligned.vel_t_ns - aligned.t0_ns) * 1e-9
    v = aligned.velocity[:, 0]
    lo, hi = max(vt[0], tt[0]) + 1.0, min(vt[-1], tt[-1]) - 1.0
    lag, k, b = _calibration(vt, v, tt, path, lo, hi)
    rows = [("raw commands", _densities(vt, v, tt, path, lo, hi))]
    rows.append(
        (f"scale {k:.3f}, lag {lag:.2f} s, bias {b:+.4f} m/s", _densities(vt + lag, k * v + b, tt, path, lo, hi))
    )
    vt = vt + lag
    v_true = (np.interp(vt + 0.1, tt, path) - np.interp(vt - 0.1, tt, path)) / 0.2
    for seg in SPEED_SEGMENTS_S:
        for kind in ("scale", "bias"):
            speed = _per_segment(vt, v, v_true, lo, hi, seg, kind)
            rows.append((f"lag, oracle {kind} per {seg:g} s", _densities(vt, speed, tt, path, lo, hi)))
    return [f"| {name} | {label} | " + " | ".join(f"{d:.4f}" for d in dens) + " |" for label, dens in rows]


def detection_errors(streams, aligned) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Range and bearing errors of every detection against the truth, with its time (s) and landmark index."""
    t = np.repeat((aligned.det_t_ns - aligned.t0_ns) * 1e-9, np.diff(aligned.det_offsets))
    yaw, pos = _truth_yaw(streams, t, aligned.t0_ns)
    ids = aligned.landmark_ids
    lm = np.array([streams.landmark_truth[int(ids[i])][:2] for i in aligned.det_idx]) - pos
    c, s = np.cos(yaw), np.sin(yaw)
    true = np.stack([c * lm[:, 0] + s * lm[:, 1], -s * lm[:, 0] + c * lm[:, 1]], axis=1)
    y = aligned.det_y[:, :2]
    d_range = np.linalg.norm(y, axis=1) - np.linalg.norm(true, axis=1)
    d_bearing = (np.arctan2(y[:, 1], y[:, 0]) - np.arctan2(true[:, 1], true[:, 0]) + np.pi) % (2 * np.pi) - np.pi
    return d_range, d_bearing, t, aligned.det_idx


def detection_cells(streams, aligned) -> list[str]:
    from slamobs.pipeline.noise_estimation import pair_indices

    dr, db, t, lm = detection_errors(streams, aligned)
    means = [(dr[lm == i].mean(), db[lm == i].mean()) for i in np.unique(lm) if np.count_nonzero(lm == i) > 5]
    cells = [
        f"{dr.std():.3f} / {db.std():.4f}",
        f"{np.std([m[0] for m in means]):.3f} / {np.std([m[1] for m in means]):.4f}",
    ]
    for lag in LAGS_S:
        a, b = pair_indices(t, lm, np.zeros(t.size, int), (lag,))
        cells.append(
            f"{np.sqrt(np.mean((dr[b] - dr[a]) ** 2) / 2):.3f} / {np.sqrt(np.mean((db[b] - db[a]) ** 2) / 2):.4f}"
        )
    return cells


def _pairs(t: np.ndarray, lm: np.ndarray) -> tuple[np.ndarray, ...]:
    """Indices of detection pairs (sorted by time ``t``): two different landmarks in one frame, and one landmark
    0.5-1.5 s apart."""
    a, b, c, d = [], [], [], []
    for k in range(t.size):
        j = k + 1
        while j < t.size and t[j] - t[k] < 1.5:
            if lm[j] != lm[k] and t[j] - t[k] < SAME_FRAME_S:
                a.append(k), b.append(j)
            elif lm[j] == lm[k] and t[j] - t[k] >= 0.5:
                c.append(k), d.append(j)
            j += 1
    return tuple(np.array(x, np.int64) for x in (a, b, c, d))


def shared_cells(streams, aligned) -> list[str]:
    """The ``--shared`` table's cells for one robot (module docstring)."""

    def corr(x: np.ndarray, i: np.ndarray, j: np.ndarray) -> float:
        return float(np.sum(x[i] * x[j]) / np.sqrt(np.sum(x[i] ** 2) * np.sum(x[j] ** 2)))

    dr, db, t, lm = detection_errors(streams, aligned)
    ok = np.abs(db) < MISASSOCIATED_RAD
    dr, db, t, lm = dr[ok], db[ok], t[ok], lm[ok]
    for i in np.unique(lm):
        dr[lm == i] -= dr[lm == i].mean()
        db[lm == i] -= db[lm == i].mean()
    order = np.argsort(t, kind="stable")
    dr, db, t, lm = dr[order], db[order], t[order], lm[order]
    a, b, c, d = _pairs(t, lm)
    yaw1, _ = _truth_yaw(streams, t + 0.05, aligned.t0_ns)
    yaw0, _ = _truth_yaw(streams, t - 0.05, aligned.t0_ns)
    rate = (yaw1 - yaw0) / 0.1
    delta = -float(np.sum(rate * db) / np.sum(rate * rate))
    left = db + rate * delta
    return [
        f"{a.size}",
        f"{corr(dr, a, b):.2f} / {corr(db, a, b):.2f}",
        f"{corr(dr, c, d):.2f} / {corr(db, c, d):.2f}",
        f"{delta:+.3f} s, {1 - np.var(left) / np.var(db):.2f}",
        f"{corr(left, a, b):.2f}",
    ]


def law_cells(streams, aligned, law) -> list[str]:
    """The ``--law`` table's cells for one robot (module docstring): per bin, truth / law σ (m) and the truth's
    RMS over its robust scale."""
    t = np.repeat((aligned.det_t_ns - aligned.t0_ns) * 1e-9, np.diff(aligned.det_offsets))
    yaw, pos = _truth_yaw(streams, t, aligned.t0_ns)
    lm = np.array([streams.landmark_truth[int(aligned.landmark_ids[i])][:2] for i in aligned.det_idx]) - pos
    c, s = np.cos(yaw), np.sin(yaw)
    true = np.stack([c * lm[:, 0] + s * lm[:, 1], -s * lm[:, 0] + c * lm[:, 1]], axis=1)
    d2 = np.sum((aligned.det_y[:, :2] - true) ** 2, axis=1)  # planar: the third component's error is 0
    r = np.linalg.norm(aligned.det_y, axis=1)
    cells = []
    for lo, hi in zip(LAW_BINS_M[:-1], LAW_BINS_M[1:]):
        m = (r >= lo) & (r < hi)
        if np.count_nonzero(m) < 30:
            cells.append("-")
            continue
        robust = np.median(d2[m]) / (2.0 * np.log(2.0)) * 2.0 / 3.0  # a 2-D Gaussian's median |d|² is 2 ln2 s²
        per_axis = d2[m] / 3.0
        trimmed = float(np.sqrt(np.mean(per_axis[per_axis <= 16.0 * robust])))
        cells.append(f"{trimmed:.3f} / {float(law.sigma(np.median(r[m]))):.3f} ({trimmed / np.sqrt(robust):.2f})")
    return cells


def ratio_cells(streams, aligned, ratio) -> list[str]:
    """The ``--ratio`` table's cells for one robot (module docstring); ``ratio``: ``noise: auto``'s estimate or None."""
    from slamobs.pipeline.noise_estimation import MAX_TRIPLET_S

    dr, db, t, lm = detection_errors(streams, aligned)
    across = db * np.linalg.norm(aligned.det_y[:, :2], axis=1)
    ok = np.abs(db) < MISASSOCIATED_RAD
    dr, across, t, lm = dr[ok], across[ok], t[ok], lm[ok]
    order = np.lexsort((t, lm))
    dr, across, t, lm = dr[order], across[order], t[order], lm[order]
    near = (lm[1:] == lm[:-1]) & (np.diff(t) <= MAX_TRIPLET_S)
    along_rms, across_rms = float(np.sqrt(np.mean(dr**2))), float(np.sqrt(np.mean(across**2)))
    return [
        f"{along_rms:.3f} / {across_rms:.3f}",
        f"{along_rms / across_rms:.2f}",
        "1 (kept)" if ratio is None else f"{float(ratio.value):.2f} ± {float(ratio.uncertainty):.2f}",
        " / ".join(f"{np.corrcoef(x[:-1][near], x[1:][near])[0, 1]:.2f}" for x in (dr, across)),
    ]


def _refined_best(costs: np.ndarray) -> float:
    """The lag of :data:`OFFSET_LAGS_S` of least ``costs``, moved to the vertex of the parabola through it and its
    neighbours."""
    j = int(np.argmin(costs))
    if 0 < j < costs.size - 1 and (den := costs[j - 1] - 2 * costs[j] + costs[j + 1]) > 0:
        return float(OFFSET_LAGS_S[j] + 0.5 * (costs[j - 1] - costs[j + 1]) / den * OFFSET_STEP_S)
    return float(OFFSET_LAGS_S[j])


def _command_lag(vt: np.ndarray, u: np.ndarray, tt: np.ndarray, truth: np.ndarray, lo: float, hi: float) -> float:
    """The lag (s) of the command ``u`` (held from each stamp ``vt``) behind Vicon's cumulative ``truth`` (on ``tt``):
    the command stamped t is the motion at t + lag (least squares over the windows, one scale fitted)."""
    start = np.arange(lo, hi - OFFSET_WINDOW_S, OFFSET_WINDOW_S / 4)
    want = np.interp(start + OFFSET_WINDOW_S, tt, truth) - np.interp(start, tt, truth)
    cmd = np.r_[0.0, np.cumsum(u[:-1] * np.diff(vt))]
    costs = []
    for lag in OFFSET_LAGS_S:
        a = np.interp(start + OFFSET_WINDOW_S - lag, vt, cmd) - np.interp(start - lag, vt, cmd)
        k = np.sum(a * want) / max(np.sum(a * a), 1e-12)
        costs.append(np.mean((k * a - want) ** 2))
    return _refined_best(np.array(costs))


def _detection_lag(streams, aligned, lo: float, hi: float) -> float:
    """The lag (s) of the detection stamps behind Vicon: a detection stamped t is the pose at t + lag, by the bearings
    (per-landmark means removed, mis-associations out, the best 90 %)."""
    t = np.repeat((aligned.det_t_ns - aligned.t0_ns) * 1e-9, np.diff(aligned.det_offsets))
    ok = (np.abs(detection_errors(streams, aligned)[1]) < MISASSOCIATED_RAD) & (t >= lo) & (t < hi)
    ids = aligned.landmark_ids
    world = np.array([streams.landmark_truth[int(ids[i])][:2] for i in aligned.det_idx[ok]])
    y, lm, t = aligned.det_y[ok, :2], aligned.det_idx[ok], t[ok]
    costs = []
    for lag in OFFSET_LAGS_S:
        yaw, pos = _truth_yaw(streams, t + lag, aligned.t0_ns)
        rel, c, s = world - pos, np.cos(yaw), np.sin(yaw)
        e = np.arctan2(y[:, 1], y[:, 0]) - np.arctan2(-s * rel[:, 0] + c * rel[:, 1], c * rel[:, 0] + s * rel[:, 1])
        e = (e + np.pi) % (2 * np.pi) - np.pi
        for i in np.unique(lm):
            e[lm == i] -= e[lm == i].mean()
        e2 = np.sort(e**2)
        costs.append(np.mean(e2[: int(0.9 * e2.size)]))
    return _refined_best(np.array(costs))


def offset_cells(streams, aligned) -> list[str]:
    """The ``--offset`` table's cells for one robot (module docstring)."""
    from slamobs.pipeline.observers.time_offset import decide

    found = decide(aligned)
    tt, path = _truth_path(streams, aligned.t0_ns)
    yaw, _ = _truth_yaw(streams, tt, aligned.t0_ns)
    vt = (aligned.vel_t_ns - aligned.t0_ns) * 1e-9
    lo, hi = max(vt[0], tt[0]) + 1.0, min(vt[-1], tt[-1]) - 1.0
    mid = float(np.median((aligned.det_t_ns - aligned.t0_ns) * 1e-9))
    cells = [f"{found['estimate_s']:+.3f}", "applied" if found["applied"] else found["why_not_applied"][:26]]
    for a, b in ((lo, hi), (lo, mid), (mid, hi)):
        turn = _command_lag(vt, aligned.omega[:, 2], tt, yaw, a, b)
        speed = _command_lag(vt, aligned.velocity[:, 0], tt, path, a, b)
        seen = _detection_lag(streams, aligned, a, b)
        cells.append(f"{turn:+.3f} / {speed:+.3f} / {seen:+.3f}: **{seen - turn:+.3f}**")
    return cells


def visit_cells(streams, aligned) -> list[str]:
    """``--visits``' cells of one robot (module docstring): within-visit and between-visit spreads of the range
    and across errors (m), mis-associations left out."""
    dr, db, t, lm = detection_errors(streams, aligned)
    rng = np.linalg.norm(aligned.det_y[:, :2], axis=1) - dr
    ok = np.abs(db) < MISASSOCIATED_RAD
    within, medians, counts = [], [], []
    for i in np.unique(lm):
        rows = np.flatnonzero(ok & (lm == i))
        cuts = np.r_[0, np.flatnonzero(np.diff(t[rows]) > VISIT_GAP_S) + 1, rows.size]
        for a, b in zip(cuts[:-1], cuts[1:]):
            if b - a >= MIN_VISIT:
                v = rows[a:b]
                errs = (dr[v], db[v] * rng[v])
                within.append([_robust(e) for e in errs])
                medians.append([float(np.median(e)) for e in errs])
                counts.append(b - a)
    within, medians, n = np.array(within), np.array(medians), np.array(counts)
    white = np.sqrt(np.mean(within**2 * (np.pi / 2) / n[:, None], axis=0))  # a median's variance, white errors
    return [
        f"{n.size}",
        *(
            f"{np.median(within[:, k]):.3f} / {np.std(medians[:, k]):.3f} ({white[k]:.3f}) / "
            f"{np.max(np.abs(medians[:, k])):.2f}"
            for k in range(2)
        ),
        f"{np.count_nonzero(~ok)}",
    ]


def misassociated_rows(name: str, streams, aligned, robots: dict) -> list[str]:
    """``--visits``' mis-associations of one robot: time, id, where the detection puts it against the survey, and
    the surveyed landmark or other robot nearest that place."""
    dr, db, t, lm = detection_errors(streams, aligned)
    yaw, pos = _truth_yaw(streams, t, aligned.t0_ns)
    y = aligned.det_y[:, :2]
    c, s = np.cos(yaw), np.sin(yaw)
    place = pos + np.stack([c * y[:, 0] - s * y[:, 1], s * y[:, 0] + c * y[:, 1]], axis=1)
    ids = aligned.landmark_ids
    survey = {int(k): np.asarray(v[:2]) for k, v in streams.landmark_truth.items()}
    t_abs = aligned.t0_ns + np.round(t * 1e9).astype(np.int64)
    out = []
    for k in np.flatnonzero(np.abs(db) >= MISASSOCIATED_RAD):
        near = {f"landmark {i}": float(np.linalg.norm(place[k] - p)) for i, p in survey.items()}
        for other, truth in robots.items():
            if other != name and truth.t_ns[0] <= t_abs[k] <= truth.t_ns[-1]:
                at = [np.interp(t_abs[k], truth.t_ns, truth.position[:, a]) for a in range(2)]
                near[other] = float(np.linalg.norm(place[k] - np.array(at)))
        best = min(near, key=near.get)
        own = int(ids[lm[k]])
        out.append(
            f"| {name} | {t[k] - t.min():.1f} | {own} | {np.linalg.norm(y[k]):.2f} / {dr[k]:+.2f} / {db[k]:+.2f} | "
            f"{near[f'landmark {own}']:.2f} | {best} ({near[best]:.2f} m) |"
        )
    return out


def main() -> None:
    from slamobs.pipeline.alignment import align
    from slamobs.pipeline.api import read_log
    from slamobs.pipeline.noise import estimate_log_noise, resolve_noise, stream_density
    from slamobs.pipeline.noise_estimation import MAX_TRIPLET_S

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default="mrclam6,mrclam7", help="comma-separated MR.CLAM robots or datasets")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-real-logs")
    ap.add_argument("--speed", action="store_true", help="also the commanded speed's error taken apart (third table)")
    ap.add_argument("--shared", action="store_true", help="also the detections' error shared across landmarks (fourth)")
    ap.add_argument("--law", action="store_true", help="also the detection law beside the truth's per range (fifth)")
    ap.add_argument("--ratio", action="store_true", help="also the range's error against the across one (sixth)")
    ap.add_argument("--offset", action="store_true", help="also the detections' offset by the truth (seventh)")
    ap.add_argument("--visits", action="store_true", help="also each visit's errors and the mis-associations (eighth)")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    logs = [g for g in all_logs(args.cache, args.logs.split(",")) if g.name.startswith("mrclam") and not g.skip]
    heads = " | ".join(f"g / v Vicon T={w:g}s" for w in WINDOWS_S)
    print(f"| robot | g / v auto | {heads} |\n|" + " --- |" * (2 + len(WINDOWS_S)))
    rows, speed, shared, laws, ratios, offsets, visits, wrong = [], [], [], [], [], [], [], []
    robots = {g.name: read_log(g.path).truth for g in logs} if args.visits else {}
    for log in logs:
        streams = read_log(log.path)
        aligned = align(streams)
        lv = streams.linear_velocity
        estimated = estimate_log_noise(
            aligned, stream_density(lv.t_ns, lv.xyz) if args.law and lv is not None else "aligned"
        )
        noise = resolve_noise(estimated=estimated)
        vicon = motion_cells(streams, aligned)
        pairs = [f"{vicon[2 * k]} / {vicon[2 * k + 1]}" for k in range(len(WINDOWS_S))]
        print(f"| {log.name} | {np.max(noise.gyro):.3f} / {np.max(noise.velocity):.3f} | " + " | ".join(pairs) + " |")
        rows.append(f"| {log.name} | " + " | ".join(detection_cells(streams, aligned)) + " |")
        speed += speed_rows(log.name, streams, aligned) if args.speed else []
        if args.shared:
            shared.append(f"| {log.name} | " + " | ".join(shared_cells(streams, aligned)) + " |")
        if args.law and estimated.detection is not None:
            laws.append(f"| {log.name} | " + " | ".join(law_cells(streams, aligned, estimated.detection)) + " |")
        if args.ratio:
            ratios.append(f"| {log.name} | " + " | ".join(ratio_cells(streams, aligned, estimated.ratio)) + " |")
        if args.offset:
            offsets.append(f"| {log.name} | " + " | ".join(offset_cells(streams, aligned)) + " |")
        if args.visits:
            visits.append(f"| {log.name} | " + " | ".join(visit_cells(streams, aligned)) + " |")
            wrong += misassociated_rows(log.name, streams, aligned, robots)
    lags = " | ".join(f"lag {lag:g}s" for lag in LAGS_S)
    print(f"\n| robot | range m / bearing rad sd | per-landmark mean sd | {lags} |\n|" + " --- |" * (3 + len(LAGS_S)))
    print("\n".join(rows))
    if speed:
        windows = " | ".join(f"v Vicon T={w:g}s" for w in WINDOWS_S)
        print(f"\n| robot | commanded speed | {windows} |\n|" + " --- |" * (2 + len(WINDOWS_S)))
        print("\n".join(speed))
    if shared:
        print(
            "\n| robot | pairs in one frame | two landmarks, one frame: range / bearing r | one landmark 0.5-1.5 s: "
            "range / bearing r | stamp offset by the yaw rate, bearing variance it explains | one frame's bearing r "
            "after it |"
            "\n|" + " --- |" * 6
        )
        print("\n".join(shared))
    if laws:
        bins = " | ".join(f"{lo:g}-{hi:g} m" for lo, hi in zip(LAW_BINS_M[:-1], LAW_BINS_M[1:]))
        print(f"\n| robot (truth / law σ m, truth RMS over its robust scale) | {bins} |\n|" + " --- |" * 5)
        print("\n".join(laws))
    if ratios:
        print(
            f"\n| robot | range / across RMS m | truth's ratio | noise: auto's ratio | correlation within "
            f"{MAX_TRIPLET_S:g} s, range / across |\n|" + " --- |" * 5
        )
        print("\n".join(ratios))
    if offsets:
        lags = "the commands' turn / speed lag, the detections' lag: offset"
        print(
            f"\n| robot | offset the pairs find | decided | {lags}, whole log | first half | second half |"
            "\n|" + " --- |" * 6
        )
        print("\n".join(offsets))
    if visits:
        print(
            "\n| robot | visits | range error: within a visit / between visits (white) / largest visit m | across: "
            "the same | mis-associated |\n|" + " --- |" * 5
        )
        print("\n".join(visits))
        print("\n| robot | t s | id | range m / range error m / bearing error rad | from its survey m | nearest |")
        print("| --- | --- | --- | --- | --- | --- |\n" + "\n".join(wrong))


if __name__ == "__main__":
    main()
