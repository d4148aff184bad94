"""ROS bags: ROS 1 ``.bag``, ROS 2 bag directories (sqlite3 and mcap) and bare ``.mcap`` / ``.db3`` files.

Reading goes through rosbags' ``AnyReader`` (no ROS install). A bare ``.mcap`` that rosbags cannot
open (no summary section, e.g. a recording cut off mid-write) is read by streaming it with the
``mcap`` package and decoding the CDR payloads with the rosbags ROS 2 Jazzy typestore.

Topics: the LiDAR topic is the only ``sensor_msgs/msg/PointCloud2`` topic, or the one named by
``topic`` (several candidates: :class:`DatasetError` listing them and naming ``--topic``). Ground
truth comes from ``gt_topic`` (``geometry_msgs/msg/PoseStamped``, ``nav_msgs/msg/Odometry`` or
``geometry_msgs/msg/TransformStamped``, taken as ``T_world_lidar``), else from
``/ground_truth/pose`` when present, else from the only pose-typed topic whose name contains
``ground_truth``/``groundtruth``/``gt``; other pose topics (e.g. wheel ``/odom``) are never taken as
ground truth silently. Ground truth is matched by header stamp (see
:class:`~deepbbs_ros.datasets.base.PoseTrack`: exact, else interpolated between the two bracketing
poses within the tolerance, else the nearest within it).

Writing uses rosbags' rosbag2 ``Writer`` (format version 9, as ROS 2 Jazzy writes): mcap storage by
default with zstd chunk compression (rosbags' ``CompressionMode.STORAGE``, which the metadata
records as no bag-level compression, like rosbag2's own mcap plugin), or sqlite3. Both topics get
an explicit offered QoS profile (reliable, volatile, keep-last 10): a reliable publisher matches both
reliable and best-effort subscribers when the bag is played back.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from deepbbs_ros.datasets.base import (
    APOLLO_LIDAR_TOPIC,
    GT_POSE_TOPIC,
    WORLD_FRAME,
    PoseTrack,
    Scan,
    ScanSource,
)
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


def _rosbags_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error

    return (AnyReaderError, Reader1Error, Reader2Error)


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
class _AnyBackend:
    """rosbags AnyReader: ROS 1 .bag, rosbag2 directories, bare .mcap/.db3 with a summary."""

    def __init__(self, path: Path) -> None:
        from rosbags.highlevel import AnyReader

        ros1 = path.suffix == ".bag"
        self.reader = AnyReader([path], default_typestore=_typestore(ros1))
        self.reader.open()
        self.kind = "rosbag1" if ros1 else "rosbag2"
        self.topics: dict[str, tuple[str, int]] = {}
        for c in self.reader.connections:
            typ, cnt = self.topics.get(c.topic, (c.msgtype, 0))
            self.topics[c.topic] = (typ, cnt + int(c.msgcount))
        self.start_ns = int(self.reader.start_time) if self.reader.connections else 0
        self.end_ns = int(self.reader.end_time) - 1 if self.reader.connections else 0  # end_time is last + 1
        if path.is_dir():
            meta = path / "metadata.yaml"
            text = meta.read_text() if meta.is_file() else ""
            self.kind = "rosbag2-sqlite3" if "sqlite3" in text or any(path.glob("*.db3")) else "rosbag2-mcap"
        elif path.suffix in (".mcap", ".db3"):
            self.kind = "mcap" if path.suffix == ".mcap" else "db3"

    def messages(self, topics: list[str]) -> Iterator[tuple[str, str, Any]]:
        conns = [c for c in self.reader.connections if c.topic in topics]
        for conn, _t, raw in self.reader.messages(connections=conns):
            yield conn.topic, conn.msgtype, self.reader.deserialize(raw, conn.msgtype)

    def close(self) -> None:
        self.reader.close()


class _McapStreamBackend:
    """The ``mcap`` package streaming a bare .mcap (works without a summary / on a cut-off file)."""

    kind = "mcap"

    def __init__(self, path: Path) -> None:
        self.path = path
        self.files = sorted(path.glob("*.mcap")) if path.is_dir() else [path]
        self.kind = "rosbag2-mcap" if path.is_dir() else "mcap"
        self.typestore = _typestore()
        self.topics: dict[str, tuple[str, int]] = {}
        self.start_ns = self.end_ns = 0
        self.scan_error: str | None = None
        stamps = []
        try:
            for _schema, channel, message in self._iter(None):
                typ, cnt = self.topics.get(channel.topic, (_schema.name if _schema else "?", 0))
                self.topics[channel.topic] = (typ, cnt + 1)
                stamps.append(message.log_time)
        except _StreamEnd as err:
            self.scan_error = str(err)
        if stamps:
            self.start_ns, self.end_ns = min(stamps), max(stamps)

    def _iter(self, topics: list[str] | None):
        from mcap.exceptions import McapError
        from mcap.reader import NonSeekingReader

        for file in self.files:
            with open(file, "rb") as f:
                try:
                    reader = NonSeekingReader(f, validate_crcs=True)
                    yield from reader.iter_messages(topics=topics, log_time_order=False)
                except (McapError, EOFError, ValueError, OSError) as err:
                    detail = f"{type(err).__name__}: {err}" if str(err).strip() else type(err).__name__
                    raise _StreamEnd(f"{file}: bag is truncated or corrupt ({detail})") from None

    def _register(self, schema) -> None:
        from rosbags.typesys import get_types_from_msg

        name = schema.name
        if name in self.typestore.fielddefs:
            return
        if schema.encoding == "ros2msg":
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

    def messages(self, topics: list[str]) -> Iterator[tuple[str, str, Any]]:
        for schema, channel, message in self._iter(topics):
            if schema is None or channel.message_encoding != "cdr":
                raise BagError(f"{self.path}: topic {channel.topic} is not CDR-encoded ROS 2 data")
            self._register(schema)
            yield channel.topic, schema.name, self.typestore.deserialize_cdr(message.data, schema.name)

    def close(self) -> None:
        pass


class _StreamEnd(BagError):
    pass


# -------------------------------------------------------------------------------------------- reader
class BagSource(ScanSource):
    """Scans from a ROS 1/ROS 2 bag or bare mcap file, in recording order, index 0-based.

    Recording order is stamp order for bags written by this package (log time = header stamp)
    and for normal recordings of one LiDAR.
    """

    def __init__(
        self,
        path: Path | str,
        *,
        topic: str | None = None,
        gt_topic: str | None = None,
        gt_tolerance_s: float = 0.05,
        lenient: bool = False,
    ) -> None:
        super().__init__(path, lenient=lenient)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag")
        self.backend = self._open_backend()
        self.format = self.backend.kind
        self.topic = self._pick_topic(topic)
        self.gt_topic = self._pick_gt_topic(gt_topic)
        self.gt_tolerance_ns = int(round(gt_tolerance_s * 1e9))
        self.gt: PoseTrack | None = None
        self.has_ground_truth = self.gt_topic is not None

    # --- opening -------------------------------------------------------------------------------
    def _open_backend(self):
        errors = _rosbags_errors()
        try:
            return _AnyBackend(self.path)
        except (*errors, OSError, KeyError, ValueError, IndexError) as err:
            msg = str(err).strip() or type(err).__name__
            if (self.path.suffix == ".mcap" and self.path.is_file()) or (
                self.path.is_dir() and any(self.path.glob("*.mcap"))
            ):
                backend = _McapStreamBackend(self.path)  # no summary (cut off) or unusual writer
                if backend.scan_error and not backend.topics:
                    raise BagError(f"{self.path}: cannot read bag: {msg}; {backend.scan_error}") from None
                if backend.scan_error:
                    self.fault(BagError(backend.scan_error))
                return backend
            raise BagError(f"{self.path}: cannot read bag (truncated or corrupt?): {msg}") from None

    def _pick_topic(self, topic: str | None) -> str:
        clouds = sorted(t for t, (typ, _) in self.backend.topics.items() if typ == POINTCLOUD2)
        if topic is not None:
            if topic not in self.backend.topics:
                raise BagError(f"{self.path}: no topic {topic!r}; PointCloud2 topics: {', '.join(clouds) or 'none'}")
            if topic not in clouds:
                raise BagError(f"{self.path}: topic {topic!r} is {self.backend.topics[topic][0]}, not {POINTCLOUD2}")
            return topic
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

    def _load_gt(self) -> PoseTrack:
        stamps, poses = [], []
        self.gt_error: BagError | None = None
        try:
            for _topic, typ, msg in self.backend.messages([self.gt_topic]):
                T, stamp_ns = _gt_to_matrix(msg, typ)
                stamps.append(stamp_ns)
                poses.append(T)
        except BagError as err:
            self.gt_error = err
        except (*_rosbags_errors(), DeepBBSError, OSError, KeyError, ValueError) as err:
            self.gt_error = BagError(f"{self.path}: cannot read ground truth on {self.gt_topic}: {err}")
        if self.gt_error is not None:
            self.fault(self.gt_error)  # lenient: scans keep coming while their ground truth was read
        return PoseTrack(stamps, poses, self.gt_tolerance_ns)

    # --- iteration -----------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.backend.topics[self.topic][1])

    def _scans(self) -> Iterator[Scan]:
        from msg_adapters.pointcloud2 import pointcloud2_to_arrays

        if self.has_ground_truth and self.gt is None:
            self.gt = self._load_gt()
        index = 0
        it = self.backend.messages([self.topic])
        while True:
            try:
                item = next(it, None)
            except BagError:
                raise
            except (*_rosbags_errors(), OSError, KeyError, ValueError) as err:
                raise BagError(
                    f"{self.path}: bag is truncated or corrupt after {index} scans on {self.topic}: {err}"
                ) from None
            if item is None:
                return
            _topic, _typ, msg = item
            names = [str(f.name) for f in msg.fields if str(f.name) not in ("x", "y", "z")]
            try:
                cloud = pointcloud2_to_arrays(msg, names)
            except DeepBBSError as err:
                raise BagError(f"{self.path}: scan {index} on {self.topic}: {err}") from None
            T = None
            if self.has_ground_truth:
                T = self.gt.lookup(cloud.stamp_ns)
                if T is None and self.gt_error is not None:
                    raise self.gt_error
                if T is None:
                    raise BagError(
                        f"{self.path}: scan {index} (stamp {cloud.stamp_ns * 1e-9:.6f} s) has no ground truth on "
                        f"{self.gt_topic} within {self.gt_tolerance_ns * 1e-9:g} s"
                    )
            yield Scan(index, cloud.stamp_ns, cloud.xyz, dict(cloud.fields), frame_id=cloud.frame_id, T_world_lidar=T)
            index += 1

    def close(self) -> None:
        self.backend.close()

    def info(self) -> dict:
        d = super().info()
        d["duration_s"] = (self.backend.end_ns - self.backend.start_ns) * 1e-9
        d["start_ns"] = self.backend.start_ns
        d["topics"] = [{"topic": t, "type": typ, "count": n} for t, (typ, n) in sorted(self.backend.topics.items())]
        return d


# -------------------------------------------------------------------------------------------- writer
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
) -> int:
    """Write scans as a rosbag2 directory (``storage`` ``"mcap"``, zstd chunks, or ``"sqlite3"``).

    Each scan becomes a ``sensor_msgs/msg/PointCloud2`` on ``topic`` (x y z float32 + every field of
    ``Scan.fields``, header stamp = ``stamp_ns``, frame = ``Scan.frame_id``; or, with ``driver``
    ``"velodyne"`` / ``"ouster"``, that driver's layout, :func:`msg_adapters.layouts.driver_cloud`, with
    ``shape`` = (beams, columns) for the organised Ouster cloud); each ground-truth pose a
    ``geometry_msgs/msg/PoseStamped`` on ``gt_topic`` (frame ``world``, pose = ``T_world_lidar``, same
    stamp). Log times equal the header stamps. The output is byte-for-byte deterministic.

    Returns:
        the number of scans written.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    from msg_adapters.layouts import driver_cloud
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2
    from msg_adapters.transforms import matrix_to_pose_stamped

    out = Path(out)
    if storage not in ("mcap", "sqlite3"):
        raise BagError(f"rosbag2 storage must be 'mcap' or 'sqlite3', got {storage!r}")
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    typestore = _typestore()
    qos = [_qos()]
    n = 0
    try:
        writer = Writer(out, version=9, storage_plugin=plugin)
        if storage == "mcap":
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with writer:
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
