"""The precision stage ("polish"): small_gicp GICP on the dense scans, started from the DeepBBS++ estimate.

DeepBBS++ finds the right basin from far (large yaw, metres of offset) with its sampled points; GICP on
the dense scans is precise once it starts inside that basin. ``registration.polish`` ("gicp" by
default, "plane_icp", or "none") runs this stage last in ``DeepBBSRegistration.register``
(core/registration.py). No ROS import.

Clouds: the **whole** cropped scan, ground included, on a ``polish_voxel`` grid, with covariances
(GICP) or normals (point-to-plane ICP) from ``polish_neighbors`` neighbours: exactly the clouds and the
settings of the small_gicp GICP baseline (``deepbbs_ros.baselines``, ``eval.baseline_*`` defaults), so
that, started inside the basin, the stage lands on GICP's own fixed point. (The earlier polish used a
random subset of 3000 non-ground voxels plus 1500 ground points and a 1 m correspondence distance:
another cost function, whose optimum lay 1-3 cm off GICP's.) Each scan's cloud is prepared once
(:func:`prepare_polish_cloud`, called by ``DeepBBSRegistration.preprocess``) and kept in its
``PreprocessResult``, so in odometry and in the node every scan pays for it once.

Transforms follow CONVENTIONS.md: ``T_target_source`` (4, 4) float64, p_target = R p_source + t, the
same direction as ``small_gicp.align(target, source, ..., init_T_target_source)``.

Safety: the result is rejected (the DeepBBS++ estimate kept) when small_gicp reports non-convergence,
when it moves the estimate by more than ``polish_max_trans`` metres or ``polish_max_rot_deg`` degrees
(both 0 = no limit, the default: a limit threw away good corrections from far starts), or when a cloud
has too few points.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.config import RegistrationConfig
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.reprs import short_repr

__all__ = ["PolishCloud", "PolishResult", "finish", "polish", "prepare_polish_cloud", "prepared_cloud",
           "SMALL_GICP_TYPE", "threads_or_all"]

#: registration.polish -> small_gicp registration_type
SMALL_GICP_TYPE = {"gicp": "GICP", "plane_icp": "PLANE_ICP"}
MIN_POLISH_POINTS = 10  # fewer points per cloud (after the voxel grid): no polish
#: polish(..., check=...): the source voxels scored at the check (a spread subset of about this many, on this grid)
CHECK_POINTS, CHECK_CELL = 1000, 1.0


def cpu_cores() -> int:
    """The CPU cores this process may run on (its affinity: ``taskset``, a container's cpuset), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this platform
        return max(1, os.cpu_count() or 1)


def threads_or_all(n: int) -> int:
    """``n`` threads, or every CPU core this process may use for ``n <= 0``."""
    return n if n > 0 else cpu_cores()


@dataclass
class PolishCloud:
    """One scan ready for small_gicp: the voxelised ``small_gicp.PointCloud`` (with covariances and
    normals, or neither for point-to-point ICP), its ``small_gicp.KdTree``; ``n_points`` after the voxel
    grid; ``n_cropped`` the finite points inside the range crop before it; ``prepare_ms`` the time it
    took. Sensor frame, metres."""

    cloud: Any
    tree: Any
    n_points: int
    prepare_ms: float = 0.0
    n_cropped: int = 0
    # (neighbors, registration_type, threads) while the k-d tree and covariances wait (prepare_polish_cloud(
    # defer=True)): :meth:`complete` builds them; the voxel grid (``points()``) is there already
    pending: tuple[int, str, int] | None = None
    # (neighbors, registration_type, threads) of its k-d tree and covariances, built or pending: what a copy of this
    # cloud in another process builds again (pickling keeps the voxel grid only, with the k-d tree and covariances
    # deferred: small_gicp's objects do not pickle, and building them is the work that process is there for)
    spec: tuple[int, str, int] | None = None
    # the grid it was put on (m; before a max_voxels coarsening), 0 for none: polish() scales its correspondence
    # distance with the finer of a pair's grids
    voxel: float = 0.0
    # the scan's scene-sized grid (m; prepare_polish_cloud's voxel_angle, :func:`scene_voxel`) when finer than
    # ``voxel``, else 0 (none); then ``fine_source`` holds the cropped scan (N, 3) it is built from when a finish
    # first asks (:meth:`finer`, :func:`finish`); a scan with none keeps (and pickles) nothing more
    fine_voxel: float = 0.0
    fine_source: np.ndarray | None = field(default=None, repr=False)
    _fine: PolishCloud | None = field(default=None, repr=False, compare=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def __getstate__(self) -> dict:
        return {"points": self.points(), "n_points": self.n_points, "prepare_ms": self.prepare_ms,
                "n_cropped": self.n_cropped, "spec": self.spec, "voxel": self.voxel, "fine_voxel": self.fine_voxel,
                "fine_source": self.fine_source}

    def __setstate__(self, state: dict) -> None:
        import small_gicp

        self.cloud = small_gicp.PointCloud(np.ascontiguousarray(state["points"], dtype=np.float64))
        self.tree, self.n_points, self.n_cropped = None, state["n_points"], state["n_cropped"]
        self.prepare_ms, self.spec, self.pending = state["prepare_ms"], state["spec"], state["spec"]
        self.voxel = state.get("voxel", 0.0)
        self.fine_voxel, self.fine_source, self._fine = state.get("fine_voxel", 0.0), state.get("fine_source"), None
        self._lock = threading.Lock()

    def complete(self, threads: int | None = None) -> PolishCloud:
        """Build the deferred k-d tree and covariances (``threads`` overrides the preparation's); no-op when
        there is nothing pending. Thread-safe (the node's registration thread and an input thread may both
        need a cached cloud): built once. Returns self."""
        if self.pending is None:
            return self
        with self._lock:
            if self.pending is None:
                return self
            t0 = time.perf_counter()
            neighbors, registration_type, th = self.pending
            self.tree = _tree_and_covariances(self.cloud, neighbors, registration_type,
                                              th if threads is None else threads)
            self.pending = None
            self.prepare_ms += (time.perf_counter() - t0) * 1e3
        return self

    def finer(self) -> PolishCloud | None:
        """This scan on its scene-sized grid (:attr:`fine_voxel`), with k-d tree and covariances, built on first
        call (thread-safe, once); None when it has none."""
        if self.fine_voxel <= 0 or self.fine_source is None or self.spec is None:
            return None
        with self._lock:
            if self._fine is None:
                neighbors, registration_type, th = self.spec
                self._fine = _prepared(self.fine_source, self.fine_voxel, neighbors, registration_type, th)
                self._fine.voxel = self.fine_voxel
        return self._fine

    def points(self) -> np.ndarray:
        """(n_points, 3) float64 voxel centroids."""
        return np.asarray(self.cloud.points())[:, :3].copy()

    def transformed(self, T: np.ndarray, neighbors: int, registration_type: str = "GICP",
                    threads: int = 0) -> PolishCloud:
        """This cloud moved by T (4, 4) (p' = R p + t), re-prepared (evaluation's extra yaw on a source)."""
        pts = self.points() @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3]
        return _prepared(pts, 0.0, neighbors, registration_type, threads)


class _FramedTree:
    """A prepared cloud's k-d tree (frame B) queried with points in frame A: they are moved by ``T_b_a`` first."""

    def __init__(self, base: Any, T_b_a: np.ndarray) -> None:
        self.base = base
        self.R, self.t = np.asarray(T_b_a, np.float64)[:3, :3].copy(), np.asarray(T_b_a, np.float64)[:3, 3].copy()

    def batch_nearest_neighbor_search(self, points: np.ndarray, num_threads: int = 1) -> Any:
        p = np.asarray(points, dtype=np.float64) @ self.R.T + self.t
        return self.base.batch_nearest_neighbor_search(p, num_threads=num_threads)


@dataclass(eq=False)
class PolishView(PolishCloud):
    """A part of a larger prepared cloud (a map's: voxel grid, k-d tree and covariances built once, frame B) seen
    from frame A: the precision-stage target of a map crop with no preparation of its own. ``local`` (n_points, 3)
    float64 the part's voxel centroids in frame A (``points()``), ``T_base`` (4, 4) ``T_b_a``. :func:`polish` aligns
    on the whole base cloud from ``T_base @ T_init`` and answers in frame A (GICP is the same in any frame, to
    rounding); ``tree`` answers queries in frame A. Pickled as a plain deferred :class:`PolishCloud` of ``local``."""

    T_base: np.ndarray = field(default_factory=lambda: np.eye(4))
    local: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @classmethod
    def of(cls, base: PolishCloud, local: np.ndarray, T_b_a: np.ndarray) -> PolishView:
        """The view of ``base`` (completed here) whose centroids in frame A are ``local`` (N, 3), ``T_b_a`` (4, 4)."""
        base.complete()
        T = np.asarray(T_b_a, dtype=np.float64).copy()
        return cls(base.cloud, _FramedTree(base.tree, T), len(local), n_cropped=len(local), spec=base.spec,
                   T_base=T, local=np.ascontiguousarray(local, dtype=np.float64))

    def points(self) -> np.ndarray:
        return self.local.copy()

    def __reduce__(self) -> tuple:
        return _plain_cloud, (self.__getstate__(),)


def _plain_cloud(state: dict) -> PolishCloud:
    pc = PolishCloud.__new__(PolishCloud)
    pc.__setstate__(state)
    return pc


def prepare_polish_cloud(points: np.ndarray, voxel: float, neighbors: int, *, registration_type: str = "GICP",
                         min_range: float = 0.0, max_range: float = float("inf"), threads: int = 0,
                         defer: bool = False, max_voxels: int = 0, voxel_angle: float = 0.0) -> PolishCloud:
    """Raw scan -> :class:`PolishCloud`: finite points within [min_range, max_range] m, a ``voxel`` m grid
    (0 = none), a k-d tree, and covariances + normals from ``neighbors`` neighbours (``"GICP"``,
    ``"PLANE_ICP"``) or nothing (``"ICP"``). Shared by the precision stage and the small_gicp baselines.

    Args:
        points: (N, 3) float xyz, sensor frame, metres; NaN/Inf rows allowed (dropped).
        threads: small_gicp threads (0 = every core).
        defer: only the voxel grid now; :meth:`PolishCloud.complete` (or :func:`polish`) builds the k-d
            tree and covariances later (``DeepBBSRegistration`` does it while the network process runs).
        max_voxels: at most this many voxels (0 = no cap): a denser grid's centroids go on a coarser grid,
            ``voxel * sqrt(n / max_voxels)`` (a scan's voxels fill surfaces: their count goes as 1 / voxel^2).
        voxel_angle: > 0: the scan's scene-sized grid, this angle (rad) seen from the sensor at the scan's median
            range, within [``voxel`` / 4, ``voxel``] (:func:`scene_voxel`): the cloud stays on ``voxel`` (GICP's
            grid: its basin and its cost); where that grid is finer (``fine_voxel``) the cropped scan is kept to
            build it from when a finish first asks (:meth:`PolishCloud.finer`): a corridor's or a small room's scan
            (median range 1-4 m) gets a grid fine enough for its walls, floor and ceiling, whose corners a ``voxel``
            grid with ``neighbors`` covariances blends, to finish on (:func:`finish`); 0: ``voxel`` only.
    """
    from deepbbs_ros.core.preprocess import crop_range

    t0 = time.perf_counter()
    pts = as_xyz(points, "polish", dtype=None)  # (N, 3) only: never a silent reshape (core/points.py)
    pts = np.compress(crop_range(pts, min_range, max_range), pts, axis=0).astype(np.float64, copy=False)
    # the scene's grid first, while the cropped scan is still in the CPU's caches (its subsample is a strided read)
    fine = scene_voxel(pts, voxel, voxel_angle) if voxel > 0 and voxel_angle > 0 else voxel
    out = _prepared(pts, voxel, neighbors, registration_type, threads, defer, max_voxels)
    out.n_cropped, out.voxel = len(pts), float(voxel)
    if fine < voxel:  # a narrow place's scan: the cropped scan kept to build its finer grid from when asked
        out.fine_voxel, out.fine_source = fine, pts
    out.prepare_ms = (time.perf_counter() - t0) * 1e3
    return out


def scene_voxel(points: np.ndarray, voxel: float, angle: float, samples: int = 1024) -> float:
    """The grid (m) for a scan's points (N, 3) (sensor frame): ``angle`` (rad) seen from the sensor at their median
    range (of an even subsample of about ``samples``: a few hundredths of a millisecond), within [``voxel`` / 4,
    ``voxel``]."""
    if len(points) == 0:
        return float(voxel)
    sub = points[:: max(1, len(points) // samples)]
    sq = np.einsum("ij,ij->i", sub, sub)
    r50 = float(np.sqrt(np.partition(sq, len(sq) // 2)[len(sq) // 2]))
    return float(np.clip(angle * r50, 0.25 * voxel, voxel))


def prepared_cloud(points: np.ndarray, neighbors: int, registration_type: str = "GICP",
                   threads: int = 0) -> PolishCloud:
    """Points already on the voxel grid (N, 3) (e.g. a :class:`PolishCloud`'s centroids, moved) -> a
    :class:`PolishCloud` with a new k-d tree and covariances, without another voxel grid."""
    t0 = time.perf_counter()
    out = _prepared(np.asarray(points, dtype=np.float64), 0.0, neighbors, registration_type, threads)
    out.prepare_ms = (time.perf_counter() - t0) * 1e3
    return out


def _prepared(pts: np.ndarray, voxel: float, neighbors: int, registration_type: str, threads: int,
              defer: bool = False, max_voxels: int = 0) -> PolishCloud:
    import small_gicp

    th = threads_or_all(threads)
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    if voxel > 0 and len(pts):
        # the voxel grid on one thread whatever ``threads``: on more, small_gicp cuts the sorted points into blocks
        # of 1024 and writes them in the order the threads finish (a voxel across two blocks becomes two centroids,
        # another cloud on every run); k-d trees and covariances are the same on any number of threads
        cloud = small_gicp.voxelgrid_sampling(pts, voxel, num_threads=1)
        v = voxel
        for _ in range(3):  # the 1 / voxel^2 law is approximate: at most three coarser grids
            if not 0 < max_voxels < cloud.size():
                break
            v *= max(1.02, float(np.sqrt(cloud.size() / max_voxels)))
            cloud = small_gicp.voxelgrid_sampling(np.asarray(cloud.points())[:, :3], v, num_threads=1)
    else:
        cloud = small_gicp.PointCloud(pts)
    spec = (neighbors, registration_type, th)
    if defer:
        return PolishCloud(cloud, None, int(cloud.size()), n_cropped=len(pts), pending=spec, spec=spec)
    tree = _tree_and_covariances(cloud, neighbors, registration_type, th)
    return PolishCloud(cloud, tree, int(cloud.size()), n_cropped=len(pts), spec=spec)


def _tree_and_covariances(cloud: Any, neighbors: int, registration_type: str, threads: int) -> Any:
    """The k-d tree of a small_gicp cloud; its covariances + normals estimated in place (not for "ICP")."""
    import small_gicp

    th = threads_or_all(threads)
    n = int(cloud.size())
    tree = small_gicp.KdTree(cloud, num_threads=th) if n else None
    if n >= MIN_POLISH_POINTS and registration_type != "ICP":
        small_gicp.estimate_normals_covariances(cloud, tree, num_neighbors=neighbors, num_threads=th)
    return tree


def _as_cloud(c: np.ndarray | PolishCloud, cfg: RegistrationConfig, reg_type: str) -> PolishCloud:
    """A prepared cloud as is; raw (N, 3) points: finite rows, ``polish_voxel`` grid, covariances."""
    if isinstance(c, PolishCloud):
        return c.complete()
    pts = as_xyz(c, "polish", dtype=np.float64)
    return _prepared(pts[np.isfinite(pts).all(axis=1)], cfg.polish_voxel, cfg.polish_neighbors, reg_type,
                     cfg.polish_threads)


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
        timings_ms: {"prepare": voxel grid + trees + covariances (0 for prepared clouds), "align", "total"}.
    """

    __repr__ = short_repr  # one readable line: arrays as shape and dtype (deepbbs_ros/reprs.py)

    T_target_source: np.ndarray
    applied: bool
    reason: str
    converged: bool = False
    iterations: int = 0
    num_inliers: int = 0
    delta_trans_m: float = 0.0
    delta_rot_deg: float = 0.0
    timings_ms: dict[str, float] = field(default_factory=dict)
    check_score: float = float("nan")  # the score at the check (polish(..., check=...)); nan when none was made
    #: small_gicp's (H (6, 6), error, inliers) at its last linearisation (core/covariance.py reads a pose's covariance
    #: from them); None when it did not run
    hessian: tuple[np.ndarray, float, int] | None = None


def correspondence_distance(clouds, cfg: RegistrationConfig) -> float:
    """``polish_max_corr_dist`` scaled by the finer of the two clouds' grids over ``polish_voxel`` (the shipped
    ratio of the two, kept on a scene-sized grid: :func:`scene_voxel`); as is when either has no grid recorded."""
    grids = [getattr(c, "voxel", 0.0) for c in clouds]
    if cfg.polish_voxel <= 0 or min(grids) <= 0:
        return cfg.polish_max_corr_dist
    return cfg.polish_max_corr_dist * min(1.0, min(grids) / cfg.polish_voxel)


def finish(source: Any, target: Any, T: np.ndarray, cfg: RegistrationConfig) -> PolishResult | None:
    """GICP again from ``T`` (4, 4), on both scans' scene-sized grids (:meth:`PolishCloud.finer`: built on first
    use), the correspondence distance scaled with the finer grid: where GICP on ``polish_voxel`` converged, its
    minimum in a narrow place lies off the truth by the grid's blend (degrees in a 2-3 m corridor), and the finer grid
    pins it in a few iterations (its own basin is narrower: it finishes, it does not start). None when either scan
    has no finer grid (its median range puts ``registration.polish_voxel_angle`` at ``polish_voxel`` or above)."""
    fine = [c.finer() if isinstance(c, PolishCloud) else None for c in (source, target)]
    if fine[0] is None or fine[1] is None:
        return None
    return polish(fine[0], fine[1], T, cfg)


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
    import small_gicp

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
        return small_gicp.align(
            clouds[1].cloud, (clouds[0] if source is None else source).cloud, tree,
            init_T_target_source=T_start,
            registration_type=reg_type,
            max_correspondence_distance=corr,
            num_threads=1 if cfg.exact_gicp else threads_or_all(cfg.polish_threads),
            max_iterations=iterations,
            rotation_epsilon=float(np.radians(cfg.polish_rot_eps_deg)),
            translation_epsilon=cfg.polish_trans_eps,
        )  # fmt: skip

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
    T = np.asarray(res.T_target_source, dtype=np.float64).copy()
    if T_base is not None:
        T = np.linalg.solve(T_base, T)
    dT = np.linalg.inv(T_init) @ T
    d_trans = float(np.linalg.norm(T[:3, 3] - T_init[:3, 3]))
    d_rot = float(np.degrees(np.arccos(np.clip((np.trace(dT[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))
    if judged:
        reason = f"stopped after {iterations} iterations: judged hopeless there (score {check_score:.2f})"
    elif stopped:
        reason = f"stopped after {iterations} iterations: score {check_score:.2f} < {check[1]:.2f}"
    elif not res.converged:
        reason = f"not converged in {iterations} iterations"
    elif int(res.num_inliers) < MIN_POLISH_POINTS:
        reason = f"only {res.num_inliers} correspondences within {corr:.2f} m"
    elif 0 < cfg.polish_max_trans < d_trans:
        reason = f"moved {d_trans:.2f} m > polish_max_trans {cfg.polish_max_trans} m"
    elif 0 < cfg.polish_max_rot_deg < d_rot:
        reason = f"turned {d_rot:.2f} deg > polish_max_rot_deg {cfg.polish_max_rot_deg} deg"
    else:
        reason = "ok"
    applied = reason == "ok"
    return PolishResult(
        T_target_source=T if applied else T_init.copy(),
        applied=applied,
        reason=reason,
        converged=bool(res.converged),
        iterations=iterations,
        num_inliers=int(res.num_inliers),
        delta_trans_m=d_trans,
        delta_rot_deg=d_rot,
        check_score=check_score,
        timings_ms={"prepare": (t1 - t0) * 1e3, "align": (t2 - t1) * 1e3, "total": (t2 - t0) * 1e3},
        hessian=(np.asarray(res.H, dtype=np.float64), float(res.error), int(res.num_inliers)),
    )
