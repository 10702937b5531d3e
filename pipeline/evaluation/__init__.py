"""Error report of a run against ground truth, and evo-compatible trajectory metrics.

``sync`` (association, interpolation, clock offset) -> ``align`` (SE(3)/Sim(3)/scale/yaw/origin) ->
``metrics`` and ``rpe`` (APE/RPE definitions of evo 1.38.1) are composed by ``trajectory_error``; ``report``
adds what evo does not measure (map, biases, convergence, drift) and writes the run's report files.
"""

from slamobs.pipeline.evaluation.metrics import (
    LandmarkErrors,
    ape_errors,
    ape_rotation_deg,
    ape_translation,
    apply_alignment,
    associate,
    landmark_errors,
    rpe_errors,
    statistics,
    umeyama,
)
from slamobs.pipeline.evaluation.report import (
    ReportOptions,
    build_report,
    evaluate_report,
    evaluate_tables,
    render_markdown,
    write_report,
)

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
