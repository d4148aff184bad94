"""The ``localization`` section: global localization in a prior map and tracking in it."""

from __future__ import annotations

from dataclasses import dataclass

from deepbbs_ros.config.keys import _check


@dataclass
class LocalizationConfig:
    """Global localization in a prior map (core/localization.py): ``MapLocalizer`` finds a scan's pose in the map
    with no initial guess, ``MapTracker`` tracks it from scan to scan; the node's ``node.target_mode: localization``
    and ``deepbbs-replay --mode localization``."""

    map_path: str = ""  # node: load the map from this .pcd / .ply file (map frame) instead of the map topic
    map_voxel: float = 0.2  # m; the map is put on this voxel grid when loaded (0 = as given)
    place_spacing: float = 4.0  # m between candidate places: keyframes of the map's trajectory this far apart
    # m; with a trajectory, candidate places are also put on a lattice up to this far to either side of the drive
    # (where the map has free ground): a query driven in another lane or the other way; 0 = keyframes only
    place_band: float = 14.0
    place_band_step: float = 1.75  # m, the lattice's step along and across the drive
    offset_clearance: float = 1.0  # m; a lattice place (place_band) needs ground and no obstacle within this radius
    # m; without a trajectory the candidate places are a grid of this step over the map's drivable space
    # (core/places.py: ground seen from close by, where the mapping sensor passed): finer than place_spacing, since a
    # place may lie beside the path as well as along it
    grid_spacing: float = 2.5
    # m; grid places (no trajectory): where a place's descriptor is centred above its ground; a search puts the scan at
    # its own height above the ground, measured from the scan's ground plane
    sensor_height: float = 1.8
    # m; grid places: a place keeps at least this distance from obstacles (columns with returns 0.3-2 m above their
    # ground whose ground the map does not see densely: walls, parked cars; not the mapping car's roof, canopy)
    free_clearance: float = 1.5
    descriptor_radius: float = 60.0  # m; the place descriptor (Scan Context) covers this radius around a place
    descriptor_rings: int = 20  # rings of the descriptor (radial bins)
    # innermost rings left out of the ranking (near-range cells differ most between lanes and directions)
    descriptor_skip_rings: int = 2
    descriptor_sectors: int = 60  # sectors of the descriptor (yaw bins; the yaw of a match is good to 360 / this deg)
    descriptor_cell: float = 1.0  # m; the height grid the descriptors are read from (max height above local ground)
    # m; the scan is also described about the points this far ahead, behind and to either side of the sensor (a
    # 3 x 3 grid), each matched against every place: a place up to about this far from the scan ranks as if the scan
    # stood on it (the lattice is coarse along the drive). 0 = only about the sensor
    descriptor_shift: float = 0.9
    # distinct places (best descriptor matches) registered per global search, best first; once one is accepted, the
    # rest only while their descriptor distance is within descriptor_margin of its (places that look alike)
    top_k: int = 4
    # places; in a map with more candidate places than this (over about 250 m of road without its trajectory) the
    # scan's descriptor about its sensor alone ranks every place first, and the descriptors about the points around it
    # (descriptor_shift) are matched with the best this many only (a ninth of the ranking's time per place; the same
    # candidates as with every place for every query of the localization benchmark's 1 km maps); 0 = all
    rank_shortlist: int = 2000
    descriptor_margin: float = 0.04  # descriptor distance (0..1) within which two places look alike
    # an accepted answer scoring below this does not stop the search early: all top_k places are registered (rivals?),
    # unless the map verdict is sure of it (registration.verdict_sure): then only the look-alike places are
    confident_score: float = 0.8
    # every answer in a map (a search's, tracking's, a hint's) is accepted when the map verdict's probability that it
    # is right (core/map_verdict.py, calibrated on simulated maps of every kind of place) reaches this
    min_probability: float = 0.7
    # the registration's own global search (other start yaws, shifted starts) on each candidate: "off" (the
    # descriptor's yaw is good to a sector; the search costs ~1 s per wrong place) or "auto" (as configured)
    candidate_search: str = "off"
    # when no candidate is accepted, the best this many are registered again from the opposite yaw where the
    # descriptor's yaw failed (a street looks alike both ways: a drive the other way matched a place 180 deg off);
    # 0 = never
    flip_starts: int = 4
    # the failed candidates are retried (GICP alone, the opposite yaw, poses slid along the road) only when the best
    # first answer's probability (min_probability's) is at least this; below (and retry_descriptor), GICP alone only,
    # then no pose (a scan outside the map: the other retries would double its time to "no pose"); 0 = always retry
    retry_probability: float = 0.05
    # descriptor distance (0..1, descriptor_margin's) of the best-ranked place from which on a first round under
    # retry_probability ends the search (the descriptor matches no place either: simulated and real in-map scans
    # 0.13-0.51, scans from elsewhere 0.31-0.46); 0 = the probability alone
    retry_descriptor: float = 0.35
    # a first round whose best probability is under this ends the search whatever the descriptor's match (scans from
    # elsewhere whose descriptor matches a place: best first answers 0.003-0.004 on the simulated urban map); 0 = off
    retry_floor: float = 0.01
    candidate_separation: float = 12.0  # m; places closer than this count as one candidate (the best kept)
    crop_radius: float = 0.0  # m; map points within this of a place form its registration target; 0 = max_range
    # the GICP of a candidate place (the precision stage of its registration, GICP alone, the probes) looks at its fit
    # after this many iterations when it has not converged: under polish_check_score it stops there (a wrong place:
    # GICP wanders on it for its whole budget, ~5 ms an iteration); 0 = no check
    polish_check_iters: int = 10
    polish_check_score: float = 0.3  # the verdict's score (0..1) under which polish_check_iters stops a GICP
    # a global search's candidate GICP (DeepBBS++'s precision stage, GICP alone; not the accepted pose's probes) not
    # converged after polish_check_iters also stops there, rejected, when the map verdict gives its pose there a
    # probability under this (retry_floor's "not here": 85 % of wrong places, which GICP wanders on for up to ~200 ms);
    # a right pose still converging can score under it there (0.0001-0.003 on 7 of 27 right answers still converging):
    # its place fails like a wrong one and is retried by GICP alone from the descriptor's start; 0 = no such check
    polish_check_probability: float = 0.01
    # a global search's candidate GICP runs its first polish_check_iters iterations on the scan's GICP cloud put on a
    # coarser grid of about this many voxels, the rest of its budget on the whole cloud (the check asks whether a start
    # is hopeless, not where to the centimetre; on the wrong places of a search, most of them, the leg costs a
    # fraction). Measured on the benchmark's maps: 1000 (the check's own sample, core/polish.py CHECK_POINTS) cost a
    # rolled highway scan its placement (0.69 < 0.7; 0.75 with the whole cloud and with 2000); a grid of the check's
    # 1 m cells kept half the voxels of a scan (its far points stay alone in their cells); 0 = the whole cloud
    polish_check_voxels: int = 2000
    # the map's GICP cloud (voxel grid, k-d tree, covariances) is prepared once when the map is loaded (about 0.6 s and
    # 60 MB per km of road) and every crop is a view of it (a crop costs ~20 ms instead of ~115 ms); false: each crop
    # prepares its own cloud (less memory for a very large map)
    shared_cloud: bool = True
    # crops whose preprocessing is kept (least recently used dropped; about 1 MB each, 6-13 MB without shared_cloud)
    crop_cache: int = 16
    # two valid answers farther apart than this (m) are different places; with scores within ambiguity_margin of each
    # other the answer is "ambiguous" (no pose)
    ambiguity_distance: float = 5.0
    # score difference under which two valid answers at different places tie (a wrong place on a highway scored 0.71
    # against a look-alike's 0.60)
    ambiguity_margin: float = 0.15
    # m; the chosen pose is probed by GICP from starts this far off in four directions: a pose that stays off with a
    # valid score (a featureless road) is ambiguous; 0 = no probe
    ambiguity_probe: float = 1.5
    # a probe that stays off is a rival only within this score of the pose (a free slide scores the same; a correct
    # pose with a slightly worse optimum nearby scores a few hundredths less)
    ambiguity_probe_margin: float = 0.03
    # an accepted pose the fit leaves freer than a wrong pose's distance (2 tolerances of 0.3 m / 1 deg) along some
    # direction (a narrow field of view, a corridor) is refused when GICP from it moved along that direction both ways
    # finds another minimum beyond the tolerance that fits as well (core/second_minimum.py on the map crop:
    # tracking's answers, a hint's; a search's where no probe ran, ambiguity_probe): a handheld Livox Avia scan moved
    # 1 m / 2 deg still scored 0.89-0.99
    second_minimum: bool = True
    # m; > 0: the probe's GICP runs on the scan's GICP cloud put on this coarser grid (about half the probe's time; its
    # poses are refined on the whole cloud). 0 = the whole cloud: on a straight highway the coarse cloud's probes all
    # settled on a pose slid 0.76 m along the road, the whole cloud's found the right one beside it (better score)
    probe_voxel: float = 0.0
    # m; the chosen pose is also probed from starts this far ahead, behind and to either side of its heading (GICP from
    # a place a lane off, or a facade's repeat along the street, can settle there with a passing score; the right
    # pose then wins); when no place is accepted, the best answer from this far ahead and behind (a pose slid along
    # the road); 0 = none
    far_probe: float = 3.5
    # m; the accepted pose is refined by a second GICP on the same clouds with this correspondence distance (the
    # registration's 2 m leaves 0.2-0.6 m along a road with few features: the far pairs pull); 0 = off
    refine_corr_dist: float = 0.5
    refine_tracking: bool = True  # refine tracked poses too (not only those found by a search)
    # tracking: a rejected pose from the guess is searched among the places within this radius (m) of the guess
    # before giving up on the scan (0 = no local search)
    track_search_radius: float = 30.0
    # tracking: a scan whose GICP score from the prediction is below this share of the recent scans' (median) is
    # rejected at once, with no DeepBBS++ retry and no local search (a kidnap, the map's end: the global search
    # decides); 0 = never
    track_drop: float = 0.5
    lost_after: int = 2  # MapTracker: this many rejected scans in a row -> lost (the next scans search the whole map)
    max_speed: float = 40.0  # m/s; MapTracker: a pose implying a faster motion since the last one counts as rejected
    # the node keeps the scans that arrive while a search runs (at most this many, the newest): once the search places a
    # scan, the tracker follows its pose through them to the newest scan, so that tracking goes on from a fresh
    # prediction; about 3.7 MB each for a KITTI HDL-64E scan (raw and prepared); 0 = off (the scans that arrived
    # meanwhile are dropped and the next one is tracked from the found pose)
    bridge_scans: int = 30

    def validate(self) -> None:
        _check(self.map_voxel >= 0, "localization.map_voxel", "must be >= 0 (0 = as given)")
        _check(self.place_spacing > 0, "localization.place_spacing", "must be > 0")
        _check(self.bridge_scans >= 0, "localization.bridge_scans", "must be >= 0 (0 = off)")
        _check(self.place_band >= 0, "localization.place_band", "must be >= 0 (0 = keyframes only)")
        _check(self.place_band_step > 0, "localization.place_band_step", "must be > 0")
        _check(self.offset_clearance >= 0, "localization.offset_clearance", "must be >= 0")
        _check(self.grid_spacing > 0, "localization.grid_spacing", "must be > 0")
        _check(self.sensor_height > 0, "localization.sensor_height", "must be > 0")
        _check(self.free_clearance >= 0, "localization.free_clearance", "must be >= 0")
        _check(self.descriptor_radius > 0, "localization.descriptor_radius", "must be > 0")
        _check(self.descriptor_rings >= 2, "localization.descriptor_rings", "must be >= 2")
        _check(0 <= self.descriptor_skip_rings < self.descriptor_rings, "localization.descriptor_skip_rings",
               "must be in [0, descriptor_rings)")
        _check(self.descriptor_sectors >= 8, "localization.descriptor_sectors", "must be >= 8")
        _check(0 < self.descriptor_cell <= self.descriptor_radius / 4, "localization.descriptor_cell",
               "must be > 0 and <= descriptor_radius / 4")
        _check(0 <= self.descriptor_shift <= self.descriptor_radius / 4, "localization.descriptor_shift",
               "must be >= 0 and <= descriptor_radius / 4")
        _check(self.top_k >= 1, "localization.top_k", "must be >= 1")
        _check(self.rank_shortlist >= 0, "localization.rank_shortlist", "must be >= 0 (0 = every place)")
        _check(0 <= self.descriptor_margin <= 1, "localization.descriptor_margin", "must be in [0, 1]")
        _check(0 <= self.min_probability <= 1, "localization.min_probability", "must be in [0, 1]")
        _check(0 <= self.confident_score <= 1, "localization.confident_score", "must be in [0, 1]")
        _check(self.candidate_search in ("off", "auto"), "localization.candidate_search",
               f"must be 'off' or 'auto', got {self.candidate_search!r}")
        _check(self.candidate_separation >= 0, "localization.candidate_separation", "must be >= 0")
        _check(self.crop_radius >= 0, "localization.crop_radius", "must be >= 0 (0 = preprocess.max_range)")
        _check(self.crop_cache >= 1, "localization.crop_cache", "must be >= 1")
        _check(self.polish_check_iters >= 0, "localization.polish_check_iters", "must be >= 0 (0 = no check)")
        _check(0 <= self.polish_check_score <= 1, "localization.polish_check_score", "must be in [0, 1]")
        _check(0 <= self.polish_check_probability <= 1, "localization.polish_check_probability", "must be in [0, 1]")
        _check(self.polish_check_voxels >= 0, "localization.polish_check_voxels", "must be >= 0 (0 = the whole cloud)")
        _check(self.ambiguity_distance > 0, "localization.ambiguity_distance", "must be > 0")
        _check(0 <= self.ambiguity_margin <= 1, "localization.ambiguity_margin", "must be in [0, 1]")
        _check(self.ambiguity_probe >= 0, "localization.ambiguity_probe", "must be >= 0 (0 = no probe)")
        _check(0 <= self.ambiguity_probe_margin <= 1, "localization.ambiguity_probe_margin", "must be in [0, 1]")
        _check(self.probe_voxel >= 0, "localization.probe_voxel", "must be >= 0 (0 = the scan's own GICP cloud)")
        _check(self.flip_starts >= 0, "localization.flip_starts", "must be >= 0")
        _check(0 <= self.retry_probability <= 1, "localization.retry_probability", "must be in [0, 1]")
        _check(0 <= self.retry_descriptor <= 1, "localization.retry_descriptor", "must be in [0, 1]")
        _check(0 <= self.retry_floor <= 1, "localization.retry_floor", "must be in [0, 1]")
        _check(self.far_probe >= 0, "localization.far_probe", "must be >= 0 (0 = no far probe)")
        _check(self.track_search_radius >= 0, "localization.track_search_radius", "must be >= 0 (0 = none)")
        _check(self.refine_corr_dist >= 0, "localization.refine_corr_dist", "must be >= 0 (0 = off)")
        _check(0 <= self.track_drop <= 1, "localization.track_drop", "must be in [0, 1]")
        _check(self.lost_after >= 1, "localization.lost_after", "must be >= 1")
        _check(self.max_speed > 0, "localization.max_speed", "must be > 0")
