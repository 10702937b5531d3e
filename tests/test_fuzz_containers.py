"""Fuzz: flipped bytes and cuts at random points of a ROS1 bag, an MCAP file and a rosbag2 sqlite3 log.

Every case ends with exit code 0 (a cut recording says that it was cut) or exit code 2 and one ``error:`` line:
never a traceback, never a hang, never a file outside the output directory. The cases run in two long-lived
worker processes (``fuzz_worker.py``) with a watchdog per case: a case that does not answer in time is a hang,
its worker is replaced and the remaining cases go on.
"""

from __future__ import annotations

import json
import random
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from slamobs.pipeline.simulate import simulate, write_log

from container_logs import write_container  # noqa: E402 - the multi-chunk writers of the reader tests

SEED = 1616
CASES_PER_CONTAINER = 70
WORKERS = 2
HANG_S = 60.0  # a case that takes longer is a hang (a normal one takes well under a second)
WORKER = Path(__file__).with_name("fuzz_worker.py")


def _mutate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    kind = rng.choice(("flip", "cut", "flip+cut"))
    out = bytearray(data)
    if "flip" in kind:
        for _ in range(rng.randint(1, 16)):
            out[rng.randrange(len(out))] ^= rng.randrange(1, 256)
    if "cut" in kind:
        out = out[: rng.randrange(1, len(out))]
    return bytes(out), kind


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    """(case directory, log name, mutation, container) for every case, the damaged log written in place."""
    root = tmp_path_factory.mktemp("fuzz")
    sim = simulate("figure8", duration=2.0, seed=8)
    bases = {
        "bag": write_container(sim, root / "base.bag", "bag", "lz4"),
        "mcap": write_container(sim, root / "base.mcap", "mcap", "zstd"),
        "db3": write_log(sim, root / "base_ros2", "ros2"),
    }
    rng = random.Random(SEED)
    out = []
    for container, base in bases.items():
        for k in range(CASES_PER_CONTAINER):
            case = root / f"{container}-{k:03d}"
            case.mkdir()
            if container == "db3":
                shutil.copytree(base, case / "log")
                db = next((case / "log").glob("*.db3"))
                data, kind = _mutate(db.read_bytes(), rng)
                db.write_bytes(data)
                name = "log"
            else:
                data, kind = _mutate(base.read_bytes(), rng)
                name = f"log.{container}"
                (case / name).write_bytes(data)
            out.append((case, name, kind, container))
    (root / "quick.yaml").write_text("evaluation:\n  plots: false\n")
    return root, out


class _Worker:
    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, str(WORKER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        assert json.loads(self._line(HANG_S * 2)) == {"ready": True}

    def _line(self, timeout: float) -> str | None:
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        return self.proc.stdout.readline() if ready else None

    def send(self, case: dict) -> None:
        self.proc.stdin.write(json.dumps(case) + "\n")
        self.proc.stdin.flush()

    def answer(self, timeout: float) -> dict | None:
        line = self._line(timeout)
        return json.loads(line) if line else None

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


def test_damaged_containers_end_cleanly(cases):
    root, todo = cases
    config = str(root / "quick.yaml")
    before_root = sorted(p.name for p in root.iterdir())
    pending = list(todo)
    results: dict[Path, dict] = {}
    workers = [_Worker() for _ in range(WORKERS)]
    busy: dict[int, tuple] = {}
    started: dict[int, float] = {}
    try:
        while pending or busy:
            for w in range(WORKERS):
                if w not in busy and pending:
                    case = pending.pop(0)
                    workers[w].send({"dir": str(case[0]), "log": case[1], "config": config})
                    busy[w], started[w] = case, time.monotonic()
            for w in list(busy):
                got = workers[w].answer(0.05)
                if got is not None:
                    results[busy.pop(w)[0]] = got
                elif time.monotonic() - started[w] > HANG_S:
                    results[busy.pop(w)[0]] = {"hang": True}
                    workers[w].stop()
                    workers[w] = _Worker()
    finally:
        for worker in workers:
            worker.stop()

    problems = []
    codes = {0: 0, 2: 0}
    for case, name, kind, container in todo:
        r = results[case]
        label = f"{case.name} ({kind})"
        if r.get("hang"):
            problems.append(f"{label}: no answer within {HANG_S} s")
            continue
        if r["traceback"]:
            problems.append(f"{label}: traceback\n{r['traceback']}")
            continue
        if r["code"] not in codes:
            problems.append(f"{label}: exit code {r['code']}: {r['stderr']}")
            continue
        codes[r["code"]] += 1
        inputs = [name] + ([f"{name}/{p.name}" for p in (case / name).iterdir()] if (case / name).is_dir() else [])
        if sorted(r["files"]) != sorted(inputs):  # nothing but the input and ``out``, no hidden leftover
            problems.append(f"{label}: files outside the output {r['files']}")
        err = r["stderr"].strip()
        if r["code"] == 2:
            if len(err.splitlines()) != 1 or not err.startswith("error: "):
                problems.append(f"{label}: not one error line: {err!r}")
            if (case / "out").exists():
                problems.append(f"{label}: output left behind after a failure")
        else:
            if r["notes"] is None:
                problems.append(f"{label}: exit 0 without run.json")
            elif (
                "cut" in kind
                and container != "db3"
                and not any("incomplete" in n or "damaged" in n for n in r["notes"])
            ):
                problems.append(f"{label}: a cut recording ran without saying so: {r['notes']}")
    assert sorted(p.name for p in root.iterdir()) == before_root  # nothing written next to the cases
    assert not problems, "\n".join(problems)
    assert codes[0] and codes[2], codes  # the damage both was survived and was refused somewhere
