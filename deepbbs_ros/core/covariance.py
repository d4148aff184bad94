"""Pose covariance of a GICP solution (no ROS import).

Convention (CONVENTIONS.md, ROS covariance order, what robot_localization and AMCL read): the covariance of
``T = T_target_source = (R, t)`` is that of ``delta = [dt (3), dtheta (3)]`` (x, y, z, rot x, rot y, rot z; m, rad)
with ``T_true = (exp(dtheta) R, t + dt)``: the position error in the target frame and the rotation error as a left
perturbation (target-frame axes, about the pose's own origin). For a pose at the origin it is the left perturbation
``T_true = exp(delta) T``; far from the origin it keeps the position variance the position's (the SE(3) left
perturbation would read a rotation about the map's origin).

small_gicp linearises its cost ``E = 1/2 sum_i r_i^T M_i r_i`` (``r_i = b_i - T a_i``, ``M_i = (C_b + R C_a R^T)^-1``
from the clouds' normalised covariances, eigenvalues (1e-3, 1, 1): a shape, not the residuals' variance) for a
**right** perturbation ``T exp(xi)``, ``xi = [rot (3), trans (3)]``. The estimate's covariance is the M-estimator's
"sandwich" ``H^-1 (sum_i g_i g_i^T) H^-1`` (``g_i = J_i^T M_i r_i``, ``H = sum J^T M J``), which needs no noise model;
but neighbouring points' errors are not independent (the same surface, laser ring and voxel grid, map and scan
sampled from other places), so the gradients are summed per cell of a grid of :data:`CLUSTER_CELL` m first and the
outer products taken of the cells' sums (the cluster-robust covariance, :func:`sandwich_covariance`): correlated
errors within a cell count once, as they move the pose. Then:

1. for few cells the outer products understate the spread: a cell that pins a direction pulls the solution towards
   its own error, so its residuals look smaller than its error is. The covariance is the leave-one-cell-out
   (jackknife) covariance, :func:`jackknife_meat`, whose ``(H - H_c)^-1`` is each cell's leverage (where leaving a
   cell out leaves a singular Hessian: ``H^-1 B H^-1`` times the small-sample factor ``G / (G - 6)`` for ``G`` cells);
   the localization's, from every pair, is then widened along each direction as Student's t with the direction's
   effective number of cells (:func:`student_widened`): an estimate from a few dozen cells is itself uncertain;
2. along a weak translation direction (a corridor, a straight road with little beside it) the start's uncertainty
   is added: there GICP's answer is where the start left it, not a measurement (localization: directions below
   :data:`WEAK_RATIO`, anywhere within the correspondence distance; odometry: the directions its own degeneracy
   check holds, core/degeneracy.py, with the motion model's deviations along them, :meth:`MotionFloor.weak_sigma`);
3. the odometry adds the sweep's model error (:class:`MotionFloor`): deskewing with the constant velocity leaves the
   motion it missed, and a scan lands half of it off: per axis of the scan, sqrt(2) / 2 of the root mean square of
   the recent deviations from the prediction (a step differences two scans) less the registration noise in them
   (which the GICP part counts), and per rotation axis at least that of
   the rotation the deskew missed within the sweep (twice the registered motion's deviation from the deskew's: a
   body's roll and pitch sway); the first motion, with no prediction to deviate from, the voxel map's quantisation
   (:func:`quantisation_floor`);
4. move to the convention above: ``T exp([v, w]) = (exp(R w) R, t + R v)``, ``Sigma = B Sigma_right B^T`` with
   ``B = diag(R, R)``.

No constant is fitted: the estimator, the cell and the floors are chosen from their meaning
(``scripts/benchmarks/covariance.py --fit`` prints the factor the simulated sets would still fit on top of them).
docs/node.md has the figures. The raw ``s^2 H^-1``
(:func:`gicp_covariance`) is far overconfident: on simulated drives its median NEES was 16 to 209 for the
localization and 380 to 16,000 for the odometry's steps (chi2(6)'s: 5.35).

This module holds the entry points (odometry, localization, a raw GICP solution); the cluster-robust machinery
(steps 1, 2 and 4) is in core/cluster_robust.py, the covariances' SE(3) algebra in core/se3_covariance.py.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.cluster_robust import (  # noqa: F401  (re-exported)
    _PERM,
    CLUSTER_CELL,
    MIN_CLUSTERS,
    MIN_EFFECTIVE_CELLS,
    VARIANCE_FLOOR,
    WEAK_RATIO,
    _add_weak,
    _robust,
    _to_parent,
    clustered_terms,
    effective_cells,
    jackknife_meat,
    sandwich_covariance,
    student_widened,
)
from deepbbs_ros.core.gicp_pairs import cell_terms, matched_pairs, voxel_pairs  # noqa: F401  (re-exported)
from deepbbs_ros.core.motion_floor import MOTION_WINDOW, SWEEP_SPREAD, MotionFloor, floor_term, quantisation_floor
from deepbbs_ros.core.se3_covariance import adjoint, compose, compose_jacobians, conjugated, pose_error, skew  # noqa: F401

__all__ = ["MOTION_WINDOW", "SWEEP_SPREAD", "MotionFloor", "adjoint", "clustered_terms", "compose",
           "compose_jacobians", "conjugated", "effective_cells", "floor_term", "gicp_covariance", "gicp_hessian",
           "gicp_part", "is_covariance", "jackknife_meat", "matched_pairs", "odometry_covariance", "pose_error",
           "quantisation_floor", "sandwich_covariance", "scan_covariance", "skew", "student_widened", "voxel_pairs"]

#: the factor on the localization's cluster-robust covariance: none (the leave-one-cell-out covariance,
#: :func:`jackknife_meat`, covers what the residuals of few cells understate; ``scripts/benchmarks/covariance.py
#: --fit`` prints the factor the simulated sets would still fit on top of it)
LOCALIZATION_INFLATION = 1.0
#: the odometry's: none (its floor, :data:`SWEEP_SPREAD`, is not fitted either)
ODOMETRY_INFLATION = 1.0
#: the odometry's covariance pairs every k-th point of a larger scan (its cost: the floor dominates, and on simulated
#: drives 2,000 points moved the mean NEES by under 6 %; every pair, with or without the t, brought no step set inside
#: and cost 2.6 to 3.9 times as much)
ODOMETRY_MAX_POINTS = 2000
#: the localization's pairs: every point (0), as the pose is from every point (pairs of every k-th point give the
#: covariance of that thinner estimate: on simulated drives its mean NEES 1.1 to 3.1 times under every pair's)
LOCALIZATION_MAX_POINTS = 0
#: the localization's covariance widened as Student's t (:func:`student_widened`)
LOCALIZATION_STUDENT = True
#: the odometry's step covariance widened as Student's t (:func:`student_widened`): not (measured with every pair:
#: one simulated set fewer inside its band, KITTI 02's pose over; on 2,000 pairs the VLP-16 open road's steps over;
#: the sweep floor is most of a step's rotation variance; docs/node.md, "Tried, not shipped")
ODOMETRY_STUDENT = False


def gicp_covariance(H: np.ndarray, e: float, num_inliers: int, T_target_source: np.ndarray) -> np.ndarray | None:
    """The raw ``s^2 H^-1`` (module convention) from small_gicp's ``H``, ``e`` and ``num_inliers`` at the solution:
    what the residuals say when every pair is independent (far too confident: the module docstring); None when they
    cannot give one (fewer than 7 inliers, a singular or non-finite ``H``)."""
    H = np.asarray(H, dtype=np.float64)
    n = int(num_inliers)
    if H.shape != (6, 6) or not np.isfinite(H).all() or n < 7 or not np.isfinite(e):
        return None
    Hr = H[np.ix_(_PERM, _PERM)]
    Hr = 0.5 * (Hr + Hr.T)
    w, V = np.linalg.eigh(Hr)
    if w[-1] <= 0 or w[0] <= w[-1] * 1e-14:
        return None
    s2 = max(2.0 * float(e) / (3 * n - 6), 1e-12)
    R = np.asarray(T_target_source, dtype=np.float64)[:3, :3]
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = R
    out = B @ (s2 * (V / w) @ V.T) @ B.T
    out = 0.5 * (out + out.T)
    out[np.diag_indices(6)] += VARIANCE_FLOOR
    return out


def gicp_hessian(source: Any, target: Any, T_target_source: np.ndarray, *, max_corr_dist: float,
                 registration_type: str = "GICP", threads: int = 1) -> tuple[np.ndarray, float, int]:
    """small_gicp's ``(H, e, num_inliers)`` of ``source`` (a prepared small_gicp cloud, the source's frame) on
    ``target`` (a prepared cloud with a ``.cloud`` and ``.tree``, e.g. :class:`~deepbbs_ros.core.polish.PolishCloud`
    or a ``PolishView``) linearised at ``T_target_source`` (one Gauss-Newton iteration; its update is not used).
    A ``PolishView`` target is linearised on its base cloud at ``T_base @ T``: the right-perturbation Hessian is
    the same in any target frame."""
    import small_gicp

    T = np.asarray(T_target_source, dtype=np.float64)
    T_base = getattr(target, "T_base", None)
    tree = target.tree if T_base is None else target.tree.base
    start = T if T_base is None else np.asarray(T_base) @ T
    src = getattr(source, "cloud", source)
    res = small_gicp.align(target.cloud, src, tree, init_T_target_source=start, registration_type=registration_type,
                           max_correspondence_distance=float(max_corr_dist), num_threads=max(1, int(threads)),
                           max_iterations=1)
    return np.asarray(res.H, dtype=np.float64), float(res.error), int(res.num_inliers)


def is_covariance(cov: Any, max_diagonal: float = float("inf")) -> bool:
    """Whether ``cov`` is a finite, symmetric, positive definite (6, 6) matrix with every diagonal below
    ``max_diagonal``."""
    c = np.asarray(cov, dtype=np.float64) if cov is not None else None
    if c is None or c.shape != (6, 6) or not np.isfinite(c).all():
        return False
    if not np.allclose(c, c.T, rtol=1e-6, atol=1e-12):
        return False
    return bool(np.linalg.eigvalsh(c)[0] > 0 and np.all(np.diag(c) < max_diagonal))


def odometry_covariance(cloud: Any, vmap: Any, T_map_scan: np.ndarray, voxel_size: float,
                        floor: np.ndarray | None = None, weak: np.ndarray | None = None,
                        model: MotionFloor | None = None, weak_sigma: Any = None) -> np.ndarray | None:
    """The covariance of the odometry's ``T_map_scan`` (the module's convention, the local map's frame, the map held
    fixed) from its VGICP pairs on ``vmap`` (the local map before the scan joins it) at the pose, plus the model error
    ``floor`` (:class:`MotionFloor`: (6,) standard deviations, m and rad, along the scan's own axes x, y, z, roll,
    pitch, yaw); None (no deviation from a prediction measured yet: the first motion, a restart) gives the voxel
    map's quantisation instead (:func:`quantisation_floor`). ``weak``: (K, 3) unit directions, map frame, that the
    odometry's degeneracy check found weak (core/degeneracy.py ``analyse``, ``odometry.degenerate_ratio``; None: the
    Hessian's own test at :data:`WEAK_RATIO`): along each the pose is the prediction's, and its variance is what the
    motion model knows there (``model.weak_sigma``: the deviations along it, growing with the steps held in a row;
    without a model or a deviation, the whole deviation ``|floor[:3]| / SWEEP_SPREAD``, or a voxel); ``weak_sigma``:
    (K,) m per weak direction given by the caller (NaN: as above), e.g. the first motion's spread of places along its
    weakest direction (core/odometry_first.py)."""
    pairs = voxel_pairs(cloud, vmap, T_map_scan, voxel_size, ODOMETRY_MAX_POINTS)
    R = np.asarray(T_map_scan, dtype=np.float64)[:3, :3]
    first = floor is None
    if first:
        motion = float(np.linalg.norm(np.asarray(T_map_scan, dtype=np.float64)[:3, 3]))  # from the first scan
        floor, sigma = quantisation_floor(cloud, voxel_size, motion), voxel_size
    else:
        floor = np.asarray(floor, dtype=np.float64)
        sigma = float(np.linalg.norm(floor[:3])) / SWEEP_SPREAD
    weak_scan = None if weak is None else np.asarray(weak, dtype=np.float64).reshape(-1, 3) @ R
    if weak_scan is not None and len(weak_scan) and model is not None and not first:
        known = np.array([model.weak_sigma(d) for d in weak_scan])
        sigma = np.where(np.isfinite(known), known, sigma)
    if weak_scan is not None and weak_sigma is not None:
        given = np.asarray(weak_sigma, dtype=np.float64).reshape(-1)
        sigma = np.where(np.isfinite(given), given, np.broadcast_to(sigma, given.shape))
    robust = _robust(pairs, ODOMETRY_INFLATION, student=ODOMETRY_STUDENT)
    if robust is None:
        return None
    cov_right, H = robust
    if model is not None:  # the registration noise its next deviations from the prediction carry
        model.add_noise(np.diag(cov_right))
    _add_weak(cov_right, H, sigma, weak_scan)
    return _to_parent(cov_right, T_map_scan) + floor_term(floor, T_map_scan)


def gicp_part(cloud: Any, vmap: Any, T_map_scan: np.ndarray, voxel_size: float) -> np.ndarray | None:
    """(6, 6) the data's own uncertainty at ``T_map_scan`` that the odometry's hold weighs against the prediction's
    (core/odometry_hold.py; the module's convention, map frame): the cluster-robust covariance ``H^-1 B H^-1 G / (G -
    6)`` of the scan's VGICP pairs on ``vmap``, nothing added along weak directions and no floor; None without pairs.
    Not the leave-one-cell-out form the published covariance takes (:func:`jackknife_meat`): that one is wider where
    few cells pin a direction, which is where the hold decides, and there it held steps the data had right (a
    simulated VLP-16 highway, ``scripts/benchmarks/odometry.py --seed 11 --rigs highway:vlp16:car --rig-frames 40``:
    ATE 0.872 m with it, 0.145 m without)."""
    pairs = voxel_pairs(cloud, vmap, T_map_scan, voxel_size, ODOMETRY_MAX_POINTS)
    return sandwich_covariance(pairs, T_map_scan, ODOMETRY_INFLATION, weak=np.zeros((0, 3)), jackknife=False,
                               student=ODOMETRY_STUDENT)


def scan_covariance(source: Any, target: Any, T_map_target: np.ndarray, T_map_scan: np.ndarray, config: Any,
                    threads: int = 1) -> np.ndarray | None:
    """The covariance of ``T_map_scan`` (the module's convention, map frame) from the precision-stage clouds: the
    scan's ``source`` and a map crop's ``target`` (frame ``T_map_target``), paired at the pose with the
    correspondence distance of the stage that gave it (``localization.refine_corr_dist`` when the refinement runs,
    else ``registration.polish_max_corr_dist``); None without clouds or pairs."""
    rc, lc = config.registration, config.localization
    if source is None or target is None or rc.polish == "none":
        return None
    corr = lc.refine_corr_dist if lc.refine_corr_dist > 0 else rc.polish_max_corr_dist
    T_target_scan = np.linalg.solve(np.asarray(T_map_target, dtype=np.float64), np.asarray(T_map_scan, np.float64))
    try:
        pairs = matched_pairs(source, target, T_target_scan, corr, threads, LOCALIZATION_MAX_POINTS)
    except (RuntimeError, ValueError, IndexError):  # a cloud without covariances
        return None
    # along a weak direction the answer is anywhere GICP's reach (``corr``) left it: uniform, corr / sqrt(3)
    return sandwich_covariance(pairs, T_map_scan, LOCALIZATION_INFLATION, weak_sigma=corr / 3.0 ** 0.5,
                               student=LOCALIZATION_STUDENT)
