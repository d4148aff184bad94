"""The odometry's first motion: GICP coarse to fine from identity (no ROS import).

The first motion has no prediction: GICP starts at identity, and its basin (about a map voxel, the correspondence
distance) is smaller than what a car moves in one period (1.5-2 m at 10 Hz on a highway, 1-4.5 m at 2 Hz). On a
straight road, whose scans slide along it, GICP then settles near identity, the constant-velocity model starts at
standstill and the map is built from scans placed metres short: the drive stays metres behind for tens of scans.
KISS-ICP's answer is a wide first threshold (2 m) that shrinks as its motion model learns; here the first motion
runs on a pyramid: the first scan's map with voxels and correspondence distances ``PYRAMID`` times the odometry's,
coarse to fine, each level starting where the coarser one ended; the odometry's own map alignment follows. On
scans that need no pyramid (small first motions) every level lands where plain GICP does.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PYRAMID", "coarse_start"]

#: the coarse levels, in multiples of the map voxel and of the correspondence distance (coarsest first)
PYRAMID = (4.0, 2.0)


def coarse_start(first: np.ndarray, scan: np.ndarray, voxel: float, max_corr_dist: float, neighbors: int,
                 threads: int, init: np.ndarray | None = None) -> np.ndarray:
    """``T_first_scan`` (4, 4) float64 of ``scan`` (N, 3) against ``first`` (M, 3) (both in their sensor frames, metres)
    after GICP on every ``PYRAMID`` level from ``init`` (identity by default): the start of the fine alignment."""
    import small_gicp

    T = np.eye(4) if init is None else np.asarray(init, dtype=np.float64)
    first, scan = (np.ascontiguousarray(a, dtype=np.float64) for a in (first, scan))
    for m in PYRAMID:
        grid = 0.5 * m * voxel
        tgt, _ = small_gicp.preprocess_points(first, downsampling_resolution=grid, num_neighbors=neighbors,
                                              num_threads=threads)
        src, _ = small_gicp.preprocess_points(scan, downsampling_resolution=grid, num_neighbors=neighbors,
                                              num_threads=threads)
        if tgt.size() < 10 or src.size() < 10:  # too coarse for this scan: the finer levels decide
            continue
        vmap = small_gicp.GaussianVoxelMap(m * voxel)
        vmap.insert(tgt)
        res = small_gicp.align(vmap, src, T, max_correspondence_distance=m * max_corr_dist, num_threads=threads)
        T = np.asarray(res.T_target_source, dtype=np.float64)
    return T
