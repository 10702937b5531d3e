"""The error types the CLI turns into a one-line message and a non-zero exit code."""

from __future__ import annotations


class InputError(Exception):
    """Bad input: names the file, the topic (if any) and the problem in one line."""

    def __init__(self, path: object, problem: str, topic: str | None = None) -> None:
        self.path = str(path)
        self.topic = topic
        self.problem = problem
        where = f"{self.path}" + (f" [{topic}]" if topic else "")
        super().__init__(f"{where}: {problem}")


class OutputError(InputError):
    """The output cannot or must not be written (disk full, read-only or forbidden place, an ``-o`` that would
    replace an input): one line naming the output path. A subclass of InputError so every caller that turns
    input errors into one line handles it too."""


class GainError(ValueError):
    """A gain or observer option is unknown, missing, not a number, or outside its admissible range."""



class ResourceError(OutputError):
    """The machine, not the input, stopped the work: out of memory, threads, file descriptors or disk space.

    One line naming the file being read or written and what ran out. A batch records it as a failure of the
    machine, retried by the next batch, never as a bad log that ``--skip-failed`` would skip.
    """


#: Texts of exceptions that are a failure of the machine without saying so by their type: a shared library that
#: could not be mapped (an ImportError or OSError), a decompressor's or allocator's own out-of-memory error.
_MEMORY_TEXTS = ("failed to map segment", "cannot allocate memory", "allocation error", "not enough memory",
                 "out of memory", "memory allocation failed")
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
        why = (f"the memory limit (ulimit -v {memory >> 10}) leaves no room for its stack" if memory is not None
               else f"the process and thread limit (ulimit -u {procs}) is reached" if procs is not None
               else "the system refused it")
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
