"""The node's scan-to-scan odometry (``RegistrationNode(odometry_method="scan_to_scan")``, no ROS import):
:class:`ScanToScanOdometry`, scan k registered against scan k-1, one ``step(cloud)`` per scan."""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.covariance import compose
from deepbbs_ros.node.inputs import Cloud
from deepbbs_ros.node.odometry_estimate import OdometryEstimate, motion_twist
from deepbbs_ros.node.pair_registration import UNKNOWN_TWIST_COV, register_clouds, registration_covariance


class ScanToScanOdometry:
    """Scan-to-scan odometry over preprocessed clouds: scan k is registered against scan k-1.

    Args:
        registration: the node's registration (``register(source_pp, target_pp)``).
        covariance: compute the twist and the pose / twist covariances (``node.publish_odometry``);
            without it they are zeros (only ``~/odometry`` carries them).

    The pose covariance accumulates the step covariances along the chain ``T_odom_k = T_odom_{k-1} @ T_step``
    (:func:`deepbbs_ros.core.covariance.compose`).
    """

    def __init__(self, registration: Any, *, covariance: bool = True) -> None:
        self.registration = registration
        self.covariance = covariance
        self.reset()

    def reset(self) -> None:
        """Restart at identity: the next scan becomes the origin."""
        self._prev: Cloud | None = None
        self._T_odom = np.eye(4)
        self._cov_odom = np.zeros((6, 6))

    def step(self, cloud: Cloud) -> OdometryEstimate:
        """Register ``cloud`` (scan k) against the previous scan and advance ``T_odom``.

        Raises:
            BadInput: the registration failed (the previous scan stays the reference).
        """
        prev = self._prev
        if prev is None:  # the first scan is the origin: pose known exactly, velocity unknown
            self._prev, self._T_odom, self._cov_odom = cloud, np.eye(4), np.zeros((6, 6))
            return OdometryEstimate(np.eye(4), np.zeros((6, 6)), np.zeros(6), np.eye(6) * UNKNOWN_TWIST_COV)
        reg = register_clouds(self.registration, cloud, prev)  # T_{k-1}_k
        dt = (cloud.stamp_ns - prev.stamp_ns) * 1e-9
        if self.covariance:
            cov_step = registration_covariance(cloud, prev, reg)
            self._cov_odom = compose(self._T_odom, self._cov_odom, reg.T, cov_step)
            twist, twist_cov = motion_twist(reg.T, cov_step, dt)
        else:
            twist, twist_cov = np.zeros(6), np.zeros((6, 6))
        self._T_odom = self._T_odom @ reg.T
        self._prev = cloud
        return OdometryEstimate(self._T_odom.copy(), self._cov_odom.copy(), twist, twist_cov, reg.T, reg, dt)
