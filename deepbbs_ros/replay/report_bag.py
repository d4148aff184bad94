"""The replay's results bag: the estimates (and the ground truth, clouds, the map) as a rosbag2 (mcap) for Foxglove."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.replay.methods import topic_name
from deepbbs_ros.replay.runner import LocalizationResults, OdometryResults, PairResults

#: the results bag of a localization run holds the map with at most this many points (a regular subsample)
BAG_MAP_POINTS = 1_000_000


def write_results_bag(path: Path, res: PairResults | OdometryResults | LocalizationResults, *,
                      world_frame: str = "world", map_frame: str = "map") -> dict[str, int]:
    """Write the estimates as a rosbag2 (mcap storage) that Foxglove opens.

    Pairs mode: ``/deepbbs_replay/<method>/pose`` PoseStamped (``T_target_source``, frame = target frame,
    stamp = source stamp), ``/deepbbs_replay/ground_truth/pose`` and, for the first few pairs,
    ``/deepbbs_replay/target_cloud`` and ``/deepbbs_replay/<method>/aligned_cloud`` (source points moved
    into the target frame by the estimate). Odometry mode: ``/deepbbs_replay/<method>/odometry`` and
    ``/deepbbs_replay/ground_truth/odometry`` nav_msgs/Odometry (``world_frame`` -> sensor frame).
    Localization mode: ``/deepbbs_replay/localization/pose`` PoseStamped (``T_map_scan`` in ``map_frame``, the
    published poses only), ``/deepbbs_replay/ground_truth/pose`` and the map once (``/deepbbs_replay/map``
    PointCloud2, at the first scan's stamp, at most :data:`BAG_MAP_POINTS` points).
    Returns the message count per topic.
    """
    from rosbags.typesys import Stores, get_typestore

    from deepbbs_ros.datasets.rosbag import rosbag2_writer
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2
    from msg_adapters.transforms import matrix_to_odometry, matrix_to_pose_stamped

    ts = get_typestore(Stores.ROS2_JAZZY)
    counts: dict[str, int] = {}
    messages: list[tuple[int, str, str, Any]] = []  # (stamp, topic, type, msg)

    def add(stamp, topic, msgtype, msg):
        messages.append((int(stamp), topic, msgtype, msg))

    if isinstance(res, PairResults):
        seen_gt = set()
        for r in res.records:
            if r.trial != 0 or not np.isfinite(r.T_est).all():
                continue
            add(r.src_stamp_ns, f"/deepbbs_replay/{topic_name(r.method)}/pose", "geometry_msgs/msg/PoseStamped",
                matrix_to_pose_stamped(r.T_est, r.src_stamp_ns, r.frame_id, flavor="rosbags"))
            if r.pair not in seen_gt:
                seen_gt.add(r.pair)
                add(r.src_stamp_ns, "/deepbbs_replay/ground_truth/pose", "geometry_msgs/msg/PoseStamped",
                    matrix_to_pose_stamped(r.T_gt, r.src_stamp_ns, r.frame_id, flavor="rosbags"))
        for c in res.clouds:
            add(c["stamp_ns"], "/deepbbs_replay/target_cloud", "sensor_msgs/msg/PointCloud2",
                arrays_to_pointcloud2(c["target"], stamp_ns=c["stamp_ns"], frame_id=c["frame_id"], flavor="rosbags"))
            for name, T in c["T_est"].items():
                if not np.isfinite(T).all():
                    continue
                xyz = (c["source"].astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
                add(c["stamp_ns"], f"/deepbbs_replay/{topic_name(name)}/aligned_cloud", "sensor_msgs/msg/PointCloud2",
                    arrays_to_pointcloud2(xyz, stamp_ns=c["stamp_ns"], frame_id=c["frame_id"], flavor="rosbags"))
    elif isinstance(res, LocalizationResults):
        if res.map_xyz is not None and res.records:
            xyz = np.asarray(res.map_xyz)[:: max(1, -(-len(res.map_xyz) // BAG_MAP_POINTS))].astype(np.float32)
            stamp = res.records[0].stamp_ns
            add(stamp, "/deepbbs_replay/map", "sensor_msgs/msg/PointCloud2",
                arrays_to_pointcloud2(xyz, stamp_ns=stamp, frame_id=map_frame, flavor="rosbags"))
        for r in res.records:
            if r.valid and np.isfinite(r.T_map_est).all():
                add(r.stamp_ns, "/deepbbs_replay/localization/pose", "geometry_msgs/msg/PoseStamped",
                    matrix_to_pose_stamped(r.T_map_est, r.stamp_ns, map_frame, flavor="rosbags"))
            if r.T_map_gt is not None:
                add(r.stamp_ns, "/deepbbs_replay/ground_truth/pose", "geometry_msgs/msg/PoseStamped",
                    matrix_to_pose_stamped(r.T_map_gt, r.stamp_ns, map_frame, flavor="rosbags"))
    else:
        n = res.frames
        child = res.frame_id or "lidar"
        tracks = [(topic_name(m), res.T_world_est[m][:n]) for m in res.methods]
        if res.has_ground_truth:
            tracks.append(("ground_truth", res.T_world_gt[:n]))
        for stem, poses in tracks:
            for k, T in enumerate(poses):
                add(res.stamps_ns[k], f"/deepbbs_replay/{stem}/odometry", "nav_msgs/msg/Odometry",
                    matrix_to_odometry(T, res.stamps_ns[k], world_frame, child, flavor="rosbags"))

    messages.sort(key=lambda m: m[0])
    with rosbag2_writer(path, "mcap") as writer:  # zstd chunks with chunk, data and summary CRCs
        conns = {}
        for stamp, topic, msgtype, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], stamp, ts.serialize_cdr(msg, msgtype))
            counts[topic] = counts.get(topic, 0) + 1
    return counts
