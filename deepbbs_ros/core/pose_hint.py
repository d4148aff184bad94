"""A pose hint (an operator's initial pose, RViz's "2D Pose Estimate", Nav2's ``/initialpose``; no ROS): the search
near it, in two halves. :class:`HintSearch`, a mixin of :class:`~deepbbs_ros.core.localization.MapLocalizer`:
registration from the hint (``localize_near``, DeepBBS++ on the crop nearest it, from each yaw in turn).
:class:`HintSteps`, a mixin of :class:`~deepbbs_ros.core.tracking.MapTracker`: a hint kept until the next scan
(``hint``), that scan registered from it at ``HINT_YAW_STEP`` steps within its yaw window, then the places within its
reach searched, an answer accepted only within that reach. Frames as in core/map_localizer.py.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.core.localization_types import LocalizationResult, PreparedScan, _rz, _yaw
from deepbbs_ros.errors import LocalizationError

#: MapTracker.hint: the places within this many standard deviations of the hint's position are searched first, and an
#: answer within as many of its yaw accepted; at least HINT_MIN_RADIUS m / HINT_MIN_YAW rad (an exact hint)
HINT_SIGMAS, HINT_MIN_RADIUS, HINT_MIN_YAW = 3.0, 10.0, np.radians(30.0)
#: MapTracker.hint: DeepBBS++ starts from the hint's yaw, and this far apart either side within its yaw window
HINT_YAW_STEP = np.radians(45.0)


class HintSearch:
    """Registration from a pose hint for :class:`~deepbbs_ros.core.localization.MapLocalizer` (module docstring)."""

    def localize_near(self, scan: Any, T_hint: np.ndarray, yaws: Any = (0.0,)) -> LocalizationResult:
        """The pose of ``scan`` (raw (N, 3) or a :class:`PreparedScan`) registered from a pose hint ``T_hint``
        (``T_map_scan`` (4, 4); its height replaced by the scan's own above the map's ground there) turned by each of
        ``yaws`` (rad) in turn, on the crop nearest it: DeepBBS++ from each start, the first the verdict accepts (mode
        "hint"); none: not valid, the best of them."""
        t0 = time.perf_counter()
        timings: dict[str, float] = {}
        prepared = scan if isinstance(scan, PreparedScan) else self.prepare(scan)
        src = prepared.pre
        T = np.asarray(T_hint, dtype=np.float64).copy()
        d = np.linalg.norm(self._places[:, :2, 3] - T[:2, 3], axis=1)
        near = int(np.argmin(d))
        if d[near] <= max(self.config.localization.place_spacing, 0.25 * self.crop_radius):
            crop = self._crop(near)
        else:  # off the places: a crop at the hint
            C = np.eye(4)
            C[:3, 3] = T[:3, 3]
            near, crop = -1, self._crop(-1, C)
        h, g = self._sensor_height(src), self.grid.ground_at(T[None, :2, 3], np.nan)[0]
        if h is not None and np.isfinite(g):
            T[2, 3] = g + h
        best = LocalizationResult(T, False, float("nan"), "hint", "no start from the hint passed the verdict",
                                  candidates=0, path="deepbbs", place=near)
        for yaw in yaws:
            t = time.perf_counter()
            reg = self._register(src, crop, np.linalg.inv(crop.T_map_place) @ T @ _rz(float(yaw)), yaw_search=False)
            timings["register"] = timings.get("register", 0.0) + (time.perf_counter() - t) * 1e3
            best.candidates += 1
            T_map_scan = crop.T_map_place @ reg.T_target_source
            if self._accepts_at(src, crop, T_map_scan):
                res = self._tracked(src, crop, T_map_scan, float(reg.score), "deepbbs", near, timings)
                res.mode, res.candidates = "hint", best.candidates
                best = res
                break
            if not (reg.score <= best.score):  # nan-safe: the better one
                best.T_map_scan, best.score = T_map_scan, float(reg.score)
        best.timings_ms = timings
        timings["total"] = (time.perf_counter() - t0) * 1e3
        return best


class HintSteps:
    """A pending pose hint for :class:`~deepbbs_ros.core.tracking.MapTracker` (module docstring)."""

    def hint(self, T_map_scan: np.ndarray, covariance: np.ndarray | None = None) -> None:
        """A pose hint (an operator's initial pose, RViz's "2D Pose Estimate"): forget the pose, and the next
        :meth:`step` registers the scan from the hint (:meth:`MapLocalizer.localize_near`: its yaw, and
        ``HINT_YAW_STEP`` steps within ``HINT_SIGMAS`` sigma of it), then searches the places within ``HINT_SIGMAS``
        standard deviations of its position (at least ``HINT_MIN_RADIUS`` m), accepting an answer only within that reach
        and ``HINT_SIGMAS`` sigma of its yaw (at least ``HINT_MIN_YAW``); when the verdict rejects there, the whole map.
        ``T_map_scan`` (4, 4); ``covariance`` (6, 6) x y z rot x rot y rot z (None: the minimum reach)."""
        T = np.asarray(T_map_scan, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise LocalizationError(f"hint: expected a finite (4, 4) T_map_scan, got shape {T.shape}")
        cov = np.zeros((6, 6)) if covariance is None else np.nan_to_num(np.asarray(covariance, dtype=np.float64))
        sigma_xy = float(np.sqrt(max(cov[0, 0], cov[1, 1], 0.0)))
        sigma_yaw = float(np.sqrt(max(cov[5, 5], 0.0)))
        self.reset()
        self._hint = (T, max(HINT_SIGMAS * sigma_xy, HINT_MIN_RADIUS), max(HINT_SIGMAS * sigma_yaw, HINT_MIN_YAW))

    def _step_hint(self, scan: Any) -> LocalizationResult | None:
        """The search near a pending :meth:`hint` (consumed) for a :class:`PreparedScan`: DeepBBS++ from the hint,
        then the places within its reach; the result when the verdict accepts a pose within its reach, else None (the
        caller searches the whole map)."""
        T_hint, radius, max_yaw = self._hint
        self._hint = None
        # DeepBBS++ from the hint, at its yaw, then HINT_YAW_STEP either side within its window
        steps = np.arange(1, int(min(max_yaw, np.pi) / HINT_YAW_STEP) + 1) * HINT_YAW_STEP
        yaws = [0.0] + [s * y for y in steps for s in (1.0, -1.0)]
        res = self.localizer.localize_near(scan, T_hint, yaws)
        if res.valid and self._near(res, T_hint, radius, max_yaw):
            return res
        xy = self.localizer.places[:, :2, 3]
        d = np.linalg.norm(xy - T_hint[:2, 3], axis=1)
        among = np.flatnonzero(d <= radius)
        if len(among) == 0:
            among = np.argsort(d)[:1]  # the hint off the places: the nearest one
        res = self.localizer.localize(scan, None, among=among)
        if not res.valid or not self._near(res, T_hint, radius, max_yaw):
            return None  # no pose, or one outside the hint's reach: the whole map decides
        res.mode = "hint"
        return res

    @staticmethod
    def _near(res: LocalizationResult, T_hint: np.ndarray, radius: float, max_yaw: float) -> bool:
        """Whether a pose lies within a hint's reach: ``radius`` m and ``max_yaw`` rad of its yaw."""
        off = float(np.linalg.norm(res.T_map_scan[:2, 3] - T_hint[:2, 3]))
        turn = abs(float(np.angle(np.exp(1j * (_yaw(res.T_map_scan) - _yaw(T_hint))))))
        return off <= radius and (max_yaw >= np.pi or turn <= max_yaw)
