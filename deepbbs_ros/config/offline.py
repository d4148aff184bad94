"""The ``train`` and ``eval`` sections: deepbbs-train, and the pair protocol and thresholds of deepbbs-replay."""

from __future__ import annotations

from dataclasses import dataclass

from deepbbs_ros.config.keys import _check


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
    # per-pair pose term: "squared" = rot + trans_weight * trans (the paper's); "bounded" = its pseudo-Huber with
    # the scale of a pair at the success tolerance (eval.success_rot_deg / success_trans): squared below it,
    # growing like the error above, so no pair pulls more than ~1.4 pairs at the tolerance (see train/loss.py)
    pose_loss: str = "squared"
    # degrees; a pair the network's own pass leaves further off in rotation is left out of the step's loss (0 = none
    # is: every pair counts, as the shipped model was trained). Sensor-mix pairs in halls and garages the network
    # cannot solve in one pass (>10 deg) carried 94-95 % of the rotation term and cost the translation precision
    hard_pair_deg: float = 0.0
    # L2-SP: alpha of alpha/2 ||w - w_start||^2 added to each step's loss, w_start the weights the run started from
    # (--init); 0 = off. Holds a fine-tune near the shipped weights (train/anchor.py)
    sp_weight: float = 0.0
    max_dist: float = 5.0  # m; pairs of frames at most this far apart
    # how pairs are drawn: "pairs" = drives in proportion to their pair count (capped at 2000), then any of their
    # pairs; "distance" = every drive alike, then the pair's distance uniform over tenths of max_dist (slow
    # mounts, handheld or legged, have most pairs under 1 m: drawn by count they teach that scans are close)
    pair_balance: str = "pairs"
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
        _check(self.pose_loss in ("squared", "bounded"), "train.pose_loss",
               f"must be 'squared' or 'bounded', got {self.pose_loss!r}")
        _check(self.hard_pair_deg >= 0, "train.hard_pair_deg", "must be >= 0")
        _check(self.sp_weight >= 0, "train.sp_weight", "must be >= 0")
        _check(self.checkpoint_minutes >= 0, "train.checkpoint_minutes", "must be >= 0")
        _check(self.lr > 0, "train.lr", "must be > 0")
        _check(0 < self.lr_gamma <= 1, "train.lr_gamma", "must be in (0, 1]")
        _check(0 < self.beta <= 1, "train.beta", "must be in (0, 1]")
        _check(self.theta > 0, "train.theta", "must be > 0")
        _check(self.max_dist > 0, "train.max_dist", "must be > 0")
        _check(self.pair_balance in ("pairs", "distance"), "train.pair_balance",
               f"must be 'pairs' or 'distance', got {self.pair_balance!r}")
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
