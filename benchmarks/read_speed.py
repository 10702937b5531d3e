"""Messages per second decoding fixed-layout topics: rosbags (AnyReader + deserialize) vs. slamobs readers.

    .venv/bin/python benchmarks/read_speed.py [--seconds 60] [--repeat 3] [--no-real] [LOG ...]

For every log (by default a simulated figure8 of ``--seconds`` at 200 Hz IMU in all three containers,
plus every log of ``../shared/realdata`` when present) both readers decode every topic whose type is in
``rows.LAYOUTS`` (Imu, Odometry, TwistStamped, MagneticField, PoseStamped, ...) into the same columns:
header stamp, record time, the layout's values and the frame ids.

* rosbags: ``AnyReader`` opens the log, ``messages()`` yields every message of those topics, each is
  deserialised and its fields copied into preallocated arrays (what slamobs did before fastdecode).
* ours: ``open_log``, then ``fastdecode.read_rows`` for all those topics in one pass.
* per topic: ``open_log``, then one ``decode_rows`` per topic (each pass reads the chunks again), which
  is what ``read_log`` does unless it prefetches with ``read_rows``.

"msg/s" is messages / time from the opened log to the decoded columns; "incl. open" is the speed-up
when opening (rosbags' ROS1 index, metadata YAML, typestore; the same code for rosbag2 on both sides)
is counted too. Each side runs once to warm up (numba kernels, rosbags' generated deserialisers), then
``--repeat`` times alternating; the best CPU time of this process is kept, so other load on a shared
machine counts less. "identical" compares stamps, record times, frame ids and the bits of every value.

"inflate bound" is rosbags' read time over the CPU time of only reading and decompressing the chunks that
hold those topics (ROS1 and MCAP; both readers must do at least that): the largest speed-up any reader can
reach on that file. On bz2-compressed bags libbz2 alone takes most of the time, which caps the speed-up there.

``--tf`` prints another table instead: transforms per second decoding TF topics (``tf2_msgs/TFMessage``,
``tf/tfMessage``) with ``decode.decode_tf``, through rosbags' deserialiser (the path before tfdecode, still the
fallback) and from the bytes (``tfdecode``), on a simulated dynamic ``/tf`` (``--seconds`` at 100 Hz, 3
transforms per message, all three containers) and on every TF topic of ``../shared/realdata`` (the bz2 of
tagslam test_11 is unpacked to a temporary bag). Same timing rules; "identical" compares stamps, record
times, parent and child names and the bits of every value.
"""

from __future__ import annotations

import argparse
import bz2
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from slamobs.pipeline.readers import decode, tfdecode
from slamobs.pipeline.readers.chunks import Chunked, read_unit
from slamobs.pipeline.readers.container import open_log, storages
from slamobs.pipeline.readers.decode import decode_rows, decode_tf
from slamobs.pipeline.readers.rows import LAYOUTS, TfRows, frame_name
from slamobs.pipeline.readers.fastdecode import read_rows
from slamobs.pipeline.readers.roles import TF_TYPES, topics_of
from slamobs.pipeline.simulate import make_typestore, simulate, write_log
from slamobs.pipeline.simulate.logwriter import write_raw_log

sys.path.insert(0, str(Path(__file__).resolve().parent))
from end_to_end import MIN_READ_SPEEDUP, load, met  # noqa: E402

REALDATA = Path(os.environ.get("SLAMOBS_REALDATA") or Path(__file__).resolve().parents[2] / "shared" / "realdata")
Columns = dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]]  # topic -> t, rec, values, frames


def _rosbags(path: Path) -> tuple[Columns, int, float, float]:
    """Columns, message count, CPU seconds to open, CPU seconds to read."""
    start = time.process_time()
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        opened = time.process_time()
        conns = [c for c in reader.connections if c.msgtype in LAYOUTS]
        if not conns:  # messages(connections=[]) would mean "all"
            return {}, 0, opened - start, 0.0
        n = {t: 0 for t in {c.topic for c in conns}}
        size = {t: max(sum(c.msgcount for c in conns if c.topic == t), 1) for t in n}
        out = {
            t: (np.empty(size[t], np.int64), np.empty(size[t], np.int64), np.empty((size[t], LAYOUTS[m].width)), [])
            for t, m in {c.topic: c.msgtype for c in conns}.items()
        }
        for conn, rec, raw in reader.messages(connections=conns):
            msg: Any = reader.deserialize(raw, conn.msgtype)
            t_ns, rec_ns, values, frames = out[conn.topic]
            i = n[conn.topic]
            if i == t_ns.shape[0]:
                continue  # index counts short: not expected for these logs
            t_ns[i] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            rec_ns[i] = rec
            values[i] = LAYOUTS[conn.msgtype].row(msg)
            frames.append(frame_name(msg.header.frame_id))
            n[conn.topic] = i + 1
        done = time.process_time()
    total = sum(n.values())
    columns = {t: (a[: n[t]], b[: n[t]], v[: n[t]], f) for t, (a, b, v, f) in out.items()}
    return columns, total, opened - start, done - opened


def _ours(path: Path, one_pass: bool) -> tuple[Columns, int, float, float]:
    start = time.process_time()
    with open_log(path) as reader:
        opened = time.process_time()
        table = {t: conns for t, (meta, conns) in topics_of(reader).items() if meta.msgtype in LAYOUTS}
        if one_pass:
            rows = read_rows(reader, path, table)
        else:
            rows = {t: decode_rows(reader, path, t, conns) for t, conns in table.items()}
        done = time.process_time()
    out = {t: (r.t_ns, r.rec_ns, _layout_values(r), [r.frame_names[k] for k in r.frame]) for t, r in rows.items()}
    return out, sum(len(r.t_ns) for r in rows.values()), opened - start, done - opened


def _layout_values(r) -> np.ndarray:
    """A topic's rows in its whole layout: the values and, where the layout has them, the stated variances that
    ``Rows`` keeps as runs of equal rows (``Rows.stated``), expanded, so "identical" compares them too."""
    return r.values if r.stated is None else np.hstack([r.values, r.stated.expanded()])


def _inflate_only(path: Path) -> float | None:
    """CPU seconds to read and decompress every chunk holding a decoded topic (None: not a chunked log)."""
    with open_log(path) as reader:
        conns = [c for conns in (v for _, v in topics_of(reader).values()) for c in conns if c.msgtype in LAYOUTS]
        units = []
        for storage, ids, _ in storages(reader, conns):
            if not isinstance(storage, Chunked):
                return None
            wanted = set(ids.ids.tolist())
            units += [(storage, u) for u in storage.units if not u.conns or u.conns & wanted]
        start = time.process_time()
        for storage, unit in units:
            read_unit(storage.bio, unit)
        return time.process_time() - start


def _same(a: Columns, b: Columns) -> bool:
    if a.keys() != b.keys():
        return False
    for topic, (t1, r1, v1, f1) in a.items():
        t2, r2, v2, f2 = b[topic]
        if not (np.array_equal(t1, t2) and np.array_equal(r1, r2) and f1 == f2):
            return False
        if v1.shape != v2.shape or not np.array_equal(v1.view(np.uint64), v2.view(np.uint64)):
            return False
    return True


def _logs(args: argparse.Namespace, tmp: Path) -> list[tuple[str, Path]]:
    logs = [(str(p), Path(p)) for p in args.logs]
    if args.logs:
        return logs
    sim = simulate("figure8", duration=args.seconds, seed=1)
    for container, name in (("bag", "figure8.bag"), ("mcap", "figure8.mcap"), ("ros2", "figure8_ros2")):
        logs.append((f"sim {args.seconds:g} s {name}", write_log(sim, tmp / name, container)))
    counts = REALDATA / "COUNTS.json"
    if not args.no_real and counts.is_file():
        for rel in sorted(json.loads(counts.read_text())):
            logs.append((rel, REALDATA / rel))
    return logs


# --------------------------------------------------------------------------- TF topics (--tf)


def _tf_sim_log(path: Path, container: str, seconds: float, rate: float = 100.0) -> Path:
    """A dynamic /tf of ``seconds`` at ``rate`` with 3 transforms per message (and a /tf_static)."""
    ros1 = container == "bag"
    ts = make_typestore(ros1=ros1)
    t = ts.types
    rng = np.random.default_rng(0)
    msgtype = "tf2_msgs/msg/TFMessage"
    edges = [("odom", "base_link"), ("map", "odom"), ("base_link", "camera_link")]
    t0 = 1_700_000_000 * 1_000_000_000

    def message(stamp: int, pairs: list[tuple[str, str]]) -> bytes:
        items = []
        for parent, child in pairs:
            time_ = t["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
            header = t["std_msgs/msg/Header"](**({"seq": 0} if ros1 else {}), stamp=time_, frame_id=parent)
            x, y, z, qx, qy, qz, qw = rng.normal(size=7)
            transform = t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            )
            items.append(
                t["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child, transform=transform)
            )
        msg = t[msgtype](transforms=items)
        return bytes(ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype))

    stamps = [t0 + int(k * 1e9 / rate) for k in range(int(seconds * rate))]
    topics = {
        "/tf_static": [(t0, message(t0, [("base_link", "imu"), ("base_link", "laser")]))],
        "/tf": [(s + 200_000, message(s, edges)) for s in stamps],
    }
    return write_raw_log(path, container, topics, msgtype, ts)


def _tf_logs(args: argparse.Namespace, tmp: Path) -> list[tuple[str, Path]]:
    logs = [(str(p), Path(p)) for p in args.logs]
    if args.logs:
        return logs
    for container, name in (("bag", "tf.bag"), ("mcap", "tf.mcap"), ("ros2", "tf_ros2")):
        logs.append((f"sim {args.seconds:g} s /tf {name}", _tf_sim_log(tmp / name, container, args.seconds)))
    counts = REALDATA / "COUNTS.json"
    if not args.no_real and counts.is_file():
        for rel, doc in sorted(json.loads(counts.read_text()).items()):
            if any(topic["type"] in TF_TYPES for topic in doc["topics"].values()):
                logs.append((rel, REALDATA / rel))
        packed = REALDATA / "tagslam_test" / "test_11" / "reference.bag.bz2"
        if packed.is_file():
            unpacked = tmp / "test_11_reference.bag"
            with bz2.open(packed) as src, unpacked.open("wb") as dst:
                shutil.copyfileobj(src, dst, 1 << 20)
            logs.append(("tagslam_test/test_11/reference.bag.bz2 (unpacked)", unpacked))
    return logs


def _tf_decode(path: Path, fast: bool) -> tuple[dict[str, TfRows], float]:
    """decode_tf of every TF topic (rosbags or bytes), and the CPU seconds from the opened log to the rows."""
    real, fast_from = tfdecode.tf_layout, decode.TF_FAST_MESSAGES
    decode.TF_FAST_MESSAGES = 0  # every TF topic through the path measured, however small
    if not fast:
        tfdecode.tf_layout = lambda *args: None  # type: ignore[assignment]  # the rosbags fallback
    try:
        with open_log(path) as reader:
            start = time.process_time()
            rows = {
                t: decode_tf(reader, path, t, conns)
                for t, (meta, conns) in topics_of(reader).items()
                if meta.msgtype in TF_TYPES
            }
            return rows, time.process_time() - start
    finally:
        tfdecode.tf_layout, decode.TF_FAST_MESSAGES = real, fast_from


def _tf_same(a: dict[str, TfRows], b: dict[str, TfRows]) -> bool:
    if a.keys() != b.keys():
        return False
    for topic, x in a.items():
        y = b[topic]
        if not (np.array_equal(x.t_ns, y.t_ns) and np.array_equal(x.rec_ns, y.rec_ns)):
            return False
        if [x.frame_names[k] for k in x.parent] != [y.frame_names[k] for k in y.parent]:
            return False
        if [x.frame_names[k] for k in x.child] != [y.frame_names[k] for k in y.child]:
            return False
        if x.values.shape != y.values.shape or not np.array_equal(x.values.view(np.uint64), y.values.view(np.uint64)):
            return False
    return True


def tf_table(args: argparse.Namespace) -> None:
    """The ``--tf`` table: transforms/s of decode_tf through rosbags and from the bytes."""
    header = ("file", "topics", "messages", "transforms", "rosbags tf/s", "ours tf/s", "speed-up", "identical")
    rows = []
    with tempfile.TemporaryDirectory(prefix="read_speed_tf-") as tmp:
        for name, path in _tf_logs(args, Path(tmp)):
            want, _ = _tf_decode(path, False)  # warm-up
            got, _ = _tf_decode(path, True)
            count = sum(r.t_ns.size for r in got.values())
            if not got:
                continue
            with open_log(path) as reader:
                messages = sum(m.count for t, (m, _) in topics_of(reader).items() if t in got)
            ref = ours = float("inf")
            for _ in range(args.repeat):
                ref = min(ref, _tf_decode(path, False)[1])
                ours = min(ours, _tf_decode(path, True)[1])
            rows.append(
                (
                    name,
                    ",".join(sorted(got)),
                    str(messages),
                    str(count),
                    f"{count / ref:,.0f}",
                    f"{count / ours:,.0f}",
                    f"{ref / ours:.1f}x",
                    "yes" if _tf_same(want, got) else "NO",
                )
            )
            print(" | ".join(rows[-1]), file=sys.stderr, flush=True)
    _print(header, rows)


def _print(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    print()
    for row in [header, ["-" * w for w in widths], *rows]:
        print("  ".join(c.rjust(w) if i >= 2 else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("logs", nargs="*", help="logs to read (default: simulated + real logs)")
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the simulated logs")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-real", action="store_true", help="skip ../shared/realdata")
    parser.add_argument("--tf", action="store_true", help="TF topics: decode_tf through rosbags vs. tfdecode")
    args = parser.parse_args()
    if args.tf:
        tf_table(args)
        return
    header = (
        "file",
        "container",
        "messages",
        "rosbags msg/s",
        "ours msg/s",
        "speed-up",
        "incl. open",
        "per topic msg/s",
        "inflate bound",
        "identical",
    )
    rows, speedups = [], []
    with tempfile.TemporaryDirectory(prefix="read_speed-") as tmp:
        for name, path in _logs(args, Path(tmp)):
            with open_log(path) as reader:
                kind = "ros1" if not reader.is2 else path.suffix.lstrip(".")
                if path.is_dir():
                    storage = next(p for p in sorted(path.iterdir()) if p.suffix in {".db3", ".mcap"}).suffix[1:]
                    kind = f"rosbag2 ({storage})"
            want, count, _, _ = _rosbags(path)  # warm-up
            got, _, _, _ = _ours(path, True)
            _ours(path, False)
            if not count:
                continue
            ref = one = each = (float("inf"), float("inf"))  # (read, open + read)
            inflate = float("inf")
            for _ in range(args.repeat):
                for which in ("ref", "one", "each"):
                    if which == "ref":
                        _, _, t_open, t_read = _rosbags(path)
                        ref = (min(ref[0], t_read), min(ref[1], t_open + t_read))
                    else:
                        _, _, t_open, t_read = _ours(path, which == "one")
                        best = one if which == "one" else each
                        best = (min(best[0], t_read), min(best[1], t_open + t_read))
                        one, each = (best, each) if which == "one" else (one, best)
                t_inflate = _inflate_only(path)
                inflate = min(inflate, t_inflate) if t_inflate is not None else None
            speedups.append((name, kind, ref[0] / one[0], ref[0] / inflate if inflate else None))
            rows.append(
                (
                    name,
                    kind,
                    str(count),
                    f"{count / ref[0]:,.0f}",
                    f"{count / one[0]:,.0f}",
                    f"{ref[0] / one[0]:.1f}x",
                    f"{ref[1] / one[1]:.1f}x",
                    f"{count / each[0]:,.0f}",
                    f"{ref[0] / inflate:.1f}x" if inflate else "-",
                    "yes" if _same(want, got) else "NO",
                ),
            )
            print(" | ".join(rows[-1]), file=sys.stderr, flush=True)
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    print()
    for row in [header, ["-" * w for w in widths], *rows]:
        print("  ".join(c.rjust(w) if i >= 2 else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths))))
    print_floors(speedups)


def print_floors(speedups: list[tuple[str, str, float, float | None]]) -> None:
    """Issue 27: reading is at least ``MIN_READ_SPEEDUP`` x rosbags on every file (each container its line). A
    file whose inflate bound is below the floor says so: no reader reaches the floor there (bz2 ROS1 bags, where
    decompressing the chunks is most of rosbags' time), and how much of that bound this reader reaches."""
    print(f"# floors (issue 27); {load()}")
    for name, kind, ratio, bound in speedups:
        line = f"{name} ({kind}): {ratio:.1f}x rosbags (>= {MIN_READ_SPEEDUP:g}x): {met(ratio >= MIN_READ_SPEEDUP)}"
        if ratio < MIN_READ_SPEEDUP and bound is not None and bound < MIN_READ_SPEEDUP:
            line += (
                f" (out of reach: reading and decompressing its chunks alone is {bound:.1f}x faster than rosbags; "
                f"this read reaches {ratio / bound:.0%} of that bound)"
            )
        print(line)
    for kind in ("ros1", "mcap", "db3"):
        if not any(kind in k for _, k, _, _ in speedups):
            print(f"{kind}: no log read: MISSED")


if __name__ == "__main__":
    main()
