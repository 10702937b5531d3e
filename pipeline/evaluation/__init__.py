"""Error report of a run against ground truth, and evo-compatible trajectory metrics.

``sync`` (association, interpolation, clock offset) -> ``align`` (SE(3)/Sim(3)/scale/yaw/origin) ->
``metrics`` and ``rpe`` (APE/RPE definitions of evo 1.38.1) are composed by ``trajectory_error``; ``report``
adds what evo does not measure (map, biases, convergence, drift) and writes the run's report files.
"""

# Loaded on first use (PEP 562): a module of this package (``plots`` in a figure helper process) is imported
# without the report and pandas.
_FROM = {
    **dict.fromkeys(("LandmarkErrors", "ape_errors", "ape_rotation_deg", "ape_translation", "apply_alignment",
                     "associate", "landmark_errors", "rpe_errors", "statistics", "umeyama"), "metrics"),
    **dict.fromkeys(("ReportOptions", "build_report", "evaluate_report", "evaluate_tables", "render_markdown",
                     "write_report"), "report"),
}


def __getattr__(name: str):
    if name in _FROM:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{_FROM[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "LandmarkErrors",
    "ReportOptions",
    "ape_errors",
    "ape_rotation_deg",
    "ape_translation",
    "apply_alignment",
    "associate",
    "build_report",
    "evaluate_report",
    "evaluate_tables",
    "landmark_errors",
    "render_markdown",
    "rpe_errors",
    "statistics",
    "umeyama",
    "write_report",
]
