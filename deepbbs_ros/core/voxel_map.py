"""Points kept one per voxel (no ROS import): :func:`voxel_down_sample` (KISS-ICP's: the first point seen in each
voxel is kept) and :class:`VoxelMap`, a grid that grows scan by scan (core/mapping.py's accumulation)."""

from __future__ import annotations

import numpy as np

from deepbbs_ros.errors import DatasetError


def voxel_down_sample(points: np.ndarray, voxel: float) -> np.ndarray:
    """(N, 3) -> (M, 3) float64, one point per ``voxel``-metre cell (the first one in ``points`` order)."""
    from kiss_icp.voxelization import voxel_down_sample as kiss_voxel_down_sample

    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(pts):
        return pts
    return np.asarray(kiss_voxel_down_sample(pts, float(voxel)), dtype=np.float64).reshape(-1, 3)


class VoxelMap:
    """Points accumulated on a voxel grid: ``add`` world points, ``points`` the grid's (M, 3) float64.

    New points wait in a buffer and are merged (the grid's points first, so theirs stay) once the buffer holds
    ``flush_points`` or as many points as the grid, whichever is more: each merge costs about the points added
    since the last one (amortised linear in the scans), memory stays within about twice the map."""

    def __init__(self, voxel: float, flush_points: int = 2_000_000) -> None:
        if not voxel > 0:
            raise DatasetError(f"map voxel must be > 0 m, got {voxel}")
        self.voxel = float(voxel)
        self.flush_points = int(flush_points)
        self._grid = np.zeros((0, 3))
        self._pending: list[np.ndarray] = []
        self._pending_n = 0

    def add(self, points: np.ndarray) -> None:
        """``points`` (N, 3) in the map frame, metres."""
        self._pending.append(voxel_down_sample(points, self.voxel))  # a scan's own duplicates first: cheaper
        self._pending_n += len(self._pending[-1])
        if self._pending_n >= max(self.flush_points, len(self._grid)):
            self._flush()

    def _flush(self) -> None:
        if self._pending:
            self._grid = voxel_down_sample(np.concatenate([self._grid, *self._pending]), self.voxel)
            self._pending, self._pending_n = [], 0

    @property
    def points(self) -> np.ndarray:
        """(M, 3) float64 map points, one per voxel."""
        self._flush()
        return self._grid

    def __len__(self) -> int:
        return len(self.points)
