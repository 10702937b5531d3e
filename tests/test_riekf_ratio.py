"""riekf's range-against-bearing ratio from its own innovations where the turn rate is held (docs/noise.md, "Range
against bearing"; docs/benchmarks.md, "riekf learns the range-against-bearing ratio from its own innovations"): a
MR.CLAM-format folder written here (commanded v/ω held over 0.2 s, flat range-bearing detections), imported and run.
White isotropic detections keep ρ = 1; a range error four times the across one that changes slowly (the triplets
within 1 s cancel it, as MR.CLAM's) gives ρ > 1."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from cli_checks import invoke
from slamobs.pipeline.alignment import align
from slamobs.pipeline.noise import estimate_log_noise, resolve_noise, stream_density
from slamobs.pipeline.observers import OBSERVERS, ObserverOptions
from slamobs.pipeline.readers import read_log

HEADER = "# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n# produced by a test\n# {what}\n"
#: subject -> barcode (robot 1; landmarks 6..17 on a 4 x 3 grid)
LANDMARKS = {6 + i: (-4.5 + 3.0 * (i % 4), -3.0 + 3.0 * (i // 4)) for i in range(12)}
BARCODES = {1: 5, **{s: 20 + s for s in LANDMARKS}}
T0, SECONDS, HOLD_S, DT = 1248444175.103, 240.0, 0.2, 0.01
#: the commands' error (m/s, rad/s, held over HOLD_S), the across-the-line detection σ (m), the range error's
#: correlation time (s: slow against the triplets' 1 s)
SIGMA_V, SIGMA_W, SIGMA_ACROSS, RANGE_TAU = 0.01, 0.06, 0.03, 20.0


def _write(path: Path, what: str, rows: list[str]) -> None:
    path.write_text(HEADER.format(what=what) + "".join(f"{r}\n" for r in rows))


def _folder(folder: Path, ratio: float, slow: bool, seed: int) -> Path:
    """Robot 1 drives a wandering loop among the landmarks for ``SECONDS``; its odometry file holds the commands
    (the true v/ω plus an error, each held ``HOLD_S``); a measurement every 0.2 s of each landmark nearer than 4 m,
    its across-the-line error white ``SIGMA_ACROSS``, its range error ``ratio`` times that (a first-order
    Gauss-Markov per landmark with ``RANGE_TAU`` when ``slow``, else white)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, SECONDS, DT)
    k_hold = (t / HOLD_S).astype(int)
    v_true = 0.25 + 0.05 * np.sin(2 * np.pi * t / 37.0)
    w_true = 0.12 * np.sin(2 * np.pi * t / 23.0) + 0.08
    th = np.cumsum(w_true) * DT
    x, y = np.cumsum(v_true * np.cos(th)) * DT - 1.0, np.cumsum(v_true * np.sin(th)) * DT - 1.5
    held = np.r_[0, np.flatnonzero(np.diff(k_hold)) + 1]  # each command's first sample: v/ω held until the next
    v_cmd = np.round(v_true[held] + rng.normal(0.0, SIGMA_V, held.size), 3)[k_hold]
    w_cmd = np.round(w_true[held] + rng.normal(0.0, SIGMA_W, held.size), 3)[k_hold]
    gt = np.arange(0, t.size, 2)  # Vicon at 50 Hz
    _write(
        folder / "Robot1_Groundtruth.dat",
        "Time [s]    x [m]    y [m]    orientation [rad]",
        [f"{T0 + t[k]:.3f} \t {x[k]:.8f} \t {y[k]:.8f} \t {np.angle(np.exp(1j * th[k])):.4f}" for k in gt],
    )
    od = np.arange(0, t.size, 3)  # the commands sampled at ~33 Hz: each value repeated over its hold
    _write(
        folder / "Robot1_Odometry.dat",
        "Time [s] v w",
        [f"{T0 + t[k]:.3f} \t {v_cmd[k]:.3f} \t {w_cmd[k]:.3f}" for k in od],
    )
    sigma_r, step = ratio * SIGMA_ACROSS, 0.2
    a = np.exp(-step / RANGE_TAU) if slow else 0.0
    slow_err = {s: rng.normal(0.0, sigma_r) for s in LANDMARKS}
    meas = []
    for k in np.arange(int(0.5 / DT), t.size, int(step / DT)):
        for s, (lx, ly) in LANDMARKS.items():
            slow_err[s] = a * slow_err[s] + np.sqrt(1.0 - a * a) * rng.normal(0.0, sigma_r)
            dx, dy = lx - x[k], ly - y[k]
            r = np.hypot(dx, dy)
            if r < 4.0:
                rr = r + slow_err[s]
                bearing = np.arctan2(dy, dx) - th[k] + rng.normal(0.0, SIGMA_ACROSS) / r
                meas.append(f"{T0 + t[k]:.3f} \t {BARCODES[s]:3d} \t {rr:.4f} \t {np.angle(np.exp(1j * bearing)):.4f}")
    _write(folder / "Robot1_Measurement.dat", "Time [s]    Subject #    range [m]    bearing [rad]", meas)
    _write(folder / "Barcodes.dat", "Subject #    Barcode #", [f"{s:3d} \t {b:3d}" for s, b in BARCODES.items()])
    _write(
        folder / "Landmark_Groundtruth.dat",
        "Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]",
        [f"{s:3d} \t {lx:.8f} \t {ly:.8f} \t 0.0001 \t 0.0001" for s, (lx, ly) in LANDMARKS.items()],
    )
    return folder


def _riekf(folder: Path, tmp: Path, triplets: bool = True):
    """riekf on the imported folder with the levels a run resolves; without ``triplets``, as if the triplets had
    found no ratio."""
    out = tmp / "robot1.mcap"
    res = invoke("import", "mrclam", folder, "-o", out, "--robot", "1")
    assert res.exit_code == 0, res.output
    streams = read_log(out)
    stream = align(streams, keep_directions=False)
    lv = streams.linear_velocity
    estimated = estimate_log_noise(stream, stream_density(lv.t_ns, lv.xyz))
    noise = resolve_noise(estimated=estimated if triplets else replace(estimated, ratio=None))
    filt = OBSERVERS["riekf"].start(stream, {}, replace(ObserverOptions(out_every=10), noise=noise))
    filt.advance(filt.n_vel)
    return noise, filt


def test_riekf_keeps_1_on_white_isotropic_detections(tmp_path):
    """White isotropic detections: the ladder's deviance does not beat ρ = 1 by the χ² quantile (the vertical axis,
    exactly 0 on these flat detections, left out). The triplets' verdict is set aside (on a planar log they count the
    error-free vertical axis across the line of sight and find about √2; docs/benchmarks.md, session 37 (h-ratio2)):
    the test is of riekf's rule."""
    (tmp_path / "MRCLAM_Ratio").mkdir()
    noise, filt = _riekf(_folder(tmp_path / "MRCLAM_Ratio", 1.0, False, 4210), tmp_path, triplets=False)
    assert "gyro" in noise.held and noise.sources.get("detection_ratio", "default") == "default", noise.sources
    used = filt.stats["metadata"]["filter"]["noise"]["levels"]["detection_ratio"]
    assert "innovation deviance" in used["method"] and used["value"] == 1.0, used


def test_riekf_finds_a_slow_range_error_the_triplets_miss(tmp_path):
    """A range error four times the across one that changes slowly (20 s): the triplets find no ratio, riekf's
    deviance over the ladder takes one above 1 and says so."""
    (tmp_path / "MRCLAM_Ratio").mkdir()
    noise, filt = _riekf(_folder(tmp_path / "MRCLAM_Ratio", 4.0, True, 4211), tmp_path)
    assert "gyro" in noise.held and noise.sources.get("detection_ratio", "default") == "default", noise.sources
    used = filt.stats["metadata"]["filter"]["noise"]["levels"]["detection_ratio"]
    assert "innovation deviance" in used["method"] and used["value"] > 1.0, used
    assert any(n.startswith("riekf: detection_ratio") for n in filt.stats["notes"]), filt.stats["notes"]


def test_the_notes_before_riekf_chooses_the_ratio_do_not_state_1(tmp_path):
    """Where riekf's passes choose ``detection_ratio`` (the turn rate held), the notes a run prints before them
    (``estimator_input``) gave ``detection_ratio = 1 (default: riekf's innovation deviance ...)`` and the triplets'
    ``... the same σ kept on every axis``, then riekf's own note a ratio of 4 or 8 (MR.CLAM; docs/benchmarks.md,
    session 38 (h-newuser10)): riekf's say the ratio is its passes' choice and state no value; batch's (its own
    evidence weighs range against bearing) name no method of riekf's."""
    from slamobs.pipeline.config import RunConfig
    from slamobs.pipeline.run import estimator_input, prepare_log

    (tmp_path / "MRCLAM_Ratio").mkdir()
    _folder(tmp_path / "MRCLAM_Ratio", 4.0, True, 4361)  # the triplets: across 2.3x along, no ratio
    out = tmp_path / "robot1.mcap"
    res = invoke("import", "mrclam", tmp_path / "MRCLAM_Ratio", "-o", out, "--robot", "1")
    assert res.exit_code == 0, res.output
    for name in ("riekf", "batch"):
        config = replace(RunConfig(), observer=name)
        notes = estimator_input(prepare_log(out, config, directions=False), config).notes
        said = [n for n in notes if "detection_ratio" in n or "line of sight" in n]
        across = [n for n in said if "error across the line of sight" in n]
        assert across and "no ratio taken from it" in across[0] and "the same σ kept" not in across[0], said
        assert not any("detection_ratio = 1 (default: riekf" in n for n in said), said
        ratio = [n for n in said if n.startswith("noise: detection_ratio")]
        if name == "riekf":
            assert ratio and "chosen in riekf's run by its passes" in ratio[0] and "innovation deviance" in ratio[0], (
                said
            )
        else:
            assert ratio == ["noise: detection_ratio = 1 (default)"], said
