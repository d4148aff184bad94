"""``deepbbs-ros map-server MAP``: a map server for pip installs (no ``ros2`` / ``pcl_ros`` needed).

Reads a ``.pcd`` / ``.ply`` point cloud (:func:`deepbbs_ros.datasets.maps.read_map`) and latches it as one
``sensor_msgs/PointCloud2`` on a topic, reliable and transient local with depth 1 (as map servers do: a subscriber
that joins later still gets it), until Ctrl-C / SIGTERM. The node's ``target_cloud`` in ``node.target_mode``
latched or localization takes it::

    deepbbs-ros map-server site.pcd --topic /map/points --frame map
    deepbbs-node --ros-args -p node.target_mode:=localization -r source_cloud:=/points -r target_cloud:=/map/points
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from deepbbs_ros.errors import NodeError

if TYPE_CHECKING:  # numpy is imported where it is used: `deepbbs-ros --help` stays quick
    import numpy as np

#: coordinates farther than this (m) from the origin (UTM, a survey) are sent as float64: float32 keeps ~1 cm there
FLOAT64_BEYOND = 100_000.0


def add_parser(sub: Any) -> None:
    ms = sub.add_parser(
        "map-server", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="latch a .pcd / .ply map as a PointCloud2 on a topic until stopped (a map server)",
        description="Read MAP (.pcd or .ply) and publish it once as sensor_msgs/PointCloud2 on --topic, reliable "
                    "and transient local with depth 1 (latched: a subscriber that joins later still gets it), until "
                    "Ctrl-C / SIGTERM. The stamp is the time of publication; the points are in --frame.",
        epilog="example:\n  deepbbs-ros map-server site.pcd --topic /map/points --frame map --voxel 0.2",
    )
    ms.add_argument("map", metavar="MAP", help="the map file, .pcd or .ply (points in the map frame)")
    ms.add_argument("--topic", default="/map/points", help="the topic to latch it on (default: /map/points)")
    ms.add_argument("--frame", default="map", help="header.frame_id of the cloud (default: map)")
    ms.add_argument("--voxel", type=float, default=0.0, metavar="M",
                    help="publish the centroid of each M m voxel instead of every point (default: 0, every point)")


def load(args: argparse.Namespace) -> tuple[np.ndarray, str]:
    """(points (N, 3) float64, a line describing them) from ``args.map`` and ``args.voxel``; one-line errors
    (a bad file, flag or frame) before any DDS."""
    from rclpy.validate_topic_name import validate_topic_name

    from deepbbs_ros.datasets.maps import read_map

    if not args.frame or args.frame.startswith("/") or any(c.isspace() for c in args.frame):
        raise NodeError(f"--frame: invalid frame id {args.frame!r} (not empty, no leading '/', no spaces)")
    if not args.voxel >= 0:
        raise NodeError(f"--voxel must be >= 0 m, got {args.voxel:g}")
    try:
        validate_topic_name(args.topic)
    except Exception as err:  # rclpy's InvalidTopicNameException: its first line names the problem
        raise NodeError(f"--topic {args.topic!r}: {str(err).splitlines()[0]}") from None
    pts = read_map(args.map, trajectory=False).points
    read = len(pts)
    if args.voxel > 0:
        pts = voxel_centroids(pts, args.voxel)
    kept = f", {len(pts)} after the {args.voxel:g} m voxel grid" if args.voxel > 0 else ""
    return pts, f"{args.map}: {read} points{kept}"


def voxel_centroids(points: np.ndarray, voxel: float) -> np.ndarray:
    """(M, 3) float64 the centroid of the points (N, 3) of every occupied ``voxel`` m cube (float64 throughout:
    a map in UTM keeps its millimetres)."""
    import numpy as np

    key = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    sums = np.stack([np.bincount(inv, weights=points[:, j], minlength=len(counts)) for j in range(3)], axis=1)
    return sums / counts[:, None]


def serve(node: Any, points: np.ndarray, args: argparse.Namespace, what: str) -> int:
    """Publish ``points`` once on ``args.topic`` (reliable, transient local, depth 1) and keep the publisher until
    Ctrl-C / SIGTERM (exit code 0)."""
    import numpy as np
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from msg_adapters.pointcloud2 import arrays_to_pointcloud2

    far = bool(len(points)) and float(np.abs(points).max()) > FLOAT64_BEYOND
    msg = arrays_to_pointcloud2(points, stamp_ns=node.get_clock().now().nanoseconds, frame_id=args.frame,
                                xyz_dtype=np.float64 if far else np.float32)
    qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub = node.create_publisher(PointCloud2, args.topic, qos)
    pub.publish(msg)
    print(f"{args.topic}: {what} in {args.frame!r} ({'float64' if far else 'float32'} x y z; latched; Ctrl-C to "
          "stop)", flush=True)
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.5)
    return 0
