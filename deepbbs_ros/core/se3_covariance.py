"""Pose covariances under SE(3) algebra (no ROS): composition, conjugation by a mounting, the adjoint, the pose error
they describe. The convention is core/covariance.py's (ROS order ``[dt, dtheta]``: the position error in the parent
frame and the rotation error as a left perturbation about the pose's own origin).
"""

from __future__ import annotations

import numpy as np


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
