"""Conversions between ROS messages and numpy (no rclpy/rosbags import at module level).

- :mod:`msg_adapters.pointcloud2`: ``sensor_msgs/PointCloud2`` <-> (N, 3) float32 xyz + named fields.
- :mod:`msg_adapters.transforms`: (4, 4) float64 transforms <-> Pose / PoseStamped / TransformStamped /
  Odometry; ``builtin_interfaces/Time`` <-> integer nanoseconds (re-exported from :mod:`msg_adapters.stamps`;
  quaternions, the inverse: :mod:`msg_adapters.rotations`).
- :mod:`msg_adapters.layouts`: field layouts real LiDAR drivers publish, and a builder for them.

Readers are duck-typed (rclpy and rosbags messages); writers take ``flavor="rclpy" | "rosbags"``.
Both submodules re-exported here import only numpy; rclpy/rosbags are imported when a message is built.
"""

from msg_adapters.pointcloud2 import CloudArrays, arrays_to_pointcloud2, pointcloud2_to_arrays, pointcloud2_to_xyz
from msg_adapters.transforms import (
    TransformFormatError,
    matrix_to_odometry,
    matrix_to_pose,
    matrix_to_pose_stamped,
    matrix_to_transform_stamped,
    ns_to_stamp,
    odometry_to_matrix,
    pose_stamped_to_matrix,
    pose_to_matrix,
    stamp_to_ns,
    time_to_ns,
    transform_stamped_to_matrix,
)

__all__ = [
    "CloudArrays",
    "TransformFormatError",
    "arrays_to_pointcloud2",
    "matrix_to_odometry",
    "matrix_to_pose",
    "matrix_to_pose_stamped",
    "matrix_to_transform_stamped",
    "ns_to_stamp",
    "odometry_to_matrix",
    "pointcloud2_to_arrays",
    "pointcloud2_to_xyz",
    "pose_stamped_to_matrix",
    "pose_to_matrix",
    "stamp_to_ns",
    "time_to_ns",
    "transform_stamped_to_matrix",
]
