"""Error report of a run against ground truth, and evo-compatible trajectory metrics.

``sync`` (association, interpolation, clock offset) -> ``align`` (SE(3)/Sim(3)/scale/yaw/origin) ->
``metrics`` and ``rpe`` (APE/RPE definitions of evo 1.38.1) are composed by ``trajectory_error``;
``trajectory_evaluation`` pairs and aligns a run's estimate once, ``sections`` computes each report section on
it (with what evo does not measure: map, biases, convergence, drift), ``markdown`` renders the report,
``figure_jobs`` plans its figures and ``report`` composes them and writes the run's report files.
"""

# Loaded on first use (PEP 562): a module of this package (``plots`` in a figure helper process) is imported
# without the report and pandas.
_FROM = {
    **dict.fromkeys(
        (
            "LandmarkErrors",
            "ape_errors",
            "ape_rotation_deg",
            "ape_translation",
            "apply_alignment",
            "associate",
            "landmark_errors",
            "rpe_errors",
            "statistics",
            "umeyama",
        ),
        "metrics",
    ),
    **dict.fromkeys(("build_report", "evaluate_report", "evaluate_tables", "write_report"), "report"),
    "ReportOptions": "trajectory_evaluation",
    "render_markdown": "markdown",
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
