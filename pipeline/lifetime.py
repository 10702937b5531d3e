"""Child processes that cannot outlive their parent (batch workers, the figure helper).

A local worker asks the kernel to SIGKILL it when its parent dies (Linux ``prctl(PR_SET_PDEATHSIG)``: works
even when the parent is SIGKILLed or OOM-killed), and runs a watchdog thread that exits when it is
re-parented, for systems without the prctl. The watchdog cannot run while a compiled kernel holds the GIL,
so on such systems a worker may finish its current stretch first; on Linux the signal is immediate.

The binding happens while the new process unpickles its start-up arguments (:class:`BindOnArrival` comes
first), before the heavy imports that follow, so even a worker still starting dies with its batch. This
module therefore imports nothing heavy at its top.

The cyclic garbage collector of a command is off while it imports the pipeline (:func:`collected_after_imports`).

Temporaries that a killed process leaves (a run's output directory, a WAL recording's copy) carry an owner marker
(:func:`owner_marker`); the next process removes them once :func:`owner_alive` says their owner is gone.
"""

from __future__ import annotations

import ctypes
import gc
import os
import signal
import socket
import sys
import threading
import time
from contextlib import contextmanager

PR_SET_PDEATHSIG = 1
#: Exit status of a worker that found its batch gone.
ORPHANED = 70


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Linux: deliver ``sig`` to this process when its parent exits. False where unavailable."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def watch(alive, interval: float = 0.5, name: str = "slamobs-lifeline") -> threading.Thread:
    """A daemon thread that ends the process (``os._exit``) as soon as ``alive()`` is false."""

    def loop() -> None:
        while True:
            time.sleep(interval)
            if not alive():
                os._exit(ORPHANED)

    thread = threading.Thread(target=loop, name=name, daemon=True)
    thread.start()
    return thread


#: How long :func:`end_children` waits for its killed children to be gone.
CHILDREN_GONE_S = 2.0


def children(pid: int | None = None) -> list[int]:
    """The live child processes of ``pid`` (this process), from Linux ``/proc`` (none elsewhere)."""
    pid = os.getpid() if pid is None else pid
    found = []
    try:
        entries = os.listdir("/proc")
    except OSError:
        return found
    for entry in entries:
        if entry.isdigit() and (fields := _stat_fields(entry)) and int(fields[1]) == pid and fields[0] != b"Z":
            found.append(int(entry))
    return found


def end_children() -> None:
    """SIGKILL every child process of this one and reap it (at most :data:`CHILDREN_GONE_S`): for an exit that cannot
    wait for the code that owns them (a compile helper, figure helpers; their own children are bound to them and go
    with them)."""
    killed = []
    for child in children():
        try:
            os.kill(child, signal.SIGKILL)
            killed.append(child)
        except OSError:
            pass
    deadline = time.monotonic() + CHILDREN_GONE_S
    for child in killed:
        while time.monotonic() < deadline:
            try:
                if os.waitpid(child, os.WNOHANG)[0]:
                    break
            except ChildProcessError:  # reaped by its owner meanwhile
                break
            time.sleep(0.005)


def others_leave(inside, within: float) -> bool:
    """Wait (at most ``within`` seconds) until no thread but this one has a frame on its stack for which
    ``inside(frame)`` is true: an exit that ends the process at once must not cut another thread's work in two
    (a child being started, a semaphore being released). True once none has; False at the deadline."""
    me = threading.get_ident()
    deadline = time.monotonic() + within
    while True:
        frames = sys._current_frames()  # noqa: SLF001 - documented; the only view of other threads' stacks
        if not any(_on_stack(frame, inside) for ident, frame in frames.items() if ident != me):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)


def _on_stack(frame, inside) -> bool:
    while frame is not None:
        if inside(frame):
            return True
        frame = frame.f_back
    return False


class BindOnArrival:
    """Pickled as the first start-up argument of a worker: unpickling it binds the new process to ``pid``
    (:func:`arrived`)."""

    def __init__(self, pid: int) -> None:
        self.pid = pid

    def __reduce__(self):
        return (arrived, (self.pid,))


def arrived(parent_pid: int) -> None:
    """A batch worker starting: bound to ``parent_pid`` (:func:`bind_to_parent`), its cyclic garbage collector off
    while the rest of its start-up arguments are unpickled (the run function's module imports the pipeline, numba
    among it: ~150 collections that find nothing); ``batch.lifeline.worker_main`` turns it on again once it has
    imported what its runs need (:func:`collected_after_imports`)."""
    bind_to_parent(parent_pid)
    gc.disable()


def bind_to_parent(parent_pid: int) -> None:
    """Make this (worker) process die with ``parent_pid``: parent-death signal plus watchdog thread.

    Checked once right away: a parent that died before the prctl took effect would never signal.
    """
    set_parent_death_signal()
    if os.getppid() != parent_pid:
        os._exit(ORPHANED)
    watch(lambda: os.getppid() == parent_pid)


# --------------------------------------------------------------------------- owners of temporaries


def _stat_fields(pid: int | str) -> list[bytes] | None:
    """The fields of Linux ``/proc/PID/stat`` after the command name (state, parent, group, ...; None when gone)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()
    except (OSError, IndexError):
        return None


def start_time(pid: int) -> str | None:
    """When process ``pid`` started (clock ticks since boot, Linux ``/proc``), to tell a reused pid apart."""
    fields = _stat_fields(pid)
    return fields[19].decode() if fields is not None and len(fields) > 19 else None


def owner_marker() -> dict:
    """Who made a temporary file or directory: this process (pid, host, start time), for :func:`owner_alive`."""
    return {"pid": os.getpid(), "host": socket.gethostname(), "start": start_time(os.getpid())}


def owner_alive(owner: dict) -> bool:
    """Whether the process that made a temporary file or directory (its :func:`owner_marker`) may still be using
    it (other hosts: assume so)."""
    if owner.get("host") != socket.gethostname():
        return True
    pid = int(owner.get("pid", -1))
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # another user's live process
    start = owner.get("start")
    return start is None or start_time(pid) in (None, start)


@contextmanager
def collected_after_imports():
    """A command (``run``, ``compare``, ``batch run`` and its local workers) with Python's cyclic garbage collector
    off until the pipeline is imported (``imported``, yielded, called then), after which the objects that exist are
    frozen (``gc.freeze``: left out of every collection) until the command ends. The imports (~0.3 CPU s before a
    run reads its log: numba, rosbags, the package) make ~150 collections that find next to nothing (modules,
    classes and functions live to the end), and later collections walked those objects again: a fresh run of a
    90 s log spent 0.071-0.072 CPU s in the collector, 0.030-0.034 with this (docs/benchmarks.md, sessions 29 and
    30). Objects only: the results are the same. Frozen objects are back at the end (``gc.get_objects`` lists
    them again, a process running several runs collects its cycles); objects frozen before, by whoever calls this
    in-process, stay as they were."""
    enabled = gc.isenabled()
    ours = gc.get_freeze_count() == 0

    def imported() -> None:
        if ours:
            gc.freeze()
        if enabled:
            gc.enable()

    gc.disable()
    try:
        yield imported
    finally:
        if ours:
            gc.unfreeze()
        if enabled:
            gc.enable()
