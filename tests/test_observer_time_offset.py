"""The observers' detection time offset (session 33): decided by the reference estimators' rule before the observer
starts (``ObserverSpec._started``, ``time_offset.decide``), applied where reliable, said in the notes and in run.json
``observer.time_offset``; an offset only the halves' check held back is warned of (``time_offset.unapplied_note``)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pyarrow.parquet as pq
import pytest

from slamobs.pipeline.alignment import align, held_stamps
from slamobs.pipeline.api import run_log
from slamobs.pipeline.observers import time_offset
from slamobs.pipeline.simulate import expected_streams, simulate
from slamobs.pipeline.simulate.logwriter import write_log
from cli_checks import invoke
from noisy_logs import rig_noise

LATE_S = 0.3


def _run(tmp_path, observer: str, late: float) -> tuple[dict, float]:
    log = write_log(simulate("figure8", seed=3438, duration=60.0, detection_offset=late), tmp_path / f"l{late:g}.mcap")
    out = tmp_path / f"{observer}-{late:g}"
    run_log(log, out, config={"observer": observer, "evaluation": {"plots": False}})
    report = json.loads((out / "report.json").read_text())
    return json.loads((out / "run.json").read_text()), report["ape"]["translation_m"]["rmse"]


@pytest.mark.parametrize("observer", ["fast-adaptation", "hashim"])
def test_an_observer_moves_detections_stamped_late_and_its_twin_on_time_moves_nothing(tmp_path, observer):
    # seed=3438's figure 8, its detections stamped LATE_S late: fast-adaptation was 0.634 m against 0.053 on its twin
    # on time, with no word; now the stamps are moved as riekf's are, the APE near the twin's, and a note says so
    late, late_ape = _run(tmp_path, observer, LATE_S)
    twin, twin_ape = _run(tmp_path, observer, 0.0)
    offset = late["observer"]["time_offset"]
    assert offset["applied"] and abs(offset["estimate_s"] + LATE_S) < 0.02, offset
    assert late["output"]["clock"]["detections_moved_s"] == offset["estimate_s"]
    assert any(n.startswith(f"{observer}: detection stamps moved by -0.") for n in late["notes"]), late["notes"]
    assert late_ape < 1.5 * twin_ape, (late_ape, twin_ape)
    assert not twin["observer"]["time_offset"]["applied"]
    assert twin["output"]["clock"]["detections_moved_s"] == 0.0
    assert not [n for n in twin["notes"] if "detection stamps" in n], twin["notes"]


def test_an_offset_the_halves_held_back_is_warned_of_and_none_is_not():
    # the detections on time for the first half, LATE_S late after it (a camera clock that stepped): the search finds
    # an offset clear of zero that the halves' check holds back; the warning names what was found and why not
    stream = align(expected_streams(simulate("figure8", seed=3439, duration=60.0)))
    t = stream.det_t_ns
    stepped = replace(stream, det_t_ns=t + np.where(t > np.median(t), int(LATE_S * 1e9), 0))
    offset = time_offset.decide(stepped)
    assert not offset["applied"] and offset["why_not_applied"].startswith(time_offset.HALVES_DISAGREE)
    (warning,) = time_offset.unapplied_note("fast-adaptation", offset)
    assert warning.startswith("warning: fast-adaptation: the detection stamps look") and "late" in warning
    assert time_offset.note("fast-adaptation", offset) == [warning]  # the one note every estimator makes
    on_time = time_offset.decide(stream)
    assert not on_time["applied"] and time_offset.unapplied_note("fast-adaptation", on_time) == []


def _stepped_log(path):
    """seed=3439's figure 8 written with its detections LATE_S late from mid-log (a camera clock that stepped)."""
    sim = simulate("figure8", seed=3439, duration=60.0)
    d = sim.detections
    step = np.where(d.t_ns > np.median(d.t_ns), int(LATE_S * 1e9), 0)
    return write_log(replace(sim, detections=replace(d, t_ns=d.t_ns + step, rec_ns=d.rec_ns + step)), path)


@pytest.mark.parametrize("estimator", ["riekf", "batch"])
def test_the_reference_estimators_warn_of_an_offset_the_halves_held_back_in_the_observers_words(tmp_path, estimator):
    # seed=3439's figure 8 written with its detections LATE_S late from mid-log: riekf and batch decide by the
    # observers' rule and held the offset back as they do, but only the observers said so (session 33)
    log = _stepped_log(tmp_path / "s.mcap")
    run_log(log, tmp_path / estimator, config={"observer": estimator, "evaluation": {"plots": False}})
    run = json.loads((tmp_path / estimator / "run.json").read_text())
    offset = run["observer"]["time_offset"]
    assert not offset["applied"] and offset["why_not_applied"].startswith(time_offset.HALVES_DISAGREE)
    said = [n for n in run["notes"] if "detection stamps look" in n]
    assert said == time_offset.unapplied_note(estimator, offset), run["notes"]
    assert said[0].startswith(f"warning: {estimator}: the detection stamps look 0.")


def test_info_noise_warns_of_an_offset_the_halves_held_back_in_the_runs_words(tmp_path):
    # `slamobs info --noise` printed the detection pairs' misread warnings but not the held-back offset's that every
    # run gives (session 34): now the same sentence, without an estimator's name (time_offset.note(None, ...))
    log = _stepped_log(tmp_path / "s.mcap")
    said = [x.strip() for x in invoke("info", "--noise", log).output.splitlines() if "detection stamps look" in x]
    assert len(said) == 1 and said[0].startswith("warning: the detection stamps look 0."), said
    assert f"not applied: {time_offset.HALVES_DISAGREE}" in said[0] and "every estimator applies" in said[0], said


def test_decide_is_the_estimates_decision_without_its_reporting_checks():
    # one rule written once: the observers' decision is the reference estimators' (the same fields, the same values)
    stream = align(expected_streams(simulate("figure8", seed=3440, duration=30.0, detection_offset=-0.2)))
    decided, estimated = time_offset.decide(stream), time_offset.estimate(stream)
    assert decided["applied"] and decided == {k: estimated[k] for k in decided}
    assert "gyro_misreads" not in decided and "gyro_misreads" in estimated


def test_decide_on_a_stream_without_detections_applies_nothing():
    # a time window can hold no detection: the observer still starts (nothing paired, nothing searched)
    stream = align(expected_streams(simulate("figure8", seed=3441, duration=10.0)))
    none = replace(stream, det_t_ns=stream.det_t_ns[:0], det_offsets=stream.det_offsets[:1], det_idx=stream.det_idx[:0])
    offset = time_offset.decide(replace(none, det_y=stream.det_y[:0]))
    assert offset["pairs"] == 0 and not offset["applied"] and time_offset.note("fast-adaptation", offset) == []


def test_the_lever_arm_and_velocity_scale_at_an_applied_offset_are_those_of_the_stamps_it_corrects():
    # the checks at the applied shift read the pairs as the corrected stamps do at none, bias Jacobian included
    # (Consistency.at_shift): the lever arm took the zero shift's, y 0.0181 ± 0.0026 m there against 0.0017 on the
    # corrected stamps (seed=3471, detections 0.3 s late), where the velocity scale already agreed
    stream = align(expected_streams(simulate("figure8", seed=3471, duration=30.0, detection_offset=LATE_S)))
    late = time_offset.estimate(stream)
    corrected = time_offset.estimate(time_offset.shifted(stream, late))
    assert late["applied"] and not corrected["applied"]
    for check in ("lever_arm", "velocity_scale"):
        for key, value in late[check].items():
            if isinstance(value, dict):  # the scales fitted with the arm (velocity_scale's with_arm)
                for k, v in value.items():
                    np.testing.assert_allclose(np.array(v, float), np.array(corrected[check][key][k], float), atol=1e-9)
                continue
            np.testing.assert_allclose(np.array(value, float), np.array(corrected[check][key], float), atol=1e-9)


@pytest.mark.parametrize(("early", "applied"), [(0.0, False), (0.1, True)])
def test_a_4_hz_rig_whose_twist_reads_half_applies_no_offset_it_lacks_and_keeps_one_it_has(early, applied):
    # benchmarks/handheld_logs.py's rig with IMU and twist at 4 Hz, the twist read x0.5 (the detections see twice its
    # motion): the search's own lag (0.125 s) plus the scale's pull on it, +0.133 s, was past the lag's 5 standard
    # errors and applied though the detections are on time; it fits only 1.08x better than the lag itself, the gain
    # the same misread shows against zero on a 200 Hz rig, so it is held back. Detections 0.1 s early: still applied
    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import NoiseModel
    from slamobs.pipeline.simulate.scenarios import handheld

    nm = NoiseModel(gyro=30 * DEFAULTS["gyro"][0] * 2.0, odom_linear=10 * DEFAULTS["velocity"][0] * 2.0)  # at 4 Hz
    sim = simulate(handheld(), noise=nm, duration=60.0, seed=3635, imu_rate=4.0, odom_rate=4.0, detection_offset=-early)
    stream = align(expected_streams(sim))
    offset = time_offset.decide(replace(stream, velocity=0.5 * stream.velocity))
    lag = time_offset.hold_lag(stream)
    assert offset["applied"] == applied, offset
    assert abs(offset["estimate_s"] - (early + lag)) < 0.02, offset  # the search reads a true offset plus its lag
    if not applied:
        assert "better than the search's own lag" in offset["why_not_applied"], offset


def test_detections_on_the_imu_clock_beside_an_odometry_half_a_second_off_are_found():
    # a generated hand-held rig whose odometry's stamps are 0.5 s off the IMU's and the detections' (docs/benchmarks.md,
    # "Logs nobody has run yet, round 7"): the alignment moves the IMU's stamps +0.5 s onto the odometry's clock, and
    # the detections' +0.503 s was held back at the search's edge (±0.5 s): riekf lost at 14.6 m, its warnings blaming
    # the detections' scale. The search reaches past the IMU's move: applied, and the odometry named as the stream off
    from dataclasses import replace

    from slamobs.pipeline.alignment import align
    from slamobs.pipeline.observers import time_offset
    from slamobs.pipeline.simulate import expected_streams, simulate
    from slamobs.pipeline.simulate.scenarios import handheld

    sim = simulate(handheld(), seed=2, duration=30.0, imu_rate=200.0, odom_rate=10.0)
    late = replace(sim, odom=replace(sim.odom, t_ns=sim.odom.t_ns + 500_000_000))
    stream = align(expected_streams(late))
    assert abs(stream.gyro_moved_s - 0.5) < 0.01
    record = time_offset.estimate(stream)
    assert record["applied"] and abs(record["estimate_s"] - 0.5) < 0.01, record
    said = time_offset.note("riekf", record)
    assert any("so the odometry is the stream stamped 0.500 s late" in n for n in said), said
    assert not any("scale" in n for n in said), said


def _odometry_log(tmp_path, sampling: str, early: float = 0.0):
    """benchmarks/handheld_logs.py's rig with IMU and odometry at 4 Hz, each sample instantaneous or the mean over
    the interval before its stamp (``simulate(sampling=...)``), the detections ``early`` s early."""
    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import NoiseModel
    from slamobs.pipeline.simulate.scenarios import handheld

    nm = NoiseModel(gyro=30 * DEFAULTS["gyro"][0] * 2.0, odom_linear=10 * DEFAULTS["velocity"][0] * 2.0)  # at 4 Hz
    sim = simulate(
        handheld(),
        noise=nm,
        duration=60.0,
        seed=3928,
        imu_rate=4.0,
        odom_rate=4.0,
        detection_offset=-early,
        sampling=sampling,
    )
    return sim, write_log(sim, tmp_path / f"{sampling}{early:g}.mcap")


@pytest.mark.parametrize(("early", "applied"), [(0.0, False), (0.1, True)])
def test_a_4_hz_odometry_twist_of_interval_means_is_restamped_to_its_midpoints(tmp_path, early, applied):
    # the odometry's twist is both velocities (as TagSLAM test_22's) and each sample the mean over the interval before
    # its stamp, which is the motion at the interval's midpoint: stamped half an interval late. Read as means against
    # its own poses, the reader restamps both velocities to the midpoints (riekf's and batch's stamps), and the
    # search, which holds each sample until the next, takes each at its interval's start (h-meanoffset: +0.249 s
    # read and held back on time; h-meanoffset2: the midpoints, the twin's reading). 0.1 s early is still applied
    from slamobs.pipeline.readers import read_log

    twin_stream = align(read_log(_odometry_log(tmp_path, "instant", early)[1], {"angular_velocity": "/odom"}))
    twin = time_offset.decide(twin_stream)
    sim, log = _odometry_log(tmp_path, "mean", early)
    streams = read_log(log, {"angular_velocity": "/odom"})
    assert streams.twist_sampling["model"] == "mean", streams.twist_sampling
    for got in (streams.angular_velocity.t_ns, streams.linear_velocity.t_ns):
        assert np.array_equal(got, sim.odom.t_ns - 125_000_000)  # 4 Hz: half of 0.25 s, the first by the median
    stream = align(streams)
    offset = time_offset.decide(stream)
    assert time_offset.hold_lag(stream) == 0.0  # the search holds each mean from its interval's start (h-midstamp)
    assert abs(time_offset.hold_lag(twin_stream) - 0.125) < 0.005
    assert offset["sampling"]["model"] == "mean", offset["sampling"]
    assert "restamped to interval midpoints" in offset["sampling"]["why"], offset["sampling"]
    assert offset["applied"] == twin["applied"] == applied, (offset, twin)
    # the twin's search reads the offset plus its half-interval lag (+0.124 s on time, +0.226 s 0.1 s early); holding
    # each mean over exactly the interval it averages, this one reads the offset itself, closer (h-midstamp; at
    # b332a8a4 it read as the twin: fails)
    assert abs(offset["estimate_s"] - early) < 0.5 * abs(twin["estimate_s"] - early), (offset, twin)
    assert offset["sampling"]["stamps"] == "interval midpoints", offset["sampling"]  # riekf's and batch's
    # an estimator that holds each sample until the next takes each at its interval's start: 0.25 s before its stamp
    # as recorded (the previous sample's stamp), the first by the median interval (h-midstamp)
    assert np.array_equal(stream.vel_start_ns, sim.odom.t_ns - 250_000_000)
    assert np.array_equal(held_stamps(stream).vel_t_ns, stream.vel_start_ns)
    assert twin_stream.vel_start_ns is None and held_stamps(twin_stream) is twin_stream


def test_fast_adaptation_holds_each_interval_mean_over_the_interval_it_averages(tmp_path):
    # fast-adaptation holds each velocity sample from its stamp until the next: stamped at the end of the interval it
    # averages it ran a whole interval late (h-meanoffset: 0.301 -> 0.745 m on such a 4 Hz rig once the false offset
    # was held back), at the midpoint half an interval late, as on the instantaneous twin (h-meanoffset2). At its
    # interval's start each sample is held over exactly the interval it averages, as the odometry's own dead
    # reckoning holds it: its poses are at those starts, the record says so, and its error is at most half the
    # twin's, whose instants it holds half an interval late, the largest part of its error at 4 Hz (a round rule;
    # h-midstamp: 0.108 against 0.357 m; taken at the midpoints, b332a8a4: 0.315 against 0.357 m, fails)
    apes = {}
    for sampling in ("instant", "mean"):
        sim, log = _odometry_log(tmp_path, sampling)
        out = tmp_path / f"fa-{sampling}"
        cfg = {"topics": {"angular_velocity": "/odom"}, "evaluation": {"plots": False}}
        run_log(log, out, observer="fast-adaptation", config=cfg)
        record = json.loads((out / "run.json").read_text())["observer"]["time_offset"]
        assert not record["applied"], record
        apes[sampling] = json.loads((out / "report.json").read_text())["ape"]["translation_m"]["rmse"]
        t = pq.read_table(out / "poses.parquet", columns=["t_ns"]).column("t_ns").to_numpy()
        if sampling == "mean":
            assert record["sampling"]["stamps"] == "interval starts", record["sampling"]
            assert np.isin(t, sim.odom.t_ns - 250_000_000).all()
        else:
            assert "stamps" not in record["sampling"] and np.isin(t, sim.odom.t_ns).all(), record["sampling"]
    assert apes["mean"] < 0.5 * apes["instant"], apes


def test_an_odometry_twist_is_read_against_its_own_poses(tmp_path):
    # interval means fit the poses' increment before each stamp; instantaneous samples the central difference of
    # poses that follow the motion (a VIO's); poses dead-reckoned by holding each twist until the next fit the
    # increment after it and say nothing of the sampling. Only the first moves the search's zero
    from slamobs.pipeline.readers.odometry import twist_sampling
    from slamobs.pipeline.simulate.scenarios import handheld
    from slamobs.pipeline.streams import PoseStream, Vec3Stream

    def read(sim, truth_poses: bool) -> dict:
        o = sim.odom
        position, quat = o.position, o.quat_xyzw
        if truth_poses:
            from slamobs.pipeline.lie import rots_to_quats

            tr = handheld().sample((o.t_ns - sim.start_ns) * 1e-9)
            position, quat = tr.P, rots_to_quats(tr.R)
        poses = PoseStream("/odom", "odom", "base_link", o.t_ns, o.rec_ns, position, quat)
        twist = lambda xyz: Vec3Stream("/odom", "base_link", o.t_ns, o.rec_ns, xyz)  # noqa: E731
        return twist_sampling(poses, twist(o.angular), twist(o.linear))

    from slamobs.pipeline.readers import read_log

    mean, _ = _odometry_log(tmp_path, "mean")
    inst, inst_log = _odometry_log(tmp_path, "instant")
    assert read(mean, False)["model"] == "mean"
    assert read(inst, True)["model"] == "instant"
    assert read(inst, False)["model"] == "held"
    record = time_offset.decide(align(read_log(inst_log, {"angular_velocity": "/odom"})))["sampling"]
    assert record["model"] == "instant" and "dead-reckoned" in record["why"], record


def test_a_lag_the_halves_held_back_is_not_read_as_the_detections_scale():
    # seed=4126 (session 37): each detection frame stamped 0-0.3 s late; the offset found (0.139 s late) was held
    # back by the halves, and the velocity scale, fitted at zero shift, read the lag of a yawing rig as a lateral
    # scale of -6.36x (warning: the detections' scale is off, tags.size). Here a hand-held rig's detections 0.1 s
    # late, then 0.2 s from mid-log, each frame ± 0.05 s: at zero shift y read -7.19x and z -1.16x, both warned; at
    # the offset found 0.85 and 0.97, none
    from slamobs.pipeline.simulate.scenarios import handheld

    sim = simulate(handheld(), seed=4171, duration=60.0, imu_rate=200.0, odom_rate=10.0)
    d = sim.detections
    frames, at = np.unique(d.t_ns, return_inverse=True)
    late_s = np.where(frames > frames[0] + (frames[-1] - frames[0]) / 2, 0.2, 0.1)
    late = np.round((late_s + np.random.default_rng(4171).uniform(-0.05, 0.05, frames.size)) * 1e9).astype(np.int64)
    stream = align(expected_streams(replace(sim, detections=replace(d, t_ns=d.t_ns + late[at]))))
    offset = time_offset.estimate(stream)
    assert not offset["applied"] and offset["why_not_applied"].startswith(time_offset.HALVES_DISAGREE)
    assert offset["estimate_s"] < -0.1
    assert time_offset.velocity_misread(offset["velocity_scale"]) == [], offset["velocity_scale"]
    assert not [n for n in time_offset.note("riekf", offset) if "as far as its velocity says" in n]


def test_the_lever_arm_reads_the_pairs_the_velocity_scale_reads_on_an_odometry_with_gaps():
    # session 39 (h-review11): the velocity scale fitted only the pairs whose span holds no gap of the odometry's
    # samples (h-misled10), the lever arm every pair, and ``over_scale`` divided the one's cost by the other's. A
    # hand-held rig's twist of a point 0.2 m ahead with half its 10 Hz odometry lost at random (seed=4716, 60 s):
    # on every pair the arm fitted 1.20x, 0.94x of the scales' cost on fewer pairs, and went unnamed while its y
    # velocity was named 0.532x as far; on the scale's pairs it fits 1.24x, 1.03x the scales', and is named with the
    # scale it explains
    from noisy_logs import rig_noise

    from slamobs.pipeline.simulate.scenarios import handheld

    sc = handheld()
    sim = simulate(sc, noise=rig_noise(200.0, 10.0), seed=4716, duration=60.0, imu_rate=200.0, odom_rate=10.0)
    o = sim.odom
    omega = sc.sample((o.t_ns - sim.start_ns) * 1e-9).omega
    o = replace(o, linear=o.linear + np.cross(omega, [0.2, 0.0, 0.0]))
    keep = np.random.default_rng(4716).random(o.t_ns.shape[0]) < 0.5
    thinned = replace(o, **{f: getattr(o, f)[keep] for f in o.__dataclass_fields__})
    stream = align(expected_streams(replace(sim, odom=thinned)))
    assert stream.velocity_gaps.shape[0] > 0
    offset = time_offset.estimate(stream)
    assert offset["lever_arm"]["r_m"][0] == pytest.approx(0.2, abs=0.03), offset["lever_arm"]
    said = time_offset.note(None, offset)
    arm = [n for n in said if "as the velocity of a point (" in n]
    assert len(arm) == 1 and "the velocity's scale along y" in arm[0] and "which it explains" in arm[0], said
    assert not [n for n in said if "moved along y" in n], said


def test_a_lever_arm_that_explains_the_lag_and_scale_is_named_in_their_place():
    # seed=4127 (session 37): a hand-held rig's twist that of a point 0.2 m ahead of the body; the pairs fitted the
    # arm exactly but at 1.30x, under LEVER_ARM_GAIN, and named a 0.124 s lag and a 0.546x y scale instead, both false.
    # Here the same rig (seed=4416, 60 s, the benchmark's noise: gyro x30, velocity x10): the arm is named, with the
    # lag and scale it explains, and neither is named on its own; a clean twist (no arm) names nothing
    from noisy_logs import rig_noise

    from slamobs.pipeline.simulate.scenarios import handheld

    sc = handheld()
    sim = simulate(sc, noise=rig_noise(200.0, 10.0), seed=4416, duration=60.0, imu_rate=200.0, odom_rate=10.0)
    clean = time_offset.estimate(align(expected_streams(sim)))
    assert time_offset.note(None, clean) == [] and time_offset.arm_explains(clean) == {}
    o = sim.odom
    omega = sc.sample((o.t_ns - sim.start_ns) * 1e-9).omega
    ahead = replace(sim, odom=replace(o, linear=o.linear + np.cross(omega, [0.2, 0.0, 0.0])))
    offset = time_offset.estimate(align(expected_streams(ahead)))
    assert offset["lever_arm"]["r_m"][0] == pytest.approx(0.2, abs=0.03), offset["lever_arm"]
    said = time_offset.note(None, offset)
    assert len(said) == 1 and "as the velocity of a point (" in said[0], said
    assert "which it explains" in said[0], said
    assert not time_offset.misread(offset)  # the estimate is whole, on another point


def test_a_detection_scale_on_every_axis_inside_the_velocity_band_is_named_and_its_twin_as_drawn_is_not(tmp_path):
    # seed=4628 of benchmarks/handheld_logs.py's round 11 (docs/benchmarks.md, "Logs nobody has run yet, round 11"):
    # a hand-held rig's detections 1.1x (a detector given a tag size 10 % small) multiplied its APE by ten with no
    # word: the pairs' scale on every axis was 6-9 standard errors past 1, but inside VELOCITY_SCALE_OFF. Every axis
    # off alike (time_offset.common_scale) is now named, the causes with it; the same log as drawn says nothing
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.run import prepare_log
    from slamobs.pipeline.simulate.scenarios import handheld

    nm = rig_noise(200.0, 10.0)
    sim = simulate(handheld(), noise=nm, duration=90.0, seed=4740, imu_rate=200.0, odom_rate=10.0, detection_rate=15.0)

    def said(scale: float) -> list[str]:
        read = replace(sim, detections=replace(sim.detections, xyz=sim.detections.xyz * scale))
        log = write_log(read, tmp_path / f"{scale:g}.mcap")
        offset = time_offset.estimate(prepare_log(log, load_config(None)).aligned)
        return [n for n in time_offset.note(None, offset) if "the detections say the body moved" in n]

    assert said(1.0) == []
    (named,) = said(1.1)
    assert "on every axis the pairs fit" in named and "tags.size" in named, named


def test_the_common_scale_leaves_the_real_logs_factors_and_one_axis_unsaid():
    # time_offset.common_scale on the pairs' scales as recorded (docs/benchmarks.md, "A detection scale on every axis,
    # session 39"): TagSLAM 11 and 21's axes agree in sign, 15-40 standard errors from 1, but their mean is 2.2 % and
    # 1.9 % off (under COMMON_SCALE_OFF); a MR.CLAM robot's one axis (0.845 ± 0.057) and a clean hand-held rig's axes on
    # both sides of 1 say nothing; seed=4628's (detections 1.1x) is named, as is a flight's 0.9
    def rec(scale, sigma, fitted=None):
        return {"scale": scale, "sigma": sigma, "fitted": fitted or scale}

    none = [
        rec([0.963, 0.887, 0.983], [0.0039, 0.0079, 0.0015]),  # TagSLAM 11
        rec([0.988, 0.985, 0.980], [0.0014, 0.0012, 0.0005]),  # TagSLAM 21
        rec([0.845, None, None], [0.057, None, None]),  # MR.CLAM 7 r5
        rec([1.033, 1.160, 1.047], [0.011, 0.026, 0.025], [1.009, 1.038, 0.958]),  # seed=4755, clean
    ]
    assert [time_offset.common_scale(r) for r in none] == [None] * 4
    named = time_offset.common_scale(rec([1.083, 1.243, 1.176], [0.012, 0.028, 0.028], [1.062, 1.129, 1.074]))
    assert named is not None and abs(named["scale"] - 1.118) < 0.002, named
    flight = time_offset.common_scale(rec([0.888, 0.916, 0.903], [0.0068, 0.0027, 0.0032], [0.884, 0.916, 0.903]))
    assert flight is not None and abs(flight["scale"] - 0.909) < 0.002, flight
