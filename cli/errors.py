"""How every command ends when it cannot finish: one line on stderr and a documented exit code.

- bad input, a bad option value, an output that cannot or must not be written: ``error: FILE: problem``,
  exit code 2 (nothing is written; an existing output is unchanged);
- out of memory, threads, file descriptors or disk (``ulimit -v``, ``-n``, a full disk): ``error: FILE: not enough
  memory for ...`` (or ``cannot start a thread``, ``too many open files``, ``No space left on device``), exit code
  2 as well, never a traceback or a hang;
- Ctrl-C (SIGINT), SIGTERM or SIGHUP (a closed terminal): ``interrupted``, the run is abandoned cleanly (its
  temporary output removed), exit code 130, 143 or 129 (128 + the signal number, as a shell reports a process
  killed by it).

:data:`EXIT_CODES` maps each kind of error (``pipeline/errors.py``) to its code. The command group applies
this to every command (:func:`handled`), so commands contain no error plumbing.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager, suppress
from typing import NoReturn

import click

from slamobs.pipeline.errors import (
    BadConfig,
    BadInput,
    BadOutput,
    InfrastructureFailure,
    Interruption,
    ResourceFailure,
    SlamobsError,
    kind_of,
    one_line,
)

#: Exit code of bad input (missing or unreadable file, bad config); 1 is left to partial failures (batch).
INPUT_ERROR_EXIT = 2

#: The exit code of each kind of error; an interruption's is 128 plus its signal number (130 for SIGINT, 143
#: for SIGTERM), what a shell reports for a process the signal killed.
EXIT_CODES: dict[type[SlamobsError], int] = {
    BadInput: INPUT_ERROR_EXIT,
    BadConfig: INPUT_ERROR_EXIT,
    BadOutput: INPUT_ERROR_EXIT,
    ResourceFailure: INPUT_ERROR_EXIT,
    InfrastructureFailure: 3,  # batch and tune: the batch cannot go on (scheduler lost, no usable workers)
    Interruption: 128,
}


def exit_code(err: SlamobsError) -> int:
    """The exit code :data:`EXIT_CODES` gives the kind of ``err``."""
    code = EXIT_CODES.get(kind_of(err), INPUT_ERROR_EXIT)  # the root itself: as bad input
    return code + int(getattr(err, "signum", signal.SIGINT)) if isinstance(err, Interruption) else code


def exit_input_error(err: BaseException | str, code: int = INPUT_ERROR_EXIT) -> NoReturn:
    click.echo(f"error: {' '.join(str(err).split())}", err=True)
    for line in getattr(err, "details", ()):
        click.echo(f"  {line}", err=True)
    sys.exit(code)


#: Set by the console script (``cli.main.entry``): when a command has finished or was interrupted the process
#: ends at once. By then every ``with`` block has unwound (outputs complete and renamed, or temporary outputs
#: removed; files closed); the interpreter's teardown (up to a second with numba, pyarrow and matplotlib
#: loaded) would only delay the exit.
EXIT_AT_ONCE = False


def interrupted_line(signum: int) -> str:
    """What an interrupted command says (on stderr, a line of its own)."""
    name = signal.Signals(signum).name
    from slamobs.pipeline.interrupts import published

    # outputs published since the command began that are still there: a compare's runs are published inside its
    # temporary output, which the interruption removed
    kept = [p for p in published if os.path.exists(p)]
    if kept:  # the signal came after the output was complete (while the command printed its summary)
        return f"\ninterrupted ({name}) after the output was complete: {', '.join(kept)}\n"
    return f"\ninterrupted ({name}): stopped; nothing was written and an existing output is unchanged\n"


def exit_interrupted(err: KeyboardInterrupt) -> NoReturn:
    signum = getattr(err, "signum", signal.SIGINT)
    click.echo(interrupted_line(signum), err=True, nl=False)
    code = EXIT_CODES[Interruption] + int(signum)
    if EXIT_AT_ONCE:
        _end_now(code)
    sys.exit(code)


def end_signals_at_once() -> None:
    """Outside a command's own handling (before it starts and after it has finished): SIGTERM, SIGINT or SIGHUP end
    the process at once with 143/130/129 (one inherited as ignored stays ignored). Nothing is being written then
    (outputs complete and renamed, or not begun); left at the default, a SIGTERM in the interpreter's teardown
    killed the process by the signal (a batch stopped just as it finished exited -15, not 143), a SIGINT printed
    a traceback, and a SIGTERM in the moment between the command's handlers and these did the same."""
    for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        with suppress(ValueError, OSError):  # not the main thread
            if signal.getsignal(signum) is not signal.SIG_IGN:
                signal.signal(signum, end_by_signal)


def end_by_signal(signum: int, _frame) -> None:
    """The handler a command's signals end it by (public: tests/test_interrupts.py calls it)."""
    _end_now(128 + signum)


def exit_at_once(code: object) -> None:
    """After a command has finished: with :data:`EXIT_AT_ONCE`, end the process now with the exit status
    ``sys.exit(code)`` gives; return (and let the caller exit normally) otherwise, or while a thread or child
    process that the interpreter's shutdown would wait for is still running."""
    if not EXIT_AT_ONCE:
        return
    _end_daemonic_children()
    if _still_running():
        return
    _release_semaphores()
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # sys.exit("message") prints it and exits with 1
        with suppress(Exception):
            print(code, file=sys.stderr)
        status = 1
    _end_now(status)


def _end_now(status: int) -> NoReturn:
    """Flush stdout and stderr and end the process without the interpreter's teardown."""
    for stream in (sys.stdout, sys.stderr):
        with suppress(Exception):
            stream.flush()
    os._exit(status & 0xFF)


#: How long the exit waits for its killed daemonic children to be gone.
DAEMONIC_CHILD_S = 5.0


def _end_daemonic_children() -> None:
    """Kill the daemonic multiprocessing children and wait for them (at most :data:`DAEMONIC_CHILD_S`), so the exit
    can skip the interpreter's teardown, which would SIGTERM them, wait for them without bound, then collect garbage.
    They hold no output by then (a batch's or Dask's workers, the figure helper). A batch stopped while its local
    Dask cluster started had worker processes its nannies spawned after the stop: its exit took 3-6 s after its
    line at load 10-20 (SIGTERM while they imported, then the teardown's garbage collection)."""
    mp = sys.modules.get("multiprocessing")
    if mp is None:
        return
    import time

    killed = []
    for proc in mp.active_children():
        if proc.daemon:
            with suppress(Exception):
                proc.kill()
                killed.append(proc)
    deadline = time.monotonic() + DAEMONIC_CHILD_S
    for proc in killed:  # join, not only its sentinel: that is ready before the child can be reaped
        with suppress(Exception):
            proc.join(max(0.0, deadline - time.monotonic()))


#: How long the exit waits for another thread to finish releasing or making a semaphore.
SEMAPHORE_S = 2.0


def _release_semaphores() -> None:
    """Run multiprocessing's finalizers of priority 0 and up (its semaphores' unlinking; not a queue's join, at -5),
    as its exit hook would: skipped, the resource tracker warned "There appear to be 9 leaked semaphore objects"
    under a batch stopped while its local Dask cluster started (a nanny's queues still open).

    Another thread may be releasing one itself (the local cluster's event loop collecting a closed nanny's queue):
    ended between its unlink and the tracker's unregister, the tracker warned "1 leaked semaphore objects" and
    "[Errno 2] No such file or directory" under the batch's line (1 of 5 Ctrl-C trials as the cluster started).
    The exit waits for it (and for a semaphore being made), then runs the finalizers made meanwhile."""
    util = sys.modules.get("multiprocessing.util")
    if util is None:
        return
    from slamobs.pipeline.lifetime import others_leave

    with suppress(Exception):
        util._run_finalizers(0)  # noqa: SLF001 - no public name for what the exit hook runs
        others_leave(_on_a_semaphore, SEMAPHORE_S)
        util._run_finalizers(0)  # noqa: SLF001


def _on_a_semaphore(frame) -> bool:
    """A frame of multiprocessing making or releasing a semaphore (``SemLock.__init__``, ``SemLock._cleanup``, or
    the finalizer that calls the latter, its entry already taken from the registry)."""
    code = frame.f_code
    if code.co_filename.endswith(os.path.join("multiprocessing", "synchronize.py")):
        return True
    if code.co_name != "__call__" or not code.co_filename.endswith(os.path.join("multiprocessing", "util.py")):
        return False
    callback = getattr(frame.f_locals.get("self"), "_callback", None)
    return getattr(callback, "__qualname__", "").startswith("SemLock.")


def _still_running() -> bool:
    """A non-daemon thread or a multiprocessing child is alive (the interpreter's shutdown waits for them)."""
    if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        return True
    mp = sys.modules.get("multiprocessing")
    return bool(mp is not None and mp.active_children())


def os_error_line(err: OSError) -> str:
    """An OS error as ``FILE: problem`` (the file it concerns, if known)."""
    text = err.strerror or one_line(err) or type(err).__name__
    return f"{err.filename}: {text}" if err.filename else text


#: What the running command works on, for a lack of memory or threads that no deeper layer put in its words
#: (an import of the pipeline failing under ``ulimit -v``): (file, what is being done, MB it needs or None).
_subject: tuple[object, str, int | None] | None = None


def working_on(path: object, what: str, needs_mb: int | None = None) -> None:
    """Name the file a command works on (and the memory it needs) for the message of a lack of resources."""
    global _subject
    _subject = (path, what, needs_mb)


def _resource_line(err: Exception):
    """``err`` as a ResourceError naming the command's file (or ``slamobs COMMAND``), None if it is no such error."""
    from slamobs.pipeline.errors import resource_error

    if _subject is not None:
        return resource_error(err, *_subject)
    words = [w for w in sys.argv[1:2] if not w.startswith("-")]
    return resource_error(err, " ".join(["slamobs", *words]), "this command")


@contextmanager
def handled():
    """Run a command: slamobs' errors, OS errors and a lack of memory, threads or descriptors anywhere become one
    line and the exit code of their kind (2 for OS errors and the machine's), SIGINT/SIGTERM exit 130/143."""
    from slamobs.pipeline.interrupts import as_interruption, raise_when_safe

    from slamobs.pipeline.native import check_numpy_room

    global _subject
    _subject = None  # until the command names its file, if it has one
    try:
        # the console script's process may end from another thread inside numba's compiler, saying this line
        with as_interruption(), raise_when_safe(interrupted_line if EXIT_AT_ONCE else None):
            check_numpy_room()  # NumPy's OpenBLAS would end the process ("OpenBLAS error", exit 1) if it cannot start
            yield
    except KeyboardInterrupt as err:  # Interruption, and Python's own for a SIGINT before the handlers
        exit_interrupted(err)
    except SlamobsError as err:
        exit_input_error(err, exit_code(err))
    except BrokenPipeError:
        sys.exit(128 + signal.SIGPIPE)  # the reader of our output went away: nothing to report to
    except Exception as err:
        # out of memory, threads or descriptors wherever it happened (an import, a library's thread start)
        if (machine := _resource_line(err)) is not None:
            exit_input_error(machine)
        if isinstance(err, OSError):
            exit_input_error(os_error_line(err))
        raise
