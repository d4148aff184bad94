"""Sequence metrics (each the quantity evo computes on the trajectory files of :mod:`deepbbs_ros.metrics.files`): KITTI
drift (the devkit's ``calcSequenceErrors``), ATE after SE(3) Umeyama alignment, APE rotation, RPE. The conventions:
:mod:`deepbbs_ros.metrics`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from deepbbs_ros.metrics.pairs import rotation_angle, rotation_error_deg

KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)  # m, devkit segment lengths
KITTI_STEP = 10  # frames between segment starts (devkit ``step_size``)


# --------------------------------------------------------------------------------------------------
# sequence metrics
# --------------------------------------------------------------------------------------------------
def stack_poses(poses: Sequence[np.ndarray] | np.ndarray, name: str) -> np.ndarray:
    P = np.asarray(poses, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] != (4, 4):
        raise ValueError(f"{name}: expected (N,4,4) poses, got shape {P.shape}")
    return P


def _inv(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (…, 4, 4)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def trajectory_distances(T_world: Sequence[np.ndarray] | np.ndarray) -> np.ndarray:
    """(N,) cumulative path length in metres along the positions of ``T_world`` (first entry 0)."""
    P = stack_poses(T_world, "trajectory_distances")
    steps = np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def kitti_segment_errors(
    T_world_est: Sequence[np.ndarray] | np.ndarray,
    T_world_gt: Sequence[np.ndarray] | np.ndarray,
    lengths: Sequence[float] = KITTI_LENGTHS,
    step: int = KITTI_STEP,
) -> np.ndarray:
    """Per-segment errors of the KITTI odometry devkit (``calcSequenceErrors``).

    For every first frame ``f = 0, step, 2 step, …`` and every length ``L``, the last frame ``l`` is the
    first frame whose ground-truth path distance exceeds ``dist[f] + L`` (segments that run past the
    end are skipped). With ``E = (est_f^-1 est_l)^-1 (gt_f^-1 gt_l)``, the segment errors are
    ``t_err = ||t(E)|| / L`` (m/m) and ``r_err = angle(E) / L`` (rad/m).

    Returns:
        (S, 4) float64 rows ``[first_frame, length_m, t_err (m/m), r_err (rad/m)]``.
    """
    est = stack_poses(T_world_est, "kitti_drift(est)")
    gt = stack_poses(T_world_gt, "kitti_drift(gt)")
    if est.shape != gt.shape:
        raise ValueError(f"kitti_drift: {len(est)} estimated poses but {len(gt)} ground-truth poses")
    dist = trajectory_distances(gt)
    rows = []
    for first in range(0, len(gt), step):
        for length in lengths:
            later = np.nonzero(dist[first:] > dist[first] + length)[0]
            if later.size == 0:
                continue
            last = first + int(later[0])
            d_gt = _inv(gt[first]) @ gt[last]
            d_est = _inv(est[first]) @ est[last]
            E = _inv(d_est) @ d_gt
            r = float(rotation_angle(E))
            t = float(np.linalg.norm(E[:3, 3]))
            rows.append((first, length, t / length, r / length))
    return np.asarray(rows, dtype=np.float64).reshape(-1, 4)


def kitti_drift(
    T_world_est: Sequence[np.ndarray] | np.ndarray,
    T_world_gt: Sequence[np.ndarray] | np.ndarray,
    lengths: Sequence[float] = KITTI_LENGTHS,
    step: int = KITTI_STEP,
) -> dict[str, float]:
    """KITTI drift averaged over all segments (devkit definition).

    Returns:
        ``{"t_err_pct": mean t_err * 100, "r_err_deg_per_100m": mean r_err * 180/pi * 100,
        "segments": S}``; the errors are NaN when the ground-truth path is shorter than every length.
    """
    seg = kitti_segment_errors(T_world_est, T_world_gt, lengths, step)
    if seg.shape[0] == 0:
        return {"t_err_pct": float("nan"), "r_err_deg_per_100m": float("nan"), "segments": 0}
    return {
        "t_err_pct": float(seg[:, 2].mean() * 100.0),
        "r_err_deg_per_100m": float(np.degrees(seg[:, 3].mean()) * 100.0),
        "segments": int(seg.shape[0]),
    }


def umeyama_alignment(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, float]:
    """Least-squares similarity ``dst ≈ s R src + t`` (Umeyama 1991).

    Args:
        src, dst: (N, 3) float64 corresponding positions, N >= 3 (N = 1, 2 fall back to a translation /
            the best rotation about the line, as the SVD allows).
    Returns:
        (T (4, 4) float64 with ``[R t]``, scale s; s = 1 unless ``with_scale``).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or src.shape[0] == 0:
        raise ValueError(f"umeyama_alignment: expected matching (N,3) arrays, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / src.shape[0]
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = 1.0
    if with_scale:
        var_s = (xs**2).sum() / src.shape[0]
        s = float(np.trace(np.diag(D) @ S) / var_s) if var_s > 0 else 1.0
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = mu_d - s * R @ mu_s
    return T, s


def _pair_of(T_world_est, T_world_gt, name: str) -> tuple[np.ndarray, np.ndarray]:
    est = stack_poses(T_world_est, f"{name}(est)")
    gt = stack_poses(T_world_gt, f"{name}(gt)")
    if est.shape != gt.shape:
        raise ValueError(f"{name}: {len(est)} estimated poses but {len(gt)} ground-truth poses")
    return est, gt


def ate_errors(
    T_world_est: Sequence[np.ndarray] | np.ndarray, T_world_gt: Sequence[np.ndarray] | np.ndarray
) -> np.ndarray:
    """Absolute trajectory error per frame: (N,) metres between the estimated positions, moved by the SE(3)
    Umeyama alignment onto the ground-truth positions (no scale), and the ground-truth positions.

    evo's APE translation part with ``-a`` (``evo_ape tum gt.tum est.tum -a``): the same per-frame errors.
    """
    est, gt = _pair_of(T_world_est, T_world_gt, "ate")
    p_est, p_gt = est[:, :3, 3], gt[:, :3, 3]
    T, _ = umeyama_alignment(p_est, p_gt)
    aligned = p_est @ T[:3, :3].T + T[:3, 3]
    return np.linalg.norm(aligned - p_gt, axis=1)


def ate_rmse(T_world_est: Sequence[np.ndarray] | np.ndarray, T_world_gt: Sequence[np.ndarray] | np.ndarray) -> float:
    """Absolute trajectory error: RMSE (m) of :func:`ate_errors` (SE(3) Umeyama alignment, no scale);
    evo's ``evo_ape tum gt.tum est.tum -a`` rmse."""
    e = ate_errors(T_world_est, T_world_gt)
    return float(np.sqrt(np.mean(e**2)))


def ape_rotation_deg(T_world_est: Sequence[np.ndarray] | np.ndarray,
                     T_world_gt: Sequence[np.ndarray] | np.ndarray) -> np.ndarray:
    """Absolute rotation error per frame without alignment: (N,) degrees, the angle of ``gt_k^-1 est_k``.

    The replay's trajectories start at the first ground-truth pose, so no alignment is needed (an SE(3)
    alignment fitted to positions alone leaves the rotation about a straight drive's direction free).
    evo's ``evo_ape tum gt.tum est.tum --pose_relation angle_deg`` (no ``-a``).
    """
    est, gt = _pair_of(T_world_est, T_world_gt, "ape_rotation")
    return rotation_error_deg(est, gt)


def rpe(
    T_world_est: Sequence[np.ndarray] | np.ndarray, T_world_gt: Sequence[np.ndarray] | np.ndarray, delta: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose error between frames ``k - delta`` and ``k`` (``delta`` in frames).

    ``E_k = (gt_{k-d}^-1 gt_k)^-1 (est_{k-d}^-1 est_k)``; returns ((N-d,) ``||t(E_k)||`` m, (N-d,) angle of
    ``R(E_k)`` deg). evo's ``evo_rpe tum gt.tum est.tum --delta d --delta_unit f`` (translation_part, and
    ``--pose_relation angle_deg``), consecutive pairs, no alignment.
    """
    est, gt = _pair_of(T_world_est, T_world_gt, "rpe")
    if len(est) <= delta:
        return np.zeros(0), np.zeros(0)
    d_est = _inv(est[:-delta]) @ est[delta:]
    d_gt = _inv(gt[:-delta]) @ gt[delta:]
    E = _inv(d_gt) @ d_est
    trans = np.linalg.norm(E[:, :3, 3], axis=1)
    rot = np.degrees(rotation_angle(E))
    return trans, rot


