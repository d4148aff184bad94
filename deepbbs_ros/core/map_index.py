"""The map's points for fast crops (no ROS): a voxel grid's centroids, and the points sorted by their 10 m cell.
"""

from __future__ import annotations

import numpy as np


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """(N, 3) -> (M, 3) float32: the centroid of the points of every occupied ``voxel`` m cube (0: as given)."""
    pts = np.asarray(points, dtype=np.float64)
    if voxel <= 0 or len(pts) == 0:
        return pts.astype(np.float32)
    key = np.floor(pts / voxel).astype(np.int64)
    key -= key.min(axis=0)
    dims = key.max(axis=0) + 1
    flat = (key[:, 0] * dims[1] + key[:, 1]) * dims[2] + key[:, 2]
    _, inv, counts = np.unique(flat, return_inverse=True, return_counts=True)
    out = np.stack([np.bincount(inv, weights=pts[:, j], minlength=len(counts)) for j in range(3)], axis=1)
    return (out / counts[:, None]).astype(np.float32)


class _CellIndex:
    """Map points sorted by their ``cell`` m square (x, y), for fast crops."""

    def __init__(self, points: np.ndarray, cell: float) -> None:
        self.cell = cell
        ij = np.floor(points[:, :2] / cell).astype(np.int64)
        self.lo = ij.min(axis=0)
        ij -= self.lo
        self.ny = int(ij[:, 1].max()) + 1
        self.nx = int(ij[:, 0].max()) + 1
        key = ij[:, 0] * self.ny + ij[:, 1]
        order = np.argsort(key, kind="stable")
        self.points = points[order]
        key = key[order]
        self.starts = np.searchsorted(key, np.arange(self.nx * self.ny + 1))

    def within(self, xy: np.ndarray, radius: float) -> np.ndarray:
        """(M, 3) the points within ``radius`` m of xy (2,), horizontally."""
        lo = np.floor((np.asarray(xy) - radius) / self.cell).astype(np.int64) - self.lo
        hi = np.floor((np.asarray(xy) + radius) / self.cell).astype(np.int64) - self.lo
        lo, hi = np.maximum(lo, 0), np.minimum(hi, [self.nx - 1, self.ny - 1])
        parts = []
        for i in range(lo[0], hi[0] + 1):
            a, b = self.starts[i * self.ny + lo[1]], self.starts[i * self.ny + hi[1] + 1]
            if b > a:
                parts.append(self.points[a:b])
        if not parts:
            return np.zeros((0, 3), np.float32)
        p = np.concatenate(parts)
        d = p[:, :2] - np.asarray(xy, dtype=np.float32)
        return p[np.einsum("ij,ij->i", d, d) <= radius * radius]
