"""Alignment: one time base, body frame, detections in order, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from slamobs.pipeline.alignment import align, unbridged
from slamobs.pipeline.blocks import row_norms3
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.frames import static_transform
from slamobs.pipeline.lie import quat_to_rot, rot_to_quat, so3_exp
from slamobs.pipeline.readers.decode import static_transforms
from slamobs.pipeline.readers.rows import TfRows
from slamobs.pipeline.streams import DetectionStream, LogStreams, PoseStream, Transform, TransformSeries, Vec3Stream

NS = 1_000_000_000


def _vec(topic, frame, t_s, xyz):
    t = (np.asarray(t_s) * NS).astype(np.int64) + 5 * NS
    return Vec3Stream(topic, frame, t, t + 1000, np.asarray(xyz, float))


def _streams(**kw):
    t_om = np.arange(0, 2.0, 0.01)
    t_v = np.arange(0, 2.0, 0.05)
    base = dict(
        path="mem.bag",
        angular_velocity=_vec("/imu", "imu", t_om, np.tile([0.0, 0.0, 0.5], (t_om.size, 1))),
        linear_velocity=_vec("/odom", "base_link", t_v, np.column_stack([t_v, np.zeros_like(t_v), np.ones_like(t_v)])),
        detections=DetectionStream(
            "/fid",
            "camera",
            t_ns=np.array([1.5, 0.5, 1.0]).__mul__(NS).astype(np.int64) + 5 * NS,
            rec_ns=np.array([1.5, 0.5, 1.0]).__mul__(NS).astype(np.int64) + 5 * NS,
            offsets=np.array([0, 2, 3, 5]),
            ids=np.array([7, 3, 3, 9, 9]),
            xyz=np.arange(15, dtype=float).reshape(5, 3),
        ),
        static_tf=[
            Transform(
                "base_link", "camera", np.array([0.1, 0.0, -0.2]), rot_to_quat(so3_exp(np.array([0.0, 0.3, 0.0])))
            ),
            Transform("base_link", "imu", np.zeros(3), rot_to_quat(so3_exp(np.array([0.0, 0.0, np.pi / 2])))),
        ],
    )
    base.update(kw)
    return LogStreams(**base)


def test_time_base_rotation_and_interpolation():
    s = _streams()
    a = align(s)
    assert a.body_frame == "base_link"
    assert np.all(np.diff(a.vel_t_ns) > 0)
    r_bi = so3_exp(np.array([0.0, 0.0, np.pi / 2]))
    assert np.allclose(a.omega, (r_bi @ np.array([0.0, 0.0, 0.5]))[None])
    # linear velocity x = t (linear), interpolated exactly onto the 100 Hz base
    t_rel = (a.vel_t_ns - 5 * NS) * 1e-9
    assert np.allclose(a.velocity[:, 0], t_rel, atol=1e-12)
    assert a.vel_t_ns[-1] <= s.linear_velocity.t_ns[-1]


def test_detections_sorted_in_body_frame_with_repeated_ids_dropped():
    s = _streams()
    a = align(s)
    # frames sorted by time: 0.5 (ids 3), 1.0 (ids 9, 9 -> one), 1.5 (ids 7, 3)
    assert list(a.det_t_ns - 5 * NS) == [int(0.5 * NS), int(1.0 * NS), int(1.5 * NS)]
    assert list(a.det_offsets) == [0, 1, 2, 4]
    assert list(a.det_ids) == [3, 9, 7, 3]
    assert any("repeated ids" in n for n in a.notes)
    r, t = static_transform(s.static_tf, "base_link", "camera")
    assert np.allclose(a.det_y[0], r @ s.detections.xyz[2] + t)
    assert np.allclose(a.det_y[2], r @ s.detections.xyz[0] + t)
    assert list(a.landmark_ids) == [3, 7, 9]


def test_lever_arm_of_odometry_frame():
    # Odometry reported in a frame 1 m ahead of the body origin while turning at 0.5 rad/s about z:
    # v_body = v_frame - omega x t.
    tfs = [Transform("base_link", "odom_frame", np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))]
    s = _streams(static_tf=_streams().static_tf + tfs)
    s.linear_velocity = Vec3Stream(
        "/odom",
        "odom_frame",
        s.linear_velocity.t_ns,
        s.linear_velocity.rec_ns,
        np.tile([0.0, 0.5, 0.0], (len(s.linear_velocity), 1)),
    )
    s.angular_velocity = Vec3Stream(
        "/imu", "base_link", s.angular_velocity.t_ns, s.angular_velocity.rec_ns, s.angular_velocity.xyz
    )
    a = align(s, body_frame="base_link")
    assert np.allclose(a.velocity, 0.0, atol=1e-12)  # the point ahead moves only because the body turns


def test_static_transform_chains_and_inverts():
    q = rot_to_quat(so3_exp(np.array([0.1, -0.2, 0.3])))
    tfs = [Transform("a", "b", np.array([1.0, 2, 3]), q), Transform("b", "c", np.array([0.0, 1, 0]), q)]
    r_ac, t_ac = static_transform(tfs, "a", "c")
    r = quat_to_rot(q)
    assert np.allclose(r_ac, r @ r)
    assert np.allclose(t_ac, r @ np.array([0.0, 1, 0]) + np.array([1.0, 2, 3]))
    r_ca, t_ca = static_transform(tfs, "/c", "a")
    assert np.allclose(r_ca @ r_ac, np.eye(3)) and np.allclose(r_ca @ t_ac + t_ca, 0)
    assert static_transform(tfs, "a", "zzz") is None


def test_missing_extrinsic_is_a_one_line_error_naming_the_topic():
    s = _streams(static_tf=[])
    with pytest.raises(InputError) as err:
        align(s)
    msg = str(err.value)
    assert "mem.bag" in msg and "/imu" in msg and "imu" in msg and "\n" not in msg
    # the way that works for a camera (TagSLAM test_22's corners: cameras: [cameras.yaml, camera_poses.yaml, ...])
    assert "or give the transform: the camera of tag corners or images takes it from files in cameras: a Kalibr" in msg
    # ... unless the user says that frame is the body frame
    a = align(_streams(static_tf=[]), identity_frames=("imu", "camera"))
    assert a.det_y.shape == (4, 3)
    # ... and the report says which extrinsics were assumed, not measured
    assumed = [n for n in a.notes if "frames.assume_identity: TF has no transform" in n]
    assert {n.split(":")[0] for n in assumed} == {"/imu", "/fid"}, a.notes


def test_missing_roles_and_disjoint_times_are_errors():
    with pytest.raises(InputError, match=r"inputs needed by every estimator is missing \(detections\)") as err:
        align(_streams(detections=None))
    # the detections' line named its 15 message types in 900 characters; now the first way and where the rest are
    # (slamobs info, one line each); a role with few ways keeps them all
    (line,) = err.value.details
    assert line.startswith("detections (landmark detections): set topics.detections to a topic of type fiducial_msgs/")
    assert line.endswith("; or one of 5 other kinds of topic (`slamobs info` lists them, with what each needs)")
    assert len(line) < 300 and "sensor_msgs/msg/Image" not in line
    with pytest.raises(InputError) as err:
        align(_streams(angular_velocity=None))
    assert "slamobs evaluate" not in str(err.value)
    # the role's words in brackets hold no brackets of their own: "angular_velocity (angular velocity (gyro))"
    assert err.value.details[0].startswith("angular_velocity (angular velocity, gyro): set topics.angular_velocity")
    # a log of poses only (evo's ROS_example.bag): what it is good for, and a command that works
    t = np.arange(3, dtype=np.int64) * NS
    truth = PoseStream("groundtruth", "world", "body", t, t, np.zeros((3, 3)), np.tile([0.0, 0, 0, 1], (3, 1)))
    with pytest.raises(InputError, match=r"its poses \(groundtruth\) are a trajectory: `slamobs evaluate mem.bag:"):
        align(_streams(angular_velocity=None, linear_velocity=None, truth=truth))
    with pytest.raises(InputError) as err:
        align(_streams(angular_velocity=None))
    assert "; or nav_msgs/msg/Odometry  [a zero twist.angular is differentiated" in err.value.details[0]
    late = _streams()
    late.linear_velocity = Vec3Stream(
        "/odom",
        "base_link",
        late.linear_velocity.t_ns + 100 * NS,
        late.linear_velocity.rec_ns,
        late.linear_velocity.xyz,
    )
    with pytest.raises(InputError, match="do not overlap") as err:
        align(late)
    # both on header stamps: one of them may be on another clock, which time.source: auto finds
    assert str(err.value).endswith(
        "do not overlap in time; is one of them on another clock (simulated time)? try time.source: auto"
    )


def test_record_time_option_uses_record_stamps():
    s = _streams()
    a = align(s, time_source="record")
    assert a.vel_t_ns[0] == s.angular_velocity.rec_ns[0]


def test_assume_identity_applies_only_where_tf_has_no_transform(tmp_path):
    """Issue 12 item 2, on a simulated log whose IMU is mounted upside down with its own /tf_static entry."""
    import json

    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.simulate import expected_streams, simulate, write_log

    sim = simulate("figure8-imu-flipped", duration=12.0, seed=1, imu_rate=100.0)
    ref = align(expected_streams(sim))
    listed = align(expected_streams(sim), identity_frames=("imu_link",))
    assert np.array_equal(listed.omega, ref.omega) and np.array_equal(listed.directions.body, ref.directions.body)
    warn = [n for n in listed.notes if n.startswith("warning: frames.assume_identity lists 'imu_link'")]
    assert len(warn) == 1 and "turned 180.0 deg" in warn[0]
    forced = align(expected_streams(sim), override_identity=("imu_link",))
    np.testing.assert_allclose(forced.omega[:, 1:], -ref.omega[:, 1:])  # the 180° turn about x is gone
    assert any(n.startswith("warning: frames.override_identity: frame 'imu_link'") for n in forced.notes)
    # the same through `slamobs run`: the warning lands in run.json, the estimate is the one TF gives
    log = write_log(sim, tmp_path / "flipped.mcap")
    ape = {}
    for name, frames in (
        ("tf", {}),
        ("listed", {"assume_identity": ["imu_link"]}),
        ("forced", {"override_identity": ["imu_link"]}),
    ):
        summary = run_log(
            log, tmp_path / name, config={"observer": "hashim", "frames": frames, "evaluation": {"plots": False}}
        )
        ape[name] = summary.report["ape"]["translation_m"]["rmse"]
        notes = json.loads((tmp_path / name / "run.json").read_text())["notes"]
        assert any(n.startswith("warning: frames.") for n in notes) == (name != "tf")
    assert ape["listed"] == ape["tf"] and ape["forced"] > 2 * ape["tf"]


def test_detection_helpers_give_numpys_arrays():
    """The hand-off's shortcuts (a row's norm by columns, ids by a table, repeats compared within a frame) give
    the arrays of the NumPy calls they replace, and fall back to them where the shortcut does not apply."""
    from slamobs.pipeline.blocks import MAX_FRAME_RUN, first_of_pairs, repeated_pairs, unique_inverse

    rng = np.random.default_rng(3)
    x = rng.normal(size=(5000, 3)) * 10.0 ** rng.integers(-8, 8, size=(5000, 1))
    assert row_norms3(x).tobytes() == np.linalg.norm(x, axis=1).tobytes()
    assert row_norms3(x[::2]).tobytes() == np.linalg.norm(x[::2], axis=1).tobytes()  # strided rows
    for ids in (
        rng.integers(-5, 40, size=3000),  # negative ids too
        np.array([2**40, 3, 2**40, 7]),  # a range too wide for the table: NumPy's sort
        rng.integers(0, 30, size=3000).astype(np.int32),
    ):
        got, want = unique_inverse(ids), np.unique(ids, return_inverse=True)
        assert [g.tobytes() for g in got] == [w.tobytes() for w in want] and got[0].dtype == want[0].dtype

    def lexsorted(a, b):
        order = np.lexsort((b, a))
        repeat = (a[order[1:]] == a[order[:-1]]) & (b[order[1:]] == b[order[:-1]])
        return np.sort(order[np.concatenate(([True], ~repeat))])

    frames = np.repeat(np.arange(400), rng.integers(1, 12, size=400))
    ids = rng.integers(0, 6, size=frames.size)  # many repeats within a frame
    long_run = np.repeat(np.arange(3), [2, MAX_FRAME_RUN + 5, 1])  # a frame longer than the row-by-row limit
    for a, b in (
        (frames, ids),
        (frames[::-1].copy(), ids),  # frames not in order: sorted
        (long_run, rng.integers(0, 4, size=long_run.size)),
        (np.array([4]), np.array([1])),
    ):
        assert first_of_pairs(a, b).tolist() == lexsorted(a, b).tolist()
        repeated = np.ones(a.shape[0], bool)
        repeated[lexsorted(a, b)] = False
        assert repeated_pairs(a, b).tolist() == repeated.tolist()  # the readers' mask of the repeats
    assert first_of_pairs(frames, ids).size < frames.size  # the case above had repeats to drop


def test_a_gap_in_one_topic_giving_both_velocities_is_noted_once():
    """MR.CLAM's /robot1/velocity (TwistStamped: gyro and velocity) printed its gap note twice."""
    t = np.r_[np.arange(0, 1.0, 0.01), np.arange(2.0, 3.0, 0.01)]  # a 1 s gap
    twist = _vec("/twist", "base_link", t, np.tile([0.1, 0.0, 0.0], (t.size, 1)))
    a = align(_streams(angular_velocity=twist, linear_velocity=twist))
    gaps = [n for n in a.notes if "gap(s) longer than" in n]
    assert len(gaps) == 1 and gaps[0].startswith("/twist:")


def test_an_imu_dropping_samples_in_short_bursts_is_named_and_a_held_command_is_not():
    """A 100 Hz gyro with 0.06 s dropped every 0.5 s (bursts under GAP_WARN_S 0.5 s): the run said nothing, the
    sample before each burst held across it (session 18). A stream that repeats its values (a command logged as
    held, MR.CLAM's velocity) with the same gaps keeps its old note: its gaps are the command held."""
    t = np.arange(0, 2.0, 0.01)
    t = t[(t % 0.5) > 0.05 + 1e-9]
    rng = np.random.default_rng(0)
    measured = np.column_stack([np.zeros((t.size, 2)), 0.5 + 0.01 * rng.standard_normal(t.size)])
    a = align(_streams(angular_velocity=_vec("/imu", "imu", t, measured)))
    said = [n for n in a.notes if "gap" in n]
    assert len(said) == 1 and said[0].startswith("warning: /imu: 3 gaps over 5x its median interval 10 ms"), said
    assert "longest 0.070 s" in said[0] and "holds the sample before each gap" in said[0], said
    a = align(_streams(angular_velocity=_vec("/imu", "imu", t, np.tile([0.0, 0.0, 0.5], (t.size, 1)))))
    assert not [n for n in a.notes if "gap" in n], a.notes  # a held command, no gap over 0.5 s: nothing


def test_a_gyro_sampled_through_an_odometry_gap_is_not_said_to_have_dropped_samples():
    """Odometry silent 12 s (over limits.max_gap and limits.max_odometry_gap) beside a 100 Hz IMU that recorded every
    sample: the run drops the IMU's samples inside the odometry's gap and then said "/imu: 1 gap ... samples dropped?
    the run holds the sample before each gap across it", of an IMU that dropped none and a run that segments there
    (a generated flight, seed=3448, session 33). The odometry's gap is said; the IMU's is not."""
    t_om = np.arange(0, 26.0, 0.01)
    t_v = np.arange(0, 26.0, 0.1)
    t_v = t_v[(t_v < 7.0) | (t_v > 19.0)]
    rng = np.random.default_rng(1)
    gyro = np.column_stack([np.zeros((t_om.size, 2)), 0.5 + 0.01 * rng.standard_normal(t_om.size)])
    odom = np.column_stack([1.0 + 0.01 * rng.standard_normal(t_v.size), np.zeros((t_v.size, 2))])
    a = align(
        _streams(
            angular_velocity=_vec("/imu", "imu", t_om, gyro), linear_velocity=_vec("/odom", "base_link", t_v, odom)
        )
    )
    assert any(n.startswith("warning: /odom: 1 gap over") for n in a.notes), a.notes
    assert any("inside /odom gaps longer than limits.max_odometry_gap" in n for n in a.notes), a.notes
    assert not [n for n in a.notes if n.startswith(("/imu", "warning: /imu"))], a.notes


def _silent_odometry(
    silent: tuple[float, float], gyro_silent: tuple[float, float] | None = None, detections=None, **kw
):
    """A 100 Hz IMU and 10 Hz odometry over 30 s, the odometry silent over ``silent`` (s), the IMU over
    ``gyro_silent``, aligned with ``kw``."""
    t_om, t_v = np.arange(0, 30.0, 0.01), np.arange(0, 30.0, 0.1)
    t_v = t_v[(t_v < silent[0]) | (t_v > silent[1])]
    if gyro_silent:
        t_om = t_om[(t_om < gyro_silent[0]) | (t_om > gyro_silent[1])]
    gyro = np.tile([0.0, 0.0, 0.5], (t_om.size, 1))
    odom = np.column_stack([1.0 + 0.1 * np.sin(t_v), np.zeros((t_v.size, 2))])
    more = {} if detections is None else {"detections": detections}
    streams = _streams(
        angular_velocity=_vec("/imu", "imu", t_om, gyro), linear_velocity=_vec("/odom", "base_link", t_v, odom), **more
    )
    return align(streams, **kw)


def test_an_odometry_gap_the_gyro_recorded_through_is_bridged_up_to_max_odometry_gap():
    """Odometry silent 5.1-8 s (a VIO reset, a driver restart) while the IMU records: the run split there and held
    the pose, riekf 1.061 m against batch 0.029 on a generated hand-held walk with two 5.1 s silences (seed=3459,
    session 33); up to limits.max_odometry_gap the gyro keeps the attitude and the velocity is interpolated across
    with its noise widened (``velocity_gaps``), no segment. Longer, or the gyro silent too, or the limit off: split."""
    a = _silent_odometry((10.0, 18.0))
    assert a.segment_starts.size == 0, a.notes
    assert np.diff(a.vel_t_ns).max() < 0.02 * NS  # the IMU's samples in the gap are kept
    assert a.velocity_gaps.shape == (1, 2) and (a.velocity_gaps[0, 1] - a.velocity_gaps[0, 0]) > 8 * NS
    said = [n for n in a.notes if "bridged, not split" in n]
    assert len(said) == 1 and said[0].startswith("/odom: 1 gap longer than limits.max_gap 5 s at +9.90 s (8."), said
    assert not [n for n in a.notes if "segments" in n], a.notes
    for silent, gyro_silent, kw in (
        ((10.0, 22.0), None, {}),  # past limits.max_odometry_gap 10 s
        ((10.0, 18.0), (10.0, 18.0), {}),  # the gyro silent too: nothing keeps the attitude
        ((10.0, 18.0), None, {"limits": {"max_odometry_gap": None}}),  # switched off: max_gap as before
    ):
        a = _silent_odometry(silent, gyro_silent, **kw)
        assert a.segment_starts.size == 1, (silent, gyro_silent, kw, a.notes)
        assert not [n for n in a.notes if "bridged" in n], a.notes


def _gap_detections() -> DetectionStream:
    """Three landmarks seen every 0.5 s from 5.5 to 33.5 s of :func:`_silent_odometry`'s log."""
    t_det = np.arange(0.5, 29.0, 0.5)
    return DetectionStream(
        "/fid",
        "camera",
        t_ns=(t_det * NS).astype(np.int64) + 5 * NS,
        rec_ns=(t_det * NS).astype(np.int64) + 5 * NS,
        offsets=np.arange(0, 3 * t_det.size + 1, 3),
        ids=np.tile([1, 2, 3], t_det.size),
        xyz=np.tile([[1.0, 0, 2], [0, 1.0, 2], [-1.0, 0, 2]], (t_det.size, 1)),
    )


def test_batch_splits_a_bridged_odometry_gap_as_the_split_run_did():
    """batch carried across a bridged gap was the worse (a generated figure 8, odometry silent 7 s: 0.22 m against
    0.009 m split; docs/benchmarks.md, session 33): ``unbridged`` gives it the stream the split run had, the
    gyro's samples and the detection frames inside the gap dropped, a segment after it."""
    bridged = _silent_odometry((10.0, 18.0), detections=_gap_detections())
    split = _silent_odometry((10.0, 18.0), detections=_gap_detections(), limits={"max_odometry_gap": None})
    assert bridged.bridged_gaps.shape == (1, 2) and split.bridged_gaps.shape == (0, 2)
    got = unbridged(bridged)
    assert got.segment_starts.tolist() == split.segment_starts.tolist() and split.segment_starts.size == 1
    for name in ("vel_t_ns", "omega", "velocity", "det_t_ns", "det_offsets", "det_idx", "det_y", "landmark_ids"):
        assert np.array_equal(getattr(got, name), getattr(split, name)), name
    assert got.det_t_ns.size < bridged.det_t_ns.size
    assert unbridged(split) is split


def test_every_cut_of_an_aligned_stream_keeps_the_fields_it_does_not_cut():
    """The three cuts of an AlignedStream (``windowed``, ``unbridged``, ``observers.base.split_jumps``) go through
    ``alignment.subset`` / ``relabelled``: every field none of them cuts is the input's own object, a field added to
    the dataclass later included (a guard: ``windowed`` once built a new AlignedStream from a list of fields and lost
    those added after it, session 32; at session 34's base all three kept them)."""
    from dataclasses import fields, replace

    from slamobs.pipeline.alignment import time_window, windowed
    from slamobs.pipeline.observers.base import split_jumps

    a = replace(
        _silent_odometry((10.0, 18.0), detections=_gap_detections()),
        base_frame={"frame": "base_link"},
        gyro_turn={"turn": 1},
        gyro_moved_s=0.1,
    )
    assert a.bridged_gaps.shape == (1, 2) and a.segment_starts.size == 0
    cut = {"vel_t_ns", "omega", "velocity", "directions", "segment_starts", "det_t_ns", "det_offsets", "det_y"}
    ids = {"det_idx", "landmark_ids"}
    t_mid = int(a.det_t_ns[a.det_t_ns.size // 2])
    for name, out, changed in (
        ("windowed", windowed(a, time_window(2.0, 25.0, a.t0_ns), "log"), cut | ids | {"t0_ns", "notes"}),
        ("unbridged", unbridged(a), cut | ids | {"bridged_gaps"}),
        ("split_jumps", split_jumps(a, [{"id": 2, "t_ns": t_mid}], np.empty(0, np.int64)), ids),
    ):
        assert out.vel_t_ns.size < a.vel_t_ns.size or out.landmark_ids.size > a.landmark_ids.size, name
        for f in fields(a):
            if f.name not in changed:
                assert getattr(out, f.name) is getattr(a, f.name), (name, f.name)


def test_a_subset_by_slices_is_the_subset_by_their_indices():
    """``alignment.subset``'s two cases (slices, whose arrays are views; sorted indices) cut alike: the same
    samples, segment starts moved onto them, detections and landmark ids rebuilt from those kept."""
    from dataclasses import fields

    from slamobs.pipeline.alignment import subset

    a = unbridged(_silent_odometry((10.0, 18.0), detections=_gap_detections()))
    assert a.segment_starts.size == 1
    by_slice = subset(a, slice(500, 1500), slice(10, 30))
    by_index = subset(a, np.arange(500, 1500), np.arange(10, 30))
    assert by_slice.segment_starts.tolist() == [int(a.segment_starts[0]) - 500]
    assert by_slice.det_t_ns.size == 20 and by_slice.det_offsets[0] == 0 and by_slice.landmark_ids.tolist() == [1, 2, 3]
    for f in fields(a):
        x, y = getattr(by_slice, f.name), getattr(by_index, f.name)
        assert np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y or x is y, f.name


def test_a_velocity_stream_repeating_stamps_with_other_values_is_named():
    """Every 5th odometry message sent twice with one stamp, the second saying the body stood still: riekf 0.053 m
    against 0.011 m on a generated figure 8, with only the readers' note (session 19). One such repeat is not."""
    t_v = np.arange(0, 2.0, 0.05)
    k = np.sort(np.r_[np.arange(t_v.size), np.arange(0, t_v.size, 5)])
    v = np.column_stack([np.ones(k.size), np.zeros(k.size), 0.01 * np.arange(k.size)])
    v[np.r_[False, k[1:] == k[:-1]]] = 0.0
    a = align(_streams(linear_velocity=_vec("/odom", "base_link", t_v[k], v)))
    said = [n for n in a.notes if "share their stamp" in n]
    assert len(said) == 1 and said[0].startswith("warning: /odom: 8 of its 48 samples share their stamp"), said
    once = np.r_[np.arange(t_v.size), 20]
    a = align(_streams(linear_velocity=_vec("/odom", "base_link", np.sort(t_v[once]), np.ones((once.size, 3)))))
    assert not [n for n in a.notes if "share their stamp" in n], a.notes


def test_detections_after_the_last_time_base_sample_are_dropped():
    # the IMU's header clock jumps an hour ahead at 1 s, the odometry runs on to 2 s: the time base ends at 1 s,
    # and the frames at 1.5 s (after it, where no estimator has motion) must go; batch indexed past its keyframes
    t_om = np.arange(0, 2.0, 0.01)
    t_om = np.where(t_om > 1.0, t_om + 3600.0, t_om)
    a = align(_streams(angular_velocity=_vec("/imu", "imu", t_om, np.tile([0.0, 0.0, 0.5], (t_om.size, 1)))))
    assert a.vel_t_ns[-1] == 6 * NS
    assert a.det_t_ns.tolist() == [int(5.5 * NS), 6 * NS]
    assert "1 detection frame outside the velocity span dropped" in a.notes


def test_time_base_keeps_the_last_sample_of_each_stamp():
    # a driver stamping its IMU samples in pairs: half the time base's periods were zero, and the noise estimate
    # of riekf and batch (median period) divided by zero; the estimators integrated only the later of each pair
    t_om = np.repeat(np.arange(0, 2.0, 0.02), 2)
    w = np.column_stack([np.zeros(t_om.size), np.zeros(t_om.size), np.tile([0.1, 0.5], t_om.size // 2)])
    a = align(_streams(angular_velocity=_vec("/imu", "imu", t_om, w)))
    assert np.all(np.diff(a.vel_t_ns) > 0) and a.vel_t_ns.size == 98  # the stamps inside /odom's 0-1.95 s
    assert np.allclose(a.omega, (so3_exp(np.array([0.0, 0.0, np.pi / 2])) @ np.array([0.0, 0.0, 0.5]))[None])
    assert "/imu: 100 angular-velocity samples dropped, each sharing its stamp with a later one" in "\n".join(a.notes)


def test_a_sensor_without_frame_id_is_said_to_be_taken_as_the_body():
    # detections without a frame id were moved by no transform with only the reader's 'empty frame id' (figure-8
    # sample log: APE 0.72 m, rotation APE 138 deg, riekf lost)
    s = _streams()
    s.detections = DetectionStream(**{**s.detections.__dict__, "frame_id": ""})
    a = align(s)
    assert "/fid: no frame id: taken as the body frame 'base_link' (no transform applied)" in a.notes
    assert a.det_y.shape[0] and all(any(np.array_equal(y, x) for x in s.detections.xyz) for y in a.det_y)


def test_a_transform_dropped_as_nan_is_named_where_it_is_missing():
    # a /tf_static camera transform with a NaN: the run said only "'camera' is in no transform"
    rows = TfRows(
        "/tf_static",
        np.zeros(2, np.int64),
        np.zeros(2, np.int64),
        np.array([0, 0], np.int32),
        np.array([1, 2], np.int32),
        np.array([[0.1, 0, 0, 0, 0, 0, np.nan], [0, 0, 0, 0, 0, 0, 1.0]]),
        ["base_link", "camera", "imu"],
    )
    found, warnings, dropped, _ = static_transforms(rows)
    assert [(t.parent, t.child) for t in found] == [("base_link", "imu")]
    assert warnings == ["1 NaN/Inf static transform dropped: base_link->camera"]
    assert dropped == {("base_link", "camera"): warnings[0]}
    s = _streams(static_tf=found, static_tf_dropped={e: f"/tf_static: {w}" for e, w in dropped.items()})
    with pytest.raises(
        InputError,
        match=r"'camera' is in no transform; .*; /tf_static: 1 NaN/Inf static transform "
        r"dropped: base_link->camera; set frames.body",
    ):
        align(s)


def test_a_zero_quaternion_on_tf_static_is_named_as_such_not_as_nan(tmp_path):
    # a generated log whose /tf_static IMU transform has the quaternion (0, 0, 0, 0) (how some drivers say 'unknown'):
    # the error called it "1 NaN/Inf static transform dropped", which sent the user looking for NaNs
    from dataclasses import replace

    from slamobs.pipeline.config import RunConfig
    from slamobs.pipeline.run import prepare_log
    from slamobs.pipeline.simulate import simulate, write_log

    sim = simulate("figure8", seed=5, duration=5.0)
    imu = next(t for t in sim.static_tf if t.child == "imu_link")
    unknown = replace(imu, quat_xyzw=np.zeros(4))
    static_tf = [t if t is not imu else unknown for t in sim.static_tf]
    log = write_log(replace(sim, static_tf=static_tf), tmp_path / "z.mcap")
    with pytest.raises(InputError) as err:
        prepare_log(log, RunConfig(), directions=False, noise=False)
    said = str(err.value)
    assert str(log) in said and "[/imu/data]" in said and "NaN" not in said, said
    assert "/tf_static: 1 static transform with a zero quaternion (0, 0, 0, 0: not a rotation) dropped: " in said
    assert "base_link->imu_link" in said


def test_velocities_recorded_on_two_clocks_are_not_sent_to_time_source_record():
    # a generated figure 8 whose IMU has header stamps and record times since boot (the odometry on UNIX time): the
    # error said "try time.source: auto or record", neither of which can join them
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    streams = expected_streams(simulate("figure8", seed=5, duration=5.0), path="boot.mcap")
    om = streams.angular_velocity
    boot = om.rec_ns - om.rec_ns[0] + 100 * 10**9  # 100 s after boot
    streams.angular_velocity = replace(om, t_ns=boot + (om.t_ns - om.rec_ns), rec_ns=boot)
    for source in ("header", "record"):
        with pytest.raises(InputError) as err:
            align(streams, time_source=source)
        said = str(err.value)
        assert said.startswith("boot.mcap: angular velocity (/imu/data: ") and "time.source: auto" not in said
        assert (
            "; their record times do not overlap either (/imu/data: 100.000 .. 105.000 s, /odom: 1700000000" in said
        ), said
        assert "(one on a clock since boot, the other on UNIX time)" in said and "no time.source joins them" in said
    streams.angular_velocity = replace(om, t_ns=boot)  # its stamps alone since boot: record time joins them
    with pytest.raises(
        InputError, match="do not overlap in time; is one of them on another clock .* time.source: auto"
    ):
        align(streams)


def test_two_tags_that_share_an_id_are_named():
    # a generated figure 8 with one tag's id given to another tag all along (two tag families with the same id):
    # 118 repeats within a frame dropped with a plain note, the second tag's other 39 detections taken as the
    # first's, its landmark gone from the map, and no warning
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    sim = simulate("figure8", seed=5, duration=20.0)
    assert not [n for n in align(expected_streams(sim)).notes if n.startswith("warning")]
    det = sim.detections
    ids = det.ids.copy()
    ids[ids == 60] = 10
    notes = align(expected_streams(replace(sim, detections=replace(det, ids=ids)))).notes
    said = [n for n in notes if "two tags share the id" in n]
    assert len(said) == 1 and said[0].startswith("warning: ") and " id 10 seen twice" in said[0], notes


def test_an_id_misread_in_one_frame_is_not_named_only_as_two_tags_sharing_it():
    """One detection's id misread as another tag's in view (round 10's seed=4382, 1 % of the ids misread at random):
    the warning said only `two tags share the id (two tag families ...)`, a cause the log does not have; it now
    counts the frames holding the id and names a misread id beside two tags."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    sim = simulate("figure8", seed=5, duration=20.0)
    det = sim.detections
    frame = np.repeat(np.arange(det.t_ns.size), np.diff(det.offsets))
    both = np.flatnonzero((np.bincount(frame[det.ids == 10], minlength=det.t_ns.size) > 0) & (np.diff(det.offsets) > 1))
    k = next(i for i in range(det.offsets[both[0]], det.offsets[both[0] + 1]) if det.ids[i] != 10)
    ids = det.ids.copy()
    ids[k] = 10  # one detection in one frame misread as id 10, tag 10 beside it
    seen = int(np.unique(frame[ids == 10]).size)
    notes = align(expected_streams(replace(sim, detections=replace(det, ids=ids)))).notes
    said = [n for n in notes if "two tags share the id" in n]
    assert len(said) == 1 and f" id 10 seen twice in 1 of the {seen} frames holding it" in said[0], notes
    assert "or another tag's id was misread there" in said[0]


def test_velocity_checks_by_columns_give_numpys_answers():
    """The velocity streams' checks compare rows a column at a time (``blocks.equal_rows``) and sum squares by
    columns (``blocks.row_squares3``, the bias check's rms): the same booleans and bits as the NumPy reductions
    along the short axis they replace (NaN rows, signed zeros, overflow, strided rows), which take ~3x as long."""
    from slamobs.pipeline.blocks import equal_rows, row_squares3

    rng = np.random.default_rng(5)
    a = rng.integers(-2, 3, size=(4000, 3)).astype(np.float64)
    b = a.copy()
    b[rng.integers(0, 4000, 500), rng.integers(0, 3, 500)] += 1.0
    a[7], b[9] = np.nan, -0.0
    a[9] = 0.0
    for x, y in ((a, b), (a[::2], b[::2]), (a[:, :2], b[:, :2]), (a[:0], b[:0])):
        assert np.array_equal(equal_rows(x, y), np.all(x == y, axis=1))
        assert np.array_equal(~equal_rows(x, y), np.any(x != y, axis=1))
    x = rng.normal(size=(5000, 3)) * 10.0 ** rng.integers(-160, 160, size=(5000, 1))
    with np.errstate(over="ignore", under="ignore"):
        for rows in (x, x[::3], x[:0]):
            assert row_squares3(rows).tobytes() == np.sum(rows**2, axis=1).tobytes()


@pytest.mark.parametrize("late_s", [0.3, 2.0])
def test_a_gyro_stamped_off_the_odometrys_clock_is_named(late_s):
    """The IMU's stamps and record times both 0.3 s (2 s) late against the odometry's and the detections' (a log
    converted with record time = stamp, the IMU on another clock): no header-against-record rule sees it; a
    generated figure 8 so written gave riekf 0.53 m against 0.011 m (2 s: lost), exit 0, no warning (session 21).
    The odometry's own angular velocity, against the gyro's, names it; the log as generated says nothing."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    sim = simulate("figure8", seed=5, duration=20.0)
    assert not [n for n in align(expected_streams(sim, "x.mcap")).notes if "stamps look" in n]
    shift = int(late_s * NS)
    imu = replace(sim.imu, t_ns=sim.imu.t_ns + shift, rec_ns=sim.imu.rec_ns + shift)
    said = [n for n in align(expected_streams(replace(sim, imu=imu), "x.mcap")).notes if "stamps look" in n]
    assert len(said) == 1, said
    assert said[0].startswith(f"warning: /imu/data: its angular velocity's stamps look {late_s:.3f} s late against")


@pytest.mark.parametrize(("late_s", "offset_s"), [(0.3, 0.0), (-0.3, 0.1)])
def test_a_gyro_stamped_late_is_moved_onto_the_odometrys_clock_not_read_as_a_detection_offset(late_s, offset_s):
    """Issue 23 (session 27): the IMU's stamps and record times 0.3 s late, the detections on time. Its lag was
    only warned of, and the detection pairs' offset search, dead-reckoning on the late gyro, read it as the
    detections' offset and applied +0.277 s (a 30 s log: riekf 0.52 m, batch 0.58 m against 0.012 / 0.0065 as
    generated). Now the gyro's stamps are moved onto the odometry's clock first and the note says so: no offset is
    applied where there is none, and a real one (detections 0.1 s late beside a gyro 0.3 s early) is found as on a
    log without the lag (main: -0.425 s applied for a true -0.1)."""
    from dataclasses import replace

    from slamobs.pipeline.observers import time_offset
    from slamobs.pipeline.simulate import expected_streams, simulate

    sim = simulate("figure8", seed=5, duration=20.0, detection_offset=offset_s)
    shift = int(late_s * NS)
    imu = replace(sim.imu, t_ns=sim.imu.t_ns + shift, rec_ns=sim.imu.rec_ns + shift)
    stream = align(expected_streams(replace(sim, imu=imu), "x.mcap"))
    est = time_offset.estimate(stream)
    assert abs(est["estimate_s"] + offset_s) < 0.01, est
    assert est["applied"] == (offset_s != 0.0), est
    (said,) = [n for n in stream.notes if "stamps look" in n]
    assert f"The run moved its stamps by {-late_s:+.3f} s onto /odom's clock" in said, said


def test_a_gyro_late_on_a_ground_robot_is_named_or_said_unchecked():
    """A generated ground robot turns slowly: its IMU 0.3 s late fit only 1.9x better so shifted, under the check's
    4x, and the run said nothing (session 23). Where a 0.3 s lag would fit under 4x worse the check now warns when the
    lag gains half of that, and otherwise says the lag could not be checked (too little rotation): never silent."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    sim = simulate("ground", seed=9647, duration=60.0)
    notes = align(expected_streams(sim, "x.mcap")).notes
    assert not [n for n in notes if "stamps look" in n], notes
    (unchecked,) = [n for n in notes if "could not be checked" in n]
    assert unchecked.startswith("/imu/data: its stamps' lag against /odom's own angular velocity could not be checked")
    assert "too little rotation (a lag of 0.3 s would fit only " in unchecked and "shorter lags go unseen" in unchecked
    shift = int(0.3 * NS)
    imu = replace(sim.imu, t_ns=sim.imu.t_ns + shift, rec_ns=sim.imu.rec_ns + shift)
    said = [n for n in align(expected_streams(replace(sim, imu=imu), "x.mcap")).notes if "stamps look" in n]
    assert len(said) == 1 and "slow turns: a 0.3 s lag fits only" in said[0], said
    late = float(said[0].split("stamps look ")[1].split(" s late")[0])
    assert 0.25 <= late <= 0.35, said
    assert f"The run moved its stamps by {-late:+.3f} s onto /odom's clock" in said[0], said  # session 27


def _aligned_imu_late(sim, late_s: float):
    """The generated log ``sim`` aligned with its IMU's stamps and record times ``late_s`` late."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams

    shift = int(late_s * NS)
    imu = replace(sim.imu, t_ns=sim.imu.t_ns + shift, rec_ns=sim.imu.rec_ns + shift)
    return align(expected_streams(replace(sim, imu=imu), "x.mcap"))


@pytest.mark.parametrize("late_s", [0.0, 0.3])
def test_a_slow_ground_logs_gyro_is_moved_only_by_a_lag_both_halves_of_the_span_find(late_s):
    """A clean ten-minute ground robot (100 Hz IMU, 10 Hz odometry, the densities of round 8's seed=3983) on slow
    turns: the best of the fine grid's lags fit its own samples 1.05x better 0.100 s early, over the slow-turn rule's
    1.04x, and the run moved the IMU by +0.100 s on noise (session 36). A lag is now moved only when the lag each half
    of the span finds fits the other half better too by as much: the clean log's stays (a note: could not be
    checked), the same log's IMU 0.3 s late is still moved back by most of it."""
    from dataclasses import replace

    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import NoiseModel, simulate

    nm = replace(
        NoiseModel(),
        gyro=10 * DEFAULTS["gyro"][0] * np.sqrt(100.0),
        odom_linear=5 * DEFAULTS["velocity"][0] * np.sqrt(10.0),
    )
    stream = _aligned_imu_late(
        simulate("ground", noise=nm, duration=600.0, seed=3983, imu_rate=100.0, odom_rate=10.0), late_s
    )
    said = [n for n in stream.notes if "stamps look" in n]
    if late_s == 0.0:
        assert stream.gyro_moved_s == 0.0 and not said, said
        assert [n for n in stream.notes if "could not be checked" in n], stream.notes
    else:
        assert len(said) == 1 and -0.4 < stream.gyro_moved_s < -0.15, (stream.gyro_moved_s, said)


@pytest.mark.parametrize(("scenario", "late_s"), [("ground", 0.0), ("handheld", 0.1)])
def test_a_2hz_odometrys_lag_moves_the_imu_only_by_many_standard_errors(scenario, late_s):
    """2 Hz odometry on a ground robot's slow turns (180 s, round 11's seed=4632 kind, every clock right): the best of
    the fine grid's lags fit the other half of the span 1.04x better than as stamped, over the slow-turn rule's 1.03x
    but 0.9 standard errors of the misfits' difference from none, and the run moved the right IMU by -0.100 s
    (session 39). A lag is now moved only where that held-out gain is ``GYRO_LAG_SIGMAS`` standard errors or more:
    the ground robot's IMU stays, a hand-held rig's 2 Hz odometry beside an IMU 0.1 s late (20 standard errors) is
    still moved back by it."""
    from dataclasses import replace

    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import NoiseModel, simulate
    from slamobs.pipeline.simulate.scenarios import handheld

    nm = replace(
        NoiseModel(),
        gyro=30 * DEFAULTS["gyro"][0] * np.sqrt(200.0),
        odom_linear=10 * DEFAULTS["velocity"][0] * np.sqrt(2.0),
    )
    sc, duration = ("ground", 180.0) if scenario == "ground" else (handheld(), 90.0)
    stream = _aligned_imu_late(
        simulate(sc, noise=nm, duration=duration, seed=4787, imu_rate=200.0, odom_rate=2.0), late_s
    )
    said = [n for n in stream.notes if "stamps look" in n]
    if late_s == 0.0:
        assert stream.gyro_moved_s == 0.0 and not said, said
    else:
        assert len(said) == 1 and abs(stream.gyro_moved_s + late_s) < 0.02, (stream.gyro_moved_s, said)


@pytest.mark.parametrize("odom_hz", [2.0, 10.0])
def test_a_velocity_stream_too_slow_for_the_motion_is_named_from_the_imu(odom_hz):
    """A hand-held rig's 1.8 Hz step bob (4 cm) in 2 Hz odometry, above its 1 Hz Nyquist frequency (round 11's
    seed=4631): the samples fold it onto slower motion, the velocity level came out 1.3-3.4x the white truth and
    nothing said why (session 39). The IMU's accelerometer sees the bob: a warning names the stream too slow, the
    motion's velocity (0.32 m/s RMS, the bob's 0.04 * 2 pi 1.8 / sqrt 2) and what to do; at 10 Hz nothing."""
    from dataclasses import replace

    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate import NoiseModel, expected_streams, simulate
    from slamobs.pipeline.simulate.scenarios import handheld

    nm = replace(NoiseModel(), odom_linear=10 * DEFAULTS["velocity"][0] * np.sqrt(odom_hz))
    sim = simulate(handheld(), noise=nm, duration=60.0, seed=4795, imu_rate=200.0, odom_rate=odom_hz)
    said = [n for n in align(expected_streams(sim, "x.mcap")).notes if "too slow for the motion" in n]
    if odom_hz == 10.0:
        assert not said, said
        return
    assert len(said) == 1 and said[0].startswith("warning: /odom: its linear velocity at 2 Hz is too slow"), said
    rms = float(said[0].split("accelerometer shows ")[1].split(" m/s RMS")[0])
    assert abs(rms - 0.04 * 2 * np.pi * 1.8 / np.sqrt(2)) < 0.03, said
    assert "(most near 1.8 Hz)" in said[0] and "record a faster odometry topic" in said[0], said


def test_the_coarse_lag_grid_by_fft_is_the_fit_per_lag():
    """The gyro-lag check's coarse grid (every lag of ±20 s at 0.05 s) sums the fit's pairs by FFT on a uniform
    grid (session 22: 0.005 CPU s on a 90 s log where the fit per lag took 0.035-0.05): on odometry stamped on that
    grid it gives the fit per lag's misfits, lags that leave too little overlap included, and its best lag is the
    IMU's."""
    from slamobs.pipeline.alignment import GYRO_LAG_MAX_S, GYRO_LAG_STEP_S, coarse_lag_misfits, lag_misfits

    rng = np.random.default_rng(11)
    t_g = np.sort(rng.uniform(0.0, 50.0, 12000)) * NS  # ends 5 s after the odometry: the late lags see too little
    t_g = t_g.astype(np.int64)
    w_g = np.cumsum(rng.normal(size=(12000, 3)), axis=0) * 0.01  # a wandering rate, nothing periodic
    step = int(GYRO_LAG_STEP_S * NS)
    t_o = 25 * NS + step * np.arange(400)  # 20 s of odometry on the coarse step
    rot = so3_exp(np.array([0.3, -1.2, 2.0]))
    w_o = np.vstack([w_g[np.searchsorted(t_g, t + int(0.7 * NS))] for t in t_o]) @ rot.T + 0.02  # IMU 0.7 s late
    w_o += rng.normal(size=w_o.shape) * 1e-3
    half = step  # the odometry's mean over its stamp and the two either side (where they are)
    b = np.vstack([w_o[np.abs(t_o - t) <= half].mean(axis=0) for t in t_o])
    lags = np.arange(-GYRO_LAG_MAX_S, GYRO_LAG_MAX_S + 0.5 * GYRO_LAG_STEP_S, GYRO_LAG_STEP_S)
    by_lag = lag_misfits(t_g, w_g, t_o, b, lags, half)
    by_fft = coarse_lag_misfits(t_g, w_g, t_o, w_o, half)
    assert np.isnan(by_lag).any() and np.isfinite(by_lag).sum() > 500
    np.testing.assert_allclose(by_fft, by_lag, rtol=1e-8, atol=1e-10)
    assert lags[np.nanargmin(by_fft)] == pytest.approx(0.7)


def test_id_time_order_is_lexsorts_order():
    """``blocks.id_time_order`` (the resightings check's and the time offset's pairs' sort): NumPy's radix sort of
    16-bit ids where the times are sorted and the ids fit, ``np.lexsort`` otherwise; the same order either way."""
    from slamobs.pipeline.blocks import id_time_order

    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 100, 5000))
    for ids in (
        rng.integers(0, 40, 5000),
        rng.integers(-300, 300, 5000),
        rng.integers(0, 1 << 16, 5000),
        rng.integers(-(1 << 20), 1 << 20, 5000),
        np.zeros(0, np.int64),
    ):
        for times in (t[: ids.size], rng.uniform(0, 100, ids.size)):  # sorted, and not
            assert np.array_equal(id_time_order(ids, times), np.lexsort((times, ids)))


def test_a_camera_extrinsic_published_once_on_tf_names_tf_not_the_time_span():
    """A fixed camera's extrinsic published once on /tf instead of /tf_static (session 24): every detection frame
    fell outside the /tf edge's span and the error said "no landmark detections inside the velocity time span",
    naming neither /tf nor the camera's frame. Now it names the transform and where it belongs."""
    s = _streams()
    cam = s.static_tf[0]
    t = np.array([5 * NS])
    once = TransformSeries("/tf", "base_link", "camera", t, t, cam.translation[None], cam.quat_xyzw[None])
    with pytest.raises(InputError) as err:
        align(_streams(static_tf=s.static_tf[1:], tf=[once]))
    said = str(err.value)
    assert "[/fid]" in said and "/tf's transform from frame 'camera' to body 'base_link'" in said, said
    assert "publish a fixed extrinsic on /tf_static" in said, said


def test_a_gyro_in_degrees_per_second_beside_its_accelerometer_does_not_crash_the_alignment():
    """An IMU whose angular_velocity is in deg/s, its accelerometer on the same topic (session 24): every sample's
    body acceleration (omega x v) is far off gravity, the tilt check trusted none, np.bincount of nothing gave an int
    array and `slamobs run` ended in a numpy casting traceback. Now the alignment runs (the detection pairs name the
    unit: 464x better divided by 57.3 on a generated figure 8)."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    sim = simulate("figure8", seed=5, duration=20.0)
    degs = replace(sim.imu, gyro=sim.imu.gyro * (180.0 / np.pi))
    a = align(expected_streams(replace(sim, imu=degs), "x.mcap"))
    assert a.omega.shape[0] > 1000 and float(np.abs(a.omega).max()) > 20.0


def test_one_landmark_id_seen_at_several_places_is_named():
    """A tag id misdecoded: a tenth of a generated figure 8's detections given id 9999 (session 24): each is another
    tag, so landmark 9999 sits nowhere; fast-adaptation (no gate) ran at 1.09 m against 0.12 m, exit 0, no word.
    Its consecutive detections, one moved by the velocities to the next, miss by metres; the log as generated says
    nothing (every id within 1.3x of the run's median misfit; MR.CLAM's at most 2.3x)."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    streams = expected_streams(simulate("figure8", seed=5, duration=10.0), "x.mcap")
    assert not [n for n in align(streams).notes if "one id seen at several places" in n]
    ids = streams.detections.ids.copy()
    ids[::10] = 9999
    said = [n for n in align(replace(streams, detections=replace(streams.detections, ids=ids))).notes if "9999" in n]
    assert len(said) == 1 and said[0].startswith("warning: /fiducial_transforms: landmark id 9999 ("), said
    assert "one id seen at several places" in said[0], said


def test_a_landmark_id_misread_now_and_then_is_named_by_its_distance_to_the_other_ids():
    """A tag id misread rarely: one detection every second of a generated figure 8 given id 9999 (each another tag,
    no two within the 0.5 s the check above pairs; every 2 s over 40 s: fast-adaptation ran at 0.68 m against 0.12 m,
    its map 1.44 m against 0.11 m, exit 0, no word, session 25). Its distance to the other ids seen in the same frame
    changes by metres (the other ids' by 1.2x the run's median at most); the log as generated, or with one
    landmark's detections misread (9999 then one more static landmark, harmless), says nothing."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    streams = expected_streams(simulate("figure8", seed=5, duration=20.0), "x.mcap")
    det = streams.detections

    def said(ids):
        notes = align(replace(streams, detections=replace(det, ids=ids))).notes
        return [n for n in notes if "9999" in n]

    frames = np.flatnonzero(np.diff(det.offsets) > 0)
    every_s = np.searchsorted(det.t_ns[frames], det.t_ns[frames[0]] + np.arange(0, 20) * 1_000_000_000)
    ids = det.ids.copy()
    sizes = np.diff(det.offsets)[frames[every_s]]
    ids[det.offsets[frames[every_s]] + (3 * np.arange(20)) % sizes] = 9999  # one detection of a frame every second
    got = said(ids)
    assert len(got) == 1 and got[0].startswith("warning: /fiducial_transforms: landmark id 9999 ("), got
    assert "its distance to the other ids seen in the same frame changes" in got[0], got
    assert not said(np.where(det.ids == det.ids[0], 9999, det.ids))  # one static landmark under another id


def test_a_gyro_whose_frame_reaches_the_body_turned_is_named_by_the_odometrys_own_turn():
    """An IMU rolled 90 deg (its yaw rate on its y axis, as robot_localization's test1 IMU reads it) whose frame the
    log does not transform, listed in frames.assume_identity as info suggests: fast-adaptation absorbed the turn into
    its gyro bias (a generated figure 8: APE 0.103 m against 0.046 m, gyro bias error 0.45 rad/s, exit 0, no word,
    session 26). The odometry's own angular velocity turns about z where the gyro, so taken, turns about y: named.
    The same IMU with its extrinsic on /tf_static, and the log as generated, say nothing."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate
    from slamobs.pipeline.simulate.scenarios import customize, get_scenario

    sim = simulate(customize(get_scenario("figure8"), imu_rpy_deg=(90.0, 0.0, 0.0)), seed=5, duration=20.0)
    streams = expected_streams(sim, "x.mcap")

    def said(s, **kw):
        return [n for n in align(s, **kw).notes if "its gyro turns about" in n]

    untold = replace(streams, static_tf=[t for t in streams.static_tf if t.child != "imu_link"])
    got = said(untold, identity_frames=("imu_link",))
    assert len(got) == 1 and got[0].startswith("warning: /imu/data: in the body frame its gyro turns about"), got
    assert "90 deg apart" in got[0] and "'imu_link' reaches the body turned" in got[0], got
    assert not said(streams)  # the turn on /tf_static: the gyro is brought into the body right
    assert not said(expected_streams(simulate("figure8", seed=5, duration=20.0), "x.mcap"))


def test_a_gyro_mounted_upside_down_and_taken_as_the_body_is_named():
    """imu_tools' Phidgets sample IMU is mounted upside down (its accelerometer reads -9.88 m/s^2 on z) and its log
    has no TF: `info` says to list its frame in frames.assume_identity if it is mounted as the body. So listed on a
    generated figure 8 whose IMU is rolled 180 deg: the gyro turns about the odometry's axis the other way, and the
    check took the angle between the axes unsigned (2 deg): fast-adaptation 0.148 m against 0.046 m with the
    extrinsic, its z gyro bias off by 0.64 rad/s, exit 0, no word (session 30). Now the reversed turn is named; the
    same IMU with its /tf_static edge says nothing."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate
    from slamobs.pipeline.simulate.scenarios import customize, get_scenario

    streams = expected_streams(
        simulate(customize(get_scenario("figure8"), imu_rpy_deg=(180.0, 0.0, 0.0)), seed=5, duration=20.0), "x.mcap"
    )

    def said(s, **kw):
        return [n for n in align(s, **kw).notes if "its gyro turns about" in n]

    untold = replace(streams, static_tf=[t for t in streams.static_tf if t.child != "imu_link"])
    turned = align(untold, identity_frames=("imu_link",)).gyro_turn
    assert turned is not None and turned["angle_deg"] > 150.0, turned
    got = said(untold, identity_frames=("imu_link",))
    assert len(got) == 1 and "it turns the other way: an IMU mounted upside down" in got[0], got
    assert "'imu_link' reaches the body turned" in got[0], got
    assert not said(streams)  # the roll on /tf_static: the gyro is brought into the body right


def test_an_odometry_stuck_while_the_gyro_turns_is_named():
    """A figure 8 whose odometry reads a zero twist (linear and angular) over 6 of its 20 s (a frozen driver): riekf
    0.81 m against 0.011 m on the 40 s log so rewritten, warned only as a velocity scale "in another unit or scale?"
    (session 27). Zero while the gyro turns: named with its stretch; the log as generated, and a zero linear velocity
    where the odometry's own angular velocity turns (a robot turning on the spot), say nothing."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    streams = expected_streams(simulate("figure8", seed=5, duration=20.0), "x.mcap")

    def said(s):
        return [n for n in align(s).notes if "reads exactly zero" in n]

    assert not said(streams)
    lv, tw = streams.linear_velocity, streams.twist_angular
    held = (lv.t_ns >= lv.t_ns[0] + 8 * NS) & (lv.t_ns < lv.t_ns[0] + 14 * NS)
    v, w = lv.xyz.copy(), tw.xyz.copy()
    v[held] = 0.0
    on_the_spot = replace(streams, linear_velocity=replace(lv, xyz=v))
    assert not said(on_the_spot)
    w[held] = 0.0
    got = said(replace(on_the_spot, twist_angular=replace(tw, xyz=w)))
    assert len(got) == 1 and got[0].startswith("warning: /odom: its twist reads exactly zero for 6.0 s in 1 stretch"), (
        got
    )
    assert "(8.0-14.0 s into the log) while /imu/data's gyro turns at a median" in got[0], got


def _vio_on_rig(streams):
    """``streams`` with TagSLAM test 22's layout: the odometry's twist in 'camera_pose_frame', which TF places 120 deg
    about (1, -1, 1) and 0.032 m off the base frame 'rig' (base_link renamed)."""
    from dataclasses import replace

    vio = Transform("rig", "camera_pose_frame", np.array([0.0, 0.032, 0.0]), np.array([0.5, -0.5, 0.5, 0.5]))
    return replace(
        streams,
        linear_velocity=replace(streams.linear_velocity, frame_id="camera_pose_frame"),
        twist_angular=replace(streams.twist_angular, frame_id="camera_pose_frame"),
        static_tf=[*(replace(t, parent="rig") if t.parent == "base_link" else t for t in streams.static_tf), vio],
    )


def test_an_odometry_frame_beside_the_base_says_where_tf_places_the_base():
    """An odometry whose twist is in a frame 0.5 m beside base_link, TF giving it: the run takes that frame as the
    body, right by itself, but a truth of base_link is 0.5 m off it (a figure 8: riekf APE 0.49 m, 0.011 m with
    frames.body: base_link), and the body-frame note spoke of a turned truth only (session 27). Now TF's placing of
    the base is said with the key that makes it the body; the log as generated says nothing of it."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate

    streams = expected_streams(simulate("figure8", seed=5, duration=10.0), "x.mcap")

    def said(s):
        return [n for n in align(s).notes if n.startswith("TF places the body frame")]

    assert not said(streams)
    lever = Transform("base_link", "odom_lever", np.array([0.0, 0.5, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))
    moved = replace(
        streams,
        linear_velocity=replace(streams.linear_velocity, frame_id="odom_lever"),
        twist_angular=replace(streams.twist_angular, frame_id="odom_lever"),
        static_tf=[*streams.static_tf, lever],
    )
    got = said(moved)
    assert got == [
        "TF places the body frame 'odom_lever' against 'base_link' (static, from /tf_static or the cameras: files: "
        "turned 0.0 deg, offset 0.500 m): a truth of 'base_link' is that far off these poses, the offset turning with "
        "the robot, and is turned by that angle; frames.body: base_link makes the base the body"
    ], got
    # TagSLAM's rig: its VIO odometry's child frame (test 22's camera_pose_frame) is turned 120 deg against the rig
    # its reference trajectory tracks, the transform from tagslam.yaml's T_body_odom (a cameras: file); it went
    # unnamed, and the report offered frames.truth_rotation (evaluation only) where frames.body: rig mends the run
    on_rig = _vio_on_rig(streams)  # 120 deg about (1, -1, 1)
    assert said(on_rig) == [
        "TF places the body frame 'camera_pose_frame' against 'rig' (static, from /tf_static or the cameras: files: "
        "turned 120.0 deg, offset 0.032 m): a truth of 'rig' is that far off these poses, the offset turning with the "
        "robot, and is turned by that angle; frames.body: rig makes the base the body"
    ], said(on_rig)


def test_a_truth_carried_from_the_base_is_not_offered_frames_body():
    """h-bodyframe's notes on TagSLAM test 22 with ``frames.truth: rig`` (benchmarks/real_logs.py's config): the run
    carries the rig's truth to the body, yet its notes said a truth of the base "looks turned" and offered
    ``frames.body: rig``, advice for what was already done. With the truth carried, the body note says so and the
    base note is not given, in the run and in the report (``sections.body_frame_notes``); without it both stand."""

    from slamobs.pipeline.evaluation.sections import body_frame_notes
    from slamobs.pipeline.simulate import expected_streams, simulate

    on_rig = _vio_on_rig(expected_streams(simulate("figure8", seed=5, duration=10.0), "x.mcap"))
    plain, carried = align(on_rig), align(on_rig, truth_frame="rig")
    assert [n for n in plain.notes if n.startswith("TF places the body frame")], plain.notes
    assert carried.truth_body is not None and carried.truth_body["frame"] == "rig"
    assert not [n for n in carried.notes if n.startswith("TF places the body frame")], carried.notes
    body = [n for n in carried.notes if n.startswith("the run took 'camera_pose_frame'")]
    assert len(body) == 1 and "looks turned" not in body[0] and "the truth, of 'rig', is carried" in body[0], body
    assert any(n.startswith("the truth is of the frame 'rig'") for n in carried.notes), carried.notes
    report = {"ape": {"truth_frame_turn": {"angle_deg": 12.0}}}
    run_input = {"body_frame": "camera_pose_frame", "body_frame_from": carried.body_from}
    run_input |= {"base_frame": carried.base_frame, "truth_body": carried.truth_body}
    said = body_frame_notes(report, run_input)
    assert said == [body[0]], said
    said = body_frame_notes(report, {**run_input, "truth_body": None})
    assert len(said) == 2 and "frames.body: rig makes the base the body" in said[1], said


def _warned_sim():
    """A generated figure 8 whose IMU is stamped 0.3 s late with its gyro's x and y swapped, and a tenth of its
    detections given id 9999: two warn-only checks speak (its accelerometer, the misread id), and the gyro's lag, no
    warn-only check since its stamps are moved by it (session 27)."""
    from dataclasses import replace

    from slamobs.pipeline.simulate import simulate

    sim = simulate("figure8", seed=5, duration=30.0)
    ids = sim.detections.ids.copy()
    ids[::10] = 9999
    late = int(0.3 * NS)
    imu = replace(sim.imu, t_ns=sim.imu.t_ns + late, rec_ns=sim.imu.rec_ns + late, gyro=sim.imu.gyro[:, [1, 0, 2]])
    return replace(sim, imu=imu, detections=replace(sim.detections, ids=ids))


WARNED = ("stamps look 0.300 s late", "landmark id 9999 (", "the gyro reads as if its x and y were swapped")


def test_the_warn_only_checks_run_later_give_their_notes_in_their_places():
    """``align(warn_only_later=True)`` leaves the checks whose result is a note only to its caller (the run computes
    them beside the observer, session 26); their notes joined in are the notes ``align`` gives, in its order (the
    misread id's warning before the accelerometer's, each among the notes of its stream). The IMU turned by an
    extrinsic the run is told to ignore: the gyro's axes against the odometry's own turn are no warn-only check (the
    detection pairs' misread check reads that turn, ``gyro_turn``): said by ``align`` itself either way; nor the
    gyro's lag (its stamps moved by it)."""
    from slamobs.pipeline.simulate import expected_streams, simulate
    from slamobs.pipeline.simulate.scenarios import customize, get_scenario

    rolled = simulate(customize(get_scenario("figure8"), imu_rpy_deg=(90.0, 0.0, 0.0)), seed=5, duration=20.0)
    for sim, kw, said, deferred in (
        (_warned_sim(), {}, WARNED[1:], True),
        (_warned_sim(), {}, WARNED[:1], False),
        (rolled, {"override_identity": ("imu_link",)}, ("its gyro turns about",), False),
    ):
        now = align(expected_streams(sim, "x.mcap"), **kw)
        later = align(expected_streams(sim, "x.mcap"), warn_only_later=True, **kw)
        assert now.warn_only is None and all(any(s in n for n in now.notes) for s in said), now.notes
        assert any(s in n for n in later.notes for s in said) is not deferred, later.notes
        assert later.warn_only.joined(later.notes, later.warn_only.run()) == now.notes
    assert later.gyro_turn is not None and later.gyro_turn == now.gyro_turn


def test_a_run_s_notes_are_the_same_with_the_warn_only_checks_beside_its_observer(tmp_path, monkeypatch):
    """``slamobs run`` computes the alignment's warn-only checks after the alignment, on a thread beside the observer
    (0.17 of the one-hour log's 0.30 CPU s of align off the main thread, session 26): run.json's notes are those of
    a run that computed them in the alignment, every warning in its place."""
    import json

    from slamobs.pipeline import alignment
    from slamobs.pipeline import run as run_mod
    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.simulate import write_log

    log = write_log(_warned_sim(), tmp_path / "warned.mcap")
    aligned, ran = [], []  # whether the log was aligned when the checks ran
    checks, prepare = alignment.WarnOnly.run, run_mod.prepare_log
    monkeypatch.setattr(alignment.WarnOnly, "run", lambda self: ran.append(bool(aligned)) or checks(self))

    def prepared(*args, later: bool, **kw):
        aligned.clear()
        out = prepare(*args, **{**kw, "warn_only_later": kw["warn_only_later"] and later})
        aligned.append(True)
        return out

    config = {"evaluation": {"plots": False}}
    for name, later in (("beside", True), ("in-align", False)):
        monkeypatch.setattr(run_mod, "prepare_log", lambda *a, later=later, **kw: prepared(*a, later=later, **kw))
        run_log(log, tmp_path / name, config=config)
        assert ran[-1] == later
    # the first run in a process with a cold kernel cache (a clean clone, an xdist worker that ran no estimator yet)
    # says what it compiled, the second not: that note is no alignment note and is left out of the comparison
    beside, in_align = (
        [n for n in json.loads((tmp_path / d / "run.json").read_text())["notes"] if not n.startswith("first run: ")]
        for d in ("beside", "in-align")
    )
    assert all(any(s in n for n in beside) for s in WARNED), beside
    assert beside == in_align


def test_one_sample_dropped_is_counted_in_the_singular():
    # "1 angular-velocity samples dropped": the counts of the alignment's notes go through errors.plural
    t_om = np.arange(0, 2.0, 0.02)
    t_om = np.insert(t_om, 10, t_om[10])  # one stamp twice
    w = np.tile([0.0, 0.0, 0.5], (t_om.size, 1))
    a = align(_streams(angular_velocity=_vec("/imu", "imu", t_om, w)))
    assert "/imu: 1 angular-velocity sample dropped, each sharing its stamp with a later one" in "\n".join(a.notes)


def test_a_saturating_gyro_is_named():
    # a generated hand-held rig whose yaw rate reaches 2.5 rad/s, its gyro clipped at 2.4 rad/s (3 % of the samples)
    # or 1 rad/s (docs/benchmarks.md, "Logs nobody has run yet, round 7": riekf lost at 7.9 m, fast-adaptation 0.50 m
    # "converged", no word); as read (its largest reading held once) nothing is said
    from dataclasses import replace

    from slamobs.pipeline.simulate import expected_streams, simulate
    from slamobs.pipeline.simulate.scenarios import handheld

    sim = simulate(handheld(12.0, 0.6), seed=2, duration=30.0)
    assert not [n for n in align(expected_streams(sim)).notes if "saturating" in n]
    for clip in (2.4, 1.0):
        clipped = replace(sim, imu=replace(sim.imu, gyro=np.clip(sim.imu.gyro, -clip, clip)))
        said = [n for n in align(expected_streams(clipped)).notes if "saturating" in n]
        assert len(said) == 1 and f"about z ±{clip:g} rad/s" in said[0] and "/imu/data" in said[0], said
