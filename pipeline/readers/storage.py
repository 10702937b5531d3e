"""What every storage format hands the decoders: serialised messages as :class:`RawBatch` es, and its errors.

A storage reader (one module per format: :mod:`.ros1`, :mod:`.mcap`, :mod:`.rosbag2_sqlite`; the table is in
:mod:`.container`) is rosbags' reader interface plus :class:`StorageReader`'s two methods. The decoders
(:mod:`.fastdecode`, :mod:`.tfdecode`) take the batches it yields, joined by :func:`grouped`.
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from slamobs.pipeline.errors import BadInput

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator, Sequence


class DamagedError(BadInput):
    """Bytes of a log that cannot be read (bad compression, checksum, records); becomes an InputError."""


#: Record times are int64 nanoseconds here; MCAP stores uint64, so a time at or past 2^63 ns (the year 2262)
#: would wrap to a negative time, and one close below it overflows the sums of times and spans downstream. Every
#: ROS clock stays below 2^62 ns (ROS 1's uint32 seconds end in 2106), so only a corrupt file reaches it.
TIME_LIMIT_NS = 2**62
TIME_RANGE = (
    "outside 0 to 2^62 ns (1970 to 2116, past any ROS clock; a uint64 time at or past 2^63 would be read as negative)"
)


class TimeRangeError(BadInput):
    """Record times outside 0 to TIME_LIMIT_NS; becomes a one-line InputError naming the log."""


@dataclass(frozen=True)
class RawBatch:
    """Serialised messages of one chunk (or one block of sqlite rows) as a buffer and offset arrays.

    Payload ``i`` is ``data[start[i] : start[i] + size[i]]``; ``conn[i]`` indexes the connections that
    were asked for. Keeping the chunk's buffer instead of one ``bytes`` per message is what lets
    :mod:`.fastdecode` decode a batch with array operations.
    """

    data: np.ndarray  # (B,) uint8
    conn: np.ndarray  # (n,) int64
    rec_ns: np.ndarray  # (n,) int64
    start: np.ndarray  # (n,) int64
    size: np.ndarray  # (n,) int64

    def __post_init__(self) -> None:
        # The buffer is read only, wherever it came from (bytes, a joined group): the compiled decoders are then
        # compiled for one array type, not once per writability.
        if self.data.flags.writeable:
            view = self.data.view()
            view.flags.writeable = False
            object.__setattr__(self, "data", view)

    def __len__(self) -> int:
        return int(self.conn.shape[0])

    def payload(self, i: int) -> bytes:
        """Serialised message ``i``."""
        first = int(self.start[i])
        return self.data[first : first + int(self.size[i])].tobytes()

    def take(self, rows: np.ndarray) -> RawBatch:
        """The messages ``rows`` (indices or mask), sharing the buffer."""
        return RawBatch(self.data, self.conn[rows], self.rec_ns[rows], self.start[rows], self.size[rows])

    def in_record_order(self) -> RawBatch:
        """Stably sorted by record time (rosbags' order: by time, ties in file order)."""
        if self.rec_ns.size < 2 or bool(np.all(self.rec_ns[1:] >= self.rec_ns[:-1])):
            return self
        return self.take(np.argsort(self.rec_ns, kind="stable"))


def concat(batches: Sequence[RawBatch]) -> RawBatch:
    """One batch holding ``batches`` in order (their buffers joined)."""
    if len(batches) == 1:
        return batches[0]
    shifts = np.cumsum([0, *(b.data.shape[0] for b in batches[:-1])])
    return placed(np.concatenate([b.data for b in batches]), batches, shifts)


def placed(data: np.ndarray, batches: Sequence[RawBatch], at: Sequence[int]) -> RawBatch:
    """One batch of ``batches`` whose buffers already lie in ``data``, batch ``k``'s from byte ``at[k]`` on:
    :func:`concat` without copying the bytes (a chunk reader decompresses a group's chunks into one buffer)."""
    return RawBatch(
        data,
        np.concatenate([b.conn for b in batches]),
        np.concatenate([b.rec_ns for b in batches]),
        np.concatenate([b.start + s for b, s in zip(batches, at, strict=True)]),
        np.concatenate([b.size for b in batches]),
    )


def joined(blobs: Sequence[bytes], conn: np.ndarray, rec_ns: np.ndarray) -> RawBatch:
    """A batch of separate payloads (sqlite rows, per-message decompressed ones) in one buffer."""
    size = np.fromiter(map(len, blobs), np.int64, len(blobs))
    start = np.zeros(size.shape[0], np.int64)
    np.cumsum(size[:-1], out=start[1:])
    return RawBatch(np.frombuffer(b"".join(blobs), np.uint8), conn, rec_ns, start, size)


#: Decode batches of at least this many bytes: a chunk is often a few hundred kB, and each decode call costs
#: a fixed amount of Python work per topic. The storage readers' read-ahead is counted in such groups too.
GROUP_BYTES = 16 << 20

#: Batches read ahead of the decoding (by one loading thread, :func:`read_ahead`), in decoding groups: the
#: decoder takes :data:`GROUP_BYTES` (16 MB) at a time, the thread keeps about two groups ready.
AHEAD_GROUPS = 2


def read_ahead(batches: Iterator[RawBatch | None], name: str) -> Iterator[RawBatch | None]:
    """``batches``, in order, computed by one thread (named ``name``) ahead of the caller.

    The thread is the only one that runs ``batches`` (and touches the file or database behind it) while this
    runs: reading and decompressing chunks, or SQLite stepping rows, run without the GIL and so overlap the
    decoding of the batches before. It keeps at most :data:`AHEAD_GROUPS` decoding groups of bytes ready (one
    batch always fits). An exception it meets is raised here, where its batch would have come; closing this
    generator (or an exception of the caller) stops the thread, closes ``batches`` there and waits for it.
    """
    budget = AHEAD_GROUPS * GROUP_BYTES  # read when called: a test may set smaller groups
    ready: collections.deque = collections.deque()
    room = threading.Condition()
    state = {"held": 0, "stop": False}  # bytes loaded and not yet taken; the caller is done

    def work() -> None:
        try:
            while True:
                try:
                    item: tuple[bool, object] | None = (True, next(batches))
                except StopIteration:
                    item = None
                except BaseException as err:  # noqa: BLE001 - handed to the caller, raised there
                    item = (False, err)
                size = int(item[1].data.nbytes) if item is not None and item[0] and item[1] is not None else 0
                with room:
                    while state["held"] and state["held"] + size > budget and not state["stop"]:
                        room.wait()
                    if state["stop"]:
                        return
                    state["held"] += size
                    ready.append((item, size))
                    room.notify_all()
                if item is None or not item[0]:
                    return
        finally:
            close = getattr(batches, "close", None)
            if close is not None:  # a generator's clean-up (an SQL cursor) runs where it ran
                close()

    thread = threading.Thread(target=work, name=name, daemon=True)
    thread.start()
    try:
        while True:
            with room:
                while not ready:
                    room.wait()
                item, size = ready.popleft()
                state["held"] -= size
                room.notify_all()
            if item is None:
                return
            ok, value = item
            if not ok:
                raise value
            yield value
    finally:
        with room:
            state["stop"] = True
            room.notify_all()
        thread.join()


def grouped(batches: Iterable[RawBatch]) -> Iterator[RawBatch]:
    """Consecutive batches joined until they hold ``GROUP_BYTES`` (the order of the messages is kept); a batch
    of half a group or more is passed on alone (after the group before it), not copied into a group."""
    group: list[RawBatch] = []
    size = 0
    for batch in batches:
        if 2 * int(batch.data.shape[0]) >= GROUP_BYTES:
            if group:
                yield concat(group)
                group, size = [], 0
            yield batch
            continue
        group.append(batch)
        size += int(batch.data.shape[0])
        if size >= GROUP_BYTES:
            yield concat(group)
            group, size = [], 0
    if group:
        yield concat(group)


class ConnIds:
    """Storage connection ids -> index into the requested connections, vectorised."""

    def __init__(self, mapping: dict[int, int]) -> None:
        order = sorted(mapping)
        self.ids = np.array(order, np.int64)
        self.index = np.array([mapping[i] for i in order], np.int64)

    def __bool__(self) -> bool:
        return bool(self.ids.size)

    def lookup(self, ids: np.ndarray) -> np.ndarray:
        """Index per id, -1 where the id was not asked for."""
        if not self.ids.size:
            return np.full(ids.shape[0], -1, np.int64)
        k = np.minimum(np.searchsorted(self.ids, ids), self.ids.size - 1)
        return np.where(self.ids[k] == ids, self.index[k], -1)


class StorageReader(Protocol):
    """What the readers need of an opened storage file beyond rosbags' reader interface (``connections``,
    ``metadata``, ``open``, ``close``, ``messages``): its messages in batches, and what it had to recover."""

    def batches(self, ids: ConnIds, ordered: bool) -> Iterator[RawBatch]:
        """Messages of the connections ``ids`` asks for; ``ordered``: in record-time order, else file order."""
        ...

    def damage_texts(self) -> list[str]:
        """One note per thing recovered or skipped (empty for an intact file)."""
        ...
