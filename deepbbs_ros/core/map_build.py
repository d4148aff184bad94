"""A localization map's part built once (no ROS): the map on its voxel grid and its 10 m cell index, the height grid
and the descriptor's template, the candidate places (the trajectory's keyframes with a lattice beside them,
core/drive_places.py, when it fits the map, core/map_fit.py; else a grid over the drivable space, core/places.py),
their descriptors, and the map's GICP cloud (``localization.shared_cloud``), of which every crop is a view.

A mixin of :class:`~deepbbs_ros.core.localization.MapLocalizer`, whose constructor calls :meth:`MapBuild._build_map`
then :meth:`MapBuild._map_cloud`. Frames as in core/map_localizer.py.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.descriptors import _HeightGrid, _PolarTemplate, _spectra
from deepbbs_ros.core.drive_places import keyframe_places
from deepbbs_ros.core.localization_types import _as_cloud
from deepbbs_ros.core.map_fit import check_trajectory
from deepbbs_ros.core.map_index import _CellIndex, voxel_downsample
from deepbbs_ros.core.polish import SMALL_GICP_TYPE, prepare_polish_cloud
from deepbbs_ros.errors import LocalizationError

MIN_MAP_POINTS = 100  # a map with fewer points is refused
#: bytes per voxel of a small_gicp cloud with covariances and normals (point, normal: 4 doubles; covariance: 16) and
#: its k-d tree (about 32)
CLOUD_BYTES = 224


class MapBuild:
    """The map's part of :class:`~deepbbs_ros.core.localization.MapLocalizer` (module docstring)."""

    def _build_map(self, map_points: np.ndarray, trajectory: np.ndarray | None) -> None:
        """Everything per place (``self.config`` set): points, cell index, height grid, places, descriptors."""
        cfg = self.config
        lc = cfg.localization
        pts = _as_cloud(map_points, "map")
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts) < MIN_MAP_POINTS:
            raise LocalizationError(f"map: {len(pts)} finite points, at least {MIN_MAP_POINTS} are needed")
        self._index = _CellIndex(voxel_downsample(pts, lc.map_voxel), cell=10.0)
        self.points = self._index.points  # (N, 3) float32 the map on its voxel grid (sorted by 10 m cells)
        self.crop_radius = lc.crop_radius or cfg.preprocess.max_range
        self.grid = _HeightGrid(self.points, lc.descriptor_cell, pad=lc.descriptor_radius)
        self.template = _PolarTemplate(lc.descriptor_radius, lc.descriptor_rings, lc.descriptor_sectors,
                                       lc.descriptor_cell)
        self.trajectory_warning = ""  # a trajectory that does not fit the map (core/map_fit.py): grid places instead
        if trajectory is not None:  # its poses off the map (a cropped map) are no place either
            fit = check_trajectory(self.points, trajectory)
            self.trajectory_warning = fit.message
            trajectory = np.asarray(trajectory, dtype=np.float64)[fit.on_map] if fit.fits else None
        if trajectory is not None:
            self._places, self.keyframes = keyframe_places(trajectory, self.grid, lc)
        else:
            self._places = self._grid_places()
            self.keyframes = 0
        if len(self._places) == 0:
            raise LocalizationError("map: no candidate place (no free space with ground under it; give the map's "
                                    "trajectory, or lower localization.free_clearance)")
        self.descriptors = self.template.describe(self.grid, self._places[:, :2, 3])
        skip = min(lc.descriptor_skip_rings, lc.descriptor_rings - 1)
        self._spectra = _spectra(self.descriptors[:, skip:])  # the places' half of every query's match

    def _map_cloud(self) -> tuple[Any, _CellIndex | None]:
        """(the map's GICP cloud in the map frame, its voxel centroids by 10 m cell) when crops are views of it
        (``localization.shared_cloud``), else (None, None)."""
        rc = self.config.registration
        if not self.config.localization.shared_cloud or rc.polish == "none":
            return None, None
        pc = prepare_polish_cloud(self.points, rc.polish_voxel, rc.polish_neighbors,
                                  registration_type=SMALL_GICP_TYPE[rc.polish],
                                  threads=self.registration.gicp_threads())
        return pc, _CellIndex(pc.points(), cell=10.0)

    @property
    def nbytes(self) -> int:
        """Bytes held for the map besides the crops' cache: its points, the height grid, the descriptors, its GICP
        cloud (``shared_cloud``)."""
        g = self.grid
        cloud = 0 if self._cloud is None else self._cloud.n_points * CLOUD_BYTES + self._voxels.points.nbytes
        return int(self.points.nbytes + self._index.starts.nbytes + g.height.nbytes
                   + g.ground.nbytes + g.zmax.nbytes + g.count.nbytes + g.occupied.nbytes + self.descriptors.nbytes
                   + sum(a.nbytes for a in self._spectra) + cloud)

    # -- places ----------------------------------------------------------------------------------------------------
    @property
    def places(self) -> np.ndarray:
        """(P, 4, 4) float64 candidate place poses ``T_map_place`` (gravity-aligned, at the sensor's position)."""
        return self._places

    def _grid_places(self) -> np.ndarray:
        """Places over the map's drivable space (core/places.py): one per ``grid_spacing`` square block, the column
        farthest from obstacles, ``sensor_height`` above its ground (the search puts the scan at its own height)."""
        from deepbbs_ros.core.places import grid_places

        lc, g = self.config.localization, self.grid
        return grid_places(self.points, g.origin, g.cell, g.shape, lc.grid_spacing, lc.free_clearance,
                           lc.sensor_height, lc.map_voxel)
