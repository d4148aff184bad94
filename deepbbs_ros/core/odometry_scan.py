"""The odometry's scan on its way in (no ROS import): finite points deskewed to the stamp and cropped
(:meth:`OdometryScan._deskew`), the map voxel from the first scan (:meth:`_size_voxels`), the small_gicp cloud
(:meth:`_prepare`), whether it aligns against the map's planes (:meth:`_map_planes`), and the first two scans
deskewed again once the first velocity is known (:meth:`_restart_deskewed`).

:class:`OdometryScan` is a part of :class:`~deepbbs_ros.core.odometry.DeepBBSOdometry` (a mixin).
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import degeneracy as _deg
from deepbbs_ros.core import line_share as _lines
from deepbbs_ros.core.local_map import LocalMap
from deepbbs_ros.core.motion_model import MotionModel
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.core.preprocess import deskew
from deepbbs_ros.errors import RegistrationError

#: the gate's floor, in map voxels: a perfectly predictable drive's centimetres are no jump
GATE_FLOOR = 0.1


class OdometryScan:
    """The scan's deskewing and preparation in :class:`~deepbbs_ros.core.odometry.DeepBBSOdometry` (module
    docstring)."""

    # what it reads of the DeepBBSOdometry it is part of
    config: Config
    threads: int
    frames: int
    period: float
    voxel_size: float
    delta: np.ndarray
    swept: np.ndarray | None
    sweep_times: np.ndarray | None
    _local: LocalMap
    _motion: MotionModel
    _gate: _deg.MotionGate
    _shares: deque
    _tree: Any
    _first_raw: tuple[np.ndarray, np.ndarray] | None

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

    def _restart_deskewed(self, points: np.ndarray, times: np.ndarray) -> tuple[Any, np.ndarray]:
        """Second scan: both scans deskewed with the first velocity and the map rebuilt from the first (a
        map of distorted first scans would bias every later deskewed scan). -> (cloud, frame) of scan 1."""
        raw0, times0 = self._first_raw
        self._first_raw = None
        self._local.map = self._local._new_map()
        self._local.insert(self._prepare(self._deskew(raw0, times0, 1.0, self.delta)), np.eye(4))
        frame = self._deskew(points, times, 1.0, self.delta)
        return self._prepare(frame), frame
