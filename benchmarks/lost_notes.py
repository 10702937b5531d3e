"""Does an observer without a gate say when its estimate is lost, and only then? Its APE beside the
map-against-trajectory check (``run.json`` ``observer.resightings``: landmarks seen again after 10 s or more out of
view, their median innovation over the run's usual one) and whether the "likely lost" note fired.

    .venv/bin/python benchmarks/lost_notes.py [--observers fast-adaptation hashim] [--cache DIR] [--only loop mrclam]

Logs: ``session_logs.py``'s ten and ``unseen_logs.py``'s twelve (made in the cache once), the sample logs, each
``slamobs simulate`` scenario at its default noise (seeds 0 and 1), and the real logs of ``real_logs.py``
(MR.CLAM 6 and 7, TagSLAM 11, 21, 22; skipped when ``$SLAMOBS_REALDATA`` is absent). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import real_logs  # benchmarks/ is the script's directory
import session_logs
import unseen_logs

from slamobs.pipeline.api import run_log
from slamobs.pipeline.simulate import SCENARIOS

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"


def logs(cache: Path) -> list[tuple[str, Path, dict]]:
    """(name, path, config) of every log the table covers."""
    out = [(p.name, p, {}) for p in session_logs.make_logs(cache / "session")]
    for case in unseen_logs.CASES:
        for seed in (1, 2, 3):
            out.append((f"unseen {case.name}-s{seed}", unseen_logs.make_log(case, seed, cache / "unseen")[0], {}))
    out += [(f"sample {n}", SAMPLES / n, {}) for n in ("circle.bag", "figure8.mcap")]
    out.append(("sample figure8_camera.mcap", SAMPLES / "figure8_camera.mcap", {"tags": {"size": 0.8}}))
    code = "from slamobs.cli.main import entry; entry()"
    for sc in SCENARIOS:
        for seed in (0, 1):
            path = cache / "simulate" / f"{sc}-s{seed}.mcap"
            if not path.exists():
                path.parent.mkdir(parents=True, exist_ok=True)
                subprocess.run([sys.executable, "-c", code, "simulate", sc, "--seed", str(seed), "-o", str(path)])
            out.append((f"simulate {sc} s{seed}", path, {}))
    wanted = ["mrclam6", "mrclam7", "tagslam-11", "tagslam-21", "tagslam-22"]
    out += [(lg.name, lg.path, lg.config) for lg in real_logs.all_logs(cache / "real", wanted) if not lg.skip]
    return out


def run(log: Path, observer: str, config: dict) -> str:
    """One table row's cells after the log's name: APE, map error, the check's numbers, the note."""
    out = Path(tempfile.mkdtemp(prefix="slamobs-lost-"))
    try:
        run_log(log, out, observer=observer, config=config, force=True)
        meta = json.loads((out / "run.json").read_text())
        rep = json.loads((out / "report.json").read_text()) if (out / "report.json").is_file() else {}
    except Exception as exc:  # an error is a result of the sweep
        return f"error: {str(exc)[:100]} | | | | |"
    finally:
        shutil.rmtree(out, ignore_errors=True)
    ape = ((rep.get("ape") or {}).get("translation_m") or {}).get("rmse")
    map_m = ((rep.get("landmarks") or {}).get("error_m") or {}).get("median")
    check = (meta.get("observer") or {}).get("resightings") or {}
    ratio = check.get("ratio")
    fired = any("likely lost" in n for n in meta.get("notes") or [])
    return " | ".join(
        [
            "-" if ape is None else f"{ape:.3f}",
            "-" if map_m is None else f"{map_m:.3g}",
            str(check.get("detections", "-")),
            "-" if ratio is None else f"{ratio:.2f}",
            "**fires**" if fired else "no",
        ]
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--observers", nargs="+", default=["fast-adaptation"])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slamobs-lost-notes")
    ap.add_argument("--only", nargs="+", help="only logs whose name contains one of these")
    args = ap.parse_args()
    print("| log | observer | APE m | map m | re-sightings | ratio | likely-lost note |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for name, path, config in logs(args.cache):
        if args.only and not any(w in name for w in args.only):
            continue
        config = {**config, "evaluation": {**config.get("evaluation", {}), "plots": False}}
        for obs in args.observers:
            print(f"| {name} | {obs} | {run(path, obs, config)} |", flush=True)


if __name__ == "__main__":
    main()
