"""Scan sources (readers) and writers for bags, Apollo-style folders, KITTI folders and folders of scans.

One file per format, like kiss-icp's ``datasets/``: :mod:`.rosbag` (ROS 1 ``.bag``, rosbag2
directories with sqlite3 or mcap storage, bare ``.mcap``), :mod:`.apollo` (Apollo-SouthBay
``pcds/`` + ``poses/gt_poses.txt``), :mod:`.kitti` (KITTI odometry ``velodyne/`` + ``poses.txt`` +
``calib.txt``), :mod:`.folder` (plain folders of ``.bin``/``.pcd`` scans) and :mod:`.pcd` (PCD
files). :func:`open_source` picks the reader from the path,
:func:`write_scans` the writer from a format name. No ROS install is needed (rosbags, mcap). Every reader
hands out ground-truth rotations that are rotations (a matrix read from text is projected onto SO(3), a
quaternion normalised), so the same scans give the same metrics whatever their format.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from deepbbs_ros.datasets.base import (
    APOLLO_LIDAR_FRAME,
    APOLLO_LIDAR_TOPIC,
    GT_POSE_TOPIC,
    WORLD_FRAME,
    Scan,
    ScanSource,
)
from deepbbs_ros.datasets.pcd import read_pcd, write_pcd
from deepbbs_ros.datasets.poses import PoseTrack
from deepbbs_ros.errors import DatasetError

WRITE_FORMATS = ("apollo", "kitti", "mcap", "db3", "bag")

__all__ = [
    "APOLLO_LIDAR_FRAME",
    "APOLLO_LIDAR_TOPIC",
    "GT_POSE_TOPIC",
    "WORLD_FRAME",
    "WRITE_FORMATS",
    "PoseTrack",
    "Scan",
    "ScanSource",
    "open_source",
    "read_pcd",
    "write_pcd",
    "write_scans",
]


def open_source(
    path: Path | str,
    *,
    topic: str | None = None,
    gt_topic: str | None = None,
    gt_tolerance_s: float = 0.05,
    lenient: bool = False,
    any_topic: bool = False,
) -> ScanSource:
    """Open a recording as a :class:`ScanSource` (iterable of :class:`Scan`, ``len``, ``info()``).

    Args:
        path: a ROS 1 ``.bag``; a rosbag2 directory (sqlite3 or mcap); a bare ``.mcap`` or ``.db3``;
            an Apollo session folder (``pcds/``); a KITTI sequence folder (``velodyne/``); a plain
            folder of ``.bin`` (KITTI records) or ``.pcd`` scans, read in name order without ground truth.
        topic: PointCloud2 topic (bags only); None picks the only one.
        gt_topic: ground-truth PoseStamped/Odometry/TransformStamped topic (bags only); None takes
            ``/ground_truth/pose`` (or the only pose topic named ``*ground_truth*``/``*gt*``) if present.
        gt_tolerance_s: seconds; how far a ground-truth stamp may be from a scan's header stamp.
        lenient: yield every valid scan before a fault and record the fault in ``.errors`` instead
            of raising.
        any_topic: bags with several PointCloud2 topics open without ``topic`` (for listing them:
            ``topic`` is then None and iterating raises).

    Raises:
        DatasetError / BagError: unknown path, unreadable or truncated recording, malformed pose
            file (file and line), ambiguous topic (lists the candidates, names ``--topic``).
    """
    from deepbbs_ros.datasets.apollo import ApolloSource, is_apollo_folder
    from deepbbs_ros.datasets.folder import FolderSource, is_scan_folder
    from deepbbs_ros.datasets.kitti import KittiSource, is_kitti_folder
    from deepbbs_ros.datasets.rosbag import BagSource, is_bag

    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such file or directory")
    if gt_tolerance_s < 0:
        raise DatasetError(f"gt_tolerance_s must be >= 0, got {gt_tolerance_s}")
    folder_only = (topic, gt_topic) != (None, None)
    if is_apollo_folder(path):
        if folder_only:
            raise DatasetError(f"{path}: --topic/--gt-topic apply to bags, not to an Apollo folder")
        return ApolloSource(path, lenient=lenient)
    if is_kitti_folder(path):
        if folder_only:
            raise DatasetError(f"{path}: --topic/--gt-topic apply to bags, not to a KITTI folder")
        return KittiSource(path, lenient=lenient)
    if is_scan_folder(path) and not (path / "metadata.yaml").is_file():
        if folder_only:
            raise DatasetError(f"{path}: --topic/--gt-topic apply to bags, not to a folder of scans")
        return FolderSource(path, lenient=lenient)
    if is_bag(path):
        return BagSource(path, topic=topic, gt_topic=gt_topic, gt_tolerance_s=gt_tolerance_s, lenient=lenient,
                         any_topic=any_topic)
    raise DatasetError(
        f"{path}: not a recording this package reads (.bag, rosbag2 directory, .mcap, .db3, "
        "Apollo folder with pcds/, KITTI folder with velodyne/, folder of .bin or .pcd scans)"
    )


def write_scans(
    scans: Iterable[Scan],
    out: Path | str,
    fmt: str,
    *,
    topic: str = APOLLO_LIDAR_TOPIC,
    gt_topic: str = GT_POSE_TOPIC,
    progress: bool = False,
    driver: str | None = None,
    shape: tuple[int, int] = (0, 0),
) -> int:
    """Write scans to ``out`` as ``fmt``: ``"apollo"``, ``"kitti"``, ``"mcap"`` (rosbag2 directory,
    zstd-compressed mcap), ``"db3"`` (rosbag2 directory, sqlite3) or ``"bag"`` (a ROS 1 ``.bag`` file,
    ``write_rosbag1``). ``out`` must not exist or be empty. ``driver`` / ``shape``: rosbag2 clouds in a
    driver's field layout (see ``write_rosbag``).

    Returns:
        the number of scans written.
    """
    if fmt not in WRITE_FORMATS:
        raise DatasetError(f"unknown output format {fmt!r}; choose one of {', '.join(WRITE_FORMATS)}")
    if progress:
        from tqdm import tqdm

        total = len(scans) if hasattr(scans, "__len__") else None
        scans = tqdm(scans, total=total, unit="frames", desc=f"writing {fmt}")
    if fmt == "apollo":
        from deepbbs_ros.datasets.apollo import write_apollo

        return write_apollo(scans, out)
    if fmt == "kitti":
        from deepbbs_ros.datasets.kitti import write_kitti

        return write_kitti(scans, out)
    if fmt == "bag":
        if driver is not None:
            raise DatasetError("a driver's cloud layout is written to rosbag2 only (mcap, db3), not to a ROS 1 bag")
        from deepbbs_ros.datasets.rosbag import write_rosbag1

        return write_rosbag1(scans, out, topic=topic, gt_topic=gt_topic)
    from deepbbs_ros.datasets.rosbag import write_rosbag

    return write_rosbag(scans, out, storage="mcap" if fmt == "mcap" else "sqlite3", topic=topic, gt_topic=gt_topic,
                        driver=driver, shape=shape)
