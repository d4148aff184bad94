"""Preprocessing step 1: finite points inside the range crop, outside the self-filter box (no ROS import)."""

from __future__ import annotations

import numpy as np

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.core.points import as_xyz


def crop_range(points: np.ndarray, min_range: float, max_range: float) -> np.ndarray:
    """Mask of finite points with ``min_range <= ||p|| <= max_range``.

    Args:
        points: (N, 3) float xyz, metres; NaN/Inf rows are allowed (and never kept).
        min_range, max_range: metres, Euclidean distance from the sensor origin.

    Returns:
        (N,) bool mask.
    """
    pts = as_xyz(points, "preprocess")
    with np.errstate(invalid="ignore", over="ignore"):
        r2 = np.einsum("ij,ij->i", pts, pts)
    # NaN compares False; Inf gives r2 = inf > max_range**2.
    return (r2 >= min_range * min_range) & (r2 <= max_range * max_range)


def crop_mask(points: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """(N,) bool mask of the points of ``points`` (N, 3) that step 1 keeps: :func:`crop_range` with the config's
    ranges, and outside ``cfg.self_filter_box`` ``[xmin, xmax, ymin, ymax, zmin, zmax]`` (sensor frame) when set."""
    keep = crop_range(points, cfg.min_range, cfg.max_range)
    box = cfg.self_filter_box
    if len(box) == 6:
        pts = as_xyz(points, "preprocess")
        inside = np.ones(len(pts), dtype=bool)
        for axis in range(3):
            inside &= (pts[:, axis] >= box[2 * axis]) & (pts[:, axis] <= box[2 * axis + 1])
        keep &= ~inside
    return keep
