"""Preprocessing steps 3 to 5: the voxel grid, its canonical order, farthest-point sampling, the dense subset.

No ROS import.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.errors import RegistrationError


def voxel_downsample(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """One point per occupied voxel: the centroid of the points in it.

    Voxels are the cubes ``floor(p / voxel_size)``. The output is ordered by voxel key, hence
    deterministic for a given input set.

    Args:
        points: (N, 3) finite xyz, metres.
        voxel_size: edge length in metres; ``<= 0`` returns the input unchanged (as float32).

    Returns:
        (M, 3) float32 centroids, M = number of occupied voxels.
    """
    pts = as_xyz(points, "preprocess")
    if voxel_size <= 0 or len(pts) == 0:
        return pts
    # Pack the integer voxel coordinates into one int64 key, 21 bits per axis (no per-axis
    # reductions: those are slow on (N, 3) arrays).
    # int32 keys (10 bits per axis, faster to sort) when the cloud spans fewer than 1024 voxels.
    ijk = np.floor(pts * np.float32(1.0 / voxel_size))
    lo, hi = float(ijk.min()), float(ijk.max())
    if hi - lo >= 1 << 21:
        raise RegistrationError(
            f"voxel_downsample: cloud spans more than 2**21 voxels of {voxel_size} m along an axis"
        )
    bits, dtype = (10, np.int32) if hi - lo < 1 << 10 else (21, np.int64)
    ijk = (ijk - np.float32(lo)).astype(dtype)
    keys = (ijk[:, 0] << (2 * bits)) | (ijk[:, 1] << bits) | ijk[:, 2]
    order = np.argsort(keys)
    keys = keys[order]
    starts = np.flatnonzero(np.concatenate(([True], keys[1:] != keys[:-1])))
    sums = np.add.reduceat(np.take(pts, order, axis=0).astype(np.float64), starts, axis=0)
    counts = np.diff(np.append(starts, len(keys)))
    return (sums / counts[:, None]).astype(np.float32)


def canonical_order(points: np.ndarray) -> np.ndarray:
    """(N, 3) points sorted by x, then y, then z: the same array for the same set of points in any order.

    small_gicp's multi-threaded voxel grid returns its centroids in a run-dependent order; the random
    candidate subset and the start point of the sampling are index based, so a grid is put in this order
    first to keep the sampled points (and the registration) reproducible. One argsort on x, a full
    lexsort only when two x are equal.
    """
    pts = np.asarray(points)
    order = np.argsort(pts[:, 0], kind="stable")
    xs = pts[order, 0]
    if len(xs) > 1 and (xs[1:] == xs[:-1]).any():
        order = np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0]))
    return np.take(pts, order, axis=0)


# -- step 4: farthest-point sampling --------------------------------------------------------------
def farthest_point_sample(points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Indices of ``n`` farthest-point samples (bucket FPS of ``fpsample``).

    Deterministic for a given input and seed: the seed picks the start index. When the cloud has
    fewer than ``n`` points, the FPS order of all of them is repeated cyclically (each point appears
    ``floor(n / m)`` or ``ceil(n / m)`` times) so that the output always has ``n`` entries.

    Args:
        points: (M, 3) finite xyz, metres, M >= 1.
        n: number of samples, >= 1.
        seed: start-point seed.

    Returns:
        (n,) int64 indices into ``points``.
    """
    pts = as_xyz(points, "preprocess")
    m = len(pts)
    if m == 0:
        raise RegistrationError("farthest_point_sample: empty point cloud")
    if n < 1:
        raise RegistrationError(f"farthest_point_sample: n must be >= 1, got {n}")
    k = min(n, m)
    start = int(np.random.default_rng(seed).integers(m))
    if m < 16:  # bucket FPS needs 2**h <= m; a plain FPS on a handful of points is instant
        idx = _fps_exact(pts, k, start)
    else:
        import fpsample

        # Tree height after the fpsample paper: bucket size 2**h, larger clouds want deeper trees.
        # (measured on LiDAR voxel clouds: h = 5 is fastest for 4k-8k points).
        h = int(np.clip(int(np.log2(m)) - 7, 3, 9))
        idx = fpsample.bucket_fps_kdline_sampling(pts, k, h, start_idx=start).astype(np.int64)
    if k < n:
        idx = np.resize(idx, n)  # cyclic repetition of the full FPS order
    return idx


def dense_subsample(points: np.ndarray, max_points: int, seed: int = 0) -> np.ndarray:
    """At most ``max_points`` of ``points`` as a seeded uniform random subset (order kept).

    Used on voxel centroids, which are already evenly spread: a random subset keeps that evenness at
    a fraction of the cost of farthest-point sampling.

    Args:
        points: (K, 3) float32 xyz, metres.
        max_points: cap; ``<= 0`` or ``>= K`` returns ``points`` unchanged.
        seed: subset seed.

    Returns:
        (min(K, max_points), 3) float32.
    """
    if max_points <= 0 or len(points) <= max_points:
        return points
    sub = np.random.default_rng([seed, 5150]).choice(len(points), max_points, replace=False)
    return np.take(points, np.sort(sub), axis=0)


def _fps_exact(pts: np.ndarray, k: int, start: int) -> np.ndarray:
    """Textbook O(k M) farthest-point sampling (used for tiny clouds)."""
    idx = np.empty(k, dtype=np.int64)
    idx[0] = start
    dist = np.sum((pts - pts[start]) ** 2, axis=1)
    for i in range(1, k):
        idx[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.sum((pts - pts[idx[i]]) ** 2, axis=1))
    return idx
