"""Split ROS1 recordings (issue 26, part 6): the ``NAME_N.bag`` parts of one recording, as a directory or as several
paths, read as one log in order, with the gaps between the files in the notes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from rosbags.rosbag1 import Reader, Writer

from cli_checks import SAMPLES, invoke
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.readers import inspect_log, read_log
from slamobs.pipeline.readers.container import OVERLAP_ERROR_S, check_part_order

LOG = SAMPLES / "circle.bag"
NS = 1_000_000_000


def split_bag(src: Path, out: Path, cuts_s: list[float], drop_s: tuple[float, float] | None = None) -> list[Path]:
    """``src`` as ``rec_0.bag``, ``rec_1.bag``, ... cut at ``cuts_s`` seconds after its start (as ``rosbag record
    --split`` writes them: each part with the connections of its messages); messages in ``drop_s`` left out."""
    out.mkdir(parents=True)
    with Reader(src) as reader:
        t0 = reader.start_time
        cuts = [t0 + int(c * 1e9) for c in cuts_s]
        paths = [out / f"rec_{k}.bag" for k in range(len(cuts) + 1)]
        writers = [Writer(p) for p in paths]
        conns: list[dict] = [{} for _ in paths]
        for w in writers:
            w.open()
        for conn, t, raw in reader.messages():
            if drop_s is not None and t0 + drop_s[0] * 1e9 <= t < t0 + drop_s[1] * 1e9:
                continue
            k = sum(t >= c for c in cuts)
            if conn.id not in conns[k]:
                conns[k][conn.id] = writers[k].add_connection(
                    conn.topic,
                    conn.msgtype,
                    msgdef=conn.msgdef.data,
                    md5sum=conn.digest,
                    callerid=conn.ext.callerid,
                    latching=conn.ext.latching,
                )
            writers[k].write(conns[k][conn.id], t, raw)
        for w in writers:
            w.close()
    return paths


@pytest.fixture(scope="module")
def parts(tmp_path_factory) -> list[Path]:
    return split_bag(LOG, tmp_path_factory.mktemp("split") / "rec", [10.0, 20.0])


def test_rosbag_split_parts_named_after_their_start_are_one_recording_in_any_directory(parts, tmp_path):
    """``rosbag record --split -o session`` writes session_2024-05-01-12-00-00_0.bag, _1.bag, ... wherever it runs:
    the start time in their names marks them as one recording, whatever the directory is called; whole logs named
    flight_0.bag, flight_1.bag in it are not (test_whole_logs_that_only_look_like_parts_are_one_line)."""
    shelf = tmp_path / "bags"
    shelf.mkdir()
    for k, part in enumerate(parts):
        shutil.copy(part, shelf / f"session_2024-05-01-12-00-00_{k}.bag")
    whole, split = inspect_log(LOG), inspect_log(shelf)
    assert split.container == "ros1-split" and split.storage == "3 bag files"
    assert {t.topic: t.count for t in split.topics} == {t.topic: t.count for t in whole.topics}


def test_info_reads_the_parts_as_one_log_in_order(parts):
    whole, split = inspect_log(LOG), inspect_log(parts[0].parent)
    assert split.container == "ros1-split" and split.storage == "3 bag files"
    assert {t.topic: t.count for t in split.topics} == {t.topic: t.count for t in whole.topics}
    assert split.duration_s == pytest.approx(whole.duration_s)
    (note,) = [w for w in split.warnings if w.startswith("split recording of 3 ROS1 bags")]
    assert note.index("rec_0.bag 0.000") < note.index("rec_1.bag 10.0") < note.index("rec_2.bag 20.0")
    # the parts given one by one, in any order, are the same log
    res = invoke("info", parts[2], parts[0], parts[1], "--json")
    assert res.exit_code == 0 and json.loads(res.stdout)["path"] == str(parts[0].parent)


def test_one_part_given_alone_says_its_other_parts_lie_beside_it(parts):
    """``rec/rec_0.bag`` of three given as the log: run and info read its 10 s of the recording's 30 s with no word
    (exit 0, a result over a third of the recording). Now a warning names the parts and the directory to give."""
    said = (
        f"warning: rec_1.bag is one part of a split recording (3 parts beside each other: rec_0.bag, rec_1.bag, "
        f"rec_2.bag): slamobs reads rec_1.bag alone, so a run's result covers that part of the recording only; give "
        f"the directory {parts[1].parent} to read the parts as one log"
    )
    assert said in read_log(parts[1]).warnings and said in inspect_log(parts[1]).warnings
    assert not any("one part of a split recording" in w for w in read_log(parts[1].parent).warnings)


def test_a_gap_between_files_is_reported(tmp_path):
    gapped = split_bag(LOG, tmp_path / "rec", [10.0, 20.0], drop_s=(9.5, 10.7))
    notes = inspect_log(gapped[0].parent).warnings
    (gap,) = [n for n in notes if "without messages between rec_0.bag and rec_1.bag" in n]
    assert 1.15 < float(gap.split("split recording: ")[1].split(" s")[0]) < 1.25  # 9.5 to 10.7 s, rates ~100 Hz
    assert not any("between rec_1.bag and rec_2.bag" in n for n in notes)


def test_a_run_on_the_parts_is_the_run_on_the_whole_log(parts, tmp_path):
    config = tmp_path / "run.yaml"
    config.write_text("evaluation:\n  plots: false\n")  # the figures are most of a short run's time
    for name, log in (("whole", [LOG]), ("split", parts)):
        res = invoke("run", *log, "-o", tmp_path / name, "--config", config, "-q")
        assert res.exit_code == 0, res.output
    for table in ("poses", "landmarks", "biases"):
        whole = pd.read_parquet(tmp_path / "whole" / f"{table}.parquet")
        assert whole.equals(pd.read_parquet(tmp_path / "split" / f"{table}.parquet")), table
    meta = json.loads((tmp_path / "split" / "run.json").read_text())
    assert meta["input"]["path"] == str(parts[0].parent.resolve())
    assert any(n.startswith("split recording of 3 ROS1 bags") for n in meta["notes"])


def test_what_is_not_one_split_recording_is_one_line(parts, tmp_path):
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for p in parts:
        shutil.copy(p, mixed / p.name)
    shutil.copy(parts[0], mixed / "other_0.bag")
    res = invoke("info", mixed, catch_exceptions=True)
    assert res.exit_code == 2 and "holds the parts of 2 recordings (other_*.bag, rec_*.bag)" in res.output
    assert len(res.output.strip().splitlines()) == 1
    res = invoke("run", parts[0], parts[1], "-o", tmp_path / "out", catch_exceptions=True)
    assert res.exit_code == 2 and "give the directory" in res.output and not (tmp_path / "out").exists()
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "rec_0.bag").write_bytes(parts[0].read_bytes())
    (bad / "rec_1.bag").write_text("not a bag")
    res = invoke("info", bad, catch_exceptions=True)
    assert res.exit_code == 2 and f"{bad / 'rec_1.bag'}: not a ROS1 bag" in res.output


def test_a_cut_part_is_named_in_the_recovery_note(parts, tmp_path):
    # a recording whose last part was cut said 'ROS1 bag is incomplete ...' without saying which of its files
    cut = tmp_path / "cut" / "rec"
    cut.mkdir(parents=True)
    for p in parts:
        shutil.copy(p, cut / p.name)
    last = cut / parts[-1].name
    last.write_bytes(last.read_bytes()[: last.stat().st_size // 2])
    notes = read_log(cut).warnings
    assert any(n.startswith(f"{last.name}: ROS1 bag is incomplete (") for n in notes), notes
    assert not any(n.startswith("ROS1 bag is incomplete") for n in notes)


def test_whole_logs_that_only_look_like_parts_are_one_line(tmp_path):
    # two flights saved as flight_0.bag, flight_1.bag: read as one log their samples interleaved (6001 "repeated
    # stamps with different values" and exit 0 on two copies of a simulated MCAP); parts of one recording follow
    # each other in time
    flights = tmp_path / "flight"  # named after its files, as a recorder lays out the parts of one recording
    flights.mkdir()
    for k in (0, 1):
        shutil.copy(LOG, flights / f"flight_{k}.bag")
    for command in (("info", flights), ("run", flights, "-o", tmp_path / "out")):
        res = invoke(*command, catch_exceptions=True)
        assert res.exit_code == 2, res.output
        assert "flight_1.bag starts" in res.output and "not the parts of one split recording" in res.output
        assert len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
    # a recorder's cache may overlap two parts by milliseconds: still one recording, up to OVERLAP_ERROR_S
    parts = [Path("rec_0.bag"), Path("rec_1.bag")]
    end = 10 * NS
    check_part_order(tmp_path, parts, [(0, end), (end - int(0.9 * OVERLAP_ERROR_S * NS), 20 * NS)])
    with pytest.raises(InputError, match="rec_1.bag starts 1.100 s before rec_0.bag ends"):
        check_part_order(tmp_path, parts, [(0, end), (end - int(1.1 * OVERLAP_ERROR_S * NS), 20 * NS)])


def test_a_directory_of_whole_logs_is_one_line_for_every_command_and_batch_runs_each(tmp_path):
    # two flights recorded one after the other (no overlap), saved as flights/flight_0.mcap, flight_1.mcap: run read
    # them as one log across the gap while batch took them as two; the parts of one recording are named after their
    # directory (the one rule, container._one_recording, for run, info, compare, tune and batch discovery)
    from slamobs.pipeline.batch.discover import discover
    from slamobs.pipeline.simulate import simulation, write_log

    flights, flight = tmp_path / "flights", tmp_path / "flight"
    for k in (0, 1):
        sim = simulation("circle", duration=3.0, start_ns=1_700_000_000 * NS + k * 60 * NS)
        write_log(sim, flights / f"flight_{k}.mcap")
        write_log(sim, flight / f"flight_{k}.mcap")
    wanted = f"{flights}: holds 2 logs (flight_0.mcap, flight_1.mcap), not one recording"
    for command in (
        ("info", flights),
        ("run", flights, "-o", tmp_path / "out"),
        ("compare", flights, "--observers", "hashim,riekf", "-o", tmp_path / "out"),
        ("tune", flights, "--observer", "hashim", "-o", tmp_path / "out"),
    ):
        res = invoke(*command, catch_exceptions=True)
        assert res.exit_code == 2, (command[0], res.output)
        assert wanted in res.output and f"`slamobs batch {flights}`" in res.output, (command[0], res.output)
        (line,) = [line for line in res.output.splitlines() if not line.startswith(f"{command[0]}: ")]  # progress
        assert line.startswith(f"error: {wanted}"), (command[0], res.output)
    assert not (tmp_path / "out").exists()
    assert [e.path for e in discover([flights])] == [flights / "flight_0.mcap", flights / "flight_1.mcap"]
    # named after their directory they are the parts of one recording, for info and batch alike
    info = inspect_log(flight)
    assert info.container == "ros2-split" and info.duration_s > 60
    assert [e.path for e in discover([flight])] == [flight]


def test_a_directory_of_whole_bags_says_what_to_run(tmp_path):
    # imu_tools/ holding ardrone_imu.bag, sparkfun_razor.bag said 'ardrone_imu.bag is not named NAME_N.bag as the
    # parts of a split recording are', not what to run instead
    logs = tmp_path / "imu_tools"
    logs.mkdir()
    for name in ("ardrone_imu.bag", "sparkfun_razor.bag"):
        shutil.copy(LOG, logs / name)
    res = invoke("info", logs, catch_exceptions=True)
    assert res.exit_code == 2 and res.output == (
        f"error: {logs}: holds 2 logs (ardrone_imu.bag, sparkfun_razor.bag), not one recording (the parts of one are "
        f"named after their directory: imu_tools/imu_tools_0.bag): run one file, or `slamobs batch {logs}` over them\n"
    )
    (logs / "sparkfun_razor.bag").unlink()
    with pytest.raises(InputError, match=rf"holds one log, ardrone_imu.bag, not the parts of a recording: run {logs}/"):
        read_log(logs)


def split_rosbag2(src: Path, out: Path, cuts_s: list[float]) -> Path:
    """The rosbag2 directory ``src`` as a split recording ``out/NAME_0.db3``, ``NAME_1.db3``, ... cut at ``cuts_s``
    seconds after its start, with the metadata.yaml rosbag2 writes for one (every file listed, each with its start,
    duration and message count)."""
    import yaml
    from rosbags.rosbag2 import Reader as Reader2
    from rosbags.rosbag2 import Writer as Writer2

    out.mkdir(parents=True)
    with Reader2(src) as reader:
        cuts = [reader.start_time + int(c * NS) for c in cuts_s]
        writers = [Writer2(out / f"p{k}", version=9) for k in range(len(cuts) + 1)]
        conns: list[dict] = [{} for _ in writers]
        for w in writers:
            w.open()
        for conn, t, raw in reader.messages():
            k = sum(t >= c for c in cuts)
            if conn.id not in conns[k]:
                conns[k][conn.id] = writers[k].add_connection(
                    conn.topic, conn.msgtype, msgdef=conn.msgdef.data, rihs01=conn.digest
                )
            writers[k].write(conns[k][conn.id], t, raw)
        for w in writers:
            w.close()
    meta = yaml.safe_load((src / "metadata.yaml").read_text())
    files = []
    for k in range(len(writers)):
        (part,) = yaml.safe_load((out / f"p{k}" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["files"]
        (out / f"p{k}" / part["path"]).rename(out / f"{out.name}_{k}.db3")
        files.append({**part, "path": f"{out.name}_{k}.db3"})
        shutil.rmtree(out / f"p{k}")
    info = meta["rosbag2_bagfile_information"]
    info["relative_file_paths"], info["files"] = [f["path"] for f in files], files
    (out / "metadata.yaml").write_text(yaml.safe_dump(meta))
    return out


def test_a_rosbag2_recording_with_a_listed_file_missing_runs_on_the_others_with_a_gap(tmp_path):
    """metadata.yaml lists x_0.db3, x_1.db3, x_2.db3 and x_1 is gone: it was an error ('Some database files are
    missing'); the parts there are are read, info names the missing file and the span it held (from metadata.yaml's
    per-file start and duration, else the parts around it), and the alignment starts a new segment after it: the
    3 s hole is shorter than limits.max_gap, so the velocities were interpolated across it."""
    from slamobs.pipeline.alignment import align

    rec = split_rosbag2(SAMPLES / "circle_ros2", tmp_path / "x", [10.0, 13.0])
    whole = read_log(rec)
    assert "missing" not in " ".join(whole.warnings) and align(whole).segment_starts.size == 0
    (rec / "x_1.db3").unlink()
    res = invoke("info", rec)
    assert res.exit_code == 0, res.output
    assert "rosbag2 directory with missing files (2 of 3 .db3 files)" in res.output
    (note,) = [w for w in inspect_log(rec).warnings if "x_1.db3" in w]
    assert note.startswith("split recording: x_1.db3, listed in metadata.yaml, is missing: 10.00")
    assert "of the recording (2.9" in note and "messages) not read; a gap" in note and f"    {note}" in res.output
    streams = read_log(rec)
    aligned = align(streams)
    (start,) = aligned.segment_starts
    t = aligned.vel_t_ns
    assert 2.9 < (t[start] - t[start - 1]) / NS < 3.1 and (t[start - 1] - t[0]) / NS == pytest.approx(10.0, abs=0.02)
    assert any(
        "where a split recording's file is missing at +9.98 s (3.0 s): the run has 2" in n for n in aligned.notes
    )
    # without per-file information (metadata before version 5) the span is the one between the parts around it
    text = (rec / "metadata.yaml").read_text()
    (rec / "metadata.yaml").write_text(text.replace("  files:", "  old_files:"))
    (note,) = [w for w in inspect_log(rec).warnings if "x_1.db3" in w]
    assert note.startswith("split recording: x_1.db3, listed in metadata.yaml, is missing: the 3.0")
    assert "s between x_0.db3 and x_2.db3 (9.99" in note
    for k in (0, 2):
        (rec / f"x_{k}.db3").unlink()
    with pytest.raises(InputError, match=r"x: none of the 3 storage files metadata.yaml lists is in it \(x_0.db3, "):
        inspect_log(rec)


def test_info_rate_is_over_the_time_recorded_not_the_missing_part(tmp_path):
    """The IMU of circle_ros2 is 100 Hz; with x_1.db3 (3 s of 30) gone, the rate averaged over the whole span read
    90 Hz in info's topic table and readiness: the gap the clocks table reports is left out of the span."""
    rec = split_rosbag2(SAMPLES / "circle_ros2", tmp_path / "x", [10.0, 13.0])
    (rec / "x_1.db3").unlink()
    rates = {t.topic: t.rate_hz for t in inspect_log(rec).topics}
    assert rates["/imu/data"] == pytest.approx(100.0, rel=1e-3) and rates["/odom"] == pytest.approx(25.0, rel=1e-3)
    res = invoke("info", rec)
    assert "(sensor_msgs/msg/Imu, 100.0 Hz)" in res.output, res.output


def test_a_missing_part_number_is_a_gap_too(parts, tmp_path):
    """rec_0.bag and rec_2.bag without rec_1.bag: the note names the missing file and the span between its
    neighbours ('parts 1 are missing' before), and the run starts a new segment after it."""
    from slamobs.pipeline.alignment import align

    rec = tmp_path / "rec"
    rec.mkdir()
    for k in (0, 2):
        shutil.copy(parts[k], rec / parts[k].name)
    streams = read_log(rec)
    (note,) = [w for w in streams.warnings if "rec_1.bag" in w]
    assert (
        note.startswith("split recording: rec_1.bag is missing: the 10.0") and "between rec_0.bag and rec_2.bag" in note
    )
    assert align(streams, limits={"max_gap": None}).segment_starts.size == 1
