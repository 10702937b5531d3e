"""What the chunked formats (:mod:`.ros1`, :mod:`.mcap`) share: chunks as units, reading them ahead of the
decoding, the compiled record walk's results, and the damage report.

Chunks are read whole (one buffer, offset arrays: :class:`.storage.RawBatch`) rather than message by message,
so :mod:`.fastdecode` can decode them with array operations. A damaged chunk that the file's index (ROS1) or
summary (MCAP) knows is skipped and counted; a file without a usable index is scanned by its format's reader,
which keeps every complete message (also from the readable part of a cut-off chunk).
"""

from __future__ import annotations

import bz2
import struct
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, BinaryIO

import lz4.frame
import numpy as np
import zstandard
from isal.isal_zlib import crc32  # zlib's CRC-32, the same bits, 7-13x faster (ISA-L); frees the GIL
from slamobs.pipeline.cores import cores
from slamobs.pipeline.errors import machine_failure, one_line
from numba import types
from slamobs.pipeline.kernel_cache import subroutine, worth_compiling

from . import storage
from .storage import ConnIds, DamagedError, RawBatch, concat, placed

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator, Sequence

    from rosbags.interfaces import Connection

_NS = 1_000_000_000


@dataclass(frozen=True)
class Unit:
    """A chunk (or the readable part of a cut-off one): where its bytes are and what it holds."""

    pos: int  # file offset of the (compressed) records
    size: int  # bytes available there
    compression: str  # ROS1: none, bz2, lz4; MCAP: "", zstd, lz4
    raw_size: int  # declared uncompressed size (checked unless partial)
    start_ns: int  # record time span, inclusive
    end_ns: int
    conns: frozenset[int]  # connection/channel ids in it (empty: unknown, always read)
    crc_at: int = -1  # MCAP: file offset of the uncompressed CRC32 (-1: none)
    partial: bool = False  # cut off: decompress what is there and keep the complete records
    indexed: bool = False  # found through the file's index / summary: a damaged one is skipped, counted
    messages: int = -1  # messages in it according to the index (-1: unknown)
    recovered: bool = False  # found by a scan, which reported where its records end


def _inflate(blob: bytes, compression: str, raw_size: int, partial: bool) -> bytes:
    """Decompress chunk records; a partial chunk yields whatever complete blocks it holds."""
    if compression in {"", "none"}:
        return blob
    if partial:
        try:
            if compression == "zstd":
                return zstandard.ZstdDecompressor().decompressobj().decompress(blob)
            if compression == "lz4":
                return lz4.frame.LZ4FrameDecompressor().decompress(blob)
            if compression == "bz2":
                return bz2.BZ2Decompressor().decompress(blob)
        except (RuntimeError, OSError, ValueError, zstandard.ZstdError) as err:
            if machine_failure(err):
                raise
            return b""
    if compression == "zstd":
        raw = zstandard.ZstdDecompressor().decompress(blob, max_output_size=raw_size)
    elif compression == "lz4":
        raw = lz4.frame.decompress(blob)
    elif compression == "bz2":
        raw = bz2.decompress(blob)
    else:
        msg = f"unsupported chunk compression {compression!r}"
        raise DamagedError(msg)
    if len(raw) != raw_size:
        msg = f"chunk decompressed to {len(raw)} bytes instead of {raw_size}"
        raise DamagedError(msg)
    return raw


def read_unit(bio: BinaryIO, unit: Unit, out: np.ndarray | None = None) -> np.ndarray:
    """The unit's records, decompressed and checked against the stored CRC32 (MCAP).

    ``out``: :func:`slot_bytes` bytes of a group's buffer (a complete unit) to decompress into, its read-only
    view returned: the group's chunks then need not be copied into one buffer for the decoder.
    """
    if out is not None and unit.compression in {"", "none"}:
        bio.seek(unit.pos)
        got = bio.readinto(out)
        if got != unit.size:
            msg = f"chunk at byte {unit.pos} is cut off"
            raise DamagedError(msg)
        return _checked(out, _stored_crc(bio, unit), unit)
    return unpack_unit(*read_blob(bio, unit), unit, out)


def read_blob(bio: BinaryIO, unit: Unit) -> tuple[bytes, bytes | None]:
    """The unit's bytes as stored and its stored CRC32's bytes (None: none): all :func:`unpack_unit` needs of the
    file, so that units read one after the other can be decompressed on two threads."""
    bio.seek(unit.pos)
    blob = bio.read(unit.size)
    if len(blob) != unit.size:
        msg = f"chunk at byte {unit.pos} is cut off"
        raise DamagedError(msg)
    return blob, _stored_crc(bio, unit)


def _stored_crc(bio: BinaryIO, unit: Unit) -> bytes | None:
    if unit.crc_at < 0 or unit.partial:
        return None
    bio.seek(unit.crc_at)
    return bio.read(4)


def unpack_unit(blob: bytes, crc: bytes | None, unit: Unit, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`read_unit` of the bytes :func:`read_blob` read (decompression, zstd's into ``out``, and the CRC32
    run without the GIL)."""
    data = _inflate_into(blob, unit, out) if out is not None else None
    if data is None:
        raw = _inflate(blob, unit.compression, unit.raw_size, unit.partial)
        data = np.frombuffer(raw, np.uint8)
        if out is not None:
            out[:] = data
            data = out
    return _checked(data, crc, unit)


def _checked(data: np.ndarray, crc_bytes: bytes | None, unit: Unit) -> np.ndarray:
    """``data`` checked against the stored CRC32 (0: none), as a read-only array."""
    if crc_bytes is not None:
        (crc,) = struct.unpack("<I", crc_bytes)
        if crc and crc32(data) != crc:
            msg = f"chunk at byte {unit.pos} fails its checksum"
            raise DamagedError(msg)
    if data.flags.writeable:  # as np.frombuffer gives it: the compiled walks are compiled for read-only buffers
        data = data.view()
        data.flags.writeable = False
    return data


def _inflate_into(blob: bytes, unit: Unit, out: np.ndarray) -> np.ndarray | None:
    """A zstd chunk decompressed straight into ``out`` (its declared size); None for another compression."""
    if unit.compression != "zstd":
        return None
    reader = _zstd().stream_reader(blob, read_size=len(blob), read_across_frames=False)
    got = 0
    while got < out.shape[0] and (step := reader.readinto(out[got:])):
        got += step
    if got != unit.raw_size or reader.read(1):
        msg = f"chunk does not decompress to its declared {unit.raw_size} bytes"
        raise DamagedError(msg)
    return out


_THREAD = threading.local()


def _zstd() -> zstandard.ZstdDecompressor:
    """This thread's zstd decompressor (one may not be used by two threads at once; each stream it reads starts
    afresh): making one took ~16 us, a third of a small chunk's decompression, for each of a log's chunks."""
    dctx = getattr(_THREAD, "zstd", None)
    if dctx is None:
        dctx = _THREAD.zstd = zstandard.ZstdDecompressor()
    return dctx


def slot_bytes(unit: Unit) -> int:
    """Bytes a complete unit's records take once decompressed."""
    return unit.size if unit.compression in {"", "none"} else unit.raw_size


def load_groups(units: Sequence[Unit]) -> list[list[Unit]]:
    """Consecutive units in decoding groups of :data:`.storage.GROUP_BYTES` (as :func:`.storage.grouped` joins their
    batches), each loaded into one buffer; a cut-off unit (whose size is known only once read) is a group alone."""
    groups: list[list[Unit]] = []
    group: list[Unit] = []
    size = 0
    for unit in units:
        if unit.partial:
            groups += [group, [unit]] if group else [[unit]]
            group, size = [], 0
            continue
        group.append(unit)
        size += slot_bytes(unit)
        if size >= storage.GROUP_BYTES:
            groups.append(group)
            group, size = [], 0
    if group:
        groups.append(group)
    return groups


# Scanner status codes.
CLEAN, CUT, BAD = 0, 1, 2
#: A filling walk's arrays are full (:func:`records` then counts first).
FULL = 3


@subroutine(types.int64)
def u32(buf, p):  # pragma: no cover - compiled
    return np.int64(buf[p]) | (np.int64(buf[p + 1]) << 8) | (np.int64(buf[p + 2]) << 16) | (np.int64(buf[p + 3]) << 24)


@dataclass(frozen=True)
class Records:
    """Records found in a buffer, and where and how the walk ended."""

    op: np.ndarray
    conn: np.ndarray
    t_ns: np.ndarray
    hpos: np.ndarray
    dpos: np.ndarray
    dlen: np.ndarray
    stop: int
    status: int


_EVERY = np.empty(0, np.int64)


def records(
    walk: Callable[..., tuple[int, int, int]], buf: np.ndarray, wanted: np.ndarray = _EVERY, most: int = -1
) -> Records:
    """The records (``wanted`` (:func:`wanted_table`): only the requested messages, ``conn`` their index among the
    requested connections). With ``most`` (the unit's message count by the index) one filling walk into arrays of
    that many; without it, or when the walk finds more, a counting walk first (the arrays exactly as long as the
    record count): a ROS1 record's header fields are parsed at each walk, the second as long as the first."""
    if most >= 0:
        arrays = np.empty((6, most), np.int64)
        n, stop, status = walk(buf, True, *arrays, wanted)
        if status != FULL:
            return Records(*arrays[:, :n], stop=int(stop), status=int(status))
    n, _, _ = walk(buf, False, _EVERY, _EVERY, _EVERY, _EVERY, _EVERY, _EVERY, wanted)
    arrays = [np.empty(n, np.int64) for _ in range(6)]
    n, stop, status = walk(buf, True, *arrays, wanted)
    return Records(*arrays, stop=int(stop), status=int(status))


#: A log of fewer messages (by its index or summary) may be walked by the record walk's array code (its Python
#: loop costs ~0.5-1.5 us a record, the compiled walk's first compilation ~0.5 s; :func:`chosen_walk`).
ARRAY_WALK_MESSAGES = 262_144


def chosen_walk(
    kernel: Callable[..., tuple[int, int, int]],
    array_walk: Callable[..., tuple[int, int, int]],
    messages: Sequence[int],
) -> Callable[..., tuple[int, int, int]]:
    """The record walk of a log whose units hold ``messages`` (-1: not known): ``array_walk`` (the kernel's results by
    array code) where :func:`.kernel_cache.worth_compiling` says so for fewer than :data:`ARRAY_WALK_MESSAGES` known
    messages (a first run on one core), else the kernel."""
    if min(messages, default=0) < 0 or worth_compiling(kernel, sum(messages), ARRAY_WALK_MESSAGES):
        return kernel
    return array_walk


#: Connection ids up to this are looked up by a table in the record walks (MCAP's are 16-bit; ROS1 bags count
#: from 0); a larger one takes the whole record list and :func:`message_batch`.
_TABLE_IDS = 1 << 16


def wanted_table(ids: ConnIds) -> np.ndarray | None:
    """Storage connection id -> index into the requested connections (-1: not requested), for the record walks;
    None when an id is too large for a table."""
    if not ids.ids.size or int(ids.ids.max()) >= _TABLE_IDS or int(ids.ids.min()) < 0:
        return None
    table = np.full(int(ids.ids.max()) + 1, -1, np.int64)
    table[ids.ids] = ids.index
    return table


def message_batch(data: np.ndarray, recs: Records, message_op: int, ids: ConnIds) -> RawBatch:
    """The requested messages among ``recs`` (every record of the buffer)."""
    index = ids.lookup(recs.conn)
    keep = (recs.op == message_op) & (index >= 0)
    return RawBatch(data, index[keep], recs.t_ns[keep], recs.dpos[keep], recs.dlen[keep])


def _clusters(units: Iterable[Unit]) -> Iterator[list[Unit]]:
    """Consecutive units whose time spans overlap (their messages must be merged to be in order)."""
    group: list[Unit] = []
    end = 0
    for unit in units:
        if group and unit.start_ns < end:
            group.append(unit)
            end = max(end, unit.end_ns)
            continue
        if group:
            yield group
        group, end = [unit], unit.end_ns
    if group:
        yield group


#: What reading a damaged chunk raises (decompressors, checksums, record walks).
_CHUNK_ERRORS = (DamagedError, RuntimeError, OSError, ValueError, EOFError, struct.error, zstandard.ZstdError)


def prefetched(load: Callable[[Unit], RawBatch | None], units: Sequence[Unit]) -> Iterator[RawBatch | None]:
    """``load(unit)`` of every unit, in order, computed by one thread ahead of the caller (:func:`.storage.read_ahead`).

    Reading, decompressing and checking a chunk (file I/O, zstd/lz4/bz2, CRC32 and the record walk all run
    without the GIL) overlap the decoding of the chunks before; a single unit is loaded by the caller.
    """
    loads = (load(unit) for unit in units)
    return loads if len(units) < 2 else storage.read_ahead(loads, "slamobs-chunk-reader")


class Chunked:
    """What the ROS1 and MCAP readers share: units, loading them, the damage report.

    A damaged chunk that the file's index (ROS1) or summary (MCAP) knows is skipped and counted: the index
    says where the next chunk starts and how many messages the damaged one held (:meth:`damage_texts`).
    """

    units: list[Unit]
    damage: str | None
    bio: BinaryIO | None
    message_op: int
    walk: Callable[..., tuple[int, int, int]]
    label: str

    def batches(self, ids: ConnIds, ordered: bool) -> Iterator[RawBatch]:
        """Requested messages chunk by chunk; ``ordered``: in record-time order across chunks.

        Chunks without a requested connection (per the index) are not read at all.
        """
        wanted = set(ids.ids.tolist())
        units = [u for u in self.units if not u.conns or u.conns & wanted]
        read = 0
        if not ordered:  # a decoding group's chunks loaded at once, into one buffer
            groups = load_groups(units)
            self._start_inflater(len(groups))
            loads = prefetched(lambda group: self._load_group(group, ids), groups)
        else:
            loads = prefetched(lambda unit: self._load_or_skip(unit, ids), units)
        try:
            if not ordered:
                for batch in loads:
                    if batch is not None:
                        read += 1
                        yield batch
            else:
                for group in _clusters(units):
                    loaded = [b for _ in group if (b := next(loads)) is not None]
                    if loaded:
                        read += len(loaded)
                        yield concat(loaded).in_record_order()
        finally:
            loads.close()  # the loading thread is stopped and done before the file may be closed
            self._stop_inflater()
        if units and not read:
            why = self.lost[min(self.lost)][2] if getattr(self, "lost", None) else "damaged"
            msg = f"every chunk holding the topics read is damaged ({why})"
            raise DamagedError(msg)

    def _start_inflater(self, groups: int) -> None:
        """The second lane of :meth:`_load_units` for a log of several decoding groups, where two cores are free
        to run it (a short log's one group is loaded as before)."""
        self.inflater = None
        if groups >= 2 and cores() >= 2:
            from concurrent.futures import ThreadPoolExecutor

            self.lost = getattr(self, "lost", {})  # made here: both lanes may record a damaged unit
            self.inflater = ThreadPoolExecutor(1, thread_name_prefix="slamobs-inflate")

    def _stop_inflater(self) -> None:
        pool, self.inflater = getattr(self, "inflater", None), None
        if pool is not None:
            pool.shutdown(wait=True)

    def _load_group(self, group: list[Unit], ids: ConnIds) -> RawBatch | None:
        """The requested messages of a group of complete units, each decompressed into its part of one buffer."""
        if len(group) == 1:
            return self._load_or_skip(group[0], ids)
        sizes = [slot_bytes(unit) for unit in group]
        data = np.empty(sum(sizes), np.uint8)
        slots, pos = [], 0
        for size in sizes:
            slots.append((pos, data[pos : pos + size]))
            pos += size
        loaded = self._load_units(group, ids, [out for _, out in slots])
        batches = [batch for batch in loaded if batch is not None]  # a damaged unit skipped leaves its part unused
        at = [p for (p, _), batch in zip(slots, loaded, strict=True) if batch is not None]
        if not batches:
            return None
        view = data.view()
        view.flags.writeable = False
        return placed(view, batches, at)

    def _load_units(self, group: list[Unit], ids: ConnIds, outs: list[np.ndarray]) -> list[RawBatch | None]:
        """:meth:`_load_or_skip` of each unit of a group into its slot, in order. Compressed units are read from
        the file here, then decompressed, checked and walked on two lanes (this thread and :attr:`inflater`, whose
        work runs without the GIL): the loading lane, the read's longest, is halved."""
        pool = getattr(self, "inflater", None)
        if pool is None or any(unit.compression in {"", "none"} or unit.partial for unit in group):
            return [self._load_or_skip(unit, ids, out) for unit, out in zip(group, outs, strict=True)]
        blobs = []
        for unit in group:  # the file is read by this thread only, in order
            try:
                blobs.append(read_blob(self.bio, unit))
            except _CHUNK_ERRORS as err:  # raised (or the unit skipped) where its unpacking would be
                blobs.append(err)
        work = list(zip(group, blobs, outs, strict=True))
        half = (len(work) + 1) // 2

        def lane(items) -> list[RawBatch | None]:
            return [self._load_or_skip(unit, ids, out, blob) for unit, blob, out in items]

        beside = pool.submit(lane, work[half:])
        try:
            mine = lane(work[:half])
        finally:
            error = beside.exception()  # waits: nothing writes into the group's buffer after this returns
        if error is not None:
            raise error
        return mine + beside.result()

    def _load_or_skip(self, unit: Unit, ids: ConnIds, out: np.ndarray | None = None, blob=None) -> RawBatch | None:
        if not unit.indexed:
            return self.load(unit, ids, out, blob)
        try:
            return self.load(unit, ids, out, blob)
        except _CHUNK_ERRORS as err:
            if machine_failure(err):  # e.g. zstd's "Allocation error": the chunk is fine, the memory is not
                raise
            self.lose(unit.pos, unit.messages, unit.start_ns, one_line(err).rstrip(".") or type(err).__name__)
            return None

    def lose(self, pos: int, messages: int, start_ns: int, why: str) -> None:
        """Record a chunk (at file offset ``pos``) whose messages could not be read."""
        if not hasattr(self, "lost"):
            self.lost: dict[int, tuple[int, int, str]] = {}
        self.lost.setdefault(pos, (messages, start_ns, why))

    def damage_texts(self) -> list[str]:
        """The recovery note and one note about the chunks skipped by their index, if any."""
        texts = [self.damage] if getattr(self, "damage", None) else []
        lost = getattr(self, "lost", {})
        if lost:
            known = [m for m, _, _ in lost.values() if m >= 0]
            count = f"{sum(known)} messages lost" + (" (and an unknown number)" if len(known) < len(lost) else "")
            first = min(lost)
            t0 = min((u.start_ns for u in self.units), default=lost[first][1])
            at = ", ".join(f"byte {p} (record time +{(lost[p][1] - t0) / _NS:.3f} s)" for p in sorted(lost)[:3])
            more = ", ..." if len(lost) > 3 else ""
            texts.append(
                f"{self.label} has {len(lost)} damaged chunk(s) at {at}{more}: skipped with the help of the "
                f"index, reading went on with the next intact chunk; {count} ({lost[first][2]})"
            )
        return texts

    def load(self, unit: Unit, ids: ConnIds, out: np.ndarray | None = None, blob=None) -> RawBatch:
        """Decompress (into ``out``, see :func:`read_unit`) and scan one unit (damaged records at its end: the
        complete ones before them are kept and the rest counted lost when the index says how many it held).
        ``blob``: what :func:`read_blob` read of it (or raised), else it is read here."""
        if blob is None:
            assert self.bio
            data = read_unit(self.bio, unit, out)
        elif isinstance(blob, BaseException):
            raise blob
        else:
            data = unpack_unit(*blob, unit, out)
        wanted = wanted_table(ids)
        if wanted is not None:  # the requested messages straight from the walk
            recs = records(self.walk, data, wanted, unit.messages)
            if recs.status == CLEAN or (recs.status == CUT and unit.partial):
                return RawBatch(data, recs.conn, recs.t_ns, recs.dpos, recs.dlen)
        recs = records(self.walk, data)
        if recs.status == BAD or (recs.status == CUT and not unit.partial):
            if unit.recovered:  # the scan kept the complete records before the damage and said so
                return message_batch(data, recs, self.message_op, ids)
            if not unit.indexed:
                msg = f"records of the chunk at byte {unit.pos} are damaged"
                raise DamagedError(msg)
            found = int(np.count_nonzero(recs.op == self.message_op))
            self.lose(
                unit.pos,
                unit.messages - found if unit.messages >= 0 else -1,
                unit.start_ns,
                f"damaged records inside the chunk at byte {unit.pos}",
            )
        return message_batch(data, recs, self.message_op, ids)


def damage_note(
    label: str, why: str, count: int, span: tuple[int, int] | None, stop: int, size: int, where: str
) -> str:
    """The one-line note about a recovered file: what was wrong, what was kept, where reading stopped."""
    until = f" up to record time +{(span[1] - span[0]) / _NS:.3f} s" if span is not None else ""
    return (
        f"{label} is incomplete ({why}): recovered {count} complete messages{until} by scanning; "
        f"reading stopped at byte {stop} of {size} ({where})"
    )


def ordered_messages(
    source: Chunked,
    connections: list[Connection],
    start: int | None,
    stop: int | None,
) -> Iterator[tuple[Connection, int, bytes]]:
    ids = ConnIds({c.id: i for i, c in enumerate(connections)})
    for batch in source.batches(ids, ordered=True):
        for i in range(len(batch)):
            t = int(batch.rec_ns[i])
            if (start is None or t >= start) and (stop is None or t < stop):
                yield connections[int(batch.conn[i])], t, batch.payload(i)
