"""The reference estimators on logs that break their assumptions (issue 23, part 2; docs/observers.md §11):
riekf recovers from a noise jump and says so, and says so when it cannot; batch is never worse than its seed;
the detection stream's time offset is estimated from the data. Short simulated logs (figure8), altered where
the simulator has no option."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.cores import cores
from slamobs.pipeline.lie import umeyama
from slamobs.pipeline.noise import DEFAULTS, NoiseConfig, resolve_noise
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.observers.fast_adaptation import SPEC as FA
from slamobs.pipeline.observers.riekf import SPEC as RIEKF
from slamobs.pipeline.simulate import NoiseModel, expected_streams, simulate

#: Detection noise of these logs (m, every range): small, so that 50x of it is still informative.
SIGMA = 0.002
DURATION = 40.0


@pytest.fixture(scope="module")
def log():
    sim = simulate("figure8", seed=3, duration=DURATION, noise=NoiseModel(detection_base=SIGMA, detection_per_m=0.0))
    return sim, align(expected_streams(sim))


def noise():
    return resolve_noise(NoiseConfig(detection=SIGMA, detection_per_m=0.0))


def second_half(stream) -> np.ndarray:
    """Detections after the middle of the log."""
    t = np.repeat(stream.det_t_ns, np.diff(stream.det_offsets))
    return t > (stream.det_t_ns[0] + stream.det_t_ns[-1]) // 2


def ids_swapped(stream, late: np.ndarray, a: int, b: int) -> np.ndarray:
    """The detections' landmark indices with landmarks ``a`` and ``b`` swapped where ``late`` (an id reused: the jump
    checks' tests)."""
    idx = stream.det_idx.copy()
    idx[late & (stream.det_idx == a)], idx[late & (stream.det_idx == b)] = b, a
    return idx


def swap_between_candidates(stream, landmarks) -> tuple[np.ndarray, list[int]]:
    """Detections from the first time after the middle at which each of the two ``landmarks``' ids, once their
    detections from then on are swapped, has its change point (its detections before, the first sighting left out
    as the jump search leaves it) between two indices the coarse search tries (``split_candidates``); and those
    change points."""
    from slamobs.pipeline.observers.base import split_candidates

    t = np.repeat(stream.det_t_ns, np.diff(stream.det_offsets))
    ma, mb = (np.sort(t[stream.det_idx == x]) for x in landmarks)
    for start in np.unique(np.concatenate([ma, mb])):
        if start <= (t[0] + t[-1]) // 2:
            continue
        before = int(np.searchsorted(ma, start)), int(np.searchsorted(mb, start))
        sizes = before[0] + mb.shape[0] - before[1] - 1, before[1] + ma.shape[0] - before[0] - 1
        change = [before[0] - 1, before[1] - 1]
        if not any(k in set(split_candidates(n).tolist()) for k, n in zip(change, sizes, strict=True)):
            return t >= start, change
    raise AssertionError("no swap time with both change points between the search's indices")


def ape(sim, result, last_share: float = 1.0) -> float:
    """Position RMSE against the simulator's truth after a rigid alignment, over the last share of the run."""
    idx = np.searchsorted(sim.mocap.t_ns, result.t_ns).clip(0, sim.mocap.t_ns.shape[0] - 1)
    truth = sim.mocap.position[idx]
    rot, trans, _ = umeyama(result.position, truth)
    err = np.linalg.norm(result.position @ rot.T + trans - truth, axis=1)
    return float(np.sqrt(np.mean(err[int((1 - last_share) * err.shape[0]) :] ** 2)))


def test_riekf_recovers_from_a_50x_detection_noise_jump_and_says_so(log):
    """Halfway, the detection noise jumps from 2 mm to 10 cm: without recovery every later detection fails the
    gate (the filter dead-reckons, half the log unused); with it, one recovery raises the detection variances
    and the second half is tracked with the detections again."""
    sim, stream = log
    jump = second_half(stream)
    rng = np.random.default_rng(5)
    y = stream.det_y.copy()
    y[jump] += SIGMA * np.sqrt(50**2 - 1) * rng.standard_normal((int(jump.sum()), 3))
    clean = RIEKF.run(stream, {}, ObserverOptions(noise=noise()))
    res = RIEKF.run(replace(stream, det_y=y), {}, ObserverOptions(noise=noise()))
    assert clean.stats["metadata"]["filter"]["status"] == "converged"
    f = res.stats["metadata"]["filter"]
    assert f["status"] == "recovered" and 1 <= f["recoveries"] <= 3
    t_jump = DURATION / 2
    assert t_jump < f["recovery_log"][0]["t_s"] < t_jump + 3.0
    assert f["gated_detections"] < 0.15 * jump.sum()  # without the recovery: all of them
    assert any("failed the gate: recovered by multiplying the detection variances" in n for n in res.stats["notes"])
    assert not any(n.startswith("error:") for n in res.stats["notes"])
    # 10 cm detections, clean odometry: the second half stays near the clean run's accuracy
    assert ape(sim, res, 0.5) < 3 * ape(sim, clean, 0.5) + 0.01


def test_a_landmark_id_reused_mid_log_for_another_landmark_is_named(log):
    """Halfway, two landmarks' ids are swapped (a tag printed again, a barcode reassigned): riekf gates the later
    detections of both and said nothing of it (MR.CLAM 6 r1 with landmark 6's id given to landmark 16: batch's map
    0.09 -> 2.2 m); the innovations of each landmark on either side of the swap say so, and nothing on the log as
    generated."""
    from slamobs.pipeline.observers.base import jump_note, landmark_jumps

    _, stream = log
    late = second_half(stream)
    a, b = np.argsort(np.bincount(stream.det_idx[late]))[-2:]  # the two landmarks seen most after the middle
    idx = ids_swapped(stream, late, a, b)
    swapped = replace(stream, det_idx=idx)
    for s, expected in ((stream, []), (swapped, sorted(stream.landmark_ids[[a, b]].tolist()))):
        res = RIEKF.run(s, {}, ObserverOptions(noise=noise()))
        jumps = landmark_jumps(res.det_t_ns, res.det_ids, np.linalg.norm(res.innovation, axis=1))
        assert sorted(j["id"] for j in jumps) == expected, jumps
        t_det = np.repeat(s.det_t_ns, np.diff(s.det_offsets))
        for j in jumps:  # the change point: the landmark's first detection after the swap
            first_late = t_det[late & (s.det_idx == np.searchsorted(s.landmark_ids, j["id"]))].min()
            assert abs(j["t_ns"] - first_late) <= 500_000_000, (j, first_late)
        said = jump_note("riekf", jumps, int(s.vel_t_ns[0]))
        assert len(said) == len(expected[:1]) and all("id reused for another landmark" in n for n in said)


def test_a_landmark_id_shared_by_two_tags_seen_in_turn_is_split_by_its_stretches(log):
    """Two landmarks never in one frame and seen in turn (five switches) given one id: riekf keeps the first place
    and gates the other's detections; the one change point the jump search finds (27.6 s) leaves both places on
    each side, so the run made again mixed them under the new id. The far stretches are found instead, each split
    off whole: the run made again has no jump and the same map as the log as generated."""
    from slamobs.pipeline.observers.base import jump_note, landmark_jumps, split_jumps, split_places

    _, stream = log
    frame = np.repeat(np.arange(stream.det_t_ns.shape[0]), np.diff(stream.det_offsets))
    a, b = np.searchsorted(stream.landmark_ids, [52, 57])
    assert not set(frame[stream.det_idx == a]) & set(frame[stream.det_idx == b])  # never in one frame
    idx = stream.det_idx.copy()
    idx[idx == b] = a
    shared = replace(stream, det_idx=idx)
    res = RIEKF.run(shared, {}, ObserverOptions(noise=noise()))
    jumps = landmark_jumps(res.det_t_ns, res.det_ids, np.linalg.norm(res.innovation, axis=1))
    assert [j["id"] for j in jumps] == [52] and len(jumps[0]["far_spans"]) == 3, jumps
    assert jumps[0]["far"][0] == np.count_nonzero(stream.det_idx == b), jumps  # exactly the other tag's detections
    again = RIEKF.run(split_jumps(shared, jumps, np.empty(0, np.int64)), {}, ObserverOptions(noise=noise()))
    assert landmark_jumps(again.det_t_ns, again.det_ids, np.linalg.norm(again.innovation, axis=1)) == []
    clean = RIEKF.run(stream, {}, ObserverOptions(noise=noise()))
    for mine, other in ((52, 52), (jumps[0]["new_id"], 57)):
        here = again.landmark_xyz[np.searchsorted(again.landmark_ids, mine)]
        assert np.linalg.norm(here - clean.landmark_xyz[np.searchsorted(clean.landmark_ids, other)]) < 0.01
    said = jump_note("riekf", jumps, int(stream.vel_t_ns[0]))
    assert len(said) == 1 and "landmark 52 seen at two places in turn (236 detections in 3 stretches" in said[0]
    # made again, the two places are the two tags' (landmarks 52 and 57 of the log), far apart for their σ
    split_places(jumps, again.landmark_ids, again.landmark_xyz, again.landmark_cov)
    assert jumps[0]["one_place"] is False and jumps[0]["apart_m"] > 0.5, jumps
    said = jump_note("riekf", jumps, int(stream.vel_t_ns[0]))
    assert len(said) == 1 and "id reused for another landmark" in said[0] and "one place after all" not in said[0]


def test_a_split_whose_two_landmarks_come_out_at_one_place_says_the_jump_was_no_second_place(log):
    """A landmark's own detections over a stretch split off as if they had jumped (as riekf split TagSLAM test_11's
    landmark 24, whose 75 detections 23.7x its usual distance from the map came out, as landmark 521, 0.06 m from
    it at σ 0.29 m, and the warning said an id reused or a landmark moved, give them an id of their own): made again,
    the two estimates lie within their stated covariances, and the warning says one place, the jump more likely the
    estimate's than an id reused."""
    from slamobs.pipeline.observers.base import jump_note, split_jumps, split_places

    _, stream = log
    t = np.repeat(stream.det_t_ns, np.diff(stream.det_offsets))
    a = int(np.searchsorted(stream.landmark_ids, 52))
    mine = np.sort(t[stream.det_idx == a])
    span = [int(mine[mine.shape[0] // 3]), int(mine[2 * mine.shape[0] // 3])]  # its middle third, one stretch
    jumps = [{"id": 52, "t_ns": span[0], "before": [10, 1.0], "after": [10, 25.0], "far_spans": [span]}]
    jumps[0].update(far=[10, 25.0], near=[10, 1.0])
    again = RIEKF.run(split_jumps(stream, jumps, np.empty(0, np.int64)), {}, ObserverOptions(noise=noise()))
    split_places(jumps, again.landmark_ids, again.landmark_xyz, again.landmark_cov)
    assert jumps[0]["one_place"] is True and jumps[0]["apart_d2"] < 7.82 and jumps[0]["apart_dof"] == 3, jumps
    said = jump_note("riekf", jumps, int(stream.vel_t_ns[0]))
    assert len(said) == 1 and "one place after all" in said[0] and "id reused for another landmark" not in said[0]
    assert f"those landmark {jumps[0]['new_id']}; made again, the two {jumps[0]['apart_m']:.3g} m apart" in said[0]


def test_a_second_tag_seen_once_mid_log_under_the_id_is_a_jump():
    """Generated innovations shaped as a hand-held rig's whose second tag with id 10 is seen once, 16.5 m from the
    first, for 6 s mid-log (seed=3653: 38 near, 86 at 155x, 100 near): no one change point has three quarters of a
    side far, so no jump was found, riekf said it had lost the log while 0.06 m off, batch came out 1.89 m off. The
    far stretch is the jump; with every landmark far over it (the pose off, not the landmark) it is none."""
    from slamobs.pipeline.observers.base import landmark_jumps

    rng = np.random.default_rng(3653)
    n = 224  # landmark 0's detections, every fifth of the log's
    t, ids = np.arange(5 * n) * 10_000_000, np.tile(np.arange(5), n)
    norms = 0.1 * np.exp(0.3 * rng.standard_normal(t.shape[0]))
    mine = np.flatnonzero(ids == 0)
    norms[mine[38:124]] *= 155.0
    jumps = landmark_jumps(t, ids, norms)
    assert [(j["id"], j["far"][0], j["far_spans"]) for j in jumps] == [(0, 86, [[t[mine[38]], t[mine[123]]]])], jumps
    assert landmark_jumps(t, ids, np.where(ids == 0, 0.1, norms)) == []  # calm: nothing
    pose_off = norms.copy()
    pose_off[(t >= t[mine[38]]) & (t <= t[mine[123]])] *= 155.0
    pose_off[mine[38:124]] /= 155.0  # every landmark far over the stretch once, landmark 0 as far as the others
    assert landmark_jumps(t, ids, pose_off) == []


@pytest.mark.parametrize("far_first", [False, True])
def test_a_jump_between_the_coarse_search_s_indices_is_split_exactly(far_first):
    """Generated innovations: landmark 0 among four calm ones, 60x its usual distance from the map from (or, with
    ``far_first``, until) a change point that is none of the indices the coarse search tries (from 276 detections on,
    ``split_candidates`` skips some), at several places on 300 to 2000 detections: the split is that change point,
    not the nearest candidate (one early gives the new landmark a detection of the old place)."""
    from slamobs.pipeline.observers.base import landmark_jumps, split_candidates

    for n in (300, 357, 600, 2000):
        tried = set(split_candidates(n).tolist())
        for k in [k for k in range(n // 5, 4 * n // 5) if k not in tried][::7][:4]:
            rng = np.random.default_rng(k)
            t, ids = np.arange(5 * n) * 10_000_000, np.tile(np.arange(5), n)
            norms = 0.01 * np.exp(0.3 * rng.standard_normal(t.shape[0]))
            mine = np.flatnonzero(ids == 0)
            norms[mine[:k] if far_first else mine[k:]] *= 60.0
            jumps = landmark_jumps(t, ids, norms)
            assert [(j["id"], j["before"][0], j["t_ns"]) for j in jumps] == [(0, k, t[mine[k]])], (n, k, jumps)


def test_a_reused_landmark_id_is_split_and_the_run_made_again(tmp_path):
    """The sample figure 8 with two landmarks' ids swapped from the middle on: the run finds the jumps, runs again
    with each one's later detections as a landmark of its own, and says so; the new landmarks sit where the other
    id's first half put them (before: one id for two places, batch's map on MR.CLAM 6 r1 0.09 -> 2.2 m).

    The swap is at a time where each landmark's change point falls between two of the indices the coarse jump
    search tries (``split_candidates``: at most 256, and landmark 18 has 357 detections): the search refines its
    best candidate over the indices between its neighbours, so the split falls exactly at the swap. Without that,
    it went to whichever neighbour won by rounding: one detection late passed, one early gave the new landmark a
    detection of the old place, which the second run kept it at (8.1 m off, with a riekf kernel compiled
    elsewhere)."""
    import json

    import pyarrow.parquet as pq

    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import prepare_log, run_prepared

    config = parse_config({"observer": "riekf", "evaluation": {"plots": False}})
    prepared = prepare_log(Path(__file__).parents[1] / "sample_logs" / "figure8.mcap", config, directions=False)
    stream = prepared.aligned
    a, b = np.argsort(np.bincount(stream.det_idx[second_half(stream)]))[-2:]  # the two seen most after the middle
    late, change = swap_between_candidates(stream, (a, b))
    idx = ids_swapped(stream, late, a, b)
    prepared.aligned = replace(stream, det_idx=idx)
    summary = run_prepared(prepared, tmp_path / "run", config)
    jumps = json.loads((tmp_path / "run" / "run.json").read_text())["observer"]["landmark_jumps"]
    id_a, id_b = stream.landmark_ids[[a, b]].tolist()
    assert sorted(j["id"] for j in jumps) == sorted([id_a, id_b]), jumps
    assert {j["id"]: j["before"][0] for j in jumps} == {id_a: change[0], id_b: change[1]}, jumps  # at the swap
    new = {j["id"]: j["new_id"] for j in jumps}
    assert set(new.values()).isdisjoint(stream.landmark_ids.tolist() + list(prepared.streams.landmark_truth))
    lm = pq.read_table(tmp_path / "run" / "landmarks.parquet").to_pandas().set_index("id")[["x", "y", "z"]]
    for mine, other in ((id_a, id_b), (id_b, id_a)):  # after the swap, "mine" names the other landmark
        assert np.linalg.norm(lm.loc[new[mine]] - lm.loc[other]) < 0.05, (mine, lm.loc[new[mine]], lm.loc[other])
    said = [n for n in summary.notes if "id reused for another landmark" in n]
    assert len(said) == 1 and "the run was made again" in said[0] and f"landmark {new[id_a]}" in said[0]
    assert f"[detections {stream.topics['detections']}]:" in said[0], said  # the topic (a log may hold several)
    assert "first_pass_s" in summary.timings


def test_batch_takes_the_jumps_its_riekf_start_shows():
    """batch's own innovations can hide a reused id (MR.CLAM 6 r1, id 6 given to landmark 16 from 500 s: batch kept
    its riekf start, weighed the range down, 3.75 m APE and no jump in its own innovations); a start run with a gate
    (riekf) records the jumps in its innovations, which the run splits as it does its own."""
    from slamobs.pipeline.observers import get_observer
    from slamobs.pipeline.smoother.seed import observer_seed

    sim = simulate("figure8", seed=3, duration=DURATION, noise=NoiseModel(detection_base=SIGMA, detection_per_m=0.0))
    stream = align(expected_streams(sim))
    late = second_half(stream)
    a, b = np.argsort(np.bincount(stream.det_idx[late]))[-2:]
    idx = ids_swapped(stream, late, a, b)
    kf_t = stream.seconds(stream.det_t_ns)
    options = ObserverOptions(noise=noise())
    assert observer_seed("riekf", stream, {}, options, kf_t).landmark_jumps == []
    fa = get_observer("fast-adaptation").resolve_gains(None)
    assert observer_seed("fast-adaptation", replace(stream, det_idx=idx), fa, options, kf_t).landmark_jumps == []
    jumps = observer_seed("riekf", replace(stream, det_idx=idx), {}, options, kf_t).landmark_jumps
    assert sorted(j["id"] for j in jumps) == sorted(stream.landmark_ids[[a, b]].tolist()), jumps


def test_batch_judges_a_jump_on_its_own_whitened_residuals(tmp_path):
    """batch's jump check reads each detection's χ² under the noise model its solve weighs it with
    (``ObserverResult.innovation_d2``), not ‖e‖ in metres: on the shipped camera log the tag 27's first detections,
    at 10-11 m on 320x240 JPEGs (σ(r) there several times the run's median), were 25x the run's median distance in
    metres and named a jump (split as landmark 61, "an id reused or a landmark moved"; no id is reused in that
    simulated log); whitened they are no jump. Two ids swapped halfway on a generated log still are, in batch's own
    whitened residuals."""
    import json

    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.estimators import get_estimator
    from slamobs.pipeline.observers.base import InnovationRecord, landmark_jumps
    from slamobs.pipeline.run import run_log

    sample = Path(__file__).parents[1] / "sample_logs" / "figure8_camera.mcap"
    config = parse_config({"observer": "batch", "tags": {"size": 0.8}, "evaluation": {"plots": False}})
    summary = run_log(sample, tmp_path / "run", config)
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["observer"]["landmark_jumps"] == [], run["observer"]["landmark_jumps"]
    assert not [n for n in summary.notes if "batch: landmark" in n]

    sim = simulate("figure8", seed=3, duration=DURATION, noise=NoiseModel(detection_base=SIGMA, detection_per_m=0.0))
    stream = align(expected_streams(sim))
    late = second_half(stream)
    a, b = np.argsort(np.bincount(stream.det_idx[late]))[-2:]
    idx = ids_swapped(stream, late, a, b)
    batch = get_estimator("batch")
    for s, expected in ((stream, []), (replace(stream, det_idx=idx), sorted(stream.landmark_ids[[a, b]].tolist()))):
        res = batch.run(s, {}, ObserverOptions(noise=noise()))
        assert res.innovation_d2 is not None and res.innovation_d2.shape == res.det_ids.shape
        record = InnovationRecord()
        record.add(res)
        assert sorted(j["id"] for j in landmark_jumps(*record.arrays())) == expected


def test_batch_takes_its_riekf_start_s_jumps_before_its_own(tmp_path, monkeypatch):
    """Where batch's riekf start and its own residuals both name jumps, the start's are split: the smoother's fit
    spreads over both places, and on a hand-held log with two tags on one id (seed=3835) batch's own residuals named
    another landmark (31, at 25x in metres), whose split took the run to 1.55 m APE, while the start named the
    shared id (0.033 m split by it). Here batch's own check is made to name a landmark that did not jump; the run
    splits the two ids its start names."""
    import json

    import slamobs.pipeline.run as run_module
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import prepare_log, run_prepared

    config = parse_config({"observer": "batch", "evaluation": {"plots": False}})
    prepared = prepare_log(Path(__file__).parents[1] / "sample_logs" / "figure8.mcap", config, directions=False)
    stream = prepared.aligned
    a, b = np.argsort(np.bincount(stream.det_idx[second_half(stream)]))[-2:]
    late, _ = swap_between_candidates(stream, (a, b))
    idx = ids_swapped(stream, late, a, b)
    prepared.aligned = replace(stream, det_idx=idx)
    other = int(stream.landmark_ids[np.setdiff1d(np.unique(stream.det_idx), [a, b])[0]])
    wrong = {"id": other, "t_ns": int(stream.det_t_ns[stream.det_t_ns.shape[0] // 2]), "before": [10, 1.0]}
    wrong["after"] = [10, 30.0]
    monkeypatch.setattr(run_module, "landmark_jumps", lambda *arrays: [dict(wrong)])
    run_prepared(prepared, tmp_path / "run", config)
    jumps = json.loads((tmp_path / "run" / "run.json").read_text())["observer"]["landmark_jumps"]
    assert sorted(j["id"] for j in jumps if "new_id" in j) == sorted(stream.landmark_ids[[a, b]].tolist()), jumps


def test_riekf_that_cannot_recover_says_so_in_an_error_line(log):
    """Halfway, the detections are associated with random landmarks: no noise level explains them, so the
    filter gives up with status lost and an error line, not a quiet trajectory."""
    _, stream = log
    jump = second_half(stream)
    idx = stream.det_idx.copy()
    idx[jump] = np.random.default_rng(6).integers(0, stream.landmark_ids.shape[0], int(jump.sum()))
    res = RIEKF.run(replace(stream, det_idx=idx), {}, ObserverOptions(noise=noise()))
    f = res.stats["metadata"]["filter"]
    assert f["status"] == "lost" and f["lost_at_s"] > DURATION / 2
    errors = [n for n in res.stats["notes"] if n.startswith("error: riekf: lost the log")]
    assert len(errors) == 1 and f"{f['lost_at_s']:.2f} s" in errors[0]


def test_batch_is_never_worse_than_a_poor_fast_adaptation_seed_and_names_the_winner():
    """fast-adaptation started 170° off with a slow pose gain (k_w 0.01) is metres off after 15 s; the smoother
    from it stops in a local minimum where most detections fail the gate. That doubt makes batch try dead
    reckoning and riekf too, and keep the lowest graph cost: the optimum, millimetres from the truth."""
    from slamobs.pipeline.estimators import get_estimator
    from slamobs.pipeline.lie import so3_exp
    from slamobs.pipeline.simulate import get_scenario
    from slamobs.pipeline.smoother.estimator import BatchSmoother
    from slamobs.pipeline.smoother.preintegration import keyframe_times
    from slamobs.pipeline.smoother.seed import observer_seed
    from slamobs.pipeline.smoother.settings import BatchSettings

    pytest.importorskip("gtsam")
    sc = get_scenario("figure8")
    sim = simulate(sc, duration=15.0, seed=4)
    stream = align(expected_streams(sim))
    kf_t = keyframe_times(stream.seconds(stream.vel_t_ns), stream.seconds(stream.det_t_ns), 0.2)
    truth = sc.sample(kf_t + (stream.t0_ns - sim.start_ns) * 1e-9)
    gains = {"k_w": 0.01}
    spec = get_estimator("fast-adaptation")
    stepper = spec.start(stream, spec.resolve_gains(gains), ObserverOptions())
    stepper.state.r_hat[:] = so3_exp(np.radians(170.0) * np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)) @ truth.R[0]
    seed = observer_seed("fast-adaptation", stream, gains, ObserverOptions(), kf_t, stepper=stepper)
    run = BatchSmoother(stream, {}, ObserverOptions(), settings=BatchSettings(max_iterations=15), seed=seed)
    summary = run.solve()
    sol = run.result["solution"]

    def ape(pos):
        rot, trans, _ = umeyama(pos, truth.P)
        return float(np.sqrt(np.mean(np.sum((pos @ rot.T + trans - truth.P) ** 2, axis=1))))

    assert ape(seed.pos) > 1.0 and ape(sol.pos) < 0.02  # the seed is poor; batch is not
    robust = summary["robust"]
    costs = {name: c["cost"] for name, c in robust["candidates"].items()}
    assert robust["winner"] == summary["seed"] == min(costs, key=costs.get) != "fast-adaptation"
    assert costs["fast-adaptation"] > 10 * costs[robust["winner"]]
    assert robust["candidates"]["dead-reckoning"]["seed_ape_m"] > 1.0  # the starts disagreed, and it says by how much
    # each candidate's trajectory against the winner's: 0 for the winner, the poor seed's minimum far from it
    assert robust["candidates"][robust["winner"]]["solution_ape_m"] == 0.0
    assert robust["candidates"]["fast-adaptation"]["solution_ape_m"] > 1.0
    (note,) = [n for n in run.stats["notes"] if n.startswith("batch: first solution doubtful")]
    assert f"kept '{robust['winner']}'" in note and "many detections fail" in note
    assert not any("local minimum" in n for n in run.stats["notes"])  # the winner passes the gate


#: The time-offset estimate's tolerance on the figure8 log (s): about a tenth of the detection period (20 Hz).
OFFSET_TOLERANCE_S = 0.005


@pytest.mark.parametrize("offset", [0.1, -0.03, 0.0])
def test_detection_time_offset_is_estimated_and_applied_only_when_reliable(offset):
    """Detections stamped ``offset`` s late (the simulator's option): the estimate moves them back within
    OFFSET_TOLERANCE_S, riekf applies it and says so; without an offset nothing is applied (the run unchanged)."""
    from slamobs.pipeline.observers import time_offset

    sim = simulate("figure8", seed=2, duration=20.0, detection_offset=offset)
    stream = align(expected_streams(sim))
    est = time_offset.estimate(stream)
    assert abs(est["estimate_s"] + offset) < OFFSET_TOLERANCE_S
    assert est["applied"] == (offset != 0.0)
    if offset == 0.0:
        assert time_offset.shifted(stream, est) is stream and time_offset.note("riekf", est) == []
        return
    res = RIEKF.run(stream, {}, ObserverOptions())
    assert res.stats["metadata"]["time_offset"] == est
    (note,) = [n for n in res.stats["notes"] if "onto the velocity clock" in n]
    assert note.startswith(f"riekf: detection stamps moved by {est['estimate_s']:+.4f} s") and note.endswith("applied")
    # the filter ran on the corrected stamps (its detection rows carry them)
    shift_ns = int(round(est["estimate_s"] * 1e9))
    assert np.array_equal(res.det_t_ns, np.repeat(stream.det_t_ns + shift_ns, np.diff(stream.det_offsets)))


def test_an_offset_the_costs_do_not_tell_from_zero_carries_no_standard_error():
    """No offset, 2 Hz detections, a noisy odometry: the cost curve is flat and ragged, its least point (-0.18 s)
    fits only ~1.03x better than no shift and is not applied; the curvature there read ± 0.022 s, eight standard
    errors off zero. The record gives no σ then, but the span of shifts fitting within MIN_GAIN of the best, zero
    inside it."""
    from slamobs.pipeline.observers import time_offset

    gyro, vel = DEFAULTS["gyro"][0] * 30 * np.sqrt(50), DEFAULTS["velocity"][0] * 10 * np.sqrt(50)
    noise = replace(NoiseModel(), gyro=gyro, odom_linear=vel)
    sim = simulate("ground", noise=noise, seed=3262, duration=60.0, imu_rate=50.0, odom_rate=50.0, detection_rate=2.0)
    est = time_offset.estimate(align(expected_streams(sim)))
    assert not est["applied"] and est["cost_gain"] < time_offset.MIN_GAIN
    assert est["sigma_s"] is None
    lo, hi = est["indistinct_s"]
    assert lo <= min(0.0, est["estimate_s"]) and max(0.0, est["estimate_s"]) <= hi


@pytest.mark.parametrize("offset", [0.0, 0.1])
def test_an_offset_inside_the_searchs_own_lag_on_a_10_hz_velocity_is_not_applied(offset):
    """Issue 23: the search holds each 10 Hz velocity sample until the next, where riekf and batch interpolate, and
    so finds half the 0.1 s interval (+0.05 s) on a log with no offset: inside its own lag, that is not applied
    (on main it was, riekf 0.030 -> 0.104 m). Detections 0.1 s late are still found (read 0.05 s short, the same
    lag) and applied."""
    from slamobs.pipeline.observers import time_offset

    sim = simulate("figure8", seed=2, duration=20.0, detection_offset=offset, imu_rate=10.0, odom_rate=10.0)
    stream = align(expected_streams(sim))
    est = time_offset.estimate(stream)
    lag = time_offset.hold_lag(stream)
    assert lag == pytest.approx(0.05)
    assert est["estimate_s"] == pytest.approx(lag - offset, abs=OFFSET_TOLERANCE_S)
    assert est["applied"] == (offset != 0.0)
    if offset == 0.0:
        assert "within the search's own lag (0.0500 s" in est["why_not_applied"]


def _without_pending_estimate(stats: dict, done: dict) -> dict:
    """``stats`` of a stretch returned while the time offset's reporting checks still ran (its ``time_offset`` None:
    ``RiEKF.advance`` waits only for whether it is applied) with the estimate's record and notes of ``done``."""
    if stats["metadata"]["time_offset"] is not None:
        return stats
    return {
        **stats,
        "metadata": {**stats["metadata"], "time_offset": done["metadata"]["time_offset"]},
        "notes": done["notes"],
    }


@pytest.mark.parametrize("offset", [0.1, 0.0])
def test_riekf_started_during_the_time_offset_estimate_equals_one_started_after_it(offset, monkeypatch):
    """riekf starts on the recorded stamps while the offset is estimated on the other core
    (``time_offset.Background``): its first stretch is kept when the estimate is not applied, run again on the
    moved stamps when it is. Either way every output equals that of the filter started after the estimate
    (one core: ``Background`` estimates at once), stretch by stretch."""
    from slamobs.pipeline.observers import time_offset

    sim = simulate("figure8", seed=2, duration=20.0, detection_offset=offset)
    stream = align(expected_streams(sim))

    def stretches(wait=False, ready=False):
        st = RIEKF.start(stream, {}, ObserverOptions())
        if wait:  # the estimate read before the filter runs: waited for, the filter started again when applied
            assert st.time_offset["applied"] == (offset != 0.0)
        if ready:  # the estimate done before the filter's first kernel call: an applied one stops that filter at once
            st._offset.result()
        return [st.advance(stop) for stop in (1500, 2600, st.n_vel)]

    assert cores() > 1 or pytest.skip("one core: nothing runs concurrently")
    assert time_offset.Background(stream)._thread is not None  # the estimate on its own thread
    both, waited, ready = stretches(), stretches(wait=True), stretches(ready=True)
    monkeypatch.setattr(time_offset, "cores", lambda: 1)
    assert time_offset.Background(stream)._thread is None
    after = stretches()
    assert both[-1].stats["metadata"]["time_offset"]["applied"] == (offset != 0.0)
    for a, b in [*zip(both, after, strict=True), *zip(waited, after, strict=True), *zip(ready, after, strict=True)]:
        assert _without_pending_estimate(a.stats, b.stats) == b.stats
        for f in ("t_ns", "rotation", "position", "gyro_bias", "det_t_ns", "innovation", "pose_cov", "landmark_cov"):
            assert np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True), f


def test_riekf_returns_its_first_stretch_before_the_time_offset_reports(monkeypatch):
    """The first stretch waits only for whether the offset is applied, not for the estimate's reporting checks
    (gyro misreads, velocity scale: a third of its work on the 1 h log); the last stretch holds the whole estimate."""
    import threading

    from slamobs.pipeline.observers import time_offset

    assert cores() > 1 or pytest.skip("one core: nothing runs concurrently")
    stream = align(expected_streams(simulate("figure8", seed=2, duration=20.0)))
    release, checks = threading.Event(), time_offset.gyro_misreads

    def held(c):
        assert release.wait(60.0)
        return checks(c)

    monkeypatch.setattr(time_offset, "gyro_misreads", held)
    st = RIEKF.start(stream, {}, ObserverOptions())
    first = st.advance(1500)  # returns while the checks are held
    assert first.stats["metadata"]["time_offset"] is None and not release.is_set()
    release.set()
    last = st.advance(st.n_vel)
    assert last.stats["metadata"]["time_offset"] == time_offset.estimate(stream)


def test_riekf_recovers_from_gyro_noise_100x_the_default_by_raising_the_motion_noise():
    """The gyro 100x noisier than the defaults assume (issue 23): without the recovery the filter gated 4274 of
    4433 detections and ended 3 m off. The frames' innovations move together (a pose error, not noisy
    detections), so the recovery raises the motion noise and the covariance."""
    sim = simulate("figure8", seed=3, duration=DURATION, noise=NoiseModel(gyro=0.5))
    stream = align(expected_streams(sim))
    res = RIEKF.run(stream, {}, ObserverOptions())
    f = res.stats["metadata"]["filter"]
    assert f["status"] == "recovered" and f["noise_factor"] > 10.0
    assert f["recovery_log"][0]["action"].startswith("the motion noise variances")
    assert f["gated_detections"] < 0.1 * stream.det_idx.shape[0]
    assert ape(sim, res) < 0.3
    # the detection pairs' bias start is not used: the default gyro level does not explain them
    assert not f["bias_priors"]["from_pairs"]["used"]
    assert sum("bias estimate is not used (the pairs' residuals are" in n for n in res.stats["notes"]) == 1


def test_a_start_that_reaches_the_same_minimum_does_not_replace_the_configured_seed():
    """``choose``: a candidate wins only by more than TIE_COST (half-χ² units); a tie keeps the first solution,
    and the note says it was a tie."""
    from types import SimpleNamespace

    from slamobs.pipeline.smoother import candidates as cands

    def cand(name, cost):
        pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        c = cands.Candidate(SimpleNamespace(name=name, pos=pos, rot=None, landmarks=None), sol=SimpleNamespace(pos=pos))
        c.cost = cost
        return c

    first, riekf = cand("fast-adaptation", 637.518), cand("riekf", 637.487)
    assert cands.choose([first, riekf]) is first
    far = cand("riekf", first.cost - cands.TIE_COST - 0.5)
    assert cands.choose([first, far]) is far
    _, note = cands.record("test", [first, riekf], first, first.seed)
    assert "kept 'fast-adaptation' (no start lowers the cost by more than 1: a tie)" in note
    assert note.endswith("the other solutions against the kept one: riekf 0 m")  # one minimum, reached twice


def test_every_start_is_tried_on_a_short_log_and_only_when_doubtful_on_a_long_one(log, monkeypatch):
    """A clean log's first solution passes every doubt check; on a log of at most ALWAYS_MAX_KEYFRAMES keyframes
    the other starts are tried anyway (a wrong minimum can pass the checks), the lowest robust cost kept and the
    note saying why; above the limit they are not (each start would be a long solve). The same trajectory either
    way here: the starts reach one minimum, and a tie keeps the configured seed's solution."""
    from slamobs.pipeline.smoother import candidates as cands
    from slamobs.pipeline.smoother.estimator import BatchSmoother

    _, stream = log
    short = BatchSmoother(stream, {}, ObserverOptions(), noise=noise())
    summary = short.solve()
    robust = summary["robust"]
    assert robust["reason"].startswith("every start tried on a log of") and robust["winner"] == "fast-adaptation"
    assert {"dead-reckoning", "riekf"} <= set(robust["candidates"])
    assert any(n.startswith("batch: every start tried") for n in short.stats["notes"])
    monkeypatch.setattr(cands, "ALWAYS_MAX_KEYFRAMES", 10)
    long = BatchSmoother(stream, {}, ObserverOptions(), noise=noise())
    assert "robust" not in long.solve()
    assert np.allclose(long.result["solution"].pos, short.result["solution"].pos, atol=1e-6)


def test_batch_s_gate_warning_names_the_detection_topic():
    """batch's warning of a solution most detections fail the χ² gate at (a wrong minimum) names the detection
    topic it is about, as the other checks' warnings do (``alignment.stream_topics``); none where none is known."""
    from slamobs.pipeline.smoother.estimator import gate_note

    said = gate_note(900, 1000, "riekf", {"detections": "/cam0/tags", "angular_velocity": "/imu"})
    assert said.startswith("warning: batch: 900 of 1000 detections [detections /cam0/tags] fail the χ² gate"), said
    assert "1000 detections fail the χ² gate" in gate_note(900, 1000, "riekf", {})


@pytest.mark.parametrize("drift", [0.05, 0.0])
def test_riekf_says_when_wheel_slip_makes_it_overconfident(drift):
    """Wheel slip (a slowly varying velocity error the noise model lacks) passes the gate but makes the innovations
    correlated in time: the filter records it and says its covariance understates the error; without slip the
    check finds nothing and writes nothing."""
    sim = simulate("figure8", seed=2, duration=30.0, noise=replace(NoiseModel(), odom_linear_drift=drift))
    res = RIEKF.run(align(expected_streams(sim)), {}, ObserverOptions())
    con = res.stats["metadata"]["filter"]["consistency"]
    said = [n for n in res.stats["notes"] if n.startswith("riekf: overconfident from")]
    if drift:
        assert con["overconfident"] >= 1 and con["log"][0]["median_d2"] > 6.25 and len(said) == 1
    else:
        assert con == {"overconfident": 0, "log": []} and not said
    assert res.stats["metadata"]["filter"]["blind"] == []  # no blind stretch: nothing re-opened


def test_riekf_learns_its_velocity_bias_walk_from_wheel_slip_and_says_so():
    """Wheel slip (0.05 m/s, 10 s time scale) moves the velocity bias faster than the default walk lets the filter
    follow: its bias corrections grow beyond what it expects of them, and the walk is raised (run.json
    observer.filter.walk, a note), which brings the later trajectory closer than with the walk held at its default
    (given in the configuration: kept as given). Without slip the corrections are what the filter expects and the
    walk stays."""
    slip = align(
        expected_streams(
            simulate("figure8", seed=2, duration=60.0, noise=replace(NoiseModel(), odom_linear_drift=0.05))
        )
    )
    learned = RIEKF.run(slip, {}, ObserverOptions())
    f = learned.stats["metadata"]["filter"]["walk"]
    assert f["learned"] and f["raises"] and f["raises"][0]["ratio"] > 4.0
    assert f["velocity_bias_walk"] > 10 * f["given_m_s_sqrt_s"]
    assert sum(n.startswith("riekf: velocity-bias walk learned from the log") for n in learned.stats["notes"]) == 1
    held = RIEKF.run(slip, {}, ObserverOptions(noise=resolve_noise(NoiseConfig(velocity_bias_walk=1e-4))))
    h = held.stats["metadata"]["filter"]["walk"]
    assert not h["learned"] and h["raises"] == [] and h["velocity_bias_walk"] == 1e-4
    assert not any("velocity-bias walk learned" in n for n in held.stats["notes"])
    sim = simulate("figure8", seed=2, duration=60.0, noise=replace(NoiseModel(), odom_linear_drift=0.05))
    assert ape(sim, learned, 0.4) < 0.8 * ape(sim, held, 0.4)
    clean = RIEKF.run(align(expected_streams(simulate("figure8", seed=2, duration=60.0))), {}, ObserverOptions())
    assert clean.stats["metadata"]["filter"]["walk"]["raises"] == []
    assert learned.stats["metadata"]["filter"]["walk"]["passes"] == 1  # not a ground robot on its floor: not run again


def _walking_gyro_log(walk: float):
    """A ground robot (120 s, IMU 100 / odometry 20 Hz, 30x the default gyro and 10x the velocity density) whose gyro
    bias walks ``walk`` rad/s/√s (the walk added to the gyro samples, as ``benchmarks/handheld_logs.py`` does): the
    simulation, its aligned stream and its true white levels."""
    gyro, vel = 30 * DEFAULTS["gyro"][0], 10 * DEFAULTS["velocity"][0]
    nm = replace(NoiseModel(), gyro=gyro * np.sqrt(100), odom_linear=vel * np.sqrt(20), detection_base=0.03)
    sim = simulate(
        "ground", seed=3819, duration=120.0, noise=replace(nm, detection_per_m=0.006), imu_rate=100, odom_rate=20
    )
    rng = np.random.default_rng(3826)
    dt = np.diff(sim.imu.t_ns, prepend=sim.imu.t_ns[0]) * 1e-9
    bias = np.cumsum(rng.standard_normal((dt.shape[0], 3)) * walk * np.sqrt(dt)[:, None], axis=0)
    sim = replace(sim, imu=replace(sim.imu, gyro=sim.imu.gyro + bias))
    return (
        sim,
        align(expected_streams(sim)),
        NoiseConfig(gyro=gyro, velocity=vel, detection=0.03, detection_per_m=0.006),
    )


def test_riekf_learns_its_gyro_bias_walk_from_a_gyro_bias_that_walks_and_says_so():
    """A gyro bias walking 0.003 rad/s/√s (30x the default walk) on a ground robot: the heading error the frozen bias
    leaves grows faster than the filter allows, and its gyro-bias corrections exceed what it expects of them. The
    first stretch is run again with the gyro's walk learned (run.json observer.filter.walk.gyro, a note), and riekf
    is within 0.6x of fast-adaptation's APE (0.20 against 0.48 m; before, without the gyro's walk, 0.43: the
    velocity's walk took the error). Without the walk nothing is learned for the gyro; given in the configuration,
    the walk is kept as given."""
    sim, stream, true = _walking_gyro_log(0.003)
    noise = resolve_noise(true)
    res = RIEKF.run(stream, {}, ObserverOptions(noise=noise))
    fa = FA.run(stream, {gain.name: gain.default for gain in FA.gains}, ObserverOptions(noise=noise))
    assert ape(sim, res) < 0.6 * ape(sim, fa)
    g = res.stats["metadata"]["filter"]["walk"]["gyro"]
    assert g["learned"] and g["start_walk"] > 5 * g["given_rad_s_sqrt_s"]
    assert sum(n.startswith("riekf: gyro-bias walk learned from the log") for n in res.stats["notes"]) == 1
    given = RIEKF.run(stream, {}, ObserverOptions(noise=resolve_noise(replace(true, gyro_bias_walk=1e-4))))
    assert given.stats["metadata"]["filter"]["walk"]["gyro"] == {
        "learned": False,
        "given_rad_s_sqrt_s": 1e-4,
        "start_walk": 1e-4,
        "gyro_bias_walk": 1e-4,
    }
    sim0, stream0, _ = _walking_gyro_log(0.0)
    g0 = RIEKF.run(stream0, {}, ObserverOptions(noise=noise)).stats["metadata"]["filter"]["walk"]["gyro"]
    assert g0["start_walk"] == g0["gyro_bias_walk"] == g0["given_rad_s_sqrt_s"]


def test_riekf_narrows_its_bias_priors_when_its_last_detections_all_fail_the_gate_and_keeps_them_only_if_it_helps(
    log, monkeypatch
):
    """The last 25 detections moved 3 m (fewer than half a recovery window: no recovery is judged): the first pass
    ends with its track lost, so riekf runs again with both bias priors narrowed 4x, 16x, 64x; the detections stay
    off (no bias explains them), every pass ends so, and a last pass puts the priors back: the trajectory is the
    first pass's (a run allowed no narrowing), and the note says the narrowing did not help. With a bias prior given
    in the configuration it runs once; run.json's ``start_sigma`` is the prior each started with."""
    from slamobs.pipeline.observers import riekf

    _, stream = log
    y = stream.det_y.copy()
    y[-25:] += 3.0
    moved = replace(stream, det_y=y)
    res = RIEKF.run(moved, {}, ObserverOptions(noise=noise()))
    pri = res.stats["metadata"]["filter"]["bias_priors"]
    assert pri["narrowed_passes"] == 3 and not pri["kept"] and pri["factor"] == 1.0, pri
    assert len(pri["gated_in_a_row_before"]) == 4 and min(pri["gated_in_a_row_before"]) >= 20
    assert pri["gated_in_a_row_at_end"] >= 20 and pri["velocity_bias"] == 0.2
    assert sum("narrowed up to 0.0156x the runs held such a run too" in n for n in res.stats["notes"]) == 1
    fp = pri["from_pairs"]  # what the last pass started with, the priors put back (factor 1)
    assert pri["start_sigma"] == (fp["sigma"] if fp["used"] else [0.2] * 6), pri
    given = resolve_noise(NoiseConfig(detection=SIGMA, detection_per_m=0.0, gyro_bias=0.2))
    once = RIEKF.run(moved, {}, ObserverOptions(noise=given))
    assert once.stats["metadata"]["filter"]["bias_priors"]["narrowed_passes"] == 0
    assert once.stats["metadata"]["filter"]["bias_priors"]["start_sigma"] == [0.2] * 6  # a prior given: no pairs'
    monkeypatch.setattr(riekf, "MAX_PRIOR_PASSES", 0)  # the first pass, then the priors put back at once
    first = RIEKF.run(moved, {}, ObserverOptions(noise=noise()))
    assert first.stats["metadata"]["filter"]["bias_priors"]["narrowed_passes"] == 0
    np.testing.assert_array_equal(res.position, first.position)  # the priors as they were: the same trajectory


def test_riekf_takes_a_lost_track_before_the_end_and_half_failing_beside_passing_ones_as_lost(log):
    """A track lost before the log's end counts, and a frame where as many detections fail as pass does not end the
    run: 25 frames mid-log with half their detections (rounded up) moved 3 m while the others pass (with two tags
    back after a blind stretch the state may fit one and not the other; TagSLAM test_22 at a gyro level of 0.034-0.1
    went 0.7-2.8 m off so, converged, the priors never narrowed) make riekf narrow its bias priors, with a note. The log
    as simulated: no narrowing."""
    _, stream = log
    counts = np.diff(stream.det_offsets)
    y = stream.det_y.copy()
    for f in range(counts.size // 2, counts.size // 2 + 25):  # 25 frames in a row mid-log: half of each moved
        a = stream.det_offsets[f]
        y[a : a + max(counts[f] // 2, 1)] += 3.0
    res = RIEKF.run(replace(stream, det_y=y), {}, ObserverOptions(noise=noise()))
    pri = res.stats["metadata"]["filter"]["bias_priors"]
    assert pri["narrowed_passes"] >= 1 and pri["gated_in_a_row_before"][0] >= 20, pri
    assert pri["gated_in_a_row_at_end"] < 20, pri
    assert sum("bias priors narrowed" in n for n in res.stats["notes"]) == 1, res.stats["notes"]
    plain = RIEKF.run(stream, {}, ObserverOptions(noise=noise()))
    p = plain.stats["metadata"]["filter"]["bias_priors"]
    assert p["narrowed_passes"] == 0 and p["gated_in_a_row_longest"] < 20, p


def test_riekf_narrows_its_bias_priors_past_the_first_pass_that_holds_while_its_likelihood_says_so():
    """A figure 8 (seed=3431, 4 landmarks, the gyro 100x the default density, the filter given 0.3x of it) with no
    detection from 25 to 43 s: the default bias priors lose the track at the return, and one narrowing pass keeps the
    gate (under ``LOST_IN_A_ROW`` in a row) but not the trajectory. The narrowing went on no further (as TagSLAM
    test_22 at a gyro level of 0.045, 0.56 m off where narrower priors give 0.23); now a narrower pass whose
    innovations' deviance per detection is lower is taken, and the one after it, worse, is not: the run is closer
    to the truth than with the first narrowing's priors given, and the note says which narrowings were tried."""
    from slamobs.pipeline.observers import riekf
    from slamobs.pipeline.simulate.scenarios import customize, get_scenario

    rate, gyro, vel = 100.0, 100 * DEFAULTS["gyro"][0], 4 * DEFAULTS["velocity"][0]
    nm = NoiseModel(
        gyro=gyro * np.sqrt(rate), odom_linear=vel * np.sqrt(rate), detection_base=0.01, detection_per_m=0.01
    )
    sc = customize(get_scenario("figure8"), landmarks=4, detection_gaps=((25.0, 43.0),))
    sim = simulate(sc, noise=nm, detection_rate=10, duration=58.0, seed=3431, imu_rate=rate, odom_rate=rate)
    stream = align(expected_streams(sim))
    levels = dict(gyro=0.3 * gyro, velocity=vel, detection=0.01, detection_per_m=0.01)
    res = RIEKF.run(stream, {}, ObserverOptions(noise=resolve_noise(NoiseConfig(**levels))))
    pri = res.stats["metadata"]["filter"]["bias_priors"]
    assert pri["narrowed_passes"] >= 2 and pri["kept"], pri
    tried = pri["narrowed_tried"]
    assert len(tried) >= 2, pri
    kept = min(tried, key=lambda t: t["deviance_mean"])
    assert kept["pass"] == pri["narrowed_passes"] and kept is not tried[0], tried
    assert kept["deviance_mean"] < tried[0]["deviance_mean"] and kept["gated"] < tried[0]["gated"], tried
    first = riekf.PRIOR_NARROWING * DEFAULTS["gyro_bias"][0]
    given = resolve_noise(NoiseConfig(**levels, gyro_bias=first, velocity_bias=first))
    assert ape(sim, res) < ape(sim, RIEKF.run(stream, {}, ObserverOptions(noise=given)))
    assert sum("of the narrowings tried" in n for n in res.stats["notes"]) == 1, res.stats["notes"]


def test_riekf_says_so_when_its_last_detections_fail_the_gate_too_few_to_narrow_its_priors(log):
    """The last 10 detections moved 3 m: fewer than ``LOST_IN_A_ROW`` in a row fail the gate at the end, so the
    priors are not narrowed and the status stays as it was; the run says its end is off (before, nothing did: TagSLAM
    test_22 cut at 31 s ended 4.7 m off, converged, silent). The log as simulated ends with none failing: no note."""
    from slamobs.pipeline.observers import riekf

    _, stream = log
    y = stream.det_y.copy()
    y[-10:] += 3.0
    res = RIEKF.run(replace(stream, det_y=y), {}, ObserverOptions(noise=noise()))
    pri = res.stats["metadata"]["filter"]["bias_priors"]
    assert riekf.TAIL_NOTE_IN_A_ROW <= pri["gated_in_a_row_at_end"] < riekf.LOST_IN_A_ROW, pri
    assert pri["narrowed_passes"] == 0
    said = [n for n in res.stats["notes"] if "in a row failed the gate (status gated_at_end): the pose" in n]
    assert len(said) == 1 and f"its last {pri['gated_in_a_row_at_end']} " in said[0], res.stats["notes"]
    plain = RIEKF.run(stream, {}, ObserverOptions(noise=noise()))
    assert plain.stats["metadata"]["filter"]["bias_priors"]["gated_in_a_row_at_end"] < riekf.TAIL_NOTE_IN_A_ROW
    assert not any("in a row failed the gate" in n for n in plain.stats["notes"])


def test_riekf_status_never_claims_more_than_its_notes(log):
    """The status is ``filter_status``'s: a run whose last detections fail the gate (the note above) is not
    ``converged`` (it was, TagSLAM test_22 cut at 28.5-31 s, 2.7-4.7 m off at the end), with what was checked; the
    log as simulated stays ``converged``."""
    from slamobs.pipeline.observers import riekf

    _, stream = log
    y = stream.det_y.copy()
    y[-10:] += 3.0
    f = RIEKF.run(replace(stream, det_y=y), {}, ObserverOptions(noise=noise())).stats["metadata"]["filter"]
    assert f["bias_priors"]["gated_in_a_row_at_end"] >= riekf.TAIL_NOTE_IN_A_ROW and f["recoveries"] == 0, f
    assert f["status"] == "gated_at_end" and f["status_checked"] == riekf.STATUSES["gated_at_end"], f
    plain = RIEKF.run(stream, {}, ObserverOptions(noise=noise())).stats["metadata"]["filter"]
    assert plain["status"] == "converged" and "fewer than" in plain["status_checked"], plain
    assert riekf.filter_status(True, 0, 30) == "lost"  # gave up: lost, whatever the end
    assert riekf.filter_status(False, 2, riekf.TAIL_NOTE_IN_A_ROW) == "gated_at_end"  # a recovery, then a failing end
    assert riekf.filter_status(False, 2, riekf.TAIL_NOTE_IN_A_ROW - 1) == "recovered"


def _gap_run(tmp_path, seed: int, floor, late=None, walk=None) -> dict:
    """riekf on benchmarks/unseen_logs.py's ground robot (wheel slip, 0-2 landmarks in view, the 50x gyro) with no
    detection from 50 to 90 s (and ``late``: a landmark first seen then), with ``noise.floor`` ``floor``: run.json."""
    import json

    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import write_log
    from slamobs.pipeline.simulate.scenarios import customize, get_scenario

    sc = customize(get_scenario("ground"), detection_gaps=((50.0, 90.0),), first_seen=(late,) if late else None)
    nm = replace(
        NoiseModel(),
        gyro=50 * DEFAULTS["gyro"][0] / np.sqrt(0.05),
        odom_linear=4 * DEFAULTS["velocity"][0] / np.sqrt(0.05),
        odom_linear_drift=0.02,
        stereo_pixel=4.0,
        stereo_focal=1000.0,
        stereo_baseline=0.5,
    )
    sim = simulate(sc, noise=nm, duration=160.0, seed=seed, imu_rate=20.0, odom_rate=20.0, detection_rate=12.0)
    write_log(replace(sim, noise=replace(nm, gyro=0.0, odom_linear=0.0)), tmp_path / "gap.mcap", overwrite=True)
    # walk: noise.velocity_bias_walk given (the walk neither learned from the log nor raised)
    config = {
        "evaluation": {"plots": False},
        "noise": {"floor": floor} | ({"velocity_bias_walk": walk} if walk else {}),
    }
    run_log(tmp_path / "gap.mcap", tmp_path / "out", observer="riekf", config=config, force=True)
    return json.loads((tmp_path / "out" / "run.json").read_text())


def test_riekf_re_anchors_the_pose_after_a_blind_stretch_and_says_so(tmp_path):
    """The ground robot with no detection for 40 s: the first re-observed landmarks fall outside the dead-reckoned
    covariance. Before, nearly all of them failed the gate, the recovery raised the detection noise instead and the
    filter lost the log (20 % gated, an error line); now the position's covariance is re-opened to the error they
    show and they re-anchor the pose, with a note. (The floor, noise.floor, keeps this log's pose through the gap,
    so that nothing fails the gate after it: the blind stretch without it. The walk learned from the log from the start
    keeps this log's covariance wide enough that nothing fails either: the walk given at its default here, as the
    ground logs' walk was before it was learned from the start.)"""
    meta = _gap_run(tmp_path, 2, False, walk=1e-4)
    f = meta["observer"]["filter"]
    assert f["status"] != "lost" and f["gated_detections"] < 0.1 * meta["counts"]["detections"], f
    assert len(f["blind"]) == 1 and f["blind"][0]["blind_s"] > 40.0 and f["blind"][0]["gated_share"] > 0.9
    assert sum("without a known landmark's detection" in n for n in meta["notes"]) == 1


def test_riekf_on_the_floor_re_opens_the_heading_after_a_blind_stretch(tmp_path):
    """unseen_logs.py's gap-40s-late-s3: the heading is 45 deg off after the gap while the floor held roll and pitch,
    so the yaw's variance grew by the gyro's noise alone (σ 10 deg) and nearly every re-sighting fails the gate: the
    blind check must see that return as it is (the lone-detection linearisation term is off while it judges one;
    with the term on, the check never acted here) and re-open the pose, and the run must end neither lost nor mostly
    gated. When this test was written, re-opening the position alone lost the log at 100 s (12 % gated; docs/
    benchmarks.md, "The floor's faults"); since then the run holds without the heading's re-opening too (0.741 m
    against 0.827 with it, session 34's h-riekf22c), so what this guards is the check's action, not the heading's."""
    meta = _gap_run(tmp_path, 3, "auto", late=(5, 100.0), walk=1e-4)  # as before the walk was learned from the start
    f = meta["observer"]["filter"]
    assert f["planar"]["held"] and len(f["blind"]) == 1 and f["blind"][0]["gated_share"] > 0.9
    assert f["status"] != "lost" and f["gated_detections"] < 0.1 * meta["counts"]["detections"], f


def test_a_re_solve_that_ends_worse_than_the_seed_keeps_the_seed(log, monkeypatch):
    """ "Never worse than its seed" holds for the final solution, not only the first: a re-solve after the first
    solution (here the correlation step, replaced by one whose solution drifted 2 m away) that ends with a higher
    graph cost than the start as it is, under the final noise model, gives way to the start, and the record and
    note say so; a run whose re-solves did their work keeps its solution, with both costs recorded."""
    from slamobs.pipeline.smoother.estimator import BatchSmoother
    from slamobs.pipeline.smoother.settings import BatchSettings

    _, stream = log
    settings = BatchSettings(noise_evidence="off", detection_anisotropy="off", detection_correlation="off")
    good = BatchSmoother(stream, {}, ObserverOptions(), settings=settings, noise=noise())
    check = good.solve()["seed_check"]
    assert check["kept"] == "solution" and check["cost"]["solution"] < check["cost"]["fast-adaptation (unsmoothed)"]

    def drifted(self, chosen, keyframes, segments, progress):
        sol = chosen.sol
        ramp = np.linspace(0.0, 2.0, sol.pos.shape[0])[:, None] * np.array([1.0, 0.0, 0.0])
        return replace(chosen, sol=replace(sol, pos=sol.pos + ramp)), {"skipped": "test"}, []

    monkeypatch.setattr(BatchSmoother, "_decorrelate", drifted)
    bad = BatchSmoother(stream, {}, ObserverOptions(), settings=settings, noise=noise())
    check = bad.solve()["seed_check"]
    assert check["kept"] == "fast-adaptation (unsmoothed)", check
    assert check["cost"]["fast-adaptation (unsmoothed)"] < check["cost"]["solution"] - 1.0
    seed = bad.result["seed"]
    assert np.array_equal(bad.result["solution"].pos, seed.pos)
    assert any("scored worse than a start as it is" in n for n in bad.stats["notes"]), bad.stats["notes"]


def test_an_angular_velocity_in_degrees_or_of_the_wrong_sign_is_named():
    # MR.CLAM with its gyro in deg/s: riekf APE 0.49 -> 3.8 m, its sign flipped: 48 m, and no word of the gyro;
    # the detection pairs say which reading fits them
    from slamobs.pipeline.observers import time_offset

    stream = align(expected_streams(simulate("figure8", seed=2, duration=20.0)))
    assert time_offset.note("riekf", time_offset.estimate(stream)) == []  # as recorded: no misread fits better
    for factor, what in ((np.degrees(1.0), "divided by 57.3 (deg/s?)"), (-1.0, "angular velocity's sign flipped")):
        misread = time_offset.estimate(replace(stream, omega=stream.omega * factor))
        said = [n for n in time_offset.note("riekf", misread) if n.startswith("warning: riekf: the detections fit")]
        assert len(said) == 1 and what in said[0], (factor, said)


def test_info_and_the_run_say_the_same_misread_sentences():
    """``info --noise`` (``note(None, ...)``) says each sentence the run says, without the estimator's name and what
    the estimate used: one source for both (session 18; info cut the run's sentences before)."""
    from slamobs.pipeline.observers import time_offset

    offset = {
        "pairs": 321,
        "applied": True,
        "estimate_s": 0.0421,
        "sigma_s": 0.003,
        "gyro_misreads": {"with its angular velocity's sign flipped": 9.0},
        "extrinsic_turn": {"gain": 12.0, "rotvec_deg": [0.0, 180.0, 0.0]},  # not named: the gyro is
        "velocity_scale": {"scale": [1000.0, 1.0, None], "sigma": [1.0, 0.1, None]},
    }
    gyro = (
        "the detections fit the odometry 9x better with its angular velocity's sign flipped (321 detection pairs, "
        "trimmed mean squared residual): check the gyro's unit and axes, or whether the detections are mirrored (an "
        "axis of their frame flipped: a left-handed camera extrinsic, a bearing of the wrong sign), which the "
        "detections cannot tell from it"
    )
    (velocity,) = time_offset.velocity_misread(offset["velocity_scale"])
    velocity = (
        f"the detections say the body moved {velocity} (321 detection pairs, the odometry's bias fitted with it): "
        f"{time_offset.SCALE_CAUSES}"
    )
    # a tag size off reads as this scale too (session 28): the sentence names both causes and the key of each
    assert "tags.size" in velocity and "the velocity's unit" in velocity and "cannot tell which" in velocity
    assert time_offset.note(None, offset) == [f"warning: {gyro}", f"warning: {velocity}"]
    assert time_offset.note("riekf", offset) == [
        "riekf: detection stamps moved by +0.0421 s (± 0.003) onto the velocity clock, estimated from the data (321 "
        "detection pairs; docs/observers.md, Time offset): applied",
        f"warning: riekf: {gyro}; the estimate used it as read",
        f"warning: riekf: {velocity}; the estimate used them as read",
    ]
    turned = {**offset, "gyro_misreads": {}, "velocity_scale": None, "applied": False}
    turn = (
        "the detections fit the odometry 12x better turned by 180 deg about the body's y (321 detection pairs, "
        "trimmed mean squared residual): check the camera's extrinsic (turned about one of its axes, or given as the "
        "inverse transform)"
    )
    assert time_offset.note(None, turned) == [f"warning: {turn}"]
    assert time_offset.note("batch", turned) == [f"warning: batch: {turn}; the estimate used it as read"]


def test_a_log_of_too_few_detection_pairs_has_no_misread_note():
    # riekf on sample_logs/figure8.mcap --end 1 ended in a traceback (ValueError from zip): the offset's estimate
    # returns before its checks on fewer than MIN_PAIRS pairs, and the note read their absence as three empty axes
    from slamobs.pipeline.observers import time_offset

    stream = align(expected_streams(simulate("figure8", seed=2, duration=1.0)))
    offset = time_offset.estimate(stream)
    assert offset["pairs"] < time_offset.MIN_PAIRS and "velocity_scale" not in offset
    assert time_offset.note("riekf", offset) == [] and time_offset.note(None, offset) == []
    assert not time_offset.misread(offset)


def test_landmark_jumps_after_a_misread_velocity_are_not_split(tmp_path):
    """The odometry's twist given in the truth's world frame (generated figure 8, seed 5, 40 s): riekf loses its
    pose (APE 1.85 m), the detection pairs name the twist's frame, and landmarks seen before and after the loss
    "jump"; round 6 split them as reused ids and ran again. Now they are named as the lost pose's, not split."""
    import json

    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.lie import quats_to_rots
    from slamobs.pipeline.run import prepare_log, run_prepared
    from slamobs.pipeline.simulate import write_log

    sim = simulate("figure8", seed=5, duration=40.0)
    m, o = sim.mocap, sim.odom
    near = np.clip(np.searchsorted(m.t_ns, o.t_ns), 0, m.t_ns.size - 1)
    world = np.einsum("nij,nj->ni", quats_to_rots(m.quat_xyzw[near]), o.linear)
    write_log(replace(sim, odom=replace(o, linear=world)), tmp_path / "world.mcap")
    config = parse_config({"observer": "riekf", "evaluation": {"plots": False}})
    summary = run_prepared(prepare_log(tmp_path / "world.mcap", config, directions=False), tmp_path / "run", config)
    jumps = json.loads((tmp_path / "run" / "run.json").read_text())["observer"]["landmark_jumps"]
    assert jumps and not any("new_id" in j for j in jumps), jumps
    said = [n for n in summary.notes if "jumps that follow a misread input" in n]
    assert len(said) == 1 and "not made again" in said[0], summary.notes
    assert any("looks like it is in a world frame" in n for n in summary.notes), summary.notes


def test_a_camera_extrinsic_turned_or_inverted_is_named():
    # a generated figure 8 with its camera turned 90 deg about its z, or its extrinsic given as the inverse transform:
    # riekf APE 9-11 m, and only "the body moved along x 2.08x as far as its velocity says" (round 6)
    from slamobs.pipeline.lie import quats_to_rots, rots_to_quats, so3_exp
    from slamobs.pipeline.observers import time_offset

    sim = simulate("figure8", seed=2, duration=20.0)
    record = time_offset.estimate(align(expected_streams(sim)))
    said = [n for n in time_offset.note("riekf", record) if "turned" in n]
    assert said == [] and record["camera_turned"] is False  # as recorded: no turn fits better
    camera = sim.static_tf[0]
    r = quats_to_rots(np.asarray(camera.quat_xyzw)[None])[0]
    turned = r @ so3_exp(np.array([0.0, 0.0, np.pi / 2]))
    for rot, shift in ((turned, camera.translation), (r.T, -r.T @ camera.translation)):
        tf = replace(camera, quat_xyzw=rots_to_quats(np.ascontiguousarray(rot[None]))[0], translation=shift)
        stream = align(expected_streams(replace(sim, static_tf=[tf, *sim.static_tf[1:]])))
        record = time_offset.estimate(stream)
        notes = time_offset.note("riekf", record)
        said = [n for n in notes if "check the camera's extrinsic" in n]
        assert len(said) == 1 and record["camera_turned"] is True, notes  # the flag the report reads


def test_a_camera_extrinsic_stated_a_few_degrees_off_is_named():
    # a camera's stated extrinsic 5-10 deg off about the body's z (seed=3856/3857 of round 7): riekf and batch near
    # their plain APE but NEES 89-463, and no axis turn fits: nothing named it
    from slamobs.pipeline.lie import quats_to_rots, rots_to_quats, so3_exp
    from slamobs.pipeline.observers import time_offset

    sim = simulate("figure8", seed=2, duration=20.0)
    record = time_offset.estimate(align(expected_streams(sim)))
    assert record["small_turn"] is None and record["camera_turned"] is False  # as stated: no turn named
    camera = sim.static_tf[0]
    r = quats_to_rots(np.asarray(camera.quat_xyzw)[None])[0]
    for deg in (6.0, -10.0):
        turned = so3_exp(np.array([0.0, 0.0, np.radians(deg)])) @ r
        tf = replace(camera, quat_xyzw=rots_to_quats(np.ascontiguousarray(turned[None]))[0])
        record = time_offset.estimate(align(expected_streams(replace(sim, static_tf=[tf, *sim.static_tf[1:]]))))
        said = [n for n in time_offset.note("riekf", record) if "check the camera's extrinsic" in n]
        # the turn that undoes the stated one (on this figure 8 the velocity's fitted bias takes a fifth of it)
        fitted = record["small_turn"]["rotvec_deg"]
        assert 0.7 < -fitted[2] / deg < 1.1 and np.hypot(*fitted[:2]) < 1.0, fitted
        assert len(said) == 1 and record["camera_turned"] is False, said  # the estimate's frame is not turned
        assert f"deg about the body's {'-' if deg > 0 else ''}z" in said[0] and "a few degrees off" in said[0], said
        assert time_offset.misread(record) is False  # the estimate is whole: landmark jumps still split


def test_a_camera_stated_under_3_deg_tilted_is_named_by_the_deviance_not_a_floor():
    # seed=9993 (session 38's unseen log): a camera stated 3 deg tilted in /tf_static went unnamed, its turn fitted
    # 2.86 deg (gain 1.31, halves 0.58 deg apart) under the 3 deg floor alone. A hand-held rig (seed=4719, 90 s) with
    # its camera stated 2.5 deg off in roll fits 2.8 deg at 1.29x, halves 0.34 deg apart: named now (the floor replaced
    # by the χ² rule of a deviance); its twin as stated names nothing
    from noisy_logs import rig_noise

    from slamobs.pipeline.lie import quats_to_rots, rots_to_quats, so3_exp
    from slamobs.pipeline.observers import time_offset
    from slamobs.pipeline.simulate.scenarios import handheld

    sim = simulate(handheld(), noise=rig_noise(200.0, 10.0), seed=4719, duration=90.0, imu_rate=200.0, odom_rate=10.0)
    record = time_offset.estimate(align(expected_streams(sim)))
    assert record["small_turn"] is None and not [n for n in time_offset.note("riekf", record) if "extrinsic" in n]
    camera = sim.static_tf[0]
    turned = so3_exp(np.array([np.radians(2.5), 0.0, 0.0])) @ quats_to_rots(np.asarray(camera.quat_xyzw)[None])[0]
    tf = replace(camera, quat_xyzw=rots_to_quats(np.ascontiguousarray(turned[None]))[0])
    record = time_offset.estimate(align(expected_streams(replace(sim, static_tf=[tf, *sim.static_tf[1:]]))))
    fitted = record["small_turn"]["rotvec_deg"]
    assert np.linalg.norm(fitted) < 3.0 and fitted[0] == pytest.approx(-2.5, abs=0.3), fitted
    said = [n for n in time_offset.note("riekf", record) if "check the camera's extrinsic" in n]
    assert len(said) == 1 and "a few degrees off" in said[0], said


def test_mirrored_detections_are_named_with_the_gyro_they_read_as():
    # a mirror (one axis of the detections' frame flipped) turns them the other way: to the detection pairs the
    # same as a gyro of the wrong sign on a ground robot, whose warning said "check the gyro" only
    from slamobs.pipeline.observers import time_offset

    stream = align(expected_streams(simulate("ground", seed=2, duration=30.0)))
    assert time_offset.note("riekf", time_offset.estimate(stream)) == []
    mirrored = stream.det_y * np.array([1.0, -1.0, 1.0])
    said = time_offset.note("riekf", time_offset.estimate(replace(stream, det_y=mirrored)))
    assert len(said) == 1 and "sign flipped" in said[0] and "the detections are mirrored" in said[0], said


@pytest.mark.parametrize("scenario", ["figure8", "figure8-wide", "ground", "circle", "loop"])
def test_bearings_in_degrees_are_named(scenario):
    # MR.CLAM 6 r1 with its bearings in degrees: riekf APE 0.49 -> 4.2 m and no word; the detection law the
    # noise estimate fits is then of the order of the ranges (1.55 m at 3 m), which no sensor's noise is. On a
    # body that turns slowly (ground, circle, loop) it is 0.10-0.17 of them, under the scatter warning's 0.25:
    # their azimuths read again as degrees scatter 30-40x less
    from slamobs.pipeline.noise import estimate_log_noise

    stream = align(expected_streams(simulate(scenario, seed=2, duration=30.0)))
    y = stream.det_y
    r, azimuth = np.hypot(y[:, 0], y[:, 1]), np.degrees(np.arctan2(y[:, 1], y[:, 0]))
    in_degrees = np.stack([r * np.cos(azimuth), r * np.sin(azimuth), y[:, 2]], axis=1)
    assert [n for n in estimate_log_noise(stream).notes if n.startswith("warning")] == []
    said = [n for n in estimate_log_noise(replace(stream, det_y=in_degrees)).notes if n.startswith("warning")]
    assert len(said) == 1 and "the detections scatter" in said[0] and "degrees" in said[0], said


def test_a_gyro_in_degrees_is_named_by_the_noise_estimate_not_the_detections():
    # a generated hand-held rig with its gyro in deg/s (docs/benchmarks.md, "Logs nobody has run yet, round 6"):
    # the dead reckoning between a triplet's detections turns 57.3x too far, the detections scatter by 0.6 of
    # their range, and the noise estimate's warning said to check the detections' unit and frame, beside riekf's
    # and batch's own warning naming the gyro
    from slamobs.pipeline.noise import estimate_log_noise
    from slamobs.pipeline.simulate.scenarios import handheld

    stream = align(expected_streams(simulate(handheld(), seed=2, duration=30.0)))
    assert [n for n in estimate_log_noise(stream).notes if n.startswith("warning")] == []
    said = [n for n in estimate_log_noise(replace(stream, omega=np.degrees(stream.omega))).notes if "warning" in n]
    assert len(said) == 1 and "a gyro in deg/s" in said[0] and "the detections' unit" not in said[0], said


def test_a_velocity_in_another_unit_or_of_the_wrong_sign_on_one_axis_is_named():
    # MR.CLAM with its velocity in km/h: riekf APE 0.49 -> 0.89 m, of the wrong sign: lost, and no word of the
    # velocity; the detection pairs give each axis's scale (the odometry's bias fitted with it)
    from slamobs.pipeline.observers import time_offset

    stream = align(expected_streams(simulate("figure8", seed=2, duration=20.0)))
    as_read = time_offset.estimate(stream)
    assert as_read["velocity_scale"]["scale"][0] == pytest.approx(1.0, abs=0.01)
    assert [n for n in time_offset.note("riekf", as_read) if "velocity" in n] == []
    assert as_read["velocity_scale"]["scale"][1] is None  # the lateral axis: its velocity as read is mostly noise
    for factor, said_of in (
        ((3.6, 3.6, 3.6), ("along x 0.277x", "along z 0.274x", "km/h?")),
        ((-1, 1, 1), ("along x -1", "wrong sign")),
    ):
        misread = time_offset.estimate(replace(stream, velocity=stream.velocity * np.array(factor)))
        said = [n for n in time_offset.note("riekf", misread) if "the detections say the body moved" in n]
        assert said and all(any(w in n for n in said) for w in said_of), (factor, said)
    # constant motion: a scale is a bias there, so nothing is said of it
    circle = align(expected_streams(simulate("circle", seed=2, duration=20.0)))
    for factor in (1.0, 3.6):
        est = time_offset.estimate(replace(circle, velocity=circle.velocity * factor))
        assert est["velocity_scale"]["scale"] == [None, None, None]


def test_the_written_pose_covariance_after_a_recovery_is_the_filters_own():
    """After a recovery scales the motion noise, the pose covariance written at each row is still the filter's
    (ξ_R, ξ_P) block as its flush makes it (turned to δθ, δp): the bias walks added between flushes are the scaled
    ones the filter itself propagates, not the configured ones (they were, so every written pose covariance after
    a recovery left out part of the bias walks' growth)."""
    from slamobs.pipeline.lie import skew
    from slamobs.pipeline.observers.base import output_rows
    from slamobs.pipeline.observers.riekf import RiEKF

    sim = simulate("figure8", seed=3, duration=DURATION, noise=NoiseModel(gyro=0.5))
    stream = align(expected_streams(sim))
    walks = resolve_noise(NoiseConfig(gyro_bias_walk=0.01, velocity_bias_walk=0.01))
    every = 20
    filt = RiEKF(stream, {}, ObserverOptions(out_every=every), noise=walks)
    filt.cov_rows = np.zeros((output_rows(filt.n_vel, every, 0, filt.n_vel), 12, 12))
    res = filt.advance(filt.n_vel)
    f = res.stats["metadata"]["filter"]
    assert f["status"] == "recovered" and f["noise_factor"] > 10.0
    t_rec = f["recovery_log"][0]["t_s"]
    after = np.flatnonzero((res.t_ns - res.t_ns[0]) * 1e-9 > t_rec + 1.0)
    assert after.size > 50
    widened = f["correlation"]["factors"][-1]  # the detections' correlation in time (tests/test_riekf_correlation.py)
    for k in after[::5]:
        j = np.eye(6)
        j[3:, :3] = -skew(res.position[k])
        expect = widened * (j @ filt.cov_rows[k, :6, :6] @ j.T)
        assert np.allclose(res.pose_cov[k], expect, rtol=1e-9, atol=1e-15), k


def test_a_held_fit_that_makes_the_detections_noiseless_is_named_not_used():
    # MR.CLAM 6 r1 with its bearings negated (mirrored), and a generated figure 8 with its velocities held for ten
    # samples: the held streams' fit gave the detection pairs' whole spread to the motion and scaled the detection
    # law by 1e-6 (σ ~1e-8 m), which riekf and batch used, with no word
    from slamobs.pipeline.noise import estimate_log_noise

    for scenario, mirror in (("figure8", 1.0), ("ground", -1.0)):
        stream = align(expected_streams(simulate(scenario, seed=3, duration=60.0)))
        n = stream.omega.shape[0] // 10 * 10  # commanded velocities: each value held for ten samples
        held = {
            k: np.r_[np.repeat(getattr(stream, k)[:n:10], 10, axis=0), getattr(stream, k)[n:]]
            for k in ("omega", "velocity")
        }
        found = estimate_log_noise(replace(stream, **held, det_y=stream.det_y * np.array([1.0, mirror, 1.0])))
        said = [n for n in found.notes if "put the detections' own error at 1e-06x" in n]
        assert len(said) == 1 and "kept as the triplets measured it" in said[0], (scenario, found.notes)
        assert found.detection.held_scale == 1.0 and 0.003 < found.detection.base.value < 0.03, found.detection


def test_a_turned_camera_extrinsic_is_named_beside_the_velocity():
    # a generated figure 8 whose /tf_static camera extrinsic is turned 90 deg about its z (or given as the inverse
    # transform): riekf APE 0.013 -> 9.1 m (10.7 m), and the only warning said to check the velocity's unit
    from slamobs.pipeline.lie import so3_exp
    from slamobs.pipeline.observers import time_offset

    stream = align(expected_streams(simulate("figure8", seed=2, duration=20.0)))
    turned = stream.det_y @ so3_exp(np.array([0.0, 0.0, np.pi / 2])).T
    said = [n for n in time_offset.note("riekf", time_offset.estimate(replace(stream, det_y=turned))) if "moved" in n]
    assert said and all("frame's extrinsic: a camera turned" in n for n in said), said


@pytest.mark.parametrize("scenario", ["figure8", "ground"])
def test_a_twist_in_a_world_frame_is_named_as_such(scenario):
    # the odometry's twist in the truth's world frame (a frame its poses do not share, so the reader does not turn
    # it): riekf APE 1.85 m on a figure 8, and the only warnings named the velocity's scale on x and y ("check the
    # velocity's unit and axes"); turned into the body by the dead-reckoned heading it fits the pairs 14-84x better
    from slamobs.pipeline.lie import quats_to_rots
    from slamobs.pipeline.observers import time_offset

    sim = simulate(scenario, seed=2, duration=30.0)
    assert time_offset.note("riekf", time_offset.estimate(align(expected_streams(sim)))) == []
    m, o = sim.mocap, sim.odom
    near = np.clip(np.searchsorted(m.t_ns, o.t_ns), 0, m.t_ns.size - 1)
    world = np.einsum("nij,nj->ni", quats_to_rots(m.quat_xyzw[near]), o.linear)
    offset = time_offset.estimate(align(expected_streams(replace(sim, odom=replace(o, linear=world)))))
    for said in (time_offset.note("riekf", offset), time_offset.note(None, offset)):  # a run, `info --noise`
        assert len(said) == 1 and "twist looks like it is in a world frame, not the body's" in said[0], said
        assert "child_frame_id" in said[0]


def test_a_ground_robots_axes_that_do_not_move_get_no_velocity_scale():
    # wheel slip (a velocity bias wandering 0.02 m/s on every axis, as `unseen_logs.py`'s ground logs) gives the
    # ground robot's y and z a velocity as read that is only noise; their scale, fitted ~0 (the detections see no
    # motion there), was named as a misread unit ("along y 0.0191x ... in another unit or scale?") on every seed
    from slamobs.pipeline.observers import time_offset

    stream = align(
        expected_streams(simulate("ground", seed=1, duration=60.0, noise=NoiseModel(odom_linear_drift=0.02)))
    )
    est = time_offset.estimate(stream)
    assert est["velocity_scale"]["scale"][0] == pytest.approx(1.0, abs=0.1)
    assert est["velocity_scale"]["scale"][1:] == [None, None]
    assert time_offset.note("riekf", est) == []
    # the axis that moves is still measured: the velocity in cm/s is named
    said = time_offset.note("riekf", time_offset.estimate(replace(stream, velocity=stream.velocity * 100.0)))
    assert len(said) == 1 and "along x" in said[0] and "cm/s?" in said[0], said


def test_a_very_noisy_velocity_is_not_named_as_scaled_and_a_real_scale_still_is():
    # velocity noise x300 the simulator's (6 m/s per sample at 50 Hz) on a clean figure 8: the noise in the velocity's
    # own displacement pulled the fitted scale toward 0 and it was named ("along x 0.206x as far as its velocity
    # says ... in another unit or scale?", docs/benchmarks.md "Generated logs nobody tuned on"); with the recorded
    # density on the stream (run.prepare_log) the dilution is taken off, or the axis left unsaid where it dominates
    from slamobs.pipeline.noise import stream_density
    from slamobs.pipeline.observers import time_offset

    def stream_of(times: float, scale: float):
        ls = expected_streams(simulate("figure8", seed=2101, duration=20.0, noise=NoiseModel(odom_linear=0.02 * times)))
        lv = ls.linear_velocity
        ls = replace(ls, linear_velocity=replace(lv, xyz=lv.xyz / scale))  # the detections say `scale` x as far
        density = np.resize(np.asarray(stream_density(lv.t_ns, lv.xyz / scale).value, float), 3)
        return replace(align(ls, keep_directions=False), velocity_density=density)

    noisy = time_offset.estimate(stream_of(300.0, 1.0))
    assert time_offset.note("riekf", noisy) == []
    assert max(noisy["velocity_scale"]["dilution"]) > time_offset.MAX_SCALE_DILUTION
    # the dilution taken off is an upper bound (the level is), so an axis is named only where its scale as fitted is
    # off too: at x100 a true 2x is fitted 1.50 (read 2.18) and left unsaid, a true 3x fitted 2.24, read 3.27, named
    scaled = time_offset.estimate(stream_of(100.0, 3.0))
    said = [n for n in time_offset.note("riekf", scaled) if "the detections say the body moved" in n]
    assert len(said) == 1 and "along x" in said[0], said
    assert scaled["velocity_scale"]["scale"][0] == pytest.approx(3.0, abs=0.4)


def test_one_axis_level_of_unresolved_motion_does_not_scale_the_others():
    # a 5 Hz hand-held odometry (benchmarks/handheld_logs.py seed=3347): its vertical samples' level is a bob the rate
    # does not resolve, 8x the white level; the axes' mean level diluted x by 0.49 and its scale, as fitted 0.976,
    # was read "along x 1.92x as far as its velocity says" (the simulator scaled nothing). Here a clean figure 8 is
    # told a vertical level 180x its own (x's mean dilution 0.42): each axis's scale takes its own level off
    from slamobs.pipeline.noise import stream_density
    from slamobs.pipeline.observers import time_offset

    ls = expected_streams(simulate("figure8", seed=2101, duration=20.0))
    lv = ls.linear_velocity
    level = np.resize(np.asarray(stream_density(lv.t_ns, lv.xyz).value, float), 3) * np.array([1.0, 1.0, 180.0])

    def estimate(scale: float) -> dict:  # the detections say `scale` x as far as the velocity
        scaled = replace(ls, linear_velocity=replace(lv, xyz=lv.xyz / scale))
        return time_offset.estimate(replace(align(scaled, keep_directions=False), velocity_density=level / scale))

    clean = estimate(1.0)
    assert clean["velocity_scale"]["scale"][0] == pytest.approx(1.0, abs=0.02)
    assert [n for n in time_offset.note("riekf", clean) if "the detections say the body moved" in n] == []
    said = [n for n in time_offset.note("riekf", estimate(2.0)) if "the detections say the body moved" in n]
    assert len(said) == 1 and "along x 2" in said[0], said  # a true scale is still named


def test_an_odometry_stamped_late_against_the_gyro_is_named():
    # the odometry stamped with its record time (80-90 ms late) while the IMU and the detections use header stamps:
    # riekf 0.038 m against 0.011 clean on a figure 8 and only an "overconfident" note; the detection pairs' time
    # offset (against both velocity streams at once) is 0.008 s and not applied. Read 80-90 ms earlier, the
    # velocity fits the pairs better than as stamped, which the time offset now names (a ground robot's steady
    # motion does not show it: 1.005x, not named; nor is anything on the clean logs)
    from slamobs.pipeline.observers import time_offset

    ground = time_offset.estimate(align(expected_streams(simulate("ground", seed=2, duration=30.0))))
    assert time_offset.note("riekf", ground) == []
    sim = simulate("figure8", seed=2, duration=30.0)
    clean = time_offset.estimate(align(expected_streams(sim)))
    assert time_offset.note("riekf", clean) == [] and clean["velocity_lag"]["gain"] < 1.05, clean["velocity_lag"]
    o = sim.odom
    late = np.maximum.accumulate(o.t_ns + 80_000_000 + np.random.default_rng(0).integers(0, 10_000_000, o.t_ns.size))
    streams = expected_streams(replace(sim, odom=replace(o, t_ns=late, rec_ns=late)))
    # with the odometry's own angular velocity the alignment finds the lag against the gyro and moves the IMU onto
    # the odometry's clock (session 27): one clock for both velocities, the detections moved onto it by the pairs
    both = align(streams)
    assert any("stamps look 0.08" in n and "The run moved its stamps by +0.08" in n for n in both.notes), both.notes
    on_one = time_offset.estimate(both)
    assert on_one["applied"] and 0.07 < on_one["estimate_s"] < 0.1 and on_one["velocity_lag"]["gain"] < 1.05
    # ... by as much as the IMU was moved: the IMU and the detections agree as stamped, so the warning names the
    # odometry as the late stream (session 28: it named the IMU only), and the estimate is not called lost
    (said,) = [n for n in time_offset.note("riekf", on_one) if "warning" in n]
    assert "the odometry is the stream stamped 0.08" in said and "s late, not the IMU" in said, said
    assert "time.topics: {/odom: record}" in said and not time_offset.misread(on_one)
    # an IMU stamped late (the detections on the odometry's clock): moved, and nothing said of the odometry
    imu = replace(sim.imu, t_ns=sim.imu.t_ns + 85_000_000, rec_ns=sim.imu.rec_ns + 85_000_000)
    imu_late = time_offset.estimate(align(expected_streams(replace(sim, imu=imu))))
    assert not imu_late["applied"] and time_offset.note("riekf", imu_late) == [], imu_late
    # an odometry that gives its linear velocity only: the pairs' velocity lag names it
    streams = expected_streams(replace(sim, odom=replace(o, t_ns=late, rec_ns=late)))
    streams.twist_angular = None
    offset = time_offset.estimate(align(streams))
    assert 0.07 < offset["velocity_lag"]["lag_s"] < 0.1, offset["velocity_lag"]
    for said in (time_offset.note("riekf", offset), time_offset.note(None, offset)):  # a run, `info --noise`
        assert len(said) == 1 and "linear velocity's stamps look 0.0" in said[0] and "s late against" in said[0], said


def test_a_long_log_s_velocity_lag_is_searched_on_its_first_samples(monkeypatch):
    """The lag search's 21 dead reckonings of the whole one-hour log cost 1.5 CPU s and made riekf's filter stage
    1.67 -> 2.5 s wall (session 18): past ``PREFIX_SAMPLES`` samples it searches the log's first that many.
    Here the bound is lowered to half this log: the lag is still found, on the prefix's pairs only."""
    from slamobs.pipeline.observers import time_offset

    sim = simulate("figure8", seed=2, duration=30.0)
    o = sim.odom
    late = np.maximum.accumulate(o.t_ns + 80_000_000 + np.random.default_rng(0).integers(0, 10_000_000, o.t_ns.size))
    streams = expected_streams(replace(sim, odom=replace(o, t_ns=late, rec_ns=late)))
    streams.twist_angular = None  # linear velocity only: the lag is the pairs' to find, not the alignment's
    stream = align(streams)
    monkeypatch.setattr(time_offset, "PREFIX_SAMPLES", stream.vel_t_ns.shape[0] // 2)
    seen = []
    monkeypatch.setattr(
        time_offset, "velocity_lag", lambda c, shift, f=time_offset.velocity_lag: seen.append(c) or f(c, shift)
    )
    offset = time_offset.estimate(stream)
    assert 0.07 < offset["velocity_lag"]["lag_s"] < 0.1, offset["velocity_lag"]
    assert seen[0].stream.vel_t_ns.shape[0] <= stream.vel_t_ns.shape[0] // 2 + 1
    assert seen[0].a.shape[0] < offset["pairs"]


def test_a_long_log_s_pairs_come_from_stretches_of_it_whose_samples_alone_are_read(monkeypatch):
    """The estimate dead-reckoned the whole one-hour log (720,000 samples, over and over for the bias Jacobian and
    the checks: 1.1 CPU s beside riekf's filter) for 2,000 pairs of 1-2 s each: on a log of more than
    ``MAX_PAIRS`` pairs it takes them from ``BLOCKS`` stretches spread over the log and reads those samples only
    (docs/benchmarks.md, "The time offset's cost, session 21"). Each pair's residuals are the whole log's dead
    reckoning's (to rounding: only the motion inside the pair enters), and a known offset is still found and
    applied. Here the stretches are fewer and shorter, so that a 60 s log has them."""
    from slamobs.pipeline.observers import time_offset

    monkeypatch.setattr(time_offset, "BLOCKS", 4)
    monkeypatch.setattr(time_offset, "MAX_PAIRS", 500)
    monkeypatch.setattr(time_offset, "WORLD_TWIST_WINDOW_S", 4.0)
    stream = align(expected_streams(simulate("figure8", seed=2, duration=60.0, detection_offset=0.1)))
    c = time_offset.Consistency(stream, np.zeros(6))
    assert c.a.shape[0] == 500 and 2 * c.stream.vel_t_ns.shape[0] < stream.vel_t_ns.shape[0]
    assert c.stream.segment_starts.shape[0] == 3  # four stretches, each dead-reckoned on its own
    whole = c.varied(stream=stream)
    whole.poses = whole._poses(c.bias)
    shifts = np.array([-0.52, -0.1, 0.0, 0.1, 0.52])
    np.testing.assert_allclose(c.residuals(shifts), whole.residuals(shifts), rtol=0, atol=1e-9)
    est = time_offset.estimate(stream)
    assert est["pairs"] == 500 and est["applied"] and abs(est["estimate_s"] + 0.1) < OFFSET_TOLERANCE_S, est


def test_a_long_log_s_gyro_misreads_are_tested_on_its_first_samples(monkeypatch):
    """The misreads' four dead reckonings of the whole one-hour log cost 0.27 CPU s beside riekf's filter (stage
    1.67 -> 1.75-1.84 s, session 19): past ``PREFIX_SAMPLES`` samples they read the log's first that many. Here the
    bound is lowered to half a log whose gyro x and z are swapped: the swap is still named, from the prefix's pairs."""
    from slamobs.pipeline.observers import time_offset

    sim = simulate("figure8", seed=5, duration=30.0)
    swapped = replace(sim, imu=replace(sim.imu, gyro=sim.imu.gyro[:, [2, 1, 0]].copy()))
    stream = align(expected_streams(swapped))
    monkeypatch.setattr(time_offset, "PREFIX_SAMPLES", stream.vel_t_ns.shape[0] // 2)
    seen = []
    monkeypatch.setattr(time_offset, "gyro_misreads", lambda c, f=time_offset.gyro_misreads: seen.append(c) or f(c))
    offset = time_offset.estimate(stream)
    assert offset["gyro_misreads"]["with its angular velocity's x and z swapped"] >= time_offset.GYRO_MISREAD_GAIN
    assert seen[0].stream.vel_t_ns.shape[0] <= stream.vel_t_ns.shape[0] // 2 + 1
    assert seen[0].a.shape[0] < offset["pairs"]


def test_the_pairs_gyro_misread_names_the_alignments_turned_gyro_only_when_it_undoes_that_turn():
    """A gyro whose yaw rate the alignment found on y (an IMU rolled 90 deg taken as the body): the detection pairs'
    "y and z swapped" undoes that turn, so its warning names the turned-gyro warning instead of a cause of its own,
    and the velocity scale read along that heading says so. A turn the swap does not undo (yaw on x), or none: the
    misread's own words."""
    from slamobs.pipeline.observers import time_offset

    offset = {
        "pairs": 2000,
        "applied": False,
        "topics": {"angular_velocity": "/imu/data", "linear_velocity": "/odom"},
        "gyro_misreads": {"with its angular velocity's y and z swapped": 35.9, time_offset.SIGN_FLIPPED: 0.5},
        "velocity_scale": {"scale": [2.35, 1.0, 1.0], "sigma": [0.1, 0.1, 0.1]},
        "gyro_turn": {
            "topic": "/imu/data",
            "frame": "imu_link",
            "gyro_axis": [0.01, 1.0, -0.01],
            "odometry_axis": [0.0, 0.01, 1.0],
            "angle_deg": 90.0,
            "misfit": 0.012,
            "span_s": 40.0,
        },
    }
    gyro, scale = time_offset.note("riekf", offset)
    assert "35.9x better with its angular velocity's y and z swapped" in gyro, gyro
    assert "the same turn the warning on /imu/data's gyro measures (90 deg" in gyro, gyro
    assert "a swap of two axes is the nearest misread tried" in gyro, gyro
    assert "record the transform of 'imu_link' on /tf_static" in gyro and "check the gyro's unit" not in gyro, gyro
    assert "along x 2.35x" in scale and "the turned gyro upsets this reading too" in scale, scale
    other = {**offset["gyro_turn"], "gyro_axis": [1.0, 0.0, 0.0]}  # a yaw on x: y and z swapped leaves it on x
    for turn in (other, None):
        gyro, scale = time_offset.note("riekf", {**offset, "gyro_turn": turn})
        assert "check the gyro's unit and axes" in gyro and "the same turn" not in gyro, gyro
        assert "upsets" not in scale, scale
    # an IMU upside down taken as the body (session 30): its gyro turns the other way, which the sign flip undoes;
    # the warning named "a swap of two axes" as the nearest misread
    upside = {**offset["gyro_turn"], "gyro_axis": [0.01, -0.01, -1.0], "odometry_axis": [0.0, 0.01, 1.0]}
    flipped = {"with its angular velocity's y and z swapped": 0.5, time_offset.SIGN_FLIPPED: 103.0}
    gyro, _ = time_offset.note("riekf", {**offset, "gyro_misreads": flipped, "gyro_turn": {**upside, "angle_deg": 179}})
    assert "the same turn the warning on /imu/data's gyro measures (179 deg" in gyro, gyro
    assert "the sign flip is the nearest misread tried" in gyro and "swap" not in gyro, gyro


def test_an_odometry_twist_beside_the_body_that_no_tf_gives_is_named_as_a_lever_arm():
    # the twist of a point 0.5 m beside the body given as the body's (child_frame_id the base, no TF of the arm):
    # riekf 0.170 m against 0.011 on a figure 8, fast-adaptation 0.158 against 0.119, with notes of wheel slip only
    # (session 27); the pairs fit the arm as a velocity v + ω × r (session 28)
    from slamobs.pipeline.observers import time_offset

    sim = simulate("figure8", seed=2, duration=30.0)
    clean = time_offset.estimate(align(expected_streams(sim)))
    assert np.linalg.norm(clean["lever_arm"]["r_m"]) < 0.03 and time_offset.note("riekf", clean) == []
    o = sim.odom
    beside = replace(o, linear=o.linear + np.cross(o.angular, [0.0, 0.5, 0.0]))
    offset = time_offset.estimate(align(expected_streams(replace(sim, odom=beside))))
    assert offset["lever_arm"]["r_m"][1] == pytest.approx(0.5, abs=0.03), offset["lever_arm"]
    for said in (time_offset.note("riekf", offset), time_offset.note(None, offset)):  # a run, `info --noise`
        assert len(said) == 1 and "as the velocity of a point (" in said[0] and "a lever arm no TF gives" in said[0]
        assert "stated position off by that same translation (stated minus true)" in said[0], said
    assert not time_offset.misread(offset)  # the estimate is whole, on another point: landmark jumps still split


def _walker(scale: float):
    """A walker's figure 8 (``figure8-wide``'s landmarks, 8 x 4 m, 1.5 m high, heading along the path) with a 1.8 Hz
    step bob of 4 cm, its odometry's twist divided by ``scale`` (the detections then say ``scale`` x as far)."""
    from slamobs.pipeline.simulate.scenarios import Trajectory, get_scenario, rot_z

    w, a, fb = 2 * np.pi / 60.0, 8.0, 2 * np.pi * 1.8

    def trajectory(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        th = w * t
        xd, xdd = a * w * np.cos(th), -a * w * w * np.sin(th)
        yd, ydd = a * w * np.cos(2 * th), -2 * a * w * w * np.sin(2 * th)
        z, zd, zdd = 1.5 + 0.04 * np.sin(fb * t), 0.04 * fb * np.cos(fb * t), -0.04 * fb * fb * np.sin(fb * t)
        rot = rot_z(np.arctan2(yd, xd))
        yaw_rate = (xd * ydd - yd * xdd) / (xd * xd + yd * yd)
        v = np.einsum("nji,nj->ni", rot, np.stack([xd, yd, zd], -1)) / scale
        pos = np.stack([a * np.sin(th), a / 2 * np.sin(2 * th), z], -1)
        omega = np.stack([np.zeros_like(t), np.zeros_like(t), yaw_rate], -1)
        return Trajectory(t, rot, pos, omega, v, np.stack([xdd, ydd, zdd], -1))

    return replace(get_scenario("figure8-wide"), name="walker", trajectory=trajectory)


def test_a_slow_hand_held_odometrys_velocity_scale_is_named_and_its_twin_as_recorded_is_not(tmp_path):
    # a hand-held rig's 4 Hz twist (benchmarks/handheld_logs.py): its vertical samples' level is the step bob the rate
    # does not resolve (15x the white level); pooled into the axes' mean it diluted x over MAX_SCALE_DILUTION and the
    # check stood down on every axis, so a velocity 2x off went unsaid (seed=3345: nothing at 1.5x, 2x or km/h). The
    # mean is now pooled from the white levels (the pairs' on the folded axis); the unscaled twin says nothing
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.observers import time_offset
    from slamobs.pipeline.run import prepare_log
    from slamobs.pipeline.simulate import write_log

    def said(scale: float, late: float = 0.0) -> list[str]:
        nm = NoiseModel(odom_linear=0.03 * np.sqrt(4.0), gyro=0.01 * np.sqrt(200.0))
        kw = dict(duration=90.0, seed=3370, imu_rate=200.0, odom_rate=4.0, detection_offset=late)
        sim = simulate(_walker(scale), noise=nm, **kw)
        log = tmp_path / f"walker-{scale:g}-{late:g}.mcap"
        write_log(sim, log, overwrite=True)
        prepared = prepare_log(log, load_config(None))
        assert "from the means of sample pairs" in prepared.velocity_noise.method  # its z folded
        assert prepared.aligned.gyro_moved_s == 0.0  # no lag drawn (session 36: moved -0.065 s on noise)
        offset = time_offset.estimate(prepared.aligned)
        # the 0.3 s found (within 0.04 s); applied, or held back as its halves disagree on this 4 Hz twist (-0.262
        # and -0.314 s: applied at -0.326 s only while the gyro was moved 0.065 s on noise, before session 36)
        assert abs(offset["estimate_s"] + late) < 0.04, offset
        assert offset["applied"] == (late != 0.0) or "halves disagree" in offset["why_not_applied"], offset
        return [n for n in time_offset.note("riekf", offset) if "the detections say the body moved" in n]

    assert said(1.0) == []
    (named,) = said(2.0)
    assert "along x 2" in named, named
    # its detections stamped 0.3 s late: the scale is fitted at the applied offset (at zero shift the lateral axis of
    # handheld_logs.py's such logs read -17x to 19x), still silent as recorded and naming a true 2x
    assert said(1.0, 0.3) == []
    assert any("along x 2" in n for n in said(2.0, 0.3)), said(2.0, 0.3)


def test_a_hand_held_rig_with_imu_and_twist_at_4_hz_names_no_lateral_scale_and_a_km_h_velocity_still_is(tmp_path):
    # benchmarks/handheld_logs.py's rig with its gyro at 4 Hz too: the detection search finds its own lag (0.125 s:
    # its dead reckoning holds each sample until the next), which held the offset back, and the velocity-scale check
    # read the pairs at zero shift, half an interval late: "along y 11.6x ... (in another unit or scale?)" on this
    # velocity in m/s (seed=9957 at session 33: 10.9x). The checks now read the pairs at the search's shift there
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.observers import time_offset
    from slamobs.pipeline.run import prepare_log
    from slamobs.pipeline.simulate import write_log
    from slamobs.pipeline.simulate.scenarios import handheld

    nm = NoiseModel(gyro=30 * DEFAULTS["gyro"][0] * 2.0, odom_linear=10 * DEFAULTS["velocity"][0] * 2.0)  # at 4 Hz
    sim = simulate(handheld(), noise=nm, duration=60.0, seed=3635, imu_rate=4.0, odom_rate=4.0)

    def said(unit: float) -> list[str]:
        read = replace(sim, odom=replace(sim.odom, linear=sim.odom.linear * unit))
        log = write_log(read, tmp_path / f"{unit:g}.mcap")
        offset = time_offset.estimate(prepare_log(log, load_config(None)).aligned)
        assert offset["why_not_applied"].startswith("within the search's own lag"), offset.get("why_not_applied")
        return [n for n in time_offset.note(None, offset) if "the detections say the body moved" in n]

    assert said(1.0) == []
    (named,) = said(3.6)  # the velocity in km/h: x named as such, y not named with it
    assert "along x 0.2" in named and "in km/h?" in named and "along y" not in named, named


def test_an_odometry_thinned_at_random_is_not_named_in_km_h_and_in_km_h_it_still_is(tmp_path):
    # seed=4392 of benchmarks/handheld_logs.py's round 10 (docs/benchmarks.md, "Logs nobody has run yet, round 10"):
    # a ground robot's 10 Hz odometry with 70 % of its messages lost at random (gaps up to 2.3 s). Interpolated across
    # its gaps, the velocity holds its noise there, which gave the lateral axis a "motion" fitted at 0.164: "along y
    # 0.276x as far as its velocity says (± 0.056: in km/h?)" on a velocity in m/s. Only the pairs whose span the
    # samples cover are fitted now; the same thinned twist in km/h is still named so
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.observers import time_offset
    from slamobs.pipeline.run import prepare_log
    from slamobs.pipeline.simulate import write_log

    nm = NoiseModel(
        gyro=30 * DEFAULTS["gyro"][0] * np.sqrt(200.0),
        odom_linear=10 * DEFAULTS["velocity"][0] * np.sqrt(10.0),
        detection_base=0.03,
        detection_per_m=0.006,
    )
    kw = dict(duration=180.0, seed=4392, imu_rate=200.0, odom_rate=10.0, detection_rate=15.0)
    sim = simulate("ground", noise=nm, **kw)
    rows = np.random.default_rng(4392 + 19).random(sim.odom.t_ns.shape[0]) < 0.3
    odom = replace(sim.odom, **{f: getattr(sim.odom, f)[rows] for f in sim.odom.__dataclass_fields__})

    def said(unit: float) -> list[str]:
        log = write_log(replace(sim, odom=replace(odom, linear=odom.linear * unit)), tmp_path / f"{unit:g}.mcap")
        offset = time_offset.estimate(prepare_log(log, load_config(None)).aligned)
        return [n for n in time_offset.note(None, offset) if "the detections say the body moved" in n]

    assert said(1.0) == []
    (named,) = said(3.6)
    assert "along x 0.2" in named and "in km/h?" in named and "along y" not in named, named


@pytest.mark.parametrize("scenario", ["handheld", "ground"])
def test_a_twist_turned_from_the_body_is_named(scenario):
    # generated logs whose odometry's twist is turned 180 deg about z (a robot driving "backwards"; docs/benchmarks.md,
    # "Logs nobody has run yet, round 7"): on the hand-held rig the pairs named a twist in a world frame (7.55x,
    # riekf APE 2.6 m), on the ground robot only the camera's extrinsic, which on planar motion fits alike
    from slamobs.pipeline.observers import time_offset
    from slamobs.pipeline.simulate.scenarios import handheld, rot_z

    sim = simulate(handheld() if scenario == "handheld" else scenario, seed=2, duration=30.0)
    stream = align(expected_streams(sim))
    assert [n for n in time_offset.note("riekf", time_offset.estimate(stream)) if "turned" in n] == []
    turn = rot_z(np.array([np.pi]))[0]
    record = time_offset.estimate(replace(stream, velocity=stream.velocity @ turn.T))
    said = [n for n in time_offset.note("riekf", record) if "turned" in n]
    assert len(said) == 1 and "twist" in said[0], said
    assert not any("world frame" in n for n in time_offset.note("riekf", record)), said
    if scenario == "handheld":  # the twist's turn alone, its axis named; the camera not
        assert "with its twist turned by 180 deg about the body's z" in said[0], said
        assert "camera" not in said[0] and record["camera_turned"] is False, said
