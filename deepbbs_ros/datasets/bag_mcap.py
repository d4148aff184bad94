"""Reading mcap recordings (rosbag2 mcap directories, bare ``.mcap`` files) chunk by chunk, every chunk checked
against its CRC, with the ``mcap`` package; damaged files are read as far as they go (no ROS install)."""

from __future__ import annotations

import re
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from deepbbs_ros.datasets.bag_common import bag_typestore, count_messages, detail
from deepbbs_ros.datasets.mcap_chunks import McapChunks
from deepbbs_ros.errors import BagError


class McapBackend(McapChunks):
    """The ``mcap`` package, chunk by chunk: rosbag2 mcap directories and bare .mcap files.

    With an intact summary section the chunks are read through its index, each one checked against
    its CRC; a damaged or missing summary (a recording cut off mid-write, zeroed bytes) falls back to
    reading the file record by record from its start. Either way a damaged chunk is a
    :class:`BagError` naming its byte range and log times, after every message before it: raised, or
    handed to ``on_damage`` and stepped over when its neighbours can still be found.
    """

    def __init__(self, path: Path) -> None:
        from mcap.reader import SeekingReader

        self.path = path
        self.files = sorted(path.glob("*.mcap")) if path.is_dir() else [path]
        self.kind = "rosbag2-mcap" if path.is_dir() else "mcap"
        self.typestore = bag_typestore()
        self.warnings: list[str] = []
        self.summaries: dict[Path, Any] = {}
        self.scan_error: str | None = None
        for file in self.files:
            try:
                with open(file, "rb") as f:
                    f.seek(max(0, file.stat().st_size - 8))
                    if f.read(8) != b"\x89MCAP0\r\n":
                        self.warnings.append(f"{file}: no footer (the file was cut off or never finished); "
                                             "read from the start")
                        continue
                    f.seek(0)  # SeekingReader checks the magic where the stream stands
                    summary = SeekingReader(f, record_size_limit=file.stat().st_size).get_summary()
                if summary is not None and summary.chunk_indexes and summary.statistics is not None:
                    self.summaries[file] = summary
                    continue
                self.warnings.append(f"{file}: no chunk index in the summary section; read from the start")
            except Exception as err:  # noqa: BLE001 - a damaged summary: read the data section in order
                self.warnings.append(f"{file}: summary section damaged ({detail(err)}); read from the start")
        self.topics: dict[str, tuple[str, int]] = {}
        if len(self.summaries) == len(self.files):
            stamps = []
            for summary in self.summaries.values():
                counts = summary.statistics.channel_message_counts
                for cid, ch in summary.channels.items():
                    schema = summary.schemas.get(ch.schema_id)
                    typ, cnt = self.topics.get(ch.topic, (schema.name if schema else "?", 0))
                    self.topics[ch.topic] = (typ, cnt + int(counts.get(cid, 0)))
                stamps += [summary.statistics.message_start_time, summary.statistics.message_end_time]
            self.start_ns, self.end_ns = min(stamps), max(stamps)
        else:  # count by reading (what a damaged file still holds)
            self.topics, self.start_ns, self.end_ns, self.scan_error = self.count()

    def count(self) -> tuple[dict[str, tuple[str, int]], int, int, str | None]:
        """Read every message: ({topic: (type, count)}, first, last log time, the damage met or None)."""
        return count_messages(self)

    def data_crc_errors(self) -> list[str]:
        """Check each file's data-section CRC (the DataEnd record's, over every byte before it: chunks,
        message indexes, metadata): one line per file whose bytes do not match it."""
        import zlib

        out = []
        for file in self.files:
            try:
                data = file.read_bytes()
                if data[-8:] != b"\x89MCAP0\r\n" or len(data) < 8 + 9 + 20 + 8 + 13:
                    continue  # cut off: no DataEnd to check against (reading reports the cut)
                summary_start = struct.unpack("<Q", data[-8 - 20 : -8 - 12])[0]
                end = summary_start if summary_start else len(data) - 8 - 9 - 20
                if data[end - 13 : end - 12] != b"\x0f":
                    continue  # DataEnd not where the footer says: the summary damage is reported as such
                want = struct.unpack("<I", data[end - 4 : end])[0]
                if want and zlib.crc32(data[: end - 13]) != want:
                    out.append(f"{file}: data section CRC mismatch (bytes 0-{end - 13} do not match the CRC "
                               "written with them)")
            except OSError as err:
                out.append(f"{file}: cannot read: {err.strerror or err}")
        return out

    # --- reading (_file_messages and _chunk_messages: datasets/mcap_chunks.py) ---------------------------
    def raw(self, topics: list[str] | None, on_damage=None) -> Iterator[tuple[str, str, int, Any]]:
        """(topic, msgtype, log_time_ns, (schema, channel, message)) in recording order; BagError on damage
        (a damaged chunk that can be stepped over goes to ``on_damage`` when given)."""
        for file in self.files:
            for schema, channel, message in self._file_messages(file, on_damage):
                if channel is None:
                    raise BagError(f"{file}: message at log time {message.log_time * 1e-9:.6f} s has no channel "
                                   "record (corrupt file)")
                if topics is not None and channel.topic not in topics:
                    continue
                yield channel.topic, (schema.name if schema else "?"), int(message.log_time), (schema, channel, message)

    def decode(self, msgtype: str, data: Any) -> Any:
        schema, channel, message = data
        if schema is None or channel.message_encoding != "cdr":
            raise BagError(f"{self.path}: topic {channel.topic} is not CDR-encoded ROS 2 data")
        self._register(schema)
        return self.typestore.deserialize_cdr(message.data, schema.name)

    def _register(self, schema) -> None:
        from rosbags.typesys import get_types_from_msg

        name = schema.name
        if name in self.typestore.fielddefs:
            return
        if schema.encoding != "ros2msg":
            raise BagError(f"{self.path}: type {name} has a {schema.encoding!r} definition (only ros2msg is read)")
        text = schema.data.decode()
        types = {}
        parts = re.split(r"^={10,}\s*$", text, flags=re.MULTILINE)
        types.update(get_types_from_msg(parts[0], name))
        for part in parts[1:]:
            head, _, body = part.strip().partition("\n")
            if head.startswith("MSG: "):
                sub = head[5:].strip()
                if "/msg/" not in sub:
                    sub = sub.replace("/", "/msg/")
                types.update(get_types_from_msg(body, sub))
        self.typestore.register(types)

    def close(self) -> None:
        pass
