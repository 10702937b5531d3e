"""riekf's consistency per block on the ground-robot logs of ``unseen_logs.py``: the time-averaged NEES of the
attitude (3 DoF; roll/pitch 2, yaw 1) and the position (3 DoF; horizontal 2, vertical 1), the RMS errors and the
median σ the filter reports, given the true noise (as ``unseen_logs.py``'s "true" runs), with and without wheel
slip, and with extra noise keys (e.g. a velocity-bias random walk). A consistent filter gives NEES ≈ its DoF.

    .venv/bin/python benchmarks/riekf_ground_nees.py [--cache DIR] [--seeds 1 2 3] [--cases 0 3]
        [--walks 0 0.003 0.009] [--gyro-x 1] [--isotropic]

The errors are those of the right-invariant filter (``η = R̂Rᵀ``: ``ξ_R = log η``, ``ξ_P = P̂ − ηP``) against the
simulator's truth in the start pose's frame (the filter's gauge), after the first 2 s; the final map's mean landmark
NEES (3 DoF, ``landmarks.parquet``'s covariance) and RMS error against the simulator's landmarks in that frame (with
the median σ, the root of the covariance's trace); the velocity-bias walk the run ended with and its passes over the
log (run.json ``observer.filter.walk``). ``walk`` 0 keeps the default ``velocity_bias_walk`` (learned from the log).
``--gyro-x`` and ``--isotropic`` change the log (gyro density; the simulator's additive detection law in place of the
stereo-like one) to take the errors apart.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from unseen_logs import CASES, make_log, scenario  # benchmarks/ is the script's directory

from slamobs.pipeline.api import run_log
from slamobs.pipeline.lie import quats_to_rots, so3_log
from slamobs.pipeline.simulate import simulate

AXES = ("rx", "ry", "rz", "x", "y", "z")
BLOCKS = {"att": [0, 1, 2], "rp": [0, 1], "yaw": [2], "pos": [3, 4, 5], "xy": [3, 4], "z": [5]}
SKIP_S = 2.0


def nees(case, log: Path, truth: dict, extra: dict, out: Path) -> dict:
    noise = {k: v for k, v in truth.items() if k != "median_range_m"} | extra
    run_log(log, out, observer="riekf", config={"evaluation": {"plots": False}, "noise": noise}, force=True)
    p = pq.read_table(out / "poses.parquet").to_pandas()
    run = json.loads((out / "run.json").read_text())
    notes = [n for n in run.get("notes") or [] if n.startswith("error")]
    lm = pq.read_table(out / "landmarks.parquet").to_pandas()
    shutil.rmtree(out, ignore_errors=True)
    sc = scenario(case)
    t0 = simulate(sc, duration=0.5, seed=1, noise=False).start_ns
    t = (p.t_ns.to_numpy() - t0) * 1e-9
    tr = sc.sample(t)
    r_true = np.einsum("ji,njk->nik", tr.R[0], tr.R)
    p_true = np.einsum("ji,nj->ni", tr.R[0], tr.P - tr.P[0])
    r_hat = quats_to_rots(np.ascontiguousarray(p[["qx", "qy", "qz", "qw"]].to_numpy()))
    eta = np.einsum("nij,nkj->nik", r_hat, r_true)
    err = np.c_[
        np.array([so3_log(e) for e in eta]), p[["x", "y", "z"]].to_numpy() - np.einsum("nij,nj->ni", eta, p_true)
    ]

    def c(a: str, b: str) -> np.ndarray:
        return p[f"cov_{a}_{b}"].to_numpy() if f"cov_{a}_{b}" in p else p[f"cov_{b}_{a}"].to_numpy()

    cov = np.stack([np.stack([c(a, b) for b in AXES], -1) for a in AXES], -2)
    keep = t > SKIP_S
    e, cv = err[keep], cov[keep]
    res = {
        k: float(np.mean([x[i] @ np.linalg.solve(s[np.ix_(i, i)], x[i]) for x, s in zip(e, cv)]))
        for k, i in BLOCKS.items()
    }
    res["rms"] = np.sqrt(np.mean(e**2, axis=0))
    res["sigma"] = np.sqrt(np.median(np.diagonal(cv, axis1=1, axis2=2), axis=0))
    res["lost"] = bool(notes)
    # the final map against the simulator's landmarks moved into the start pose's frame (the filter's gauge)
    lm = lm[np.isin(lm.id.to_numpy(), sc.landmark_ids)]
    i = np.searchsorted(sc.landmark_ids, lm.id.to_numpy())
    lm_err = lm[["x", "y", "z"]].to_numpy() - (sc.landmarks[i] - tr.P[0]) @ tr.R[0]
    lm_cov = np.stack([np.stack([c_lm(lm, a, b) for b in "xyz"], -1) for a in "xyz"], -2)
    res["lm_nees"] = float(np.mean(np.einsum("ni,ni->n", lm_err, np.linalg.solve(lm_cov, lm_err[..., None])[..., 0])))
    res["lm_err"] = float(np.sqrt(np.mean(np.sum(lm_err**2, axis=1))))
    res["lm_sigma"] = float(np.sqrt(np.median(np.trace(lm_cov, axis1=1, axis2=2))))
    walk = run["observer"]["filter"]["walk"]
    res["walk"] = f"{walk['velocity_bias_walk']:.2g} ({walk.get('passes', 1)})"
    return res


def c_lm(lm, a: str, b: str) -> np.ndarray:
    return lm[f"cov_{a}{b}"].to_numpy() if f"cov_{a}{b}" in lm else lm[f"cov_{b}{a}"].to_numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-unseen-logs")
    ap.add_argument("--cases", type=int, nargs="+", default=[0], help="indices into unseen_logs.CASES")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--gyro-x", type=float, help="the gyro's density over the default (unseen_logs: 50)")
    ap.add_argument("--isotropic", action="store_true", help="the additive detection law, not stereo-like")
    ap.add_argument("--walks", type=float, nargs="+", default=[0.0], help="velocity_bias_walk (0: the default)")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    print(
        "| log | slip m/s | velocity_bias_walk | NEES att (3) / rp (2) / yaw (1) | NEES pos (3) / xy (2) / z (1) | "
        "RMS err rx ry rz deg (σ) | RMS err x y z m (σ) | landmark NEES (3) | map err m (σ) | walk (passes) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for base in (CASES[i] for i in args.cases):
        if args.gyro_x:
            base = replace(base, name=f"{base.name}-gyro{args.gyro_x:g}", gyro_x=args.gyro_x)
        if args.isotropic:
            base = replace(base, name=f"{base.name}-iso", pixel=0.0)
        for case in (base, replace(base, name=f"{base.name}-noslip", drift=0.0)):
            for seed in args.seeds:
                log, truth = make_log(case, seed, args.cache)
                for walk in args.walks:
                    extra = {"velocity_bias_walk": walk} if walk > 0 else {}
                    r = nees(case, log, truth, extra, args.cache / "runs" / f"nees-{case.name}-{seed}")
                    att = " / ".join(f"{r[k]:.1f}" for k in ("att", "rp", "yaw"))
                    pos = " / ".join(f"{r[k]:.1f}" for k in ("pos", "xy", "z"))
                    fmt = lambda v, f: " ".join(f % x for x in v)  # noqa: E731
                    rot = f"{fmt(np.degrees(r['rms'][:3]), '%.1f')} ({fmt(np.degrees(r['sigma'][:3]), '%.1f')})"
                    xyz = f"{fmt(r['rms'][3:], '%.2f')} ({fmt(r['sigma'][3:], '%.2f')})"
                    name = f"{case.name}-s{seed}{' (lost)' if r['lost'] else ''}"
                    w = walk if walk > 0 else "default"
                    lmc = f"{r['lm_nees']:.1f} | {r['lm_err']:.2f} ({r['lm_sigma']:.2f})"
                    print(
                        f"| {name} | {case.drift:g} | {w} | {att} | {pos} | {rot} | {xyz} | {lmc} | {r['walk']} |",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
