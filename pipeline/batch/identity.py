"""What a log is, independent of where it is: content hash, run key, run_id, and the cache that makes
re-hashing free; also the code hash that tells two slamobs installations apart.

A run is identified by what went into it: the log's content hash and the effective config's hash. Its
``run_id`` is the log's name (for people) plus 12 hex digits of that pair, so a log that is moved, copied or
re-mounted is the same run, and one log run with two configs gives two runs side by side.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import stat
from pathlib import Path, PurePosixPath

from slamobs.pipeline.batch.discover import LOG_SUFFIXES, check_openable, file_kind
from slamobs.pipeline.errors import InputError

#: Bytes read from each end of a file for the content hash; smaller files are hashed whole.
HASH_CHUNK = 1 << 20
HASH_VERSION = "v1"


def run_key(content_hash: str, config_hash: str) -> str:
    """12 hex digits of (content, config): the part of a run_id that makes it unique."""
    return hashlib.sha256(f"{content_hash}\0{config_hash}".encode()).hexdigest()[:12]


def path_key(path: Path) -> str:
    """Key of a log that could not be hashed (missing, unreadable): its absolute path stands in."""
    return "p" + hashlib.sha256(os.fsencode(os.path.abspath(path))).hexdigest()[:11]  # any bytes a name holds


def run_id_for(path: Path, key: str) -> str:
    """Readable, unique id: the log's name (without the container suffix) and ``key``."""
    name = Path(path).name
    for suffix in LOG_SUFFIXES:
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._-")[:48] or "log"
    return f"{name}-{key}"


def _content_files(path: Path) -> list[tuple[str, Path, os.stat_result]]:
    """(relative name, path, stat) of every file a log's content hash covers, in hashing order.

    A log file is itself; a rosbag2 directory is each of its non-hidden files (symbolic links to directories
    are not followed). Anything that is not a regular file (FIFO, device, socket, link loop) is an InputError.
    """
    top = check_openable(path)
    if stat.S_ISREG(top.st_mode):
        return [("", path, top)]
    found = []
    for here, dirs, files in os.walk(path, followlinks=False):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        for name in files:
            if name.startswith("."):
                continue
            f = Path(here) / name
            st = check_openable(f)
            if not stat.S_ISREG(st.st_mode):  # a symbolic link to a directory: not part of the recording
                continue
            found.append((PurePosixPath(f.relative_to(path)), f, st))
    found.sort(key=lambda x: x[0])
    return [(str(rel), f, st) for rel, f, st in found]


def stat_key(path: Path) -> str:
    """What the hash cache is keyed by: (device, inode, size, mtime) of every file of the log.

    Raises InputError like :func:`content_hash` (FIFOs, devices and link loops are refused without opening).
    """
    parts = [
        os.fsencode(f"{rel}\0{st.st_dev}:{st.st_ino}:{st.st_size}:{st.st_mtime_ns}")
        for rel, _, st in _content_files(path)
    ]
    return hashlib.sha256(b"\n".join(parts)).hexdigest()[:32]


def content_hash(path: Path) -> str:
    """Fingerprint of a log's content, independent of mtime and location, cheap for big logs.

    Per file (every non-hidden file of a rosbag2 directory, by relative name): its size, and its bytes if
    at most 2 MiB, else its first and last MiB. Bag/MCAP indexes and rosbag2 metadata sit at the ends, and
    a recording that grows or is re-recorded changes its size, so this catches real changes; an edit only
    in the middle of a big file that keeps its size is not seen (use ``--force``).
    """
    path = Path(path)
    h = hashlib.sha256(HASH_VERSION.encode())
    for rel, f, _ in _content_files(path):
        try:
            # O_NONBLOCK: a file swapped for a FIFO after the check must not block the open
            fd = os.open(f, os.O_RDONLY | os.O_NONBLOCK)
        except OSError as err:
            raise InputError(f, f"cannot read: {err.strerror}") from None
        with open(fd, "rb") as fh:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                raise InputError(f, f"{file_kind(st.st_mode)}, not a log file")
            size = st.st_size
            h.update(os.fsencode(f"\0{rel}\0{size}\0"))
            try:
                if size <= 2 * HASH_CHUNK:
                    h.update(fh.read())
                else:
                    h.update(fh.read(HASH_CHUNK))
                    fh.seek(size - HASH_CHUNK)
                    h.update(fh.read(HASH_CHUNK))
            except OSError as err:
                raise InputError(f, f"cannot read: {err.strerror}") from None
    return f"{HASH_VERSION}:{h.hexdigest()[:32]}"


class HashCache:
    """Content hashes by :func:`stat_key`, kept in ``path`` (JSON), so an unchanged log is never read again.

    A log copied, touched or rewritten gets a new key (inode, mtime or size differ) and is hashed afresh; a
    moved log keeps its inode on the same file system and is recognised without reading it.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        try:
            self.entries: dict[str, str] = json.loads(self.path.read_text())
        except (OSError, ValueError):
            self.entries = {}
        self.dirty = False

    def lookup(self, log: Path) -> tuple[str, str | None]:
        """(cache key, content hash or None when the log must be read); raises InputError like content_hash."""
        key = stat_key(log)
        return key, self.entries.get(key)

    def content_hash(self, log: Path, key: str | None = None) -> str:
        key = key or stat_key(log)
        found = self.entries.get(key)
        if found is None:
            found = self.entries[key] = content_hash(log)
            self.dirty = True
        return found

    def save(self) -> None:
        if not self.dirty:
            return
        tmp = self.path.with_name(f".{self.path.name}.tmp-{os.getpid()}")
        tmp.write_text(json.dumps(self.entries, separators=(",", ":")))
        os.replace(tmp, self.path)
        self.dirty = False


_CODE_HASH: str | None = None


def code_hash() -> str:
    """16 hex digits over the installed package's sources (``*.py`` and schemas), computed once per process:
    two installations with the same version but different code (an edited checkout) differ here."""
    global _CODE_HASH
    if _CODE_HASH is None:
        root = Path(__file__).resolve().parents[2]  # the slamobs package: pipeline/batch/identity.py
        files = [root / "__init__.py"]
        for sub in ("pipeline", "cli", "schemas"):
            files += [
                p
                for p in (root / sub).rglob("*")
                if p.suffix in (".py", ".json") and p.is_file() and "__pycache__" not in p.parts
            ]
        h = hashlib.sha256()
        for p in sorted(files):
            h.update(f"{p.relative_to(root).as_posix()}\0".encode())
            h.update(p.read_bytes())
        _CODE_HASH = h.hexdigest()[:16]
    return _CODE_HASH
