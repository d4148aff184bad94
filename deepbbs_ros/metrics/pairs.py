"""Rotations and per-pair errors (CONVENTIONS.md): the angle of a rotation, the rotation nearest a matrix read from a
file, pair errors, success, summaries of errors and runtimes. The conventions: :mod:`deepbbs_ros.metrics`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


# --------------------------------------------------------------------------------------------------
# rotations
# --------------------------------------------------------------------------------------------------
def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation nearest to ``R`` in the Frobenius norm: ``U diag(1, 1, det(U V^T)) V^T`` of the SVD
    ``R = U S V^T`` (det +1, so a reflection is never returned).

    A pose file keeps 6-7 significant digits (KITTI) or so, leaving ``R^T R`` about 1e-6 off the
    identity; readers pass every matrix they read through this once, so that every metric downstream
    scores a rotation.

    Args:
        R: (3, 3) or (..., 3, 3) float64 matrices, finite (non-finite ones are returned unchanged).
    Returns:
        (..., 3, 3) float64 rotation matrices (``R^T R = I`` to about 1e-16).
    """
    R = np.array(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"nearest_rotation: expected (...,3,3) matrices, got shape {R.shape}")
    finite = np.isfinite(R).all(axis=(-2, -1))
    if not finite.all():
        out = R.copy()
        out[finite] = nearest_rotation(R[finite])
        return out
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., :, 2] *= np.where(d == 0, 1.0, d)[..., None]
    return U @ Vt


def project_pose(T: np.ndarray) -> np.ndarray:
    """(4, 4) or (..., 4, 4) poses with the rotation block made a rotation (:func:`nearest_rotation`)
    and the last row ``[0, 0, 0, 1]``; a copy, float64."""
    T = np.array(T, dtype=np.float64)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"project_pose: expected (...,4,4) poses, got shape {T.shape}")
    T[..., :3, :3] = nearest_rotation(T[..., :3, :3])
    T[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return T


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians, in [0, pi]: ``atan2(||vee(R - R^T)|| / 2, (trace(R) - 1) / 2)``.

    Both arguments are exact to about 1e-16 for a rotation (``sin`` and ``cos`` of the angle), so the
    angle is too, near 0 and near pi alike (``arccos`` of the cosine alone loses everything below about
    1e-8 rad). The same value as scipy's ``Rotation.from_matrix(R).magnitude()``, which evo uses.

    Args:
        R: (3, 3) or (..., 3, 3) rotations (also accepts (..., 4, 4) transforms). NaN in, NaN out.
    Returns:
        float64 scalar array or (...,) radians.
    """
    R = np.asarray(R, dtype=np.float64)[..., :3, :3]
    s = 0.5 * np.sqrt((R[..., 2, 1] - R[..., 1, 2]) ** 2 + (R[..., 0, 2] - R[..., 2, 0]) ** 2
                      + (R[..., 1, 0] - R[..., 0, 1]) ** 2)
    c = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)
    return np.arctan2(s, c)


# --------------------------------------------------------------------------------------------------
# per-pair errors
# --------------------------------------------------------------------------------------------------
def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """Geodesic angle between rotations, degrees: the angle of ``R_gt^T R_est`` (:func:`rotation_angle`).

    Args:
        R_est, R_gt: (3, 3) or (B, 3, 3) rotation matrices (also accepts (…, 4, 4) transforms).
    Returns:
        float64 scalar array (or (B,)) in degrees, in [0, 180].
    """
    R_est = np.asarray(R_est, dtype=np.float64)[..., :3, :3]
    R_gt = np.asarray(R_gt, dtype=np.float64)[..., :3, :3]
    return np.degrees(rotation_angle(np.swapaxes(R_gt, -1, -2) @ R_est))


def translation_error_m(t_est: np.ndarray, t_gt: np.ndarray) -> np.ndarray:
    """``||t_est - t_gt||`` in metres; t: (3,) or (B, 3)."""
    return np.linalg.norm(np.asarray(t_est, np.float64) - np.asarray(t_gt, np.float64), axis=-1)


def pair_errors(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (deg) and translation (m) error of estimated ``T_target_source`` against ground truth.

    Args:
        T_est, T_gt: (4, 4) or (B, 4, 4) float64.
    Returns:
        (rot_err_deg, trans_err_m), scalars or (B,) float64.
    """
    T_est = np.asarray(T_est, dtype=np.float64)
    T_gt = np.asarray(T_gt, dtype=np.float64)
    if T_est.shape[-2:] != (4, 4) or T_gt.shape[-2:] != (4, 4):
        raise ValueError(f"pair_errors: expected (...,4,4) transforms, got {T_est.shape} and {T_gt.shape}")
    return rotation_error_deg(T_est, T_gt), translation_error_m(T_est[..., :3, 3], T_gt[..., :3, 3])


def success_mask(
    rot_err_deg: np.ndarray, trans_err_m: np.ndarray, rot_thresh_deg: float = 1.0, trans_thresh_m: float = 0.3
) -> np.ndarray:
    """(B,) bool: ``rot_err_deg <= rot_thresh_deg`` and ``trans_err_m <= trans_thresh_m`` (NaN fails)."""
    rot = np.asarray(rot_err_deg, dtype=np.float64)
    tr = np.asarray(trans_err_m, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return (rot <= rot_thresh_deg) & (tr <= trans_thresh_m)


def success_rate(
    rot_err_deg: np.ndarray, trans_err_m: np.ndarray, rot_thresh_deg: float = 1.0, trans_thresh_m: float = 0.3
) -> float:
    """Fraction of pairs within both thresholds (NaN when there are no pairs)."""
    ok = success_mask(rot_err_deg, trans_err_m, rot_thresh_deg, trans_thresh_m)
    return float(ok.mean()) if ok.size else float("nan")


def summarize(errors: Sequence[float] | np.ndarray) -> dict[str, float]:
    """``{"mean", "rmse", "median", "p95", "max"}`` of finite values (NaN entries when none)."""
    e = np.asarray(errors, dtype=np.float64).ravel()
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {k: float("nan") for k in ("mean", "rmse", "median", "p95", "max")}
    return {
        "mean": float(e.mean()),
        "rmse": float(np.sqrt(np.mean(e**2))),
        "median": float(np.median(e)),
        "p95": float(np.percentile(e, 95)),
        "max": float(e.max()),
    }


def runtime_summary(runtimes_ms: Sequence[float] | np.ndarray) -> dict[str, float]:
    """``{"mean", "p50", "p95"}`` of runtimes in milliseconds (NaN when empty)."""
    r = np.asarray(runtimes_ms, dtype=np.float64).ravel()
    r = r[np.isfinite(r)]
    if r.size == 0:
        return {"mean": float("nan"), "p50": float("nan"), "p95": float("nan")}
    return {"mean": float(r.mean()), "p50": float(np.median(r)), "p95": float(np.percentile(r, 95))}


