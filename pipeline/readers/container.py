"""Storage formats of ROS logs: recognising a path's container, the table of formats, opening a log, and raw
message access; every failure is an :class:`InputError`.

The container is recognised by its first bytes, not by its suffix, so that a text file renamed
``.bag`` gets a clear message and a valid log with an odd suffix still opens. rosbags' ``AnyReader``
chooses its reader from the suffix, so a log whose suffix does not match its content is opened through
a temporary symlink with the expected suffix.

``AnyReader`` stays the handle the rest of the readers use (topics, typestore, deserialisation), but its
storage readers are replaced by the ones in :data:`FORMATS` (one module per format: :mod:`.ros1`,
:mod:`.mcap`, :mod:`.rosbag2_sqlite`), which yield messages in batches (:class:`.storage.StorageReader`) and
recover what they can of a truncated file (:func:`damage_notes`). A rosbag2 directory holds files of one of
those formats. Adding a format means its module and one row of :data:`FORMATS`.

A ROS1 recording split into several bag files (``rosbag record --split``: ``name_0.bag``, ``name_1.bag``, …) is
one log too: the directory holding its parts (:func:`split_parts`). ``AnyReader`` reads several ROS1 bags as one
(a topic's connections from every file, messages in file order, each file in record order); the notes say how
the files follow each other in time (:func:`part_notes`: gaps between them, overlaps, missing parts).
"""

from __future__ import annotations

import json
import re
import stat
import tempfile
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path, PurePath
from typing import TYPE_CHECKING

import numpy as np
import zstandard
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import Reader as Reader2
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.rosbag2.reader import DirectoryReader
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from slamobs.pipeline.errors import InputError, one_line, resource_error
from slamobs.pipeline.paths import check_input, check_yaml_depth, read_yaml

from . import mcap, ros1, rosbag2_sqlite, sqlitefile
from .storage import TIME_LIMIT_NS, TIME_RANGE, ConnIds, DamagedError, RawBatch, StorageReader, TimeRangeError, joined

if TYPE_CHECKING:
    from collections.abc import Collection, Iterator, Sequence

    from rosbags.interfaces import Connection

#: "rosbag2", "ros2-partial" (a rosbag2 directory whose metadata.yaml lists files it lacks), "ros1-split" or
#: "ros2-split" (directories) or the kind of one of FORMATS: "ros1", "mcap", "db3"
Kind = str
#: the kinds of a directory without metadata.yaml whose files are the parts of one split recording (one log)
SPLIT_KINDS: frozenset[Kind] = frozenset({"ros1-split", "ros2-split"})


@dataclass(frozen=True)
class Format:
    """A storage format: how its files start, and the reader that replaces rosbags' own for it."""

    kind: Kind
    label: str  # human readable, used in messages
    magic: bytes  # what its files start with
    suffix: str  # the suffix rosbags chooses its reader by
    storage_id: str  # ``storage_identifier`` in a rosbag2 directory's metadata.yaml ("": not in rosbag2)
    replaces: type  # rosbags' reader for it
    reader: type[StorageReader]  # ours, constructed from the file's path like rosbags'


#: The storage formats, in the order their magic is tried.
FORMATS: tuple[Format, ...] = (
    Format("ros1", "ROS1 bag", ros1.MAGIC, ".bag", "", Reader1, ros1.Ros1Bag),
    Format("mcap", "MCAP file", mcap.MAGIC, ".mcap", "mcap", McapReader, mcap.McapStorage),
    Format(
        "db3",
        "rosbag2 sqlite3 file",
        rosbag2_sqlite.MAGIC,
        ".db3",
        "sqlite3",
        Sqlite3Reader,
        rosbag2_sqlite.Sqlite3Storage,
    ),
)

_READERS = tuple(f.reader for f in FORMATS)

#: Human readable container names, used in messages.
LABELS: dict[str, str] = {
    "rosbag2": "rosbag2 directory",
    "ros1-split": "split ROS1 recording",
    "ros2-split": "rosbag2 directory without metadata.yaml",
    "ros2-partial": "rosbag2 directory with missing files",
} | {f.kind: f.label for f in FORMATS}

_ZIP_MAGIC = b"PK\x03\x04"
_WRAPPERS: tuple[tuple[bytes, str], ...] = (
    (b"BZh", "bzip2"),
    (b"\x1f\x8b", "gzip"),
    (b"\x28\xb5\x2f\xfd", "zstd"),
    (b"\xfd7zXZ\x00", "xz"),
    (_ZIP_MAGIC, "zip"),
)
_NOT_A_LOG = "not a ROS1 bag, rosbag2 directory or MCAP file"

# Types used when a log holds no message definitions at all (rosbag2 sqlite3 logs before Iron).
_FALLBACK_STORE = Stores.ROS2_HUMBLE


@dataclass(frozen=True)
class MissingPart:
    """A part of a split recording that is not there: a file its metadata.yaml lists, or a part number between
    those in the directory; with what metadata.yaml says of it (None where it says nothing)."""

    name: str
    before: int  # how many of the parts read come before it in the recording
    start_ns: int | None = None
    duration_ns: int | None = None
    messages: int | None = None
    listed: bool = False  # metadata.yaml lists it (else: a part number missing between those there)


@dataclass(frozen=True)
class Container:
    """What a path holds: ``kind`` and, for rosbag2 directories, the storage plugin."""

    path: Path
    kind: Kind
    storage: str = ""
    note: str = ""  # how the path was interpreted, when it needed interpreting (a warning of the run)
    parts: tuple[Path, ...] = ()  # a split recording's files, in order (ROS1 bags, or rosbag2 files without metadata)
    missing: tuple[MissingPart, ...] = ()  # the files metadata.yaml lists that are not in the directory

    @property
    def label(self) -> str:
        """Human readable container name."""
        return LABELS[self.kind] + (f" ({self.storage})" if self.storage else "")


def detect_container(path: str | Path) -> Container:
    """Recognise the container of ``path`` from its content.

    Raises:
        InputError: The path is missing, unreadable or not a ROS log.

    """
    path = Path(path)
    st = check_input(path, "ROS log")  # never open a FIFO or a device: the read would block or never end
    if stat.S_ISDIR(st.st_mode):
        try:
            entries = sorted(path.iterdir())
        except OSError as err:
            raise InputError(path, f"cannot list the directory: {one_line(err.strerror or err)}") from None
        for entry in entries:  # what rosbags would open in it must be openable
            if entry.name == "metadata.yaml" or entry.suffix in {".db3", ".mcap", ".zstd"}:
                check_input(entry, "storage file of a rosbag2 directory", directory_ok=False)
        meta = path / "metadata.yaml"
        text = _metadata_text(path, meta)
        if text is None and (parts := split_parts(path, entries)):
            return Container(path, "ros1-split", f"{len(parts)} bag files", parts=_one_recording(path, parts))
        if text is None:  # rosbag2 writes metadata.yaml when a recording closes: a crash leaves none (or an empty one)
            which = "an empty" if meta.is_file() else "no"
            inner = [x for x in entries if x.suffix in {".db3", ".mcap"} and x.is_file()]
            if len(inner) == 1:
                found = detect_container(inner[0])
                note = f"{path.name} has {which} metadata.yaml (recording not closed?): read {inner[0].name} directly"
                return replace(found, note=note)
            if parts := _storage_parts(inner):
                note = f"{path.name} has {which} metadata.yaml (recording not closed?): read its {len(parts)} files"
                return Container(
                    path, "ros2-split", f"{len(parts)} {parts[0].suffix} files", note, _one_recording(path, parts)
                )
            names = ", ".join(x.name for x in inner[:3]) + (", ..." if len(inner) > 3 else "")
            hint = (
                f" (directory has {which} metadata.yaml and {len(inner)} storage files, {names}: the parts of a "
                f"recording that was not closed? `ros2 bag reindex {path}` writes its metadata.yaml; or open one "
                "file directly)"
                if inner
                else (" (its metadata.yaml is empty)" if meta.is_file() else _other_data(path))
            )
            raise InputError(path, _NOT_A_LOG + hint)
        check_yaml_depth(text, meta, "metadata.yaml")  # rosbags parses it: 15 s before failing on 3000 '['
        match = re.search(r'storage_identifier:\s*["\']?([\w.-]+)', text)
        _check_storage_id(path, match.group(1) if match else "", entries)
        return _partial(path, text, entries) or Container(path, "rosbag2", match.group(1) if match else "")
    try:
        with path.open("rb") as fobj:
            head = fobj.read(16)
    except OSError as err:
        raise InputError(path, f"cannot read file: {one_line(err.strerror)}") from None
    for fmt in FORMATS:
        if head.startswith(fmt.magic):
            return Container(path, fmt.kind, note=_part_alone(path))
    if not head:
        raise InputError(path, f"{_NOT_A_LOG} (empty file)")
    if head.startswith(_ZIP_MAGIC) and (said := evo_result_hint(path)):
        raise InputError(path, _NOT_A_LOG + said)
    for magic, name in _WRAPPERS:
        if head.startswith(magic):
            raise InputError(path, f"{_NOT_A_LOG} ({name}-compressed: decompress it first)")
    raise InputError(path, _NOT_A_LOG + _other_data(path))


#: the storage file names a metadata.yaml may list
_STORAGE_NAME = re.compile(r"[^\s'\"/]+\.(?:db3|mcap)(?:\.zstd)?\b")


def _partial(path: Path, text: str, entries: Sequence[Path]) -> Container | None:
    """A rosbag2 directory whose metadata.yaml lists storage files that are not in it, as the parts that are (the
    missing ones with what metadata.yaml says of them: their time span and message count); None when every listed
    file is there (only then is metadata.yaml parsed here).

    Raises:
        InputError: No listed file is there, or the files are compressed (read only through a whole metadata.yaml).
    """
    have = {e.name for e in entries}
    if all(name in have for name in _STORAGE_NAME.findall(text)):
        return None
    info = (read_yaml(path / "metadata.yaml", "metadata.yaml") or {}).get("rosbag2_bagfile_information")
    listed = info.get("relative_file_paths") if isinstance(info, dict) else None
    if not isinstance(listed, list) or all(PurePath(str(x)).name in have for x in listed):
        return None  # rosbags says what is wrong with it
    names = [PurePath(str(x)).name for x in listed]
    lost = [n for n in names if n not in have]
    said = ", ".join(lost[:3]) + (", ..." if len(lost) > 3 else "")
    if len(lost) == len(names):
        raise InputError(path, f"none of the {len(names)} storage files metadata.yaml lists is in it ({said})")
    if str(info.get("compression_mode") or "none").lower() != "none":
        raise InputError(
            path,
            f"metadata.yaml lists {said}, not in the directory, and the recording is compressed "
            f"({info.get('compression_mode')} mode), which slamobs reads only whole: restore the missing file",
        )
    per_file = {PurePath(str(f.get("path"))).name: f for f in info.get("files") or [] if isinstance(f, dict)}
    missing, parts = [], []
    for name in names:
        if name in have:
            parts.append(path / name)
            continue
        f = per_file.get(name, {})
        start, dur = _int(f, "starting_time", "nanoseconds_since_epoch"), _int(f, "duration", "nanoseconds")
        missing.append(MissingPart(name, len(parts), start, dur, _int(f, "message_count"), listed=True))
    suffix = parts[0].suffix
    return Container(
        path, "ros2-partial", f"{len(parts)} of {len(names)} {suffix} files", parts=tuple(parts), missing=tuple(missing)
    )


def _int(d: dict, *keys: str) -> int | None:
    """``d[k0][k1]...`` when it is an integer, else None (a metadata.yaml may leave it out)."""
    for k in keys:
        d = d.get(k) if isinstance(d, dict) else None
    return d if isinstance(d, int) and not isinstance(d, bool) else None


def _check_storage_id(path: Path, storage_id: str, entries: Sequence[Path]) -> None:
    """A metadata.yaml naming one storage (``storage_identifier``) over storage files that all are another (a
    metadata.yaml edited or copied from another recording): one line naming both, not the reader's complaint
    about the other format's first bytes ('File magic is invalid')."""
    by_id = {f.storage_id: f for f in FORMATS if f.storage_id}
    files = [x for x in entries if x.suffix in {".db3", ".mcap"} and x.is_file()]
    if storage_id not in by_id or not files:
        return
    try:
        kinds = {detect_container(x).kind for x in files}
    except InputError:  # a damaged storage file: the reader says what is wrong with it
        return
    stored = {f.kind: f for f in by_id.values()}
    if by_id[storage_id].kind in kinds or len(kinds) != 1 or (found := next(iter(kinds))) not in stored:
        return
    actual = stored[found]
    raise InputError(
        path,
        f"metadata.yaml says storage_identifier: {storage_id}, but its storage files are {actual.label}s "
        f"({', '.join(x.name for x in files[:3])}): set storage_identifier: {actual.storage_id} "
        "(metadata.yaml of another recording?)",
    )


#: suffixes of trajectory files (TUM, EuRoC CSV, KITTI): a file of them given as a log gets a hint
_TRAJECTORY_SUFFIXES = (".txt", ".csv", ".tum")


def _other_data(path: Path) -> str:
    """A hint for input that is no log but that slamobs takes elsewhere ("" when none applies): an MR.CLAM dataset
    folder (converted by ``slamobs import mrclam``), a trajectory file (truth of a run, or ``slamobs evaluate``)."""
    if path.is_dir() and (path / "Barcodes.dat").is_file():
        return f" (an MR.CLAM dataset folder: `slamobs import mrclam {path} -o LOG.mcap` converts one robot of it)"
    if path.is_file() and path.suffix.lower() in _TRAJECTORY_SUFFIXES:
        return (
            " (a trajectory file? `slamobs evaluate` compares two; evaluation.truth_file in a run's config makes it "
            "the run's truth)"
        )
    return ""


def evo_result_hint(path: Path) -> str:
    """`` (an evo result archive ...)``: what ``path`` holds and what reads it, when it is a zip with evo's
    ``stats.json`` (``evo_ape``/``evo_rpe --save_results`` and ``slamobs evaluate --save_results`` write one);
    "" for any other file. Decompressing it gives no log nor trajectory: it holds an evaluation's errors."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            if "stats.json" not in names:
                return ""
            info = json.loads(archive.read("info.json")) if "info.json" in names else {}
            stats = json.loads(archive.read("stats.json"))
    except (OSError, zipfile.BadZipFile, ValueError, KeyError):
        return ""
    info = info if isinstance(info, dict) else {}
    title = str(info.get("title") or "errors").splitlines()[0]
    pair = f" of {info['est_name']} against {info['ref_name']}" if info.get("est_name") and info.get("ref_name") else ""
    rmse = stats.get("rmse") if isinstance(stats, dict) else None
    level = f", rmse {rmse:.6g}" if isinstance(rmse, (int, float)) else ""
    return (
        f" (an evo result archive: {title}{pair}{level}; it holds an evaluation's errors, not poses: evo_res reads "
        "it, and `slamobs evaluate TRUTH EST` computes them from the two trajectories)"
    )


def _storage_parts(files: Sequence[Path]) -> tuple[Path, ...]:
    """The storage files of a rosbag2 recording without metadata.yaml as its parts in order: all ``NAME_N`` of one
    name and one storage format; empty when they are not."""
    named = [(PART.match(f.name), f) for f in files]
    if any(m is None for m, _ in named) or len({(m["name"], f.suffix) for m, f in named}) != 1:
        return ()
    if len({detect_container(f).kind for _, f in named}) != 1:
        return ()
    return tuple(f for _, f in sorted((int(m["index"]), f) for m, f in named))


def _metadata_text(path: Path, meta: Path) -> str | None:
    """The text of a rosbag2 directory's ``metadata.yaml``; None when there is none or it holds nothing (a recording
    that crashed while writing it)."""
    if not meta.is_file():
        return None
    try:
        text = meta.read_text(errors="replace")
    except OSError as err:
        raise InputError(path, f"cannot read metadata.yaml: {one_line(err.strerror)}") from None
    return text if text.strip() else None


# --------------------------------------------------------------------------- split ROS1 recordings

#: ``rosbag record --split`` names (and rosbag2's storage files): the recording's name, an underscore, the index
PART = re.compile(r"^(?P<name>.+)_(?P<index>\d+)\.(?:bag|db3|mcap)$")
#: a gap between two files longer than this (seconds) is reported
GAP_NOTE_S = 0.05
#: a file starting more than this (seconds) before the one before it ends is not the next part of one recording
#: (the parts of a split recording follow each other; a writer's cache may overlap them by milliseconds)
OVERLAP_ERROR_S = 1.0


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
            raise _separate_logs(directory, sorted(bags), f"{directory.name}/{directory.name}_0.bag")
        found.setdefault(m["name"], []).append((int(m["index"]), bag))
    if len(found) > 1:
        names = ", ".join(f"{n}_*.bag" for n in sorted(found))
        raise InputError(directory, f"holds the parts of {len(found)} recordings ({names}): give one directory each")
    parts = sorted(next(iter(found.values()), []))
    for _, bag in parts:
        check_input(bag, "part of a split ROS1 recording", directory_ok=False)
        with bag.open("rb") as fobj:
            if not fobj.read(len(ros1.MAGIC)).startswith(ros1.MAGIC):
                raise InputError(bag, "not a ROS1 bag (a part of the split recording in its directory)")
    return tuple(bag for _, bag in parts)


#: ``rosbag record --split -o PREFIX`` names every part after the recording's start: PREFIX_2024-05-01-12-00-00_N.bag
ROSBAG_START = re.compile(r"\d{4}-\d{2}-\d{2}-\d{2}-\d{2}-\d{2}$")


def _part_alone(path: Path) -> str:
    """A warning when the file ``path`` is one part of a split recording whose other parts lie beside it (named as
    :func:`_one_recording` takes a directory's parts): the run reads that part alone, so its result covers a part
    of the recording (``rec/rec_0.bag`` of three given as the log: the first 10 s of 30 s, with no word)."""
    m = PART.match(path.name)
    if m is None or not (m["name"] == path.parent.name or (path.suffix == ".bag" and ROSBAG_START.search(m["name"]))):
        return ""
    try:
        siblings = sorted(
            (int(s["index"]), e.name)
            for e in path.parent.iterdir()
            if e.suffix == path.suffix and (s := PART.match(e.name)) is not None and s["name"] == m["name"]
        )
    except OSError:
        return ""
    if len(siblings) < 2:
        return ""
    names = [name for _, name in siblings]
    shown = ", ".join(names) if len(names) <= 4 else f"{names[0]}, {names[1]}, ..., {names[-1]}"
    return (
        f"warning: {path.name} is one part of a split recording ({len(names)} parts beside each other: {shown}): "
        f"slamobs reads {path.name} alone, so a run's result covers that part of the recording only; give the "
        f"directory {path.parent} to read the parts as one log"
    )


def _one_recording(directory: Path, parts: tuple[Path, ...]) -> tuple[Path, ...]:
    """``parts`` when they are laid out as a recorder lays out the parts of one recording: named after their
    directory (``rec/rec_0.db3``, as rosbag2 names them), or ROS1 bags named after the recording's start time as
    ``rosbag record --split`` names them (``any/session_2024-05-01-12-00-00_0.bag``). The one rule of what a
    directory of ``NAME_N`` files is, for ``run``, ``info`` and batch discovery alike.

    Raises:
        InputError: The files are named otherwise (``flights/flight_0.mcap``, ``flight_1.mcap``): whole logs that
            only look like parts.
    """
    name = PART.match(parts[0].name)["name"]
    if name == directory.name or (parts[0].suffix == ".bag" and ROSBAG_START.search(name)):
        return parts
    raise _separate_logs(directory, parts, f"{name}/{parts[0].name}")


def _separate_logs(directory: Path, files: Sequence[Path], example: str) -> InputError:
    """The error for a directory whose log files are not the parts of one recording (``example``: how a part of one
    would be named), saying what to run instead."""
    if len(files) == 1:
        return InputError(directory, f"holds one log, {files[0].name}, not the parts of a recording: run {files[0]}")
    listed = ", ".join(p.name for p in files[:3]) + (", ..." if len(files) > 3 else "")
    return InputError(
        directory,
        f"holds {len(files)} logs ({listed}), not one recording (the parts of one are named after their directory: "
        f"{example}): run one file, or `slamobs batch {directory}` over them",
    )


def check_part_order(directory: Path, parts: Sequence[Path], spans: Sequence[tuple[int, int]]) -> None:
    """The parts follow each other in record time, as the parts of one split recording do; ``spans`` as in
    :func:`part_notes`.

    Raises:
        InputError: A part starts more than :data:`OVERLAP_ERROR_S` before the one before it ends: whole logs that
            only look like parts (two flights ``flight_0.mcap``, ``flight_1.mcap``), whose samples read as one log
            would interleave two runs of the same clock.
    """
    for (p, (_, end)), (q, (start, _)) in zip(zip(parts, spans), zip(parts[1:], spans[1:])):
        if (end - start) / 1e9 > OVERLAP_ERROR_S:
            raise InputError(
                directory,
                f"{q.name} starts {(end - start) / 1e9:.3f} s before {p.name} ends: these are not the parts of one "
                "split recording but separate logs (run each alone, or `slamobs batch` over them)",
            )


def missing_numbers(parts: Sequence[Path]) -> tuple[MissingPart, ...]:
    """The part numbers between the first and the last of ``parts`` (``NAME_N`` files, in order) that none has."""
    named = [PART.match(p.name) for p in parts]
    if any(m is None for m in named):
        return ()
    indices = [int(m["index"]) for m in named]
    name, suffix = named[0]["name"], parts[0].suffix
    return tuple(
        MissingPart(f"{name}_{i}{suffix}", int(np.searchsorted(indices, i)))
        for i in sorted(set(range(indices[0], indices[-1] + 1)) - set(indices))
    )


def holes(spans: Sequence[tuple[int, int]], missing: Sequence[MissingPart]) -> list[tuple[int, int]]:
    """The record-time spans between the parts read where missing parts were: from the last message before to the
    first after (none for a part missing before the first or after the last: the log is shorter, not holed)."""
    return [(spans[k - 1][1], spans[k][0]) for k in sorted({m.before for m in missing}) if 0 < k < len(spans)]


def _missing_note(m: MissingPart, parts: Sequence[Path], spans: Sequence[tuple[int, int]], t0: int) -> str:
    """One missing part: its span in the recording (metadata.yaml's, else the parts' around it) and what the run
    does about it."""
    head = f"split recording: {m.name}{', listed in metadata.yaml,' if m.listed else ''} is missing"
    if m.start_ns is not None and m.duration_ns is not None:
        a, b = (m.start_ns - t0) / 1e9, (m.start_ns + m.duration_ns - t0) / 1e9
        count = f", {m.messages} messages" if m.messages is not None else ""
        span = f"{a:.3f}–{b:.3f} s of the recording ({b - a:.3f} s{count}) not read"
    elif 0 < m.before < len(parts):
        a, b = (spans[m.before - 1][1] - t0) / 1e9, (spans[m.before][0] - t0) / 1e9
        between = f"{parts[m.before - 1].name} and {parts[m.before].name}"
        span = f"the {b - a:.3f} s between {between} ({a:.3f}–{b:.3f} s) not read"
    else:
        side = "before" if m.before == 0 else "after"
        span = f"what it held {side} {parts[min(m.before, len(parts) - 1)].name} not read"
    if 0 < m.before < len(parts):
        return f"{head}: {span}; a gap: the run starts a new segment after it (nothing is integrated across it)"
    return f"{head}: {span}; the run covers the parts there are"


def part_notes(
    parts: Sequence[Path], spans: Sequence[tuple[int, int]], missing: Sequence[MissingPart] = ()
) -> list[str]:
    """What a run should know of how the parts follow each other: each part's span, gaps between parts longer than
    :data:`GAP_NOTE_S`, overlaps and the parts that are missing (``missing``: metadata.yaml's, else the part numbers
    not there, :func:`missing_numbers`). ``spans`` are each part's first and last record time."""
    missing = list(missing or missing_numbers(parts))
    t0 = min([a for a, _ in spans] + [m.start_ns for m in missing if m.start_ns is not None])
    listed = ", ".join(f"{p.name} {(a - t0) / 1e9:.3f}–{(b - t0) / 1e9:.3f} s" for p, (a, b) in zip(parts, spans))
    files = "ROS1 bags" if parts[0].suffix == ".bag" else f"{parts[0].suffix} files"
    notes = [f"split recording of {len(parts)} {files} read as one: {listed}"]
    notes += [_missing_note(m, parts, spans, t0) for m in missing]
    holed = {m.before for m in missing}
    for k, ((p, (_, end)), (q, (start, _))) in enumerate(zip(zip(parts, spans), zip(parts[1:], spans[1:])), 1):
        gap = (start - end) / 1e9
        if k in holed:  # said with the missing part
            continue
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


def _explain(container: Container, err: BaseException) -> InputError:
    """Turn a reader exception into the one-line InputError for this container: out of memory, threads or
    descriptors is the machine's failure (:class:`~slamobs.pipeline.errors.ResourceError`), never a corrupt log."""
    if (machine := resource_error(err, container.path, f"reading the {container.label}")) is not None:
        return machine
    reason = one_line(err.args[0] if len(err.args) == 1 else err)
    if not reason:
        reason = "index and data disagree" if isinstance(err, AssertionError) else type(err).__name__
    reason = re.sub(r"\('(.*)',\)", r"\1", reason)  # rosbags nests args tuples in some messages
    if len(reason) > 300:  # e.g. a whole message definition quoted by the parser
        reason = reason[:297] + "..."
    if isinstance(err, PermissionError):
        return InputError(container.path, "permission denied")
    if isinstance(err, TimeRangeError):
        return InputError(container.path, reason)
    if "Profile is not ros2" in reason:
        return InputError(container.path, "unsupported MCAP file: profile is not ros2")
    if "Bag version" in reason:
        return InputError(container.path, f"unsupported {container.label}: {reason}")
    if container.kind == "rosbag2" and reason.startswith("A metadata key is missing"):
        if said := _missing_topic_key(container.path):
            return InputError(container.path, said)
    if container.kind == "db3" or container.storage == "sqlite3":
        reason += sqlitefile.cut_short(container.path)
    return InputError(container.path, f"corrupt or truncated {container.label}: {reason}")


#: the keys rosbags needs in each of metadata.yaml's ``topics_with_message_count`` entries (``message_count`` beside
#: ``topic_metadata``, the others in it)
_TOPIC_KEYS = ("name", "type", "serialization_format")


def _missing_topic_key(path: Path) -> str | None:
    """What rosbags' 'A metadata key is missing KeyError('type')' means when the key is missing from a topic's entry
    in metadata.yaml: which topic, which key, and how the log can still be read (the storage file holds its topics'
    types: a lone storage file is read without metadata.yaml). None when no topic entry lacks a key."""
    info = (read_yaml(path / "metadata.yaml", "metadata.yaml") or {}).get("rosbag2_bagfile_information")
    entries = info.get("topics_with_message_count") if isinstance(info, dict) else None
    for k, entry in enumerate(entries if isinstance(entries, list) else []):
        topic = entry.get("topic_metadata") if isinstance(entry, dict) else None
        if not isinstance(topic, dict):
            continue
        lost = [key for key in _TOPIC_KEYS if key not in topic] + (
            ["message_count"] if "message_count" not in entry else []
        )
        if lost:
            break
    else:
        return None
    name = topic.get("name") or f"number {k + 1} of topics_with_message_count"
    head = f"metadata.yaml: topic {name} has no `{lost[0]}:` key (rosbags reads no topic of the directory without it)"
    files = [path / PurePath(str(f)).name for f in info.get("relative_file_paths") or []]
    if len(files) != 1 or not files[0].is_file() or str(info.get("compression_mode") or "none").lower() != "none":
        return f"{head}: restore it in metadata.yaml"
    alone = f"give {files[0]} itself (its topics are read without metadata.yaml)"
    if lost[0] != "type" or not topic.get("name"):
        return f"{head}: restore it in metadata.yaml, or {alone}"
    try:
        with open_log(files[0]) as reader:
            stored = {c.topic: c.msgtype for c in reader.connections}
    except InputError:
        return f"{head}: restore it in metadata.yaml"
    if name not in stored:
        return f"{head}: restore it in metadata.yaml ({files[0].name} holds no topic {name})"
    return (
        f"{head}; {files[0].name} records its type, {stored[name]}: add `type: {stored[name]}` to that topic's "
        f"topic_metadata in metadata.yaml, or {alone}"
    )


# --------------------------------------------------------------------------- access


def _inflate_each(batch: RawBatch) -> RawBatch:
    """rosbag2 ``compression_mode: message``: every payload is a zstd frame of its own."""
    dctx = zstandard.ZstdDecompressor()
    blobs = [dctx.decompressobj().decompress(batch.payload(i)) for i in range(len(batch))]
    return joined(blobs, batch.conn, batch.rec_ns)


def storages(reader: AnyReader, connections: Sequence[Connection]) -> Iterator[tuple[object, ConnIds, bool]]:
    """(storage, ids, message-compressed) for every storage holding some of ``connections``."""
    for sub in reader.readers:
        storage = sub.storage if isinstance(sub, Reader2) else sub
        if isinstance(storage, DirectoryReader):
            per_message = storage.metadata.compression_mode == "message"
            for inner in storage.storages:
                mapping = {
                    x.id: i
                    for i, c in enumerate(connections)
                    if c.owner is storage
                    for x in inner.connections
                    if x.topic == c.topic and x.msgtype == c.msgtype
                }
                yield inner, ConnIds(mapping), per_message
        else:
            yield storage, ConnIds({c.id: i for i, c in enumerate(connections) if c.owner is storage}), False


def iter_batches(
    reader: AnyReader,
    path: str | Path,
    connections: Sequence[Connection],
    *,
    ordered: bool = False,
) -> Iterator[RawBatch]:
    """Messages of ``connections`` (any mix of topics) as :class:`RawBatch` es, one pass over the file.

    Without ``ordered`` batches come in file order (within a batch too); sort the decoded columns by
    record time. With ``ordered`` they come in record-time order, as rosbags yields messages.

    Raises:
        InputError: A chunk or row cannot be read (corrupt data).

    """
    try:
        for storage, ids, per_message in storages(reader, connections):
            if not ids:
                continue
            if not isinstance(storage, _READERS):  # pragma: no cover - every storage rosbags opens is replaced
                msg = f"unsupported storage {type(storage).__name__}"
                raise DamagedError(msg)
            for batch in storage.batches(ids, ordered):
                _check_record_times(batch, path, connections)
                yield _inflate_each(batch) if per_message else batch
    except InputError:
        raise
    except GeneratorExit:
        raise
    except Exception as err:  # decompression, struct, sqlite errors alike
        raise _explain(detect_container(path), err) from None


def _check_record_times(batch: RawBatch, path: str | Path, connections: Sequence[Connection]) -> None:
    """One line naming the topic when a message's record time is outside 0 to TIME_LIMIT_NS (a summary may not
    show it; rosbag2 sqlite3 files have none to check)."""
    bad = (batch.rec_ns < 0) | (batch.rec_ns >= TIME_LIMIT_NS)
    if bad.any():
        topic = connections[int(batch.conn[np.argmax(bad)])].topic
        raise InputError(
            path,
            f"{int(bad.sum())} messages have a record (log) time {TIME_RANGE}: the log's times "
            "are corrupt (repair or re-record the log)",
            topic,
        )


def iter_raw(
    reader: AnyReader,
    path: str | Path,
    connections: Collection[Connection],
) -> Iterator[tuple[Connection, int, bytes]]:
    """Yield ``(connection, record_ns, rawdata)`` of ``connections`` in record-time order.

    Read failures become InputError; errors raised by the consumer's loop body do not pass through here.
    """
    conns = list(connections)
    for batch in iter_batches(reader, path, conns, ordered=True):
        for i in range(len(batch)):
            yield conns[int(batch.conn[i])], int(batch.rec_ns[i]), batch.payload(i)


_NOTES = "_slamobs_notes"  # attribute of an opened reader: how its path was interpreted
_HOLES = "_slamobs_holes"  # attribute of an opened reader: record-time spans its missing parts leave


def missing_spans(reader: AnyReader) -> list[tuple[int, int]]:
    """The record-time spans (first, last ns) the missing parts of a split recording leave between the parts read:
    gaps the alignment must not interpolate across (empty for a whole log)."""
    return list(getattr(reader, _HOLES, ()))


def damage_notes(reader: AnyReader) -> list[str]:
    """What was recovered from truncated or unindexed files (empty for intact logs)."""
    notes = list(getattr(reader, _NOTES, ()))
    files = []
    for sub in reader.readers:
        storage = sub.storage if isinstance(sub, Reader2) else sub
        files += storage.storages if isinstance(storage, DirectoryReader) else [storage]
    for s in files:  # the parts of a split recording: each note names its file
        if isinstance(s, _READERS):
            notes += [f"{Path(s.path).name}: {text}" if len(files) > 1 else text for text in s.damage_texts()]
    return notes


# --------------------------------------------------------------------------- opening


@contextmanager
def _rosbags_path(container: Container) -> Iterator[Path]:
    """Yield a path whose suffix makes ``AnyReader`` choose the right reader."""
    path = container.path
    want = next((f.suffix for f in FORMATS if f.kind == container.kind), None)
    if container.kind in ("rosbag2", "ros2-partial", "ros1-split", "ros2-split"):  # a split recording opens its parts
        ok = container.kind != "rosbag2" or path.suffix != ".bag"
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


def _use_own_readers(reader: AnyReader) -> None:
    """Swap rosbags' readers for the ones of :data:`FORMATS` (before they open anything)."""
    ours = {f.replaces: f.reader for f in FORMATS}
    if not reader.is2:
        reader.readers = [ours[Reader1](p) for p in reader.paths]
        return
    for sub in reader.readers:
        if isinstance(sub.storage, DirectoryReader):
            sub.storage.STORAGE_PLUGINS = {
                **DirectoryReader.STORAGE_PLUGINS,
                **{f.storage_id: f.reader for f in FORMATS if f.storage_id},
            }
        elif type(sub.storage) in ours:
            sub.storage = ours[type(sub.storage)](sub.storage.path)


class _FallbackTypes:
    """The typestore rosbags falls back to for a bag that stores no message definitions, built only if one does
    (rosbags reads nothing but its ``fielddefs``; building the ROS 2 store imports its predecessors, ~0.1 s)."""

    @property
    def fielddefs(self):
        return get_typestore(_FALLBACK_STORE).fielddefs


@contextmanager
def open_log(path: str | Path) -> Iterator[AnyReader]:
    """Open a ROS1 bag, rosbag2 directory, MCAP or db3 file as an opened rosbags ``AnyReader``.

    Truncated ROS1 bags and MCAP files open with what could be recovered (see :func:`damage_notes`).
    Reader errors raised inside the ``with`` block (corrupt chunks, undecodable messages) are turned into
    :class:`InputError` as well.

    Raises:
        InputError: Missing path, unknown container, corrupt or truncated file.

    """
    container = detect_container(path)
    with _rosbags_path(container) as rpath:
        try:
            reader = AnyReader(list(container.parts or [rpath]), default_typestore=_FallbackTypes())  # type: ignore[arg-type]
            _use_own_readers(reader)
            reader.open()
        except Exception as err:  # any reader failure means a bad file
            raise _explain(container, err) from None
        notes = [container.note] if container.note else []
        if container.parts:  # how the files follow each other in time
            spans = [(r.start_time, r.end_time - 1) for r in reader.readers]
            try:
                check_part_order(container.path, container.parts, spans)
            except InputError:
                reader.close()
                raise
            missing = container.missing or missing_numbers(container.parts)
            notes += part_notes(container.parts, spans, missing)
            setattr(reader, _HOLES, holes(spans, missing))
        if notes:
            setattr(reader, _NOTES, notes)
        try:
            yield reader
        except (Ros1ReaderError, Ros2ReaderError, SerdeError, DamagedError) as err:
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
