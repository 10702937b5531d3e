"""Where the compiled numeric kernels are kept, and when they are stale; kernel modules take ``njit`` from here.

numba caches a ``cache=True`` function under a stamp of its own source file only. But a kernel's compiled code
also holds the code of the functions it calls (numba inlines and links them in) and the constants it reads, and
those often live in other modules: after an edit there (say ``shared_steps.landmark_sums``), numba went on
loading the old kernel. Here a kernel's stamp is a hash of its module's source and of every slamobs module that
module imports, transitively (everything its code can reach), and the hash is part of its cache file names: an
edit anywhere a kernel can reach compiles it again, and no two versions of the sources read each other's files.

Compiled kernels so depend on the sources alone, not on where they are installed, so they are kept once per
user rather than next to each installed copy, and a second install location of the same sources (another
virtual environment, a second checkout) loads what the first one compiled. The directory is
``$NUMBA_CACHE_DIR/slamobs`` when numba's cache directory is set, else the user cache directory
(``~/.cache/slamobs`` on Linux), with one subdirectory per numba version (numba checks its version when it reads
an index and would otherwise overwrite the other version's); where it cannot be written, the ``__pycache__``
next to the sources, numba's own place, with the same stamps. What numba keys an entry by (argument types, the
CPU name and features, the Python version in the file name) keeps kernels for different machines sharing a home
directory apart.

The locator is installed when this module is imported, so every kernel module imports ``njit`` from here: it is
then in place before the first kernel is decorated. ``njit(cache=True)`` here sets a kernel's cache up (its
locator, source stamp and index file) when the kernel is first compiled or loaded, not when it is decorated: a
run imports ~100 kernels and calls ~10, and setting up the others' caches was ~0.06 s of its start.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
import re
import sys
import time
import weakref
from functools import lru_cache, update_wrapper
from pathlib import Path

import numba
from numba.core import caching

from slamobs.pipeline import native
from slamobs.pipeline.cores import cores

__all__ = [
    "KERNEL_ROWS",
    "cache_root",
    "cached",
    "compiled_for",
    "directory_lock",
    "install",
    "njit",
    "prune",
    "source_stamp",
    "subroutine",
    "worth_compiling",
]

#: Cache files not written for this many days are removed when a run has compiled something (kernels of
#: sources that changed, or of other versions; one still in use is compiled again, at most once per period).
MAX_AGE_DAYS = 30

#: The directory of the ``slamobs`` package (``pipeline/`` is in it), installed or a checkout.
PACKAGE_ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "slamobs"

# `from X import a, b` / `from X import (a,\n b)` / `import X, Y`, anywhere in a module (lazy imports included)
_IMPORT = re.compile(
    r"^[ \t]*(?:from[ \t]+([\w.]+)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)|import[ \t]+([\w., \t]+))", re.MULTILINE
)


@lru_cache(maxsize=None)
def _module_file(name: str, root: str, package: str) -> str | None:
    """Source file of module ``name`` of ``package`` rooted at ``root`` (None for other modules)."""
    first, _, rest = name.partition(".")
    if first != package:
        return None
    base = os.path.join(root, *rest.split(".")) if rest else root
    for candidate in (os.path.join(base, "__init__.py"), base + ".py"):
        if os.path.isfile(candidate):
            return candidate
    return None


def _imports(path: str, source: str, root: str, package: str) -> set[str]:
    """Source files of the ``package`` modules that the module at ``path`` imports (submodules named in a
    ``from X import`` list included)."""
    rel = os.path.relpath(path, root)[: -len(".py")].split(os.sep)
    name = ".".join((package, *rel))
    here = name[: -len(".__init__")] if rel[-1] == "__init__" else name.rpartition(".")[0]
    found: set[str] = set()
    for frm, names, plain in _IMPORT.findall(source):
        if frm:
            if frm.startswith("."):
                dots = len(frm) - len(frm.lstrip("."))
                base = here.rsplit(".", dots - 1)[0] if dots > 1 else here
                frm = f"{base}.{frm[dots:]}" if frm[dots:] else base
            targets = [frm, *(f"{frm}.{n.split()[0]}" for n in names.strip("()").split(",") if n.strip())]
        else:
            targets = [n.split()[0] for n in plain.split(",") if n.strip()]
        for target in targets:
            if (file := _module_file(target, root, package)) is not None:
                found.add(file)
    return found


@lru_cache(maxsize=None)
def _read(path: str, root: str, package: str) -> tuple[bytes, frozenset[str]]:
    """A module's source hash and the package modules it imports (each file read once per process)."""
    with open(path, "rb") as f:
        data = f.read()
    return hashlib.sha256(data).digest(), frozenset(_imports(path, data.decode("utf-8"), root, package))


def source_stamp(path: str | Path, root: str | Path = PACKAGE_ROOT, package: str = PACKAGE) -> str:
    """Hash of the module at ``path`` and of every ``package`` module it imports, directly or not."""
    return _stamp(os.path.realpath(path), os.path.realpath(root), package)


def forget_stamps() -> None:
    """Forget the sources read and the stamps computed so far in this process (:func:`source_stamp` reads each
    file once per process): the next stamp reads the files again, as after an edit under a running process."""
    _read.cache_clear()
    _stamp.cache_clear()


@lru_cache(maxsize=None)
def _stamp(path: str, root: str, package: str) -> str:
    seen: set[str] = set()
    todo = [path]
    while todo:
        file = todo.pop()
        if file not in seen:
            seen.add(file)
            todo += _read(file, root, package)[1]
    digest = hashlib.sha256()
    for file in sorted(seen):
        rel = os.path.relpath(file, root).replace(os.sep, "/")
        digest.update(rel.encode() + b"\0" + _read(file, root, package)[0])
    return digest.hexdigest()[:16]


def cache_root() -> Path:
    """The per-user directory of the compiled kernels of this numba version."""
    if numba.config.CACHE_DIR:
        base = Path(numba.config.CACHE_DIR) / PACKAGE
    else:
        try:
            from numba.misc.appdirs import AppDirs

            base = Path(AppDirs(appname=PACKAGE, appauthor=False).user_cache_dir)
        except ImportError:  # pragma: no cover - numba without its vendored appdirs
            base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / PACKAGE
    return base / f"kernels-numba{numba.__version__}"


def cached(module: str, qualname: str) -> bool:
    """Whether function ``qualname`` of package module ``module`` has been compiled for the current sources (for
    any argument types), found without importing the module: its cache index exists."""
    path = Path(importlib.util.find_spec(module).origin).resolve()
    rel = path.relative_to(PACKAGE_ROOT)
    name = f"{path.stem}.{qualname}-*-{source_stamp(path)}.py{sys.version_info[0]}{sys.version_info[1]}*.nbi"
    return any(any(where.glob(name)) for where in (cache_root() / rel.parent, path.parent / "__pycache__"))


#: Arrays at least this long take a compiled kernel where array code gives the same numbers (the report's
#: rotation-angle blocks, products, segment errors, running medians; the readers' string codes); shorter ones the
#: array code: a kernel's first compilation (0.2-1 s) would cost a short log's first run more than it saves (a
#: 3-minute log's 36 000 poses at 200 Hz compile none of them; a long log's blocks are 65 536 rows).
KERNEL_ROWS = 65_536


def compiled_for(n: int, kernel, rows: int = KERNEL_ROWS) -> bool:
    """Whether ``n`` rows take the compiled ``kernel``: from ``rows`` on, and from ``rows // 64`` on once this
    process has the kernel (compiled or loaded: a long log's last block and its shorter pieces, e.g. the RPE's
    pairs, need not take the slower array code; a short log still compiles nothing)."""
    return n >= rows or (n >= rows // 64 and bool(kernel.signatures))


def worth_compiling(kernel, n: int, rows: int) -> bool:
    """Whether work of ``n`` rows (a log's records or messages) takes ``kernel`` rather than its array code (the same
    results, slower): from ``rows`` on, when the kernel is in this process or in the kernel cache already, or when
    the process may run on a second core (a first run's compile helper then compiles the estimator's kernels beside
    it, and later runs load this one from the cache). So on one core a short log's first run does not compile it,
    and a warm run loads it wherever a run has compiled it."""
    if n >= rows or kernel.signatures or cores() >= 2:
        return True
    func = kernel.py_func
    return cached(func.__module__, func.__qualname__)


_WRITABLE: dict[str, bool] = {}


def njit(*args, **kwargs):
    """numba's ``njit``, made cheaper to load from the cache: with ``cache=True`` the kernel's cache is made at its
    first use (:class:`_FirstUseCache`), and a call does not first scan every installed package's metadata for
    numba extensions (``importlib.metadata.entry_points()``, ~0.06 s at a process's first kernel call): numba's
    compiler still loads them before it compiles anything (its CPU context's refresh), and a kernel loaded from
    the cache is compiled code already. Same compiled code, same cache files. Explicit signatures: numba's own.
    No kernel is passed as a first-class function value, so none compiles numba's C-callable wrapper
    (``no_cfunc_wrapper``: ~5 % of the LLVM IR a fast-adaptation run lowers, optimises and caches).

    ``nrt=False``: compiled without numba's runtime, for a kernel that allocates no array (it works in the arrays
    it is given, and makes at most views of them): numba then counts no references to its arrays. Otherwise it
    lowers every use of an array variable with an increment and a decrement of the array's count (which LLVM
    later removes again): the fast-adaptation event loop and its callees are ~25 % less IR to compile without
    them. The functions it calls are compiled the same way when it compiles them first; a kernel that allocates
    does not compile with it (numba's typing error names the allocation).

    Its floating-point flags are its own (``fastmath``, strict unless given), never its caller's: numba lets a kernel
    without them take those of the kernel compiling it first (``inherit_if_not_set``), so a helper of riekf's
    ``fastmath={"contract"}`` kernels fused ``a * b + c`` in a process that compiled it from one of them and not in a
    process that compiled it from elsewhere first (a test, another estimator), and the cache kept whichever came
    first (docs/benchmarks.md, "A cached kernel that gave another answer")."""
    if args and not callable(args[0]):
        return numba.njit(*args, **kwargs)
    cache = kwargs.pop("cache", False)
    kwargs.setdefault("no_cfunc_wrapper", True)
    kwargs.setdefault("fastmath", False)  # its own flags, not those of the first kernel that compiles it
    if not kwargs.pop("nrt", True):
        kwargs["_nrt"] = False

    def decorate(func):
        kernel = numba.njit(**kwargs)(func)
        if cache:
            kernel._cache = _FirstUseCache(func)
        kernel._compilation_chain_init_hook = _no_extensions_yet
        return kernel

    return decorate(args[0]) if args else decorate


def _no_extensions_yet() -> None:
    """A kernel's hook before it types its arguments: nothing (see :func:`njit`)."""


def subroutine(returns, error_model: str = "python", fastmath=False):
    """A helper of the kernels compiled into each kernel that calls it, not as a kernel of its own.

    A helper decorated with :func:`njit` is a kernel like any other when a kernel calls it: numba compiles it on its
    own (optimised machine code, a Python wrapper, a cache file), then links it into the caller, whose library is
    optimised and turned into machine code again as a whole. A subroutine is typed and lowered into the calling
    kernel's own library (once per kernel and argument types), so the machine code is generated once, for the
    kernel. The fast-adaptation event loop with its sub-step and the rotation helpers compiles in ~20 % less CPU,
    to the same arithmetic. Its result type is declared (``returns``, a numba type), not inferred by compiling it;
    it is compiled without numba's runtime, so one that allocates does not compile (it works in the arrays it is
    given). ``error_model``: numba's, as for :func:`njit`.

    ``fastmath``: its own floating-point flags (numba's, e.g. ``{"contract"}``; strict by default), whatever its
    caller's. Every kernel carries its own copy of the subroutine under one symbol name with weak linkage (one
    definition wins where two kernels' copies meet, linked into a third kernel or loaded into one process), so
    every copy must be the same code: compiled with the caller's flags, a copy in a ``fastmath={"contract"}``
    kernel fused ``a * b + c`` where a strict kernel's copy rounded twice, and numba's name for it held a counter
    of the compiling process, so kernels compiled in different processes carried different bodies under one name
    and a process ran whichever it linked first (docs/benchmarks.md, "A cached kernel that gave another
    answer"). Here the name holds a hash of the subroutine's sources (:func:`source_stamp`) and flags instead:
    one name, one body, in every process.

    Called from Python, it runs as an ordinary kernel (:func:`njit`, compiled at the first such call)."""

    def decorate(func):
        return _Subroutine(func, returns, error_model, fastmath)

    return decorate


def _code_stamp(func) -> str:
    """Hash of the source of ``func``'s module and of what it imports (:func:`source_stamp`; a module outside the
    package: its file alone)."""
    path = Path(func.__code__.co_filename).resolve()
    try:
        path.relative_to(PACKAGE_ROOT)
    except ValueError:
        return hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    return source_stamp(path)


class _Subroutine:
    """:func:`subroutine`'s helper: numba types a call of it by its declared result type, and lowers it as a call of
    the function compiled into the caller's library (numba's ``compile_internal`` without code generation, as its
    own internal helpers), with its own flags and a name the same in every process; Python calls go to a kernel
    made on first use."""

    def __init__(self, func, returns, error_model: str, fastmath) -> None:
        from numba.core import types
        from numba.core.cpu_options import FastMathOptions
        from numba.core.imputils import lower_builtin
        from numba.core.typing.templates import AbstractTemplate, infer_global, signature

        self.py_func = func
        self.error_model = error_model
        self.fastmath = FastMathOptions(fastmath)
        self._uid: str | None = None
        self._kernel = None
        #: per library being compiled: argument types -> the function compiled into it
        self._lowered: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        update_wrapper(self, func)

        class Call(AbstractTemplate):
            key = self

            def generic(self, args, kws):
                if not kws:
                    return signature(returns, *(types.unliteral(a) for a in args))

        infer_global(self, types.Function(Call))
        lower_builtin(self, types.VarArg(types.Any))(self._lower)

    def _mangle(self, name, argtypes, *, abi_tags=(), uid=None):
        """numba's symbol name with, in place of its per-process counter, a hash of the sources and the flags
        (the argument types are in the name already)."""
        from numba.core.funcdesc import default_mangler

        if self._uid is None:
            flags = ",".join(sorted(self.fastmath.flags))
            key = f"{self.py_func.__module__}.{self.py_func.__qualname__}|{_code_stamp(self.py_func)}|{flags}"
            self._uid = "s" + hashlib.sha256(f"{key}|{self.error_model}".encode()).hexdigest()[:16]
        return default_mangler(name, argtypes, abi_tags=abi_tags, uid=self._uid)

    def _lower(self, context, builder, sig, args):
        from numba.core import compiler

        library = context.active_code_library
        done = self._lowered.setdefault(library, {})
        if (fndesc := done.get(sig)) is None:
            flags = compiler.Flags()
            flags.error_model = self.error_model
            if self.fastmath:
                flags.fastmath = self.fastmath
            flags.no_compile = flags.no_cpython_wrapper = flags.no_cfunc_wrapper = True
            # without the runtime whatever the caller's (a caller with it would otherwise pass it on), with its own
            # floating-point flags (the caller's context carries the caller's) and name
            own = context.subtarget(enable_nrt=False, fastmath=self.fastmath if self.fastmath else False)
            own.mangler = self._mangle
            own.cached_internal_func = {}  # numba's helpers compiled in it: with its flags too, not shared
            compiled = compiler.compile_internal(
                context.typing_context, own, library, self.py_func, sig.args, sig.return_type, flags, {}
            )
            fndesc = done[sig] = compiled.fndesc
        return context.call_internal(builder, fndesc, sig, args)

    def __call__(self, *args):
        if self._kernel is None:
            kernel = njit(cache=True, error_model=self.error_model, fastmath=self.fastmath if self.fastmath else False)
            self._kernel = kernel(self.py_func)
        return self._kernel(*args)


class _FirstUseCache:
    """Stands in for numba's ``FunctionCache`` of a kernel until something of it is needed (numba asks only when
    it compiles or loads the kernel, under its compiler lock), then makes it and passes everything on to it."""

    def __init__(self, py_func) -> None:
        self._py_func = py_func
        self._cache = None

    def __getattr__(self, name: str):
        if name.startswith("__") or "_py_func" not in self.__dict__:  # copying, pickling: nothing made for them
            raise AttributeError(name)
        if self._cache is None:
            cache = caching.FunctionCache(self._py_func)
            if isinstance(locator := cache._impl.locator, KernelLocator):
                cache._cache_file = _CheckedIndex(cache.cache_path, cache._impl.filename_base, locator._stamp)
            self._cache = cache
        return getattr(self._cache, name)


#: Seconds a process waits for another one's write into a cache directory before it skips its own (the kernel is
#: then compiled again by the next run that needs it); a write takes milliseconds.
LOCK_WAIT_S = 10.0
#: The lock file of a cache directory (numba's files are written there under it).
LOCK_NAME = "slamobs-kernels.lock"


@contextlib.contextmanager
def directory_lock(directory: str | Path, wait_s: float | None = None):
    """Hold the exclusive lock of cache ``directory`` (``flock`` of its :data:`LOCK_NAME`, released by the kernel
    when its holder dies): yields True once held, or where files cannot be locked (a read-only directory, a file
    system without locks: what numba did without it); False when another process has held it for ``wait_s``
    (default :data:`LOCK_WAIT_S`; a stopped holder: the caller skips its write rather than wait without end)."""
    try:
        import fcntl

        fd = os.open(os.path.join(directory, LOCK_NAME), os.O_RDONLY | os.O_CREAT, 0o666)
    except (ImportError, OSError):
        yield True
        return
    try:
        limit = time.monotonic() + (LOCK_WAIT_S if wait_s is None else wait_s)
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                held = True
                break
            except BlockingIOError:
                if time.monotonic() >= limit:
                    held = False
                    break
                time.sleep(0.005)
            except OSError:  # no locks on this file system
                held = None
                break
        yield held is not False
    finally:
        os.close(fd)  # releases the lock


class _CheckedIndex(caching.IndexDataCacheFile):
    """numba's index and data files of one kernel, written by one process at a time, and a data file loaded only when
    it holds the argument types asked for.

    numba saves a new entry by reading the kernel's index, taking the first data-file number it does not list,
    writing the index, then the data file, with no lock: two processes saving two argument types of one kernel at
    once could both take ``.1.nbc``, and the index then named one's compiled code for the other's types. Every
    later run calling it with those types ran the other code (a TypeError, or wrong numbers: the APE's row norms
    ran without the reference subtracted) until the sources changed (docs/benchmarks.md, "The kernel cache written
    by two processes"). Here a save holds the cache directory's :func:`directory_lock` (skipped when another
    process holds it for :data:`LOCK_WAIT_S`), and a data file whose signature is not its key's is a cache miss:
    the kernel is compiled and its file written over, so a cache spoilt before mends itself."""

    def save(self, key, data):
        with directory_lock(self._cache_path) as held:
            if held:
                super().save(key, data)

    def load(self, key):
        data = super().load(key)
        if data is None:
            return None
        signature = data[3] if isinstance(data, tuple) and len(data) > 3 else None
        args = getattr(signature, "args", None)  # a numba whose data files keep no signature there: loaded as before
        return data if args is None or tuple(args) == tuple(key[0]) else None


class KernelLocator(caching._CacheLocator):
    """numba cache locator of the package's kernels: files under :func:`cache_root` laid out like the package,
    stamped and named with :func:`source_stamp` (other functions are left to numba's own locators)."""

    def __init__(self, py_func, path: Path, cache_path: Path) -> None:
        self._lineno = py_func.__code__.co_firstlineno
        self._py_file = str(path)  # numba names it in its warning about a kernel it cannot cache
        self._stamp = source_stamp(path)
        self._cache_path = str(cache_path)

    def get_cache_path(self) -> str:
        return self._cache_path

    def get_source_stamp(self) -> str:
        return self._stamp

    def get_disambiguator(self) -> str:
        return f"{self._lineno}-{self._stamp}"

    @classmethod
    def from_function(cls, py_func, py_file):
        path = Path(py_file).resolve()
        try:
            rel = path.relative_to(PACKAGE_ROOT)
        except ValueError:
            return None
        for where in (cache_root() / rel.parent, path.parent / "__pycache__"):
            self = cls(py_func, path, where)
            if (ok := _WRITABLE.get(self._cache_path)) is None:
                try:
                    self.ensure_cache_path()
                    ok = True
                except OSError:
                    ok = False
                _WRITABLE[self._cache_path] = ok
            if ok:
                return self
        return None


def prune(max_age_days: float = MAX_AGE_DAYS, root: Path | None = None) -> int:
    """Remove the cache files older than ``max_age_days``; returns how many. A kernel whose files go while
    another process uses them is compiled again there (numba treats a missing file as a cache miss). Also the
    temporary files numba writes a cache file in before renaming it into place (``NAME.nbi.tmp.UID``), which a
    process killed while it wrote one (a run ended inside the compiler, its compile helper) leaves behind. Each
    directory is pruned holding its :func:`directory_lock`, so an old file's age and its removal are of one file,
    not of the file another process has just renamed into its place (a directory locked for :data:`LOCK_WAIT_S`
    is left for the next prune)."""
    root = cache_root() if root is None else root
    limit = time.time() - max_age_days * 86400.0
    removed = 0
    directories: dict[Path, list[Path]] = {}
    for file in [*root.rglob("*.nb[ci]"), *root.rglob("*.nb[ci].tmp.*")]:
        directories.setdefault(file.parent, []).append(file)
    for directory, files in directories.items():
        with directory_lock(directory) as held:  # not a file another process has just written in its old one's place
            for file in files if held else ():
                try:
                    if file.stat().st_mtime < limit:
                        file.unlink()
                        removed += 1
                except OSError:  # gone already, or not ours to remove
                    pass
    return removed


def _save_or_skip(save):
    """numba's ``Cache.save_overload`` for our kernels, where a cache file that cannot be written (disk full, a
    file-size or quota limit, a read-only cache) only means compiling again next time: numba raises it, and a
    run reading a good log then failed with the write error (the reader took it for a damaged chunk)."""

    def save_overload(self, sig, data):
        try:
            return save(self, sig, data)
        except OSError:
            if not isinstance(getattr(self._impl, "locator", None), KernelLocator):
                raise

    save_overload.slamobs_skips_unwritable = True
    return save_overload


def _helpers_kept_per_flags(subtarget):
    """numba's ``BaseContext.subtarget`` for the compiling contexts, where numba's own helpers compiled in one (the
    implementations of ``x ** n``, ``arr.sum()``, ``np.empty``, ... that its lowering compiles once per process,
    ``compile_subroutine``) are kept apart per floating-point flags. numba keeps them in one dictionary shared by every
    context of the process, keyed by function and types but not by flags, and compiles one with the flags of the
    context that asks first: a helper first asked for by a riekf ``{"contract"}`` kernel was fused into the strict
    kernels that asked for it later in that process (``ratio**4`` in ``riekf._walk_check``), and one first asked for
    by a strict kernel stayed unfused in the contracting kernels; so a kernel's code depended on what the compiling
    process had compiled before, and the cache kept it (docs/benchmarks.md, "A cached kernel that gave other last
    digits"). Here each flag set has its own dictionary: a helper takes the flags of the kernel it is compiled into."""

    def flags_of(context) -> frozenset:
        return frozenset(context.fastmath.flags) if context.fastmath else frozenset()

    def subtarget_(self, **kws):
        made = subtarget(self, **kws)
        if made.cached_internal_func is self.cached_internal_func and flags_of(made) != flags_of(self):
            shelves = self.__dict__.get("slamobs_helpers_per_flags")
            if shelves is None:  # the first one made from this context; contexts made from it carry the same
                shelves = self.slamobs_helpers_per_flags = {flags_of(self): self.cached_internal_func}
            made.slamobs_helpers_per_flags = shelves
            made.cached_internal_func = shelves.setdefault(flags_of(made), {})
        return made

    subtarget_.slamobs_helpers_per_flags = True
    return subtarget_


def install() -> None:
    """Put :class:`KernelLocator` first among numba's cache locators, let its cache writes fail quietly, and keep
    numba's compiled helpers apart per floating-point flags (:func:`_helpers_kept_per_flags`; once)."""
    from numba.core.base import BaseContext

    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    if KernelLocator not in impl._locator_classes:
        impl._locator_classes = [KernelLocator, *impl._locator_classes]
    if not getattr(caching.Cache.save_overload, "slamobs_skips_unwritable", False):
        caching.Cache.save_overload = _save_or_skip(caching.Cache.save_overload)
    if not getattr(BaseContext.subtarget, "slamobs_helpers_per_flags", False):
        BaseContext.subtarget = _helpers_kept_per_flags(BaseContext.subtarget)


install()
native.start()  # BLAS starts here, on the importing (main) thread, not on a reader's; numba's array functions lazily
