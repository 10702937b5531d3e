"""The observer run ahead on a log's prefixes while the log is read (pipeline/speculation.py): the run directory is
the staged run's byte for byte whether the whole log's stream takes the run over or the run starts again, and no
thread outlives the run. The sample log is read in small decoding groups and run in short stretches, so that a
one-minute log has the hour's many groups and stretches."""

from __future__ import annotations

import json
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from slamobs.pipeline import run as R
from slamobs.pipeline import speculation
from slamobs.pipeline.config import load_config
from slamobs.pipeline.readers import storage

LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "figure8.mcap"


@pytest.fixture
def small_pieces(monkeypatch):
    """Groups of 128 KB (the sample log: five of ~10.7 s, read a chunk at a time: its first prefix misses landmarks
    seen later, so the run ahead starts again on the second), stretches of 1024 samples (6), settled 0.5 s before a
    prefix's end."""
    monkeypatch.setattr(storage, "GROUP_BYTES", 1 << 17)
    monkeypatch.setattr(R, "STRETCH_SAMPLES", 1024)
    monkeypatch.setattr(speculation, "SETTLE_NS", 500_000_000)
    monkeypatch.setattr("slamobs.pipeline.cores.cores", lambda: 2)


@pytest.fixture
def inline(monkeypatch):
    """Each prefix built and run on the reader's thread as it is offered: on a log read in a few ms the thread
    would still be on the first when the read ends."""
    monkeypatch.setattr(speculation.Speculation, "offer", lambda self, build: self._run(build))


def _config(**evaluation):
    config = replace(load_config(None), observer="fast-adaptation")
    return replace(config, evaluation=replace(config.evaluation, plots=False, **evaluation))


def _files(out: Path) -> dict[str, bytes]:
    """Every file of a run directory but run.json, whose timings differ, and the file sizes' listing naming it."""
    return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.name not in ("run.json", "slamobs-output.json")}


def test_run_ahead_gives_the_staged_run_byte_for_byte(tmp_path, monkeypatch, small_pieces, inline):
    R.run_log(LOG, tmp_path / "ahead", _config())
    taken = json.loads((tmp_path / "ahead" / "run.json").read_text())["timings_s"]["ahead_samples"]
    assert taken > 1024, taken  # the whole log's stream took over a run a stretch or more ahead
    assert not [t for t in threading.enumerate() if t.name == "slamobs-speculate"]
    monkeypatch.setattr(R, "speculation_for", lambda *a, **k: None)
    R.run_log(LOG, tmp_path / "staged", _config())
    assert "ahead_samples" not in json.loads((tmp_path / "staged" / "run.json").read_text())["timings_s"]
    assert _files(tmp_path / "ahead") == _files(tmp_path / "staged")
    assert len(_files(tmp_path / "ahead")) >= 8  # the tables and the report
    ahead, staged = (json.loads((tmp_path / d / "run.json").read_text()) for d in ("ahead", "staged"))
    for doc in (ahead, staged):  # what numba compiled first is the process's, not the run's
        doc.pop("timings_s"), doc.pop("compiled", None)
        doc["notes"] = [n for n in doc["notes"] if not n.startswith("first run: compiled")]
    assert ahead == staged  # notes, warnings, counts, segments


def test_a_stream_that_disagrees_starts_the_run_again(tmp_path, monkeypatch, small_pieces, inline):
    """A prefix that the whole log contradicts (here: every check says so) leaves the staged run."""
    seen = []
    monkeypatch.setattr(speculation, "agrees", lambda *a: seen.append(a[2]) or False)
    R.run_log(LOG, tmp_path / "ahead", _config())
    assert seen  # the check ran, and refused
    assert json.loads((tmp_path / "ahead" / "run.json").read_text())["timings_s"]["ahead_samples"] == 0
    monkeypatch.setattr(R, "speculation_for", lambda *a, **k: None)
    R.run_log(LOG, tmp_path / "staged", _config())
    assert _files(tmp_path / "ahead") == _files(tmp_path / "staged")


def _stream(n: int = 400, frames: int = 40):
    from slamobs.pipeline.alignment import AlignedStream

    rng = np.random.default_rng(1)
    det_t = np.arange(frames, dtype=np.int64) * 100_000_000 + 5_000_000
    return AlignedStream(
        t0_ns=0,
        vel_t_ns=np.arange(n, dtype=np.int64) * 10_000_000,
        omega=rng.normal(size=(n, 3)),
        velocity=rng.normal(size=(n, 3)),
        det_t_ns=det_t,
        det_offsets=np.arange(frames + 1, dtype=np.int64) * 2,
        det_idx=np.tile([0, 1], frames),
        det_y=rng.normal(size=(2 * frames, 3)),
        landmark_ids=np.array([3, 7]),
        body_frame="base_link",
    )


def test_agrees_compares_what_the_run_read_and_its_look_ahead():
    ran, ahead = _stream(), 500_000_000  # sample 100 is at 1 s: compared up to 1.5 s (150 samples, 15 frames)
    assert speculation.agrees(ran, _stream(), 100, ahead)
    later = _stream()
    later.omega[200] += 1.0  # past the look-ahead
    later.det_y[-1] += 1.0
    assert speculation.agrees(ran, later, 100, ahead)
    for change in (
        lambda s: s.omega.__setitem__((120, 0), 0.0) or s,  # within it
        lambda s: s.det_y.__setitem__((2 * 14, 1), 0.0) or s,
        lambda s: s.vel_t_ns.__setitem__(slice(140, None), s.vel_t_ns[140:] + 1) or s,
        lambda s: replace(s, landmark_ids=np.array([3, 8])),
        lambda s: replace(s, segment_starts=np.array([130])),
        lambda s: replace(s, t0_ns=1),
        lambda s: replace(s, det_offsets=np.concatenate((s.det_offsets[:-1], [s.det_offsets[-1] + 1]))),
    ):
        assert not speculation.agrees(ran, change(_stream()), 100, ahead)
    assert not speculation.agrees(ran, _stream(n=120), 100, ahead)  # the other stream ends before the look-ahead


def test_pieces_of_a_stretch_joined_are_the_stretch(small_pieces):
    from slamobs.pipeline.observers.base import joined

    config = _config()
    prepared = R.prepare_log(LOG, config, directions=False, noise=False)
    est = R.estimator_input(prepared, config)
    whole = est.spec.start(prepared.aligned, est.gains, est.options).advance(3000)
    stepper = est.spec.start(prepared.aligned, est.gains, est.options)
    parts = [stepper.advance(stop) for stop in (700, 1400, 2100, 3000)]
    got = joined([replace(p, landmark_xyz=np.array(p.landmark_xyz)) for p in parts])
    for name in ("t_ns", "rotation", "position", "gyro_bias", "vel_bias", "det_t_ns", "det_ids", "innovation"):
        assert np.array_equal(getattr(got, name), getattr(whole, name)), name
    assert np.array_equal(got.landmark_xyz, whole.landmark_xyz)
    assert got.stats == whole.stats


def test_run_ahead_on_its_thread_gives_the_staged_run(tmp_path, monkeypatch, small_pieces):
    """On its own thread, however far the run got ahead (or not), the same bytes, and the thread is gone."""
    R.run_log(LOG, tmp_path / "ahead", _config())
    assert "ahead_samples" in json.loads((tmp_path / "ahead" / "run.json").read_text())["timings_s"]
    assert not [t for t in threading.enumerate() if t.name == "slamobs-speculate"]
    monkeypatch.setattr(R, "speculation_for", lambda *a, **k: None)
    R.run_log(LOG, tmp_path / "staged", _config())
    assert _files(tmp_path / "ahead") == _files(tmp_path / "staged")


def test_no_prefix_past_the_bounds():
    """Long logs: no prefix past MAX_PREFIX_ROWS rows, none once the run ahead reached MAX_AHEAD samples."""
    sp = speculation.Speculation(None, {}, None, None, 1024, ())
    assert sp.wants({"angular_velocity": 600})
    assert not sp.wants({"angular_velocity": speculation.MAX_PREFIX_ROWS + 1})
    sp._stepper = type("Stepper", (), {"iv": speculation.MAX_AHEAD})()
    assert not sp.wants({"angular_velocity": speculation.MAX_AHEAD + 4096})
