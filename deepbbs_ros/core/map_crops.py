"""A localization map's crops (no ROS): the map within ``localization.crop_radius`` of a place, in the place's frame,
prepared for registration (a view of the map's GICP cloud with ``localization.shared_cloud``, else a cloud of its own)
and kept in an LRU of ``localization.crop_cache``; :meth:`MapCrops.prefetch` prepares the next one ahead of tracking.

A mixin of :class:`~deepbbs_ros.core.localization.MapLocalizer`, which builds the map (``_index``, ``_places``,
``_cloud``, ``_voxels``, ``_crops``, ``crop_radius``). Frames as in core/localization.py.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core.localization_types import MIN_SCAN_POINTS, _Crop
from deepbbs_ros.core.map_index import _CellIndex
from deepbbs_ros.core.polish import PolishView
from deepbbs_ros.core.preprocess import crop_range
from deepbbs_ros.core.scans import prepare_view
from deepbbs_ros.errors import LocalizationError


class MapCrops:
    """The crops of :class:`~deepbbs_ros.core.localization.MapLocalizer`'s places (module docstring)."""

    # -- crops -----------------------------------------------------------------------------------------------------
    def crop_points(self, T_map_place: np.ndarray) -> np.ndarray:
        """(M, 3) float32 map points within ``crop_radius`` (horizontally) of the place, in the place's frame."""
        return self._local(self._index, T_map_place).astype(np.float32)

    def _local(self, index: _CellIndex, T_map_place: np.ndarray) -> np.ndarray:
        """(M, 3) float64 the points of ``index`` within ``crop_radius`` (horizontally) of the place, in its frame."""
        c = T_map_place[:3, 3]
        return (index.within(c[:2], self.crop_radius).astype(np.float64) - c) @ T_map_place[:3, :3]

    def _view_points(self, T_map_place: np.ndarray) -> np.ndarray:
        """(M, 3) float64 the map's GICP voxel centroids within ``crop_radius`` (horizontally) of the place and within
        the scans' range (``preprocess.min_range``, ``max_range``) of it, in the place's frame (the crop of a scan
        taken there)."""
        pts = self._local(self._voxels, T_map_place)
        if not len(pts):  # no map there: _crop says so (crop_range would refuse the empty cloud)
            return pts
        pp = self.config.preprocess
        return np.compress(crop_range(pts, pp.min_range, pp.max_range), pts, axis=0)

    def _crop(self, place: int, T_map_place: np.ndarray | None = None) -> _Crop:
        """The preprocessed crop of place ``place`` (LRU), or (``place`` -1) one at ``T_map_place`` (not kept)."""
        if place >= 0 and place in self._crops:
            self._crops.move_to_end(place)
            return self._crops[place]
        T = self._places[place] if place >= 0 else T_map_place
        local = self.crop_points(T) if self._cloud is None else self._view_points(T)
        if len(local) < MIN_SCAN_POINTS:
            raise LocalizationError(f"map: {len(local)} points within {self.crop_radius:.0f} m of "
                                    f"[{T[0, 3]:.1f}, {T[1, 3]:.1f}]")
        if self._cloud is None:
            crop = _Crop(T.copy(), self.registration.preprocess(local))
        else:  # a view of the map's GICP cloud: nothing to prepare but the network's points
            crop = _Crop(T.copy(), prepare_view(self.config, PolishView.of(self._cloud, local, T)))
        if place >= 0:
            self._crops[place] = crop
            while len(self._crops) > self.config.localization.crop_cache:
                self._crops.popitem(last=False)
        return crop


    def prefetch(self, T_map_scan: np.ndarray) -> int:
        """Prepare and keep the crop that tracking a scan at ``T_map_scan`` (4, 4) would register on (the place
        nearest it, once the crop tracked now no longer reaches it), so that the scan that reaches a new place does
        not wait for its crop. Meant for a background thread while :meth:`localize` tracks on another (the node: with
        the pose predicted a second ahead); a kept crop is only added, never evicted, here. Returns the place
        prepared, -1 when the tracked crop still serves, the crop is kept already, or the pose is off the places."""
        lc = self.config.localization
        T = np.asarray(T_map_scan, dtype=np.float64)
        d = np.linalg.norm(self._places[:, :2, 3] - T[:2, 3], axis=1)
        near = int(np.argmin(d))
        reach = max(lc.place_spacing, 0.25 * self.crop_radius)  # as _track: a crop serves while this close
        current = self._track_place
        if (current >= 0 and d[current] <= reach) or d[near] > reach or near in self._crops:
            return -1
        local = self.crop_points(self._places[near])
        if len(local) < MIN_SCAN_POINTS:
            return -1
        crop = _Crop(self._places[near].copy(), self.registration.preprocess(local))
        self._crops.setdefault(near, crop)  # one dict operation: safe beside the tracking thread's own
        return near

