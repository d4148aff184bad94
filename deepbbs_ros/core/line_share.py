"""How well a scan's own neighbourhoods determine planes: the share of line-like neighbourhoods (no ROS import).

GICP weighs each scan point by the plane fitted through its nearest neighbours in its scan. On a sparse spinning
sensor (16 beams) those neighbours lie on one scan line: the neighbourhood is a line, its width across the line a
tiny fraction of its length, and the plane through it is undetermined (any plane containing the line fits). Such a
scan is better aligned against planes fitted through the map's voxel means (many sweeps: the surface's own plane,
core/map_target.py). ``line_share`` measures it: the share of sampled points whose ``k`` nearest neighbours have a
width (the second principal axis's standard deviation) below ``LINE_WIDTH`` times their length (the first's).
Measured (the odometry's ``voxel_size / 2`` grid, 20 neighbours, per scan): a simulated VLP-16 on a highway 0.04-0.34
(the median of a drive 0.12-0.29, with the place), in a corridor at most 0.05; every 32- to 128-beam and solid-state
sensor tried at most 0.07 (KITTI HDL-64E, nuScenes HDL-32E, Livox Avia, simulated OS0-64, OS1-32, XT-32, Helios-32,
Mid-360).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["EVERY", "LINE_WIDTH", "line_share"]

#: a neighbourhood narrower than this fraction of its length is a line: its plane is undetermined
LINE_WIDTH = 0.1
#: the odometry measures every this many scans (2-3 ms a measurement on 9,000 points; a sensor's share changes with the
#: place, over tens of scans)
EVERY = 4


def line_share(points: np.ndarray, tree: Any, k: int, sample: int = 500, threads: int = 1) -> float:
    """The share of line-like neighbourhoods among up to ``sample`` evenly spaced points of ``points`` (N, 3), with
    their ``k`` nearest neighbours from ``tree`` (a small_gicp ``KdTree`` of ``points``); nan for fewer than ``k``."""
    pts = np.asarray(points, dtype=np.float64)[:, :3]
    if len(pts) < k:
        return float("nan")
    query = np.ascontiguousarray(pts[:: max(1, len(pts) // sample)])
    idx, _ = tree.batch_knn_search(query, k, num_threads=threads)
    nb = pts[np.asarray(idx, dtype=np.intp)]  # (M, k, 3)
    X = nb - nb.mean(axis=1, keepdims=True)
    w = np.linalg.eigvalsh(np.matmul(X.transpose(0, 2, 1), X) / k)  # ascending
    return float(np.mean(np.maximum(w[:, 1], 0.0) < LINE_WIDTH**2 * np.maximum(w[:, 2], 1e-12)))
