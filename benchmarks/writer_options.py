"""The writer's CPU and the tables' size on a finished run's tables, with Parquet options varied (issue 27).

    .venv/bin/python benchmarks/writer_options.py RUN_DIR [--variants current,level=1,stats,lz4] [--repeat 5]

Reads the run's five long tables back (values as written) and writes them again the way a run does: the
observer's four tables in six stretches through ``TableWriter`` (two lanes), then ``poses_aligned`` as the
report writes it. Each variant changes ``writers.parquet_options``: ``level=N`` a zstd level, ``stats`` min/max
statistics for every column, ``lz4`` another codec, ``codec=NAME`` any codec pyarrow has (``snappy``, ``gzip``,
``brotli``; its default level unless a ``level=N`` follows), ``plain`` the float columns PLAIN instead of
byte-stream split, ``page=BYTES`` a data page size (``+`` joins them). Prints the process CPU (fastest and slowest
of ``--repeat``, the first write of all left out), the files' size, the time ``pandas.read_parquet`` takes to read
``poses.parquet`` back (the median of ``--reads``: users read these files) and whether every value reads back
bit-equal. Run it under two trees' ``PYTHONPATH`` to compare them.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

NAMES = ("poses", "biases", "innovations", "landmark_tracks")
STRETCHES = 6


def _variant(base, spec: str):
    def options(schema):
        out = base(schema)
        for part in spec.split("+"):
            key, _, value = part.partition("=")
            if key == "level":
                out["compression_level"] = int(value)
            elif key == "stats":
                out["write_statistics"] = True
            elif key == "lz4":
                out["compression"], out["compression_level"] = "lz4", None
            elif key == "codec":
                out["compression"], out["compression_level"] = value, None
            elif key == "plain":
                out["column_encoding"] = {c: e for c, e in out["column_encoding"].items() if e != "BYTE_STREAM_SPLIT"}
                out["column_encoding"].update({c: "PLAIN" for c in floats(schema)})
            elif key == "page":
                out["data_page_size"] = int(value)
            elif key != "current":
                raise SystemExit(f"unknown variant part {part!r}")
        return out

    return options


def floats(schema) -> list[str]:
    """The float columns of ``schema``."""
    import pyarrow as pa

    return [f.name for f in schema if pa.types.is_floating(f.type)]


def read_seconds(path: Path, reads: int) -> float:
    """The median wall seconds of ``pandas.read_parquet(path)`` over ``reads`` reads (after one not counted)."""
    import pandas as pd

    pd.read_parquet(path)
    times = []
    for _ in range(reads):
        t = time.perf_counter()
        pd.read_parquet(path)
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main() -> None:
    from slamobs.pipeline import writers

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--variants", default="current,level=1,stats,level=1+stats,lz4")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--reads", type=int, default=9, help="pandas reads of poses.parquet per variant")
    args = ap.parse_args()
    tables = {}
    for name in (*NAMES, "poses_aligned"):
        t = pq.read_table(args.run / f"{name}.parquet")
        tables[name] = {c: t.column(c).to_numpy() for c in t.column_names if t.column(c).null_count == 0}
    parts = []
    for k in range(STRETCHES):
        stretch = {}
        for name in NAMES:
            rows = len(next(iter(tables[name].values())))
            a, b = rows * k // STRETCHES, rows * (k + 1) // STRETCHES
            stretch[name] = {c: v[a:b] for c, v in tables[name].items()}
        parts.append(stretch)
    base = writers.parquet_options
    head = f"| variant | CPU s (fastest-slowest of {args.repeat}) | MB | poses MB | poses pandas read s |"
    print(head + " values equal |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    for spec in args.variants.split(","):
        writers.parquet_options = _variant(base, spec)
        cpu, size, equal = [], 0, True
        for r in range(args.repeat + 1):
            out = Path(tempfile.mkdtemp(prefix="slamobs-writer-options-"))
            try:
                c = time.process_time()
                sink = writers.TableWriter(out)
                for stretch in parts:
                    sink.write(stretch)
                sink.close({"benchmark": 1})
                aligned = writers.TableWriter(out)
                aligned.write({"poses_aligned": tables["poses_aligned"]})
                aligned.close({"benchmark": 1})
                if r:
                    cpu.append(time.process_time() - c)
                size = sum(p.stat().st_size for p in out.glob("*.parquet"))
                if r == 1:
                    poses_mb = (out / "poses.parquet").stat().st_size / 1e6
                    read_s = read_seconds(out / "poses.parquet", args.reads)
                    for name, columns in tables.items():
                        back = pq.read_table(out / f"{name}.parquet", columns=list(columns))
                        equal &= all(np.asarray(back.column(c)).tobytes() == v.tobytes() for c, v in columns.items())
            finally:
                shutil.rmtree(out)
        print(
            f"| {spec} | {min(cpu):.3f}-{max(cpu):.3f} | {size / 1e6:.2f} | {poses_mb:.2f} | {read_s:.3f} "
            f"| {'yes' if equal else 'NO'} |",
            flush=True,
        )
    writers.parquet_options = base
    print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
