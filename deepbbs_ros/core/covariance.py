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
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.gicp_pairs import cell_terms, matched_pairs, voxel_pairs
from deepbbs_ros.core.motion_floor import MOTION_WINDOW, SWEEP_SPREAD, MotionFloor, floor_term, quantisation_floor

__all__ = ["MOTION_WINDOW", "SWEEP_SPREAD", "MotionFloor", "adjoint", "clustered_terms", "compose",
           "compose_jacobians", "conjugated", "effective_cells", "floor_term", "gicp_covariance", "gicp_hessian",
           "gicp_part", "is_covariance", "jackknife_meat", "matched_pairs", "odometry_covariance", "pose_error",
           "quantisation_floor", "sandwich_covariance", "scan_covariance", "skew", "student_widened", "voxel_pairs"]

#: m; the cells whose pairs' residual gradients are summed before their outer products (the correlation length of
#: GICP's residual errors: neighbouring points see the same surface, ring and voxel grid, and their errors move
#: together); halved (down to 1 m) until a scan has :data:`MIN_CLUSTERS` cells (a small room). Chosen, not fitted:
#: on simulated HDL-64E and VLP-16 drives the sets' mean NEES are closest to one another from 10 to 20 m
CLUSTER_CELL = 12.0
MIN_CLUSTERS = 24
#: a translation direction is weak (:func:`sandwich_covariance`) where the Hessian's eigenvalue along it is below
#: this share of the largest (a synthetic 4 m corridor: 2e-3 to 5e-3; a simulated highway 1e-2 to 5e-2)
WEAK_RATIO = 0.01
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
#: effective cells below which Student's t has no variance to speak of (:func:`student_widened`): the factor stops at
#: t_3's, 3 (under 2 % of the directions on simulated drives; 5 or 1,000 there left every set's count the same)
MIN_EFFECTIVE_CELLS = 3.0
#: variance floor, m^2 / rad^2 on the diagonal: noise-free synthetic scenes must not give a singular covariance
VARIANCE_FLOOR = 1e-10

# [rot, trans] (small_gicp) -> [trans, rot] (ROS)
_PERM = np.array([3, 4, 5, 0, 1, 2])


def skew(v: np.ndarray) -> np.ndarray:
    """(3,) -> (3, 3) with ``skew(v) @ u == cross(v, u)``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of ``T`` for perturbations ordered ``[translation, rotation]``:
    ``T exp(xi) = exp(Ad(T) xi) T``."""
    R, t = T[:3, :3], T[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[:3, 3:] = skew(t) @ R
    Ad[3:, 3:] = R
    return Ad


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


def compose(T_a: np.ndarray, cov_a: np.ndarray | None, T_b: np.ndarray, cov_b: np.ndarray | None) -> np.ndarray:
    """(6, 6) covariance of ``T_a @ T_b`` (first order, independent errors; the module's convention for each: ``cov_a``
    in ``T_a``'s parent frame, ``cov_b`` in ``T_a``'s child frame; None = exact).

    ``R' = exp(da) R_a exp(db) R_b = exp(da + R_a db) R`` and ``t' = t + dt_a + da x (R_a t_b) + R_a dt_b``."""
    Ja, Jb = compose_jacobians(T_a, T_b)
    out = np.zeros((6, 6))
    if cov_a is not None:
        out += Ja @ np.asarray(cov_a, dtype=np.float64) @ Ja.T
    if cov_b is not None:
        out += Jb @ np.asarray(cov_b, dtype=np.float64) @ Jb.T
    return 0.5 * (out + out.T)


def compose_jacobians(T_a: np.ndarray, T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(6, 6) Jacobians of ``T_a @ T_b``'s error with respect to ``T_a``'s and ``T_b``'s (:func:`compose`: the error of
    ``T_a @ T_b`` is ``Ja e_a + Jb e_b``)."""
    Ta, Tb = np.asarray(T_a, dtype=np.float64), np.asarray(T_b, dtype=np.float64)
    Ja = np.eye(6)
    Ja[:3, 3:] = -skew(Ta[:3, :3] @ Tb[:3, 3])
    Jb = np.zeros((6, 6))
    Jb[:3, :3] = Jb[3:, 3:] = Ta[:3, :3]
    return Ja, Jb


def conjugated(T_base_sensor: np.ndarray, T_odom_sensor: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(6, 6) covariance of ``T_base_sensor @ T_odom_sensor @ inv(T_base_sensor)`` (the base's odometry, the mounting
    exact) from ``cov``, that of ``T_odom_sensor``."""
    T_bs = np.asarray(T_base_sensor, dtype=np.float64)
    T_sb = np.linalg.inv(T_bs)
    X = np.asarray(T_odom_sensor, dtype=np.float64) @ T_sb
    return compose(T_bs, None, X, compose(T_odom_sensor, cov, T_sb, None))


def pose_error(T_true: np.ndarray, T_est: np.ndarray) -> np.ndarray:
    """(6,) ``[dt, dtheta]`` with ``T_true = (exp(dtheta) R_est, t_est + dt)``: the error the covariances describe."""
    from scipy.spatial.transform import Rotation

    Tt, Te = np.asarray(T_true, dtype=np.float64), np.asarray(T_est, dtype=np.float64)
    return np.concatenate([Tt[:3, 3] - Te[:3, 3], Rotation.from_matrix(Tt[:3, :3] @ Te[:3, :3].T).as_rotvec()])


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


def sandwich_covariance(pairs: tuple[np.ndarray, ...] | None, T_out: np.ndarray, inflation: float,
                        cell: float | None = None, weak_sigma: Any = 0.0,
                        weak: np.ndarray | None = None, jackknife: bool = True,
                        student: bool = False) -> np.ndarray | None:
    """(6, 6) covariance (the module's convention, axes of ``T_out``'s parent) of the GICP solution whose matched
    pairs are ``pairs`` (:func:`matched_pairs`, :func:`voxel_pairs`): ``inflation`` times the leave-one-cell-out
    covariance (:func:`jackknife_meat`; ``jackknife=False``: ``H^-1 B H^-1 * G / (G - 6)``) of the pairs'
    (:func:`cell_terms`) on ``cell``-m cells, :data:`CLUSTER_CELL` halved down to 1 m until there are
    :data:`MIN_CLUSTERS` of them; ``G`` the cells); along each weak translation direction (an eigen-direction of
    the Hessian's translation block below :data:`WEAK_RATIO` of its largest: a corridor, a straight road with little
    beside it) the variance grows by ``weak_sigma ** 2`` (m^2: the start's own uncertainty, where the answer along it
    is where the start left it; ``weak``: (K, 3) unit directions in the scan's frame found weak by the caller, the
    odometry's degeneracy check, instead of that test, with ``weak_sigma`` one value or (K,) per direction).
    ``student``: each direction widened as Student's t with its effective number of cells (:func:`student_widened`).
    None without pairs or with a singular Hessian."""
    robust = _robust(pairs, inflation, cell, jackknife, student)
    if robust is None:
        return None
    cov_right, H = robust
    _add_weak(cov_right, H, weak_sigma, weak)
    return _to_parent(cov_right, T_out)


def _robust(pairs: tuple[np.ndarray, ...] | None, inflation: float, cell: float | None = None,
            jackknife: bool = True, student: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """The cluster-robust covariance of :func:`sandwich_covariance` in the scan's axes, ROS order, nothing added
    along weak directions, and small_gicp's Hessian ``H`` (6, 6, ``[rot, trans]``); None without pairs or with a
    singular Hessian. ``jackknife``: :func:`jackknife_meat`'s instead of ``G / (G - 6) * H^-1 B H^-1``; ``student``:
    :func:`student_widened`."""
    if pairs is None:
        return None
    H, Gc, Hc = clustered_terms(pairs, cell)
    G = len(Gc)
    w, V = np.linalg.eigh(H)
    if G <= 6 or not np.isfinite(w).all() or w[-1] <= 0 or w[0] <= w[-1] * 1e-14:
        return None
    cov = jackknife_meat(H, Gc, Hc) if jackknife else None
    left_out = cov is not None
    if cov is None:
        Hi = (V / w) @ V.T
        cov = G / (G - 6) * (Hi @ (Gc.T @ Gc) @ Hi)
    if student:
        cov = student_widened(cov, H, Hc, left_out)
    return (inflation * cov)[np.ix_(_PERM, _PERM)], H


def clustered_terms(pairs: tuple[np.ndarray, ...], cell: float | None = None) -> tuple[np.ndarray, np.ndarray,
                                                                                       np.ndarray]:
    """small_gicp's Hessian ``H`` (6, 6, ``[rot, trans]``, symmetrised) of the GICP ``pairs`` and each cell's gradient
    ``Gc`` (G, 6) and Hessian ``Hc`` (G, 6, 6) (:func:`core.gicp_pairs.cell_terms`), the cells ``cell`` m
    (:data:`CLUSTER_CELL` when None), halved down to 1 m until there are :data:`MIN_CLUSTERS` of them."""
    a, Ca, b, Cb, T = pairs
    cell = float(cell or CLUSTER_CELL)
    H, Gc, Hc = cell_terms(a, Ca, b, Cb, T, cell)
    while len(Gc) < MIN_CLUSTERS and cell > 1.0:
        cell = max(1.0, cell / 2)
        H, Gc, Hc = cell_terms(a, Ca, b, Cb, T, cell)
    return 0.5 * (H + H.T), Gc, Hc


def jackknife_meat(H: np.ndarray, grads: np.ndarray, hessians: np.ndarray) -> np.ndarray | None:
    """(6, 6) the leave-one-cell-out (jackknife) covariance of the GICP solution, small_gicp's ``[rot, trans]``:
    ``(G - 1) / G * sum_c d_c d_c^T``, ``d_c = (H - H_c)^-1 g_c`` the pose's move when cell ``c`` is left out (one
    Newton step from the solution, where the gradients sum to zero), from the cells' gradients ``g_c`` (G, 6) and
    Hessians ``H_c`` (G, 6, 6) (:func:`~deepbbs_ros.core.gicp_pairs.cell_terms`). ``H^-1 B H^-1`` weighs each cell's
    gradient by the whole Hessian, which holds that cell's own pairs, and so is too small where few cells pin the
    pose (a cell that pins a direction pulls the solution towards its own error); the jackknife's ``(H - H_c)^-1``
    is that cell's leverage, so no factor needs fitting for it (CR3 in the cluster-robust literature). None where
    leaving a cell out leaves a singular Hessian (the caller keeps ``H^-1 B H^-1``)."""
    G = len(grads)
    w = np.linalg.eigvalsh(H)
    rest = H[None] - 0.5 * (hessians + hessians.transpose(0, 2, 1))
    try:
        d = np.linalg.solve(rest, grads[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        return None
    if not np.isfinite(d).all() or np.linalg.eigvalsh(rest)[:, 0].min() <= w[-1] * 1e-12:
        return None
    return (G - 1) / G * (d.T @ d)


def effective_cells(H: np.ndarray, hessians: np.ndarray, basis: np.ndarray, left_out: bool = True) -> np.ndarray:
    """(K,) how many cells' worth of information the cluster-robust variance along each column of ``basis`` (6, K;
    small_gicp's ``[rot, trans]``) rests on: Satterthwaite's ``(sum_c l_c)^2 / sum_c l_c^2`` with ``l_c`` the variance
    cell ``c``'s term adds along the direction when a cell's gradient varies as its share of the Hessian, ``H_c``
    (the errors GICP's cost weighs; the design's, not the residuals', so not itself noisy): ``w^T A_c H_c A_c^T w``,
    ``A_c = (H - H_c)^-1`` (``left_out``, :func:`jackknife_meat`) or ``H^-1``. G equal cells give G; one cell that
    pins the direction, about 1 (as Bell and McCaffrey's degrees of freedom for cluster-robust variances)."""
    Hc = 0.5 * (hessians + hessians.transpose(0, 2, 1))
    A = np.linalg.inv(H[None] - Hc) if left_out else np.broadcast_to(np.linalg.inv(H), Hc.shape)
    Y = np.matmul(A.transpose(0, 2, 1), basis)  # (G, 6, K): A_c^T w
    lam = np.einsum("cki,cki->ci", Y, Hc @ Y)  # (G, K): (A_c^T w)^T H_c (A_c^T w)
    return np.square(lam.sum(axis=0)) / np.maximum(np.square(lam).sum(axis=0), 1e-300)


def student_widened(cov: np.ndarray, H: np.ndarray, hessians: np.ndarray, left_out: bool = True) -> np.ndarray:
    """(6, 6) ``cov`` (a cluster-robust covariance, small_gicp's ``[rot, trans]``, rad and m) widened along each of
    its eigen-directions to Student's t's variance, ``nu / (nu - 2)`` (at most 3, :data:`MIN_EFFECTIVE_CELLS`), with
    ``nu`` the direction's effective number of cells (:func:`effective_cells`): the covariance is estimated from a few
    dozen cells, and with a variance estimated on ``nu`` degrees of freedom taken as exact, the error over its
    standard deviation is a t, whose square averages ``nu / (nu - 2)``, not 1: most where a direction rests on a few
    cells."""
    w, U = np.linalg.eigh(0.5 * (cov + cov.T))
    nu = np.maximum(effective_cells(H, hessians, U, left_out), MIN_EFFECTIVE_CELLS)
    return (U * (w * nu / (nu - 2.0))) @ U.T


def _add_weak(cov_right: np.ndarray, H: np.ndarray, weak_sigma: Any, weak: np.ndarray | None) -> None:
    """:func:`sandwich_covariance`'s weak directions added to ``cov_right`` (scan axes, ROS order) in place."""
    if weak is None:
        wt, Vt = np.linalg.eigh(H[3:, 3:])
        weak = Vt[:, wt < WEAK_RATIO * wt[-1]].T  # (K, 3), the scan's frame
    weak = np.asarray(weak, dtype=np.float64).reshape(-1, 3)
    sig2 = np.square(np.broadcast_to(np.asarray(weak_sigma, dtype=np.float64), (len(weak),)))
    cov_right[:3, :3] += (weak.T * sig2) @ weak


def _to_parent(cov_right: np.ndarray, T_out: np.ndarray) -> np.ndarray:
    """``cov_right`` (scan axes, ROS order) in the axes of ``T_out``'s parent, symmetric, with the variance floor."""
    R = np.asarray(T_out, dtype=np.float64)[:3, :3]
    Bm = np.zeros((6, 6))
    Bm[:3, :3] = Bm[3:, 3:] = R
    out = Bm @ cov_right @ Bm.T
    out = 0.5 * (out + out.T)
    out[np.diag_indices(6)] += VARIANCE_FLOOR
    return out


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
