"""4x4 transforms <-> ``Pose`` / ``PoseStamped`` / ``TransformStamped`` / ``nav_msgs/Odometry``, stamps <-> ns.

Conventions (docs/CONVENTIONS.md): a transform is a (4, 4) float64 homogeneous matrix acting on column
vectors, ``p_target = R @ p_source + t``, named ``T_target_source``. A ``PoseStamped`` whose
``header.frame_id`` is ``target`` and whose pose is ``T_target_source`` holds ``t`` in
``pose.position`` and ``R`` in ``pose.orientation``; a ``TransformStamped`` from ``frame_id`` (target)
to ``child_frame_id`` (source) holds the same ``T_target_source``. Quaternions are (x, y, z, w),
normalised, written with ``w >= 0``.

Readers are duck-typed (rclpy and rosbags messages share field names); writers take
``flavor="rclpy"`` (``geometry_msgs.msg`` ...) or ``flavor="rosbags"`` (typestore ROS2_JAZZY).
Nothing here imports rclpy or rosbags at module level.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from deepbbs_ros.errors import TransformFormatError

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

_NS = 1_000_000_000
_FLAVORS = ("rclpy", "rosbags")
_ORTHO_TOL = 1e-4  # max |R^T R - I| accepted before a matrix is refused as "not a rotation"


# --------------------------------------------------------------------------------------------------
# stamps
# --------------------------------------------------------------------------------------------------


def time_to_ns(sec: Any, nanosec: Any, error: type[Exception] = TransformFormatError) -> int:
    """``builtin_interfaces/Time`` fields -> integer nanoseconds, checked: ``sec`` an int32 and
    ``0 <= nanosec < 1e9`` (a stamp that does not fit the message, or whose ``nanosec`` would carry into
    another second, raises ``error`` naming the stamp). Shared by every reader of stamps here."""
    try:
        s, n = int(sec), int(nanosec)
    except (TypeError, ValueError, OverflowError) as err:
        raise error(f"stamp sec={sec!r} nanosec={nanosec!r} is not a pair of integers") from err
    if not -(2**31) <= s < 2**31:
        raise error(f"stamp sec={s} does not fit builtin_interfaces/Time (int32 seconds)")
    if not 0 <= n < _NS:
        raise error(f"stamp nanosec={n} is out of range (must be 0 <= nanosec < 1000000000; sec={s})")
    return s * _NS + n


def stamp_to_ns(stamp: Any) -> int:
    """``builtin_interfaces/Time`` (either flavour, or an ``rclpy.time.Time``) -> integer nanoseconds.

    Raises:
        TransformFormatError: not a stamp, ``sec`` outside int32 or ``nanosec`` outside [0, 1e9).
    """
    if hasattr(stamp, "sec") and hasattr(stamp, "nanosec"):
        return time_to_ns(stamp.sec, stamp.nanosec)
    if hasattr(stamp, "nanoseconds"):  # rclpy.time.Time
        return int(stamp.nanoseconds)
    raise TransformFormatError(f"not a stamp: {type(stamp).__name__} has neither sec/nanosec nor nanoseconds")


def _split_ns(ns: int) -> tuple[int, int]:
    if isinstance(ns, (float, np.floating)) and not float(ns).is_integer():
        raise TransformFormatError(f"stamp {ns!r} ns is not an integer number of nanoseconds")
    sec, nanosec = divmod(int(ns), _NS)
    if not -(2**31) <= sec < 2**31:
        raise TransformFormatError(f"stamp {int(ns)} ns does not fit builtin_interfaces/Time (int32 seconds)")
    return sec, nanosec


def _check_flavor(flavor: str) -> None:
    if flavor not in _FLAVORS:
        raise TransformFormatError(f"unknown message flavor {flavor!r} (expected 'rclpy' or 'rosbags')")


@functools.lru_cache(maxsize=1)
def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _types(flavor: str):
    """A namespace giving the message classes of one flavour by short name."""
    _check_flavor(flavor)
    if flavor == "rosbags":
        t = _typestore().types
        return {
            "Time": t["builtin_interfaces/msg/Time"],
            "Header": t["std_msgs/msg/Header"],
            "Point": t["geometry_msgs/msg/Point"],
            "Quaternion": t["geometry_msgs/msg/Quaternion"],
            "Vector3": t["geometry_msgs/msg/Vector3"],
            "Pose": t["geometry_msgs/msg/Pose"],
            "PoseStamped": t["geometry_msgs/msg/PoseStamped"],
            "Transform": t["geometry_msgs/msg/Transform"],
            "TransformStamped": t["geometry_msgs/msg/TransformStamped"],
            "Twist": t["geometry_msgs/msg/Twist"],
            "PoseWithCovariance": t["geometry_msgs/msg/PoseWithCovariance"],
            "TwistWithCovariance": t["geometry_msgs/msg/TwistWithCovariance"],
            "Odometry": t["nav_msgs/msg/Odometry"],
        }
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import (
        Point,
        Pose,
        PoseStamped,
        PoseWithCovariance,
        Quaternion,
        Transform,
        TransformStamped,
        Twist,
        TwistWithCovariance,
        Vector3,
    )
    from nav_msgs.msg import Odometry
    from std_msgs.msg import Header

    return {
        "Time": Time,
        "Header": Header,
        "Point": Point,
        "Quaternion": Quaternion,
        "Vector3": Vector3,
        "Pose": Pose,
        "PoseStamped": PoseStamped,
        "Transform": Transform,
        "TransformStamped": TransformStamped,
        "Twist": Twist,
        "PoseWithCovariance": PoseWithCovariance,
        "TwistWithCovariance": TwistWithCovariance,
        "Odometry": Odometry,
    }


def ns_to_stamp(ns: int, flavor: str = "rclpy") -> Any:
    """Integer nanoseconds -> ``builtin_interfaces/Time`` (``sec`` floor-divided, ``0 <= nanosec < 1e9``)."""
    sec, nanosec = _split_ns(ns)
    return _types(flavor)["Time"](sec=sec, nanosec=nanosec)


def _header(types, stamp_ns: int, frame_id: str):
    sec, nanosec = _split_ns(stamp_ns)
    return types["Header"](stamp=types["Time"](sec=sec, nanosec=nanosec), frame_id=str(frame_id))


# --------------------------------------------------------------------------------------------------
# rotations
# --------------------------------------------------------------------------------------------------


def quaternion_to_matrix(q: Any) -> np.ndarray:
    """Quaternion (x, y, z, w) (array-like of 4, any norm > 0) -> (3, 3) float64 rotation matrix."""
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    if q.shape != (4,) or not np.isfinite(q).all():
        raise TransformFormatError(f"quaternion must be 4 finite numbers (x, y, z, w), got {q.tolist()}")
    norm = np.linalg.norm(q)
    if norm < 1e-12:
        raise TransformFormatError("quaternion has zero norm; it is not a rotation")
    x, y, z, w = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix -> (4,) float64 quaternion (x, y, z, w), unit norm, ``w >= 0``.

    Uses the largest of the four diagonal combinations (Shepperd), so it is stable near 180 degrees.
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[0, 0], R[1, 1], R[2, 2]
    trace = m00 + m11 + m22
    cands = np.array([trace, m00, m11, m22])
    k = int(np.argmax(cands))
    if k == 0:
        s = 2.0 * np.sqrt(max(1.0 + trace, 0.0))
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    elif k == 1:
        s = 2.0 * np.sqrt(max(1.0 + m00 - m11 - m22, 0.0))
        q = np.array([0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s])
    elif k == 2:
        s = 2.0 * np.sqrt(max(1.0 - m00 + m11 - m22, 0.0))
        q = np.array([(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(max(1.0 - m00 - m11 + m22, 0.0))
        q = np.array([(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def _check_matrix(T: Any) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise TransformFormatError(f"transform must be a (4, 4) matrix, got shape {T.shape}")
    if not np.isfinite(T).all():
        raise TransformFormatError("transform contains NaN or Inf")
    if np.abs(T[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-9:
        raise TransformFormatError(f"transform's last row is {T[3].tolist()}, expected [0, 0, 0, 1]")
    R = T[:3, :3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > _ORTHO_TOL or np.linalg.det(R) < 0:
        raise TransformFormatError(
            f"transform's 3x3 block is not a proper rotation (|R^T R - I| = {err:.2e}, det {np.linalg.det(R):.4f})"
        )
    return T


def invert(T: Any) -> np.ndarray:
    """The inverse of a rigid transform (4, 4) ``T_target_source``: ``T_source_target = [R^T, -R^T t]``.

    Raises TransformFormatError when ``T`` or its inverse is not finite: a finite but huge translation (say 1e308 m)
    whose ``-R^T t`` overflows is no transform a pose can be composed with."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise TransformFormatError(f"transform must be a finite (4, 4) matrix, got {T.tolist()}")
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    with np.errstate(over="ignore", invalid="ignore"):  # said below
        out[:3, 3] = -(T[:3, :3].T @ T[:3, 3])
    if not np.isfinite(out).all():
        raise TransformFormatError(f"the inverse of the transform is not finite (translation {T[:3, 3].tolist()} m)")
    return out


# --------------------------------------------------------------------------------------------------
# Pose / PoseStamped / TransformStamped / Odometry
# --------------------------------------------------------------------------------------------------


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
