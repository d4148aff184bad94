"""Stamps and message classes: ``builtin_interfaces/Time`` <-> integer nanoseconds, and the message classes of
the two flavours (``flavor="rclpy"``: ``geometry_msgs.msg`` ...; ``flavor="rosbags"``: typestore ROS2_JAZZY).

Readers are duck-typed; nothing here imports rclpy or rosbags at module level.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from deepbbs_ros.errors import TransformFormatError

_NS = 1_000_000_000
_FLAVORS = ("rclpy", "rosbags")


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
