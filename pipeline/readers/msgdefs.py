"""Message definitions a log does not carry: ``.msg`` files from a directory, and naming exactly what is missing.

ROS1 bags and recent rosbag2/MCAP files store every definition, but rosbag2 sqlite3 logs before Iron and some
MCAP writers do not, and then a custom type cannot be decoded. ``msg_dir`` is a tree of ``pkg/msg/Type.msg``
files (a ROS workspace's ``src`` works). Standard types still missing after that (say ``geometry_msgs`` used by
a custom type whose definition came alone) are taken from rosbags' built-in ROS2 Humble / ROS1 Noetic store, so
a user only ever supplies their own packages. Definitions stored in the log always win.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from slamobs.pipeline.errors import InputError, one_line
from slamobs.pipeline.paths import check_input

if TYPE_CHECKING:
    from collections.abc import Collection

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

HINT = "give its .msg file with --msg-dir (config msg_dir: a directory holding pkg/msg/Type.msg)"


def complete_definitions(reader: AnyReader, msg_dir: str | Path | None = None) -> list[str]:
    """Add the types the opened log lacks: ``msg_dir/**/pkg/msg/Type.msg`` files, then standard types.

    Returns the names added.

    Raises:
        InputError: ``msg_dir`` is not a directory, or a ``.msg`` file cannot be read or parsed.

    """
    added = _read_msg_dir(reader.typestore, msg_dir) if msg_dir is not None else {}
    reader.typestore.register(added)
    return sorted(added) + _fill_standard(reader)


def _read_msg_dir(typestore: Typestore, msg_dir: str | Path) -> dict[str, object]:
    root = Path(msg_dir)
    if not root.is_dir():
        raise InputError(root, "message definition directory not found" if not root.exists() else "not a directory")
    added: dict[str, object] = {}
    for file in sorted(root.rglob("*.msg")):
        if file.parent.name != "msg":
            continue
        name = f"{file.parent.parent.name}/msg/{file.stem}"
        if name in typestore.fielddefs or name in added:
            continue
        check_input(file, "message definition", directory_ok=False)
        try:
            added.update(get_types_from_msg(file.read_text(encoding="utf-8"), name))
        except OSError as err:
            raise InputError(file, f"cannot read message definition: {err.strerror}") from None
        except Exception as err:  # rosbags raises its parser's errors for bad syntax
            reason = one_line(err)[:200] or type(err).__name__
            raise InputError(file, f"cannot parse message definition {name}: {reason}") from None
    return added


def _fill_standard(reader: AnyReader) -> list[str]:
    """Register built-in definitions for missing types the log's types use (one at a time: each may need more)."""
    typestore = reader.typestore
    builtin = None
    added: list[str] = []
    pending = sorted({conn.msgtype for conn in reader.connections})
    while pending:
        found = missing_type(typestore, pending[-1])
        if found is None:
            pending.pop()
            continue
        builtin = builtin or get_typestore(Stores.ROS2_HUMBLE if reader.is2 else Stores.ROS1_NOETIC)
        if found[0] not in builtin.fielddefs:
            pending.pop()  # a custom type: require_types names it when its topic is read
            continue
        typestore.register({found[0]: builtin.fielddefs[found[0]]})
        added.append(found[0])
    return added


def missing_type(typestore: Typestore, msgtype: str) -> tuple[str, str] | None:
    """First type needed to decode ``msgtype`` that ``typestore`` lacks, with the type that uses it."""
    stack, seen = [(msgtype, "")], set()
    while stack:
        name, user = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        if name not in typestore.fielddefs:
            return name, user
        for _, (kind, desc) in reversed(typestore.fielddefs[name][1]):
            if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
                kind, desc = desc[0]
            if kind == Nodetype.NAME:
                stack.append((desc, name))
    return None


def require_types(reader: AnyReader, path: str | Path, connections: Collection[Connection]) -> None:
    """Fail before decoding when a type (or a type it uses) has no definition in the log or ``msg_dir``.

    Raises:
        InputError: Names the missing type, the type using it and the topic.

    """
    for conn in connections:
        if (found := missing_type(reader.typestore, conn.msgtype)) is not None:
            name, user = found
            used = f" (used by {user})" if user else ""
            raise InputError(path, f"message definition for {name}{used} is not stored in the log; {HINT}", conn.topic)
