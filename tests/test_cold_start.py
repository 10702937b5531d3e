"""What a run compiles: a first run (empty kernel cache) pays for every kernel it compiles, so a fast-adaptation
run compiles (or loads) the kernels it calls and none of riekf, the smoother or the other observers."""

from __future__ import annotations

import json
import os
import subprocess
import sys

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
    "slamobs.pipeline.observers.time_offset",
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
    )
    assert out.returncode == 0, out.stderr
    kernels = json.loads(out.stdout.strip().splitlines()[-1])
    # the observer's own event loop, for one set of argument types
    assert kernels["slamobs.pipeline.observers.fast_adaptation._advance"] == 1
    # its helpers are subroutines compiled inside it, not kernels of their own (kernel_cache.subroutine)
    helpers = ("._integrate", "._substeps", ".se3_exp_into", ".project_so3_into", "._quat_of_rot", "._rot_of_quat")
    assert [k for k in kernels if k.endswith(helpers)] == []
    assert [k for k in kernels if k.startswith(OTHERS)] == []


def test_the_event_loop_takes_its_small_state_arrays_packed():
    """A first run compiles a Python wrapper that unboxes each array argument of a kernel (~4-8 ms of compiling
    each): fast-adaptation's event loop takes its state's small arrays as rows of two (19 arrays, were 27), and
    the state's attributes are views of them, so what the kernel writes is what the stepper reads."""
    import numpy as np
    from numba.core import types

    from slamobs.pipeline import compile_ahead
    from slamobs.pipeline.observers import fast_adaptation

    ((_, name, spec),) = compile_ahead.PLANS["fast-adaptation"]
    assert name == "_advance"
    assert sum(isinstance(t, types.Array) for t in compile_ahead.argument_types(spec)) <= 19
    state = fast_adaptation._State(4, np.eye(3), np.arange(3.0), np.ones(3), np.full(3, 2.0))
    assert len(state.arrays()) == 4
    for attr in ("r_hat", "p_hat", "b_om", "b_v", "om_m", "v_m", "d_r", "d_p", "fs"):
        assert np.shares_memory(getattr(state, attr), state.st), attr
    for attr in ("ns", "counter"):
        assert np.shares_memory(getattr(state, attr), state.ni), attr
    assert (state.r_hat == np.eye(3)).all() and (state.p_hat == np.arange(3.0)).all()
    assert (state.b_v == 2.0).all() and state.fs[1] == -np.inf and state.ns[-1] == -1
