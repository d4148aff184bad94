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
:class:`~deepbbs_ros.datasets.poses.PoseTrack`: exact, else interpolated between the two bracketing
poses within the tolerance, else the nearest within it). Ground-truth quaternions are normalised on
reading (:func:`msg_adapters.transforms.quaternion_to_matrix`), so every pose is a rotation to about 1e-16.

Writing uses rosbags' rosbag2 ``Writer`` (format version 9, as ROS 2 Jazzy writes): mcap storage by
default with zstd chunk compression (rosbags' ``CompressionMode.STORAGE``, which the metadata
records as no bag-level compression, like rosbag2's own mcap plugin), the mcap file itself written
by ``mcap.writer.Writer`` with chunk, data-section and summary CRCs (:func:`rosbag2_writer`), or
sqlite3. Both topics get an explicit offered QoS profile (reliable, volatile, keep-last 10): a
reliable publisher matches both reliable and best-effort subscribers when the bag is played back.
:func:`write_rosbag1` writes the same messages as a ROS 1 ``.bag``.

This module is the reader (:class:`BagSource`); the parts live in their own modules: the rosbags backend
(``datasets/bag_any.py``), the mcap backend (``datasets/bag_mcap.py``), the topic choice (``datasets/bag_topics.py``),
the writers (``datasets/bag_write.py``) and what they share (``datasets/bag_common.py``). Their public names stay
importable from here.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from deepbbs_ros.datasets.bag_any import AnyBackend
from deepbbs_ros.datasets.bag_common import POINTCLOUD2, POSE_TYPES, detail, is_bag, is_mcap
from deepbbs_ros.datasets.bag_info import BagInfo
from deepbbs_ros.datasets.bag_mcap import McapBackend
from deepbbs_ros.datasets.bag_topics import cloud_topics, gt_to_matrix, pick_gt_topic, pick_topic, several_clouds
from deepbbs_ros.datasets.bag_write import rosbag2_writer, write_rosbag, write_rosbag1
from deepbbs_ros.datasets.base import Scan, ScanSource
from deepbbs_ros.datasets.poses import PoseTrack
from deepbbs_ros.errors import BagError, DeepBBSError

__all__ = [  # the public names, wherever they live
    "POINTCLOUD2", "POSE_TYPES", "BagSource", "is_bag", "rosbag2_writer", "write_rosbag", "write_rosbag1",
]


class BagSource(BagInfo, ScanSource):
    """Scans from a ROS 1/ROS 2 bag or bare mcap file, in recording order, index 0-based.

    Recording order is stamp order for bags written by this package (log time = header stamp)
    and for normal recordings of one LiDAR. Scans and ground truth are read in one pass: a scan is
    yielded once the poses around its stamp have been read, so damage in the middle of a recording
    costs only what comes after it. What it holds (``info``, ``read_counts``) and its copy (``copy_to``):
    datasets/bag_info.py.
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
        self.cloud_topics = cloud_topics(self.backend.topics)
        self.topic = pick_topic(self.path, self.backend.topics, topic, any_topic)
        self.gt_topic = pick_gt_topic(self.path, self.backend.topics, gt_topic)
        self.gt_tolerance_ns = int(round(gt_tolerance_s * 1e9))
        self.gt: PoseTrack | None = None
        self.has_ground_truth = self.gt_topic is not None

    # --- opening -------------------------------------------------------------------------------
    def _open_backend(self):
        if is_mcap(self.path):
            backend = McapBackend(self.path)
            if backend.scan_error and not backend.topics:
                raise BagError(f"{self.path}: cannot read bag: {backend.scan_error}")
            return backend  # damage met while counting is met (and reported) again while reading
        try:
            return AnyBackend(self.path)
        except Exception as err:  # noqa: BLE001 - damaged headers/indexes reach rosbags' parsers in many ways
            raise BagError(f"{self.path}: cannot read bag (truncated or corrupt?): {detail(err)}") from None

    # --- iteration -----------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.backend.topics[self.topic][1]) if self.topic else 0

    def _scans(self) -> Iterator[Scan]:
        from msg_adapters.pointcloud2 import pointcloud2_to_arrays

        if self.topic is None:
            raise several_clouds(self.path, self.cloud_topics)
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
                    raise BagError(f"{self.path}: {what} on {topic} cannot be decoded ({detail(err)})") from None
                if topic == self.gt_topic and self.has_ground_truth:
                    try:
                        T, stamp_ns = gt_to_matrix(msg, typ)
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
