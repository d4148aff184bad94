"""DeepBBS++ odometry: GICP against a local Gaussian voxel map, with DeepBBS++ where the motion prior fails.

``DeepBBSOdometry.register_frame`` reads top-down, as kiss-icp's ``register_frame``::

    deskew      per-point times (Velodyne ``time``, Ouster ``t``) + the constant-velocity twist (the mean of
                the last ``odometry.deskew_window`` motions) -> the scan at its stamp (``odometry.deskew``)
    prepare     crop, ``voxel_size / 2`` grid, covariances (small_gicp ``preprocess_points``)
    predict     constant velocity scaled to the stamp gap: T_map_k = T_map_{k-1} @ delta^(dt / period)
    align       VGICP of the scan against the local map (small_gicp ``GaussianVoxelMap``, ``voxel_size``
                voxels, least-recently-used voxels dropped; core/local_map.py) from the prediction
                (core/motion_model.py); the first motion, which has none, from identity coarse to fine
                (core/first_motion.py); where the scans' own neighbourhoods are lines (``odometry.line_share``,
                core/line_share.py: a sparse sensor's scan lines) or with ``odometry.map_covariances`` GICP
                against the map's voxel means, covariances from their map neighbours (core/map_target.py)
    hold        along the directions the VGICP's Hessian cannot constrain (a corridor's axis, an open field's
                plane: ``odometry.degenerate_ratio``) a slide beyond the gate (below) is undone: the prediction's
                position is kept there (core/degeneracy.py)
    check       fit = share of scan points with a map correspondence (core/odometry_check.py); on a fit drop, a
                stamp gap longer than ``odometry.gap_trust`` periods (shorter ones: only when the fit drops) or
                the first motion DeepBBS++ registers the scan against the previous one (wide basin, no prior)
                and the map alignment runs again from there, and from the prediction refined coarse to fine
                against the previous scan; so does a step that deviates from the prediction by more than
                ``odometry.gate_sigmas`` times the motion model's observed deviation (KISS-ICP's adaptive
                threshold); a start wins over the prediction's alignment only with a clearly better fit
                (the starts: core/odometry_starts.py)
    update      map, velocity

Why: scan-to-map GICP is precise (per-frame errors of millimetres to centimetres where KISS-ICP's
point-to-point ICP has centimetres) and the map keeps it from drifting like chained scan-to-scan
registration; its constant-velocity prediction is exactly what breaks on long runs of dropped frames, sharp
turns at low frame rates and a wrong prior, and DeepBBS++ needs no prior. On ordinary frames DeepBBS++ does
not run.

Frames and conventions (CONVENTIONS.md): the map frame is the first scan's sensor frame at its stamp;
``register_frame`` returns ``T_first_k`` (4, 4) float64, the pose of scan k's sensor at its stamp in that
frame; ``T_{k-1}_k = inv(T_first_{k-1}) @ T_first_k``. Map, registration and voxel grids from
``small_gicp``; no ROS import.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import covariance as _cov
from deepbbs_ros.core import degeneracy as _deg
from deepbbs_ros.core import line_share as _lines
from deepbbs_ros.core import odometry_hold as _held
from deepbbs_ros.core.local_map import LocalMap
from deepbbs_ros.core.motion_model import MotionModel, se3_power
from deepbbs_ros.core.odometry_check import suspect
from deepbbs_ros.core.odometry_starts import OdometryStarts
from deepbbs_ros.core.odometry_step import Laps as _Laps
from deepbbs_ros.core.odometry_step import OdometryStep, floor_covariance
from deepbbs_ros.core.odometry_step import cloud_points as _cloud_points
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.core.polish import threads_or_all
from deepbbs_ros.core.preprocess import deskew
from deepbbs_ros.errors import RegistrationError

#: the gate's floor, in map voxels: a perfectly predictable drive's centimetres are no jump
GATE_FLOOR = 0.1

__all__ = ["DeepBBSOdometry", "OdometryStep", "deskew", "se3_power"]


class DeepBBSOdometry(OdometryStarts):
    """Scan-to-local-map GICP odometry with DeepBBS++ as the initialiser where the motion prior fails.

    Args:
        config: ``preprocess.min_range``/``max_range`` (crop), the ``odometry`` section, and for DeepBBS++
            the ``preprocess``/``model``/``registration`` sections.
        registration: a :class:`~deepbbs_ros.core.registration.DeepBBSRegistration` to use (shared with
            other users of the same network); built from ``config`` on first need when None, unless
            ``odometry.deepbbs_init`` is "never".
    """

    def __init__(self, config: Config | None = None, registration: Any = None) -> None:
        self.config = (config or Config()).validate()
        self.threads = threads_or_all(self.config.odometry.threads)
        self._local = LocalMap(self.config, self.threads)  # the voxel map, its voxel, its target, the alignment
        self._reg = registration
        #: the driver that publishes the scans (``msg_adapters.layouts.recognise_driver``; the node sets it from its
        #: input's first message): DeepBBS++'s preprocessing settles ``preprocess.sensor`` "auto" with it
        self.driver: str | None = None
        self.reset()

    def reset(self) -> None:
        """Forget the map and the motion: the next scan becomes the origin."""
        oc = self.config.odometry
        self._local.reset()
        self.frames = 0
        self.pose = np.eye(4)  # T_first_{k-1}
        self._motion = MotionModel(oc.gap_factor, oc.deskew_window)  # velocity, period, previous stamp
        self._prev_points: np.ndarray | None = None
        self._prev_pp: Any = None
        self._cur_pp: Any = None
        self._first_raw: tuple[np.ndarray, np.ndarray] | None = None
        self._fits: deque[float] = deque(maxlen=max(1, oc.fit_window))
        self.deepbbs_calls = 0
        self.deepbbs_rejected = 0  # DeepBBS++ answers the verdict rejected (the constant-velocity track stood)
        self._deepbbs_path = "deepbbs"  # the path of DeepBBS++'s last answer (RegistrationResult.path)
        self._gate = _deg.MotionGate(oc.gate_sigmas, oc.fit_window, GATE_FLOOR * self.voxel_size)
        self._sweep = _cov.MotionFloor(oc.sweep_floor)  # the step covariance's model error
        self.swept: np.ndarray | None = None  # the motion per period the last scan was deskewed with (None: not)
        self.sweep_times: np.ndarray | None = None  # the last frame's per-point times, s since its stamp (None: none)
        self.degenerate_frames = 0  # frames in a degenerate place (a direction held)
        self._planes = False  # this scan aligns against the map's planes (map_covariances or line_share)
        self.plane_frames = 0  # frames aligned against the map's planes
        self._shares: deque[float] = deque(maxlen=max(1, oc.fit_window // _lines.EVERY))  # the last line shares
        self._tree: Any = None  # the k-d tree of the last prepared scan

    # the local map's and the motion model's state, under the names callers use
    voxel_size = property(lambda self: self._local.voxel_size, doc="The map voxel, m.")
    _map = property(lambda self: self._local.map)
    _map_version = property(lambda self: self._local.version)
    _target = property(lambda self: self._local.target)
    period = property(lambda self: self._motion.period, doc="The nominal scan period, s (0 until two stamps).")

    @property
    def delta(self) -> np.ndarray:
        """The last motion per nominal period (4, 4): the constant-velocity model."""
        return self._motion.delta

    @delta.setter
    def delta(self, value: np.ndarray) -> None:
        self._motion.delta = value

    @property
    def registration(self) -> Any:
        """The DeepBBS++ registration (built on first use)."""
        if self._reg is None:
            from deepbbs_ros.core.registration import DeepBBSRegistration

            self._reg = DeepBBSRegistration(self.config)
            self._reg.warmup()
        return self._reg

    # -- the pipeline ------------------------------------------------------------------------------
    def register_frame(self, points: np.ndarray, times: np.ndarray | None = None,
                       stamp_ns: int | None = None) -> OdometryStep:
        """Add scan k: (N, 3) xyz in its sensor frame (metres, NaN rows dropped; another shape is a
        RegistrationError, :mod:`deepbbs_ros.core.points`), optional (N,) per-point times in seconds since
        ``stamp_ns`` (the scan stamp, ns). Returns the :class:`OdometryStep`."""
        clock = _Laps()
        scale, gap = self._motion.time_scale(stamp_ns)
        frame = self._deskew(points, times, scale)
        if self.frames == 0 and self.config.odometry.voxel_size <= 0:
            self._size_voxels(frame)
        clock.lap("deskew")
        cloud = self._prepare(frame)
        self._planes = self._map_planes(cloud)
        clock.lap("prepare")
        if self.frames == 0:
            return self._first(frame, cloud, stamp_ns, clock, points, times)
        # predict + align: GICP against the voxel map from the constant-velocity prediction (the first motion, which
        # has none, from identity coarse to fine: core/first_motion.py)
        prior = self._motion.predict(self.pose, scale)
        pose, fit = self._align(cloud, self._coarse_start(frame, prior) if self.frames == 1 else prior)
        pose, deg = self._hold(pose, prior, cloud)
        clock.lap("align")
        # check: DeepBBS++ where the prior is suspect, and the other starts
        dev, limit = _deg.deviation(pose, prior), self._gate.limit()
        reason = suspect(self.config.odometry, self.frames, scale, gap, fit, self._fits, dev, limit)
        won, path = False, "gicp"
        if reason:
            pose, fit, won, path, deg = self._other_starts(frame, cloud, prior, pose, fit, deg)
            clock.lap("deepbbs")
        along = None
        if self.frames == 1:  # the first motion along the direction its data pin least (core/odometry_first.py)
            pose, fit, deg, along = self._along(frame, cloud, pose, fit, deg)
            clock.lap("align")
        dev = _deg.deviation(pose, prior)
        if self.frames >= 3:  # the motion model's own error (not the first motion's): where the place measures it
            self._gate.update(_deg.deviation(_deg.hold(pose, prior, deg.weak), prior))
        self.degenerate_frames += bool(deg.axes)
        self.plane_frames += self._planes
        T_prev_k = np.linalg.inv(self.pose) @ pose
        self._motion.update(T_prev_k, scale)
        if self.frames == 1 and self._first_raw is not None and self._has_times(times):
            # the first velocity is known only now: deskew the first two scans with it and restart the map
            cloud, frame = self._restart_deskewed(points, times)
            clock.lap("prepare")
        # update: map (the covariance's pairs first: the map without this scan), velocity, previous scan
        floor = self._sweep.update(pose, prior if self.frames >= 2 else None, self.delta, self.swept, bool(deg.axes))
        weak, weak_sigma = deg.weak, None
        if along is not None and along.sigma > 0:  # the first motion's places along the direction: its uncertainty
            weak, weak_sigma = np.vstack([deg.weak, along.direction]), [np.nan] * len(deg.weak) + [along.sigma]
        cov = _cov.odometry_covariance(cloud, self._map, pose, self.voxel_size, floor, weak, self._sweep, weak_sigma)
        cross = self._held_cross(pose, deg.weak) if cov is not None else None
        self._local.insert(cloud, pose)
        self.pose = pose
        self._fits.append(fit)
        self._remember(frame, stamp_ns, bool(reason))
        self.frames += 1
        return OdometryStep(pose.copy(), T_prev_k, bool(reason), won, reason, fit, clock.done(), _cloud_points(cloud),
                            path, cov, deg.label, dev, limit, floor_covariance(floor, pose, cov), cross)

    # -- stages ------------------------------------------------------------------------------------
    def _size_voxels(self, frame: np.ndarray) -> None:
        """The map voxel from the first scan (core/local_map.py); the gate's floor follows it."""
        if self._local.size_from(frame):
            self._gate = _deg.MotionGate(self.config.odometry.gate_sigmas, self.config.odometry.fit_window,
                                         GATE_FLOOR * self.voxel_size)

    def _map_planes(self, cloud: Any) -> bool:
        """Align against the map's planes: ``odometry.map_covariances``, or more than ``odometry.line_share`` of the
        scans' neighbourhoods are lines, measured on every ``EVERY``-th scan and averaged over the last
        ``odometry.fit_window`` scans (core/line_share.py; one scan's share varies by a third with the place)."""
        oc = self.config.odometry
        if oc.map_covariances or oc.line_share >= 1:
            return oc.map_covariances
        if self.frames % _lines.EVERY == 0 or not self._shares:
            share = _lines.line_share(np.asarray(cloud.points()), self._tree, oc.neighbors, threads=self.threads)
            if np.isfinite(share):
                self._shares.append(share)
        return bool(self._shares and np.mean(self._shares) > oc.line_share)

    def _has_times(self, times: np.ndarray | None) -> bool:
        return bool(self.config.odometry.deskew and times is not None and len(times) and np.ptp(times) > 0)

    def _deskew(self, points: np.ndarray, times: np.ndarray | None, scale: float,
                delta: np.ndarray | None = None) -> np.ndarray:
        """Finite points, deskewed to the stamp with ``delta`` (default: the velocity so far, from the
        third scan on), cropped to [min_range, max_range]: (N, 3) float64."""
        from deepbbs_ros.core.preprocess import crop_mask

        pp = self.config.preprocess
        pts = as_xyz(points, "odometry", dtype=np.float64)  # (N, 3) only (core/points.py)
        if delta is None and self.frames >= 2 and self.period > 0:
            delta = self._motion.deskew_delta()
        self.swept, self.sweep_times = None, None
        if self._has_times(times):
            tt = np.asarray(times, dtype=np.float64).reshape(-1)
            if len(tt) == len(pts):
                ok = np.isfinite(pts).all(axis=1)
                pts, tt = pts[ok], tt[ok]
                if delta is not None:
                    pts = deskew(pts, tt, delta, self.period)
                    self.swept = delta
                self.sweep_times = tt
        keep = crop_mask(pts, pp)
        frame = pts[keep]
        if self.sweep_times is not None:  # each point's time in the sweep (scripts/benchmarks/_sweep_share.py)
            self.sweep_times = self.sweep_times[keep]
        if len(frame) < 10:
            raise RegistrationError(f"odometry: only {len(frame)} valid points within the crop range")
        return frame

    def _prepare(self, frame: np.ndarray) -> Any:
        """small_gicp cloud of the scan: ``voxel_size / 2`` grid, covariances from ``odometry.neighbors``."""
        import small_gicp

        cloud, self._tree = small_gicp.preprocess_points(
            np.ascontiguousarray(frame), downsampling_resolution=0.5 * self.voxel_size,
            num_neighbors=self.config.odometry.neighbors, num_threads=self.threads)
        if cloud.size() < 10:
            raise RegistrationError(f"odometry: only {cloud.size()} points after the voxel grid")
        return cloud

    def _align(self, cloud: Any, init: np.ndarray, iters: int | None = None) -> tuple[np.ndarray, float]:
        """The scan against the local map from ``init`` -> (pose (4, 4), fit = inlier share)."""
        return self._local.align(cloud, init, self._planes, iters)

    def _hold(self, pose: np.ndarray, start: np.ndarray, cloud: Any) -> tuple[np.ndarray, _deg.Degeneracy]:
        """The last VGICP's degeneracy at ``pose`` and ``pose`` held to ``start`` beyond the gate along its weak
        directions (the Hessian's ratio test, core/degeneracy.py), and along those the data pin less than the
        prediction does moved to the two's weighted mean (core/odometry_hold.py); not on the first motion (its start,
        identity, is no prediction)."""
        H = self._local.hessian
        deg = _deg.analyse(H, pose[:3, :3], self.config.odometry.degenerate_ratio)
        limit = self._gate.limit()
        if self.frames < 2 or not np.isfinite(limit):
            return pose, deg
        R = pose[:3, :3]
        held, sigmas = _held.held_directions(
            pose, start, _held.translation_directions(H, R), limit,
            lambda: _cov.gicp_part(cloud, self._map, pose, self.voxel_size),
            lambda d: np.fmax(self._sweep.weak_sigma(R.T @ d), self._sweep.last_deviation(R.T @ d)))
        pose = _deg.hold(_held.blend(pose, start, held, sigmas), start, deg.weak, limit)
        return pose, _held.merged(deg, held, R)

    def _held_cross(self, pose: np.ndarray, weak: np.ndarray) -> np.ndarray | None:
        """(6, 6) map frame: along each ``weak`` direction (K, 3, map frame) held at ``pose``, the accumulated pose's
        covariance gain from the held steps' shared velocity error (``MotionFloor.held_cross``); None: none."""
        R = pose[:3, :3]
        out = np.zeros((6, 6))
        for d in np.asarray(weak, dtype=np.float64).reshape(-1, 3):
            out[:3, :3] += self._sweep.held_cross(R.T @ d) * np.outer(d, d)
        return out if out.any() else None

    def _restart_deskewed(self, points: np.ndarray, times: np.ndarray) -> tuple[Any, np.ndarray]:
        """Second scan: both scans deskewed with the first velocity and the map rebuilt from the first (a
        map of distorted first scans would bias every later deskewed scan). -> (cloud, frame) of scan 1."""
        raw0, times0 = self._first_raw
        self._first_raw = None
        self._local.map = self._local._new_map()
        self._local.insert(self._prepare(self._deskew(raw0, times0, 1.0, self.delta)), np.eye(4))
        frame = self._deskew(points, times, 1.0, self.delta)
        return self._prepare(frame), frame

    def _first(self, frame, cloud, stamp_ns, clock, points=None, times=None) -> OdometryStep:
        self._first_raw = (np.asarray(points), np.asarray(times)) if self._has_times(times) else None
        self._local.insert(cloud, np.eye(4))
        self._remember(frame, stamp_ns, False)
        self.frames = 1
        if self.config.odometry.deepbbs_init != "never":
            # the first motion always asks DeepBBS++: this scan's preprocessing for it is done now, while a live
            # node has nothing waiting (the next scan is a period away), not on the first motion's long step
            try:
                self._prev_pp = self._preprocess(frame)
            except RegistrationError:
                self._prev_pp = None  # the first motion tries again (and fails the same way: no DeepBBS++)
            clock.lap("deepbbs")
        return OdometryStep(np.eye(4), np.eye(4), timings_ms=clock.done(), points=_cloud_points(cloud))

    def _remember(self, frame: np.ndarray, stamp_ns: int | None, consulted: bool) -> None:
        """Keep scan k for DeepBBS++ at k+1 (its preprocessing too, when DeepBBS++ already made it)."""
        self._prev_points = frame
        self._prev_pp = self._cur_pp if consulted else None
        self._cur_pp = None
        self._motion.prev_stamp = None if stamp_ns is None else int(stamp_ns)
