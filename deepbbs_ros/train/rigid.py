"""Rigid-motion helpers for the training pairs (no ROS): (4, 4) float64 transforms ``T_target_source`` (p_target =
R p_source + t, CONVENTIONS.md), built, inverted, applied to (N, 3) points, and drawn at random."""

from __future__ import annotations

import numpy as np


def yaw_matrix(yaw: float) -> np.ndarray:
    """(3, 3) float64 rotation by ``yaw`` radians about z."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) transform."""
    R, t = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ t)


def transform(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``points @ R.T + t`` for (N, 3) points and a (4, 4) transform, same dtype as ``points``."""
    return (points @ T[:3, :3].T.astype(points.dtype) + T[:3, 3].astype(points.dtype)).astype(points.dtype)


def random_motion(rng: np.random.Generator, yaw_max_deg: float, trans_max: float, small_tilt_deg: float = 1.0,
                  ) -> np.ndarray:
    """A random rigid motion: yaw uniform in +-yaw_max_deg, small roll/pitch, translation uniform in a
    disc of radius ``trans_max`` (horizontal) with a small vertical part. (4, 4) float64."""
    yaw = np.deg2rad(rng.uniform(-yaw_max_deg, yaw_max_deg))
    roll, pitch = np.deg2rad(rng.uniform(-small_tilt_deg, small_tilt_deg, size=2))
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    R = yaw_matrix(yaw) @ Ry @ Rx
    r = trans_max * np.sqrt(rng.random())
    phi = rng.uniform(0, 2 * np.pi)
    t = np.array([r * np.cos(phi), r * np.sin(phi), rng.uniform(-0.1, 0.1) * min(trans_max, 1.0)])
    return make_T(R, t)
