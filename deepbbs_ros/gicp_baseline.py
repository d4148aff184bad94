"""The small_gicp baselines (no ROS): point-to-point ICP, point-to-plane ICP and GICP on the baseline's clouds
(``eval.baseline_input``: dense, ground kept, or DeepBBS++'s own preprocessing; see :mod:`deepbbs_ros.baselines`),
and the result every baseline registration returns. ``T_target_source`` as ``small_gicp.align(target, source,
init_T_target_source)`` gives it (CONVENTIONS.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.points import as_transform, as_xyz
from deepbbs_ros.core.polish import prepare_polish_cloud, threads_or_all
from deepbbs_ros.errors import ConfigError, RegistrationError
from deepbbs_ros.reprs import short_repr

#: replay method name -> small_gicp ``registration_type``
SMALL_GICP_TYPES = {"icp": "ICP", "plane-icp": "PLANE_ICP", "gicp": "GICP"}


@dataclass
class BaselineResult:
    """Result of one baseline registration.

    Attributes:
        T_target_source: (4, 4) float64.
        converged: the solver's own convergence flag.
        iterations: solver iterations.
        num_inliers: correspondences within ``max_correspondence_distance`` at the end.
        timings_ms: ``{"preprocess", "register", "total"}`` (preprocess 0 when inputs were prepared).
    """

    __repr__ = short_repr  # one readable line: arrays as shape and dtype (deepbbs_ros/reprs.py)

    T_target_source: np.ndarray
    converged: bool
    iterations: int
    num_inliers: int
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class PreparedCloud:
    """A cloud ready for small_gicp: the downsampled ``PointCloud`` (normals/covariances as needed) and its
    ``KdTree``; ``n_points`` after downsampling; ``preprocess_ms`` the time it took."""

    cloud: Any
    tree: Any
    n_points: int
    preprocess_ms: float


class SmallGicpRegistration:
    """Point-to-point ICP, point-to-plane ICP or GICP from ``small_gicp``.

    Args:
        method: ``"icp"``, ``"plane-icp"`` or ``"gicp"``.
        config: the package config; uses ``preprocess`` (crop ranges, or the whole DeepBBS++
            preprocessing when ``eval.baseline_input == "deepbbs"``) and the ``eval.baseline_*`` keys.
        threads: small_gicp threads (0 = every core); None = ``eval.threads`` (an offline run's). The GICP anchor
            node passes ``registration.polish_threads``, the threads of the DeepBBS++ node's precision stage.
    """

    def __init__(self, method: str, config: Config | None = None, threads: int | None = None) -> None:
        if method not in SMALL_GICP_TYPES:
            raise ConfigError(f"unknown small_gicp method {method!r} (known: {', '.join(SMALL_GICP_TYPES)})")
        self.method = method
        self.registration_type = SMALL_GICP_TYPES[method]
        self.config = config or Config()
        self.num_threads = threads_or_all(self.config.eval.threads if threads is None else threads)

    # -- preprocessing ------------------------------------------------------------------------------
    def preprocess(self, points: np.ndarray) -> PreparedCloud:
        """Raw scan (N, 3) float32/64 in its sensor frame -> :class:`PreparedCloud` (NaN rows dropped).

        Raises:
            RegistrationError: not an (N, 3) real array, empty (:mod:`deepbbs_ros.core.points`), or fewer
                than 10 points survive.
        """
        ev, pp = self.config.eval, self.config.preprocess
        t0 = time.perf_counter()
        points = as_xyz(points, self.method, dtype=None)  # (N, 3) only, as every entry point (core/points.py)
        if ev.baseline_input == "deepbbs":
            from deepbbs_ros.core.preprocess import preprocess

            pts = np.asarray(preprocess(points, pp, seed=pp.seed).points, dtype=np.float64)
            prep = prepare_polish_cloud(pts, 0.0, ev.baseline_neighbors, registration_type=self.registration_type,
                                        threads=self.num_threads)
        else:  # the same clouds as DeepBBS++'s GICP precision stage (core/polish.py)
            prep = prepare_polish_cloud(points, ev.baseline_voxel_size, ev.baseline_neighbors,
                                        registration_type=self.registration_type, min_range=pp.min_range,
                                        max_range=pp.max_range, threads=self.num_threads)
            if prep.n_cropped < 10:
                raise RegistrationError(f"{self.method}: only {prep.n_cropped} points within the crop range")
        cloud, tree, n = prep.cloud, prep.tree, prep.n_points
        if n < 10:
            raise RegistrationError(f"{self.method}: only {n} points left after preprocessing (need >= 10)")
        return PreparedCloud(cloud, tree, n, (time.perf_counter() - t0) * 1e3)

    # -- registration -------------------------------------------------------------------------------
    def align(
        self, source: PreparedCloud, target: PreparedCloud, T_init: np.ndarray | None = None
    ) -> BaselineResult:
        """Register prepared clouds; returns ``T_target_source`` starting from ``T_init`` (identity if None)."""
        import small_gicp

        ev = self.config.eval
        init = np.eye(4) if T_init is None else as_transform(T_init)
        t0 = time.perf_counter()
        res = small_gicp.align(
            target.cloud,
            source.cloud,
            target.tree,
            init_T_target_source=init,
            registration_type=self.registration_type,
            max_correspondence_distance=ev.baseline_max_corr_dist,
            num_threads=self.num_threads,
            max_iterations=ev.baseline_max_iters,
        )
        reg_ms = (time.perf_counter() - t0) * 1e3
        T = np.asarray(res.T_target_source, dtype=np.float64).copy()
        return BaselineResult(
            T_target_source=T,
            converged=bool(res.converged),
            iterations=int(res.iterations),
            num_inliers=int(res.num_inliers),
            timings_ms={"preprocess": 0.0, "register": reg_ms, "total": reg_ms},
        )

    def register(self, source: np.ndarray, target: np.ndarray, T_init: np.ndarray | None = None) -> BaselineResult:
        """Raw scans (N, 3), (M, 3) -> ``T_target_source``; timings include both preprocessings."""
        src = self.preprocess(source)
        tgt = self.preprocess(target)
        res = self.align(src, tgt, T_init)
        pre = src.preprocess_ms + tgt.preprocess_ms
        res.timings_ms.update(preprocess=pre, total=pre + res.timings_ms["register"])
        return res
