"""The cores this process may run on: its CPU affinity where the system has one (Linux), else the machine's count;
and the lower priority of a helper thread beside the run's critical one."""

from __future__ import annotations

import os
import sys
import threading

#: Nice steps a helper thread (the tables' writer, the report's clock-offset search, the time offset's reporting
#: checks) takes below the thread it runs beside: the estimator's own thread, on which the run waits, is then not
#: preempted by its helpers when the cores are short (riekf's filter stage on the hour: docs/benchmarks.md, session
#: 22). Under Linux's autogroups (sessions share the cores by group) only their share beside the run's own threads
#: changes; without them they also yield to other processes' threads.
HELPER_NICE = 10


def cores() -> int:
    """The cores this process may run on (its CPU affinity, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def lower_this_thread() -> None:
    """The calling thread's priority ``HELPER_NICE`` steps lower, on Linux, where a thread's nice value is its own
    (elsewhere ``setpriority`` would lower the whole process: nothing is done). Call it on a helper thread only; it
    lasts as long as the thread."""
    if not sys.platform.startswith("linux"):
        return
    tid = threading.get_native_id()
    try:
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + HELPER_NICE, 19))
    except OSError:  # a thread may always lower itself; a sandbox may still refuse: it runs as it was
        pass
