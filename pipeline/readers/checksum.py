"""CRC-32 (zlib's) of decompressed chunk records at memory speed: carry-less multiplication (x86 ``PCLMULQDQ``).

An MCAP chunk stores the CRC-32 of its uncompressed records, and a chunk that fails it is damaged: every byte a
read decompresses is checked. zlib's ``crc32`` (1.2.13 here) reads ~2 GB/s, which was a fifth of a 60 s MCAP's
read; folding 64 bytes at a time with carry-less products (Intel's "Fast CRC Computation for Generic Polynomials
Using PCLMULQDQ", the reflected CRC-32 constants Linux's ``crc32-pclmul`` uses) reads them 3-5x faster. The
result is the same 32 bits as ``zlib.crc32`` (``tests/test_checksum.py`` compares them on every length and
offset up to a few hundred bytes and on chunk-sized buffers).

The kernel is one more to compile (~0.3 s of CPU): a process uses it once it is compiled, or when its kernel cache
holds it, or when one read checks at least :data:`COMPILE_BYTES` (there compiling costs less than it saves over a
few reads); else zlib checks the bytes. Where the CPU has no ``PCLMULQDQ`` (or numba is told to compile for
another CPU) zlib always does.
"""

from __future__ import annotations

import platform
import zlib
from functools import lru_cache

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from slamobs.pipeline.kernel_cache import cached, njit

#: A read checking at least this many bytes compiles the kernel if it is not compiled or cached yet: at ~0.35 ns
#: a byte saved, 256 MiB (~30 minutes of the benchmarks' figure-8 logs) saves ~0.1 s of the ~0.3 s it costs once.
COMPILE_BYTES = 256 << 20
#: Buffers shorter than this go to zlib (the kernel folds 64 bytes at a time; a call has its fixed cost).
_MIN_BYTES = 4096

_V2 = ir.VectorType(ir.IntType(64), 2)


def _vector(builder: ir.IRBuilder, lo: ir.Value, hi: ir.Value) -> ir.Value:
    first = builder.insert_element(ir.Constant(_V2, ir.Undefined), lo, ir.Constant(ir.IntType(32), 0))
    return builder.insert_element(first, hi, ir.Constant(ir.IntType(32), 1))


def _clmul(builder: ir.IRBuilder, a: ir.Value, b: ir.Value, imm: int) -> ir.Value:
    """``PCLMULQDQ``: the 128-bit carry-less product of a 64-bit half of ``a`` and one of ``b`` (``imm``)."""
    fnty = ir.FunctionType(_V2, [_V2, _V2, ir.IntType(8)])
    fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.x86.pclmulqdq")
    return builder.call(fn, [a, b, ir.Constant(ir.IntType(8), imm)])


def _halves(context, builder: ir.IRBuilder, sig, vec: ir.Value) -> ir.Value:
    i32 = ir.IntType(32)
    parts = [builder.extract_element(vec, ir.Constant(i32, 0)), builder.extract_element(vec, ir.Constant(i32, 1))]
    return context.make_tuple(builder, sig.return_type, parts)


@intrinsic
def _fold(typingctx, lo, hi, k_lo, k_hi, d_lo, d_hi):
    """The 128 bits (lo, hi) carried forward over the constants: clmul(lo, k_lo) ^ clmul(hi, k_hi) ^ (d_lo, d_hi)."""
    u = types.uint64
    sig = types.UniTuple(u, 2)(u, u, u, u, u, u)

    def codegen(context, builder, signature, args):
        x, k = _vector(builder, args[0], args[1]), _vector(builder, args[2], args[3])
        both = builder.xor(_clmul(builder, x, k, 0x00), _clmul(builder, x, k, 0x11))
        return _halves(context, builder, signature, builder.xor(both, _vector(builder, args[4], args[5])))

    return sig, codegen


@intrinsic
def _product(typingctx, a, b):
    """The 128-bit carry-less product of two 64-bit words, as (low, high) words."""
    sig = types.UniTuple(types.uint64, 2)(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        zero = ir.Constant(ir.IntType(64), 0)
        vec = _clmul(builder, _vector(builder, args[0], zero), _vector(builder, args[1], zero), 0x00)
        return _halves(context, builder, signature, vec)

    return sig, codegen


@intrinsic
def _u64(typingctx, buf, at):
    """The 8 bytes of a uint8 array from byte ``at`` on as a little-endian word (unaligned; not bounds-checked)."""
    sig = types.uint64(buf, at)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        return builder.load(builder.bitcast(builder.gep(data, [args[1]]), ir.IntType(64).as_pointer()), align=1)

    return sig, codegen


# Constants of the reflected CRC-32 (polynomial 0x104C11DB7): x^(k) mod P, bit-reflected.
_K1, _K2 = np.uint64(0x154442BD4), np.uint64(0x1C6E41596)  # fold by 512 bits
_K3, _K4 = np.uint64(0x1751997D0), np.uint64(0x0CCAA009E)  # fold by 128 bits
_K5 = np.uint64(0x163CD6124)  # 64 -> 32 bits
_MU, _POLY = np.uint64(0x1F7011641), np.uint64(0x1DB710641)  # Barrett reduction
_M32 = np.uint64(0xFFFFFFFF)


@njit(cache=True, nogil=True, nrt=False)
def _crc32_blocks(buf, crc):  # pragma: no cover - compiled
    """zlib's CRC-32 of ``buf``, which is a whole number of 16-byte blocks and at least 64 bytes, continuing
    ``crc``: four 128-bit lanes folded 64 bytes at a time, then into one, then reduced to 32 bits."""
    n = buf.shape[0]
    x0l = _u64(buf, 0) ^ (np.uint64(crc) ^ _M32)
    x0h, x1l, x1h = _u64(buf, 8), _u64(buf, 16), _u64(buf, 24)
    x2l, x2h, x3l, x3h = _u64(buf, 32), _u64(buf, 40), _u64(buf, 48), _u64(buf, 56)
    p = 64
    while p + 64 <= n:
        x0l, x0h = _fold(x0l, x0h, _K1, _K2, _u64(buf, p), _u64(buf, p + 8))
        x1l, x1h = _fold(x1l, x1h, _K1, _K2, _u64(buf, p + 16), _u64(buf, p + 24))
        x2l, x2h = _fold(x2l, x2h, _K1, _K2, _u64(buf, p + 32), _u64(buf, p + 40))
        x3l, x3h = _fold(x3l, x3h, _K1, _K2, _u64(buf, p + 48), _u64(buf, p + 56))
        p += 64
    x0l, x0h = _fold(x0l, x0h, _K3, _K4, x1l, x1h)
    x0l, x0h = _fold(x0l, x0h, _K3, _K4, x2l, x2h)
    x0l, x0h = _fold(x0l, x0h, _K3, _K4, x3l, x3h)
    while p + 16 <= n:
        x0l, x0h = _fold(x0l, x0h, _K3, _K4, _u64(buf, p), _u64(buf, p + 8))
        p += 16
    lo, hi = _product(x0l, _K4)  # 128 -> 96 bits
    lo ^= x0h
    b_lo, b_hi = _product(lo & _M32, _K5)  # 96 -> 64 bits
    lo = b_lo ^ ((lo >> np.uint64(32)) | (hi << np.uint64(32)))
    c_lo, _ = _product(lo & _M32, _MU)  # Barrett: the quotient, then the remainder
    d_lo, _ = _product(c_lo & _M32, _POLY)
    return np.uint32(((lo ^ d_lo) >> np.uint64(32)) ^ _M32)


@lru_cache(maxsize=1)
def _cpu_has_pclmul() -> bool:
    """Whether the kernels are compiled for this x86 CPU and it has ``PCLMULQDQ``."""
    if platform.machine().lower() not in {"x86_64", "amd64"}:
        return False
    from numba.core import config

    if config.CPU_NAME or config.CPU_FEATURES:  # numba told to compile for another (e.g. a generic) CPU
        return False
    import llvmlite.binding as llvm

    return bool(llvm.get_host_cpu_features().get("pclmul", False))


_state = {"ready": False}


def prepare(total_bytes: int) -> None:
    """Before a read that will check ``total_bytes``: make the kernel ready when it is cached, or when the read is
    long enough to pay for compiling it (:data:`COMPILE_BYTES`)."""
    if _state["ready"] or not _cpu_has_pclmul():
        return
    if total_bytes >= COMPILE_BYTES or _crc32_blocks.signatures or cached(__name__, "_crc32_blocks"):
        _crc32_blocks(_read_only(np.zeros(64, np.uint8)), 0)
        _state["ready"] = True


def _read_only(data: np.ndarray) -> np.ndarray:
    """A read-only view (the kernel is compiled for one array type, as the record walks are)."""
    if data.flags.writeable:
        data = data.view()
        data.flags.writeable = False
    return data


def crc32(data: np.ndarray) -> int:
    """``zlib.crc32(data)`` of a 1-d uint8 array, by the kernel once it is ready (:func:`prepare`)."""
    n = data.shape[0]
    if not _state["ready"] or n < _MIN_BYTES:
        return zlib.crc32(data)
    m = n - n % 16
    return zlib.crc32(data[m:], int(_crc32_blocks(_read_only(data[:m]), 0)))
