"""Out of memory, threads or file descriptors: one ``error:`` line naming the file, exit code 2; never a hang, a
traceback, a log blamed as corrupt, or a run that exits 0 without its report.

The limits are real (``resource.setrlimit`` in the child before it starts) where the outcome does not depend on
timing: an address-space limit under which the interpreter's imports already fail, a descriptor limit a run cannot
live with. Where the failure must come from one place (a chunk's decompression, the report, a thread start), the
failing call raises what it raises under a limit (measured: MemoryError, zstd's "Allocation error", RuntimeError
"can't start new thread").
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest
from click.testing import CliRunner

from slamobs.cli.main import main
from slamobs.pipeline.errors import InputError, ResourceError

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_logs" / "figure8.mcap"
SLAMOBS = [sys.executable, "-c", "from slamobs.cli.main import entry; entry()"]
MB = 1 << 20


def limited(**limits: int):
    """A ``preexec_fn`` setting ``RLIMIT_<name>`` (soft and hard) to each value."""

    def apply() -> None:
        for name, value in limits.items():
            resource.setrlimit(getattr(resource, f"RLIMIT_{name}"), (value, value))

    return apply


def run_cli(args: list[str], preexec=None, env=None, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*SLAMOBS, *args],
        capture_output=True,
        text=True,
        preexec_fn=preexec,
        timeout=timeout,
        env=env,
        stdin=subprocess.DEVNULL,
    )


def one_line(proc: subprocess.CompletedProcess, *needles: str) -> str:
    err = proc.stderr.strip()
    assert proc.returncode == 2 and len(err.splitlines()) == 1, (proc.returncode, err[-2000:])
    assert err.startswith("error: ") and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


def test_address_space_too_small_to_start_is_one_line(tmp_path):
    """At 250 MB the imports of a run fail (a shared object that cannot be mapped: 'libllvmlite.so' not found,
    an ImportError traceback of pyarrow or apsw before): one line naming the log and what a run needs."""
    out = tmp_path / "out"
    proc = run_cli(["run", str(SAMPLE), "-o", str(out), "-q"], limited(AS=250 * MB))
    err = one_line(
        proc,
        f"error: {SAMPLE}: not enough memory for a run of this log; needs about ",
        "(the limit (ulimit -v) is 250 MB)",
    )
    assert "corrupt" not in err
    assert not out.exists()


def test_address_space_too_small_for_numpy_is_one_line(tmp_path):
    """At 100 MB NumPy's import maps its libraries but its OpenBLAS cannot start: it printed "OpenBLAS error:
    Memory allocation still failed after 10 retries, giving up." and ended the process with exit code 1."""
    out = tmp_path / "out"
    proc = run_cli(["run", str(SAMPLE), "-o", str(out), "-q"], limited(AS=100 * MB))
    one_line(proc, "error: slamobs run: not enough memory for this command (the limit (ulimit -v) is 100 MB)")
    assert not out.exists()


@pytest.mark.parametrize("limit_mb", [300, 400, 450])
def test_run_under_an_address_space_limit_ends_in_one_line(tmp_path, limit_mb):
    """Limits a run of the sample log needs more than (it passes from about 650 MB): wherever it runs out (imports,
    reading, loading a kernel, a thread, the report), it ends with the one line and exit code 2 within the timeout,
    and nothing is written. Before: an ImportError or MemoryError traceback (exit 1), 'corrupt or truncated MCAP
    file: can't start new thread', or an abort ('LLVM ERROR: out of memory')."""
    out = tmp_path / "out"
    proc = run_cli(["run", str(SAMPLE), "-o", str(out), "-q"], limited(AS=limit_mb * MB))
    err = one_line(proc, f"error: {SAMPLE}: ", f"(ulimit -v{'' if 'thread' in proc.stderr else ')'} ")
    assert "not enough memory for " in err or "cannot start a thread for " in err, err
    assert "corrupt" not in err and not out.exists()
    assert not [p for p in tmp_path.iterdir()], list(tmp_path.iterdir())  # no temporary output left


def test_run_under_a_limit_it_fits_in_succeeds_with_its_report(tmp_path):
    """Under ``ulimit -v 900000`` the sample log's run is complete, report included (before, it needed about
    1000000: each thread's malloc arena and pyarrow's mimalloc reserved address space ahead; at 800000-1000000 it
    exited 0 without its report)."""
    out = tmp_path / "out"
    proc = run_cli(["run", str(SAMPLE), "-o", str(out), "-q"], limited(AS=900 * MB), timeout=300)
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr[-2000:]
    assert (out / "report.json").is_file()
    assert json.loads((out / "run.json").read_text())["report_error"] is None


def test_numba_never_loads_scipys_blas(tmp_path):
    """numba imports ``scipy.linalg.cython_blas`` when it loads its array functions; on the chunk-reading thread
    that started SciPy's OpenBLAS, which under ``ulimit -v 400000`` retried its 32 MB allocation for ever with the
    GIL held (the run spun, deaf to SIGTERM). A stand-in SciPy whose ``linalg`` records being imported shows that a
    run no longer imports it (the real SciPy need not be installed): neither a first run, whose compiler loads the
    array functions, nor a run that loads its kernels from the cache (they are loaded where one needs them)."""
    fake = tmp_path / "fake"
    (fake / "scipy" / "linalg").mkdir(parents=True)
    marker = tmp_path / "linalg-imported"
    (fake / "scipy" / "__init__.py").write_text('__version__ = "1.17.0"\n')
    (fake / "scipy" / "linalg" / "__init__.py").write_text(
        textwrap.dedent(f"""\
        import threading
        open({str(marker)!r}, "a").write(threading.current_thread().name + "\\n")
        raise ImportError("stand-in scipy.linalg")
        """)
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(fake), os.environ.get("PYTHONPATH", "")]),
        "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
    }
    for k in range(2):  # compiled, then loaded from the cache
        out = tmp_path / f"out{k}"
        # a cold cache: the first run compiles (the bound is for a hang: the cold riekf run of test_interrupts_compile
        # took over 300 s at load 16-20 on 2 cores)
        proc = run_cli(["run", str(SAMPLE), "-o", str(out), "-q"], env=env, timeout=1200)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert (out / "report.json").is_file()
        assert not marker.exists(), marker.read_text()


def test_batch_out_of_descriptors_names_out_and_the_limit(tmp_path):
    """A descriptor limit with ``batch -j 2`` (reported with ``ulimit -n 16``; 12 leaves a margin): it said 'Too many
    open files' (no file, no limit) when a worker's pipe could not be made."""
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("figure8.mcap", "circle.bag"):
        (logs / name).symlink_to(ROOT / "sample_logs" / name)
    out = tmp_path / "batch"
    proc = run_cli(["batch", str(logs), "-o", str(out), "-j", "2", "-q"], limited(NOFILE=12), timeout=300)
    one_line(proc, f"error: {out}: too many open files (ulimit -n 12) ", "raise the limit, e.g. ulimit -n 1024")


def test_run_out_of_descriptors_is_one_line(tmp_path):
    """A run with 7 descriptors (it needs about 9)."""
    out = tmp_path / "out"
    proc = run_cli(["run", str(SAMPLE), "-o", str(out), "-q"], limited(NOFILE=7))
    one_line(proc, "too many open files (ulimit -n 7) ", "raise the limit")
    assert not out.exists()


# --------------------------------------------------------------------------- one place failing, in process


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_one_line(res, *needles: str) -> str:
    err = res.stderr.strip()
    assert res.exit_code == 2 and len(err.splitlines()) == 1 and err.startswith("error: "), (res.exit_code, err)
    for needle in needles:
        assert needle in err, (needle, err)
    return err


@pytest.mark.parametrize("failure", [MemoryError(), RuntimeError("can't start new thread")])
def test_a_report_that_runs_out_fails_the_run(tmp_path, monkeypatch, failure):
    """Out of memory or threads while the report is made: the run fails (exit 2, nothing written). Before, the
    report's failure became a note and the run exited 0 without report.json (seen at ulimit -v 1000000)."""
    import slamobs.pipeline.evaluation as evaluation

    def runs_out(*_a, **_k):
        raise failure

    monkeypatch.setattr(evaluation, "evaluate_tables", runs_out)
    out = tmp_path / "out"
    err = assert_one_line(invoke("run", SAMPLE, "-o", out, "-q"), f"error: {SAMPLE}: ")
    assert (
        "not enough memory for a run of this log; needs about " in err
        if isinstance(failure, MemoryError)
        else "cannot start a thread for a run of this log" in err
    ), err
    assert not out.exists()


def test_a_thread_that_cannot_start_is_not_a_corrupt_log(tmp_path, monkeypatch):
    """The chunk-reading thread cannot start: before, 'corrupt or truncated MCAP file: can't start new thread'."""
    start = threading.Thread.start

    def refuse(self):
        if self.name == "slamobs-chunk-reader":
            raise RuntimeError("can't start new thread")
        start(self)

    from slamobs.pipeline.readers import storage

    monkeypatch.setattr(threading.Thread, "start", refuse)
    monkeypatch.setattr(storage, "GROUP_BYTES", 4000)  # several groups: a log under one group is read without it
    out = tmp_path / "out"
    err = assert_one_line(
        invoke("run", SAMPLE, "-o", out, "-q"), f"error: {SAMPLE}: cannot start a thread for reading the MCAP file"
    )
    assert "corrupt" not in err and not out.exists()


@pytest.mark.parametrize("failure", [MemoryError(), "zstd"])
def test_a_chunk_that_cannot_be_decompressed_for_lack_of_memory_is_not_damage(monkeypatch, failure):
    """Decompressing a chunk runs out of memory (zstd says 'Allocation error : not enough memory'): the log is not
    corrupt and no chunk is skipped as damaged (before: 'corrupt or truncated MCAP file: MemoryError', or the
    chunk counted as lost and the run went on without it)."""
    import zstandard

    from slamobs.pipeline.readers import chunks, read_log

    def runs_out(*_a, **_k):
        if failure == "zstd":
            raise zstandard.ZstdError("decompression error: Allocation error : not enough memory")
        raise MemoryError

    monkeypatch.setattr(chunks, "_inflate", runs_out)
    with pytest.raises(InputError) as caught:
        read_log(SAMPLE)
    assert isinstance(caught.value, ResourceError), caught.value
    assert str(caught.value).startswith(f"{SAMPLE}: not enough memory for reading the MCAP file"), caught.value


def test_the_figure_helper_out_of_memory_fails_the_run(tmp_path, monkeypatch):
    """The figure helper process (same limit as its run) runs out of memory: it exits with OUT_OF_MEMORY, printing
    nothing, and collecting its figures raises the ResourceError (before: its traceback, then 'the figure helper
    process ended with status 1', which the report turned into a note: a run without its report, exit 0)."""
    import functools

    from slamobs.pipeline.evaluation import plot_worker

    monkeypatch.setattr(
        plot_worker.subprocess,
        "Popen",
        functools.partial(subprocess.Popen, preexec_fn=limited(AS=200 * MB), stderr=subprocess.PIPE),
    )
    workers = plot_worker.PlotWorkers(1)
    try:
        workers.submit([("plot_biases", "biases.png", {})])
        with pytest.raises(ResourceError, match="not enough memory for drawing the report's figures"):
            workers.collect(tmp_path)
        assert workers.jobs and not list(tmp_path.iterdir())
    finally:
        workers.close()


def test_compiling_or_loading_a_kernel_without_room_is_a_memory_error(tmp_path):
    """LLVM out of memory aborts the process ('LLVM ERROR: out of memory', 'std::bad_alloc'); with less than
    native.COMPILE_MB (128 MB) of address space to spare a compilation or a cache load raises MemoryError instead,
    and works again once there is room."""
    code = textwrap.dedent("""\
        import resource
        from slamobs.pipeline import kernel_cache
        from numba import njit

        def size():
            with open("/proc/self/status") as status:
                return next(int(line.split()[1]) for line in status if line.startswith("VmSize:")) * 1024

        @njit
        def add(x):
            return x + 1

        resource.setrlimit(resource.RLIMIT_AS, (size() + 96 * 2**20, resource.RLIM_INFINITY))
        try:
            add(1)
        except MemoryError as err:
            print("MemoryError:", err)
        resource.setrlimit(resource.RLIMIT_AS, (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
        print(add(1))
        """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    first, second = proc.stdout.splitlines()
    assert first.startswith("MemoryError: ") and first.endswith("left to compile a kernel (needs 128 MB)"), first
    assert second == "2"


def test_freed_heap_memory_goes_back_between_stages():
    """``native.return_freed_memory`` (between the estimator and the report) gives freed heap pages back: after
    many freed medium arrays the process's resident size does not grow by calling it, and where glibc is not
    there it is a no-op (False), never an error."""
    import platform

    import numpy as np

    from slamobs.pipeline import native

    def resident_kb() -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4

    kept = [np.ones(200_000) for _ in range(40)]  # 1.6 MB each: above glibc's first mmap threshold
    del kept
    kept = [np.ones(20_000) for _ in range(2000)]  # 160 kB each: from the heap once the threshold has grown
    del kept
    before = resident_kb()
    trimmed = native.return_freed_memory()
    assert isinstance(trimmed, bool)
    if platform.libc_ver()[0] == "glibc":
        assert resident_kb() <= before


def test_returning_freed_memory_starts_no_process(monkeypatch):
    """``native.return_freed_memory`` runs between the estimator and the report, where the run is serial: it finds
    ``malloc_trim`` in the process's own C library, without ``ctypes.util.find_library``'s ``ldconfig -p`` child
    (2-24 ms of a run's wall, docs/benchmarks.md session 31)."""
    import subprocess

    from slamobs.pipeline import native

    started = []

    class Recorded(subprocess.Popen):
        def __init__(self, args, *a, **k):
            started.append(args)
            super().__init__(args, *a, **k)

    monkeypatch.setattr(subprocess, "Popen", Recorded)
    trimmed = native.return_freed_memory()
    assert started == []
    assert isinstance(trimmed, bool)
