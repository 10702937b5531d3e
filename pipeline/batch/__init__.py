"""Batch runs over datasets: many logs through :func:`pipeline.run.run_log`, in parallel, resumable.

``discover`` turns inputs into logs, ``runner`` plans and records, ``executor`` runs (local processes or
Dask), ``dataset`` owns the output layout (partitioned tables, per-run directories, ``summary.parquet``).
"""

from slamobs.pipeline.batch.discover import LogEntry, content_hash, discover, read_manifest, run_id_for
from slamobs.pipeline.batch.runner import BatchOptions, BatchResult, DaskMissing, Progress, check_config, run_batch

__all__ = [
    "BatchOptions",
    "BatchResult",
    "DaskMissing",
    "LogEntry",
    "Progress",
    "check_config",
    "content_hash",
    "discover",
    "read_manifest",
    "run_batch",
    "run_id_for",
]
