"""The precision stage ("polish"): small_gicp GICP on the dense scans, started from the DeepBBS++ estimate.

DeepBBS++ finds the right basin from far (large yaw, metres of offset) with its sampled points; GICP on
the dense scans is precise once it starts inside that basin. ``registration.polish`` ("gicp" by
default, "plane_icp", or "none") runs this stage last in ``DeepBBSRegistration.register``
(core/registration.py). No ROS import.

Transforms follow CONVENTIONS.md: ``T_target_source`` (4, 4) float64, p_target = R p_source + t, the
same direction as ``small_gicp.align(target, source, ..., init_T_target_source)``.

Safety: the result is rejected (the DeepBBS++ estimate kept) when small_gicp reports non-convergence,
when it moves the estimate by more than ``polish_max_trans`` metres or ``polish_max_rot_deg`` degrees
(both 0 = no limit, the default: a limit threw away good corrections from far starts), or when a cloud
has too few points.

Modules: the prepared clouds in ``core/polish_cloud.py`` (:class:`PolishCloud`, :func:`prepare_polish_cloud`) and
``core/polish_view.py`` (:class:`PolishView`, a map crop); a run's result and its judging in ``core/polish_result.py``
(:class:`PolishResult`, :func:`outcome`); the thread counts in ``core/threads.py``; their names are importable from
here too.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.config import RegistrationConfig
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.core.polish_cloud import (
    MIN_POLISH_POINTS,
    PolishCloud,
    _prepared,
    finer_pair,
    grid_scale,
    prepare_polish_cloud,
    prepared_cloud,
    scene_voxel,
)
from deepbbs_ros.core.polish_result import PolishResult, outcome
from deepbbs_ros.core.polish_view import PolishView
from deepbbs_ros.core.threads import cpu_cores, threads_or_all

__all__ = ["MIN_POLISH_POINTS", "PolishCloud", "PolishResult", "PolishView", "correspondence_distance", "cpu_cores",
           "finer_pair", "finish", "gicp_align", "polish", "prepare_polish_cloud", "prepared_cloud", "scene_voxel",
           "SMALL_GICP_TYPE", "threads_or_all"]

#: registration.polish -> small_gicp registration_type
SMALL_GICP_TYPE = {"gicp": "GICP", "plane_icp": "PLANE_ICP"}
#: polish(..., check=...): the source voxels scored at the check (a spread subset of about this many, on this grid)
CHECK_POINTS, CHECK_CELL = 1000, 1.0


def _as_cloud(c: np.ndarray | PolishCloud, cfg: RegistrationConfig, reg_type: str) -> PolishCloud:
    """A prepared cloud as is; raw (N, 3) points: finite rows, ``polish_voxel`` grid, covariances."""
    if isinstance(c, PolishCloud):
        return c.complete()
    pts = as_xyz(c, "polish", dtype=np.float64)
    return _prepared(pts[np.isfinite(pts).all(axis=1)], cfg.polish_voxel, cfg.polish_neighbors, reg_type,
                     cfg.polish_threads)


def correspondence_distance(clouds, cfg: RegistrationConfig) -> float:
    """``polish_max_corr_dist`` scaled by the finer of the two clouds' grids over ``polish_voxel`` (the shipped
    ratio of the two, kept on a scene-sized grid: :func:`scene_voxel`); as is when either has no grid recorded."""
    return cfg.polish_max_corr_dist * grid_scale(clouds, cfg.polish_voxel)


def finish(source: Any, target: Any, T: np.ndarray, cfg: RegistrationConfig) -> PolishResult | None:
    """GICP again from ``T`` (4, 4), on both scans' scene-sized grids (:meth:`PolishCloud.finer`: built on first
    use), the correspondence distance scaled with the finer grid: where GICP on ``polish_voxel`` converged, its
    minimum in a narrow place lies off the truth by the grid's blend (degrees in a 2-3 m corridor), and the finer grid
    pins it in a few iterations (its own basin is narrower: it finishes, it does not start). None when either scan
    has no finer grid (its median range puts ``registration.polish_voxel_angle`` at ``polish_voxel`` or above)."""
    fine = finer_pair(source, target)
    return None if fine is None else polish(fine[0], fine[1], T, cfg)


def gicp_align(target: Any, source: Any, tree: Any, T_start: np.ndarray, iterations: int, cfg: RegistrationConfig,
               corr: float) -> Any:
    """One small_gicp run with the precision stage's settings (``registration.polish*``, ``exact_gicp``): ``source``
    onto ``target`` (small_gicp point clouds, ``tree`` the target's k-d tree) from ``T_start`` (4, 4)
    ``T_target_source``, at most ``iterations``, correspondences within ``corr`` metres -> small_gicp's result."""
    import small_gicp

    return small_gicp.align(
        target, source, tree,
        init_T_target_source=T_start,
        registration_type=SMALL_GICP_TYPE[cfg.polish],
        max_correspondence_distance=corr,
        num_threads=1 if cfg.exact_gicp else threads_or_all(cfg.polish_threads),
        max_iterations=iterations,
        rotation_epsilon=float(np.radians(cfg.polish_rot_eps_deg)),
        translation_epsilon=cfg.polish_trans_eps,
    )  # fmt: skip


def polish(source: np.ndarray | PolishCloud, target: np.ndarray | PolishCloud, T_init: np.ndarray,
           cfg: RegistrationConfig, check: tuple | None = None) -> PolishResult:
    """Local fine alignment of ``source`` onto ``target`` from ``T_init`` with small_gicp.

    Args:
        source: (N, 3) float source points (sensor frame, metres; prepared here with ``polish_voxel`` and
            ``polish_neighbors``, no range crop) or a :class:`PolishCloud` prepared with the same type.
        target: (M, 3) float target points or a :class:`PolishCloud`, same conventions.
        T_init: (4, 4) float64 initial ``T_target_source`` (the DeepBBS++ estimate).
        cfg: ``registration.polish*`` keys; ``cfg.polish`` must be "gicp" or "plane_icp".
        check: (iterations, score) or (iterations, score, judge): a polish not converged after that many iterations
            whose pose then scores under ``score`` (the verdict's fitness at ``verdict_dist`` of a spread subset of the
            source's voxels), or that ``judge(T_target_source)`` (the pose there, (4, 4) in the target's frame) calls
            hopeless (False), stops there, rejected (GICP on a wrong place wanders for its whole budget); None: no
            check. A fourth item, a :class:`PolishCloud` of the source on a coarser grid (or None): the first leg up
            to the check aligns it instead of the source (the check asks whether a start is hopeless, not where to the
            centimetre: on a wrong place the leg costs a fraction), the rest of the budget the source itself.

    Returns:
        :class:`PolishResult`; ``T_target_source`` is ``T_init`` unless the polish was accepted.
    """
    t0 = time.perf_counter()
    T_init = np.asarray(T_init, dtype=np.float64).reshape(4, 4)
    reg_type = SMALL_GICP_TYPE[cfg.polish]
    clouds = [_as_cloud(c, cfg, reg_type) for c in (source, target)]
    if isinstance(clouds[0], PolishView):
        raise ValueError("polish: a PolishView is a target only")
    t1 = time.perf_counter()
    for c in clouds:
        if c.n_points < MIN_POLISH_POINTS:
            ms = (t1 - t0) * 1e3
            return PolishResult(T_init.copy(), False, f"only {c.n_points} points after the voxel grid",
                                timings_ms={"prepare": ms, "align": 0.0, "total": ms})
    # a view of a larger cloud (PolishView, a map crop): aligned on the whole cloud in its frame, answered in ours
    T_base = clouds[1].T_base if isinstance(clouds[1], PolishView) else None
    tree = clouds[1].tree if T_base is None else clouds[1].tree.base
    corr = correspondence_distance(clouds, cfg)

    def align(T_start: np.ndarray, iterations: int, source: Any = None) -> Any:
        return gicp_align(clouds[1].cloud, (clouds[0] if source is None else source).cloud, tree, T_start, iterations,
                          cfg, corr)

    start = T_init if T_base is None else T_base @ T_init
    stopped = judged = False  # the check stopped it (judge: its judge did)
    if check is None or not 0 < check[0] < cfg.polish_max_iters:
        res, check_score = align(start, cfg.polish_max_iters), float("nan")
        iterations = int(res.iterations)
    else:  # a first leg, a look at the fit, the rest of the budget only when it is worth it
        from deepbbs_ros.core.verdict import fitness, spread_subset

        lead = check[3] if len(check) > 3 else None  # the first leg on a coarser copy of the source
        res = align(start, check[0], lead)
        iterations, check_score = int(res.iterations), float("nan")
        T_now = np.asarray(res.T_target_source)
        if not res.converged:
            pts = spread_subset(clouds[0].points(), CHECK_POINTS, CHECK_CELL)
            check_score = fitness(pts, tree, T_now, cfg.verdict_dist)
            stopped = not check_score >= check[1]  # nan-safe
            if not stopped and len(check) > 2 and check[2] is not None:
                stopped = not check[2](T_now if T_base is None else np.linalg.solve(T_base, T_now))
                judged = stopped
            if not stopped:
                res = align(T_now, cfg.polish_max_iters - check[0])
                iterations += int(res.iterations)
        elif lead is not None:  # the coarse leg converged: the whole cloud from there
            res = align(T_now, cfg.polish_max_iters - check[0])
            iterations += int(res.iterations)
    t2 = time.perf_counter()
    stop = ""
    if judged:
        stop = f"stopped after {iterations} iterations: judged hopeless there (score {check_score:.2f})"
    elif stopped:
        stop = f"stopped after {iterations} iterations: score {check_score:.2f} < {check[1]:.2f}"
    return outcome(res, T_init, cfg, corr, T_base, iterations, check_score, stop, (t0, t1, t2))
