"""REP-105 frames of ``node.target_mode: localization``: what a Nav2 stack expects of a localizer (ROS layer).

Every frame keeps one parent::

    map_frame ──(this node)──▶ odom_frame ──(the odometry source)──▶ base_frame ──(/tf_static)──▶ <cloud frame>

Each localized scan gives ``T_map_sensor``; the base's pose is ``T_map_base = T_map_sensor @ inv(T_base_sensor)``
(``T_base_sensor`` from ``/tf_static``) and, with ``T_odom_base`` at the scan's stamp,
``T_map_odom = T_map_base @ inv(T_odom_base)``: broadcast on ``/tf`` stamped ``node.transform_tolerance`` s after
the scan (as AMCL does), and again every ``node.map_odom_period`` s between scans. ``node.localization_odom``
says who owns ``odom -> base``: ``"tf"`` another node (looked up in the node's TF buffer, fed from ``/tf``),
``"lidar"`` the node's own LiDAR odometry on the same scans (published here, at the scan's stamp), ``"none"``: no
odom frame, ``map -> base`` is published instead. The sensor frame and the base frame are never made a child here.

``~/pose``, ``~/transform``, ``~/odometry`` and ``~/pose_with_covariance`` (geometry_msgs/PoseWithCovarianceStamped,
as AMCL's ``amcl_pose``: reliable, transient local, depth 1) give ``T_map_base``. ``/initialpose`` (RViz's "2D Pose
Estimate": the base's pose in the map frame) becomes a hint for the tracker (``MapTracker.hint``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from deepbbs_ros.node.covariance import skew
from deepbbs_ros.node.inputs import Cloud
from deepbbs_ros.node.outputs import crop_covariance
from deepbbs_ros.node.pipeline import UNKNOWN_TWIST_COV, OdometryEstimate, Registered
from deepbbs_ros.node.tf_buffer import TransformBuffer
from deepbbs_ros.node.tf_static import base_motion
from msg_adapters.transforms import (
    matrix_to_odometry,
    matrix_to_pose,
    matrix_to_pose_stamped,
    matrix_to_transform_stamped,
    ns_to_stamp,
    pose_to_matrix,
    stamp_to_ns,
)

#: ~/pose_with_covariance: AMCL's amcl_pose QoS (the last pose waits for a late subscriber)
POSE_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
INITIALPOSE_TOPIC = "/initialpose"


def move_pivot(cov: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """A (6, 6) pose covariance (x, y, z, rot x, rot y, rot z; map axes) whose rotation turns about one point, moved to
    turn about the point ``lever`` (3,) m further (map axes): ``dp' = dp + dtheta x lever``, i.e. ``M Sigma M^T``
    with ``M = [[I, -[lever]_x], [0, I]]``."""
    M = np.eye(6)
    M[:3, 3:] = -skew(np.asarray(lever, dtype=np.float64))
    out = M @ np.asarray(cov, dtype=np.float64) @ M.T
    return 0.5 * (out + out.T)


def base_pose_covariance(result: Any, src: Cloud, reg: Registered, crop: np.ndarray | None,
                         T_map_sensor: np.ndarray, T_map_base: np.ndarray) -> np.ndarray:
    """The (6, 6) covariance of ``T_map_base`` (position of the base in map axes, rotation in map axes about it: what
    robot_localization reads). ``result.covariance`` when the localizer gives one (about the sensor's origin), else
    the registration's residual covariance against the map crop (``registration_covariance``, about the map origin,
    from the points the result says it registered); the unknown-value placeholder when neither exists."""
    cov = getattr(result, "covariance", None)
    if cov is not None:
        cov = np.asarray(cov, dtype=np.float64)
        if cov.shape == (6, 6) and np.isfinite(cov).all():
            return move_pivot(cov, T_map_base[:3, 3] - T_map_sensor[:3, 3])
    if crop is None:
        return np.eye(6) * UNKNOWN_TWIST_COV
    # the residuals of the points the result says it registered (none in this mode today: the placeholder); a k-d
    # tree of the whole crop per scan would cost ~27 ms of the tracking's ~40 ms
    cov = crop_covariance(src, reg, crop)
    if np.all(np.diag(cov) >= UNKNOWN_TWIST_COV):
        return cov
    return move_pivot(cov, T_map_base[:3, 3])


class Rep105:
    """The localization mode's outputs in REP-105 frames (module docstring).

    Args:
        node: the rclpy node (publishers, /initialpose subscription, clock, logger).
        ncfg: the ``node`` config section.
        outputs: the node's :class:`~deepbbs_ros.node.outputs.Outputs` (``~/pose``, ``~/transform``, ``~/odometry``,
            ``~/aligned_cloud``, and ``/tf`` as ``outputs.tf``).
        tf: the node's TF buffer (``/tf``, ``/tf_static``).
        extrinsic: ``cloud frame -> T_base_sensor`` (4, 4) (the node's ``/tf_static`` lookup).
        warn: ``(kind, message)``: a rate-limited warning.
        on_hint: ``(T_map_base (4, 4), covariance (6, 6))`` for each valid ``/initialpose``.
    """

    def __init__(self, node: Any, ncfg: Any, outputs: Any, tf: TransformBuffer,
                 extrinsic: Callable[[str], np.ndarray], warn: Callable[[str, str], None],
                 on_hint: Callable[[np.ndarray, np.ndarray], None]) -> None:
        self.cfg, self.outputs, self.tf = ncfg, outputs, tf
        self._node, self._extrinsic, self._warn, self._on_hint = node, extrinsic, warn, on_hint
        self.mode = ncfg.localization_odom
        self.base = ncfg.base_frame
        self.pose_cov = node.create_publisher(PoseWithCovarianceStamped, "~/pose_with_covariance", POSE_QOS)
        self.sub_initialpose = node.create_subscription(PoseWithCovarianceStamped, INITIALPOSE_TOPIC,
                                                        self._on_initialpose, 10)
        self.last_map_odom: tuple[np.ndarray, int, str] | None = None  # (T_map_odom, its scan's stamp ns, map frame)
        self._last_sent = 0.0  # monotonic time of the last map -> odom broadcast
        self.status = "no pose yet"  # /diagnostics: localization.map -> odom
        self.problem = ""  # the /diagnostics WARN message while map -> odom cannot be updated, else ""
        self.hints = 0
        self._waited = False  # the first scan waits node.tf_timeout for odom -> base (_odom_base)
        self.timer = None
        if self.mode != "none" and ncfg.map_odom_period > 0 and outputs.tf is not None:
            self.timer = node.create_timer(ncfg.map_odom_period, self.republish)

    # -- one scan ----------------------------------------------------------------------------------------------
    def odometry_step(self, src: Cloud, step: OdometryEstimate) -> None:
        """``node.localization_odom: lidar``: the node's own odometry of this scan (``T_odom_sensor``) as
        ``odom -> base`` on /tf at the scan's stamp, and into the TF buffer for :meth:`localized`."""
        base = self.base or src.frame_id
        T_odom_base = base_motion(self._extrinsic(src.frame_id), step.T_odom)
        self.tf.add_stamped(self.cfg.odom_frame, base, src.stamp_ns, T_odom_base)
        if self.outputs.tf is not None:
            self.outputs.tf([matrix_to_transform_stamped(T_odom_base, src.stamp_ns, self.cfg.odom_frame, base)])

    def localized(self, src: Cloud, frame: str, reg: Registered, result: Any, crop: np.ndarray | None) -> None:
        """One valid pose ``reg.T = T_map_sensor``: the base's pose on the topics, map -> odom (or map -> base) on
        /tf."""
        base = self.base or src.frame_id
        T_base_sensor = self._extrinsic(src.frame_id)
        T_map_base = reg.T @ np.linalg.inv(T_base_sensor)
        stamp = src.stamp_ns
        cov = base_pose_covariance(result, src, reg, crop, reg.T, T_map_base)
        out = self.outputs
        out.pose.publish(matrix_to_pose_stamped(T_map_base, stamp, frame))
        out.transform.publish(matrix_to_transform_stamped(T_map_base, stamp, frame, base))
        if out.odometry is not None:
            out.odometry.publish(matrix_to_odometry(T_map_base, stamp, frame, base, np.zeros(6), cov,
                                                    np.eye(6) * UNKNOWN_TWIST_COV))
        msg = PoseWithCovarianceStamped()
        msg.header.stamp, msg.header.frame_id = ns_to_stamp(stamp), frame
        msg.pose.pose = matrix_to_pose(T_map_base)
        msg.pose.covariance = [float(v) for v in cov.reshape(-1)]
        self.pose_cov.publish(msg)
        out.published += 1
        out._aligned(src, reg.T, frame)
        if out.tf is None:
            return
        if self.mode == "none":
            out.tf([matrix_to_transform_stamped(T_map_base, stamp, frame, base)])
            self.status = f"publishing {frame} -> {base} (no odom frame)"
            return
        T_odom_base = self._odom_base(base, stamp)
        if T_odom_base is None:
            return
        with np.errstate(over="ignore", invalid="ignore"):  # checked just below: a warning here would only repeat it
            T_map_odom = T_map_base @ np.linalg.inv(T_odom_base)
        if not np.isfinite(T_map_odom).all():  # an absurd odom -> base on /tf (finite, but its inverse overflows)
            odom = self.cfg.odom_frame
            self.status = self.problem = f"{odom} -> {base} on /tf is not usable: {frame} -> {odom} not updated"
            self._warn("bad_odom_tf", f"{odom} -> {base} on /tf at the scan's stamp {stamp} ns gives no finite "
                       f"{frame} -> {odom} (translation {T_odom_base[:3, 3].tolist()}): not updated, the pose is "
                       "still published on the topics")
            return
        self.last_map_odom = (T_map_odom, stamp, frame)
        self._send(stamp)
        self.status, self.problem = "ok", ""

    def _odom_base(self, base: str, stamp_ns: int) -> np.ndarray | None:
        odom = self.cfg.odom_frame
        # tf2's canTransform with a timeout: wait for the odometry to reach the scan's stamp, on the first scan (the
        # odometry may not be up yet) and while its transforms arrive, not for a stamp it has passed already
        newest = self.tf.newest(odom, base)
        wait = self.cfg.tf_timeout if (not self._waited or (newest is not None and newest < stamp_ns)) else 0.0
        self._waited = True
        T = self.tf.wait(odom, base, wait, stamp_ns) if self.mode == "tf" else self.tf.lookup(odom, base, stamp_ns)
        if T is None:
            self.status = self.problem = (f"no {odom} -> {base} at the scan's stamp: {self.cfg.map_frame} -> {odom} "
                                          "not updated")
            self._warn("no_odom_tf", f"no transform {odom} -> {base} on /tf at the scan's stamp {stamp_ns} ns "
                       f"(waited {wait:.1f} s): {self.cfg.map_frame} -> {odom} not updated, the pose is still "
                       "published on the topics; run an odometry source that publishes it, or set "
                       "node.localization_odom:=lidar (the node's own) or none (map -> base directly)")
        return T

    def _send(self, stamp_ns: int) -> None:
        T_map_odom, _, frame = self.last_map_odom
        post = stamp_ns + int(self.cfg.transform_tolerance * 1e9)
        self.outputs.tf([matrix_to_transform_stamped(T_map_odom, post, frame, self.cfg.odom_frame)])
        self._last_sent = time.monotonic()

    def republish(self) -> None:
        """The timer: the last map -> odom again, stamped now (+ the tolerance), when none went out for a period."""
        if self.last_map_odom is None or time.monotonic() - self._last_sent < 0.5 * self.cfg.map_odom_period:
            return
        now = self._node.get_clock().now().nanoseconds
        self._send(max(int(now), self.last_map_odom[1]))

    # -- /initialpose ------------------------------------------------------------------------------------------
    def _on_initialpose(self, msg: PoseWithCovarianceStamped) -> None:
        frame = msg.header.frame_id or self.cfg.map_frame
        if frame != self.cfg.map_frame:
            self._warn("initialpose_frame", f"{INITIALPOSE_TOPIC} in frame {frame!r} ignored: the map frame is "
                       f"{self.cfg.map_frame!r} (node.map_frame)")
            return
        try:
            T = pose_to_matrix(msg.pose.pose)
            cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)
        except Exception as err:  # noqa: BLE001 - a zero quaternion, NaN: the message is not one to use
            self._warn("initialpose_bad", f"{INITIALPOSE_TOPIC} ignored: {err}")
            return
        if not (np.isfinite(T).all() and np.isfinite(cov).all()):
            self._warn("initialpose_bad", f"{INITIALPOSE_TOPIC} ignored: not finite")
            return
        self.hints += 1
        self._on_hint(T, cov)
        x, y = T[0, 3], T[1, 3]
        yaw = np.degrees(np.arctan2(T[1, 0], T[0, 0]))
        self._node.get_logger().info(
            f"{INITIALPOSE_TOPIC}: x {x:.2f} y {y:.2f} m, yaw {yaw:.1f} deg (stamp {stamp_to_ns(msg.header.stamp)} "
            f"ns): the next scan is searched there first")

    def diagnostics(self) -> dict[str, Any]:
        """The values /diagnostics shows under ``localization.*``."""
        return {"odom source": self.mode, "map -> odom": self.status, "initial poses received": self.hints}
