"""Writing scans as bags: rosbag2 (mcap with every CRC, or sqlite3) and ROS 1 ``.bag`` (no ROS install).

rosbags' rosbag2 ``Writer`` (format version 9, as ROS 2 Jazzy writes) with mcap storage written by
``mcap.writer.Writer`` (zstd chunks, chunk, data-section and summary CRCs: :func:`rosbag2_writer`) or sqlite3; both
topics get an explicit offered QoS profile (reliable, volatile, keep-last 10). :func:`write_rosbag1` writes the same
messages as a ROS 1 ``.bag``. The rosbag2 writer and its QoS profile: datasets/rosbag2_writer.py (imported from
here too).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from deepbbs_ros.datasets.bag_common import POINTCLOUD2, POSE_TYPES, bag_typestore
from deepbbs_ros.datasets.base import APOLLO_LIDAR_TOPIC, GT_POSE_TOPIC, WORLD_FRAME, Scan
from deepbbs_ros.datasets.rosbag2_writer import _CrcMcapStorage, qos_profile, rosbag2_writer  # noqa: F401  (re-exported)
from deepbbs_ros.errors import BagError


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
    typestore = bag_typestore()
    qos = [qos_profile()]
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
    ts = bag_typestore(ros1=True)
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
