"""Rotations of the transforms: quaternion (x, y, z, w) <-> (3, 3) matrix, the check of a (4, 4) rigid
transform, its inverse (conventions: :mod:`msg_adapters.transforms`). numpy only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.errors import TransformFormatError

_ORTHO_TOL = 1e-4  # max |R^T R - I| accepted before a matrix is refused as "not a rotation"


def quaternion_to_matrix(q: Any) -> np.ndarray:
    """Quaternion (x, y, z, w) (array-like of 4, any norm > 0) -> (3, 3) float64 rotation matrix."""
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    if q.shape != (4,) or not np.isfinite(q).all():
        raise TransformFormatError(f"quaternion must be 4 finite numbers (x, y, z, w), got {q.tolist()}")
    norm = np.linalg.norm(q)
    if norm < 1e-12:
        raise TransformFormatError("quaternion has zero norm; it is not a rotation")
    x, y, z, w = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix -> (4,) float64 quaternion (x, y, z, w), unit norm, ``w >= 0``.

    Uses the largest of the four diagonal combinations (Shepperd), so it is stable near 180 degrees.
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[0, 0], R[1, 1], R[2, 2]
    trace = m00 + m11 + m22
    cands = np.array([trace, m00, m11, m22])
    k = int(np.argmax(cands))
    if k == 0:
        s = 2.0 * np.sqrt(max(1.0 + trace, 0.0))
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    elif k == 1:
        s = 2.0 * np.sqrt(max(1.0 + m00 - m11 - m22, 0.0))
        q = np.array([0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s])
    elif k == 2:
        s = 2.0 * np.sqrt(max(1.0 - m00 + m11 - m22, 0.0))
        q = np.array([(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(max(1.0 - m00 - m11 + m22, 0.0))
        q = np.array([(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def _check_matrix(T: Any) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise TransformFormatError(f"transform must be a (4, 4) matrix, got shape {T.shape}")
    if not np.isfinite(T).all():
        raise TransformFormatError("transform contains NaN or Inf")
    if np.abs(T[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-9:
        raise TransformFormatError(f"transform's last row is {T[3].tolist()}, expected [0, 0, 0, 1]")
    R = T[:3, :3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > _ORTHO_TOL or np.linalg.det(R) < 0:
        raise TransformFormatError(
            f"transform's 3x3 block is not a proper rotation (|R^T R - I| = {err:.2e}, det {np.linalg.det(R):.4f})"
        )
    return T


def invert(T: Any) -> np.ndarray:
    """The inverse of a rigid transform (4, 4) ``T_target_source``: ``T_source_target = [R^T, -R^T t]``.

    Raises TransformFormatError when ``T`` or its inverse is not finite: a finite but huge translation (say 1e308 m)
    whose ``-R^T t`` overflows is no transform a pose can be composed with."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise TransformFormatError(f"transform must be a finite (4, 4) matrix, got {T.tolist()}")
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    with np.errstate(over="ignore", invalid="ignore"):  # said below
        out[:3, 3] = -(T[:3, :3].T @ T[:3, 3])
    if not np.isfinite(out).all():
        raise TransformFormatError(f"the inverse of the transform is not finite (translation {T[:3, 3].tolist()} m)")
    return out
