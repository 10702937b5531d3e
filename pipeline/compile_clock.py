"""Time numba spends compiling kernels in this process (first runs only: compiled kernels are cached on disk).

numba announces every compilation as a ``numba:compile`` event (not cache loads); a listener counts them and
adds up the time of the outermost ones (a kernel compiles the functions it calls inside its own event).
:func:`compile_watch` lets a caller hear about compilation while it happens (the CLI says so on stderr).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from numba.core import event


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

    def on_start(self, ev: event.Event) -> None:
        if self.depth == 0:
            self.started = time.perf_counter()
        self.depth += 1
        self._tell()

    def on_end(self, ev: event.Event) -> None:
        self.depth -= 1
        self.functions += 1
        if self.depth == 0:
            self.seconds += time.perf_counter() - self.started
        self._tell()

    def now(self) -> float:
        """Seconds compiled so far, the compilation under way included."""
        return self.seconds + (time.perf_counter() - self.started if self.depth else 0.0)

    def _tell(self) -> None:
        for watcher in list(self.watchers):
            watcher(self.now(), self.depth > 0)


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
