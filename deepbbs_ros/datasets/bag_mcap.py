"""Reading mcap recordings (rosbag2 mcap directories, bare ``.mcap`` files) chunk by chunk, every chunk checked
against its CRC, with the ``mcap`` package; damaged files are read as far as they go (no ROS install)."""

from __future__ import annotations

import re
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from deepbbs_ros.datasets.bag_common import bag_typestore, count_messages, detail
from deepbbs_ros.errors import BagError


class McapBackend:
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

    # --- reading -------------------------------------------------------------------------------
    def _chunk_messages(self, file: Path, chunk, where: str, channels: dict, schemas: dict):
        from mcap.records import Channel, Message, Schema
        from mcap.stream_reader import breakup_chunk

        try:
            records = breakup_chunk(chunk, validate_crc=True)
        except Exception as err:  # noqa: BLE001 - CRC mismatch, zstd/lz4 errors, garbage lengths
            t0, t1 = chunk.message_start_time * 1e-9, chunk.message_end_time * 1e-9
            raise BagError(f"{file}: damaged chunk at bytes {where} (log time {t0:.6f} to {t1:.6f} s): "
                           f"{detail(err)}") from None
        messages = []
        for r in records:
            if isinstance(r, Schema):
                schemas[r.id] = r
            elif isinstance(r, Channel):
                channels[r.id] = r
            elif isinstance(r, Message):
                messages.append(r)
        messages.sort(key=lambda m: m.log_time)  # stable: recording order within a chunk
        return messages

    def _file_messages(self, file: Path, on_damage=None):
        """(schema, channel, message) of one file in recording order. A damaged chunk whose neighbours
        can still be found (through the index, or a chunk record whose length is intact) goes to
        ``on_damage(BagError)`` when given, and reading goes on after it; otherwise it raises."""

        def damaged(err: BagError) -> None:
            if on_damage is None:
                raise err
            on_damage(err)

        from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema

        summary = self.summaries.get(file)
        size = file.stat().st_size
        with open(file, "rb") as f:
            if summary is not None:
                from mcap.data_stream import ReadDataStream

                channels, schemas = dict(summary.channels), dict(summary.schemas)
                for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
                    where = f"{ci.chunk_start_offset}-{ci.chunk_start_offset + ci.chunk_length}"
                    try:
                        f.seek(ci.chunk_start_offset)
                        head = f.read(9)
                        chunk = Chunk.read(ReadDataStream(f))
                        # the chunk's own header must say what its index says: a damaged header (a zeroed
                        # CRC field, size or compression) would otherwise read as a valid empty chunk
                        seen = (head[:1], chunk.compression, len(chunk.data), chunk.uncompressed_size,
                                chunk.message_start_time, chunk.message_end_time)
                        want = (b"\x06", ci.compression, ci.compressed_size, ci.uncompressed_size,
                                ci.message_start_time, ci.message_end_time)
                        if seen != want:
                            raise BagError(f"{file}: damaged chunk at bytes {where}: its header does not match "
                                           "the summary's chunk index")
                        messages = self._chunk_messages(file, chunk, where, channels, schemas)
                    except BagError as err:
                        damaged(err)
                        continue
                    except Exception as err:  # noqa: BLE001 - an index pointing at damaged bytes
                        damaged(BagError(f"{file}: damaged chunk at bytes {where}: {detail(err)}"))
                        continue
                    yield from _with_channels(messages, channels, schemas)
                return
            channels, schemas = {}, {}
            reader = _CheckedStreamReader(f, emit_chunks=True, record_size_limit=size)
            records = reader.records
            pos = 0
            while True:
                pos = f.tell()
                try:
                    record = next(records, None)
                except Exception as err:  # noqa: BLE001 - truncation, zeroed bytes, garbage lengths
                    raise BagError(f"{file}: bag is truncated or corrupt at byte {pos} of {size} "
                                   f"({detail(err)})") from None
                if record is None or isinstance(record, (DataEnd, Footer)):
                    return
                if isinstance(record, _BadRecord):
                    damaged(BagError(f"{file}: damaged record at bytes {pos}-{f.tell()} (opcode {record.opcode:#04x}, "
                                     "not an mcap record)"))
                    continue
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Chunk):
                    try:
                        messages = self._chunk_messages(file, record, f"{pos}-{f.tell()}", channels, schemas)
                    except BagError as err:
                        damaged(err)
                        continue
                    yield from _with_channels(messages, channels, schemas)
                elif isinstance(record, Message):
                    yield from _with_channels([record], channels, schemas)

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

class _BadRecord:
    """A record whose opcode no mcap writer uses (0x00, or an unassigned one below 0x80): damage."""

    def __init__(self, opcode: int) -> None:
        self.opcode = opcode


def _CheckedStreamReader(*args, **kwargs):
    """``mcap.stream_reader.StreamReader`` that returns a :class:`_BadRecord` (its bytes skipped) for an
    opcode no writer uses, where StreamReader skips it silently (a zeroed chunk opcode would hide the
    whole chunk)."""
    from mcap.opcode import Opcode
    from mcap.stream_reader import StreamReader

    class Reader(StreamReader):
        def _read_record(self, opcode: int, length: int):
            if opcode < 0x80 and opcode not in set(Opcode):
                self._stream.read(length)
                return _BadRecord(opcode)
            return super()._read_record(opcode, length)

    return Reader(*args, **kwargs)


def _with_channels(messages, channels: dict, schemas: dict):
    """(schema or None, channel or None, message) of each mcap ``Message`` record, from the records read so far."""
    for m in messages:
        ch = channels.get(m.channel_id)
        yield (schemas.get(ch.schema_id) if ch else None), ch, m
