"""What a run may open and where it may write.

Inputs are opened only when they are regular files or directories: opening a FIFO blocks until someone
writes to it and a character device may never end, so both (and sockets, block devices) are refused with a
one-line error before anything opens them; a symbolic link loop or a dangling link is named as such.

An output directory never replaces or holds an input, never lies inside an input directory (a rosbag2
directory, a msg directory), is never the working directory or one above it, and ``--force`` replaces only
what slamobs wrote (a directory holding ``run.json`` or ``comparison.json``, or an empty one): a mistyped
``-o`` must not delete a user's files.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from slamobs.pipeline.errors import InputError, OutputError

#: Files that mark a directory as slamobs output (``run``, ``compare``, ``tune``), the only kind ``--force`` replaces.
OUTPUT_MARKERS = ("run.json", "comparison.json", "tune.journal")

_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _stat_error(path: Path, err: OSError) -> InputError:
    if err.errno == errno.ELOOP:
        return InputError(path, "symbolic link loop (following the links never reaches a file)")
    if err.errno == errno.ENOENT:
        if path.is_symlink():
            return InputError(path, f"dangling symbolic link (to {os.readlink(path)}, which does not exist)")
        return InputError(path, "no such file")
    if err.errno == errno.EACCES:
        return InputError(path, "permission denied")
    if err.errno == errno.ENOTDIR:
        return InputError(path, "no such file (a part of the path is not a directory)")
    return InputError(path, f"cannot read: {err.strerror or err}")


def check_input(path: str | Path, what: str = "file", *, directory_ok: bool = True) -> os.stat_result:
    """The ``stat`` of an input that may be opened: a regular file (or a directory when ``directory_ok``).

    Raises:
        InputError: Missing, a link loop or dangling link, unreadable, or not a regular file or directory.

    """
    path = Path(path)
    try:
        st = os.stat(path)
    except OSError as err:
        raise _stat_error(path, err) from None
    if stat.S_ISREG(st.st_mode) or (directory_ok and stat.S_ISDIR(st.st_mode)):
        return st
    if stat.S_ISDIR(st.st_mode):
        raise InputError(path, f"is a directory, not a {what}")
    kind = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
    raise InputError(path, f"{kind}, not a {what}: only regular files and directories are read")


def _resolved(path: str | Path) -> Path:
    return Path(os.path.abspath(os.path.realpath(path)))


def _within(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def check_output(out: str | Path, inputs: Iterable[str | Path | None] = (), *, force: bool = False) -> None:
    """Refuse an output directory that would destroy an input or a user's files (nothing is touched).

    ``inputs`` are every path the run reads (log, config, msg directory, truth file); ``None`` entries are
    skipped. Without ``force`` an existing non-empty output is an error as well.

    Raises:
        OutputError: The output is the working directory (or above it), an input, holds an input, lies
            inside an input directory, exists as a file, or (``force``) is a directory slamobs did not write.

    """
    raw = str(out)
    if not raw.strip():
        raise OutputError("-o ''", "the output path is empty: name a new directory")
    target = _resolved(out)
    cwd = _resolved(os.getcwd())
    if _within(cwd, target):
        raise OutputError(out, "the output would replace the working directory (or a directory above it): "
                               "name a new directory")
    for item in inputs:
        if item is None or not str(item):
            continue
        src = _resolved(item)
        if _within(src, target):
            what = "is the input" if src == target else "contains the input"
            raise OutputError(out, f"the output {what} {item}: it would be deleted; choose another -o")
        if Path(item).is_dir() and _within(target, src):
            raise OutputError(out, f"the output lies inside the input directory {item}; choose another -o")
    if not os.path.lexists(out):
        return
    if not Path(out).is_dir():
        raise OutputError(out, "exists and is not a directory; choose another -o")
    try:
        entries = os.listdir(out)
    except OSError as err:
        raise OutputError(out, f"cannot read the existing output: {err.strerror or err}") from None
    if not entries:
        return
    if not force:
        raise OutputError(out, "output exists (use --force to replace it)")
    if not any(name in entries for name in OUTPUT_MARKERS):
        raise OutputError(out, f"exists and is not a slamobs output (no {' or '.join(OUTPUT_MARKERS)}): "
                               "--force replaces only earlier runs; remove it yourself or choose another -o")


def read_text(path: str | Path, what: str, errors: str = "strict") -> str:
    """A user's text file (config, camera file, map, manifest) as UTF-8, with or without the byte order mark that
    spreadsheets and Windows editors write; unreadable or not UTF-8 is one line naming it and the ``what``.
    ``errors="replace"`` keeps undecodable bytes for a parser that names the offending line itself."""
    try:
        raw = Path(path).read_bytes()
    except OSError as err:
        raise InputError(path, f"cannot read the {what}: {err.strerror or err}") from None
    try:
        return raw.decode("utf-8-sig", errors=errors)
    except UnicodeDecodeError as err:
        raise InputError(path, f"not UTF-8 text (byte 0x{raw[err.start]:02x} at offset {err.start}): save the {what} "
                               "as UTF-8") from None


def check_output_file(out: str | Path, inputs: Iterable[str | Path | None]) -> None:
    """Refuse an output file that is one of ``inputs`` (a file the command reads) or lies inside an input
    directory: writing it would destroy what the command was given (``evaluate --save-results`` onto the
    truth file, ``export --mcap`` onto the run's own table). ``LOG:TOPIC`` inputs count as their log.

    Raises:
        OutputError: The output is an input or inside an input directory.

    """
    target = _resolved(out)
    for item in inputs:
        if item is None or not str(item):
            continue
        path = Path(item)
        if not os.path.lexists(path) and ":" in str(item):  # LOG:TOPIC
            path = Path(str(item).rsplit(":", 1)[0])
        src = _resolved(path)
        if target == src or (path.is_dir() and _within(target, src)):
            where = "is" if target == src else "lies inside"
            raise OutputError(out, f"the output {where} the input {item}: it would be destroyed; choose another path")


@contextmanager
def exclusive(lock_file: Path, out: Path, holder: str) -> Iterator[None]:
    """Hold ``lock_file`` exclusively (a flock: the kernel releases it when the process dies, so a killed batch or
    tune never leaves a stale lock); one line naming ``out`` when ``holder`` (e.g. "another batch") has it."""
    with open(lock_file, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(out, f"{holder} is writing to this directory") from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def log_size(path: str | Path) -> int:
    """Bytes on disk of a log file or rosbag2 directory."""
    p = Path(path)
    if p.is_dir():
        return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
    return p.stat().st_size


#: Address space (``ulimit -v``) a run needs: a base (interpreter, numba and LLVM, pyarrow, the threads' stacks
#: and malloc arena, pyarrow, matplotlib) and an amount per MB of log, from the smallest limits under which runs
#: through the CLI succeeded (16-20 MB steps): sample_logs/figure8.mcap (1.9 MB) 670-684 MB, a simulated 600 s
#: figure8 (26 MB) 702-722 MB. A guide for the message of a run that ran out, not a check.
RUN_BASE_MB, RUN_MB_PER_LOG_MB = 660, 2.0


def run_memory_mb(log: str | Path) -> int | None:
    """About how much address space a run of ``log`` needs, in MB (rounded up to 50), None when its size is
    unknown."""
    try:
        size_mb = log_size(log) / 2**20
    except OSError:
        return None
    return int(-(-(RUN_BASE_MB + RUN_MB_PER_LOG_MB * size_mb) // 50) * 50)
