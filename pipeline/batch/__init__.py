"""Batch runs over datasets: many logs through the run pipeline, in parallel, into one consistent dataset.

``discover`` finds the logs, ``identity`` says what each is (content hash, run_id), ``runner`` plans and
commits, ``local`` and ``dask_exec`` run the logs (``executor`` is the worker side), ``dataset`` owns the
layout and its consistency, ``ledger`` the run records and ``summary.parquet``, ``compact`` merges the
per-run partitions.
"""

import importlib

# eager (and light): the function ``discover`` shadows its submodule of the same name
from slamobs.pipeline.batch.discover import LogEntry, discover, read_manifest  # noqa: F401 - in __all__

#: Public names and the submodule that holds each (imported on first use: a worker process importing one
#: submodule does not pay for all of them).
_WHERE = {
    "compact_dataset": "compact",
    "InfrastructureError": "executor",
    "content_hash": "identity",
    "run_id_for": "identity",
    "run_key": "identity",
    "finished": "ledger",
    "read_summary": "ledger",
    "BatchOptions": "runner",
    "BatchResult": "runner",
    "DaskMissing": "runner",
    "Progress": "runner",
    "check_config": "runner",
    "compact_batch": "runner",
    "run_batch": "runner",
}
__all__ = sorted([*_WHERE, "LogEntry", "discover", "read_manifest"])


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
