"""Figures drawn by helper processes are the figures the run would have drawn itself."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from batch_checks import alive, children

from slamobs.pipeline.evaluation import plot_worker


def _jobs():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 90.0, 5000)
    return [
        (
            "plot_errors",
            "errors.png",
            dict(
                t_s=t,
                position_error_m=np.abs(rng.normal(size=t.size)),
                attitude_error_deg=np.abs(rng.normal(size=t.size)),
                band_m=0.5,
                convergence_t_s=12.0,
            ),
        ),
        (
            "plot_landmark_errors",
            "landmarks.png",
            dict(ids=np.arange(7), error_traj_m=rng.random(7), error_map_m=rng.random(7)),
        ),
    ]


def test_helpers_draw_the_same_png_bytes(tmp_path):
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    jobs = _jobs()
    drawn_here = plot_worker.draw(jobs, lambda name: here / name)
    workers = plot_worker.PlotWorkers(2)  # one figure each
    procs = list(workers.procs)
    workers.submit(jobs)
    drawn_there = workers.collect(there)
    assert [p.name for p in drawn_there] == [p.name for p in drawn_here] == [j[1] for j in jobs]
    for a, b in zip(drawn_here, drawn_there):
        assert a.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert a.read_bytes() == b.read_bytes(), a.name
    assert all(p.poll() is not None for p in procs) and workers.procs == []


#: Draws the pickled jobs into a directory in a fresh process, matplotlib's figure imported first by itself
#: (``full``: the help text of every Artist class generated as usual) or by the report's first figure (``lean``).
_DRAW_IN_A_FRESH_PROCESS = """
import pickle, sys
from pathlib import Path
if sys.argv[1] == "full":
    import matplotlib.figure
from slamobs.pipeline.evaluation import plot_worker
out = Path(sys.argv[3])
plot_worker.draw(pickle.loads(Path(sys.argv[2]).read_bytes()), lambda name: out / name)
from matplotlib import artist, lines
print(lines.Line2D.set.__doc__ is None, bool(artist.kwdoc(lines.Line2D)))
"""


def test_figures_drawn_without_matplotlib_s_help_text_have_the_same_bytes(tmp_path):
    jobs = tmp_path / "jobs.pickle"
    jobs.write_bytes(pickle.dumps(_jobs()))
    printed = {}
    for how in ("full", "lean"):
        (tmp_path / how).mkdir()
        done = subprocess.run(
            [sys.executable, "-c", _DRAW_IN_A_FRESH_PROCESS, how, str(jobs), str(tmp_path / how)],
            capture_output=True,
            text=True,
            check=True,
        )
        printed[how] = done.stdout.split()
    assert printed == {"full": ["False", "True"], "lean": ["True", "True"]}  # left out, and put back after
    for name in ("errors.png", "landmarks.png"):
        assert (tmp_path / "lean" / name).read_bytes() == (tmp_path / "full" / name).read_bytes(), name


def test_batches_drawn_side_by_side_come_back_in_order(tmp_path):
    """One helper, a batch per submit: each batch is drawn by its own forked child, the PNGs return in the
    order of the jobs."""
    jobs = _jobs() + _jobs()[::-1]
    drawn_here = plot_worker.draw(jobs, lambda name: tmp_path / f"here-{name}")
    workers = plot_worker.PlotWorkers(1)
    for job in jobs:
        workers.submit([(job[0], f"{len(workers.jobs)}-{job[1]}", job[2])])
    drawn_there = workers.collect(tmp_path)
    assert [p.name for p in drawn_there] == [f"{k}-{j[1]}" for k, j in enumerate(jobs)]
    assert [p.read_bytes() for p in drawn_there] == [p.read_bytes() for p in drawn_here]


def test_a_failed_figure_fails_the_collect(tmp_path, capfd):
    bad = (
        "plot_errors",
        "bad.png",
        dict(t_s=np.arange(3.0), position_error_m=np.arange(2.0), attitude_error_deg=np.arange(3.0)),
    )
    workers = plot_worker.PlotWorkers(1)
    workers.submit(_jobs()[:1])
    workers.submit([bad])
    with pytest.raises(RuntimeError, match="figure helper"):
        workers.collect(tmp_path)
    assert "Traceback" in capfd.readouterr().err  # the child said why
    assert not (tmp_path / "errors.png").exists()


def test_unused_helpers_are_stopped():
    with plot_worker.PlotWorkers(1) as workers:
        procs = list(workers.procs)
        assert procs[0].poll() is None
    assert procs[0].returncode is not None and workers.procs == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_helper_dies_with_a_killed_run():
    """SIGKILL of the run while its helper's child draws (stdin already closed) takes the helper and the
    drawing child along at once."""
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\nimport numpy as np\n"
            "from slamobs.pipeline.evaluation import plot_worker\n"
            "t = np.linspace(0.0, 90.0, 20000)\n"
            "job = ('plot_errors', 'e.png', dict(t_s=t, position_error_m=np.sin(t) ** 2,"
            " attitude_error_deg=np.cos(t) ** 2, band_m=0.5, convergence_t_s=1.0))\n"
            "w = plot_worker.PlotWorkers(1)\nw.submit([job] * 60)\n"  # ~20 s of drawing
            "print(w.procs[0].pid, flush=True)\ntime.sleep(60)\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    helper = int(parent.stdout.readline())
    # forked once warm (its imports: seconds on a loaded machine; the bound only turns a helper that never draws
    # into a failure)
    deadline = time.monotonic() + 120.0
    while not (drawing := children(helper)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert drawing, "the helper forked no child to draw"
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 3.0  # far less than the figures would take
    while any(alive(p) for p in [helper, *drawing]):
        assert time.monotonic() < deadline, (
            f"figure helper {helper} or its child {drawing} runs on after its run was killed"
        )
        time.sleep(0.05)


def test_the_figure_helper_is_chosen_by_free_cores_unless_the_environment_says(monkeypatch):
    """``SLAMOBS_FIGURE_HELPER=1`` starts the figure helper without a free core (a benchmark measuring a quiet
    machine's run on a shared one), ``=0`` never; unset, a free core decides."""
    monkeypatch.delenv(plot_worker.ENV, raising=False)
    assert plot_worker.helper_wanted(1) and not plot_worker.helper_wanted(0)
    monkeypatch.setenv(plot_worker.ENV, "1")
    assert plot_worker.helper_wanted(0)
    monkeypatch.setenv(plot_worker.ENV, "0")
    assert not plot_worker.helper_wanted(2)


def test_free_cores_counts_what_runs_now():
    """Runnable threads right now (the fourth field of /proc/loadavg, this process one of them), not the load
    average, which still counts runs that ended a minute ago."""

    cpus = len(os.sched_getaffinity(0))
    assert plot_worker.free_cores("1.90 1.50 1.20 1/80 999") == cpus - 1  # busy a minute ago, idle now
    assert plot_worker.free_cores(f"0.10 0.10 0.10 {cpus + 1}/80 999") == 0  # as many others as cores: none
    assert plot_worker.free_cores("0.00 0.00 0.00 0/80 999") == cpus - 1


def test_a_run_draws_with_helpers_its_caller_started_and_stops_them(tmp_path):
    """The CLI starts the figure helper before it imports the pipeline (it imports matplotlib meanwhile) and hands
    it to ``run_log``: the run's figures come from it, and the run stops it; a run without figures
    (``evaluation.plots: false``) stops it at once and writes none, and so does a run that fails before reading."""
    from pathlib import Path

    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.run import run_log

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "figure8.mcap"
    for plots in (True, False):
        workers = plot_worker.PlotWorkers(1)
        helper = workers.procs[0]
        out = tmp_path / f"plots-{plots}"
        summary = run_log(log, out, parse_config({"evaluation": {"plots": plots}}), plot_workers=workers)
        assert workers.procs == [] and helper.returncode is not None
        pngs = sorted(p.name for p in out.glob("*.png"))
        assert pngs == (sorted(summary.metadata["figures"]) if plots else [])
        assert (len(pngs) > 0) == plots
    taken = tmp_path / "taken"  # a run that fails its checks before reading (an output it must not replace)
    taken.mkdir()
    (taken / "notes.txt").write_text("a user's file\n")
    workers = plot_worker.PlotWorkers(1)
    with pytest.raises(InputError):
        run_log(log, taken, parse_config({}), plot_workers=workers)
    assert workers.procs == [] and (taken / "notes.txt").is_file()


def test_a_killed_helper_s_figures_are_drawn_here(tmp_path):
    """A helper killed (the kernel's OOM killer sends SIGKILL) before a batch smaller than the pipe's buffer left
    it: closing its stdin raised BrokenPipeError, which the CLI takes for a closed stdout (exit 141, no message);
    then the figure helper's failure removed a run's whole error report. Its figures are drawn in this process
    instead, the same bytes."""
    jobs = _jobs()
    drawn_here = plot_worker.draw(jobs, lambda name: tmp_path / f"here-{name}")
    workers = plot_worker.PlotWorkers(1)
    workers.procs[0].kill()
    workers.procs[0].wait()
    workers.submit(jobs)
    drawn = workers.collect(tmp_path)
    assert [p.name for p in drawn] == [j[1] for j in jobs]
    assert [p.read_bytes() for p in drawn] == [p.read_bytes() for p in drawn_here]
    assert workers.procs == []
