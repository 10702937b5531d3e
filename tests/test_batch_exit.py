"""How a stopped command ends: it waits for a child process's start and a semaphore's release so neither prints,
kills its daemonic children, lets a process started after the stop end on SIGTERM, and hands a signal another
thread received to the main thread (each in a fresh interpreter).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from batch_checks import alive


_ENDS_WHILE_A_CHILD_STARTS = """
import multiprocessing, os, sys, threading, time
from multiprocessing import resource_tracker, util

from slamobs.pipeline.batch.dask_exec import spawns_settled

resource_tracker.ensure_running()  # started by a first spawn, through the same call: not the child slowed below
launch, launched = util.spawnv_passfds, threading.Event()


def slow(*args):  # the child exists, its start data not yet written (a nanny's start as the batch ends)
    pid = launch(*args)
    launched.set()
    time.sleep(1.5)
    return pid


util.spawnv_passfds = slow
child = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(60,), daemon=True)
threading.Thread(target=child.start, daemon=True).start()
assert launched.wait(60)  # the end comes while the child starts (a fixed 0.5 s: a loaded machine may not be there yet)
if sys.argv[1] == "settle":
    spawns_settled()
for proc in multiprocessing.active_children():  # what the exit does (cli.errors.exit_at_once)
    proc.kill()
    proc.join(5)
os._exit(0)
"""


def test_a_process_that_ends_while_a_child_process_starts_waits_for_the_start_so_the_child_prints_nothing():
    """A batch that ended while a local Dask nanny started its worker process (a thread between fork-exec and
    writing the child's start data) left the child to read a closed pipe: ``EOFError: Ran out of input`` and a
    traceback under the batch's line (1 of 5 Ctrl-C trials, kill5). ``spawns_settled`` (the cluster's close and
    a failed start) waits for the start; then the exit kills the child. Both ways here, the child's start slowed."""
    seen = {}
    for how in ("settle", "no"):
        done = subprocess.run(
            [sys.executable, "-c", _ENDS_WHILE_A_CHILD_STARTS, how], capture_output=True, text=True, timeout=120
        )
        seen[how] = (done.returncode, done.stderr)
    assert seen["no"][0] == 0 and "EOFError" in seen["no"][1], seen  # the fault, reproduced without the wait
    assert seen["settle"] == (0, ""), seen


_ENDS_WHILE_A_THREAD_RELEASES_A_SEMAPHORE = """
import multiprocessing, os, sys, threading, time
from multiprocessing import resource_tracker, util

from slamobs.cli import errors

resource_tracker.ensure_running()
unregister, telling = resource_tracker.unregister, threading.Event()


def slow(name, rtype):  # unlinked, the tracker not yet told (a loaded machine: 5 ms in the kill test)
    telling.set()
    time.sleep(1.0)
    unregister(name, rtype)


resource_tracker.unregister = slow


def release():  # the local cluster's event loop collecting a closed nanny's queue
    lock = multiprocessing.get_context("spawn").Lock()
    del lock


threading.Thread(target=release, daemon=True).start()
telling.wait(30)
if sys.argv[1] == "exit":
    errors.EXIT_AT_ONCE = True
    errors.exit_at_once(130)
util._run_finalizers(0)  # the exit before: its own finalizers only
os._exit(130)
"""


def test_an_exit_while_another_thread_releases_a_semaphore_waits_so_the_resource_tracker_prints_nothing():
    """A batch stopped as its local cluster started ended (``os._exit``) while the cluster's event loop thread
    released a nanny's queue semaphore, between its unlink and telling the resource tracker: the tracker printed
    "There appear to be 1 leaked semaphore objects" and "[Errno 2] No such file or directory" under the batch's
    line (2 of 10 Ctrl-C trials, the kill test above; 1 in 5 full-suite runs). The exit now waits for the release.
    Both ways here, the release slowed; stderr read to its end, so the tracker's shutdown is in it."""
    seen = {}
    for how in ("exit", "no"):
        done = subprocess.run(
            [sys.executable, "-c", _ENDS_WHILE_A_THREAD_RELEASES_A_SEMAPHORE, how],
            capture_output=True,
            text=True,
            timeout=120,
        )
        seen[how] = (done.returncode, done.stderr)
    assert seen["no"][0] == 130 and "leaked semaphore" in seen["no"][1], seen  # the fault, without the wait
    assert seen["exit"] == (130, ""), seen


def test_a_process_started_after_the_stop_still_ends_on_sigterm():
    """Once stopped, the batch ignored further signals with ``SIG_IGN``, which survives exec: the worker processes a
    starting local Dask cluster spawned after a SIGHUP ignored SIGTERM, and the batch's exit (multiprocessing's
    SIGTERM, then its wait) took 11-50 s after the batch's line under load 20. A process started after the stop
    must end on SIGTERM."""
    from slamobs.cli.jobs import EXIT_SIGNAL, Stopped, on_signal

    previous = {sig: signal.signal(sig, on_signal) for sig in EXIT_SIGNAL}
    try:
        with pytest.raises(Stopped):
            os.kill(os.getpid(), signal.SIGHUP)
            for _ in range(400):  # the handler runs at a bytecode boundary
                time.sleep(0.005)
        os.kill(os.getpid(), signal.SIGTERM)  # a second signal during the clean-up: nothing
        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(300)"])
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
    try:
        child.terminate()
        assert child.wait(timeout=60) == -signal.SIGTERM
    finally:
        child.kill()
        child.wait()


EXIT_WITH_A_DAEMONIC_CHILD = """
import multiprocessing, sys, time
from slamobs.cli import errors
if __name__ == "__main__":
    child = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(300,), daemon=True)
    child.start()
    print(child.pid, flush=True)
    errors.EXIT_AT_ONCE = True
    errors.exit_at_once(7)
    print("the interpreter's teardown", flush=True)
"""


def test_a_command_ends_at_once_with_its_daemonic_children_killed():
    """A daemonic multiprocessing child alive at the end (the worker processes a starting local Dask cluster spawned
    after the stop) sent the command through the interpreter's teardown: SIGTERM to the child, a wait without bound,
    then garbage collection (3-6 s after a stopped batch's line at load 10-20, and "Task exception was never
    retrieved" tracebacks of its nannies as they were collected). The exit kills the child and ends at once."""
    done = subprocess.run(
        [sys.executable, "-c", EXIT_WITH_A_DAEMONIC_CHILD], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 7, done.stderr
    assert "teardown" not in done.stdout and "leaked" not in done.stderr, done.stdout + done.stderr
    assert not alive(int(done.stdout.split()[0]))


SIGNAL_TO_ANOTHER_THREAD = """
import signal, threading, time
from slamobs.cli.jobs import EXIT_SIGNAL, Stopped, on_signal, signals_to_the_main_thread
for sig in EXIT_SIGNAL:
    signal.signal(sig, on_signal)
go = threading.Event()
def other():
    go.wait()
    time.sleep(0.5)
    signal.pthread_kill(threading.get_ident(), signal.SIGHUP)  # the kernel's choice: not the main thread
    time.sleep(600)
threading.Thread(target=other, daemon=True).start()
try:
    with signals_to_the_main_thread():
        go.set()
        threading.Event().wait(600)  # a lock wait, as distributed's sync() while a local cluster starts
    print("the wait ended")
except Stopped as stop:
    print("stopped by", stop.signum, flush=True)
"""


def test_a_signal_handed_to_another_thread_stops_a_main_thread_waiting_on_a_lock():
    """SIGHUP while a local Dask cluster starts: the main thread waits on a lock in distributed's ``sync()``, and the
    kernel may hand the signal to one of Dask's threads; Python then ran the batch's handler only when that wait
    returned (the batch's line 2-8 s after the signal at load 8-20). The signal is sent on to the main thread."""
    done = subprocess.run([sys.executable, "-c", SIGNAL_TO_ANOTHER_THREAD], capture_output=True, text=True, timeout=60)
    assert done.stdout.strip() == f"stopped by {int(signal.SIGHUP)}", done.stdout + done.stderr
