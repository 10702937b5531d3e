"""What a command shows on stderr while it works: a self-overwriting status line on a terminal, and the notice
that numba is compiling the numeric kernels (first run only), with or without a terminal."""

from __future__ import annotations

import os
import sys
import threading
import time
from contextlib import contextmanager

import click

COMPILING = "compiling numeric kernels, first run only"


class StatusLine:
    """What a command is doing and since when, as one self-overwriting line on a terminal's stderr (long logs
    and first runs take a while); ``compiling`` adds the compile notice to the line."""

    #: Seconds between two redraws for the compile notice alone (numba reports every function it compiles).
    REDRAW_S = 0.25

    def __init__(self) -> None:
        self._start = time.perf_counter()
        self._message = ""
        self._compile = ""
        self._drawn = 0.0

    def __call__(self, message: str) -> None:
        self._message = message
        self._show()

    def compiling(self, seconds: float, active: bool = True) -> None:
        """Show (``active``) or drop the compile notice with the seconds compiled so far."""
        text = f"{COMPILING}: {seconds:.0f} s ..." if active else ""
        if text != self._compile and (
            time.perf_counter() - self._drawn >= self.REDRAW_S or not text or not self._compile
        ):
            self._compile = text
            self._show()

    def _show(self) -> None:
        text = " | ".join(t for t in (self._message, self._compile) if t)
        self._drawn = time.perf_counter()
        click.echo(f"\r\x1b[K[{self._drawn - self._start:6.1f} s] {text}", nl=False, err=True)

    def clear(self) -> None:
        click.echo("\r\x1b[K", nl=False, err=True)


#: Seconds between two progress lines when stderr is not a terminal (a log file, CI); the environment variable
#: ``SLAMOBS_PROGRESS_EVERY`` sets another.
LINE_EVERY_S = 10.0


class Progress:
    """A command's progress, used as ``with Progress(quiet) as progress: work(progress=progress)``: on a terminal
    the status line (redrawn each second, so its clock runs while one step lasts), otherwise a plain line
    ``[  10.0 s] what it does`` every ``LINE_EVERY_S`` while the command works (the last message again when a
    step is long; a command done sooner prints none); nothing when ``quiet``. ``status`` is the terminal's
    :class:`StatusLine` (None elsewhere), for :func:`compile_notice`."""

    def __init__(self, quiet: bool = False, every_s: float | None = None) -> None:
        self.quiet = quiet
        self.status = status_line(quiet)
        self.every = every_s if every_s is not None else float(os.environ.get("SLAMOBS_PROGRESS_EVERY", LINE_EVERY_S))
        self.message = ""
        self.compile = ""  # the compile notice while numba compiles (:func:`compile_notice`), added to each line
        self._start = self._printed = time.perf_counter()  # a command done (or failed) sooner prints nothing
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None

    def __call__(self, message: str) -> None:
        if self.quiet:
            return
        with self._lock:
            self.message = message
            if self.status is not None:
                self.status(message)
            elif time.perf_counter() - self._printed >= self.every:
                self._line()

    def compiling(self, seconds: float, active: bool = True) -> None:
        """The compile notice on the plain lines that follow (``active``), or none: a step's count that stays at
        0 for a minute is then read as the kernels compiling, not as a hang (riekf's first run on a log file)."""
        with self._lock:
            self.compile = f"{COMPILING}: {seconds:.0f} s so far" if active else ""

    def _line(self) -> None:
        self._printed = time.perf_counter()
        text = " | ".join(t for t in (self.message, self.compile) if t)
        click.echo(f"[{self._printed - self._start:6.1f} s] {text}", err=True)

    def _heartbeat(self) -> None:
        while not self._stop.wait(1.0 if self.status is not None else self.every / 2):
            with self._lock:
                if not self.message:
                    continue
                if self.status is not None:
                    self.status._show()
                elif time.perf_counter() - self._printed >= self.every:
                    self._line()

    def __enter__(self) -> Progress:
        if not self.quiet:
            self._beat = threading.Thread(target=self._heartbeat, daemon=True)
            self._beat.start()
        return self

    def __exit__(self, *_exc) -> None:
        self._stop.set()
        if self._beat is not None:
            self._beat.join()
        if self.status is not None:
            self.status.clear()


def status_line(quiet: bool) -> StatusLine | None:
    """A status line when stderr is a terminal and the command is not quiet, else None."""
    return StatusLine() if not quiet and sys.stderr.isatty() else None


@contextmanager
def compile_notice(status: StatusLine | None = None, *, quiet: bool = False, lines: Progress | None = None):
    """Say on stderr when numba starts compiling inside the block: on ``status`` (or a terminal line of its
    own) with the seconds so far, else one plain line, and on each of ``lines``' progress lines while it lasts;
    nothing when ``quiet``."""
    if quiet:
        yield
        return
    from slamobs.pipeline.compile_clock import compile_watch

    own = status is None and sys.stderr.isatty()
    line = StatusLine() if own else status
    said = False

    def on_compile(seconds: float, active: bool) -> None:
        nonlocal said
        if line is not None:
            line.compiling(seconds, active)
        else:
            if not said:
                click.echo(f"{COMPILING} ...", err=True)
            if lines is not None:
                lines.compiling(seconds, active)
        said = True

    try:
        with compile_watch(on_compile):
            yield
    finally:
        if own and said:
            line.clear()
