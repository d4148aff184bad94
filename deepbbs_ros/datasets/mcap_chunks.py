"""An mcap file's messages chunk by chunk (the ``mcap`` package, no ROS install): :class:`McapChunks`, the reading
half of datasets/bag_mcap.py's ``McapBackend``: through the summary's chunk index, each chunk checked against its
CRC and its index entry, or record by record from the file's start when the summary is damaged or missing."""

from __future__ import annotations

from pathlib import Path

from deepbbs_ros.datasets.bag_common import detail
from deepbbs_ros.errors import BagError


class McapChunks:
    """Messages of one file in recording order, a damaged chunk a :class:`BagError` (a mixin of ``McapBackend``,
    which fills ``summaries``)."""

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
