"""The node's pipeline, run on the registration worker thread (no ROS import).

* :func:`register_clouds`: one pair of preprocessed :class:`~deepbbs_ros.node.inputs.Cloud` s ->
  ``T_target_source``, the registration result and its timings.
* :class:`ScanToScanOdometry`: odometry mode, one :meth:`~ScanToScanOdometry.step` per scan,
  ``T_odom_k = T_odom_{k-1} @ T_{k-1}_k`` (CONVENTIONS.md), every scan preprocessed once (on arrival)
  and kept as the next scan's target. It returns an :class:`OdometryEstimate`, everything the outputs
  need (pose, twist, covariances).

Another odometry (a local map with deskewing, say) replaces :class:`ScanToScanOdometry` in one place,
``RegistrationNode._make_odometry``: any object with ``reset()`` and ``step(cloud) -> OdometryEstimate``.
The cloud gives it the raw points ``cloud.xyz``, the per-point times ``cloud.times`` (s since the stamp,
or None), ``cloud.stamp_ns``, and the preprocessed ``cloud.pp`` (computed on arrival); a pipeline with
``step(points, times, stamp_ns) -> T_odom_k`` is wrapped by calling it there and filling the estimate
(``motion_twist`` and ``registration_covariance`` below give the twist and covariances).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.covariance import adjoint, alignment_quality, twist_covariance, twist_from_delta
from deepbbs_ros.node.inputs import BadInput, Cloud

#: twist covariance when the velocity is unknown (first scan, or two clouds of the same instant)
UNKNOWN_TWIST_COV = 1e6


@dataclass
class Registered:
    """One registration.

    Attributes:
        T: (4, 4) float64 ``T_target_source`` (finite).
        result: the registration's own result (``RegistrationResult`` for DeepBBS++).
        timings_ms: ``register`` (wall time of the call) and ``register.<stage>`` from the result.
    """

    T: np.ndarray
    result: Any
    timings_ms: dict[str, float] = field(default_factory=dict)


def register_clouds(registration: Any, source: Cloud, target: Cloud) -> Registered:
    """``registration.register(source.pp, target.pp)`` -> :class:`Registered`.

    Raises:
        BadInput: ``registration_failed`` on RegistrationError or a non-finite transform.
    """
    t0 = time.perf_counter()
    try:
        result = registration.register(source.pp, target.pp)
    except RegistrationError as err:
        raise BadInput("registration_failed", str(err)) from err
    timings = {"register": (time.perf_counter() - t0) * 1e3}
    for k, v in (getattr(result, "timings_ms", None) or {}).items():
        if k != "total":
            timings[f"register.{k}"] = float(v)
    T = np.asarray(result.T_target_source, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise BadInput("registration_failed", "registration returned a non-finite transform")
    return Registered(T, result, timings)


def registration_covariance(source: Cloud, target: Cloud, reg: Registered) -> np.ndarray:
    """(6, 6) covariance of ``reg.T`` (x, y, z, rot x, rot y, rot z; left perturbation in the target
    frame) from the residuals of the registered (preprocessed) points, :mod:`deepbbs_ros.node.covariance`."""
    src = getattr(source.pp, "points", None)
    tgt = getattr(target.pp, "points", None)
    if src is None or tgt is None:  # a registration without sampled points: no residuals to use
        return np.eye(6) * UNKNOWN_TWIST_COV
    q = alignment_quality(
        src,
        tgt,
        reg.T,
        weights=getattr(reg.result, "gamma", None),
        converged=bool(getattr(reg.result, "converged", True)),
    )
    return q.covariance


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
    """

    T_odom: np.ndarray
    pose_covariance: np.ndarray
    twist: np.ndarray
    twist_covariance: np.ndarray
    T_prev_curr: np.ndarray | None = None
    registered: Registered | None = None


class ScanToScanOdometry:
    """Scan-to-scan odometry over preprocessed clouds: scan k is registered against scan k-1.

    Args:
        registration: the node's registration (``register(source_pp, target_pp)``).
        covariance: compute the twist and the pose / twist covariances (``node.publish_odometry``);
            without it they are zeros (only ``~/odometry`` carries them).

    The pose covariance accumulates the step covariances moved into the odometry frame,
    ``Sigma_k = Sigma_{k-1} + Ad(T_odom_{k-1}) Sigma_step Ad(T_odom_{k-1})^T``.
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
            Ad = adjoint(self._T_odom)
            self._cov_odom = self._cov_odom + Ad @ cov_step @ Ad.T
            twist, twist_cov = motion_twist(reg.T, cov_step, dt)
        else:
            twist, twist_cov = np.zeros(6), np.zeros((6, 6))
        self._T_odom = self._T_odom @ reg.T
        self._prev = cloud
        return OdometryEstimate(self._T_odom.copy(), self._cov_odom.copy(), twist, twist_cov, reg.T, reg)
