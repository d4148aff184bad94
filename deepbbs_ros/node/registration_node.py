"""The live registration node ``deepbbs_registration`` (console script ``deepbbs-node``).

Inputs (relative names: remap them the ROS way, ``-r source_cloud:=/lidar/points``):

* ``node.mode: pair`` (default): ``source_cloud`` and ``target_cloud`` (sensor_msgs/PointCloud2),
  paired by approximate time (``node.queue_size`` per input, ``node.slop`` seconds).
* ``node.mode: odometry``: one input ``cloud``; the scans run through the odometry of ``deepbbs-replay
  --mode odometry --method deepbbs++`` (:class:`deepbbs_ros.core.odometry.DeepBBSOdometry`, the
  ``odometry`` config section): deskewing with the per-point times (Velodyne ``time``, Ouster ``t``),
  GICP against a local voxel map, and DeepBBS++ (the node's network) consulted on stamp gaps, fit drops
  and the first motion (:class:`deepbbs_ros.node.pipeline.LocalMapOdometry`). The chained scan-to-scan
  odometry (scan k registered against scan k-1) stays available as ``odometry_method="scan_to_scan"``
  of :class:`RegistrationNode` (the GICP anchor uses it).

Outputs (docs/CONVENTIONS.md, :mod:`deepbbs_ros.node.outputs`):

* ``~/pose`` (geometry_msgs/PoseStamped). Pair mode: ``T_target_source``, ``frame_id`` = target cloud
  frame, stamp = source stamp. Odometry mode: the pose ``T_odom_k`` of scan k (the odom frame is the
  first scan's sensor frame at its stamp: identity at the first scan), ``frame_id`` = ``node.odom_frame``.
* ``~/transform`` (geometry_msgs/TransformStamped): the same transform, ``child_frame_id`` = the source
  frame (pair mode) or ``node.base_frame`` / the cloud frame (odometry mode).
* opt-in: ``~/odometry`` (nav_msgs/Odometry: twist from the motion since the previous scan over the stamp
  gap, covariances from the registration residuals of that motion, :mod:`deepbbs_ros.node.covariance`,
  accumulated along the trajectory in odometry mode), ``/tf`` (``node.publish_tf``; needs
  tf2_msgs; odometry mode broadcasts ``odom_frame -> base_frame``), ``~/aligned_cloud`` (pair mode: the
  source cloud moved into the target frame; odometry mode: the scan moved into ``node.odom_frame``).
* ``/diagnostics``: latency per stage, clouds / pairs received, processed, dropped, errors per kind,
  model, device. ``~/reset`` (std_srvs/Trigger): restart odometry at identity and clear the synchroniser.

Threads: the executor's callbacks only hand messages on. Each input has its own thread that decodes and
checks every cloud on arrival and preprocesses it for DeepBBS++ (pair mode, scan-to-scan odometry; the
local-map odometry works on the raw points and preprocesses only the scans it consults DeepBBS++ on)
(:mod:`deepbbs_ros.node.inputs`; at most one message waits per input, older ones are dropped and
counted), so a pair's latency is mostly its registration. Registration / odometry runs on one worker
thread behind a "latest" slot (:mod:`deepbbs_ros.node.worker`, :mod:`deepbbs_ros.node.pipeline`): the
newest pair or scan wins, stale ones are dropped and counted. Bad input
(malformed PointCloud2, empty, too few points, NaN-only, missing or changed frames) is logged once per
kind and period (``node.error_log_period``), nothing is published for it, and the node goes on.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

from deepbbs_ros.config import Config
from deepbbs_ros.entry import cli_entry
from deepbbs_ros.errors import ConfigError, DeepBBSError, NodeError
from deepbbs_ros.node.dds import apply_default_profile
from deepbbs_ros.node.diagnostics import RateLimitedErrors, StageTimes
from deepbbs_ros.node.inputs import BadInput, Cloud, CloudInput, PreprocessCache
from deepbbs_ros.node.outputs import Outputs, TfBroadcaster
from deepbbs_ros.node.pipeline import LocalMapOdometry, ScanToScanOdometry, register_clouds
from deepbbs_ros.node.sync import ApproximateTimeSync
from deepbbs_ros.node.worker import LatestSlotWorker

NODE_NAME = "deepbbs_registration"
ODOMETRY_METHODS = ("local_map", "scan_to_scan")
PAIR_INPUTS = ("source_cloud", "target_cloud")
ODOM_INPUT = "cloud"


#: the config sections the node reads (declared as ROS parameters); ``odometry`` too in odometry mode. ``model``
#: comes from the checkpoint, ``train`` / ``eval`` belong to deepbbs-train / deepbbs-replay.
NODE_SECTIONS = ("preprocess", "registration", "node")
_NOT_NODE = {
    "model": "the model section comes from the checkpoint (registration.weights)",
    "train": "a deepbbs-train setting",
    "eval": "a deepbbs-replay setting",
    "odometry": "used in node.mode odometry only",
}


def node_parameters(cfg: Config, mode: str) -> dict[str, Any]:
    """The parameters the node declares (dotted name -> value of ``cfg``) for ``mode``: every key of
    :data:`NODE_SECTIONS`, plus ``odometry.*`` in odometry mode. New keys of these sections are picked up."""
    sections = NODE_SECTIONS + (("odometry",) if mode == "odometry" else ())
    return {k: v for k, v in cfg.to_flat().items() if k.partition(".")[0] in sections}


def nearest_parameter(name: str, known: Any) -> list[str]:
    """The known dotted names closest to ``name``: those whose last part equals its last part (flat,
    KISS-ICP-style names such as ``mode`` or ``base_frame``), else the closest spellings."""
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


def check_parameter_names(names: Any, used: dict[str, Any], flat: dict[str, Any],
                          mode: str) -> tuple[list[str], list[str], list[str]]:
    """(errors, warnings, notes) for parameter names given to the node that it does not declare.

    A name in a declared section that is not a config key (``node.mod``) is an error; a config key of a
    section the node does not use (``train.lr``) and any other unknown name (flat names such as ``mode``)
    are warnings naming the nearest declared parameter; ``odometry.*`` in pair mode (a params file for
    both modes) is one note. Flat names are not taken as aliases: ``voxel_size`` could be
    ``preprocess.voxel_size`` or ``odometry.voxel_size``."""
    sections = {k.partition(".")[0] for k in used}
    errors, warnings, other_mode = [], [], []
    for name in sorted(names):
        if name in used:
            continue
        section = name.partition(".")[0]
        near = nearest_parameter(name, used)
        hint = f"; did you mean {' or '.join(near)}?" if near else ""
        if name in flat and section == "odometry":  # a params file for both modes: one line for them all
            other_mode.append(name)
        elif name in flat:
            why = _NOT_NODE.get(section, "not a node parameter")
            warnings.append(f"parameter {name} is ignored: {why}")
        elif "." in name and section in sections:
            errors.append(f"unknown parameter {name}{hint}")
        else:
            warnings.append(f"unknown parameter {name} is ignored (the node's parameters are dotted, "
                            f"e.g. node.mode){hint}")
    notes = []
    if other_mode:
        notes.append(f"{len(other_mode)} odometry.* parameter(s) not used: {_NOT_NODE['odometry']} (node.mode={mode})")
    return errors, warnings, notes


def _qos_text(qos: QoSProfile) -> str:
    """``reliable/5`` or ``best_effort/5`` (reliability / history depth)."""
    rel = "reliable" if qos.reliability == ReliabilityPolicy.RELIABLE else "best_effort"
    return f"{rel}/{qos.depth}"


def _validate_frame(key: str, frame: str) -> None:
    if frame and (frame.startswith("/") or any(c.isspace() for c in frame)):
        raise NodeError(f"{key}: invalid frame id {frame!r} (no leading '/', no spaces)")


def check_weights(cfg: Config) -> Path:
    """The checkpoint the node will load; NodeError naming the path when it does not exist."""
    if cfg.registration.weights:
        path = Path(cfg.registration.weights).expanduser()
        if not path.is_file():
            raise NodeError(f"registration.weights: file not found: {path}")
        return path
    from deepbbs_ros.core.checkpoint import default_weights_path

    path = Path(default_weights_path())
    if not path.is_file():
        raise NodeError(
            f"registration.weights is '' (the shipped model) but {path} does not exist; "
            "train one with deepbbs-train or set registration.weights"
        )
    return path


def load_registration(cfg: Config) -> tuple[Any, str]:
    """(DeepBBSRegistration, weights path) for the node; NodeError naming the parameter on a bad
    device or a missing checkpoint."""
    from deepbbs_ros.device import resolve_device

    try:
        resolve_device(cfg.registration.device)
    except ConfigError as err:
        raise NodeError(str(err)) from err
    weights = str(check_weights(cfg))
    from deepbbs_ros.core.registration import DeepBBSRegistration

    reg = DeepBBSRegistration(cfg, weights=weights)
    reg.warmup()  # the first registrations set up torch's kernels (seconds): before the first scan, not on it
    return reg, weights


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
        **node_kwargs: Any,
    ) -> None:
        super().__init__(node_name, **node_kwargs)
        self.cfg = self._declare_config(config or Config())
        ncfg = self.cfg.node
        _validate_frame("node.odom_frame", ncfg.odom_frame)
        _validate_frame("node.base_frame", ncfg.base_frame)
        if not ncfg.odom_frame:
            raise NodeError("node.odom_frame: must not be empty")
        if odometry_method not in ODOMETRY_METHODS:
            raise NodeError(f"odometry_method must be one of {', '.join(ODOMETRY_METHODS)}, got {odometry_method!r}")
        self.odometry_method = odometry_method
        self._errors = RateLimitedErrors(lambda text: self.get_logger().error(text), ncfg.error_log_period)
        self._stages = StageTimes()
        self._lock = threading.Lock()
        self._odom_lock = threading.Lock()  # the odometry state: worker thread vs ~/reset
        self._counts = {"received": 0, "pairs": 0, "processed": 0, "rejected": 0, "untrusted": 0}
        self._last_result: dict[str, float] = {}

        # the model: device and weights checked first, with errors naming the parameter
        self._owns_reg = registration is None  # closed with the node (its network process)
        if registration is None:
            registration, self._weights = load_registration(self.cfg)
        else:
            self._weights = str(getattr(registration, "weights", "") or "<injected model>")
        self.reg = registration
        self._device = str(getattr(registration, "device", "cpu"))
        if ncfg.publish_odometry:  # warm the imports the first odometry message needs
            import scipy.spatial  # noqa: F401
            import scipy.spatial.transform  # noqa: F401

        # pipeline: synchroniser (pair mode), odometry (odometry mode), the registration worker
        self.sync = ApproximateTimeSync(2, ncfg.queue_size, ncfg.slop, self._on_pair)
        self.odometry = self._make_odometry()
        self.worker = LatestSlotWorker(self._process, self._on_thread_error, name="deepbbs-registration")
        self._cache = PreprocessCache(self.reg.preprocess)
        # preprocessing on arrival only where every scan is registered by the network
        self._preprocess_on_arrival = not isinstance(self.odometry, LocalMapOdometry)

        # topics: a bad (remapped) name becomes NodeError, after stopping the threads started so far
        self.inputs: list[CloudInput] = []
        try:
            self.outputs = Outputs(self, ncfg, self._qos(), self._errors.log, tf_broadcaster)
            names = PAIR_INPUTS if ncfg.mode == "pair" else (ODOM_INPUT,)
            # one QoS object per subscription: rclpy applies qos_overrides.<topic>.* to it in place
            self._subs = [self._make_input(i, name, self._qos()) for i, name in enumerate(names)]
        except NodeError:
            self._stop_threads()
            raise
        except Exception as err:  # rclpy raises several types for bad (remapped) names
            self._stop_threads()
            raise NodeError(f"cannot create topics: {err}".replace("\n", " ")) from err
        self.srv_reset = self.create_service(Trigger, "~/reset", self._on_reset)
        # diagnostics on the steady (wall) clock: with use_sim_time a ROS-time timer stops with /clock (a bag
        # that ended would leave the counters frozen); the messages still carry the node's time
        self._diag_timer = self.create_timer(ncfg.diagnostics_period, self._publish_diagnostics,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        #: the QoS each input really got, after ``qos_overrides.<topic>.subscription.*``: topic -> "reliable/5"
        self.input_qos = {inp.topic: _qos_text(sub.qos_profile) for inp, sub in zip(self.inputs, self._subs)}
        qos_text = ", ".join(f"{t}: {q}" for t, q in self.input_qos.items())
        self.get_logger().info(
            f"mode={ncfg.mode} inputs=[{', '.join(i.topic for i in self.inputs)}] device={self._device} "
            f"weights={self._weights} qos=[{qos_text}] slop={ncfg.slop}s "
            f"queue={ncfg.queue_size}" + (f" odometry={self.odometry_method}" if self.odometry else "")
        )

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
        used = node_parameters(defaults, mode)
        ignore = [n for n in overrides if n not in used and (self.has_parameter(n) or n.startswith("qos_overrides."))]
        errors, warnings, notes = check_parameter_names([n for n in overrides if n not in ignore], used, flat, mode)
        if errors:
            raise NodeError("; ".join(errors))
        for text in warnings:
            self.get_logger().warning(text)
        for text in notes:
            self.get_logger().info(text)
        self.parameter_warnings = warnings
        for key, value in used.items():
            self.declare_parameter(key, value, ParameterDescriptor(name=key, dynamic_typing=True))
        values = {k: self.get_parameter(k).value for k in used}
        try:
            return Config.from_flat({**flat, **values})
        except ConfigError as err:
            raise NodeError(str(err)) from err

    def _on_set_parameters(self, params) -> SetParametersResult:
        ours = [p.name for p in params if p.name in node_parameters(self.cfg, self.cfg.node.mode)]
        if ours:
            return SetParametersResult(successful=False, reason=f"restart the node to change {', '.join(ours)}")
        return SetParametersResult(successful=True)

    # -- inputs (executor thread, then one thread per input) -----------------------------------------
    def _make_input(self, index: int, name: str, qos: QoSProfile):
        pair = self.cfg.node.mode == "pair"

        def on_cloud(cloud: Cloud) -> None:  # on the input's thread, once the cloud is preprocessed
            self._stages.add(cloud.timings_ms)
            if pair:
                self.sync.add(index, cloud.stamp_ns, cloud)
            else:
                self._on_scan(cloud)

        sub = self.create_subscription(
            PointCloud2, name, lambda msg: self._on_message(index, msg), qos,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )  # fmt: skip
        self.inputs.append(
            CloudInput(
                self.resolve_topic_name(name), self._cache if self._preprocess_on_arrival else None,
                self.cfg.node.min_points, on_cloud, self._on_bad, self._on_thread_error,
                increasing_stamps=not pair, gate=self.worker.room, deskew=self._stream_deskew(),
            )
        )  # fmt: skip
        return sub

    def _on_message(self, index: int, msg: PointCloud2) -> None:
        t_recv = time.perf_counter()
        with self._lock:
            self._counts["received"] += 1
        self.inputs[index].submit(msg, t_recv)

    def _on_bad(self, kind: str, message: str) -> None:
        with self._lock:
            self._counts["rejected"] += 1
        self._errors.log(kind, message)

    def _on_pair(self, items) -> None:
        (_, src), (_, tgt) = items
        with self._lock:
            self._counts["pairs"] += 1
        self.worker.submit(("pair", src, tgt))

    def _on_scan(self, cloud: Cloud) -> None:
        with self._lock:
            self._counts["pairs"] += 1
        self.worker.submit(("odometry", cloud, None))

    def _stream_deskew(self):
        """A per-topic velocity follower + deskew (``core.deskew.StreamDeskew``) where each scan is
        preprocessed on arrival by DeepBBS++ with its precision stage and ``node.pair_deskew`` is on; None
        elsewhere."""
        if not self._preprocess_on_arrival or not hasattr(self.reg, "deskew_scan"):
            return None
        if not (self.cfg.preprocess.deskew and self.cfg.node.pair_deskew) or self.cfg.registration.polish == "none":
            return None
        from deepbbs_ros.core.deskew import StreamDeskew

        return StreamDeskew(self.reg)

    def _on_reset(self, request, response):
        self.sync.reset()
        for inp in self.inputs:
            inp.reset()
        if self.odometry is not None:
            with self._odom_lock:
                self.odometry.reset()
        response.success = True
        response.message = "odometry restarted at identity; synchroniser and frame memory cleared"
        self.get_logger().info(response.message)
        return response

    def _on_thread_error(self, job, exc: BaseException) -> None:
        text = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        self._errors.log("internal_error", f"unexpected {text}; the node continues")
        self.get_logger().debug("".join(traceback.format_exception(exc)))

    # -- registration worker ------------------------------------------------------------------------
    def _process(self, job: tuple[str, Cloud, Cloud | None]) -> None:
        mode, src, tgt = job
        t_start = time.perf_counter()
        t_in = src.t_recv if tgt is None else max(src.t_recv, tgt.t_recv)
        t_ready = src.t_ready if tgt is None else max(src.t_ready, tgt.t_ready)
        timings = {"queue_wait": (t_start - t_ready) * 1e3}
        try:
            if mode == "pair":
                reg = register_clouds(self.reg, src, tgt)
                t0 = time.perf_counter()
                if getattr(reg.result, "valid", True):
                    self.outputs.pair(src, tgt, reg)
                else:  # the verdict: a pose that cannot be trusted is not published (counted, logged rate-limited)
                    self._untrusted(reg.result)
            else:
                with self._odom_lock:  # ~/reset runs on the executor thread
                    step = self.odometry.step(src)
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
        if reg is None:  # the odometry origin: nothing was registered
            return
        timings.update(reg.timings_ms)
        timings["publish"] = (t_end - t0) * 1e3
        timings["total"] = (t_end - t_in) * 1e3
        self._stages.add(timings)

    def _untrusted(self, result: Any) -> None:
        with self._lock:
            self._counts["untrusted"] += 1
        self._errors.log("untrusted_pose", f"pose not published: the verdict's score {result.score:.2f} is below "
                         f"registration.verdict_threshold {self.cfg.registration.verdict_threshold} (the scans do not "
                         "overlap, or no start yaw registered them)")

    # -- diagnostics --------------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """Counters of the node, its inputs, the synchroniser and the worker (also on /diagnostics)."""
        with self._lock:
            out: dict[str, Any] = dict(self._counts)
            out.update(self._last_result)
        out["published"] = self.outputs.published
        out["dropped"] = self.worker.dropped
        out["input_dropped"] = [inp.dropped for inp in self.inputs]
        out["preprocess_cache"] = {"hits": self._cache.hits, "misses": self._cache.misses}
        out["sync"] = dict(self.sync.stats)
        out["sync_queue"] = list(self.sync.queue_lengths())
        out["errors"] = dict(self._errors.counts)
        out["latency_ms"] = self._stages.summary()
        if isinstance(self.odometry, LocalMapOdometry):
            out["deepbbs_consulted"], out["deepbbs_won"] = self.odometry.consulted, self.odometry.won
        return out

    def _publish_diagnostics(self) -> None:
        s = self.stats()
        values = {
            "mode": self.cfg.node.mode,
            "device": self._device,
            "weights": self._weights,
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
        }
        if "deepbbs_consulted" in s:
            values["odometry: DeepBBS++ consulted / won"] = f"{s['deepbbs_consulted']} / {s['deepbbs_won']}"
        for kind, n in sorted(s["errors"].items()):
            values[f"errors.{kind}"] = n
        for stage, st in sorted(s["latency_ms"].items()):
            values[f"latency_ms.{stage}"] = f"median {st['median']:.1f} p99 {st['p99']:.1f} max {st['max']:.1f}"
        for k in self._last_result:
            if k in s:
                values[f"last.{k}"] = f"{s[k]:.3f}"
        self.outputs.publish_diagnostics(
            f"{self.get_name()}: registration", self._device, values, sum(s["errors"].values()),
            self.get_clock().now().to_msg(),
        )  # fmt: skip

    def _stop_threads(self) -> None:
        for inp in self.inputs:
            inp.stop()
        self.worker.stop()

    def destroy_node(self):
        self._stop_threads()
        if self._owns_reg and hasattr(self.reg, "close"):
            self.reg.close()
        return super().destroy_node()


def _result_summary(result: Any) -> dict[str, float]:
    """The last result's figures for /diagnostics: the odometry's fit (an ``OdometryStep``), else the
    registration's inlier ratio and convergence."""
    if hasattr(result, "fit") and hasattr(result, "T_first_k"):
        return {"odometry_fit": float(result.fit), "odometry_deepbbs": float(bool(result.deepbbs))}
    return {
        "inlier_ratio": float(getattr(result, "inlier_ratio", float("nan"))),
        "converged": float(bool(getattr(result, "converged", False))),
        "verdict_score": float(getattr(result, "score", float("nan"))),
    }


def _parser(prog: str, description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog,
        description=f"{description} ROS arguments go after --ros-args (remaps, -p name:=value, --params-file FILE).",
    )
    g = p.add_argument_group("configuration")
    g.add_argument("--config", metavar="YAML", help="config file (plain sections or a ROS parameter file); "
                   "ROS parameters given with --ros-args override it")
    g = p.add_argument_group("transport")
    g.add_argument("--no-shm-profile", action="store_true",
                   help="do not apply the shipped Fast DDS shared-memory profile (resources/fastdds_shm.xml)")
    return p


def run_node(
    argv: list[str] | None,
    prog: str,
    description: str,
    make_node: Callable[[Config], Node],
) -> int:
    """Parse ``[--config YAML] [--ros-args ...]``, build the node with ``make_node(config)`` and spin it
    until Ctrl-C / SIGTERM (the ROS 2 demos' skeleton). Shared by ``deepbbs-node`` and the GICP anchor."""
    full = list(sys.argv) if argv is None else [prog, *argv]
    args = _parser(prog, description).parse_args(_strip_ros_args(full)[1:])
    defaults = Config.from_yaml(args.config) if args.config else Config()
    if not args.no_shm_profile:
        apply_default_profile()
    try:
        rclpy.init(args=full)
    except Exception as err:  # rclpy's RCLError: bad --ros-args (remap rules, parameter syntax)
        first = str(err).split(", at ")[0].replace("failed to initialize rcl: ", "")
        raise NodeError(f"invalid ROS arguments: {first}") from err
    node = None
    try:
        node = make_node(defaults)
        executor = MultiThreadedExecutor(num_threads=2)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except DeepBBSError:
        raise
    except Exception:
        # SIGINT/SIGTERM make rclpy's signal handler shut the context down; if that lands while the
        # executor is building its wait set, rclpy raises RCLError ("context is not valid") instead
        # of ExternalShutdownException. That is a clean shutdown, anything else is a real error.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


@cli_entry("deepbbs-node")
def main(argv: list[str] | None = None) -> int:
    """``deepbbs-node [--config YAML] [--ros-args ...]``: run until Ctrl-C."""
    return run_node(argv, "deepbbs-node", "Live DeepBBS++ registration node.", RegistrationNode)


def _strip_ros_args(argv: list[str]) -> list[str]:
    """argv without the ``--ros-args ... [--]`` sections (rclpy's remove_ros_args, without a context)."""
    out, in_ros = [], False
    for a in argv:
        if a == "--ros-args":
            in_ros = True
        elif in_ros and a == "--":
            in_ros = False
        elif not in_ros:
            out.append(a)
    return out


if __name__ == "__main__":
    sys.exit(main())
