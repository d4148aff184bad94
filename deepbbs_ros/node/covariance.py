"""Covariance and twist of a registration result, for ``nav_msgs/Odometry`` (no ROS import).

The localization's and the odometry's covariances come from their GICP's Hessian
(:mod:`deepbbs_ros.core.covariance`); this point-to-point one is pair mode's and the fallback.

The pose covariance is the least-squares covariance of point-to-point alignment evaluated at the solution
(as ICP covariance estimates do): with the aligned source points ``q_i = R p_i + t``, their
nearest target points at distance ``d_i``, the inlier set ``I`` (``d_i <= tau``), weights ``w_i`` (the
network's best-buddy weights gamma when given, normalised to mean 1) and the left perturbation
``delta = [dt (3), dtheta (3)]`` (ROS covariance order x, y, z, rot x, rot y, rot z),

    J_i = [I_3, -[q_i]_x]          (3 x 6),   H = sum_{i in I} w_i J_i^T J_i,
    sigma^2 = sum w_i d_i^2 / (3 sum w_i),   Sigma = sigma^2 H^{-1} / inlier_fraction,

inflated 100x when the registration did not converge. It therefore grows with the residuals, with
partial overlap and with degenerate geometry (a corridor leaves one direction weakly constrained).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepbbs_ros.core.covariance import adjoint, skew

__all__ = ["AlignmentQuality", "adjoint", "alignment_quality", "skew", "twist_covariance", "twist_from_delta"]

_SIGMA2_FLOOR = 1e-6  # m^2; noise-free synthetic data must not give a singular covariance
_NOT_CONVERGED_INFLATION = 100.0


@dataclass
class AlignmentQuality:
    """Residual statistics and covariance of one registration.

    Attributes:
        covariance: (6, 6) float64 pose covariance, order (x, y, z, rot x, rot y, rot z), m^2 / rad^2.
        inlier_fraction: fraction of aligned source points within ``tau`` of the target.
        rmse: root mean square nearest-neighbour distance of the inliers, metres.
        tau: inlier threshold used, metres.
    """

    covariance: np.ndarray
    inlier_fraction: float
    rmse: float
    tau: float


def alignment_quality(
    source: np.ndarray,
    target: np.ndarray,
    T_target_source: np.ndarray,
    *,
    weights: np.ndarray | None = None,
    converged: bool = True,
    tau: float | None = None,
) -> AlignmentQuality:
    """Covariance of ``T_target_source`` from the residuals of the aligned clouds.

    Args:
        source: (N, 3) float32/64 source points (the preprocessed points that were registered).
        target: (M, 3) target points.
        T_target_source: (4, 4) float64 registration result.
        weights: (N,) optional per-source-point weights (gamma); other lengths are ignored.
        converged: the registration's own verdict; False inflates the covariance.
        tau: inlier distance, metres; default ``max(3 * median distance, 0.05)``.
    """
    from scipy.spatial import cKDTree

    src = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    tgt = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    T = np.asarray(T_target_source, dtype=np.float64)
    q = src @ T[:3, :3].T + T[:3, 3]
    d, _ = cKDTree(tgt).query(q, k=1)
    if tau is None:
        tau = max(3.0 * float(np.median(d)), 0.05)
    inl = d <= tau
    n_in = int(inl.sum())
    frac = n_in / max(len(d), 1)
    if n_in < 3:
        return AlignmentQuality(np.eye(6) * 1e6, frac, float("inf"), float(tau))
    w = np.ones(n_in)
    if weights is not None and len(weights) == len(src):
        w = np.clip(np.asarray(weights, dtype=np.float64)[inl], 0.0, None)
        w = w / w.mean() if w.sum() > 0 else np.ones(n_in)
    qi, di = q[inl], d[inl]
    sigma2 = max(float(np.sum(w * di**2) / (3.0 * w.sum())), _SIGMA2_FLOOR)
    # H = sum w J^T J with J = [I, -[q]x]
    H = np.zeros((6, 6))
    H[:3, :3] = np.eye(3) * w.sum()
    S = np.einsum("i,ij->j", w, qi)
    H[:3, 3:] = -skew(S)
    H[3:, :3] = skew(S)
    qq = np.einsum("i,ij,ik->jk", w, qi, qi)
    H[3:, 3:] = np.trace(qq) * np.eye(3) - qq  # sum w [q]x^T [q]x
    cov = sigma2 * np.linalg.pinv(H) / max(frac, 1e-3)
    if not converged:
        cov *= _NOT_CONVERGED_INFLATION
    cov = 0.5 * (cov + cov.T)
    rmse = float(np.sqrt(np.sum(w * di**2) / w.sum()))
    return AlignmentQuality(cov, frac, rmse, float(tau))


def twist_from_delta(T_prev_curr: np.ndarray, dt: float) -> np.ndarray:
    """(6,) twist ``[vx, vy, vz, wx, wy, wz]`` in the current frame from the motion over ``dt`` s."""
    from scipy.spatial.transform import Rotation

    R, t = T_prev_curr[:3, :3], T_prev_curr[:3, 3]
    v = R.T @ t / dt
    w = Rotation.from_matrix(R).as_rotvec() / dt
    return np.concatenate([v, w])


def twist_covariance(T_prev_curr: np.ndarray, cov_prev_curr: np.ndarray, dt: float) -> np.ndarray:
    """(6, 6) covariance of :func:`twist_from_delta` from the covariance of ``T_prev_curr``.

    ``cov_prev_curr`` is the registration covariance of ``T = (R, t)`` for a left perturbation in the
    previous frame, ``T' = exp(delta) T`` with ``delta = [dt_ (3), dtheta (3)]`` (as
    :func:`alignment_quality` gives it). To first order the twist ``[R^T t, log(R)] / dt`` moves by
    ``[R^T dt_, J_l^-1(phi) dtheta] / dt`` (``phi = log(R)``, ``J_l`` the left Jacobian of SO(3); the
    translation part does not depend on ``dtheta``), so ``Sigma_twist = M Sigma M^T`` with
    ``M = diag(R^T, J_l^-1(phi)) / dt``.
    """
    from scipy.spatial.transform import Rotation

    R = np.asarray(T_prev_curr, dtype=np.float64)[:3, :3]
    phi = Rotation.from_matrix(R).as_rotvec()
    th = float(np.linalg.norm(phi))
    P = skew(phi)
    if th < 1e-6:
        c = 1.0 / 12.0
    else:
        c = 1.0 / th**2 - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th))
    M = np.zeros((6, 6))
    M[:3, :3] = R.T
    M[3:, 3:] = np.eye(3) - 0.5 * P + c * P @ P
    M /= dt
    cov = M @ np.asarray(cov_prev_curr, dtype=np.float64) @ M.T
    return 0.5 * (cov + cov.T)
