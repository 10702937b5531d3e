"""The threads a run uses to overlap its stages: chunks loaded ahead of the decoder, stretches written while
the observer runs. Order is kept, an error surfaces in the caller's thread at the item it belongs to, memory
ahead is bounded, and stopping early leaves no thread running."""

from __future__ import annotations

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
    gate = threading.Event()
    written = []

    def write(item):
        gate.wait(5)
        written.append(item)

    writes = BackgroundWrites(write)
    writes.put(0)  # being written (waits at the gate)
    writes.put(1)  # waiting in the queue
    threading.Timer(0.1, gate.set).start()
    writes.cancel()  # the run failed: the item being written finishes, the waiting one is dropped
    assert written == [0]
    assert not writes._thread.is_alive()
