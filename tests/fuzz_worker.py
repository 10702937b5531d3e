"""Worker of ``test_fuzz_containers.py``: runs ``slamobs run`` in-process on one damaged log per input line.

Reads JSON lines ``{"dir": CASE_DIR, "log": NAME, "config": PATH}`` from stdin and answers each with one JSON line
(exit code, stderr, a traceback if the command raised, the files of the case directory outside ``out`` and the
run's notes). Kept alive across cases: starting an interpreter with numba, pyarrow and the pipeline costs seconds.
"""

from __future__ import annotations

import json
import os
import sys
import traceback
from pathlib import Path


def main() -> None:
    from click.testing import CliRunner

    from slamobs.cli.main import main as cli

    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        case = json.loads(line)
        here = Path(case["dir"])
        os.chdir(here)
        res = CliRunner().invoke(cli, ["run", case["log"], "-o", "out", "--config", case["config"], "-q"])
        tb = None
        if res.exception is not None and not isinstance(res.exception, SystemExit):
            tb = "".join(traceback.format_exception(res.exception))
        files = sorted(str(p.relative_to(here)) for p in here.rglob("*") if p.parts[len(here.parts)] != "out")
        notes = None
        if (here / "out" / "run.json").is_file():
            notes = json.loads((here / "out" / "run.json").read_text())["notes"]
        os.chdir("/")
        print(
            json.dumps({"code": res.exit_code, "stderr": res.stderr, "traceback": tb, "files": files, "notes": notes}),
            flush=True,
        )


if __name__ == "__main__":
    main()
