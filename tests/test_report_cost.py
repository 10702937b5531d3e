"""What a run's report costs (issue 27): the figures a run draws by default, the tables it reads back without
pandas, and the work only some estimators need (the recorded velocity's noise density)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from slamobs.pipeline.evaluation.figure_jobs import MAIN_FIGURES, MAIN_RUN_FIGURES, chosen, drawn
from slamobs.pipeline.streams import PoseStream
from slamobs.pipeline.writers import null_columns, read_columns

JOBS = [("plot_x", name, {}) for name in ("trajectory.png", "map.png", "biases.png", *MAIN_FIGURES)]


def test_plots_choose_the_figures():
    assert chosen(JOBS, "all") == JOBS
    assert chosen(JOBS, False) == []
    assert [j[1] for j in chosen(JOBS, True)] == list(MAIN_FIGURES)
    assert [j[1] for j in chosen(JOBS, True, MAIN_RUN_FIGURES)] == ["trajectory.png", "map.png"]
    assert drawn("biases.png", "all") and not drawn("biases.png", True) and drawn("errors.png", True)
    assert not drawn("errors.png", False)


@pytest.fixture(scope="module")
def table_with_nulls(tmp_path_factory):
    """Two row groups: a column of values, one with some nulls, one null throughout (an observer's covariance)."""
    rng = np.random.default_rng(3)
    n = 1000
    some = pa.array(rng.normal(size=n), mask=rng.random(n) < 0.3)
    table = pa.table(
        {
            "t_ns": np.arange(n, dtype=np.int64),
            "x": rng.normal(size=n),
            "some": some,
            "none": pa.nulls(n, pa.float64()),
        }
    )
    path = tmp_path_factory.mktemp("t") / "poses.parquet"
    pq.write_table(table, path, row_group_size=600)
    return path, table


def test_read_columns_gives_nulls_as_nan_like_pyarrow(table_with_nulls):
    path, table = table_with_nulls
    got = read_columns(path)
    assert list(got) == table.column_names
    for name in table.column_names:
        want = table.column(name).to_numpy(zero_copy_only=False)
        assert got[name].dtype == want.dtype and np.array_equal(got[name], want, equal_nan=True), name


def test_skip_null_leaves_out_only_the_columns_null_throughout(table_with_nulls):
    path, _ = table_with_nulls
    assert null_columns(pq.ParquetFile(path)) == {"none"}
    assert list(read_columns(path, skip_null=True)) == ["t_ns", "x", "some"]


def test_reading_columns_with_nulls_does_not_import_pandas(table_with_nulls):
    """pyarrow's to_numpy of a column with nulls imports pandas (1-1.7 s of every report before)."""
    code = (
        "import sys; from slamobs.pipeline.writers import read_columns; "
        f"read_columns({str(table_with_nulls[0])!r}); print('pandas' in sys.modules)"
    )
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "False\n"


def test_only_estimators_with_noise_levels_estimate_the_recorded_velocity_noise(monkeypatch):
    """fast-adaptation's run does not compute the velocity's noise density (0.5 s on an hour); riekf's does."""
    from slamobs.pipeline import noise, run
    from slamobs.pipeline.config import RunConfig
    from cli_checks import SAMPLES

    calls = []
    real = noise.stream_density
    monkeypatch.setattr(noise, "stream_density", lambda *a: calls.append(1) or real(*a))
    log = SAMPLES / "figure8.mcap"
    without = run.prepare_log(log, RunConfig(), directions=False, noise=False)
    assert without.velocity_noise is None and not without.aligned.velocity_density.any()
    assert calls == []
    prepared = run.prepare_log(log, RunConfig(), directions=False)
    assert prepared.velocity_noise is not None
    assert calls == [1]
    # on the stream for the detection pairs' velocity-scale check (time_offset.velocity_scale)
    assert np.array_equal(prepared.aligned.velocity_density, np.resize(prepared.velocity_noise.value, 3))


def test_compiled_running_medians_equal_the_array_code(monkeypatch):
    """The running median of the errors (convergence, the errors figure) from the compiled loop of long logs is
    the array code's, bit for bit: odd and even window counts, strided windows, repeated values."""
    from slamobs.pipeline.evaluation import metrics, slam_metrics

    rng = np.random.default_rng(7)
    n = 50_000
    t = np.cumsum(rng.integers(5_000_000, 15_000_000, size=n))
    errors = np.round(np.abs(rng.standard_cauchy(n)), 3)  # ties, and outliers the median ignores
    found = {}
    for use in (True, False):
        monkeypatch.setattr(metrics, "KERNEL_ROWS", 1 if use else 1 << 62)
        found[use] = [
            slam_metrics.error_level(t, errors, fraction, points) for fraction, points in ((0.1, 2000), (0.01, 777))
        ]
    counts = set()
    for (grid_a, level_a), (grid_b, level_b) in zip(found[True], found[False]):
        assert np.array_equal(grid_a, grid_b) and np.array_equal(level_a, level_b)
        assert np.ptp(level_a) > 0
    for fraction in (0.1, 0.01):  # both parities of the window's count occur
        half = 0.5 * fraction * float(t[-1] - t[0])
        width = np.searchsorted(t, t + half, side="right") - np.searchsorted(t, t - half, side="left")
        step = np.maximum(1, width // slam_metrics.WINDOW_SAMPLES)
        counts |= {int(c) % 2 for c in (width + step - 1) // step}
    assert counts == {0, 1}


def test_compiled_row_norms_equal_numpy_norm(monkeypatch):
    """The report's row norms of long arrays (APE, RPE, path lengths, the truth check) are ``np.linalg.norm(x -
    y, axis=1)`` bit for bit: three and four columns, tiny to overflowing magnitudes, zeros, inf and NaN."""
    from slamobs.pipeline.evaluation import metrics

    rng = np.random.default_rng(11)
    for cols in (3, 4):
        x = rng.normal(size=(4000, cols)) * 10.0 ** rng.integers(-160, 160, size=(4000, 1))
        y = rng.normal(size=(4000, cols)) * np.abs(x).max(axis=1, keepdims=True)
        x[0], x[1], x[2, 0], x[3, 1] = 0.0, -0.0, np.inf, np.nan
        monkeypatch.setattr(metrics, "KERNEL_ROWS", 1)
        got = metrics.row_norms(x), metrics.row_norms(x, y), metrics.row_norms(x[1:], x[:-1])
        with np.errstate(over="ignore", invalid="ignore"):
            want = (
                np.linalg.norm(x, axis=1),
                np.linalg.norm(x - y, axis=1),
                np.linalg.norm(np.diff(x, axis=0), axis=1),
            )
        for g, w in zip(got, want):
            assert g.tobytes() == w.tobytes()
        assert np.isinf(got[0]).any() and np.isnan(got[0]).any() and (got[0] == 0).any()
        monkeypatch.setattr(metrics, "KERNEL_ROWS", 1 << 62)
        with np.errstate(over="ignore"):  # overflowing squares on purpose: NumPy's path warns, as NumPy does
            assert metrics.row_norms(x, y).tobytes() == want[1].tobytes()


def test_order_statistics_equal_numpy_median_and_percentile():
    """The report's median and percentiles from one partition are NumPy's ``median`` and ``percentile`` bit for
    bit: every length from 1 to 40 (both parities, percentile ranks at and between samples), long vectors, ties,
    constant vectors; a NaN gives NumPy's NaN."""
    from slamobs.pipeline.evaluation.metrics import PERCENTILES, order_statistics

    rng = np.random.default_rng(5)
    for n in [*range(1, 41), 1000, 1001, 65_537]:
        for e in (np.abs(rng.standard_cauchy(n)), np.round(rng.random(n), 1), np.full(n, 0.3)):
            median, percentiles = order_statistics(e)
            assert np.float64(median).tobytes() == np.median(e).tobytes()
            assert percentiles.tobytes() == np.percentile(e, PERCENTILES).tobytes()
    e = rng.random(100)
    e[7] = np.nan
    median, percentiles = order_statistics(e)
    assert np.isnan(median) and np.isnan(percentiles).all()


def test_scaled_kinds_statistics_from_the_base_kinds_ranks_are_numpys():
    """The segment errors' % and per-metre kinds take their median and percentiles from the metre and degree
    kinds' ranks (``drift.kind_statistics``): every statistic the same bits as ``metrics.statistics`` of the scaled
    array itself (so as NumPy's), on long vectors with ties, tiny and huge values, odd and even counts, and with a
    NaN (NumPy's NaN)."""
    from slamobs.pipeline.evaluation.drift import SEGMENT_ERROR_KINDS, kind_statistics, per_metre, percent
    from slamobs.pipeline.evaluation.metrics import statistics

    rng = np.random.default_rng(3)
    for n, length in ((4096, 3.7), (65_537, 0.3), (100_000, 1472.92)):
        trans = np.abs(rng.standard_cauchy(n)) * 1e-3
        trans[: n // 10] = np.round(trans[: n // 10], 4)  # ties
        trans[-5:] = (5e-324, 1e-300, 1e150, 0.0, 0.0)
        rot = np.round(rng.random(n) * 3, 3)
        errs = dict(zip(SEGMENT_ERROR_KINDS, (trans, percent(trans, length), rot, per_metre(rot, length), rot, trans)))
        for kind, stats in kind_statistics(errs, length).items():
            assert stats == statistics(np.array(errs[kind])), kind
            assert stats["p95"] == float(np.percentile(errs[kind], 95)) and stats["median"] == float(
                np.median(errs[kind])
            )
        trans[7] = np.nan
        errs = dict(zip(SEGMENT_ERROR_KINDS, (trans, percent(trans, length), rot, per_metre(rot, length), rot, trans)))
        got = kind_statistics(errs, length)
        assert np.isnan(got["translation_pct"]["median"]) and np.isnan(got["translation_pct"]["p99"])


def test_ranked_puts_the_values_of_each_rank_where_a_sort_does():
    """``ranked`` (one single-rank partition after another) leaves at every asked rank the value a sort puts
    there, NaN last, for rank sets with the ends, neighbours and repeats of ties."""
    from slamobs.pipeline.evaluation.metrics import ranked

    rng = np.random.default_rng(11)
    for n in (1, 2, 3, 10, 1000, 4097):
        for e in (rng.standard_normal(n), np.round(rng.random(n), 1), np.full(n, 0.5)):
            if n > 3:
                e[rng.integers(0, n, 2)] = np.nan
            for ranks in (np.array([0]), np.array([n - 1]), np.unique(rng.integers(0, n, 7)), np.arange(n)):
                got = ranked(e, ranks)
                assert got[ranks].tobytes() == np.sort(e)[ranks].tobytes()
                assert np.sort(got).tobytes() == np.sort(e).tobytes()  # a permutation of e, e untouched
    e = rng.random(20)
    before = e.copy()
    ranked(e, np.array([3, 10]))
    assert e.tobytes() == before.tobytes()


def test_median_is_numpy_median_bit_for_bit():
    """``metrics.median`` is ``float(np.median(e))``: even and odd lengths on both sides of ``RANKED_ROWS``, floats
    with ties, integer stamp steps, a NaN (NaN)."""
    from slamobs.pipeline.evaluation.metrics import RANKED_ROWS, median

    rng = np.random.default_rng(12)
    for n in (1, 2, 3, RANKED_ROWS - 1, RANKED_ROWS, RANKED_ROWS + 1, 10_000, 10_001):
        for e in (rng.standard_normal(n), np.round(rng.random(n), 1), rng.integers(4_990_000, 5_010_000, n)):
            assert np.float64(median(e)).tobytes() == np.float64(np.median(e)).tobytes()
        e = rng.random(n)
        e[n // 3] = np.nan
        assert np.isnan(median(e))


def test_a_loaded_kernel_takes_the_shorter_pieces_of_a_long_log(monkeypatch):
    """Once a report kernel is in the process, the pieces of a long log shorter than ``KERNEL_ROWS`` (its last
    block, the RPE's pairs) take it too, with the array code's numbers; shorter ones still take the array code."""
    from slamobs.pipeline.evaluation import metrics
    from slamobs.pipeline.lie import quats_to_rots

    rng = np.random.default_rng(9)
    n = metrics.KERNEL_ROWS // 64
    a, b = (quats_to_rots(rng.normal(size=(n, 4))) for _ in range(2))
    array_calls = []
    real = metrics.matrix_quats
    monkeypatch.setattr(metrics, "matrix_quats", lambda m: array_calls.append(len(m)) or real(m))
    with monkeypatch.context() as mp:
        mp.setattr(metrics, "KERNEL_ROWS", 1 << 62)
        want = metrics.relative_angles(a, b)
        mp.setattr(metrics, "KERNEL_ROWS", 1)
        metrics.relative_angles(a[:2], b[:2])  # the kernel is now in the process
    assert array_calls == [n]
    assert metrics.relative_angles(a, b).tobytes() == want.tobytes()
    assert array_calls == [n]  # the kernel's
    metrics.relative_angles(a[1:], b[1:])
    assert array_calls == [n, n - 1]


def test_rotation_rows_kept_or_converted_each_time_are_the_same(monkeypatch):
    """RotationRows gives the same matrices whether it keeps all rows' matrices (up to ``MATRICES_KEPT_ROWS``)
    or converts the rows asked for each time: slices, index arrays, single rows, turned copies, pair indices."""
    from slamobs.pipeline.evaluation import metrics
    from slamobs.pipeline.lie import quats_to_rots

    rng = np.random.default_rng(2)
    q = rng.normal(size=(500, 4))
    index = rng.integers(0, 500, size=300)
    left = quats_to_rots(rng.normal(size=(1, 4)))[0]
    asks = (slice(None), slice(10, 90), np.array([5, 3, 299]), 7)
    found = {}
    for kept in (1 << 20, 0):
        monkeypatch.setattr(metrics, "MATRICES_KEPT_ROWS", kept)
        rows = metrics.RotationRows(q, index=index)
        found[kept] = [r[a] for r in (rows, rows.turned(left), rows) for a in asks]
    for a, b in zip(found[1 << 20], found[0]):
        assert a.tobytes() == b.tobytes()
    assert np.array_equal(found[0][0], quats_to_rots(q[index]))


def test_compiled_rotation_products_equal_numpy_matmul(monkeypatch):
    """The report's compiled 3×3 products of long logs (a rotation times every matrix of a stack; each matrix
    times another's transpose) are NumPy's ``matmul``: to the last bit where its OpenBLAS rounds with FMA (the
    project's VM), within an ulp elsewhere."""
    from slamobs.pipeline.evaluation import metrics
    from slamobs.pipeline.evaluation.drift import turns
    from slamobs.pipeline.lie import quats_to_rots

    rng = np.random.default_rng(4)
    a, b = (quats_to_rots(rng.normal(size=(5000, 4))) for _ in range(2))
    left = quats_to_rots(rng.normal(size=(1, 4)))[0]
    monkeypatch.setattr(metrics, "KERNEL_ROWS", 1)
    got = metrics.rotated(left, a), turns(a, b)
    monkeypatch.setattr(metrics, "KERNEL_ROWS", 1 << 62)
    want = metrics.rotated(left, a), turns(a, b)
    for g, w in zip(got, want):
        assert g.shape == w.shape == (5000, 3, 3)
        np.testing.assert_allclose(g, w, rtol=0, atol=4e-16)
    assert np.allclose(want[1], np.einsum("nij,nkj->nik", a, b))  # what turns computes: a_k b_kᵀ


REPORT_SECTIONS = (
    "ape",
    "ape_by_alignment",
    "rpe",
    "drift",
    "segment_errors",
    "time_offset",
    "landmarks",
    "biases",
    "convergence",
    "uncertainty",
)


@pytest.fixture(scope="module")
def compiled_and_array_runs(tmp_path_factory):
    """A sample log run twice: with the report's and the writer's compiled kernels taken at any size (as on a
    long log), and with the array code only."""
    from cli_checks import SAMPLES
    from slamobs.pipeline import writers
    from slamobs.pipeline.config import EvaluationConfig, RunConfig
    from slamobs.pipeline.evaluation import metrics
    from slamobs.pipeline.run import run_log

    config = RunConfig(evaluation=EvaluationConfig(plots=False))
    runs = {}
    with pytest.MonkeyPatch.context() as mp:
        for name, rows in (("compiled", 1), ("array", 1 << 62)):
            mp.setattr(metrics, "KERNEL_ROWS", rows)
            mp.setattr(writers, "ROUND_KERNEL_ROWS", rows)
            runs[name] = tmp_path_factory.mktemp(name) / "run"
            run_log(SAMPLES / "circle.bag", runs[name], config)
    return runs


def _assert_numbers_close(a, b, where: str = "") -> None:
    """Equal JSON documents but for floats, which agree to 1e-12 relative."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _assert_numbers_close(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            _assert_numbers_close(x, y, f"{where}[{k}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert b == pytest.approx(a, rel=1e-12, abs=1e-300), where
    else:
        assert a == b, where


def test_compiled_paths_give_the_tables_and_report_of_the_array_code(compiled_and_array_runs):
    """The same Parquet values (the rounding kernel and the two writing lanes) and the same report numbers (the
    segment, rotation and running-median kernels; 1e-12 relative: BLAS without FMA rounds its products
    differently) whichever path a log's length selects."""
    import json

    runs = compiled_and_array_runs
    for name in ("poses", "biases", "innovations", "landmark_tracks", "landmarks", "poses_aligned"):
        got, want = (read_columns(runs[k] / f"{name}.parquet") for k in ("compiled", "array"))
        assert list(got) == list(want), name
        for column in got:
            assert np.array_equal(got[column], want[column], equal_nan=True), (name, column)
    reports = {k: json.loads((runs[k] / "report.json").read_text()) for k in runs}
    assert reports["compiled"]["segment_errors"]["per_length"][0]["n_segments"] > 100
    _assert_numbers_close(reports["array"], reports["compiled"])


def test_the_runs_report_is_what_slamobs_report_computes_from_its_files(compiled_and_array_runs, monkeypatch):
    """The report a run writes (computed from its tables as written) is the one ``slamobs report RUN`` computes
    again from the run directory: every section's numbers, with the long-log kernels as the run had them."""
    import json

    from slamobs.pipeline import writers
    from slamobs.pipeline.evaluation import metrics
    from slamobs.pipeline.evaluation import plot_worker
    from slamobs.pipeline.evaluation.run_dir import report_run

    monkeypatch.setattr(plot_worker, "draw", lambda jobs, path_of: [])  # the numbers only, not the figures
    run = compiled_and_array_runs["compiled"]
    before = json.loads((run / "report.json").read_text())
    monkeypatch.setattr(metrics, "KERNEL_ROWS", 1)
    monkeypatch.setattr(writers, "ROUND_KERNEL_ROWS", 1)
    again, _ = report_run(run)
    assert json.loads((run / "report.json").read_text()) == again  # the files hold what it returned
    for section in REPORT_SECTIONS:
        assert again[section] == before[section], section
    assert again["method"]["association"] == before["method"]["association"]


def test_compiled_step_angles_give_the_clock_offset_of_the_array_code(monkeypatch):
    """The clock-offset search of a long log takes its step angles from a compiled loop: the same offset, to the
    bit, as the array code (quaternions not of unit length, both signs of w)."""
    from slamobs.pipeline.evaluation import metrics
    from slamobs.pipeline.evaluation import sync

    rng = np.random.default_rng(9)
    n = 30_000
    t = np.arange(n, dtype=np.int64) * 10_000_000
    yaw = np.cumsum(0.02 * np.sin(0.003 * np.arange(n)) ** 2 + 0.002 * rng.random(n))
    wobble = 0.1 * np.sin(0.001 * np.arange(n) + rng.random())
    q = np.stack([wobble, 0.5 * wobble**2 + 0.01, np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
    q[::7] *= -1.7
    pos = np.stack([np.cos(0.001 * np.arange(n)), np.sin(0.001 * np.arange(n)), np.zeros(n)], axis=1)
    found, steps = {}, {}
    for use in (True, False):
        monkeypatch.setattr(metrics, "KERNEL_ROWS", 1 if use else 1 << 62)
        found[use] = sync.estimate_time_offset(t, pos, q, t[::2] - 37_000_000, pos[::2], q[::2])
        steps[use] = sync.step_angles(q)
    assert np.array_equal(steps[True], steps[False]) and found[True] == found[False]
    assert found[True].offset_s == pytest.approx(0.037, abs=0.002) and found[True].signal == "angular rate |ω|"


def test_tables_handed_over_give_the_report_of_the_files_read_back(tmp_path, monkeypatch):
    """A run hands its report the tables as written, without reading the three files back; a run whose tables
    would keep more than ``HANDOVER_BYTES`` reads them back; both write the same report, byte for byte."""
    from cli_checks import SAMPLES
    from slamobs.pipeline import run, writers
    from slamobs.pipeline.config import EvaluationConfig, RunConfig

    read = []
    real = writers.read_columns
    monkeypatch.setattr(writers, "read_columns", lambda path, **kw: read.append(path.name) or real(path, **kw))
    config = RunConfig(evaluation=EvaluationConfig(plots=False))
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "handed", config)
    assert read == []
    monkeypatch.setattr(run, "HANDOVER_BYTES", 0)
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "read", config)
    assert sorted(read) == ["biases.parquet", "landmarks.parquet", "poses.parquet"]
    for name in ("report.json", "report.md", "poses_aligned.parquet", "landmarks_aligned.parquet"):
        assert (tmp_path / "handed" / name).read_bytes() == (tmp_path / "read" / name).read_bytes(), name


def test_segment_errors_beside_the_other_sections_give_the_report_computed_in_turn(tmp_path, monkeypatch):
    """The report computes its segment errors on a thread beside the other sections, from the pairs as soon as
    the trajectories are paired (an alignment without scale) or once the alignment is fitted (Sim(3)); where no
    thread can be started (no room under a memory limit) or the log has more pairs than ``MATRICES_KEPT_ROWS`` it
    computes them in turn: the same report, byte for byte."""
    from cli_checks import SAMPLES
    from slamobs.pipeline import run
    from slamobs.pipeline.config import EvaluationConfig, RunConfig
    from slamobs.pipeline.evaluation import report

    started = []
    real = report.Pending
    monkeypatch.setattr(report, "Pending", lambda func, *a: started.append(func.__qualname__) or real(func, *a))
    config = RunConfig(evaluation=EvaluationConfig(plots=False))
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "beside", config)
    assert started == ["SegmentErrorsSection.process_pairs"]
    sim3 = RunConfig(evaluation=EvaluationConfig(plots=False, align="sim3"))
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "sim3_beside", sim3)
    assert started[1:] == ["SegmentErrorsSection.process_data"]
    started.clear()

    def no_room(*_a):
        raise MemoryError("no room")

    monkeypatch.setattr(report, "Pending", no_room)
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "in_turn", config)
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "sim3_in_turn", sim3)
    monkeypatch.setattr(report, "Pending", lambda func, *a: started.append(func.__qualname__) or real(func, *a))
    monkeypatch.setattr(report, "MATRICES_KEPT_ROWS", 10)  # a log longer than that: in turn, no thread
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "long", config)
    assert started == []
    beside = (tmp_path / "beside" / "report.json").read_bytes()
    assert b'"segment_errors"' in beside and b'"n_segments"' in beside
    for name in ("report.json", "report.md", "poses_aligned.parquet"):
        assert (tmp_path / "beside" / name).read_bytes() == (tmp_path / "in_turn" / name).read_bytes(), name
        assert (tmp_path / "beside" / name).read_bytes() == (tmp_path / "long" / name).read_bytes(), name
        assert (tmp_path / "sim3_beside" / name).read_bytes() == (tmp_path / "sim3_in_turn" / name).read_bytes(), name


def test_aligned_rows_are_written_before_the_report_waits_for_the_work_beside(tmp_path, monkeypatch):
    """A run writes the aligned tables' rows once its main thread's sections are done, before it waits for the
    clock-offset search and the segment errors (then the second core is not left idle while one thread writes
    them at the end); the footer comes last. The tables are the bytes written in one go (as ``slamobs report``
    writes them), and a report that fails after the rows were written leaves no aligned table."""
    import threading

    from cli_checks import SAMPLES
    from slamobs.pipeline import run
    from slamobs.pipeline.config import EvaluationConfig, RunConfig
    from slamobs.pipeline.evaluation import report, trajectory_evaluation

    events, reporting = [], []
    rows, wait = report.aligned_rows, trajectory_evaluation.Pending.result
    monkeypatch.setattr(report, "aligned_rows", lambda *a: events.append("rows") or rows(*a))
    evaluate = run.evaluate_run  # the report's waits only: not the alignment's warn-only notes, joined before it
    monkeypatch.setattr(run, "evaluate_run", lambda *a, **kw: reporting.append(True) or evaluate(*a, **kw))
    # the main thread's waits (the offset check beside it waits for the run's offset search, started with the
    # observer: that wait holds no core)
    monkeypatch.setattr(
        trajectory_evaluation.Pending,
        "result",
        lambda self: (
            (threading.current_thread() is threading.main_thread() and reporting and events.append("wait"))
            or wait(self)
        ),
    )
    config = RunConfig(evaluation=EvaluationConfig(plots=False))
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "ahead", config)
    assert events and events[0] == "rows" and events.count("rows") == 1, events
    monkeypatch.setattr(report, "aligned_rows", rows)
    at_once = tmp_path / "at_once"
    at_once.mkdir()
    written = []
    real_write = report.write_report

    def write_at_once(rep, out, *args, **kwargs):  # the rows and the footer in one go
        ev, meta = kwargs["evaluation"], kwargs["metadata"]
        kwargs["aligned"].abort()
        written.extend(report.write_aligned_tables(at_once, rep, ev, args[2], meta))
        return real_write(rep, tmp_path / "ahead_again", *args, **{**kwargs, "aligned": None})

    monkeypatch.setattr(report, "write_report", write_at_once)
    monkeypatch.setattr("slamobs.pipeline.evaluation.write_report", write_at_once)
    run.run_log(SAMPLES / "figure8.mcap", tmp_path / "unused", config)
    for name in report.ALIGNED_TABLES:
        assert (tmp_path / "ahead" / name).read_bytes() == (at_once / name).read_bytes(), name

    def fails(*_a, **_kw):
        raise ValueError("the report cannot be written")

    monkeypatch.setattr("slamobs.pipeline.evaluation.write_report", fails)
    summary = run.run_log(SAMPLES / "figure8.mcap", tmp_path / "failed", config)
    assert summary.report is None
    assert not [name for name in report.ALIGNED_TABLES if (tmp_path / "failed" / name).exists()]


def test_pending_work_is_done_by_the_thread_or_by_the_caller_when_the_thread_has_not_begun(monkeypatch):
    """``Pending`` computes on its thread; when the caller asks for the result before the thread has begun (a
    loaded machine), the caller computes it and the thread finds it taken: computed once, either way, and an
    error is raised to the caller from both."""
    import threading

    from slamobs.pipeline.evaluation.trajectory_evaluation import Pending

    ran = []

    def work(x, fail=False):
        ran.append(threading.current_thread().name)
        if fail:
            raise ValueError("bad")
        return 2 * x

    done = Pending(work, 21)
    assert done.result() == 42 and done.result() == 42 and len(ran) == 1
    with pytest.raises(ValueError, match="bad"):
        Pending(work, 1, fail=True).result()
    ran.clear()
    monkeypatch.setattr(threading.Thread, "start", lambda self: None)  # the thread never begins
    late = Pending(work, 5)
    assert late.result() == 10 and late.result() == 10 and ran == [threading.current_thread().name]
    late._run()  # the thread, beginning after all, finds the work taken
    assert ran == [threading.current_thread().name]
    with pytest.raises(ValueError, match="bad"):
        Pending(work, 1, fail=True).result()


def test_a_pending_ctrl_c_or_sigterm_ends_the_wait_for_work_beside(monkeypatch):
    """The main thread waiting for work on a thread (``Pending.result``) is inside threading's wait, where a
    signal's exception is not raised (``pipeline.interrupts``): it looks for a pending Ctrl-C/SIGTERM between
    waits and raises it while the work is still going on."""
    import signal
    import threading

    from slamobs.pipeline import interrupts
    from slamobs.pipeline.evaluation.trajectory_evaluation import Pending

    begun, release, finished = threading.Event(), threading.Event(), []

    def work():
        begun.set()
        release.wait(10)
        finished.append(True)

    pending = Pending(work)
    assert begun.wait(10)  # the thread has the work
    monkeypatch.setattr(interrupts, "requested", signal.SIGTERM)
    monkeypatch.setattr(interrupts, "_raised", False)
    try:
        with pytest.raises(interrupts.Interrupted):
            pending.result()
        assert not finished
    finally:
        release.set()


def test_rate_on_grid_marks_the_same_samples_outside_the_span():
    """The clock-offset search's resampling marks the grid points outside the stream's span by bisection (the grid
    rises): the same NaNs and bits as comparing every point, for grids past either end, inside, and outside."""
    from slamobs.pipeline.evaluation import sync

    rng = np.random.default_rng(5)
    t = np.cumsum(rng.integers(4_000_000, 6_000_000, size=400)).astype(np.int64) + 10**18
    inc = rng.random(399)
    step = 10_000_000
    nans = set()
    for start, n in ((t[0] - 7 * step, 260), (t[0] + 3, 50), (t[-1] - 3 * step, 40), (t[-1] + step, 5), (t[0], 1)):
        for shift in (0, 1, -1, 4_999_999, -step):
            grid = start + np.arange(n, dtype=np.int64) * step - shift
            got = sync.rate_on_grid(t, inc, grid, step)
            cum_t, cum = sync.accumulate(t, inc)
            edges = np.append(grid, grid[-1] + step).astype(np.float64)
            at = np.interp(edges, cum_t, cum)
            want = (at[1:] - at[:-1]) / (step / sync.NS_PER_S)
            want[(grid < t[0]) | (grid + step > t[-1])] = np.nan
            assert got.tobytes() == want.tobytes()
            nans.add((bool(np.isnan(got[0])), bool(np.isnan(got[-1])), bool(np.isnan(got).all())))
    assert {(True, True, False), (False, False, False), (True, True, True)} <= nans  # both ends, none, all


def test_fft_size_is_the_smallest_length_of_factors_2_3_5():
    """The clock-offset search pads its FFTs to the smallest 2^a 3^b 5^c at or past the length it needs (no
    product wraps around), not to the next power of two."""
    from slamobs.pipeline.evaluation import sync

    def smooth(m: int) -> bool:
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        return m == 1

    for n in [*range(1, 2000), 360_401, 524_288, 524_289]:
        size = sync.fft_size(n)
        assert size >= n and smooth(size) and not any(smooth(m) for m in range(n, size)), n
    assert sync.fft_size(360_300 + 101) == 364_500  # the hour's grid: not 2^19


def test_compiled_offset_correlation_is_the_array_codes_to_round_off(monkeypatch):
    """A long log's golden-section search takes each trial offset's correlation from one compiled pass: the array
    code's value to 1e-12 at offsets inside, across and past the stream's span (reference NaNs, too few points:
    -1), and the same offset to the bit from ``estimate_time_offset``."""
    from slamobs.pipeline.evaluation import sync

    rng = np.random.default_rng(11)
    n = 3000
    t = np.cumsum(rng.integers(4_000_000, 6_000_000, size=n)).astype(np.int64)
    steps = 0.01 + 0.02 * np.sin(0.01 * np.arange(n - 1)) ** 2 + 0.002 * rng.random(n - 1)
    step = 10_000_000
    grid = t[0] - 50 * step + np.arange((t[-1] - t[0]) // step + 100, dtype=np.int64) * step
    ref = sync.rate_on_grid(t, steps, grid - 23_000_000, step)
    ref[::13] = np.nan
    value = {}
    for kernel in (True, False):
        monkeypatch.setattr(sync, "CORRELATION_KERNEL_ROWS", 1 if kernel else 1 << 62)
        corr = sync.offset_correlation(ref, t, steps, grid, step)
        value[kernel] = [corr(tau) for tau in (-2.5e7, -1.23e6, 0.0, 7.7e6, 2.3e7, 3.1e10, -3.1e10, (t[-1] - t[0]) - 5)]
    assert value[True] == pytest.approx(value[False], rel=1e-12, abs=1e-14)
    assert value[True][5] == value[True][6] == -1.0 and max(value[True]) > 0.9
    yaw = np.cumsum(0.02 * np.sin(0.003 * np.arange(20_000)) ** 2)
    q = np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
    tt = np.arange(20_000, dtype=np.int64) * 10_000_000
    pos = np.zeros((20_000, 3))
    found = {}
    for kernel in (True, False):
        monkeypatch.setattr(sync, "CORRELATION_KERNEL_ROWS", 1 if kernel else 1 << 62)
        found[kernel] = sync.estimate_time_offset(tt, pos, q, tt[::2] - 37_000_000, pos[::2], q[::2])
    assert found[True].offset_s == found[False].offset_s == pytest.approx(0.037, abs=0.002)
    assert found[True].peak_correlation == pytest.approx(found[False].peak_correlation, rel=1e-12)


def test_a_truths_searches_share_its_side_and_a_bracket_walks_only_the_estimates_span(monkeypatch):
    """``log_time_offset`` searches one truth up to six times (the bias fit's search again, the log's halves): the
    truth's steps, its rates on the grid and their spectra are made once (``sync.ReferenceMotion``), the same
    offset to the bit as searches that each make their own. A golden-section bracket crops the compiled pass to
    the estimate's span (a half of the log: half the grid), the same correlation to the bit."""
    from slamobs.pipeline.evaluation import sync, trajectory_evaluation

    n = 20_000
    yaw = np.cumsum(0.02 * np.sin(0.003 * np.arange(n)) ** 2)
    q = np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
    t = np.arange(n, dtype=np.int64) * 10_000_000
    truth = PoseStream("/mocap", "world", "base", t + 37_000_000, t + 37_000_000, np.zeros((n, 3)), q)
    omega = np.zeros((n, 3))
    omega[1:, 2] = np.diff(yaw) / 0.01  # the turn since the sample before: 5 ms behind, 32 ms found
    made, counted = [], sync.pose_steps
    monkeypatch.setattr(sync, "pose_steps", lambda *a: made.append(1) or counted(*a))
    found = trajectory_evaluation.log_time_offset(truth, t, omega, np.zeros((n, 3)))
    assert len(made) == 1 and found.offset_s == pytest.approx(0.032, abs=0.002) and found.uncertainty_s is not None
    one = sync.ReferenceMotion(truth.t_ns, truth.position, truth.quat_xyzw)
    again = []
    for part in (slice(None), slice(0, n // 2), slice(n // 2, n)):  # each search with its own reference too
        steps = sync.velocity_steps(t[part], omega[part], np.zeros((n, 3))[part])
        own = sync.ReferenceMotion(truth.t_ns, truth.position, truth.quat_xyzw)
        again.append(sync.time_offset_of_steps(one, t[part], steps) == sync.time_offset_of_steps(own, t[part], steps))
    assert all(again)
    grid = t[0] - 100 * 10_000_000 + np.arange(n + 200, dtype=np.int64) * 10_000_000
    monkeypatch.setattr(sync, "CORRELATION_KERNEL_ROWS", 1)  # the compiled pass on a short grid
    ref = sync.rate_on_grid(t + 37_000_000, sync.step_angles(q), grid, 10_000_000)
    half = slice(n // 2, n)
    steps = sync.velocity_steps(t[half], omega[half], np.zeros((n, 3))[half])[0]
    whole = sync.offset_correlation(ref, t[half], steps, grid, 10_000_000)
    cropped = sync.offset_correlation(ref, t[half], steps, grid, 10_000_000, (20_000_000, 40_000_000))
    taus = np.linspace(20_000_000, 40_000_000, 9)
    assert [cropped(tau) for tau in taus] == [whole(tau) for tau in taus]
    assert max(whole(tau) for tau in taus) > 0.9


def test_yaw_fit_centres_each_mean_once_same_bits():
    """``align.yaw_fit`` takes each mean once and centres only the horizontal columns: the same rotation and
    translation, bit for bit, as the whole centred arrays with the means taken again for the translation."""
    from slamobs.pipeline.evaluation.align import yaw_fit

    rng = np.random.default_rng(8)
    for n in (2, 3, 1000, 70_001):
        x = rng.normal(size=(n, 3)) * 40.0 + 3.0
        turn = np.array([[0.6, -0.8, 0.0], [0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])
        y = x @ turn.T + rng.normal(size=(n, 3)) * 0.05 + 7.0
        xc, yc = x - x.mean(axis=0), y - y.mean(axis=0)
        th = np.arctan2(
            np.sum(xc[:, 0] * yc[:, 1] - xc[:, 1] * yc[:, 0]), np.sum(xc[:, 0] * yc[:, 0] + xc[:, 1] * yc[:, 1])
        )
        rot = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
        got_rot, got_trans = yaw_fit(x, y)
        assert got_rot.tobytes() == rot.tobytes()
        assert got_trans.tobytes() == (y.mean(axis=0) - rot @ x.mean(axis=0)).tobytes()


def test_rms_extent_same_bits_as_the_centred_sum_along_rows():
    """``slam_metrics.rms_extent`` adds each centred column's squares in turn: the same bits as NumPy's
    ``sqrt(mean(sum((x - mean) ** 2, axis=1)))``, on offset, rounded (ties), constant and one-row positions."""
    from slamobs.pipeline.evaluation.slam_metrics import rms_extent

    rng = np.random.default_rng(4)
    for n in (1, 2, 7, 1000, 70_001):
        for x in (rng.normal(size=(n, 3)) * 30 + 1e4, np.round(rng.normal(size=(n, 3)), 2), np.full((n, 3), 0.1)):
            want = np.sqrt(np.mean(np.sum((x - x.mean(axis=0)) ** 2, axis=1)))
            assert np.float64(rms_extent(x)).tobytes() == want.tobytes()
    assert rms_extent(np.ones((5, 2))) == 0.0  # other shapes: NumPy's own expression


def test_apply_alignment_same_bits_as_the_whole_expression():
    """``align.apply_alignment`` multiplies by a scale of 1 not at all and adds the translation in place: the same
    bits as ``scale * p @ R.T + t`` for scales 1 and not, zero and other translations, rows and one point."""
    from slamobs.pipeline.evaluation.align import apply_alignment

    rng = np.random.default_rng(6)
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    for p in (rng.normal(size=(1000, 3)) * 50.0, -np.zeros((4, 3)), rng.normal(size=3)):
        for scale in (1.0, 0.7):
            for trans in (np.zeros(3), rng.normal(size=3)):
                got = apply_alignment(rot, trans, scale, p)
                want = scale * p @ rot.T + trans
                assert got.shape == want.shape and got.tobytes() == want.tobytes()


def test_statistics_mean_and_std_are_numpys():
    """``metrics.statistics`` hands its mean to ``np.std``: mean and std the same bits as ``np.mean`` and
    ``np.std`` of the vector, for one to many values, ties, heavy tails and constants."""
    from slamobs.pipeline.evaluation.metrics import statistics

    rng = np.random.default_rng(9)
    for n in (1, 2, 3, 1000, 100_001):
        for e in (rng.random(n), np.abs(rng.standard_cauchy(n)), np.full(n, 0.1), np.round(rng.random(n), 2)):
            got = statistics(e)
            assert np.float64(got["mean"]).tobytes() == np.mean(e).tobytes()
            assert np.float64(got["std"]).tobytes() == np.std(e).tobytes()


def test_valid_truth_keeps_the_same_poses_on_its_finite_path():
    """``valid_truth`` checks a truth finite throughout as a whole (no per-row reductions): all kept, the stream
    itself returned; a NaN quaternion entry, an infinite position or a zero quaternion still drop their pose
    alone (the per-row path), and so does a tiny quaternion on the finite path."""
    from slamobs.pipeline.evaluation.trajectory_evaluation import valid_truth
    from slamobs.pipeline.streams import PoseStream

    rng = np.random.default_rng(12)
    n = 1000
    for bad in (None, "nan_quat", "inf_position", "zero_quat", "tiny_quat"):
        q = rng.normal(size=(n, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        pos = rng.normal(size=(n, 3))
        if bad == "nan_quat":
            q[17, 2] = np.nan
        elif bad == "inf_position":
            pos[17, 0] = -np.inf
        elif bad in ("zero_quat", "tiny_quat"):
            q[17] = 0.0 if bad == "zero_quat" else 1e-9
        t = np.arange(n, dtype=np.int64)
        truth = PoseStream("/truth", "world", "body", t, t, pos, q)
        kept, dropped = valid_truth(truth)
        if bad is None:
            assert kept is truth and dropped == 0
        else:
            assert dropped == 1 and np.array_equal(kept.t_ns, np.delete(t, 17))
            assert kept.quat_xyzw.tobytes() == np.delete(q, 17, axis=0).tobytes()


def test_a_logs_search_takes_its_velocity_steps_once_a_bias_and_resamples_only_the_signal_it_reads(monkeypatch):
    """``log_time_offset``'s halves slice the whole log's velocity steps (those between a half's samples: the same
    bits as the half's own), and a search resamples the estimate's speed only when the speed is correlated: the
    truth's angular rate pins this log's lag, so each of its four searches (the log, the bias fit's search again,
    the halves) resamples one signal of the estimate (main: 4 velocity steps, 4 + 8 rates)."""
    from slamobs.pipeline.evaluation import sync, trajectory_evaluation

    n = 20_000
    yaw = np.cumsum(0.02 * np.sin(0.003 * np.arange(n)) ** 2)
    q = np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
    t = np.arange(n, dtype=np.int64) * 10_000_000
    truth = PoseStream("/mocap", "world", "base", t + 37_000_000, t + 37_000_000, np.zeros((n, 3)), q)
    omega, velocity = np.zeros((n, 3)), np.zeros((n, 3))
    omega[1:, 2] = np.diff(yaw) / 0.01
    velocity[:, 0] = 1.0 + 0.1 * np.sin(0.001 * np.arange(n))
    steps_made, resampled = [], []
    counted_steps, counted_rates = trajectory_evaluation.velocity_steps, sync.rate_on_grid
    monkeypatch.setattr(sync, "CORRELATION_KERNEL_ROWS", 1)  # the refinement's compiled pass: no rate_on_grid
    monkeypatch.setattr(trajectory_evaluation, "velocity_steps", lambda *a: steps_made.append(1) or counted_steps(*a))
    monkeypatch.setattr(sync, "rate_on_grid", lambda *a: resampled.append(1) or counted_rates(*a))
    found = trajectory_evaluation.log_time_offset(truth, t, omega, velocity)
    assert found.signal == "angular rate |ω|" and found.offset_s == pytest.approx(0.032, abs=0.002)
    assert found.uncertainty_s is not None
    assert len(steps_made) == 2  # the log's, the debiased log's; the halves slice the latter
    # the truth's two signals on the log's grid and on the second half's (it starts later: the truth then starts
    # the grid), and one of the estimate's a search
    assert len(resampled) == 2 + 2 + 4
