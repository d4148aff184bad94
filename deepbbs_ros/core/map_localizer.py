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
composes the parts: ``MapLocalizer`` builds the map (places, descriptors, GICP cloud) with core/map_build.py, takes
its crops from core/map_crops.py, a scan's description and ranking from core/place_ranking.py, registration on a crop
and its checks from core/candidate_checks.py, its global search from
:class:`~deepbbs_ros.core.place_search.PlaceSearch`, its tracking from a guess from
:class:`~deepbbs_ros.core.guess_tracking.GuessTracking` and its registration from a pose hint from core/pose_hint.py.
Its public names, and the tracker's, are importable from core/localization.py.

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
from deepbbs_ros.core.guess_tracking import GuessTracking
from deepbbs_ros.core.localization_types import MIN_SCAN_POINTS, LocalizationResult, PreparedScan, _as_cloud, _Crop
from deepbbs_ros.core.map_build import CLOUD_BYTES, MIN_MAP_POINTS, MapBuild  # noqa: F401  (the constants re-exported)
from deepbbs_ros.core.map_crops import MapCrops
from deepbbs_ros.core.map_index import voxel_downsample
from deepbbs_ros.core.place_ranking import PlaceRanking
from deepbbs_ros.core.place_search import PlaceSearch
from deepbbs_ros.core.pose_hint import HintSearch
from deepbbs_ros.errors import DeepBBSError, LocalizationError

__all__ = ["LocalizationResult", "MapLocalizer", "PreparedScan", "voxel_downsample"]


class MapLocalizer(MapBuild, HintSearch, GuessTracking, PlaceSearch, MapCrops, PlaceRanking, CandidateChecks):
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
        self._build_map(map_points, trajectory)  # points, places, descriptors (core/map_build.py)
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
