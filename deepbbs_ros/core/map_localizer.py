"""Global localization in a prior map: a scan's pose in the map with no initial guess, then tracking (no ROS).

``MapLocalizer.localize`` reads top-down::

    places      candidate places, built once: keyframes along the map's trajectory every localization.place_spacing
                m and a lattice of localization.place_band_step m up to place_band m to either side of the drive
                (other lanes, the other way; core/drive_places.py), or (no trajectory) a grid of
                localization.grid_spacing over the map's drivable space and its ground coverage's peaks away from it
                (a drive's ends, a one-scan map; core/places.py)
    describe    a yaw-invariant place descriptor per place, built once from the map's height grid (Scan Context:
                ring x sector max height above the local ground, localization.descriptor_*), and the same from
                the scan (core/descriptors.py)
    rank        every place against the scan (in a map of more than localization.rank_shortlist places, the places
                the descriptor about the sensor alone ranks best), every column shift (a circular correlation by FFT;
                the best shift is the scan's yaw), the scan also described about points localization.descriptor_shift
                m ahead, behind and to either side (a place between the lattice's rows); the localization.top_k best
                places at least candidate_separation m apart, each from its best-matching point of the scan
    register    (the search: core/place_search.py) DeepBBS++ (core/registration.py) of the scan on each candidate's
                map crop (the map within localization.crop_radius of the place: a view of the map's GICP cloud,
                prepared once with the map (localization.shared_cloud), and the network's points sampled from it,
                kept in an LRU) from the descriptor's yaw (GICP alone beside an answer under confident_score: a
                lane off?); every answer is judged by the map verdict (core/map_verdict.py: the probability that
                the pose is right, calibrated on simulated maps) against localization.min_probability; when no
                place is accepted (and the best's probability is localization.retry_probability or more: else a
                scan outside the map, no pose at once), the failed ones again with GICP alone, then DeepBBS++ from
                the opposite yaw (localization.flip_starts), then GICP from poses slid along the road
    ambiguity   two accepted answers at places more than localization.ambiguity_distance apart with scores within
                ambiguity_margin: no pose ("ambiguous"); the chosen pose is also probed by GICP from starts
                ambiguity_probe m off and far_probe m ahead, behind and to either side: a pose that slides (a
                featureless road) is ambiguous too, a better optimum nearby (the next lane, the next repeat of a
                facade) replaces it (core/acceptance.py)
    refine      a second GICP from the accepted pose with localization.refine_corr_dist (a tracked one too with
                localization.refine_tracking)

With a guess (tracking, core/guess_tracking.py): GICP of the scan on the crop of the place nearest the guess, from
the guess, and the map verdict (``DeepBBSRegistration.register(..., good_start=True)`` instead when the registration
offers it); DeepBBS++ from the guess when that is rejected, and the places within localization.track_search_radius
(as above) when that is too.

Measured (the localization benchmark's simulated 1 km urban map, 1.5 M points at 0.2 m, 3950 places; quiet machine,
2 cores): map build 2.0 s, of which 0.6 s the map's GICP cloud (278 k voxels), 137 MB held (62 MB of it that cloud);
a global search's time hardly grows with the map (p50 0.45, 0.40, 0.40 s at 250, 500, 1000 m of road): one FFT row per
place, then a fixed number of registrations.
:class:`MapTracker` (core/tracking.py) is the state machine around it (the node's and the replay's): constant-velocity
prediction, lost after localization.lost_after rejected scans, then the global search until found again. The results
and the search's data types are in core/localization_types.py, the map's cell index in core/map_index.py; this module
builds the map (places, descriptors, GICP cloud); ``MapLocalizer`` takes its crops from core/map_crops.py, a scan's
description and ranking from core/place_ranking.py, registration on a crop and its checks from
core/candidate_checks.py, its global search from :class:`~deepbbs_ros.core.place_search.PlaceSearch` and its tracking
from a guess from :class:`~deepbbs_ros.core.guess_tracking.GuessTracking`. Its public names, and the tracker's, are
importable from core/localization.py.

Frames (docs/CONVENTIONS.md): map points and poses are in the map frame; a scan is in its sensor frame;
``T_map_scan`` (4, 4) float64 with p_map = R p_scan + t. A place's frame is gravity-aligned (map axes) with its
origin at the place's sensor position; its crop is expressed in that frame.
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.candidate_checks import CandidateChecks
from deepbbs_ros.core.descriptors import _HeightGrid, _PolarTemplate, _spectra
from deepbbs_ros.core.drive_places import keyframe_places
from deepbbs_ros.core.guess_tracking import GuessTracking
from deepbbs_ros.core.localization_types import (
    MIN_SCAN_POINTS,
    LocalizationResult,
    PreparedScan,
    _as_cloud,
    _Crop,
    _rz,
)
from deepbbs_ros.core.map_crops import MapCrops
from deepbbs_ros.core.map_fit import check_trajectory
from deepbbs_ros.core.map_index import _CellIndex, voxel_downsample
from deepbbs_ros.core.place_ranking import PlaceRanking
from deepbbs_ros.core.place_search import PlaceSearch
from deepbbs_ros.core.polish import SMALL_GICP_TYPE, prepare_polish_cloud
from deepbbs_ros.errors import DeepBBSError, LocalizationError

__all__ = ["LocalizationResult", "MapLocalizer", "PreparedScan", "voxel_downsample"]

MIN_MAP_POINTS = 100  # a map with fewer points is refused
#: bytes per voxel of a small_gicp cloud with covariances and normals (point, normal: 4 doubles; covariance: 16) and
#: its k-d tree (about 32)
CLOUD_BYTES = 224


class MapLocalizer(GuessTracking, PlaceSearch, MapCrops, PlaceRanking, CandidateChecks):
    """Finds a scan's pose in a prior map (module docstring).

    Args:
        map_points: (N, 3) metres, map frame (put on ``localization.map_voxel``).
        config: the whole configuration (defaults if None); ``localization`` is this class's section.
        registration: the :class:`~deepbbs_ros.core.registration.DeepBBSRegistration` to use (built from
            ``config`` when None: the shipped model).
        trajectory: optional (K, 4, 4) ``T_map_sensor`` poses of the drive the map was built from: keyframes every
            ``place_spacing`` m are the candidate places (``keyframes`` of them, first), with a ``place_band_step``
            lattice up to ``place_band`` m to either side of the drive; without it the places are a ``grid_spacing``
            grid over the map's free space (cells with ground seen from close by and no obstacle up to
            ``sensor_height`` within ``free_clearance``).

    Everything per place is built here (``build_ms`` says how long, ``nbytes`` how much memory it holds): the height
    grid, the places, their descriptors, and the map's GICP cloud (``localization.shared_cloud``: voxel grid, k-d
    tree, covariances, about 0.6 s and 60 MB per km of road), of which every crop is a view. A crop's network points
    are sampled when first needed and kept (``localization.crop_cache`` of them, about 1 MB each; 6-13 MB each with
    a cloud of their own, without ``shared_cloud``).

    Raises:
        LocalizationError: an empty map, a map that is not (N, 3) finite numbers, too few points, a bad trajectory.
    """

    def __init__(self, map_points: np.ndarray, config: Config | None = None, *, registration: Any = None,
                 trajectory: np.ndarray | None = None) -> None:
        t0 = time.perf_counter()
        self.config = cfg = config if config is not None else (registration.config if registration is not None
                                                               else Config())
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
        self._crops: OrderedDict[int, _Crop] = OrderedDict()
        self._track_place = -1  # the place whose crop tracking used last
        self._track_scores: deque[float] = deque(maxlen=10)  # GICP scores of the last scans tracked from a guess
        self._guess_crop: _Crop | None = None  # tracking off the places: the crop at an earlier guess
        self._lead_of: tuple[Any, Any] | None = None  # (the scan's GICP cloud, its coarse copy): :meth:`_lead`
        self.build_ms = (time.perf_counter() - t0) * 1e3  # the map's part (not the model's loading)
        if registration is None:
            from deepbbs_ros.core.registration import DeepBBSRegistration

            registration = DeepBBSRegistration(cfg)
        self.registration = registration
        t0 = time.perf_counter()
        self._cloud, self._voxels = self._map_cloud()
        self.build_ms += (time.perf_counter() - t0) * 1e3

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

    # -- localize --------------------------------------------------------------------------------------------------
    def localize(self, scan: Any, guess: np.ndarray | None = None, *, times: np.ndarray | None = None,
                 stamp_ns: int | None = None, motion: tuple[np.ndarray, float] | None = None,
                 among: np.ndarray | None = None, starts: Any = ()) -> LocalizationResult:
        """The pose of ``scan`` in the map.

        Args:
            scan: (N, 3) metres, sensor frame (raw; NaN rows dropped), or its :class:`PreparedScan` (:meth:`prepare`;
                then ``times``, ``stamp_ns``, ``motion`` are not used).
            guess: None -> global search over the whole map; (4, 4) ``T_map_scan`` -> tracking: registration on the
                crop nearest the guess, from the guess (GICP, the verdict); when the verdict rejects it, DeepBBS++
                from the guess, then the places within ``track_search_radius`` are searched, unless its score is
                below ``track_drop`` times the recent tracked scans' (a kidnap: rejected at once, a GICP's price).
                Never a wrong pose on purpose: the verdict rejects.
            times, stamp_ns, motion: per-point times (N,) s since the stamp and the sensor's known motion
                (``T_prev_cur``, seconds) for deskewing (``DeepBBSRegistration.preprocess``); optional.
            among: with no guess, the places (indices into :attr:`places`) searched instead of all (a pose hint's).
            starts: with a guess, other (4, 4) starts for its GICP (the tracker's last pose at rest, mirrored), in the
                order of their fit with it (core/guess_tracking.py).

        Raises:
            LocalizationError: a scan that is not (N, 3) numbers, with too few finite points, a bad guess.
        """
        t0 = time.perf_counter()
        timings: dict[str, float] = {}
        if guess is not None:
            guess = np.asarray(guess, dtype=np.float64)
            if guess.shape != (4, 4) or not np.isfinite(guess).all():
                raise LocalizationError(f"guess: expected a finite (4, 4) T_map_scan, got shape {guess.shape}")
        prepared = scan if isinstance(scan, PreparedScan) else self.prepare(scan, times, stamp_ns, motion)
        pts, src = prepared.points, prepared.pre
        timings["preprocess"] = prepared.preprocess_ms if prepared is scan else (time.perf_counter() - t0) * 1e3
        if guess is not None:
            res = self._track(pts, src, guess, timings, starts)
        else:
            res = self._global(pts, src, among, timings)
        res.timings_ms = timings
        timings["total"] = (time.perf_counter() - t0) * 1e3
        return res

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

    def prepare(self, scan: Any, times: np.ndarray | None = None, stamp_ns: int | None = None,
                motion: tuple[np.ndarray, float] | None = None) -> PreparedScan:
        """The scan's part of :meth:`localize`: a raw scan (N, 3) (sensor frame, NaN rows dropped; ``times``,
        ``stamp_ns``, ``motion`` as there) -> its :class:`PreparedScan` (GICP cloud with k-d tree and covariances, the
        network's sampling waiting for a first read). The node does it on the scan's input thread, on arrival, with the
        motion :meth:`MapTracker.motion` knows then; :meth:`localize` takes the result in place of the scan.

        Raises:
            LocalizationError: a scan that is not (N, 3) numbers, with too few finite points.
        """
        t0 = time.perf_counter()
        pts = _as_cloud(scan, "scan")
        if not np.isfinite(pts).all():  # a copy only when there is something to drop (the node's scans are finite)
            pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts) < MIN_SCAN_POINTS:
            raise LocalizationError(f"scan: {len(pts)} finite points, at least {MIN_SCAN_POINTS} are needed")
        try:
            # the sampling waits for its first read (tracking: never)
            src = self.registration.preprocess(pts, times, stamp_ns, motion, lazy=True)
        except DeepBBSError as err:
            raise LocalizationError(f"scan: {err}") from err
        return PreparedScan(pts, src, (time.perf_counter() - t0) * 1e3)
