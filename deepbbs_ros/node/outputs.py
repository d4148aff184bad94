"""The node's outputs: publishers and the messages built from a registration (ROS layer).

* ``~/pose`` (geometry_msgs/PoseStamped) and ``~/transform`` (geometry_msgs/TransformStamped), always;
* ``~/odometry`` (nav_msgs/Odometry: pose, twist and both covariances) when ``node.publish_odometry``;
* ``/tf`` when ``node.publish_tf`` (odometry mode; pair mode also needs ``node.pair_tf``): ``odom_frame ->
  base_frame``, or its inverse ``base_frame -> odom_frame`` with ``node.invert_tf``; needs tf2_msgs
  (``deepbbs-ros build-interfaces``), or a ``tf_broadcaster`` callable given to the node;
* odometry mode publishes the base's motion, ``T_odom_base = T_base_sensor @ T_odom_sensor @
  inv(T_base_sensor)`` with ``T_base_sensor`` from ``/tf_static`` (:mod:`deepbbs_ros.node.tf_static`;
  ``extrinsic(cloud_frame)`` given by the node; identity when ``node.base_frame`` is empty);
* ``~/aligned_cloud`` when ``node.publish_aligned_cloud``: pair mode, the source moved into the target
  frame (``frame_id`` = target frame); odometry mode, the scan moved by its pose into ``node.odom_frame``
  (``frame_id`` = odom frame), so consecutive scans overlay in RViz with the fixed frame ``odom``;
* ``/diagnostics`` (diagnostic_msgs/DiagnosticArray).

Frames and stamps follow docs/CONVENTIONS.md: a message's stamp is the source cloud's, never the wall clock.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TransformStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import PointCloud2

from deepbbs_ros.config import NodeConfig
from deepbbs_ros.core.covariance import conjugated
from deepbbs_ros.errors import NodeError
from deepbbs_ros.node.covariance import twist_from_delta
from deepbbs_ros.node.inputs import BadInput, Cloud
from deepbbs_ros.node.pipeline import (
    UNKNOWN_TWIST_COV,
    OdometryEstimate,
    Registered,
    motion_twist,
    registration_covariance,
)
from deepbbs_ros.node.tf_static import BAD_MOUNT, base_covariance, base_motion, unusable_mount
from msg_adapters.pointcloud2 import arrays_to_pointcloud2
from msg_adapters.transforms import matrix_to_odometry, matrix_to_pose_stamped, matrix_to_transform_stamped

TfBroadcaster = Callable[[list[Any]], None]  # list of geometry_msgs/TransformStamped -> broadcast on /tf


class Outputs:
    """The publishers of one node (created on ``node``) and what they publish.

    Args:
        node: the rclpy node that owns the publishers.
        ncfg: ``node`` section of the config.
        cloud_qos: QoS of ``~/aligned_cloud`` (the inputs' QoS).
        on_error: ``(kind, message)`` for rate-limited warnings (e.g. a same-frame TF refused).
        tf_broadcaster: replaces the ``/tf`` publisher when ``node.publish_tf`` is set (tests, or a
            tf2_ros broadcaster); default: a tf2_msgs/TFMessage publisher on ``/tf``.
        extrinsic: ``cloud_frame -> T_base_sensor`` (4, 4) for odometry mode; default: identity.

    Raises:
        NodeError: ``node.publish_tf`` without tf2_msgs and without ``tf_broadcaster``.
    """

    def __init__(
        self,
        node: Any,
        ncfg: NodeConfig,
        cloud_qos: Any,
        on_error: Callable[[str, str], None],
        tf_broadcaster: TfBroadcaster | None = None,
        extrinsic: Callable[[str], np.ndarray] | None = None,
    ) -> None:
        self.cfg = ncfg
        self._extrinsic = extrinsic or (lambda frame: np.eye(4))
        self._on_error = on_error
        self.published = 0
        self.pose = node.create_publisher(PoseStamped, "~/pose", 10)
        self.transform = node.create_publisher(TransformStamped, "~/transform", 10)
        self.diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.odometry = node.create_publisher(Odometry, "~/odometry", 10) if ncfg.publish_odometry else None
        self.aligned = None
        if ncfg.publish_aligned_cloud:
            self.aligned = node.create_publisher(PointCloud2, "~/aligned_cloud", cloud_qos)
        self.tf: TfBroadcaster | None = None
        # localization mode: REP-105's map -> odom (node/rep105.py), never the sensor frame as a child of map
        if ncfg.publish_tf and (ncfg.mode == "odometry" or ncfg.pair_tf or ncfg.target_mode == "localization"):
            self.tf = tf_broadcaster or _tf_publisher(node)

    # -- one registration ---------------------------------------------------------------------------
    def _pose_and_transform(self, T: np.ndarray, stamp_ns: int, frame: str, child: str) -> None:
        self.pose.publish(matrix_to_pose_stamped(T, stamp_ns, frame))
        ts = matrix_to_transform_stamped(T, stamp_ns, frame, child)
        self.transform.publish(ts)
        if self.tf is not None:
            if frame == child:
                self._on_error("tf_same_frame", f"not broadcasting {frame} -> {child} on /tf: same frame")
            elif self.cfg.invert_tf:  # base -> odom: the tree of a stack whose odom frame has another parent
                self.tf([matrix_to_transform_stamped(np.linalg.inv(T), stamp_ns, child, frame)])
            else:
                self.tf([ts])
        self.published += 1

    def pair(self, src: Cloud, tgt: Cloud, reg: Registered) -> None:
        """Pair mode: ``T_target_source`` in the target frame, stamped with the source stamp; on
        ``~/odometry`` with the registration covariance and the twist over the two stamps."""
        self._pose_and_transform(reg.T, src.stamp_ns, tgt.frame_id, src.frame_id)
        if self.odometry is not None:
            cov = registration_covariance(src, tgt, reg)
            twist, twist_cov = motion_twist(reg.T, cov, (src.stamp_ns - tgt.stamp_ns) * 1e-9)
            self.odometry.publish(
                matrix_to_odometry(reg.T, src.stamp_ns, tgt.frame_id, src.frame_id, twist, cov, twist_cov)
            )
        self._aligned(src, reg.T, tgt.frame_id)

    def localized(self, src: Cloud, frame: str, reg: Registered, target_points: np.ndarray | None) -> None:
        """Latched target: ``T_map_source`` in the map ``frame``, stamped with the source stamp; on
        ``~/odometry`` with the localization's covariance (else the registration covariance against the map crop; no
        velocity: unknown twist)."""
        self._pose_and_transform(reg.T, src.stamp_ns, frame, src.frame_id)
        if self.odometry is not None:
            cov = getattr(reg.result, "covariance", None)  # the localization's own (core/covariance.py)
            if cov is not None:
                cov = np.asarray(cov, dtype=np.float64)
            elif target_points is None:
                cov = np.eye(6) * UNKNOWN_TWIST_COV
            else:
                cov = crop_covariance(src, reg, target_points)
            self.odometry.publish(
                matrix_to_odometry(reg.T, src.stamp_ns, frame, src.frame_id, np.zeros(6), cov,
                                   np.eye(6) * UNKNOWN_TWIST_COV)
            )  # fmt: skip
        self._aligned(src, reg.T, frame)

    def odometry_step(self, cloud: Cloud, step: OdometryEstimate) -> None:
        """Odometry mode: the base's pose ``T_odom_base`` in ``node.odom_frame`` -> ``node.base_frame`` (or the
        cloud frame): the sensor's odometry conjugated with ``T_base_sensor``, twist and covariances moved along;
        ``~/aligned_cloud``: the scan in the odom frame."""
        odom, child = self.cfg.odom_frame, self.cfg.base_frame or cloud.frame_id
        T_bs = self._extrinsic(cloud.frame_id)
        moved = not np.allclose(T_bs, np.eye(4))
        with np.errstate(over="ignore", invalid="ignore"):  # an absurd mounting: checked below
            T_odom = base_motion(T_bs, step.T_odom)
            twist_and_covs = ()
            if self.odometry is not None:
                twist = step.twist
                if step.T_prev_curr is not None and step.dt > 1e-3 and moved:
                    twist = twist_from_delta(base_motion(T_bs, step.T_prev_curr), step.dt)  # in the base frame
                twist_and_covs = (twist, conjugated(T_bs, step.T_odom, step.pose_covariance),
                                  base_covariance(T_bs, step.twist_covariance))
        if moved and not all(np.isfinite(a).all() for a in (T_odom, *twist_and_covs)):
            raise BadInput(BAD_MOUNT, unusable_mount(child, cloud.frame_id, f"the pose or covariance of {child} it "
                                                     f"gives is not finite (translation {T_bs[:3, 3].tolist()} m)"))
        self._pose_and_transform(T_odom, cloud.stamp_ns, odom, child)
        if self.odometry is not None:
            self.odometry.publish(matrix_to_odometry(T_odom, cloud.stamp_ns, odom, child, *twist_and_covs))
        # the scan (sensor frame) moved into the odom frame, stamped with that frame: it lines up with every
        # earlier scan in RViz (fixed frame odom), whatever TF holds; T_odom_base @ T_base_sensor
        self._aligned(cloud, T_odom @ T_bs, odom)

    def _aligned(self, src: Cloud, T: np.ndarray, frame: str) -> None:
        if self.aligned is None:
            return
        xyz = (src.xyz.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
        self.aligned.publish(arrays_to_pointcloud2(xyz, stamp_ns=src.stamp_ns, frame_id=frame))

    # -- diagnostics ---------------------------------------------------------------------------------
    def publish_diagnostics(self, name: str, hardware_id: str, values: dict[str, Any], n_errors: int, stamp,
                            warning: str = "") -> None:
        """One DiagnosticStatus (OK; WARN once any error was counted, or with a ``warning``: its message) with
        ``values`` as key/values."""
        level, message = DiagnosticStatus.OK, "running"
        if n_errors:
            level, message = DiagnosticStatus.WARN, f"{n_errors} bad inputs / errors so far"
        if warning:
            level, message = DiagnosticStatus.WARN, warning
        status = DiagnosticStatus(
            level=level,
            name=name,
            message=message,
            hardware_id=hardware_id,
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
        )
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = stamp
        self.diagnostics.publish(arr)


class _Points:
    """A preprocessed-cloud stand-in: the points the covariance reads (``.points``)."""

    def __init__(self, points: np.ndarray) -> None:
        self.points = points


def crop_covariance(src: Cloud, reg: Registered, target_points: np.ndarray) -> np.ndarray:
    """(6, 6) :func:`registration_covariance` of ``reg`` (the source on a map crop) against ``target_points`` (M, 3),
    the crop's points in the pose's frame."""
    return registration_covariance(src, Cloud(target_points, 0, "", 0.0, pp=_Points(target_points)), reg)


def _tf_publisher(node: Any) -> TfBroadcaster:
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError as err:
        raise NodeError(
            "node.publish_tf needs the tf2_msgs package, which is not installed: build it with "
            "`deepbbs-ros build-interfaces` (`make venv` does; ROS: ros-jazzy-tf2-msgs), or set node.publish_tf:=false"
        ) from err
    pub = node.create_publisher(TFMessage, "/tf", 100)
    return lambda transforms: pub.publish(TFMessage(transforms=transforms))

