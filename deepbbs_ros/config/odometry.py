"""The ``odometry`` section: local-map LiDAR odometry (GICP against a voxel map, DeepBBS++ where the prior fails)."""

from __future__ import annotations

from dataclasses import dataclass

from deepbbs_ros.config.keys import _check


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
    # the step covariance's rotation floor: fixed (core/motion_floor.py) | adaptive (its variance scaled so that the
    # last steps' innovations from the constant-velocity prediction have their expected mean NIS) | adaptive_bound
    # (the largest such scale their NIS does not reject at 2.5 %); core/floor_scale.py: not the default, measured
    # overconfident on the simulated VLP-16 drives
    sweep_floor: str = "fixed"

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
        _check(self.sweep_floor in ("fixed", "adaptive", "adaptive_bound"), "odometry.sweep_floor",
               f"must be 'fixed', 'adaptive' or 'adaptive_bound', got {self.sweep_floor!r}")
