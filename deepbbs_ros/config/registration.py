"""The ``model`` and ``registration`` sections: the network, and the DeepBBS++ pipeline of ``register()`` (deep
passes, refinement, precision stage, verdict, global search, good start)."""

from __future__ import annotations

from dataclasses import dataclass, field

from deepbbs_ros.config.keys import _check


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
    # rad; > 0: GICP, run on polish_voxel, finishes on a scan's scene-sized grid, this angle seen from the sensor at
    # its median range (after the crop), at least polish_voxel / 4, polish_max_corr_dist scaled with it (core/polish.py
    # scene_voxel, finish): in the precision stage, and where the good start's verdict did not take GICP's pose;
    # scans whose median range puts it at polish_voxel or above (8 m at 1/16) are not touched; 0 = polish_voxel only
    # (measured in docs/sensors.md)
    polish_voxel_angle: float = 0.0625
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
    # a valid pose left free by more than a tolerance along its weakest direction is checked for a second minimum there
    # (core/second_minimum.py: GICP from the pose moved both ways along it); one as good beyond the tolerance -> invalid
    second_minimum: bool = True
    # the pair's check (not the good start's, not localization's) where its first starts find no other minimum and
    # the fit leaves a slide free: GICP from the pose moved 2, 4, ... times as far along its weakest translation,
    # both ways, up to the target cloud's extent along it (the scene's own size); a minimum within half a step of
    # its start that fits as well -> invalid (a slide of metres along a hall lies beyond the first starts' 1.5 m)
    second_minimum_reach: bool = False
    # the verdict's probability times P(the pose within success_rot_deg / success_trans | its covariance)
    # (core/within.py: the cluster-robust covariance of its GICP pairs, core/covariance.py), where that can change
    # the decision: a pose free to slide (a corridor, a straight road) is consistent anywhere along the slide, but
    # not sure to be within the tolerance. "pair": the registration's verdict; "all": the good start's as well;
    # "off" (the default: "pair" turns away wrong slides but also right poses in corridors, docs/sensors.md)
    verdict_within: str = "off"
    # a global search's answer (another start than the given one) is valid only when its fitness (the score) reaches
    # this too: a flip that lays the ground on the ground fits little else (simulated Avia courtyard flips scored
    # 0.002-0.01 with probability 0.91-0.92; right answers on a real handheld Livox Avia walk scored 0.25 and more)
    search_min_score: float = 0.1
    # the global search's answer is weighed against its other candidates (core/search_ambiguity.py): where one beyond
    # 2 deg / 0.5 m of it is valid too, P(right) is at most p / (p + p_other) and the answer is not valid; the given
    # start's valid answer that is not sure (verdict_sure) runs the search to be weighed too, unless register() was told
    # good_start and the answer stayed within good_start_max_*. Far starts: docs/sensors.md
    search_ambiguity: bool = False
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
    # register(..., good_start=True) gives GICP from the vouched start its own budget (polish_max_iters) and takes its
    # answer wherever the good-start verdict accepts it (the localization's tracking too, with the map verdict);
    # these limits name it "beyond the good start's limits" past them and bound the coarse try's answer (twice them)
    good_start_max_iters: int = 10  # GICP iterations a vouched start should need
    good_start_max_trans: float = 3.0  # m; how far GICP should move a vouched start
    good_start_max_rot_deg: float = 10.0  # deg; idem for rotation
    # the grid on which the good start judges GICP's pose finished on the scene-sized grids (polish_voxel_angle):
    # "gicp" (GICP's polish_voxel grid, the one the verdict's coefficients were fitted on); "scene" (those scene-sized
    # grids, verdict_dist scaled with them, then the second-minimum check there: one more simulated wrong pose
    # accepted, tried); "both": "gicp", then, where GICP's grid does not hold the pose along its weakest direction
    # (pinned under the verdict file's held_pinned), taken when "scene" takes it and GICP's grid does with pinned read
    # on the scene's grids (core/finish_verdict.py: the Mid-360 corridor's right poses taken instead of the search,
    # but two more simulated wrong poses accepted on held-out seed 43; docs/sensors.md, tried, not the default)
    good_start_finish_grid: str = "gicp"
    # the same for the full pipeline's answer finished on the scene-sized grids: "gicp" (judged again on GICP's grid)
    # or "both" (then as good_start_finish_grid "both", at verdict_probability; tried, not the default)
    finish_grid: str = "gicp"
    # where GICP from the start and its finish are rejected and the finished pose is degenerate (core/finish_verdict.py
    # degenerate: GICP's grid neither holds nor takes it, and takes it with pinned read on the scene's grids: the hold
    # the verdict lacks is the scene's, which no other start changes), answer it at once, not valid ("not valid:
    # degenerate along ..."), instead of the coarse try and the full pipeline
    good_start_degenerate: bool = True
    # the second-minimum check (core/second_minimum.py, as the registration's verdict runs it) on the good start's
    # poses taken on GICP's grid too: a pose GICP slides to another minimum as good along its weakest direction is not
    # taken (the next try answers). Checked where the fit leaves the pose freer than a slide's distance (5 tolerances),
    # or than a wrong pose's (2) when the verdict is not sure (verdict_sure). On: simulated seeds 39-43 wrong accepted
    # 22 -> 14, right rejected 273 -> 286 (mostly low-overlap; nothing chosen on 42, 43: 4 -> 3, 111 -> 116); it costs
    # two more GICP runs on every pose of a corridor nothing pins (OS0-64 legged: CPU x1.27 -> x1.65 GICP's)
    good_start_second_minimum: bool = True
    # the skew check (core/sweep_skew.py), where the verdict would accept, on Livox-like sweeps with per-point times
    # only (spinning sweeps and scans without times: nothing runs): each sweep's own motion (one Gauss-Newton step
    # with the pose and its rate over the sweep); where the pose error the two imply, less skew_sigmas standard errors,
    # exceeds success_rot_deg / success_trans, the pose cannot be right: not valid ("sweep skew"). On: simulated wrong
    # solid-state poses accepted 2 -> 0, 4 -> 0 (seeds 39, 40), no right pose rejected on those or held-out seed 41
    skew_check: bool = True
    skew_sigmas: float = 2.0  # standard errors taken off the estimate: the least error the sweeps' motion implies

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
        _check(self.polish_voxel_angle >= 0, "registration.polish_voxel_angle", "must be >= 0 (0 = polish_voxel)")
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
        _check(self.good_start_finish_grid in ("gicp", "scene", "both"), "registration.good_start_finish_grid",
               f"must be 'gicp', 'scene' or 'both', got {self.good_start_finish_grid!r}")
        _check(self.finish_grid in ("gicp", "both"), "registration.finish_grid",
               f"must be 'gicp' or 'both', got {self.finish_grid!r}")
        _check(self.verdict_within in ("off", "pair", "all"), "registration.verdict_within",
               f"must be 'off', 'pair' or 'all', got {self.verdict_within!r}")
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
        _check(self.skew_sigmas >= 0, "registration.skew_sigmas", "must be >= 0")


#: the network alone (``deepbbs-replay --method deepbbs``, ``deepbbs-train evaluate --methods deepbbs``): the deep
#: passes from the one start given, with no refinement, no precision stage and no global search (whose other starts
#: end in GICP): the network's own answer
NETWORK_ALONE = {"registration.refine": False, "registration.polish": "none", "registration.global_search": "off"}
