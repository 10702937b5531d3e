"""APE with SE(3) Umeyama alignment on large trajectories: slamobs vs evo 1.38.1, side by side.

    SLAMOBS_EVO_PYTHON=/path/to/evo-venv/bin/python .venv/bin/python benchmarks/ape_speed.py [--poses 100000]

Writes a truth and an estimate (another frame, noise, jittered stamps) as TUM files, then times the same
evaluation both ways, best of ``--repeat`` runs after one warm-up (numba compilation and imports excluded):

* ``sync+align+APE``: association (nearest stamp, 0.01 s), SE(3) Umeyama on all pairs, APE translation part and
  its statistics, from trajectories already in memory (evo: ``PoseTrajectory3D`` objects built beforehand;
  slamobs: PoseStreams);
* ``files -> stats``: the same starting from the two TUM files (parsing included).

evo runs in a subprocess with the interpreter named by SLAMOBS_EVO_PYTHON (its own venv: evo is GPL-3.0 and
pulls SciPy, neither of which slamobs imports), timing evo's Python API (``evo.core.sync``,
``PoseTrajectory3D.align``, ``evo.core.metrics.APE``) with ``time.perf_counter`` inside that process.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: One BLAS thread, as ``slamobs evaluate`` runs (cli/main.py sets it before NumPy loads): with OpenBLAS's threads
#: the in-memory APE of 100,000 poses took 31.7 ms of CPU instead of 21.8 (the alignment's (N, 3) x (3, 3)
#: products). evo runs with the BLAS threads its users get.
_USER_BLAS = os.environ.get("OPENBLAS_NUM_THREADS")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from end_to_end import MIN_APE_FILES_SPEEDUP, load, met  # noqa: E402

EVO_TIMER = r"""
import json, sys, time, copy
import numpy as np
from evo.core import metrics, sync
from evo.tools import file_interface as fi

ref_path, est_path, repeat = sys.argv[1], sys.argv[2], int(sys.argv[3])

def evaluate(ref, est):
    r, e = sync.associate_trajectories(ref, est, max_diff=0.01)
    e.align(r, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((r, e))
    return ape.get_all_statistics(), len(ape.error)

def best(fn):
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out

ref0, est0 = fi.read_tum_trajectory_file(ref_path), fi.read_tum_trajectory_file(est_path)
t_mem, (stats, n) = best(lambda: evaluate(ref0, est0))
t_files, _ = best(lambda: evaluate(fi.read_tum_trajectory_file(ref_path), fi.read_tum_trajectory_file(est_path)))
print(json.dumps({"memory_s": t_mem, "files_s": t_files, "stats": {k: float(v) for k, v in stats.items()}, "n": n}))
"""


def make_files(n: int, out: Path) -> tuple[Path, Path]:
    from slamobs.pipeline.lie import quats_to_rots, rots_to_quats, so3_exp
    from slamobs.pipeline.readers.trajectory_files import write_tum
    from slamobs.pipeline.streams import PoseStream

    rng = np.random.default_rng(0)
    t0 = 1_700_000_000 * 1_000_000_000
    t = t0 + np.arange(n, dtype=np.int64) * 10_000_000  # 100 Hz
    s = (t - t0) / 1e9
    pos = np.column_stack([30 * np.sin(0.01 * s), 20 * np.sin(0.02 * s), 2 + np.cos(0.05 * s)])
    yaw = 0.05 * s
    rots = np.zeros((n, 3, 3))
    rots[:, 0, 0] = np.cos(yaw)
    rots[:, 0, 1] = -np.sin(yaw)
    rots[:, 1, 0] = np.sin(yaw)
    rots[:, 1, 1] = np.cos(yaw)
    rots[:, 2, 2] = 1.0
    truth = PoseStream("truth", "", "", t, t, pos, rots_to_quats(rots))
    rc = so3_exp(np.array([0.2, -0.1, 1.0]))
    est_t = t + rng.integers(-2_000_000, 2_000_000, n)  # ±2 ms jitter, same rate: every pose is paired
    est_pos = pos @ rc.T + [5.0, -3.0, 1.0] + 0.05 * rng.standard_normal((n, 3))
    est = PoseStream(
        "est",
        "",
        "",
        est_t,
        est_t,
        est_pos,
        rots_to_quats(np.einsum("ij,njk->nik", rc, quats_to_rots(truth.quat_xyzw))),
    )
    return write_tum(out / "truth.txt", truth), write_tum(out / "est.txt", est)


def time_slamobs(ref_path: Path, est_path: Path, repeat: int) -> dict:
    from slamobs.pipeline.evaluation.trajectory_error import AlignOptions, SyncOptions, ape
    from slamobs.pipeline.readers.trajectory_files import read_trajectory

    def from_files():
        return ape(
            read_trajectory(ref_path), read_trajectory(est_path), "trans_part", SyncOptions(0.01), AlignOptions("se3")
        )

    ref, est = read_trajectory(ref_path), read_trajectory(est_path)

    def in_memory():
        return ape(ref, est, "trans_part", SyncOptions(0.01), AlignOptions("se3"))

    out = {}
    for key, fn in (("memory_s", in_memory), ("files_s", from_files)):
        res = fn()  # warm-up: numba kernels compile (or load from cache) here
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            res = fn()
            times.append(time.perf_counter() - t)
        out[key] = min(times)
        out["stats"], out["n"] = res.stats, int(res.errors.shape[0])
    return out


def time_evo(python: str, ref_path: Path, est_path: Path, repeat: int) -> dict:
    env = {**os.environ, "HOME": str(ref_path.parent), "MPLBACKEND": "Agg"}  # evo writes settings under $HOME
    if _USER_BLAS is None:  # evo with the BLAS threads its users get
        env.pop("OPENBLAS_NUM_THREADS")
    done = subprocess.run(
        [python, "-c", EVO_TIMER, str(ref_path), str(est_path), str(repeat)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--poses", type=int, default=100_000, help="poses in each trajectory")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per variant (the best is reported)")
    args = parser.parse_args()
    evo_python = os.environ.get("SLAMOBS_EVO_PYTHON")
    with tempfile.TemporaryDirectory(prefix="ape-speed-") as tmp:
        ref_path, est_path = make_files(args.poses, Path(tmp))
        ours = time_slamobs(ref_path, est_path, args.repeat)
        evo = time_evo(evo_python, ref_path, est_path, args.repeat) if evo_python else None

    print(
        f"APE, SE(3) Umeyama alignment, translation part: {args.poses} poses per trajectory, {ours['n']} pairs; "
        f"best of {args.repeat}"
    )
    print(f"python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} CPUs")
    print()
    print(f"| {'step':<20} | {'slamobs [s]':>11} | {'evo 1.38.1 [s]':>14} | {'speed-up':>8} |")
    print(f"|{'-' * 22}|{'-' * 13}|{'-' * 16}|{'-' * 10}|")
    for key, label in (("memory_s", "sync+align+APE"), ("files_s", "files -> stats")):
        e = evo[key] if evo else None
        e_txt = f"{e:14.4f}" if e is not None else f"{'(no evo)':>14}"
        sp = f"{e / ours[key]:7.1f}x" if e is not None else f"{'-':>8}"
        print(f"| {label:<20} | {ours[key]:11.4f} | {e_txt} | {sp} |")
    if evo:
        diff = max(abs(ours["stats"][k] - v) for k, v in evo["stats"].items())
        print()
        print(
            f"same numbers: rmse {ours['stats']['rmse']:.9f} (slamobs) vs {evo['stats']['rmse']:.9f} (evo), "
            f"largest statistic difference {diff:.2e}; pairs {ours['n']} vs {evo['n']}"
        )
    else:
        print("\nset SLAMOBS_EVO_PYTHON to a python with evo==1.38.1 for the evo column")
    print(f"# floors (issue 27); {load()}")
    ratio = f"{evo['files_s'] / ours['files_s']:.1f}x evo" if evo else "not measured (no evo)"
    ok = bool(evo) and evo["files_s"] / ours["files_s"] >= MIN_APE_FILES_SPEEDUP
    print(f"APE from two TUM files of {args.poses} poses: {ratio} (>= {MIN_APE_FILES_SPEEDUP:g}x): {met(ok)}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
