"""One typed configuration shared by the node, the CLIs, training and the YAML files.

The schema is a tree of dataclasses: :class:`Config` has one section per area (``preprocess``,
``model``, ``registration``, ``node``, ``train``, ``eval``). The same tree is

* loaded from YAML (``Config.from_yaml``), either plain sections or a ROS 2 parameter file
  (``<node_name>: ros__parameters: {...}`` or ``/**: ros__parameters: {...}``; ``config/deepbbs_ros.yaml``
  is one, keyed ``/**`` so that it applies to the node under any name),
* declared as ROS parameters with dotted names (``preprocess.voxel_size``) via
  :meth:`Config.to_flat` / :meth:`Config.from_flat`,
* saved next to every result (``Config.to_dict``) and inside checkpoints.

Units are SI (metres, seconds); angles are radians unless the name ends in ``_deg``.
Unknown keys, wrong types and out-of-range values raise :class:`~deepbbs_ros.errors.ConfigError`
naming the offending key.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from deepbbs_ros.errors import ConfigError


def _check(cond: bool, key: str, msg: str) -> None:
    if not cond:
        raise ConfigError(f"config: {key} {msg}")


def nearest_keys(name: str, known: Any) -> list[str]:
    """The known dotted names closest to ``name``: those whose last part equals its last part (flat,
    KISS-ICP-style names such as ``mode`` or ``voxel_size``), else the closest spelling (``eval.strid`` ->
    ``eval.stride``), else the key whose last part is spelt closest. Empty when nothing is close."""
    import difflib

    known = list(known)
    leaf = name.rpartition(".")[2]
    same = [k for k in known if k.rpartition(".")[2] == leaf]
    if same:
        return same
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    if close:
        return close
    leaves = {k.rpartition(".")[2]: k for k in known}
    return [leaves[m] for m in difflib.get_close_matches(leaf, list(leaves), n=1, cutoff=0.6)]


def did_you_mean(name: str, known: Any) -> str:
    """``"; did you mean a.b?"`` (or ``"a.b or c.b"``) for :func:`nearest_keys`, ``""`` when none is close."""
    near = nearest_keys(name, known)
    return f"; did you mean {' or '.join(near)}?" if near else ""


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
    # deepbbs_ros/core/sensors.py ("hdl64", "hdl32", "vlp16", "ouster", "hesai", "robosense", "livox_avia",
    # "livox_mid360"); it sets the defaults of min_range, voxel_size and ground_search, a setting changed from its
    # default always wins
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
        from deepbbs_ros.core.sensors import SENSORS

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


@dataclass
class ModelConfig:
    """The embedding network (DGCNN + transformer) and the coordinate scaling."""

    # Defaults are a reduced DGCNN/DCP (paper: k=20, widths 64-64-128-256, emb 512, ff 1024; ~5.7 M
    # parameters): ~0.1 M parameters, so that a pass on 2x1000 points fits the 2-core CPU budget and
    # the model trains on a CPU. The 1000x1000 attention (3 per direction) dominates the pass.

    k: int = 16  # neighbours of the DGCNN edge convolutions (on xyz)
    dgcnn_widths: list[int] = field(default_factory=lambda: [32, 32, 64, 128])  # widths of the DGCNN layers
    emb_dims: int = 64  # width of the point embedding
    n_heads: int = 4  # attention heads of the transformer
    n_blocks: int = 1  # transformer encoder/decoder blocks (0 = DGCNN only)
    ff_dims: int = 128  # transformer feed-forward width
    dropout: float = 0.0  # transformer dropout while training
    # LiDAR scenes are ~100 m across; the network and temperatures were designed for unit-sized
    # objects. Coordinates are multiplied by ``scale`` on the way in and translations divided by it
    # on the way out (scale = 1/40 maps an 80 m crop radius to 2 units).
    scale: float = 0.025
    temperature_min: float = 0.01  # clamp range of the predicted temperature T (scaled units)
    temperature_max: float = 1.0  # (scaled units)
    xi: float = 0.4  # alpha = xi * median_j min_i ||phi_pj - phi_pi||

    def validate(self) -> None:
        _check(self.k >= 1, "model.k", "must be >= 1")
        _check(
            len(self.dgcnn_widths) >= 1 and all(w > 0 for w in self.dgcnn_widths),
            "model.dgcnn_widths",
            "must be a non-empty list of positive widths",
        )
        _check(self.emb_dims > 0, "model.emb_dims", "must be > 0")
        _check(self.n_heads >= 1, "model.n_heads", "must be >= 1")
        _check(self.emb_dims % self.n_heads == 0, "model.emb_dims", "must be divisible by n_heads")
        _check(self.n_blocks >= 0, "model.n_blocks", "must be >= 0")
        _check(self.ff_dims > 0, "model.ff_dims", "must be > 0")
        _check(0 <= self.dropout < 1, "model.dropout", "must be in [0, 1)")
        _check(self.scale > 0, "model.scale", "must be > 0")
        _check(
            0 < self.temperature_min < self.temperature_max,
            "model.temperature_min",
            "must satisfy 0 < temperature_min < temperature_max",
        )
        _check(self.xi > 0, "model.xi", "must be > 0")


@dataclass
class RegistrationConfig:
    """The DeepBBS iterations, the DeepBBS++ refinement, ablation switches and the device."""

    device: str = "auto"  # "auto" (CUDA when present), "cpu", "cuda", "cuda:N"
    weights: str = ""  # checkpoint path; "" = the model shipped with the package
    max_deep_iters: int = 2  # network passes per registration; the precision stage needs only the basin
    deep_rot_tol_deg: float = 0.4  # stop deep iterations when the increment is below both
    deep_trans_tol: float = 0.05  # m
    refine: bool = False  # DeepBBS++ SoftBBS refinement in 3D space (the paper's; off: the GICP precision stage wins)
    refine_max_iters: int = 46  # iterations of the SoftBBS refinement (registration.refine)
    refine_k: int = 16  # nearest target points per source point in the sparse refinement
    refine_rot_tol_deg: float = 0.005  # the refinement stops when the increment is below both
    refine_trans_tol: float = 0.001  # m
    refine_temperature: float = 1.0  # m; T of gamma's spatial term in the refinement; 0 = paper (1 scaled unit)
    refine_overlap_crop: bool = True  # refine only on points inside both sensors' max_range (unbiased ends)
    refine_alpha_start: float = 4.0  # coarse-to-fine: alpha x this first, halved on convergence to x1 (1 = paper)
    dense_refine: bool = False  # final refinement on preprocess' dense_points (voxelised non-ground)
    dense_refine_k: int = 6  # nearest dense target points per dense source point
    dense_refine_max_iters: int = 15  # iterations of the dense refinement (registration.dense_refine)
    dense_refine_xi: float = 0.4  # alpha = xi * median nearest-neighbour distance of the dense source
    dense_refine_temperature: float = 1.0  # m; T of gamma's spatial term exp(-D/T) in the dense stage
    polish: str = "gicp"  # precision stage (small_gicp) from the DeepBBS++ estimate: gicp|plane_icp|none
    polish_voxel: float = 0.5  # m; voxel grid of the precision clouds (whole cropped scan, ground kept); 0 = none
    polish_max_corr_dist: float = 2.0  # m; small_gicp max_correspondence_distance (= eval.baseline_max_corr_dist)
    polish_max_iters: int = 50  # (= eval.baseline_max_iters)
    polish_neighbors: int = 20  # neighbours for covariances / normals (= eval.baseline_neighbors)
    # at most this many voxels in a scan's GICP cloud: a denser one is put on a coarser grid (0 = polish_voxel as is);
    # the pair-mode node sets it from node.polish_max_voxels
    polish_max_voxels: int = 0
    polish_max_trans: float = 0.0  # m; a polish moving the estimate further is rejected (DeepBBS++ kept); 0 = no limit
    polish_max_rot_deg: float = 0.0  # deg; idem for rotation; 0 = no limit
    polish_threads: int = 0  # small_gicp threads; 0 = every core (deepbbs-replay: eval.threads unless that is 0)
    # small_gicp's GICP solve on one thread (trees and covariances keep polish_threads): its sums in one order, so the
    # same pose to the last bit on any machine; about twice the solve's time on 2 cores
    exact_gicp: bool = False
    # small_gicp's convergence: stop when an iteration moves the estimate less than both (small_gicp's own default is
    # 1 mm: fewer iterations from the network's estimate, the same errors on real scans)
    polish_rot_eps_deg: float = 0.1
    polish_trans_eps: float = 0.005  # m
    deep_iterations: bool = True  # ablation: False = one network pass only
    deep: bool = True  # ablation: False = refinement only (from identity)
    fixed_temperature: float = 0.0  # ablation: > 0 replaces the predicted T (scaled units)
    use_gamma: bool = True  # ablation: False = uniform weights in Procrustes
    spatial_gamma: bool = True  # ablation: False = gamma without the exp(-D/T) spatial term
    inlier_dist: float = 1.0  # m; RegistrationResult.inlier_ratio = share of source points this close to the target
    # the network passes in a worker process on a CPU (core/network_process.py): "auto" with 2+ cores and weights
    # from a checkpoint file (they then overlap small_gicp, which holds the GIL), "off" in this process
    network_process: str = "auto"
    # torch CPU threads while register() runs the network (set and restored around it); 0 = leave torch's setting
    # alone. 1: on 2x512 points a second thread costs more in hand-offs than it gives (OMP_WAIT_POLICY=PASSIVE,
    # docs/node.md), and it leaves the other cores to small_gicp and the rest of the robot
    # (deepbbs-replay: eval.threads unless that is 0)
    threads: int = 1
    success_rot_deg: float = 1.0  # a registration "converged" only within these of ...
    success_trans: float = 0.3  # ... the evaluation thresholds (docs/CONVENTIONS.md)
    # the verdict (core/verdict.py): RegistrationResult.probability = the calibrated probability that the pose is
    # within 1 deg / 0.3 m of the truth (fitted on simulated pairs of every sensor, mount and place:
    # scripts/calibrate_verdict.py); valid when it reaches verdict_probability. RegistrationResult.score = the
    # fitness: share of the source's sampled points within verdict_dist of the target's precision-stage cloud
    verdict_dist: float = 0.5  # m
    verdict_probability: float = 0.7  # a result is valid when its probability of being right reaches this
    # the global search's answers (other starts than the given one) end the search only from this probability; a valid
    # one under it is weighed against the next best start's, the given start's GICP answer and its own 180-degree twin,
    # the most probable kept: a nearly symmetric place's flip can reach verdict_probability (simulated courtyard
    # flips scored 0.91-0.92, their right poses 0.97-1.0)
    verdict_sure: float = 0.95
    # a global search's answer (another start than the given one) is valid only when its fitness (the score) reaches
    # this too: a flip that lays the ground on the ground fits little else (simulated Avia courtyard flips scored
    # 0.002-0.01 with probability 0.91-0.92; right answers on a real handheld Livox Avia walk scored 0.25 and more)
    search_min_score: float = 0.1
    # the fitness under which the global search ("auto") runs on the deep answer; and the verdict on clouds without a
    # precision stage (registration.polish none, preprocessed arrays), for which the probability is not calibrated
    verdict_threshold: float = 0.35
    # the global search (core/global_search.py): other start yaws when the answer fails the verdict ("auto"), on
    # every registration ("always") or never ("off"); global_yaws starts at 360 / global_yaws degree steps (the
    # given start included), the global_polish best of them (ranked by their fitness before it) get the precision stage
    global_search: str = "auto"
    global_yaws: int = 4  # start yaws of the search, 360 / global_yaws degrees apart (the given start included)
    global_polish: int = 2  # the best this many starts (ranked by their fitness) get the precision stage
    # the network process runs the other start yaws' first passes right after the given start's (while this process
    # builds the GICP clouds), stopped as soon as the answer from the given start fits: "auto" when the search ran
    # in one of the last 8 registrations (a stream of good starts pays nothing), "always", or "off"
    global_speculate: str = "auto"
    # the search's ranking passes (one from each other start yaw) run on the first global_rank_points of the sampled
    # points (a farthest-point prefix: the same coverage, sparser); the start kept gets the remaining passes on all of
    # them (0 = all: rank on the full clouds)
    global_rank_points: int = 256
    # none valid after the yaw starts: the best turned by 180 deg, starts this far and twice as far around both
    global_shift: float = 8.0  # m; 0 = off
    # register(..., good_start=True), the caller vouches for T_init (consecutive scans, a fixed mounting, a map from
    # the last pose): GICP alone from it on the precision-stage clouds, judged by the verdict (its spread subset of the
    # source's GICP voxels, ground included); the full pipeline (deep passes, search) runs only when that rejects
    good_start_probability: float = 0.7  # the good-start verdict: valid when its probability of being right reaches it
    good_start_points: int = 512  # source voxels the good-start verdict scores (a spread subset of its GICP cloud)
    good_start_max_iters: int = 10  # GICP iterations from a good start: not converged by then -> the full pipeline
    good_start_max_trans: float = 3.0  # m; GICP moving the start further: the start was not good -> the full pipeline
    good_start_max_rot_deg: float = 10.0  # deg; idem for rotation

    def validate(self) -> None:
        dev = self.device
        _check(
            dev in ("auto", "cpu", "cuda") or (dev.startswith("cuda:") and dev[5:].isdigit()),
            "registration.device",
            f"must be 'auto', 'cpu', 'cuda' or 'cuda:N', got {dev!r}",
        )
        _check(self.max_deep_iters >= 1, "registration.max_deep_iters", "must be >= 1")
        _check(self.deep_rot_tol_deg > 0, "registration.deep_rot_tol_deg", "must be > 0")
        _check(self.deep_trans_tol > 0, "registration.deep_trans_tol", "must be > 0")
        _check(self.refine_max_iters >= 1, "registration.refine_max_iters", "must be >= 1")
        _check(self.refine_k >= 0, "registration.refine_k", "must be >= 0 (0 = dense)")
        _check(self.refine_temperature >= 0, "registration.refine_temperature", "must be >= 0 (0 = paper)")
        _check(self.refine_alpha_start >= 1, "registration.refine_alpha_start", "must be >= 1 (1 = paper)")
        _check(self.dense_refine_k >= 1, "registration.dense_refine_k", "must be >= 1")
        _check(self.dense_refine_max_iters >= 1, "registration.dense_refine_max_iters", "must be >= 1")
        _check(self.dense_refine_xi > 0, "registration.dense_refine_xi", "must be > 0")
        _check(self.dense_refine_temperature > 0, "registration.dense_refine_temperature", "must be > 0")
        _check(
            self.polish in ("none", "gicp", "plane_icp"),
            "registration.polish",
            f"must be 'none', 'gicp' or 'plane_icp', got {self.polish!r}",
        )
        _check(self.polish_voxel >= 0, "registration.polish_voxel", "must be >= 0 (0 = no voxel grid)")
        _check(self.polish_max_corr_dist > 0, "registration.polish_max_corr_dist", "must be > 0")
        _check(self.polish_max_iters >= 1, "registration.polish_max_iters", "must be >= 1")
        _check(self.polish_neighbors >= 5, "registration.polish_neighbors", "must be >= 5")
        _check(self.polish_max_voxels >= 0, "registration.polish_max_voxels", "must be >= 0 (0 = no cap)")
        _check(self.polish_max_trans >= 0, "registration.polish_max_trans", "must be >= 0 (0 = no limit)")
        _check(self.polish_max_rot_deg >= 0, "registration.polish_max_rot_deg", "must be >= 0 (0 = no limit)")
        _check(self.polish_threads >= 0, "registration.polish_threads", "must be >= 0 (0 = every core)")
        _check(self.polish_rot_eps_deg > 0, "registration.polish_rot_eps_deg", "must be > 0")
        _check(self.polish_trans_eps > 0, "registration.polish_trans_eps", "must be > 0")
        _check(self.fixed_temperature >= 0, "registration.fixed_temperature", "must be >= 0")
        _check(self.inlier_dist > 0, "registration.inlier_dist", "must be > 0")
        _check(self.network_process in ("auto", "off"), "registration.network_process",
               f"must be 'auto' or 'off', got {self.network_process!r}")
        _check(self.threads >= 0, "registration.threads", "must be >= 0 (0 = leave torch's setting)")
        _check(self.verdict_dist > 0, "registration.verdict_dist", "must be > 0")
        _check(0 <= self.verdict_threshold <= 1, "registration.verdict_threshold", "must be in [0, 1]")
        _check(0 <= self.verdict_probability <= 1, "registration.verdict_probability", "must be in [0, 1]")
        _check(0 <= self.verdict_sure <= 1, "registration.verdict_sure", "must be in [0, 1]")
        _check(0 <= self.search_min_score <= 1, "registration.search_min_score", "must be in [0, 1]")
        _check(self.global_search in ("auto", "always", "off"), "registration.global_search",
               f"must be 'auto', 'always' or 'off', got {self.global_search!r}")
        _check(self.global_yaws >= 1, "registration.global_yaws", "must be >= 1 (1 = the given start only)")
        _check(self.global_polish >= 1, "registration.global_polish", "must be >= 1")
        _check(self.global_speculate in ("auto", "always", "off"), "registration.global_speculate",
               f"must be 'auto', 'always' or 'off', got {self.global_speculate!r}")
        _check(self.global_rank_points == 0 or self.global_rank_points >= 16, "registration.global_rank_points",
               "must be 0 (all sampled points) or >= 16")
        _check(self.global_shift >= 0, "registration.global_shift", "must be >= 0 (0 = off)")
        _check(0 <= self.good_start_probability <= 1, "registration.good_start_probability", "must be in [0, 1]")
        _check(self.good_start_points >= 16, "registration.good_start_points", "must be >= 16")
        _check(self.good_start_max_iters >= 1, "registration.good_start_max_iters", "must be >= 1")
        _check(self.good_start_max_trans > 0, "registration.good_start_max_trans", "must be > 0")
        _check(self.good_start_max_rot_deg > 0, "registration.good_start_max_rot_deg", "must be > 0")
        _check(self.deep or self.refine, "registration.deep", "and refine cannot both be false")


@dataclass
class NodeConfig:
    """The live rclpy node (topics are remapped the ROS way, not configured here)."""

    mode: str = "pair"  # "pair": source_cloud vs target_cloud; "odometry": scan k vs scan k-1
    queue_size: int = 10  # approximate-time synchroniser queue per input
    slop: float = 0.05  # s; max stamp difference of a synchronised pair
    qos_reliability: str = "best_effort"  # "best_effort" (sensor data) | "reliable"
    qos_depth: int = 5  # history depth of the input subscriptions
    publish_odometry: bool = True  # ~/odometry (nav_msgs/Odometry: pose, twist, covariances)
    # odometry mode: odom_frame -> base_frame on /tf (REP-105); localization: map_frame -> odom_frame; needs tf2_msgs
    # (built by `make venv`, or `deepbbs-ros build-interfaces`). Pair mode broadcasts target -> source frame only with
    # node.pair_tf
    publish_tf: bool = True
    pair_tf: bool = False  # pair mode (not localization): broadcast target frame -> source frame on /tf
    invert_tf: bool = False  # broadcast base_frame -> odom_frame instead (another node owns odom's tree)
    publish_aligned_cloud: bool = False  # ~/aligned_cloud: the source in the target frame (odometry: in odom)
    # odometry mode: the fixed frame of ~/odometry and of the TF it broadcasts; localization: map_frame's child
    odom_frame: str = "odom"
    # odometry and localization: the published poses are the base's, T_base_sensor looked up on /tf_static
    # (robot_state_publisher); "" = the cloud's frame (no lookup)
    base_frame: str = "base_link"
    # s after start-up / the first scan to wait for base_frame <- cloud frame; then identity. Localization: also how
    # long a scan waits for odom_frame -> base_frame at its stamp on /tf
    tf_timeout: float = 1.0
    # pair mode: "stamped" pairs source and target by stamp (slop); "latched" takes the target topic as a map /
    # reference cloud (transient_local, reliable): the latest target serves every source, cropped around the
    # current estimate, the answer is the scan's pose in the target frame, the last answer the next start;
    # "localization": each source's pose in a prior map (localization.map_path, else the latched target topic)
    # with no initial pose: the whole map searched, then tracked; lost and found again (~/relocalize)
    target_mode: str = "stamped"
    map_frame: str = "map"  # localization: the frame of the map read from localization.map_path
    # localization: who provides odom_frame -> base_frame (REP-105). "tf": an odometry source (wheel odometry, an
    # EKF) on /tf, looked up at each scan's stamp; the node publishes map_frame -> odom_frame. "lidar": the node's own
    # LiDAR odometry on the same scans publishes odom_frame -> base_frame, and map_frame -> odom_frame from it.
    # "none": the node publishes map_frame -> base_frame itself (no odom frame)
    localization_odom: str = "tf"
    # s; localization: map_frame -> odom_frame is stamped this long after its scan (as AMCL's transform_tolerance),
    # so that lookups up to then need no extrapolation
    transform_tolerance: float = 1.0
    # s; localization: the last map_frame -> odom_frame is broadcast again this often between scans (0 = with each
    # localized scan only)
    map_odom_period: float = 0.2
    # localization: a background thread prepares the map crop of the place the tracked pose reaches next, so that the
    # scan that gets there does not wait for it
    map_prefetch: bool = True
    initial_pose: list[float] = field(default_factory=lambda: [0.0] * 6)  # latched: first start x y z roll pitch yaw
    map_crop_radius: float = 0.0  # m; latched: map points within this of the estimate; 0 = preprocess.max_range
    unpaired_warn_after: float = 3.0  # s; an input that never pairs is reported (log, /diagnostics) after this
    warmup: bool = True  # run every stage once on a synthetic scan before reporting ready (first scans answered)
    # odometry mode: scans that may wait for the odometry (beyond that the oldest is dropped): a short transient
    # (the first motion, which asks DeepBBS++; a busy moment) is answered late instead of leaving a gap; pair mode
    # keeps 1 (newest wins)
    odometry_backlog: int = 6
    min_points: int = 100  # clouds with fewer valid points are rejected
    diagnostics_period: float = 1.0  # s
    error_log_period: float = 5.0  # s; rate limit of repeated error messages per kind
    # pair mode with raw sweeps: follow each input's velocity and deskew its clouds (core/deskew.py; more precise on
    # raw sweeps) at the cost of a second GICP per pair: off by default, because two 10 Hz HDL-64E inputs then no
    # longer fit two CPU cores. Odometry mode always deskews.
    pair_deskew: bool = False
    # pair mode: network passes per registration in the node (replaces registration.max_deep_iters there; 0 = keep
    # it). The precision stage only needs the basin: on real nearby scans one pass lands GICP on the same pose as two
    deep_passes: int = 1
    # pair mode: a scan's GICP cloud has at most this many voxels (registration.polish_max_voxels there; 0 = keep
    # it). The k-d trees, covariances and GICP scale with the voxels: a speed option for dense scans where
    # centimetres matter less (a cap costs precision)
    polish_max_voxels: int = 0
    # pair mode: the registration (the GICP clouds' k-d trees and covariances, GICP, the network's own process) runs in
    # a process of its own, the node's process keeps rclpy, decoding and preprocessing (node/registration_process.py):
    # auto = on in pair mode on a CPU with 2+ cores; on = in pair mode; off = in the node's process. Odometry mode
    # keeps the registration in the node's process
    registration_process: str = "auto"
    # pair mode: the last valid answer is the next pair's good start (register(..., good_start=True): GICP alone from
    # it, the full pipeline only when its stricter verdict rejects); a latched target: the last valid pose. Not for
    # the first pair, after a rejected pose, ~/reset, or a source stamp more than good_start_max_gap s from the last
    good_start: bool = True
    good_start_max_gap: float = 0.5  # s; pair mode: a longer gap since the last answer's source stamp: no good start

    def validate(self) -> None:
        hint = (f" ({self.mode!r} is a target mode: node.mode:=pair with node.target_mode:={self.mode})"
                if self.mode in ("stamped", "latched", "localization") else "")
        _check(self.mode in ("pair", "odometry"), "node.mode", f"must be 'pair' or 'odometry', got {self.mode!r}{hint}")
        _check(self.queue_size >= 1, "node.queue_size", "must be >= 1")
        _check(self.slop >= 0, "node.slop", "must be >= 0")
        _check(
            self.qos_reliability in ("best_effort", "reliable"),
            "node.qos_reliability",
            f"must be 'best_effort' or 'reliable', got {self.qos_reliability!r}",
        )
        _check(self.qos_depth >= 1, "node.qos_depth", "must be >= 1")
        _check(self.min_points >= 3, "node.min_points", "must be >= 3")
        _check(self.diagnostics_period > 0, "node.diagnostics_period", "must be > 0")
        _check(self.error_log_period >= 0, "node.error_log_period", "must be >= 0")
        _check(self.tf_timeout >= 0, "node.tf_timeout", "must be >= 0")
        _check(self.target_mode in ("stamped", "latched", "localization"), "node.target_mode",
               f"must be 'stamped', 'latched' or 'localization', got {self.target_mode!r}")
        _check(self.localization_odom in ("tf", "lidar", "none"), "node.localization_odom",
               f"must be 'tf', 'lidar' or 'none', got {self.localization_odom!r}")
        _check(self.transform_tolerance >= 0, "node.transform_tolerance", "must be >= 0")
        _check(self.map_odom_period >= 0, "node.map_odom_period", "must be >= 0 (0 = with each localized scan)")
        _check(len(self.initial_pose) == 6, "node.initial_pose", "must be [x, y, z, roll, pitch, yaw]")
        _check(self.map_crop_radius >= 0, "node.map_crop_radius", "must be >= 0 (0 = preprocess.max_range)")
        _check(self.unpaired_warn_after > 0, "node.unpaired_warn_after", "must be > 0")
        _check(self.odometry_backlog >= 1, "node.odometry_backlog", "must be >= 1")
        _check(self.deep_passes >= 0, "node.deep_passes", "must be >= 0 (0 = registration.max_deep_iters)")
        _check(self.polish_max_voxels >= 0, "node.polish_max_voxels",
               "must be >= 0 (0 = registration.polish_max_voxels)")
        _check(self.registration_process in ("auto", "on", "off"), "node.registration_process",
               f"must be 'auto', 'on' or 'off', got {self.registration_process!r}")
        _check(self.good_start_max_gap >= 0, "node.good_start_max_gap", "must be >= 0")


@dataclass
class OdometryConfig:
    """Local-map odometry (core/odometry.py): ``deepbbs-replay --mode odometry --method deepbbs++`` and the
    node's ``node.mode: odometry``. GICP against a local voxel map with DeepBBS++ where the motion prior fails."""

    # DeepBBS++ re-initialises: auto (long stamp gap, fit drop, first motion) | always | never
    deepbbs_init: str = "auto"
    # m; local map voxel (VGICP); the scan grid is half of it; 0 = the first scan's median range / 10, at most
    # preprocess.max_range / 100 (KISS-ICP's map voxel; smaller indoors, where a car's voxel blurs the walls)
    voxel_size: float = 0.0
    neighbors: int = 20  # neighbours for the scan's covariances
    max_corr_dist: float = 1.0  # m; GICP correspondence distance against the map
    max_iters: int = 20  # GICP iterations per alignment
    lru_horizon: int = 100  # map voxels not seen for this many scans are dropped ...
    lru_clear_cycle: int = 10  # ... checked every this many scans
    deskew: bool = True  # motion compensation from per-point times (Velodyne time, Ouster t) when a cloud has them
    deskew_window: int = 4  # the deskew's velocity: mean of this many last motions (1 = the last: unstable)
    gap_factor: float = 1.5  # a stamp gap: above this many nominal periods (dropped scans) ...
    # ... DeepBBS++ checks a gap longer than this many periods (3.5: one or two dropped scans are left to GICP from the
    # constant-velocity prediction scaled to the gap, checked by the fit as every scan); a gap up to it asks
    # DeepBBS++ only when the fit after GICP falls below fit_drop x the running median
    gap_trust: float = 3.5
    fit_drop: float = 0.8  # fit = share of scan points with a map correspondence; below this x the median: DeepBBS++
    fit_window: int = 20  # frames in the running median of the fit (and in the gate's deviation, gate_sigmas)
    fit_margin: float = 0.02  # a start (DeepBBS++'s, a coarse-to-fine one) beats the prediction's fit by this to win
    threads: int = 0  # small_gicp threads; 0 = every core (deepbbs-replay: eval.threads unless that is 0)
    # degenerate place (corridor, tunnel, open field): a translation direction of the GICP Hessian with an eigenvalue
    # below this x the largest; along it the prediction's position is kept and /diagnostics warns; 0 = never
    degenerate_ratio: float = 0.005
    # DeepBBS++ also checks a step that deviates from the constant-velocity prediction by more than this x the rms of
    # the last fit_window steps' deviations (at least a quarter of the map voxel); 0 = off
    gate_sigmas: float = 4.0
    # GICP against the map's voxel means with covariances fitted through their map neighbours (many sweeps: the
    # surface's plane) instead of the voxel map's mean of each scan's own covariances (on a sparse sensor a point's
    # neighbours in its scan lie on one line and the plane through them points anywhere), on every scan; off: on the
    # scans line_share picks
    map_covariances: bool = False
    # with map_covariances off, a scan aligns against the map's planes all the same when more than this share of the
    # points have line-like neighbourhoods (narrower than a tenth of their length: a sparse sensor's scan lines, whose
    # plane is undetermined), measured every 4th scan and averaged over the last fit_window scans; medians 0.12-0.29 a
    # drive with a 16-beam sensor on a road, at most 0.05 with 32 beams and more; 1 = never
    line_share: float = 0.1
    # the map's planes (voxel means, their k-d tree and covariances) are rebuilt once more than this share of the
    # voxel means within the scan's reach are new or moved by more than 5 % of a voxel since the last build; 0 = after
    # every scan
    map_refresh: float = 0.2

    def validate(self) -> None:
        _check(self.deepbbs_init in ("auto", "always", "never"), "odometry.deepbbs_init",
               f"must be 'auto', 'always' or 'never', got {self.deepbbs_init!r}")
        _check(self.voxel_size >= 0, "odometry.voxel_size", "must be >= 0 (0 = from the first scan)")
        _check(self.neighbors >= 5, "odometry.neighbors", "must be >= 5")
        _check(self.max_corr_dist > 0, "odometry.max_corr_dist", "must be > 0")
        _check(self.max_iters >= 1, "odometry.max_iters", "must be >= 1")
        _check(self.lru_horizon >= 1 and self.lru_clear_cycle >= 1, "odometry.lru_horizon",
               "and odometry.lru_clear_cycle must be >= 1")
        _check(self.deskew_window >= 1, "odometry.deskew_window", "must be >= 1")
        _check(self.gap_factor > 1, "odometry.gap_factor", "must be > 1")
        _check(self.gap_trust >= 1, "odometry.gap_trust", "must be >= 1 (1: every gap asks DeepBBS++)")
        _check(0 < self.fit_drop <= 1, "odometry.fit_drop", "must be in (0, 1]")
        _check(self.fit_window >= 1, "odometry.fit_window", "must be >= 1")
        _check(self.fit_margin >= 0, "odometry.fit_margin", "must be >= 0")
        _check(self.threads >= 0, "odometry.threads", "must be >= 0 (0 = every core)")
        _check(0 <= self.degenerate_ratio < 1, "odometry.degenerate_ratio", "must be in [0, 1) (0 = never)")
        _check(self.gate_sigmas >= 0, "odometry.gate_sigmas", "must be >= 0 (0 = off)")
        _check(0 <= self.line_share <= 1, "odometry.line_share", "must be in [0, 1] (1 = never)")
        _check(0 <= self.map_refresh < 1, "odometry.map_refresh", "must be in [0, 1) (0 = after every scan)")


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


@dataclass
class TrainConfig:
    """deepbbs-train: data, augmentation, loss and optimiser."""

    epochs: int = 20  # training epochs
    steps_per_epoch: int = 150  # optimiser steps per epoch
    batch_size: int = 8  # pairs per step (per process under torchrun)
    num_points: int = 0  # points per training cloud; 0 = preprocess.num_points (validation always uses that)
    lr: float = 1e-3  # Adam learning rate
    lr_step: int = 8  # epochs between learning-rate decays
    lr_gamma: float = 0.5  # learning-rate factor at each decay
    grad_clip: float = 1.0  # max gradient norm; 0 disables clipping
    beta: float = 0.95  # weight of the correspondence loss: beta ** epoch
    theta: float = 1.0  # m; a source point has a true partner within theta (1000 FPS points: ~2 m apart)
    trans_weight: float = 1.0  # weight of the translation term (1 = the paper's loss; scaled units, see train/loss.py)
    max_dist: float = 5.0  # m; pairs of frames at most this far apart
    yaw_aug_deg: float = 45.0  # extra random yaw on top of the real relative pose
    trans_aug: float = 1.0  # m; extra random translation
    crop_prob: float = 0.3  # probability of a partial-overlap crop of one cloud
    noise_sigma: float = 0.01  # m
    val_every: int = 1  # epochs
    val_pairs: int = 16  # fixed held-out pairs per validation set (plain and with extra yaw)
    checkpoint_minutes: float = 10.0  # also save the latest state this often within an epoch; 0 = epoch ends only
    seed: int = 0  # seeds the pair draws, augmentation and initial weights

    def validate(self) -> None:
        for name in ("epochs", "steps_per_epoch", "batch_size", "lr_step", "val_every", "val_pairs"):
            _check(getattr(self, name) >= 1, f"train.{name}", "must be >= 1")
        _check(self.num_points == 0 or self.num_points >= 16, "train.num_points", "must be 0 or >= 16")
        _check(self.grad_clip >= 0, "train.grad_clip", "must be >= 0")
        _check(self.trans_weight > 0, "train.trans_weight", "must be > 0")
        _check(self.checkpoint_minutes >= 0, "train.checkpoint_minutes", "must be >= 0")
        _check(self.lr > 0, "train.lr", "must be > 0")
        _check(0 < self.lr_gamma <= 1, "train.lr_gamma", "must be in (0, 1]")
        _check(0 < self.beta <= 1, "train.beta", "must be in (0, 1]")
        _check(self.theta > 0, "train.theta", "must be > 0")
        _check(self.max_dist > 0, "train.max_dist", "must be > 0")
        _check(0 <= self.crop_prob <= 1, "train.crop_prob", "must be in [0, 1]")
        _check(self.noise_sigma >= 0, "train.noise_sigma", "must be >= 0")


@dataclass
class EvalConfig:
    """Pair protocol and success thresholds of docs/CONVENTIONS.md."""

    stride: int = 100  # pairs mode: a source frame every `stride` frames
    max_dist: float = 5.0  # m; pairs mode: target = last frame within max_dist of the source
    max_pair_frames: int = 300  # pairs mode: the target is searched at most this many frames ahead
    success_rot_deg: float = 1.0  # a pair succeeds within this rotation error ...
    success_trans: float = 0.3  # m; ... and this translation error
    odom_stride: int = 1  # odometry mode: register every k-th frame against the previous kept one
    odom_init: str = "constant_velocity"  # odometry initial guess: "constant_velocity" | "identity"
    perturb_yaw_deg: float = 0.0  # random initial yaw of the source, uniform in [-x, x] (basin test)
    perturb_trans: float = 0.0  # m; random horizontal initial offset of the source, |offset| <= x
    trials: int = 1  # perturbed trials per pair
    seed: int = 0  # seeds the perturbations
    # Baselines (small_gicp ICP / point-to-plane ICP / GICP): "dense" = crop to
    # [preprocess.min_range, preprocess.max_range] + voxel grid (ground kept, what ICP needs);
    # "deepbbs" = exactly the DeepBBS++ preprocessing (1000 FPS non-ground points).
    baseline_input: str = "dense"
    baseline_voxel_size: float = 0.5  # m
    baseline_max_corr_dist: float = 2.0  # m
    baseline_max_iters: int = 50  # ICP / GICP iterations of the baselines
    baseline_neighbors: int = 20  # neighbours for normals / covariances
    kiss_matcher_voxel: float = 0.3  # m; KISS-Matcher's voxel size (its default for outdoor LiDAR)
    kiss_deskew: bool = True  # KISS-ICP motion compensation when scans carry a per-point "time"
    drop_frames: int = 0  # odometry robustness: this many gaps of drop_min..drop_max skipped scans (seeded by seed)
    drop_min: int = 3  # shortest gap of drop_frames (scans)
    drop_max: int = 10  # longest gap of drop_frames (scans)
    wrong_prior: int = 0  # odometry robustness: this many frames whose motion prior is off by a random motion
    wrong_prior_yaw_deg: float = 30.0  # ... of up to this yaw
    wrong_prior_trans: float = 2.0  # m ... and up to this horizontal shift
    # threads of every threaded library in an offline run (deepbbs-replay): small_gicp in the baselines, in DeepBBS++'s
    # precision stage and odometry (they replace registration.polish_threads, odometry.threads), KISS-ICP, and torch in
    # the network (registration.threads). 1: one recording's figures are the same on any number of cores and in a
    # fleet (small_gicp's and KISS-ICP's parallel sums and voxel grids follow the thread count and the scheduling);
    # N > 1: faster on a large machine, figures that change with N and from run to run; 0 = each section's own
    # setting (the live node's: small_gicp and KISS-ICP on every core)
    threads: int = 1
    bag_aligned_clouds: int = 5  # pairs whose aligned source cloud goes into the results bag

    def validate(self) -> None:
        _check(self.drop_frames >= 0, "eval.drop_frames", "must be >= 0")
        _check(1 <= self.drop_min <= self.drop_max, "eval.drop_min", "must be >= 1 and <= eval.drop_max")
        _check(self.wrong_prior >= 0, "eval.wrong_prior", "must be >= 0")
        _check(self.wrong_prior_yaw_deg >= 0 and self.wrong_prior_trans >= 0, "eval.wrong_prior_yaw_deg",
               "and eval.wrong_prior_trans must be >= 0")
        _check(self.stride >= 1, "eval.stride", "must be >= 1")
        _check(self.max_dist > 0, "eval.max_dist", "must be > 0")
        _check(self.max_pair_frames >= 1, "eval.max_pair_frames", "must be >= 1")
        _check(self.success_rot_deg > 0, "eval.success_rot_deg", "must be > 0")
        _check(self.success_trans > 0, "eval.success_trans", "must be > 0")
        _check(self.odom_stride >= 1, "eval.odom_stride", "must be >= 1")
        _check(
            self.odom_init in ("constant_velocity", "identity"),
            "eval.odom_init",
            f"must be 'constant_velocity' or 'identity', got {self.odom_init!r}",
        )
        _check(0 <= self.perturb_yaw_deg <= 180, "eval.perturb_yaw_deg", "must be in [0, 180]")
        _check(self.perturb_trans >= 0, "eval.perturb_trans", "must be >= 0")
        _check(self.trials >= 1, "eval.trials", "must be >= 1")
        _check(
            self.baseline_input in ("dense", "deepbbs"),
            "eval.baseline_input",
            f"must be 'dense' or 'deepbbs', got {self.baseline_input!r}",
        )
        _check(self.baseline_voxel_size > 0, "eval.baseline_voxel_size", "must be > 0")
        _check(self.baseline_max_corr_dist > 0, "eval.baseline_max_corr_dist", "must be > 0")
        _check(self.baseline_max_iters >= 1, "eval.baseline_max_iters", "must be >= 1")
        _check(self.baseline_neighbors >= 5, "eval.baseline_neighbors", "must be >= 5")
        _check(self.kiss_matcher_voxel > 0, "eval.kiss_matcher_voxel", "must be > 0")
        _check(self.threads >= 0, "eval.threads", "must be >= 0 (0 = each section's own thread setting)")
        _check(self.bag_aligned_clouds >= 0, "eval.bag_aligned_clouds", "must be >= 0")


@dataclass
class Config:
    """The whole configuration; one section per area."""

    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    node: NodeConfig = field(default_factory=NodeConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    localization: LocalizationConfig = field(default_factory=LocalizationConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def validate(self) -> Config:
        for f in dataclasses.fields(self):
            getattr(self, f.name).validate()
        return self

    # -- conversion -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Nested plain dict (YAML/JSON friendly)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> Config:
        """Build from nested sections; missing keys keep their defaults, unknown keys are errors."""
        data = dict(data or {})
        cfg = cls()
        sections = {f.name: f for f in dataclasses.fields(cls)}
        data = _nest_dotted(data, sections)
        for name, values in data.items():
            if name not in sections:
                hint = did_you_mean(name, list(sections) + list(cls().to_flat()))
                raise ConfigError(f"config: unknown section {name!r}" + (hint or f" (known: {', '.join(sections)})"))
            if values is None:
                continue
            if not isinstance(values, dict):
                raise ConfigError(f"config: section {name!r} must be a mapping, got {type(values).__name__}")
            setattr(cfg, name, _build_section(type(getattr(cfg, name)), name, values))
        return cfg.validate()

    def to_flat(self) -> dict[str, Any]:
        """Dotted names as used for ROS parameters: ``{"preprocess.voxel_size": 0.3, ...}``."""
        return {f"{s}.{k}": v for s, sec in self.to_dict().items() for k, v in sec.items()}

    @classmethod
    def from_flat(cls, flat: dict[str, Any]) -> Config:
        """Inverse of :meth:`to_flat`; keys without a dot are errors."""
        nested: dict[str, dict[str, Any]] = {}
        for key, value in flat.items():
            section, sep, name = key.partition(".")
            if not sep or not name:
                raise ConfigError(f"config: parameter {key!r} is not of the form 'section.name'")
            nested.setdefault(section, {})[name] = value
        return cls.from_dict(nested)

    def replace(self, **flat: Any) -> Config:
        """A copy with some dotted keys changed: ``cfg.replace(**{"preprocess.num_points": 512})``."""
        merged = self.to_flat()
        for key in flat:
            if key not in merged:
                raise ConfigError(f"config: unknown parameter {key!r}{did_you_mean(key, merged)}")
        merged.update(flat)
        return Config.from_flat(merged)

    @classmethod
    def from_yaml(cls, path: str | Path) -> Config:
        """Load plain sections, or a ROS 2 parameter file (``<node>: ros__parameters: ...``)."""
        import yaml

        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text())
        except FileNotFoundError as err:
            raise ConfigError(f"config: file not found: {path}") from err
        except yaml.YAMLError as err:
            raise ConfigError(f"config: {path} is not valid YAML: {err}".replace("\n", " ")) from err
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise ConfigError(f"config: {path} must hold a mapping at the top level")
        data = _unwrap_ros_params(data)
        try:
            return cls.from_dict(data)
        except ConfigError as err:
            raise ConfigError(f"{err} (in {path})") from err

    def to_yaml(self, path: str | Path | None = None, node_name: str | None = None) -> str:
        """Dump as YAML; with ``node_name`` as a ROS 2 parameter file. Writes ``path`` if given."""
        import yaml

        data: dict[str, Any] = self.to_dict()
        if node_name:
            data = {node_name: {"ros__parameters": data}}
        text = yaml.safe_dump(data, sort_keys=False)
        if path is not None:
            Path(path).write_text(text)
        return text


def _unwrap_ros_params(data: dict[str, Any]) -> dict[str, Any]:
    """``{node: {ros__parameters: {...}}}`` or ``{/**: {ros__parameters: ...}}`` -> the inner dict."""
    if len(data) == 1:
        (inner,) = data.values()
        if isinstance(inner, dict) and "ros__parameters" in inner:
            params = dict(inner["ros__parameters"])
            params.pop("use_sim_time", None)
            return params
    return data


def _nest_dotted(data: dict[str, Any], sections: Any) -> dict[str, Any]:
    """Dotted top-level keys of a known section (``preprocess.voxel_size: 0.3``, as a ROS 2 parameter file
    may write them) moved into their section; a key given both ways is an error."""
    out: dict[str, Any] = {}
    dotted = []
    for key, value in data.items():
        section, sep, name = str(key).partition(".")
        if sep and name and section in sections:
            dotted.append((key, section, name, value))
        else:
            out[key] = value
    for key, section, name, value in dotted:
        inner = out.get(section)
        if inner is None:
            inner = out[section] = {}
        elif not isinstance(inner, dict):
            continue  # from_dict names the bad section
        else:
            inner = out[section] = dict(inner)
        if name in inner:
            raise ConfigError(f"config: {key} is given twice (as {key} and under {section}:)")
        inner[name] = value
    return out


def _build_section(cls: type, section: str, values: dict[str, Any]) -> Any:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in values.items():
        if key not in known:
            hint = did_you_mean(f"{section}.{key}", Config().to_flat())
            raise ConfigError(f"config: unknown parameter {section}.{key}"
                              + (hint or f" (known in {section}: {', '.join(sorted(known))})"))
        kwargs[key] = _coerce(value, hints[key], f"{section}.{key}")
    return cls(**kwargs)


def _coerce(value: Any, hint: Any, key: str) -> Any:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        for arg in typing.get_args(hint):
            if arg is type(None) and value is None:
                return None
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        return _coerce(value, args[0], key)
    if origin is list:
        (item,) = typing.get_args(hint)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config: {key} must be a list, got {value!r}")
        return [_coerce(v, item, f"{key}[{i}]") for i, v in enumerate(value)]
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"config: {key} must be true or false, got {value!r}")
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ConfigError(f"config: {key} must be an integer, got {value!r}")
    if hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise ConfigError(f"config: {key} must be a number, got {value!r}")
    if hint is str:
        if isinstance(value, str):
            return value
        if isinstance(value, bool):  # YAML 1.1 and ROS parameters (-p name:=on / off) read on / off as booleans
            return "on" if value else "off"
        raise ConfigError(f"config: {key} must be a string, got {value!r}")
    return value


def load_config(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Defaults, then a YAML file (if given), then dotted overrides: the order every CLI uses."""
    cfg = Config.from_yaml(path) if path else Config()
    if overrides:
        cfg = cfg.replace(**overrides)
    return cfg
