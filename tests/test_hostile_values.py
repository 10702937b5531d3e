"""Hostile values (issue 28), part of the hostile-input catalogue of ``test_hostile_inputs.py``: YAML alias bombs
and cycles, 64-bit record times and ids, odd JSON and edited tables are one line naming the file, never a
traceback, a hang or a silently wrapped number."""

from __future__ import annotations

import sqlite3
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_hostile_inputs import invoke, no_runtime_warnings, one_line_error

from slamobs.pipeline.simulate import simulate, write_log
from slamobs.pipeline.simulate.sensors import TOPIC_TRUTH

NS = 1_000_000_000
TWO63 = 2**63

#: Nine lines, each alias nine times the one before: 9^9 (387 million) strings once expanded.
BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{k}: &{k} [{', '.join([f'*{p}'] * 9)}]\n" for p, k in zip("abcdefgh", "bcdefghi")
)
YAML_CASES = {
    "bomb": (BOMB, "alias bomb"),
    "cycle": ("a: &a [*a]\n", "*a refers to a value that contains it"),
    # ruamel's scanner spent 15 s on a 4 kB file of '[' before its RecursionError
    "flow": ("[" * 2000 + "]" * 2000 + "\n", "nests [ ] or { } 2000 levels deep"),
    "block": ("- " * 2000 + "x\n", "nested too deeply"),
}


@pytest.fixture(scope="module")
def sim():
    return simulate("figure8", duration=3.0, seed=28, imu_rate=100.0)


@pytest.fixture(scope="module")
def mcap_log(sim, tmp_path_factory) -> Path:
    return write_log(sim, tmp_path_factory.mktemp("values") / "f8.mcap")


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> Path:
    cfg = tmp_path_factory.mktemp("cfg") / "quick.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    return cfg


# --------------------------------------------------------------------------- YAML


@pytest.mark.parametrize("case", list(YAML_CASES))
def test_yaml_bomb_cycle_and_depth_are_one_line_in_run_and_batch(mcap_log, tmp_path, case):
    text, needle = YAML_CASES[case]
    cfg = tmp_path / "run.yaml"
    cfg.write_text(text)
    start = time.process_time()
    one_line_error(invoke("run", mcap_log, "-o", tmp_path / "out", "--config", cfg), str(cfg), needle)
    assert time.process_time() - start < 30  # a guard against the minutes of the bomb, not a speed test
    res = invoke("batch", mcap_log, "-o", tmp_path / "batch", "--config", cfg)
    assert "Traceback" not in res.output + res.stderr and "RecursionError" not in res.output + res.stderr
    assert res.exit_code == 2 and needle in res.output + res.stderr, (res.exit_code, res.output, res.stderr)


@pytest.mark.parametrize("what", ["manifest", "map", "camera file"])
def test_every_yaml_file_is_read_with_the_alias_budget(tmp_path, what):
    from slamobs.pipeline.batch.discover import read_manifest
    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.known_map import read_map
    from slamobs.pipeline.vision.cameras import read_camera_files

    path = tmp_path / ("logs.yaml" if what == "manifest" else "tagslam.yaml" if what == "map" else "cams.yaml")
    path.write_text(BOMB)
    read = {"manifest": read_manifest, "map": read_map, "camera file": lambda p: read_camera_files([p])}
    with pytest.raises(InputError, match=f"aliases expand the {what} by 4.9e\\+08 values"):
        read[what](path)
    from slamobs.pipeline.config import load_config

    cfg = tmp_path / "run.yaml"  # aliases within the budget still work
    cfg.write_text("limits: {max_range: &r 50.0, max_gap: *r}\n")
    assert load_config(cfg).limits.max_gap == 50.0


# --------------------------------------------------------------------------- 64-bit record times


def _shifted_mcap(src: Path, dst: Path, shift: int = 0, edit=None, indexed: bool = True) -> Path:
    """``src`` rewritten with the MCAP writer, every log and publish time moved by ``shift`` (uint64 on disk) and
    the text of its simulation truth (a std_msgs/String) replaced by ``edit(text)``; without ``indexed`` the
    summary has no chunk indexes and no statistics (the reader scans the chunks)."""
    from mcap.reader import make_reader
    from mcap.writer import IndexType, Writer

    from slamobs.pipeline.simulate.logwriter import make_typestore

    ts = make_typestore(ros1=False)
    with src.open("rb") as fin, dst.open("wb") as fout:
        writer = Writer(fout) if indexed else Writer(fout, index_types=IndexType.NONE, use_statistics=False)
        writer.start(profile="ros2", library="slamobs-tests")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg in make_reader(fin).iter_messages():
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            data = msg.data
            if edit is not None and channel.topic == TOPIC_TRUTH:
                text = edit(ts.deserialize_cdr(data, schema.name).data)
                data = bytes(ts.serialize_cdr(ts.types[schema.name](data=text), schema.name))
            writer.add_message(
                channels[channel.id],
                log_time=msg.log_time + shift,
                data=data,
                publish_time=msg.publish_time + shift,
                sequence=msg.sequence,
            )
        writer.finish()
    return dst


def _span(log: Path) -> tuple[int, int]:
    """First and last log time of an MCAP file, from its summary."""
    from mcap.reader import make_reader

    with log.open("rb") as f:
        stats = make_reader(f).get_summary().statistics
    return stats.message_start_time, stats.message_end_time


def test_record_times_past_2_63_are_one_line_in_info_and_run(mcap_log, tmp_path, quick):
    log = _shifted_mcap(mcap_log, tmp_path / "year2262.mcap", TWO63)
    one_line_error(invoke("info", log), str(log), "outside 0 to 2^62 ns")
    scanned = _shifted_mcap(mcap_log, tmp_path / "scanned.mcap", TWO63, indexed=False)
    one_line_error(invoke("info", scanned), str(scanned), f"record (log) times {TWO63 + _span(mcap_log)[0]} to")
    rec = tmp_path / "rec.yaml"
    rec.write_text(quick.read_text() + "time:\n  source: record\n")
    for cfg in (quick, rec):  # with record times the run used to go on with negative t_ns
        one_line_error(invoke("run", log, "-o", tmp_path / "out", "--config", cfg), str(log), "outside 0 to 2^62 ns")
    # just below 2^63: no wrap, but the report's sums of times overflowed (numpy RuntimeWarnings, a wrong offset)
    edge = _shifted_mcap(mcap_log, tmp_path / "edge.mcap", TWO63 - 2 - _span(mcap_log)[1])
    with no_runtime_warnings():
        one_line_error(invoke("run", edge, "-o", tmp_path / "out", "--config", rec), str(edge), "outside 0 to 2^62 ns")
    assert not (tmp_path / "out").exists()


def test_a_wrapped_record_time_the_summary_does_not_show_names_the_topic(sim, tmp_path, quick):
    """rosbag2 (sqlite3) stores int64 record times: a negative one is refused per message, naming its topic."""
    log = write_log(sim, tmp_path / "neg", "ros2")
    (db,) = log.glob("*.db3")
    with sqlite3.connect(db) as con:
        con.execute("UPDATE messages SET timestamp = timestamp - ? WHERE id % 7 = 0", (TWO63 - 1,))
    one_line_error(invoke("run", log, "-o", tmp_path / "out", "--config", quick), str(log), "outside 0 to 2^62 ns")


# --------------------------------------------------------------------------- 64-bit ids


def _tf_tags_mcap(src: Path, dst: Path, id_shift: int) -> Path:
    """``src`` with its fiducial detections written as TF tag frames ``tag_<id + id_shift>`` on /tf."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from slamobs.pipeline.simulate.logwriter import make_typestore
    from slamobs.pipeline.simulate.sensors import TOPIC_DETECTIONS

    ts = make_typestore(ros1=False)
    tf_type, stamped = "tf2_msgs/msg/TFMessage", ts.types["geometry_msgs/msg/TransformStamped"]
    with src.open("rb") as fin, dst.open("wb") as fout:
        writer = Writer(fout)
        writer.start(profile="ros2", library="slamobs-tests")
        msgdef, _ = ts.generate_msgdef(tf_type, ros_version=2)
        tf_channel = writer.register_channel("/tf", "cdr", writer.register_schema(tf_type, "ros2msg", msgdef.encode()))
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg in make_reader(fin).iter_messages():
            if channel.topic == TOPIC_DETECTIONS:
                arr = ts.deserialize_cdr(msg.data, schema.name)
                tags = [
                    stamped(header=arr.header, child_frame_id=f"tag_{f.fiducial_id + id_shift}", transform=f.transform)
                    for f in arr.transforms
                ]
                data = bytes(ts.serialize_cdr(ts.types[tf_type](transforms=tags), tf_type))
                writer.add_message(tf_channel, log_time=msg.log_time, publish_time=msg.publish_time, data=data)
                continue
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            writer.add_message(
                channels[channel.id],
                log_time=msg.log_time,
                data=msg.data,
                publish_time=msg.publish_time,
                sequence=msg.sequence,
            )
        writer.finish()
    return dst


@pytest.fixture(scope="module")
def tags_config(tmp_path_factory) -> Path:
    cfg = tmp_path_factory.mktemp("cfg") / "tags.yaml"
    cfg.write_text('evaluation:\n  plots: false\nframes:\n  tag_pattern: "tag_{id}"\noutput:\n  export: [mcap]\n')
    return cfg


def _final_map_labels(results: Path) -> tuple[list[str], list[int]]:
    """Text and marker id of every label of the last map message of a results MCAP."""
    from mcap.reader import make_reader

    from slamobs.pipeline.results_mcap import TOPIC_LANDMARKS
    from slamobs.pipeline.simulate.logwriter import make_typestore

    with results.open("rb") as f:
        *_, (schema, _, msg) = make_reader(f).iter_messages(topics=[TOPIC_LANDMARKS])
    final = make_typestore(ros1=False).deserialize_cdr(msg.data, schema.name).markers[1:]
    return [m.text for m in final], [m.id for m in final]


def test_tag_ids_beyond_int32_are_exported_with_their_labels(mcap_log, tmp_path, tags_config):
    """A visualization_msgs/Marker id is an int32: TF tag ids past it were a struct.error traceback in
    ``run --export mcap`` and ``export``; the labels now keep the ids, the markers a rank each."""
    import pandas as pd

    log = _tf_tags_mcap(mcap_log, tmp_path / "tags3e9.mcap", 3_000_000_000)
    out = tmp_path / "out"
    res = invoke("run", log, "-o", out, "--config", tags_config, "-q")
    assert res.exit_code == 0, res.stderr
    ids = pd.read_parquet(out / "landmarks.parquet")["id"].tolist()
    assert min(ids) > 3_000_000_000
    texts, marker_ids = _final_map_labels(out / "results.mcap")
    assert texts == [str(i) for i in ids] and len(set(marker_ids)) == len(ids) and max(marker_ids) < 2**31
    res = invoke("export", out, "--mcap", tmp_path / "again.mcap")
    assert res.exit_code == 0, res.stderr
    assert _final_map_labels(tmp_path / "again.mcap") == (texts, marker_ids)


def test_tag_id_beyond_int64_is_one_line(mcap_log, tmp_path, tags_config):
    log = _tf_tags_mcap(mcap_log, tmp_path / "tags2e63.mcap", TWO63)
    one_line_error(
        invoke("run", log, "-o", tmp_path / "out", "--config", tags_config),
        str(log),
        "[/tf]",
        "outside the 64-bit integers",
        "tag_pattern",
    )


# --------------------------------------------------------------------------- odd run directories


@pytest.fixture(scope="module")
def run_dir(mcap_log, quick, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "f8"
    res = invoke("run", mcap_log, "-o", out, "--config", quick, "-q")
    assert res.exit_code == 0, res.stderr
    return out


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[]", "the file is a JSON array"),
        ('{"input": [1]}', "'input' is a JSON array"),
        ("[" * 100_000 + "]" * 100_000, "unreadable run.json"),
    ],
)
def test_run_json_of_another_shape_is_one_line(run_dir, tmp_path, text, needle):
    import shutil

    odd = tmp_path / "run"
    shutil.copytree(run_dir, odd)
    (odd / "run.json").write_text(text)
    for args in (("report", odd), ("export", odd, "--mcap", tmp_path / "r.mcap")):
        one_line_error(invoke(*args), str(odd / "run.json"), needle)


def test_export_of_a_table_without_a_column_is_one_line(run_dir, tmp_path):
    import shutil

    import pyarrow.parquet as pq

    odd = tmp_path / "run"
    shutil.copytree(run_dir, odd)
    table = odd / "poses.parquet"
    pq.write_table(pq.read_table(table).drop(["qw"]), table)
    one_line_error(invoke("export", odd, "--mcap", tmp_path / "r.mcap"), str(table), "no column qw")
    assert not (tmp_path / "r.mcap").exists()


# --------------------------------------------------------------------------- messages that name the real cause


def test_detections_all_dropped_by_the_range_gate_say_so(sim, tmp_path, quick):
    """Every detection at range 0: the run said 'no landmark detections inside the velocity time span'."""
    det = sim.detections
    log = write_log(replace(sim, detections=replace(det, xyz=np.zeros_like(det.xyz))), tmp_path / "zero.mcap")
    n = det.xyz.shape[0]
    one_line_error(
        invoke("run", log, "-o", tmp_path / "out", "--config", quick),
        str(log),
        "[/fiducial_transforms]",
        f"all {n} detections inside the velocity time span were dropped by the range gate",
        f"{n} closer than limits.min_range 0.05 m",
        "null switches a gate off",
    )


def test_identical_odometry_stamps_are_one_line_without_warnings(sim, tmp_path, quick):
    odom = sim.odom
    log = write_log(replace(sim, odom=replace(odom, t_ns=np.full_like(odom.t_ns, odom.t_ns[0]))), tmp_path / "s.mcap")
    with no_runtime_warnings():
        res = invoke("run", log, "-o", tmp_path / "out", "--config", quick)
    one_line_error(res, str(log), "all", "samples have the same time", "set time.source: record")


def test_stamps_after_2038_are_one_line_before_the_run_and_in_export(mcap_log, run_dir, tmp_path, tags_config):
    """A ROS 2 stamp holds int32 seconds: the results MCAP of stamps after 2038-01-19 was a struct.error
    traceback (export) after the whole run (run --export mcap)."""
    import shutil

    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    log = _shifted_mcap(mcap_log, tmp_path / "y2065.mcap", 2_000_000_000 * NS)
    cfg = tmp_path / "rec.yaml"
    cfg.write_text("evaluation:\n  plots: false\ntime:\n  source: record\noutput:\n  export: [mcap]\n")
    res = invoke("run", log, "-o", tmp_path / "out", "--config", cfg)
    one_line_error(res, str(log), "outside the int32 seconds of a ROS 2 message stamp", "output.export")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.yaml", "y2065.mcap"]
    odd = tmp_path / "run"
    shutil.copytree(run_dir, odd)
    table = odd / "poses.parquet"
    poses = pq.read_table(table)
    shifted = pc.add(poses["t_ns"], pa.scalar(2_000_000_000 * NS, pa.int64()))
    pq.write_table(poses.set_column(poses.schema.get_field_index("t_ns"), "t_ns", shifted), table)
    one_line_error(invoke("export", odd, "--mcap", tmp_path / "r.mcap"), str(table), "int32 seconds")


def test_simulation_truth_nested_too_deeply_is_one_line(mcap_log, tmp_path, quick):
    """json's decoder recurses per level: a deep truth message was a RecursionError traceback."""
    log = _shifted_mcap(mcap_log, tmp_path / "deep.mcap", edit=lambda _text: "[" * 100_000 + "]" * 100_000)
    one_line_error(
        invoke("run", log, "-o", tmp_path / "out", "--config", quick), str(log), f"[{TOPIC_TRUTH}]", "nested too deeply"
    )


def test_ids_equal_in_their_low_32_bits_are_different_landmarks(sim):
    """Repeated ids within a frame were found on a key of the id's low 32 bits: ids 7 and 7 + 2^32 in one frame
    were one id seen twice, and one of the two detections was dropped."""
    from slamobs.pipeline.alignment import align
    from slamobs.pipeline.simulate import expected_streams

    s = expected_streams(sim, "mem.mcap")
    det = s.detections
    k = int(np.flatnonzero(np.diff(det.offsets) >= 2)[0])  # a frame with two detections
    ids = det.ids.copy()
    ids[det.offsets[k] : det.offsets[k] + 2] = [7, 7 + 2**32]
    aligned = align(replace(s, detections=replace(det, ids=ids)))
    assert not [n for n in aligned.notes if "repeated ids" in n], aligned.notes
    assert {7, 7 + 2**32} <= set(aligned.landmark_ids.tolist())
    assert aligned.det_idx.shape[0] == align(s).det_idx.shape[0]


def test_rosbag2_metadata_nested_too_deeply_is_one_line_before_rosbags_parses_it(sim, tmp_path):
    """rosbags parses metadata.yaml with ruamel: 3000 '[' took it 15 s before a RecursionError."""
    log = write_log(sim, tmp_path / "deep", "ros2")
    meta = log / "metadata.yaml"
    meta.write_text(meta.read_text().replace("custom_data:", "custom_data: " + "[" * 3000 + "]" * 3000 + "\n  x:", 1))
    one_line_error(invoke("info", log), str(meta), "nests [ ] or { } 3000 levels deep")
