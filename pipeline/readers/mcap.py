"""MCAP files (profile ros2; bare or a rosbag2 directory's storage): rosbags' reader, read chunk-wise.

With a usable summary the chunks it lists are read whole (:mod:`.chunks`) and a damaged one is skipped and
counted; a file whose summary is missing or damaged (a crashed recording) is scanned record by record instead,
and every complete message is kept.
"""

from __future__ import annotations

import struct
from contextlib import suppress
from dataclasses import dataclass, field
from io import BytesIO
from typing import TYPE_CHECKING, BinaryIO

import numpy as np
import zstandard
from rosbags.interfaces import Connection, ConnectionExtRosbag2
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.rosbag2.storage_mcap import Channel, McapReader, Schema, Statistics, get_msgdef, get_qos
from slamobs.pipeline.errors import machine_failure, one_line
from slamobs.pipeline.kernel_cache import njit

from .chunks import (
    BAD,
    CLEAN,
    CUT,
    FULL,
    Chunked,
    Unit,
    chosen_walk,
    damage_note,
    ordered_messages,
    read_unit,
    records,
    u32,
)
from .storage import TIME_LIMIT_NS, TIME_RANGE, DamagedError, TimeRangeError

if TYPE_CHECKING:
    from collections.abc import Collection, Iterator
    from pathlib import Path

#: What an MCAP file starts with.
MAGIC = b"\x89MCAP0\r\n"
#: Opcode of a message record.
MESSAGE_MCAP = 5


def mcap_library(head: bytes) -> str:
    """The ``library`` of an MCAP file's header record (the program that wrote it) from the file's first bytes; ""
    when they are not an MCAP file's."""
    try:
        if not head.startswith(MAGIC) or head[8] != 0x01:
            return ""
        at = 8 + 1 + 8
        profile = int.from_bytes(head[at : at + 4], "little")
        at += 4 + profile
        size = int.from_bytes(head[at : at + 4], "little")
        return head[at + 4 : at + 4 + size].decode("utf-8", "replace")
    except IndexError:
        return ""


@njit(cache=True, nogil=True, nrt=False)
def _mcap_walk(buf, fill, op, conn, t_ns, hpos, dpos, dlen, wanted):  # pragma: no cover - compiled
    """Walk MCAP records (opcode, uint64 length, body); messages get channel, log time and payload. ``wanted``
    (channel id -> index, -1: not wanted; empty: every record): only the wanted messages, their channel as the
    index (:func:`.chunks.records`). Filling stops (``FULL``) before a record the arrays have no room for."""
    end = buf.shape[0]
    pos = 0
    n = 0
    while pos < end:
        if pos + 9 > end:
            return n, pos, CUT
        length = u32(buf, pos + 1) | (u32(buf, pos + 5) << 32)
        if length < 0 or length > end - pos - 9:
            return n, pos, CUT
        rop = np.int64(buf[pos])
        message = rop == 5
        if message and length < 22:
            return n, pos, BAD
        channel = np.int64(buf[pos + 9]) | (np.int64(buf[pos + 10]) << 8) if message else -1
        if wanted.shape[0]:  # one walk for both: the filtered one keeps wanted messages, their index as channel
            if channel < 0 or channel >= wanted.shape[0] or wanted[channel] < 0:
                pos += 9 + length
                continue
            channel = wanted[channel]
        if fill:
            if n == op.shape[0]:
                return n, pos, FULL
            op[n] = rop
            conn[n] = channel
            hpos[n] = pos
            if message:
                t_ns[n] = u32(buf, pos + 15) | (u32(buf, pos + 19) << 32)
                dpos[n] = pos + 31
                dlen[n] = length - 22
            else:
                t_ns[n] = -1
                dpos[n] = pos + 9
                dlen[n] = length
        n += 1
        pos += 9 + length
    return n, pos, CLEAN


_LENGTH = struct.Struct("<Q")
_U64 = np.arange(8)


def mcap_walk_array(buf, fill, op, conn, t_ns, hpos, dpos, dlen, wanted):
    """:func:`_mcap_walk` without compiling it, for a short log's first run (:func:`.chunks.chosen_walk`): the
    records' starts by a Python loop over their lengths (0.5-1.5 us a record), everything else by array code; the same
    records, arrays and stop (what a failure or a full array stops at) as the kernel's. Public:
    tests/test_readers.py checks it against the kernel on cut and damaged chunks."""
    end = buf.shape[0]
    starts: list[int] = []
    pos, status = 0, CLEAN
    while pos < end:
        if pos + 9 > end:
            status = CUT
            break
        (length,) = _LENGTH.unpack_from(buf, pos + 1)  # unsigned: a length past 2**63 is past the end too
        if length > end - pos - 9:
            status = CUT
            break
        starts.append(pos)
        pos += 9 + length
    at = np.array(starts, np.int64)
    lengths = buf[at[:, None] + 1 + _U64].view("<i8")[:, 0]
    message = buf[at] == MESSAGE_MCAP
    bad = np.flatnonzero(message & (lengths < 22))
    if bad.size:  # the kernel checks a record before it filters or fills
        at, pos, status = at[: bad[0]], int(at[bad[0]]), BAD
        lengths, message = lengths[: at.shape[0]], message[: at.shape[0]]
    channel = np.full(at.shape[0], -1, np.int64)
    channel[message] = buf[at[message] + 9].astype(np.int64) | (buf[at[message] + 10].astype(np.int64) << 8)
    if wanted.shape[0]:
        keep = message & (channel < wanted.shape[0])
        keep[keep] = wanted[channel[keep]] >= 0
        at, lengths, message, channel = at[keep], lengths[keep], message[keep], channel[keep]
        channel = wanted[channel]
    n = at.shape[0]
    if fill:
        if n > op.shape[0]:
            n, pos, status = op.shape[0], int(at[op.shape[0]]), FULL
            at, lengths, message, channel = at[:n], lengths[:n], message[:n], channel[:n]
        op[:n] = buf[at]
        conn[:n] = channel
        hpos[:n] = at
        t_ns[:n] = np.where(message, buf[at[:, None] + 15 + _U64].view("<i8")[:, 0], -1)
        dpos[:n] = at + np.where(message, 31, 9)
        dlen[:n] = np.where(message, lengths - 22, lengths)
    return n, pos, status


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


@dataclass
class _Tally:
    """What a scan of an MCAP file's data section has found so far."""

    counts: dict[int, int] = field(default_factory=dict)  # channel id -> messages
    count: int = 0
    first: int = 2**63 - 1
    last: int = 0
    chunks: int = 0

    def add(self, channels: list[int], found: list[int], lo: int, hi: int) -> None:
        for cid, c in zip(channels, found, strict=True):
            self.counts[cid] = self.counts.get(cid, 0) + c
        self.count += sum(found)
        self.first, self.last = min(self.first, lo), max(self.last, hi)


class McapStorage(Chunked, McapReader):
    """rosbags' MCAP reader with chunk-wise reading, and a scan when the summary is missing or damaged; with a
    usable summary a damaged chunk is skipped and counted."""

    message_op = MESSAGE_MCAP
    label = "MCAP file"
    walk = staticmethod(_mcap_walk)

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.units: list[Unit] = []
        self.damage: str | None = None

    def _open(self) -> None:
        try:
            super()._open()
        except (Ros2ReaderError, struct.error, TypeError, ValueError, AssertionError, OSError, KeyError) as err:
            if not self.data_start:  # bad magic, header or profile: not ours to repair
                if self.bio is not None and self.bio.seek(0, 2) == len(MAGIC):  # rosbags: "ord() expected a character"
                    msg = "the file ends after its magic bytes, before the header record"
                    raise Ros2ReaderError(msg) from None
                raise
            assert self.bio
            size = self.bio.seek(0, 2)
            self.schemas, self.channels, self.connections, self.chunks = {}, {}, [], []
            self.statistics = None
            self._scan(size, f"summary unreadable: {one_line(err).rstrip('.')}")
            self._check_times()
            return
        if self.chunks:
            self.units = [
                Unit(
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
            self.walk = chosen_walk(_mcap_walk, mcap_walk_array, [u.messages for u in self.units])
        else:
            self._scan(self.data_end, None)
        self._check_times()

    def _check_times(self) -> None:
        """Refuse a log whose summary (or scan) puts record times outside 0 to TIME_LIMIT_NS."""
        meta = self.metadata
        if meta.message_count and not 0 <= meta.start_time <= meta.end_time <= TIME_LIMIT_NS:
            lo, hi = meta.start_time % 2**64, (meta.end_time - 1) % 2**64  # as stored (uint64), not as wrapped
            msg = (
                f"record (log) times {lo} to {hi} ns are {TIME_RANGE}: the MCAP file's times are corrupt "
                "(repair or re-record the log)"
            )
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
        tally = _Tally()
        where = "end of file"
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
                stop = self._scan_chunk(pos, size, cut, tally)
                if stop is not None:
                    pos, where = (size if cut else pos), stop
                    break
            elif cut:
                where = "inside a record"
                break
            elif op == MESSAGE_MCAP:
                channel, _, log_time, _ = struct.unpack("<HIQQ", bio.read(22))
                if run and run[1] == pos:
                    run[1] = pos + 9 + length
                    run[2], run[3] = min(run[2], log_time), max(run[3], log_time)
                else:
                    self._flush_run(run)
                    run = [pos, pos + 9 + length, log_time, log_time]
                run.append(channel)
                tally.add([channel], [1], log_time, log_time)
            elif op in {0x03, 0x04}:
                with suppress(Ros2ReaderError, struct.error, UnicodeDecodeError):
                    self._add_schema_or_channel(op, bio.read(length))
            elif op in {0x0F, 0x02}:  # data end, footer: the data section is complete
                where = "end of the data section"
                break
            pos += 9 + length
        self._flush_run(run)
        self._scanned(tally)
        if why is not None and not tally.count:
            msg = f"{why}, and no complete message before byte {min(pos, size)} ({where})"
            raise Ros2ReaderError(msg)
        if why is not None:
            span = (tally.first, tally.last) if tally.count else None
            self.damage = damage_note("MCAP file", why, tally.count, span, min(pos, size), size, where)

    def _scan_chunk(self, pos: int, size: int, cut: bool, tally: _Tally) -> str | None:
        """The chunk record at ``pos`` (its op and length read): its schemas and channels kept, its messages a
        unit; where the scan stops (a damaged or cut chunk), None to go on."""
        bio = self.bio
        assert bio
        fixed = bio.read(28)
        comp_len = bio.read(4)
        if len(fixed) < 28 or len(comp_len) < 4:
            return "inside a chunk header"
        t0, t1, raw_size, _ = struct.unpack("<QQQI", fixed)
        compression = bio.read(int.from_bytes(comp_len, "little")).decode(errors="replace")
        packed = bio.read(8)
        if len(packed) < 8:
            return "inside a chunk header"
        data_pos = bio.tell()
        avail = min(int.from_bytes(packed, "little"), size - data_pos)
        unit = Unit(data_pos, avail, compression, raw_size, t0, t1, frozenset(), pos + 33, partial=cut)
        try:
            data = read_unit(bio, unit)
        except (DamagedError, RuntimeError, OSError, ValueError, zstandard.ZstdError) as err:
            if machine_failure(err):
                raise
            return f"unreadable chunk: {one_line(err).rstrip('.')}"
        recs = records(_mcap_walk, data)
        for k in np.flatnonzero((recs.op == 0x03) | (recs.op == 0x04)):
            d0 = int(recs.dpos[k])
            with suppress(Ros2ReaderError, struct.error, UnicodeDecodeError):
                self._add_schema_or_channel(int(recs.op[k]), data[d0 : d0 + int(recs.dlen[k])].tobytes())
        msgs = recs.op == MESSAGE_MCAP
        if msgs.any():
            ids, found = np.unique(recs.conn[msgs], return_counts=True)
            t = recs.t_ns[msgs]
            lo, hi = int(t.min()), int(t.max())
            channels = frozenset(ids.tolist())
            self.units.append(
                Unit(data_pos, avail, compression, raw_size, lo, hi, channels, pos + 33, cut, recovered=True)
            )
            tally.add(ids.tolist(), found.tolist(), lo, hi)
            tally.chunks += 1
        if cut or recs.status != CLEAN:
            return "inside a chunk" if cut else "at damaged records inside a chunk"
        return None

    def _scanned(self, tally: _Tally) -> None:
        """Statistics, connections and metadata as the scan found them."""
        count, first, last = tally.count, tally.first, tally.last
        self.statistics = Statistics(
            count, len(self.schemas), len(self.channels), 0, 0, tally.chunks, first, last, tally.counts
        )
        self.connections = [c._replace(msgcount=tally.counts.get(c.id, 0)) for c in self.connections]
        self.metadata = self.metadata._replace(
            duration=last - first + 1 if count else 0,
            start_time=first if count else 2**63 - 1,
            end_time=last + 1 if count else 0,
            message_count=count,
        )

    def _flush_run(self, run: list[int]) -> None:
        if run:
            self.units.append(Unit(run[0], run[1] - run[0], "", run[1] - run[0], run[2], run[3], frozenset(run[4:])))

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
        yield from ordered_messages(self, list(connections), start, stop)
