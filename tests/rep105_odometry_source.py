"""A stand-in for a robot's odometry and robot_state_publisher, in a process of its own (tests/test_node_rep105.py).

Reads ``--poses`` (an .npz: ``stamps`` (K,) ns, ``T_map_base`` (K, 4, 4) the base's true poses, ``T_base_sensor``
(4, 4), ``sensor_frame``) and publishes ``base_link -> <sensor_frame>`` on /tf_static (transient local) and a
drifting ``odom -> base_link`` on /tf at ~40 Hz: ``T_odom_base(t) = inv(D(t)) @ T_map_base(t)`` with the odom frame
drifting in the map, ``D(t)`` = 0.4 m/s along x, -0.2 m/s along y, 2 deg/s of yaw since the first stamp (the true
map -> odom). The stamps step through the poses' span, 25 ms apart (the poses' own stamps among them), and start
over at its end. Prints ``ready`` once the span was published whole.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def drift(t_s: float) -> np.ndarray:
    """``T_map_odom`` at ``t_s`` s after the first stamp: the odom frame's drift in the map."""
    yaw = np.radians(2.0) * t_s
    D = np.eye(4)
    D[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    D[:3, 3] = [0.4 * t_s, -0.2 * t_s, 0.0]
    return D


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", required=True)
    ap.add_argument("--seconds", type=float, default=120.0)
    args = ap.parse_args()
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from tf2_msgs.msg import TFMessage

    from deepbbs_ros.node.tf_buffer import interpolate
    from msg_adapters.transforms import matrix_to_transform_stamped

    data = np.load(args.poses)
    stamps, poses = data["stamps"].astype(np.int64), data["T_map_base"]
    rclpy.init()
    node = rclpy.create_node("rep105_odometry_source")
    static_qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub_static = node.create_publisher(TFMessage, "/tf_static", static_qos)
    pub_tf = node.create_publisher(TFMessage, "/tf", 100)
    pub_static.publish(TFMessage(transforms=[matrix_to_transform_stamped(
        data["T_base_sensor"], int(stamps[0]), "base_link", str(data["sensor_frame"]))]))
    grid = np.unique(np.concatenate([np.arange(stamps[0], stamps[-1], 25_000_000), stamps]))
    end = time.monotonic() + args.seconds
    first = True
    while time.monotonic() < end:
        for s in grid:
            k = min(int(np.searchsorted(stamps, s, side="right")) - 1, len(stamps) - 2)
            a = (s - stamps[k]) / (stamps[k + 1] - stamps[k])
            T_map_base = interpolate(poses[k], poses[k + 1], float(a))
            T_odom_base = np.linalg.inv(drift((s - stamps[0]) * 1e-9)) @ T_map_base
            pub_tf.publish(TFMessage(transforms=[matrix_to_transform_stamped(T_odom_base, int(s), "odom",
                                                                             "base_link")]))
            time.sleep(0.025)
        if first:
            print("ready", flush=True)
            first = False
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
