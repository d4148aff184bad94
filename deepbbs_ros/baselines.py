"""Classical baselines that DeepBBS++ is compared with: small_gicp ICP / point-to-plane ICP / GICP, KISS-ICP.

No ROS import. Transforms follow docs/CONVENTIONS.md: registration of ``source`` against ``target`` returns
``T_target_source`` (4, 4) float64 with ``p_target = R @ p_source + t`` — the same direction as
``small_gicp.align(target, source, init_T_target_source)``, pinned by ``tests/test_baselines.py``.

Input clouds ("which preprocessing"):

* ``eval.baseline_input = "dense"`` (default): crop to ``[preprocess.min_range, preprocess.max_range]``
  then a voxel grid of ``eval.baseline_voxel_size`` metres, **ground kept**. ICP-type methods need
  dense, ground-bearing clouds (the ground pins z, roll and pitch); on DeepBBS++'s 1000 non-ground
  points they are handicapped.
* ``eval.baseline_input = "deepbbs"``: exactly DeepBBS++'s preprocessing (crop, ground removal,
  voxel grid, farthest-point sampling to ``preprocess.num_points``).

KISS-ICP always runs its own pipeline on the raw scan (adaptive threshold, local voxel map, motion
compensation), with the same crop ranges; that is the point of the baseline.

Here: KISS-Matcher; KISS-ICP is :mod:`deepbbs_ros.kiss_icp_baseline`'s, the small_gicp baselines and the result type
:mod:`deepbbs_ros.gicp_baseline`'s, :func:`one_cpu` :mod:`deepbbs_ros.one_cpu`'s (all exported here too).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.points import as_transform, as_xyz
from deepbbs_ros.errors import ConfigError, RegistrationError
from deepbbs_ros.gicp_baseline import (  # noqa: F401  (re-exported)
    SMALL_GICP_TYPES,
    BaselineResult,
    PreparedCloud,
    SmallGicpRegistration,
)
from deepbbs_ros.kiss_icp_baseline import KissICPOdometry  # noqa: F401  (re-exported)
from deepbbs_ros.one_cpu import _current_cpu, one_cpu  # noqa: F401  (re-exported)


@dataclass
class MatcherCloud:
    """A scan ready for KISS-Matcher: the cropped points (N, 3) float32 (KISS-Matcher voxelises them itself),
    and, for ``kiss-matcher+gicp``, the GICP baseline's cloud; ``preprocess_ms`` the time it took."""

    points: np.ndarray
    gicp: PreparedCloud | None
    preprocess_ms: float


class KissMatcherRegistration:
    """KISS-Matcher (``kiss_matcher``, MIT SPARK): a global registration (FPFH-like features, graph-based
    outlier pruning, GNC solver) that needs no initial guess; ``kiss-matcher+gicp`` refines its answer with
    the small_gicp GICP baseline on the baseline's clouds (``eval.baseline_*``).

    A global method ignores the start guess; to register "from a start" ``T_init`` honestly, :meth:`align`
    moves the source points by ``T_init`` (what a wrong start means for the clouds) and composes the answer
    back, so every trial sees another cloud. Args: ``method`` "kiss-matcher" or "kiss-matcher+gicp";
    ``config`` uses the preprocess crop, ``eval.kiss_matcher_voxel`` and the ``eval.baseline_*`` keys.
    """

    def __init__(self, method: str, config: Config | None = None) -> None:
        if method not in ("kiss-matcher", "kiss-matcher+gicp"):
            raise ConfigError(f"unknown KISS-Matcher method {method!r}")
        try:
            import kiss_matcher  # noqa: F401
        except ImportError as err:  # an optional wheel on exotic platforms
            raise ConfigError(f"{method}: the kiss-matcher package is not installed ({err})") from err
        self.method = method
        self.config = config or Config()
        self.gicp = SmallGicpRegistration("gicp", self.config) if method.endswith("+gicp") else None
        self._one_cpu = self.config.eval.threads == 1  # see one_cpu: KISS-Matcher has no thread setting

    def preprocess(self, points: np.ndarray) -> MatcherCloud:
        """Raw scan (N, 3) -> :class:`MatcherCloud` (finite points within the preprocess crop)."""
        from deepbbs_ros.core.preprocess import crop_range

        pp = self.config.preprocess
        t0 = time.perf_counter()
        pts = as_xyz(points, self.method, dtype=None)
        pts = np.ascontiguousarray(np.compress(crop_range(pts, pp.min_range, pp.max_range), pts, axis=0),
                                   dtype=np.float32)
        if len(pts) < 10:
            raise RegistrationError(f"{self.method}: only {len(pts)} points within the crop range")
        gicp = self.gicp.preprocess(points) if self.gicp is not None else None
        return MatcherCloud(pts, gicp, (time.perf_counter() - t0) * 1e3)

    def align(self, source: MatcherCloud, target: MatcherCloud, T_init: np.ndarray | None = None) -> BaselineResult:
        """-> ``T_target_source``; ``T_init`` only moves the source cloud (see the class)."""
        import kiss_matcher

        P = np.eye(4) if T_init is None else as_transform(T_init)
        t0 = time.perf_counter()
        src = source.points if np.allclose(P, np.eye(4)) else \
            np.ascontiguousarray(source.points @ P[:3, :3].T.astype(np.float32) + P[:3, 3].astype(np.float32))
        voxel = self.config.eval.kiss_matcher_voxel
        matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel_size=voxel))
        with one_cpu(self._one_cpu):
            sol = matcher.estimate(src, target.points)
        T = np.eye(4)
        T[:3, :3] = np.asarray(sol.rotation, dtype=np.float64)
        T[:3, 3] = np.asarray(sol.translation, dtype=np.float64).reshape(3)
        T = T @ P  # the answer for the moved source, composed back: T_target_source of the original source
        inliers = int(matcher.get_num_final_inliers())
        converged, iterations = bool(sol.valid), 0
        if self.gicp is not None and source.gicp is not None and target.gicp is not None:
            g = self.gicp.align(source.gicp, target.gicp, T)
            T, converged, iterations, inliers = g.T_target_source, bool(sol.valid) and g.converged, g.iterations, \
                g.num_inliers
        ms = (time.perf_counter() - t0) * 1e3
        return BaselineResult(T_target_source=T, converged=converged, iterations=iterations, num_inliers=inliers,
                              timings_ms={"preprocess": 0.0, "register": ms, "total": ms})
