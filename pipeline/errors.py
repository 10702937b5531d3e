"""The error types the CLI turns into a one-line message and a non-zero exit code."""

from __future__ import annotations

import errno


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

    One line naming the file being read or written and what ran out. A batch reports it as a failure of the
    machine and does not record it, so the next batch runs the log again: never a bad log that
    ``--skip-failed`` would skip.
    """


#: OS errors that say the machine refused or ran out (disk or quota full, read-only file system, permission,
#: memory, file descriptors), whatever file the work was on.
RESOURCE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOMEM,
                             errno.EMFILE, errno.ENFILE})


def output_error(path: object, problem: str, err: OSError) -> OutputError:
    """The error for an output that could not be written because of ``err``: a ResourceError when the machine
    ran out or refused (see RESOURCE_ERRNOS), else an OutputError."""
    kind = ResourceError if getattr(err, "errno", None) in RESOURCE_ERRNOS else OutputError
    return kind(path, problem)


def is_resource_failure(err: BaseException) -> bool:
    """The machine, not the input, stopped the work: a ResourceError, a MemoryError or a resource OS error."""
    return (isinstance(err, (ResourceError, MemoryError))
            or (isinstance(err, OSError) and err.errno in RESOURCE_ERRNOS))
