"""The odometry's first motion along the direction its data pin least: starts along it, judged above the floor (no ROS
import).

On a straight road the first motion's alignment (core/first_motion.py's pyramid from identity, DeepBBS++'s start,
then the map) can settle at the wrong place along the road: the first scan's map and the second scan share the
sensor's own sampling pattern (the rings a spinning sensor draws on the ground, which move with it), and with little
beside the road to say otherwise the cost has a minimum near standstill. On the simulated HDL-64E highway the
alignment stopped at -0.13 m for a true 1.58 m, with 85 % of the points matched there against 84 % at the truth; the
constant-velocity model then carried that standstill for 17 scans. Without the floor's points (core/ground.py
``find_floor``) the truth matches the most points (87 % against 84 %; on the VLP-16 and OS1-64 highway 76 % against
70 % and 85 % against 73 %).

So the first motion also aligns the scans' points above the floor, from starts along the weakest translation
direction of the alignment's Hessian (every ``max_corr_dist``, GICP's reach, up to the distance a car at
:data:`TOP_SPEED` covers in the stamp interval, at most :data:`MAX_STARTS` each way), and a start wins over the
answer so far only with a share of matched points above the floor higher by ``odometry.fit_margin``. The places it
found whose share is within that margin of the best are the first motion's ambiguity along the direction: their
spread is the first motion's uncertainty there (:class:`AlongSearch` ``sigma``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["MAX_STARTS", "TOP_SPEED", "AlongSearch", "above_floor", "search_along"]

#: m/s: the fastest a carrier moves (a car at 144 km/h): the first motion's search reaches this times the stamp interval
TOP_SPEED = 40.0
#: the starts each way along the direction at most
MAX_STARTS = 6


@dataclass
class AlongSearch:
    """What the search along the weak direction found.

    pose: (4, 4) the best start's alignment above the floor (the answer so far when none won); won: a start won.
    direction: (3,) the searched unit direction (the first scan's frame); fit, fit_before: the share of matched points
    above the floor of the winner and of the answer so far; sigma: m, the root mean square distance along the
    direction of the places whose share lies within the margin of the best (0: one place).
    """

    pose: np.ndarray
    won: bool
    direction: np.ndarray
    fit: float
    fit_before: float
    sigma: float = 0.0


def above_floor(points: np.ndarray, preprocess: Any) -> np.ndarray:
    """The points (N, 3) more than half ``preprocess.ground_layer`` above the scan's floor (core/ground.py
    ``find_floor``); all of them where no floor is found (indoors on stairs, a sensor looking up)."""
    from deepbbs_ros.core.ground import find_floor

    pts = np.asarray(points, dtype=np.float64)
    plane = find_floor(pts, preprocess)
    if plane is None:
        return pts
    keep = pts @ np.asarray(plane[:3]) + float(plane[3]) > 0.5 * preprocess.ground_layer
    return pts[keep] if keep.sum() >= 100 else pts


def search_along(first: np.ndarray, scan: np.ndarray, pose: np.ndarray, direction: np.ndarray, reach: float,
                 voxel: float, corr: float, margin: float, neighbors: int, threads: int) -> AlongSearch:
    """Align ``scan`` (N, 3, above the floor) on ``first`` (M, 3, above the floor, the first scan's frame) from ``pose``
    (4, 4, the answer so far) moved along the unit ``direction`` (3,) by multiples of ``corr`` up to ``reach`` m each
    way (at most :data:`MAX_STARTS`), with the odometry's ``voxel`` and correspondence distance ``corr``."""
    import small_gicp

    d = np.asarray(direction, dtype=np.float64)
    d = d / max(float(np.linalg.norm(d)), 1e-12)
    tgt, _ = small_gicp.preprocess_points(np.ascontiguousarray(first), downsampling_resolution=0.5 * voxel,
                                          num_neighbors=neighbors, num_threads=threads)
    src, _ = small_gicp.preprocess_points(np.ascontiguousarray(scan), downsampling_resolution=0.5 * voxel,
                                          num_neighbors=neighbors, num_threads=threads)
    pose = np.asarray(pose, dtype=np.float64)
    if tgt.size() < 10 or src.size() < 10:
        return AlongSearch(pose, False, d, float("nan"), float("nan"))
    vmap = small_gicp.GaussianVoxelMap(voxel)
    vmap.insert(tgt)

    def align(T: np.ndarray) -> tuple[np.ndarray, float]:
        res = small_gicp.align(vmap, src, T, max_correspondence_distance=corr, num_threads=threads)
        return np.asarray(res.T_target_source, dtype=np.float64), res.num_inliers / max(1, src.size())

    here, fit0 = align(pose)
    n = int(min(MAX_STARTS, max(1, np.floor(reach / corr))))
    found = [(here, fit0)]
    for k in [s * i for i in range(1, n + 1) for s in (1, -1)]:
        start = here.copy()
        start[:3, 3] += k * corr * d
        T, fit = align(start)
        if all(abs(float(d @ (T[:3, 3] - U[:3, 3]))) > 0.5 * corr for U, _ in found):
            found.append((T, fit))
    best, fit_b = max(found, key=lambda x: x[1])
    won = fit_b > fit0 + margin
    chosen, fit_c = (best, fit_b) if won else (pose, fit0)
    near = [float(d @ (T[:3, 3] - chosen[:3, 3])) for T, f in found if f >= fit_b - margin]
    sigma = float(np.sqrt(np.mean(np.square(near)))) if near else 0.0
    return AlongSearch(best if won else pose, won, d, fit_c, fit0, sigma)
