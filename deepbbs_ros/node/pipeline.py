"""The node's pipeline, run on the registration worker thread (no ROS import).

* :func:`register_clouds`: one pair of preprocessed :class:`~deepbbs_ros.node.inputs.Cloud` s ->
  ``T_target_source``, the registration result and its timings.
* :class:`LocalMapOdometry` (odometry mode, the default): one :meth:`~LocalMapOdometry.step` per scan runs
  :class:`deepbbs_ros.core.odometry.DeepBBSOdometry`, the pipeline of ``deepbbs-replay --mode odometry
  --method deepbbs++`` (deskew + GICP against a local voxel map, DeepBBS++ consulted on long stamp gaps, fit
  drops and the first motion), on the raw points, per-point times and stamp of each scan.
* :class:`MapTarget` (pair mode, ``node.target_mode: latched``): every source against the latest map, cropped
  around the current estimate (the last answer; ``node.initial_pose`` at first), answered in the map frame.
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

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.core.covariance import SWEEP_SPREAD, compose
from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.covariance import alignment_quality, twist_covariance, twist_from_delta
from deepbbs_ros.node.inputs import BadInput, Cloud

#: the share of a step's sweep floor (``OdometryStep.covariance_floor``) that is the scan's own pose error: the floor
#: is a step's, the difference of two scans each off by its own sweep's error, so twice one scan's variance
#: (core/covariance.py ``SWEEP_SPREAD``: sqrt(2) / 2 of the deviations' root mean square)
SCAN_FLOOR_SHARE = SWEEP_SPREAD ** 2
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


def takes_good_start(registration: Any) -> bool:
    """Whether ``registration.register`` takes ``good_start`` (DeepBBS++ and its registration process; not the
    GICP anchor, which always starts from its start)."""
    import inspect

    try:
        return "good_start" in inspect.signature(registration.register).parameters
    except (TypeError, ValueError, AttributeError):
        return False


def register_clouds(registration: Any, source: Cloud, target: Cloud, T_init: np.ndarray | None = None,
                    good_start: bool = False) -> Registered:
    """``registration.register(source.pp, target.pp[, T_init=...][, good_start=True])`` -> :class:`Registered`;
    ``good_start`` (the caller vouches for ``T_init``) is passed only to a registration that takes it.

    Raises:
        BadInput: ``registration_failed`` on RegistrationError or a non-finite transform.
    """
    t0 = time.perf_counter()
    try:
        if T_init is None:
            result = registration.register(source.pp, target.pp)
        elif good_start and takes_good_start(registration):
            result = registration.register(source.pp, target.pp, T_init=T_init, good_start=True)
        else:
            result = registration.register(source.pp, target.pp, T_init=T_init)
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
    frame) from the residuals of the registered (preprocessed) points, :mod:`deepbbs_ros.node.covariance`: the
    clouds the result says it registered (DeepBBS++: its sampled points, or on the good-start path the subsets of
    the GICP clouds its verdict scored), else the preprocessed clouds' points."""
    src, tgt = _registered_points(reg.result, "source"), _registered_points(reg.result, "target")
    if src is None or tgt is None:
        src, tgt = getattr(source.pp, "points", None), getattr(target.pp, "points", None)
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


def _registered_points(result: Any, name: str) -> np.ndarray | None:
    """``result.source`` / ``result.target`` when the result carries them ((N >= 3, 3)), else None."""
    pts = getattr(result, name, None)
    if isinstance(pts, np.ndarray) and pts.ndim == 2 and pts.shape[1] == 3 and len(pts) >= 3:
        return pts
    return None


class PairStart:
    """Pair mode (stamped): the last valid answer as the next pair's good start.

    Consecutive scans (scan k against scan k-1) move about as the last pair did, and two sensors on one vehicle
    keep their mounting: the last answer ``T_target_source`` is a start DeepBBS++ can vouch for
    (``register(..., good_start=True)``: GICP alone from it when its stricter verdict accepts, the full pipeline
    when not). No good start for the first pair, after a pose the verdict rejected, when the frames changed, after
    ``~/reset``, or when the source stamp is more than ``node.good_start_max_gap`` s from the last answer's.
    Thread-safe (the registration thread updates it, ``~/reset`` clears it)."""

    def __init__(self, max_gap_s: float, enabled: bool = True) -> None:
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.enabled = bool(enabled)
        self._lock = threading.Lock()
        self._last: tuple[np.ndarray, str, str, int] | None = None  # (T, source frame, target frame, source stamp)

    def reset(self) -> None:
        with self._lock:
            self._last = None

    def start(self, source: Cloud, target: Cloud) -> np.ndarray | None:
        """The good start for the pair (source, target), or None (no start vouched for: the full pipeline)."""
        with self._lock:
            last = self._last
        if not self.enabled or last is None:
            return None
        T, src_frame, tgt_frame, stamp = last
        frames = (source.frame_id, target.frame_id)
        if (src_frame, tgt_frame) != frames or abs(source.stamp_ns - stamp) > self.max_gap_ns:
            return None
        return T.copy()

    def update(self, source: Cloud, target: Cloud, reg: Registered) -> None:
        """Keep a valid answer as the next start; a rejected one forgets it."""
        with self._lock:
            if getattr(reg.result, "valid", True):
                self._last = (reg.T.copy(), source.frame_id, target.frame_id, int(source.stamp_ns))
            else:
                self._last = None


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
    adding to it.
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
            floor = getattr(out, "covariance_floor", None) if getattr(out, "covariance", None) is not None else None
            floor = np.zeros((6, 6)) if floor is None else np.asarray(floor, dtype=np.float64)  # odometry frame
            B = np.zeros((6, 6))
            B[:3, :3] = B[3:, 3:] = self._T_odom[:3, :3].T  # -> scan k-1's frame, as cov_step
            self._cov_chain = compose(self._T_odom, self._cov_chain, T_step, cov_step - B @ floor @ B.T)
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


#: latched target: the map is cropped again once the estimate moved this share of the crop radius from its centre
RECROP_SHARE = 0.2


def pose_from_xyzrpy(values: Any) -> np.ndarray:
    """``[x, y, z, roll, pitch, yaw]`` (m, rad; ``R = Rz(yaw) Ry(pitch) Rx(roll)``) -> (4, 4) float64."""
    from scipy.spatial.transform import Rotation

    x, y, z, roll, pitch, yaw = (float(v) for v in values)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    T[:3, 3] = (x, y, z)
    return T


@dataclass
class _Crop:
    map_id: int
    T_map_crop: np.ndarray  # the estimate the crop is centred on
    cloud: Cloud  # the cropped map in the crop frame, preprocessed


class MapTarget:
    """A latched, static target (a map or any reference cloud, ``node.target_mode: latched``).

    The latest map (:meth:`set_map`, raw points in the map frame) pairs with every source, with no stamp
    matching. For each source the map is cropped around the current estimate ``T_map_sensor`` (points within
    ``node.map_crop_radius``, default ``preprocess.max_range``), expressed in that estimate's frame and
    preprocessed like a scan (kept until the estimate moves ``RECROP_SHARE`` of the radius); the source is
    registered against the crop from the estimate, and the answer ``T_map_source`` is the next estimate.
    The first estimate is ``node.initial_pose`` (and again after :meth:`reset`). A valid answer is the next source's
    good start (``register(..., good_start=True)``, ``node.good_start``); the initial pose and the pose before a
    rejected answer get the full pipeline.
    """

    def __init__(self, config: Any) -> None:
        self.config = config
        self._lock = threading.Lock()
        self.map: Cloud | None = None
        self._crop: _Crop | None = None
        self.reset()

    def reset(self) -> None:
        """The next source starts from ``node.initial_pose`` again."""
        with self._lock:
            self.T_map_sensor = pose_from_xyzrpy(self.config.node.initial_pose)
            self._answered = False  # the estimate is the last valid answer (a good start), not the initial pose

    def set_map(self, cloud: Cloud) -> None:
        with self._lock:
            self.map, self._crop = cloud, None

    def _crop_at(self, registration: Any, map_cloud: Cloud, T_map_c: np.ndarray) -> _Crop:
        radius = self.config.node.map_crop_radius or self.config.preprocess.max_range
        pts = np.asarray(map_cloud.xyz, dtype=np.float64)
        local = (pts - T_map_c[:3, 3]) @ T_map_c[:3, :3]  # inv(T_map_c) applied to the map points
        local = local[np.einsum("ij,ij->i", local, local) <= radius * radius].astype(np.float32)
        if len(local) < self.config.node.min_points:
            raise BadInput("registration_failed",
                           f"target (map): {len(local)} points within {radius:.1f} m of the estimate "
                           f"[{T_map_c[0, 3]:.1f}, {T_map_c[1, 3]:.1f}, {T_map_c[2, 3]:.1f}] "
                           "(node.initial_pose / node.map_crop_radius; ~/reset restarts there)")
        try:
            pp = registration.preprocess(local)
        except RegistrationError as err:
            raise BadInput("preprocess_failed", f"target (map) crop: {err}") from err
        return _Crop(id(map_cloud), T_map_c.copy(),
                     Cloud(local, map_cloud.stamp_ns, map_cloud.frame_id, map_cloud.t_recv, pp=pp))

    def register(self, registration: Any, source: Cloud) -> tuple[Registered, np.ndarray]:
        """(``Registered`` with ``T = T_map_source``, the crop's preprocessed points (M, 3) in the map frame).

        Raises:
            BadInput: no map yet, too few map points around the estimate, or the registration failed.
        """
        with self._lock:
            map_cloud, T_start, crop = self.map, self.T_map_sensor.copy(), self._crop
            good = self._answered and self.config.node.good_start
        if map_cloud is None:
            raise BadInput("no_target", "no target (map) received yet")
        radius = self.config.node.map_crop_radius or self.config.preprocess.max_range
        timings: dict[str, float] = {}
        if (crop is None or crop.map_id != id(map_cloud)
                or np.linalg.norm(T_start[:3, 3] - crop.T_map_crop[:3, 3]) > RECROP_SHARE * radius):
            t0 = time.perf_counter()
            crop = self._crop_at(registration, map_cloud, T_start)
            timings["map_crop"] = (time.perf_counter() - t0) * 1e3
        T_init = np.linalg.inv(crop.T_map_crop) @ T_start
        reg = register_clouds(registration, source, crop.cloud, T_init=T_init, good_start=good)
        T_map_source = crop.T_map_crop @ reg.T
        with self._lock:
            if self.map is map_cloud:
                self._crop = crop
                if getattr(reg.result, "valid", True):  # a pose the verdict rejects is not the next start
                    self.T_map_sensor = T_map_source.copy()
                    self._answered = True
                else:  # nor a good one: the next source gets the full pipeline from the last valid pose
                    self._answered = False
        reg.timings_ms.update(timings)
        pts = getattr(crop.cloud.pp, "points", None)
        pts_map = None if pts is None else (np.asarray(pts, np.float64) @ crop.T_map_crop[:3, :3].T
                                            + crop.T_map_crop[:3, 3])
        return Registered(T_map_source, reg.result, reg.timings_ms), pts_map
