"""A real rclpy round trip: one node publishes a converted cloud over DDS, another receives and decodes it.

The two nodes live in two rclpy contexts (two DDS participants), so the message really goes through
Fast DDS discovery, serialization and transport on loopback (tests/conftest.py sets
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a per-run ROS_DOMAIN_ID before rclpy is imported).
"""

from __future__ import annotations

import time

import numpy as np
import rclpy

from msg_adapters.layouts import OUSTER, build_cloud
from msg_adapters.pointcloud2 import arrays_to_pointcloud2, pointcloud2_to_arrays
from msg_adapters.transforms import matrix_to_pose_stamped, pose_stamped_to_matrix

TIMEOUT_S = 15.0


def _exchange(messages: list, msg_type, topic: str) -> list:
    """Publish each message from one context until the other context's subscriber has received them all."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy

    qos = QoSProfile(
        depth=10, reliability=QoSReliabilityPolicy.RELIABLE, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL
    )
    ctx_pub, ctx_sub = rclpy.Context(), rclpy.Context()
    rclpy.init(context=ctx_pub)
    rclpy.init(context=ctx_sub)
    received: list = []
    pub_node = sub_node = executor = None
    try:
        pub_node = rclpy.create_node("deepbbs_test_publisher", context=ctx_pub)
        sub_node = rclpy.create_node("deepbbs_test_subscriber", context=ctx_sub)
        publisher = pub_node.create_publisher(msg_type, topic, qos)
        sub_node.create_subscription(msg_type, topic, received.append, qos)
        executor = SingleThreadedExecutor(context=ctx_sub)
        executor.add_node(sub_node)
        deadline = time.monotonic() + TIMEOUT_S
        while sub_node.count_publishers(topic) == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        for msg in messages:
            publisher.publish(msg)
        while len(received) < len(messages) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        if executor is not None:
            executor.shutdown()
        for node in (pub_node, sub_node):
            if node is not None:
                node.destroy_node()
        rclpy.try_shutdown(context=ctx_sub)
        rclpy.try_shutdown(context=ctx_pub)
    assert len(received) == len(messages), f"received {len(received)} of {len(messages)} messages in {TIMEOUT_S} s"
    return received


def test_pointcloud2_and_pose_over_dds(rng):
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import PointCloud2

    # a cloud built by the encoder and one in the Ouster driver layout (organised, NaN row, padding)
    xyz = rng.uniform(-50, 50, (5000, 3)).astype(np.float32)
    intensity = rng.uniform(0, 255, 5000).astype(np.float32)
    encoded = arrays_to_pointcloud2(
        xyz, {"intensity": intensity}, stamp_ns=1_700_000_000_000_000_123, frame_id="velodyne64"
    )
    h, w = 32, 256
    grid = rng.uniform(1, 80, (h * w, 3))
    grid[4 * w : 5 * w] = np.nan
    ouster = build_cloud(
        OUSTER,
        {"x": grid[:, 0], "y": grid[:, 1], "z": grid[:, 2], "ring": np.repeat(np.arange(h), w)},
        height=h,
        width=w,
        stamp_ns=42,
        frame_id="os",
    )

    got = _exchange([encoded, ouster], PointCloud2, "/deepbbs_test/points")
    got.sort(key=lambda m: m.header.frame_id)
    a = pointcloud2_to_arrays(got[1], ["intensity"])  # velodyne64
    np.testing.assert_array_equal(a.xyz, xyz)
    np.testing.assert_array_equal(a.fields["intensity"], intensity)
    assert (a.stamp_ns, a.frame_id) == (1_700_000_000_000_000_123, "velodyne64")
    b = pointcloud2_to_arrays(got[0], ["ring"])  # os
    keep = np.ones(h * w, bool)
    keep[4 * w : 5 * w] = False
    np.testing.assert_array_equal(b.xyz, grid[keep].astype(np.float32))
    np.testing.assert_array_equal(b.fields["ring"], np.repeat(np.arange(h), w)[keep])
    assert (b.height, b.width, b.stamp_ns, b.frame_id) == (h, w, 42, "os")

    # and a PoseStamped carrying T_target_source
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.5, -1.25, 0.0625]
    (pose,) = _exchange([matrix_to_pose_stamped(T, 99, "velodyne64")], PoseStamped, "/deepbbs_test/pose")
    T_back, stamp_ns, frame_id = pose_stamped_to_matrix(pose)
    np.testing.assert_allclose(T_back, T, atol=1e-15)
    assert (stamp_ns, frame_id) == (99, "velodyne64")
