"""Ctrl-C, SIGTERM and SIGHUP as an exception raised only where unwinding is safe.

Python raises a signal's exception wherever the main thread is. Inside numba's or llvmlite's compiler locks,
a thread start or a queue's condition, that leaves a lock held or a thread nobody stops: a SIGTERM while a
cached kernel loaded hung a run forever (a reading thread waited for llvmlite's lock), crashed it (a writer
thread outlived its tables) or was swallowed as a ``SystemError`` of a compiled call. So the CLI's handler
(:func:`raise_when_safe`) records the request and raises :class:`Interrupted` at once only when no frame of
the main thread's stack is in such code; otherwise it looks again every :data:`RETRY_S` seconds. The pipeline
also calls :func:`check` between stretches and before an output is published, so a request is never lost
(an exception raised inside a finalizer is printed and dropped by Python). The price is latency where the
main thread stays long in such code: a kernel's first compilation (a SIGTERM waited 0.4-2.5 s for it).
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

from slamobs.pipeline.errors import Interruption

RETRY_S = 0.02
#: Top-level modules a signal's exception must not unwind through: compiler and thread-pool locks, thread
#: starts and joins, queue conditions, imports, finalizers and child-process starts.
UNSAFE_MODULES = frozenset(
    {
        "numba",
        "llvmlite",
        "concurrent",
        "threading",
        "queue",
        "weakref",
        "subprocess",
        "multiprocessing",
        "tempfile",
        "shutil",
        "importlib",
        "_frozen_importlib",
        "_frozen_importlib_external",
    }
)

#: Handled like SIGTERM unless inherited as ignored (a background job's SIGINT, ``nohup``'s SIGHUP): a closed
#: terminal's SIGHUP killed a run at once (exit 129, no message) and left its temporary output behind.
HANGUP_LIKE = (signal.SIGINT, signal.SIGHUP)
#: The signal number of a pending Ctrl-C/SIGTERM/SIGHUP, None when there is none.
requested: int | None = None
_raised = False
_critical = 0  # depth of :func:`critical` blocks
_main_critical = 0  # ... of those the main thread is in
_after_critical: list = []  # what :func:`after_critical` deferred to the end of the main thread's critical block
#: Outputs published under their final names since the command began (its interrupted message names them).
published: list[str] = []


class Interrupted(Interruption):
    """Ctrl-C or SIGTERM, raised like Ctrl-C's KeyboardInterrupt so every ``finally`` and cleanup runs."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def check() -> None:
    """Raise :class:`Interrupted` if a Ctrl-C or SIGTERM is pending (a safe point of the main thread)."""
    global _raised
    if requested is not None and threading.current_thread() is threading.main_thread():
        _raised = True
        raise Interrupted(requested)


def interruption(err: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM (a KeyboardInterrupt) that ``err`` was raised while handling, if any.

    A signal raises its KeyboardInterrupt wherever the main thread is; raised inside a compiled function's
    call it comes back as a ``SystemError`` ("returned a result with an exception set"), and a writer closed
    half way through a table raises its own error on the way out. Such an error is the interruption, not a
    bad input or a failed report: callers that turn errors into messages or notes check this first."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return err
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return None


@contextmanager
def as_interruption():
    """An error raised by a signal's unwinding (see :func:`interruption`) leaves the block as that signal's
    KeyboardInterrupt, so callers that turn errors into messages, notes or failed rows never see it."""
    try:
        yield
    except Exception as err:
        if (stop := interruption(err)) is not None:
            raise stop from None
        raise


@contextmanager
def critical():
    """A block a signal must not cut in two (several renames that make one output): raised after it (by this
    module's handler, or by a command's own through :func:`after_critical`)."""
    global _critical, _main_critical
    main = threading.current_thread() is threading.main_thread()
    _critical += 1
    _main_critical += main
    try:
        yield
    finally:
        _critical -= 1
        _main_critical -= main
        if main and not _main_critical and _after_critical:
            action = _after_critical.pop(0)
            _after_critical.clear()
            action()


def after_critical(action) -> bool:
    """For a command's own signal handler (batch's and tune's :func:`cli.jobs.on_signal`, which raise at once, not at
    a safe point): when the main thread is in a :func:`critical` block, run ``action`` (the handler's raise) as the
    block ends and return True; False outside one (act now). Without it a first SIGTERM cut ``DaskPool.close`` in
    two and skipped the batch's staging clean-up after it (a stopped batch left its staging directory)."""
    if not _main_critical or threading.current_thread() is not threading.main_thread():
        return False
    _after_critical.append(action)
    return True


def _unsafe(frame) -> bool:
    """In a :func:`critical` block, or some frame of the stack from ``frame`` down is in :data:`UNSAFE_MODULES`
    or a finalizer."""
    if _critical:
        return True
    while frame is not None:
        module = frame.f_globals.get("__name__") or ""
        if module.partition(".")[0] in UNSAFE_MODULES or frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


def _on_signal(signum: int, frame) -> None:
    global requested
    if requested is None:
        requested = signum
    _raise_if_safe(frame)


def _on_retry(_signum: int, frame) -> None:
    if requested is not None and signal.getsignal(signal.SIGTERM) is _on_signal:  # not handed over
        _raise_if_safe(frame)


def take_pending() -> int | None:
    """For a command that handles SIGINT and SIGTERM itself from now on (batch, tune): stop looking for a safe
    point and return the signal that arrived before its handlers were installed, if one did (it raises it its own
    way)."""
    global _raised
    signal.setitimer(signal.ITIMER_REAL, 0)
    if requested is not None and not _raised:
        _raised = True
        return requested
    return None


def note_published(path) -> None:
    """Record that ``path`` now holds a complete output under its final name."""
    published.append(str(path))


def _raise_if_safe(frame) -> None:
    global _raised
    if _raised:  # the clean-up of the first signal runs; a second one must not cut it short
        return
    if _unsafe(frame):
        signal.setitimer(signal.ITIMER_REAL, RETRY_S)
        return
    _raised = True
    raise Interrupted(requested)


@contextmanager
def raise_when_safe():
    """While the block runs (main thread only), SIGTERM, SIGINT and SIGHUP (the last two unless inherited as
    ignored, as in a background job or under ``nohup``) raise :class:`Interrupted` at the first safe point; a request
    still pending when the block
    ends (the command finished in code where raising was unsafe) is raised then. Afterwards the previous handlers
    are back and nothing is pending."""
    global requested, _raised
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    published.clear()
    signals = [signal.SIGTERM] + [sig for sig in HANGUP_LIKE if signal.getsignal(sig) is not signal.SIG_IGN]
    previous = {sig: signal.signal(sig, _on_signal) for sig in signals}
    previous[signal.SIGALRM] = signal.signal(signal.SIGALRM, _on_retry)
    try:
        yield
        if requested is not None and not _raised:
            _raised = True
            raise Interrupted(requested)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        requested, _raised = None, False
