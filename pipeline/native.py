"""Native libraries started up front, on the main thread, while memory is there (before any kernel is loaded).

Under an address-space limit (``ulimit -v``) some native libraries cannot be turned into an error message when
their own allocation fails. OpenBLAS allocates a 32 MB buffer at the first matrix product: NumPy's copy then
prints "OpenBLAS error" and ends the process (exit 1), SciPy's retries for ever with the GIL held (a run spun at
100 % CPU, deaf to SIGTERM). LLVM, compiling a kernel or loading a compiled one, aborts (SIGABRT). Here the BLAS
buffer is taken at once, numba never loads SciPy's BLAS, and a compilation or cache load starts only with room to
spare: a MemoryError otherwise, which the run and the CLI report in one line. The room is checked against the
limit and the process's mapped size (``/proc/self/status``), so without a limit nothing is checked.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager

#: What OpenBLAS's first matrix product maps (its 32 MB buffer and more: NumPy imported, 97 MB, it failed under
#: ``ulimit -v 130000`` and passed under 140000), with some margin.
BLAS_START_MB = 56


#: What importing NumPy maps (84 MB: its libraries) and its OpenBLAS's start-up then takes (up to 43 MB): OpenBLAS
#: ends the process with "OpenBLAS error" when that fails, already inside ``import numpy`` under ``ulimit -v 90000``.
NUMPY_START_MB = 136


def check_numpy_room() -> None:
    """Before NumPy is first imported: raise MemoryError when the limit leaves no room for it to start."""
    if "numpy" not in sys.modules:
        check_room("load NumPy and start its OpenBLAS", NUMPY_START_MB)


def _headroom_mb() -> float | None:
    """Address space left under ``ulimit -v`` (MB), None when unlimited or unknown."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/status") as status:
            size_kb = next(int(line.split()[1]) for line in status if line.startswith("VmSize:"))
    except (ImportError, OSError, StopIteration, ValueError):
        return None
    return (soft / 1024 - size_kb) / 1024


def start_blas() -> None:
    """Take OpenBLAS's buffer now (one tiny product), or raise MemoryError when the limit leaves no room."""
    import numpy as np  # out of memory, its import fails with an ImportError (a library it cannot map)

    check_room("start OpenBLAS", BLAS_START_MB)
    one = np.ones((2, 2))
    one @ one


def load_array_functions_without_blas() -> None:
    """Load numba's array functions (``numba.np.arraymath``) now, in this thread, without SciPy's BLAS.

    numba imports ``scipy.linalg.cython_blas`` (when SciPy is installed) as it loads its array functions, on the
    first kernel compiled or loaded that needs them: in a run, on the thread that reads the log's chunks. That
    started SciPy's OpenBLAS (see above). No kernel here calls BLAS (np.dot, np.linalg), so numba is told there is
    none (it then compiles every kernel as before); a SciPy imported by someone else afterwards loads as usual."""
    with array_functions_without_blas():
        import numba.np.arraymath  # noqa: F401


@contextmanager
def array_functions_without_blas():
    """numba's array functions, where numba imports them inside this block, load as
    :func:`load_array_functions_without_blas` loads them: ``import scipy.linalg`` fails meanwhile (nothing is
    imported here; once they are loaded, or SciPy's ``linalg`` is, nothing changes)."""
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        yield
        return
    sys.modules["scipy.linalg"] = None  # type: ignore[assignment]  # `import scipy.linalg...` raises ImportError
    try:
        yield
    finally:
        if sys.modules.get("scipy.linalg", 0) is None:
            del sys.modules["scipy.linalg"]


#: Address space LLVM may take to compile a kernel or load a compiled one from the cache: out of memory it aborts
#: the process ("LLVM ERROR: out of memory" or "std::bad_alloc", SIGABRT) instead of raising (seen in 2 of 4 runs
#: of the sample log under ``ulimit -v 400000``, where the loads found 100 MB to spare).
COMPILE_MB = 128


class _CompileGuard:
    """A ``numba:compile`` listener: an outermost compilation starts only with :data:`COMPILE_MB` to spare under
    ``ulimit -v``, else it raises MemoryError (numba releases its locks on the way out)."""

    def __init__(self) -> None:
        self.depth = 0

    def on_start(self, _ev) -> None:
        self.depth += 1
        if self.depth == 1:
            try:
                check_room("compile a kernel")
            except MemoryError:
                self.depth -= 1
                raise
            load_array_functions_without_blas()  # numba's compiler loads them (its registries) next

    def on_end(self, _ev) -> None:
        self.depth = max(0, self.depth - 1)


def check_room(what: str, needs_mb: float = COMPILE_MB) -> None:
    """Raise MemoryError when ``ulimit -v`` leaves less than ``needs_mb`` for ``what`` (a native library that
    aborts the process when its own allocation fails: LLVM, OpenBLAS)."""
    room = _headroom_mb()
    if room is not None and room < needs_mb:
        raise MemoryError(f"{room:.0f} MB of address space left to {what} (needs {needs_mb:g} MB)")


def guard_compilation() -> None:
    """Check the room before every numba compilation and cache load in this process (once)."""
    from numba.core import caching, event

    load = caching.Cache.load_overload
    if getattr(load, "_slamobs_guarded", False):
        return

    class Guard(_CompileGuard, event.Listener):
        pass

    event.register("numba:compile", Guard())

    def guarded_load(self, sig, target_context):
        check_room("load a compiled kernel")
        if not hasattr(self, "_load_overload"):  # a numba whose cache is laid out otherwise: its own load
            with array_functions_without_blas():
                return load(self, sig, target_context)
        return load_cached(self, sig, target_context)

    guarded_load._slamobs_guarded = True
    caching.Cache.load_overload = guarded_load


def load_cached(cache, sig, target_context):
    """numba's ``Cache.load_overload`` without its ``target_context.refresh()``: a compiled kernel from the cache
    needs numba's runtime (NRT) started, not numba's typing and lowering registries, whose installation
    (importing and registering every NumPy and Python implementation numba has) is ~0.25 s of CPU at the first
    load of a process, most of the fixed cost of loading a short run's kernels. A cache miss compiles, and
    numba's compiler refreshes the context itself first. The kernel loaded is the same machine code either way."""
    from numba.core.runtime import rtsys

    rtsys.initialize(target_context)
    with cache._guard_against_spurious_io_errors(), array_functions_without_blas():  # a kernel that allocates needs
        return cache._load_overload(sig, target_context)  # them: unpickling it imports them, the others do not


def start() -> None:
    """All of the above: what a process that runs kernels does first (:mod:`.kernel_cache` calls it)."""
    start_blas()
    guard_compilation()  # numba's array functions (~0.06 s) are loaded when a kernel compiled or loaded needs them


def return_freed_memory() -> bool:
    """Give the C heap's free pages back to the system (glibc's ``malloc_trim``; elsewhere nothing, False).
    Arrays freed by a stage stay in the heap for reuse once glibc has raised its mmap threshold, so the next
    stage's arrays land beside them and the peak counts both: returned between batch's smoother and its report,
    the one-hour run's sampled peak went from 1089-1135 to ~1000 MB. A few milliseconds."""
    import ctypes

    try:  # the C library this process runs on (as cli/main.py and lifetime.py find it): ``ctypes.util.find_library``
        trim = ctypes.CDLL(None).malloc_trim  # ran ``ldconfig -p`` in a child process, ~10 ms of the hour's serial wall
    except (OSError, AttributeError):
        return False
    return bool(trim(0))
