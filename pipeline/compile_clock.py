"""Time numba spends compiling kernels in this process (first runs only: compiled kernels are cached on disk).

numba announces every compilation as a ``numba:compile`` event (not cache loads); a listener counts them and
adds up the time of the outermost ones (a kernel compiles the functions it calls inside its own event).
"""

from __future__ import annotations

import threading
import time
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

    def on_start(self, ev: event.Event) -> None:
        if self.depth == 0:
            self.started = time.perf_counter()
        self.depth += 1

    def on_end(self, ev: event.Event) -> None:
        self.depth -= 1
        self.functions += 1
        if self.depth == 0:
            self.seconds += time.perf_counter() - self.started


_CLOCK: _Clock | None = None
_LOCK = threading.Lock()


def compile_mark() -> CompileMark:
    """What has been compiled so far (the listener is registered on first use)."""
    global _CLOCK
    with _LOCK:
        if _CLOCK is None:
            _CLOCK = _Clock()
            event.register("numba:compile", _CLOCK)
        return CompileMark(_CLOCK.functions, _CLOCK.seconds)


def compiled_since(mark: CompileMark) -> CompileMark:
    """What was compiled after ``mark``."""
    now = compile_mark()
    return CompileMark(now.functions - mark.functions, now.seconds - mark.seconds)
