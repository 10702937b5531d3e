"""The chunk checksum kernel (readers/checksum.py): zlib's CRC-32 bit for bit, and a chunk failing it still damaged."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from mcap.reader import make_reader

from slamobs.pipeline.readers import checksum, read_log
from slamobs.pipeline.simulate import simulate

from test_readers_damage import _write  # noqa: F401 - the damage tests' log writer (small chunks)

pytestmark = pytest.mark.skipif(not checksum._cpu_has_pclmul(), reason="the kernel needs x86 PCLMULQDQ")


@pytest.fixture(scope="module")
def ready():
    """The kernel compiled (a read of COMPILE_BYTES would compile it), restored afterwards."""
    before = dict(checksum._state)
    checksum.prepare(checksum.COMPILE_BYTES)
    assert checksum._state["ready"]
    yield
    checksum._state.update(before)


def test_kernel_is_zlibs_crc32(ready):
    """Every length around the kernel's 16- and 64-byte steps, at every alignment, continuing a CRC or not."""
    rng = np.random.default_rng(5)
    buf = rng.integers(0, 256, 300_000, dtype=np.uint8)
    for n in [*range(64, 400), 4095, 4096, 4111, 65_536 + 7, 262_144 + 9]:
        for offset in range(8):
            part = buf[offset : offset + n]
            m = n - n % 16
            for start in (0, 0x12345678):
                blocks = int(checksum._crc32_blocks(checksum._read_only(part[:m]), start))
                assert zlib.crc32(part[m:], blocks) == zlib.crc32(part, start), (n, offset, start)
        assert checksum.crc32(part) == zlib.crc32(part), n
    assert checksum.crc32(np.zeros(0, np.uint8)) == 0


def test_corrupt_uncompressed_chunk_is_damaged_with_the_kernel(ready, tmp_path):
    """A byte changed inside an uncompressed chunk's records (their structure intact) fails the chunk's CRC: the
    chunk is skipped and counted, as with zlib's check."""
    sim = simulate("figure8", duration=2.0, seed=3)
    src = _write(sim, tmp_path / "full.mcap", "mcap")
    data = bytearray(src.read_bytes())
    with src.open("rb") as fobj:
        index = make_reader(fobj).get_summary().chunk_indexes[1]
    assert index.compression == "" and index.uncompressed_size >= checksum._MIN_BYTES
    last = index.chunk_start_offset + index.chunk_length - 1  # the last byte of the last message's payload
    data[last] ^= 0x01
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(data))
    got = read_log(path)
    notes = [w for w in got.warnings if "damaged chunk" in w]
    assert len(notes) == 1 and "fails its checksum" in notes[0], got.warnings
