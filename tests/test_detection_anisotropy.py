"""Range and bearing weighed apart in ``batch`` (issue 23; docs/noise.md "Range and bearing weighed apart").

The solver's kernels for a detection information ``S/σ²`` (:func:`pipeline.smoother.solver._shaped_normal`,
``border_row``): with ``S = I`` they solve exactly as the isotropic ones; with a ratio of 4 their gradient is the
objective's (central differences) and, where the detections' residuals are zero, their pose-landmark and
landmark blocks are its Hessian's. On a generated log with white isotropic detections the evidence keeps them
isotropic (the solution is the one without the model); with a white range error 6x the across one it takes a
ratio above 1 and the trajectory gets closer to the truth than with isotropic detections. With a slow (time
correlated) range error the ratio's evidence is computed on detections a correlation time apart: it takes a larger
ratio than on every detection and a lower APE; white detections are not thinned. Once a ratio is applied the
motion levels are scanned again: scanned against isotropic detections they soak up the range error. Once a ratio
has beaten isotropy by the evidence's margin, the highest-scoring ratio is kept, not the one nearest 1.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import noisy_logs
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.lie import so3_exp
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.simulate import expected_streams, simulate
from slamobs.pipeline.smoother import anisotropy as an
from slamobs.pipeline.smoother import correlation as dc
from slamobs.pipeline.smoother import evidence as ev
from slamobs.pipeline.smoother import graph as g
from slamobs.pipeline.smoother.estimator import BatchSmoother
from slamobs.pipeline.smoother.settings import BatchSettings

#: the generated log's extra white range error (m) along each detection's line of sight
RANGE_SD = 0.15


@pytest.fixture(scope="module")
def generated():
    sim = simulate("figure8", duration=30.0, seed=3)
    return sim, align(expected_streams(sim), keep_directions=False)


def smoothed(sim, stream, mode: str):
    """The smoother (noise: auto's defaults, no evidence scan of the motion levels, white detections) and its
    keyframes' APE against the truth."""
    settings = BatchSettings(noise_evidence="off", detection_correlation="off", detection_anisotropy=mode)
    return noisy_logs.smoothed(sim, stream, settings)


@pytest.fixture(scope="module")
def solved(generated):
    """The first problem of the generated log and its isotropic solution."""
    _, stream = generated
    settings = BatchSettings(noise_evidence="off", detection_correlation="off", detection_anisotropy="off")
    problem, guess = BatchSmoother(stream, {}, ObserverOptions(), settings=settings).first_problem()
    return problem, g.solve(problem, guess, relative_tolerance=1e-12)


def _moved(pt, i: int, k: int, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The rotations and positions of ``pt`` with keyframe ``i`` moved by ``h`` along its body axis ``k`` (0-2:
    rotation, 3-5: translation)."""
    step = np.zeros(3)
    step[k % 3] = h
    rot, pos = pt[0].copy(), pt[1].copy()
    if k < 3:
        rot[i] = rot[i] @ so3_exp(step)
    else:
        pos[i] = pos[i] + rot[i] @ step
    return rot, pos


def _point(sol) -> tuple:
    return tuple(np.ascontiguousarray(a, float) for a in (sol.rot, sol.pos, sol.landmarks, sol.bias))


def test_the_identity_shape_solves_as_the_isotropic_detections(solved):
    problem, sol = solved
    shaped = replace(problem, det_shape=np.tile(np.eye(3), (problem.det_y.shape[0], 1, 1)))
    start = g.Guess(sol.rot, sol.pos, sol.landmarks + 0.05, sol.bias)
    a, b = g.solve(problem, start), g.solve(shaped, start)
    assert a.summary["iterations"] > 0
    assert np.allclose(a.pos, b.pos, atol=1e-9) and np.allclose(a.landmarks, b.landmarks, atol=1e-9)
    assert a.summary["final_error"] == pytest.approx(b.summary["final_error"], rel=1e-12)


def test_the_shaped_gradient_is_the_objectives(solved):
    """``Jᵀr`` of the shaped normal equations against central differences of the objective, at a point away from
    the minimum (landmarks moved by up to 5 cm): the landmarks' and one keyframe's (rotation and position in its
    body frame, the retraction's)."""
    problem, sol = solved
    shaped = replace(problem, det_shape=an.shape(problem.det_y, 4.0))
    rng = np.random.default_rng(0)
    moved = g.Guess(sol.rot, sol.pos, sol.landmarks + rng.uniform(-0.05, 0.05, sol.landmarks.shape), sol.bias)
    ne = g.Normal(shaped, moved)
    pt = _point(moved)
    ne.linearize(pt)
    h = 1e-6
    for lm in range(min(3, pt[2].shape[0])):
        for k in range(3):
            up, down = pt[2].copy(), pt[2].copy()
            up[lm, k] += h
            down[lm, k] -= h
            fd = (ne.error((pt[0], pt[1], up, pt[3])) - ne.error((pt[0], pt[1], down, pt[3]))) / (2 * h)
            assert ne.gb[3 * lm + k] == pytest.approx(fd, rel=1e-4, abs=1e-3)
    i = int(problem.kf_of_det[len(problem.kf_of_det) // 2])
    for k in range(6):
        sides = [ne.error((*_moved(pt, i, k, sign * h), pt[2], pt[3])) for sign in (1.0, -1.0)]
        assert ne.ga[i, k] == pytest.approx((sides[0] - sides[1]) / (2 * h), rel=1e-4, abs=1e-3)


def test_the_shaped_blocks_are_the_hessians_at_zero_residuals(solved):
    """Detections moved onto the solution's predictions (their residuals zero, so Gauss–Newton's matrix is the
    Hessian of their part): a keyframe's border row (pose x landmark) and a landmark's diagonal block against
    central differences of the landmarks' gradient."""
    from slamobs.pipeline.smoother.solver import border_row

    problem, sol = solved
    kf = problem.kf_of_det
    y = np.einsum("mji,mj->mi", sol.rot[kf], sol.landmarks[problem.det_idx] - sol.pos[kf])
    exact = replace(problem, det_y=y, det_shape=an.shape(y, 4.0))
    guess = g.Guess(sol.rot, sol.pos, sol.landmarks, sol.bias)
    pt = _point(guess)

    def landmark_gradient(rot, pos, lms) -> np.ndarray:
        ne = g.Normal(exact, guess)
        ne.linearize((rot, pos, lms, pt[3]))
        return ne.gb[: 3 * lms.shape[0]].copy()

    ne = g.Normal(exact, guess)
    ne.linearize(pt)
    i = int(kf[len(kf) // 2])
    rot, pos, lms, det_start, det_idx, weight, shape, mb, seg_of, bias0 = ne._geo()
    row = np.zeros((6, ne.c.shape[0]))
    border_row(i, rot, pos, lms, det_start[i], det_start[i + 1], det_idx, weight, shape, mb, seg_of, bias0, row)
    seen = np.unique(det_idx[det_start[i] : det_start[i + 1]])
    assert seen.size > 0
    h = 1e-6
    for k in range(6):
        diff = [landmark_gradient(*_moved(pt, i, k, sign * h), pt[2]) for sign in (1.0, -1.0)]
        fd = (diff[0] - diff[1]) / (2 * h)
        cols = np.concatenate([3 * seen + c for c in range(3)])
        assert np.allclose(row[k, cols], fd[cols], rtol=1e-4, atol=1e-2 * np.abs(row[k, cols]).max())
    lm = int(seen[0])
    for k in range(3):
        up, down = pt[2].copy(), pt[2].copy()
        up[lm, k] += h
        down[lm, k] -= h
        fd = (landmark_gradient(pt[0], pt[1], up) - landmark_gradient(pt[0], pt[1], down)) / (2 * h)
        block = ne.c[3 * lm : 3 * lm + 3, 3 * lm + k]
        assert np.allclose(block, fd[3 * lm : 3 * lm + 3], rtol=1e-4, atol=1e-2 * np.abs(block).max())


def test_a_white_log_keeps_isotropic_detections(generated):
    sim, stream = generated
    auto, ape_auto = smoothed(sim, stream, "auto")
    _, ape_off = smoothed(sim, stream, "off")
    record = auto.stats["metadata"]["smoother"]["detection_anisotropy"]
    assert record["applied"] is False and record["ratio"] == 1.0, record
    assert auto.det_shape is None
    assert ape_auto == ape_off


def with_range_error(stream, sd: float, seed: int):
    """``stream`` with a white error of ``sd`` (m) added along each detection's line of sight."""
    rng = np.random.default_rng(seed)
    y = stream.det_y
    err = sd * rng.normal(size=y.shape[0])
    return replace(stream, det_y=y + y / np.linalg.norm(y, axis=1, keepdims=True) * err[:, None])


def test_a_range_error_is_weighed_apart_and_the_trajectory_follows(generated):
    sim, stream = generated
    noisy = with_range_error(stream, RANGE_SD, seed=4)
    auto, ape_auto = smoothed(sim, noisy, "auto")
    _, ape_off = smoothed(sim, noisy, "off")
    record = auto.stats["metadata"]["smoother"]["detection_anisotropy"]
    assert record["applied"] is True and record["ratio"] >= 4.0, record
    assert ape_auto < ape_off, (ape_auto, ape_off)


def test_a_long_log_skips_the_ratio_and_says_so(generated, monkeypatch):
    """Above the evidence's keyframe limit each ratio would cost a solve of a long log: skipped, with a note; off
    skips it silently."""
    from slamobs.pipeline.smoother import estimator

    sim, stream = generated
    noisy = with_range_error(stream, RANGE_SD, seed=4)
    monkeypatch.setattr(estimator, "EVIDENCE_MAX_KEYFRAMES", 100)
    long, _ = smoothed(sim, noisy, "auto")
    assert "keyframes" in long.stats["metadata"]["smoother"]["detection_anisotropy"]["skipped"]
    assert any("not weighed apart" in n for n in long.stats["notes"]), long.stats["notes"]
    assert long.det_shape is None
    off, _ = smoothed(sim, noisy, "off")
    assert "is off" in off.stats["metadata"]["smoother"]["detection_anisotropy"]["skipped"]
    assert not any("not weighed apart" in n for n in off.stats["notes"]), off.stats["notes"]


def test_once_isotropy_is_left_the_ratio_with_the_highest_evidence_is_kept():
    # MR.CLAM 7-r4's thinned scan: 16 beats 8 by less than the margin, both beat 1 by far more
    scores = {1.0: 92.119, 2.0: 110.371, 4.0: 123.827, 8.0: 133.058, 16.0: 135.461}
    assert ev.best_scale(scores) == 8.0  # the motion levels' tie rule: nearest 1 among the near-ties
    assert an.winner(scores, ev.best_scale(scores)) == 16.0
    near = {1.0: 10.0, 2.0: 12.0, 4.0: 14.0}  # none beats isotropy by the margin: isotropic, not the highest
    assert an.winner(near, ev.best_scale(near)) == 1.0
    assert an.winner({1.0: 0.0, 2.0: 50.0, 4.0: None}, 2.0) == 2.0


def test_thinning_keeps_detections_a_spacing_apart_along_each_track():
    t = np.array([0.0, 0.4, 1.1, 1.3, 2.5, 0.2, 0.3, 5.0])
    lm = np.array([0, 0, 0, 0, 0, 1, 1, 1])
    kept = dc.thinned(t, lm, 1.0)
    assert kept.tolist() == [0, 2, 4, 5, 7]
    assert dc.thinned(t, lm, 0.0).tolist() == list(range(t.size))


def test_white_detections_are_not_thinned_for_the_ratio(generated):
    sim, stream = generated
    auto, _ = noisy_logs.smoothed(sim, stream, BatchSettings(noise_evidence="off"))
    assert "thinned" not in auto.stats["metadata"]["smoother"]["detection_anisotropy"]


def test_a_slow_range_error_takes_the_ratio_on_nearly_independent_detections(monkeypatch):
    """A slow range error (0.15 m, 5 s) on a log whose odometry is noisy enough to absorb it: on every detection
    the evidence counts the slow error as many independent ones and stops at a ratio of 4; on detections a
    correlation time apart it takes 8, and the trajectory gets closer to the truth."""
    sim, stream, truth = noisy_logs.noisy_figure8(30.0, 3)
    noisy = noisy_logs.with_slow_range_error(stream, 0.15, 5.0, seed=4)
    settings = BatchSettings(noise_evidence="off")
    thin, ape_thin = noisy_logs.smoothed(sim, noisy, settings, noise=truth)
    monkeypatch.setattr(BatchSmoother, "_independent_detections", lambda *args: None)
    every, ape_every = noisy_logs.smoothed(sim, noisy, settings, noise=truth)
    a, b = (s.stats["metadata"]["smoother"]["detection_anisotropy"] for s in (thin, every))
    assert a["thinned"]["detections"] < a["thinned"]["of"] / 5, a
    assert a["ratio"] > b["ratio"], (a, b)
    assert ape_thin < ape_every, (ape_thin, ape_every)
    assert any("detections" in n and "apart" in n for n in thin.stats["notes"]), thin.stats["notes"]


def test_the_motion_levels_are_scanned_again_once_the_range_is_weighed_apart(monkeypatch):
    """Against isotropic detections with a range error the evidence inflates the motion levels (they absorb it);
    with the ratio applied the second scan lowers them again, and the trajectory is closer to the truth than with
    the first scan's levels. run.json's scale is of the level the run started from, over both scans."""
    sim, stream, truth = noisy_logs.noisy_figure8(30.0, 3)
    noisy = with_range_error(stream, RANGE_SD, seed=4)
    noise = replace(truth, sources={**truth.sources, "velocity": "estimated", "gyro": "estimated"})
    settings = BatchSettings(detection_correlation="off")
    again, ape_again = noisy_logs.smoothed(sim, noisy, settings, noise=noise)
    weigh_range = BatchSmoother._weigh_range

    def not_again(self, *args):
        chosen, record, notes = weigh_range(self, *args)
        return chosen, {**record, "applied": False}, notes

    monkeypatch.setattr(BatchSmoother, "_weigh_range", not_again)
    once, ape_once = noisy_logs.smoothed(sim, noisy, settings, noise=noise)
    scale = {s: s.stats["metadata"]["smoother"]["noise_scale"]["velocity"]["scale"] for s in (again, once)}
    assert scale[again] < scale[once], scale
    used = np.asarray(again.stats["metadata"]["noise"]["velocity"])
    np.testing.assert_allclose(used, truth.velocity * scale[again])
    assert ape_again < ape_once, (ape_again, ape_once)
    assert again.stats["metadata"]["smoother"]["detection_anisotropy"]["motion_scanned_again"] is True
    scans = [n for n in again.stats["notes"] if n.startswith("batch: velocity noise level chosen by the evidence")]
    assert len(scans) > len([n for n in once.stats["notes"] if n.startswith("batch: velocity noise level chosen")])
    assert any("again after range and bearing were weighed apart)" in n for n in scans)  # not a bare repetition


def test_a_ratio_set_in_the_configuration_holds_from_the_first_solve(generated):
    """``noise: detection_ratio`` set by the user overrides batch's own scan (issue 23: a key set overrides that
    key alone): applied from the first solve with the configured meaning (the law the mean over the axes), no
    ratio scanned, run.json and the notes say where it came from; on the range-error log it brings the
    trajectory closer to the truth than isotropic detections. Set to 1 it keeps the detections isotropic even
    where the scan would weigh them apart."""
    from slamobs.pipeline.noise import NoiseConfig, resolve_noise

    sim, stream = generated
    noisy = with_range_error(stream, RANGE_SD, seed=4)
    settings = BatchSettings(noise_evidence="off", detection_correlation="off")
    for ratio in (6.0, 1.0):
        noise = resolve_noise(NoiseConfig(detection_ratio=ratio))
        assert noise.sources["detection_ratio"] == "config"
        smoother, ape = noisy_logs.smoothed(sim, noisy, settings, noise=noise)
        record = smoother.stats["metadata"]["smoother"]["detection_anisotropy"]
        assert record["source"] == "config" and record["ratio"] == ratio and "log_evidence" not in record, record
        assert any("from the configuration" in n for n in smoother.stats["notes"]), smoother.stats["notes"]
        if ratio == 1.0:
            assert record["applied"] is False and smoother.det_shape is None
            continue
        assert record["applied"] is True
        across, along = noise.ratio_split()
        assert along / across == pytest.approx(ratio**2) and 2 * across + along == pytest.approx(3.0)
        info = np.linalg.inv(smoother.det_shape[0])  # the variance shape: trace 3, the range's 36x an across one's
        assert np.trace(info) == pytest.approx(3.0)
        u = noisy.det_y[0] / np.linalg.norm(noisy.det_y[0])
        assert u @ info @ u == pytest.approx(along)
        _, ape_iso = smoothed(sim, noisy, "off")
        assert ape < ape_iso, (ape, ape_iso)


def test_the_evidence_counts_the_shapes_log_determinant(solved):
    """``Σ log det Σ`` of the detections with a shape ``S`` is that of ``σ² S⁻¹``: the scan's own shape keeps the
    volume (``det S = 1``, no change), a ratio set in the configuration (the trace kept) does not, and the
    evidence must count it wherever shapes of different volume are compared."""
    from slamobs.pipeline.noise import NoiseConfig, resolve_noise
    from slamobs.pipeline.smoother import evidence as ev

    problem, _ = solved
    m = problem.det_y.shape[0]
    iso = ev.detection_log_det(problem)
    kept = replace(problem, det_shape=an.shape(problem.det_y, 4.0))
    assert ev.detection_log_det(kept) == pytest.approx(iso, abs=1e-6 * m)
    across, along = resolve_noise(NoiseConfig(detection_ratio=6.0)).ratio_split()
    trace = replace(problem, det_shape=an.shape(problem.det_y, 6.0, (across, along)))
    assert ev.detection_log_det(trace) == pytest.approx(iso + m * np.log(across * across * along), rel=1e-9)
