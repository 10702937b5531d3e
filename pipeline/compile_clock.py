"""Time numba spends compiling kernels in this process (first runs only: compiled kernels are cached on disk).

numba announces every compilation as a ``numba:compile`` event (not cache loads); a listener counts them and
adds up the time of the outermost ones (a kernel compiles the functions it calls inside its own event).
:func:`compile_watch` lets a caller hear about compilation while it happens (the CLI says so on stderr);
:func:`compiled_functions` lists what was compiled, with each function's own time (its callees' excluded),
which is how the first-run cost is found and kept down (``benchmarks/compile_profile.py``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from numba.core import event


@dataclass(frozen=True)
class Compiled:
    """One compilation: ``module.qualname`` for argument types ``signature``; ``seconds`` its own wall time
    (the functions it compiled on the way excluded), ``total`` with them, ``cpu`` its own CPU time (what a
    busy machine does not inflate), ``depth`` 0 for an outermost one."""

    function: str
    signature: str
    seconds: float
    total: float
    cpu: float
    depth: int


@dataclass(frozen=True)
class CompileMark:
    """Compiled functions and seconds spent compiling so far in this process."""

    functions: int
    seconds: float


class _Clock(event.Listener):
    def __init__(self) -> None:
        self.depth = 0
        self.started = 0.0
        self.functions = 0
        self.seconds = 0.0
        self.watchers: list[Callable[[float, bool], None]] = []
        self.stack: list[list[float]] = []  # per open event: [start, nested seconds, start CPU, nested CPU]
        self.log: list[Compiled] = []

    def on_start(self, ev: event.Event) -> None:
        now = time.perf_counter()
        if self.depth == 0:
            self.started = now
        self.depth += 1
        self.stack.append([now, 0.0, time.process_time(), 0.0])
        self._tell()

    def on_end(self, ev: event.Event) -> None:
        now = time.perf_counter()
        self.depth -= 1
        self.functions += 1
        if self.depth == 0:
            self.seconds += now - self.started
        if self.stack:
            start, nested, cpu_start, cpu_nested = self.stack.pop()
            total, cpu = now - start, time.process_time() - cpu_start
            if self.stack:
                self.stack[-1][1] += total
                self.stack[-1][3] += cpu
            self.log.append(
                Compiled(_name(ev.data), _signature(ev.data), total - nested, total, cpu - cpu_nested, self.depth)
            )
        self._tell()

    def now(self) -> float:
        """Seconds compiled so far, the compilation under way included."""
        return self.seconds + (time.perf_counter() - self.started if self.depth else 0.0)

    def _tell(self) -> None:
        for watcher in list(self.watchers):
            watcher(self.now(), self.depth > 0)


def _name(data) -> str:
    func = getattr((data or {}).get("dispatcher"), "py_func", None)
    return f"{func.__module__}.{func.__qualname__}" if func is not None else "?"


def _signature(data) -> str:
    return ", ".join(str(a) for a in (data or {}).get("args", ()))


_CLOCK: _Clock | None = None
_LOCK = threading.Lock()


def _clock() -> _Clock:
    global _CLOCK
    with _LOCK:
        if _CLOCK is None:
            _CLOCK = _Clock()
            event.register("numba:compile", _CLOCK)
        return _CLOCK


def compile_mark() -> CompileMark:
    """What has been compiled so far (the listener is registered on first use)."""
    clock = _clock()
    return CompileMark(clock.functions, clock.seconds)


@contextmanager
def compile_watch(callback: Callable[[float, bool], None]) -> Iterator[None]:
    """Inside the block ``callback(seconds, compiling)`` is called at every compile event: seconds spent
    compiling since the block began, and whether a compilation is under way."""
    clock = _clock()
    base = clock.now()

    def watcher(now: float, compiling: bool) -> None:
        callback(now - base, compiling)

    clock.watchers.append(watcher)
    try:
        yield
    finally:
        clock.watchers.remove(watcher)


def compiled_since(mark: CompileMark) -> CompileMark:
    """What was compiled after ``mark``."""
    now = compile_mark()
    return CompileMark(now.functions - mark.functions, now.seconds - mark.seconds)


def compiled_functions() -> list[Compiled]:
    """Every compilation heard in this process so far, in the order they finished."""
    return list(_clock().log)
