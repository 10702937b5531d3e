"""Compaction: many small per-run partitions -> a few large files per table, same columns, same readers.

A batch of 10k short logs leaves 10k partitions per table; every reader then opens 10k files (duckdb took
7 s to group them). Compaction streams them, in run_id order, into ``<table>/compacted-<gen>-<n>.parquet``
files of up to ``FILE_ROWS`` rows with row groups of ``GROUP_ROWS`` rows, each file listing its run_ids in
its footer. Compacted files that are still small are merged again, so repeated small batches do not pile
up files either. Runs whose tables differ in columns (another slamobs version) go to separate files.

The switch is crash-safe: the new files are written under hidden names, a journal
(``_slamobs/compaction.json``) lists the renames and the files they replace, the renames are made, the
replaced files deleted, the journal removed (:mod:`dataset` keeps the journal: :func:`finish_compaction`, run
by every batch at start, completes a journal whose renames all happened, or rolls it back otherwise). Readers
may see a run twice only during the few milliseconds between the renames and the deletions.
"""

from __future__ import annotations

import json
import re
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from slamobs.pipeline.batch.dataset import (
    ALL_TABLES,
    JOURNAL,
    DatasetIndex,
    apply_journal,
    finish_compaction,
    signals_deferred,
    write_journal,
)
from slamobs.pipeline.stored_runs import COMPACTED, PART, RUN_IDS_KEY, compacted_run_ids, partition_file
from slamobs.pipeline.batch.ledger import meta_dir
from slamobs.pipeline.errors import output_error
from slamobs.pipeline.interrupts import critical
from slamobs.pipeline.writers import parquet_options

FILE_ROWS = 8 << 20
GROUP_ROWS = 1 << 20


@dataclass
class TableCompaction:
    table: str
    files_before: int
    files_after: int
    runs: int
    rows: int


def _gen(names) -> int:
    gens = [int(m.group(1)) for n in names if (m := re.match(rf"{COMPACTED}(\d+)-", n))]
    return max(gens, default=0) + 1


class Writer:
    """Consecutive units (one run's partition or a small compacted file) into files of <= file_rows rows.
    Public: tests/test_batch_hostile.py fills the disk under its file opening."""

    def __init__(self, base: Path, gen: int, file_rows: int, group_rows: int) -> None:
        self.base, self.gen, self.file_rows, self.group_rows = base, gen, file_rows, group_rows
        self.done: list[tuple[Path, Path]] = []  # (hidden temporary, final name)
        self.writer: pq.ParquetWriter | None = None
        self.schema: pa.Schema | None = None
        self.buf: list[pa.Table] = []
        self.buf_rows = self.file_rows_now = 0
        self.run_ids: list[str] = []

    def _open(self, schema: pa.Schema) -> None:
        final = self.base / f"{COMPACTED}{self.gen:06d}-{len(self.done):04d}.parquet"
        tmp = self.base / f".{final.name}.tmp"
        self.done.append((tmp, final))  # first: a writer that fails to open may have created the file
        self.writer = pq.ParquetWriter(tmp, schema, **parquet_options(schema))
        self.schema = schema

    def _flush_group(self) -> None:
        if self.buf:
            group = pa.concat_tables(self.buf).unify_dictionaries().combine_chunks()
            self.writer.write_table(group, row_group_size=max(1, group.num_rows))
            self.buf, self.buf_rows = [], 0

    def abandon(self) -> None:
        """After a failure (a full disk fails the close too): close quietly and delete every file written."""
        if self.writer is not None:
            with suppress(Exception):
                self.writer.close()
            self.writer = None
        for tmp, _ in self.done:
            tmp.unlink(missing_ok=True)

    def close_file(self) -> None:
        if self.writer is not None:
            self._flush_group()
            self.writer.add_key_value_metadata({RUN_IDS_KEY: json.dumps(sorted(set(self.run_ids)))})
            self.writer.close()
            self.writer, self.schema, self.run_ids, self.file_rows_now = None, None, [], 0

    def add(self, path: Path, run_ids: list[str]) -> int:
        f = pq.ParquetFile(path)
        schema = f.schema_arrow.remove_metadata()
        rows = f.metadata.num_rows
        if self.writer is not None and (
            not schema.equals(self.schema, check_metadata=True) or self.file_rows_now + rows > self.file_rows
        ):
            self.close_file()
        if self.writer is None:
            self._open(schema)
        for g in range(f.num_row_groups):
            self.buf.append(f.read_row_group(g).replace_schema_metadata(None))
            self.buf_rows += self.buf[-1].num_rows
            if self.buf_rows >= self.group_rows:
                self._flush_group()
        f.close()
        self.file_rows_now += rows
        self.run_ids += run_ids
        return rows


def compact_dataset(
    out: Path, index: DatasetIndex | None = None, *, file_rows: int = FILE_ROWS, group_rows: int = GROUP_ROWS
) -> list[TableCompaction]:
    """Merge the fresh partitions (and small compacted files) of every table; returns what changed.

    The caller holds the batch lock. ``index`` (updated in place) saves a scan when the caller has one.
    """
    out = Path(out)
    index = index or DatasetIndex.scan(out)
    renames: list[tuple[Path, Path]] = []
    replaced: list[Path] = []
    try:
        report = _write_tables(out, index, renames, replaced, file_rows, group_rows)
        if renames:
            try:
                write_journal(out, renames, replaced)
            except OSError as err:
                raise _cannot_write(meta_dir(out) / JOURNAL, err) from None
    except BaseException:
        for tmp, _ in renames:  # nothing is renamed before the journal is written: the dataset is unchanged
            tmp.unlink(missing_ok=True)
        raise
    if renames:
        # a signal must not cut the switch in two (kill_matrix seed 47: SIGHUP after the renames, the replaced
        # per-run files left: a stopped batch left every row of a run twice); it is raised after
        with signals_deferred(), critical():
            apply_journal(out)
        index.__dict__.update(DatasetIndex.scan(out).__dict__)
    return report


def _write_tables(
    out: Path,
    index: DatasetIndex,
    renames: list[tuple[Path, Path]],
    replaced: list[Path],
    file_rows: int,
    group_rows: int,
) -> list[TableCompaction]:
    """Write the compacted files of every table under hidden names (``renames``: temporary -> final)."""
    report = []
    for table in ALL_TABLES:
        fresh = sorted(index.fresh.get(table, ()))
        files = index.compacted.get(table, {})
        small = sorted(n for n in files if pq.read_metadata(out / table / n).num_rows < file_rows // 2)
        if not fresh and len(small) < 2:
            continue
        units = [(partition_file(out, table, rid), [rid]) for rid in fresh]
        units += [(out / table / n, sorted(files[n])) for n in small]
        units.sort(key=lambda u: u[1][0] if u[1] else "")
        writer = Writer(out / table, _gen(files), file_rows, group_rows)
        rows = 0
        try:
            for path, ids in units:
                rows += writer.add(path, ids)
            writer.close_file()
        except OSError as err:  # named here: pyarrow's messages (disk full) do not say which file
            writer.abandon()
            raise _cannot_write(writer.done[-1][1] if writer.done else out / table, err) from None
        except BaseException:
            writer.abandon()
            raise
        renames += writer.done
        replaced += [path.parent if path.name == PART else path for path, _ in units]
        report.append(
            TableCompaction(
                table,
                len(fresh) + len(files),
                len(files) - len(small) + len(writer.done),
                sum(len(ids) for _, ids in units),
                rows,
            )
        )
    return report


def _cannot_write(path: Path, err: OSError) -> Exception:
    return output_error(
        path,
        err,
        "cannot write it",
        "; the dataset is unchanged (its runs stay in their per-run files; compact later: slamobs batch compact OUT)",
    )


__all__ = [
    "FILE_ROWS",
    "GROUP_ROWS",
    "JOURNAL",
    "TableCompaction",
    "compact_dataset",
    "compacted_run_ids",
    "finish_compaction",
]
