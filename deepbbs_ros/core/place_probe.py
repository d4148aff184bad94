"""The global search's probes (no ROS): :class:`PlaceProbes`, the part of
:class:`~deepbbs_ros.core.place_search.PlaceSearch` that runs GICP from starts around the best answer (``_probe``) to
find a better optimum nearby or a pose that slides (a rival), on a coarser cloud of the scan (``_probe_cloud``). A
mixin: it works on the localizer's registration and configuration and on the search's ``_answer``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.localization_types import _Answer, _heading
from deepbbs_ros.core.polish import SMALL_GICP_TYPE, polish, prepare_polish_cloud

MIN_PROBE_POINTS = 200  # a probe cloud on localization.probe_voxel with fewer voxels: the scan's own cloud instead


class PlaceProbes:
    """The probes of :class:`~deepbbs_ros.core.place_search.PlaceSearch` (module docstring)."""

    def _probe(self, src: Any, best: _Answer) -> list[_Answer]:
        """GICP on the best answer's crop from starts ``ambiguity_probe`` m off its pose along +-x, +-y of the map
        and ``far_probe`` m ahead, behind and to either side of its heading: -> their answers (a pose pinned down
        brings each back; on a featureless stretch they stay off with as good a score; a better score is a better
        optimum nearby: the next lane, the next repeat of a facade along the street)."""
        from deepbbs_ros.core import verdict

        lc, rc = self.config.localization, self.config.registration
        crop = best.crop
        if lc.ambiguity_probe <= 0 or src.polish_cloud is None or crop.pre.polish_cloud is None:
            return []
        src_pc, tgt_pc = src.polish_cloud, crop.pre.polish_cloud
        for pc in (src_pc, tgt_pc):
            if getattr(pc, "pending", None) is not None:
                pc.complete(threads=self.registration.gicp_threads())
        src_pc = self._probe_cloud(src_pc)
        T = np.linalg.inv(crop.T_map_place) @ best.T
        starts = [np.array([dx, dy], np.float64) * lc.ambiguity_probe for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))]
        head = _heading(T)
        if lc.far_probe > 0:  # the lanes either side of the heading, and as far along it
            starts += [side * lc.far_probe * d for d in (np.array([-head[1], head[0]]), head) for side in (1.0, -1.0)]
        out = []
        for off in starts:
            S = T.copy()
            S[:2, 3] += off
            pol = polish(src_pc, tgt_pc, S, rc, check=self._check)
            if not pol.applied:
                continue
            score = verdict.fitness(src.points, tgt_pc.tree, pol.T_target_source, rc.verdict_dist)
            out.append(self._answer(score, crop.T_map_place @ pol.T_target_source, best.place, crop, src, probe=True))
        return out

    def _probe_cloud(self, pc: Any) -> Any:
        """The scan's GICP cloud for the probe: its voxel centroids on a ``localization.probe_voxel`` m grid (a probe
        asks whether a start comes back, not where to the centimetre; the pose it finds is refined on the whole cloud),
        or the cloud itself (``probe_voxel`` 0, or fewer than MIN_PROBE_POINTS voxels on that grid)."""
        v = self.config.localization.probe_voxel
        if v <= 0:
            return pc
        rc = self.config.registration
        coarse = prepare_polish_cloud(pc.points(), v, rc.polish_neighbors,
                                      registration_type=SMALL_GICP_TYPE.get(rc.polish, "GICP"),
                                      threads=self.registration.gicp_threads())
        return coarse if coarse.n_points >= MIN_PROBE_POINTS else pc
