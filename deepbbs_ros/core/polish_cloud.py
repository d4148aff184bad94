"""The precision stage's prepared cloud (:class:`PolishCloud`): one scan on small_gicp's voxel grid, k-d tree and
covariances, and its scene-sized finer grid.

Clouds: the **whole** cropped scan, ground included, on a ``polish_voxel`` grid, with covariances
(GICP) or normals (point-to-plane ICP) from ``polish_neighbors`` neighbours: exactly the clouds and the
settings of the small_gicp GICP baseline (``deepbbs_ros.baselines``, ``eval.baseline_*`` defaults), so
that, started inside the basin, the stage lands on GICP's own fixed point. (The earlier polish used a
random subset of 3000 non-ground voxels plus 1500 ground points and a 1 m correspondence distance:
another cost function, whose optimum lay 1-3 cm off GICP's.) Each scan's cloud is prepared once
(:func:`prepare_polish_cloud`, called by ``DeepBBSRegistration.preprocess``) and kept in its
``PreprocessResult``, so in odometry and in the node every scan pays for it once. A part of a larger prepared
cloud (a map crop) is a ``core.polish_view.PolishView``. No ROS import.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.core.threads import threads_or_all

__all__ = ["MIN_POLISH_POINTS", "PolishCloud", "finer_pair", "grid_scale", "prepare_polish_cloud", "prepared_cloud",
           "scene_voxel"]

MIN_POLISH_POINTS = 10  # fewer points per cloud (after the voxel grid): no polish


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
    # first asks (:meth:`finer`, core.polish.finish); a scan with none keeps (and pickles) nothing more
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



def prepare_polish_cloud(points: np.ndarray, voxel: float, neighbors: int, *, registration_type: str = "GICP",
                         min_range: float = 0.0, max_range: float = float("inf"), threads: int = 0,
                         defer: bool = False, max_voxels: int = 0, voxel_angle: float = 0.0) -> PolishCloud:
    """Raw scan -> :class:`PolishCloud`: finite points within [min_range, max_range] m, a ``voxel`` m grid
    (0 = none), a k-d tree, and covariances + normals from ``neighbors`` neighbours (``"GICP"``,
    ``"PLANE_ICP"``) or nothing (``"ICP"``). Shared by the precision stage and the small_gicp baselines.

    Args:
        points: (N, 3) float xyz, sensor frame, metres; NaN/Inf rows allowed (dropped).
        threads: small_gicp threads (0 = every core).
        defer: only the voxel grid now; :meth:`PolishCloud.complete` (or ``core.polish.polish``) builds the k-d
            tree and covariances later (``DeepBBSRegistration`` does it while the network process runs).
        max_voxels: at most this many voxels (0 = no cap): a denser grid's centroids go on a coarser grid,
            ``voxel * sqrt(n / max_voxels)`` (a scan's voxels fill surfaces: their count goes as 1 / voxel^2).
        voxel_angle: > 0: the scan's scene-sized grid, this angle (rad) seen from the sensor at the scan's median
            range, within [``voxel`` / 4, ``voxel``] (:func:`scene_voxel`): the cloud stays on ``voxel`` (GICP's
            grid: its basin and its cost); where that grid is finer (``fine_voxel``) the cropped scan is kept to
            build it from when a finish first asks (:meth:`PolishCloud.finer`): a corridor's or a small room's scan
            (median range 1-4 m) gets a grid fine enough for its walls, floor and ceiling, whose corners a ``voxel``
            grid with ``neighbors`` covariances blends, to finish on (core.polish.finish); 0: ``voxel`` only.
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


def finer_pair(source: Any, target: Any) -> tuple[PolishCloud, PolishCloud] | None:
    """Both scans on their scene-sized grids (:meth:`PolishCloud.finer`, built on first use); None when either is no
    :class:`PolishCloud` or has no finer grid."""
    fine = [c.finer() if isinstance(c, PolishCloud) else None for c in (source, target)]
    return None if fine[0] is None or fine[1] is None else (fine[0], fine[1])


def grid_scale(clouds: Any, polish_voxel: float) -> float:
    """The finer of the ``clouds``' grids over ``polish_voxel``, at most 1: how a scene-sized grid scales GICP's
    correspondence distance and the verdict's (the shipped ratio of each to ``polish_voxel``, kept on a finer grid);
    1 when ``polish_voxel`` <= 0 or either cloud has no grid recorded."""
    grids = [getattr(c, "voxel", 0.0) for c in clouds]
    if polish_voxel <= 0 or min(grids) <= 0:
        return 1.0
    return min(1.0, min(grids) / polish_voxel)


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

