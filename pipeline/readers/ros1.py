"""ROS1 bags (format 2.0): rosbags' reader opened from the connection and chunk records only, read chunk-wise.

rosbags builds a Python object per message when it opens a bag (its index) and decodes messages one by one;
here the index section gives the chunks, which are read whole (:mod:`.chunks`). A bag without a usable index
(not closed, truncated, index damaged) is scanned chunk by chunk and every complete message is kept.
"""

from __future__ import annotations

import re
import struct
from contextlib import suppress
from io import BytesIO
from typing import TYPE_CHECKING

import numpy as np
from rosbags.interfaces import Connection, ConnectionExtRosbag1, MessageDefinition
from rosbags.interfaces import MessageDefinitionFormat as Fmt
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag1.reader import ChunkInfo as Ros1ChunkInfo
from rosbags.rosbag1.reader import Header, RecordType, normalize
from rosbags.typesys.msg import normalize_msgtype
from slamobs.pipeline.errors import machine_failure, one_line
from slamobs.pipeline.kernel_cache import njit

from .chunks import BAD, CLEAN, CUT, FULL, Chunked, Unit, damage_note, ordered_messages, read_unit, records, u32
from .storage import DamagedError

if TYPE_CHECKING:
    from collections.abc import Collection, Iterator
    from pathlib import Path

#: What a ROS1 bag starts with (the version follows).
MAGIC = b"#ROSBAG V"
#: Op of a message data record.
MSGDATA_ROS1 = 2


@njit(cache=True, nogil=True)
def _ros1_walk(buf, fill, op, conn, t_ns, hpos, dpos, dlen, wanted):  # pragma: no cover - compiled
    """Walk ROS1 records (header length, ``name=value`` fields, data length, data); count or fill. ``wanted``
    (connection id -> index, -1: not wanted; empty: every record): only the wanted messages, their connection as
    the index (:func:`.chunks.records`). Filling stops (``FULL``) before a record the arrays have no room for."""
    end = buf.shape[0]
    pos = 0
    n = 0
    while pos < end:
        if pos + 4 > end:
            return n, pos, CUT
        hl = u32(buf, pos)
        if pos + 8 + hl > end:
            return n, pos, CUT
        q = pos + 4
        hend = q + hl
        rop, rconn, rtime = -1, -1, np.int64(-1)
        while q < hend:
            if q + 4 > hend:
                return n, pos, BAD
            fl = u32(buf, q)
            f0 = q + 4
            q = f0 + fl
            if q > hend:
                return n, pos, BAD
            eq = f0
            while eq < q and buf[eq] != 61:  # '='
                eq += 1
            if eq == q:
                return n, pos, BAD
            name_len = eq - f0
            v = eq + 1
            if name_len == 2 and buf[f0] == 111 and buf[f0 + 1] == 112 and q - v >= 1:  # op
                rop = np.int64(buf[v])
            elif name_len == 4 and buf[f0] == 99 and buf[f0 + 1] == 111 and q - v >= 4:  # conn
                rconn = u32(buf, v)
            elif name_len == 4 and buf[f0] == 116 and buf[f0 + 1] == 105 and q - v >= 8:  # time
                rtime = u32(buf, v) * 1_000_000_000 + u32(buf, v + 4)
        if rop < 0:
            return n, pos, BAD
        dl = u32(buf, hend)
        if hend + 4 + dl > end:
            return n, pos, CUT
        if wanted.shape[0]:
            if rop != 2 or rconn < 0 or rconn >= wanted.shape[0] or wanted[rconn] < 0:
                pos = hend + 4 + dl
                continue
            rconn = wanted[rconn]
        if fill:
            if n == op.shape[0]:
                return n, pos, FULL
            op[n] = rop
            conn[n] = rconn
            t_ns[n] = rtime
            hpos[n] = pos
            dpos[n] = hend + 4
            dlen[n] = dl
        n += 1
        pos = hend + 4 + dl
    return n, pos, CLEAN


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


class Ros1Bag(Chunked, Reader1):
    """rosbags' ROS1 reader, opened from connection and chunk records only (no per-message index).

    A bag without a usable index (not closed, truncated, index damaged) is scanned chunk by chunk; with a
    usable index a damaged chunk is skipped and counted.
    """

    message_op = MSGDATA_ROS1
    label = "ROS1 bag"
    walk = staticmethod(_ros1_walk)

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self.units: list[Unit] = []
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
                self._recover(data_start, size, f"index unreadable: {one_line(err).rstrip('.')}")

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
                unit = Unit(
                    bio.tell(),
                    datasize,
                    compression,
                    header.get_uint32("size"),
                    info.start_time,
                    info.end_time - 1,
                    frozenset(info.connection_counts),
                    indexed=True,
                    messages=messages,
                )
            except (Ros1ReaderError, struct.error, UnicodeDecodeError, ValueError, KeyError, OSError) as err:
                # a damaged chunk header: the index knows where the next chunk starts
                self.lose(info.pos, messages, info.start_time, f"chunk header: {one_line(err).rstrip('.')}")
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
                unit = Unit(
                    data_pos, size - data_pos if cut else dlen, compression, raw_size, 0, 0, frozenset(), partial=cut
                )
                try:
                    data = read_unit(bio, unit)
                except (DamagedError, RuntimeError, OSError, ValueError) as err:
                    if machine_failure(err):
                        raise
                    where = f"unreadable chunk: {one_line(err).rstrip('.')}"
                    break
                recs = records(_ros1_walk, data)
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
                        Unit(
                            unit.pos,
                            unit.size,
                            unit.compression,
                            unit.raw_size,
                            int(t.min()),
                            int(t.max()),
                            frozenset(ids.tolist()),
                            partial=cut,
                            recovered=True,
                        ),
                    )
                    self.chunk_infos.append(
                        Ros1ChunkInfo(pos, int(t.min()), int(t.max()) + 1, dict(zip(ids.tolist(), counts.tolist()))),
                    )
                    count += int(msgs.sum())
                    last_ns = int(t.max()) if last_ns is None else max(last_ns, int(t.max()))
                if cut or recs.status != CLEAN:
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
        self.damage = damage_note("ROS1 bag", why, count, span, min(pos, size), size, where)

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
        yield from ordered_messages(self, list(connections or self.connections), start, stop)
