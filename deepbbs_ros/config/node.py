"""The ``node`` section: the live rclpy node (modes, QoS, frames, TF, diagnostics)."""

from __future__ import annotations

from dataclasses import dataclass, field

from deepbbs_ros.config.keys import _check


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
