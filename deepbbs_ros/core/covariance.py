"""Pose covariance of a GICP solution (no ROS import).

Convention (CONVENTIONS.md, ROS covariance order, what robot_localization and AMCL read): the covariance of
``T = T_target_source = (R, t)`` is that of ``delta = [dt (3), dtheta (3)]`` (x, y, z, rot x, rot y, rot z; m, rad)
with ``T_true = (exp(dtheta) R, t + dt)``: the position error in the target frame and the rotation error as a left
perturbation (target-frame axes, about the pose's own origin). For a pose at the origin it is the left perturbation
``T_true = exp(delta) T``; far from the origin it keeps the position variance the position's (the SE(3) left
perturbation would read a rotation about the map's origin).

small_gicp linearises its cost ``E = 1/2 sum_i r_i^T M_i r_i`` (``r_i = b_i - T a_i``, ``M_i = (C_b + R C_a R^T)^-1``
from the clouds' covariances) for a **right** perturbation ``T exp(xi)`` with ``xi = [rot (3), trans (3)]``: its
result carries that Hessian ``H`` (6 x 6, Gauss-Newton ``J^T M J``), the cost ``e`` and the inlier count ``n`` at
the last linearisation. Then:

1. reorder ``H`` to ``[trans, rot]`` and invert it;
2. scale by the residual variance of unit weight, ``s^2 = 2 e / (3 n - 6)`` (small_gicp's point covariances are
   normalised, eigenvalues (1e-3, 1, 1): only their shape is metric, so the scale has to come from the residuals);
3. move to the convention above: ``T exp([v, w]) = (exp(R w) R, t + R v)``, so ``Sigma = B Sigma_right B^T`` with
   ``B = diag(R, R)``;
4. inflate weak (degenerate) directions (:func:`calibrated`): along each eigen-direction of the translation block and
   of the rotation block of the information, the variance times ``(lambda_max / lambda) ** exponent`` (a corridor, a
   straight road with little beside it: along it GICP barely moves the pose and its error there is mostly where the
   start left it, not residual noise; a synthetic 4 m wide corridor has a ratio ``lambda / lambda_max`` of 2e-3, a
   simulated highway 1e-2 to 5e-2, a street 0.1 to 0.3);
5. multiply the translation block by ``factors[0]`` and the rotation block by ``factors[1]`` (``D Sigma D``):
   neighbouring voxels' residuals are not independent (the same surface, the same laser ring, the voxel grid's own
   discretisation, map and scan sampled from other places), so ``n`` overstates the independent measurements; each
   factor is the ratio of ``n`` to an effective sample size.

The constants (:data:`LOCALIZATION_FACTORS`, :data:`ODOMETRY_FACTORS` and the exponents) were fitted on simulated
drives only (``scripts/benchmarks/covariance.py --fit``: urban, suburban, highway and open-road scenes with HDL-64E
and VLP-16 sensors; the pooled mean NEES of each block made 3) and checked on real scans; docs/node.md has the
figures. The raw ``s^2 H^-1`` is far overconfident: on the simulated sets the median NEES of its localization poses
was 16 to 209 and of its odometry steps 380 to 16,000 (chi2(6)'s: 5.35).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["adjoint", "calibrated", "compose", "conjugated", "gicp_covariance", "gicp_hessian", "is_covariance",
           "pose_error", "scan_covariance", "skew"]

#: weak-direction exponent: the variance along an eigen-direction of a block of the information with ``lambda`` is
#: multiplied by ``(lambda_max / lambda) ** exponent`` (chosen, not fitted: 1 for the localization, where a corridor
#: needs it; 0 for the odometry, whose simulated drives' NEES spread more with it)
LOCALIZATION_WEAK_EXPONENT_CHOSEN = 1.0
ODOMETRY_WEAK_EXPONENT_CHOSEN = 0.0
LOCALIZATION_WEAK_EXPONENT = LOCALIZATION_WEAK_EXPONENT_CHOSEN
ODOMETRY_WEAK_EXPONENT = ODOMETRY_WEAK_EXPONENT_CHOSEN
#: (translation, rotation) ratio of n to the effective sample size of the residuals of the localization's GICP on a
#: map crop and of the odometry's VGICP on its local map (module docstring), fitted by ``scripts/benchmarks/
#: covariance.py --fit`` on simulated drives only (urban, suburban, highway, open road; HDL-64E and VLP-16): the
#: pooled mean NEES of each block made 3
LOCALIZATION_FACTORS = (7.614, 6.109)
ODOMETRY_FACTORS = (1089.1, 617.6)
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


def gicp_covariance(H: np.ndarray, e: float, num_inliers: int, T_target_source: np.ndarray, *,
                    factors: tuple[float, float] = (1.0, 1.0), weak_exponent: float = 0.0) -> np.ndarray | None:
    """(6, 6) covariance of ``T_target_source`` (the module's convention) from small_gicp's ``H``, ``e`` and
    ``num_inliers`` at the solution (module docstring, steps 1-5); None when they cannot give one (fewer than 7
    inliers, a singular or non-finite ``H``). ``factors``, ``weak_exponent``: see :func:`calibrated` (the defaults:
    the raw ``s^2 H^-1``)."""
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
    cov_right = s2 * (V / w) @ V.T
    R = np.asarray(T_target_source, dtype=np.float64)[:3, :3]
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = R
    return calibrated(B @ cov_right @ B.T, factors, weak_exponent)


def calibrated(cov: np.ndarray, factors: tuple[float, float], weak_exponent: float) -> np.ndarray:
    """The raw covariance ``s^2 H^-1`` (module convention) made honest: along each eigen-direction of the translation
    and of the rotation block of its information (eigenvalue ``lambda``, the block's largest ``lambda_max``) the
    variance times ``(lambda_max / lambda) ** weak_exponent``, then the translation block times ``factors[0]`` and the
    rotation block times ``factors[1]`` (correlations scaled along: ``D Sigma D``, positive definite as before)."""
    cov = 0.5 * (cov + cov.T)
    S = np.eye(6)
    if weak_exponent:
        info = np.linalg.inv(cov)
        for sl in (slice(0, 3), slice(3, 6)):
            w, V = np.linalg.eigh(0.5 * (info[sl, sl] + info[sl, sl].T))
            g = (w[-1] / np.maximum(w, w[-1] * 1e-12)) ** (0.5 * weak_exponent)
            S[sl, sl] = (V * g) @ V.T
    D = np.diag(np.sqrt([factors[0]] * 3 + [factors[1]] * 3)) @ S
    out = D @ cov @ D.T
    out = 0.5 * (out + out.T)
    out[np.diag_indices(6)] += VARIANCE_FLOOR
    return out


def compose(T_a: np.ndarray, cov_a: np.ndarray | None, T_b: np.ndarray, cov_b: np.ndarray | None) -> np.ndarray:
    """(6, 6) covariance of ``T_a @ T_b`` (first order, independent errors; the module's convention for each: ``cov_a``
    in ``T_a``'s parent frame, ``cov_b`` in ``T_a``'s child frame; None = exact).

    ``R' = exp(da) R_a exp(db) R_b = exp(da + R_a db) R`` and ``t' = t + dt_a + da x (R_a t_b) + R_a dt_b``."""
    Ta, Tb = np.asarray(T_a, dtype=np.float64), np.asarray(T_b, dtype=np.float64)
    out = np.zeros((6, 6))
    if cov_a is not None:
        Ja = np.eye(6)
        Ja[:3, 3:] = -skew(Ta[:3, :3] @ Tb[:3, 3])
        out += Ja @ np.asarray(cov_a, dtype=np.float64) @ Ja.T
    if cov_b is not None:
        Jb = np.zeros((6, 6))
        Jb[:3, :3] = Jb[3:, 3:] = Ta[:3, :3]
        out += Jb @ np.asarray(cov_b, dtype=np.float64) @ Jb.T
    return 0.5 * (out + out.T)


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


def is_covariance(cov: Any, max_diagonal: float = float("inf")) -> bool:
    """Whether ``cov`` is a finite, symmetric, positive definite (6, 6) matrix with every diagonal below
    ``max_diagonal``."""
    c = np.asarray(cov, dtype=np.float64) if cov is not None else None
    if c is None or c.shape != (6, 6) or not np.isfinite(c).all():
        return False
    if not np.allclose(c, c.T, rtol=1e-6, atol=1e-12):
        return False
    return bool(np.linalg.eigvalsh(c)[0] > 0 and np.all(np.diag(c) < max_diagonal))


def scan_covariance(source: Any, target: Any, T_map_target: np.ndarray, T_map_scan: np.ndarray, config: Any,
                    threads: int = 1) -> np.ndarray | None:
    """The covariance of ``T_map_scan`` (the module's convention, map frame) from the precision-stage clouds: the
    scan's ``source`` and a map crop's ``target`` (frame ``T_map_target``), linearised at the pose with the
    correspondence distance of the stage that gave it (``localization.refine_corr_dist`` when the refinement runs,
    else ``registration.polish_max_corr_dist``); None without clouds or when the GICP gives none."""
    from deepbbs_ros.core.polish import SMALL_GICP_TYPE

    rc, lc = config.registration, config.localization
    if source is None or target is None or rc.polish == "none":
        return None
    corr = lc.refine_corr_dist if lc.refine_corr_dist > 0 else rc.polish_max_corr_dist
    T_target_scan = np.linalg.solve(np.asarray(T_map_target, dtype=np.float64), np.asarray(T_map_scan, np.float64))
    try:
        H, e, n = gicp_hessian(source, target, T_target_scan, max_corr_dist=corr,
                               registration_type=SMALL_GICP_TYPE[rc.polish], threads=threads)
    except (RuntimeError, ValueError):  # small_gicp on a cloud without covariances
        return None
    return gicp_covariance(H, e, n, T_map_scan, factors=LOCALIZATION_FACTORS, weak_exponent=LOCALIZATION_WEAK_EXPONENT)
