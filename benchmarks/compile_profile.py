"""What a first run compiles: every numba function, its signature and its own compile time, cold wall time.

    .venv/bin/python benchmarks/compile_profile.py [LOG] [--observer NAME] [--top N] [--json]

Runs ``slamobs run LOG`` in a fresh process with an empty numba cache directory (``NUMBA_CACHE_DIR``: nothing
the project cached before is used) and lists what :mod:`pipeline.compile_clock` heard: one row per compiled
function and signature, its own seconds (the functions it compiled on the way excluded), largest first, then
the totals per module. Without ``LOG`` a 3-minute ``figure8`` log is generated (once, in ``<tmp>/slamobs-bench``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

SLAMOBS = Path(sys.executable).with_name("slamobs")

#: Run in the child: the CLI's run command in-process, then the compile log as JSON into the file named last.
CHILD = """
import json, sys
from slamobs.pipeline.compile_clock import compiled_functions
from slamobs.cli.main import main
try:
    main(sys.argv[1:-1], standalone_mode=False)
finally:
    with open(sys.argv[-1], "w") as f:
        json.dump([c.__dict__ for c in compiled_functions()], f)
"""


def default_log() -> Path:
    cache = Path(tempfile.gettempdir()) / "slamobs-bench"
    cache.mkdir(parents=True, exist_ok=True)
    log = cache / "figure8-180s.mcap"
    if not log.exists():
        subprocess.run(
            [str(SLAMOBS), "simulate", "figure8", "--duration", "180", "-o", str(log)],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    return log


def profile(log: Path, observer: str, extra: list[str]) -> tuple[float, list[dict]]:
    """Cold wall seconds of ``slamobs run`` and its compile log."""
    with (
        tempfile.TemporaryDirectory(prefix="slamobs-numba-") as numba_dir,
        tempfile.TemporaryDirectory(prefix="slamobs-out-") as out,
    ):
        env = {**os.environ, "NUMBA_CACHE_DIR": numba_dir}
        dump = Path(out) / "compiled.json"
        args = [
            sys.executable,
            "-c",
            CHILD,
            "run",
            str(log),
            "-o",
            str(Path(out) / "run"),
            "-q",
            "--observer",
            observer,
            *extra,
            str(dump),
        ]
        start = time.perf_counter()
        proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        if os.waitstatus_to_exitcode(status):
            raise SystemExit(os.waitstatus_to_exitcode(status))
        rows = json.loads(dump.read_text())
    return wall, usage.ru_utime + usage.ru_stime, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", nargs="?", type=Path)
    ap.add_argument("--observer", default="fast-adaptation")
    ap.add_argument("--top", type=int, default=40, help="rows of the function table")
    ap.add_argument("--json", action="store_true", help="print the compile log as JSON instead")
    args, extra = ap.parse_known_args()
    log = args.log or default_log()
    wall, cpu_all, rows = profile(log, args.observer, extra)
    if args.json:
        print(json.dumps({"wall_s": wall, "cpu_s": cpu_all, "compiled": rows}))
        return
    own = sum(r["seconds"] for r in rows)
    cpu = sum(r["cpu"] for r in rows)
    print(
        f"# {log.name}, observer {args.observer}, empty numba cache: {wall:.1f} s wall ({cpu_all:.1f} s CPU), "
        f"{len(rows)} compilations, {own:.1f} s compiling ({cpu:.1f} s CPU)"
    )
    print(f"{'CPU s':>6} {'wall s':>6} {'+callees':>8}  function (signature)")
    for r in sorted(rows, key=lambda r: -r["cpu"])[: args.top]:
        sig = r["signature"] if len(r["signature"]) < 90 else r["signature"][:87] + "..."
        print(f"{r['cpu']:>6.2f} {r['seconds']:>6.2f} {r['total']:>8.2f}  {'  ' * r['depth']}{r['function']} ({sig})")
    per_module: dict[str, list[float]] = defaultdict(lambda: [0, 0.0])
    for r in rows:
        m = per_module[r["function"].split(".<locals>")[0].rsplit(".", 1)[0]]
        m[0] += 1
        m[1] += r["cpu"]
    print(f"\n{'module':<50} {'n':>4} {'CPU s':>6}")
    for name, (n, s) in sorted(per_module.items(), key=lambda kv: -kv[1][1]):
        print(f"{name:<50} {n:>4} {s:>6.2f}")


if __name__ == "__main__":
    main()
