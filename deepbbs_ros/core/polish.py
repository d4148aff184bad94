"""Optional final "polish": a local fine alignment with small_gicp started from the DeepBBS++ estimate.

DeepBBS++ has a wide basin (robust to large initial yaw) and gets the rotation right, but its
translation comes from ~1000 sampled points; GICP / point-to-plane ICP on the dense clouds is precise
once it starts close to the truth. ``registration.polish`` ("none" | "gicp" | "plane_icp") runs this
stage after the refinement (core/registration.py). No ROS import.

Clouds: the voxelised non-ground points (``PreprocessResult.dense_points``) plus, with
``registration.polish_ground``, the ground-layer points (``PreprocessResult.ground_points``), put on a
``polish_voxel`` grid. Transforms follow CONVENTIONS.md: ``T_target_source`` (4, 4) float64,
p_target = R p_source + t, the same direction as ``small_gicp.align(target, source, ..., init_T_target_source)``.

Safety: the polish is rejected (the DeepBBS++ estimate kept) when small_gicp reports non-convergence,
when it moves the estimate by more than ``polish_max_trans`` metres or ``polish_max_rot_deg`` degrees,
or when a cloud has too few points.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from deepbbs_ros.config import RegistrationConfig

__all__ = ["PolishResult", "polish", "SMALL_GICP_TYPE"]

#: registration.polish -> small_gicp registration_type
SMALL_GICP_TYPE = {"gicp": "GICP", "plane_icp": "PLANE_ICP"}
MIN_POLISH_POINTS = 10  # fewer points per cloud (after the voxel grid): no polish


@dataclass
class PolishResult:
    """The outcome of one polish.

    Attributes:
        T_target_source: (4, 4) float64; the polished estimate when ``applied``, else ``T_init``.
        applied: the polish was accepted.
        reason: "ok", or why it was rejected ("not converged", "moved 2.4 m > 2.0 m", ...).
        converged: small_gicp's own convergence flag (False when it did not run).
        iterations: small_gicp iterations (0 when it did not run).
        num_inliers: correspondences within ``polish_max_corr_dist`` at the end.
        delta_trans_m, delta_rot_deg: how far the polish moved the estimate (also when rejected).
        timings_ms: {"prepare": voxel grid + trees + covariances, "align": small_gicp, "total"}.
    """

    T_target_source: np.ndarray
    applied: bool
    reason: str
    converged: bool = False
    iterations: int = 0
    num_inliers: int = 0
    delta_trans_m: float = 0.0
    delta_rot_deg: float = 0.0
    timings_ms: dict[str, float] = field(default_factory=dict)


def polish_cloud(dense: np.ndarray | None, ground: np.ndarray | None, use_ground: bool) -> np.ndarray | None:
    """(K, 3) dense points [+ (G, 3) ground points] -> (K [+ G], 3) float64, or None without dense points."""
    if dense is None:
        return None
    parts = [np.asarray(dense, dtype=np.float64).reshape(-1, 3)]
    if use_ground and ground is not None and len(ground):
        parts.append(np.asarray(ground, dtype=np.float64).reshape(-1, 3))
    return np.concatenate(parts) if len(parts) > 1 else parts[0]


def polish(source: np.ndarray, target: np.ndarray, T_init: np.ndarray, cfg: RegistrationConfig) -> PolishResult:
    """Local fine alignment of ``source`` onto ``target`` from ``T_init`` with small_gicp.

    Args:
        source: (N, 3) float source points (sensor frame, metres), e.g. dense + ground points.
        target: (M, 3) float target points, same conventions.
        T_init: (4, 4) float64 initial ``T_target_source`` (the DeepBBS++ estimate).
        cfg: ``registration.polish*`` keys; ``cfg.polish`` must be "gicp" or "plane_icp".

    Returns:
        :class:`PolishResult`; ``T_target_source`` is ``T_init`` unless the polish was accepted.
    """
    import small_gicp

    t0 = time.perf_counter()
    T_init = np.asarray(T_init, dtype=np.float64).reshape(4, 4)
    reg_type = SMALL_GICP_TYPE[cfg.polish]
    threads = cfg.polish_threads
    clouds, trees = [], []
    for pts in (source, target):
        pts = np.ascontiguousarray(np.asarray(pts, dtype=np.float64).reshape(-1, 3))
        pts = pts[np.isfinite(pts).all(axis=1)]
        if cfg.polish_voxel > 0 and len(pts):
            cloud = small_gicp.voxelgrid_sampling(pts, cfg.polish_voxel, num_threads=threads)
        else:
            cloud = small_gicp.PointCloud(pts)
        if cloud.size() < MIN_POLISH_POINTS:
            ms = (time.perf_counter() - t0) * 1e3
            return PolishResult(T_init.copy(), False, f"only {cloud.size()} points after the voxel grid",
                                timings_ms={"prepare": ms, "align": 0.0, "total": ms})
        tree = small_gicp.KdTree(cloud, num_threads=threads)
        if reg_type == "GICP":
            small_gicp.estimate_covariances(cloud, tree, num_neighbors=cfg.polish_neighbors, num_threads=threads)
        else:
            small_gicp.estimate_normals(cloud, tree, num_neighbors=cfg.polish_neighbors, num_threads=threads)
        clouds.append(cloud)
        trees.append(tree)
    t1 = time.perf_counter()
    res = small_gicp.align(
        clouds[1], clouds[0], trees[1],
        init_T_target_source=T_init,
        registration_type=reg_type,
        max_correspondence_distance=cfg.polish_max_corr_dist,
        num_threads=threads,
        max_iterations=cfg.polish_max_iters,
    )  # fmt: skip
    t2 = time.perf_counter()
    T = np.asarray(res.T_target_source, dtype=np.float64).copy()
    dT = np.linalg.inv(T_init) @ T
    d_trans = float(np.linalg.norm(T[:3, 3] - T_init[:3, 3]))
    d_rot = float(np.degrees(np.arccos(np.clip((np.trace(dT[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))
    if not res.converged:
        reason = f"not converged in {res.iterations} iterations"
    elif int(res.num_inliers) < MIN_POLISH_POINTS:
        reason = f"only {res.num_inliers} correspondences within {cfg.polish_max_corr_dist} m"
    elif d_trans > cfg.polish_max_trans:
        reason = f"moved {d_trans:.2f} m > polish_max_trans {cfg.polish_max_trans} m"
    elif d_rot > cfg.polish_max_rot_deg:
        reason = f"turned {d_rot:.2f} deg > polish_max_rot_deg {cfg.polish_max_rot_deg} deg"
    else:
        reason = "ok"
    applied = reason == "ok"
    return PolishResult(
        T_target_source=T if applied else T_init.copy(),
        applied=applied,
        reason=reason,
        converged=bool(res.converged),
        iterations=int(res.iterations),
        num_inliers=int(res.num_inliers),
        delta_trans_m=d_trans,
        delta_rot_deg=d_rot,
        timings_ms={"prepare": (t1 - t0) * 1e3, "align": (t2 - t1) * 1e3, "total": (t2 - t0) * 1e3},
    )
