"""Header stamps vs record times: clock kinds, offsets between topics, order, duplicates, gaps, rate changes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.writer import Writer as McapWriter
from rosbags.rosbag1 import Writer as Bag1Writer

from slamobs.cli.info_cmd import info
from slamobs.pipeline.config import parse_config
from slamobs.pipeline.readers import format_info, inspect_log, read_log
from slamobs.pipeline.readers.decode import clean_order
from slamobs.pipeline.readers.inspect import CLOCK_TOLERANCE_S, apply_clocks, recommend_clocks, stamp_stats
from slamobs.pipeline.simulate import make_typestore
from slamobs.pipeline.streams import DetectionStream, LogStreams

NS = 1_000_000_000
WALL = 1_700_000_000 * NS
IMU, POSE, TWIST = "sensor_msgs/msg/Imu", "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TwistStamped"


def _grid(seconds: float, rate: float, start: float = 0.0) -> np.ndarray:
    return np.round((start + np.arange(int(round(seconds * rate))) / rate) * NS).astype(np.int64)


def _write(path, topics: dict[str, list[tuple[int, int, float]]]):
    """A log with an Imu ``/imu``, a PoseStamped ``/pose`` and a TwistStamped ``/vel`` (the value its linear x, its
    angular velocity zero): (header stamp, record time, value) each."""
    ros1 = path.suffix == ".bag"
    ts = make_typestore(ros1=ros1)
    t = ts.types
    quat = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)

    def message(topic: str, stamp: int, value: float) -> object:
        time = t["builtin_interfaces/msg/Time"](sec=stamp // NS, nanosec=stamp % NS)
        extra = {"seq": 0} if ros1 else {}
        header = t["std_msgs/msg/Header"](stamp=time, frame_id="imu" if topic == "/imu" else "world", **extra)
        vec = t["geometry_msgs/msg/Vector3"](x=value, y=0.0, z=0.0)
        if topic == "/imu":
            return t[IMU](
                header=header, orientation=quat, orientation_covariance=np.zeros(9), angular_velocity=vec,
                angular_velocity_covariance=np.zeros(9), linear_acceleration=vec,
                linear_acceleration_covariance=np.zeros(9),
            )  # fmt: skip
        if topic == "/vel":
            zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            return t[TWIST](header=header, twist=t["geometry_msgs/msg/Twist"](linear=vec, angular=zero))
        point = t["geometry_msgs/msg/Point"](x=value, y=0.0, z=0.0)
        return t[POSE](header=header, pose=t["geometry_msgs/msg/Pose"](position=point, orientation=quat))

    types = {"/imu": IMU, "/pose": POSE, "/vel": TWIST}
    items = sorted((rec, topic, stamp, value) for topic, msgs in topics.items() for stamp, rec, value in msgs)
    if ros1:
        with Bag1Writer(path) as writer:
            conns = {tp: writer.add_connection(tp, types[tp], typestore=ts) for tp in topics}
            for rec, topic, stamp, value in items:
                writer.write(conns[topic], rec, ts.serialize_ros1(message(topic, stamp, value), types[topic]))
        return path
    with path.open("wb") as stream:
        writer = McapWriter(stream)
        writer.start(profile="ros2", library="test")
        channels = {}
        for topic in topics:
            msgdef = ts.generate_msgdef(types[topic], ros_version=2)[0]
            schema = writer.register_schema(types[topic], "ros2msg", msgdef.encode())
            channels[topic] = writer.register_channel(topic, "cdr", schema)
        for rec, topic, stamp, value in items:
            data = bytes(ts.serialize_cdr(message(topic, stamp, value), types[topic]))
            writer.add_message(channels[topic], log_time=rec, data=data, publish_time=rec)
        writer.finish()
    return path


def _topic(summary, name):
    return next(t for t in summary.topics if t.topic == name)


def _steady(rate: float, seconds: float, header_offset_ns: int, latency_ns: int = 2_000_000, start: int = WALL):
    """(stamp, record, value): stamps on a grid from ``start`` + offset, recorded ``latency`` later."""
    grid = _grid(seconds, rate) + start
    return [(int(g) + header_offset_ns, int(g) + latency_ns, float(k)) for k, g in enumerate(grid)]


@pytest.mark.parametrize("suffix", [".bag", ".mcap"])
def test_constant_offset_between_topics(tmp_path, suffix):
    path = _write(tmp_path / f"offset{suffix}", {"/imu": _steady(100, 5, 0), "/pose": _steady(50, 5, NS // 2)})
    summary = inspect_log(path)
    imu, pose = _topic(summary, "/imu"), _topic(summary, "/pose")
    assert summary.clock_reference == "/imu" and summary.record_clock == "wall"
    assert (imu.header_clock, pose.header_clock) == ("wall", "wall")
    assert imu.offset_s == pytest.approx(-0.002, abs=1e-9)
    assert pose.offset_s == pytest.approx(0.498, abs=1e-9)
    assert pose.relative_offset_s == pytest.approx(0.5, abs=1e-9) and imu.relative_offset_s == 0
    assert imu.offset_spread_s == pytest.approx(0.0, abs=1e-9)
    assert summary.clocks == {"/imu": "header", "/pose": "record"}
    assert any("/pose: header clock is +0.500 s off /imu's" in w for w in summary.warnings)

    streams = read_log(path)
    assert recommend_clocks(streams)[0] == summary.clocks
    # run read /pose on its header stamps without a word (info alone warned; MR.CLAM's detections 120 s off:
    # riekf's map error 0.24 -> 10.3 m, no note): the same warning, with what the run does instead
    said = [w for w in streams.warnings if "header clock is +0.500 s off /imu's" in w]
    assert said == [
        "warning: /pose: header clock is +0.500 s off /imu's (wall clock), use record time for it; this run reads "
        "header stamps (time.source: header): time.source: auto takes that advice"
    ]
    assert not any("header clock" in w for w in read_log(path, clocks="record").warnings)
    fixed = apply_clocks(streams, summary.clocks)
    np.testing.assert_array_equal(fixed.truth.t_ns, streams.truth.rec_ns)
    np.testing.assert_array_equal(fixed.truth.position, streams.truth.position)
    assert fixed.angular_velocity is streams.angular_velocity


def test_latency_below_tolerance_is_not_an_offset(tmp_path):
    small = int(0.5 * CLOCK_TOLERANCE_S * NS)
    path = _write(tmp_path / "latency.bag", {"/imu": _steady(100, 3, 0), "/pose": _steady(50, 3, -small)})
    summary = inspect_log(path)
    assert summary.clocks == {"/imu": "header", "/pose": "header"}
    assert not any("header clock" in w for w in summary.warnings)


def test_records_held_back_in_bursts_are_not_a_clock_offset(tmp_path):
    """A topic recorded in bursts (every frame of a second written at its end: a driver or relay that batches) has its
    median header-minus-record 0.5 s off the IMU's, but its stamps are right: record time would move each frame by up
    to 1 s. round 11's seed=4633: ``use record time for it``, and time.source: auto taking it, put
    riekf at 1.53 m and batch at 1.32 m (header stamps: 0.081 and 0.033)."""
    pose = [(WALL + int(g), WALL + -(-int(g) // NS) * NS + 2_000_000, float(k)) for k, g in enumerate(_grid(5, 50))]
    path = _write(tmp_path / "bursts.mcap", {"/imu": _steady(100, 5, 0), "/pose": pose})
    summary = inspect_log(path)
    assert _topic(summary, "/pose").offset_s < -0.4  # the median is off: the old rule's "clock"
    assert summary.clocks == {"/imu": "header", "/pose": "header"}
    assert not any("header clock" in w for w in summary.warnings), summary.warnings
    streams = read_log(path, clocks="auto")
    assert not any("header clock" in w for w in streams.warnings) and not streams.clocks
    np.testing.assert_array_equal(streams.truth.t_ns, [p[0] for p in pose])


def test_sim_time_stamps_next_to_wall_clock_record_times(tmp_path):
    sim_start = 12 * NS  # a simulator clock started 12 s ago
    topics = {"/imu": _steady(100, 3, sim_start - WALL), "/pose": _steady(50, 3, sim_start - WALL)}
    summary = inspect_log(_write(tmp_path / "sim.bag", topics))
    imu = _topic(summary, "/imu")
    assert imu.header_clock == "sim" and summary.record_clock == "wall"
    assert imu.offset_s == pytest.approx((sim_start - WALL - 2_000_000) / NS)
    assert summary.clocks == {"/imu": "header", "/pose": "header"}  # one simulation clock for both: fine
    assert "header stamps are simulation time next to wall-clock record times: /imu, /pose" in summary.warnings


def test_reference_off_record_time_means_record_time_for_all(tmp_path):
    topics = {"/imu": _steady(100, 3, 12 * NS - WALL), "/pose": _steady(50, 3, 0)}  # only the imu is simulated
    summary = inspect_log(_write(tmp_path / "mixed.bag", topics))
    assert summary.clocks == {"/imu": "record", "/pose": "record"}
    # advice a user can follow: info names the key (a run reads header stamps unless told)
    assert any("use record time for every topic (set time.source: auto;" in w for w in summary.warnings)
    one = inspect_log(_write(tmp_path / "one.bag", {"/imu": _steady(1, 1, 0)}))
    assert "(0.000 s, 1 message)" in format_info(one)  # was '1 messages'


def test_zero_stamps_use_record_time(tmp_path):
    imu = [(0, rec, value) for _, rec, value in _steady(100, 2, 0)]
    summary = inspect_log(_write(tmp_path / "zero.bag", {"/imu": imu, "/pose": _steady(50, 2, 0)}))
    assert _topic(summary, "/imu").header_clock == "zero"
    assert _topic(summary, "/imu").repeated_stamps is None  # every stamp is 0: nothing to say
    assert summary.clocks == {"/imu": "record", "/pose": "header"}
    assert "/imu: header stamps are all zero" in summary.warnings


def test_out_of_order_duplicates_and_repeated_stamps(tmp_path):
    msgs = _steady(100, 2, 0)
    msgs[10], msgs[11] = (msgs[11][0], msgs[10][1], msgs[11][2]), (msgs[10][0], msgs[11][1], msgs[10][2])
    msgs[50], msgs[51] = (msgs[51][0], msgs[50][1], msgs[51][2]), (msgs[50][0], msgs[51][1], msgs[50][2])
    msgs.append((msgs[20][0], msgs[20][1] + 1, msgs[20][2]))  # exact duplicate, recorded again
    msgs.append((msgs[30][0], msgs[30][1] + 1, -1.0))  # same stamp, other value
    summary = inspect_log(_write(tmp_path / "order.bag", {"/imu": msgs}))
    imu = _topic(summary, "/imu")
    assert (imu.out_of_order, imu.duplicates, imu.repeated_stamps) == (2, 1, 1)  # a swapped pair: one step back
    warning = next(w for w in summary.warnings if w.startswith("/imu:"))
    assert "2 out-of-order stamps, 1 exact duplicate, 1 repeated stamp with different values" in warning
    streams = read_log(tmp_path / "order.bag")
    assert np.all(np.diff(streams.angular_velocity.t_ns) >= 0)


@pytest.mark.parametrize("suffix", [".bag", ".mcap"])
def test_every_message_recorded_twice_is_said_and_read_as_once(tmp_path, suffix):
    """A driver publishing twice (each message recorded again 1 ns later): the run reads the stream of a log holding
    each once, and the note and info say every message is there twice (not only 'N exact duplicates dropped')."""
    once = [(stamp, rec, np.sin(k / 10.0)) for k, (stamp, rec, _) in enumerate(_steady(50, 4, 0))]
    twice = sorted([*once, *((stamp, rec + 1, value) for stamp, rec, value in once)], key=lambda m: m[1])
    logs = {
        name: _write(tmp_path / f"{name}{suffix}", {"/imu": msgs}) for name, msgs in (("once", once), ("twice", twice))
    }
    a, b = (read_log(logs[name]).angular_velocity for name in ("once", "twice"))
    assert np.array_equal(a.t_ns, b.t_ns) and np.array_equal(a.xyz, b.xyz)
    said = (
        "200 exact duplicates dropped (every message recorded twice: a driver publishing twice? the stream is its 200"
    )
    assert any(w.startswith(f"/imu: {said}") for w in read_log(logs["twice"]).warnings)
    summary = inspect_log(logs["twice"])
    assert _topic(summary, "/imu").rate_hz == _topic(inspect_log(logs["once"]), "/imu").rate_hz
    assert any(w.startswith("/imu: 200 exact duplicates (every message recorded twice") for w in summary.warnings)


def test_a_note_of_one_role_of_a_topic_serving_two_names_the_role(tmp_path):
    """A TwistStamped whose angular velocity is all zero serves both velocities: the note is the angular one's."""
    log = _write(tmp_path / "vel.mcap", {"/vel": _steady(50, 2, 0)})
    notes = [w for w in read_log(log).warnings if "/vel" in w]
    said = "all values are zero (field not filled by the publisher?): the run takes the body as never turning"
    assert notes == [f"/vel (angular_velocity): {said}"], notes
    # info says it too, from the first messages (an odometry's zero twist.angular is differentiated: not said)
    assert (
        "/vel: every angular velocity of its first 100 messages is zero (field not filled by the publisher?): if all"
        in ("\n".join(inspect_log(log).warnings))
    )


def test_info_reads_further_before_calling_a_gyro_that_reads_zero_at_the_start_unfilled(tmp_path):
    """A robot that stands or drives straight at the start measures a zero angular velocity (MR.CLAM 6-r5 turns first
    at its 173rd message): info read its first 50 and warned "field not filled by the publisher?", which run, reading
    them all, never says. It reads further before it warns."""
    turning_late = [(s, r, 0.0 if k < 120 else 0.1) for s, r, k in _steady(100, 3, 0)]
    log = _write(tmp_path / "late.mcap", {"/imu": turning_late})
    assert not [w for w in inspect_log(log).warnings if "every angular velocity" in w]
    never = _write(tmp_path / "never.mcap", {"/imu": [(s, r, 0.0) for s, r, _ in _steady(100, 3, 0)]})
    said = "/imu: every angular velocity of its first 300 messages is zero (field not filled by the publisher?)"
    assert any(w.startswith(said) for w in inspect_log(never).warnings)


def test_header_stamp_notes_are_left_out_when_the_run_reads_record_times(tmp_path):
    # time.source: record read the record times but still noted the header stamps' disorder ('2 out-of-order
    # stamps, 1 repeated stamp with different values'): notes describe the clock the run reads
    msgs = _steady(100, 2, 0)
    msgs[10], msgs[11] = (msgs[11][0], msgs[10][1], msgs[11][2]), (msgs[10][0], msgs[11][1], msgs[10][2])
    msgs[50], msgs[51] = (msgs[51][0], msgs[50][1], msgs[51][2]), (msgs[50][0], msgs[51][1], msgs[50][2])
    msgs.append((msgs[20][0], msgs[20][1] + 1, msgs[20][2]))  # exact duplicate, recorded again: dropped on any clock
    msgs.append((msgs[30][0], msgs[30][1] + 1, -1.0))  # same stamp, other value
    log = _write(tmp_path / "order.bag", {"/imu": msgs, "/pose": _steady(50, 2, 0)})

    def notes(clocks):
        return [w for w in read_log(log, clocks=clocks).warnings if w.startswith("/imu")]

    assert notes(None) == [
        "/imu: 2 out-of-order stamps, 1 exact duplicate dropped, 1 repeated stamp with different values"
    ]
    assert notes("record") == notes({"/imu": "record"}) == ["/imu: 1 exact duplicate dropped"]
    assert parse_config({"time": {"source": "record"}}).reader_options()["clocks"] == "record"


def test_gap(tmp_path):
    msgs = [m for m in _steady(100, 6, 0) if not (WALL + 3 * NS <= m[0] < WALL + 4 * NS)]
    imu = _topic(inspect_log(_write(tmp_path / "gap.bag", {"/imu": msgs})), "/imu")
    assert imu.gaps == 1
    assert imu.max_gap_s == pytest.approx(1.01, abs=1e-9) and imu.max_gap_at_s == pytest.approx(2.99, abs=1e-9)
    assert imu.rate_segments == ()
    # says what a gap is here: MR.CLAM's velocity had '621 gaps' in info beside run's '32 gap(s) longer than 0.5 s'
    warnings = inspect_log(tmp_path / "gap.bag").warnings
    assert "/imu: 1 gap over 5x the median interval (longest 1.010 s at +2.990 s)" in warnings


def test_rate_change(tmp_path):
    fast = _grid(10, 200) + WALL
    slow = _grid(10, 100, start=10) + WALL
    msgs = [(int(s), int(s) + 2_000_000, 0.0) for s in np.concatenate([fast, slow])]
    summary = inspect_log(_write(tmp_path / "rate.bag", {"/imu": msgs}))
    imu = _topic(summary, "/imu")
    assert len(imu.rate_segments) == 2
    (t0, r0), (t1, r1) = imu.rate_segments
    assert (t0, r0) == (0.0, pytest.approx(200.0)) and r1 == pytest.approx(100.0)
    assert 9.5 <= t1 <= 10.5
    assert imu.gaps == 0
    assert any("rate changes: 200 Hz -> 100 Hz at +" in w for w in summary.warnings)


def test_info_text_and_json(tmp_path):
    path = _write(tmp_path / "offset.bag", {"/imu": _steady(100, 2, 0), "/pose": _steady(50, 2, NS // 2)})
    text = format_info(inspect_log(path))
    assert "clocks (record time: wall clock; offsets vs /imu)" in text
    assert "hdr-rec [s]" in text and "+0.500" in text
    result = CliRunner().invoke(info, [str(path), "--json"])
    assert result.exit_code == 0
    doc = json.loads(result.stdout)
    pose = next(t for t in doc["topics"] if t["topic"] == "/pose")
    assert pose["clock"] == "record" and pose["relative_offset_s"] == pytest.approx(0.5)
    assert doc["clock_reference"] == "/imu" and doc["record_clock"] == "wall"


def test_stamp_stats_and_apply_clocks_on_arrays():
    t = np.array([0, 10, 20, 30], np.int64) + WALL
    stats = stamp_stats(t, t + 5)
    assert (stats.header_clock, stats.offset_ns, stats.spread_ns, stats.out_of_order) == ("wall", -5, 0, 0)
    det = DetectionStream(
        "/fiducials", "camera", t_ns=np.array([1, 2, 3]), rec_ns=np.array([30, 10, 20]),
        offsets=np.array([0, 2, 2, 3]), ids=np.array([7, 8, 9]), xyz=np.arange(9.0).reshape(3, 3),
    )  # fmt: skip
    moved = apply_clocks(LogStreams("x", detections=det), {"/fiducials": "record"}).detections
    np.testing.assert_array_equal(moved.t_ns, [10, 20, 30])
    np.testing.assert_array_equal(moved.offsets, [0, 0, 1, 3])
    np.testing.assert_array_equal(moved.ids, [9, 7, 8])
    np.testing.assert_array_equal(moved.xyz[0], [6.0, 7.0, 8.0])
    with pytest.raises(ValueError, match="unknown clock"):
        apply_clocks(LogStreams("x"), {"/a": "gps"})


def test_a_clock_set_back_is_named_in_the_out_of_order_note():
    # every stamp of a log set back 1 s at once read as '1 out-of-order stamp' (the run's APE went from 0.05 m to
    # 0.36 m on the figure-8 sample log; record time gives 0.05 m back)
    ms = 1_000_000
    values = np.zeros((5, 3))
    _, _, step = clean_order(np.array([0, 1000, 2000, 500, 3000]) * ms, np.arange(5) * 1000 * ms, values)
    assert step.text() == "1 out-of-order stamp (a step back of 1.500 s: a clock set back? time.source: auto or record)"
    _, _, jitter = clean_order(np.array([0, 10, 5, 20, 30]) * ms, np.arange(5) * 10 * ms, values)
    assert jitter.text() == "1 out-of-order stamp"


def test_info_names_a_clock_set_back_as_the_run_does(tmp_path):
    """A header clock set back 5 s mid-log: info said only '1 out-of-order stamp' (beside a 'header clocks
    disagree' line that did not say why) where the run's note names the step; both now give the same words."""
    msgs = _steady(100, 4, 0)
    msgs = msgs[:200] + [(stamp - 5 * NS, rec, value) for stamp, rec, value in msgs[200:]]
    log = _write(tmp_path / "back.mcap", {"/imu": msgs})
    info = inspect_log(log).warnings
    words = "1 out-of-order stamp (a step back of 4.990 s: a clock set back? time.source: auto or record)"
    assert words in next(w for w in info if w.startswith("/imu:"))
    assert any(words in w for w in read_log(log, clocks={"/imu": "header"}).warnings)  # header stamps, as asked


def test_a_clock_set_back_or_forward_mid_log_is_read_on_record_time_by_default(tmp_path):
    """A header clock set back 5 s mid-log (or forward 30 s) under the default header stamps: the run read the
    stamps that step (MR.CLAM 6 r1 with every clock set back 5 s: riekf lost the log; the detections' set forward
    30 s: riekf map 0.24 -> 7.2 m), with a note that `time.source: auto` helps; now it reads record time for every
    topic and says so, as info does."""
    steady = _steady(100, 4, 0)
    for delta, how in ((-5, "stamps step back 4.990 s"), (30, "jump 30.000 s ahead 2.0 s in")):
        msgs = steady[:200] + [(stamp + delta * NS, rec, value) for stamp, rec, value in steady[200:]]
        log = _write(tmp_path / f"step{delta}.mcap", {"/imu": msgs})
        streams = read_log(log)
        assert streams.clocks == {"/imu": "record"}
        np.testing.assert_array_equal(streams.angular_velocity.t_ns, streams.angular_velocity.rec_ns)
        said = [w for w in streams.warnings if "mid-log" in w]
        assert len(said) == 1 and f"(/imu: {how}): this run reads record time for every topic" in said[0], said
        info = inspect_log(log)
        assert any(w.startswith("header clock set back or forward mid-log (/imu") for w in info.warnings)
        assert info.clocks == {"/imu": "record"}
    assert read_log(_write(tmp_path / "steady.mcap", {"/imu": steady})).clocks == {}


def test_header_stamps_left_0_on_a_few_messages_are_named_so_not_as_a_clock_set_back(tmp_path):
    """2 % of a topic's header stamps 0 among set ones (a publisher that left some unset; round 10's seed=4384):
    the run read record time, right, but said `header clock set back or forward mid-log (/odom: stamps step back
    1700000088.701 s)`, a clock the log does not have; it now names the stamps left 0, and a clock that also steps
    among the set stamps is still named."""
    steady = _steady(100, 4, 0)
    unset = [(0 if k % 50 == 25 else stamp, rec, value) for k, (stamp, rec, value) in enumerate(steady)]
    streams = read_log(_write(tmp_path / "unset.mcap", {"/imu": unset}))
    assert streams.clocks == {"/imu": "record"}
    said = [w for w in streams.warnings if "header" in w and "record time for every topic" in w]
    assert len(said) == 1 and said[0].startswith(
        "warning: some header stamps 0 (/imu: 8 of its 400 header stamps 0: left unset by its publisher?): "
    ), said
    back = unset[:200] + [(stamp and stamp - 5 * NS, rec, value) for stamp, rec, value in unset[200:]]
    said = [w for w in read_log(_write(tmp_path / "both.mcap", {"/imu": back})).warnings if "mid-log" in w]
    assert (
        len(said) == 1
        and "(/imu: 8 of its 400 header stamps 0: left unset by its publisher?, stamps step back" in said[0]
    )


def test_clocks_set_back_together_are_said_to_step_not_to_disagree(tmp_path):
    """Every header clock set back 5 s mid-log (an NTP step on the recording machine): the topics' median offsets
    fall on either side of the step, and info said 'header clocks disagree' with the reference's offset, as if
    the topics were on different machines; it now says the clocks step against record time."""

    def stepped(rate):
        msgs = _steady(rate, 4, 0)
        half = len(msgs) // 2 + (1 if rate == 50 else -1)  # medians on either side of the step
        return msgs[:half] + [(stamp - 5 * NS, rec, value) for stamp, rec, value in msgs[half:]]

    summary = inspect_log(_write(tmp_path / "stepped.mcap", {"/imu": stepped(100), "/pose": stepped(50)}))
    clock = [w for w in summary.warnings if "clocks" in w]
    assert len(clock) == 1 and clock[0].startswith("header clocks step against record time (/imu"), clock
    assert "spreads over 5.000 s" in clock[0] and "disagree" not in clock[0]
    assert set(summary.clocks.values()) == {"record"}
    # a jittery reference (spread 0.2 s) whose offset is 1 s from another topic's still disagrees: no step
    rng = np.random.default_rng(4)
    jitter = [(g, g + 300_000_000 + int(rng.uniform(0, 0.25) * NS), 0.0) for g, _, _ in _steady(100, 4, 0)]
    late = [(g, r + 1_300_000_000, v) for g, r, v in _steady(50, 4, 0)]
    other = inspect_log(_write(tmp_path / "jitter.mcap", {"/imu": jitter, "/pose": late}))
    assert any(w.startswith("header clocks disagree (/pose vs /imu)") for w in other.warnings), other.warnings


def test_the_recording_clock_set_back_is_said_where_no_stamp_steps_against_record_time(tmp_path):
    """The recording machine's clock set back 1.0037 s mid-log, record times and header stamps alike: no stamp
    steps against record time, so nothing was said; the seconds before the step and after it interleave (a figure
    8 so: riekf lost the log, 2.94 m off where the clean log gives 0.011 m, a misread id its only word). Now a
    warning names the stretch where every topic comes twice as dense; a steady log has none. ``info`` says it in
    the run's words (it listed only each topic's repeated stamps: seed=3973, seed=3974)."""
    set_back = 1_003_700_000

    def recorded(rate):
        return [(s - set_back * (r >= WALL + 5 * NS), r - set_back * (r >= WALL + 5 * NS), v) for s, r, v in
                _steady(rate, 10, 0)]  # fmt: skip

    log = _write(tmp_path / "set_back.mcap", {"/imu": recorded(100), "/vel": recorded(50)})
    streams = read_log(log)
    (said,) = [w for w in streams.warnings if "clock set back mid-log" in w]
    assert [f"warning: {w}" for w in inspect_log(log).warnings if "clock set back mid-log" in w] == [said]
    assert said.startswith(
        "warning: every topic's samples come about twice as dense from 4.0 s to 5.0 s into the log"
    ), said
    assert "(against /imu's 100 Hz, /vel's 50 Hz)" in said and "time.start, time.end" in said
    plain = _write(tmp_path / "steady.mcap", {"/imu": _steady(100, 10, 0), "/vel": _steady(50, 10, 0)})
    assert not any("clock set back mid-log" in w for w in read_log(plain).warnings)
    assert not any("clock set back mid-log" in w for w in inspect_log(plain).warnings)


def _imu_extrinsic_on_tf(src, dst):
    """The simulated MCAP ``src`` with its base_link -> imu_link extrinsic moved from /tf_static to /tf, one
    message per IMU message (recorded with it), whose header stamps are disordered: pairs swapped, a stamp repeated
    with another value (record times stay in order)."""
    from mcap.reader import make_reader

    from slamobs.pipeline.simulate.sensors import FRAME_IMU, TOPIC_IMU, TOPIC_TF_STATIC

    ts = make_typestore(ros1=False)
    tf_type = "tf2_msgs/msg/TFMessage"
    with src.open("rb") as fin, dst.open("wb") as fout:
        writer = McapWriter(fout)
        writer.start(profile="ros2", library="slamobs-tests")
        msgdef, _ = ts.generate_msgdef(tf_type, ros_version=2)
        tf_channel = writer.register_channel("/tf", "cdr", writer.register_schema(tf_type, "ros2msg", msgdef.encode()))
        schemas, channels, edge, k, last = {}, {}, None, 0, None
        for schema, channel, msg in make_reader(fin).iter_messages():
            data = msg.data
            if channel.topic == TOPIC_TF_STATIC:
                tfm = ts.deserialize_cdr(msg.data, tf_type)
                edge = next(t for t in tfm.transforms if t.child_frame_id == FRAME_IMU)
                kept = [t for t in tfm.transforms if t.child_frame_id != FRAME_IMU]
                data = bytes(ts.serialize_cdr(ts.types[tf_type](transforms=kept), tf_type))
            elif channel.topic == TOPIC_IMU and edge is not None:
                imu = ts.deserialize_cdr(msg.data, schema.name)
                ns = imu.header.stamp.sec * NS + imu.header.stamp.nanosec - 15_000_000 * (k % 50 == 10)  # early
                stamp = last if k % 50 == 30 else type(imu.header.stamp)(sec=ns // NS, nanosec=ns % NS)
                turn = 0.01 * (k % 50 == 30)  # the stamp before, repeated with another value
                last, k = stamp, k + 1
                rot = type(edge.transform.rotation)(x=np.sin(turn / 2), y=0.0, z=0.0, w=np.cos(turn / 2))
                t = type(edge)(
                    header=type(edge.header)(stamp=stamp, frame_id=edge.header.frame_id),
                    child_frame_id=FRAME_IMU,
                    transform=type(edge.transform)(translation=edge.transform.translation, rotation=rot),
                )
                tf_data = bytes(ts.serialize_cdr(ts.types[tf_type](transforms=[t]), tf_type))
                writer.add_message(tf_channel, log_time=msg.log_time, publish_time=msg.publish_time, data=tf_data)
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            writer.add_message(channels[channel.id], log_time=msg.log_time, data=data, publish_time=msg.publish_time)
        writer.finish()
    return dst


def test_tf_notes_describe_the_clock_the_run_reads(tmp_path):
    # time.source: record read /tf on its record times, but its edges were still sorted, cleaned and described
    # on their header stamps ('/tf: base_link->imu_link: 4 out-of-order stamps, 2 repeated stamps dropped')
    from slamobs.pipeline.alignment import align
    from slamobs.pipeline.simulate import simulate, write_log

    src = write_log(simulate("circle", duration=2.0, seed=3), tmp_path / "sim.mcap")
    log = _imu_extrinsic_on_tf(src, tmp_path / "tf.mcap")

    def tf_notes(clocks):
        streams = read_log(log, clocks=clocks)
        return streams, [w for w in streams.warnings if w.startswith("/tf:")]

    header, notes = tf_notes(None)
    assert len(notes) == 1 and "out-of-order stamp" in notes[0] and "repeated stamp" in notes[0]
    record, notes = tf_notes("record")
    assert notes == []  # the record times are in order and distinct: nothing to say, nothing dropped
    (edge,) = [s for s in record.tf if s.child == "imu_link"]
    n_imu = len(record.angular_velocity)
    assert len(edge) == n_imu and np.all(np.diff(edge.t_ns) > 0) and np.array_equal(edge.t_ns, edge.rec_ns)
    assert len([s for s in header.tf if s.child == "imu_link"][0]) < n_imu  # the header stamps' repeats dropped
    aligned = align(record, time_source="record")
    assert any("through /tf (base_link->imu_link)" in n and "time-varying" in n for n in aligned.notes)


def test_a_header_clock_set_forward_is_named_by_info_and_run(tmp_path):
    # MR.CLAM with its detections' header clock set 30 s forward halfway: no stamp goes out of order, info and run
    # said nothing, and riekf's map error went 0.24 -> 7.2 m
    imu = _steady(100, 6, 0)
    pose = _steady(50, 6, 0)
    pose = [(s + (30 * NS if k >= 150 else 0), r, v) for k, (s, r, v) in enumerate(pose)]
    path = _write(tmp_path / "forward.mcap", {"/imu": imu, "/pose": pose})
    said = (
        "header stamps jump 30.000 s ahead of record time 3.0 s into the topic (a clock set forward? "
        "time.source: record, or the topic in time.topics: record, reads record time)"
    )
    assert any(w.startswith("/pose: ") and said in w for w in read_log(path, clocks={"/pose": "header"}).warnings)
    assert any(w.startswith("/pose: ") and said in w for w in inspect_log(path).warnings)
    assert read_log(path).clocks == {"/imu": "record", "/pose": "record"}  # by default: the clock steps
    assert not any(said in w for w in read_log(path, clocks="record").warnings)
    # a recorder that stalls 1 s and then writes the held messages at once moves record times, not the stamps
    steady = _steady(100, 6, 0)
    stalled = [(s, steady[200][1] if 100 <= k < 200 else r, v) for k, (s, r, v) in enumerate(steady)]
    calm = _write(tmp_path / "stall.mcap", {"/imu": stalled, "/pose": _steady(50, 6, 0)})
    assert not any("ahead of record time" in w for w in read_log(calm).warnings + list(inspect_log(calm).warnings))


def test_every_detection_frame_recorded_twice_is_said_as_for_the_velocities():
    # MR.CLAM with every detection message recorded three times: run said '2024 exact duplicates dropped', info
    # that every message was there twice or more
    from slamobs.pipeline.readers.decode import clean_frames

    t = np.repeat(np.arange(4) * NS, 2)
    lengths = np.ones(8, np.int64)
    ids = np.repeat(np.arange(4), 2)
    values = np.repeat(np.arange(12.0).reshape(4, 3), 2, axis=0)
    *_, cleaning = clean_frames(t, t + 1, lengths, ids, values, np.zeros(8, np.int32), ["cam"])
    assert cleaning.text() == (
        "4 exact duplicates dropped (every message recorded twice: a driver publishing twice? the stream is its 4 "
        "distinct samples, read as a log holding each once)"
    )


def test_info_counts_the_nan_values_a_run_drops_in_the_run_s_words(tmp_path):
    """A magnetometer half NaN (imu_tools' phidgets_imu_upside_down.bag: 6990 of 13964) was not in ``info``."""
    imu = [(s, r, float("nan") if k % 4 == 1 else v) for k, (s, r, v) in enumerate(_steady(100, 2, 0))]
    pose = [(s, r, float("inf") if k < 3 else v) for k, (s, r, v) in enumerate(_steady(50, 2, 0))]
    path = _write(tmp_path / "nan.mcap", {"/imu": imu, "/pose": pose})
    summary = inspect_log(path)
    assert _topic(summary, "/imu").nonfinite == {"angular_velocity": 50, "accel": 50}
    assert _topic(summary, "/pose").nonfinite == {"truth": 3}
    run_notes = [w for w in read_log(path).warnings if "NaN/Inf" in w]
    assert sorted(run_notes) == ["/imu: 50 NaN/Inf samples dropped", "/pose: 3 NaN/Inf samples dropped"]
    for note in run_notes:  # the run's note, word for word, then what it means
        assert any(w.startswith(f"{note} (of its ") for w in summary.warnings), (note, summary.warnings)
    text = format_info(summary)
    assert "NaN/Inf" in text.splitlines()[4] and " 50  " in text.splitlines()[5]  # the topic table's column
    doc = json.loads(CliRunner().invoke(info, [str(path), "--json"]).stdout)
    assert next(t for t in doc["topics"] if t["topic"] == "/imu")["nonfinite"] == {"angular_velocity": 50, "accel": 50}


def test_info_clocks_column_says_what_a_run_with_the_config_reads(tmp_path):
    """evo's aruco_images.bag: the column ``use`` said ``record`` where a run reads header stamps by default."""
    topics = {"/imu": _steady(100, 3, 12 * NS - WALL), "/pose": _steady(50, 3, 0)}  # the clocks disagree
    path = _write(tmp_path / "mixed.bag", topics)
    summary = inspect_log(path)
    assert summary.clocks == {"/imu": "record", "/pose": "record"}  # what time.source: auto reads
    assert {t.topic: t.run_clock for t in summary.topics} == {"/imu": "header", "/pose": "header"}
    assert {t.topic: t.run_clock for t in inspect_log(path, clocks="auto").topics} == summary.clocks
    assert {t.run_clock for t in inspect_log(path, clocks="record").topics} == {"record"}
    assert {t.topic: t.run_clock for t in inspect_log(path, clocks={"/pose": "record"}).topics} == {
        "/imu": "header",
        "/pose": "record",
    }
    text = format_info(summary)
    header = next(line for line in text.splitlines() if "hdr-rec [s]" in line)
    assert header.split()[1:4] == ["run", "reads", "auto"] and " use " not in header
    assert ["/imu", "header", "record", "sim"] in [line.split()[:4] for line in text.splitlines()]
    config = tmp_path / "run.yaml"
    config.write_text("time:\n  source: record\n")
    doc = json.loads(CliRunner().invoke(info, [str(path), "--json", "--config", str(config)]).stdout)
    assert {t["run_clock"] for t in doc["topics"]} == {"record"}


def test_info_says_what_its_columns_count(tmp_path):
    """``rate``, ``spread``, ``gaps``: the tables name their definitions (a new user read rate as messages/span)."""
    text = format_info(inspect_log(_write(tmp_path / "one.bag", {"/imu": _steady(100, 2, 0)})))
    assert "rate: distinct header stamps per second of the time recorded" in text
    assert "spread: its 5th-95th percentile width" in text and "gaps: intervals over 5x the median" in text


def test_a_topic_of_one_message_is_not_judged_against_the_reference_clock(tmp_path):
    """fiducials_ubiquity's aruco_images.bag: info said "header clocks disagree" from its one image's stamp 0.95 s
    off 15 camera_info stamps. A topic with fewer than MIN_CLOCK_STAMPS stamps keeps its header clock, unjudged, and
    a reference of one stamp judges none; MIN_CLOCK_STAMPS stamps 1.2 s off are still a clock of their own."""
    from slamobs.pipeline.readers.inspect import MIN_CLOCK_STAMPS

    off = int(1.2 * NS)
    late = _steady(50, 3, off)
    for name, topics in {
        "one": {"/imu": _steady(100, 3, 0), "/pose": late[:1]},
        "reference": {"/imu": _steady(100, 3, 0)[:1], "/pose": late},
    }.items():
        summary = inspect_log(_write(tmp_path / f"{name}.bag", topics))
        assert summary.clocks == {"/imu": "header", "/pose": "header"}, name
        assert not any("header clock" in w for w in summary.warnings), (name, summary.warnings)
    summary = inspect_log(_write(tmp_path / "few.bag", {"/imu": _steady(100, 3, 0), "/pose": late[:MIN_CLOCK_STAMPS]}))
    assert summary.clocks == {"/imu": "header", "/pose": "record"}
    assert any("/pose: header clock is +1.200 s off /imu's" in w for w in summary.warnings), summary.warnings
