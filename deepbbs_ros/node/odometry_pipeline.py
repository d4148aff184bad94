"""The node's odometry, one ``step(cloud)`` per scan (no ROS import): :class:`LocalMapOdometry` (the default) and
:class:`ScanToScanOdometry` (node/scan_to_scan.py), each returning an :class:`OdometryEstimate`
(node/odometry_estimate.py; see :mod:`deepbbs_ros.node.pipeline`); those names are imported from here too."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.core.covariance import SWEEP_SPREAD, compose
from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.covariance import alignment_quality
from deepbbs_ros.node.inputs import BadInput, Cloud
from deepbbs_ros.node.odometry_estimate import OdometryEstimate, motion_twist
from deepbbs_ros.node.pair_registration import UNKNOWN_TWIST_COV, Registered
from deepbbs_ros.node.scan_to_scan import ScanToScanOdometry

__all__ = ["SCAN_FLOOR_SHARE", "LocalMapOdometry", "OdometryEstimate", "ScanToScanOdometry", "motion_twist"]

#: the share of a step's sweep floor (``OdometryStep.covariance_floor``) that is the scan's own pose error: the floor
#: is a step's, the difference of two scans each off by its own sweep's error, so twice one scan's variance
#: (core/covariance.py ``SWEEP_SPREAD``: sqrt(2) / 2 of the deviations' root mean square)
SCAN_FLOOR_SHARE = SWEEP_SPREAD ** 2


def _step_part(out, name: str) -> np.ndarray:
    """(6, 6) the step's covariance part ``name`` (``OdometryStep.covariance_floor``, ``covariance_held``: odometry
    frame); zeros where the odometry gave no covariance or no such part."""
    part = getattr(out, name, None) if getattr(out, "covariance", None) is not None else None
    return np.zeros((6, 6)) if part is None else np.asarray(part, dtype=np.float64)


class LocalMapOdometry:
    """Odometry mode's default: :class:`deepbbs_ros.core.odometry.DeepBBSOdometry` per scan, the same
    pipeline (same config, same numbers) as ``deepbbs-replay --mode odometry --method deepbbs++``.

    Args:
        config: the node's :class:`~deepbbs_ros.config.Config` (``preprocess`` crop, the ``odometry``
            section; ``preprocess``/``model``/``registration`` for DeepBBS++).
        registration: the node's registration, shared with the odometry (its network): DeepBBS++ runs
            only when the odometry consults it (long stamp gap, fit drop, first motion).
        covariance: compute the twist and the pose / twist covariances (``node.publish_odometry``).

    Pose: ``T_odom_k = T_first_k`` (the odom frame is the first scan's sensor frame at its stamp).
    Twist: the motion since the previous scan ``T_{k-1}_k`` over the stamp gap (:func:`motion_twist`).
    Covariances: the step covariance is that of scan k's VGICP on the local map (``OdometryStep.covariance``,
    :mod:`deepbbs_ros.core.covariance`: cluster-robust, from its GICP pairs, with the sweep's model error), moved
    into scan k-1's frame; without one, the point-to-point residual covariance of
    :mod:`deepbbs_ros.node.covariance` of scan k against scan k-1 under the step's motion. The pose covariance
    composes the steps' GICP parts along ``T_odom_k = T_odom_{k-1} @ T_{k-1}_k`` (independent steps: the drift of a
    chain) and adds the current scan's own sweep error once (its share :data:`SCAN_FLOOR_SHARE` of the step's floor
    ``OdometryStep.covariance_floor``): that error belongs to the scan, and the next step undoes it rather than
    adding to it. Where the odometry held a direction several steps in a row, the held steps share the velocity's
    error along it, and the chain adds their covariance (``OdometryStep.covariance_held``).
    """

    def __init__(self, config: Any, registration: Any, *, covariance: bool = True) -> None:
        from deepbbs_ros.core.odometry import DeepBBSOdometry

        self.odometry = DeepBBSOdometry(config, registration=registration)
        self.covariance = covariance
        self.consulted = 0  # scans on which DeepBBS++ was consulted ...
        self.won = 0  # ... and those where its start gave the better fit
        self.degenerate = ""  # the last scan's place, when degenerate (OdometryStep.degenerate): /diagnostics warns
        self.degenerate_frames = 0  # scans in a degenerate place so far
        self.reset()

    def reset(self) -> None:
        """Restart at identity: the next scan becomes the origin (map and motion forgotten)."""
        self.odometry.reset()
        self._prev_stamp: int | None = None
        self._T_odom = np.eye(4)
        self._cov_odom = np.zeros((6, 6))
        self._cov_chain = np.zeros((6, 6))  # the GICP parts composed: the pose covariance less the scan's own floor
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
        self.degenerate = getattr(out, "degenerate", "")
        self.degenerate_frames += bool(self.degenerate)
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(T_step))):
            self.reset()
            raise BadInput("registration_failed", "odometry returned a non-finite pose; restarting at identity")
        timings = {"register": (time.perf_counter() - t0) * 1e3}
        timings.update({f"register.{k}": float(v) for k, v in out.timings_ms.items() if k != "total"})
        prev_stamp, self._prev_stamp = self._prev_stamp, cloud.stamp_ns
        if prev_stamp is None:  # the origin: pose known exactly, velocity unknown
            self._T_odom, self._cov_odom, self._cov_chain = np.eye(4), np.zeros((6, 6)), np.zeros((6, 6))
            self._prev_grid = (cloud if out.points is None else out.points) if self.covariance else None
            return OdometryEstimate(np.eye(4), np.zeros((6, 6)), np.zeros(6), np.eye(6) * UNKNOWN_TWIST_COV)
        self.consulted += int(out.deepbbs)
        self.won += int(out.won)
        dt = (cloud.stamp_ns - prev_stamp) * 1e-9
        twist, twist_cov = np.zeros(6), np.zeros((6, 6))
        if self.covariance:
            t1 = time.perf_counter()
            cov_step = self._step_covariance(cloud, T_step, dt, out.points, getattr(out, "covariance", None))
            floor, held = _step_part(out, "covariance_floor"), _step_part(out, "covariance_held")  # odometry frame
            B = np.zeros((6, 6))
            B[:3, :3] = B[3:, 3:] = self._T_odom[:3, :3].T  # -> scan k-1's frame, as cov_step
            self._cov_chain = compose(self._T_odom, self._cov_chain, T_step, cov_step - B @ (floor - held) @ B.T)
            self._cov_odom = self._cov_chain + SCAN_FLOOR_SHARE * floor
            twist, twist_cov = motion_twist(T_step, cov_step, dt)
            timings["covariance"] = (time.perf_counter() - t1) * 1e3
        self._T_odom = T
        reg = Registered(T_step, out, timings)
        return OdometryEstimate(T.copy(), self._cov_odom.copy(), twist, twist_cov, T_step, reg, dt)

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

    def _step_covariance(self, cloud: Cloud, T_step: np.ndarray, dt: float,
                         registered: np.ndarray | None = None, map_cov: np.ndarray | None = None) -> np.ndarray:
        """(6, 6) covariance of ``T_{k-1}_k`` (scan k-1's frame): ``map_cov`` (the VGICP covariance of ``T_odom_k``,
        odometry frame) rotated into scan k-1's frame; without it, from the residuals of scan k's ICP grid against
        scan k-1's map grid under the step's motion. ``registered``: scan k as the odometry registered it (deskewed,
        cropped, that grid: ``OdometryStep.points``), used as it is instead of deskewing and gridding the raw scan
        again (~3x cheaper on a 120k-point scan)."""
        from kiss_icp.voxelization import voxel_down_sample

        if map_cov is not None:
            self._prev_grid = registered
            B = np.zeros((6, 6))
            B[:3, :3] = B[3:, 3:] = self._T_odom[:3, :3].T
            return B @ np.asarray(map_cov, dtype=np.float64) @ B.T
        prev = self._prev_grid
        if isinstance(prev, Cloud):  # the origin, deskewed with the first motion now that it is known
            prev = self._grid(prev, T_step, dt)
        grid = registered if registered is not None and len(registered) >= 3 else self._grid(cloud, T_step, dt)
        self._prev_grid = grid
        source = np.asarray(voxel_down_sample(grid, self.odometry.voxel_size * 1.5))
        if prev is None or len(prev) < 3 or len(source) < 3:
            return np.eye(6) * UNKNOWN_TWIST_COV
        return alignment_quality(source, prev, T_step).covariance


