"""Static transforms of ``/tf_static`` and the REP-105 base motion (no ROS import).

``robot_state_publisher`` (or ``static_transform_publisher``) latches the robot's fixed frames on
``/tf_static`` as ``tf2_msgs/TFMessage``: each ``TransformStamped`` holds ``T_parent_child``. The node keeps
them in a :class:`StaticTransforms` tree and looks up ``T_base_sensor`` (any chain of static frames between
``node.base_frame`` and the cloud's frame). Odometry runs in the sensor frame; what the node publishes is
the base's motion (as KISS-ICP's ROS 2 node does)::

    T_odom_base = T_base_sensor @ T_odom_sensor @ inv(T_base_sensor)

(:func:`base_motion`), i.e. the odom frame is the base frame at the first scan.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from deepbbs_ros.node.covariance import adjoint

#: the error kind (log, /diagnostics ``errors.bad_tf_static``) of a scan whose sensor mounting the node cannot use
BAD_MOUNT = "bad_tf_static"


class StaticTransforms:
    """A thread-safe tree of static transforms, fed with ``tf2_msgs/TFMessage`` (``add_message``)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._parent: dict[str, tuple[str, np.ndarray]] = {}  # child -> (parent, T_parent_child)

    def add(self, parent: str, child: str, T_parent_child: np.ndarray) -> None:
        with self._cond:
            self._parent[str(child)] = (str(parent), np.asarray(T_parent_child, dtype=np.float64))
            self._cond.notify_all()

    def add_message(self, msg: Any, rejected: list[str] | None = None) -> int:
        """Add every transform of a TFMessage; returns how many were added (invalid ones are skipped, and said in
        ``rejected``: :func:`valid_transforms`)."""
        n = 0
        for T, _, parent, child in valid_transforms(msg, rejected):
            self.add(parent, child, T)
            n += 1
        return n

    @property
    def frames(self) -> set[str]:
        with self._cond:
            return set(self._parent) | {p for p, _ in self._parent.values()}

    def _root(self, frame: str) -> tuple[str, np.ndarray]:
        """(root frame, ``T_root_frame``) following the parents of ``frame`` (cycles stop the walk)."""
        T, cur, seen = np.eye(4), frame, set()
        while cur in self._parent and cur not in seen:
            seen.add(cur)
            parent, T_parent_cur = self._parent[cur]
            T = T_parent_cur @ T
            cur = parent
        return cur, T

    def lookup(self, target: str, source: str) -> np.ndarray | None:
        """``T_target_source`` (4, 4) through the static tree, or None when the frames are not connected."""
        if target == source:
            return np.eye(4)
        with self._cond:
            (root_t, T_rt), (root_s, T_rs) = self._root(target), self._root(source)
        if root_t != root_s:
            return None
        return np.linalg.inv(T_rt) @ T_rs

    def wait(self, target: str, source: str, timeout: float, *at: Any) -> np.ndarray | None:
        """:meth:`lookup` (``at``: what a subclass's lookup takes beyond the frames, e.g. a stamp), waiting up to
        ``timeout`` s for the transforms to arrive."""
        end = time.monotonic() + max(0.0, timeout)
        with self._cond:
            while True:
                T = self.lookup(target, source, *at)
                if T is not None:
                    return T
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)


def valid_transforms(msg: Any, rejected: list[str] | None = None) -> Iterator[tuple[np.ndarray, int, str, str]]:
    """``(T_parent_child (4, 4), stamp_ns, parent, child)`` of each usable transform of a TFMessage: a malformed one
    (zero quaternion, NaN, no frame names, a frame its own parent) is skipped, and said in ``rejected``
    (``"parent -> child: why"``) when a list is given."""
    from msg_adapters.transforms import transform_stamped_to_matrix

    for ts in getattr(msg, "transforms", []):
        names = f"{getattr(getattr(ts, 'header', None), 'frame_id', '')!r} -> {getattr(ts, 'child_frame_id', '')!r}"
        try:
            T, stamp_ns, parent, child = transform_stamped_to_matrix(ts)
        except Exception as err:  # noqa: BLE001 - a malformed transform (zero quaternion, NaN) is not one to use
            why = str(err)
        else:
            if not (parent and child):
                why = "a frame name is empty"
            elif parent == child:
                why = "a frame is its own parent"
            elif not np.all(np.isfinite(T)):
                why = "not finite"
            else:
                yield T, stamp_ns, parent, child
                continue
        if rejected is not None:
            rejected.append(f"{names}: {why}")


def base_motion(T_base_sensor: np.ndarray, T_odom_sensor: np.ndarray) -> np.ndarray:
    """``T_odom_base = T_base_sensor @ T_odom_sensor @ inv(T_base_sensor)`` (odom = the base at the first scan)."""
    T_bs = np.asarray(T_base_sensor, dtype=np.float64)
    return T_bs @ np.asarray(T_odom_sensor, dtype=np.float64) @ np.linalg.inv(T_bs)


def base_covariance(T_base_sensor: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """A (6, 6) pose / twist covariance of the sensor's motion moved to the base's, ``Ad Sigma Ad^T``."""
    Ad = adjoint(np.asarray(T_base_sensor, dtype=np.float64))
    out = Ad @ np.asarray(cov, dtype=np.float64) @ Ad.T
    return 0.5 * (out + out.T)


def unusable_mount(base: str, frame: str, why: str) -> str:
    """The error line of a ``base <- frame`` transform on ``/tf_static`` the node cannot compose poses with."""
    return (f"{base} <- {frame} on /tf_static is not usable: {why}; the scan's outputs are withheld until a usable "
            "transform arrives (check robot_state_publisher's URDF or the static_transform_publisher arguments)")
