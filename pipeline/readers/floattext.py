"""Text lines of stamped float rows, byte-for-byte as Python writes them, without a Python call per number.

``repr(float)`` costs about a microsecond per value, so a one-hour trajectory (millions of numbers) took
seconds to export as TUM. Arrow's float-to-string cast finds the same shortest round-trip digits in C++;
only its layout differs from Python's (``1e-05`` vs ``0.00001``, ``1.0`` vs ``1``), so a compiled pass
re-lays the digits out exactly as ``repr`` does (positional for decimal exponents -4 < e <= 16, else
``d.ddde±XX``; ``.0`` on integral values; ``nan``, ``inf``) and writes the stamps exactly
(``sec.nnnnnnnnn``). Rows are formatted in blocks, so memory stays bounded for any length.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from slamobs.pipeline.kernel_cache import njit

BLOCK_ROWS = 65_536
_NS = 1_000_000_000
_MAX_VALUE = 25  # longest repr of a float64 ("-2.2250738585072014e-308") plus a separator
_MAX_STAMP = 32


@njit(cache=True)
def _put_int(out, o, v):  # pragma: no cover - compiled
    """Decimal digits of ``v >= 0`` at ``out[o:]``; returns the new end."""
    k = 1
    rest = v // 10
    while rest:
        k += 1
        rest //= 10
    for j in range(o + k - 1, o - 1, -1):
        out[j] = 48 + v % 10
        v //= 10
    return o + k


@njit(cache=True)
def _put_repr(out, o, data, a, b, digits):  # pragma: no cover - compiled
    """Python's ``repr`` of the float whose shortest form Arrow wrote at ``data[a:b]``; returns the new end."""
    i = a
    neg = data[i] == 45  # '-'
    start = a + 1 if neg else a
    # The common case, checked without reading every character: a fraction ('.' among the first 18
    # characters: at most 17 digits precede it), no exponent (Arrow's is within the last five characters),
    # at least 1e-4 (not "0.0000"). Then Arrow's text is repr's text.
    plain = not (
        b - start > 5
        and data[start] == 48
        and data[start + 2] == 48
        and data[start + 3] == 48
        and data[start + 4] == 48
        and data[start + 5] == 48
    )
    point = False
    for j in range(start, min(b, start + 18)):
        if data[j] == 46:
            point = True
            break
        if data[j] == 101:
            break
    for j in range(max(start, b - 5), b):
        if data[j] == 101:  # 'e'
            plain = False
    if plain and point:
        out[o : o + (b - a)] = data[a:b]
        return o + (b - a)
    if neg:
        out[o] = 45
        o += 1
        i += 1
    if data[i] == 110 or data[i] == 105:  # nan, inf: same text
        for j in range(i, b):
            out[o] = data[j]
            o += 1
        return o
    n = 0  # significant digits collected
    before_point = 0  # digits (leading zeros included) before the decimal point
    leading = 0  # zeros before the first nonzero digit
    point = False
    exp = 0
    while i < b:
        c = data[i]
        if c == 46:  # '.'
            point = True
        elif c == 101 or c == 69:  # 'e'
            i += 1
            sign = 1
            if data[i] == 45:
                sign = -1
                i += 1
            elif data[i] == 43:
                i += 1
            e = 0
            while i < b:
                e = e * 10 + (data[i] - 48)
                i += 1
            exp = sign * e
            break
        else:
            if not point:
                before_point += 1
            if n == 0 and c == 48:
                leading += 1
            else:
                digits[n] = c
                n += 1
        i += 1
    while n > 0 and digits[n - 1] == 48:  # trailing zeros are not significant
        n -= 1
    if n == 0:
        out[o] = 48
        out[o + 1] = 46
        out[o + 2] = 48
        return o + 3
    decpt = before_point - leading + exp  # value = 0.d1d2...dn x 10**decpt
    if -4 < decpt <= 16:
        if decpt <= 0:
            out[o] = 48
            out[o + 1] = 46
            o += 2
            for _ in range(-decpt):
                out[o] = 48
                o += 1
            for j in range(n):
                out[o] = digits[j]
                o += 1
        elif decpt >= n:
            for j in range(n):
                out[o] = digits[j]
                o += 1
            for _ in range(decpt - n):
                out[o] = 48
                o += 1
            out[o] = 46
            out[o + 1] = 48
            o += 2
        else:
            for j in range(n):
                if j == decpt:
                    out[o] = 46
                    o += 1
                out[o] = digits[j]
                o += 1
        return o
    out[o] = digits[0]
    o += 1
    if n > 1:
        out[o] = 46
        o += 1
        for j in range(1, n):
            out[o] = digits[j]
            o += 1
    e = decpt - 1
    out[o] = 101
    out[o + 1] = 45 if e < 0 else 43
    o += 2
    e = -e if e < 0 else e
    if e < 10:
        out[o] = 48
        o += 1
    return _put_int(out, o, e)


@njit(cache=True)
def _lines(t_ns, offsets, data, ncols):  # pragma: no cover - compiled
    """``sec.nnnnnnnnn v1 v2 ...\\n`` per row; values are row-major Arrow strings (``offsets``, ``data``)."""
    n = t_ns.shape[0]
    out = np.empty(n * (_MAX_STAMP + ncols * _MAX_VALUE), np.uint8)
    digits = np.empty(64, np.uint8)
    o = 0
    for r in range(n):
        t = t_ns[r]
        if t < 0:
            out[o] = 45
            o += 1
            t = -t
        o = _put_int(out, o, t // 1_000_000_000)
        out[o] = 46
        o += 1
        frac = t % 1_000_000_000
        for p in range(8, -1, -1):
            out[o + p] = 48 + frac % 10
            frac //= 10
        o += 9
        for c in range(ncols):
            out[o] = 32
            o += 1
            k = r * ncols + c
            o = _put_repr(out, o, data, offsets[k], offsets[k + 1], digits)
        out[o] = 10
        o += 1
    return out[:o]


def _shortest(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Arrow's shortest round-trip strings of ``values`` (flattened): (int32 offsets, utf-8 bytes)."""
    import pyarrow as pa

    arr = pa.array(np.ascontiguousarray(values, dtype=np.float64).ravel()).cast(pa.string())
    _, offsets, data = arr.buffers()
    off = np.frombuffer(offsets, np.int32, len(arr) + 1, arr.offset * 4)
    raw = np.frombuffer(data, np.uint8) if data is not None else np.zeros(0, np.uint8)
    return off, raw


def iter_stamped_rows(t_ns: np.ndarray, *values: np.ndarray) -> Iterator[bytes]:
    """Lines ``f"{sec}.{nsec:09d}" + "".join(" " + repr(v) for v in row) + "\\n"``, a block of rows at a time;
    the row is the rows of ``values`` ((N, k) arrays) side by side, joined block by block (no full copy)."""
    t = np.asarray(t_ns, dtype=np.int64)
    parts = [
        np.asarray(v, dtype=np.float64).reshape(t.shape[0], -1) if t.shape[0] else np.asarray(v, dtype=np.float64)
        for v in values
    ]
    ncols = sum(p.shape[1] for p in parts)
    for start in range(0, t.shape[0], BLOCK_ROWS):
        block = slice(start, start + BLOCK_ROWS)
        offsets, data = _shortest(np.hstack([p[block] for p in parts]))
        yield _lines(np.ascontiguousarray(t[block]), offsets, data, ncols).tobytes()


def stamped_rows(t_ns: np.ndarray, *values: np.ndarray) -> bytes:
    """All lines of :func:`iter_stamped_rows` as one string of bytes."""
    return b"".join(iter_stamped_rows(t_ns, *values))
