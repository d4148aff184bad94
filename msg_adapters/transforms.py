"""4x4 transforms <-> ``Pose`` / ``PoseStamped`` / ``TransformStamped`` / ``nav_msgs/Odometry``, stamps <-> ns.

Conventions (docs/CONVENTIONS.md): a transform is a (4, 4) float64 homogeneous matrix acting on column
vectors, ``p_target = R @ p_source + t``, named ``T_target_source``. A ``PoseStamped`` whose
``header.frame_id`` is ``target`` and whose pose is ``T_target_source`` holds ``t`` in
``pose.position`` and ``R`` in ``pose.orientation``; a ``TransformStamped`` from ``frame_id`` (target)
to ``child_frame_id`` (source) holds the same ``T_target_source``. Quaternions are (x, y, z, w),
normalised, written with ``w >= 0``.

Readers are duck-typed (rclpy and rosbags messages share field names); writers take
``flavor="rclpy"`` (``geometry_msgs.msg`` ...) or ``flavor="rosbags"`` (typestore ROS2_JAZZY).
Nothing here imports rclpy or rosbags at module level. Stamps and the message classes are
:mod:`msg_adapters.stamps`, the rotations :mod:`msg_adapters.rotations`; their public names are re-exported here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.errors import TransformFormatError
from msg_adapters.rotations import _check_matrix, invert, matrix_to_quaternion, quaternion_to_matrix
from msg_adapters.stamps import _header, _types, ns_to_stamp, stamp_to_ns, time_to_ns

__all__ = [
    "TransformFormatError",
    "invert",
    "matrix_to_odometry",
    "matrix_to_pose",
    "matrix_to_pose_stamped",
    "matrix_to_quaternion",
    "matrix_to_transform_stamped",
    "ns_to_stamp",
    "odometry_covariances",
    "odometry_to_matrix",
    "odometry_twist",
    "pose_stamped_to_matrix",
    "pose_to_matrix",
    "quaternion_to_matrix",
    "stamp_to_ns",
    "time_to_ns",
    "transform_stamped_to_matrix",
]


def _matrix(position: Any, orientation: Any) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quaternion_to_matrix([orientation.x, orientation.y, orientation.z, orientation.w])
    T[:3, 3] = (float(position.x), float(position.y), float(position.z))
    if not np.isfinite(T[:3, 3]).all():
        raise TransformFormatError(f"translation is not finite: {T[:3, 3].tolist()}")
    return T


def pose_to_matrix(pose: Any) -> np.ndarray:
    """``geometry_msgs/Pose`` -> (4, 4) float64 ``T_frame_child`` (``p_frame = R p_child + t``)."""
    return _matrix(pose.position, pose.orientation)


def _pose(types, T: np.ndarray):
    T = _check_matrix(T)
    qx, qy, qz, qw = (float(v) for v in matrix_to_quaternion(T[:3, :3]))
    x, y, z = (float(v) for v in T[:3, 3])
    return types["Pose"](
        position=types["Point"](x=x, y=y, z=z), orientation=types["Quaternion"](x=qx, y=qy, z=qz, w=qw)
    )


def matrix_to_pose(T: np.ndarray, flavor: str = "rclpy") -> Any:
    """(4, 4) rigid transform -> ``geometry_msgs/Pose`` (quaternion x, y, z, w with w >= 0)."""
    return _pose(_types(flavor), T)


def pose_stamped_to_matrix(msg: Any) -> tuple[np.ndarray, int, str]:
    """``geometry_msgs/PoseStamped`` -> ``(T_frame_child (4, 4) float64, stamp_ns, header.frame_id)``."""
    return pose_to_matrix(msg.pose), stamp_to_ns(msg.header.stamp), str(msg.header.frame_id)


def matrix_to_pose_stamped(T: np.ndarray, stamp_ns: int = 0, frame_id: str = "", flavor: str = "rclpy") -> Any:
    """``T_target_source`` -> ``geometry_msgs/PoseStamped`` with ``header.frame_id = frame_id`` (the target)."""
    types = _types(flavor)
    return types["PoseStamped"](header=_header(types, stamp_ns, frame_id), pose=_pose(types, T))


def transform_stamped_to_matrix(msg: Any) -> tuple[np.ndarray, int, str, str]:
    """``geometry_msgs/TransformStamped`` -> ``(T_frame_child, stamp_ns, frame_id, child_frame_id)``.

    ``T_frame_child`` maps points in ``child_frame_id`` into ``header.frame_id``.
    """
    tf = msg.transform
    T = _matrix(tf.translation, tf.rotation)
    return T, stamp_to_ns(msg.header.stamp), str(msg.header.frame_id), str(msg.child_frame_id)


def matrix_to_transform_stamped(
    T: np.ndarray, stamp_ns: int = 0, frame_id: str = "", child_frame_id: str = "", flavor: str = "rclpy"
) -> Any:
    """``T_frame_child`` (4, 4) -> ``geometry_msgs/TransformStamped`` (``frame_id`` parent, ``child_frame_id``)."""
    types = _types(flavor)
    pose = _pose(types, T)
    p, q = pose.position, pose.orientation
    transform = types["Transform"](
        translation=types["Vector3"](x=p.x, y=p.y, z=p.z),
        rotation=types["Quaternion"](x=q.x, y=q.y, z=q.z, w=q.w),
    )
    return types["TransformStamped"](
        header=_header(types, stamp_ns, frame_id), child_frame_id=str(child_frame_id), transform=transform
    )


def odometry_to_matrix(msg: Any) -> tuple[np.ndarray, int, str, str]:
    """``nav_msgs/Odometry`` -> ``(T_frame_child, stamp_ns, frame_id, child_frame_id)`` (pose part only)."""
    T = pose_to_matrix(msg.pose.pose)
    return T, stamp_to_ns(msg.header.stamp), str(msg.header.frame_id), str(msg.child_frame_id)


def odometry_twist(msg: Any) -> np.ndarray:
    """``nav_msgs/Odometry`` twist -> (6,) float64 ``[vx, vy, vz, wx, wy, wz]`` in ``child_frame_id``."""
    t = msg.twist.twist
    return np.array([t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z], dtype=np.float64)


def odometry_covariances(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """``nav_msgs/Odometry`` -> ``(pose_covariance (6, 6), twist_covariance (6, 6))`` float64, row-major."""
    pose_cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6).copy()
    twist_cov = np.asarray(msg.twist.covariance, dtype=np.float64).reshape(6, 6).copy()
    return pose_cov, twist_cov


def _covariance(name: str, value: Any) -> np.ndarray:
    if value is None:
        return np.zeros(36, dtype=np.float64)
    arr = np.asarray(value, dtype=np.float64)
    if arr.size != 36 or arr.shape not in ((6, 6), (36,)):
        raise TransformFormatError(f"{name} must be (6, 6) or (36,), got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise TransformFormatError(f"{name} contains NaN or Inf")
    return np.ascontiguousarray(arr.reshape(36))


def matrix_to_odometry(
    T: np.ndarray,
    stamp_ns: int = 0,
    frame_id: str = "",
    child_frame_id: str = "",
    twist: Any = None,
    pose_covariance: Any = None,
    twist_covariance: Any = None,
    flavor: str = "rclpy",
) -> Any:
    """``T_frame_child`` -> ``nav_msgs/Odometry``.

    Args:
        T: (4, 4) pose of ``child_frame_id`` in ``frame_id`` (e.g. ``T_odom_lidar``).
        twist: optional (6,) ``[vx, vy, vz, wx, wy, wz]`` (m/s, rad/s) in ``child_frame_id``; zeros if None.
        pose_covariance, twist_covariance: optional (6, 6) or (36,) row-major; zeros if None.
    """
    types = _types(flavor)
    if twist is None:
        tw = np.zeros(6)
    else:
        tw = np.asarray(twist, dtype=np.float64).reshape(-1)
        if tw.shape != (6,) or not np.isfinite(tw).all():
            raise TransformFormatError(f"twist must be 6 finite numbers [vx, vy, vz, wx, wy, wz], got {tw.tolist()}")
    V = types["Vector3"]
    twist_msg = types["Twist"](
        linear=V(x=float(tw[0]), y=float(tw[1]), z=float(tw[2])),
        angular=V(x=float(tw[3]), y=float(tw[4]), z=float(tw[5])),
    )
    return types["Odometry"](
        header=_header(types, stamp_ns, frame_id),
        child_frame_id=str(child_frame_id),
        pose=types["PoseWithCovariance"](
            pose=_pose(types, T), covariance=_covariance("pose_covariance", pose_covariance)
        ),
        twist=types["TwistWithCovariance"](
            twist=twist_msg, covariance=_covariance("twist_covariance", twist_covariance)
        ),
    )
