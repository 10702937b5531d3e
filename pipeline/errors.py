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
KINDS: tuple[type[SlamobsError], ...] = (BadInput, BadConfig, BadOutput, ResourceFailure, InfrastructureFailure,
                                         Interruption)


def kind_of(err: BaseException) -> type[SlamobsError] | None:
    """The kind of ``err`` (the first kind in its class's MRO), None for an error that is not slamobs'."""
    for cls in type(err).__mro__:
        if cls in KINDS:
            return cls
    return None


class InputError(BadInput):
    """Bad input: names the file, the topic (if any) and the problem in one line."""

    def __init__(self, path: object, problem: str, topic: str | None = None) -> None:
        self.path = str(path)
        self.topic = topic
        self.problem = problem
        where = f"{self.path}" + (f" [{topic}]" if topic else "")
        super().__init__(f"{where}: {problem}")


class OutputError(BadOutput, InputError):
    """The output cannot or must not be written (disk full, read-only or forbidden place, an ``-o`` that would
    replace an input): one line naming the output path. Also an InputError, so every caller that turns input
    errors into one line handles it too."""


class GainError(BadConfig, ValueError):
    """A gain or observer option is unknown, missing, not a number, or outside its admissible range."""


class ResourceError(ResourceFailure, OutputError):
    """The machine, not the input, stopped the work: out of memory, threads, file descriptors or disk space.

    One line naming the file being read or written and what ran out. A batch reports it as a failure of the
    machine and does not record it, so the next batch runs the log again: never a bad log that
    ``--skip-failed`` would skip.
    """


#: OS errors that say the machine refused or ran out (disk or quota full, read-only file system, permission,
#: memory, file descriptors), whatever file the work was on.
RESOURCE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOMEM,
                             errno.EMFILE, errno.ENFILE})


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
    return (isinstance(err, (ResourceError, MemoryError))
            or (isinstance(err, OSError) and err.errno in RESOURCE_ERRNOS))


def one_line(text: object) -> str:
    """Any text (an exception's too) on one line: every run of whitespace, newlines included, becomes one space."""
    return " ".join(str(text).split())
