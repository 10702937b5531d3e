"""Trajectory files and pose topics as :class:`PoseStream`: TUM, EuRoC CSV, KITTI, ``poses.parquet``, and
``geometry_msgs/PoseStamped`` / ``nav_msgs/Odometry`` topics of a log; TUM export of a poses table.

These are the inputs evo users already have, read the way evo 1.38.1 reads them (same columns, same quaternion
order, rows kept in file order) so that errors computed on them are comparable. Stamps are parsed exactly from
their decimal text into int64 nanoseconds (evo keeps float seconds, whose 0.24 µs resolution at 1.7e9 s can
break exact ties differently). Every failure is an :class:`InputError` naming the file.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from slamobs.pipeline.errors import InputError, one_line, resource_error
from slamobs.pipeline.paths import check_input, read_bytes, read_text
from slamobs.pipeline.streams import PoseStream

from .container import detect_container, evo_result_hint, open_log
from .decode import decode_rows, pose_stream
from .roles import EDGE_ARROW, TRUTH_FORMS, did_you_mean, parse_edge, topics_of
from .rows import LAYOUTS

NS_PER_S = 1_000_000_000
FORMATS = ("tum", "euroc", "kitti", "parquet", "topic")
POSE_COLUMNS = ("t_ns", "x", "y", "z", "qx", "qy", "qz", "qw")
_PLAIN_DECIMAL = re.compile(r"^[+-]?\d+(\.\d*)?$")
_SEPARATOR = re.compile(r"[,\s]+")
#: largest |RᵀR − I| entry of a KITTI rotation: real files, written with 6-9 significant digits, stay below 1e-6
ROTATION_TOLERANCE = 1e-4


@dataclass(frozen=True)
class Trajectory:
    """A loaded trajectory and how it was read.

    ``timed`` is False for KITTI files without a times file: their poses carry no stamps (``t_ns`` holds the
    row index) and are paired by index, as evo pairs ``PosePath3D`` files.
    """

    stream: PoseStream
    format: str
    name: str
    timed: bool = True
    #: (N, 3, 3) rotation matrices as written in the file (KITTI), used instead of the quaternions so that
    #: slightly non-orthonormal matrices give the numbers evo gives
    rotations: np.ndarray | None = None


def stamp_ns(text: str) -> int:
    """Seconds written in decimal (``1311868164.363181``, ``1.403715529112143517e+09``) to exact nanoseconds
    (half-even rounding below 1 ns)."""
    if _PLAIN_DECIMAL.match(text):
        whole, _, frac = text.partition(".")
        if len(frac) <= 9:
            sign = -1 if whole.startswith("-") else 1
            return int(whole) * NS_PER_S + sign * int(frac.ljust(9, "0") or "0")
    try:
        return int((Decimal(text) * NS_PER_S).to_integral_value())
    except InvalidOperation:
        raise ValueError(f"not a number: {text!r}") from None


def _read_bytes(path: Path, what: str) -> bytes:
    check_input(path, f"{what} file", directory_ok=False)
    return read_bytes(path, f"{what} file")


def _data_lines(text: str | bytes):
    """(line number, fields) of the rows of a file, as :func:`_rows` reads them (blank and ``#`` lines skipped);
    ``text`` as bytes: ASCII (as the fast path of :func:`_rows` returns it)."""
    if isinstance(text, bytes):
        text = text.decode("ascii")
    for lineno, line in enumerate(text.replace(",", " ").splitlines(), 1):
        tok = line.split()
        if tok and not tok[0].startswith("#"):
            yield lineno, tok


def _line_of(text: str | bytes, row: int) -> int:
    """The line number of row ``row`` (from 0) of :func:`_rows`, for naming it in an error."""
    return next(lineno for k, (lineno, _) in enumerate(_data_lines(text)) if k == row)


def _row_error(
    path: Path, text: str, min_fields: int, fixed: int | None, what: str, numeric_from: int = 1
) -> InputError:
    """The first offending line of a file the fast parser rejected, named with its number; ``numeric_from``: the
    first field that must be a number (a stamp before it is parsed by :func:`_stamps`)."""
    for lineno, tok in _data_lines(text):
        if (fixed is not None and len(tok) != fixed) or len(tok) < min_fields:
            want = f"{fixed}" if fixed is not None else f"at least {min_fields}"
            return InputError(path, f"line {lineno}: {what} rows have {want} fields, this one has {len(tok)}")
        try:
            numbers = [float(v) for v in tok[numeric_from:min_fields]]
        except ValueError:
            return InputError(path, f"line {lineno}: not a number in {' '.join(tok)[:80]!r}")
        if not np.isfinite(numbers).all():  # inf / nan would make every error statistic inf / nan
            return InputError(path, f"line {lineno}: not a finite number in {' '.join(tok)[:80]!r}")
    return InputError(path, f"unreadable {what} file")


#: a file with any of these takes the general path: comments, commas, and whitespace other than spaces and
#: newlines, which Python's ``str.split`` (the error path, :func:`_data_lines`) treats as a separator too
_NOT_PLAIN_TEXT = b"#,\t\x0b\x0c\x1c\x1d\x1e\x1f"


def _plain(text: bytes) -> bool:
    """Whether ``text`` holds none of :data:`_NOT_PLAIN_TEXT` (``bytes.find``: memchr, far faster than a regex)."""
    return not any(text.find(c) >= 0 for c in _NOT_PLAIN_TEXT)


def _fast_rows(text: bytes, min_fields: int, fixed: int | None, numeric_from: int):
    """:func:`_rows` for the regular case, through pyarrow's CSV reader (numbers parsed by fast_float, correctly
    rounded like ``float()``): ASCII rows of fields separated by single spaces, every field a finite number, no
    comments. The first column comes back as float64 (``numeric_from=0``) or as a pyarrow string array whose
    tokens are all non-empty. ``None`` for anything else: the general path then parses it, or names its fault.

    With ``fixed`` columns every field but a text first one is parsed as a number, which refuses each of
    :data:`_NOT_PLAIN_TEXT` but a tab before or after a number (where it separates as a space does): only the
    first column's text is searched for them. Otherwise (extra columns, not parsed) the whole file is."""
    if not text.isascii() or (fixed is None and not _plain(text)):
        return None
    import pyarrow as pa  # lazy, like pandas in _rows
    import pyarrow.compute as pc
    from pyarrow import csv

    types = {f"f{k}": pa.float64() for k in range(numeric_from == 1, fixed or min_fields)}
    try:
        table = csv.read_csv(
            pa.py_buffer(text),
            read_options=csv.ReadOptions(autogenerate_column_names=True, block_size=1 << 24),
            parse_options=csv.ParseOptions(delimiter=" ", quote_char=False),
            convert_options=csv.ConvertOptions(column_types={"f0": pa.string(), **types}),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return None
    if table.num_rows == 0 or table.num_columns < min_fields or fixed not in (None, table.num_columns):
        return None
    cols = [table.column(k).combine_chunks() for k in range(min_fields)]
    if any(c.null_count for c in cols[numeric_from == 1 :]):
        return None
    values = np.column_stack([c.to_numpy() for c in cols[1:]]) if min_fields > 1 else np.empty((table.num_rows, 0))
    first = cols[0].to_numpy() if numeric_from == 0 else cols[0]
    if not np.isfinite(values).all() or (numeric_from == 0 and not np.isfinite(first).all()):
        return None
    if numeric_from == 1 and pc.min(pc.utf8_length(first)).as_py() == 0:
        return None
    if numeric_from == 1 and fixed is not None and not _plain(_text_bytes(first)):
        return None
    return first, values


def _text_bytes(strings) -> bytes:
    """The characters of a pyarrow string array, one after the other."""
    offsets = np.frombuffer(strings.buffers()[1], np.int32)[strings.offset : strings.offset + len(strings) + 1]
    return strings.buffers()[2].to_pybytes()[offsets[0] : offsets[-1]] if len(strings) else b""


def _texts(first) -> np.ndarray:
    """The first column of :func:`_rows` as a NumPy array of str (the fast path gives a pyarrow array)."""
    return first if isinstance(first, np.ndarray) else np.asarray(first.to_pylist(), dtype=str)


def _rows(
    path: Path, min_fields: int, fixed: int | None, what: str, numeric_from: int = 1
) -> tuple[np.ndarray, np.ndarray, str | bytes]:
    """First column as text and the next ``min_fields - 1`` columns as floats (``fixed``: exactly that many fields
    per row), and the text (for :func:`_line_of`; the file's ASCII bytes where the fast path read it). Fields are
    separated by spaces, tabs or commas; ``#`` starts a comment line. Parsed by pandas' C tokenizer (a 100k-line
    file in a fraction of a second); any irregular row, or a number that is not finite, is named by its line.
    ``numeric_from=0``: the first column must be a finite number too (KITTI)."""
    raw = _read_bytes(path, what)
    fast = _fast_rows(raw, min_fields, fixed, numeric_from)
    if fast is not None:
        return *fast, raw
    import pandas as pd  # lazy: pandas takes a noticeable part of a second, and only irregular text files need it

    text = read_text(path, f"{what} file", raw=raw)
    try:
        df = pd.read_csv(
            io.StringIO(text.replace(",", " ")),
            sep=r"\s+",
            header=None,
            comment="#",
            dtype={0: str},
            engine="c",
            skip_blank_lines=True,
        )
    except (pd.errors.ParserError, ValueError):
        raise _row_error(path, text, min_fields, fixed, what) from None
    except pd.errors.EmptyDataError:
        raise InputError(path, f"no poses in {what} file") from None
    if len(df) == 0:
        raise InputError(path, f"no poses in {what} file")
    ncols = df.shape[1]
    if (fixed is not None and ncols != fixed) or ncols < min_fields:
        raise _row_error(path, text, min_fields, fixed, what)
    values = df.iloc[:, 1:min_fields]
    # a column with text (pandas >= 3: a string dtype that NumPy cannot interpret) or true/false is not numbers
    if not all(pd.api.types.is_numeric_dtype(t) and not pd.api.types.is_bool_dtype(t) for t in values.dtypes):
        raise _row_error(path, text, min_fields, fixed, what)
    values = values.to_numpy(np.float64)
    if fixed is not None and df.iloc[:, min_fields:].isna().to_numpy().any() or not np.isfinite(values).all():
        raise _row_error(path, text, min_fields, fixed, what, numeric_from)
    tokens = df[0].to_numpy(dtype=object).astype(str)  # not to_numpy(str): a NaN cell made it one character wide
    if numeric_from == 0:
        try:
            ok = np.isfinite(tokens.astype(np.float64)).all()
        except ValueError:
            ok = False
        if not ok:
            raise _row_error(path, text, min_fields, fixed, what, numeric_from)
    return tokens, values, text


def _check_quats(path: Path, quat_xyzw: np.ndarray, where) -> None:
    """Every quaternion can be normalised: a zero one (all four 0, a placeholder for "no rotation") would make
    the rotation errors NaN. ``where(k)`` names row ``k`` (``line 3``)."""
    n2 = np.einsum("ij,ij->i", quat_xyzw, quat_xyzw)
    bad = np.flatnonzero(~((n2 > 0) & np.isfinite(n2)))
    if bad.size:
        k = int(bad[0])
        problem = (
            "zero quaternion: no rotation" if n2[k] == 0 else f"quaternion {quat_xyzw[k].tolist()} cannot be normalised"
        )
        raise InputError(path, f"{where(k)}: {problem}")


_POW10 = 10 ** np.arange(19, dtype=np.int64)
_WIDTH = 24


def _plain_stamps_ns(tokens: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised exact parse of plain decimal stamps ``d{1,10}[.d{0,9}]`` on the bytes of the text; returns
    the nanoseconds and which tokens were plain (the others need :func:`stamp_ns`)."""
    width = max(1, min(_WIDTH, int(np.char.str_len(tokens).max()) if tokens.size else 1))
    u = np.asarray(tokens).astype(f"S{width}").view(np.uint8).reshape(-1, width)
    j = np.arange(width, dtype=np.int64)
    digit = (u >= 48) & (u <= 57)
    dot = u == 46
    inside = u != 0
    length = inside.sum(axis=1)
    n_dot = dot.sum(axis=1)
    dot_at = np.where(n_dot > 0, np.argmax(dot, axis=1), length)
    plain = (
        ((digit | dot) == inside).all(axis=1)
        & (n_dot <= 1)
        & (dot_at >= 1)
        & ((dot_at <= 9) | ((dot_at == 10) & (u[:, 0] < 57)))  # < 9e9 s: no int64 overflow
        & (length - dot_at - 1 <= 9)
    )
    rel = dot_at[:, None] - j[None, :]  # digit position relative to the dot: 1 = units, 0 = the dot
    exp = np.where(rel > 0, rel + 8, rel + 9)  # ns per unit of the digit, as a power of ten
    weight = np.where(digit & (exp >= 0), _POW10[np.clip(exp, 0, 18)], 0)
    ns = ((u.astype(np.int64) - 48) * weight).sum(axis=1)
    return ns, plain


def _arrow_stamps_ns(tokens) -> np.ndarray | None:
    """Exact nanoseconds of a pyarrow string array of stamps in seconds, through pyarrow's exact decimal parse
    (scale 9: the unscaled integer is the stamp in ns); ``None`` when any stamp has more than 9 decimals, is not a
    decimal or is out of int64 range (then :func:`_stamps` parses them one by one, rounding like
    :func:`stamp_ns`)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    try:
        dec = pc.cast(tokens, pa.decimal128(38, 9))
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        return None
    if dec.null_count:
        return None
    words = np.frombuffer(dec.buffers()[1], np.int64).reshape(-1, 2)[dec.offset : dec.offset + len(dec)]
    low, high = words[:, 0], words[:, 1]
    if not np.array_equal(high, low >> 63):  # the 128-bit value does not fit in int64
        return None
    return low.copy()


def _stamps(path: Path, tokens: np.ndarray) -> np.ndarray:
    """Exact nanoseconds of decimal-second stamps: vectorised for plain decimals with up to 9 decimals, through
    :func:`stamp_ns` for the rest (signs, exponents, more digits)."""
    if not isinstance(tokens, np.ndarray):
        fast = _arrow_stamps_ns(tokens)
        if fast is not None:
            return fast
    tokens = np.asarray(_texts(tokens), dtype=str)
    out, plain = _plain_stamps_ns(tokens)
    plain &= np.char.str_len(tokens) <= _WIDTH
    for k in np.flatnonzero(~plain):
        token = str(tokens[k])
        try:
            out[k] = stamp_ns(token)
        except ValueError as err:
            raise InputError(path, f"row {k + 1}: bad timestamp {token!r}: {err}") from None
        except OverflowError:
            raise InputError(path, f"row {k + 1}: timestamp {token!r} is out of range (int64 nanoseconds)") from None
    return out


def _stream(name: str, t_ns: np.ndarray, position: np.ndarray, quat_xyzw: np.ndarray, frame: str = "") -> PoseStream:
    return PoseStream(
        name, frame, "", t_ns, t_ns.copy(), np.ascontiguousarray(position), np.ascontiguousarray(quat_xyzw)
    )


def load_tum(path: str | Path) -> PoseStream:
    """TUM trajectory: ``timestamp tx ty tz qx qy qz qw`` per line (seconds), ``#`` comments."""
    path = Path(path)
    first, v, text = _rows(path, 8, 8, "TUM")
    _check_quats(path, v[:, 3:7], lambda k: f"line {_line_of(text, k)}")
    return _stream(str(path), _stamps(path, first), v[:, 0:3], v[:, 3:7])


def load_euroc_csv(path: str | Path) -> PoseStream:
    """EuRoC ``state_groundtruth_estimate0/data.csv``: ``t [ns], p xyz, q wxyz, ...`` (extra columns ignored)."""
    path = Path(path)
    first, v, text = _rows(path, 8, None, "EuRoC CSV")
    _check_quats(path, v[:, 3:7], lambda k: f"line {_line_of(text, k)}")
    try:
        t_ns = _texts(first).astype(np.int64)
    except ValueError:
        t_ns = _stamps(path, first) // NS_PER_S  # written as float nanoseconds
    return _stream(str(path), t_ns, v[:, 0:3], v[:, [4, 5, 6, 3]])


def load_kitti(path: str | Path, times: str | Path | None = None) -> PoseStream:
    """KITTI poses: the first three rows of the 4x4 pose matrix per line.

    Without ``times`` (one stamp in seconds per line, KITTI ``times.txt``) the stamps are the row indices in
    nanoseconds (0, 1, 2, ...), meaningful only for pairing by index. With them, the times must increase: the
    rows are consecutive frames, so a time that repeats or goes back means the times belong to other poses (or
    were written with too few digits). Each rotation block must be a rotation to ``ROTATION_TOLERANCE`` (as
    written, a few digits, not exactly orthonormal); it becomes a quaternion (which re-orthonormalises it);
    :func:`kitti_rotations` gives the matrices as written.
    """
    return _kitti(Path(path), times)[0]


def kitti_rotations(path: str | Path) -> np.ndarray:
    """The (N, 3, 3) rotation blocks of a KITTI pose file, as written."""
    path = Path(path)
    first, v, _ = _rows(path, 12, 12, "KITTI", numeric_from=0)
    return np.ascontiguousarray(np.column_stack([first.astype(np.float64), v]).reshape(-1, 3, 4)[:, :, :3])


def _kitti(path: Path, times: str | Path | None) -> tuple[PoseStream, np.ndarray]:
    first, v, text = _rows(path, 12, 12, "KITTI", numeric_from=0)
    m = np.column_stack([first.astype(np.float64), v]).reshape(-1, 3, 4)
    from slamobs.pipeline.lie import rots_to_quats  # lazy: compiled kernels, needed for KITTI files only

    rot = np.ascontiguousarray(m[:, :, :3])
    off = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    bad = np.flatnonzero(~((off <= ROTATION_TOLERANCE) & (det > 0)))
    if bad.size:
        k = int(bad[0])
        raise InputError(
            path, f"line {_line_of(text, k)}: not a rotation matrix (max |RᵀR − I| = {off[k]:.3g}, det = {det[k]:.3g})"
        )
    quat = rots_to_quats(rot)
    if times is None:
        t_ns = np.arange(m.shape[0], dtype=np.int64)
    else:
        tpath = Path(times)
        tok, _, ttext = _rows(tpath, 1, 1, "KITTI times")
        t_ns = _stamps(tpath, tok)
        tok = _texts(tok)
        if t_ns.shape[0] != m.shape[0]:
            raise InputError(tpath, f"{t_ns.shape[0]} stamps for {m.shape[0]} poses in {path}")
        step = np.diff(t_ns)
        if (step <= 0).any():
            k = int(np.argmax(step <= 0)) + 1
            how = "times decrease" if step[k - 1] < 0 else "time repeats"
            raise InputError(
                tpath,
                f"{how} at line {_line_of(ttext, k)} ({tok[k]} after {tok[k - 1]}): KITTI rows are consecutive frames",
            )
    return _stream(str(path), t_ns, m[:, :, 3], quat), rot


def load_poses_parquet(path: str | Path) -> PoseStream:
    """``poses.parquet`` of a run (``t_ns, x y z, qx qy qz qw``), in file order."""
    import pyarrow.parquet as pq  # lazy: pyarrow is slow to import, needed for Parquet trajectories only

    path = Path(path)
    try:
        table = pq.read_table(path)
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except Exception as err:  # pyarrow raises several types for a bad file
        if (machine := resource_error(err, path, "reading the trajectory")) is not None:
            raise machine from None
        raise InputError(path, f"cannot read Parquet: {one_line(err)}") from None
    missing = [c for c in POSE_COLUMNS if c not in table.column_names]
    if missing:
        raise InputError(path, f"not a poses table: lacks column(s) {missing}")
    import pyarrow as pa  # lazy: as pyarrow.parquet above

    for c in POSE_COLUMNS:
        kind = table.schema.field(c).type
        if not (pa.types.is_integer(kind) or (c != "t_ns" and pa.types.is_floating(kind))):
            want = "integer nanoseconds" if c == "t_ns" else "numbers"
            raise InputError(path, f"not a poses table: column {c} holds {kind}, not {want}")
        if table.column(c).null_count:
            k = table.column(c).is_null().to_pylist().index(True)
            raise InputError(path, f"row {k} (from 0): no value in column {c}")
    cols = {c: table.column(c).to_numpy() for c in POSE_COLUMNS}
    pos = np.column_stack([cols["x"], cols["y"], cols["z"]]).astype(np.float64)
    quat = np.column_stack([cols["qx"], cols["qy"], cols["qz"], cols["qw"]]).astype(np.float64)
    finite = np.isfinite(np.column_stack([pos, quat]))
    if not finite.all():
        k, j = (int(i[0]) for i in np.nonzero(~finite))
        raise InputError(path, f"row {k} (from 0): not a finite number in column {POSE_COLUMNS[1 + j]}")
    _check_quats(path, quat, lambda k: f"row {k} (from 0)")
    return _stream(str(path), cols["t_ns"].astype(np.int64), pos, quat)


#: What to do with a GPS fix named as a trajectory (robot_localization's test1 has /fix beside its odometry): it is
#: latitude, longitude and altitude, no orientation, so no pose to pair with an estimate's.
GPS_FIX_HINT = (
    ": a GPS fix is latitude and longitude with no orientation, not a pose in metres; convert it to a local "
    "trajectory first (robot_localization's navsat_transform_node writes an Odometry topic of it, with the heading "
    "from the IMU) and name that topic, or a TUM file of its positions in metres"
)


def load_pose_topic(log: str | Path, topic: str, *, time_source: str = "header") -> PoseStream:
    """A pose topic of a log (``geometry_msgs/PoseStamped``, ``nav_msgs/Odometry``, or any type the readers
    decode into a position and a quaternion), with header stamps or, with ``time_source="record"``, the record
    time; decoded and cleaned by the readers (sorted, exact duplicates dropped)."""
    log = Path(log)
    with open_log(log) as reader:
        table = topics_of(reader)
        if topic not in table:
            alt = "/" + topic.lstrip("/") if "/" + topic.lstrip("/") in table else topic.lstrip("/")
            if alt not in table:
                known = ", ".join(sorted(table)[:12]) or "none"
                mean = did_you_mean(topic, sorted(table))
                raise InputError(log, f"topic not in the log ({mean}topics: {known})", topic)
            topic = alt
        meta, conns = table[topic]
        layout = LAYOUTS.get(meta.msgtype)
        if layout is None or not {"position", "quat_xyzw"} <= set(layout.columns):
            poses = sorted(t for t, lay in LAYOUTS.items() if {"position", "quat_xyzw"} <= set(lay.columns))
            raise InputError(
                log,
                f"type {meta.msgtype} is not a trajectory (expected one of {', '.join(poses)})"
                + GPS_FIX_HINT * (meta.msgtype == "sensor_msgs/msg/NavSatFix"),
                topic,
            )
        stream, _ = pose_stream(decode_rows(reader, log, topic, conns))
    if len(stream) == 0:
        raise InputError(log, "no poses on topic", topic)
    if time_source == "record":
        stream = PoseStream(**{**stream.__dict__, "t_ns": stream.rec_ns})
    return stream


def _is_log(path: Path) -> bool:
    try:
        detect_container(path)
    except InputError:
        return False
    return True


def detect_format(path: str | Path) -> str:
    """``tum``, ``euroc``, ``kitti`` or ``parquet`` from the content of ``path``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no such file" if not path.exists() else "not a trajectory file")
    with path.open("rb") as f:
        head = f.read(4096)
    if head.startswith(b"PAR1"):
        return "parquet"
    for raw in head.decode("utf-8-sig", errors="replace").splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        tok = _SEPARATOR.split(line)
        if "," in line and len(tok) >= 8 and tok[0].isdigit() and len(tok[0]) >= 15:
            return "euroc"
        if len(tok) == 8:
            return "tum"
        if len(tok) == 12:
            return "kitti"
        if len(tok) == 1 and re.fullmatch(r"[+-]?[\d.]+(?:[eE][+-]?\d+)?", tok[0]):
            raise InputError(
                path,
                "one number a line: KITTI's times.txt, not poses? KITTI pose files are paired by index "
                "(`slamobs evaluate kitti GT.txt EST.txt`); a run takes such stamps for a KITTI truth as "
                "evaluation.truth_times",
            )
        break
    if said := evo_result_hint(path):  # a zip without evo's stats.json gets ""
        raise InputError(path, "not a trajectory" + said)
    raise InputError(
        path,
        "unknown trajectory format (expected TUM, EuRoC CSV, KITTI or poses.parquet; a log needs a topic: LOG:TOPIC)",
    )


def split_topic_source(source: str) -> tuple[Path, str] | None:
    """``LOG:TOPIC`` -> (log, topic) when the part before a ``:`` is an existing log, else None."""
    if Path(source).exists():
        return None
    for k, ch in enumerate(source):
        if ch == ":" and k > 0:
            log = Path(source[:k])
            if log.exists() and _is_log(log):
                return log, source[k + 1 :]
    return None


@dataclass(frozen=True)
class TruthSpec:
    """A truth as given (``topics.truth``, ``evaluation.truth_file``, ``report --truth``, ``evaluate TRUTH``):
    ``kind`` is ``topic``, ``edge`` (a TF edge ``parent->child``) or ``file`` (TUM / EuRoC CSV / KITTI); ``log``
    is the log a topic or edge is read from when given as ``LOG:TOPIC`` (None: the run's own log)."""

    kind: str
    name: str
    log: Path | None = None


def parse_truth(text: str | Path) -> TruthSpec:
    """The one truth grammar: ``LOG:TOPIC`` or ``LOG:parent->child`` (an existing log), ``parent->child``, an
    existing file, else a topic of the run's log. ROS names hold no ``:``, so a ``:`` names a log.

    Raises:
        InputError: Empty, a malformed TF edge, or ``X:Y`` where ``X`` is no log.

    """
    text = str(text).strip()
    if not text:
        raise InputError("truth", f"empty truth specification ({TRUTH_FORMS})")
    spec = None
    if (found := split_topic_source(text)) is not None:
        spec = TruthSpec("edge" if EDGE_ARROW in found[1] else "topic", found[1].strip(), found[0])
    elif Path(text).exists():
        return TruthSpec("file", text)
    elif ":" in text:
        where = text.rsplit(":", 1)[0] if EDGE_ARROW not in text else text.split(":", 1)[0]
        raise InputError(where, f"no such log: truth {text!r} reads as LOG:TOPIC ({TRUTH_FORMS})")
    elif "." in Path(text).name and EDGE_ARROW not in text:  # ROS topic names hold no '.': a file that is not there
        raise InputError(text, f"no such file (a name with a '.' is a file: topics hold none; {TRUTH_FORMS})")
    spec = spec or TruthSpec("edge" if EDGE_ARROW in text else "topic", text)
    if spec.kind == "edge" and not all(parse_edge(spec.name) or ("",)):
        raise InputError(spec.log or "truth", f"truth TF edge {spec.name!r} is not 'parent->child' ({TRUTH_FORMS})")
    if not spec.name:
        raise InputError(spec.log or "truth", f"no topic after the log in {text!r} ({TRUTH_FORMS})")
    return spec


def read_trajectory(source: str | Path, fmt: str | None = None, *, kitti_times: str | Path | None = None) -> Trajectory:
    """Load ``source``: a TUM / EuRoC CSV / KITTI file, a ``poses.parquet``, or ``LOG:TOPIC``.

    ``fmt`` forces the file format (one of ``FORMATS`` minus ``topic``); by default it is detected from the
    content.
    """
    source = str(source)
    topic = split_topic_source(source) if fmt in (None, "topic") else None
    if topic is not None:
        return Trajectory(load_pose_topic(*topic), "topic", topic[1])
    if fmt == "topic":
        raise InputError(source, "not LOG:TOPIC with an existing log")
    path = Path(source)
    if path.is_dir():
        try:
            detect_container(path)
        except InputError as err:  # say why it is not a log either (e.g. a rosbag2 folder without metadata.yaml)
            why = err.problem if err.path == str(path) else str(err)
            raise InputError(path, f"a folder that is neither a trajectory file nor a log: {why}") from None
    if path.is_dir() or (path.is_file() and _is_log(path)):
        raise InputError(path, "a log holds several topics: name one as LOG:TOPIC")
    fmt = fmt or detect_format(path)
    if fmt not in FORMATS:
        raise InputError(path, f"unknown format {fmt!r} (one of {', '.join(FORMATS[:-1])})")
    if fmt == "tum":
        return Trajectory(load_tum(path), fmt, source)
    if fmt == "euroc":
        return Trajectory(load_euroc_csv(path), fmt, source)
    if fmt == "kitti":
        stream, rot = _kitti(path, kitti_times)
        return Trajectory(stream, fmt, source, timed=kitti_times is not None, rotations=rot)
    return Trajectory(load_poses_parquet(path), fmt, source)


def format_stamp(t_ns: int) -> str:
    """Exact decimal seconds of an int nanosecond stamp (``1311868164.363181000``)."""
    t = int(t_ns)
    sign = "-" if t < 0 else ""
    q, r = divmod(abs(t), NS_PER_S)
    return f"{sign}{q}.{r:09d}"


def tum_text(t_ns: np.ndarray, position: np.ndarray, quat_xyzw: np.ndarray) -> str:
    """TUM lines ``t x y z qx qy qz qw``: stamps exact to the nanosecond (:func:`format_stamp`), values as
    ``repr`` writes them (round-trip precision); formatted in compiled code (:mod:`.floattext`)."""
    from .floattext import stamped_rows  # lazy: compiled formatting, needed only when writing TUM

    return stamped_rows(
        np.asarray(t_ns), np.asarray(position).reshape(-1, 3), np.asarray(quat_xyzw).reshape(-1, 4)
    ).decode()


def write_tum(path: str | Path, stream: PoseStream) -> Path:
    """Write ``stream`` as a TUM trajectory file (readable by evo and :func:`load_tum`), block by block."""
    from .floattext import iter_stamped_rows  # lazy: as in tum_text

    path = Path(path)
    with path.open("wb") as f:
        for block in iter_stamped_rows(np.asarray(stream.t_ns), stream.position, stream.quat_xyzw):
            f.write(block)
    return path


def poses_table_stream(poses, name: str = "poses") -> PoseStream:
    """A poses table (DataFrame with ``t_ns, x y z, qx qy qz qw``) as a PoseStream, rows in time order."""
    missing = [c for c in POSE_COLUMNS if c not in poses.columns]
    if missing:
        raise ValueError(f"poses table lacks column(s) {missing}; has {list(poses.columns)}")
    t = poses["t_ns"].to_numpy(np.int64)
    order = np.argsort(t, kind="stable")
    pos = poses[["x", "y", "z"]].to_numpy(np.float64)[order]
    quat = poses[["qx", "qy", "qz", "qw"]].to_numpy(np.float64)[order]
    return _stream(name, t[order], pos, quat)
