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
kind and period (``node.error_log_period``), nothing is published for it, and the node goes on. No callback ends the
executor (:mod:`deepbbs_ros.node.callbacks`): one that raises (a bug, or input nothing else checks) is one error line
naming it, counted on /diagnostics as ``errors.callback <name>``; a failed service answers ``success: false``.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_srvs.srv import Trigger

from deepbbs_ros.config import Config
from deepbbs_ros.entry import cli_entry
from deepbbs_ros.errors import NodeError
from deepbbs_ros.node.callbacks import GuardedCallbacks
from deepbbs_ros.node.inputs import CloudInput
from deepbbs_ros.node.localization import NodeLocalization
from deepbbs_ros.node.map_data import load_map_file
from deepbbs_ros.node.node_diagnostics import NodeDiagnostics, stop_line
from deepbbs_ros.node.node_inputs import InputHandlers
from deepbbs_ros.node.node_jobs import JUMP_BACK_S, RegistrationJobs, _result_summary, _step_line  # noqa: F401
from deepbbs_ros.node.node_parameters import NodeParameters, check_frames
from deepbbs_ros.node.node_services import NodeServices
from deepbbs_ros.node.node_tf import NodeTf
from deepbbs_ros.node.outputs import Outputs, TfBroadcaster
from deepbbs_ros.node.parameters import (
    load_registration,
)
from deepbbs_ros.node.pipeline import LocalMapOdometry, MapTarget, PairStart, ScanToScanOdometry, takes_good_start
from deepbbs_ros.node.preprocess_cache import PreprocessCache, arrival_preprocess
from deepbbs_ros.node.qos import input_qos, qos_text
from deepbbs_ros.node.rep105 import Rep105
from deepbbs_ros.node.run import run_node
from deepbbs_ros.node.sync import ApproximateTimeSync
from deepbbs_ros.node.tf_buffer import TransformBuffer
from deepbbs_ros.node.warmup import warm_up
from deepbbs_ros.node.worker import LatestSlotWorker

NODE_NAME = "deepbbs_registration"
ODOMETRY_METHODS = ("local_map", "scan_to_scan")


class RegistrationNode(NodeParameters, InputHandlers, RegistrationJobs, NodeDiagnostics, NodeTf, NodeServices,
                       GuardedCallbacks, Node):
    """See the module docstring. The node composes its parts: the parameters
    (:mod:`~deepbbs_ros.node.node_parameters`), the inputs (:mod:`~deepbbs_ros.node.node_inputs`), the
    worker's jobs (:mod:`~deepbbs_ros.node.node_jobs`), the counters and /diagnostics
    (:mod:`~deepbbs_ros.node.node_diagnostics`), TF (:mod:`~deepbbs_ros.node.node_tf`), the services
    (:mod:`~deepbbs_ros.node.node_services`), every callback guarded (:mod:`~deepbbs_ros.node.callbacks`); here: its
    construction, one phase per lifecycle step, and its end.

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
        check_frames(ncfg)
        if odometry_method not in ODOMETRY_METHODS:
            raise NodeError(f"odometry_method must be one of {', '.join(ODOMETRY_METHODS)}, got {odometry_method!r}")
        self.odometry_method = odometry_method
        localization = ncfg.mode == "pair" and ncfg.target_mode == "localization"
        map_file = None
        if localization and self.cfg.localization.map_path:  # read (and refused) before the model loads
            map_file = load_map_file(self.cfg.localization.map_path, ncfg.map_frame)
        self._choose_inputs(remaps, map_file is not None)
        self._init_counters(ncfg.error_log_period)
        self._odom_lock = threading.Lock()  # the odometry state: worker thread vs ~/reset
        self._last_odom_stamp: int | None = None  # odometry mode: a stamp far before it is a time jump (reset)
        self._map_target = MapTarget(self.cfg) if ncfg.mode == "pair" and ncfg.target_mode == "latched" else None
        self._pair_start = PairStart(ncfg.good_start_max_gap, False)  # stamped pairs: the last valid answer (below)

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
            self.outputs = Outputs(self, ncfg, input_qos(ncfg), self._errors.log, tf_broadcaster,
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
            self._subscribe_inputs = [self._make_input(i, name, input_qos(ncfg))
                                      for i, name in enumerate(self.input_names)]
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
        """The warm-up (:func:`~deepbbs_ros.node.warmup.warm_up`) where ``node.warmup`` asks for it and the model is the
        node's own."""
        self.warmed_up = False
        if self.cfg.node.warmup and self._owns_reg:  # an injected registration (tests, the GICP anchor) is the caller's
            try:
                warm_up(self.cfg.preprocess.max_range, self.reg, self.odometry, self._odom_lock,
                        self._preprocess_on_arrival)
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
        self.input_qos = {inp.topic: qos_text(sub.qos_profile) for inp, sub in zip(self.inputs, self._subs)}
        qos_line = ", ".join(f"{t}: {q}" for t, q in self.input_qos.items())
        self.get_logger().info(
            f"mode={ncfg.mode} inputs=[{', '.join(i.topic for i in self.inputs)}] device={self._device} "
            f"weights={self._weights} qos=[{qos_line}] slop={ncfg.slop}s "
            f"queue={ncfg.queue_size}" + (f" odometry={self.odometry_method}" if self.odometry else "")
            + (f" target=latched ({self.inputs[1].topic})" if self._map_target is not None else "")
            + (f" target=localization (map {map_file.source if map_file else self.inputs[1].topic})"
               if self.localization is not None else "")
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

    # -- the end: threads stopped, counts logged, the node's own model closed ------------------------------------
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
        self.get_logger().info(stop_line(self.stats(), self.localization))
        if self._owns_reg and hasattr(self.reg, "close"):
            self.reg.close()


@cli_entry("deepbbs-node")
def main(argv: list[str] | None = None) -> int:
    """``deepbbs-node [--config YAML] [--ros-args ...]``: run until Ctrl-C."""
    return run_node(argv, "deepbbs-node", "Live DeepBBS++ registration node.", RegistrationNode)


if __name__ == "__main__":
    sys.exit(main())
