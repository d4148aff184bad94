"""The odometry's starts other than the prediction (no ROS import): DeepBBS++'s registration of the scan against the
previous one (no prior needed), the prediction refined coarse to fine against the previous scan, and the first
motion searched along the direction its data pin least (core/odometry_first.py). A start wins over the prediction's
alignment only with a better fit by ``odometry.fit_margin``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import degeneracy as _deg
from deepbbs_ros.core import first_motion as _first
from deepbbs_ros.core import odometry_first as _search
from deepbbs_ros.core.local_map import LocalMap
from deepbbs_ros.errors import RegistrationError

__all__ = ["OdometryStarts"]


class OdometryStarts:
    """Part of :class:`~deepbbs_ros.core.odometry.DeepBBSOdometry`: the other starts of a suspect frame."""

    # what it reads of the DeepBBSOdometry it is part of
    config: Config
    threads: int
    frames: int
    pose: np.ndarray
    period: float
    voxel_size: float
    driver: str | None
    registration: Any
    deepbbs_calls: int
    deepbbs_rejected: int
    _local: LocalMap
    _prev_points: np.ndarray | None
    _prev_pp: Any
    _cur_pp: Any
    _deepbbs_path: str
    _align: Callable[..., tuple[np.ndarray, float]]  # DeepBBSOdometry._align: the scan on the local map
    _hold: Callable[..., tuple[np.ndarray, _deg.Degeneracy]]  # DeepBBSOdometry._hold: the weak directions held

    def _other_starts(self, frame: np.ndarray, cloud: Any, prior: np.ndarray, pose: np.ndarray, fit: float,
                      deg: _deg.Degeneracy) -> tuple[np.ndarray, float, bool, str, _deg.Degeneracy]:
        """The other starts of a suspect frame: DeepBBS++'s (no prior needed) and, after the first motion (whose start
        already was), the prediction refined coarse to fine against the previous scan (a wider basin than the map's
        voxel); the constant-velocity track (``pose``, ``fit``, ``deg``) stands unless a start's alignment fits
        better by ``odometry.fit_margin``. -> (pose, fit, won = DeepBBS++'s start won, path, degeneracy)."""
        won, path = False, "gicp"
        starts = []
        T_prev_k = self._deepbbs(frame)
        if T_prev_k is not None:
            starts.append((self.pose @ T_prev_k, True, self._deepbbs_path))
        if self.frames > 1:
            starts.append((self._coarse_start(frame, prior), False, "gicp"))
        for init_b, deep, path_b in starts:
            pose_b, fit_b = self._align(cloud, init_b)
            pose_b, deg_b = self._hold(pose_b, init_b, cloud)
            if fit_b > fit + self.config.odometry.fit_margin:
                pose, fit, won, path, deg = pose_b, fit_b, deep, path_b, deg_b
        return pose, fit, won, path, deg

    def _along(self, frame: np.ndarray, cloud: Any, pose: np.ndarray, fit: float,
               deg: _deg.Degeneracy) -> tuple[np.ndarray, float, _deg.Degeneracy, Any]:
        """The first motion searched along the weakest direction of its alignment, above the floor
        (core/odometry_first.py): -> (pose, fit, degeneracy, the search)."""
        oc = self.config.odometry
        self._align(cloud, pose, 1)  # the Hessian at the answer so far
        w, V = np.linalg.eigh(0.5 * (self._local.hessian[3:, 3:] + self._local.hessian[3:, 3:].T))
        if not (np.isfinite(w).all() and w[-1] > 0):
            return pose, fit, deg, None
        reach = _search.TOP_SPEED * (self.period if self.period > 0 else 0.1)
        res = _search.search_along(_search.above_floor(self._prev_points, self.config.preprocess),
                                  _search.above_floor(frame, self.config.preprocess), pose, pose[:3, :3] @ V[:, 0],
                                  reach, self.voxel_size, oc.max_corr_dist, oc.fit_margin, oc.neighbors, self.threads)
        if res.won:
            pose, fit = self._align(cloud, res.pose)
            deg = _deg.analyse(self._local.hessian, pose[:3, :3], oc.degenerate_ratio)
        return pose, fit, deg, res

    def _coarse_start(self, frame: np.ndarray, start: np.ndarray) -> np.ndarray:
        """``start`` (4, 4, the first scan's frame) refined on the coarse levels against the previous scan."""
        oc = self.config.odometry
        rel = _first.coarse_start(self._prev_points, frame, self.voxel_size, oc.max_corr_dist, oc.neighbors,
                                  self.threads, np.linalg.inv(self.pose) @ start)
        return self.pose @ rel

    def _deepbbs(self, frame: np.ndarray) -> np.ndarray | None:
        """DeepBBS++ ``T_{k-1}_k`` of the (deskewed) scan against the previous one; None if it fails."""
        reg = self.registration
        try:
            if self._prev_pp is None and self._prev_points is not None:
                self._prev_pp = self._preprocess(self._prev_points)
            cur = self._preprocess(frame)
            if self._prev_pp is None:
                return None
            res = reg.register(cur, self._prev_pp)
        except RegistrationError:
            return None
        self._cur_pp = cur
        self.deepbbs_calls += 1
        self._deepbbs_path = getattr(res, "path", "deepbbs")
        if not getattr(res, "valid", True):  # the verdict rejected it (no start registered the two scans)
            self.deepbbs_rejected += 1
            return None
        return res.T_target_source

    def _preprocess(self, frame: np.ndarray) -> Any:
        """DeepBBS++'s preprocessing of a (deskewed) scan, with :attr:`driver` when one is known."""
        kwargs = {} if self.driver is None else {"driver": self.driver}
        return self.registration.preprocess(frame.astype(np.float32), **kwargs)
