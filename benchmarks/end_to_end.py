"""``slamobs run`` end to end on long simulated logs: wall time, time per stage, peak memory, output size.

    .venv/bin/python benchmarks/end_to_end.py [--hours 1 4] [--containers mcap bag] [--cache DIR] [--exports]

Logs are the ``figure8-wide`` scenario (30 landmarks, about 8 in view) at IMU 200 Hz, odometry 50 Hz,
magnetometer 50 Hz, detections 20 Hz and motion capture 100 Hz, generated once into a cache directory
(default: ``<tmp>/slamobs-bench``, not the repository) by ``slamobs simulate``, which writes them piece by
piece. Each log is run by ``slamobs run`` in its own process; its peak RSS is that process's ``ru_maxrss``.
Stages are the ``timings_s`` of the run's ``run.json``. Before the table, a short log is run twice with an
empty numba cache directory: the difference is what the first run spends compiling (later runs load the
kernels from the cache). The floors of the issue are checked at the end, among them that a default run
directory is at most twice its Parquet tables. ``--exports`` runs the first log once more with every optional
export (``--export tum,evo,mcap``) and prints the size of each group of files per hour of log.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SLAMOBS = Path(sys.executable).with_name("slamobs")
SCENARIO = "figure8-wide"
STAGES = ("read_s", "align_s", "observer_s", "write_s", "report_s")
SUFFIX = {"mcap": ".mcap", "bag": ".bag"}

# Floors (issue "Speed and memory"): a one-hour log in 20 s and 1 GB; four hours in under twice the memory.
MAX_WALL_1H_S = 20.0
MAX_RSS_1H_MB = 1024.0
MAX_PARQUET_1H_MB = 50.0
# Issue "small run directories": a default run directory is at most twice its Parquet tables.
MAX_OUT_PER_PARQUET = 2.0
#: File groups of a run directory, for the export sizes.
GROUPS = {"Parquet tables": ("*.parquet",), "report + figures": ("report.*", "*.png", "run.json"),
          "tum (estimate_tum.txt, truth_tum.txt)": ("*_tum.txt",), "evo (ape_evo.zip)": ("*.zip",),
          "mcap (results.mcap)": ("*.mcap",)}


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _child(args: list[str], env: dict[str, str] | None = None) -> tuple[float, float, int]:
    """Run a command; wall seconds, peak RSS in MB of that process, exit status."""
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage
        wall = time.perf_counter() - start
        proc.returncode = code = os.waitstatus_to_exitcode(status)
        if code:
            err.seek(0)
            print(f"failed: {' '.join(args)}\n{err.read().decode(errors='replace')}", file=sys.stderr)
    return wall, usage.ru_maxrss / 1024.0, code


def make_log(cache: Path, hours: float, container: str) -> Path:
    """The cached simulated log (generated on first use)."""
    path = cache / f"{SCENARIO}-{hours:g}h{SUFFIX[container]}"
    if not path.exists():
        print(f"# generating {path.name} (once; cached) ...", flush=True)
        wall, rss, rc = _child([str(SLAMOBS), "simulate", SCENARIO, "-o", str(path), "--duration",
                                str(hours * 3600), "--container", container])
        if rc:
            raise SystemExit(rc)
        print(f"#   {wall:.0f} s, peak RSS {rss:.0f} MB", flush=True)
    return path


def message_count(hours: float) -> int:
    from slamobs.pipeline.simulate import simulation

    return sum(simulation(SCENARIO, duration=hours * 3600).topic_counts().values())


def size_mb(path: Path, pattern: str = "*") -> float:
    return sum(f.stat().st_size for f in path.glob(pattern) if f.is_file()) / 1e6


def run(log: Path, out: Path, env: dict[str, str] | None = None, extra: tuple[str, ...] = ()) -> dict:
    """``slamobs run`` on ``log`` in a child process; its numbers and those of its run directory."""
    wall, rss, rc = _child([str(SLAMOBS), "run", str(log), "-o", str(out), "--force", "-q", *extra], env)
    if rc:
        raise SystemExit(rc)
    meta = json.loads((out / "run.json").read_text())
    return {"wall": wall, "rss": rss, "timings": meta["timings_s"], "parquet_mb": size_mb(out, "*.parquet"),
            "out_mb": size_mb(out), "span_s": (meta["span_ns"][1] - meta["span_ns"][0]) / 1e9,
            "compiled": meta.get("compiled", {})}


def export_sizes(log: Path, hours: float, out: Path) -> None:
    """The first log with every export: MB per hour of log of each group of files, and the export time."""
    r = run(log, out, extra=("--export", "tum,evo,mcap"))
    tables = size_mb(out, "*.parquet")
    t = r["timings"]
    print(f"# run directory with --export tum,evo,mcap ({log.name}; export stage {t.get('export_s', 0):.1f} s, "
          f"report {t.get('report_s', 0):.1f} s)")
    print(f"{'files':<40} {'MB per hour':>11} {'x Parquet':>9}")
    for name, patterns in GROUPS.items():
        mb = sum(size_mb(out, p) for p in patterns)
        print(f"{name:<40} {mb / hours:>11.1f} {mb / tables:>9.2f}")


def short_log(cache: Path) -> Path:
    log = cache / f"{SCENARIO}-60s.mcap"
    if not log.exists():
        _child([str(SLAMOBS), "simulate", SCENARIO, "-o", str(log), "--duration", "60"])
    return log


def compile_times(cache: Path) -> tuple[float, float, dict]:
    """Wall seconds of a short run with an empty numba cache directory, then of the same run again, and what
    the first run's run.json says it compiled."""
    log = short_log(cache)
    with tempfile.TemporaryDirectory(prefix="slamobs-numba-") as numba_dir:
        env = {**os.environ, "NUMBA_CACHE_DIR": numba_dir}
        first = run(log, cache / "runs" / "compile", env)
        second = run(log, cache / "runs" / "compile", env)["wall"]
    return first["wall"], second, first["compiled"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1.0, 4.0], help="log durations in hours")
    ap.add_argument("--containers", nargs="+", default=["mcap", "bag"], choices=sorted(SUFFIX))
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-bench",
                    help="where the generated logs and run directories are kept")
    ap.add_argument("--no-compile", action="store_true", help="skip the numba compile-time measurement")
    ap.add_argument("--exports", action="store_true", help="also measure the optional exports on the first log")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    logs = [(h, c, make_log(args.cache, h, c)) for h in args.hours for c in args.containers]

    print(f"# slamobs run end to end, {cpu_model()}, {os.cpu_count()} cores, python {platform.python_version()}; "
          f"scenario {SCENARIO}: IMU 200 Hz, odometry 50 Hz, magnetometer 50 Hz, detections 20 Hz "
          f"(30 landmarks, ~8 in view), mocap 100 Hz; observer fast-adaptation, every sample written")
    if not args.no_compile:
        first, second, compiled = compile_times(args.cache)
        print(f"# numba: 60 s log with an empty cache {first:.1f} s, again (cached) {second:.1f} s; the first run "
              f"compiled {compiled.get('functions', 0)} functions in {compiled.get('seconds', 0.0):.1f} s")
    run(short_log(args.cache), args.cache / "runs" / "warmup")  # the project's numba cache is filled
    head = (f"{'log':<22} {'container':<9} {'duration':>8} {'messages':>10} {'wall s':>7} {'x real':>7} "
            + " ".join(f"{s[:-2]:>8}" for s in STAGES) + f" {'peak RSS MB':>11} {'parquet MB':>10} {'out MB':>7}"
            + f" {'out/pq':>6}")
    print(head)
    results = {}
    for hours, container, log in logs:
        r = run(log, args.cache / "runs" / f"{log.stem}-{container}")
        results[hours, container] = r
        t = r["timings"]
        print(f"{log.name:<22} {container:<9} {hours:>7g}h {message_count(hours):>10,} {r['wall']:>7.1f} "
              f"{r['span_s'] / r['wall']:>6.0f}x " + " ".join(f"{t.get(s, float('nan')):>8.2f}" for s in STAGES)
              + f" {r['rss']:>11.0f} {r['parquet_mb']:>10.1f} {r['out_mb']:>7.1f}"
              + f" {r['out_mb'] / r['parquet_mb']:>6.2f}", flush=True)
    if args.exports and logs:
        hours, container, log = logs[0]
        export_sizes(log, hours, args.cache / "runs" / "exports")

    print("# floors")
    for container in args.containers:
        one, four = results.get((1.0, container)), results.get((4.0, container))
        if one:
            ok = (one["wall"] <= MAX_WALL_1H_S and one["rss"] <= MAX_RSS_1H_MB
                  and one["parquet_mb"] < MAX_PARQUET_1H_MB)
            print(f"{container}: 1 h in {one['wall']:.1f} s (<= {MAX_WALL_1H_S:g}), peak {one['rss']:.0f} MB "
                  f"(<= {MAX_RSS_1H_MB:g}), parquet {one['parquet_mb']:.1f} MB (< {MAX_PARQUET_1H_MB:g}): "
                  f"{'ok' if ok else 'MISSED'}")
        for (hours, c), r in results.items():
            if c == container:
                ratio = r["out_mb"] / r["parquet_mb"]
                print(f"{container} {hours:g} h: run directory {r['out_mb']:.1f} MB = {ratio:.2f} x its Parquet "
                      f"tables (<= {MAX_OUT_PER_PARQUET:g}): {'ok' if ratio <= MAX_OUT_PER_PARQUET else 'MISSED'}")
        if one and four:
            ratio = four["rss"] / one["rss"]
            print(f"{container}: 4 h peak / 1 h peak = {ratio:.2f} (< 2): {'ok' if ratio < 2 else 'MISSED'}")
    shutil.rmtree(args.cache / "runs", ignore_errors=True)


if __name__ == "__main__":
    main()
