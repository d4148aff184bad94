"""The odometry's stages on one scan (no ROS import), in the order ``DeepBBSOdometry.register_frame`` calls them:
deskew and prepare, predict and align on the local map (its weak directions held), check (DeepBBS++ and the other
starts where the prior is suspect), learn the motion, the step's covariance, update. :class:`Frame` carries what one
call learns on its way.

:class:`OdometryStages` is a part of :class:`~deepbbs_ros.core.odometry.DeepBBSOdometry` (a mixin).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import covariance as _cov
from deepbbs_ros.core import degeneracy as _deg
from deepbbs_ros.core import odometry_hold as _held
from deepbbs_ros.core.local_map import LocalMap
from deepbbs_ros.core.motion_model import MotionModel
from deepbbs_ros.core.odometry_check import suspect
from deepbbs_ros.core.odometry_step import Laps, OdometryStep, cloud_points, floor_covariance


@dataclass
class Frame:
    """One scan on its way through ``DeepBBSOdometry.register_frame``: its input, then what each stage adds."""

    points: np.ndarray  # the scan as given (N, 3)
    times: np.ndarray | None  # per-point times, s since the stamp
    stamp_ns: int | None
    scale: float  # the stamp gap in nominal periods (core/motion_model.py)
    gap: float
    clock: Laps = field(default_factory=Laps)
    frame: Any = None  # (N, 3) deskewed, cropped
    cloud: Any = None  # its small_gicp cloud
    prior: Any = None  # (4, 4) the constant-velocity prediction
    pose: Any = None  # (4, 4) T_first_k so far
    fit: float = float("nan")
    deg: Any = None  # core/degeneracy.py Degeneracy at the pose
    reason: str = ""  # why DeepBBS++ was consulted ("" not)
    won: bool = False
    path: str = "gicp"
    along: Any = None  # the first motion's search along its weak direction (core/odometry_first.py), or None
    dev: float = float("nan")  # m between the pose and the prediction
    limit: float = float("inf")  # the gate's limit before this scan
    T_prev_k: Any = None
    floor: Any = None  # the sweep's model error (core/motion_floor.py)
    cov: Any = None
    cross: Any = None


class OdometryStages:
    """The stages of :class:`~deepbbs_ros.core.odometry.DeepBBSOdometry` (module docstring)."""

    # what it reads of the DeepBBSOdometry it is part of
    config: Config
    frames: int
    pose: np.ndarray
    delta: np.ndarray
    voxel_size: float
    swept: np.ndarray | None
    degenerate_frames: int
    plane_frames: int
    _local: LocalMap
    _motion: MotionModel
    _gate: _deg.MotionGate
    _sweep: _cov.MotionFloor
    _fits: deque
    _planes: bool
    _first_raw: tuple[np.ndarray, np.ndarray] | None
    _map: Any

    def _deskew_and_prepare(self, f: Frame) -> None:
        """deskew (the map voxel from the first scan, when not set), prepare, and whether it aligns on planes."""
        f.frame = self._deskew(f.points, f.times, f.scale)
        if self.frames == 0 and self.config.odometry.voxel_size <= 0:
            self._size_voxels(f.frame)
        f.clock.lap("deskew")
        f.cloud = self._prepare(f.frame)
        self._planes = self._map_planes(f.cloud)
        f.clock.lap("prepare")

    def _predict_and_align(self, f: Frame) -> None:
        """predict + align + hold: GICP against the voxel map from the constant-velocity prediction (the first
        motion, which has none, from identity coarse to fine: core/first_motion.py), its weak directions held."""
        f.prior = self._motion.predict(self.pose, f.scale)
        pose, f.fit = self._align(f.cloud, self._coarse_start(f.frame, f.prior) if self.frames == 1 else f.prior)
        f.pose, f.deg = self._hold(pose, f.prior, f.cloud)
        f.clock.lap("align")

    def _check(self, f: Frame) -> None:
        """check: DeepBBS++ where the prior is suspect, and the other starts; the first motion also along the
        direction its data pin least (core/odometry_first.py)."""
        f.dev, f.limit = _deg.deviation(f.pose, f.prior), self._gate.limit()
        f.reason = suspect(self.config.odometry, self.frames, f.scale, f.gap, f.fit, self._fits, f.dev, f.limit)
        if f.reason:
            f.pose, f.fit, f.won, f.path, f.deg = self._other_starts(f.frame, f.cloud, f.prior, f.pose, f.fit, f.deg)
            f.clock.lap("deepbbs")
        if self.frames == 1:
            f.pose, f.fit, f.deg, f.along = self._along(f.frame, f.cloud, f.pose, f.fit, f.deg)
            f.clock.lap("align")
        f.dev = _deg.deviation(f.pose, f.prior)

    def _learn_motion(self, f: Frame) -> None:
        """The gate learns the motion model's error (not the first motion's: where the place measures it), the
        velocity the step; at the first motion, the first two scans deskewed again with it."""
        if self.frames >= 3:
            self._gate.update(_deg.deviation(_deg.hold(f.pose, f.prior, f.deg.weak), f.prior))
        self.degenerate_frames += bool(f.deg.axes)
        self.plane_frames += self._planes
        f.T_prev_k = np.linalg.inv(self.pose) @ f.pose
        self._motion.update(f.T_prev_k, f.scale)
        if self.frames == 1 and self._first_raw is not None and self._has_times(f.times):
            # the first velocity is known only now: deskew the first two scans with it and restart the map
            f.cloud, f.frame = self._restart_deskewed(f.points, f.times)
            f.clock.lap("prepare")

    def _step_covariance(self, f: Frame) -> None:
        """The step's covariance against the map without this scan (core/covariance.py), its sweep's model error
        and, along held directions, the held steps' shared error."""
        deg, pose = f.deg, f.pose
        f.floor = self._sweep.update(pose, f.prior if self.frames >= 2 else None, self.delta, self.swept,
                                     bool(deg.axes))
        weak, weak_sigma = deg.weak, None
        if f.along is not None and f.along.sigma > 0:  # the first motion's places along the direction: its uncertainty
            weak, weak_sigma = np.vstack([deg.weak, f.along.direction]), [np.nan] * len(deg.weak) + [f.along.sigma]
        f.cov = _cov.odometry_covariance(f.cloud, self._map, pose, self.voxel_size, f.floor, weak, self._sweep,
                                         weak_sigma)
        f.cross = self._held_cross(pose, deg.weak) if f.cov is not None else None

    def _update(self, f: Frame) -> OdometryStep:
        """update: the map takes the scan, the pose, the fits, the previous scan -> the step."""
        self._local.insert(f.cloud, f.pose)
        self.pose = f.pose
        self._fits.append(f.fit)
        self._remember(f.frame, f.stamp_ns, bool(f.reason))
        self.frames += 1
        return OdometryStep(f.pose.copy(), f.T_prev_k, bool(f.reason), f.won, f.reason, f.fit, f.clock.done(),
                            cloud_points(f.cloud), f.path, f.cov, f.deg.label, f.dev, f.limit,
                            floor_covariance(f.floor, f.pose, f.cov), f.cross)

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
