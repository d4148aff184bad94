"""ROS bags: ROS 1 ``.bag``, ROS 2 bag directories (sqlite3 and mcap) and bare ``.mcap`` / ``.db3`` files.

Reading (no ROS install): ROS 1 bags and sqlite3 rosbag2 go through rosbags' ``AnyReader``; mcap
(rosbag2 directories and bare files) is read chunk by chunk with the ``mcap`` package, the CDR
payloads decoded with the rosbags ROS 2 Jazzy typestore. Each chunk is checked against its CRC; the
chunks are found through the summary's chunk index, or, when the summary is damaged or missing (a
recording cut off mid-write), by reading the file from its start. Damage is a :class:`BagError`
naming the file, the byte range and the log times; a damaged chunk that can be stepped over (intact
index, or an intact chunk record length) costs only its own messages when the source is lenient.
Scans and ground truth are read in one pass.

Topics: the LiDAR topic is the only ``sensor_msgs/msg/PointCloud2`` topic, or the one named by
``topic`` (several candidates: :class:`DatasetError` listing them and naming ``--topic``). Ground
truth comes from ``gt_topic`` (``geometry_msgs/msg/PoseStamped``, ``nav_msgs/msg/Odometry`` or
``geometry_msgs/msg/TransformStamped``, taken as ``T_world_lidar``), else from
``/ground_truth/pose`` when present, else from the only pose-typed topic whose name contains
``ground_truth``/``groundtruth``/``gt``; other pose topics (e.g. wheel ``/odom``) are never taken as
ground truth silently. Ground truth is matched by header stamp (see
:class:`~deepbbs_ros.datasets.base.PoseTrack`: exact, else interpolated between the two bracketing
poses within the tolerance, else the nearest within it). Ground-truth quaternions are normalised on
reading (:func:`msg_adapters.transforms.quaternion_to_matrix`), so every pose is a rotation to about 1e-16.

Writing uses rosbags' rosbag2 ``Writer`` (format version 9, as ROS 2 Jazzy writes): mcap storage by
default with zstd chunk compression (rosbags' ``CompressionMode.STORAGE``, which the metadata
records as no bag-level compression, like rosbag2's own mcap plugin), the mcap file itself written
by ``mcap.writer.Writer`` with chunk, data-section and summary CRCs (:func:`rosbag2_writer`), or
sqlite3. Both topics get an explicit offered QoS profile (reliable, volatile, keep-last 10): a
reliable publisher matches both reliable and best-effort subscribers when the bag is played back.
:func:`write_rosbag1` writes the same messages as a ROS 1 ``.bag``.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from deepbbs_ros.datasets.base import APOLLO_LIDAR_TOPIC, GT_POSE_TOPIC, WORLD_FRAME, PoseTrack, Scan, ScanSource
from deepbbs_ros.errors import BagError, DatasetError, DeepBBSError

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry", "geometry_msgs/msg/TransformStamped")
_GT_NAME = re.compile(r"(^|[/_])(ground_?truth|groundtruth|gt)([/_]|$)", re.IGNORECASE)


def is_bag(path: Path) -> bool:
    """True for a ROS 1 ``.bag``, a bare ``.mcap``/``.db3`` or a rosbag2 directory."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file() or any(path.glob("*.mcap")) or any(path.glob("*.db3"))
    return path.suffix in (".bag", ".mcap", ".db3")


def _typestore(ros1: bool = False):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_JAZZY)


def _gt_to_matrix(msg: Any, msgtype: str):
    """(T (4, 4), stamp_ns) from a PoseStamped / Odometry / TransformStamped message."""
    from msg_adapters.transforms import odometry_to_matrix, pose_stamped_to_matrix, transform_stamped_to_matrix

    if msgtype == "geometry_msgs/msg/PoseStamped":
        T, stamp_ns, _ = pose_stamped_to_matrix(msg)
    elif msgtype == "nav_msgs/msg/Odometry":
        T, stamp_ns, _, _ = odometry_to_matrix(msg)
    else:
        T, stamp_ns, _, _ = transform_stamped_to_matrix(msg)
    return T, stamp_ns


# ------------------------------------------------------------------------------------------ backends
def _detail(err: BaseException) -> str:
    text = str(err).strip().splitlines()[0] if str(err).strip() else ""
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def _metadata_counts(path: Path) -> dict[str, int] | None:
    """``{topic: message_count}`` as a rosbag2 directory's metadata.yaml states it, or None."""
    meta = path / "metadata.yaml"
    if not path.is_dir() or not meta.is_file():
        return None
    try:
        import yaml

        doc = yaml.safe_load(meta.read_text())
        entries = doc["rosbag2_bagfile_information"]["topics_with_message_count"] or []
        return {str(e["topic_metadata"]["name"]): int(e["message_count"]) for e in entries}
    except Exception:  # noqa: BLE001 - a damaged metadata.yaml only loses the comparison
        return None


class _AnyBackend:
    """rosbags AnyReader: ROS 1 .bag, rosbag2 sqlite3 directories, bare .db3."""

    def __init__(self, path: Path) -> None:
        from rosbags.highlevel import AnyReader

        ros1 = path.suffix == ".bag"
        self.path = path
        self.reader = AnyReader([path], default_typestore=_typestore(ros1))
        self.reader.open()
        self.kind = "rosbag1" if ros1 else ("db3" if path.suffix == ".db3" else "rosbag2-sqlite3")
        self.warnings: list[str] = []
        self.topics: dict[str, tuple[str, int]] = {}
        for c in self.reader.connections:
            typ, cnt = self.topics.get(c.topic, (c.msgtype, 0))
            self.topics[c.topic] = (typ, cnt + int(c.msgcount))
        self.start_ns = int(self.reader.start_time) if self.reader.connections else 0
        self.end_ns = int(self.reader.end_time) - 1 if self.reader.connections else 0  # end_time is last + 1

    def raw(self, topics: list[str] | None, on_damage=None) -> Iterator[tuple[str, str, int, Any]]:
        """(topic, msgtype, log_time_ns, raw bytes) in log-time order; BagError on damage."""
        conns = [c for c in self.reader.connections if topics is None or c.topic in topics]
        it = self.reader.messages(connections=conns)
        last = None
        while True:
            try:
                item = next(it, None)
            except Exception as err:  # noqa: BLE001 - damaged bytes reach rosbags' parsers in many ways
                where = f"after log time {last * 1e-9:.6f} s" if last is not None else "before the first message"
                raise BagError(f"{self.path}: bag is truncated or corrupt {where} ({_detail(err)})") from None
            if item is None:
                return
            conn, t, data = item
            last = t
            yield conn.topic, conn.msgtype, int(t), data

    def decode(self, msgtype: str, data: Any) -> Any:
        return self.reader.deserialize(data, msgtype)

    def close(self) -> None:
        self.reader.close()


class _McapBackend:
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
        self.typestore = _typestore()
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
                self.warnings.append(f"{file}: summary section damaged ({_detail(err)}); read from the start")
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
        topics: dict[str, tuple[str, int]] = {}
        lo, hi, error = None, None, None
        damage: list[str] = []
        try:
            for topic, typ, t, _data in self.raw(None, on_damage=lambda err: damage.append(str(err))):
                _typ, cnt = topics.get(topic, (typ, 0))
                topics[topic] = (typ, cnt + 1)
                lo, hi = (t, t) if lo is None else (min(lo, t), max(hi, t))
        except BagError as err:
            damage.append(str(err))
        error = "; ".join(damage) if damage else None
        return topics, lo or 0, hi or 0, error

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
                           f"{_detail(err)}") from None
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
                        damaged(BagError(f"{file}: damaged chunk at bytes {where}: {_detail(err)}"))
                        continue
                    for m in messages:
                        ch = channels.get(m.channel_id)
                        yield (schemas.get(ch.schema_id) if ch else None), ch, m
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
                                   f"({_detail(err)})") from None
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
                    for m in messages:
                        ch = channels.get(m.channel_id)
                        yield (schemas.get(ch.schema_id) if ch else None), ch, m
                elif isinstance(record, Message):
                    ch = channels.get(record.channel_id)
                    yield (schemas.get(ch.schema_id) if ch else None), ch, record

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


def _is_mcap(path: Path) -> bool:
    return (path.is_file() and path.suffix == ".mcap") or (path.is_dir() and any(path.glob("*.mcap")))


# -------------------------------------------------------------------------------------------- reader
class BagSource(ScanSource):
    """Scans from a ROS 1/ROS 2 bag or bare mcap file, in recording order, index 0-based.

    Recording order is stamp order for bags written by this package (log time = header stamp)
    and for normal recordings of one LiDAR. Scans and ground truth are read in one pass: a scan is
    yielded once the poses around its stamp have been read, so damage in the middle of a recording
    costs only what comes after it.
    """

    def __init__(
        self,
        path: Path | str,
        *,
        topic: str | None = None,
        gt_topic: str | None = None,
        gt_tolerance_s: float = 0.05,
        lenient: bool = False,
        any_topic: bool = False,
    ) -> None:
        super().__init__(path, lenient=lenient)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag")
        self.backend = self._open_backend()
        self.format = self.backend.kind
        self.warnings = list(self.backend.warnings)
        self.cloud_topics = sorted(t for t, (typ, _) in self.backend.topics.items() if typ == POINTCLOUD2)
        self.topic = self._pick_topic(topic, any_topic)
        self.gt_topic = self._pick_gt_topic(gt_topic)
        self.gt_tolerance_ns = int(round(gt_tolerance_s * 1e9))
        self.gt: PoseTrack | None = None
        self.has_ground_truth = self.gt_topic is not None

    # --- opening -------------------------------------------------------------------------------
    def _open_backend(self):
        if _is_mcap(self.path):
            backend = _McapBackend(self.path)
            if backend.scan_error and not backend.topics:
                raise BagError(f"{self.path}: cannot read bag: {backend.scan_error}")
            return backend  # damage met while counting is met (and reported) again while reading
        try:
            return _AnyBackend(self.path)
        except Exception as err:  # noqa: BLE001 - damaged headers/indexes reach rosbags' parsers in many ways
            raise BagError(f"{self.path}: cannot read bag (truncated or corrupt?): {_detail(err)}") from None

    def _pick_topic(self, topic: str | None, any_topic: bool = False) -> str | None:
        clouds = self.cloud_topics
        if topic is not None:
            if topic not in self.backend.topics:
                raise BagError(f"{self.path}: no topic {topic!r}; PointCloud2 topics: {', '.join(clouds) or 'none'}")
            if topic not in clouds:
                raise BagError(f"{self.path}: topic {topic!r} is {self.backend.topics[topic][0]}, not {POINTCLOUD2}")
            return topic
        if any_topic and len(clouds) != 1:
            return None
        if not clouds:
            listing = ", ".join(f"{t} ({typ})" for t, (typ, _) in sorted(self.backend.topics.items()))
            raise BagError(f"{self.path}: no {POINTCLOUD2} topic (topics: {listing or 'none'})")
        if len(clouds) > 1:
            raise DatasetError(
                f"{self.path}: {len(clouds)} PointCloud2 topics ({', '.join(clouds)}); pick one with --topic"
            )
        return clouds[0]

    def _pick_gt_topic(self, gt_topic: str | None) -> str | None:
        poses = sorted(t for t, (typ, _) in self.backend.topics.items() if typ in POSE_TYPES)
        if gt_topic is not None:
            if gt_topic not in self.backend.topics:
                listing = ", ".join(poses) or "none"
                raise BagError(f"{self.path}: no ground-truth topic {gt_topic!r}; pose topics: {listing}")
            typ = self.backend.topics[gt_topic][0]
            if typ not in POSE_TYPES:
                raise BagError(
                    f"{self.path}: ground-truth topic {gt_topic!r} is {typ}, not one of {', '.join(POSE_TYPES)}"
                )
            return gt_topic
        if GT_POSE_TOPIC in poses:
            return GT_POSE_TOPIC
        named = [t for t in poses if _GT_NAME.search(t)]
        return named[0] if len(named) == 1 else None

    # --- iteration -----------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.backend.topics[self.topic][1]) if self.topic else 0

    def _scans(self) -> Iterator[Scan]:
        from msg_adapters.pointcloud2 import pointcloud2_to_arrays

        if self.topic is None:
            raise DatasetError(f"{self.path}: {len(self.cloud_topics)} PointCloud2 topics "
                               f"({', '.join(self.cloud_topics)}); pick one with --topic")
        self.gt = PoseTrack([], [], self.gt_tolerance_ns)
        topics = [self.topic] + ([self.gt_topic] if self.has_ground_truth else [])
        pending: list[Scan] = []  # scans waiting for the poses around their stamp
        index = 0

        def ready(scan: Scan) -> tuple[Scan, ...]:
            """(scan with its ground truth,) or () when that was in a damaged chunk (recorded there)."""
            T = self.gt.lookup(scan.stamp_ns)
            if T is None and damaged:
                return ()
            if T is None:
                raise BagError(
                    f"{self.path}: scan {scan.index} (stamp {scan.stamp_ns * 1e-9:.6f} s) has no ground truth on "
                    f"{self.gt_topic} within {self.gt_tolerance_ns * 1e-9:g} s"
                )
            scan.T_world_lidar = T
            return (scan,)

        damaged = []

        def on_damage(err: BagError) -> None:
            damaged.append(err)
            self.skip(err)  # strict: raise; lenient: record, read on after the chunk

        it = self.backend.raw(topics, on_damage=on_damage)
        try:
            for topic, typ, _t, data in it:
                try:
                    msg = self.backend.decode(typ, data)
                except BagError:
                    raise
                except Exception as err:  # noqa: BLE001 - damaged message bytes (no CRC caught them)
                    what = f"scan {index}" if topic == self.topic else f"ground-truth message {len(self.gt)}"
                    raise BagError(f"{self.path}: {what} on {topic} cannot be decoded ({_detail(err)})") from None
                if topic == self.gt_topic and self.has_ground_truth:
                    try:
                        T, stamp_ns = _gt_to_matrix(msg, typ)
                    except DeepBBSError as err:
                        raise BagError(f"{self.path}: ground-truth message {len(self.gt)} on {topic}: {err}") from None
                    self.gt.add(stamp_ns, T)
                    while pending and self.gt.decided(pending[0].stamp_ns):
                        yield from ready(pending.pop(0))
                    continue
                names = [str(f.name) for f in msg.fields if str(f.name) not in ("x", "y", "z")]
                try:
                    cloud = pointcloud2_to_arrays(msg, names)
                except DeepBBSError as err:
                    raise BagError(f"{self.path}: scan {index} on {self.topic}: {err}") from None
                scan = Scan(index, cloud.stamp_ns, cloud.xyz, dict(cloud.fields), frame_id=cloud.frame_id)
                index += 1
                if not self.has_ground_truth:
                    yield scan
                elif self.gt.decided(scan.stamp_ns) and not pending:
                    yield from ready(scan)
                else:
                    pending.append(scan)
        except BagError as err:
            # the scans read before the damage whose ground truth is already known still count
            while pending and self.gt.lookup(pending[0].stamp_ns) is not None:
                yield from ready(pending.pop(0))
            raise err from None
        while pending:
            yield from ready(pending.pop(0))

    def close(self) -> None:
        self.backend.close()

    def read_counts(self) -> tuple[dict[str, tuple[str, int]], str | None]:
        """Read the whole recording (every chunk CRC-checked, nothing decoded): ({topic: (type, count)},
        the damage met or None)."""
        if isinstance(self.backend, _McapBackend):
            topics, _lo, _hi, error = self.backend.count()
            crc = self.backend.data_crc_errors()
            if crc and not error:  # damage outside the chunks (their own CRCs passed)
                error = "; ".join(crc)
            return topics, error
        topics: dict[str, tuple[str, int]] = {}
        try:
            for topic, typ, _t, _data in self.backend.raw(None):
                _typ, cnt = topics.get(topic, (typ, 0))
                topics[topic] = (typ, cnt + 1)
        except BagError as err:
            return topics, str(err)
        return topics, None

    def copy_to(self, out: Path | str, storage: str = "mcap", *, topic: str | None = None,
                gt_topic: str | None = None, max_frames: int | None = None) -> int:
        """Copy the LiDAR topic (and the ground-truth topic) message by message into a new rosbag2:
        the clouds keep their bytes (layout, fields, organisation, frame), each topic its type; ``topic``
        / ``gt_topic`` rename them in the copy. ROS 2 recordings only (a ROS 1 cloud has another
        serialisation: see :func:`write_rosbag`). Damage stops the copy as reading does (strict: BagError;
        lenient: recorded in ``errors``, the copy holds everything before it). Returns the clouds written.
        """
        if self.format == "rosbag1":
            raise BagError(f"{self.path}: a ROS 1 bag cannot be copied message by message; convert it with --repack")
        if self.topic is None:
            raise DatasetError(f"{self.path}: {len(self.cloud_topics)} PointCloud2 topics "
                               f"({', '.join(self.cloud_topics)}); pick one with --topic")
        names = {self.topic: topic or self.topic}
        if self.gt_topic is not None:
            names[self.gt_topic] = gt_topic or self.gt_topic
        typestore = _typestore()
        qos = [_qos()]
        n = 0
        last_cloud_t = None
        try:
            with rosbag2_writer(out, storage) as writer:
                conns: dict[str, Any] = {}
                try:
                    for src_topic, typ, t, data in self.backend.raw(list(names)):
                        if src_topic == self.topic:
                            if max_frames is not None and n >= max_frames:
                                break
                            n += 1
                            last_cloud_t = t
                        elif max_frames is not None and n >= max_frames and t > last_cloud_t:
                            continue  # ground truth after the last cloud copied
                        if isinstance(self.backend, _McapBackend):
                            self.backend._register(data[0])
                            payload = data[2].data
                        else:
                            payload = data
                        if src_topic not in conns:
                            conns[src_topic] = writer.add_connection(names[src_topic], typ, typestore=typestore,
                                                                     offered_qos_profiles=qos)
                        writer.write(conns[src_topic], t, payload)
                except BagError as err:
                    self.fault(err)
        except Exception as err:  # noqa: BLE001 - the writer's own errors (rosbags WriterError, disk full)
            if isinstance(err, DeepBBSError):
                raise
            raise BagError(f"{out}: cannot write bag: {_detail(err)}") from None
        return n

    def info(self) -> dict:
        """What the recording holds, counted by reading it (``frames`` = scans on the LiDAR topic);
        ``metadata_counts`` where metadata.yaml states other counts, ``damage`` where reading stopped."""
        counts, damage = self.read_counts()
        types = {t: typ for t, (typ, _) in self.backend.topics.items()}
        d = {
            "path": str(self.path),
            "format": self.format,
            "topic": self.topic,
            "gt_topic": self.gt_topic,
            "frames": counts.get(self.topic, ("", 0))[1] if self.topic else None,
            "ground_truth": self.has_ground_truth,
            "cloud_topics": self.cloud_topics,
            "duration_s": (self.backend.end_ns - self.backend.start_ns) * 1e-9,
            "start_ns": self.backend.start_ns,
            "topics": [{"topic": t, "type": types.get(t, counts.get(t, ("?",))[0]), "count": counts.get(t, ("", 0))[1]}
                       for t in sorted(set(types) | set(counts))],
        }
        meta = _metadata_counts(self.path)
        if meta is not None:
            differ = {t: n for t, n in meta.items() if n != counts.get(t, ("", 0))[1]}
            if differ:
                d["metadata_counts"] = differ
        if damage:
            d["damage"] = damage
        return d


# -------------------------------------------------------------------------------------------- writer
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


def _qos():
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


def write_rosbag(
    scans: Iterable[Scan],
    out: Path | str,
    *,
    storage: str = "mcap",
    topic: str = APOLLO_LIDAR_TOPIC,
    gt_topic: str = GT_POSE_TOPIC,
    driver: str | None = None,
    shape: tuple[int, int] = (0, 0),
    chunk_size: int = 2**20,
) -> int:
    """Write scans as a rosbag2 directory (``storage`` ``"mcap"``, zstd chunks, or ``"sqlite3"``).

    Each scan becomes a ``sensor_msgs/msg/PointCloud2`` on ``topic`` (x y z float32 + every field of
    ``Scan.fields``, header stamp = ``stamp_ns``, frame = ``Scan.frame_id``; or, with ``driver``
    ``"velodyne"`` / ``"ouster"`` / ``"livox"`` / ``"hesai"``, that driver's layout,
    :func:`msg_adapters.layouts.driver_cloud`, with
    ``shape`` = (beams, columns) for the organised Ouster cloud); each ground-truth pose a
    ``geometry_msgs/msg/PoseStamped`` on ``gt_topic`` (frame ``world``, pose = ``T_world_lidar``, same
    stamp). Log times equal the header stamps. mcap: zstd chunks of ``chunk_size`` bytes, each with a
    CRC, and data and summary CRCs. The output is byte-for-byte deterministic.

    Returns:
        the number of scans written.
    """
    from rosbags.rosbag2 import WriterError

    from msg_adapters.layouts import driver_cloud
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2
    from msg_adapters.transforms import matrix_to_pose_stamped

    out = Path(out)
    if storage not in ("mcap", "sqlite3"):
        raise BagError(f"rosbag2 storage must be 'mcap' or 'sqlite3', got {storage!r}")
    typestore = _typestore()
    qos = [_qos()]
    n = 0
    try:
        with rosbag2_writer(out, storage, chunk_size=chunk_size) as writer:
            cloud_conn = writer.add_connection(topic, POINTCLOUD2, typestore=typestore, offered_qos_profiles=qos)
            gt_conn = None
            for scan in scans:
                if driver is None:
                    msg = arrays_to_pointcloud2(
                        scan.points, scan.fields, stamp_ns=scan.stamp_ns, frame_id=scan.frame_id, flavor="rosbags"
                    )
                else:
                    msg = driver_cloud(driver, scan.points, scan.fields, beams=shape[0], columns=shape[1],
                                       flavor="rosbags", stamp_ns=scan.stamp_ns, frame_id=scan.frame_id)
                writer.write(cloud_conn, scan.stamp_ns, typestore.serialize_cdr(msg, POINTCLOUD2))
                if scan.T_world_lidar is not None:
                    if gt_conn is None:
                        gt_conn = writer.add_connection(
                            gt_topic, POSE_TYPES[0], typestore=typestore, offered_qos_profiles=qos
                        )
                    pose = matrix_to_pose_stamped(scan.T_world_lidar, scan.stamp_ns, WORLD_FRAME, flavor="rosbags")
                    writer.write(gt_conn, scan.stamp_ns, typestore.serialize_cdr(pose, POSE_TYPES[0]))
                n += 1
    except WriterError as err:
        raise BagError(f"{out}: cannot write bag: {err}") from None
    return n


def write_rosbag1(
    scans: Iterable[Scan],
    out: Path | str,
    *,
    topic: str = APOLLO_LIDAR_TOPIC,
    gt_topic: str = GT_POSE_TOPIC,
) -> int:
    """Write scans as a ROS 1 ``.bag`` (rosbags' rosbag1 ``Writer``, uncompressed chunks, ROS 1 Noetic types).

    The same messages as :func:`write_rosbag` in their ROS 1 form: a ``sensor_msgs/PointCloud2`` per scan on
    ``topic`` (x y z float32 + every field of ``Scan.fields``, header stamp = ``stamp_ns``, ``seq`` = the
    scan's position) and a ``geometry_msgs/PoseStamped`` per ground-truth pose on ``gt_topic`` (frame
    ``world``, pose = ``T_world_lidar``, same stamp); log times equal the header stamps.

    Returns:
        the number of scans written.
    """
    from rosbags.rosbag1 import Writer, WriterError

    from msg_adapters.pointcloud2 import arrays_to_pointcloud2
    from msg_adapters.transforms import matrix_to_pose_stamped

    out = Path(out)
    if out.suffix != ".bag":
        raise BagError(f"{out}: a ROS 1 bag is a file named *.bag")
    if out.exists():
        raise BagError(f"{out} exists already, not overwriting")
    ts = _typestore(ros1=True)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    PointField, PointCloud2 = T["sensor_msgs/msg/PointField"], T["sensor_msgs/msg/PointCloud2"]
    PoseStamped, Pose = T["geometry_msgs/msg/PoseStamped"], T["geometry_msgs/msg/Pose"]
    Point, Quaternion = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    n = 0
    try:
        with Writer(out) as writer:
            cloud_conn = writer.add_connection(topic, POINTCLOUD2, typestore=ts)
            gt_conn = None
            for n, scan in enumerate(scans, start=1):
                m2 = arrays_to_pointcloud2(scan.points, scan.fields, stamp_ns=scan.stamp_ns, frame_id=scan.frame_id,
                                           flavor="rosbags")  # the ROS 2 layout; ROS 1 adds the header's seq
                stamp = Time(sec=scan.stamp_ns // 10**9, nanosec=scan.stamp_ns % 10**9)
                fields = [PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                          for f in m2.fields]
                msg = PointCloud2(header=Header(seq=n - 1, stamp=stamp, frame_id=scan.frame_id), height=m2.height,
                                  width=m2.width, fields=fields, is_bigendian=m2.is_bigendian,
                                  point_step=m2.point_step, row_step=m2.row_step, data=m2.data, is_dense=m2.is_dense)
                writer.write(cloud_conn, scan.stamp_ns, ts.serialize_ros1(msg, POINTCLOUD2))
                if scan.T_world_lidar is not None:
                    if gt_conn is None:
                        gt_conn = writer.add_connection(gt_topic, POSE_TYPES[0], typestore=ts)
                    p2 = matrix_to_pose_stamped(scan.T_world_lidar, scan.stamp_ns, WORLD_FRAME, flavor="rosbags").pose
                    pose = Pose(position=Point(x=p2.position.x, y=p2.position.y, z=p2.position.z),
                                orientation=Quaternion(x=p2.orientation.x, y=p2.orientation.y, z=p2.orientation.z,
                                                       w=p2.orientation.w))
                    pose_msg = PoseStamped(header=Header(seq=n - 1, stamp=stamp, frame_id=WORLD_FRAME), pose=pose)
                    writer.write(gt_conn, scan.stamp_ns, ts.serialize_ros1(pose_msg, POSE_TYPES[0]))
    except WriterError as err:
        raise BagError(f"{out}: cannot write bag: {err}") from None
    return n
