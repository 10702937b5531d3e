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


def interruption(err: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM (a KeyboardInterrupt) that ``err`` was raised while handling, if any.

    A signal raises its KeyboardInterrupt wherever the main thread is; raised inside a compiled function's
    call it comes back as a ``SystemError`` ("returned a result with an exception set"), and a writer closed
    half way through a table raises its own error on the way out. Such an error is the interruption, not a
    bad input or a failed report: callers that turn errors into messages or notes check this first."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return err
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return None
