"""The reference estimators on real TagSLAM logs (``$SLAMOBS_REALDATA``, else ``../shared/realdata``), with no
noise configuration: the map against TagSLAM's survey (test_11) or TagSLAM's optimised tag positions (test_21,
test_22), after a rigid alignment, and what the robust steps said (riekf's recoveries, batch's winning seed, the
detection time offset).

    .venv/bin/python benchmarks/real_reference.py [--tests test_11 test_22] [--estimators riekf batch]

Prints one table row per log and estimator: landmarks matched, map error (median and RMSE, m; test_22 has two
tags: the error of their distance), run time, riekf's status and gated detections, the batch candidates' costs
and the time-offset estimate.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

REALDATA = Path(os.environ.get("SLAMOBS_REALDATA") or Path(__file__).resolve().parents[2] / "shared" / "realdata")
TAGSLAM = REALDATA / "tagslam_test"
#: Per log: the tag options its test in tests/test_realdata_tags.py uses, and the gains (test_11's slow bias loop).
LOGS = {
    "test_11": {"tags": {"size": 0.15}, "gains": {"fast-adaptation": {"gamma": 0.01}}},
    "test_21": {"tags": {"size": 0.16, "sizes": {i: 0.1 for i in range(100, 109)}}},
    "test_22": {"tags": {"size": 0.42}},
}


def reference_map(test: str) -> dict[int, np.ndarray]:
    """Tag positions: the survey in tagslam.yaml (test_11) or TagSLAM's optimised ones (reference.bag)."""
    from slamobs.pipeline.frames import TfBuffer
    from slamobs.pipeline.readers import read_log

    if test == "test_11":
        from slamobs.pipeline.known_map import read_map

        known = read_map(TAGSLAM / test / "tagslam.yaml")
        return dict(zip(known.ids.tolist(), known.xyz))
    s = read_log(TAGSLAM / test / "reference.bag", {"tf": "/tf"})
    tf = TfBuffer(s.static_tf, s.tf)
    return {
        int(e.child[4:]): tf.lookup("map", e.child, e.t_ns[-1:]).trans[0] for e in s.tf if e.child.startswith("tag_")
    }


def map_error(out: Path, ref: dict[int, np.ndarray]) -> tuple[int, float, float]:
    from slamobs.pipeline.lie import umeyama

    est = pd.read_parquet(out / "landmarks.parquet").set_index("id")
    ids = [i for i in est.index if i in ref]
    a, b = est.loc[ids, ["x", "y", "z"]].to_numpy(), np.array([ref[i] for i in ids])
    if len(ids) < 3:  # test_22: two tags, their distance
        err = abs(np.linalg.norm(a[0] - a[-1]) - np.linalg.norm(b[0] - b[-1]))
        return len(ids), float(err), float(err)
    rot, trans, _ = umeyama(a, b)
    err = np.linalg.norm(a @ rot.T + trans - b, axis=1)
    return len(ids), float(np.median(err)), float(np.sqrt(np.mean(err**2)))


def robust_notes(meta: dict) -> str:
    """riekf's status and gated share, batch's seeds, the time offset: what the robust steps reported."""
    obs = meta.get("observer", {})
    parts = []
    if (f := obs.get("filter")) is not None:
        status, n = f.get("status", "-"), f.get("recoveries", "-")
        parts.append(f"status {status}, gated {f['gated_detections']}, recoveries {n}")
    if (c := obs.get("smoother", {}).get("robust")) is not None:
        costs = "; ".join(f"{k}: cost {v['cost']:.4g}" for k, v in c["candidates"].items())
        parts.append(f"{costs} -> {c['winner']}")
    if (o := obs.get("time_offset")) is not None:
        parts.append(f"offset {o.get('estimate_s')} s ({'applied' if o.get('applied') else 'not applied'})")
    return "; ".join(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tests", nargs="+", default=list(LOGS))
    ap.add_argument("--estimators", nargs="+", default=["fast-adaptation", "riekf", "batch"])
    args = ap.parse_args()
    if not TAGSLAM.is_dir():
        sys.exit(f"no real logs at {TAGSLAM} (set SLAMOBS_REALDATA)")
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import run_log

    print("| log | estimator | matched | map error median m | RMSE m | run s | robust steps |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for test in args.tests:
            d = TAGSLAM / test
            ref = reference_map(test)
            for name in args.estimators:
                cfg = {
                    "cameras": [str(d / f) for f in ("cameras.yaml", "camera_poses.yaml", "tagslam.yaml")],
                    "observer": name,
                    "evaluation": {"plots": False},
                    **LOGS[test],
                }
                out = Path(tmp) / f"{test}-{name}"
                t = time.perf_counter()
                run_log(d / "tag_detections.bag", out, parse_config(cfg))
                wall = time.perf_counter() - t
                meta = json.loads((out / "run.json").read_text())
                n, med, rmse = map_error(out, ref)
                print(f"| {test} | {name} | {n} | {med:.3f} | {rmse:.3f} | {wall:.1f} | {robust_notes(meta)} |")
                sys.stdout.flush()


if __name__ == "__main__":
    main()
