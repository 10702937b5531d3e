"""Parquet outputs of a run (schemas in ``schemas/``) and the atomic run directory that holds them.

Tables are written a stretch of rows at a time (:class:`TableWriter`, one row group per stretch), so a
multi-hour run never holds its histories. Encodings suit the data: float columns are byte-stream split
(the sign/exponent/high-mantissa bytes of a smooth series compress well, the low mantissa bytes are
noise), nanosecond times delta-packed, small integer ids dictionary-encoded; all zstd. Float values are
rounded before writing: the dropped low bits are the incompressible part of a noisy estimate, far below any
estimator's accuracy. A column with a fixed step (``schemas.fixed_steps``: every length, 2**-20 m ≈ 0.95 µm near
the origin and in a UTM or ECEF frame alike; the quaternions 2**-24; the biases 2**-26) is rounded to a multiple
of it (:func:`round_step`); each ``float_bits`` above the default 28 halves the step, each below doubles it. The
other columns keep ``float_bits`` significant mantissa bits (a relative rounding of at most 2**-29 ≈ 1.9e-9); the
uncertainty columns at most their schema's own ``float_bits`` (16), and in metres never a step coarser than
2**-20 m. ``float_bits=52`` writes every bit.
"""

from __future__ import annotations

import base64
import ctypes
import errno
import json
import os
import queue
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager, suppress
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from slamobs.pipeline.blocks import rms_sigmas, unique_inverse
from slamobs.pipeline.cores import lower_this_thread
from slamobs.pipeline.errors import OutputError, output_error
from slamobs.pipeline.lifetime import owner_alive, owner_marker
from slamobs.pipeline.paths import (
    MANIFEST,
    WRITER,
    check_name,
    check_output,
    foreign_entry,
    identity,
    read_manifest,
    temporary_prefix,
)
from slamobs.schemas import DEFAULT_FLOAT_BITS, LENGTH_STEP_EXP, arrow_schema, fixed_steps

if TYPE_CHECKING:  # importing observers (numba) is for runs: stats, compare and export write without it
    from slamobs.pipeline.observers.base import ObserverResult

COMPRESSION = "zstd"
#: zstd's first fast level: the hour's tables 61.63 -> 61.74 MB (the rounded floats' low bytes are zero, the
#: rest near noise: level 1 finds little more), ~8 % less of the writer's CPU (docs/benchmarks.md, session 17)
COMPRESSION_LEVEL = -1
METADATA_KEY = b"slamobs"
FLOAT_BITS = DEFAULT_FLOAT_BITS
_EXPONENT = np.uint64(0x7FF0_0000_0000_0000)


#: Axes of the pose error ``(δθ, δp)`` in the order of the pose covariance (``cov_<a>_<b>`` columns, a ≤ b).
POSE_AXES = ("rx", "ry", "rz", "x", "y", "z")


def result_tables(res: ObserverResult) -> dict[str, dict[str, np.ndarray]]:
    """Columns of every output table, named as in ``schemas/``."""
    return {
        **stretch_tables(res),
        "landmarks": landmark_table(
            res.landmark_ids, res.landmark_xyz, res.det_t_ns, res.det_ids, landmark_cov=res.landmark_cov
        ),
    }


def pose_uncertainty_columns(cov: np.ndarray | None) -> dict[str, np.ndarray]:
    """The poses' standard deviations and covariance upper triangle from (K, 6, 6) covariances; none (the
    writer fills nulls) without them."""
    if cov is None:
        return {}
    sd = np.sqrt(np.clip(np.einsum("kii->ki", cov), 0.0, None))
    n = len(POSE_AXES)
    return {
        **{f"sigma_{a}": sd[:, 3 + i] for i, a in enumerate("xyz")},
        **{f"sigma_r{a}": sd[:, i] for i, a in enumerate("xyz")},
        **{f"cov_{POSE_AXES[i]}_{POSE_AXES[j]}": cov[:, i, j] for i in range(n) for j in range(i, n)},
    }


def landmark_uncertainty_columns(cov: np.ndarray | None) -> dict[str, np.ndarray]:
    """A landmark's RMS standard deviation and covariance upper triangle from (L, 3, 3) covariances."""
    if cov is None:
        return {}
    return {
        "sigma": rms_sigmas(cov),
        **{f"cov_{a}{b}": cov[:, i, j] for i, a in enumerate("xyz") for j, b in enumerate("xyz") if j >= i},
    }


class BackgroundWrites:
    """``write(item)`` for every item handed to :meth:`put`, in order, on one thread, while the caller computes
    the next item: the observer's stretches are written (rounded, encoded, compressed: pyarrow, without the
    GIL) while the observer (a kernel without the GIL) runs the following stretch.

    At most ``depth`` items wait. An exception of ``write`` is raised by the next :meth:`put` or by
    :meth:`finish`; :meth:`cancel` (the caller failed or was interrupted) drops what waits and waits for the
    item being written, so nothing writes into the output after it returns.
    """

    def __init__(self, write, depth: int = 1) -> None:
        self._write = write
        self._items: queue.Queue = queue.Queue(depth)
        self._error: BaseException | None = None
        self._cancelled = False
        self.last = None  # what ``write`` returned for the last item
        self.busy_s = 0.0  # seconds spent in ``write``
        self._thread = threading.Thread(target=self._run, name="slamobs-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        lower_this_thread()  # the caller's computation is the run's critical path, not the writes beside it
        while (item := self._items.get()) is not self._items:
            if self._error is not None or self._cancelled:
                continue  # drain: the caller will see the error or has given up
            t = time.perf_counter()
            try:
                self.last = self._write(item)
            except BaseException as err:  # noqa: BLE001 - raised in the caller's thread
                self._error = err
            self.busy_s += time.perf_counter() - t

    def _raise(self) -> None:
        if self._error is not None:  # kept set: the thread drains what still waits instead of writing it
            self.cancel()
            raise self._error

    def put(self, item) -> None:
        self._raise()
        self._items.put(item)

    def finish(self):
        """Wait until every item is written; what ``write`` returned for the last one."""
        self._items.put(self._items)  # the end marker
        self._thread.join()
        self._raise()
        return self.last

    def cancel(self) -> None:
        if not self._thread.is_alive():
            return
        self._cancelled = True
        while True:  # make room for the end marker without blocking on a full queue
            try:
                self._items.get_nowait()
            except queue.Empty:
                break
        self._items.put(self._items)
        self._thread.join()


def stretch_tables(res: ObserverResult) -> dict[str, dict[str, np.ndarray]]:
    """The tables with a row per sample or detection (all but ``landmarks``), of a whole run or a stretch."""
    from slamobs.pipeline.lie import rots_to_quats  # numba: only a run's result needs it

    q = rots_to_quats(np.ascontiguousarray(res.rotation)) if len(res.t_ns) else np.zeros((0, 4))
    return {
        "poses": {
            "t_ns": res.t_ns,
            "x": res.position[:, 0],
            "y": res.position[:, 1],
            "z": res.position[:, 2],
            "qx": q[:, 0],
            "qy": q[:, 1],
            "qz": q[:, 2],
            "qw": q[:, 3],
            **pose_uncertainty_columns(res.pose_cov),
        },
        "biases": {
            "t_ns": res.t_ns,
            **{f"gyro_bias_{a}": res.gyro_bias[:, i] for i, a in enumerate("xyz")},
            **{f"vel_bias_{a}": res.vel_bias[:, i] for i, a in enumerate("xyz")},
        },
        "landmark_tracks": {
            "t_ns": res.det_t_ns,
            "id": res.det_ids,
            **{a: res.track_xyz[:, i] for i, a in enumerate("xyz")},
        },
        "innovations": {
            "t_ns": res.det_t_ns,
            "id": res.det_ids,
            **{f"e{a}": res.innovation[:, i] for i, a in enumerate("xyz")},
            "e_norm": np.linalg.norm(res.innovation, axis=1),
        },
    }


def landmark_table(
    landmark_ids: np.ndarray,
    landmark_xyz: np.ndarray,
    det_t_ns: np.ndarray,
    det_ids: np.ndarray,
    landmark_cov: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The final map: per landmark ever detected its position, first/last detection time and count, and the
    position covariance where the estimator has one (``landmark_ids`` order)."""
    ids, inv = unique_inverse(np.asarray(det_ids))  # (np.unique's counts are the same as the bincount's)
    n_obs = np.bincount(inv, minlength=ids.shape[0])
    first = np.full(ids.shape, np.iinfo(np.int64).max, dtype=np.int64)
    last = np.full(ids.shape, np.iinfo(np.int64).min, dtype=np.int64)
    np.minimum.at(first, inv, det_t_ns)
    np.maximum.at(last, inv, det_t_ns)
    order = np.searchsorted(landmark_ids, ids)
    return {
        "id": ids.astype(np.int64),
        **{a: landmark_xyz[order, i] for i, a in enumerate("xyz")},
        "first_seen_ns": first,
        "last_seen_ns": last,
        "n_obs": n_obs.astype(np.int64),
        **landmark_uncertainty_columns(None if landmark_cov is None else landmark_cov[order]),
    }


#: Columns at least this long are rounded by the compiled :func:`.rounding.round_bits` and
#: :func:`.rounding.round_step_into` (a long run's stretches are 131 072 rows); shorter ones by the array code: a
#: short log's first run does not compile them.
ROUND_KERNEL_ROWS = 65_536


def round_mantissa(values: np.ndarray, bits: int, finest: int | None = None) -> np.ndarray:
    """``values`` (float64) rounded to nearest on ``bits`` significant mantissa bits (ties away from zero), as a
    new array; NaN, ±Inf and zero are kept. Relative error at most ``2**-(bits + 1)`` for normal numbers
    (values that would round up to Inf are truncated instead). With ``finest``, a value whose step at ``bits``
    would be coarser than ``2**finest`` keeps the bits that make it that fine (absolute error at most
    ``2**(finest - 1)``)."""
    a = np.array(values, dtype=np.float64)  # a copy: callers' arrays are not changed
    if bits >= 52:
        return a
    if not 1 <= bits:
        raise ValueError(f"float_bits must be 1..52, got {bits}")
    if a.ndim == 1 and a.shape[0] >= ROUND_KERNEL_ROWS:  # one compiled pass, the same bits (pipeline.rounding)
        from slamobs.pipeline.rounding import round_bits

        round_bits(a, int(bits), 0 if finest is None else int(finest), finest is not None)
        return a
    u = a.view(np.uint64)
    finite = np.isfinite(a)
    bits_in = u[finite]
    if (
        finest is not None
        and bits_in.size
        and int(np.max(bits_in & _EXPONENT) >> np.uint64(52)) - 1023 - finest <= bits
    ):
        finest = None  # every value's step is fine enough at ``bits`` (a local frame): one shift for all
    if finest is None:
        drop = np.uint64(52 - bits)
        half, keep = np.uint64(1) << (drop - np.uint64(1)), ~((np.uint64(1) << drop) - np.uint64(1))
    else:  # per value: the step of a value in [2**e, 2**(e+1)) kept on b bits is 2**(e - b)
        e = ((bits_in & _EXPONENT) >> np.uint64(52)).astype(np.int64) - 1023
        drop = (52 - np.clip(e - finest, bits, 52)).astype(np.uint64)
        one = np.uint64(1)
        half = np.where(drop > 0, one << (np.maximum(drop, one) - one), np.uint64(0))
        keep = ~((one << drop) - one)
    rounded = (bits_in + half) & keep
    overflow = rounded & _EXPONENT == _EXPONENT  # rounded up into Inf
    rounded[overflow] = bits_in[overflow] & (keep[overflow] if np.ndim(keep) else keep)
    u[finite] = rounded
    return a


def round_step(values: np.ndarray, exp: int) -> np.ndarray:
    """``values`` (float64) rounded to the nearest multiple of ``2**exp`` (ties to even), as a new array: an
    absolute error at most ``2**(exp - 1)`` whatever the value's size; NaN and ±Inf are kept, a value already a
    multiple (``|x| >= 2**(52 + exp)``) is left as it is, and -0.0 becomes 0.0. Scaling by a power of two is
    exact, so the result is the multiple itself, and its mantissa's low bits are zero."""
    if np.ndim(values) == 1 and len(values) >= ROUND_KERNEL_ROWS:  # one compiled pass, the same bits
        from slamobs.pipeline.rounding import round_step_into

        a = np.array(values, dtype=np.float64)
        round_step_into(a, int(exp))
        return a
    with np.errstate(over="ignore"):  # a value past 2**(1024 + exp) is put back below
        a = np.multiply(values, 2.0**-exp, dtype=np.float64)  # a new array: callers' arrays are not changed
    np.rint(a, out=a)
    a *= 2.0**exp
    a += 0.0  # -0.0 (a small negative value rounded to zero) reads 0.0
    whole = ~(np.abs(values) < 2.0 ** (52 + exp))  # already a multiple of the step, or NaN / ±Inf
    if whole.any():
        a[whole] = np.asarray(values, dtype=np.float64)[whole]
    return a


def parquet_options(schema: pa.Schema) -> dict:
    """Writer options per column: byte-stream split floats, delta-packed ``*_ns`` times, dictionary ids; zstd at
    :data:`COMPRESSION_LEVEL`; statistics (min, max, null count) for every column but the floats that cannot be
    null (their min and max are not read back; :func:`null_columns` needs the nullable columns' null counts)."""
    encoding, dictionary, statistics = {}, [], []
    for f in schema:
        if pa.types.is_floating(f.type):
            encoding[f.name] = "BYTE_STREAM_SPLIT"
        elif f.name.endswith("_ns"):
            encoding[f.name] = "DELTA_BINARY_PACKED"
        else:
            dictionary.append(f.name)
        if f.nullable or not pa.types.is_floating(f.type):
            statistics.append(f.name)
    return {
        "compression": COMPRESSION,
        "compression_level": COMPRESSION_LEVEL,
        "column_encoding": encoding,
        "use_dictionary": dictionary,
        "write_statistics": statistics,
    }


class TableWriter:
    """Output tables of a run written stretch by stretch into ``out_dir/<name>.parquet``.

    The run metadata is known only when the run ends (e.g. the number of internal steps), so it goes into
    the footer at :meth:`close`, together with the Arrow schema that carries it (as ``pq.write_table``
    would have stored it). A table whose first stretch is empty is still written (schema, no rows).
    The tables of one :meth:`write` are written on two lanes, the caller's thread and a helper thread (rounding
    and pyarrow's encoding and compression run without the GIL; each file has its own writer, so the files are
    the same bytes).
    """

    def __init__(
        self,
        out_dir: Path,
        float_bits: int = FLOAT_BITS,
        keep: tuple[str, ...] = (),
        keep_bytes: int | None = None,
        expected_rows: dict[str, int] | None = None,
    ) -> None:
        self.out_dir = Path(out_dir)
        self.float_bits = float_bits
        self.writers: dict[str, tuple[pq.ParquetWriter, pa.Schema]] = {}
        self._helper = None  # the second lane's thread pool, started by the first write of several tables
        self._nulls: dict[tuple[int, pa.DataType], pa.Array] = {}  # one all-null column per length and type
        #: the tables in ``keep``: each stretch's values as written (rounded), for :meth:`kept`
        self._kept: dict[str, list[tuple[int, dict[str, np.ndarray]]]] = {name: [] for name in keep}
        #: the kept values' bytes at most (None: no limit); past it nothing is kept (the reader reads the files)
        self._keep_limit = keep_bytes
        self._kept_bytes = 0
        #: the rows a kept table will have in all, where known: when the first stretches say the tables would pass
        #: ``keep_bytes``, nothing is kept from then on (what they would hold until the limit stays in the peak)
        self._expected_rows = expected_rows or {}
        self._projected_bytes = 0
        self._keep_lock = threading.Lock()  # the two lanes keep their tables at once

    def write(self, tables: dict[str, dict[str, np.ndarray]]) -> None:
        """Append one stretch of rows to each table."""
        if len(tables) < 2:
            self._write_lane(list(tables.items()))
            return
        if self._helper is None:
            from concurrent.futures import ThreadPoolExecutor

            self._helper = ThreadPoolExecutor(1, thread_name_prefix="slamobs-write")
        mine, other = _two_lanes(tables)
        beside = self._helper.submit(self._write_lane, other)
        try:
            self._write_lane(mine)
        finally:
            error = beside.exception()  # waits: nothing writes into the files after this returns
        if error is not None:
            raise error

    def _write_lane(self, tables: list[tuple[str, dict[str, np.ndarray]]]) -> None:
        for name, columns in tables:
            self._write_table(name, columns)

    def _write_table(self, name: str, columns: dict[str, np.ndarray]) -> None:
        """Append one stretch of rows to one table (opened at its first stretch)."""
        if name not in self.writers:
            schema = arrow_schema(name)
            path = self.out_dir / f"{name}.parquet"
            self.writers[name] = (
                pq.ParquetWriter(path, schema, store_schema=False, **parquet_options(schema)),
                schema,
            )
        writer, schema = self.writers[name]
        rows = len(next(iter(columns.values()))) if columns else 0
        # contiguous first: pyarrow converts a strided column (x of an (N, 3) array) element by element;
        # a nullable column the estimator has no values for (the observers' uncertainty) is all null
        steps = fixed_steps(name)
        values = {
            f.name: self._values(columns[f.name], f, steps.get(f.name))
            for f in schema
            if f.name in columns or not f.nullable
        }
        arrays = [
            _arrow_array(values[f.name], f.type) if f.name in values else self._null_column(rows, f.type)
            for f in schema
        ]
        writer.write_table(pa.Table.from_arrays(arrays, schema=schema))
        self._keep(name, rows, values)

    def _keep(self, name: str, rows: int, values: dict[str, np.ndarray]) -> None:
        """Keep one stretch of ``name`` for :meth:`kept`, unless the kept values would pass ``keep_bytes`` (or
        will, as the expected rows say): then nothing is kept any more, of any table (the caller reads the files
        back)."""
        with self._keep_lock:
            if name not in self._kept:
                return
            if self._keep_limit is not None:
                size = sum(v.nbytes for v in values.values())
                if not self._kept[name] and rows and name in self._expected_rows:
                    self._projected_bytes += size * self._expected_rows[name] // rows
                self._kept_bytes += size
                if max(self._kept_bytes, self._projected_bytes) > self._keep_limit:
                    self._kept.clear()
                    return
            self._kept[name].append((rows, values))

    def kept(self, name: str, *, skip_null: bool = False) -> dict[str, np.ndarray] | None:
        """The table ``name`` (one of ``keep``) as :func:`read_columns` reads it back from its file, from the values
        written (the same numbers: Parquet stores float64 and int64 as they are), without reading the file; None
        when it was not kept, not written or has a column of another type. Handed over once (the writer lets go
        of it)."""
        stretches = self._kept.pop(name, None)
        schema = arrow_schema(name)
        if not stretches or any(str(f.type) not in _PLAIN for f in schema):
            return None
        out = {}
        for f in schema:
            dtype = _PLAIN[str(f.type)]
            if skip_null and all(f.name not in values for _, values in stretches):
                continue  # null in every row
            parts = [values.get(f.name, np.full(rows, np.nan)) for rows, values in stretches]
            out[f.name] = np.concatenate([np.asarray(v).astype(dtype, copy=False) for v in parts])
        return out

    def _null_column(self, rows: int, kind: pa.DataType) -> pa.Array:
        """An all-null column, made once per length and type (the observers' 27 uncertainty columns of every
        stretch share it; Arrow arrays are immutable)."""
        key = (rows, kind)
        if key not in self._nulls:
            self._nulls[key] = pa.nulls(rows, kind)
        return self._nulls[key]

    def _values(self, column: np.ndarray, field: pa.Field, step_exp: int | None) -> np.ndarray:
        meta = field.metadata or {}
        if step_exp is not None and self.float_bits < 52:  # a fixed step, finer by a bit for each bit above 28
            return round_step(column, step_exp + DEFAULT_FLOAT_BITS - self.float_bits)
        bits = min(self.float_bits, int(meta.get(b"float_bits", 52)))  # a schema may keep fewer (uncertainty)
        if pa.types.is_float64(field.type) and bits < 52:
            finest = LENGTH_STEP_EXP if meta.get(b"unit") == b"m" else None
            return round_mantissa(column, bits, finest)  # contiguous, as a copy
        return np.ascontiguousarray(column)

    def close(self, metadata: dict) -> list[Path]:
        """Finish every file with the run ``metadata``; returns the paths."""
        written = []
        for name, (writer, schema) in self.writers.items():
            meta = dict(schema.metadata or {})
            meta[METADATA_KEY] = json.dumps(metadata, sort_keys=True).encode()
            final = schema.with_metadata(meta)
            writer.add_key_value_metadata(
                {
                    **{k.decode(): v.decode() for k, v in meta.items()},
                    "ARROW:schema": base64.b64encode(final.serialize().to_pybytes()).decode(),
                }
            )
            writer.close()
            written.append(self.out_dir / f"{name}.parquet")
        self.writers = {}
        self._stop_helper()
        return written

    def abort(self) -> None:
        """Close the files without metadata (the caller discards the directory)."""
        self._stop_helper()
        for writer, _ in self.writers.values():
            writer.close()
        self.writers = {}

    def _stop_helper(self) -> None:
        if self._helper is not None:
            self._helper.shutdown(wait=True)
            self._helper = None


def _two_lanes(tables: dict[str, dict[str, np.ndarray]]) -> tuple[list, list]:
    """The tables shared out between two lanes of about equal work (values to write, largest table first)."""

    def work(columns: dict[str, np.ndarray]) -> int:
        return len(columns) * (len(next(iter(columns.values()))) if columns else 0)

    lanes: tuple[list, list] = ([], [])
    load = [0, 0]
    for name, columns in sorted(tables.items(), key=lambda item: -work(item[1])):
        k = 0 if load[0] <= load[1] else 1
        lanes[k].append((name, columns))
        load[k] += work(columns)
    return lanes


#: NumPy dtypes whose contiguous arrays become Arrow arrays over the same memory (:func:`_arrow_array`)
_PLAIN = {"double": np.dtype(np.float64), "int64": np.dtype(np.int64)}


def _arrow_array(values: np.ndarray, kind: pa.DataType) -> pa.Array:
    """``pa.array(values, type=kind)`` without its pandas check: ``pa.array`` imports pandas (~0.8 s) the first
    time it is given a NumPy array, which a run without truth never needs otherwise. A contiguous column of the
    table's own dtype is wrapped as it is (no nulls; NaN stays NaN, as ``pa.array`` keeps it); anything else
    goes through ``pa.array``."""
    dtype = _PLAIN.get(str(kind))
    if dtype is not None and values.dtype == dtype and values.ndim == 1 and values.flags.c_contiguous:
        return pa.Array.from_buffers(kind, values.shape[0], [None, pa.py_buffer(values)])
    return pa.array(values, type=kind)


def write_result(out_dir: Path, res: ObserverResult, metadata: dict, float_bits: int = FLOAT_BITS) -> list[Path]:
    """All five tables of a run (and the observer's extra ones) into ``out_dir``."""
    return write_tables(out_dir, {**result_tables(res), **res.extra_tables}, metadata, float_bits)


def write_tables(
    out_dir: Path, tables: dict[str, dict[str, np.ndarray]], metadata: dict, float_bits: int = FLOAT_BITS
) -> list[Path]:
    """Tables (``result_tables`` and extra ones) into ``out_dir`` as ``<name>.parquet``, in one stretch."""
    sink = TableWriter(out_dir, float_bits)
    sink.write(tables)
    return sink.close(metadata)


def read_frame(path: Path):
    """A table written here as a pandas DataFrame, filled one row group at a time, its float columns one 2-D
    block: selecting ``x, y, z`` then gives a view, not a copy, and no Arrow copy of the file is held."""
    import pandas as pd

    f = pq.ParquetFile(path)
    schema = f.schema_arrow
    n = f.metadata.num_rows
    floats = [x.name for x in schema if pa.types.is_floating(x.type)]
    others = {x.name: np.empty(n, dtype=x.type.to_pandas_dtype()) for x in schema if x.name not in floats}
    block = np.empty((n, len(floats)))
    k = 0
    for g in range(f.num_row_groups):
        group = f.read_row_group(g)
        m = group.num_rows
        for j, name in enumerate(floats):
            block[k : k + m, j] = group.column(name).to_numpy()
        for name, out in others.items():
            out[k : k + m] = group.column(name).to_numpy()
        k += m
        del group
    frame = pd.DataFrame(block, columns=floats, copy=False)
    for pos, name in enumerate(schema.names):
        if name in others:
            frame.insert(pos, name, others.pop(name))
    return frame


def read_columns(
    path: Path, *, skip_null: bool = False, wanted: Callable[[str], bool] | None = None
) -> dict[str, np.ndarray]:
    """A table written here as its columns (NumPy arrays, in file order), without pandas: pyarrow's
    ``to_numpy`` imports pandas (~0.8 s), which a run's own report does not need. Same values as
    :func:`read_frame` (columns here have no nulls; one with nulls would go through ``to_numpy``).
    ``skip_null`` leaves out the columns null in every row (an observer's uncertainty columns: 27 columns of
    NaN, a second on an hour of poses), as the file's statistics say without reading them; ``wanted`` (a
    predicate on column names) leaves out the others unread."""
    f = pq.ParquetFile(path)
    n = f.metadata.num_rows
    absent = null_columns(f) if skip_null else set()
    out = {
        x.name: np.empty(n, dtype=_PLAIN.get(str(x.type), np.dtype(object)))
        for x in f.schema_arrow
        if x.name not in absent and (wanted is None or wanted(x.name))
    }
    k = 0
    for g in range(f.num_row_groups):
        group = f.read_row_group(g, columns=list(out))
        m = group.num_rows
        for name, column in out.items():
            at = k
            for chunk in group.column(name).chunks:
                column[at : at + len(chunk)] = _chunk_values(chunk, column.dtype)
                at += len(chunk)
        k += m
        del group
    return out


def null_columns(f: pq.ParquetFile) -> set[str]:
    """Names of the columns of ``f`` that hold no value in any row (by every row group's null count; a row
    group without statistics counts as holding values)."""
    meta = f.metadata
    if meta.num_row_groups == 0 or meta.num_rows == 0:
        return set()
    nulls = {}
    for g in range(meta.num_row_groups):
        group = meta.row_group(g)
        for c in range(group.num_columns):
            col = group.column(c)
            stats = col.statistics
            full = stats is not None and stats.has_null_count and stats.null_count == group.num_rows
            nulls[col.path_in_schema] = nulls.get(col.path_in_schema, True) and full
    return {name for name, empty in nulls.items() if empty}


def _chunk_values(chunk: pa.Array, dtype: np.dtype) -> np.ndarray:
    if chunk.null_count == 0 and dtype != np.dtype(object):  # the values buffer as it is (offset respected)
        return np.frombuffer(chunk.buffers()[1], dtype=dtype, count=len(chunk), offset=chunk.offset * dtype.itemsize)
    if dtype.kind == "f":  # nulls as NaN, as to_numpy gives them, without its import of pandas (~1 s)
        return _floats_with_nulls(chunk, dtype)
    return chunk.to_numpy(zero_copy_only=False)


def _floats_with_nulls(chunk: pa.Array, dtype: np.dtype) -> np.ndarray:
    """A float chunk with nulls as an array with NaN in their place (validity bitmap read here)."""
    n, at = len(chunk), chunk.offset
    valid_bits, values = chunk.buffers()[:2]
    if values is None or chunk.null_count == n:
        return np.full(n, np.nan, dtype=dtype)
    out = np.frombuffer(values, dtype=dtype, count=n, offset=at * dtype.itemsize).copy()
    if valid_bits is not None:
        bits = np.unpackbits(np.frombuffer(valid_bits, np.uint8), count=at + n, bitorder="little")[at:]
        out[bits == 0] = np.nan
    return out


def read_metadata(path: Path) -> dict:
    """Run metadata stored in a table written by :class:`TableWriter`."""
    meta = pq.read_schema(path).metadata or {}
    return json.loads(meta[METADATA_KEY]) if METADATA_KEY in meta else {}


def write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


#: Inside a run's temporary directory (``.OUT.tmp-XXXX``, next to OUT): the owner marker, the output being
#: written (it becomes OUT), the previous OUT while it is swapped out, and the flag set once the output is complete.
OWNER, NEW, OLD, COMPLETE = "slamobs-owner.json", "run", "old", "complete"


#: ``renameat2`` flags: fail if the target exists / swap the two paths.
RENAME_NOREPLACE, RENAME_EXCHANGE = 1, 2


def _renameat2_call(a: Path, b: Path, flags: int) -> bool:
    """``renameat2(a, b, flags)``; False where the system or the file system lacks it (an OSError otherwise)."""
    if RENAMEAT2 is None:
        return False
    if RENAMEAT2(-100, os.fsencode(a), -100, os.fsencode(b), flags) == 0:  # AT_FDCWD
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):  # e.g. a file system without the flag
        return False
    raise OSError(err, os.strerror(err), str(b))


def exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where that is unavailable.
    Public: the kill tests (tests/test_interrupts.py, tests/test_output_ownership.py) cut it."""
    return _renameat2_call(a, b, RENAME_EXCHANGE)


def place(new: Path, final: Path) -> None:
    """Rename ``new`` to ``final`` only if nothing is there at that moment (``RENAME_NOREPLACE``; elsewhere a
    directory is renamed, which the system refuses onto anything but an empty directory, and a file is linked
    then unlinked). Raises FileExistsError when something is."""
    try:
        if _renameat2_call(new, final, RENAME_NOREPLACE):
            return
    except OSError as err:
        if err.errno == errno.EEXIST:
            raise FileExistsError(errno.EEXIST, "exists", str(final)) from None
        raise
    if os.path.isdir(new) and not os.path.islink(new):
        try:
            os.rename(new, final)
        except OSError as err:
            if err.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
                raise FileExistsError(errno.EEXIST, "exists", str(final)) from None
            raise
        return
    os.link(new, final)  # FileExistsError when something is there
    os.unlink(new)


def publish(
    new: Path, final: Path, expected: tuple[int, int] | None, *, aside: Path, owned=lambda _old: None
) -> Path | None:
    """Put the complete output ``new`` (a file or directory) under ``final``, replacing only what the output
    check saw there: nothing (``expected`` None: the rename fails if something appeared meanwhile) or the entry
    of :func:`pipeline.paths.identity` ``expected`` that ``owned(path)`` still finds without a foreign entry
    (None when slamobs wrote all of it; else ``(name, why)``). The previous output is swapped out in one step
    (``RENAME_EXCHANGE``; elsewhere moved to ``aside`` first) and checked again where it landed: anything else
    goes back under ``final`` and nothing is published. Returns where the previous output now is (the caller
    removes it), or None.

    Raises:
        OutputError: Something appeared at ``final``, replaced what was checked, or was added to it.
    """
    if expected is None:
        try:
            place(new, final)
        except FileExistsError:
            raise OutputError(
                final,
                "appeared while this command was writing its output (another run, or a "
                "user's file): it was left as it is and nothing was published",
            ) from None
        return None
    try:
        if exchange(new, final):
            old, swapped = new, True
        else:
            os.rename(final, aside)
            old, swapped = aside, False
    except FileNotFoundError:  # the checked entry went meanwhile: nothing to replace any more
        return publish(new, final, None, aside=aside)
    problem = None
    if identity(old) != expected:
        problem = "was replaced while this command was writing its output (another run, or a user)"
    elif (found := owned(old)) is not None:
        problem = f"changed while this command was writing its output ({found[0]} is {found[1]})"
    if problem is None:
        if not swapped:
            place(new, final)
        return old
    if swapped:  # the other output goes back; ours is discarded with the temporary
        exchange(new, final)
    else:
        try:
            place(aside, final)
        except OSError:
            err = OutputError(
                final,
                f"{problem}; it could not be put back (something else is there now) and is "
                f"kept as {aside}; nothing was published",
            )
            err.kept = aside  # the caller must not remove it
            raise err from None
    raise OutputError(final, f"{problem}: it was left as it is and nothing was published")


def write_manifest(directory: Path) -> None:
    """The manifest (:data:`pipeline.paths.MANIFEST`) of an output directory: every file below it with its size
    and every subdirectory, so a later ``--force`` replaces it only while it holds nothing else."""
    from slamobs.pipeline.version import __version__

    files, dirs = {}, []
    for root, subdirs, names in os.walk(directory):
        base = os.path.relpath(root, directory)
        for name in subdirs:
            dirs.append(name if base == "." else f"{base}/{name}")
        for name in names:
            rel = name if base == "." else f"{base}/{name}"
            if rel != MANIFEST:
                files[rel] = os.lstat(os.path.join(root, name)).st_size
    write_json(
        Path(directory) / MANIFEST,
        {"writer": WRITER, "version": __version__, "files": dict(sorted(files.items())), "directories": sorted(dirs)},
    )


def update_manifest(directory: Path, written=(), removed=()) -> None:
    """Record files a later command (``report``, ``export``) wrote into, or removed from, an output directory
    with a manifest (their sizes as they are now); a directory without one is left without."""
    doc = read_manifest(directory)
    if doc is None:
        return
    for name in removed:
        doc["files"].pop(name, None)
    for p in written:
        doc["files"][Path(p).name] = os.lstat(p).st_size
    doc["files"] = dict(sorted(doc["files"].items()))
    tmp = Path(directory) / f".{MANIFEST}.tmp"
    write_json(tmp, doc)
    os.replace(tmp, Path(directory) / MANIFEST)


def _renameat2():
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return fn


#: Public: tests skip the exchange's kill tests where it is None.
RENAMEAT2 = _renameat2()


def _publish(container: Path, final: Path, expected: tuple[int, int] | None, force: bool) -> None:
    """Put the complete output ``container/run`` under ``final`` (:func:`publish`) and remove what it replaced:
    an earlier output (``force``, checked to hold nothing slamobs did not write) or an empty directory.

    ``final`` holds the old or the new output at every instant where the system can exchange two directories;
    elsewhere a run killed between the two renames leaves the new output flagged complete in the container and
    the old one beside it, and the next run on this parent finishes the swap (:func:`remove_stale_temporaries`).
    """
    (container / COMPLETE).touch()
    owned = foreign_entry if force else _any_entry
    old = publish(container / NEW, final, expected, aside=container / OLD, owned=owned)
    if old is not None and not force:
        os.rmdir(old)  # it was empty: never more than that


def _any_entry(directory: Path) -> tuple[str, str] | None:
    """The first entry of a directory that was empty when checked (without ``--force`` only an empty one goes)."""
    name = next(iter(sorted(os.listdir(directory))), None)
    return None if name is None else (name, "not written by slamobs")


def _finish(container: Path, owner: dict) -> None:
    """Recover what a killed or failed run left in ``container`` (finish or undo its swap), then remove it; a
    failing rename raises and keeps the container (never delete the only copy of a run, nor what is not ours)."""
    if owner.get("final"):
        _recover(container, container.parent / str(owner["final"]), owner)
    shutil.rmtree(container, ignore_errors=True)


def _recover(container: Path, final: Path, owner: dict) -> None:
    """Leave ``final`` holding the old or the new output and the container only what may be deleted.

    The owner marker records the new output's identity (``new``), what the check saw at ``final``
    (``expected``) and ``force``: what was swapped out is deleted only when it passes the same check now, as
    :func:`publish` would have checked it (a SIGKILL may come between the swap and the check); anything else goes
    back under ``final``. Markers of older versions (without ``new``) finish the swap as they did.
    """
    new, old = container / NEW, container / OLD
    complete = (container / COMPLETE).exists()
    if owner.get("new") is None:
        if not os.path.lexists(final):
            if complete and new.is_dir():
                place(new, final)
            elif os.path.lexists(old):
                place(old, final)
        return
    new_id, expected = tuple(owner["new"]), owner.get("expected")
    owned = foreign_entry if owner.get("force") else _any_entry

    def checked(path: Path) -> bool:  # still the entry the run was allowed to replace, holding nothing else
        return expected is not None and identity(path) == tuple(expected) and owned(path) is None

    if os.path.lexists(new) and identity(new) != new_id:  # exchanged: ``new`` holds what was at ``final``
        if not checked(new):
            exchange(new, final)  # back under its name; ours returns into the container
            if identity(new) != new_id:
                raise OSError(errno.EEXIST, "could not swap back", str(final))
        return
    if os.path.lexists(old):  # moved aside (no renameat2)
        if not checked(old):
            if identity(final) == new_id:
                os.rename(final, new)
            place(old, final)  # something else there now: raises, and the container is kept
        elif complete and not os.path.lexists(final):
            place(new, final)
        return
    if complete and not os.path.lexists(final) and identity(new) == new_id:
        place(new, final)


def remove_stale_temporaries(parent: Path) -> list[str]:
    """Remove the temporary directories that killed runs left in ``parent``, finishing or undoing an interrupted
    ``--force`` swap first; returns their names.

    Only directories named ``.NAME.tmp-*`` that hold an owner marker written by slamobs are touched, and only
    when their owner is no longer running on this host: a live run's directory (batch workers share a parent)
    and anything a user made are left alone.
    """
    removed = []
    try:
        entries = [e for e in os.scandir(parent) if e.name.startswith(".") and ".tmp-" in e.name]
    except OSError:
        return removed
    for entry in entries:
        try:
            if not entry.is_dir(follow_symlinks=False):
                continue
            owner = json.loads((Path(entry.path) / OWNER).read_text())
            if not isinstance(owner, dict) or owner_alive(owner):
                continue
            _finish(Path(entry.path), owner)
        except (OSError, ValueError):
            continue  # no marker (not ours), unreadable, or another run cleaned it meanwhile
        removed.append(entry.name)
    return removed


@contextmanager
def atomic_directory(final: Path, *, force: bool = False, inputs=()):
    """Yield a temporary directory that becomes ``final`` only if the block succeeds.

    ``final`` is checked first (:func:`pipeline.paths.check_output`: never an input, its container or the
    working directory; an existing non-empty ``final`` only with ``force``, and then only an earlier slamobs
    output). The output is written inside a hidden sibling ``.NAME.tmp-XXXX`` marked with its owner; with
    ``force`` the previous output is replaced only once the new one is complete, so a failure or a kill at
    any point leaves the old or the new run under ``final`` (see :func:`_publish`). Temporary directories of
    killed runs in the same parent are removed first. OS errors (disk full, read-only, permission) become an
    :class:`OutputError` naming ``final`` (a :class:`ResourceError` when the machine ran out or refused).
    """
    from slamobs.pipeline import interrupts

    final = Path(final)
    expected = check_output(final, inputs, force=force)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(final.parent)
        with interrupts.critical():  # a signal in between left a directory without its owner: never removed
            container = Path(tempfile.mkdtemp(prefix=temporary_prefix(final), dir=final.parent))
            tmp = container / NEW
            try:
                tmp.mkdir()
                owner = {
                    **owner_marker(),
                    "final": final.name,
                    "new": identity(tmp),
                    "expected": expected,
                    "force": force,
                }
                write_json(container / OWNER, owner)
            except OSError:
                shutil.rmtree(container, ignore_errors=True)
                raise
    except OSError as err:
        raise output_error(final, err, "cannot create the output") from None
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(container, 0o777 & ~umask)  # mkdtemp makes it private; a run directory is ordinary output
        with interrupts.undone_at_end(partial(_finish, container, owner)):  # a signal that ends the process
            yield tmp  # inside numba's compiler does not wait for this frame's clean-up
            write_manifest(tmp)
        interrupts.check()  # a Ctrl-C/SIGTERM that Python dropped (raised in a finalizer) never publishes
        with interrupts.critical():  # a swap and its check (and a swap back) are one step
            _publish(container, final, expected, force)
        interrupts.note_published(final)
    except OSError as err:
        with suppress(OSError):  # a failed restore keeps the container: the next run retries it
            _finish(container, owner)
        raise output_error(final, err) from None
    except BaseException as err:
        if getattr(err, "kept", None) is None:  # else the container holds what could not be put back
            with suppress(OSError):  # interrupted mid-swap: the old or the new run goes back under ``final``
                _finish(container, owner)
        raise
    shutil.rmtree(container, ignore_errors=True)


def kept_unless(is_ours, refusal: str, *, force: bool = True, nbytes: int | None = 4096, links: bool = True):
    """A ``why_kept`` for :func:`atomic_file`: without ``force`` nothing is replaced; with it only a file whose
    first ``nbytes`` satisfy ``is_ours`` (a kind of file slamobs writes), anything else kept with ``refusal`` (also
    the reason without ``force``, where "use --force" would only lead to that refusal). With ``nbytes`` None
    ``is_ours`` is given the path instead (a directory, or a format its first bytes do not tell); with ``links``
    False a symbolic link is never ours. The one test of "may this command replace what is there" (``simulate``,
    ``import``, ``export``, ``view``, ``evaluate --save_plot`` pass their own ``is_ours``)."""

    def why_kept(path: Path) -> str | None:
        if not links and Path(path).is_symlink():
            ours = False
        elif nbytes is None:
            ours = is_ours(Path(path))
        else:
            try:
                with open(path, "rb") as f:
                    head = f.read(nbytes)
            except OSError:
                head = b""
            ours = is_ours(head)
        if not ours:  # refused with or without --force: never suggest the option that would not help
            return refusal
        return None if force else "exists already (use --force to replace it)"

    return why_kept


@contextmanager
def atomic_file(final: Path, *, why_kept=lambda _path: "exists already"):
    """Yield a temporary path (in a hidden directory beside ``final``) that becomes ``final`` only if the block
    succeeds; nothing half written is ever under ``final``.

    What is at ``final`` now is replaced only when ``why_kept(final)`` returns None (slamobs wrote it and the
    command may replace it); its reason otherwise is the one-line refusal, before anything is written. At the
    swap only that same entry is replaced, and something that appeared meanwhile is kept (:func:`publish`). OS
    errors (a full disk) are one line naming ``final`` (:func:`pipeline.errors.output_error`).
    """
    from slamobs.pipeline import interrupts

    final = Path(final)
    check_name(final)
    expected = identity(final)
    if expected is not None and (why := why_kept(final)) is not None:
        raise OutputError(final, why)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        with interrupts.critical():  # a signal in between would leave it behind
            container = Path(tempfile.mkdtemp(prefix=temporary_prefix(final, "."), suffix=".tmp", dir=final.parent))
    except OSError as err:
        raise output_error(final, err, "cannot create the output") from None
    kept = None
    try:
        with interrupts.undone_at_end(partial(shutil.rmtree, container, ignore_errors=True)):
            yield container / final.name
        interrupts.check()  # a pending Ctrl-C/SIGTERM publishes nothing
        with interrupts.critical():
            publish(
                container / final.name,
                final,
                expected,
                aside=container / ".previous",
                owned=lambda p: None if (why := why_kept(p)) is None else (p.name, why),
            )
        interrupts.note_published(final)
    except OSError as err:
        raise output_error(final, err) from None
    except OutputError as err:
        kept = getattr(err, "kept", None)
        raise
    finally:
        if kept is None:  # our new output, or the replaced one (checked to be slamobs's)
            shutil.rmtree(container, ignore_errors=True)
