"""slamobs: geometric nonlinear SLAM observers over recorded robot logs (MCAP, ROS1 and ROS2 bags).

This file is the ``slamobs`` import package; the repository's ``pipeline/``, ``cli/`` and ``schemas/``
folders install as ``slamobs.pipeline``, ``slamobs.cli`` and ``slamobs.schemas``. The Python API is small and
loaded on first use, so ``import slamobs`` (and ``slamobs --help``) stays fast:

- :func:`run_log` runs an observer on a log and writes a run directory (what ``slamobs run`` does);
- :func:`read_log` decodes a log's streams into NumPy columns without running anything;
- :func:`load_run` loads a run directory's tables into pandas, with its ``run.json`` and ``report.json``.
"""

from slamobs.pipeline.version import __version__

__all__ = ["__version__", "load_run", "read_log", "run_log"]


def __getattr__(name: str):
    if name in ("run_log", "read_log", "load_run"):
        from slamobs.pipeline import api

        return getattr(api, name)
    raise AttributeError(f"module 'slamobs' has no attribute {name!r}")
