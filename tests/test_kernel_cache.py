"""The compiled-kernel cache: stamps that cover every module a kernel can reach, one place per user."""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path

from slamobs.pipeline import kernel_cache
from slamobs.pipeline.kernel_cache import KernelLocator, cache_root, prune, source_stamp


def write(root: Path, rel: str, text: str) -> Path:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_stamp_covers_the_modules_imported_directly_or_not(tmp_path):
    write(tmp_path, "__init__.py", "")
    a = write(tmp_path, "a.py", "from pkg.b import f\nfrom . import c\n\ndef k():\n    return f() + c.X\n")
    b = write(tmp_path, "b.py", "from .sub.d import (\n    g,\n)\n\ndef f():\n    return g()\n")
    write(tmp_path, "c.py", "X = 1\n")
    write(tmp_path, "sub/__init__.py", "")
    d = write(tmp_path, "sub/d.py", "def g():\n    return 2\n")
    e = write(tmp_path, "e.py", "import pkg.a\n")

    def stamps():
        kernel_cache.forget_stamps()
        return {p.name: source_stamp(p, tmp_path, "pkg") for p in (a, b, d, e)}

    before = stamps()
    d.write_text("def g():\n    return 3\n")  # two imports away from a
    after = stamps()
    assert after["a.py"] != before["a.py"] and after["b.py"] != before["b.py"] and after["d.py"] != before["d.py"]
    write(tmp_path, "c.py", "X = 5\n")  # a constant read through `from . import c`
    again = stamps()
    assert again["a.py"] != after["a.py"] and again["b.py"] == after["b.py"]
    e.write_text("import pkg.a  # imports a, a does not import it\n")
    assert stamps()["a.py"] == again["a.py"]


def test_a_kernel_is_stale_when_a_function_it_calls_from_another_module_changes(tmp_path):
    """The regression: fast_adaptation's cached kernels kept shared_steps.landmark_sums' old code."""
    root = tmp_path / "slamobs"
    shutil.copytree(
        kernel_cache.PACKAGE_ROOT / "pipeline", root / "pipeline", ignore=shutil.ignore_patterns("__pycache__")
    )
    shutil.copy(kernel_cache.PACKAGE_ROOT / "__init__.py", root / "__init__.py")
    kernel = root / "pipeline" / "observers" / "fast_adaptation.py"
    before = source_stamp(kernel, root)
    shared = root / "pipeline" / "observers" / "shared_steps.py"
    text = shared.read_text()
    assert "step = hkp\n" in text
    shared.write_text(text.replace("step = hkp\n", "step = 0.5 * hkp\n"))
    kernel_cache.forget_stamps()
    assert source_stamp(kernel, root) != before


def test_package_kernels_are_cached_by_content_not_by_location():
    from slamobs.pipeline.observers import fast_adaptation

    locator = fast_adaptation.innovation_norms._cache._impl.locator
    assert isinstance(locator, KernelLocator)
    stamp = source_stamp(fast_adaptation.__file__)
    assert locator.get_source_stamp() == stamp and locator.get_disambiguator().endswith(f"-{stamp}")
    # under the per-user root, laid out like the package: nothing of the install location in the path
    assert Path(locator.get_cache_path()) in (
        cache_root() / "pipeline" / "observers",
        Path(fast_adaptation.__file__).parent / "__pycache__",
    )
    assert str(kernel_cache.PACKAGE_ROOT) not in str(cache_root())


def test_prune_removes_only_old_cache_files(tmp_path):
    old = write(tmp_path, "pipeline/lie.f-1-aa.py311.nbi", "")
    old_data = write(tmp_path, "pipeline/lie.f-1-aa.py311.1.nbc", "")
    new = write(tmp_path, "pipeline/lie.f-1-bb.py311.nbi", "")
    other = write(tmp_path, "notes.txt", "")
    # what a process killed while numba wrote a cache file leaves: its temporary, never read
    torn = write(tmp_path, "pipeline/lie.f-1-aa.py311.1.nbc.tmp.0123456789abcdef", "")
    fresh_torn = write(tmp_path, "pipeline/lie.f-1-bb.py311.nbi.tmp.0123456789abcdef", "")
    month = time.time() - 31 * 86400
    for path in (old, old_data, other, torn):
        os.utime(path, (month, month))
    assert prune(30, tmp_path) == 3
    assert not old.exists() and not old_data.exists() and not torn.exists()
    assert new.exists() and other.exists() and fresh_torn.exists()  # a process may be writing it


def test_kernel_modules_take_njit_from_kernel_cache():
    """A kernel decorated with numba's own njit could be decorated before the locator is installed."""
    pattern = re.compile(r"^\s*from numba import .*\bnjit\b|\bnumba\.n?jit\b", re.MULTILINE)
    offenders = [
        p.relative_to(kernel_cache.PACKAGE_ROOT).as_posix()
        for p in sorted((kernel_cache.PACKAGE_ROOT / "pipeline").rglob("*.py"))
        if p.name != "kernel_cache.py" and pattern.search(p.read_text())
    ]
    assert offenders == [], "import njit from slamobs.pipeline.kernel_cache"
    assert (
        "from slamobs.pipeline.kernel_cache import njit"
        in (kernel_cache.PACKAGE_ROOT / "pipeline" / "lie.py").read_text()
    )


def test_a_kernel_numba_cannot_cache_is_a_warning_naming_its_file():
    """numba warns about a kernel it cannot cache (one holding a large global array, or compiled at
    ``NUMBA_OPT=0``) at its locator's ``_py_file``: without it the run stopped with an AttributeError, which the
    reader reported as a damaged log."""
    import types
    import warnings

    from numba.core.errors import NumbaWarning

    from slamobs.pipeline.observers import fast_adaptation

    impl = fast_adaptation.innovation_norms._cache._impl
    cres = types.SimpleNamespace(
        lifted=(),
        library=types.SimpleNamespace(has_dynamic_globals=True),
        fndesc=types.SimpleNamespace(qualname="innovation_norms"),
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert impl.check_cachable(cres) is False
    assert [w.category for w in caught] == [NumbaWarning]
    assert Path(caught[0].filename) == Path(fast_adaptation.__file__).resolve()


def test_a_cached_kernel_loads_without_numbas_registries():
    """A kernel from the cache is loaded without numba's ``refresh()`` (its typing and lowering registries,
    ~0.25 s of CPU at a short run's first load) and without the scan for numba extensions (~0.06 s): in a fresh
    process the cached kernel gives the right result, the modules only that refresh imports (numba's NumPy
    polynomial and random implementations, its array functions) stay unloaded and no extension was looked for; a
    kernel compiled
    afterwards in the same process still compiles, its extensions loaded first (numba's compiler refreshes)."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""\
        import math, sys
        import numpy as np
        import slamobs.pipeline.kernel_cache as kc
        from slamobs.pipeline import lie
        a = 0.7
        r = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
        q = lie.rot_to_quat(r)
        assert np.allclose(q, [0.0, 0.0, math.sin(a / 2), math.cos(a / 2)]), q
        print(lie.rot_to_quat.stats.cache_hits.get(lie.rot_to_quat.signatures[0], 0))
        print(sum(m in sys.modules for m in ("numba.np.polynomial.polynomial_core", "numba.np.random.legacy")))
        print(int("numba.np.arraymath" in sys.modules))
        from numba.core import entrypoints
        print(int(entrypoints._already_initialized))
        print(kc.njit(lambda x: x + 1)(41))
        print(int(entrypoints._already_initialized))
        """)
    first = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr[-2000:]  # compiled here if it was not cached yet
    again = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-2000:]
    hits, registries, array_functions, extensions_before, compiled, extensions_after = again.stdout.split()
    assert int(hits) == 1 and registries == "0" and compiled == "42"
    # nor numba's array functions (~0.06 s to import): no cached kernel of a run refers to them
    assert array_functions == "0"
    # numba's extensions (entry points) are not looked for to load a kernel, and are before compiling one
    assert extensions_before == "0" and extensions_after == "1"


def test_a_kernel_without_the_runtime_counts_no_references_and_computes_the_same():
    """``nrt=False`` (kernels that allocate nothing): no reference counting lowered, no C-callable wrapper, same
    results as numba's default; a kernel that allocates needs the runtime."""
    import numba
    import numpy as np
    import pytest

    def scale_into(a, out):
        for i in range(a.shape[0]):
            out[i] = 2.0 * a[i] + a[i] * a[i]

    lean = kernel_cache.njit(nrt=False)(scale_into)
    default = numba.njit(scale_into)
    a = np.linspace(-1.0, 1.0, 7)
    out_lean, out_default = np.empty(7), np.empty(7)
    lean(a, out_lean)
    default(a, out_default)
    assert out_lean.tobytes() == out_default.tobytes()
    (sig,) = lean.signatures
    assert "NRT_decref" not in lean.inspect_llvm(sig) and "NRT_decref" in default.inspect_llvm(sig)
    assert "cfunc." not in lean.inspect_llvm(sig)

    def allocates(n):
        x = np.empty(n)
        x[0] = 1.0
        return x[0]

    with pytest.raises(numba.core.errors.TypingError, match="empty"):
        kernel_cache.njit(nrt=False)(allocates)(3)
    # a helper it calls is compiled the same way: one that allocates is refused too, one that does not runs the
    # same from a caller with the runtime afterwards
    helper = kernel_cache.njit(allocates)
    with pytest.raises(numba.core.errors.TypingError):
        kernel_cache.njit(nrt=False)(lambda n: helper(n))(3)

    def first(a):
        return a[0] * 2.0

    plain = kernel_cache.njit(first)
    assert kernel_cache.njit(nrt=False)(lambda a: plain(a))(a) == 2.0 * a[0]

    def allocating_caller(n):
        x = np.full(n, 3.0)
        return plain(x)

    assert kernel_cache.njit(allocating_caller)(4) == 6.0


def test_a_subroutine_compiles_only_inside_its_callers():
    """``subroutine``: a kernel's helper is typed and lowered inside the kernel that calls it, with no compilation of
    its own (numba compiled an ``njit`` helper as a kernel first: its own machine code, Python wrapper and cache
    file), and computes the same; its error model is its own; called from Python it is an ordinary kernel; one that
    allocates does not compile."""
    import numba
    import numpy as np
    import pytest
    from numba import types

    from slamobs.pipeline.compile_clock import compiled_functions

    def weigh(a, w):
        return a / w, a * w

    def weigh_all(a, w, out):
        for i in range(a.shape[0]):
            out[i, 0], out[i, 1] = helper(a[i], w)

    helper = kernel_cache.subroutine(types.UniTuple(types.float64, 2))(weigh)
    kernel = kernel_cache.njit(nrt=False)(weigh_all)
    a, out = np.linspace(-1.0, 1.0, 5), np.empty((5, 2))
    before = len(compiled_functions())
    kernel(a, 3.0, out)
    assert [c.function.rsplit(".", 1)[-1] for c in compiled_functions()[before:]] == ["weigh_all"]
    expected = np.empty((5, 2))
    reference = numba.njit(weigh)
    for i in range(5):
        expected[i] = reference(a[i], 3.0)
    assert out.tobytes() == expected.tobytes()
    assert helper(a[1], 3.0) == reference(a[1], 3.0)  # from Python

    def twice(a, w):  # a second kernel calling it (twice): compiled into that one's code too
        return helper(a, w)[0] + helper(a, 2.0 * w)[1]

    assert kernel_cache.njit(nrt=False)(twice)(a[1], 3.0) == reference(a[1], 3.0)[0] + reference(a[1], 6.0)[1]
    with pytest.raises(ZeroDivisionError):
        kernel(a, 0.0, out)  # numba's default error model: Python's

    def weigh_again(a, w):  # another function: numba keeps one compilation per function and types
        return a / w, a * w

    lenient = kernel_cache.subroutine(types.UniTuple(types.float64, 2), error_model="numpy")(weigh_again)

    def weigh_lenient(a, w, out):
        for i in range(a.shape[0]):
            out[i, 0], out[i, 1] = lenient(a[i], w)

    kernel_cache.njit(nrt=False)(weigh_lenient)(a, 0.0, out)
    assert np.isinf(out[0, 0]) and np.isnan(out[2, 0])  # -1/0, 0/0

    def allocates(n):
        x = np.empty(n)
        x[0] = 1.0
        return x[0]

    grows = kernel_cache.subroutine(types.float64)(allocates)
    with pytest.raises(numba.core.errors.NumbaError):
        kernel_cache.njit(lambda n: grows(n))(3)


_HORNER = """\
import numpy as np
from numba import types
from slamobs.pipeline.kernel_cache import njit, subroutine


def horner(c, x):  # a * b + c chains: one rounding each when contracted (fused multiply-add), two when strict
    s = 0.0
    t = 0.0
{loops}
    return s * t + s


plain = subroutine(types.float64)(horner)
fused = subroutine(types.float64, fastmath={{"contract"}})(horner)


@njit(cache=True, fastmath={{"contract"}})
def contracting(c, xs):
    out = 0.0
    for x in xs:
        out += plain(c, x)
    return out


@njit(cache=True)
def strict(c, xs):
    out = 0.0
    for x in xs:
        out += plain(c, x)
    return out


@njit(cache=True)
def both(c, xs):  # links the two kernels' code, each with its copy of the subroutine
    return contracting(c, xs), strict(c, xs)


@njit(cache=True)
def strict_fused(c, xs):
    out = 0.0
    for x in xs:
        out += fused(c, x)
    return out
"""


def test_a_subroutine_is_one_body_under_one_name_in_every_process(tmp_path):
    """A subroutine is compiled with its own floating-point flags, not its caller's, under a name that does not
    depend on the compiling process: two kernels calling it, one ``fastmath={"contract"}`` and one strict, compiled
    in two processes into one cache and linked in a third (a kernel calling both), give the same bits as each
    alone, and the same as each other. Before, each copy took its caller's flags and numba's per-process counter
    into its name: both copies had one (weak) name and the third process ran the strict body for both kernels
    (the contracting kernel alone gave other bits). A subroutine declared ``{"contract"}`` fuses in a strict
    kernel."""
    import subprocess
    import sys

    # big enough that the callers keep calling it rather than inline it (a call resolved by its name)
    loops = "".join(
        f"    for k in range(c.shape[0]):\n        s = s * x + c[k] * {1 + r * 0.01}\n"
        f"        t = t * (x + {0.1 * r}) + c[k] * s\n"
        for r in range(12)
    )
    (tmp_path / "horner_kernels.py").write_text(_HORNER.format(loops=loops))
    code = (
        "import sys\nimport numpy as np\nsys.path.insert(0, sys.argv[1])\nimport horner_kernels as m\n"
        "rng = np.random.default_rng(1)\nc, xs = rng.normal(size=17) * 0.3, rng.normal(size=1000) * 0.5\n"
        "for name in sys.argv[2].split(','):\n"
        "    r = getattr(m, name)(c, xs)\n"
        "    print(name, *(float(v).hex() for v in np.atleast_1d(r)))\n"
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def run(names: str) -> dict[str, list[str]]:
        done = subprocess.run(
            [sys.executable, "-c", code, str(tmp_path), names], capture_output=True, text=True, timeout=600, env=env
        )
        assert done.returncode == 0, done.stderr[-2000:]
        return {line.split()[0]: line.split()[1:] for line in done.stdout.splitlines()}

    alone = {**run("contracting"), **run("strict")}  # each compiled in a process of its own
    linked = run("both,contracting,strict,strict_fused")  # both loaded from the cache, linked into a third
    assert linked["both"] == alone["contracting"] + alone["strict"]
    assert linked["contracting"] == alone["contracting"] and linked["strict"] == alone["strict"]
    assert alone["contracting"] == alone["strict"]  # the subroutine's flags, not the caller's
    assert linked["strict_fused"] != alone["strict"]  # its own {"contract"}, in a strict caller


def test_a_kernel_keeps_its_own_floating_point_flags_whoever_compiles_it_first():
    """numba compiles a kernel without ``fastmath`` of its own with the flags of the kernel that compiles it first
    (``inherit_if_not_set``): a strict helper first compiled from a ``{"contract"}`` kernel fused its ``a * b + c``,
    first compiled from Python or a strict kernel it did not, and the cache kept whichever came first. Here it is
    strict either way, and a helper declared ``{"contract"}`` fuses whoever calls it."""
    import numpy as np

    def madd(a, b, c):
        return a * b + c

    def twice_of(helper, fastmath):
        return kernel_cache.njit(fastmath=fastmath)(lambda a, b, c: 2.0 * helper(a, b, c))

    x = (0.1, 10.0 / 3.0, -1.0 / 3.0)
    strict = kernel_cache.njit(madd)
    twice_of(strict, {"contract"})(*x)  # compiled first from a contracting kernel
    (sig,) = strict.signatures
    assert " contract " not in strict.inspect_llvm(sig)
    assert strict(*x) == np.float64(0.1) * np.float64(10.0 / 3.0) + np.float64(-1.0 / 3.0)
    fused = kernel_cache.njit(fastmath={"contract"})(madd)
    twice_of(fused, False)(*x)  # compiled first from a strict kernel
    assert " contract " in fused.inspect_llvm(fused.signatures[0])


# Two kernels of one expression, one fused and one strict, compiled in the order given (numba compiles the helper
# implementing `x ** 4` once per process, for the first kernel that asks); each kernel's LLVM's `contract` flags.
_POWER_ORDER = """\
import sys
from slamobs.pipeline import kernel_cache

def power(x):
    return x**4 + 1.0

fused = kernel_cache.njit(fastmath={"contract"})(power)
strict = kernel_cache.njit(power)
for kernel in (fused, strict) if sys.argv[1] == "fused" else (strict, fused):
    kernel(1.1)
print(*(k.inspect_llvm(k.signatures[0]).count(" contract ") for k in (fused, strict)))
"""


def test_numbas_helpers_take_the_flags_of_the_kernel_they_are_compiled_into_in_either_order(tmp_path):
    """numba compiles its own helpers (here the one of ``x ** 4``) once per process, with the flags of the kernel
    that asks first, and gave the same to every later kernel: compiled after a ``{"contract"}`` kernel, a strict
    kernel carried fused multiplications (riekf's ``_walk_check`` and three more in a fresh run's ``_advance``, none
    after another estimator's strict kernels had asked first, the cache keeping either). Now each kernel's helpers
    have its flags, in either order."""
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    counts = {}
    for first in ("fused", "strict"):
        done = subprocess.run(
            [sys.executable, "-c", _POWER_ORDER, first], capture_output=True, text=True, timeout=600, env=env
        )
        assert done.returncode == 0, done.stderr[-2000:]
        counts[first] = tuple(int(n) for n in done.stdout.split())
    assert counts["fused"] == counts["strict"], counts  # (fused, strict) contract flags, whichever came first
    assert counts["fused"][1] == 0 and counts["fused"][0] > 1, counts


def _index_entries(cache: Path, kernel: str) -> dict[tuple, tuple]:
    """``{argument types of an index entry: argument types of the code in its data file}`` of ``kernel``'s index
    files under ``cache``."""
    import pickle

    found = {}
    for index in cache.rglob(f"{kernel}-*.nbi"):
        with open(index, "rb") as f:
            pickle.load(f)  # numba's version
            _, overloads = pickle.loads(f.read())
        for key, name in overloads.items():
            found[tuple(key[0])] = tuple(pickle.loads((index.parent / name).read_bytes())[3].args)
    return found


# A process compiling metrics.row_norms_into for one of its two argument types (`minus` an array, A; None, B), its save
# held until the other process saves too, then numba's writes interleaved as two processes' can be: the first's
# index, the other's index and data, the first's data.
_RACING_SAVE = r"""
import sys, time
from pathlib import Path
import numpy as np
from numba.core import caching
from slamobs.pipeline.evaluation import metrics

role, first, sync = sys.argv[1], sys.argv[2], Path(sys.argv[3])
save, save_index, save_data = (
    caching.Cache._save_overload, caching.IndexDataCacheFile._save_index, caching.IndexDataCacheFile._save_data
)

def meet(self, sig, data):
    (sync / role).touch()
    limit = time.monotonic() + 120
    while not (sync / ("B" if role == "A" else "A")).exists() and time.monotonic() < limit:
        time.sleep(0.01)
    save(self, sig, data)

def slow_index(self, overloads):
    time.sleep(0.3 if role == first else 0.6)
    save_index(self, overloads)

def slow_data(self, name, data):
    time.sleep(1.2 if role == first else 0)
    save_data(self, name, data)

caching.Cache._save_overload = meet
caching.IndexDataCacheFile._save_index, caching.IndexDataCacheFile._save_data = slow_index, slow_data
x = np.ones((4, 3))
metrics.row_norms_into(x, x * 0.5 if role == "A" else None, np.empty(4))
"""


def test_two_processes_saving_two_argument_types_of_a_kernel_keep_both(tmp_path, monkeypatch):
    """numba saves a kernel's new cache entry by reading its index, taking the first data-file number the index
    does not list, then writing the index and the data file, with no lock. Two processes (a batch's workers) saving
    two argument types of one kernel at once both took ``.1.nbc``: the index kept one entry and named the other
    process's code for it, and every later run calling the kernel with those types ran the wrong code (here: the
    row norms without ``minus`` subtracted). With the cache directory's lock, the second save reads the first's
    index: two entries, each naming its own code, and a later process loads both and computes right."""
    import subprocess
    import sys

    import numba
    import numpy as np

    from slamobs.pipeline.evaluation import metrics

    cache, sync = tmp_path / "cache", tmp_path / "sync"
    sync.mkdir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    racing = [
        subprocess.Popen([sys.executable, "-c", _RACING_SAVE, role, "A", str(sync)], env=env, stderr=subprocess.PIPE)
        for role in "AB"
    ]
    for proc in racing:
        assert proc.wait(timeout=300) == 0, proc.stderr.read()[-2000:]
        proc.stderr.close()
    entries = _index_entries(cache, "metrics.row_norms_into")
    assert len(entries) == 2 and all(key == code for key, code in entries.items()), entries

    monkeypatch.setattr(numba.config, "CACHE_DIR", str(cache))
    later = kernel_cache.njit(cache=True, nogil=True)(metrics.row_norms_into.py_func)  # a later run's kernel
    x, minus, out = np.arange(12.0).reshape(4, 3), np.ones((4, 3)), np.empty(4)
    later(x, minus, out)
    np.testing.assert_allclose(out, np.linalg.norm(x - minus, axis=1))
    later(x, None, out)
    np.testing.assert_allclose(out, np.linalg.norm(x, axis=1))
    assert sum(later.stats.cache_hits.values()) == 2 and not later.stats.cache_misses


def test_a_cache_entry_naming_another_signatures_code_is_compiled_again(tmp_path, monkeypatch):
    """A cache spoilt before (an index entry naming a data file that holds another argument types' code, what the
    race above left) is a cache miss: the kernel is compiled again, right, and its data file written over. numba
    itself loads the file without looking and runs the other code: a TypeError, or wrong numbers."""
    import pickle

    import numba
    import numpy as np

    from slamobs.pipeline.evaluation import metrics

    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    x, minus, out = np.arange(12.0).reshape(4, 3), np.ones((4, 3)), np.empty(4)
    first = kernel_cache.njit(cache=True, nogil=True)(metrics.row_norms_into.py_func)
    first(x, minus, out)
    first(x, None, out)
    (index,) = tmp_path.rglob("metrics.row_norms_into-*.nbi")
    with open(index, "rb") as f:
        version = pickle.load(f)
        stamp, overloads = pickle.loads(f.read())
    keys = list(overloads)
    swapped = {keys[0]: overloads[keys[1]], keys[1]: overloads[keys[0]]}
    with open(index, "wb") as f:
        pickle.dump(version, f, protocol=-1)
        f.write(pickle.dumps((stamp, swapped), protocol=-1))
    assert all(key != code for key, code in _index_entries(tmp_path, "metrics.row_norms_into").items())

    later = kernel_cache.njit(cache=True, nogil=True)(metrics.row_norms_into.py_func)
    later(x, minus, out)
    np.testing.assert_allclose(out, np.linalg.norm(x - minus, axis=1))
    later(x, None, out)
    np.testing.assert_allclose(out, np.linalg.norm(x, axis=1))
    assert sum(later.stats.cache_misses.values()) == 2
    assert all(key == code for key, code in _index_entries(tmp_path, "metrics.row_norms_into").items())


_HOLD_LOCK = (
    "import fcntl, os, sys, time\n"
    "fd = os.open(sys.argv[1], os.O_RDONLY | os.O_CREAT, 0o666)\nfcntl.flock(fd, fcntl.LOCK_EX)\n"
    "print('held', flush=True)\ntime.sleep(600)\n"
)


def test_a_cache_directory_lock_is_waited_for_boundedly_and_freed_by_its_holders_death(tmp_path, monkeypatch):
    """A process holding a cache directory's lock makes a writer wait at most ``wait_s``, then skip its write
    (False), and prune leave that directory alone; the kernel releases a killed holder's lock: the next writer
    takes it at once."""
    import subprocess
    import sys

    old = write(tmp_path, "pipeline/lie.f-1-aa.py311.nbi", "")
    month = time.time() - 31 * 86400
    os.utime(old, (month, month))
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLD_LOCK, str(old.parent / kernel_cache.LOCK_NAME)], stdout=subprocess.PIPE
    )
    try:
        assert holder.stdout.readline() == b"held\n"
        with kernel_cache.directory_lock(old.parent, wait_s=0.2) as held:
            assert held is False
        monkeypatch.setattr(kernel_cache, "LOCK_WAIT_S", 0.2)
        assert prune(30, tmp_path) == 0 and old.exists()
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    with kernel_cache.directory_lock(old.parent, wait_s=60) as held:
        assert held is True
    assert prune(30, tmp_path) == 1 and not old.exists()
