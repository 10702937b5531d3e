"""Range and bearing weighed apart: a detection's error along its line of sight and across it.

A range-bearing sensor measures the direction to a landmark better than its distance: a camera's fiducial pose
(PnP) is good across the image and poor in depth, and on MR.CLAM the range error is 0.12–0.28 m while the
bearing's is about 0.01 rad, a few centimetres across at the ranges seen (docs/benchmarks.md "The held streams
against Vicon"). The noise law ``σ(r)`` (``noise: detection``, ``_per_m``, ``_per_m2``) is one standard
deviation per axis; weighed so, the slow range error pulls the trajectory along the heading as hard as the
bearing does across it, and the smoother follows the range's noise.

The model splits ``σ`` into ``σ_r = k_r σ`` along the line of sight ``u = y/|y|`` (body frame) and ``σ_⊥ = k_⊥ σ``
across it, with ``k_r / k_⊥ = ρ`` and ``k_r k_⊥² = 1``: the error's volume (``det Σ = σ⁶``) is the isotropic
one, so the evidence's determinant terms of the detections do not change with ``ρ`` and the law's level keeps
its meaning (the geometric mean of the three axes). Scanned in riekf's shape instead (the law the mean over the
axes, its ``log det`` counted), the ratio reaches the stereo-like logs' true one (32 against 8-16 here), but batch
got worse on 3 of 7 of them, 2-10x (docs/benchmarks.md, "batch's range/bearing ratio in the triplets' shape"). The
information of a detection is ``S/σ²`` with

    S = u uᵀ / k_r² + (I − u uᵀ) / k_⊥²,      k_r = ρ^(2/3),  k_⊥ = ρ^(−1/3).

``ρ`` is chosen by the smoother's evidence (:mod:`pipeline.smoother.evidence`, the same Laplace approximation
and margin as the motion levels' scales): ``ρ = 1`` (isotropic) and ``noise.DETECTION_RATIOS`` upwards while the
evidence rises by more than ``evidence.MIN_GAIN``; once a ratio has beaten isotropy by that margin, the ratio with
the highest evidence is kept (:func:`winner`), not the one nearest 1. The residuals themselves cannot give ``ρ``:
the smoother absorbs the error in the direction it weighs least, so refitting the split from a solution's residuals
and solving again runs away (MR.CLAM 7-r1: 3.0, 6.9, 12.8, 18.5, 23.0, 26.1 over six passes). Pure numerics, no I/O.
"""

from __future__ import annotations

import numpy as np

MODEL = "sigma_range = ratio^(2/3) sigma, sigma_across = ratio^(-1/3) sigma (line of sight y/|y|, det kept)"


def shape(det_y: np.ndarray, ratio: float, split: tuple[float, float] | None = None) -> np.ndarray:
    """Each detection's body-frame information relative to ``1/σ²`` (M, 3, 3) for a range standard deviation
    ``ratio`` times the across-the-line one, determinant 1 (module docstring); or, for a ratio set in the
    configuration, with the variance factors ``split`` (across, along: ``NoiseSettings.ratio_split``, whose
    law is the mean over the axes)."""
    u = det_y / np.maximum(np.linalg.norm(det_y, axis=1), 1e-12)[:, None]
    uu = np.einsum("mi,mj->mij", u, u)
    if split is not None:
        return uu / split[1] + (np.eye(3) - uu) / split[0]
    return uu / ratio ** (4.0 / 3.0) + (np.eye(3) - uu) * ratio ** (2.0 / 3.0)


def winner(scores: dict[float, float | None], nearest_one: float) -> float:
    """The ratio kept of those scanned (``scores``: log evidence by ratio): 1 when the evidence did not leave
    isotropy by its margin (``nearest_one``, :func:`pipeline.smoother.evidence.best_scale`'s choice, is 1), else
    the ratio with the highest evidence. A motion level's x1 is the log's own estimate, so its scans keep the scale
    nearest it among near-ties; a ratio's 1 is only the isotropic default, and once the evidence has left it no
    ratio is nearer the data than another: on MR.CLAM 7-r4 the tie rule kept 8 (log Z 133.1) against 16 (135.5)
    and batch's APE was 0.246 m against 0.189 (docs/benchmarks.md, "MR.CLAM's four robots, session 19")."""
    if nearest_one == 1.0:
        return 1.0
    valid = {r: z for r, z in scores.items() if z is not None and np.isfinite(z)}
    return max(valid, key=valid.__getitem__)


def configured(ratio: float) -> tuple[dict, str]:
    """The record and note of a ratio set in the configuration (``noise: detection_ratio``): no scan."""
    how = f"the range's standard deviation {ratio:g}x the bearing's" if ratio != 1.0 else "isotropic detections"
    record = {"model": "noise: detection_ratio (sigma(r) the mean over the axes)", "ratio": ratio}
    record |= {"applied": ratio != 1.0, "source": "config"}
    return record, f"batch: range and bearing weighed by noise: detection_ratio from the configuration ({how})"


def skipped(mode: str, fixed_bias: bool, keyframes: int, max_keyframes: int) -> str | None:
    """Why the ratio is not chosen here (the detections stay isotropic), or None."""
    if mode == "off":
        return "batch.detection_anisotropy is off"
    if fixed_bias:
        return "the biases are fixed (a reference run)"
    if keyframes > max_keyframes:
        return f"the log has {keyframes} keyframes (more than {max_keyframes}): each ratio would cost a solve"
    return None


def record(scores: dict[float, float | None], winner: float, criterion: str) -> dict:
    """The choice for run.json (observer.smoother.detection_anisotropy)."""
    return {
        "model": MODEL,
        "criterion": criterion,
        "log_evidence": {f"{s:g}": (None if z is None else round(float(z), 3)) for s, z in sorted(scores.items())},
        "ratio": winner,
        "applied": winner != 1.0,
    }


def thinning_note(thinned: dict) -> str:
    """What the note adds when the ratio's evidence was computed on thinned detections."""
    return (
        f" (on {thinned['detections']} of {thinned['of']} detections, {thinned['spacing_s']:g} s apart along each "
        "landmark's track: their errors are correlated in time)"
    )


def note(scores: dict[float, float | None], winner: float) -> str:
    said = ", ".join(f"x{s:g} {'n/a' if z is None else f'{z:.1f}'}" for s, z in sorted(scores.items()))
    kept = (
        f"the range's standard deviation {winner:g}x the bearing's (σ(r) x{winner ** (2 / 3):.3g} along the line "
        f"of sight, x{winner ** (-1 / 3):.3g} across)"
        if winner != 1.0
        else "isotropic detections"
    )
    return f"batch: range and bearing weighed apart by the evidence (log marginal likelihood): {said}; kept {kept}"
