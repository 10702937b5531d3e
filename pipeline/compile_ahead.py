"""A first run's kernels compiled in a helper process while the run imports and reads its log.

A first run (nothing in the kernel cache, or sources changed) compiles every kernel it calls, one after the
other, in its own process: the readers' while it reads, the estimator's when the estimator starts, the report's
when it evaluates. Only the readers' are needed at once. With a core to spare, :func:`start` hands the
estimator's and the report's (:data:`PLANS`: kernels a run calls from Python after reading, for the argument
types it calls them with; the alignment's small one the run compiles itself while it would wait) to a helper
process that compiles them into the on-disk kernel cache while the run reads. When the run reaches such a kernel
and the helper has not compiled it yet, the run waits for it (its cache lookup does, :func:`waiting_load`)
instead of compiling it a second time, then loads it from the cache. The compiled code is the one the run would
have compiled itself: same compiler, same sources, same types.

Nothing depends on the helper: one that fails, is killed or has not answered within :data:`MAX_WAIT_S` only
means the run compiles the kernel itself; a warm run (every planned kernel's cache index present) starts none.
The helper is bound to its run (:func:`~slamobs.pipeline.lifetime.bind_to_parent`): SIGKILL or SIGTERM of the
run takes it along; it ignores Ctrl-C (the run decides what that means) and is killed when the run ends.
``SLAMOBS_COMPILE_AHEAD=0`` never starts it, ``=1`` starts it even without a spare core (tests, benchmarks).

This module imports nothing heavy at its top: the helper binds itself to the run before it imports numba.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

from slamobs.pipeline import interrupts, lifetime

#: Kernels compiled ahead: (module, function, argument types) in the order a run first calls them. Types are
#: written short: ``f``, ``i``, ``b`` a float64, int64 or bool scalar, ``f2`` a C-contiguous 2-d float64 array.
#: ``tests/test_compile_ahead.py`` checks each against the types a run calls it with. An estimator's entry is
#: called by that estimator, ``report`` by the report. The alignment's kernel (``lie.rots_quats_into``, for
#: logs with ground truth of at least ``lie.ROTATION_KERNEL_ROWS`` poses; shorter ones take array code) is not
#: handed over: the helper's path (its start-up, then the estimator's event loop) is the longer one, and the run
#: compiles that kernel in ~0.3 s while the helper is still on the loop; the report's quaternions are the same
#: kernel.
#: The time offset's decision (``time_offset.decide``, before an observer starts; the first part of riekf's
#: ``estimate``), in the order it calls them.
TIME_OFFSET_DECISION: tuple[tuple[str, str, str], ...] = (
    ("slamobs.pipeline.observers.time_offset", "_partners", "i1 f1 i1 f1"),
    ("slamobs.pipeline.lie", "integrate_body_twists", "f2 f1 f2 f2 f1"),
    ("slamobs.pipeline.observers.time_offset", "_pair_residuals", "f1 f3 f2 f2 f2 f1 f2 i1 i1 f1 f3"),
    ("slamobs.pipeline.lie", "integrate_body_twists_at_rotation_columns", "f2 f1 f2 f2 f2 f1 i1"),
    ("slamobs.pipeline.lie", "integrate_body_twists_at_columns", "f2 f1 f2 f2 f2 f1 i1"),
    ("slamobs.pipeline.observers.time_offset", "_trimmed_costs", "f3 f3 f3 f1"),
)
PLANS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "fast-adaptation": (
        *TIME_OFFSET_DECISION,
        (
            "slamobs.pipeline.observers.fast_adaptation",
            "_advance",
            "f1 f2 f2 f1 i1 i1 f2 f2 b1 f f f f i f i i i f2 f1 f1 f1 f2 i1 f1 f1 i1 f2 f1 f1 i1 i1 f3 f2 f2 f2 f2 i",
        ),
    ),
    # riekf: the run compiles its event loop itself (~28 of its ~47 CPU s on figure8.mcap; the run reaches it
    # first, after the readers' and the dead reckoning's); the helper takes what the run calls after it, the
    # time-offset search's and the report's (~11 s), so the run finds them compiled when the loop is done.
    "riekf": (
        *TIME_OFFSET_DECISION,
        ("slamobs.pipeline.lie", "integrate_body_twists_at", "f2 f1 f2 f2 f1 i1"),
        ("slamobs.pipeline.observers.time_offset", "lagged_positions", "f1 f3 f2 f2 f1 b1 f1 i1 f3"),
        ("slamobs.pipeline.evaluation.sync", "_slerp_rows", "f2 f2 f1"),
    ),
    # batch: the run seeds with dead reckoning, the time-offset search and fast-adaptation, then solves and only
    # then runs riekf (~33 of its ~80 CPU s on figure8.mcap), ~45 s into its compiling: the helper has it by then.
    "batch": (
        (
            "slamobs.pipeline.observers.riekf",
            "_advance",
            "f1 f2 f2 f1 f1 f1 i1 i1 f2 f1 f2 f1 f1 f f f f f1 b1 i i i f2 f1 f1 f1 f1 f1 i1 f1 i1 f2 i1 i1 f3 f2 f2 "
            "f2 i1 f1 f2 f1 f2 i1 f2 f1 f3 i1 f1 b1 b1 f2 f2 f2 f2 i1 f3 f2 f2 f2 f2 i f3 f3",
        ),
        ("slamobs.pipeline.smoother.preintegration", "sample_poses", "f1 f2 f2 f1 f3 f2 f2 i1 f3 f2"),
        ("slamobs.pipeline.evaluation.sync", "_slerp_rows", "f2 f2 f1"),
    ),
    # report: the truth's spikes are found on its own poses' interpolation (``truth_spikes``) before anything else
    "report": (
        ("slamobs.pipeline.evaluation.sync", "_slerp_rows", "f2 f2 f1"),
        ("slamobs.pipeline.evaluation.rpe", "_consecutive_by_accumulation", "f1 f i1"),
    ),
}

#: How long a run waits for one kernel from the helper before compiling it itself (the longest, fast-adaptation's
#: event loop, takes 3-8 s on the 2-core VM).
MAX_WAIT_S = 60.0
#: ``SLAMOBS_COMPILE_AHEAD``: ``0`` never, ``1`` always (when something is to compile), unset: with a spare core.
ENV = "SLAMOBS_COMPILE_AHEAD"
#: What the helper prints after each kernel (compiled, loaded or failed alike), followed by its name.
DONE = "compiled "


def plan(estimator: str) -> tuple[tuple[str, str, str], ...]:
    """The kernels of a run of ``estimator`` the helper compiles, in the order the run calls them (an estimator
    without an entry: the report's only)."""
    return PLANS.get(estimator, ()) + PLANS["report"]


def argument_types(spec: str) -> tuple:
    """numba argument types of a short spec (see :data:`PLANS`)."""
    from numba.core import types

    scalars = {"f": types.float64, "i": types.int64, "b": types.boolean}
    return tuple(scalars[t] if len(t) == 1 else types.Array(scalars[t[0]], int(t[1:]), "C") for t in spec.split())


def _dispatcher(module: str, name: str):
    import importlib

    return getattr(importlib.import_module(module), name)


def missing(entries) -> list[tuple[str, str, str]]:
    """The entries whose kernel is not compiled for the current sources yet."""
    from slamobs.pipeline.kernel_cache import cached

    return [e for e in entries if not cached(e[0], e[1])]


def wanted(spare_cores: int) -> bool:
    """Whether to compile ahead: with a core to spare and no address-space limit (each helper is a second
    compiler's worth of memory), unless :data:`ENV` says otherwise."""
    choice = os.environ.get(ENV, "")
    if choice in ("0", "1"):
        return choice == "1"
    try:
        import resource

        if resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY:
            return False
    except (ImportError, OSError, ValueError):
        return False
    return spare_cores > 0


class CompileAhead:
    """The helper and what it has finished: it starts before the run knows its estimator, gets the kernels to
    compile with :meth:`give`, and :meth:`wait_for` blocks until one of them is compiled."""

    def __init__(self) -> None:
        self.pending: set[str] = set()
        self.done: set[str] = set()
        self.ended = False
        self.cond = threading.Condition()
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", __name__, str(os.getpid())],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
        )
        try:
            threading.Thread(target=self._listen, name="slamobs-compile-ahead", daemon=True).start()
        except RuntimeError:  # no thread to spare
            self.close()
            raise

    def give(self, entries: list[tuple[str, str, str]]) -> None:
        """Hand the helper its kernels (none: it ends)."""
        self.pending = {f"{m}.{n}" for m, n, _ in entries}
        try:
            self.proc.stdin.write(b"".join(f"{':'.join(e)}\n".encode() for e in entries))
            self.proc.stdin.close()
        except OSError:  # the helper is gone: the run compiles them itself
            self.pending = set()

    def _listen(self) -> None:
        for line in self.proc.stdout:
            text = line.decode(errors="replace").strip()
            if text.startswith(DONE):
                with self.cond:
                    self.done.add(text[len(DONE) :])
                    self.cond.notify_all()
        with self.cond:
            self.ended = True
            self.cond.notify_all()

    def wait_for(self, name: str) -> None:
        """Return once the helper has compiled ``name``, has ended, or :data:`MAX_WAIT_S` have passed (at once
        for a kernel it does not compile). A Ctrl-C or SIGTERM meanwhile is raised here (main thread)."""
        if name not in self.pending:
            return
        limit = time.monotonic() + MAX_WAIT_S
        with self.cond:
            while name not in self.done and not self.ended and time.monotonic() < limit:
                self.cond.wait(0.05)
                if threading.current_thread() is threading.main_thread():
                    interrupts.check()

    def close(self) -> None:
        """Stop the helper if it still runs."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for pipe in (self.proc.stdin, self.proc.stdout):
            try:
                pipe.close()
            except OSError:
                pass


_ACTIVE: CompileAhead | None = None


def waiting_load(load):
    """numba's ``Cache.load_overload``, waiting first for the helper when it is compiling that kernel."""

    def load_overload(self, sig, target_context):
        helper = _ACTIVE
        if helper is not None:
            func = self._py_func
            helper.wait_for(f"{func.__module__}.{func.__qualname__}")
        return load(self, sig, target_context)

    load_overload.slamobs_waits_for_helper = True
    return load_overload


def start_early(spare_cores: int) -> CompileAhead | None:
    """The helper, started before the run reads its configuration (its start-up then overlaps the run's
    imports), when :func:`wanted` and the kernels every run calls are not compiled for these sources; None
    otherwise. Call from the main thread (the helper dies with the thread that started it)."""
    if not wanted(spare_cores):
        return None
    from slamobs.pipeline.kernel_cache import cached

    module, name, _ = PLANS["report"][0]
    return None if cached(module, name) else _spawn()


def _spawn() -> CompileAhead | None:
    """A new helper, or None when it cannot start (no process, descriptor or thread to spare: the run, which
    needs fewer, goes on and compiles in process)."""
    try:
        return CompileAhead()
    except (OSError, RuntimeError):
        return None


def start(estimator: str, spare_cores: int, helper: CompileAhead | None = None) -> CompileAhead | None:
    """Give ``helper`` (or a helper started now, when :func:`wanted`) the kernels of a run of ``estimator`` that
    are not cached yet; the helper compiling them, or None (``helper`` stopped) when there are none."""
    global _ACTIVE
    todo = missing(plan(estimator)) if helper is not None or wanted(spare_cores) else []
    if todo and helper is None:
        helper = _spawn()
    if not todo or helper is None:
        stop(helper)
        return None
    from numba.core import caching

    if not getattr(caching.Cache.load_overload, "slamobs_waits_for_helper", False):
        caching.Cache.load_overload = waiting_load(caching.Cache.load_overload)
    _ACTIVE = helper
    helper.give(todo)
    return helper


def stop(helper: CompileAhead | None) -> None:
    """End ``helper`` (None: nothing) and wait for it no more."""
    global _ACTIVE
    if helper is not None:
        if _ACTIVE is helper:
            _ACTIVE = None
        helper.close()


def _compile(lines) -> None:
    """The helper's work: compile each ``module:function:types`` line into the kernel cache as it arrives,
    saying so after each."""
    from slamobs.pipeline.kernel_cache import njit

    njit(lambda: 0)()  # numba's compiler starts up (~0.4 s) while the run reads its configuration
    for line in lines:
        module, name, spec = line.decode().strip().split(":")
        try:
            _dispatcher(module, name).compile(argument_types(spec))
        except Exception:  # noqa: BLE001 - the run compiles it itself and reports what goes wrong
            pass
        sys.stdout.write(f"{DONE}{module}.{name}\n")
        sys.stdout.flush()


if __name__ == "__main__":
    lifetime.bind_to_parent(int(sys.argv[1]))
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import slamobs.pipeline.kernel_cache  # noqa: F401 - the cache locator, before any kernel module

    _compile(sys.stdin.buffer)
