"""Figures drawn by helper processes are the figures the run would have drawn itself."""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.evaluation import plot_worker


def _jobs():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 90.0, 5000)
    return [
        ("plot_errors", "errors.png", dict(t_s=t, position_error_m=np.abs(rng.normal(size=t.size)),
                                           attitude_error_deg=np.abs(rng.normal(size=t.size)), band_m=0.5,
                                           convergence_t_s=12.0)),
        ("plot_landmark_errors", "landmarks.png", dict(ids=np.arange(7), error_traj_m=rng.random(7),
                                                       error_map_m=rng.random(7))),
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


def test_unused_helpers_are_stopped():
    with plot_worker.PlotWorkers(1) as workers:
        procs = list(workers.procs)
        assert procs[0].poll() is None
    assert procs[0].returncode is not None and workers.procs == []


def test_helper_dies_with_a_killed_run():
    """SIGKILL of the run while its helper draws (stdin already closed) takes the helper along at once."""
    import os
    import signal
    import subprocess
    import sys
    import time

    parent = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nimport numpy as np\n"
         "from slamobs.pipeline.evaluation import plot_worker\n"
         "t = np.linspace(0.0, 90.0, 20000)\n"
         "job = ('plot_errors', 'e.png', dict(t_s=t, position_error_m=np.sin(t) ** 2, attitude_error_deg=np.cos(t) ** 2,"
         " band_m=0.5, convergence_t_s=1.0))\n"
         "w = plot_worker.PlotWorkers(1)\nw.submit([job] * 60)\n"  # ~20 s of drawing
         "print(w.procs[0].pid, flush=True)\ntime.sleep(60)\n"],
        stdout=subprocess.PIPE, text=True)
    helper = int(parent.stdout.readline())
    time.sleep(0.5)
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 3.0  # far less than the figures would take
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{helper}/stat") as fh:
                if fh.read().split(") ")[1].startswith("Z"):  # a zombie has ended; only its reaping is left
                    break
        except FileNotFoundError:
            break
        time.sleep(0.05)
    else:
        raise AssertionError(f"figure helper {helper} still running after its run was killed")


def test_free_cores_counts_what_runs_now():
    """Runnable threads right now (the fourth field of /proc/loadavg, this process one of them), not the load
    average, which still counts runs that ended a minute ago."""
    import os

    cpus = len(os.sched_getaffinity(0))
    assert plot_worker.free_cores("1.90 1.50 1.20 1/80 999") == cpus - 1  # busy a minute ago, idle now
    assert plot_worker.free_cores(f"0.10 0.10 0.10 {cpus + 1}/80 999") == 0  # as many others as cores: none
    assert plot_worker.free_cores("0.00 0.00 0.00 0/80 999") == cpus - 1
