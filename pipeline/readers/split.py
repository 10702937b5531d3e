"""A ROS1 recording split into several bag files (``rosbag record --split``: ``name_0.bag``, ``name_1.bag``, …)
read as one log: a directory holding the parts.

rosbags' ``AnyReader`` reads several ROS1 bags as one (a topic's connections from every file, messages in
file order, each file in record order); this module finds and orders the parts of a directory and says how the
files follow each other in time (the gaps between them, and parts that overlap or are missing).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.paths import check_input

from .ros1 import MAGIC

if TYPE_CHECKING:
    from collections.abc import Sequence

#: ``rosbag record --split`` names: the recording's name, an underscore, the part's index
PART = re.compile(r"^(?P<name>.+)_(?P<index>\d+)\.bag$")
#: a gap between two files longer than this (seconds) is reported
GAP_NOTE_S = 0.05


def split_parts(directory: Path, entries: Sequence[Path]) -> tuple[Path, ...]:
    """The ROS1 bags among ``entries`` (the directory's), in part order; empty when there are none.

    Raises:
        InputError: A bag is not named ``NAME_N.bag``, the bags belong to several recordings, or one is not a
            ROS1 bag.
    """
    bags = [e for e in entries if e.suffix == ".bag" and not e.name.startswith(".")]
    found: dict[str, list[tuple[int, Path]]] = {}
    for bag in bags:
        m = PART.match(bag.name)
        if m is None:
            raise InputError(directory, f"{bag.name} is not named NAME_N.bag as the parts of a split recording are")
        found.setdefault(m["name"], []).append((int(m["index"]), bag))
    if len(found) > 1:
        names = ", ".join(f"{n}_*.bag" for n in sorted(found))
        raise InputError(directory, f"holds the parts of {len(found)} recordings ({names}): give one directory each")
    parts = sorted(next(iter(found.values()), []))
    for _, bag in parts:
        check_input(bag, "part of a split ROS1 recording", directory_ok=False)
        with bag.open("rb") as fobj:
            if not fobj.read(len(MAGIC)).startswith(MAGIC):
                raise InputError(bag, "not a ROS1 bag (a part of the split recording in its directory)")
    return tuple(bag for _, bag in parts)


def part_notes(parts: Sequence[Path], spans: Sequence[tuple[int, int]]) -> list[str]:
    """What a run should know of how the parts follow each other: each part's span, gaps between parts longer than
    :data:`GAP_NOTE_S`, overlaps and missing part numbers. ``spans`` are each part's first and last record time."""
    t0 = min(a for a, _ in spans)
    listed = ", ".join(f"{p.name} {(a - t0) / 1e9:.3f}–{(b - t0) / 1e9:.3f} s" for p, (a, b) in zip(parts, spans))
    notes = [f"split recording of {len(parts)} ROS1 bags read as one: {listed}"]
    indices = [int(PART.match(p.name)["index"]) for p in parts]
    missing = sorted(set(range(indices[0], indices[-1] + 1)) - set(indices))
    if missing:
        notes.append(f"split recording: parts {', '.join(map(str, missing))} are missing (not in the directory)")
    for (p, (_, end)), (q, (start, _)) in zip(zip(parts, spans), zip(parts[1:], spans[1:])):
        gap = (start - end) / 1e9
        if gap > GAP_NOTE_S:
            notes.append(f"split recording: {gap:.3f} s without messages between {p.name} and {q.name}")
        elif gap < 0:
            notes.append(f"split recording: {q.name} starts {-gap:.3f} s before {p.name} ends (the parts overlap)")
    return notes


def recording_of(paths: Sequence[Path]) -> Path:
    """The one log that ``paths`` name: the path itself, or for several bags the directory whose split recording
    they are (all its ``NAME_N.bag`` parts, in any order).

    Raises:
        InputError: Several paths that are not exactly the parts of one directory's split recording.
    """
    if len(paths) == 1:
        return Path(paths[0])
    given = [Path(p) for p in paths]
    folder = given[0].parent
    rule = "several logs are read as one only when they are all the NAME_N.bag parts of one split ROS1 recording"
    if any(p.parent.resolve() != folder.resolve() for p in given):
        raise InputError(given[0], f"{rule}, in one directory (these are in several)")
    parts = split_parts(folder, sorted(folder.iterdir()))
    if sorted(p.name for p in parts) != sorted(p.name for p in given):
        have = ", ".join(p.name for p in parts)
        raise InputError(folder, f"{rule}; the directory holds {have or 'no bags'}: give the directory")
    return folder
