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

    One line naming the file being read or written and what ran out. A batch records it as a failure of the
    machine, retried by the next batch, never as a bad log that ``--skip-failed`` would skip.
    """


#: ``errno`` values of a machine that ran out of something (disk space or quota, descriptors, memory).
RESOURCE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EMFILE, errno.ENFILE, errno.ENOMEM})


def output_error(path: object, err: OSError, doing: str = "cannot write the output") -> OutputError:
    """An OS error while writing ``path`` as one line naming it: a :class:`ResourceError` when the machine ran out
    of something (a full disk said only "No space left on device", without the file), else an :class:`OutputError`;
    the file it concerns is added when that is not ``path`` itself."""
    text = err.strerror or " ".join(str(err).split()) or type(err).__name__
    if err.filename and str(err.filename) != str(path):
        text = f"{text} ({err.filename})"
    kind = ResourceError if err.errno in RESOURCE_ERRNOS else OutputError
    return kind(path, f"{doing}: {text}")
