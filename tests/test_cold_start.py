"""What a run compiles: a first run (empty kernel cache) pays for every kernel it compiles, so a fast-adaptation
run compiles (or loads) the kernels it calls (the time offset's decision's among them) and none of riekf, the smoother
or the other observers; on one core, none of the readers' either for a short log."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.cli_checks import SAMPLES

#: Run in the child: ``slamobs run`` in-process, then every numba dispatcher's module, name and signatures.
CHILD = """
import gc, json, sys
from numba.core.registry import CPUDispatcher
from slamobs.cli.main import main
main(["run", sys.argv[1], "-o", sys.argv[2], "-q", "--observer", "fast-adaptation"], standalone_mode=False)
found = {}
for d in gc.get_objects():
    if isinstance(d, CPUDispatcher) and d.overloads:
        found[f"{d.py_func.__module__}.{d.py_func.__qualname__}"] = len(d.overloads)
print(json.dumps(found))
"""

#: Modules whose kernels only other estimators use.
OTHERS = (
    "slamobs.pipeline.observers.riekf",
    "slamobs.pipeline.observers.hashim",
    "slamobs.pipeline.observers.wang_tayebi",
    "slamobs.pipeline.observers.hybrid",
    "slamobs.pipeline.smoother.",
)


def test_a_fast_adaptation_run_has_no_kernel_of_another_estimator(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(SAMPLES / "figure8.mcap"), str(tmp_path / "run")],
        capture_output=True,
        text=True,
        env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")},  # a first run: every kernel compiled
        preexec_fn=lambda: os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}),  # on one core
    )
    assert out.returncode == 0, out.stderr
    kernels = json.loads(out.stdout.strip().splitlines()[-1])
    # the observer's own event loop, for one set of argument types, and the time offset's decision before it
    # (time_offset.decide, session 33), each once
    assert kernels["slamobs.pipeline.observers.fast_adaptation._advance"] == 1
    assert kernels["slamobs.pipeline.observers.time_offset._trimmed_costs"] == 1
    # its helpers are subroutines compiled inside it, not kernels of their own (kernel_cache.subroutine)
    helpers = (
        "._integrate",
        "._substeps",
        ".se3_exp_into",
        ".project_so3_into",
        "._quat_of_rot",
        "._rot_of_quat",
    )
    assert [k for k in kernels if k.endswith(helpers)] == []
    assert [k for k in kernels if k.startswith(OTHERS)] == []
    # a short log's rotations and quaternions are array code (lie.ROTATION_KERNEL_ROWS): its first run compiles no
    # kernel for them
    assert "slamobs.pipeline.lie.rots_quats_into" not in kernels
    # every topic's frame id is one string: coded by array code (fastdecode._one_string), no string table compiled
    assert "slamobs.pipeline.readers.fastdecode.dedup" not in kernels
    # on one core a short log is read by array code (kernel_cache.worth_compiling): no reader's kernel compiled
    assert [k for k in kernels if k.startswith("slamobs.pipeline.readers.")] == []
    # nor the RPE's consecutive pairs: their indices by array code (rpe.consecutive_by_accumulation)
    assert "slamobs.pipeline.evaluation.rpe._consecutive_by_accumulation" not in kernels


#: Run in the child: ``slamobs run`` in-process, counting the garbage collector's runs before and after the
#: pipeline's last import (``pipeline.run``), then the collector's state once the run is over.
COLLECTIONS = """
import gc, json, sys
from slamobs.cli.main import main
command = sys.argv[3:] or ["run"]
seen = {"before": 0, "after": 0}
def count(phase, info):
    if phase == "start":
        seen["after" if "slamobs.pipeline.run" in sys.modules else "before"] += 1
gc.callbacks.append(count)
main([*command, sys.argv[1], "-o", sys.argv[2], "-q"], standalone_mode=False)
print(json.dumps({**seen, "enabled": gc.isenabled(), "frozen": gc.get_freeze_count()}))
"""


@pytest.mark.parametrize("command", [[], ["compare", "--observers", "fast-adaptation"]], ids=["run", "compare"])
def test_a_run_imports_the_pipeline_without_collections_and_collects_as_before_after(tmp_path, command):
    """``run`` (session 29) and ``compare`` (session 30: 0.26-0.31 CPU s in the collector, 0.06-0.08 with it)."""
    out = subprocess.run(
        [sys.executable, "-c", COLLECTIONS, str(SAMPLES / "figure8.mcap"), str(tmp_path / "run"), *command],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    # numba's, rosbags' and the package's imports made ~150 collections that found next to nothing
    # (lifetime.collected_after_imports); a few may come from the small imports before them
    assert seen["before"] < 20, seen
    # the collector runs during the run, and is as it was (on, nothing frozen) once the run is over
    assert seen["after"] > 0
    assert seen["enabled"] is True
    assert seen["frozen"] == 0


def test_a_batch_worker_runs_its_tasks_with_the_collector_on_and_its_imports_frozen():
    """A local batch worker arrives with its collector off (``lifetime.arrived``: its start-up arguments import the
    pipeline, numba among it); ``worker_main`` imports what its runs need, then runs every task with the collector
    on and those modules frozen out of its collections, and leaves it as it was (session 30: the worker of a
    3-log batch spent 0.20-0.25 CPU s in the collector, 0.16 with it; the batch process 0.16-0.19, 0.03)."""
    import gc
    import multiprocessing
    import signal

    from slamobs.pipeline.batch.lifeline import worker_main

    ours, theirs = multiprocessing.Pipe()
    seen = []
    ours.send("task")
    ours.send(None)
    enabled = gc.isenabled()
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}  # the worker sets its own
    gc.disable()  # as lifetime.arrived leaves it
    try:
        worker_main(None, theirs, lambda task: seen.append((gc.isenabled(), gc.get_freeze_count() > 0)) or {})
        assert seen == [(True, True)]
        assert ours.recv() == ("started", None) and ours.recv() == ("row", {})
        assert gc.isenabled() and gc.get_freeze_count() == 0
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        if not enabled:
            gc.disable()
