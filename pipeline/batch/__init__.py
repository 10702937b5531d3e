"""Batch runs over datasets: many logs through the run pipeline, in parallel, into one consistent dataset.

``discover`` finds the logs, ``identity`` says what each is (content hash, run_id), ``runner`` plans and
commits, ``local`` and ``dask_exec`` run the logs (``executor`` is the worker side), ``dataset`` owns the
layout and its consistency, ``ledger`` the run records and ``summary.parquet``, ``compact`` merges the
per-run partitions.
"""

from slamobs.pipeline.batch.compact import compact_dataset
from slamobs.pipeline.batch.discover import LogEntry, discover, read_manifest
from slamobs.pipeline.batch.executor import InfrastructureError
from slamobs.pipeline.batch.identity import content_hash, run_id_for, run_key
from slamobs.pipeline.batch.ledger import read_summary
from slamobs.pipeline.batch.runner import (
    BatchOptions,
    BatchResult,
    DaskMissing,
    Progress,
    check_config,
    compact_batch,
    run_batch,
)

__all__ = [
    "BatchOptions",
    "BatchResult",
    "DaskMissing",
    "InfrastructureError",
    "LogEntry",
    "Progress",
    "check_config",
    "compact_batch",
    "compact_dataset",
    "content_hash",
    "discover",
    "read_manifest",
    "read_summary",
    "run_batch",
    "run_id_for",
    "run_key",
]
