"""Which logs a batch covers: files, directories, globs and manifests -> one :class:`LogEntry` per log.

What a log *is* (its content hash and run_id) is :mod:`identity`'s business; here only where logs are.
"""

from __future__ import annotations

import csv
import errno
import glob
import io
import os
import stat
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.paths import inside, read_text, read_yaml

LOG_SUFFIXES = (".bag", ".mcap", ".db3")  # a bare .db3: rosbag2 storage without metadata.yaml (crash)
MANIFEST_SUFFIXES = (".csv", ".yaml", ".yml")
ROSBAG2_META = "metadata.yaml"


@dataclass(frozen=True)
class LogEntry:
    """One log to run, with the per-log config a manifest gave it (None: the batch's config)."""

    path: Path
    config: Path | None = None


def is_rosbag2_dir(path: Path) -> bool:
    return path.is_dir() and (path / ROSBAG2_META).is_file()


def is_split_recording(path: Path) -> bool:
    """A directory without metadata.yaml that ``slamobs run`` reads as one log, the ``NAME_N`` parts of one split
    recording (ROS1 bags, or the .db3/.mcap files of a rosbag2 recording that was not closed: the readers' rule,
    :func:`~slamobs.pipeline.readers.container.detect_container`), laid out as a recorder lays it out: the parts
    named after their directory (``rec/rec_0.db3``, as rosbag2 names them). A directory of logs that only look like
    parts (``flights/flight_0.mcap``, ``flight_1.mcap``: whole logs) stays a directory of logs (``run`` refuses it).
    False for anything else (no logs, several names, a file not a log)."""
    if not path.is_dir() or is_rosbag2_dir(path):
        return False
    # imported here: discovery stays light for the batch CLI's start; only directories pay for the readers
    from slamobs.pipeline.readers.container import SPLIT_KINDS, detect_container

    try:
        return detect_container(path).kind in SPLIT_KINDS  # the readers' rule names the parts after the directory
    except InputError:
        return False


def _is_glob(text: str) -> bool:
    return any(c in text for c in "*?[")


def _is_manifest(path: Path) -> bool:
    if path.suffix.lower() not in MANIFEST_SUFFIXES:
        return False
    # a rosbag2 directory's own metadata.yaml names that log, not a list of logs
    return not (path.name == ROSBAG2_META and "rosbag2_bagfile_information" in path.read_text(errors="replace"))


def _walk(root: Path, links: list[Path] | None = None) -> list[Path]:
    """Logs under ``root``: .bag/.mcap/.db3 files, rosbag2 directories and split recordings (directories whose files
    are the ``NAME_N`` parts of one recording, :func:`is_split_recording`), neither descended into, so their files
    are not counted again (a directory without metadata.yaml and one storage file is walked and that file found).

    Hidden names are skipped: they are other tools' temporary files (e.g. a log still being written). Symbolic links
    to directories other than a log are not followed (a link may loop); they are added to ``links`` when given.
    """
    found: list[Path] = []
    for here, dirs, files in os.walk(root, followlinks=False):
        base = Path(here)
        descend = []
        for d in sorted(dirs):
            if d.startswith("."):
                continue
            if is_rosbag2_dir(base / d) or is_split_recording(base / d):
                found.append(base / d)
            elif (base / d).is_symlink():
                if links is not None:
                    links.append(base / d)
            else:
                descend.append(d)
        dirs[:] = descend
        found.extend(base / f for f in sorted(files) if not f.startswith(".") and f.lower().endswith(LOG_SUFFIXES))
    return sorted(found)


def file_kind(mode: int) -> str:
    """What a non-regular, non-directory file is, for error messages."""
    for test, name in (
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def check_openable(path: Path) -> os.stat_result:
    """``stat`` of a path that may be opened: a regular file or a directory, else one-line InputError.

    FIFOs and devices are refused before anything opens them (reading a FIFO blocks forever), and a
    symbolic link loop is named as such instead of "no such file".
    """
    try:
        st = os.stat(path)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise InputError(path, "symbolic link loop") from None
        if err.errno == errno.ENOENT:
            raise InputError(path, "no such file or directory") from None
        raise InputError(path, f"cannot read: {err.strerror}") from None
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        raise InputError(path, f"{file_kind(st.st_mode)}, not a log file or directory")
    return st


def _expand(path: Path, config: Path | None, origin: str, links: list[Path] | None = None) -> list[LogEntry]:
    """A path given on the command line or by a glob: a log, a directory to search, or a manifest."""
    try:
        check_openable(path)
    except InputError as err:
        raise InputError(path, f"{origin}: {err.problem}") from None
    if is_rosbag2_dir(path) or is_split_recording(path):
        return [LogEntry(path, config)]
    if path.is_dir():
        return [LogEntry(p, config) for p in _walk(path, links)]
    if path.is_file():
        if path.name == ROSBAG2_META and not _is_manifest(path):
            return [LogEntry(path.parent, config)]
        if _is_manifest(path):
            return read_manifest(path)
        if path.suffix.lower() in LOG_SUFFIXES:
            return [LogEntry(path, config)]
    raise InputError(path, f"{origin}: not a log (.bag, .mcap, .db3, rosbag2 directory) or a manifest (.csv, .yaml)")


def discover(inputs: Sequence[str | Path], links: list[Path] | None = None) -> list[LogEntry]:
    """All logs named by ``inputs``, in input order, each once; the symbolic links to directories found in a
    directory searched, and not followed, are added to ``links`` when given.

    Raises:
        InputError: A missing input, an unreadable manifest, a log listed twice with different configs,
            or no log at all.

    """
    entries: list[LogEntry] = []
    unfollowed: list[Path] = []
    for item in inputs:
        text = str(item)
        if not Path(text).exists() and _is_glob(text):
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                raise InputError(text, "pattern matches nothing")
            for m in map(Path, matches):
                if is_rosbag2_dir(m.parent) or (m.is_file() and is_split_recording(m.parent)):
                    m = m.parent  # a file inside a rosbag2 directory (or a split recording) stands for that one log
                if m.is_dir() or m.suffix.lower() in LOG_SUFFIXES + MANIFEST_SUFFIXES:
                    entries.extend(_expand(m, None, "input", unfollowed))
        else:
            entries.extend(_expand(Path(text), None, "input", unfollowed))
    unique = _dedupe(entries)
    if not unique:
        problem = "no logs found (.bag, .mcap or rosbag2 directories)"
        if unfollowed:
            shown = ", ".join(map(str, unfollowed[:3])) + (", ..." if len(unfollowed) > 3 else "")
            problem += f"; symbolic links to directories are not searched ({shown}): give them as inputs"
        raise InputError(" ".join(map(str, inputs)), problem)
    if links is not None:
        links.extend(unfollowed)
    return unique


def outside(entries: Iterable[LogEntry], directory: str | Path) -> list[LogEntry]:
    """The entries that do not lie in ``directory``: a batch's own output (its ``results.mcap`` exports) is
    never one of its logs, whatever the inputs name."""
    return [e for e in entries if not inside(e.path, directory)]


def _dedupe(entries: Iterable[LogEntry]) -> list[LogEntry]:
    seen: dict[str, LogEntry] = {}
    for e in entries:
        key = os.path.realpath(e.path)  # never raises (Path.resolve does on a symbolic link loop)
        first = seen.setdefault(key, e)
        if first.config != e.config and _resolve(first.config) != _resolve(e.config):
            raise InputError(
                e.path,
                f"listed twice with different configs ({first.config or 'no config'} and {e.config or 'no config'})",
            )
    return list(seen.values())


def _resolve(p: Path | None) -> str | None:
    return None if p is None else os.path.realpath(p)


def read_manifest(path: Path) -> list[LogEntry]:
    """Entries of a CSV (columns ``log[,config]``, header optional) or YAML manifest.

    YAML: a list of paths or of ``{log: PATH, config: PATH}`` mappings, or a mapping with that list under
    ``logs``. Relative paths are relative to the manifest. Listed logs are not checked here: a missing one
    becomes a failed run, so one bad line does not stop the batch.
    """
    try:
        rows = _csv_rows(path) if path.suffix.lower() == ".csv" else _yaml_rows(path)
    except OSError as err:
        raise InputError(path, f"cannot read manifest: {err.strerror}") from None
    base = path.parent
    out = []
    for n, (log, cfg) in enumerate(rows, 1):
        if not log:
            raise InputError(path, f"manifest entry {n}: no log path")
        out.append(LogEntry(base / log, base / cfg if cfg else None))
    return out


def _csv_rows(path: Path) -> list[tuple[str, str | None]]:
    # newline="" keeps quoted line breaks to the csv module, which also takes CRLF line ends
    reader = csv.reader(io.StringIO(read_text(path, "manifest"), newline=""))
    try:
        rows = [[c.strip() for c in r] for r in reader if r and any(c.strip() for c in r)]
    except csv.Error as err:
        raise InputError(path, f"manifest is not valid CSV: line {reader.line_num}: {err}") from None
    rows = [r for r in rows if not r[0].startswith("#")]
    if rows and rows[0][0].lower() in ("log", "path"):
        header = [c.lower() for c in rows[0]]
        rows = rows[1:]
        i_cfg = header.index("config") if "config" in header else None
        return [(r[0], (r[i_cfg] or None) if i_cfg is not None and i_cfg < len(r) else None) for r in rows]
    return [(r[0], (r[1] or None) if len(r) > 1 else None) for r in rows]


def _yaml_rows(path: Path) -> list[tuple[str, str | None]]:
    data = read_yaml(path, "manifest")
    if isinstance(data, dict) and "logs" in data:
        data = data["logs"]
    if not isinstance(data, list):
        raise InputError(path, "manifest must be a list of logs (or a mapping with a 'logs' list)")
    rows = []
    for n, item in enumerate(data, 1):
        if isinstance(item, str):
            rows.append((item, None))
        elif isinstance(item, dict) and isinstance(item.get("log", item.get("path")), str):
            cfg = item.get("config")
            rows.append((item.get("log", item.get("path")), str(cfg) if cfg else None))
        else:
            raise InputError(path, f"manifest entry {n}: expected a path or {{log: PATH, config: PATH}}")
    return rows
