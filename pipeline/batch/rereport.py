"""``slamobs report OUT/runs/<id>``: a new report of a batch run, and the dataset brought in line with it.

The report is recomputed in the run directory as for any run (:mod:`..evaluation.run_dir`); then the run's rows
in the dataset follow it: its summary row (headline metrics), its ``batch.json`` and its ``poses_aligned`` and
``landmarks_aligned`` rows (the report's alignment). Without this, ``summary.parquet`` and the dataset's aligned
tables kept the batch's numbers and disagreed with the run's own report without saying so.

**Under the batch lock.** The whole report holds ``OUT``'s lock: a report is refused (one line) while a batch
writes to ``OUT``, and a batch is refused while a report writes to it; neither ever sees the other half done.

**Atomic switch.** The new files are written under hidden names; a journal (``_slamobs/report.json``) lists the
renames, the files they make obsolete and the new summary row; then the renames are made (a compacted file
without the run's old rows, before the run's new partition: a reader never sees the run twice), the obsolete
files deleted, the row recorded, the summary rewritten and the journal removed. A report that fails or is
stopped (Ctrl-C, SIGTERM) still brings the dataset in line with whatever report the run directory holds by then.
A marker (``_slamobs/reports/<run_id>``) is written before the report starts and removed at the end. Whatever else
kills a report (SIGKILL, power loss), the next writer of ``OUT`` (a batch, ``slamobs batch compact OUT``, another
report) completes it first: a journal is rolled forward (every file it names was complete before it was
written), a marker left without one brings the dataset in line with whatever report the run directory now holds.
Until then a killed report leaves the dataset's old rows and the run directory's aligned tables, which
:func:`slamobs.load_run` prefers.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from slamobs.pipeline import interrupts
from slamobs.pipeline.batch.dataset import (
    REPORT_TMP as TMP,
    DatasetIndex,
    batch_lock,
    remove_path,
    signals_deferred,
    write_with_run_id,
    write_without,
)
from slamobs.pipeline.batch.ledger import Ledger, encode_row, finished, meta_dir
from slamobs.pipeline.stored_runs import RUN_META, partition_file, read_run_meta, run_dir

#: The dataset tables a report writes (the run directory's ``<table>.parquet`` of a re-report).
REPORT_TABLES = ("poses_aligned", "landmarks_aligned")
JOURNAL = "report.json"
MARKERS = "reports"


def batch_run(path: Path) -> tuple[Path, str] | None:
    """``(OUT, run_id)`` when ``path`` is a batch run directory ``OUT/runs/<id>``, else None (also for a copy of
    one taken out of its dataset: nothing is created above it)."""
    meta = read_run_meta(Path(path))
    out = Path(path).resolve().parent.parent
    if meta is None or not isinstance(meta.get("run_id"), str) or not meta_dir(out).is_dir():
        return None
    return out, meta["run_id"]


@contextmanager
def dataset_report(path: Path) -> Iterator[None]:
    """Around a (re)report of ``path``: for a batch run directory, hold ``OUT``'s lock, finish what a killed
    report left, and bring the run's rows in the dataset in line with the new report afterwards (see module
    doc); any other run directory: nothing.

    Raises:
        InputError: a batch (or another report) is writing to ``OUT``.

    """
    found = batch_run(path)
    if found is None:
        yield
        return
    out, rid = found
    with batch_lock(out, holder="a batch (or another report)"):
        ledger = Ledger(out)
        try:
            finish_reports(out, ledger)
            marker = meta_dir(out) / MARKERS / rid
            marker.parent.mkdir(exist_ok=True)
            marker.touch()
            try:
                yield
            finally:  # also after a failure or a Ctrl-C/SIGTERM: the run directory may hold the new report already
                # a signal now waits for the switch (a fraction of a second): held back, and the CLI's retry of a
                # pending one (interrupts' SIGALRM) does not raise inside a critical block
                with signals_deferred(), interrupts.critical():
                    sync_run(out, rid, ledger)
        finally:
            ledger.close()


def sync_run(out: Path, rid: str, ledger: Ledger) -> bool:
    """Bring the dataset's rows of run ``rid`` in line with the report its run directory holds (under the batch
    lock); returns whether anything changed. The run's marker is removed."""
    from slamobs.pipeline.evaluation.run_dir import read_json
    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.run import MAP_ERROR, headline_metrics, map_error_rmse

    rdir = run_dir(out, rid)
    meta = read_run_meta(rdir)
    row = ledger.rows.get(rid)
    changed = False
    if meta is not None and row is not None and finished(row.get("status")):
        try:
            report = read_json(rdir / "report.json") if (rdir / "report.json").is_file() else None
        except InputError:
            report = None  # damaged: the summary keeps what it has
        try:  # the run's run.json (not its batch.json): a report without trajectory truth rewrites its map_error
            run = read_json(rdir / "run.json") if (rdir / "run.json").is_file() else None
        except InputError:
            run = None
        metrics = headline_metrics(report, run) if report is not None else {MAP_ERROR: map_error_rmse(run)}
        if run is None:
            metrics.pop(MAP_ERROR)  # unreadable: the summary keeps the map error it has
        new_row = {**row, **metrics}
        fresh = [t for t in REPORT_TABLES if (rdir / f"{t}.parquet").is_file()]
        if fresh or encode_row(new_row) != encode_row(row):
            _switch(out, rid, meta, new_row, fresh, ledger)
            changed = True
    (meta_dir(out) / MARKERS / rid).unlink(missing_ok=True)
    return changed


def _switch(out: Path, rid: str, meta: dict, row: dict, fresh: list[str], ledger: Ledger) -> None:
    """Write the run's new dataset files under hidden names, then the journal, then apply it."""
    rel = lambda p: str(Path(p).relative_to(out))  # noqa: E731
    index = DatasetIndex.scan(out)
    renames: list[tuple[Path, Path]] = []
    emptied: list[Path] = []  # compacted files that held only this run: deleted before the new rows come in
    obsolete: list[Path] = []  # deleted after the renames
    tables = dict(meta["tables"])
    try:
        for table in fresh:
            for name, ids in sorted(index.compacted.get(table, {}).items()):
                if rid in ids:  # the old rows leave the compacted file (rewritten in place) ...
                    path = out / table / name
                    renames.append((path.with_name(f".{name}{TMP}"), path))  # first: a failed write leaves nothing
                    if not write_without(path, {rid}, renames[-1][0]):
                        emptied.append(renames.pop()[1])  # the run was its only one
            final = partition_file(out, table, rid)  # ... and the new ones come in as the run's partition
            tmp = out / table / f".run_id={rid}{TMP}"
            tmp.parent.mkdir(exist_ok=True)
            renames.append((tmp, final))
            tables[table] = write_with_run_id(run_dir(out, rid) / f"{table}.parquet", tmp, rid)
            obsolete.append(run_dir(out, rid) / f"{table}.parquet")  # stored once: in the dataset
        names = dict.fromkeys([*(row.get("tables") or "").split(","), *fresh])
        row = {**row, "tables": ",".join(t for t in names if t)}
        tmp = run_dir(out, rid) / f".{RUN_META}{TMP}"
        tmp.write_text(json.dumps({"run_id": rid, "tables": tables, "row": encode_row(row)}, indent=1) + "\n")
        renames.append((tmp, run_dir(out, rid) / RUN_META))
        doc = {
            "run_id": rid,
            "emptied": [rel(p) for p in emptied],
            "renames": [[rel(a), rel(b)] for a, b in renames],
            "obsolete": [rel(p) for p in obsolete],
            "row": encode_row(row),
        }
        path = meta_dir(out) / JOURNAL
        journal_tmp = path.with_name(f".{JOURNAL}.tmp-{os.getpid()}")
        journal_tmp.write_text(json.dumps(doc))
    except BaseException:
        for tmp, _ in renames:
            tmp.unlink(missing_ok=True)
        raise
    with signals_deferred():  # SIGINT/SIGTERM wait until the switch is made (a SIGKILL: see finish_reports)
        os.replace(journal_tmp, path)  # the commit point
        _apply(out, doc, ledger)


def _apply(out: Path, doc: dict, ledger: Ledger) -> None:
    """Make the switch a journal records (again, after a kill: a rename whose hidden file is gone was made)."""
    from slamobs.pipeline.writers import update_manifest

    for p in doc["emptied"]:  # first: a reader never sees the run twice
        remove_path(out / p)
    for a, b in doc["renames"]:
        if os.path.lexists(out / a):
            (out / b).parent.mkdir(exist_ok=True)
            os.replace(out / a, out / b)
    for p in doc["obsolete"]:
        remove_path(out / p)
    rid = doc["run_id"]
    if doc["row"] != encode_row(ledger.rows.get(rid) or {}):
        ledger.put(doc["row"])
    ledger.compact()
    gone = [Path(p).name for p in doc["obsolete"] if Path(p).parent == Path("runs", rid)]
    if gone and run_dir(out, rid).is_dir():
        update_manifest(run_dir(out, rid), removed=gone)
    (meta_dir(out) / JOURNAL).unlink()


def finish_reports(out: Path, ledger: Ledger) -> list[str]:
    """Complete what killed reports left (under the batch lock): the journal rolled forward, then each marked
    run brought in line with its run directory; returns the run_ids whose rows changed."""
    out = Path(out)
    path = meta_dir(out) / JOURNAL
    done = []
    if path.is_file():
        doc = json.loads(path.read_text())  # written whole (renamed into place)
        _apply(out, doc, ledger)
        done.append(doc["run_id"])
    markers = meta_dir(out) / MARKERS
    for marker in sorted(markers.iterdir()) if markers.is_dir() else ():
        if sync_run(out, marker.name, ledger):
            done.append(marker.name)
    return done
