"""One truth grammar: a topic, a TF edge ``parent->child``, a trajectory file and another log's ``LOG:TOPIC``, each
accepted by ``run`` (``--truth`` and ``topics.truth`` in a config), ``report --truth``, ``evaluate``, ``compare``
and ``batch`` configs, with one-line errors for a truth that names nothing."""

from __future__ import annotations

import json
import shutil

import pytest

from slamobs.pipeline.config import load_config
from slamobs.pipeline.readers import parse_truth, read_truth
from slamobs.pipeline.readers.trajectory_files import write_tum
from slamobs.pipeline.simulate.logwriter import make_typestore, write_log
from slamobs.pipeline.simulate.sensors import simulate

from cli_checks import invoke

TOPIC = "/mocap/pose"
EDGE = "world->mocap_body"


def _with_tf(src, dst) -> None:
    """``src`` (a ROS1 bag) copied with its truth poses also published on ``/tf`` as ``world -> mocap_body``."""
    from rosbags.rosbag1 import Reader, Writer

    ts = make_typestore(ros1=True)
    tf_type = "tf2_msgs/msg/TFMessage"
    msgs = ts.types
    with Reader(src) as reader, Writer(dst) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=ts) for c in reader.connections}
        tf_conn = writer.add_connection("/tf", tf_type, typestore=ts)
        for conn, t, raw in reader.messages():
            writer.write(conns[conn.id], t, raw)
            if conn.topic != TOPIC:
                continue
            pose = ts.deserialize_ros1(raw, conn.msgtype)
            p, q = pose.pose.position, pose.pose.orientation
            header = msgs["std_msgs/msg/Header"](seq=0, stamp=pose.header.stamp, frame_id="world")
            tf = msgs["geometry_msgs/msg/TransformStamped"](
                header=header,
                child_frame_id="mocap_body",
                transform=msgs["geometry_msgs/msg/Transform"](
                    translation=msgs["geometry_msgs/msg/Vector3"](x=p.x, y=p.y, z=p.z), rotation=q
                ),
            )
            writer.write(tf_conn, t, ts.serialize_ros1(msgs[tf_type](transforms=[tf]), tf_type))


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A short circle log with its truth also on /tf, the log without it as "another log", its truth as a TUM file,
    and a config without figures (the runs here check truths, not plots)."""
    root = tmp_path_factory.mktemp("truth")
    log, other = root / "circle_tf.bag", root / "other.bag"
    write_log(simulate("circle", duration=8.0, seed=5), other)
    _with_tf(other, log)
    tum = write_tum(root / "truth_tum.txt", read_truth(f"{other}:{TOPIC}").stream)
    config = root / "no_plots.yaml"
    config.write_text("evaluation:\n  plots: false\n")
    return {"log": log, "other": other, "tum": tum, "root": root, "config": config}


def _forms(logs) -> dict[str, str]:
    return {"topic": TOPIC, "edge": EDGE, "file": str(logs["tum"]), "log_topic": f"{logs['other']}:{TOPIC}"}


def test_parse_truth_kinds(logs):
    kinds = {name: parse_truth(text) for name, text in _forms(logs).items()}
    assert [kinds[n].kind for n in ("topic", "edge", "file", "log_topic")] == ["topic", "edge", "file", "topic"]
    assert kinds["log_topic"].log == logs["other"] and kinds["log_topic"].name == TOPIC
    other_edge = parse_truth(f"{logs['other']}:{EDGE}")
    assert (other_edge.kind, other_edge.log, other_edge.name) == ("edge", logs["other"], EDGE)


@pytest.fixture(scope="module")
def run_dirs(logs):
    """One run per truth form given with ``run --truth``; their APE (they are the same poses)."""
    out = {}
    for name, text in _forms(logs).items():
        out[name] = logs["root"] / f"run_{name}"
        res = invoke("run", logs["log"], "-o", out[name], "--truth", text, "--config", logs["config"])
        assert res.exit_code == 0, (name, res.output)
        assert "APE" in res.output, (name, res.output)
    return out


def _ape(run_dir) -> float:
    return json.loads((run_dir / "report.json").read_text())["ape"]["translation_m"]["rmse"]


def test_run_takes_every_form(run_dirs):
    apes = {name: _ape(d) for name, d in run_dirs.items()}
    assert max(apes.values()) - min(apes.values()) < 1e-3, apes  # same poses, on their own stamps or the log's


def test_report_takes_every_form(logs, run_dirs):
    base = run_dirs["topic"]
    for name, text in _forms(logs).items():
        res = invoke("report", base, "--truth", text, "--json")
        assert res.exit_code == 0, (name, res.output)
        rep = json.loads(res.stdout)
        assert abs(rep["ape"]["translation_m"]["rmse"] - _ape(run_dirs[name])) < 1e-3, name
    src = json.loads(invoke("report", base, "--truth", f"{logs['other']}:{TOPIC}", "--json").stdout)["truth_source"]
    assert src["log"] == str(logs["other"])
    # the summary named `topic /mocap/pose` alone, as if the run's own log's (round 21)
    res = invoke("report", base, "--truth", f"{logs['other']}:{TOPIC}", "--no-plots")
    assert f"truth        topic {TOPIC} of {logs['other']} (" in res.stdout, res.stdout


def test_config_topics_truth_takes_every_form(logs, tmp_path):
    for name, text in _forms(logs).items():
        path = tmp_path / f"{name}.yaml"
        path.write_text(f"topics:\n  truth: {json.dumps(text)}\n")
        config = load_config(path)
        if name in ("file", "log_topic"):
            assert config.evaluation.truth_file == text and "truth" not in config.topics, name
        else:
            assert config.topics["truth"] == text, name
    relative = tmp_path / "rel.yaml"
    shutil.copy(logs["tum"], tmp_path / "t.txt")
    relative.write_text("topics:\n  truth: t.txt\n")
    assert load_config(relative).evaluation.truth_file == str(tmp_path / "t.txt")


def test_evaluate_takes_file_and_log_forms(logs):
    est = f"{logs['other']}:/odom"
    for text in (str(logs["tum"]), f"{logs['other']}:{TOPIC}", f"{logs['log']}:{EDGE}"):
        res = invoke("evaluate", text, est, "--json")
        assert res.exit_code == 0, (text, res.output)
        assert json.loads(res.stdout)["stats"]["rmse"] > 0
    res = invoke("evaluate", TOPIC, est)
    assert res.exit_code == 2 and "needs its log" in res.output


def test_evaluate_takes_a_tf_edge_as_the_estimate_and_evos_tf_form(logs):
    """evo's tf_example.bag (a trajectory on /tf only): `evaluate LOG:TOPIC LOG:odom->base_footprint` said "topic not
    in the log (topics: /tf, /tf_static)", an estimate could not be a TF edge; evo's own `bag LOG /tf:parent.child`
    neither."""
    truth = f"{logs['other']}:{TOPIC}"
    res = invoke("evaluate", truth, f"{logs['log']}:{EDGE}", "--json")
    assert res.exit_code == 0, res.output
    edge = json.loads(res.stdout)["stats"]
    assert edge["rmse"] < 1e-6 and edge["n"] > 100  # the same poses as the truth topic it was published from
    parent, child = EDGE.split("->")
    res = invoke("evaluate", "bag", logs["log"], TOPIC, f"/tf:{parent}.{child}", "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["stats"] == edge
    res = invoke("evaluate", "bag", logs["log"], TOPIC, f"/tf_other:{parent}.{child}")
    assert res.exit_code == 2 and "/tf:parent.child" in res.output and "Traceback" not in res.output


def test_compare_and_batch_take_a_truth(logs, tmp_path):
    res = invoke(
        "compare",
        logs["log"],
        "-o",
        tmp_path / "cmp",
        "--observers",
        "fast-adaptation",
        "--truth",
        EDGE,
        "--config",
        logs["config"],
    )
    assert res.exit_code == 0, res.output
    run = json.loads((tmp_path / "cmp" / "fast-adaptation" / "report.json").read_text())
    assert run["truth_source"]["name"] == "/tf"  # the edge's poses, read from the log's /tf
    config = tmp_path / "run.yaml"
    other = f"{logs['other']}:{TOPIC}"
    config.write_text(f"topics:\n  truth: {json.dumps(other)}\nevaluation:\n  plots: false\n")
    res = invoke("batch", logs["log"], "-o", tmp_path / "batch", "--config", config)
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("/no/such/topic", "topic for role truth is not in the log"),
        ("/no/such/traj.txt", "/no/such/traj.txt: no such file"),  # a mistyped file (it read as a missing topic)
        ("missing.bag:/mocap/pose", "no such log"),
        ("world->", "is not 'parent->child'"),
    ],
)
def test_a_truth_that_names_nothing_is_one_line(logs, tmp_path, text, says):
    res = invoke("run", logs["log"], "-o", tmp_path / "out", "--truth", text)
    assert res.exit_code == 2
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and says in errors[0], res.output
    assert "a truth is a topic of the log" in errors[0]
    assert not (tmp_path / "out").exists()


def test_another_log_s_topic_mistyped_says_which_one_was_meant(logs, tmp_path):
    """`--truth reference.bag:/tagslam/odom/body` (TagSLAM test 22's reference is .../body_rig): the error listed the
    log's topics but, unlike a topic of the run's own log, did not say which one was meant."""
    res = invoke("run", logs["log"], "-o", tmp_path / "out", "--truth", f"{logs['other']}:/mocap/pos")
    assert res.exit_code == 2
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "topic not in the log (did you mean /mocap/pose? topics: " in errors[0], res.output
    assert not (tmp_path / "out").exists()


def test_truth_none_runs_and_reports_without_truth(logs, run_dirs, tmp_path):
    # session 17: `--truth none` read as a topic named "none" (exit 2); a user with a truth in the log had no way to
    # run as without it. Now no truth, not even the one the log's /mocap/pose would give by detection.
    res = invoke("run", logs["log"], "-o", tmp_path / "run", "--truth", "none", "--config", logs["config"])
    assert res.exit_code == 0, res.output
    assert "APE" not in res.output and not (tmp_path / "run" / "report.json").exists(), res.output
    assert "truth" not in json.loads((tmp_path / "run" / "run.json").read_text())["input"]["topics"]
    res = invoke("compare", logs["log"], "-o", tmp_path / "cmp", "--observers", "fast-adaptation", "--truth", "none")
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "cmp" / "fast-adaptation" / "report.json").exists()
    res = invoke("report", run_dirs["topic"], "--truth", "none")  # a run with truth, summarised without it
    assert res.exit_code == 0 and res.output.startswith("truth        none (--truth none)"), res.output
    page = (run_dirs["topic"] / "report.md").read_text()
    assert "# Run summary (no ground truth)" in page
    # its summary said "none in the log, or one too short or empty: the notes say which", and no note said
    assert "- no error report: --truth none set the run's own truth aside" in page, page


def test_a_gps_fix_named_as_a_trajectory_says_what_to_convert_it_to(tmp_path):
    """robot_localization's test1 has a NavSatFix /fix beside its odometry; `evaluate test1.bag:/fix ...` said only
    that the type is not a trajectory. It now says why (no orientation, not metres) and what to name instead."""
    import numpy as np
    from rosbags.rosbag1 import Writer

    ts = make_typestore(ros1=True)
    t, fix_type = ts.types, "sensor_msgs/msg/NavSatFix"
    path = tmp_path / "gps.bag"
    with Writer(path) as writer:
        conn = writer.add_connection("/fix", fix_type, typestore=ts)
        for k in range(5):
            stamp = t["builtin_interfaces/msg/Time"](sec=100 + k, nanosec=0)
            msg = t[fix_type](
                header=t["std_msgs/msg/Header"](seq=k, stamp=stamp, frame_id="gps"),
                status=t["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                latitude=42.3758, longitude=-71.1474, altitude=7.3, position_covariance_type=1,
                position_covariance=np.array([0.81, 0, 0, 0, 0.81, 0, 0, 0, 3.24]),
            )  # fmt: skip
            writer.write(conn, (100 + k) * 1_000_000_000, ts.serialize_ros1(msg, fix_type))
    res = invoke("evaluate", f"{path}:/fix", f"{path}:/fix")
    assert res.exit_code == 2, res.output
    assert "type sensor_msgs/msg/NavSatFix is not a trajectory" in res.output, res.output
    assert "a GPS fix is latitude and longitude with no orientation" in res.output, res.output
    assert "navsat_transform_node" in res.output and res.output.count("\n") == 1, res.output
