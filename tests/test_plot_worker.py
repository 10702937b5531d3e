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
