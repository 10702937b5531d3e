"""The cores this process may run on: its CPU affinity where the system has one (Linux), else the machine's count."""

from __future__ import annotations

import os


def cores() -> int:
    """The cores this process may run on (its CPU affinity, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
