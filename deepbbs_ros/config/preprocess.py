"""The ``preprocess`` section: crop, ground removal, voxel grid and farthest-point sampling of a scan."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from deepbbs_ros.config.keys import _check

#: the ``sensor`` rows: sensor name -> {PreprocessConfig field: (value, reason)} (applied by core/sensors.py)
SENSORS: dict[str, dict[str, tuple[Any, str]]] = {
    "hdl64": {},  # the reference: the defaults (car roof, 2 m ego crop, 80 m crop the model's scale is set for)
    "hdl32": {},  # spinning, 360 degrees, car or robot: the defaults (a roof or body: preprocess.self_filter_box)
    "vlp16": {},  # idem; sparse rings are handled by min_candidates, not by a row
    "ouster": {},  # OS0 / OS1 / OS2 at 32-128 beams: spinning, 360 degrees
    "hesai": {},  # XT-32 / Pandar: spinning, 360 degrees
    "robosense": {},  # RS-LiDAR 16 / 32 / Helios: spinning, 360 degrees
    "livox_avia": {
        "min_range": (1.0, "non-repetitive rosette with a ~1 m blind zone, handheld or on a small robot: no car "
                           "body to crop 2 m around"),
        "voxel_size": (0.2, "3,000-5,000 points a frame over 70 x 77 degrees: a 0.3 m grid leaves too few "
                            "candidates for the sampling"),
        "ground_search": ("any", "held at any tilt: the upright fit's 20-degree cone cuts a tilted floor, the floor "
                                 "search at any tilt does not"),
    },
    "livox_mid360": {
        "min_range": (0.3, "360 x 59 degrees from 0.1 m on a robot: the robot's body belongs in self_filter_box"),
        "voxel_size": (0.2, "about 20,000 points a frame spread over a hemisphere-like pattern: a finer grid"),
    },
}


@dataclass
class PreprocessConfig:
    """Scan preprocessing: crop, ground removal, voxel grid, farthest-point sampling."""

    min_range: float = 2.0  # m; returns closer than this (ego vehicle) are dropped
    max_range: float = 80.0  # m; returns farther than this are dropped
    remove_ground: bool = True  # remove the ground plane before sampling (the network sees structure, not road)
    ground_method: str = "ransac"  # "ransac" | "seeded_lsq"
    ground_layer: float = 0.5  # m; thickness of the removed layer around the fitted plane
    ground_seed_radius: float = 20.0  # m; only points within this radius seed the plane fit
    ground_max_tilt_deg: float = 20.0  # the ground normal is within this angle of +z (slopes)
    ground_ransac_iters: int = 64  # plane hypotheses of the "ransac" method
    voxel_size: float = 0.3  # m; 0 disables voxel downsampling
    num_points: int = 512  # points kept by farthest-point sampling (the network is size-agnostic; trained on 1000)
    # with the precision stage on, sample from its voxel grid (registration.polish_voxel over the whole cropped scan)
    # instead of a second grid of voxel_size on the non-ground points: one grid per scan
    share_grid: bool = True
    fps_max_candidates: int = 8192  # FPS runs on a seeded random subset of this many voxels; 0 = all
    dense_max_points: int = 3000  # PreprocessResult.dense_points: random subset of the voxels; 0 = all
    # clouds with per-point times (Velodyne time, Ouster t): deskewed with a given motion, or with their stream's
    # velocity (core/deskew.py: replay, node.pair_deskew) for the precision stage; odometry uses odometry.deskew
    deskew: bool = True
    seed: int = 0  # makes random steps (RANSAC, FPS start point) deterministic
    # the LiDAR: "auto" (the driver's PointCloud2 layout when recognised, else the cloud's shape) or a name of
    # SENSORS in deepbbs_ros/config/preprocess.py ("hdl64", "hdl32", "vlp16", "ouster", "hesai", "robosense",
    # "livox_avia", "livox_mid360"); it sets the defaults of min_range, voxel_size and ground_search, a setting
    # changed from its default always wins
    sensor: str = "auto"
    # self-filter: an axis-aligned box [xmin, xmax, ymin, ymax, zmin, zmax] in the sensor frame (m) whose points are
    # dropped (the robot's own body, a car's roof) beside min_range; [] = off
    self_filter_box: list[float] = field(default_factory=list)
    # "upright": the ground fit above only (a plane under a roughly upright sensor); "auto": that fit, and the floor
    # search at any tilt (core/ground.py) when it finds no plausible floor; "any": the floor search only
    ground_search: str = "auto"
    floor_max_tilt_deg: float = 45.0  # floor search: the floor's normal is within this angle of the sensor's +z
    floor_heights: list[float] = field(default_factory=lambda: [0.1, 3.0])  # m; the sensor's plausible heights
    floor_max_below: float = 0.2  # a floor has at most this fraction of the points more than ground_layer under it
    floor_min_support: float = 0.05  # the floor search's plane holds at least this fraction of the points
    # sparse clouds: when fewer than this many voxels (FPS candidates) remain, the voxel shrinks to
    # voxel_size * sqrt(voxels / min_candidates) (at least voxel_size / 4) so that about this many remain; 0 = off
    min_candidates: int = 1024

    def validate(self) -> None:
        _check(self.sensor == "auto" or self.sensor in SENSORS, "preprocess.sensor",
               f"must be 'auto' or one of {', '.join(SENSORS)}, got {self.sensor!r}")
        _check(len(self.self_filter_box) in (0, 6), "preprocess.self_filter_box",
               "must be [] or [xmin, xmax, ymin, ymax, zmin, zmax]")
        _check(len(self.self_filter_box) == 0 or all(
            lo < hi for lo, hi in zip(self.self_filter_box[::2], self.self_filter_box[1::2], strict=True)),
            "preprocess.self_filter_box", "each min must be below its max")
        _check(self.ground_search in ("upright", "auto", "any"), "preprocess.ground_search",
               f"must be 'upright', 'auto' or 'any', got {self.ground_search!r}")
        _check(0 < self.floor_max_tilt_deg < 90, "preprocess.floor_max_tilt_deg", "must be in (0, 90)")
        _check(len(self.floor_heights) == 2 and 0 <= self.floor_heights[0] < self.floor_heights[1],
               "preprocess.floor_heights", "must be [low, high] with 0 <= low < high")
        _check(0 <= self.floor_max_below < 1, "preprocess.floor_max_below", "must be in [0, 1)")
        _check(0 < self.floor_min_support < 1, "preprocess.floor_min_support", "must be in (0, 1)")
        _check(self.min_candidates >= 0, "preprocess.min_candidates", "must be >= 0")
        _check(self.min_range >= 0, "preprocess.min_range", "must be >= 0")
        _check(self.max_range > self.min_range, "preprocess.max_range", "must be > min_range")
        _check(
            self.ground_method in ("ransac", "seeded_lsq"),
            "preprocess.ground_method",
            f"must be 'ransac' or 'seeded_lsq', got {self.ground_method!r}",
        )
        _check(self.ground_layer > 0, "preprocess.ground_layer", "must be > 0")
        _check(self.ground_seed_radius > 0, "preprocess.ground_seed_radius", "must be > 0")
        _check(0 < self.ground_max_tilt_deg < 90, "preprocess.ground_max_tilt_deg", "must be in (0, 90)")
        _check(self.ground_ransac_iters >= 1, "preprocess.ground_ransac_iters", "must be >= 1")
        _check(self.fps_max_candidates >= 0, "preprocess.fps_max_candidates", "must be >= 0")
        _check(self.voxel_size >= 0, "preprocess.voxel_size", "must be >= 0")
        _check(self.num_points >= 3, "preprocess.num_points", "must be >= 3")
        _check(self.dense_max_points >= 0, "preprocess.dense_max_points", "must be >= 0 (0 = every voxel)")
