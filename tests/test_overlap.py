"""The threads a run uses to overlap its stages: chunks loaded ahead of the decoder, stretches written while
the observer runs. Order is kept, an error surfaces in the caller's thread at the item it belongs to, memory
ahead is bounded, and stopping early leaves no thread running."""

from __future__ import annotations

import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from slamobs.pipeline.readers import chunks, storage
from slamobs.pipeline.writers import BackgroundWrites


def _threads(prefix: str) -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith(prefix)]


def _unit(k: int):
    return SimpleNamespace(k=k)


def _batch(k: int, size: int = 1000):
    return SimpleNamespace(k=k, data=np.zeros(size, np.uint8))


def test_prefetch_keeps_order_and_bounds_what_it_holds(monkeypatch):
    monkeypatch.setattr(storage, "GROUP_BYTES", 4000)  # ahead: AHEAD_GROUPS groups of 4000 bytes
    loaded = []

    def load(unit):
        loaded.append(unit.k)
        return _batch(unit.k)

    it = chunks.prefetched(load, [_unit(k) for k in range(50)])
    first = next(it)
    time.sleep(0.2)  # the loader runs ahead as far as it may
    ahead = len(loaded) - 1
    assert first.k == 0
    # the budget plus the unit it loaded before it saw the budget was used
    assert ahead <= storage.AHEAD_GROUPS * 4000 // 1000 + 1, ahead
    assert [b.k for b in it] == list(range(1, 50))
    assert not _threads("slamobs-chunk-reader")


def test_prefetch_raises_a_load_error_at_its_unit_and_stops():
    def load(unit):
        if unit.k == 3:
            raise storage.DamagedError("chunk 3 is damaged")
        return _batch(unit.k)

    got = []
    with pytest.raises(storage.DamagedError, match="chunk 3"):
        for b in chunks.prefetched(load, [_unit(k) for k in range(10)]):
            got.append(b.k)
    assert got == [0, 1, 2]
    assert not _threads("slamobs-chunk-reader")


def test_prefetch_closed_early_waits_for_its_thread():
    started = threading.Event()

    def load(unit):
        started.set()
        time.sleep(0.01)
        return _batch(unit.k, 10)

    it = chunks.prefetched(load, [_unit(k) for k in range(10_000)])
    assert next(it).k == 0
    started.wait(5)
    it.close()  # the caller stops (an error while decoding, Ctrl-C): nothing may read the file afterwards
    assert not _threads("slamobs-chunk-reader")


def test_background_writes_keep_order_and_return_the_last():
    written = []
    writes = BackgroundWrites(lambda item: written.append(item) or item * 10)
    for k in range(20):
        writes.put(k)
    assert writes.finish() == 190
    assert written == list(range(20))
    assert not writes._thread.is_alive()


def test_background_write_error_surfaces_in_the_caller():
    written = []

    def write(item):
        if item == 2:
            raise OSError("disk full")
        written.append(item)
        return item

    writes = BackgroundWrites(write)
    with pytest.raises(OSError, match="disk full"):
        for k in range(100):
            writes.put(k)
            time.sleep(0.005)
        writes.finish()
    assert not writes._thread.is_alive()
    assert written == [0, 1]  # nothing written after the failed item


def test_background_writes_cancelled_write_nothing_more():
    gate, taken = threading.Event(), threading.Event()
    written = []

    def write(item):
        taken.set()
        gate.wait(5)
        written.append(item)

    writes = BackgroundWrites(write)
    writes.put(0)  # being written (waits at the gate)
    assert taken.wait(60)  # taken off the queue before the cancel (else the cancel drops it too: a scheduling race)
    writes.put(1)  # waiting in the queue
    threading.Timer(0.1, gate.set).start()
    writes.cancel()  # the run failed: the item being written finishes, the waiting one is dropped
    assert written == [0]
    assert not writes._thread.is_alive()


def _priority() -> int:
    import os

    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a thread's own nice value is Linux's")
def test_helper_threads_run_below_the_estimator_s_priority(monkeypatch):
    """The writer, the report's search beside the estimator and the time offset's checks after its decision run
    ``HELPER_NICE`` steps below the caller (or at the lowest priority), so they do not preempt the estimator's
    thread on a short machine (docs/benchmarks.md, session 22); the caller's own priority is left as it was."""
    from slamobs.pipeline.cores import HELPER_NICE
    from slamobs.pipeline.evaluation.trajectory_evaluation import Pending
    from slamobs.pipeline.observers import time_offset

    mine = _priority()
    lowered = min(mine + HELPER_NICE, 19)
    writes = BackgroundWrites(lambda item: _priority())
    writes.put(0)
    assert writes.finish() == lowered
    started = threading.Event()

    def search():
        started.set()
        return _priority()

    beside = Pending(search, helper=True)
    assert started.wait(60)  # begun on its thread, not in the caller's (the bound: a thread that never starts)
    assert beside.result() == lowered
    assert Pending(lambda: (time.sleep(0.05), _priority())[1]).result() == mine  # the report's other work as it was

    def estimate(stream, decided=None):
        before = _priority()
        decided({"applied": False, "estimate_s": 0.0})
        return {"before": before, "after": _priority()}

    monkeypatch.setattr(time_offset, "cores", lambda: 2)
    monkeypatch.setattr(time_offset, "estimate", estimate)
    assert time_offset.Background(None).result() == {"before": mine, "after": lowered}  # the decision at full speed
    assert _priority() == mine
