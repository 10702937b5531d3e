"""Error report of a run against ground truth: evo-compatible APE after rigid alignment, map and bias errors."""

from pipeline.evaluation.metrics import (
    LandmarkErrors,
    ape_rotation_deg,
    ape_translation,
    apply_alignment,
    associate,
    landmark_errors,
    statistics,
    umeyama,
)
from pipeline.evaluation.report import build_report, render_markdown, write_report

__all__ = [
    "LandmarkErrors",
    "ape_rotation_deg",
    "ape_translation",
    "apply_alignment",
    "associate",
    "build_report",
    "landmark_errors",
    "render_markdown",
    "statistics",
    "umeyama",
    "write_report",
]
