"""The local map as a GICP target with covariances from the map's own neighbourhoods (``odometry.map_covariances``).

small_gicp's ``GaussianVoxelMap`` keeps, per voxel, the mean of the inserted points' covariances, and each of those was
fitted through a point's nearest neighbours in its own scan. On a sparse spinning sensor (16 beams) those neighbours
lie on one scan line: the second eigenvalue is about 0, the plane through them is undetermined and small_gicp's
regularisation picks an arbitrary normal, so the map's voxels average planes that point anywhere and the alignment
slides along the road (steps biased short). The map holds many sweeps: around a voxel mean its neighbours span the
surface, so a plane fitted through them has the surface's normal. ``MapTarget`` turns the map's voxel means into a
small_gicp point cloud with covariances from ``neighbors`` map neighbours (and its k-d tree), built once per map update
and aligned against with plain GICP.

No ROS import.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["MapTarget"]


class MapTarget:
    """The map's voxel means as a GICP target (small_gicp ``PointCloud`` with covariances and its ``KdTree``).

    Args:
        neighbors: map neighbours per covariance.
        threads: small_gicp threads.
        radius: m; only the voxel means this close to the first alignment's start of a map version are kept (the
            scan's reach: preprocess.max_range plus a margin; on a highway the map reaches 100 scans back).
    """

    def __init__(self, neighbors: int, threads: int, radius: float = float("inf")) -> None:
        self.neighbors = neighbors
        self.threads = threads
        self.radius = radius
        self._key: tuple[int, int] | None = None
        self._target: tuple[Any, Any] | None = None

    def get(self, vmap: Any, version: int, center: np.ndarray | None = None) -> tuple[Any, Any]:
        """(cloud, tree) of ``vmap``'s voxel means (map frame) within ``radius`` of ``center`` (3,), rebuilt when
        ``version`` (the caller's count of map updates) or the map object changed."""
        key = (id(vmap), int(version))
        if self._key != key or self._target is None:
            self._target = build_target(vmap, self.neighbors, self.threads, center, self.radius)
            self._key = key
        return self._target

    def align(self, vmap: Any, version: int, cloud: Any, init: np.ndarray, max_corr_dist: float,
              max_iters: int) -> Any:
        """GICP of ``cloud`` (sensor frame) against the map target from ``init`` (4, 4): small_gicp's result."""
        import small_gicp

        target, tree = self.get(vmap, version, np.asarray(init)[:3, 3])
        return small_gicp.align(target, cloud, tree, init, registration_type="GICP",
                                max_correspondence_distance=max_corr_dist, num_threads=self.threads,
                                max_iterations=max_iters)


def build_target(vmap: Any, neighbors: int, threads: int, center: np.ndarray | None = None,
                 radius: float = float("inf")) -> tuple[Any, Any]:
    """small_gicp (cloud, tree) of the voxel means of ``vmap`` (those within ``radius`` of ``center``) with covariances
    from ``neighbors`` map neighbours."""
    import small_gicp

    pts = np.asarray(vmap.voxel_points(), dtype=np.float64)[:, :3]
    if center is not None and np.isfinite(radius):
        pts = pts[np.linalg.norm(pts - center, axis=1) <= radius]
    pts = np.ascontiguousarray(pts)
    cloud = small_gicp.PointCloud(pts)
    tree = small_gicp.KdTree(cloud, num_threads=threads)
    small_gicp.estimate_covariances(cloud, tree, num_neighbors=neighbors, num_threads=threads)
    return cloud, tree
