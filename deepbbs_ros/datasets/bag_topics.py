"""Which topics of a bag hold the scans and the ground truth, and the ground-truth poses as matrices (no ROS install).

The LiDAR topic is the only ``sensor_msgs/msg/PointCloud2`` topic, or the one named; ground truth comes from the topic
named, else ``/ground_truth/pose``, else the only pose-typed topic named like ground truth (see datasets/rosbag.py).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from deepbbs_ros.datasets.bag_common import POINTCLOUD2, POSE_TYPES
from deepbbs_ros.datasets.base import GT_POSE_TOPIC
from deepbbs_ros.errors import BagError, DatasetError

_GT_NAME = re.compile(r"(^|[/_])(ground_?truth|groundtruth|gt)([/_]|$)", re.IGNORECASE)


def cloud_topics(topics: dict[str, tuple[str, int]]) -> list[str]:
    """The PointCloud2 topics among ``topics`` ({name: (type, count)}), sorted."""
    return sorted(t for t, (typ, _) in topics.items() if typ == POINTCLOUD2)


def several_clouds(path: Path, clouds: list[str]) -> DatasetError:
    """The error of a recording with several PointCloud2 topics and none chosen."""
    return DatasetError(f"{path}: {len(clouds)} PointCloud2 topics ({', '.join(clouds)}); pick one with --topic")


def pick_topic(path: Path, topics: dict[str, tuple[str, int]], topic: str | None,
               any_topic: bool = False) -> str | None:
    """The LiDAR topic among ``topics`` ({name: (type, count)}): ``topic`` when given (BagError unless it is a
    PointCloud2 topic), else the only PointCloud2 topic (none: BagError; several: DatasetError, or None with
    ``any_topic``)."""
    clouds = cloud_topics(topics)
    if topic is not None:
        if topic not in topics:
            raise BagError(f"{path}: no topic {topic!r}; PointCloud2 topics: {', '.join(clouds) or 'none'}")
        if topic not in clouds:
            raise BagError(f"{path}: topic {topic!r} is {topics[topic][0]}, not {POINTCLOUD2}")
        return topic
    if any_topic and len(clouds) != 1:
        return None
    if not clouds:
        listing = ", ".join(f"{t} ({typ})" for t, (typ, _) in sorted(topics.items()))
        raise BagError(f"{path}: no {POINTCLOUD2} topic (topics: {listing or 'none'})")
    if len(clouds) > 1:
        raise several_clouds(path, clouds)
    return clouds[0]


def pick_gt_topic(path: Path, topics: dict[str, tuple[str, int]], gt_topic: str | None) -> str | None:
    """The ground-truth topic: ``gt_topic`` when given (BagError unless it is pose-typed), else
    ``/ground_truth/pose`` when present, else the only pose topic named like ground truth, else None."""
    poses = sorted(t for t, (typ, _) in topics.items() if typ in POSE_TYPES)
    if gt_topic is not None:
        if gt_topic not in topics:
            listing = ", ".join(poses) or "none"
            raise BagError(f"{path}: no ground-truth topic {gt_topic!r}; pose topics: {listing}")
        typ = topics[gt_topic][0]
        if typ not in POSE_TYPES:
            raise BagError(
                f"{path}: ground-truth topic {gt_topic!r} is {typ}, not one of {', '.join(POSE_TYPES)}"
            )
        return gt_topic
    if GT_POSE_TOPIC in poses:
        return GT_POSE_TOPIC
    named = [t for t in poses if _GT_NAME.search(t)]
    return named[0] if len(named) == 1 else None


def gt_to_matrix(msg: Any, msgtype: str):
    """(T (4, 4), stamp_ns) from a PoseStamped / Odometry / TransformStamped message."""
    from msg_adapters.transforms import odometry_to_matrix, pose_stamped_to_matrix, transform_stamped_to_matrix

    if msgtype == "geometry_msgs/msg/PoseStamped":
        T, stamp_ns, _ = pose_stamped_to_matrix(msg)
    elif msgtype == "nav_msgs/msg/Odometry":
        T, stamp_ns, _, _ = odometry_to_matrix(msg)
    else:
        T, stamp_ns, _, _ = transform_stamped_to_matrix(msg)
    return T, stamp_ns
