"""What a run may open and where it may write.

Inputs are opened only when they are regular files or directories: opening a FIFO blocks until someone
writes to it and a character device may never end, so both (and sockets, block devices) are refused with a
one-line error before anything opens them; a symbolic link loop or a dangling link is named as such.

An output directory never replaces or holds an input, never lies inside an input directory (a rosbag2
directory, a msg directory), is never the working directory or one above it, and ``--force`` replaces only
what slamobs wrote: a mistyped ``-o`` must not delete a user's files. Every output directory holds a manifest
(:data:`MANIFEST`: the writer, its version and each file with its size); a directory replaces only when every
entry is in its manifest, unchanged, and a directory from before manifests only when every entry is a name
slamobs writes (:func:`foreign_entry`). Whatever slamobs did not write is the user's.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import stat
from collections.abc import Collection, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from slamobs.pipeline.errors import InputError, OutputError

#: The manifest in every output directory slamobs writes: ``{"writer": "slamobs", "version", "files": {path: size},
#: "directories": [path]}`` (paths relative to the directory, ``/``-separated; the manifest does not list itself).
MANIFEST = "slamobs-output.json"
WRITER = "slamobs"
#: Longest file name (bytes) most Linux file systems take: a hidden temporary name must fit it too.
NAME_MAX = 255
#: What slamobs wrote into output directories before they had a manifest (``run``, ``report``, ``export``,
#: ``compare``, ``tune``): such a directory is replaced only when it holds nothing else.
LEGACY_NAMES = frozenset(
    {
        "run.json",
        "report.json",
        "report.md",
        "results.mcap",
        "trajectory_top.png",
        "errors.png",
        "biases.png",
        "landmarks.png",
        "ape_evo.zip",
        "estimate_tum.txt",
        "truth_tum.txt",
        *(
            f"{t}.parquet"
            for t in (
                "poses",
                "biases",
                "landmarks",
                "landmark_tracks",
                "innovations",
                "jumps",
                "tag_detections",
                "poses_aligned",
                "landmarks_aligned",
            )
        ),
        "comparison.json",
        "comparison.md",
        "comparison.parquet",
        "overlay.png",
        "tune.journal",
        ".tune.lock",
        "gains.yaml",
        "trials.parquet",
        "objective.png",
        "tune.json",
        "tune.md",
    }
)

_KINDS = (
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


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


def inside(path: str | Path, directory: str | Path) -> bool:
    """``path`` is ``directory`` or lies under it, symbolic links followed (a batch never reads its own OUT)."""
    return _within(_resolved(path), _resolved(directory))


def identity(path: str | Path) -> tuple[int, int] | None:
    """``(device, inode)`` of ``path`` itself (a link is not followed), None when nothing is there: what an
    output check saw, compared again when the output is published (:func:`pipeline.writers.publish`)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    return st.st_dev, st.st_ino


def read_manifest(directory: str | Path) -> dict | None:
    """The manifest of an output directory slamobs wrote (``files`` and ``directories``), None when there is
    none, it is damaged or another program wrote it."""
    import json

    try:
        doc = json.loads(Path(directory, MANIFEST).read_bytes())
    except (OSError, ValueError):
        return None
    if not (
        isinstance(doc, dict)
        and doc.get("writer") == WRITER
        and isinstance(doc.get("files"), dict)
        and isinstance(doc.get("directories", []), list)
    ):
        return None
    return doc


def foreign_entry(directory: str | Path, also: Collection[str] = ()) -> tuple[str, str] | None:
    """The first entry of ``directory`` slamobs did not write, as ``(relative path, why)``; None when slamobs wrote
    every entry (or it is empty), so replacing the directory deletes nothing of the user's. ``also``: files of
    ``directory`` itself that slamobs writes beside its manifest (a batch run's ``batch.json``).

    With a manifest an entry is ours when the manifest lists it with the same kind and size (a subdirectory with
    its own manifest, a compare's run that was re-reported, answers for itself); without one (a directory from an
    older version), when every file has a name slamobs writes and every subdirectory is a run directory of such
    files (an older compare's). Links are never followed.
    """
    try:
        return _foreign(Path(directory), "", None, "", frozenset(also))
    except OSError as err:
        return os.path.basename(err.filename or "."), f"unreadable ({err.strerror or err})"


def _foreign(root: Path, rel: str, doc: dict | None, within: str, also: frozenset[str]) -> tuple[str, str] | None:
    """:func:`foreign_entry` of ``root/rel``, governed by the manifest ``doc`` in which it is ``within``."""
    here = root / rel if rel else root
    if os.path.lexists(here / MANIFEST):
        doc, within = read_manifest(here), ""
        if doc is None:
            return _join(rel, MANIFEST), "not a slamobs manifest"
    for name in sorted(os.listdir(here)):
        path, key = _join(rel, name), _join(within, name)
        st = os.lstat(here / name)
        if not rel and name in also and stat.S_ISREG(st.st_mode):
            continue
        if doc is not None:
            if key == MANIFEST:
                continue
            if stat.S_ISDIR(st.st_mode):
                if key not in doc.get("directories", []):
                    return path, "not written by slamobs"
                if found := _foreign(root, path, doc, key, frozenset()):
                    return found
            elif not stat.S_ISREG(st.st_mode) or key not in doc["files"]:
                return path, "not written by slamobs"
            elif doc["files"][key] != st.st_size:
                return path, "changed since slamobs wrote it"
        elif stat.S_ISDIR(st.st_mode):  # an older compare's run directories, nothing deeper
            if rel or not os.path.isfile(here / name / "run.json"):
                return path, "not written by slamobs"
            if found := _foreign(root, path, None, "", frozenset()):
                return found
        elif not stat.S_ISREG(st.st_mode) or name not in LEGACY_NAMES:
            return path, "not written by slamobs"
    return None


def _join(base: str, name: str) -> str:
    return f"{base}/{name}" if base else name


def check_output(
    out: str | Path, inputs: Iterable[str | Path | None] = (), *, force: bool = False, in_place: bool = False
) -> tuple[int, int] | None:
    """Refuse an output directory that would destroy an input or a user's files (nothing is touched); returns the
    :func:`identity` of what is there (an empty directory, or with ``force`` one slamobs wrote), None when nothing
    is: publishing replaces exactly that, or nothing.

    ``inputs`` are every path the run reads (log, config, msg directory, truth file); ``None`` entries are
    skipped. Without ``force`` an existing non-empty output is an error as well (one holding a file slamobs did
    not write is refused for that, the reason ``force`` would meet). ``in_place``: the command adds
    to its own earlier output there (a tune resumed), replacing nothing, so its contents are not examined.

    Raises:
        OutputError: The output is the working directory (or above it), an input, holds an input, lies
            inside an input directory, exists as a file, or (``force``) holds a file slamobs did not write.

    """
    raw = str(out)
    if not raw.strip():
        raise OutputError("-o ''", "the output path is empty: name a new directory")
    check_name(out)
    target = _resolved(out)
    cwd = _resolved(os.getcwd())
    if _within(cwd, target):
        raise OutputError(
            out, "the output would replace the working directory (or a directory above it): name a new directory"
        )
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
        return None
    if not Path(out).is_dir() or Path(out).is_symlink():
        raise OutputError(out, "exists and is not a directory; choose another -o")
    try:
        entries = os.listdir(out)
    except OSError as err:
        raise OutputError(out, f"cannot read the existing output: {err.strerror or err}") from None
    seen = identity(out)
    if not entries or in_place:
        return seen
    found = foreign_entry(out)  # refused with or without --force: never suggest the option that would not help
    if found is not None:
        raise OutputError(
            out,
            f"is not a slamobs output: {os.path.join(out, found[0])} is {found[1]}; --force "
            "replaces only what slamobs wrote: move it away yourself or choose another -o",
        )
    if not force:
        raise OutputError(out, "output exists (use --force to replace it)")
    return seen


def check_name(out: str | Path) -> None:
    """Refuse an output name a hidden temporary beside it could not be made for (too long for the file system
    even alone), in one line instead of an OS error later."""
    if len(os.fsencode(Path(out).name)) > NAME_MAX:
        raise OutputError(out, f"the name is longer than {NAME_MAX} bytes: choose a shorter one")


def check_utf8(path: str | Path) -> None:
    """Refuse a path with a byte that is not UTF-8 in one line: pyarrow opens only paths that encode as UTF-8 (it
    raised ``UnicodeEncodeError`` naming no file)."""
    raw = os.fsencode(path)
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputError(
            path,
            f"the path holds a byte that is not UTF-8 (0x{raw[err.start]:02x}), which the Parquet "
            "library cannot open: rename it",
        ) from None


def temporary_prefix(final: str | Path, tag: str = ".tmp-") -> str:
    """``.NAME<tag>``, the prefix of a hidden temporary next to ``final`` (``tempfile`` adds 8 characters, a
    suffix may add a few more): ``NAME`` is shortened to fit :data:`NAME_MAX` bytes whatever the length of
    ``final``'s name (the owner marker, not the name, says which output a temporary directory belongs to). It is
    UTF-8 even where ``final``'s name is not (a byte that is not UTF-8 becomes U+FFFD): pyarrow opens only paths
    that encode as UTF-8, and the tables are written inside the temporary."""
    room = NAME_MAX - len(os.fsencode(tag)) - 1 - 8 - 8
    text = os.fsencode(Path(final).name).decode("utf-8", "replace").encode()[:room].decode("utf-8", "ignore")
    return "." + text + tag


def read_bytes(path: str | Path, what: str) -> bytes:
    """A user's file as bytes; unreadable is one line naming it and the ``what``."""
    try:
        return Path(path).read_bytes()
    except OSError as err:
        raise InputError(path, f"cannot read the {what}: {err.strerror or err}") from None


def read_text(path: str | Path, what: str, errors: str = "strict", raw: bytes | None = None) -> str:
    """A user's text file (config, camera file, map, manifest) as UTF-8, with or without the byte order mark that
    spreadsheets and Windows editors write; unreadable or not UTF-8 is one line naming it and the ``what``.
    ``errors="replace"`` keeps undecodable bytes for a parser that names the offending line itself. ``raw``: the
    file's bytes, already read (:func:`read_bytes`)."""
    if raw is None:
        raw = read_bytes(path, what)
    try:
        return raw.decode("utf-8-sig", errors=errors)
    except UnicodeDecodeError as err:
        raise InputError(
            path, f"not UTF-8 text (byte 0x{raw[err.start]:02x} at offset {err.start}): save the {what} as UTF-8"
        ) from None


#: Values YAML aliases (``*name``) may add to a document beyond those written out: far above what a config,
#: manifest, map or camera file repeats, far below an alias bomb (9 lines of 9 aliases each: 387 million values).
YAML_ALIAS_BUDGET = 100_000
#: Flow collections (``[ ]``, ``{ }``) nested deeper than this are refused before parsing: ruamel's scanner takes
#: time proportional to the depth for every token (500 levels: 1 s; a 4 kB file of '[': 15 s before it fails);
#: a real file nests a few levels.
YAML_MAX_FLOW_DEPTH = 64
_FLOW = re.compile(r"\"(?:[^\"\\]|\\.)*\"|'(?:[^']|'')*'|#[^\n]*|[\[\]{}]")


def read_yaml(path: str | Path, what: str) -> Any:
    """A user's YAML file (config, manifest, map, camera file) as plain data (safe types only).

    Aliases are counted before anything is built: an alias bomb would take minutes to walk and a cycle
    (``a: &a [*a]``) recurses forever in whoever walks it, so both (and nesting too deep to compose) are one line.
    """
    from ruamel.yaml import YAML, YAMLError

    text = read_text(path, what)
    check_yaml_depth(text, path, what)
    yaml = YAML(typ="safe")
    try:
        node = yaml.compose(text)
        if node is None:
            return None
        _check_aliases(node, path, what)
        return yaml.constructor.construct_document(node)
    except YAMLError as err:
        raise InputError(path, f"not valid YAML: {' '.join(str(err).split())[:300]}") from None
    except RecursionError:
        raise InputError(path, f"the {what} is nested too deeply to read (hundreds of levels)") from None


def check_yaml_depth(text: str, path: str | Path, what: str) -> None:
    """Refuse YAML ``text`` whose flow collections nest deeper than YAML_MAX_FLOW_DEPTH (for files a library
    parses too, e.g. rosbags' metadata.yaml)."""
    if (depth := _flow_depth(text)) > YAML_MAX_FLOW_DEPTH:
        raise InputError(
            path, f"the {what} nests [ ] or {{ }} {depth} levels deep (more than the {YAML_MAX_FLOW_DEPTH} read)"
        )


def _flow_depth(text: str) -> int:
    """Deepest nesting of brackets and braces outside quoted strings and comments (a plain scalar's stray
    bracket counts too: an overestimate by the few a real file has)."""
    depth = deepest = 0
    for match in _FLOW.finditer(text):
        char = match.group()
        if char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth = max(depth - 1, 0)
    return deepest


def _children(node: Any) -> list:
    value = node.value
    if not isinstance(value, list):
        return []
    return [part for item in value for part in (item if isinstance(item, tuple) else (item,))]


def _check_aliases(root: Any, path: str | Path, what: str) -> None:
    """Refuse a composed YAML graph whose aliases form a cycle or expand it beyond YAML_ALIAS_BUDGET values
    (sizes are summed per distinct node, so the check is linear in what is written)."""
    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            size[key] = 1 + sum(size[id(child)] for child in _children(node))
            continue
        if key in size:
            continue
        on_path.add(key)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in on_path:
                name = f" *{child.anchor}" if getattr(child, "anchor", None) else ""
                raise InputError(
                    path,
                    f"the YAML alias{name} refers to a value that contains it (a cycle): the "
                    f"{what} cannot be read; write the value out",
                )
            if id(child) not in size:
                stack.append((child, False))
    extra = size[id(root)] - len(size)
    if extra > YAML_ALIAS_BUDGET:
        raise InputError(
            path,
            f"YAML aliases expand the {what} by {extra:.3g} values (more than the "
            f"{YAML_ALIAS_BUDGET:,} allowed; an alias bomb?): write the repeated values out",
        )


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
