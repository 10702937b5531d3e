"""The errors slamobs raises on purpose, in one hierarchy: a root and one kind per cause.

``SlamobsError`` is the root; every exception class of the project derives from exactly one kind:

- :class:`BadInput`: the log, a file it names or a value derived from them cannot be used (:class:`InputError`
  and the readers' own errors before they become one);
- :class:`BadConfig`: an option, observer, gain or setting is unknown or out of range, or needs what is not
  installed;
- :class:`BadOutput`: the output cannot or must not be written (:class:`OutputError`);
- :class:`ResourceFailure`: the machine, not the input, stopped the work (:class:`ResourceError`); its
  :class:`InfrastructureFailure` is the machinery of a batch or tune (scheduler, workers, their environment);
- :class:`Interruption`: Ctrl-C, SIGTERM or SIGHUP, a ``KeyboardInterrupt`` so every ``finally`` runs.

The root derives from ``BaseException`` only so the interruption kind can stay out of ``except Exception``;
every other kind is an ``Exception`` too. The CLI's boundary (``cli/errors.py``) maps kinds to exit codes in
one table. The concrete classes keep their old bases as well (``GainError`` is a ``ValueError``), so code that
caught them by those still does; ``OutputError`` (and with it ``ResourceError``) still derives from
``InputError``, so every ``except InputError`` written before the kinds existed catches what it caught. A
class's kind is the first kind in its MRO (:func:`kind_of`).
"""

from __future__ import annotations

import errno


class SlamobsError(BaseException):
    """Root of every error slamobs raises on purpose; catch a kind below, or this for all of them."""


class BadInput(SlamobsError, Exception):
    """Kind: bad input (a log, a file it names, what is decoded from them)."""


class BadConfig(SlamobsError, Exception):
    """Kind: a bad option or config value, or an option that needs what is not installed."""


class BadOutput(SlamobsError, Exception):
    """Kind: the output cannot or must not be written."""


class ResourceFailure(SlamobsError, Exception):
    """Kind: the machine ran out of something (memory, threads, file descriptors, disk space)."""


class InfrastructureFailure(ResourceFailure):
    """Kind: the machinery running a batch or tune failed (scheduler lost, no usable workers, their
    environment differs)."""


class Interruption(SlamobsError, KeyboardInterrupt):
    """Kind: Ctrl-C, SIGTERM or SIGHUP; ``signum`` says which."""

    signum: int


#: The kinds (an error's kind is the first of these in its class's MRO).
KINDS: tuple[type[SlamobsError], ...] = (
    BadInput,
    BadConfig,
    BadOutput,
    ResourceFailure,
    InfrastructureFailure,
    Interruption,
)


class Unwind(Exception):
    """Not an error, and no kind: a private signal that unwinds a loop to the method of the same module that
    catches it (riekf's filter stopped once its time offset is known to move the stamps; a new tune that kept no
    trial, whose failure is raised once its files are gone); it never reaches the CLI's boundary."""


def kind_of(err: BaseException) -> type[SlamobsError] | None:
    """The kind of ``err`` (the first kind in its class's MRO), None for an error that is not slamobs'."""
    for cls in type(err).__mro__:
        if cls in KINDS:
            return cls
    return None


class InputError(BadInput):
    """Bad input: names the file, the topic (if any) and the problem in one line."""

    def __init__(self, path: object, problem: str, topic: str | None = None, *, details: tuple[str, ...] = ()) -> None:
        self.path = str(path)
        self.topic = topic
        self.problem = problem
        #: Lines a terminal shows below the one line (one per item of a list the problem counts); not in str().
        self.details = tuple(details)
        where = f"{self.path}" + (f" [{topic}]" if topic else "")
        super().__init__(f"{where}: {problem}")


class OutputError(BadOutput, InputError):
    """The output cannot or must not be written (disk full, read-only or forbidden place, an ``-o`` that would
    replace an input): one line naming the output path. Also an InputError, so every caller that turns input
    errors into one line handles it too."""


class TruthUnusable(InputError, ValueError):
    """A ground truth that names something but holds too little to judge a run by: no poses (every one NaN), or
    pose pairs covering too little of the run. ``run`` then reports without it (a note, exit 0), and ``report`` on a
    run's own truth does the same; a ValueError too, as the report's other failures are."""


class GainError(BadConfig, ValueError):
    """A gain or observer option is unknown, missing, not a number, or outside its admissible range."""


class ResourceError(ResourceFailure, OutputError):
    """The machine, not the input, stopped the work: out of memory, threads, file descriptors or disk space.

    One line naming the file being read or written and what ran out. A batch reports it as a failure of the
    machine and does not record it, so the next batch runs the log again: never a bad log that
    ``--skip-failed`` would skip.
    """


#: OS errors that say the machine refused or ran out (disk or quota full, a file size limit: ``ulimit -f`` or the
#: file system's largest file, read-only file system, permission, memory, file descriptors), whatever file the
#: work was on.
RESOURCE_ERRNOS = frozenset(
    {
        errno.ENOSPC,
        errno.EDQUOT,
        errno.EFBIG,
        errno.EROFS,
        errno.EACCES,
        errno.EPERM,
        errno.ENOMEM,
        errno.EMFILE,
        errno.ENFILE,
    }
)


def output_error(path: object, err: OSError, doing: str = "cannot write the output", then: str = "") -> OutputError:
    """An OS error while writing ``path`` as one line naming it: a :class:`ResourceError` when the machine ran out
    of something or refused (a full disk said only "No space left on device", without the file), else an
    :class:`OutputError`; the file it concerns is added when that is not ``path`` itself, ``then`` (what is kept,
    what to do) after the reason."""
    text = err.strerror or one_line(err) or type(err).__name__
    if err.filename and str(err.filename) != str(path):
        text = f"{text} ({err.filename})"
    kind = ResourceError if err.errno in RESOURCE_ERRNOS else OutputError
    return kind(path, f"{doing}: {text}{then}")


def is_resource_failure(err: BaseException) -> bool:
    """The machine, not the input, stopped the work: a ResourceError, a MemoryError or a resource OS error."""
    return isinstance(err, (ResourceError, MemoryError)) or (isinstance(err, OSError) and err.errno in RESOURCE_ERRNOS)


def one_line(text: object) -> str:
    """Any text (an exception's too) on one line: every run of whitespace, newlines included, becomes one space."""
    return " ".join(str(text).split())


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``1 log``, ``3 logs``, ``0 logs``: a count in a message (``nouns``: the plural when it is not ``noun`` + s,
    ``1 process``, ``2 processes``); the one helper of the readers' warnings and the commands' output."""
    return f"{n} {noun if n == 1 else nouns or noun + 's'}"


#: Texts of exceptions that are a failure of the machine without saying so by their type: a shared library that
#: could not be mapped (an ImportError or OSError), a decompressor's or allocator's own out-of-memory error.
_MEMORY_TEXTS = (
    "failed to map segment",
    "cannot allocate memory",
    "allocation error",
    "not enough memory",
    "out of memory",
    "memory allocation failed",
)
_THREAD_TEXTS = ("can't start new thread", "cannot start new thread")


def machine_failure(err: BaseException) -> str | None:
    """What ran out when ``err`` is a failure of the machine rather than of the input: ``"memory"``, ``"thread"``
    or ``"descriptors"`` (None otherwise). Under ``ulimit -v`` a read or an import fails with whatever its library
    raises (MemoryError, an ImportError naming a shared object, a decompressor's error); the exceptions it was
    raised while handling are looked at too (llvmlite's own ImportError hides the failed ``dlopen``; a writer's
    "cannot write the output" hides the EMFILE)."""
    found = _failure(err)
    return found[0] if found else None


def _failure(err: BaseException | None) -> tuple[str, BaseException] | None:
    """(what ran out, the exception of the chain that says so)."""
    import errno

    seen: set[int] = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, ResourceError):
            kind = "memory" if "memory" in err.problem else "thread" if "thread" in err.problem else "descriptors"
            deeper = _failure(err.__cause__ or err.__context__)  # a writer's line hides which file could not open
            if kind == "descriptors" and deeper is not None and isinstance(deeper[1], OSError):
                return deeper
            return kind, err
        if isinstance(err, MemoryError):
            return "memory", err
        if isinstance(err, OSError) and err.errno in (errno.EMFILE, errno.ENFILE):
            return "descriptors", err
        if isinstance(err, OSError) and err.errno == errno.ENOMEM:
            return "memory", err
        if not isinstance(err, InputError):
            text = str(err).lower()
            if isinstance(err, RuntimeError) and any(t in text for t in _THREAD_TEXTS):
                return "thread", err
            if any(t in text for t in _MEMORY_TEXTS):
                return "memory", err
        err = err.__cause__ or err.__context__
    return None


def _soft_limit(name: str) -> int | None:
    """The soft resource limit ``RLIMIT_<name>`` of this process, None when unlimited or unknown."""
    try:
        import resource

        soft = resource.getrlimit(getattr(resource, f"RLIMIT_{name}"))[0]
    except (ImportError, AttributeError, OSError, ValueError):
        return None
    return None if soft == resource.RLIM_INFINITY else int(soft)


def resource_error(err: BaseException, path: object, what: str, needs_mb: int | None = None) -> ResourceError | None:
    """``err`` as the one-line :class:`ResourceError` for ``path`` when it is a failure of the machine
    (:func:`machine_failure`), None otherwise. ``what`` says what was being done ("reading the log"); a memory
    failure says how much the work needs (``needs_mb``, when known) against the address-space limit."""
    found = _failure(err)
    if found is None:
        return None
    kind, err = found
    if isinstance(err, ResourceError):  # said deeper down; a caller that knows the whole need adds it
        if needs_mb and getattr(err, "needs_mb", 0) is None:
            return resource_error(MemoryError(), err.path, err.what, needs_mb)
        return err
    memory = _soft_limit("AS")
    allowed = f"the limit (ulimit -v) is {memory >> 20} MB" if memory is not None else "the machine's memory ran out"
    if kind == "memory":
        needs = f"; needs about {needs_mb} MB" if needs_mb else ""
        problem = f"not enough memory for {what}{needs} ({allowed})"
    elif kind == "thread":
        procs = _soft_limit("NPROC")
        why = (
            f"the memory limit (ulimit -v {memory >> 10}) leaves no room for its stack"
            if memory is not None
            else f"the process and thread limit (ulimit -u {procs}) is reached"
            if procs is not None
            else "the system refused it"
        )
        problem = f"cannot start a thread for {what}: {why}"
    else:
        files = _soft_limit("NOFILE")
        limit = f" (ulimit -n {files})" if files is not None else ""
        opening = getattr(err, "filename", None)
        path = opening or path
        raise_to = f": raise the limit, e.g. ulimit -n {max(4 * files, 1024)}" if files is not None else ""
        problem = f"too many open files{limit} {'when opening it ' if opening else ''}for {what}{raise_to}"
    machine = ResourceError(path, problem)
    machine.what, machine.needs_mb = what, (needs_mb if kind == "memory" else 0)
    return machine
