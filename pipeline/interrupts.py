"""Ctrl-C, SIGTERM and SIGHUP as an exception raised only where unwinding is safe.

Python raises a signal's exception wherever the main thread is. Inside numba's or llvmlite's compiler locks,
a thread start or a queue's condition, that leaves a lock held or a thread nobody stops: a SIGTERM while a
cached kernel loaded hung a run forever (a reading thread waited for llvmlite's lock), crashed it (a writer
thread outlived its tables) or was swallowed as a ``SystemError`` of a compiled call. So the CLI's handler
(:func:`raise_when_safe`) records the request and raises :class:`Interrupted` at once only when no frame of
the main thread's stack is in such code; otherwise it looks again every :data:`RETRY_S` seconds. The pipeline
also calls :func:`check` between stretches and before an output is published, so a request is never lost
(an exception raised inside a finalizer is printed and dropped by Python). The price is latency where the
main thread stays long in such code: a kernel's first compilation (a SIGTERM waited 0.4-2.5 s for it, and 25 s
for riekf's event loop, whose LLVM optimisation is one call of several seconds that runs no Python handler).

So a command that may end its process (the console script: :func:`raise_when_safe` with ``farewell``) has a
watching thread woken by every signal (the wakeup fd): when the main thread is still inside numba's compiler
:data:`COMPILER_GRACE_S` after a stop signal, the watcher ends the process itself (:func:`_end_in_compiler`): it
kills the child processes, undoes what the blocks of :func:`undone_at_end` registered (the temporary outputs),
prints the command's line and exits with 128 + the signal number. Nothing the compiler holds must outlive the
process: its locks go with it, and numba writes each cache file under a temporary name that it renames into place
(``IndexDataCacheFile._open_for_write``), the index before the data file, so a killed compiler leaves whole files
or none, an index entry without its data file (a cache miss: compiled and written again) and at worst an unused
``*.tmp.*`` file (removed by :func:`kernel_cache.prune`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from contextlib import contextmanager, suppress

from slamobs.pipeline import lifetime
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

#: Top-level modules of numba's compiler: a main thread still in them this long after a stop signal is ended from the
#: watching thread (:func:`_end_in_compiler`) instead of being waited for (riekf's event loop compiles for ~25 s).
COMPILER_MODULES = frozenset({"numba", "llvmlite"})
COMPILER_GRACE_S = 0.5
#: How long the end from the watching thread waits for another thread that is starting a child process.
CHILD_START_S = 1.0

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
_undo: list = []  # what an end from the watching thread undoes first (:func:`undone_at_end`), oldest first
_watching = False  # a watching thread of :func:`raise_when_safe` runs


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


def _package(frame) -> str:
    """The top-level package of the module ``frame`` runs in ("" for code without a module name)."""
    return (frame.f_globals.get("__name__") or "").partition(".")[0]


def _unsafe(frame) -> bool:
    """In a :func:`critical` block, or some frame of the stack from ``frame`` down is in :data:`UNSAFE_MODULES`
    or a finalizer."""
    if _critical:
        return True
    while frame is not None:
        if _package(frame) in UNSAFE_MODULES or frame.f_code.co_name == "__del__":
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


def at_end(action) -> None:
    """Until :func:`not_at_end`, an end of the process from the watching thread (:func:`_end_in_compiler`) calls
    ``action`` first: the removal of a temporary (an output, a copy of a log) that the main thread's unwinding
    would have removed. Never inside a :func:`critical` block (the watcher does not end the process in one)."""
    _undo.append(action)


def not_at_end(action) -> None:
    """Undo :func:`at_end` (an equal ``action``; none registered: nothing)."""
    with suppress(ValueError):
        _undo.remove(action)


@contextmanager
def undone_at_end(action):
    """:func:`at_end` while the block runs."""
    at_end(action)
    try:
        yield
    finally:
        not_at_end(action)


def _in_compiler(ident: int) -> bool:
    """Whether the thread ``ident`` (the main thread) is inside numba's compiler and no :func:`critical` block."""
    if _critical:
        return False
    frame = sys._current_frames().get(ident)  # noqa: SLF001 - documented; the only view of another thread's stack
    while frame is not None:
        if _package(frame) in COMPILER_MODULES:
            return True
        frame = frame.f_back
    return False


def _starting_a_child(frame) -> bool:
    return _package(frame) in ("subprocess", "multiprocessing")


def _end_in_compiler(signum: int, farewell) -> None:
    """End the process from the watching thread while the main thread compiles: child processes killed, the
    registered temporary outputs removed, the command's line printed (unbuffered), exit 128 + ``signum``."""
    global _raised
    _raised = True  # the main thread, should it leave the compiler now, raises nothing more
    lifetime.others_leave(_starting_a_child, CHILD_START_S)
    lifetime.end_children()
    for action in list(_undo)[::-1]:
        with suppress(Exception):
            action()
    for stream in (sys.stdout, sys.stderr):  # what the command printed so far (a status line), then its line
        with suppress(Exception):
            stream.flush()
    with suppress(Exception):
        os.write(2, farewell(signum).encode())
    os._exit(128 + signum)


def _watch(read: int, main: int, farewell) -> None:
    """The watching thread: each stop signal the wakeup fd names (ours to handle) gives the main thread
    :data:`COMPILER_GRACE_S` to raise it; one still inside numba's compiler then is not waited for."""
    while _watching and (data := os.read(read, 64)):
        ours = [s for s in data if s in (signal.SIGTERM, *HANGUP_LIKE) and signal.getsignal(s) is _on_signal]
        if not ours:
            continue
        deadline = time.monotonic() + COMPILER_GRACE_S
        while _watching and not _raised:
            if time.monotonic() >= deadline and _in_compiler(main):
                _end_in_compiler(requested or ours[0], farewell)
            time.sleep(RETRY_S)


@contextmanager
def _watched(farewell):
    """While the block runs, :func:`_watch` in a thread of its own (none without ``farewell`` or a thread to spare)."""
    global _watching
    if farewell is None:
        yield
        return
    read, write = os.pipe()
    os.set_blocking(write, False)
    old = signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    _watching = True
    thread = threading.Thread(
        target=_watch, args=(read, threading.get_ident(), farewell), name="slamobs-signal-watch", daemon=True
    )
    try:
        thread.start()
    except RuntimeError:  # no thread to spare: signals are raised at the first safe point only
        thread = None
    try:
        yield
    finally:
        _watching = False
        signal.set_wakeup_fd(old)
        os.close(write)  # the watcher's read returns empty and it ends
        if thread is not None:
            thread.join(1.0)
        if thread is None or not thread.is_alive():
            os.close(read)


@contextmanager
def raise_when_safe(farewell=None):
    """While the block runs (main thread only), SIGTERM, SIGINT and SIGHUP (the last two unless inherited as
    ignored, as in a background job or under ``nohup``) raise :class:`Interrupted` at the first safe point; a request
    still pending when the block
    ends (the command finished in code where raising was unsafe) is raised then. Afterwards the previous handlers
    are back and nothing is pending.

    ``farewell`` (a process that may end, the console script's): the command's line for an interruption by a
    signal number; with it, a main thread still inside numba's compiler shortly after the signal is not waited
    for (:func:`_end_in_compiler`)."""
    global requested, _raised
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    published.clear()
    signals = [signal.SIGTERM] + [sig for sig in HANGUP_LIKE if signal.getsignal(sig) is not signal.SIG_IGN]
    previous = {sig: signal.signal(sig, _on_signal) for sig in signals}
    previous[signal.SIGALRM] = signal.signal(signal.SIGALRM, _on_retry)
    try:
        with _watched(farewell):
            yield
            if requested is not None and not _raised:
                _raised = True
                raise Interrupted(requested)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        requested, _raised = None, False
