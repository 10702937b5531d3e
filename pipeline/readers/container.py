"""Container detection and opening of ROS logs, with every failure mapped to :class:`InputError`.

The container is recognised by its first bytes, not by its suffix, so that a text file renamed
``.bag`` gets a clear message and a valid log with an odd suffix still opens. rosbags' ``AnyReader``
chooses its reader from the suffix, so a log whose suffix does not match its content is opened through
a temporary symlink with the expected suffix.
"""

from __future__ import annotations

import re
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from pipeline.errors import InputError

if TYPE_CHECKING:
    from collections.abc import Collection, Iterator

    from rosbags.interfaces import Connection

Kind = Literal["ros1", "rosbag2", "mcap", "db3"]

#: Human readable container names, used in messages.
LABELS: dict[str, str] = {
    "ros1": "ROS1 bag",
    "rosbag2": "rosbag2 directory",
    "mcap": "MCAP file",
    "db3": "rosbag2 sqlite3 file",
}

_MAGIC: tuple[tuple[bytes, Kind], ...] = (
    (b"#ROSBAG V", "ros1"),
    (b"\x89MCAP0\r\n", "mcap"),
    (b"SQLite format 3\x00", "db3"),
)
_SUFFIX: dict[str, str] = {"ros1": ".bag", "mcap": ".mcap", "db3": ".db3"}
_WRAPPERS: tuple[tuple[bytes, str], ...] = (
    (b"BZh", "bzip2"),
    (b"\x1f\x8b", "gzip"),
    (b"\x28\xb5\x2f\xfd", "zstd"),
    (b"\xfd7zXZ\x00", "xz"),
    (b"PK\x03\x04", "zip"),
)
_NOT_A_LOG = "not a ROS1 bag, rosbag2 directory or MCAP file"

# Types used when a log holds no message definitions at all (rosbag2 sqlite3 logs before Iron).
_FALLBACK_STORE = Stores.ROS2_HUMBLE


@dataclass(frozen=True)
class Container:
    """What a path holds: ``kind`` and, for rosbag2 directories, the storage plugin."""

    path: Path
    kind: Kind
    storage: str = ""

    @property
    def label(self) -> str:
        """Human readable container name."""
        return LABELS[self.kind] + (f" ({self.storage})" if self.storage else "")


def _one_line(text: object) -> str:
    """Collapse an exception text to one line for the CLI."""
    return " ".join(str(text).split())


def detect_container(path: str | Path) -> Container:
    """Recognise the container of ``path`` from its content.

    Raises:
        InputError: The path is missing, unreadable or not a ROS log.

    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "no such file")
    if path.is_dir():
        meta = path / "metadata.yaml"
        if not meta.is_file():
            inner = sorted(x.name for x in path.iterdir() if x.suffix in {".db3", ".mcap"})
            hint = f" (directory has no metadata.yaml; open {inner[0]} directly)" if inner else ""
            raise InputError(path, _NOT_A_LOG + hint)
        try:
            text = meta.read_text(errors="replace")
        except OSError as err:
            raise InputError(path, f"cannot read metadata.yaml: {_one_line(err.strerror)}") from None
        match = re.search(r'storage_identifier:\s*["\']?([\w.-]+)', text)
        return Container(path, "rosbag2", match.group(1) if match else "")
    try:
        with path.open("rb") as fobj:
            head = fobj.read(16)
    except OSError as err:
        raise InputError(path, f"cannot read file: {_one_line(err.strerror)}") from None
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return Container(path, kind)
    if not head:
        raise InputError(path, f"{_NOT_A_LOG} (empty file)")
    for magic, name in _WRAPPERS:
        if head.startswith(magic):
            raise InputError(path, f"{_NOT_A_LOG} ({name}-compressed: decompress it first)")
    raise InputError(path, _NOT_A_LOG)


def _explain(container: Container, err: BaseException) -> InputError:
    """Turn a reader exception into the one-line InputError for this container."""
    reason = _one_line(err.args[0] if len(err.args) == 1 else err)
    if not reason:
        reason = "index and data disagree" if isinstance(err, AssertionError) else type(err).__name__
    reason = re.sub(r"\('(.*)',\)", r"\1", reason)  # rosbags nests args tuples in some messages
    if isinstance(err, PermissionError):
        return InputError(container.path, "permission denied")
    if "Profile is not ros2" in reason:
        return InputError(container.path, "unsupported MCAP file: profile is not ros2")
    if "not indexed" in reason:
        reason = "bag is not indexed (interrupted recording? run 'rosbag reindex')"
    elif "Bag version" in reason:
        return InputError(container.path, f"unsupported {container.label}: {reason}")
    return InputError(container.path, f"corrupt or truncated {container.label}: {reason}")


@contextmanager
def _rosbags_path(container: Container) -> Iterator[Path]:
    """Yield a path whose suffix makes ``AnyReader`` choose the right reader."""
    path = container.path
    want = _SUFFIX.get(container.kind)
    if container.kind == "rosbag2":
        ok = path.suffix != ".bag"
        want = ""
    else:
        ok = path.suffix == want
    if ok:
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="slamobs-") as tmp:
        link = Path(tmp) / f"log{want}"
        try:
            link.symlink_to(path.resolve(), target_is_directory=path.is_dir())
        except OSError:
            raise InputError(path, f"unexpected suffix for a {container.label}; rename it to *{want}") from None
        yield link


@contextmanager
def open_log(path: str | Path) -> Iterator[AnyReader]:
    """Open a ROS1 bag, rosbag2 directory, MCAP or db3 file as an opened rosbags ``AnyReader``.

    Reader errors raised inside the ``with`` block (corrupt chunks, undecodable messages) are turned into
    :class:`InputError` as well.

    Raises:
        InputError: Missing path, unknown container, corrupt or truncated file.

    """
    container = detect_container(path)
    with _rosbags_path(container) as rpath:
        try:
            reader = AnyReader([rpath], default_typestore=get_typestore(_FALLBACK_STORE))
            reader.open()
        except Exception as err:  # any reader failure means a bad file
            raise _explain(container, err) from None
        try:
            yield reader
        except (Ros1ReaderError, Ros2ReaderError, SerdeError) as err:
            raise _explain(container, err) from None
        finally:
            reader.close()


def require_definitions(reader: AnyReader, path: str | Path, connections: Collection[Connection]) -> None:
    """Fail when a connection's type cannot be decoded because its definition is not in the log.

    Raises:
        InputError: A message definition is missing.

    """
    for conn in connections:
        if conn.msgtype not in reader.typestore.fielddefs:
            raise InputError(path, f"message definition for {conn.msgtype} is not stored in the log", conn.topic)


def iter_raw(
    reader: AnyReader,
    path: str | Path,
    connections: Collection[Connection],
) -> Iterator[tuple[Connection, int, bytes]]:
    """Yield ``(connection, record_ns, rawdata)`` of ``connections`` with read failures as InputError.

    Errors raised by the consumer's loop body do not pass through here, so catching broadly is safe.
    """
    messages = reader.messages(connections=connections)
    while True:
        try:
            item = next(messages)
        except StopIteration:
            return
        except Exception as err:  # decompression, struct, sqlite errors alike
            raise _explain(detect_container(path), err) from None
        yield item
