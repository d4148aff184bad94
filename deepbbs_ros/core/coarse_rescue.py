"""The good start's second try: GICP coarse to fine from the vouched start (no ROS).

``register(..., good_start=True)`` first runs GICP from the start on the precision-stage clouds. When that does not
converge within ``registration.good_start_max_iters``, or moves the start further than ``good_start_max_trans`` /
``good_start_max_rot_deg``, the start is often still good but outside GICP's fine basin (about its correspondence
distance): scans a few metres apart with no motion prediction (a car at 2 Hz, pairs a few scans apart), a handheld
sensor turned 15-20 degrees between keyframes. Before the full pipeline (the network, perhaps the any-start search:
5-30 times GICP's price) the odometry's first-motion pyramid (core/first_motion.py) runs on the two precision-stage
clouds' voxels, coarse to fine, then GICP at full resolution from where it ended.

The pyramid reaches further than the fine basin, into wrong basins too (a facade repeated along a road), so its
answer is held to more than the first try's: it must stay within ``REACH`` times the good start's limits of the
start, and the verdict must be sure of it (``registration.verdict_sure``, the bar at which the global search stops).
Otherwise the full pipeline runs, as before.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.first_motion import coarse_start
from deepbbs_ros.core.start_gicp import good_start_gicp

__all__ = ["DENSE", "REACH", "VOXEL_FACTORS", "coarse_then_fine", "moved", "pyramid"]

#: the rescue's answer stays within this many times registration.good_start_max_trans / good_start_max_rot_deg: how far
#: a vouched start may plausibly be off, not GICP's basin, which reaches further than the scan's range suggests (GICP
#: from the start lands right, the verdict sure, 11-24 degrees and 4.6 m away on real scans whose median range puts
#: polish_max_corr_dist at 4.6-9.5 degrees of turn)
REACH = 2.0
#: the pyramid's base voxel in multiples of registration.polish_voxel (its levels: grids of 2x and 1x the base): for
#: clouds of fewer than DENSE voxels (a Livox frame, a 16-beam scan) and for denser ones, where the finer base costs
#: more than the fine GICP it saves (measured on KITTI: 1 m grids ~2x the time of 2 m grids, the same answers)
VOXEL_FACTORS = (2.0, 4.0)
DENSE = 5000


def moved(T_init: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """(m, deg) between two poses (4, 4)."""
    d = np.linalg.inv(T_init) @ T
    cos = np.clip((np.trace(d[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(d[:3, 3])), float(np.degrees(np.arccos(cos)))


def coarse_then_fine(src_pc: Any, tgt_pc: Any, T_init: np.ndarray, rc: Any, threads: int) -> tuple[Any, str]:
    """GICP on the pyramid from ``T_init`` (4, 4), then the good start's GICP from where it ended, on the
    precision-stage clouds ``src_pc`` / ``tgt_pc`` (``core.polish.PolishCloud``). -> (the :func:`core.polish.polish`
    result, "" when it is within the rescue's reach of ``T_init``, else why not: then it must not be taken)."""
    pol = good_start_gicp(src_pc, tgt_pc, pyramid(src_pc, tgt_pc, T_init, rc, threads), rc)
    if not pol.applied:
        return pol, pol.reason.replace("polish_max_", "registration.good_start_max_")
    trans, rot = moved(T_init, pol.T_target_source)
    if trans > REACH * rc.good_start_max_trans or rot > REACH * rc.good_start_max_rot_deg:
        return pol, f"moved {trans:.2f} m / {rot:.1f} deg, beyond {REACH:g}x the good start's limits"
    return pol, ""


def pyramid(src_pc: Any, tgt_pc: Any, T_init: np.ndarray, rc: Any, threads: int) -> np.ndarray:
    """GICP on the pyramid of the precision-stage clouds' voxels (core/first_motion.py, base voxel
    :data:`VOXEL_FACTORS` times ``registration.polish_voxel``) from ``T_init`` (4, 4) -> where it ended (4, 4): the
    start of a fine GICP (:func:`coarse_then_fine`; the global search's last try from the given start)."""
    n = min(src_pc.n_points, tgt_pc.n_points)
    voxel = VOXEL_FACTORS[n >= DENSE] * (rc.polish_voxel or 0.5)
    solve = 1 if rc.exact_gicp else threads  # the same answer on any machine, as the precision stage's
    return coarse_start(tgt_pc.points(), src_pc.points(), voxel, rc.polish_max_corr_dist, rc.polish_neighbors, solve,
                        np.asarray(T_init, np.float64))
