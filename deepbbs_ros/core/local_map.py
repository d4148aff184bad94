"""The odometry's local map: a small_gicp Gaussian voxel map, its voxel, and the scan's alignment against it (no ROS
import).

The scan aligns with VGICP against the voxel map (each voxel: the mean of its points and of their scans' own
covariances) or, when its own neighbourhoods are lines (``odometry.line_share``) or with ``odometry.map_covariances``,
with GICP against the map's voxel means and planes fitted through their map neighbours (core/map_target.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.map_target import MapTarget

__all__ = ["TARGET_REACH", "VOXEL_PER_MAX_RANGE", "VOXEL_PER_RANGE", "LocalMap"]

#: the map voxel is at most the first scan's median range over this (odometry.voxel_size 0) ...
VOXEL_PER_RANGE = 10.0
#: ... and at most preprocess.max_range over this (KISS-ICP's map voxel: 0.8 m at 80 m)
VOXEL_PER_MAX_RANGE = 100.0
#: the map target keeps the voxel means within this x preprocess.max_range of the start
TARGET_REACH = 1.1


class LocalMap:
    """The voxel map (``map``), its voxel (``voxel_size``), its updates so far (``version``), the map target
    (``target``) and the last alignment's GICP Hessian (``hessian``, the degeneracy check's)."""

    def __init__(self, config: Any, threads: int) -> None:
        self.config = config
        self.threads = threads
        oc = config.odometry
        # map voxel, m; with odometry.voxel_size 0 the first scan sizes it (size_from)
        self.voxel_size = oc.voxel_size if oc.voxel_size > 0 else config.preprocess.max_range / VOXEL_PER_MAX_RANGE
        self.reset()

    def reset(self) -> None:
        """An empty map (the voxel kept)."""
        oc = self.config.odometry
        self.map = self._new_map()
        self.version = 0  # map updates so far (the map target checks what changed after each)
        self.hessian = np.zeros((6, 6))
        # the map's voxel means within the scan's reach (and a margin for the other starts)
        self.target = MapTarget(oc.neighbors, self.threads, TARGET_REACH * self.config.preprocess.max_range
                                + oc.max_corr_dist, self.voxel_size, oc.map_refresh)

    def size_from(self, frame: np.ndarray) -> bool:
        """The map voxel from the first scan: its median range / ``VOXEL_PER_RANGE``, at most ``max_range / 100``;
        True when it changed (the map is then new).

        A car's spinning sensor on a road (median ranges of 10-15 m) keeps the ``max_range / 100`` voxel (0.8 m at 80
        m, KISS-ICP's; 1 m cost centimetres on KITTI's 64-beam scans); indoors, in a garage or with a sensor looking
        down at the floor (median ranges of 3-4 m) a car's voxel blurs the walls and GICP's steps wander: the voxel
        shrinks with the scene, as KISS-ICP's map follows its range."""
        rng = float(np.median(np.linalg.norm(frame, axis=1)))
        size = min(self.config.preprocess.max_range / VOXEL_PER_MAX_RANGE, rng / VOXEL_PER_RANGE)
        if not (np.isfinite(size) and size > 0 and size != self.voxel_size):
            return False
        self.voxel_size = self.target.voxel = size
        self.map = self._new_map()
        return True

    def _new_map(self) -> Any:
        import small_gicp

        vmap = small_gicp.GaussianVoxelMap(self.voxel_size)
        vmap.set_lru(self.config.odometry.lru_horizon, self.config.odometry.lru_clear_cycle)
        return vmap

    def insert(self, cloud: Any, pose: np.ndarray) -> None:
        self.map.insert(cloud, pose)
        self.version += 1  # the map target checks what changed on the next alignment

    def align(self, cloud: Any, init: np.ndarray, planes: bool, iters: int | None = None) -> tuple[np.ndarray, float]:
        """VGICP of the scan against the map from ``init`` (with ``planes``: GICP against the map target) -> (pose
        (4, 4), fit = inlier share); keeps the Hessian."""
        import small_gicp

        oc = self.config.odometry
        if planes:  # GICP against the voxel means, covariances from map neighbours (core/map_target.py)
            res = self.target.align(self.map, self.version, cloud, init, oc.max_corr_dist, iters or oc.max_iters)
        else:
            res = small_gicp.align(self.map, cloud, init, max_correspondence_distance=oc.max_corr_dist,
                                   num_threads=self.threads, max_iterations=iters or oc.max_iters)
        self.hessian = np.asarray(res.H, dtype=np.float64)
        return np.asarray(res.T_target_source, dtype=np.float64), float(res.num_inliers) / max(1, cloud.size())
