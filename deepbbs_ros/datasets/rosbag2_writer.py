"""The rosbag2 writer every rosbag2 output goes through (no ROS install): rosbags' ``Writer`` (format version 9, as
ROS 2 Jazzy writes) with its mcap storage written by ``mcap.writer.Writer`` with every CRC on (zstd chunks, chunk,
data-section and summary CRCs: :func:`rosbag2_writer`) or sqlite3, and the offered QoS profile its topics get
(:func:`qos_profile`: reliable, volatile, keep-last 10)."""

from __future__ import annotations

from pathlib import Path


class _CrcMcapStorage:
    """rosbags' mcap storage plugin, written by the ``mcap`` package's Writer with every CRC on.

    rosbags' own mcap writer leaves the chunk, data-section and summary CRCs at 0, so a flipped byte
    goes unnoticed. This plugin keeps rosbags' rosbag2 side (metadata.yaml, QoS, message definitions,
    the ``rosbag2`` metadata record) and lets ``mcap.writer.Writer`` write the file: zstd chunks of
    1 MiB with a CRC of each chunk's data, of the data section and of the summary.
    """

    chunk_size = 2**20  # bytes of messages per chunk (before compression), as rosbag2's mcap plugin

    def __init__(self, path: Path, compression) -> None:
        from mcap.writer import CompressionType
        from mcap.writer import Writer as McapWriter
        from rosbags.rosbag2.enums import CompressionMode

        self.path = path / f"{path.name}.mcap"
        self._file = self.path.open("xb")
        zstd = compression == CompressionMode.STORAGE
        self._writer = McapWriter(self._file, chunk_size=self.chunk_size,
                                  compression=CompressionType.ZSTD if zstd else CompressionType.NONE,
                                  enable_crcs=True, enable_data_crcs=True)
        from importlib.metadata import version

        library = f"deepbbs_ros (mcap {version('mcap')}, rosbags {version('rosbags')})"
        self._writer.start(profile="ros2", library=library)
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}

    def add_msgtype(self, connection) -> None:
        from rosbags.interfaces import MessageDefinitionFormat

        fmt = "ros2msg" if connection.msgdef.format == MessageDefinitionFormat.MSG else "ros2idl"
        self._schemas[connection.msgtype] = self._writer.register_schema(
            connection.msgtype, fmt, connection.msgdef.data.encode())

    def add_connection(self, connection, offered_qos_profiles: str) -> None:
        self._channels[connection.id] = self._writer.register_channel(
            connection.topic, connection.ext.serialization_format, self._schemas[connection.msgtype],
            {"offered_qos_profiles": offered_qos_profiles})

    def write(self, connection, timestamp: int, data) -> None:
        self._writer.add_message(self._channels[connection.id], timestamp, bytes(data), timestamp)

    def close(self, version: int, metadata: str) -> None:
        self._writer.add_metadata("rosbag2", {"serialized_metadata": metadata})
        self._writer.finish()
        self._file.close()

    def abort(self) -> None:
        self._file.close()


def rosbag2_writer(out: Path | str, storage: str = "mcap", *, chunk_size: int = 2**20):
    """A rosbags rosbag2 ``Writer`` (format version 9) for ``storage`` ``"mcap"`` (zstd chunks of
    ``chunk_size`` bytes, with chunk, data and summary CRCs: :class:`_CrcMcapStorage`) or ``"sqlite3"``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    storage_cls = type("_CrcMcapStorageSized", (_CrcMcapStorage,), {"chunk_size": int(chunk_size)})

    class _Writer(Writer):
        STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: storage_cls}  # noqa: RUF012

    writer = _Writer(out, version=9, storage_plugin=StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3)
    if storage == "mcap":
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    return writer


def qos_profile():
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    infinite = QosTime(0, 0)  # 0 = infinite / default, as rosbag2 writes
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=10,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.VOLATILE,
        deadline=infinite,
        lifespan=infinite,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=infinite,
        avoid_ros_namespace_conventions=False,
    )
