"""The hostile-input catalogue of issue 16, one test per case: a run never destroys its input, never hangs, never
uses a setting it did not understand, and says what is wrong in one line.

Signals, SIGKILL and the container fuzz are in ``test_interrupts.py`` and ``test_fuzz_containers.py``; hostile
values (issue 28: YAML alias bombs and cycles, record times past 2^63 ns, stamps past 2038 in a results MCAP,
landmark ids past int32 and tag ids past int64, run.json of another shape, tables without a column, JSON nested
too deeply, detections all dropped by the range gate, identical stamps) in ``test_hostile_values.py``.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.config import parse_config
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.readers import read_log, read_truth
from slamobs.pipeline.simulate import expected_streams, simulate, write_log
from slamobs.pipeline.simulate.sensors import TOPIC_DETECTIONS, TOPIC_IMU
from cli_checks import invoke

NS = 1_000_000_000


def one_line_error(res, *needles: str) -> str:
    """Exit code 2 and exactly one ``error:`` line on stderr naming every needle; never a traceback or usage text."""
    err = res.stderr.strip()
    assert res.exit_code == 2, (res.exit_code, res.output, res.stderr)
    assert len(err.splitlines()) == 1 and err.startswith("error: "), err
    assert "Traceback" not in res.output + res.stderr and "Usage:" not in res.output + res.stderr
    for needle in needles:
        assert needle in err, (needle, err)
    return err


def snapshot(root: Path) -> dict[str, str]:
    """Every path under ``root`` (hidden ones too) with a digest of its content."""
    out = {}
    for p in sorted(root.rglob("*")):
        out[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
    return out


@pytest.fixture(scope="module")
def sim():
    return simulate("figure8", duration=6.0, seed=16, imu_rate=100.0)


@pytest.fixture(scope="module")
def logs(sim, tmp_path_factory):
    base = tmp_path_factory.mktemp("hostile")
    return {"bag": write_log(sim, base / "data" / "f8.bag"), "ros2": write_log(sim, base / "data" / "f8_ros2", "ros2")}


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> Path:
    cfg = tmp_path_factory.mktemp("cfg") / "quick.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    return cfg


def _write(sim, path: Path, **changes) -> Path:
    return write_log(replace(sim, **changes), path)


# --------------------------------------------------------------------------- the output never destroys an input


@pytest.mark.parametrize(
    "case",
    [
        "the log",
        "the rosbag2 directory",
        "the directory above the log",
        "inside the rosbag2 directory",
        "the config file",
    ],
)
def test_output_never_replaces_or_holds_an_input(logs, tmp_path, quick, case):
    data = tmp_path / "data"
    data.mkdir()
    bag = data / "f8.bag"
    bag.write_bytes(logs["bag"].read_bytes())
    ros2 = data / "f8_ros2"
    ros2.mkdir()
    for f in logs["ros2"].iterdir():
        (ros2 / f.name).write_bytes(f.read_bytes())
    (data / "notes.txt").write_text("unrelated, precious")
    cfg = data / "run.yaml"
    cfg.write_text(quick.read_text())
    log, out = {
        "the log": (bag, bag),
        "the rosbag2 directory": (ros2, ros2),
        "the directory above the log": (bag, data),
        "inside the rosbag2 directory": (ros2, ros2 / "out"),
        "the config file": (bag, cfg),
    }[case]
    before = snapshot(tmp_path)
    one_line_error(invoke("run", log, "-o", out, "--force", "--config", cfg), str(out))
    assert snapshot(tmp_path) == before
    if case == "the log":
        one_line_error(invoke("compare", log, "-o", out, "--force", "--observers", "hashim"), "input")
        assert snapshot(tmp_path) == before


@pytest.mark.parametrize(("out", "said"), [(".", "working directory"), ("", "is empty")])
def test_output_is_never_the_working_directory(logs, tmp_path, monkeypatch, out, said):
    (tmp_path / "mine.txt").write_text("precious")
    (tmp_path / "run.json").write_text("{}")  # even one that looks like an earlier run
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    one_line_error(invoke("run", logs["bag"], "-o", out, "--force"), said)
    assert snapshot(tmp_path) == before


# --------------------------------------------------------------------------- settings it did not understand

BAD_CONFIGS = {
    "gains:\n  fast_adaptation: {k_p: 50}\n": ("gains.fast_adaptation", "did you mean 'fast-adaptation'"),
    "gains:\n  hashim: {k_zz: 1}\n": ("gains.hashim", "k_zz"),
    "gains:\n  fast-adaptation: {k_w: -1}\n": ("gains.fast-adaptation", "k_w"),
    "observer: fast\n": ("observer: unknown observer 'fast'",),
    "directions:\n  gravity: [0, 0, 0]\n": ("directions.gravity", "magnitude 0"),
    "directions:\n  magnetic_field: [20, 0, -45]\n": ("directions.magnetic_field", "Tesla"),
    "directions:\n  magnetic_field: [0, 0, -4.0e-5]\n": ("parallel",),
    "limits:\n  max_range: -1\n": ("limits.max_range",),
    # YAML's .nan passes every bound of the schema: it switched gates off, and riekf's noise .nan gated every
    # detection (APE 7.4 m instead of 0.01 m, exit 0)
    "limits:\n  max_gap: .nan\n": ("limits.max_gap: nan is not a finite number", "null switches the gate off"),
    "noise:\n  gyro: .nan\n": ("noise.gyro: nan is not a finite number",),
    "limits:\n  min_range: 10\n  max_range: 1\n": ("limits: min_range 10 m is not below max_range 1 m",),
    "output:\n  rate_hz: .inf\n": ("output.rate_hz: inf is not a finite number",),
    "output:\n  frame: {position: [1, 2, .nan], orientation_xyzw: [0, 0, 0, 1]}\n": ("output.frame.position.2",),
}


@pytest.mark.parametrize("text", list(BAD_CONFIGS))
def test_config_that_names_nothing_or_is_implausible_is_one_line(logs, tmp_path, text):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(text)
    out = tmp_path / "out"
    with no_runtime_warnings():
        res = invoke("run", logs["bag"], "-o", out, "--config", cfg)
    one_line_error(res, str(cfg), *BAD_CONFIGS[text])
    assert not out.exists()


class no_runtime_warnings:  # noqa: N801 - a context manager read as a phrase
    """Fails the block if it emits a RuntimeWarning (a zero gravity once gave numpy's; divide-by-zero, overflow)."""

    def __enter__(self):
        import warnings

        self._ctx = warnings.catch_warnings(record=True)
        self.caught = self._ctx.__enter__()
        warnings.simplefilter("always")
        return self

    def __exit__(self, *exc):
        self._ctx.__exit__(*exc)
        assert not [w for w in self.caught if issubclass(w.category, RuntimeWarning)], self.caught
        return False


def test_observer_option_and_non_utf8_config_are_one_line(logs, tmp_path):
    out = tmp_path / "out"
    one_line_error(
        invoke("run", logs["bag"], "-o", out, "--observer", "hashim_imu"), "--observer", "did you mean 'hashim-imu'"
    )
    cfg = tmp_path / "latin1.yaml"
    cfg.write_bytes("observer: hashim\n# Grüße\n".encode("latin-1"))
    one_line_error(invoke("run", logs["bag"], "-o", out, "--config", cfg), str(cfg), "not UTF-8")
    assert not out.exists()


def test_time_topics_and_frames_are_checked_against_the_log(sim, logs):
    with pytest.raises(InputError, match=r"time.topics names /no/such/topic"):
        read_log(logs["bag"], clocks={"/no/such/topic": "record"})
    # a topic of the log that no role reads is not recorded as applied
    streams = read_log(logs["bag"], clocks={TOPIC_IMU: "record", "/slamobs/sim_truth": "record"})
    assert streams.clocks == {TOPIC_IMU: "record"}
    base = expected_streams(sim, "mem.bag")
    with pytest.raises(InputError, match="frames.body names 'base_lnik'"):
        align(base, body_frame="base_lnik")
    with pytest.raises(InputError, match="frames.assume_identity names 'camera_optical'"):
        align(expected_streams(sim, "mem.bag"), identity_frames=("camera_optical",))


# --------------------------------------------------------------------------- plausibility gates


def _inject(sim):
    """Distance 0 and 10 km detections, a 1e6 rad/s gyro burst and a 1 km/s odometry burst."""
    s = expected_streams(sim, "mem.bag")
    xyz = s.detections.xyz.copy()
    xyz[40] = 0.0
    xyz[80] = [1e4, 0.0, 0.0]
    gyro = s.angular_velocity.xyz.copy()
    gyro[200:205] = 1e6
    vel = s.linear_velocity.xyz.copy()
    vel[30] = [1e3, 0.0, 0.0]
    return replace(
        s,
        detections=replace(s.detections, xyz=xyz),
        angular_velocity=replace(s.angular_velocity, xyz=gyro),
        linear_velocity=replace(s.linear_velocity, xyz=vel),
    )


def test_plausibility_gates_drop_and_count(sim):
    clean = align(expected_streams(sim, "mem.bag"))
    assert not [n for n in clean.notes if "limits." in n]  # the defaults drop nothing of a plausible log
    gated = align(_inject(sim))
    notes = " | ".join(gated.notes)
    assert "5 angular-velocity samples above limits.max_angular_rate" in notes
    assert "1 linear-velocity sample above limits.max_speed" in notes
    assert "1 closer than limits.min_range" in notes and "1 farther than limits.max_range" in notes
    assert np.abs(gated.omega).max() < 100 and np.linalg.norm(gated.velocity, axis=1).max() < 300
    assert gated.vel_t_ns.shape[0] == clean.vel_t_ns.shape[0] - 5
    assert gated.det_idx.shape[0] == clean.det_idx.shape[0] - 2
    off = align(_inject(sim), limits=dict.fromkeys(("min_range", "max_range", "max_angular_rate", "max_speed")))
    assert off.vel_t_ns.shape[0] == clean.vel_t_ns.shape[0] and off.det_idx.shape[0] == clean.det_idx.shape[0]


def test_gated_run_stays_close_to_the_clean_run(sim, logs, tmp_path, quick):
    s = _inject(sim)
    det, imu = sim.detections, sim.imu
    bad = _write(
        sim,
        tmp_path / "bad.bag",
        detections=replace(det, xyz=s.detections.xyz),
        imu=replace(imu, gyro=s.angular_velocity.xyz),
    )
    apes = []
    for log, out in ((logs["bag"], tmp_path / "clean"), (bad, tmp_path / "gated")):
        res = invoke("run", log, "-o", out, "--config", quick, "-q")
        assert res.exit_code == 0, res.stderr
        apes.append(json.loads((out / "report.json").read_text())["ape"]["translation_m"]["rmse"])
    notes = " ".join(json.loads((tmp_path / "gated" / "run.json").read_text())["notes"])
    assert "limits.max_angular_rate" in notes and "limits.min_range" in notes and "limits.max_range" in notes
    assert apes[1] < 1.2 * apes[0] + 0.01, apes


# --------------------------------------------------------------------------- hangs and tracebacks


def test_absurd_detection_is_bounded_and_reported(sim, tmp_path):
    """A detection at 1e9 m with the range gate off: sub-steps are capped, the run ends and says so."""
    short = simulate("circle", duration=3.0, seed=2)
    xyz = short.detections.xyz.copy()
    xyz[short.detections.offsets[-4]] = [1e9, 0.0, 0.0]  # a landmark seen before, near the end: few intervals left
    log = _write(short, tmp_path / "far.bag", detections=replace(short.detections, xyz=xyz))
    cfg = tmp_path / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\nlimits:\n  max_range: null\n")
    res = invoke("run", log, "-o", tmp_path / "out", "--config", cfg, "-q")
    if res.exit_code == 0:
        meta = json.loads((tmp_path / "out" / "run.json").read_text())
        assert meta["counts"]["capped_intervals"] > 0
        assert any("sub-steps" in n for n in meta["notes"])
    else:
        one_line_error(res, "diverged", "sub-steps")


def test_fifo_symlink_loop_and_device_are_one_line(tmp_path):
    fifo = tmp_path / "live.mcap"
    os.mkfifo(fifo)
    # a regression would block in open(); the watchdog then opens the other end so the test fails instead of hanging
    watchdog = threading.Timer(30.0, lambda: open(fifo, "wb").close())  # noqa: SIM115
    watchdog.daemon = True
    watchdog.start()
    try:
        one_line_error(invoke("run", fifo, "-o", tmp_path / "out"), str(fifo), "FIFO")
        one_line_error(invoke("info", fifo), str(fifo), "FIFO")
        ros2 = tmp_path / "rec"
        ros2.mkdir()
        os.mkfifo(ros2 / "rec_0.mcap")
        one_line_error(invoke("info", ros2), "rec_0.mcap", "FIFO")
    finally:
        watchdog.cancel()
    loop = tmp_path / "loop.bag"
    loop.symlink_to(loop)
    one_line_error(invoke("run", loop, "-o", tmp_path / "out"), "symbolic link loop")
    one_line_error(invoke("info", loop), "symbolic link loop")
    one_line_error(invoke("info", "/dev/null"), "character device")
    assert not (tmp_path / "out").exists()


def test_output_os_errors_are_one_line_and_leave_nothing(logs, tmp_path, quick, monkeypatch):
    a_file = tmp_path / "file"
    a_file.write_text("x")
    one_line_error(
        invoke("run", logs["bag"], "-o", a_file / "out", "--config", quick),
        str(a_file / "out"),
        "cannot create the output",
    )
    import tempfile

    def read_only(*_a, **_k):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    with monkeypatch.context() as m:
        m.setattr(tempfile, "mkdtemp", read_only)
        one_line_error(invoke("run", logs["bag"], "-o", tmp_path / "ro", "--config", quick), "Read-only file system")
    import pyarrow.parquet as pq

    def disk_full(*_a, **_k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(pq.ParquetWriter, "write_table", disk_full)
    one_line_error(
        invoke("run", logs["bag"], "-o", tmp_path / "full", "--config", quick),
        str(tmp_path / "full"),
        "No space left on device",
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_a_real_write_error_is_one_line(logs, tmp_path, quick):
    """A file size limit (``RLIMIT_FSIZE``) makes the Parquet writer itself fail with EFBIG, as a full disk would."""
    import resource
    import signal
    import subprocess
    import sys

    def small_files():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of being killed
        resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))

    out = tmp_path / "out"
    proc = subprocess.run(
        [
            str(Path(sys.executable).with_name("slamobs")),
            "run",
            str(logs["bag"]),
            "-o",
            str(out),
            "--config",
            str(quick),
            "-q",
        ],
        capture_output=True,
        text=True,
        preexec_fn=small_files,
        timeout=600,
    )
    err = proc.stderr.strip()
    assert proc.returncode == 2 and len(err.splitlines()) == 1, (proc.returncode, err)
    assert err.startswith(f"error: {out}: cannot write the output: ") and "too large" in err.lower(), err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_bad_truth_keeps_the_observer_output(sim, tmp_path, quick, monkeypatch):
    q = sim.mocap.quat_xyzw.copy()
    q[::50] = 0.0
    log = _write(sim, tmp_path / "zq.bag", mocap=replace(sim.mocap, quat_xyzw=q))
    out = tmp_path / "out"
    res = invoke("run", log, "-o", out, "--config", quick, "-q")
    assert res.exit_code == 0, res.stderr
    meta = json.loads((out / "run.json").read_text())
    assert any("zero quaternion" in n for n in meta["notes"]) and meta["report_error"] is None
    # whatever else breaks the report: the observer output stands and run.json says why there is no report
    import slamobs.pipeline.evaluation as evaluation

    def broken(*_a, **_k):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(evaluation, "evaluate_tables", broken)
    out2 = tmp_path / "out2"
    res = invoke("run", log, "-o", out2, "--config", quick)
    assert res.exit_code == 0 and "no error report: ZeroDivisionError" in res.output
    meta = json.loads((out2 / "run.json").read_text())
    assert meta["report_error"] == "ZeroDivisionError: division by zero" and meta["report"] is None
    assert (out2 / "poses.parquet").stat().st_size > 0 and not (out2 / "report.json").exists()


# --------------------------------------------------------------------------- leftovers of killed runs


def test_next_run_removes_only_the_temporaries_of_dead_runs(logs, tmp_path, quick):
    dead = _dead_pid()
    host = __import__("socket").gethostname()

    def container(name: str, owner: dict | None) -> Path:
        d = tmp_path / name
        (d / "run").mkdir(parents=True)
        (d / "run" / "poses.parquet").write_bytes(b"x" * 1000)
        if owner is not None:
            (d / "slamobs-owner.json").write_text(json.dumps(owner))
        return d

    stale = container(".out.tmp-dead1", {"pid": dead, "host": host, "final": "out"})
    live = container(".other.tmp-live1", {"pid": os.getpid(), "host": host, "final": "other"})
    users = container(".notes.tmp-mine", None)
    res = invoke("run", logs["bag"], "-o", tmp_path / "out", "--config", quick)
    assert res.exit_code == 0, res.stderr
    assert not stale.exists() and live.exists() and users.exists()
    assert "removed 1 temporary directory of killed runs" in res.output


def _dead_pid() -> int:
    import subprocess

    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


# --------------------------------------------------------------------------- messages that name the real cause


def test_one_hour_gap_splits_the_run_into_segments(sim, tmp_path, quick):
    cut = sim.imu.t_ns[0] + 3 * NS

    def shifted(x):
        return replace(
            x,
            t_ns=np.where(x.t_ns > cut, x.t_ns + 3600 * NS, x.t_ns),
            rec_ns=np.where(x.rec_ns > cut, x.rec_ns + 3600 * NS, x.rec_ns),
        )

    log = _write(
        sim,
        tmp_path / "gap.bag",
        imu=shifted(sim.imu),
        odom=shifted(sim.odom),
        mag=shifted(sim.mag),
        detections=shifted(sim.detections),
        mocap=shifted(sim.mocap),
    )
    out = tmp_path / "out"
    res = invoke("run", log, "-o", out, "--config", quick)
    assert res.exit_code == 0, res.stderr
    assert "diverged" not in res.output + res.stderr
    meta = json.loads((out / "run.json").read_text())
    seg = meta["segments"]
    assert len(seg) == 2 and seg[1]["start_ns"] - seg[0]["end_ns"] > 3599 * NS
    assert any("2 segments" in n for n in meta["notes"]) and any("re-anchored" in n for n in meta["notes"])
    report = json.loads((out / "report.json").read_text())
    assert report["segments"] == seg and report["ape"]["translation_m"]["rmse"] < 0.2


def test_degenerate_stamps_name_the_real_cause(sim):
    s = expected_streams(sim, "mem.bag")
    om = s.angular_velocity
    same = replace(s, angular_velocity=replace(om, t_ns=np.full_like(om.t_ns, om.t_ns[0])))
    with pytest.raises(
        InputError,
        match=r"all \d+ samples have the same time .* header stamps; its record times "
        r"advance: set time.source: record",
    ):
        align(same)
    # all-zero header stamps are replaced by record times (reader); all-zero record times too: no usable time
    zeros = np.zeros_like(om.t_ns)
    with pytest.raises(InputError, match=r"same time \(zero\) on its record time; its record times do not advance"):
        align(replace(s, angular_velocity=replace(om, t_ns=zeros, rec_ns=zeros)))
    # with time.source: record the message names the clock the run read (it said 'on its header stamps' of a stream
    # whose header stamps were fine and only its record times all alike)
    alike = replace(s, angular_velocity=replace(om, rec_ns=np.full_like(om.rec_ns, om.rec_ns[0])))
    with pytest.raises(InputError, match=r"same time \(\d+\.\d+ s\) on its record time; its record times do not adv"):
        align(alike, time_source="record")
    one = replace(s, angular_velocity=replace(om, t_ns=om.t_ns[:1], rec_ns=om.rec_ns[:1], xyz=om.xyz[:1]))
    with pytest.raises(InputError, match="has a single sample"):
        align(one)
    # header stamps all zero: the reader falls back to record time, here on another clock than the odometry's
    zero = replace(s, angular_velocity=replace(om, t_ns=om.rec_ns + 1000 * NS, rec_ns=om.rec_ns + 1000 * NS))
    with pytest.raises(
        InputError,
        match=r"record time\) and linear velocity .*header stamps\) do not overlap.*"
        r"time.source",
    ):
        align(zero)


def test_detection_frames_all_at_one_stamp_name_the_real_cause(sim):
    # a driver that stamps every frame alike: the run went on with every frame at one instant (APE 5.4 m on the
    # figure-8 sample log, riekf lost)
    s = expected_streams(sim, "mem.bag")
    det = s.detections
    same = replace(s, detections=replace(det, t_ns=np.full_like(det.t_ns, det.t_ns[5])))
    with pytest.raises(
        InputError,
        match=r"detections \(/fiducial_transforms\): all \d+ frames have the same time \(\d+\.\d+ s\) on its "
        r"header stamps; its record times advance: set time.source: record \(or time.topics: "
        r"\{/fiducial_transforms: record\}\)",
    ):
        align(same)
    assert align(same, time_source="record").det_t_ns.size > 1


def test_detections_on_another_clock_say_where_they_are(sim):
    # detections stamped on simulated time next to wall-clock velocities: the error said only 'no landmark
    # detections inside the velocity time span', not where they were nor what to set
    s = expected_streams(sim, "mem.bag")
    det = s.detections
    sim_time = replace(s, detections=replace(det, t_ns=det.t_ns - det.t_ns[0] + 5 * NS))
    with pytest.raises(
        InputError,
        match=r"no detection frame inside the velocity time span \(\d+\.\d{3} \.\. \d+\.\d{3} s\): its \d+ frames "
        r"span 5\.000 \.\. \d+\.\d{3} s on its header stamps; on another clock\? set time.source: auto \(or "
        r"time.topics: \{/fiducial_transforms: record\}\)",
    ):
        align(sim_time)
    assert align(sim_time, time_source="record").det_t_ns.size > 1


def test_all_nan_detections_name_the_real_cause(sim, tmp_path):
    det = sim.detections
    log = _write(sim, tmp_path / "nan.bag", detections=replace(det, xyz=np.full_like(det.xyz, np.nan)))
    with pytest.raises(InputError, match=rf"all {det.xyz.shape[0]} detections are NaN or Inf") as err:
        read_log(log)
    assert err.value.topic == TOPIC_DETECTIONS


def test_a_truth_of_nan_poses_says_why_it_has_none(sim, tmp_path):
    # `slamobs report` of a run on such a log said only 'no truth poses'
    mocap = sim.mocap
    log = _write(sim, tmp_path / "nan.bag", mocap=replace(mocap, position=np.full_like(mocap.position, np.nan)))
    n = mocap.position.shape[0]
    with pytest.raises(InputError, match=rf"no truth poses \(/mocap/pose: {n} NaN/Inf samples dropped\)$"):
        read_truth("/mocap/pose", log)


def test_an_imu_that_does_not_fill_its_gyro_gives_way_to_the_odometry(sim, tmp_path):
    # an IMU publishing angular_velocity all zero was the angular velocity of every run (riekf's APE on the figure-8
    # sample log: 1.07e6 m, fast-adaptation 0.084 m); the odometry's twist.angular measures it
    log = _write(sim, tmp_path / "zero.bag", imu=replace(sim.imu, gyro=np.zeros_like(sim.imu.gyro)))
    streams = read_log(log)
    assert streams.angular_velocity.topic == "/odom" and streams.accel.topic == TOPIC_IMU
    np.testing.assert_array_equal(streams.angular_velocity.xyz, sim.odom.angular)
    assert f"{TOPIC_IMU}: every angular velocity is zero (not measured): the angular velocity is /odom's" in "\n".join(
        streams.warnings
    )
    assert streams.derived["angular_velocity"] == f"/odom's angular velocity: {TOPIC_IMU}'s is all zero"
    assert not any("never turning" in w for w in streams.warnings)  # the odometry's turns are the run's
    # named in the config, the IMU stays the angular velocity
    assert read_log(log, {"angular_velocity": TOPIC_IMU}).angular_velocity.topic == TOPIC_IMU


def test_config_limits_are_parsed_and_switchable():
    cfg = parse_config({"limits": {"max_range": None, "max_gap": 60}})
    assert cfg.limits.max_range is None and cfg.limits.max_gap == 60.0 and cfg.limits.min_range == 0.05


@pytest.mark.parametrize("name", ["fast-adaptation", "hashim", "hashim-imu", "wang-tayebi", "hybrid"])
def test_kernel_work_budget_does_not_change_the_result(sim, monkeypatch, name):
    """The kernels stop after a bounded amount of work (so signals are handled) and resume exactly where they
    stopped: a tiny budget (many calls, stops before frames and samples alike) gives identical outputs."""
    from slamobs.pipeline.observers import ObserverOptions
    from slamobs.pipeline.estimators import get_estimator
    from slamobs.pipeline.observers import base

    spec = get_estimator(name)
    stream = align(expected_streams(sim, "mem.bag"))
    gains = spec.resolve_gains({})
    whole = spec.run(stream, gains, ObserverOptions())
    monkeypatch.setattr(base, "WORK_PER_CALL", 37)
    parts = spec.run(stream, gains, ObserverOptions())
    for field in ("t_ns", "rotation", "position", "gyro_bias", "vel_bias", "landmark_xyz", "track_xyz", "innovation"):
        np.testing.assert_array_equal(getattr(parts, field), getattr(whole, field), err_msg=field)
    assert parts.stats["substeps"] == whole.stats["substeps"]
    for table, columns in whole.extra_tables.items():
        for col, values in columns.items():
            np.testing.assert_array_equal(parts.extra_tables[table][col], values, err_msg=f"{table}.{col}")


def test_a_run_without_landmarks_in_view_for_long_says_so():
    """Detections that end 5 s into a 40 s log left the observer dead-reckoning for 35 s (APE 0.41 m against
    0.06 m) and the run said nothing; a frame keeps its landmarks in view for max_meas_age."""
    from slamobs.pipeline.run import blind_note

    vel = np.arange(0, 40_000_000_001, 5_000_000, dtype=np.int64)  # 200 Hz over 40 s
    frames = np.arange(0, 40_000_000_000, 50_000_000, dtype=np.int64)  # 20 Hz
    counts = np.where(frames < 5_000_000_000, 8, 0)  # landmarks in the first 5 s only
    offsets = np.concatenate(([0], np.cumsum(counts)))
    (note,) = blind_note(vel, frames, offsets, 0.5)
    assert note.startswith("no landmark in view for 34.6 s of the 40.0 s run (longest 34.6 s, from 5.5 s to 40.0 s")
    assert note.endswith("on its velocity inputs there, and its error grows")  # not "IMU": MR.CLAM has none
    everywhere = np.concatenate(([0], np.cumsum(np.full(frames.shape, 8))))
    assert blind_note(vel, frames, everywhere, 0.5) == []
    middle = np.where((frames > 10e9) & (frames < 14e9), 0, 8)  # 4 s without: under the 5 s minimum
    assert blind_note(vel, frames, np.concatenate(([0], np.cumsum(middle))), 0.5) == []


def _truth_of_first(sim, n: int):
    """The simulated mocap truth cut to its first ``n`` poses."""
    m = sim.mocap
    size = len(m.t_ns)
    return replace(m, **{k: v[:n] for k, v in vars(m).items() if isinstance(v, np.ndarray) and len(v) == size})


def test_a_truth_covering_a_moment_of_the_run_gives_no_ape(sim, tmp_path, quick):
    # 3 mocap poses over 10 ms of a 6 s run gave an APE of a few tenths of a millimetre (3 pairs, SE(3)-fitted on
    # them) printed as the run's error: the truth is said too short, and the run has the map error alone
    log = _write(sim, tmp_path / "short.bag", mocap=_truth_of_first(sim, 3))
    res = invoke("run", log, "-o", tmp_path / "out", "--config", quick)
    assert res.exit_code == 0, res.output
    assert "APE " not in res.output and not (tmp_path / "out" / "report.json").exists()
    meta = json.loads((tmp_path / "out" / "run.json").read_text())
    assert meta["report_error"] == (
        "/mocap/pose: the truth covers too little of the run to judge it: 3 pose pairs over 0.010 s of the "
        "estimate's 5.970 s (a report needs at least 10 pairs spanning at least 10% of the run); no APE"
    )
    assert meta["map_error"]["n_matched"] > 3
    assert any(n.startswith(f"no error report: {meta['report_error']}; the map error") for n in meta["notes"])


def test_the_truth_coverage_threshold():
    from slamobs.pipeline.errors import TruthUnusable
    from slamobs.pipeline.evaluation.trajectory_evaluation import MIN_TRUTH_PAIRS, check_truth_coverage
    from slamobs.pipeline.evaluation.trajectory_error import Paired

    def paired(t_s):
        t = np.asarray(t_s, float)
        t_ns = (t * NS).astype(np.int64)
        pos = np.zeros((t.size, 3))
        return Paired(t_ns, t_ns, pos, None, pos, None, None, None, "nearest", "reference", t.size, t.size)

    est = type("Est", (), {"t_ns": np.array([0, 100 * NS])})()
    check_truth_coverage(paired(np.linspace(0, 10, MIN_TRUTH_PAIRS)), est)  # 10 pairs over 10 % of 100 s: judged
    with pytest.raises(TruthUnusable, match=r"9 pose pairs over 10\.000 s of the estimate's 100\.000 s"):
        check_truth_coverage(paired(np.linspace(0, 10, MIN_TRUTH_PAIRS - 1)), est)
    with pytest.raises(TruthUnusable, match=r"1000 pose pairs over 9\.900 s"):
        check_truth_coverage(paired(np.linspace(0, 9.9, 1000)), est)


@pytest.mark.parametrize("kept", [0, 3], ids=["all-nan", "3-poses"])
def test_report_on_a_run_whose_truth_cannot_judge_it_does_what_the_run_did(sim, tmp_path, quick, kept):
    # `slamobs run` on a log whose truth is all NaN (or 3 poses over 10 ms) exits 0 with the map error alone;
    # `slamobs report` of that run exited 2 ('no truth poses', 'no report: ...')
    mocap = (
        _truth_of_first(sim, kept) if kept else replace(sim.mocap, position=np.full_like(sim.mocap.position, np.nan))
    )
    log, out = _write(sim, tmp_path / "t.bag", mocap=mocap), tmp_path / "out"
    assert invoke("run", log, "-o", out, "--config", quick).exit_code == 0
    map_error = json.loads((out / "run.json").read_text())["map_error"]
    res = invoke("report", out)
    assert res.exit_code == 0, res.output
    why = "no truth poses (/mocap/pose: 600 NaN/Inf samples dropped)" if not kept else "3 pose pairs over 0.010 s"
    assert res.output.startswith("truth        unusable (") and why in res.output.splitlines()[0]
    md = (out / "report.md").read_text()
    assert md.startswith("# Run summary (no trajectory truth") and "map_error_rmse" in md
    assert not (out / "report.json").exists()
    assert json.loads((out / "run.json").read_text())["map_error"] == map_error
    # a truth asked for by name that cannot judge the run is still the one-line error
    one_line_error(invoke("report", out, "--truth", "/mocap/pose"), "no truth poses" if not kept else "3 pose pairs")


def _clock_reset(stream, at_s: float):
    """``stream`` as the readers give it after its header clock was set back to ~1 s ``at_s`` into the recording:
    re-sorted by stamp, record times kept."""
    t = stream.t_ns.copy()
    later = stream.rec_ns >= stream.rec_ns[0] + int(at_s * NS)
    t[later] -= int(t[later][0]) - NS
    order = np.argsort(t, kind="stable")
    return replace(stream, t_ns=t[order], rec_ns=stream.rec_ns.copy()[order], xyz=stream.xyz[order])


def test_a_header_clock_reset_mid_log_is_one_line_pointing_to_record_time(sim):
    # circle.bag with every header stamp set back to ~1 s from 15 s on ran as two segments in reversed order (the
    # later half first, a 1.7e9 s gap note, then the first half); record time runs it in recording order
    streams = expected_streams(sim, "reset.bag")
    reset = replace(
        streams,
        angular_velocity=_clock_reset(streams.angular_velocity, 3.0),
        linear_velocity=_clock_reset(streams.linear_velocity, 3.0),
    )
    with pytest.raises(
        InputError, match=r"angular velocity \(/imu/data\): its header clock was reset 3\.009 s into"
    ) as e:
        align(reset)
    assert str(e.value).endswith("set time.source: record (or time.topics: {/imu/data: record})")
    on_record = align(reset, time_source="record")
    assert on_record.segment_starts.size == 0 and on_record.vel_t_ns[-1] - on_record.vel_t_ns[0] > 5.9 * NS


def test_one_rule_decides_the_gyro_stand_in_and_reads_only_what_it_needs():
    # read_log (every message) and info (the first few) both ask decode.gyro_stand_in
    from slamobs.pipeline.readers.decode import gyro_stand_in
    from slamobs.pipeline.readers.roles import IMU, ODOMETRY

    zero, moving = np.zeros((5, 3)), np.ones((5, 3))
    asked = []

    def other(xyz):
        return lambda: asked.append(1) or xyz

    assert gyro_stand_in("/imu", lambda: zero, "/odom", ODOMETRY, other(moving))
    assert not gyro_stand_in("/imu", lambda: zero, "/odom", ODOMETRY, other(zero))  # both zero: the IMU stays
    assert not gyro_stand_in("/imu", lambda: zero[:1], "/odom", ODOMETRY, other(moving))  # one sample is no evidence
    asked.clear()
    assert not gyro_stand_in("/imu", lambda: moving, "/odom", ODOMETRY, other(moving))  # a measuring IMU
    assert not gyro_stand_in("/imu", lambda: zero, "/imu", IMU, other(moving))  # the same topic
    assert not gyro_stand_in("/imu", lambda: zero, None, None, other(moving))  # no linear-velocity topic
    assert not gyro_stand_in("/imu", lambda: zero, "/v", "geometry_msgs/msg/Vector3Stamped", other(moving))
    assert not asked  # the other topic is read only when the IMU's gyro is not filled


def test_info_names_the_angular_velocity_run_takes_for_an_imu_that_does_not_fill_its_gyro(sim, tmp_path):
    # info's roles, readiness and run.yaml named the IMU whose angular_velocity is all zero, while run takes the
    # odometry's (and the run.yaml info printed, naming the IMU, would have made run keep the zeros)
    from slamobs.pipeline.readers import inspect_log
    from slamobs.pipeline.readiness import readiness

    log = _write(sim, tmp_path / "zero.bag", imu=replace(sim.imu, gyro=np.zeros_like(sim.imu.gyro)))
    got = inspect_log(log)
    assert got.roles["angular_velocity"] == "/odom" == read_log(log).angular_velocity.topic
    assert got.roles["accel"] == TOPIC_IMU
    # read further than the first 50 when those are all zero (GYRO_PROBE_FURTHER): every one of the IMU's messages
    n_imu = sim.imu.gyro.shape[0]
    assert f"{TOPIC_IMU}: every angular velocity of its first {n_imu} messages is zero (not measured)" in "\n".join(
        got.warnings
    )
    assert 'angular_velocity: "/odom"' in readiness(got).run_yaml
    assert inspect_log(_write(sim, tmp_path / "measured.bag")).roles["angular_velocity"] == TOPIC_IMU


def _restamped(stream, stamps):
    """``stream`` with header stamps ``stamps(t_ns)`` (record times kept), re-sorted by stamp as the readers give it."""
    t = stamps(stream.t_ns.copy())
    order = np.argsort(t, kind="stable")
    return replace(stream, t_ns=t[order], rec_ns=stream.rec_ns.copy()[order], xyz=stream.xyz[order])


def test_header_stamps_in_another_unit_are_one_line_naming_the_topic_and_record_time(sim):
    # MR.CLAM's velocity topic with its stamps divided by 1000 (ms written as s) was refused as 'no detection
    # frame inside the velocity time span' of the detection topic, whose clock was fine
    streams = expected_streams(sim, "milli.bag")
    milli = replace(streams, angular_velocity=_restamped(streams.angular_velocity, lambda t: t // 1000))
    with pytest.raises(InputError, match=r"angular velocity \(/imu/data\): its header stamps advance 0\.001x as fast"):
        align(milli)
    assert "set time.topics: {/imu/data: record} (or time.source: record)" in str(align_error(milli))
    assert align(milli, time_source="record").vel_t_ns.shape[0] > 100
    # a clock jumping 1 h forward mid-log keeps its pace elsewhere: a gap (two segments), not a unit
    jump = replace(
        streams,
        angular_velocity=_restamped(streams.angular_velocity, lambda t: t + (t > t[t.shape[0] // 2]) * 3600 * NS),
    )
    assert align(jump).vel_t_ns.shape[0] > 100


def test_a_log_whose_record_times_all_run_fast_is_not_said_to_have_stamps_in_another_unit():
    # a converter that wrote a 60 s log in 0.38 s: every topic's stamps advance 159x as fast as its record times,
    # and the stamps are right; the run was refused (info flagged every topic) telling the user to read record times
    from slamobs.pipeline.readers.decode import off_pace, stamp_pace

    t_imu, t_odom = np.arange(0, 60 * NS, NS // 200), np.arange(NS // 100, 60 * NS, NS // 50)
    converted = {"/imu": stamp_pace(t_imu, t_imu // 159), "/odom": stamp_pace(t_odom, t_odom // 159)}
    assert converted["/imu"] == pytest.approx(159, rel=0.01)
    assert off_pace(converted) == {}
    # the same log with the IMU's stamps in milliseconds: that topic, against the other
    milli = {**converted, "/imu": stamp_pace(t_imu // 1000, t_imu // 159), "/mag": converted["/odom"]}
    assert set(off_pace(milli)) == {"/imu"} and off_pace(milli)["/imu"] == pytest.approx(0.001, rel=0.01)
    assert off_pace({"/imu": converted["/imu"]}) == {}  # one topic alone: nothing to tell the clocks apart by


def align_error(streams) -> InputError:
    with pytest.raises(InputError) as e:
        align(streams)
    return e.value


def test_info_and_run_name_imu_stamps_in_milliseconds(sim, tmp_path):
    # info called MR.CLAM's velocity stamps divided by 1000 'simulation time next to wall-clock record times'
    from slamobs.pipeline.readers import inspect_log

    log = _write(sim, tmp_path / "milli.bag", imu=replace(sim.imu, t_ns=sim.imu.t_ns // 1000))
    info = inspect_log(log)
    imu = next(t for t in info.topics if t.topic == TOPIC_IMU)
    assert imu.stamp_pace == pytest.approx(0.001, rel=0.01)
    assert not any("simulation time" in w for w in info.warnings)
    said = f"{TOPIC_IMU}: header stamps advance 0.001x as fast as the other topics'"
    assert any(w.startswith(said) for w in info.warnings)
    out = tmp_path / "out"
    one_line_error(invoke("run", log, "-o", out), f"angular velocity ({TOPIC_IMU}): its header stamps advance 0.001x")
    assert not out.exists()


def test_a_detection_topic_whose_frame_id_changes_mid_log_is_a_warning():
    """Detections naming two camera frames on one topic (two cameras published together, a driver renaming its
    frame mid-log): every detection is placed by the most common frame's extrinsic, so the others' are misplaced;
    this was only a readers' note ("2 frame ids (...), using X"). Now a warning; a frame spelled with and without a
    leading '/' (the same frame) stays a note."""
    from slamobs.pipeline.readers.decode import clean_frames

    n = 6
    t = np.arange(n, dtype=np.int64) * 100_000_000
    lengths = np.ones(n, dtype=np.int64)
    ids = np.arange(n, dtype=np.int64) % 2
    values = np.ones((n, 3)) + np.arange(n)[:, None]
    frame = np.array([0, 0, 0, 0, 1, 1])
    *_, frame_id, cleaning = clean_frames(t, t, lengths, ids, values, frame, ["camera_left", "camera_right"])
    assert frame_id == "camera_left"
    (said,) = cleaning.warnings
    assert "camera_left 4, camera_right 2" in said and "misplaced" in said, said
    *_, frame_id, cleaning = clean_frames(t, t, lengths, ids, values, frame, ["camera", "/camera"])
    assert cleaning.warnings == [] and any("2 frame ids" in x for x in cleaning.extra), cleaning
