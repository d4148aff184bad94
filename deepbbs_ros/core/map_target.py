"""The local map as a GICP target with covariances from the map's own neighbourhoods (``odometry.map_covariances``).

small_gicp's ``GaussianVoxelMap`` keeps, per voxel, the mean of the inserted points' covariances, and each of those was
fitted through a point's nearest neighbours in its own scan. On a sparse spinning sensor (16 beams) those neighbours
lie on one scan line: the second eigenvalue is about 0, the plane through them is undetermined and small_gicp's
regularisation picks an arbitrary normal, so the map's voxels average planes that point anywhere and the alignment
slides along the road (steps biased short). The map holds many sweeps: around a voxel mean its neighbours span the
surface, so a plane fitted through them has the surface's normal. ``MapTarget`` turns the map's voxel means into a
small_gicp point cloud with covariances from ``neighbors`` map neighbours (and its k-d tree), aligned against with
plain GICP and rebuilt once the map around the scan changed by more than a share (``odometry.map_refresh``).

No ROS import.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["TOL", "MapTarget", "build_target"]

#: a voxel mean that moved by more than this many voxels since the target was built counts as changed
TOL = 0.05


class MapTarget:
    """The map's voxel means as a GICP target (small_gicp ``PointCloud`` with covariances and its ``KdTree``).

    Rebuilt when the map around the scan changed: when more than ``refresh`` of the voxel means within ``radius`` of
    the alignment's start are not in the target (new voxels, voxels that came into reach) or moved by more than
    ``TOL`` voxels since it was built. A scan adds a few per cent of new voxels (a car's sensor sees new ground
    ahead); a target that lacks them is the same surfaces a few scans younger, and rebuilding it (k-d tree and every
    covariance) after every scan cost about as much as the whole default pipeline.

    Args:
        neighbors: map neighbours per covariance.
        threads: small_gicp threads.
        radius: m; only the voxel means this close to the alignment's start are kept (the scan's reach:
            preprocess.max_range plus a margin; on a highway the map reaches 100 scans back).
        voxel: m, the map voxel (keys the voxel means; 0: every change rebuilds).
        refresh: the share of changed voxel means that triggers a rebuild (0: any change, after every map update).
    """

    def __init__(self, neighbors: int, threads: int, radius: float = float("inf"), voxel: float = 0.0,
                 refresh: float = 0.0) -> None:
        self.neighbors = neighbors
        self.threads = threads
        self.radius = radius
        self.voxel = voxel
        self.refresh = refresh
        self.builds = 0  # rebuilds so far
        self.stale = 0.0  # the share of changed voxel means the target was last used with
        self._key: tuple[int, int] | None = None
        self._target: tuple[Any, Any] | None = None
        self._map: Any = None  # the map it was built from
        self._means: np.ndarray = np.zeros((0, 3))  # the target's voxel means, sorted by _keys
        self._keys: np.ndarray = np.zeros(0, dtype=np.int64)

    def get(self, vmap: Any, version: int, center: np.ndarray | None = None) -> tuple[Any, Any]:
        """(cloud, tree) of ``vmap``'s voxel means (map frame) within ``radius`` of ``center`` (3,), rebuilt when the
        map object changed or, after ``version`` (the caller's count of map updates) changed, more than ``refresh``
        of its voxel means there changed."""
        key = (id(vmap), int(version))
        if self._map is vmap and self._key == key and self._target is not None:
            return self._target
        pts = _crop(np.asarray(vmap.voxel_points(), dtype=np.float64)[:, :3], center, self.radius)
        same_map = self._map is vmap and self._target is not None
        if same_map and self.refresh > 0 and self.voxel > 0:
            self.stale = self._changed_share(pts)
            if self.stale <= self.refresh:
                self._key = key
                return self._target
        self._target = _build(pts, self.neighbors, self.threads)
        self._key, self._map, self.stale, self.builds = key, vmap, 0.0, self.builds + 1
        if self.voxel > 0:
            self._keys, self._means = _keyed(pts, self.voxel)
        return self._target

    def _changed_share(self, pts: np.ndarray) -> float:
        """The share of ``pts`` (the map's voxel means now) not in the target or moved by more than ``TOL`` voxels."""
        if not len(pts):
            return 0.0
        keys, means = _keyed(pts, self.voxel)
        i = np.clip(np.searchsorted(self._keys, keys), 0, max(0, len(self._keys) - 1))
        if not len(self._keys):
            return 1.0
        same = self._keys[i] == keys
        moved = np.linalg.norm(self._means[i] - means, axis=1) > TOL * self.voxel
        return float(np.mean(~same | moved))

    def align(self, vmap: Any, version: int, cloud: Any, init: np.ndarray, max_corr_dist: float,
              max_iters: int) -> Any:
        """GICP of ``cloud`` (sensor frame) against the map target from ``init`` (4, 4): small_gicp's result."""
        import small_gicp

        target, tree = self.get(vmap, version, np.asarray(init)[:3, 3])
        return small_gicp.align(target, cloud, tree, init, registration_type="GICP",
                                max_correspondence_distance=max_corr_dist, num_threads=self.threads,
                                max_iterations=max_iters)


def _crop(pts: np.ndarray, center: np.ndarray | None, radius: float) -> np.ndarray:
    if center is not None and np.isfinite(radius):
        pts = pts[np.linalg.norm(pts - center, axis=1) <= radius]
    return np.ascontiguousarray(pts)


def _keyed(pts: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """(sorted voxel keys (N,) int64, the means (N, 3) in that order) of voxel means ``pts`` (N, 3)."""
    ijk = np.floor(pts / voxel).astype(np.int64) + (1 << 20)  # 21 bits an axis: +-800 km at 0.8 m
    keys = (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]
    order = np.argsort(keys)
    return keys[order], pts[order]


def _build(pts: np.ndarray, neighbors: int, threads: int) -> tuple[Any, Any]:
    import small_gicp

    cloud = small_gicp.PointCloud(pts)
    tree = small_gicp.KdTree(cloud, num_threads=threads)
    small_gicp.estimate_covariances(cloud, tree, num_neighbors=neighbors, num_threads=threads)
    return cloud, tree


def build_target(vmap: Any, neighbors: int, threads: int, center: np.ndarray | None = None,
                 radius: float = float("inf")) -> tuple[Any, Any]:
    """small_gicp (cloud, tree) of the voxel means of ``vmap`` (those within ``radius`` of ``center``) with covariances
    from ``neighbors`` map neighbours: a full rebuild."""
    return _build(_crop(np.asarray(vmap.voxel_points(), dtype=np.float64)[:, :3], center, radius), neighbors, threads)
