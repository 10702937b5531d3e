"""The ``batch`` section of ``run.yaml``: how the smoother is seeded and what it assumes."""

from __future__ import annotations

from dataclasses import dataclass

from slamobs.pipeline.errors import GainError

DEAD_RECKONING = "dead-reckoning"
BIAS_MODELS = ("constant", "random-walk")
#: when the motion levels' scales are chosen by the smoother's evidence (pipeline.smoother.evidence): never, only
#: for a stream that holds its values (its level comes from the detections and is uncertain), or always
EVIDENCE_MODES = ("off", "held", "always")
#: how the noise scales are chosen: by the evidence (``noise_evidence`` says when), or by blocked
#: cross-validation of the detections (pipeline.smoother.cross_validation; replaces the evidence)
SELECTION_MODES = ("evidence", "cross_validation")
CORRELATION_MODES = ("off", "auto")
ANISOTROPY_MODES = ("off", "auto")
INVERSE_DEPTH_MODES = ("off", "auto")
HELD_VELOCITY_MODES = ("off", "auto")
DETECTION_LEVEL_MODES = ("off", "auto")


@dataclass(frozen=True)
class BatchSettings:
    #: observer whose trajectory, map and final biases start the smoother, or "dead-reckoning"
    seed: str = "fast-adaptation"
    #: one bias for the whole log, or one per segment of ``segment_s`` seconds joined by a random walk
    bias: str = "constant"
    segment_s: float = 60.0
    #: Huber threshold of the landmark factors (in standard deviations)
    huber: float = 3.0
    #: χ² gate (3 degrees of freedom) on the whitened landmark residual at the solution: detections beyond it
    #: are dropped and the problem solved again from the solution (None: keep every detection)
    gate_chi2: float | None = 21.1
    #: longest time between keyframes (every detection frame is one; fillers keep gaps below this)
    keyframe_dt: float = 0.2
    max_iterations: int = 50
    relative_tolerance: float = 1e-5
    #: when the velocity and gyro levels' scales are chosen by the evidence (one of ``EVIDENCE_MODES``); a
    #: ``noise: velocity`` or ``gyro`` key set in run.yaml is used as given
    noise_evidence: str = "always"
    #: what chooses the noise scales (one of ``SELECTION_MODES``)
    noise_selection: str = "evidence"
    #: "auto": the detections' time correlation fitted to the first solution's residuals, each detection's
    #: variance scaled by its effective-sample factor when significant (pipeline.smoother.correlation); "off"
    detection_correlation: str = "auto"
    #: "auto": the ratio of the detections' range error to their bearing error chosen by the smoother's evidence
    #: (1 = isotropic, then x2 steps while the evidence rises; pipeline.smoother.anisotropy); "off": isotropic
    detection_anisotropy: str = "auto"
    #: "auto": with the law ``b + a·r²`` and detections in one camera's frame (z forward), each detection weighed
    #: in inverse depth (x/z, y/z, 1/z; pipeline.smoother.inverse_depth) instead of range apart from bearing; "off"
    detection_inverse_depth: str = "auto"
    #: "auto": a held (commanded) velocity's level scaled down to its first solution's residuals over short
    #: windows (pipeline.smoother.held_velocity), the evidence then leaving it; "off": the detection pairs' level
    held_velocity: str = "auto"
    #: "auto": where the detections' correlation in time is applied, the detection law scaled to the median of its
    #: solution's whitened detection residuals and solved again (pipeline.smoother.detection_level); "off"
    detection_level: str = "auto"


def batch_settings(section: dict | None) -> BatchSettings:
    """Settings from the config section (validated by the schema); the seed must name an observer."""
    from slamobs.pipeline.observers import OBSERVERS

    settings = BatchSettings(**{k: v for k, v in (section or {}).items() if v is not None})
    if settings.seed != DEAD_RECKONING and settings.seed not in OBSERVERS:
        names = [*OBSERVERS, DEAD_RECKONING]
        raise GainError(f"batch.seed '{settings.seed}' is not an observer (choose from {', '.join(names)})")
    if settings.bias not in BIAS_MODELS:
        raise GainError(f"batch.bias must be one of {', '.join(BIAS_MODELS)}, got {settings.bias!r}")
    for key, modes in (
        ("noise_evidence", EVIDENCE_MODES),
        ("noise_selection", SELECTION_MODES),
        ("detection_correlation", CORRELATION_MODES),
        ("detection_anisotropy", ANISOTROPY_MODES),
        ("detection_inverse_depth", INVERSE_DEPTH_MODES),
        ("held_velocity", HELD_VELOCITY_MODES),
        ("detection_level", DETECTION_LEVEL_MODES),
    ):
        if getattr(settings, key) not in modes:
            raise GainError(f"batch.{key} must be one of {', '.join(modes)}, got {getattr(settings, key)!r}")
    return settings
