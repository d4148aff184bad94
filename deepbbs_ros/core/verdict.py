"""The verdict on a registration: can its pose be trusted? (no ROS)

The verdict is a **probability that the pose is right** (within 1 degree / 0.3 m), calibrated on simulated pairs
of every sensor, mount and place (core/calibrated.py, fitted by ``scripts/calibrate_verdict.py``). Its inputs
(core/visibility.py) are shares that mean the same on any sensor: of the source's points under the pose, how many
land on the target's surfaces (within ``registration.verdict_dist``), how tightly (within a fifth of it of the
target's tangent planes), and how many sit where the target sensor saw through (in front of its returns in their
direction): a wrong pose puts surfaces into the target's free space, a right one only into space it could not see.
The points judged are a spread subset of the source's precision-stage voxels (:func:`spread_subset`, ground
included): on real scans they carry the simulated calibration better than the network's sampled points (far-spread
non-ground points, whose fit depends on the overlap more than on the pose). The result is ``valid`` when the
probability reaches ``registration.verdict_probability``.

The **score** is still reported: the **fitness** of the pose, the share of the source's sampled points (the
network's non-ground points, ``preprocess.num_points`` of them) within ``registration.verdict_dist`` of the target's
precision-stage cloud (the whole cropped scan on the ``registration.polish_voxel`` grid, ground included). The global
search ranks its starts by it.

Without the target's precision-stage cloud (``registration.polish: none``, or clouds registered as preprocessed
arrays) both are taken against the target's voxelised non-ground points, or its sampled points (the score within
``max(verdict_dist, inlier_dist)``): sparser references, for which the probability is not calibrated; there the
score decides, against ``registration.verdict_threshold``.

The good-start path (``register(..., good_start=True)``) judges the same points with the same coefficients, valid
from ``registration.good_start_probability``.

With ``registration.verdict_within`` "pair" (the registration's verdict; "all": the good start's too; "off", the
default) the probability is multiplied by P(the pose within the tolerance | its covariance) (core/within.py), where
that can change the decision (:func:`times_within`): the calibrated models ask whether the fit is consistent, and a
pose free to slide is consistent anywhere along the slide.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from deepbbs_ros.core import anchoring, calibrated, visibility
from deepbbs_ros.core.target_surface import spread_subset

if TYPE_CHECKING:
    from deepbbs_ros.core.polish_cloud import PolishCloud

__all__ = ["features", "fitness", "fitness_to_points", "good_start_points", "is_valid", "on_scene_grid", "probability",
           "spread_subset", "times_within"]


def good_start_points(pc: PolishCloud, rc: Any) -> np.ndarray:
    """The points the good start's verdict scores: a spread, order-independent subset of the cloud's GICP voxels
    (``registration.good_start_points``; :func:`spread_subset`)."""
    return visibility.spread_points(pc, rc.good_start_points, rc.polish_voxel or 0.5)  # kept on the cloud


def _moved(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]


def fitness(points: np.ndarray, target_tree, T: np.ndarray, dist: float, threads: int = 1) -> float:
    """Share of ``points`` (N, 3) (source frame, metres) within ``dist`` m of the target cloud whose
    ``small_gicp.KdTree`` is ``target_tree``, under ``T`` (4, 4) ``T_target_source``. 0 for no points."""
    if len(points) == 0 or target_tree is None:
        return 0.0
    return float(np.mean(anchoring.sq_dists(target_tree, _moved(points, T), threads) <= dist * dist))


def fitness_to_points(points: np.ndarray, target: np.ndarray, T: np.ndarray, dist: float) -> float:
    """:func:`fitness` against a plain target cloud (M, 3) (a k-d tree built here)."""
    from scipy.spatial import cKDTree

    if len(points) == 0 or len(target) == 0:
        return 0.0
    d, _ = cKDTree(np.asarray(target, dtype=np.float64)).query(_moved(points, T), k=1)
    return float(np.mean(d <= dist))


def probability(points: np.ndarray, T: np.ndarray, target, dist: float, model: str = "pair",
                threads: int = 1) -> float:
    """The calibrated probability (0..1) that ``T`` (4, 4) ``T_target_source`` is right, from ``points`` (N, 3)
    (source frame: the sampled points for the ``"pair"`` model, the spread voxel subset for ``"good_start"``)
    against ``target`` (its precision-stage cloud, or a plain (M, 3) cloud). 0 for no points."""
    if len(points) == 0:
        return 0.0
    return calibrated.probability(features(points, T, target, dist, model, threads), model)


def features(points: np.ndarray, T: np.ndarray, target, dist: float, model: str = "pair",
             threads: int = 1) -> np.ndarray:
    """The features (core/visibility.py ``FEATURES``) :func:`probability` reads with the ``model``: those it does not
    weigh left unmeasured (kept on a precision-stage ``target``: asked again, not measured again)."""
    anchor = calibrated.weighs(("anchored", "anchored_far"), model, floor=False)  # more searches, where they count
    view = calibrated.weighs(("in_view", "observable_rel"), model)  # the field of view, likewise
    # where only a bound on ``pinned`` reads ``anchored_far``: measured for a pose under it only
    bound = True if anchor else calibrated.anchored_below()
    return visibility.pose_features(points, T, target, dist, threads, bound, view)


def on_scene_grid(source, target, rc) -> tuple[np.ndarray, Any, float] | None:
    """What the good start judges a pose finished on the scans' scene-sized grids with
    (``registration.polish_voxel_angle``, core/polish.py :func:`~deepbbs_ros.core.polish.finish`): (a spread subset
    of the source's voxels on its finer grid, the target's finer cloud, ``registration.verdict_dist`` scaled with the
    finer of the two grids, as GICP's correspondence distance is); None where either precision-stage cloud
    ``source`` / ``target`` has no finer grid. Every distance the features read (and ``pinned``'s residual
    tolerance) shrinks with the grid: the same test at the scene's scale, where GICP's grid blends a narrow place's
    walls, floor and ceiling."""
    from deepbbs_ros.core.polish_cloud import finer_pair, grid_scale

    fine = finer_pair(source, target)
    if fine is None:
        return None
    sf, tf = fine
    dist = rc.verdict_dist * grid_scale(fine, rc.polish_voxel)
    return spread_subset(sf.points(), rc.good_start_points, sf.voxel), tf, dist


def times_within(prob: float, source, target, T: np.ndarray, rc, bar: float, verdict: str = "pair",
                 threads: int = 1) -> float:
    """``prob`` times P(the pose ``T`` (4, 4) within the tolerance | its covariance) (core/within.py; the precision
    stage's clouds ``source`` / ``target``) where ``registration.verdict_within`` names the ``verdict`` ("pair": the
    registration's; "all": the good start's too) and ``prob`` reaches ``bar`` (under it the product cannot reach it
    either: not computed); else ``prob``."""
    on = rc.verdict_within == "all" or rc.verdict_within == verdict
    if not on or not prob >= bar or source is None:
        return prob
    from deepbbs_ros.core import within

    return prob * within.within(source, target, T, rc, threads)


def is_valid(score: float, threshold: float) -> bool:
    """The decision: the score reaches the threshold (a NaN score is never valid)."""
    return bool(np.isfinite(score) and score >= threshold)
