"""The live registration node ``deepbbs_registration`` (console script ``deepbbs-node``).

Inputs (relative names: remap them the ROS way, ``-r source_cloud:=/lidar/points``; a remap whose name is
none of the node's topics is logged as a warning naming the inputs, since ROS ignores it):

* ``node.mode: pair`` (default): ``source_cloud`` and ``target_cloud`` (sensor_msgs/PointCloud2),
  paired by approximate time (``node.queue_size`` per input, ``node.slop`` seconds).
* ``node.mode: odometry``: one input ``cloud`` (or ``pointcloud_topic``, KISS-ICP's name, when that one is
  remapped and ``cloud`` is not: ``-r pointcloud_topic:=/points`` works as with KISS-ICP); the scans run
  through the odometry of ``deepbbs-replay --mode odometry --method deepbbs++``
  (:class:`deepbbs_ros.core.odometry.DeepBBSOdometry`, the
  ``odometry`` config section): deskewing with the per-point times (Velodyne ``time``, Ouster ``t``),
  GICP against a local voxel map, and DeepBBS++ (the node's network) consulted on long stamp gaps, fit drops
  and the first motion (:class:`deepbbs_ros.node.pipeline.LocalMapOdometry`). The chained scan-to-scan
  odometry (scan k registered against scan k-1) stays available as ``odometry_method="scan_to_scan"``
  of :class:`RegistrationNode` (the GICP anchor uses it).

Outputs (docs/CONVENTIONS.md, :mod:`deepbbs_ros.node.outputs`):

* ``~/pose`` (geometry_msgs/PoseStamped). Pair mode: ``T_target_source``, ``frame_id`` = target cloud
  frame, stamp = source stamp. Odometry mode: the base's pose ``T_odom_base = T_base_sensor @ T_odom_sensor @
  inv(T_base_sensor)`` (REP-105; the odom frame is the base at the first scan; ``T_base_sensor`` looked up on
  ``/tf_static`` for ``node.base_frame``, :mod:`deepbbs_ros.node.tf_static`; identity with one warning when
  none arrives within ``node.tf_timeout``, or with ``node.base_frame: ''``), ``frame_id`` = ``node.odom_frame``.
  Latched target (``node.target_mode: latched``): the scan's pose in the map frame.
* ``~/transform`` (geometry_msgs/TransformStamped): the same transform, ``child_frame_id`` = the source
  frame (pair mode) or ``node.base_frame`` / the cloud frame (odometry mode).
* ``~/odometry`` (nav_msgs/Odometry, ``node.publish_odometry``, on by default: twist from the motion since the
  previous scan over the stamp gap, covariances from the registration residuals of that motion,
  :mod:`deepbbs_ros.node.covariance`, accumulated along the trajectory in odometry mode), ``/tf``
  (``node.publish_tf``, on by default in odometry mode: ``odom_frame -> base_frame``, or the inverse with
  ``node.invert_tf``; pair mode only with ``node.pair_tf``; needs tf2_msgs: ``deepbbs-ros build-interfaces``),
  opt-in ``~/aligned_cloud`` (pair mode: the source cloud moved into the target frame; odometry mode: the scan
  moved into ``node.odom_frame``).
* ``/diagnostics``: latency per stage, clouds / pairs received, processed, dropped, errors per kind (an input
  that never pairs: ``unpaired_input``), odometry restarts on time jumps, model, device. ``~/reset``
  (std_srvs/Trigger): restart odometry at identity (a latched target: at ``node.initial_pose``) and clear the
  synchroniser.

Start-up: the model is loaded and every stage run once on a synthetic drive (``node.warmup``) before the node
logs ``ready in X s``. A scan more than 1 s before the previous one in odometry mode (a bag played again)
restarts the odometry with one log line. With ``--ros-args --log-level deepbbs_registration:=debug`` every
odometry step is logged (the path it took: GICP from the prediction, or DeepBBS++ and why; the fit; where
its time went) and every scan dropped for a newer one; the node logs its counts when it stops.

Threads: the executor's callbacks only hand messages on. Each input has its own thread that decodes and
checks every cloud on arrival and preprocesses it for DeepBBS++ (pair mode, scan-to-scan odometry; the
local-map odometry works on the raw points and preprocesses only the scans it consults DeepBBS++ on)
(:mod:`deepbbs_ros.node.inputs`; at most one message waits per input, older ones are dropped and
counted), so a pair's latency is mostly its registration. Registration / odometry runs on one worker
thread behind a "latest" slot (:mod:`deepbbs_ros.node.worker`, :mod:`deepbbs_ros.node.pipeline`): the
newest pair or scan wins, stale ones are dropped and counted. In pair mode on a CPU
(``node.registration_process: auto``) these threads hand the preprocessing and the registration to the
registration process (:mod:`deepbbs_ros.node.registration_process`), so that this process keeps only rclpy,
decoding and the hand-off; if that process dies, one line is logged and the node registers itself. Bad input
(malformed PointCloud2, empty, too few points, NaN-only, missing or changed frames) is logged once per
kind and period (``node.error_log_period``), nothing is published for it, and the node goes on.
"""

from __future__ import annotations

import functools
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

from deepbbs_ros.config import Config
from deepbbs_ros.entry import cli_entry
from deepbbs_ros.errors import ConfigError, NodeError
from deepbbs_ros.node.diagnostics import RateLimitedErrors, StageTimes
from deepbbs_ros.node.drivers import describe as describe_driver
from deepbbs_ros.node.drops import DropLog
from deepbbs_ros.node.inputs import BadInput, Cloud, CloudInput, PreprocessCache, arrival_preprocess
from deepbbs_ros.node.localization import NodeLocalization, load_map_file
from deepbbs_ros.node.outputs import Outputs, TfBroadcaster
from deepbbs_ros.node.parameters import (
    check_parameter_names,
    load_registration,
    node_parameters,
    validate_frame,
)
from deepbbs_ros.node.pipeline import (
    LocalMapOdometry,
    MapTarget,
    PairStart,
    ScanToScanOdometry,
    register_clouds,
    takes_good_start,
)
from deepbbs_ros.node.remaps import KISS_ICP_INPUT, ODOM_INPUT, PAIR_INPUTS, unmatched_remaps
from deepbbs_ros.node.rep105 import Rep105
from deepbbs_ros.node.run import run_node
from deepbbs_ros.node.sync import ApproximateTimeSync
from deepbbs_ros.node.tf_buffer import TransformBuffer
from deepbbs_ros.node.worker import LatestSlotWorker

NODE_NAME = "deepbbs_registration"
ODOMETRY_METHODS = ("local_map", "scan_to_scan")
JUMP_BACK_S = 1.0  # s; odometry mode: a stamp this far before the last one is a time jump (reset)


def _qos_text(qos: QoSProfile) -> str:
    """``reliable/5`` or ``best_effort/5`` (reliability / history depth)."""
    rel = "reliable" if qos.reliability == ReliabilityPolicy.RELIABLE else "best_effort"
    return f"{rel}/{qos.depth}"


class RegistrationNode(Node):
    """See the module docstring.

    Args:
        config: defaults of every parameter (ROS parameters override them); None = ``Config()``.
        registration: a ready registration object (``preprocess(xyz)``, ``register(src_pp, tgt_pp)``),
            e.g. a small test model or the GICP anchor; default: DeepBBS++ with ``registration.weights``.
        tf_broadcaster: used instead of a ``/tf`` publisher when ``node.publish_tf`` is set.
        odometry_method: odometry mode's pipeline: ``"local_map"`` (default; DeepBBSOdometry, as
            ``deepbbs-replay --mode odometry --method deepbbs++``) or ``"scan_to_scan"`` (scan k registered
            against scan k-1 with ``registration``, chained; each scan preprocessed on arrival).
        remaps: the command line's remap rules (:func:`~deepbbs_ros.node.remaps.remap_rules`, given by
            ``run_node``): those that match none of the node's topics are logged as warnings
            (:attr:`remap_warnings`) before the model loads.
        node_name, node_kwargs: passed to ``rclpy.node.Node``.

    Raises:
        NodeError: a bad parameter, frame id, topic name or weights path.
    """

    def __init__(
        self,
        config: Config | None = None,
        *,
        registration: Any = None,
        tf_broadcaster: TfBroadcaster | None = None,
        odometry_method: str = "local_map",
        node_name: str = NODE_NAME,
        remaps: Any = (),
        **node_kwargs: Any,
    ) -> None:
        t_start = time.perf_counter()
        super().__init__(node_name, **node_kwargs)
        t_model = self._configure_parts(config or Config(), registration, odometry_method, remaps, t_start)
        self._create_outputs(tf_broadcaster)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        t_warm = time.perf_counter()
        self._warm()
        self._subscribe()
        t_end = time.perf_counter()
        self.startup_s = t_end - t_start
        self.get_logger().info(
            f"ready in {self.startup_s:.1f} s (model {t_model:.1f} s, warm-up {t_end - t_warm:.1f} s)"
        )

    # -- phases: the plain node runs them in __init__, the managed node (node/managed.py) one per transition ------
    def _configure_parts(self, config: Config, registration: Any, odometry_method: str, remaps: Any,
                         t_start: float) -> float:
        """Read the parameters; load the map file, the model (unless ``registration`` is given) and the pipeline's
        parts (the worker's thread). Returns the model's load time (s)."""
        self.cfg = self._declare_config(config)
        ncfg = self.cfg.node
        validate_frame("node.odom_frame", ncfg.odom_frame)
        validate_frame("node.base_frame", ncfg.base_frame)
        validate_frame("node.map_frame", ncfg.map_frame)
        if not ncfg.odom_frame:
            raise NodeError("node.odom_frame: must not be empty")
        if odometry_method not in ODOMETRY_METHODS:
            raise NodeError(f"odometry_method must be one of {', '.join(ODOMETRY_METHODS)}, got {odometry_method!r}")
        self.odometry_method = odometry_method
        # inputs: KISS-ICP's pointcloud_topic is the odometry input when it is remapped and cloud is not
        self.input_names = PAIR_INPUTS if ncfg.mode == "pair" else (ODOM_INPUT,)
        localization = ncfg.mode == "pair" and ncfg.target_mode == "localization"
        map_file = None
        if localization and self.cfg.localization.map_path:  # read (and refused) before the model loads
            map_file = load_map_file(self.cfg.localization.map_path, ncfg.map_frame)
            self.input_names = PAIR_INPUTS[:1]  # the map is the file's: no map topic
        if ncfg.mode == "odometry" and self._remapped(KISS_ICP_INPUT) and not self._remapped(ODOM_INPUT):
            self.input_names = (KISS_ICP_INPUT,)
        self.remap_warnings = unmatched_remaps(remaps, ncfg.mode, self.get_name(), self.get_namespace())
        if ncfg.mode == "odometry" and self._remapped(KISS_ICP_INPUT) and self._remapped(ODOM_INPUT):
            self.remap_warnings.append(f"{KISS_ICP_INPUT} and {ODOM_INPUT} are both remapped: the input is "
                                       f"{ODOM_INPUT}'s topic, the {KISS_ICP_INPUT} remap is ignored")
        for text in self.remap_warnings:
            self.get_logger().warning(text)
        self._errors = RateLimitedErrors(lambda text: self.get_logger().error(text), ncfg.error_log_period)
        # conditions of the graph, not of a message: an input that never pairs, a target not there yet
        self._warnings = RateLimitedErrors(lambda text: self.get_logger().warning(text), ncfg.error_log_period)
        # localization: a scan dropped unanswered is said once, later ones summarised (node/drops.py)
        self._drops = DropLog(lambda text: self.get_logger().info(text), ncfg.error_log_period)
        self._stages = StageTimes()
        self._lock = threading.Lock()
        self._odom_lock = threading.Lock()  # the odometry state: worker thread vs ~/reset
        self._counts = {"received": 0, "pairs": 0, "processed": 0, "rejected": 0, "time_jumps": 0, "untrusted": 0}
        self._last_result: dict[str, float] = {}
        self._last_odom_stamp: int | None = None  # odometry mode: a stamp far before it is a time jump (reset)
        self._arrivals: dict[int, tuple[float, int]] = {}  # input index -> (monotonic arrival, stamp ns)
        self._gap_seen: float | None = None  # the last pair's time when a check last found the inputs' stamps apart
        self._last_pair_t = time.monotonic()
        self._map_target = MapTarget(self.cfg) if ncfg.mode == "pair" and ncfg.target_mode == "latched" else None
        self._pair_start = PairStart(ncfg.good_start_max_gap, False)  # stamped pairs: the last valid answer (below)
        self._paths = {"gicp": 0, "deepbbs": 0, "search": 0}  # pair mode: which registration path answered

        # the model: device and weights checked first, with errors naming the parameter
        self._owns_reg = registration is None  # closed with the node (its network process)
        if registration is None:
            registration, self._weights = load_registration(self.cfg, lambda text: self.get_logger().error(text))
            t_model = time.perf_counter() - t_start
        else:
            t_model = 0.0
            self._weights = str(getattr(registration, "weights", "") or "<injected model>")
        self.reg = registration
        self._device = str(getattr(registration, "device", "cpu"))
        # a registration that takes a good start (DeepBBS++; not the GICP anchor, which always starts from identity)
        self._pair_start.enabled = ncfg.good_start and ncfg.mode == "pair" and takes_good_start(registration)
        #: node.target_mode localization: the tracker in the prior map (node/localization.py), else None
        self.localization = NodeLocalization(self.cfg, registration) if localization else None
        if localization:  # the scans its bridge passes over: counted and said with the others
            self.localization.drop_sink = lambda why, stamp, n: self._drops.dropped(why, stamp, self.inputs[0].topic, n)
        if map_file is not None:
            self.get_logger().info(self.localization.build(map_file))
            if self.localization.map_warning:
                self.get_logger().warning(self.localization.map_warning)
        if ncfg.publish_odometry:  # warm the imports the first odometry message needs
            import scipy.spatial  # noqa: F401
            import scipy.spatial.transform  # noqa: F401

        # pipeline: synchroniser (pair mode), odometry (odometry mode), the registration worker
        self.sync = ApproximateTimeSync(2, ncfg.queue_size, ncfg.slop, self._on_pair)
        self.odometry = self._make_odometry()
        #: localization with node.localization_odom lidar: the node's own odometry of odom -> base
        self.loc_odometry = None
        if localization and ncfg.localization_odom == "lidar":
            try:
                self.loc_odometry = LocalMapOdometry(self.cfg, self.reg, covariance=False)
            except ImportError as err:
                raise NodeError(f"node.localization_odom lidar needs kiss-icp and small_gicp ({err}); install them, "
                                "or use 'tf' (an odometry source) or 'none'") from err
        self.worker = LatestSlotWorker(self._process, self._on_thread_error, name="deepbbs-registration")
        self._cache = PreprocessCache(arrival_preprocess(self.reg, self._pair_start.enabled or (
            self._map_target is not None and ncfg.good_start)))
        # preprocessing on arrival only where every scan is registered by the network (the localizer preprocesses
        # the raw scan itself, with its per-point times)
        self._preprocess_on_arrival = not isinstance(self.odometry, LocalMapOdometry) and self.localization is None
        self._map_file = map_file
        return t_model

    def _create_outputs(self, tf_broadcaster: TfBroadcaster | None) -> None:
        """Publishers, the inputs' threads (their subscriptions are made by :meth:`_subscribe`), the ``/tf_static``
        subscription, the services and the diagnostics timer."""
        ncfg = self.cfg.node
        # topics: a bad (remapped) name becomes NodeError, after stopping the threads started so far
        self.inputs: list[CloudInput] = []
        self._drivers: dict[str, str] = {}  # topic -> its driver and the preprocessing defaults (node.drivers)
        self.static_tf = TransformBuffer()  # /tf_static, and /tf in localization mode (node/tf_buffer.py)
        self._extrinsics: dict[str, Any] = {}  # cloud frame -> T_base_sensor, once known (or given up on)
        self._t_ready = self._t_tf = time.monotonic()  # the static transform's wait counts from here
        try:
            self.outputs = Outputs(self, ncfg, self._qos(), self._errors.log, tf_broadcaster,
                                   extrinsic=self._base_from_sensor)
            #: localization mode: REP-105 outputs (map -> odom, the base's pose, /initialpose; node/rep105.py)
            self.rep105 = None if self.localization is None else Rep105(
                self, ncfg, self.outputs, self.static_tf, self._base_from_sensor, self._warnings.log,
                self.localization.hint)
            if self.localization is not None:
                self.localization.extrinsic = self._base_from_sensor  # /initialpose: the base's pose -> the sensor's
            self._sub_tf_static = self._subscribe_tf_static()
            self._sub_tf = self._subscribe_tf() if self.rep105 is not None and self.rep105.mode == "tf" else None
            # one QoS object per subscription: rclpy applies qos_overrides.<topic>.* to it in place
            self._subscribe_inputs = [self._make_input(i, name, self._qos()) for i, name in enumerate(self.input_names)]
        except NodeError:
            self._stop_threads()
            raise
        except Exception as err:  # rclpy raises several types for bad (remapped) names
            self._stop_threads()
            raise NodeError(f"cannot create topics: {err}".replace("\n", " ")) from err
        self.srv_reset = self.create_service(Trigger, "~/reset", self._on_reset)
        if self.localization is not None:
            self.srv_relocalize = self.create_service(Trigger, "~/relocalize", self._on_relocalize)
        # diagnostics on the steady (wall) clock: with use_sim_time a ROS-time timer stops with /clock (a bag
        # that ended would leave the counters frozen); the messages still carry the node's time
        self._diag_timer = self.create_timer(ncfg.diagnostics_period, self._publish_diagnostics,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _warm(self) -> None:
        """:meth:`_warmup` where ``node.warmup`` asks for it and the model is the node's own."""
        self.warmed_up = False
        if self.cfg.node.warmup and self._owns_reg:  # an injected registration (tests, the GICP anchor) is the caller's
            try:
                self._warmup()
                self.warmed_up = True
            except Exception as err:  # noqa: BLE001 - a failed warm-up costs the first scans' latency, nothing else
                self.get_logger().warning(f"warm-up failed ({type(err).__name__}: {err}); the first scans run cold")

    def _subscribe(self) -> None:
        """Subscribe the inputs (after the warm-up: a publisher such as deepbbs-play sees the node once it is ready)
        and log them. Subscriptions the node answers go here, publishers in :meth:`_create_outputs`."""
        ncfg = self.cfg.node
        map_file = self._map_file
        try:
            self._subs = [make() for make in self._subscribe_inputs]
        except Exception as err:  # rclpy raises several types for bad (remapped) names
            self._stop_threads()
            raise NodeError(f"cannot create topics: {err}".replace("\n", " ")) from err
        self._t_ready = time.monotonic()
        self._last_pair_t = self._t_ready
        #: the QoS each input really got, after ``qos_overrides.<topic>.subscription.*``: topic -> "reliable/5"
        self.input_qos = {inp.topic: _qos_text(sub.qos_profile) for inp, sub in zip(self.inputs, self._subs)}
        qos_text = ", ".join(f"{t}: {q}" for t, q in self.input_qos.items())
        self.get_logger().info(
            f"mode={ncfg.mode} inputs=[{', '.join(i.topic for i in self.inputs)}] device={self._device} "
            f"weights={self._weights} qos=[{qos_text}] slop={ncfg.slop}s "
            f"queue={ncfg.queue_size}" + (f" odometry={self.odometry_method}" if self.odometry else "")
            + (f" target=latched ({self.inputs[1].topic})" if self._map_target is not None else "")
            + (f" target=localization (map {map_file.source if map_file else self.inputs[1].topic})"
               if self.localization is not None else "")
        )

    def _remapped(self, name: str) -> bool:
        """Whether a remap rule applies to the topic ``name``."""
        try:
            return self.resolve_topic_name(name) != self.resolve_topic_name(name, only_expand=True)
        except Exception:  # noqa: BLE001 - a bad remapped name is reported when the input is made
            return True

    def _qos(self) -> QoSProfile:
        """A new QoS profile from ``node.qos_reliability`` / ``node.qos_depth``."""
        ncfg = self.cfg.node
        return QoSProfile(
            depth=ncfg.qos_depth,
            history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy.BEST_EFFORT
            if ncfg.qos_reliability == "best_effort"
            else ReliabilityPolicy.RELIABLE,
        )

    def _make_odometry(self) -> LocalMapOdometry | ScanToScanOdometry | None:
        """The odometry of odometry mode (None in pair mode): ``reset()`` and ``step(cloud) ->
        OdometryEstimate`` (:mod:`deepbbs_ros.node.pipeline`), sharing the node's registration."""
        if self.cfg.node.mode != "odometry":
            return None
        cov = self.cfg.node.publish_odometry
        if self.odometry_method == "scan_to_scan":
            return ScanToScanOdometry(self.reg, covariance=cov)
        try:
            return LocalMapOdometry(self.cfg, self.reg, covariance=cov)
        except ImportError as err:
            raise NodeError(f"odometry mode needs kiss-icp and small_gicp ({err}); "
                            "install them or use the scan-to-scan odometry") from err

    # -- parameters ---------------------------------------------------------------------------------
    def _declare_config(self, defaults: Config) -> Config:
        """Declare the parameters of :data:`NODE_SECTIONS` (and ``odometry.*`` in odometry mode), read them
        and return the config (the other sections keep ``defaults``). Names the node does not use are
        reported (:func:`check_parameter_names`): a misspelt name in a declared section is a NodeError, any
        other unknown or unused name a warning naming the nearest parameter."""
        flat = defaults.to_flat()
        overrides = getattr(self, "_parameter_overrides", {}) or {}
        mode = overrides["node.mode"].value if "node.mode" in overrides else defaults.node.mode
        target = overrides["node.target_mode"].value if "node.target_mode" in overrides else defaults.node.target_mode
        used = node_parameters(defaults, mode, target)
        ignore = [n for n in overrides if n not in used and (self.has_parameter(n) or n.startswith("qos_overrides."))]
        if not any(self.has_parameter(k) for k in used):  # the first time (the managed node reads them again)
            errors, warnings, notes = check_parameter_names([n for n in overrides if n not in ignore], used, flat, mode)
            if errors:
                raise NodeError("; ".join(errors))
            for text in warnings:
                self.get_logger().warning(text)
            for text in notes:
                self.get_logger().info(text)
            self.parameter_warnings = warnings
        for key, value in used.items():
            if not self.has_parameter(key):
                self.declare_parameter(key, value, ParameterDescriptor(name=key, dynamic_typing=True))
        values = {k: self.get_parameter(k).value for k in used}
        try:
            return Config.from_flat({**flat, **values})
        except ConfigError as err:
            raise NodeError(str(err)) from err

    def _on_set_parameters(self, params) -> SetParametersResult:
        declared = node_parameters(self.cfg, self.cfg.node.mode, self.cfg.node.target_mode)
        ours = [p.name for p in params if p.name in declared]
        if ours:
            return SetParametersResult(successful=False, reason=f"restart the node to change {', '.join(ours)}")
        return SetParametersResult(successful=True)

    # -- inputs (executor thread, then one thread per input) -----------------------------------------
    def _make_input(self, index: int, name: str, qos: QoSProfile):
        pair = self.cfg.node.mode == "pair"
        latched = (self._map_target is not None or self.localization is not None) and name == "target_cloud"

        def on_cloud(cloud: Cloud) -> None:  # on the input's thread, once the cloud is preprocessed
            self._stages.add(cloud.timings_ms)
            with self._lock:
                self._arrivals[index] = (time.monotonic(), cloud.stamp_ns)
            if latched and self.localization is not None:
                self._on_localization_map(index, cloud)
            elif latched:
                self._map_target.set_map(cloud)
                self.get_logger().info(
                    f"target (map) from {self.inputs[index].topic}: {len(cloud.xyz)} points in {cloud.frame_id!r}"
                )
            elif self.localization is not None:
                self._on_localize_source(cloud)
            elif self._map_target is not None:
                self._on_map_source(cloud)
            elif pair:
                self.sync.add(index, cloud.stamp_ns, cloud)
            else:
                self._on_scan(cloud)

        if latched:  # a map server's QoS: reliable, transient local (the map published once reaches late joiners)
            qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        def subscribe():  # after the warm-up: a publisher (deepbbs-play) sees the node once it is ready
            return self.create_subscription(
                PointCloud2, name, lambda msg: self._on_message(index, msg), qos,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            )  # fmt: skip

        self.resolve_topic_name(name)  # a bad (remapped) name fails here, before the model's warm-up
        self.inputs.append(
            CloudInput(
                self.resolve_topic_name(name), self._cache if self._preprocess_on_arrival and not latched else None,
                self.cfg.node.min_points, on_cloud, self._on_bad, self._on_thread_error,
                increasing_stamps=not pair, gate=None if latched else self._input_gate(),
                deskew=None if latched else self._stream_deskew(),
                capacity=1 if pair else self.cfg.node.odometry_backlog,
                on_driver=None if latched else functools.partial(self._on_driver, index),
            )
        )  # fmt: skip
        return subscribe

    def _input_gate(self) -> Any:
        """The worker's room; in localization mode also open while a search or a bridge runs (node/bridge.py)."""
        if self.localization is None:
            return self.worker.room
        from deepbbs_ros.node.bridge import ArrivalGate

        return ArrivalGate(self.worker.room, lambda: self.localization.opens_input)

    def _on_driver(self, index: int, driver: str | None, xyz: Any) -> None:
        """An input's driver, recognised from its first message: logged, on /diagnostics, given to the odometry."""
        topic = self.inputs[index].topic
        value, line = describe_driver(topic, self.cfg.preprocess, driver, xyz, used=self.localization is None)
        with self._lock:
            self._drivers[topic] = value
        self.get_logger().info(line)
        if isinstance(self.odometry, LocalMapOdometry):  # DeepBBS++ consulted on its deskewed scans
            self.odometry.odometry.driver = driver

    # -- TF: base <- sensor from /tf_static --------------------------------------------------------
    def _subscribe_tf_static(self):
        """Subscribe ``/tf_static`` (transient local, as robot_state_publisher latches it) where odometry mode
        needs ``T_base_sensor``; None elsewhere, or without tf2_msgs (then the base frame moves as the sensor)."""
        ncfg = self.cfg.node
        if (ncfg.mode != "odometry" and self.localization is None) or not ncfg.base_frame:
            return None
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            self.get_logger().warning(
                f"tf2_msgs is not installed: no /tf_static lookup of {ncfg.base_frame} <- the cloud frame "
                "(identity used); build it with `deepbbs-ros build-interfaces`"
            )
            return None
        qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        return self.create_subscription(TFMessage, "/tf_static", self.static_tf.add_message, qos)

    def _subscribe_tf(self):
        """Localization mode with ``node.localization_odom: tf``: ``/tf`` into the TF buffer (``odom -> base`` at
        each scan's stamp); None without tf2_msgs."""
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            return None
        qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
        return self.create_subscription(TFMessage, "/tf", self.static_tf.add_dynamic_message, qos)

    def _base_from_sensor(self, frame: str):
        """``T_base_sensor`` for a cloud in ``frame`` (odometry mode, on the worker thread): looked up on
        ``/tf_static``; the first scan waits for it until ``node.tf_timeout`` s after the subscription was made
        (during start-up: the model and the warm-up usually take longer, so a running robot_state_publisher's
        transform is there before the first scan and nothing waits), then the
        identity is used with one warning (and the lookup goes on: a transform that arrives later is used
        from then on, with one log line)."""
        import numpy as np

        base = self.cfg.node.base_frame
        if not base or base == frame:
            return np.eye(4)
        known = self._extrinsics.get(frame)
        if known is not None and known[1]:
            return known[0]
        if known is None:
            left = self._t_tf + self.cfg.node.tf_timeout - time.monotonic()
            T = self.static_tf.wait(base, frame, max(0.0, left))
        else:
            T = self.static_tf.lookup(base, frame)
        if T is not None:
            self._extrinsics[frame] = (T, True)
            t, log = T[:3, 3], self.get_logger().info
            log(f"{base} <- {frame} from /tf_static: translation [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] m; "
                f"publishing the {'pose' if self.localization is not None else 'motion'} of {base}"
                + (" from now on" if known is not None else ""))
            return T
        if known is None:
            self._extrinsics[frame] = (np.eye(4), False)
            self.get_logger().warning(
                f"no transform {base} <- {frame} on /tf_static within node.tf_timeout={self.cfg.node.tf_timeout} s: "
                f"publishing the sensor's {'pose' if self.localization is not None else 'motion'} as {base}'s "
                "(identity); publish it (robot_state_publisher) "
                "or set -p \"node.base_frame:=''\" to use the cloud frame"
            )
        return np.eye(4)

    def _on_message(self, index: int, msg: PointCloud2) -> None:
        t_recv = time.perf_counter()
        with self._lock:
            self._counts["received"] += 1
        inp = self.inputs[index]
        dropped = inp.dropped
        inp.submit(msg, t_recv)
        if inp.dropped > dropped and self.localization is not None:
            self._drops.dropped("before preprocessing: a newer scan arrived while the registration was busy",
                                _stamp_ns(msg), inp.topic)
        elif inp.dropped > dropped and self.get_logger().is_enabled_for(LoggingSeverity.DEBUG):
            self.get_logger().debug(f"{inp.topic}: the oldest waiting cloud dropped (scan at "
                                    f"{_stamp_ns(msg)} ns arrived, {inp.dropped} dropped so far)")

    def _on_bad(self, kind: str, message: str) -> None:
        with self._lock:
            self._counts["rejected"] += 1
        self._errors.log(kind, message)

    def _on_pair(self, items) -> None:
        (_, src), (_, tgt) = items
        with self._lock:
            self._counts["pairs"] += 1
            self._last_pair_t = time.monotonic()
        self.worker.submit(("pair", src, tgt))

    def _on_map_source(self, cloud: Cloud) -> None:
        """Latched target: every source is paired with the latest map (no stamp matching)."""
        map_cloud = self._map_target.map
        if map_cloud is None:
            self._warnings.log("no_target", f"{self.inputs[0].topic}: scan at {cloud.stamp_ns} ns dropped: no target "
                             f"(map) on {self.inputs[1].topic} yet (latched: transient_local, reliable)")
            return
        with self._lock:
            self._counts["pairs"] += 1
            self._last_pair_t = time.monotonic()
        self.worker.submit(("map", cloud, map_cloud))

    def _on_localization_map(self, index: int, cloud: Cloud) -> None:
        """Localization: a map on the latched topic; its places and descriptors are built here (the map input's
        thread), the next scan searches it."""
        from deepbbs_ros.node.localization import MapData

        try:
            line = self.localization.build(MapData(cloud.xyz, cloud.frame_id, self.inputs[index].topic))
        except NodeError as err:
            self._on_bad("bad_map", str(err))
            return
        self.get_logger().info(line)

    def _on_localize_source(self, cloud: Cloud) -> None:
        """Localization: every scan goes to the tracker (newest wins), once there is a map."""
        if not self.localization.has_map:
            topic = self.inputs[1].topic if len(self.inputs) > 1 else "the map topic"
            self._warnings.log("no_target", f"{self.inputs[0].topic}: scan at {cloud.stamp_ns} ns dropped: no map on "
                               f"{topic} yet (latched: transient_local, reliable), and localization.map_path is empty")
            return
        with self._lock:
            self._counts["pairs"] += 1
            self._last_pair_t = time.monotonic()
        self.localization.prepare(cloud)  # its GICP cloud on this input thread, on arrival (as the other modes)
        cloud.t_ready = time.perf_counter()
        slot = self.localization.last_arrival  # the scan a submit replaces (the worker keeps one), if it still waits
        self.localization.arrived(cloud)  # kept while a search runs: its pose is carried through them (bridge.py)
        if (self.worker.submit(("localize", cloud, None)) and not self.localization.keeps_arrivals
                and not self.localization.answered(slot)):  # one the bridge answered already is no loss
            self._drops.dropped("waiting for the registration: a newer scan replaced it (the registration of a scan "
                                "took longer than the scan period)", cloud.stamp_ns, self.inputs[0].topic)

    def _on_scan(self, cloud: Cloud) -> None:
        with self._lock:
            self._counts["pairs"] += 1
        self.worker.submit(("odometry", cloud, None))

    def _stream_deskew(self):
        """A per-topic velocity follower + deskew (``core.deskew.StreamDeskew``) where each scan is
        preprocessed on arrival by DeepBBS++ with its precision stage and ``node.pair_deskew`` is on; None
        elsewhere."""
        remote = hasattr(self.reg, "stream_deskew")  # the registration process: the topic's StreamDeskew runs there
        if not self._preprocess_on_arrival or not (remote or hasattr(self.reg, "deskew_scan")):
            return None
        if not (self.cfg.preprocess.deskew and self.cfg.node.pair_deskew) or self.cfg.registration.polish == "none":
            return None
        if remote:
            return self.reg.stream_deskew()
        from deepbbs_ros.core.deskew import StreamDeskew

        return StreamDeskew(self.reg)

    def _on_reset(self, request, response):
        self.sync.reset()
        for inp in self.inputs:
            inp.reset()
        if self.odometry is not None:
            with self._odom_lock:
                self.odometry.reset()
                self._last_odom_stamp = None
        if self._map_target is not None:
            self._map_target.reset()
        if self.localization is not None:
            self.localization.relocalize()
        self._pair_start.reset()
        response.success = True
        response.message = "odometry restarted at identity; synchroniser and frame memory cleared"
        self.get_logger().info(response.message)
        return response

    def _on_relocalize(self, request, response):
        """``~/relocalize``: forget the pose; the next scan searches the whole map."""
        self.localization.relocalize()
        response.success = True
        response.message = "pose forgotten: the next scan searches the whole map"
        self.get_logger().info(f"~/relocalize: {response.message}")
        return response

    def _on_thread_error(self, job, exc: BaseException) -> None:
        text = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        frames = traceback.extract_tb(exc.__traceback__)
        where = f" (in {Path(frames[-1].filename).name}:{frames[-1].lineno}, {frames[-1].name})" if frames else ""
        self._errors.log("internal_error", f"unexpected {text}{where}; the node continues")
        self.get_logger().debug("".join(traceback.format_exception(exc)))

    # -- registration worker ------------------------------------------------------------------------
    def _process(self, job: tuple[str, Cloud, Cloud | None]) -> None:
        mode, src, tgt = job
        t_start = time.perf_counter()
        t_in = src.t_recv if tgt is None else max(src.t_recv, tgt.t_recv)
        t_ready = src.t_ready if tgt is None else max(src.t_ready, tgt.t_ready)
        timings = {"queue_wait": (t_start - t_ready) * 1e3}
        found = None  # localization: a scan a search placed (the scans that came meanwhile follow it)
        try:
            if mode == "pair":
                T_start = self._pair_start.start(src, tgt)  # the last valid answer (None: the full pipeline)
                reg = register_clouds(self.reg, src, tgt, T_init=T_start, good_start=T_start is not None)
                self._pair_start.update(src, tgt, reg)
                t0 = time.perf_counter()
                if getattr(reg.result, "valid", True):
                    self.outputs.pair(src, tgt, reg)
                else:  # the verdict: a pose that cannot be trusted is not published (counted, logged rate-limited)
                    self._untrusted(reg.result)
            elif mode == "localize":
                if self.loc_odometry is not None:  # odom -> base of the node's own odometry first, then map -> odom
                    self.rep105.odometry_step(src, self.loc_odometry.step(src))
                loc = self.localization.step(src)
                if loc is None:  # answered already, while following a search's pose to the newest scan
                    return
                reg = loc.registered
                t0 = time.perf_counter()
                self._localized(src, loc)
                found = loc if loc.result.event in ("found", "relocalized") else None
            elif mode == "map":
                reg, tgt_points = self._map_target.register(self.reg, src)
                t0 = time.perf_counter()
                if getattr(reg.result, "valid", True):
                    self.outputs.localized(src, tgt.frame_id, reg, tgt_points)
                else:
                    self._untrusted(reg.result)
            else:
                with self._odom_lock:  # ~/reset runs on the executor thread
                    self._check_time_jump(src)
                    step = self.odometry.step(src)
                    self._last_odom_stamp = src.stamp_ns
                reg = step.registered
                t0 = time.perf_counter()
                self.outputs.odometry_step(src, step)
        except BadInput as bad:
            self._on_bad(bad.kind, str(bad))
            return
        t_end = time.perf_counter()
        with self._lock:
            self._counts["processed"] += 1
            if reg is not None:
                self._last_result = _result_summary(reg.result)
                path = getattr(reg.result, "path", "") if mode != "odometry" else ""
                if path in self._paths:
                    self._paths[path] += 1
        if reg is None:  # the odometry origin: nothing was registered
            if mode == "odometry" and self.get_logger().is_enabled_for(LoggingSeverity.DEBUG):
                self.get_logger().debug(f"odometry step {src.stamp_ns} ns: origin; ms: queue_wait "
                                        f"{timings['queue_wait']:.0f} total {(t_end - t_in) * 1e3:.0f}")
            return
        timings.update(reg.timings_ms)
        timings["publish"] = (t_end - t0) * 1e3
        timings["total"] = (t_end - t_in) * 1e3
        self._stages.add(timings)
        if mode == "localize" and found is not None:
            self._follow(src, found)
        if mode == "odometry" and self.get_logger().is_enabled_for(LoggingSeverity.DEBUG):
            self.get_logger().debug(_step_line(src, reg, timings))

    def _follow(self, src: Cloud, found: Any) -> None:
        """A search placed ``src``: the scans that arrived meanwhile are tracked and published (node/bridge.py), the
        node's own odometry stepped through them first; their time is the ``bridge`` stage."""
        t0 = time.perf_counter()
        for cloud, later in self.localization.bridge(found, src.stamp_ns):
            if self.loc_odometry is not None:
                self.rep105.odometry_step(cloud, self.loc_odometry.step(cloud))
            self._localized(cloud, later)
        if self.localization.last_bridge:
            self._stages.add({"bridge": (time.perf_counter() - t0) * 1e3})
            self.get_logger().info(self.localization.last_bridge)

    def _localized(self, src: Cloud, loc: Any) -> None:
        """Publish one localized scan (REP-105 outputs); a rejected one is counted (there and as not trusted), never
        published."""
        if loc.line:
            self.get_logger().info(loc.line)
        if loc.result.valid:
            self.rep105.localized(src, loc.frame_id, loc.registered, loc.result, loc.crop)
        else:
            with self._lock:
                self._counts["untrusted"] += 1

    def _check_time_jump(self, cloud: Cloud) -> None:
        """Odometry mode: a scan more than ``JUMP_BACK_S`` before the last one (a bag played again, ``deepbbs-play
        --loop``, simulated time rewound) restarts the odometry at identity, with one log line."""
        last = self._last_odom_stamp
        if last is not None and cloud.stamp_ns < last - int(JUMP_BACK_S * 1e9):
            self.odometry.reset()
            with self._lock:
                self._counts["time_jumps"] += 1
            self.get_logger().info(
                f"{self.inputs[0].topic}: time jumped back {(last - cloud.stamp_ns) * 1e-9:.2f} s "
                f"(stamp {cloud.stamp_ns} ns after {last} ns): odometry restarted at identity"
            )

    def _warmup(self) -> None:
        """Run what the first scans would run for the first time (PointCloud2 decoding, preprocessing, the
        precision stage's GICP, the network process, the odometry or pair path) on a synthetic drive, then
        forget it: the first real scans are answered at the node's usual speed."""
        from deepbbs_ros.node.inputs import decode_cloud
        from deepbbs_ros.replay.synthetic import synthetic_drive
        from msg_adapters.layouts import VELODYNE, build_cloud

        scans = synthetic_drive(3, motion_distortion=True, max_range=min(60.0, self.cfg.preprocess.max_range))
        clouds = []
        for s in scans:
            p = s.points
            msg = build_cloud(VELODYNE, {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2],
                                         "intensity": s.fields["intensity"], "time": s.fields["time"]},
                              stamp_ns=s.stamp_ns, frame_id="deepbbs_warmup")  # fmt: skip
            xyz, times, stamp_ns, frame = decode_cloud(msg, "warm-up", 3)
            clouds.append(Cloud(xyz, stamp_ns, frame, time.perf_counter(), times))
        if self.odometry is not None:
            with self._odom_lock:
                for c in clouds:
                    if self._preprocess_on_arrival:
                        c.pp = self.reg.preprocess(c.xyz, c.times, c.stamp_ns)
                    self.odometry.step(c)
                self.odometry.reset()
                if isinstance(self.odometry, LocalMapOdometry):
                    self.odometry.consulted = self.odometry.won = 0
        else:
            for c in clouds[:2]:
                c.pp = self.reg.preprocess(c.xyz, c.times, c.stamp_ns)
            first = register_clouds(self.reg, clouds[1], clouds[0])
            register_clouds(self.reg, clouds[1], clouds[0])  # the kept target state's path too
            register_clouds(self.reg, clouds[1], clouds[0], T_init=first.T, good_start=True)  # the good-start path

    def _check_unpaired(self) -> None:
        """Pair mode (stamped): an input that has received clouds without a pair for ``node.unpaired_warn_after``
        s is reported (log and /diagnostics), naming the topics and the stamp gap."""
        if self.cfg.node.mode != "pair" or self._map_target is not None or self.localization is not None:
            return
        now = time.monotonic()
        wait = self.cfg.node.unpaired_warn_after
        with self._lock:
            arrivals, last_pair = dict(self._arrivals), self._last_pair_t
        if not arrivals or now - last_pair < wait:
            return
        recent = {i: a for i, a in arrivals.items() if now - a[0] < wait}
        if not recent:
            return  # nothing arriving: not a pairing problem
        names = [inp.topic for inp in self.inputs]
        if len(arrivals) < len(self.inputs):
            missing = [names[i] for i in range(len(self.inputs)) if i not in arrivals]
            self._warnings.log("unpaired_input", f"no pair for {now - last_pair:.1f} s: {', '.join(missing)} has "
                             f"received nothing while {', '.join(names[i] for i in recent)} receives clouds")
            return
        if self._gap_seen != last_pair:
            # reported from the second check on: at the first one the partner may still be on its input's thread
            # (one input has scan k, the other still k - 1 while scan k's is decoded: a pair a moment later)
            self._gap_seen = last_pair
            return
        (_, s0), (_, s1) = arrivals[0], arrivals[1]
        gap = (s0 - s1) * 1e-9
        self._warnings.log(
            "unpaired_input",
            f"no pair for {now - last_pair:.1f} s: {names[0]} stamps are {gap:+.3f} s from {names[1]}'s "
            f"(latest), beyond node.slop={self.cfg.node.slop} s; synchronise the stamps, raise node.slop, or "
            "use node.target_mode:=latched for a static target (a map)",
        )

    def _untrusted(self, result: Any) -> None:
        with self._lock:
            self._counts["untrusted"] += 1
        self._errors.log("untrusted_pose", f"pose not published: the verdict's probability {result.probability:.2f} is "
                         f"below registration.verdict_probability {self.cfg.registration.verdict_probability} (the "
                         "scans do not overlap, or no start yaw registered them)")

    # -- diagnostics --------------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """Counters of the node, its inputs, the synchroniser and the worker (also on /diagnostics)."""
        with self._lock:
            out: dict[str, Any] = dict(self._counts)
            out.update(self._last_result)
            out["paths"] = dict(self._paths)
        out["published"] = self.outputs.published
        out["dropped"] = self.worker.dropped
        out["input_dropped"] = [inp.dropped for inp in self.inputs]
        out["preprocess_cache"] = {"hits": self._cache.hits, "misses": self._cache.misses}
        out["sync"] = dict(self.sync.stats)
        out["sync_queue"] = list(self.sync.queue_lengths())
        out["errors"] = dict(self._errors.counts)
        out["warnings"] = dict(self._warnings.counts)
        out["latency_ms"] = self._stages.summary()
        if isinstance(self.odometry, LocalMapOdometry):
            out["deepbbs_consulted"], out["deepbbs_won"] = self.odometry.consulted, self.odometry.won
            out["degenerate"], out["degenerate_frames"] = self.odometry.degenerate, self.odometry.degenerate_frames
        return out

    def _publish_diagnostics(self) -> None:
        self._check_unpaired()
        s = self.stats()
        values = {
            "mode": self.cfg.node.mode,
            "device": self._device,
            "weights": self._weights,
            "registration process": getattr(self.reg, "state", "off") if hasattr(self.reg, "stream_deskew") else "off",
            "network process": getattr(self.reg, "network_process_state", "-"),
            "messages received": s["received"],
            "pairs synchronised": s["pairs"],
            "pairs processed": s["processed"],
            "pairs dropped (newest wins)": s["dropped"],
            "clouds dropped before preprocessing (oldest first)": ",".join(map(str, s["input_dropped"])),
            "clouds or pairs rejected (bad input)": s["rejected"],
            "poses not published (the verdict rejected them)": s["untrusted"],
            "preprocessing cache hits / misses": "{hits} / {misses}".format(**s["preprocess_cache"]),
            "sync overflow / stale / late": "{overflow} / {stale} / {late}".format(**s["sync"]),
            "sync queue lengths": ",".join(map(str, s["sync_queue"])),
            "odometry restarts on time jumps": s["time_jumps"],
        }
        with self._lock:
            values.update({f"input.{topic}.driver": v for topic, v in sorted(self._drivers.items())})
        if self.cfg.node.mode == "pair":  # which path answered: GICP from the good start, the deep passes, the search
            for path, n in s["paths"].items():
                values[f"paths.{path}"] = n
        if "deepbbs_consulted" in s:
            values["odometry: DeepBBS++ consulted / won"] = f"{s['deepbbs_consulted']} / {s['deepbbs_won']}"
            values["degenerate"] = s["degenerate"] or "no"  # e.g. "corridor-like, weak axis x (ratio 2.1e-03)"
            values["odometry: scans in degenerate places"] = s["degenerate_frames"]
        if self.localization is not None:
            values.update({f"localization.{k}": v for k, v in self.localization.diagnostics().items()})
            drops = self._drops.diagnostics()  # the bridge's drops among them (localization.drop_sink)
            values.update({f"localization.{k}": v for k, v in drops.items()})
            values.update({f"localization.{k}": v for k, v in self.rep105.diagnostics().items()})
        for kind, n in sorted(s["errors"].items()):
            values[f"errors.{kind}"] = n
        for kind, n in sorted(s["warnings"].items()):
            values[f"warnings.{kind}"] = n
        for stage, st in sorted(s["latency_ms"].items()):
            values[f"latency_ms.{stage}"] = f"median {st['median']:.1f} p99 {st['p99']:.1f} max {st['max']:.1f}"
        for k in self._last_result:
            if k in s:
                values[f"last.{k}"] = f"{s[k]:.3f}"
        self.outputs.publish_diagnostics(
            f"{self.get_name()}: registration", self._device, values,
            sum(s["errors"].values()) + sum(s["warnings"].values()),
            self.get_clock().now().to_msg(),
            self._localization_warning() or (f"degenerate place: {s['degenerate']}; the motion model holds the weak "
                                             "direction" if s.get("degenerate") else ""),
        )  # fmt: skip

    def _localization_warning(self) -> str:
        if self.localization is None:
            return ""
        return self.localization.warning() or (self.rep105.problem if self.rep105 is not None else "")

    def _stop_threads(self) -> None:
        for inp in self.inputs:
            inp.stop()
        self.worker.stop()
        if getattr(self, "localization", None) is not None:
            self.localization.stop()

    def destroy_node(self):
        self._release()
        return super().destroy_node()

    def _release(self) -> None:
        """Stop the threads, log the counts, close the node's own registration (its processes)."""
        self._stop_threads()
        s = self.stats()
        line = (f"stopping: {s['received']} clouds received, {s['processed']} processed, {s['published']} poses "
                f"published; dropped before preprocessing {sum(s['input_dropped'])}, by the worker {s['dropped']}, "
                f"rejected {s['rejected']}, not trusted {s['untrusted']}")
        if "deepbbs_consulted" in s:
            line += f"; odometry: DeepBBS++ consulted {s['deepbbs_consulted']}, won {s['deepbbs_won']}"
        if self.localization is not None:
            d = self.localization.diagnostics()
            line += (f"; localization: {d['placed']} placed, {d['rejected']} rejected, {d['recoveries']} "
                     f"recoveries, state {d['state']}")
        self.get_logger().info(line)
        if self._owns_reg and hasattr(self.reg, "close"):
            self.reg.close()


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _step_line(cloud: Cloud, reg: Any, timings: dict[str, float]) -> str:
    """One odometry step for the debug log: the stamp, the path it took (GICP from the prediction, or DeepBBS++
    consulted and why), the fit and where its time went."""
    step = reg.result
    path = "gicp"
    if getattr(step, "deepbbs", False):
        path = f"deepbbs++ ({step.reason}; {'won' if step.won else 'not used'})"
    times = {**cloud.timings_ms, **timings}
    stages = " ".join(f"{k.removeprefix('register.')} {v:.0f}" for k, v in times.items())
    return f"odometry step {cloud.stamp_ns} ns: {path}, fit {getattr(step, 'fit', float('nan')):.2f}; ms: {stages}"


def _result_summary(result: Any) -> dict[str, float]:
    """The last result's figures for /diagnostics: the odometry's fit (an ``OdometryStep``), else the
    registration's inlier ratio and convergence."""
    if hasattr(result, "fit") and hasattr(result, "T_first_k"):
        return {"odometry_fit": float(result.fit), "odometry_deepbbs": float(bool(result.deepbbs))}
    return {
        "inlier_ratio": float(getattr(result, "inlier_ratio", float("nan"))),
        "converged": float(bool(getattr(result, "converged", False))),
        "verdict_score": float(getattr(result, "score", float("nan"))),
        "verdict_probability": float(getattr(result, "probability", float("nan"))),
    }


@cli_entry("deepbbs-node")
def main(argv: list[str] | None = None) -> int:
    """``deepbbs-node [--config YAML] [--ros-args ...]``: run until Ctrl-C."""
    return run_node(argv, "deepbbs-node", "Live DeepBBS++ registration node.", RegistrationNode)


if __name__ == "__main__":
    sys.exit(main())
