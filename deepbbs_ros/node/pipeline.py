"""The node's pipeline, run on the registration worker thread (no ROS import).

* :func:`register_clouds`: one pair of preprocessed :class:`~deepbbs_ros.node.inputs.Cloud` s ->
  ``T_target_source``, the registration result and its timings.
* :class:`LocalMapOdometry` (odometry mode, the default): one :meth:`~LocalMapOdometry.step` per scan runs
  :class:`deepbbs_ros.core.odometry.DeepBBSOdometry`, the pipeline of ``deepbbs-replay --mode odometry
  --method deepbbs++`` (deskew + GICP against a local voxel map, DeepBBS++ consulted on stamp gaps, fit
  drops and the first motion), on the raw points, per-point times and stamp of each scan.
* :class:`ScanToScanOdometry` (``RegistrationNode(odometry_method="scan_to_scan")``, the GICP anchor):
  ``T_odom_k = T_odom_{k-1} @ T_{k-1}_k`` (CONVENTIONS.md), every scan preprocessed once (on arrival) and
  kept as the next scan's target.

Both return an :class:`OdometryEstimate`, everything the outputs need (pose, twist, covariances), from
``step(cloud)``, and restart at identity on ``reset()``; ``RegistrationNode._make_odometry`` picks one.
The cloud gives them the raw points ``cloud.xyz``, the per-point times ``cloud.times`` (s since the stamp,
or None), ``cloud.stamp_ns``, and the preprocessed ``cloud.pp`` (computed on arrival for scan-to-scan
only; None for the local map, which preprocesses for DeepBBS++ itself, only when it consults it).
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


class LocalMapOdometry:
    """Odometry mode's default: :class:`deepbbs_ros.core.odometry.DeepBBSOdometry` per scan, the same
    pipeline (same config, same numbers) as ``deepbbs-replay --mode odometry --method deepbbs++``.

    Args:
        config: the node's :class:`~deepbbs_ros.config.Config` (``preprocess`` crop, the ``odometry``
            section; ``preprocess``/``model``/``registration`` for DeepBBS++).
        registration: the node's registration, shared with the odometry (its network): DeepBBS++ runs
            only when the odometry consults it (stamp gap, fit drop, first motion).
        covariance: compute the twist and the pose / twist covariances (``node.publish_odometry``).

    Pose: ``T_odom_k = T_first_k`` (the odom frame is the first scan's sensor frame at its stamp).
    Twist: the motion since the previous scan ``T_{k-1}_k`` over the stamp gap (:func:`motion_twist`).
    Covariances: the step covariance is the registration-residual one of :mod:`deepbbs_ros.node.covariance`
    evaluated on the step's motion ``T_{k-1}_k``: scan k (deskewed with that motion over the stamp gap,
    cropped, on a grid of 1.5 x ``odometry.voxel_size``) against scan k-1 (a grid of
    0.5 x voxel). The pose covariance accumulates it as :class:`ScanToScanOdometry` does,
    ``Sigma_k = Sigma_{k-1} + Ad(T_odom_{k-1}) Sigma_step Ad(T_odom_{k-1})^T``: conservative, since the local
    map bounds the drift better than a chain of independent steps.
    """

    def __init__(self, config: Any, registration: Any, *, covariance: bool = True) -> None:
        from deepbbs_ros.core.odometry import DeepBBSOdometry

        self.odometry = DeepBBSOdometry(config, registration=registration)
        self.covariance = covariance
        self.consulted = 0  # scans on which DeepBBS++ was consulted ...
        self.won = 0  # ... and those where its start gave the better fit
        self.reset()

    def reset(self) -> None:
        """Restart at identity: the next scan becomes the origin (map and motion forgotten)."""
        self.odometry.reset()
        self._prev_stamp: int | None = None
        self._T_odom = np.eye(4)
        self._cov_odom = np.zeros((6, 6))
        self._prev_grid: Any = None  # scan k-1 for the covariance: (N, 3) map grid, or the raw Cloud at the origin

    def step(self, cloud: Cloud) -> OdometryEstimate:
        """Add scan k: ``DeepBBSOdometry.register_frame(cloud.xyz, cloud.times, cloud.stamp_ns)``.

        Raises:
            BadInput: ``registration_failed`` (too few points within the crop range; the odometry state is
                unchanged), or a non-finite pose (the odometry restarts at the next scan).
        """
        t0 = time.perf_counter()
        try:
            out = self.odometry.register_frame(cloud.xyz, cloud.times, cloud.stamp_ns)
        except RegistrationError as err:
            raise BadInput("registration_failed", str(err)) from err
        T, T_step = np.asarray(out.T_first_k, np.float64), np.asarray(out.T_prev_k, np.float64)
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(T_step))):
            self.reset()
            raise BadInput("registration_failed", "odometry returned a non-finite pose; restarting at identity")
        timings = {"register": (time.perf_counter() - t0) * 1e3}
        timings.update({f"register.{k}": float(v) for k, v in out.timings_ms.items() if k != "total"})
        prev_stamp, self._prev_stamp = self._prev_stamp, cloud.stamp_ns
        if prev_stamp is None:  # the origin: pose known exactly, velocity unknown
            self._T_odom, self._cov_odom = np.eye(4), np.zeros((6, 6))
            self._prev_grid = cloud if self.covariance else None
            return OdometryEstimate(np.eye(4), np.zeros((6, 6)), np.zeros(6), np.eye(6) * UNKNOWN_TWIST_COV)
        self.consulted += int(out.deepbbs)
        self.won += int(out.won)
        dt = (cloud.stamp_ns - prev_stamp) * 1e-9
        twist, twist_cov = np.zeros(6), np.zeros((6, 6))
        if self.covariance:
            t1 = time.perf_counter()
            cov_step = self._step_covariance(cloud, T_step, dt)
            Ad = adjoint(self._T_odom)
            self._cov_odom = self._cov_odom + Ad @ cov_step @ Ad.T
            twist, twist_cov = motion_twist(T_step, cov_step, dt)
            timings["covariance"] = (time.perf_counter() - t1) * 1e3
        self._T_odom = T
        reg = Registered(T_step, out, timings)
        return OdometryEstimate(T.copy(), self._cov_odom.copy(), twist, twist_cov, T_step, reg)

    # -- covariance ----------------------------------------------------------------------------------
    def _grid(self, cloud: Cloud, T_step: np.ndarray, dt: float) -> np.ndarray:
        """Scan ``cloud`` deskewed with the motion ``T_step`` over ``dt`` s (when it has times), cropped, on
        a 0.5 x voxel grid: (M, 3) float64."""
        from kiss_icp.voxelization import voxel_down_sample

        from deepbbs_ros.core.preprocess import deskew

        cfg = self.odometry.config
        pts = np.asarray(cloud.xyz, dtype=np.float64)
        times = cloud.times
        if cfg.odometry.deskew and times is not None and len(times) == len(pts) and dt > 1e-3 and np.ptp(times) > 0:
            pts = deskew(pts, times, T_step, dt)
        r = np.linalg.norm(pts, axis=1)
        pts = np.ascontiguousarray(pts[(r > cfg.preprocess.min_range) & (r < cfg.preprocess.max_range)])
        return np.asarray(voxel_down_sample(pts, self.odometry.voxel_size * 0.5))

    def _step_covariance(self, cloud: Cloud, T_step: np.ndarray, dt: float) -> np.ndarray:
        """(6, 6) covariance of ``T_{k-1}_k`` (left perturbation in scan k-1's frame) from the residuals
        of scan k's ICP grid against scan k-1's map grid under the step's motion."""
        from kiss_icp.voxelization import voxel_down_sample

        prev = self._prev_grid
        if isinstance(prev, Cloud):  # the origin, deskewed with the first motion now that it is known
            prev = self._grid(prev, T_step, dt)
        grid = self._grid(cloud, T_step, dt)
        self._prev_grid = grid
        source = np.asarray(voxel_down_sample(grid, self.odometry.voxel_size * 1.5))
        if prev is None or len(prev) < 3 or len(source) < 3:
            return np.eye(6) * UNKNOWN_TWIST_COV
        return alignment_quality(source, prev, T_step).covariance
