"""Simulated logs written as every container x compression, in small chunks (a 2 s log spans several): the
writers the reader tests and the container fuzz test share."""

from __future__ import annotations

from pathlib import Path

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.rosbag1 import Writer as Bag1Writer
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Bag2Writer

from slamobs.pipeline.simulate import make_typestore
from slamobs.pipeline.simulate.logwriter import TOPIC_TYPES, iter_messages

CHUNK = 48 * 1024  # small chunks: a 2 s log spans several


def write_container(sim, path: Path, container: str, compression: str = "") -> Path:
    """``sim`` as ``container`` (bag, mcap, ros2-sqlite3, ros2-mcap) with the given compression."""
    ros1 = container == "bag"
    ts = make_typestore(ros1=ros1)
    if container == "bag":
        writer = Bag1Writer(path)
        if compression:
            writer.set_compression(Bag1Writer.CompressionFormat[compression.upper()])
        writer.chunk_threshold = CHUNK
        with writer:
            conns = {t: writer.add_connection(t, m, typestore=ts) for t, m in TOPIC_TYPES.items()}
            for topic, rec, raw in iter_messages(sim, ts, ros1=True):
                writer.write(conns[topic], rec, raw)
    elif container == "mcap":
        with path.open("wb") as stream:
            kind = CompressionType[compression.upper() or "NONE"]
            writer = McapWriter(stream, chunk_size=CHUNK, compression=kind)
            writer.start(profile="ros2", library="test")
            channels = {}
            for topic, msgtype in TOPIC_TYPES.items():
                msgdef, _ = ts.generate_msgdef(msgtype, ros_version=2)
                schema = writer.register_schema(name=msgtype, encoding="ros2msg", data=msgdef.encode())
                channels[topic] = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema)
            for topic, rec, data in iter_messages(sim, ts, ros1=False):
                writer.add_message(channels[topic], log_time=rec, data=data, publish_time=rec)
            writer.finish()
    else:
        plugin = StoragePlugin.MCAP if container == "ros2-mcap" else StoragePlugin.SQLITE3
        writer2 = Bag2Writer(path, version=9, storage_plugin=plugin)
        if compression:
            writer2.set_compression(CompressionMode[compression.upper()], CompressionFormat.ZSTD)
        with writer2:
            conns = {t: writer2.add_connection(t, m, typestore=ts) for t, m in TOPIC_TYPES.items()}
            for topic, rec, raw in iter_messages(sim, ts, ros1=False):
                writer2.write(conns[topic], rec, raw)
    return path
