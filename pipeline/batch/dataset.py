"""The batch output directory and how a run enters and leaves it.

Layout of ``OUT/``::

    <table>/run_id=<id>/part-0.parquet     a run's rows of that table (poses, biases, ...), with a run_id column
    <table>/compacted-<gen>-<n>.parquet    many runs' rows, merged by :mod:`compact` (same columns)
    runs/<id>/                             run.json, report.json/.md, plots, batch.json (no tables: one copy)
    summary.parquet                        one row per run (:mod:`ledger`)
    _slamobs/                              lock, run records, hash cache, staging area of running logs

**One commit per run.** A worker writes everything of a run into its own staging directory
(``_slamobs/staging/<batch>/<run_id>/``) and never touches the dataset; the batch process, which holds the
lock, commits it: each table file renamed into its partition, then the run directory renamed into
``runs/`` (last, so its presence means the tables are in), then one record appended to the ledger. A run
that fails, times out or is abandoned leaves only its staging directory, which is deleted.

**Reconciled at start.** Whatever a killed batch left is settled before anything runs (:func:`reconcile`):
staging directories are deleted, a run directory whose tables are all in place but whose record is
missing is adopted (its ``batch.json`` holds the summary row), anything partial is deleted, and a recorded
run whose files are gone is dropped from the record (and runs again).

**The user's files are kept.** A run directory holding an entry slamobs did not write is never deleted: that
run is left as it is (files and record), not run again, and reported (:func:`kept_runs`); the others go on.

``run_id`` is stored inside the files as a dictionary-encoded string: that is the type pyarrow gives a
Hive partition key, so the file column and the directory key merge when ``pd.read_parquet(OUT / "poses")``
reads the dataset, and fresh partitions and compacted files read as one table.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from slamobs.pipeline.batch.ledger import SUMMARY, Ledger, encode_row, finished, meta_dir
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.paths import exclusive, foreign_entry
from slamobs.pipeline.stored_runs import (
    COMPACTED,
    RUN_IDS_KEY,
    RUN_META,
    RUNS,
    compacted_run_ids,
    partition_file,
    read_run_meta,
    run_dir,
)
from slamobs.pipeline.writers import parquet_options
from slamobs.schemas import OPTIONAL_TABLES, TABLES

LOCK = "lock"
STAGING = "staging"
ALL_TABLES = TABLES + OPTIONAL_TABLES
RUN_ID_TYPE = pa.dictionary(pa.int32(), pa.string())


def staging_root(out: Path) -> Path:
    return meta_dir(out) / STAGING


def remove_path(p: Path) -> None:
    """Delete a file, a link or a directory tree, whatever is there (nothing there is fine)."""
    shutil.rmtree(p, ignore_errors=True) if p.is_dir() and not p.is_symlink() else p.unlink(missing_ok=True)


# --- worker side: a finished run directory -> staged dataset files -----------------------------------------


def with_run_id(table: pa.Table, run_id: str) -> pa.Table:
    ids = pa.DictionaryArray.from_arrays(np.zeros(len(table), np.int32), pa.array([run_id], pa.string()))
    return table.append_column(pa.field("run_id", RUN_ID_TYPE, nullable=False), ids)


def stage_tables(staged: Path, run_id: str) -> dict[str, int]:
    """Move the tables of ``staged/run/`` to ``staged/<table>.parquet`` with a run_id column, row group by row
    group (bounded memory); returns rows per table. The run directory keeps run.json and the report."""
    rows = {}
    for table in ALL_TABLES:
        src = staged / "run" / f"{table}.parquet"
        if not src.is_file():
            continue
        rows[table] = write_with_run_id(src, staged / f"{table}.parquet", run_id)
        src.unlink()
    return rows


def write_with_run_id(src: Path, dest: Path, run_id: str) -> int:
    """Copy the table file ``src`` of a run to ``dest`` with a run_id column, row group by row group (bounded
    memory); returns its rows."""
    f = pq.ParquetFile(src)
    schema = with_run_id(f.schema_arrow.empty_table(), run_id).schema
    with pq.ParquetWriter(dest, schema, **parquet_options(schema)) as writer:
        for g in range(f.num_row_groups):
            writer.write_table(with_run_id(f.read_row_group(g), run_id))
    rows = f.metadata.num_rows
    f.close()
    return rows


def write_run_meta(staged: Path, run_id: str, tables: dict[str, int], row: dict) -> None:
    tmp = staged / "run" / f".{RUN_META}.tmp"
    tmp.write_text(json.dumps({"run_id": run_id, "tables": tables, "row": encode_row(row)}, indent=1) + "\n")
    os.replace(tmp, staged / "run" / RUN_META)


# --- batch side: commit, index, removal, reconciliation ---------------------------------------------------


def commit_run(out: Path, staged: Path, run_id: str, tables: Iterable[str]) -> None:
    """Move a staged run into the dataset: table files first, the run directory last (see module doc).
    The caller appends the record; until then :func:`reconcile` would adopt the run from its batch.json.

    Raises:
        InputError: The run directory holds an entry slamobs did not write (:func:`check_owned_runs`); nothing
            has moved.
    """
    check_owned_runs(out, [run_id])  # before anything moves: a file of the user's keeps the run as it was
    for table in tables:
        dest = partition_file(out, table, run_id)
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staged / f"{table}.parquet", dest)
    final = run_dir(out, run_id)
    final.parent.mkdir(parents=True, exist_ok=True)
    if final.exists():
        remove_path(final)
    os.replace(staged / "run", final)


@dataclass
class DatasetIndex:
    """Which run_ids have files where: run directories, fresh partitions, compacted files."""

    out: Path
    runs: set[str] = field(default_factory=set)
    fresh: dict[str, set[str]] = field(default_factory=dict)  # table -> run_ids with a partition
    compacted: dict[str, dict[str, set[str]]] = field(default_factory=dict)  # table -> file name -> run_ids

    @classmethod
    def scan(cls, out: Path) -> DatasetIndex:
        out = Path(out)
        index = cls(out)
        if (out / RUNS).is_dir():
            index.runs = {e.name for e in os.scandir(out / RUNS) if e.is_dir() and not e.name.startswith(".")}
        for table in ALL_TABLES:
            base = out / table
            if not base.is_dir():
                continue
            fresh, files = set(), {}
            for e in os.scandir(base):
                if e.name.startswith("run_id=") and e.is_dir():
                    fresh.add(e.name[len("run_id=") :])
                elif e.name.startswith(COMPACTED) and e.name.endswith(".parquet"):
                    files[e.name] = set(compacted_run_ids(Path(e.path)))
            index.fresh[table], index.compacted[table] = fresh, files
        return index

    def has(self, table: str, run_id: str) -> bool:
        if run_id in self.fresh.get(table, ()):
            return (partition_file(self.out, table, run_id)).is_file()
        return any(run_id in ids for ids in self.compacted.get(table, {}).values())

    def all_ids(self) -> set[str]:
        ids = set(self.runs)
        for table in self.fresh.values():
            ids |= table
        for files in self.compacted.values():
            for found in files.values():
                ids |= found
        return ids


def write_without(path: Path, drop: set[str], dest: Path) -> bool:
    """Write the compacted file ``path`` without the rows of ``drop`` to ``dest``; False (nothing written) when
    no run would be left in it."""
    import pyarrow.compute as pc

    remaining = [r for r in compacted_run_ids(path) if r not in drop]
    if not remaining:
        return False
    table = pq.ParquetFile(path).read()
    keep = pc.invert(pc.is_in(table["run_id"].cast(pa.string()), value_set=pa.array(sorted(drop), pa.string())))
    table = table.filter(keep)
    with pq.ParquetWriter(dest, table.schema, **parquet_options(table.schema)) as writer:
        writer.write_table(table.unify_dictionaries().combine_chunks(), row_group_size=1 << 20)
        writer.add_key_value_metadata({RUN_IDS_KEY: json.dumps(remaining)})
    return True


def _rewrite_without(path: Path, drop: set[str]) -> None:
    """Rewrite a compacted file without the rows of ``drop`` (atomically; deleted when nothing is left)."""
    tmp = path.with_name(f".{path.name}.tmp")
    if write_without(path, drop, tmp):
        os.replace(tmp, path)
    else:
        path.unlink()


#: Suffix of the hidden files a report of a batch run (:mod:`.rereport`) writes before its journal: slamobs's own,
#: so a report killed before its switch leaves nothing that stops the next batch (:func:`check_owned_runs`).
REPORT_TMP = ".report-tmp"


def foreign_in_run(out: Path, run_id: str) -> tuple[Path, str] | None:
    """The first entry of run directory ``run_id`` that slamobs did not write, as ``(path, why)``; None when it
    holds only its manifest's files, ``batch.json`` and a killed report's hidden temporaries
    (:func:`~slamobs.pipeline.paths.foreign_entry`), or is no directory (a link goes, never what it points to)."""
    path = run_dir(out, run_id)
    if not path.is_dir() or path.is_symlink():
        return None
    ours = (RUN_META, *(n for n in os.listdir(path) if n.startswith(".") and n.endswith(REPORT_TMP)))
    found = foreign_entry(path, also=ours)
    return None if found is None else (path / found[0], found[1])


def kept_runs(out: Path, run_ids: Iterable[str]) -> dict[str, str]:
    """The runs of ``run_ids`` that must stay as they are because their directory holds an entry slamobs did not
    write, each with a line naming it and the way out (a batch neither deletes nor re-runs them)."""
    kept = {}
    for rid in sorted(run_ids):
        if (found := foreign_in_run(out, rid)) is not None:
            kept[rid] = (
                f"{found[0]}: {found[1]}; run {rid} kept as it was (not deleted, not run again): "
                f"move it out of {out} and run the batch again"
            )
    return kept


def check_owned_runs(out: Path, run_ids: Iterable[str]) -> None:
    """Every run directory of ``run_ids`` holds only what slamobs wrote (:func:`foreign_in_run`), so deleting it
    (a ``--force``, a changed or pruned log, a partial run) deletes nothing of the user's. The batch leaves such
    runs out before (:func:`kept_runs`); this is the last guard.

    Raises:
        InputError: A run directory holds an entry slamobs did not write (named, with the way out); nothing has
            been deleted.
    """
    for rid in sorted(run_ids):
        if (found := foreign_in_run(out, rid)) is not None:
            raise InputError(
                found[0],
                f"{found[1]}; the batch would delete it with run {rid} (--force, a changed, pruned or partial run): "
                f"move it out of {out}",
            )


def remove_files(index: DatasetIndex, run_ids: set[str]) -> None:
    """Delete every file of ``run_ids``: partitions, rows in compacted files, run directories (each checked to hold
    only what slamobs wrote before anything is deleted: :func:`check_owned_runs`)."""
    if not run_ids:
        return
    out = index.out
    check_owned_runs(out, index.runs & run_ids)
    for table, fresh in index.fresh.items():
        for rid in fresh & run_ids:
            remove_path(partition_file(out, table, rid).parent)
        fresh -= run_ids
    for table, files in index.compacted.items():
        for name, ids in list(files.items()):
            if ids & run_ids:
                _rewrite_without(out / table / name, run_ids)
                ids -= run_ids
                if not ids:
                    del files[name]
    for rid in index.runs & run_ids:
        remove_path(run_dir(out, rid))
    index.runs -= run_ids


def drop_runs(index: DatasetIndex, ledger: Ledger, run_ids: Iterable[str]) -> None:
    """Take runs out of the dataset: files first, then the record (a kill between leaves a record whose files
    are gone, which :func:`reconcile` drops)."""
    run_ids = set(run_ids)
    remove_files(index, run_ids)
    for rid in sorted(run_ids):
        ledger.drop(rid)


def _stale_files(out: Path) -> list[Path]:
    """Temporary files of killed writers (never part of the dataset)."""
    stale = list(staging_root(out).glob("*")) + list(out.glob(f".{SUMMARY}.tmp-*"))
    stale += list(meta_dir(out).glob(".*.tmp-*")) + list((out / RUNS).glob(".*"))
    for table in ALL_TABLES:
        stale += list((out / table).glob(".*")) + list((out / table).glob("run_id=*/.*"))
    return stale


@dataclass
class Reconciled:
    adopted: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)  # partial runs whose files were deleted
    dropped: list[str] = field(default_factory=list)  # recorded runs whose files were gone
    #: runs left as they were, files and record, because their directory holds the user's: run_id -> why
    kept: dict[str, str] = field(default_factory=dict)
    stale_files: int = 0


def reconcile(out: Path, ledger: Ledger) -> tuple[DatasetIndex, Reconciled]:
    """Make disk and record agree (see module doc); returns the index of what is now in the dataset."""
    out = Path(out)
    result = Reconciled()
    finish_compaction(out)
    from slamobs.pipeline.batch.rereport import finish_reports  # imports this module

    finish_reports(out, ledger)
    stale = _stale_files(out)
    for p in stale:
        remove_path(p)
    result.stale_files = len(stale)
    index = DatasetIndex.scan(out)
    ok = {rid for rid, row in ledger.rows.items() if finished(row.get("status"))}
    for rid in sorted(ok):
        tables = [t for t in (ledger.rows[rid].get("tables") or "").split(",") if t]
        if not (rid in index.runs and all(index.has(t, rid) for t in tables)):
            result.dropped.append(rid)
    result.kept = kept_runs(out, result.dropped)
    result.dropped = [rid for rid in result.dropped if rid not in result.kept]
    drop_runs(index, ledger, result.dropped)
    ok -= set(result.dropped)
    for rid in sorted(index.runs - ok):
        meta = read_run_meta(run_dir(out, rid))
        if meta and meta.get("run_id") == rid and all(index.has(t, rid) for t in meta["tables"]) and meta.get("row"):
            ledger.put(meta["row"])
            ok.add(rid)
            result.adopted.append(rid)
    partial = index.all_ids() - ok
    result.kept |= kept_runs(out, partial)
    result.removed = sorted(partial - result.kept.keys())
    remove_files(index, set(result.removed))
    # failed (or unknown) records never keep files; a recorded failure has none by construction
    return index, result


@contextmanager
def signals_deferred():
    """Hold SIGINT/SIGTERM/SIGHUP back (delivered on exit) while the dataset is being changed.

    Blocking them for the main thread is not enough: with another thread running (Dask's client loop, a helper
    thread) the kernel hands the signal to that thread, and Python runs its handler in the main thread all the
    same, inside the block (a SIGINT cut a Dask batch's commit in two). So the Python handlers are replaced by a
    recorder for the block's length, and a signal it recorded is raised again once the old ones are back."""
    sigs = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    held: list[int] = []
    swapped = {}
    if threading.current_thread() is threading.main_thread():
        for sig in sigs:
            if callable(signal.getsignal(sig)):  # not SIG_IGN / SIG_DFL: those need no deferring
                swapped[sig] = signal.signal(sig, lambda signum, _frame: held.append(signum))
    old = signal.pthread_sigmask(signal.SIG_BLOCK, set(sigs))
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
        for sig, handler in swapped.items():
            signal.signal(sig, handler)
        if held:
            signal.raise_signal(held[0])


@contextmanager
def batch_lock(out: Path, holder: str = "another batch (or a report of one of its runs)") -> Iterator[None]:
    """One batch at a time per output directory (reconciliation must not hit a live batch); ``slamobs report``
    on one of its runs takes it too (:mod:`.rereport`). ``holder`` names the other side in the refusal."""
    out = Path(out)
    try:
        meta_dir(out).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(out, f"cannot create the output directory: {err.strerror}") from None
    with exclusive(meta_dir(out) / LOCK, out, holder):
        yield


def check_layout(out: Path) -> None:
    """Refuse an output directory of the older layout (path-based run ids, tables in runs/): mixing would
    duplicate every run; and a directory that is no batch dataset (no ``_slamobs/``) but holds names a batch
    writes and deletes (``runs/``, a table's directory): they are the user's."""
    out = Path(out)
    if meta_dir(out).is_dir():
        return
    if (out / SUMMARY).is_file():
        raise InputError(
            out, "written by an older slamobs batch (run ids from log paths); write this batch to a new directory"
        )
    if held := [f"{name}/" for name in (RUNS, *ALL_TABLES) if os.path.lexists(out / name)]:
        raise InputError(
            out,
            f"not a slamobs batch dataset (no {meta_dir(out).name}/) but holds {', '.join(held)}, which a batch "
            "writes and deletes: write the batch to a new or empty directory",
        )


# --- switching files: the journal of a compaction (see compact) -----------------------------------------

JOURNAL = "compaction.json"


def write_journal(out: Path, renames: list[tuple[Path, Path]], replaced: list[Path]) -> None:
    """Record a switch of files (hidden temporaries -> final names, and the files they replace) before it is made."""
    rel = lambda p: str(Path(p).relative_to(out))  # noqa: E731
    doc = {"renames": [[rel(a), rel(b)] for a, b in renames], "replaced": [rel(p) for p in replaced]}
    path = meta_dir(out) / JOURNAL
    tmp = path.with_name(f".{JOURNAL}.tmp-{os.getpid()}")
    try:
        tmp.write_text(json.dumps(doc))
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def apply_journal(out: Path) -> None:
    """Make the switch the journal records: the renames, then the deletions, then the journal goes."""
    path = meta_dir(out) / JOURNAL
    doc = json.loads(path.read_text())
    for a, b in doc["renames"]:
        os.replace(out / a, out / b)
    for p in doc["replaced"]:
        remove_path(out / p)
    path.unlink()


def finish_compaction(out: Path) -> None:
    """Complete or roll back a compaction a killed batch left half done (see module doc)."""
    out = Path(out)
    path = meta_dir(out) / JOURNAL
    if not path.is_file():
        return
    try:
        doc = json.loads(path.read_text())
    except ValueError:
        doc = None
    if doc is None or any((out / a).exists() for a, _ in doc["renames"]):
        # not every rename happened: the replaced files are intact, the new ones go
        for a, b in (doc or {}).get("renames", []):
            (out / a).unlink(missing_ok=True)
            (out / b).unlink(missing_ok=True)
        path.unlink()
        return
    for p in doc["replaced"]:
        remove_path(out / p)
    path.unlink()
