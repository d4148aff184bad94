"""What the node's odometry gives for one scan (no ROS import): :class:`OdometryEstimate` (pose, twist and their
covariances) and :func:`motion_twist` (a motion over a stamp gap as a twist with its covariance); the odometries
that make it: node/scan_to_scan.py, node/odometry_pipeline.py."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepbbs_ros.node.covariance import twist_covariance, twist_from_delta
from deepbbs_ros.node.pair_registration import UNKNOWN_TWIST_COV, Registered


def motion_twist(T_prev_curr: np.ndarray, cov_prev_curr: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """((6,) twist in the current frame, (6, 6) its covariance) of the motion ``T_prev_curr`` over ``dt`` s;
    zero with a huge covariance when ``dt`` is (near) zero."""
    if abs(dt) <= 1e-3:
        return np.zeros(6), np.eye(6) * UNKNOWN_TWIST_COV
    return twist_from_delta(T_prev_curr, dt), twist_covariance(T_prev_curr, cov_prev_curr, dt)


@dataclass
class OdometryEstimate:
    """What odometry mode publishes for one scan.

    Attributes:
        T_odom: (4, 4) float64 ``T_odom_k``, the scan's sensor pose in the odometry frame.
        pose_covariance: (6, 6) covariance of ``T_odom`` (zeros at the origin scan).
        twist: (6,) ``[vx, vy, vz, wx, wy, wz]`` in the scan's frame (m/s, rad/s).
        twist_covariance: (6, 6); huge when the velocity is unknown (first scan).
        T_prev_curr: (4, 4) motion since the previous scan, ``T_{k-1}_k``; None at the origin scan.
        registered: the registration behind the step (None at the origin scan).
        dt: the stamp gap of ``T_prev_curr``, s (0 at the origin scan).
    """

    T_odom: np.ndarray
    pose_covariance: np.ndarray
    twist: np.ndarray
    twist_covariance: np.ndarray
    T_prev_curr: np.ndarray | None = None
    registered: Registered | None = None
    dt: float = 0.0
