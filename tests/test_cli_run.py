"""`slamobs run` end to end: every container, every sample log, and bad input."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from slamobs.cli.progress import COMPILING
from slamobs.pipeline.simulate import simulate, write_log
from cli_checks import SAMPLES, invoke

TABLES = ("poses", "biases", "landmarks", "landmark_tracks", "innovations")


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """A short noisy figure-8 (landmarks come and go) in all three containers, unseen by any tuning."""
    base = tmp_path_factory.mktemp("logs")
    sim = simulate("figure8", duration=20.0, seed=7, imu_rate=200.0)
    return {
        c: write_log(sim, base / name, c) for c, name in (("bag", "f8.bag"), ("mcap", "f8.mcap"), ("ros2", "f8_ros2"))
    }


def _check_run(out: Path) -> dict:
    for name in TABLES:
        df = pd.read_parquet(out / f"{name}.parquet")
        assert len(df) > 0
    run = json.loads((out / "run.json").read_text())
    assert run["observer"]["name"] == "fast-adaptation"
    report = json.loads((out / "report.json").read_text())
    for png in ("trajectory_top.png", "errors.png"):  # the main figures (evaluation.plots: true)
        assert (out / png).stat().st_size > 1000
    assert not (out / "biases.png").exists()  # the others with evaluation.plots: all, or by slamobs report
    assert (out / "report.md").read_text().strip()
    return report


@pytest.mark.parametrize("container", ["bag", "mcap", "ros2"])
def test_run_on_each_container(generated, tmp_path, container):
    out = tmp_path / "out"
    res = invoke("run", generated[container], "-o", out)
    assert res.exit_code == 0, res.output
    report = _check_run(out)
    assert report["ape"]["translation_m"]["rmse"] < 0.15
    assert report["landmarks"]["error_m"]["rmse"] < 0.2
    assert report["landmarks"]["n_matched"] == report["landmarks"]["n_estimated"]


def test_containers_give_identical_results(generated, tmp_path):
    poses = []
    for c in ("bag", "mcap", "ros2"):
        out = tmp_path / c
        assert invoke("run", generated[c], "-o", out, "-q").exit_code == 0
        poses.append(pd.read_parquet(out / "poses.parquet"))
    pd.testing.assert_frame_equal(poses[0], poses[1])
    pd.testing.assert_frame_equal(poses[0], poses[2])


@pytest.mark.parametrize(
    "log,ape_max,lm_max", [("circle.bag", 0.05, 0.05), ("circle_ros2", 0.05, 0.05), ("figure8.mcap", 0.1, 0.1)]
)
def test_run_on_every_sample_log(tmp_path, log, ape_max, lm_max):
    out = tmp_path / "out"
    res = invoke("run", SAMPLES / log, "-o", out)
    assert res.exit_code == 0, res.output
    assert "APE" in res.output
    report = _check_run(out)
    assert report["ape"]["translation_m"]["rmse"] < ape_max
    assert report["landmarks"]["error_m"]["rmse"] < lm_max
    # biases converge to the simulated truth
    assert report["biases"]["error_norm"]["gyro"] < 0.02
    assert report["biases"]["error_norm"]["velocity"] < 0.05


def test_output_rate_and_config(generated, tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text("output:\n  rate_hz: 20\ngains:\n  fast-adaptation:\n    k_w: 2\n")
    out = tmp_path / "out"
    assert invoke("run", generated["mcap"], "-o", out, "--config", cfg, "-q").exit_code == 0
    poses = pd.read_parquet(out / "poses.parquet")
    dt = poses["t_ns"].diff().median() * 1e-9
    assert dt == pytest.approx(0.05, rel=0.05)
    assert json.loads((out / "run.json").read_text())["observer"]["gains"]["k_w"] == 2.0
    # default output precision: low mantissa bits cleared (stated in run.json); float_bits: 52 keeps them
    meta = json.loads((out / "run.json").read_text())
    assert {k: meta["output"][k] for k in ("rate_hz", "float_bits", "export")} == {
        "rate_hz": 20,
        "float_bits": 28,
        "export": [],
    }
    assert meta["output"]["frame"]["name"] == "start"  # fast-adaptation's default output frame
    low = poses["x"].to_numpy().view(np.uint64) & np.uint64((1 << 24) - 1)
    assert not low.any()
    cfg.write_text("output:\n  rate_hz: 20\n  float_bits: 52\ngains:\n  fast-adaptation:\n    k_w: 2\n")
    exact = tmp_path / "exact"
    assert invoke("run", generated["mcap"], "-o", exact, "--config", cfg, "-q").exit_code == 0
    full = pd.read_parquet(exact / "poses.parquet")["x"].to_numpy()
    assert (full.view(np.uint64) & np.uint64((1 << 24) - 1)).any()
    assert np.max(np.abs(poses["x"].to_numpy() - full)) <= 2.0**-21  # a length: 2**-20 m steps (schemas)
    _assert_within_stated_rounding(out, exact)
    cfg.write_text("output:\n  float_bits: 60\n")
    bad = tmp_path / "bad"
    _assert_clean_failure(invoke("run", generated["mcap"], "-o", bad, "--config", cfg), bad, "output.float_bits")


def _assert_within_stated_rounding(out: Path, exact: Path) -> None:
    """Every float column of the tables an estimator writes (the aligned ones are computed from the rounded
    poses) within its stated rounding (docs/outputs.md) of the run written with ``float_bits: 52``: a fixed step
    ``2**e`` within ``2**(e-1)``, the others a relative ``2**-29``."""
    from slamobs.schemas import TABLES, fixed_steps, table_spec

    for name in TABLES:
        a, b = pd.read_parquet(out / f"{name}.parquet"), pd.read_parquet(exact / f"{name}.parquet")
        assert len(a) == len(b) > 0, name
        for f in table_spec(name)["fields"]:
            if f["type"] != "float64" or b[f["name"]].isna().all():
                continue
            r, x = a[f["name"]].to_numpy(), b[f["name"]].to_numpy()
            step = fixed_steps(name).get(f["name"])
            bound = 2.0 ** (step - 1) if step is not None else np.abs(x) * 2.0**-29
            assert np.all(np.abs(r - x) <= bound), (name, f["name"])


def _assert_clean_failure(res, out: Path, *needles: str):
    assert res.exit_code != 0
    # one line (besides the notice that numba is compiling, which a cold cache adds before it)
    err = "\n".join(line for line in res.stderr.strip().splitlines() if not line.startswith(COMPILING))
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in res.output + res.stderr
    for n in needles:
        assert n in err, err
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]


def test_the_run_summary_names_the_alignment_its_config_chose(generated, tmp_path):
    """`evaluation.align: sim3`: the report fitted Sim(3), the run's APE line said "SE(3)-aligned" (MR.CLAM 6-r5:
    0.7311 m Sim(3)-aligned, scale 0.385, where SE(3) gives 1.4819 m)."""
    cfg = tmp_path / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\n  align: sim3\n")
    out = tmp_path / "out"
    res = invoke("run", generated["mcap"], "-o", out, "--config", cfg)
    assert res.exit_code == 0, res.output
    assert json.loads((out / "report.json").read_text())["method"]["alignment"]["type"] == "sim3"
    ape = [line for line in res.output.splitlines() if line.startswith("APE ")]
    assert len(ape) == 1 and ape[0].endswith("pairs, Sim(3)-aligned"), ape


def test_missing_file(tmp_path):
    out = tmp_path / "out"
    _assert_clean_failure(invoke("run", tmp_path / "nope.bag", "-o", out), out, "nope.bag")


def test_unknown_container(tmp_path):
    bad = tmp_path / "notes.txt"
    bad.write_text("hello")
    out = tmp_path / "out"
    _assert_clean_failure(invoke("run", bad, "-o", out), out, "notes.txt")


def test_truncated_log(generated, tmp_path):
    """An MCAP file cut at a third of its bytes (a recording that died): the complete messages before the cut are
    recovered and run, the run says so, and its poses are the full log's first poses bit for bit (the observer is
    causal), not a run of damaged data."""
    bad = tmp_path / "cut.mcap"
    data = generated["mcap"].read_bytes()
    bad.write_bytes(data[: len(data) // 3])
    cfg = tmp_path / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    out, full = tmp_path / "out", tmp_path / "full"
    res = invoke("run", bad, "-o", out, "--config", cfg)
    assert res.exit_code == 0, res.output
    notes = json.loads((out / "run.json").read_text())["notes"]
    cut_notes = [n for n in notes if n.startswith("MCAP file is incomplete")]
    assert len(cut_notes) == 1 and "recovered" in cut_notes[0] and cut_notes[0] in res.output
    assert invoke("run", generated["mcap"], "-o", full, "--config", cfg, "-q").exit_code == 0
    cut, whole = (pd.read_parquet(d / "poses.parquet") for d in (out, full))
    assert 0 < len(cut) < len(whole) / 2
    pd.testing.assert_frame_equal(cut, whole.iloc[: len(cut)].reset_index(drop=True))


def test_log_without_detections(tmp_path):
    from dataclasses import replace

    import numpy as np

    sim = simulate("circle", duration=3.0, seed=1)
    d = sim.detections
    empty = replace(
        d,
        offsets=np.zeros_like(d.offsets),
        ids=d.ids[:0],
        xyz=d.xyz[:0],
        quat_xyzw=d.quat_xyzw[:0],
        image_error=d.image_error[:0],
        object_error=d.object_error[:0],
        area=d.area[:0],
    )
    log = write_log(replace(sim, detections=empty), tmp_path / "nodet.bag")
    out = tmp_path / "out"
    _assert_clean_failure(invoke("run", log, "-o", out), out, "nodet.bag")


def test_override_naming_missing_topic(generated, tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text("topics:\n  detections: /no/such/topic\n")
    out = tmp_path / "out"
    _assert_clean_failure(invoke("run", generated["bag"], "-o", out, "--config", cfg), out, "/no/such/topic")


@pytest.mark.parametrize("gains", ["k_w: -1", "k_w: 0", "k_w: fast", "k_zz: 1"])
def test_invalid_gains_are_clear_errors(generated, tmp_path, gains):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"gains:\n  fast-adaptation:\n    {gains}\n")
    out = tmp_path / "out"
    res = invoke("run", generated["bag"], "-o", out, "--config", cfg)
    assert res.exit_code == 2
    assert "k_" in res.stderr and "Traceback" not in res.stderr
    assert not out.exists()


def test_existing_output_is_kept_without_force(generated, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    res = invoke("run", generated["bag"], "-o", out)
    assert res.exit_code == 2 and res.stderr.startswith("error: ") and "--force" in res.stderr
    assert (out / "keep.txt").read_text() == "precious"
    # --force replaces earlier runs only, never a directory of someone's files
    res = invoke("run", generated["bag"], "-o", out, "--force")
    assert res.exit_code == 2 and "not a slamobs output" in res.stderr and len(res.stderr.splitlines()) == 1
    assert (out / "keep.txt").read_text() == "precious"
    (out / "keep.txt").unlink()
    (out / "run.json").write_text("{}")  # an earlier run
    assert invoke("run", generated["bag"], "-o", out, "--force", "-q").exit_code == 0
    assert (out / "poses.parquet").exists() and json.loads((out / "run.json").read_text())["observer"]


def test_failure_during_report_leaves_nothing(generated, tmp_path, monkeypatch):
    import slamobs.pipeline.evaluation as ev

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(ev, "write_report", boom)
    out = tmp_path / "out"
    res = invoke("run", generated["bag"], "-o", out)
    assert res.exit_code == 2 and res.stderr.strip() == f"error: {out}: cannot write the output: disk full"
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == []


def test_observers_command_lists_gains():
    res = invoke("observers")
    assert res.exit_code == 0
    assert "fast-adaptation" in res.output and "k_w" in res.output
    # riekf and batch learn their noise from each log by default (noise: auto); the list read as if run.yaml's
    # `noise:` section were where their levels come from (round 21)
    assert res.output.count("no gains: noise levels learned from each log (`slamobs info --noise LOG`") == 2


def test_demo_sample_copy_runs_from_any_directory(tmp_path, monkeypatch):
    # The shipped sample is usable after copying it elsewhere (no hidden dependency on the repo layout).
    log = shutil.copy(SAMPLES / "circle.bag", tmp_path / "c.bag")
    monkeypatch.chdir(tmp_path)
    assert invoke("run", "c.bag", "-o", "o", "-q").exit_code == 0
    assert (tmp_path / "o" / "poses.parquet").exists()
    del log


def test_console_script_skips_the_teardown_only_when_nothing_is_left_running():
    """The console script ends with os._exit once a command is done (output flushed, exit status kept), unless a
    thread the interpreter's shutdown would wait for is still alive."""
    import subprocess
    import sys

    code = (
        "import atexit, sys, threading, time; atexit.register(print, 'teardown'); {extra}"
        "from slamobs.cli.main import entry; sys.argv = ['slamobs'] + sys.argv[1:]; entry()"
    )
    done = subprocess.run([sys.executable, "-c", code.format(extra=""), "observers"], capture_output=True, text=True)
    assert done.returncode == 0 and "fast-adaptation" in done.stdout and "teardown" not in done.stdout
    assert done.stdout.rstrip().endswith("slamobs repository.")  # everything flushed
    bad = subprocess.run(
        [sys.executable, "-c", code.format(extra=""), "run", "no-such.mcap", "-o", "x"], capture_output=True, text=True
    )
    assert bad.returncode == 2 and "teardown" not in bad.stdout and bad.stderr.startswith("error: ")
    # a thread alive until the main thread has finished, however long the command takes on a loaded machine
    waiting = "threading.Thread(target=lambda: (threading.main_thread().join(), time.sleep(0.1))).start(); "
    busy = subprocess.run(
        [sys.executable, "-c", code.format(extra=waiting), "observers"], capture_output=True, text=True
    )
    assert busy.returncode == 0 and busy.stdout.rstrip().endswith("teardown")


def test_help_imports_no_heavy_modules():
    """`slamobs --help` stays fast: commands import numba, rosbags, pyarrow only when they run (and NumPy loads
    after ``cli.main`` has set its BLAS thread count)."""
    import subprocess
    import sys

    code = (
        "import sys, slamobs.cli.main; heavy = [m for m in ('numpy', 'numba', 'rosbags', 'pyarrow', 'pandas', "
        "'matplotlib') if m in sys.modules]; print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
    from slamobs.cli.simulate_cmd import CONTAINERS
    from slamobs.pipeline.simulate.logwriter import CONTAINERS as WRITABLE

    assert set(CONTAINERS) == set(WRITABLE)


def test_per_topic_clock_choice_is_applied_and_recorded(generated, tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text("time:\n  topics:\n    /mocap/pose: record\n")
    out = tmp_path / "out"
    assert invoke("run", generated["bag"], "-o", out, "--config", cfg, "-q").exit_code == 0
    run = json.loads((out / "run.json").read_text())
    assert run["input"]["clocks"] == {"/mocap/pose": "record"}
    # record times lag the stamps by 1-5 ms: the report still associates (t_max_diff 10 ms)
    assert json.loads((out / "report.json").read_text())["ape"]["translation_m"]["n"] > 100


def test_config_paths_are_relative_to_the_config_file(tmp_path):
    from slamobs.pipeline.config import load_config

    (tmp_path / "cfg").mkdir()
    cfg = tmp_path / "cfg" / "run.yaml"
    cfg.write_text("msg_dir: msgs\nevaluation:\n  truth_file: gt/truth.txt\n")
    config = load_config(cfg)
    assert config.msg_dir == str((tmp_path / "cfg" / "msgs").resolve())
    assert config.evaluation.truth_file == str((tmp_path / "cfg" / "gt" / "truth.txt").resolve())


def test_every_compiled_kernel_is_cached_on_disk():
    """A second run loads the kernels instead of compiling them again: every numba function of the package
    is declared with ``cache=True`` (benchmarks/end_to_end.py measures what the first run spends compiling)."""
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    import slamobs.pipeline as pipeline

    kernels = {}
    for info in pkgutil.walk_packages(pipeline.__path__, "slamobs.pipeline."):
        module = importlib.import_module(info.name)
        kernels.update(
            {
                f"{info.name}.{k}": v
                for k, v in vars(module).items()
                if isinstance(v, CPUDispatcher) and v.__module__ == info.name
            }
        )
    assert len(kernels) > 20
    assert not [name for name, fn in kernels.items() if type(fn._cache).__name__ == "NullCache"]


def test_compile_clock_counts_compilations_not_cache_loads():
    """Runs report what they compiled (run.json ``compiled``, and a note on first runs)."""
    from numba import njit

    from slamobs.pipeline.compile_clock import compile_mark, compiled_since

    @njit  # no cache: compiled on the first call in this process
    def twice(x):
        return 2.0 * x

    mark = compile_mark()
    assert twice(1.5) == 3.0
    first = compiled_since(mark)
    assert first.functions >= 1 and first.seconds > 0.0
    mark = compile_mark()
    assert twice(2.5) == 5.0  # same signature: nothing compiled
    assert compiled_since(mark).functions == 0


def test_run_json_states_compilation(generated, tmp_path):
    """With an empty kernel cache a run compiles and says so (run.json ``compiled`` and a note); the same run again
    loads every kernel from that cache: nothing compiled, no note. Each in a fresh ``slamobs`` process: kernels
    compiled earlier in the test process would hide the compilation."""
    from batch_checks import CLI

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    cfg = tmp_path / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\n")
    metas = []
    for k in range(2):
        out = tmp_path / f"out{k}"
        done = subprocess.run(
            [*CLI, "run", str(generated["bag"]), "-o", str(out), "--config", str(cfg), "-q"],
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert done.returncode == 0, done.stderr
        metas.append(json.loads((out / "run.json").read_text()))
    first, again = metas
    assert first["compiled"]["functions"] > 0 and first["compiled"]["seconds"] > 0.0
    notes = [n for n in first["notes"] if n.startswith("first run: compiled ")]
    assert len(notes) == 1 and notes[0].startswith(f"first run: compiled {first['compiled']['functions']} numeric")
    assert again["compiled"] == {"functions": 0, "seconds": 0.0}
    assert not [n for n in again["notes"] if "compiled" in n]


def test_run_reports_progress_stage_by_stage(generated, tmp_path):
    """``run_log`` tells its caller each stage (the CLI shows it as a status line on a terminal)."""
    from slamobs.pipeline.config import RunConfig
    from slamobs.pipeline.run import run_log

    seen: list[str] = []
    run_log(generated["mcap"], tmp_path / "out", RunConfig(), progress=seen.append)
    assert seen[0].startswith("reading ") and seen[1] == "aligning the streams"
    samples = [m for m in seen if m.startswith("fast-adaptation: ")]
    total = int(samples[0].rsplit(" of ", 1)[1].split()[0])
    assert samples[0] == f"fast-adaptation: 0 of {total} samples"
    assert samples[-1] == f"fast-adaptation: {total} of {total} samples"
    assert seen[-1] == "error report"


def test_report_without_plots(generated, tmp_path):
    """``evaluation.plots: false`` (batch jobs over many short logs) writes every report file but the figures;
    ``slamobs report`` keeps to it, ``slamobs report --plots`` draws them later with the same numbers. ``run
    --no-plots`` / ``--plots`` decide whatever the config says."""
    cfg = tmp_path / "run.yaml"
    cfg.write_text("evaluation:\n  plots: false\noutput:\n  export: [tum, evo]\n")
    out = tmp_path / "out"
    assert invoke("run", generated["mcap"], "-o", out, "--config", cfg, "-q").exit_code == 0
    assert not list(out.glob("*.png"))
    assert {"report.json", "report.md", "ape_evo.zip", "estimate_tum.txt"} <= {p.name for p in out.iterdir()}
    before = json.loads((out / "report.json").read_text())["ape"]
    assert invoke("report", out, "-q").exit_code == 0
    assert not list(out.glob("*.png"))
    assert invoke("report", out, "--plots").exit_code == 0
    assert {"trajectory_top.png", "errors.png", "biases.png"} <= {p.name for p in out.glob("*.png")}
    assert json.loads((out / "report.json").read_text())["ape"] == before
    assert invoke("run", generated["mcap"], "-o", out, "--config", cfg, "--plots", "--force", "-q").exit_code == 0
    assert {p.name for p in out.glob("*.png")} == {"trajectory_top.png", "errors.png"}  # true: the main ones
    assert invoke("run", generated["mcap"], "-o", out, "--no-plots", "--force", "-q").exit_code == 0
    assert not list(out.glob("*.png")) and json.loads((out / "run.json").read_text())["output"]["plots"] is False


def test_batch_reports_its_solve_while_it_works(generated, tmp_path):
    """batch solves the whole log before its first stretch: its progress said "batch: 0 of N samples" for the
    whole solve (50 s on MR.CLAM 7-r4 on a first run); it now says the seed and the solver's iterations, those of
    the steps after the first solution with the step's name."""
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.run import run_log

    seen: list[str] = []
    cfg = tmp_path / "run.yaml"
    cfg.write_text("observer: batch\n")
    run_log(generated["mcap"], tmp_path / "out", load_config(cfg), progress=seen.append)
    import re

    stretches = [k for k, m in enumerate(seen) if re.fullmatch(r"batch: \d+ of \d+ samples", m)]
    assert seen[stretches[0]].startswith("batch: 0 of ") and len(stretches) >= 2
    during = seen[stretches[0] + 1 : stretches[1]]
    assert any(m.startswith("batch: seed observer (") for m in during), seen
    assert any(m.startswith("batch: iteration ") for m in during), seen
    # the solves after the first say which step they are (a bare "iteration 5" for 40 s on MR.CLAM 7 r3 did not)
    assert any(re.match(r"batch \([a-z -]+\): iteration \d+, error ", m) for m in during), seen
    # the scans' solves say the level and scale they try (they said nothing: the step's last line stood for 40 s)
    assert any(re.match(r"batch \(noise levels\): [a-z_]+ x[0-9.]+: iteration \d+, error ", m) for m in during), seen
