"""Container detection, opening and raw message access of ROS logs; every failure is an :class:`InputError`.

The container is recognised by its first bytes, not by its suffix, so that a text file renamed
``.bag`` gets a clear message and a valid log with an odd suffix still opens. rosbags' ``AnyReader``
chooses its reader from the suffix, so a log whose suffix does not match its content is opened through
a temporary symlink with the expected suffix.

``AnyReader`` stays the handle the rest of the readers use (topics, typestore, deserialisation), but its
ROS1 and MCAP storage readers are replaced by the ones below, because rosbags

* builds a Python object per message when opening a ROS1 bag (its index) and decodes messages one by
  one; here chunks are read whole (:class:`RawBatch`: one buffer, offset arrays) so
  :mod:`.fastdecode` can decode them with array operations, in one pass for several topics;
* refuses truncated files (a crashed recording): here a ROS1 bag without a usable index and an MCAP
  file without a usable summary are scanned record by record, every complete message is kept (also
  from the readable part of a cut-off chunk) and :func:`damage_notes` says how many and where reading
  stopped.

rosbag2 directories keep rosbags' sqlite3 reader (queried in bulk here) and its file/message zstd
decompression; their MCAP storage files use the MCAP reader below.
"""

from __future__ import annotations

import bz2
import re
import stat
import struct
import tempfile
import zlib
from contextlib import contextmanager, suppress
from dataclasses import dataclass, replace
from io import BytesIO
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Literal

import lz4.frame
import numpy as np
import zstandard
from slamobs.pipeline.kernel_cache import njit
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection, ConnectionExtRosbag1, ConnectionExtRosbag2, MessageDefinition
from rosbags.interfaces import MessageDefinitionFormat as Fmt
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag1.reader import ChunkInfo as Ros1ChunkInfo
from rosbags.rosbag1.reader import Header, RecordType, normalize
from rosbags.rosbag2 import Reader as Reader2
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.rosbag2.reader import DirectoryReader
from rosbags.rosbag2.storage_mcap import Channel, McapReader, Schema, Statistics, get_msgdef, get_qos
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.msg import normalize_msgtype

from slamobs.pipeline.errors import BadInput, InputError, machine_failure, resource_error

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterable, Iterator, Sequence

Kind = Literal["ros1", "rosbag2", "mcap", "db3"]

#: Human readable container names, used in messages.
LABELS: dict[str, str] = {
    "ros1": "ROS1 bag",
    "rosbag2": "rosbag2 directory",
    "mcap": "MCAP file",
    "db3": "rosbag2 sqlite3 file",
}

_MAGIC: tuple[tuple[bytes, Kind], ...] = (
    (b"#ROSBAG V", "ros1"),
    (b"\x89MCAP0\r\n", "mcap"),
    (b"SQLite format 3\x00", "db3"),
)
_SUFFIX: dict[str, str] = {"ros1": ".bag", "mcap": ".mcap", "db3": ".db3"}
_WRAPPERS: tuple[tuple[bytes, str], ...] = (
    (b"BZh", "bzip2"),
    (b"\x1f\x8b", "gzip"),
    (b"\x28\xb5\x2f\xfd", "zstd"),
    (b"\xfd7zXZ\x00", "xz"),
    (b"PK\x03\x04", "zip"),
)
_NOT_A_LOG = "not a ROS1 bag, rosbag2 directory or MCAP file"
_NS = 1_000_000_000

# Types used when a log holds no message definitions at all (rosbag2 sqlite3 logs before Iron).
_FALLBACK_STORE = Stores.ROS2_HUMBLE


@dataclass(frozen=True)
class Container:
    """What a path holds: ``kind`` and, for rosbag2 directories, the storage plugin."""

    path: Path
    kind: Kind
    storage: str = ""
    note: str = ""  # how the path was interpreted, when it needed interpreting (a warning of the run)

    @property
    def label(self) -> str:
        """Human readable container name."""
        return LABELS[self.kind] + (f" ({self.storage})" if self.storage else "")


def _one_line(text: object) -> str:
    """Collapse an exception text to one line for the CLI."""
    return " ".join(str(text).split())


def mcap_library(head: bytes) -> str:
    """The ``library`` of an MCAP file's header record (the program that wrote it) from the file's first bytes; ""
    when they are not an MCAP file's."""
    magic = b"\x89MCAP0\r\n"
    try:
        if not head.startswith(magic) or head[8] != 0x01:
            return ""
        at = 8 + 1 + 8
        profile = int.from_bytes(head[at : at + 4], "little")
        at += 4 + profile
        size = int.from_bytes(head[at : at + 4], "little")
        return head[at + 4 : at + 4 + size].decode("utf-8", "replace")
    except IndexError:
        return ""


def detect_container(path: str | Path) -> Container:
    """Recognise the container of ``path`` from its content.

    Raises:
        InputError: The path is missing, unreadable or not a ROS log.

    """
    from slamobs.pipeline.paths import check_input, check_yaml_depth

    path = Path(path)
    st = check_input(path, "ROS log")  # never open a FIFO or a device: the read would block or never end
    if stat.S_ISDIR(st.st_mode):
        try:
            entries = sorted(path.iterdir())
        except OSError as err:
            raise InputError(path, f"cannot list the directory: {_one_line(err.strerror or err)}") from None
        for entry in entries:  # what rosbags would open in it must be openable
            if entry.name == "metadata.yaml" or entry.suffix in {".db3", ".mcap", ".zstd"}:
                check_input(entry, "storage file of a rosbag2 directory", directory_ok=False)
        meta = path / "metadata.yaml"
        if not meta.is_file():  # rosbag2 writes metadata.yaml when a recording closes: a crash leaves none
            inner = [x for x in entries if x.suffix in {".db3", ".mcap"} and x.is_file()]
            if len(inner) == 1:
                found = detect_container(inner[0])
                return replace(found, note=f"{path.name} has no metadata.yaml (recording not closed?): "
                                           f"read {inner[0].name} directly")
            hint = (f" (directory has no metadata.yaml and {len(inner)} storage files: open one of them directly)"
                    if inner else "")
            raise InputError(path, _NOT_A_LOG + hint)
        try:
            text = meta.read_text(errors="replace")
        except OSError as err:
            raise InputError(path, f"cannot read metadata.yaml: {_one_line(err.strerror)}") from None
        check_yaml_depth(text, meta, "metadata.yaml")  # rosbags parses it: 15 s before failing on 3000 '['
        match = re.search(r'storage_identifier:\s*["\']?([\w.-]+)', text)
        return Container(path, "rosbag2", match.group(1) if match else "")
    try:
        with path.open("rb") as fobj:
            head = fobj.read(16)
    except OSError as err:
        raise InputError(path, f"cannot read file: {_one_line(err.strerror)}") from None
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return Container(path, kind)
    if not head:
        raise InputError(path, f"{_NOT_A_LOG} (empty file)")
    for magic, name in _WRAPPERS:
        if head.startswith(magic):
            raise InputError(path, f"{_NOT_A_LOG} ({name}-compressed: decompress it first)")
    raise InputError(path, _NOT_A_LOG)


def _explain(container: Container, err: BaseException) -> InputError:
    """Turn a reader exception into the one-line InputError for this container: out of memory, threads or
    descriptors is the machine's failure (:class:`~slamobs.pipeline.errors.ResourceError`), never a corrupt log."""
    if (machine := resource_error(err, container.path, f"reading the {container.label}")) is not None:
        return machine
    reason = _one_line(err.args[0] if len(err.args) == 1 else err)
    if not reason:
        reason = "index and data disagree" if isinstance(err, AssertionError) else type(err).__name__
    reason = re.sub(r"\('(.*)',\)", r"\1", reason)  # rosbags nests args tuples in some messages
    if len(reason) > 300:  # e.g. a whole message definition quoted by the parser
        reason = reason[:297] + "..."
    if isinstance(err, PermissionError):
        return InputError(container.path, "permission denied")
    if isinstance(err, TimeRangeError):
        return InputError(container.path, reason)
    if "Profile is not ros2" in reason:
        return InputError(container.path, "unsupported MCAP file: profile is not ros2")
    if "Bag version" in reason:
        return InputError(container.path, f"unsupported {container.label}: {reason}")
    return InputError(container.path, f"corrupt or truncated {container.label}: {reason}")


# --------------------------------------------------------------------------- raw batches


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


def _concat(batches: Sequence[RawBatch]) -> RawBatch:
    if len(batches) == 1:
        return batches[0]
    shifts = np.cumsum([0, *(b.data.shape[0] for b in batches[:-1])])
    return RawBatch(
        np.concatenate([b.data for b in batches]),
        np.concatenate([b.conn for b in batches]),
        np.concatenate([b.rec_ns for b in batches]),
        np.concatenate([b.start + s for b, s in zip(batches, shifts, strict=True)]),
        np.concatenate([b.size for b in batches]),
    )


class _Ids:
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


# --------------------------------------------------------------------------- chunks


@dataclass(frozen=True)
class _Unit:
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


class DamagedError(BadInput):
    """Bytes of a log that cannot be read (bad compression, checksum, records); becomes an InputError."""


#: Record times are int64 nanoseconds here; MCAP stores uint64, so a time at or past 2^63 ns (the year 2262)
#: would wrap to a negative time, and one close below it overflows the sums of times and spans downstream. Every
#: ROS clock stays below 2^62 ns (ROS 1's uint32 seconds end in 2106), so only a corrupt file reaches it.
TIME_LIMIT_NS = 2**62
_TIME_RANGE = ("outside 0 to 2^62 ns (1970 to 2116, past any ROS clock; a uint64 time at or past 2^63 would be read "
               "as negative)")


class TimeRangeError(BadInput):
    """Record times outside 0 to TIME_LIMIT_NS; becomes a one-line InputError naming the log."""


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


def _read_unit(bio: BinaryIO, unit: _Unit) -> np.ndarray:
    """The unit's records, decompressed and checked against the stored CRC32 (MCAP)."""
    bio.seek(unit.pos)
    blob = bio.read(unit.size)
    if len(blob) != unit.size:
        msg = f"chunk at byte {unit.pos} is cut off"
        raise DamagedError(msg)
    raw = _inflate(blob, unit.compression, unit.raw_size, unit.partial)
    if unit.crc_at >= 0 and not unit.partial:
        bio.seek(unit.crc_at)
        (crc,) = struct.unpack("<I", bio.read(4))
        if crc and zlib.crc32(raw) != crc:
            msg = f"chunk at byte {unit.pos} fails its checksum"
            raise DamagedError(msg)
    return np.frombuffer(raw, np.uint8)


# Scanner status codes.
_CLEAN, _CUT, _BAD = 0, 1, 2


@njit(cache=True)
def _u32(buf, p):  # pragma: no cover - compiled
    return np.int64(buf[p]) | (np.int64(buf[p + 1]) << 8) | (np.int64(buf[p + 2]) << 16) | (np.int64(buf[p + 3]) << 24)


@njit(cache=True, nogil=True)
def _ros1_walk(buf, fill, op, conn, t_ns, hpos, dpos, dlen):  # pragma: no cover - compiled
    """Walk ROS1 records (header length, ``name=value`` fields, data length, data); count or fill."""
    end = buf.shape[0]
    pos = 0
    n = 0
    while pos < end:
        if pos + 4 > end:
            return n, pos, _CUT
        hl = _u32(buf, pos)
        if pos + 8 + hl > end:
            return n, pos, _CUT
        q = pos + 4
        hend = q + hl
        rop, rconn, rtime = -1, -1, np.int64(-1)
        while q < hend:
            if q + 4 > hend:
                return n, pos, _BAD
            fl = _u32(buf, q)
            f0 = q + 4
            q = f0 + fl
            if q > hend:
                return n, pos, _BAD
            eq = f0
            while eq < q and buf[eq] != 61:  # '='
                eq += 1
            if eq == q:
                return n, pos, _BAD
            name_len = eq - f0
            v = eq + 1
            if name_len == 2 and buf[f0] == 111 and buf[f0 + 1] == 112 and q - v >= 1:  # op
                rop = np.int64(buf[v])
            elif name_len == 4 and buf[f0] == 99 and buf[f0 + 1] == 111 and q - v >= 4:  # conn
                rconn = _u32(buf, v)
            elif name_len == 4 and buf[f0] == 116 and buf[f0 + 1] == 105 and q - v >= 8:  # time
                rtime = _u32(buf, v) * 1_000_000_000 + _u32(buf, v + 4)
        if rop < 0:
            return n, pos, _BAD
        dl = _u32(buf, hend)
        if hend + 4 + dl > end:
            return n, pos, _CUT
        if fill:
            op[n] = rop
            conn[n] = rconn
            t_ns[n] = rtime
            hpos[n] = pos
            dpos[n] = hend + 4
            dlen[n] = dl
        n += 1
        pos = hend + 4 + dl
    return n, pos, _CLEAN


@njit(cache=True, nogil=True)
def _mcap_walk(buf, fill, op, conn, t_ns, hpos, dpos, dlen):  # pragma: no cover - compiled
    """Walk MCAP records (opcode, uint64 length, body); messages get channel, log time and payload."""
    end = buf.shape[0]
    pos = 0
    n = 0
    while pos < end:
        if pos + 9 > end:
            return n, pos, _CUT
        length = _u32(buf, pos + 1) | (_u32(buf, pos + 5) << 32)
        if length < 0 or length > end - pos - 9:
            return n, pos, _CUT
        rop = np.int64(buf[pos])
        if rop == 5 and length < 22:
            return n, pos, _BAD
        if fill:
            op[n] = rop
            hpos[n] = pos
            if rop == 5:
                conn[n] = np.int64(buf[pos + 9]) | (np.int64(buf[pos + 10]) << 8)
                t_ns[n] = _u32(buf, pos + 15) | (_u32(buf, pos + 19) << 32)
                dpos[n] = pos + 31
                dlen[n] = length - 22
            else:
                conn[n] = -1
                t_ns[n] = -1
                dpos[n] = pos + 9
                dlen[n] = length
        n += 1
        pos += 9 + length
    return n, pos, _CLEAN


@dataclass(frozen=True)
class _Records:
    """Records found in a buffer, and where and how the walk ended."""

    op: np.ndarray
    conn: np.ndarray
    t_ns: np.ndarray
    hpos: np.ndarray
    dpos: np.ndarray
    dlen: np.ndarray
    stop: int
    status: int


def _records(walk: Callable[..., tuple[int, int, int]], buf: np.ndarray) -> _Records:
    """Count, then fill (two passes keep the scratch arrays exactly as long as the record count)."""
    none = np.empty(0, np.int64)
    n, _, _ = walk(buf, False, none, none, none, none, none, none)
    arrays = [np.empty(n, np.int64) for _ in range(6)]
    n, stop, status = walk(buf, True, *arrays)
    return _Records(*arrays, stop=int(stop), status=int(status))


MSGDATA_ROS1, MESSAGE_MCAP = 2, 5


def _batch(data: np.ndarray, recs: _Records, message_op: int, ids: _Ids) -> RawBatch:
    """The requested messages among ``recs``."""
    index = ids.lookup(recs.conn)
    keep = (recs.op == message_op) & (index >= 0)
    return RawBatch(data, index[keep], recs.t_ns[keep], recs.dpos[keep], recs.dlen[keep])


def _clusters(units: Iterable[_Unit]) -> Iterator[list[_Unit]]:
    """Consecutive units whose time spans overlap (their messages must be merged to be in order)."""
    group: list[_Unit] = []
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


#: Decompressed chunks read ahead of the decoding (by one loading thread), in decoding groups: the decoder
#: takes :data:`.fastdecode.GROUP_BYTES` (16 MB) at a time, the thread keeps about two groups ready.
PREFETCH_GROUPS = 2


def _prefetched(load: Callable[[_Unit], RawBatch | None], units: Sequence[_Unit]) -> Iterator[RawBatch | None]:
    """``load(unit)`` of every unit, in order, computed by one thread ahead of the caller.

    Reading, decompressing and checking a chunk (file I/O, zstd/lz4/bz2, CRC32 and the record walk all run
    without the GIL) overlap the decoding of the chunks before. The thread is the only one that touches the
    file while this runs; an exception it meets is raised here, at its unit; closing the generator (or an
    exception of the caller) stops the thread and waits for it.
    """
    if len(units) < 2:  # nothing to overlap
        for unit in units:
            yield load(unit)
        return
    import collections
    import threading

    from .fastdecode import GROUP_BYTES

    budget = PREFETCH_GROUPS * GROUP_BYTES
    ready: collections.deque = collections.deque()
    room = threading.Condition()
    held = [0]  # bytes loaded and not yet taken
    stop = False

    def work() -> None:
        for unit in units:
            try:
                item = (True, load(unit))
            except BaseException as err:  # noqa: BLE001 - handed to the caller, raised there
                item = (False, err)
            size = int(item[1].data.nbytes) if item[0] and item[1] is not None else 0
            with room:
                while held[0] and held[0] + size > budget and not stop:  # one unit always fits
                    room.wait()
                if stop:
                    return
                held[0] += size
                ready.append((item, size))
                room.notify_all()
            if not item[0]:
                return

    thread = threading.Thread(target=work, name="slamobs-chunk-reader", daemon=True)
    thread.start()
    try:
        for _ in units:
            with room:
                while not ready:
                    room.wait()
                (ok, value), size = ready.popleft()
                held[0] -= size
                room.notify_all()
            if not ok:
                raise value
            yield value
    finally:
        with room:
            stop = True
            room.notify_all()
        thread.join()


class _Chunked:
    """What the ROS1 and MCAP readers share: units, loading them, the damage report.

    A damaged chunk that the file's index (ROS1) or summary (MCAP) knows is skipped and counted: the index
    says where the next chunk starts and how many messages the damaged one held (:meth:`damage_texts`).
    """

    units: list[_Unit]
    damage: str | None
    bio: BinaryIO | None
    message_op: int
    walk: Callable[..., tuple[int, int, int]]
    label: str

    def batches(self, ids: _Ids, ordered: bool) -> Iterator[RawBatch]:
        """Requested messages chunk by chunk; ``ordered``: in record-time order across chunks.

        Chunks without a requested connection (per the index) are not read at all.
        """
        wanted = set(ids.ids.tolist())
        units = [u for u in self.units if not u.conns or u.conns & wanted]
        read = 0
        loads = _prefetched(lambda unit: self._load_or_skip(unit, ids), units)
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
                        yield _concat(loaded).in_record_order()
        finally:
            loads.close()  # the loading thread is stopped and done before the file may be closed
        if units and not read:
            why = self.lost[min(self.lost)][2] if getattr(self, "lost", None) else "damaged"
            msg = f"every chunk holding the topics read is damaged ({why})"
            raise DamagedError(msg)

    def _load_or_skip(self, unit: _Unit, ids: _Ids) -> RawBatch | None:
        if not unit.indexed:
            return self.load(unit, ids)
        try:
            return self.load(unit, ids)
        except _CHUNK_ERRORS as err:
            if machine_failure(err):  # e.g. zstd's "Allocation error": the chunk is fine, the memory is not
                raise
            self.lose(unit.pos, unit.messages, unit.start_ns, _one_line(err).rstrip(".") or type(err).__name__)
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
            texts.append(f"{self.label} has {len(lost)} damaged chunk(s) at {at}{more}: skipped with the help of the "
                         f"index, reading went on with the next intact chunk; {count} ({lost[first][2]})")
        return texts

    def load(self, unit: _Unit, ids: _Ids) -> RawBatch:
        """Decompress and scan one unit (damaged records at its end: the complete ones before them are kept
        and the rest counted lost when the index says how many it held)."""
        assert self.bio
        data = _read_unit(self.bio, unit)
        recs = _records(self.walk, data)
        if recs.status == _BAD or (recs.status == _CUT and not unit.partial):
            if unit.recovered:  # the scan kept the complete records before the damage and said so
                return _batch(data, recs, self.message_op, ids)
            if not unit.indexed:
                msg = f"records of the chunk at byte {unit.pos} are damaged"
                raise DamagedError(msg)
            found = int(np.count_nonzero(recs.op == self.message_op))
            self.lose(unit.pos, unit.messages - found if unit.messages >= 0 else -1, unit.start_ns,
                      f"damaged records inside the chunk at byte {unit.pos}")
        return _batch(data, recs, self.message_op, ids)


def _damage(label: str, why: str, count: int, span: tuple[int, int] | None, stop: int, size: int, where: str) -> str:
    """The one-line note about a recovered file: what was wrong, what was kept, where reading stopped."""
    until = f" up to record time +{(span[1] - span[0]) / _NS:.3f} s" if span is not None else ""
    return (
        f"{label} is incomplete ({why}): recovered {count} complete messages{until} by scanning; "
        f"reading stopped at byte {stop} of {size} ({where})"
    )


# --------------------------------------------------------------------------- ROS1


def _ros1_connection(fields: bytes, data: bytes, owner: object) -> Connection:
    """A connection record (its header fields and its data, which is a second field block)."""
    header = Header.read(BytesIO(struct.pack("<I", len(fields)) + fields))
    info = Header.read(BytesIO(struct.pack("<I", len(data)) + data))
    latching = info.get_string("latching") if "latching" in info else None
    return Connection(
        header.get_uint32("conn"),
        normalize(header.get_string("topic")),
        normalize_msgtype(info.get_string("type")),
        MessageDefinition(Fmt.MSG, info.get_string("message_definition")),
        info.get_string("md5sum"),
        0,
        ConnectionExtRosbag1(
            info.get_string("callerid") if "callerid" in info else None,
            int(latching) if latching not in (None, "") else None,
        ),
        owner,
    )


class Ros1Bag(_Chunked, Reader1):
    """rosbags' ROS1 reader, opened from connection and chunk records only (no per-message index).

    A bag without a usable index (not closed, truncated, index damaged) is scanned chunk by chunk; with a
    usable index a damaged chunk is skipped and counted.
    """

    message_op = MSGDATA_ROS1
    label = "ROS1 bag"
    walk = staticmethod(_ros1_walk)

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self.units: list[_Unit] = []
        self.damage: str | None = None

    def open(self) -> None:
        """Read the bag header and the index section, or scan the chunks."""
        if self.bio is not None:
            msg = "Reader is already open."
            raise Ros1ReaderError(msg)
        try:
            self.bio = self.path.open("rb")
        except PermissionError:
            raise
        except OSError as err:
            msg = f"Could not open file {str(self.path)!r}: {err.strerror}."
            raise Ros1ReaderError(msg) from err
        try:
            self._open()
        except BaseException:
            with suppress(Exception):
                self.close()
            raise

    def _open(self) -> None:
        bio = self.bio
        assert bio
        magic = bio.readline().decode(errors="replace")
        if not re.match(r"#ROSBAG V2\.0\n", magic):
            version = re.match(r"#ROSBAG V(\d+)\.(\d+)", magic)
            msg = "File magic is invalid."
            if version:
                msg = f"Bag version {int(version[1]) * 100 + int(version[2])!r} is not supported."
            raise Ros1ReaderError(msg)
        header = Header.read(bio, RecordType.BAGHEADER)
        index_pos = header.get_uint64("index_pos")
        conn_count = header.get_uint32("conn_count")
        chunk_count = header.get_uint32("chunk_count")
        if "encryptor" in header and header.get_string("encryptor"):
            msg = f"Bag encryption {header.get_string('encryptor')!r} is not supported."
            raise Ros1ReaderError(msg)
        (pad,) = struct.unpack("<I", bio.read(4))
        data_start = bio.tell() + pad
        size = bio.seek(0, 2)
        if index_pos == 0:
            self._recover(data_start, size, "not indexed, the recording was not closed")
        elif index_pos > size:
            self._recover(data_start, size, "file ends before its index")
        else:
            try:
                self._read_index(index_pos, conn_count, chunk_count, size)
            except (Ros1ReaderError, struct.error, UnicodeDecodeError, ValueError, KeyError) as err:
                self.connections, self.chunk_infos, self.units, self.lost = [], [], [], {}
                self._recover(data_start, size, f"index unreadable: {_one_line(err).rstrip('.')}")

    def _read_index(self, index_pos: int, conn_count: int, chunk_count: int, size: int) -> None:
        bio = self.bio
        assert bio
        bio.seek(index_pos)
        self.connections = [self.read_connection() for _ in range(conn_count)]
        self.chunk_infos = [self.read_chunk_info() for _ in range(chunk_count)]
        for info in self.chunk_infos:
            messages = sum(info.connection_counts.values())
            try:
                bio.seek(info.pos)
                header = Header.read(bio, RecordType.CHUNK)
                (datasize,) = struct.unpack("<I", bio.read(4))
                compression = header.get_string("compression")
                if compression not in {"none", "bz2", "lz4"}:
                    msg = f"unknown chunk compression {compression[:20]!r}"
                    raise Ros1ReaderError(msg)
                if bio.tell() + datasize > size:
                    msg = "chunk beyond the end of the file"
                    raise Ros1ReaderError(msg)
                unit = _Unit(bio.tell(), datasize, compression, header.get_uint32("size"), info.start_time,
                             info.end_time - 1, frozenset(info.connection_counts), indexed=True, messages=messages)
            except (Ros1ReaderError, struct.error, UnicodeDecodeError, ValueError, KeyError, OSError) as err:
                # a damaged chunk header: the index knows where the next chunk starts
                self.lose(info.pos, messages, info.start_time, f"chunk header: {_one_line(err).rstrip('.')}")
                continue
            self.units.append(unit)
        if self.chunk_infos and not self.units:
            msg = "no chunk the index names is readable"
            raise Ros1ReaderError(msg)
        self._set_counts()

    def _set_counts(self) -> None:
        counts: dict[int, int] = {}
        for info in self.chunk_infos:
            for cid, count in info.connection_counts.items():
                counts[cid] = counts.get(cid, 0) + count
        self.connections = [c._replace(msgcount=counts.get(c.id, 0)) for c in self.connections]

    def _recover(self, pos: int, size: int, why: str) -> None:
        """Scan top-level records from ``pos``: chunks (with the connections inside) until the data ends."""
        bio = self.bio
        assert bio
        conns: dict[int, Connection] = {}
        count, last_ns, where = 0, None, "end of file"
        while pos < size:
            bio.seek(pos)
            head = bio.read(4)
            if len(head) < 4:
                where = "inside a record header"
                break
            (hlen,) = struct.unpack("<I", head)
            fields = bio.read(hlen)
            tail = bio.read(4)
            if len(fields) < hlen or len(tail) < 4:
                where = "inside a record header"
                break
            try:
                header = Header.read(BytesIO(head + fields))
                op = header.get_uint8("op")
            except Ros1ReaderError:
                where = "at a damaged record"
                break
            (dlen,) = struct.unpack("<I", tail)
            data_pos = pos + 8 + hlen
            cut = data_pos + dlen > size or (op == RecordType.CHUNK and dlen == 0)  # 0: never finalised
            if op == RecordType.CHUNK:
                try:
                    compression, raw_size = header.get_string("compression"), header.get_uint32("size")
                except Ros1ReaderError:
                    where = "at a damaged chunk header"
                    break
                unit = _Unit(data_pos, size - data_pos if cut else dlen, compression, raw_size, 0, 0, frozenset(),
                             partial=cut)
                try:
                    data = _read_unit(bio, unit)
                except (DamagedError, RuntimeError, OSError, ValueError) as err:
                    if machine_failure(err):
                        raise
                    where = f"unreadable chunk: {_one_line(err).rstrip('.')}"
                    break
                recs = _records(_ros1_walk, data)
                for k in np.flatnonzero(recs.op == RecordType.CONNECTION):
                    h0, d0 = int(recs.hpos[k]) + 4, int(recs.dpos[k])
                    with suppress(Ros1ReaderError, ValueError, UnicodeDecodeError):
                        body = data[d0 : d0 + int(recs.dlen[k])].tobytes()
                        conn = _ros1_connection(data[h0 : d0 - 4].tobytes(), body, self)
                        conns.setdefault(conn.id, conn)
                msgs = (recs.op == MSGDATA_ROS1) & np.isin(recs.conn, list(conns))
                if msgs.any():
                    ids, counts = np.unique(recs.conn[msgs], return_counts=True)
                    t = recs.t_ns[msgs]
                    self.units.append(
                        _Unit(unit.pos, unit.size, unit.compression, unit.raw_size, int(t.min()), int(t.max()),
                              frozenset(ids.tolist()), partial=cut, recovered=True),
                    )
                    self.chunk_infos.append(
                        Ros1ChunkInfo(pos, int(t.min()), int(t.max()) + 1, dict(zip(ids.tolist(), counts.tolist()))),
                    )
                    count += int(msgs.sum())
                    last_ns = int(t.max()) if last_ns is None else max(last_ns, int(t.max()))
                if cut or recs.status != _CLEAN:
                    pos = size if cut else pos
                    where = "inside a chunk" if cut else "at damaged records inside a chunk"
                    break
            elif cut:
                where = "inside a record"
                break
            elif op == RecordType.CONNECTION:
                with suppress(Ros1ReaderError, ValueError, UnicodeDecodeError):
                    conn = _ros1_connection(fields, bio.read(dlen), self)
                    conns.setdefault(conn.id, conn)
            pos = data_pos + dlen
        if not count:
            msg = f"{why}, and no complete message before byte {min(pos, size)} ({where})"
            raise Ros1ReaderError(msg)
        self.connections = sorted(conns.values(), key=lambda c: c.id)
        self._set_counts()
        span = (min(u.start_ns for u in self.units), last_ns) if last_ns is not None else None
        self.damage = _damage("ROS1 bag", why, count, span, min(pos, size), size, where)

    def close(self) -> None:
        """Close the bag."""
        super().close()
        self.units = []

    def messages(
        self,
        connections: Collection[Connection] = (),
        start: int | None = None,
        stop: int | None = None,
    ) -> Iterator[tuple[Connection, int, bytes]]:
        """Messages in record-time order (rosbags' interface, read chunk-wise)."""
        yield from _ordered_messages(self, list(connections or self.connections), start, stop)


# --------------------------------------------------------------------------- MCAP


def _schema(body: bytes) -> Schema:
    bio = BytesIO(body)
    (key,) = struct.unpack("<H", bio.read(2))
    name, encoding, data = (_sized(bio, 4) for _ in range(3))
    return Schema(key, name.decode(), encoding.decode(), data.decode())


def _sized(bio: BinaryIO, width: int) -> bytes:
    raw = bio.read(width)
    if len(raw) != width:
        msg = "record too short"
        raise Ros2ReaderError(msg)
    size = int.from_bytes(raw, "little")
    data = bio.read(size)
    if len(data) != size:
        msg = "record too short"
        raise Ros2ReaderError(msg)
    return data


class McapStorage(_Chunked, McapReader):
    """rosbags' MCAP reader with chunk-wise reading, and a scan when the summary is missing or damaged; with a
    usable summary a damaged chunk is skipped and counted."""

    message_op = MESSAGE_MCAP
    label = "MCAP file"
    walk = staticmethod(_mcap_walk)

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.units: list[_Unit] = []
        self.damage: str | None = None

    def _open(self) -> None:
        try:
            super()._open()
        except (Ros2ReaderError, struct.error, TypeError, ValueError, AssertionError, OSError, KeyError) as err:
            if not self.data_start:  # bad magic, header or profile: not ours to repair
                raise
            assert self.bio
            size = self.bio.seek(0, 2)
            self.schemas, self.channels, self.connections, self.chunks = {}, {}, [], []
            self.statistics = None
            self._scan(size, f"summary unreadable: {_one_line(err).rstrip('.')}")
            self._check_times()
            return
        if self.chunks:
            self.units = [
                _Unit(
                    c.chunk_start_offset + 49 + len(c.compression),
                    c.compressed_size,
                    c.compression,
                    c.uncompressed_size,
                    c.message_start_time,
                    c.message_end_time,
                    frozenset(c.channel_count),
                    crc_at=c.chunk_start_offset + 33,
                    indexed=True,
                    messages=sum(c.channel_count.values()) if c.channel_count else -1,
                )
                for c in self.chunks
            ]
        else:
            self._scan(self.data_end, None)
        self._check_times()

    def _check_times(self) -> None:
        """Refuse a log whose summary (or scan) puts record times outside 0 to TIME_LIMIT_NS."""
        meta = self.metadata
        if meta.message_count and not 0 <= meta.start_time <= meta.end_time <= TIME_LIMIT_NS:
            lo, hi = meta.start_time % 2**64, (meta.end_time - 1) % 2**64  # as stored (uint64), not as wrapped
            msg = (f"record (log) times {lo} to {hi} ns are {_TIME_RANGE}: the MCAP file's times are corrupt "
                   "(repair or re-record the log)")
            raise TimeRangeError(msg)

    def _add_schema_or_channel(self, op: int, body: bytes) -> None:
        if op == 0x03:
            schema = _schema(body)
            self.schemas.setdefault(schema.id, schema)
            return
        bio = BytesIO(body)
        key, schema_id = struct.unpack("<HH", bio.read(4))
        topic, encoding, metadata = _sized(bio, 4).decode(), _sized(bio, 4).decode(), _sized(bio, 4)
        if key in self.channels:
            return
        schema = self.schemas.get(schema_id)
        self.channels[key] = Channel(key, schema.name if schema else "__schemaless__", topic, encoding, metadata)
        self.connections.append(
            Connection(
                key,
                topic,
                self.channels[key].schema,
                get_msgdef(schema),
                "",
                0,
                ConnectionExtRosbag2(encoding, get_qos(metadata)),
                self,
            ),
        )

    def _scan(self, size: int, why: str | None) -> None:
        """Walk the data section record by record; chunks are decompressed and walked with the kernel."""
        bio = self.bio
        assert bio
        pos = self.data_start
        counts: dict[int, int] = {}
        count, first, last, nchunks, where = 0, None, None, 0, "end of file"
        run: list[int] = []  # top-level messages (unchunked files): [start, end, t0, t1, channel ids...]
        while pos < size:
            bio.seek(pos)
            head = bio.read(9)
            if len(head) < 9:
                where = "inside a record header"
                break
            op, length = struct.unpack("<BQ", head)
            cut = pos + 9 + length > size
            if op == 0x06:
                fixed = bio.read(28)
                comp_len = bio.read(4)
                if len(fixed) < 28 or len(comp_len) < 4:
                    where = "inside a chunk header"
                    break
                t0, t1, raw_size, _ = struct.unpack("<QQQI", fixed)
                compression = bio.read(int.from_bytes(comp_len, "little")).decode(errors="replace")
                packed = bio.read(8)
                if len(packed) < 8:
                    where = "inside a chunk header"
                    break
                data_pos = bio.tell()
                avail = min(int.from_bytes(packed, "little"), size - data_pos)
                unit = _Unit(data_pos, avail, compression, raw_size, t0, t1, frozenset(), pos + 33, partial=cut)
                try:
                    data = _read_unit(bio, unit)
                except (DamagedError, RuntimeError, OSError, ValueError, zstandard.ZstdError) as err:
                    if machine_failure(err):
                        raise
                    where = f"unreadable chunk: {_one_line(err).rstrip('.')}"
                    break
                recs = _records(_mcap_walk, data)
                for k in np.flatnonzero((recs.op == 0x03) | (recs.op == 0x04)):
                    d0 = int(recs.dpos[k])
                    with suppress(Ros2ReaderError, struct.error, UnicodeDecodeError):
                        self._add_schema_or_channel(int(recs.op[k]), data[d0 : d0 + int(recs.dlen[k])].tobytes())
                msgs = recs.op == MESSAGE_MCAP
                if msgs.any():
                    ids, found = np.unique(recs.conn[msgs], return_counts=True)
                    for cid, c in zip(ids.tolist(), found.tolist(), strict=True):
                        counts[cid] = counts.get(cid, 0) + c
                    t = recs.t_ns[msgs]
                    lo, hi = int(t.min()), int(t.max())
                    self.units.append(
                        _Unit(data_pos, avail, compression, raw_size, lo, hi, frozenset(ids.tolist()), pos + 33, cut,
                              recovered=True),
                    )
                    count += int(msgs.sum())
                    first = lo if first is None else min(first, lo)
                    last = hi if last is None else max(last, hi)
                    nchunks += 1
                if cut or recs.status != _CLEAN:
                    pos = size if cut else pos
                    where = "inside a chunk" if cut else "at damaged records inside a chunk"
                    break
            elif cut:
                where = "inside a record"
                break
            elif op == MESSAGE_MCAP:
                body = bio.read(22)
                channel, _, log_time, _ = struct.unpack("<HIQQ", body)
                if run and run[1] == pos:
                    run[1] = pos + 9 + length
                    run[2], run[3] = min(run[2], log_time), max(run[3], log_time)
                else:
                    self._flush_run(run)
                    run = [pos, pos + 9 + length, log_time, log_time]
                run.append(channel)
                counts[channel] = counts.get(channel, 0) + 1
                count += 1
                first = log_time if first is None else min(first, log_time)
                last = log_time if last is None else max(last, log_time)
            elif op in {0x03, 0x04}:
                with suppress(Ros2ReaderError, struct.error, UnicodeDecodeError):
                    self._add_schema_or_channel(op, bio.read(length))
            elif op in {0x0F, 0x02}:  # data end, footer: the data section is complete
                where = "end of the data section"
                break
            pos += 9 + length
        self._flush_run(run)
        self.statistics = Statistics(
            count, len(self.schemas), len(self.channels), 0, 0, nchunks,
            first if first is not None else 2**63 - 1, last if last is not None else 0, counts,
        )
        self.connections = [c._replace(msgcount=counts.get(c.id, 0)) for c in self.connections]
        self.metadata = self.metadata._replace(
            duration=last - first + 1 if count else 0,
            start_time=first if count else 2**63 - 1,
            end_time=last + 1 if count else 0,
            message_count=count,
        )
        if why is not None and not count:
            msg = f"{why}, and no complete message before byte {min(pos, size)} ({where})"
            raise Ros2ReaderError(msg)
        if why is not None:
            span = (first, last) if first is not None and last is not None else None
            self.damage = _damage("MCAP file", why, count, span, min(pos, size), size, where)

    def _flush_run(self, run: list[int]) -> None:
        if run:
            self.units.append(_Unit(run[0], run[1] - run[0], "", run[1] - run[0], run[2], run[3], frozenset(run[4:])))

    def close(self) -> None:
        """Close the file."""
        super().close()
        self.units = []

    def messages(
        self,
        connections: Collection[Connection],
        start: int | None = None,
        stop: int | None = None,
    ) -> Iterator[tuple[Connection, int, bytes]]:
        """Messages in record-time order (rosbags' interface, read chunk-wise)."""
        yield from _ordered_messages(self, list(connections), start, stop)


def _ordered_messages(
    source: _Chunked,
    connections: list[Connection],
    start: int | None,
    stop: int | None,
) -> Iterator[tuple[Connection, int, bytes]]:
    ids = _Ids({c.id: i for i, c in enumerate(connections)})
    for batch in source.batches(ids, ordered=True):
        for i in range(len(batch)):
            t = int(batch.rec_ns[i])
            if (start is None or t >= start) and (stop is None or t < stop):
                yield connections[int(batch.conn[i])], t, batch.payload(i)


# --------------------------------------------------------------------------- sqlite3

_SQL_ROWS, _SQL_BYTES = 8192, 1 << 20  # a batch of rows stops at either (like a chunk: bounded memory)


def _joined(blobs: Sequence[bytes], conn: np.ndarray, rec_ns: np.ndarray) -> RawBatch:
    size = np.fromiter(map(len, blobs), np.int64, len(blobs))
    start = np.zeros(size.shape[0], np.int64)
    np.cumsum(size[:-1], out=start[1:])
    return RawBatch(np.frombuffer(b"".join(blobs), np.uint8), conn, rec_ns, start, size)


def _sqlite_batches(storage: Sqlite3Reader, ids: _Ids, ordered: bool) -> Iterator[RawBatch]:
    """Rows of the requested topics in blocks of about ``_SQL_BYTES``.

    Unordered (the columnar path), SQLite itself concatenates the payloads of a window of row ids
    (``group_concat``, in C), so Python handles a few objects per block instead of three per row;
    the decoded columns are sorted by record time afterwards. Ordered, rows come by timestamp.
    """
    assert storage.dbconn
    db = storage.dbconn
    wanted = ids.ids.tolist()
    among = f"topic_id IN ({','.join('?' * len(wanted))})"
    text_is_bytes = next(iter(db.execute("PRAGMA encoding")))[0] == "UTF-8"
    if ordered or not text_is_bytes:
        cursor = db.execute(f"SELECT topic_id, timestamp, data FROM messages WHERE {among} ORDER BY timestamp", wanted)
        rows: list[tuple[int, int, bytes]] = []
        nbytes = 0
        for row in cursor:
            rows.append(row)
            nbytes += len(row[2])
            if nbytes >= _SQL_BYTES or len(rows) == _SQL_ROWS:
                yield _rows_batch(rows, ids)
                rows, nbytes = [], 0
        if rows:
            yield _rows_batch(rows, ids)
        return
    first, last = next(iter(db.execute("SELECT min(id), max(id) FROM messages")))
    query = (
        "SELECT CAST(group_concat(data, x'') AS BLOB), group_concat(length(data)), group_concat(timestamp), "
        f"group_concat(topic_id) FROM messages WHERE {among} AND id >= ? AND id < ?"
    )
    window, lo = 16, first if first is not None else 1
    while last is not None and lo <= last:
        blob, sizes, stamps, topics = next(iter(db.execute(query, [*wanted, lo, lo + window])))
        lo += window
        if blob is None:
            window = min(window * 4, _SQL_ROWS)
            continue
        size = _numbers(sizes)
        start = np.zeros(size.shape[0], np.int64)
        np.cumsum(size[:-1], out=start[1:])
        yield RawBatch(np.frombuffer(blob, np.uint8), ids.lookup(_numbers(topics)), _numbers(stamps), start, size)
        grow = _SQL_BYTES / max(len(blob), 1)  # aim the next window at _SQL_BYTES of payload
        window = int(min(max(window * min(grow, 4.0), 1), _SQL_ROWS))


def _numbers(text: str) -> np.ndarray:
    """Comma-separated integers (a ``group_concat``) as int64."""
    return np.fromstring(text, dtype=np.int64, sep=",")


def _rows_batch(rows: list[tuple[int, int, bytes]], ids: _Ids) -> RawBatch:
    topic, stamp, blobs = zip(*rows, strict=True)
    conn = ids.lookup(np.fromiter(topic, np.int64, len(topic)))
    return _joined(blobs, conn, np.fromiter(stamp, np.int64, len(stamp)))


def _inflate_each(batch: RawBatch) -> RawBatch:
    """rosbag2 ``compression_mode: message``: every payload is a zstd frame of its own."""
    dctx = zstandard.ZstdDecompressor()
    blobs = [dctx.decompressobj().decompress(batch.payload(i)) for i in range(len(batch))]
    return _joined(blobs, batch.conn, batch.rec_ns)


# --------------------------------------------------------------------------- access


def _sources(reader: AnyReader, connections: Sequence[Connection]) -> Iterator[tuple[object, _Ids, bool]]:
    """(storage, ids, message-compressed) for every storage holding some of ``connections``."""
    for sub in reader.readers:
        storage = sub.storage if isinstance(sub, Reader2) else sub
        if isinstance(storage, DirectoryReader):
            per_message = storage.metadata.compression_mode == "message"
            for inner in storage.storages:
                mapping = {
                    x.id: i
                    for i, c in enumerate(connections)
                    if c.owner is storage
                    for x in inner.connections
                    if x.topic == c.topic and x.msgtype == c.msgtype
                }
                yield inner, _Ids(mapping), per_message
        else:
            yield storage, _Ids({c.id: i for i, c in enumerate(connections) if c.owner is storage}), False


def iter_batches(
    reader: AnyReader,
    path: str | Path,
    connections: Sequence[Connection],
    *,
    ordered: bool = False,
) -> Iterator[RawBatch]:
    """Messages of ``connections`` (any mix of topics) as :class:`RawBatch` es, one pass over the file.

    Without ``ordered`` batches come in file order (within a batch too); sort the decoded columns by
    record time. With ``ordered`` they come in record-time order, as rosbags yields messages.

    Raises:
        InputError: A chunk or row cannot be read (corrupt data).

    """
    try:
        for storage, ids, per_message in _sources(reader, connections):
            if not ids:
                continue
            if isinstance(storage, _Chunked):
                batches = storage.batches(ids, ordered)
            elif isinstance(storage, Sqlite3Reader):
                batches = _sqlite_batches(storage, ids, ordered)
            else:  # pragma: no cover - every storage rosbags opens is handled above
                msg = f"unsupported storage {type(storage).__name__}"
                raise DamagedError(msg)
            for batch in batches:
                _check_record_times(batch, path, connections)
                yield _inflate_each(batch) if per_message else batch
    except InputError:
        raise
    except GeneratorExit:
        raise
    except Exception as err:  # decompression, struct, sqlite errors alike
        raise _explain(detect_container(path), err) from None


def _check_record_times(batch: RawBatch, path: str | Path, connections: Sequence[Connection]) -> None:
    """One line naming the topic when a message's record time is outside 0 to TIME_LIMIT_NS (a summary may not
    show it; rosbag2 sqlite3 files have none to check)."""
    bad = (batch.rec_ns < 0) | (batch.rec_ns >= TIME_LIMIT_NS)
    if bad.any():
        topic = connections[int(batch.conn[np.argmax(bad)])].topic
        raise InputError(path, f"{int(bad.sum())} messages have a record (log) time {_TIME_RANGE}: the log's times "
                               "are corrupt (repair or re-record the log)", topic)


def iter_raw(
    reader: AnyReader,
    path: str | Path,
    connections: Collection[Connection],
) -> Iterator[tuple[Connection, int, bytes]]:
    """Yield ``(connection, record_ns, rawdata)`` of ``connections`` in record-time order.

    Read failures become InputError; errors raised by the consumer's loop body do not pass through here.
    """
    conns = list(connections)
    for batch in iter_batches(reader, path, conns, ordered=True):
        for i in range(len(batch)):
            yield conns[int(batch.conn[i])], int(batch.rec_ns[i]), batch.payload(i)


_NOTES = "_slamobs_notes"  # attribute of an opened reader: how its path was interpreted


def damage_notes(reader: AnyReader) -> list[str]:
    """What was recovered from truncated or unindexed files (empty for intact logs)."""
    notes = list(getattr(reader, _NOTES, ()))
    for sub in reader.readers:
        storage = sub.storage if isinstance(sub, Reader2) else sub
        inner = storage.storages if isinstance(storage, DirectoryReader) else [storage]
        notes += [text for s in inner if isinstance(s, _Chunked) for text in s.damage_texts()]
    return notes


# --------------------------------------------------------------------------- opening


@contextmanager
def _rosbags_path(container: Container) -> Iterator[Path]:
    """Yield a path whose suffix makes ``AnyReader`` choose the right reader."""
    path = container.path
    want = _SUFFIX.get(container.kind)
    if container.kind == "rosbag2":
        ok = path.suffix != ".bag"
        want = ""
    else:
        ok = path.suffix == want
    if ok:
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="slamobs-") as tmp:
        link = Path(tmp) / f"log{want}"
        try:
            link.symlink_to(path.resolve(), target_is_directory=path.is_dir())
        except OSError:
            raise InputError(path, f"unexpected suffix for a {container.label}; rename it to *{want}") from None
        yield link


def _use_own_readers(reader: AnyReader) -> None:
    """Swap rosbags' ROS1 and MCAP storage readers for the chunk-wise, recovering ones above."""
    if not reader.is2:
        reader.readers = [Ros1Bag(p) for p in reader.paths]
        return
    for sub in reader.readers:
        if type(sub.storage) is McapReader:
            sub.storage = McapStorage(sub.storage.path)
        elif isinstance(sub.storage, DirectoryReader):
            sub.storage.STORAGE_PLUGINS = {**DirectoryReader.STORAGE_PLUGINS, "mcap": McapStorage}


class _FallbackTypes:
    """The typestore rosbags falls back to for a bag that stores no message definitions, built only if one does
    (rosbags reads nothing but its ``fielddefs``; building the ROS 2 store imports its predecessors, ~0.1 s)."""

    @property
    def fielddefs(self):
        return get_typestore(_FALLBACK_STORE).fielddefs


@contextmanager
def open_log(path: str | Path) -> Iterator[AnyReader]:
    """Open a ROS1 bag, rosbag2 directory, MCAP or db3 file as an opened rosbags ``AnyReader``.

    Truncated ROS1 bags and MCAP files open with what could be recovered (see :func:`damage_notes`).
    Reader errors raised inside the ``with`` block (corrupt chunks, undecodable messages) are turned into
    :class:`InputError` as well.

    Raises:
        InputError: Missing path, unknown container, corrupt or truncated file.

    """
    container = detect_container(path)
    with _rosbags_path(container) as rpath:
        try:
            reader = AnyReader([rpath], default_typestore=_FallbackTypes())  # type: ignore[arg-type]
            _use_own_readers(reader)
            reader.open()
        except Exception as err:  # any reader failure means a bad file
            raise _explain(container, err) from None
        if container.note:
            setattr(reader, _NOTES, [container.note])
        try:
            yield reader
        except (Ros1ReaderError, Ros2ReaderError, SerdeError, DamagedError) as err:
            raise _explain(container, err) from None
        finally:
            reader.close()


def require_definitions(reader: AnyReader, path: str | Path, connections: Collection[Connection]) -> None:
    """Fail when a connection's type cannot be decoded because its definition is not in the log.

    Raises:
        InputError: A message definition is missing.

    """
    for conn in connections:
        if conn.msgtype not in reader.typestore.fielddefs:
            raise InputError(path, f"message definition for {conn.msgtype} is not stored in the log", conn.topic)
