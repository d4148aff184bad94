"""A scan on a localization map's crop (no ROS): DeepBBS++ from a start, its GICP check judged by the map verdict
(``localization.polish_check_*``, on a coarser lead cloud), the map verdict's acceptance (core/acceptance.py), the
accepted pose's refinement (``localization.refine_corr_dist``) and its covariance (core/covariance.py).

A mixin of :class:`~deepbbs_ros.core.localization.MapLocalizer` (``config``, ``registration``, ``_lead_of``).
Frames as in core/localization.py.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.core import acceptance
from deepbbs_ros.core.covariance import scan_covariance
from deepbbs_ros.core.localization_types import _Crop
from deepbbs_ros.core.polish import SMALL_GICP_TYPE, polish, prepare_polish_cloud


class CandidateChecks:
    """Registration, check, acceptance, refinement and covariance on a crop (module docstring)."""

    def _sensor_height(self, src: Any) -> float | None:
        """The scan's sensor height above its ground plane (m), None without one."""
        g = getattr(src, "ground_plane", None)
        if g is None or abs(g[2]) < 0.5:
            return None
        return float(g[3] / g[2])

    def _register(self, src: Any, crop: _Crop, T_place_scan: np.ndarray, yaw_search: bool = True,
                  judged: bool = False) -> Any:
        """DeepBBS++ of the scan on the crop from T_place_scan (4, 4); ``yaw_search`` False: the given start only;
        ``judged``: its GICP checked by the map verdict too (a global search's candidate, :meth:`_check_at`)."""
        return self.registration.register(src, crop.pre, T_init=T_place_scan, yaw_search=yaw_search,
                                          polish_check=self._check_at(src, crop) if judged else self._check)

    @property
    def _check(self) -> tuple[int, float] | None:
        """The GICP check of a candidate place (``localization.polish_check_*``; core.polish.polish's ``check``)."""
        lc = self.config.localization
        return (lc.polish_check_iters, lc.polish_check_score) if lc.polish_check_iters > 0 else None

    def _check_at(self, src: Any, crop: _Crop) -> tuple | None:
        """:attr:`_check` with the map verdict as its judge on ``crop`` (``localization.polish_check_probability``)."""
        check = self._check
        if check is None:
            return None
        lead = self._lead(src)
        judge = self._judge(src, crop)
        return check if judge is None and lead is None else (*check, judge, lead)

    def _lead(self, src: Any) -> Any:
        """The scan's GICP cloud on a coarser grid of about ``localization.polish_check_voxels`` voxels for a candidate
        GICP's first leg up to its check (core.polish.polish's ``check``), built once per scan; None when that is 0 or
        the cloud has no more voxels than that."""
        n, pc = self.config.localization.polish_check_voxels, getattr(src, "polish_cloud", None)
        if n <= 0 or pc is None or pc.n_points <= n:
            return None
        if self._lead_of is not None and self._lead_of[0] is pc:
            return self._lead_of[1]
        rc = self.config.registration
        lead = prepare_polish_cloud(pc.points(), rc.polish_voxel, rc.polish_neighbors, max_voxels=n,
                                    registration_type=SMALL_GICP_TYPE.get(rc.polish, "GICP"),
                                    threads=self.registration.gicp_threads())
        lead = lead if lead.n_points < pc.n_points else None
        self._lead_of = (pc, lead)
        return lead

    def _judge(self, src: Any, crop: _Crop) -> Any:
        """The GICP check's judge of a candidate's pose (T_place_scan (4, 4) -> go on?): the map verdict's probability
        at least ``localization.polish_check_probability``; None when that is 0."""
        bar = self.config.localization.polish_check_probability
        if bar <= 0:
            return None
        return lambda T: acceptance.probability(src, crop, crop.T_map_place @ T, self.config) >= bar

    # -- acceptance (core/acceptance.py) ---------------------------------------------------------------------------
    @property
    def _threshold(self) -> float:
        return acceptance.threshold(self.config)

    def _accepts_at(self, src: Any, crop: _Crop, T_map_scan: np.ndarray) -> bool:
        """The map verdict accepts the scan at ``T_map_scan`` on ``crop``, and the pose has no second minimum as good
        (core/acceptance.py ``accepts_pose``)."""
        return acceptance.accepts_pose(src, crop, T_map_scan, self.config)

    # -- GICP: refine, covariance ----------------------------------------------------------------------------------
    def _refine(self, src: Any, crop: _Crop, T_map_scan: np.ndarray, timings: dict[str, float]) -> np.ndarray:
        """T_map_scan refined by a second GICP on the same clouds with ``refine_corr_dist`` (the registration's wider
        correspondence distance lets far pairs pull the pose along a road with few features); kept when it does not
        converge or moves more than 1 m / 2 deg (and when there is no refinement)."""
        import dataclasses

        lc, rc = self.config.localization, self.config.registration
        if lc.refine_corr_dist <= 0 or rc.polish == "none" or src.polish_cloud is None or crop.pre.polish_cloud is None:
            return T_map_scan
        t = time.perf_counter()
        cfg = dataclasses.replace(rc, polish_max_corr_dist=lc.refine_corr_dist, polish_max_trans=1.0,
                                  polish_max_rot_deg=2.0)
        pol = polish(src.polish_cloud, crop.pre.polish_cloud, np.linalg.inv(crop.T_map_place) @ T_map_scan, cfg)
        timings["refine"] = timings.get("refine", 0.0) + (time.perf_counter() - t) * 1e3
        return crop.T_map_place @ pol.T_target_source if pol.applied else T_map_scan

    def _covariance(self, src: Any, crop: _Crop, T_map_scan: np.ndarray,
                    timings: dict[str, float]) -> np.ndarray | None:
        """The covariance of a valid ``T_map_scan`` (core/covariance.py: cluster-robust, from the GICP pairs at the
        pose), timed into ``covariance``."""
        t = time.perf_counter()
        cov = scan_covariance(src.polish_cloud, crop.pre.polish_cloud, crop.T_map_place, T_map_scan, self.config,
                              self.registration.gicp_threads())
        timings["covariance"] = (time.perf_counter() - t) * 1e3
        return cov


