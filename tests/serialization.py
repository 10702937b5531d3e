"""Serialising rosbags messages in each encoding the readers handle (shared by the decoder tests)."""

from __future__ import annotations

import numpy as np

#: ROS1, little-endian CDR, big-endian CDR
ENCODINGS = ["ros1", "cdr", "cdr-big-endian"]


def serialize(ts, msg: object, msgtype: str, encoding: str) -> bytes:
    if encoding == "ros1":
        return bytes(ts.serialize_ros1(msg, msgtype))
    return bytes(ts.serialize_cdr(msg, msgtype, little_endian=encoding == "cdr"))


def deserialize(ts, raw: bytes, msgtype: str, encoding: str) -> object:
    return ts.deserialize_ros1(raw, msgtype) if encoding == "ros1" else ts.deserialize_cdr(raw, msgtype)


def as_buffer(payloads: list[bytes], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Payloads at random, unaligned offsets in one buffer (as in a decompressed chunk): the buffer, each
    payload's start and size."""
    parts, starts, pos = [], [], 0
    for payload in payloads:
        gap = bytes(rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8))
        parts += [gap, payload]
        starts.append(pos + len(gap))
        pos += len(gap) + len(payload)
    data = np.frombuffer(b"".join(parts), np.uint8)
    return data, np.array(starts, np.int64), np.array([len(p) for p in payloads], np.int64)
