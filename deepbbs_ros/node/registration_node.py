"""The live registration node ``deepbbs_registration`` (console scripts ``deepbbs-node``, ``registration_node``).

Inputs (relative names: remap them the ROS way, ``-r source_cloud:=/lidar/points``):

* ``node.mode: pair`` (default): ``source_cloud`` and ``target_cloud`` (sensor_msgs/PointCloud2),
  paired by approximate time (``node.queue_size`` per input, ``node.slop`` seconds).
* ``node.mode: odometry``: one input ``cloud``; each scan is registered against the previous one.

Outputs (CONVENTIONS.md):

* ``~/pose`` (geometry_msgs/PoseStamped). Pair mode: ``T_target_source``, ``frame_id`` = target cloud
  frame, stamp = source stamp. Odometry mode: the accumulated pose ``T_odom_k``
  (``T_odom_k = T_odom_{k-1} @ T_{k-1}_k``, identity at the first scan), ``frame_id`` = ``node.odom_frame``.
* ``~/transform`` (geometry_msgs/TransformStamped): the same transform, ``child_frame_id`` = the source
  frame (pair mode) or ``node.base_frame`` / the cloud frame (odometry mode).
* opt-in: ``~/odometry`` (nav_msgs/Odometry: twist from the motion over dt, covariance from the
  registration residuals, :mod:`deepbbs_ros.node.covariance`), ``/tf`` (``node.publish_tf``; needs
  tf2_msgs), ``~/aligned_cloud`` (the source cloud moved into the target frame).
* ``/diagnostics``: latency per stage, pairs received / processed / dropped, errors per kind, model,
  device. ``~/reset`` (std_srvs/Trigger): restart odometry at identity and clear the synchroniser.

Registration runs on one worker thread behind a "latest" slot (:mod:`deepbbs_ros.node.worker`): the
newest pair wins, stale pairs are dropped and counted. Bad input (malformed PointCloud2, empty,
too few points, NaN-only, missing or changed frames) is logged once per kind and period
(``node.error_log_period``), nothing is published for it, and the node goes on with the next pair.
"""

from __future__ import annotations

import argparse
import functools
import sys
import threading
import time
import traceback
import zlib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.cli.common import cli_entry
from deepbbs_ros.config import Config
from deepbbs_ros.errors import ConfigError, DeepBBSError, NodeError, PointCloudFormatError, RegistrationError
from deepbbs_ros.node.dds import apply_default_profile

NODE_NAME = "deepbbs_registration"
PAIR_INPUTS = ("source_cloud", "target_cloud")
ODOM_INPUT = "cloud"
_PP_CACHE = 4  # preprocessed clouds kept, keyed by (frame, stamp): a target reused as source is free


@dataclass
class _Cloud:
    """A decoded input cloud."""

    xyz: np.ndarray  # (N, 3) float32 valid points, sensor frame
    stamp_ns: int
    frame_id: str
    t_recv: float  # time.perf_counter() when the message reached the node


class _BadInput(Exception):
    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def _lazy_ros():
    """ROS imports, deferred so that ``--help`` and config errors stay fast."""
    import rclpy  # noqa: F401
    from rclpy.node import Node

    return Node


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


@functools.lru_cache(maxsize=1)
def make_node_class():
    """Build the rclpy Node subclass (deferred so that importing this module needs no rclpy)."""
    Node = _lazy_ros()

    class RegistrationNode(Node):
        """See the module docstring. ``registration=`` injects a ready DeepBBSRegistration (tests)."""

        def __init__(
            self,
            config: Config | None = None,
            *,
            registration: Any = None,
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
            self._errors = _errors_for(self, ncfg.error_log_period)
            self._stages = _stage_times()
            self._lock = threading.Lock()
            self._pp_cache: OrderedDict[tuple, Any] = OrderedDict()
            self._frames: dict[str, str] = {}
            self._odom_prev: _Cloud | None = None
            self._odom_prev_pp: Any = None
            self._T_odom: np.ndarray = np.eye(4)
            self._cov_odom: np.ndarray = np.zeros((6, 6))
            self._counts = {"received": 0, "pairs": 0, "processed": 0, "published": 0, "rejected": 0}
            self._last_result: dict[str, float] = {}

            # the model: device and weights checked first, with errors naming the parameter
            if registration is None:
                from deepbbs_ros.device import resolve_device

                try:
                    resolve_device(self.cfg.registration.device)
                except ConfigError as err:
                    raise NodeError(str(err)) from err
                self._weights = str(check_weights(self.cfg))
                from deepbbs_ros.core.registration import DeepBBSRegistration

                registration = DeepBBSRegistration(self.cfg, weights=self._weights)
            else:
                self._weights = str(getattr(registration, "weights", "") or "<injected model>")
            self.reg = registration
            self._device = str(getattr(registration, "device", "cpu"))

            self._make_io()
            if ncfg.publish_odometry:  # warm the imports the first odometry message needs
                import scipy.spatial  # noqa: F401
                import scipy.spatial.transform  # noqa: F401

                from msg_adapters.transforms import matrix_to_odometry

                matrix_to_odometry(np.eye(4), 0, "a", "b")
            from deepbbs_ros.node.sync import ApproximateTimeSync
            from deepbbs_ros.node.worker import LatestSlotWorker

            self.sync = ApproximateTimeSync(2, ncfg.queue_size, ncfg.slop, self._on_pair)
            self.worker = LatestSlotWorker(self._process, self._on_worker_error, name="deepbbs-registration")
            self._diag_timer = self.create_timer(ncfg.diagnostics_period, self._publish_diagnostics)
            self.add_on_set_parameters_callback(self._on_set_parameters)
            inputs = PAIR_INPUTS if ncfg.mode == "pair" else (ODOM_INPUT,)
            names = ", ".join(self.resolve_topic_name(t) for t in inputs)
            self.get_logger().info(
                f"mode={ncfg.mode} inputs=[{names}] device={self._device} weights={self._weights} "
                f"qos={ncfg.qos_reliability}/{ncfg.qos_depth} slop={ncfg.slop}s queue={ncfg.queue_size}"
            )

        # -- parameters ---------------------------------------------------------------------------
        def _declare_config(self, defaults: Config) -> Config:
            from rcl_interfaces.msg import ParameterDescriptor

            flat = defaults.to_flat()
            sections = {k.partition(".")[0] for k in flat}
            overrides = getattr(self, "_parameter_overrides", {}) or {}
            unknown = sorted(k for k in overrides if k.partition(".")[0] in sections and k not in flat)
            if unknown:
                raise NodeError(f"unknown parameter(s): {', '.join(unknown)}")
            for key, value in flat.items():
                self.declare_parameter(key, value, ParameterDescriptor(name=key, dynamic_typing=True))
            values = {k: self.get_parameter(k).value for k in flat}
            try:
                return Config.from_flat(values)
            except ConfigError as err:
                raise NodeError(str(err)) from err

        def _on_set_parameters(self, params):
            from rcl_interfaces.msg import SetParametersResult

            ours = [p.name for p in params if p.name in self.cfg.to_flat()]
            if ours:
                return SetParametersResult(successful=False, reason=f"restart the node to change {', '.join(ours)}")
            return SetParametersResult(successful=True)

        # -- topics -------------------------------------------------------------------------------
        def _make_io(self) -> None:
            from diagnostic_msgs.msg import DiagnosticArray
            from geometry_msgs.msg import PoseStamped, TransformStamped
            from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
            from rclpy.qos_overriding_options import QoSOverridingOptions
            from sensor_msgs.msg import PointCloud2
            from std_srvs.srv import Trigger

            ncfg = self.cfg.node
            qos = QoSProfile(
                depth=ncfg.qos_depth,
                history=HistoryPolicy.KEEP_LAST,
                reliability=ReliabilityPolicy.BEST_EFFORT
                if ncfg.qos_reliability == "best_effort"
                else ReliabilityPolicy.RELIABLE,
            )
            overrides = QoSOverridingOptions.with_default_policies()
            try:
                if ncfg.mode == "pair":
                    self._subs = [
                        self.create_subscription(
                            PointCloud2, name, self._make_cb(i), qos, qos_overriding_options=overrides
                        )
                        for i, name in enumerate(PAIR_INPUTS)
                    ]
                else:
                    self._subs = [
                        self.create_subscription(
                            PointCloud2, ODOM_INPUT, self._on_scan, qos, qos_overriding_options=overrides
                        )
                    ]
                self.pub_pose = self.create_publisher(PoseStamped, "~/pose", 10)
                self.pub_transform = self.create_publisher(TransformStamped, "~/transform", 10)
                self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
                self.pub_odom = self.pub_tf = self.pub_aligned = None
                if ncfg.publish_odometry:
                    from nav_msgs.msg import Odometry

                    self.pub_odom = self.create_publisher(Odometry, "~/odometry", 10)
                if ncfg.publish_aligned_cloud:
                    self.pub_aligned = self.create_publisher(PointCloud2, "~/aligned_cloud", qos)
                if ncfg.publish_tf:
                    try:
                        from tf2_msgs.msg import TFMessage
                    except ImportError as err:
                        raise NodeError(
                            "node.publish_tf needs the tf2_msgs package (ROS: ros-jazzy-tf2-msgs), "
                            "which is not installed"
                        ) from err
                    self.pub_tf = self.create_publisher(TFMessage, "/tf", 100)
            except NodeError:
                raise
            except Exception as err:  # rclpy raises several types for bad (remapped) names
                raise NodeError(f"cannot create topics: {err}".replace("\n", " ")) from err
            self.srv_reset = self.create_service(Trigger, "~/reset", self._on_reset)

        def _make_cb(self, index: int):
            def cb(msg) -> None:
                t_recv = time.perf_counter()
                from msg_adapters.transforms import stamp_to_ns

                with self._lock:
                    self._counts["received"] += 1
                self.sync.add(index, stamp_to_ns(msg.header.stamp), (msg, t_recv))

            return cb

        def _on_pair(self, items) -> None:
            (_, (src, t_src)), (_, (tgt, t_tgt)) = items
            with self._lock:
                self._counts["pairs"] += 1
            self.worker.submit(("pair", src, tgt, max(t_src, t_tgt)))

        def _on_scan(self, msg) -> None:
            t_recv = time.perf_counter()
            with self._lock:
                self._counts["received"] += 1
                self._counts["pairs"] += 1
            self.worker.submit(("odometry", msg, None, t_recv))

        def _on_reset(self, request, response):
            self.sync.reset()
            with self._lock:
                self._odom_prev = self._odom_prev_pp = None
                self._T_odom = np.eye(4)
                self._cov_odom = np.zeros((6, 6))
                self._frames.clear()
                self._pp_cache.clear()
            response.success = True
            response.message = "odometry restarted at identity; synchroniser and frame memory cleared"
            self.get_logger().info(response.message)
            return response

        # -- worker thread ------------------------------------------------------------------------
        def _on_worker_error(self, job, exc: BaseException) -> None:
            text = "".join(traceback.format_exception_only(type(exc), exc)).strip()
            self._errors.log("internal_error", f"unexpected {text}; the node continues")
            self.get_logger().debug("".join(traceback.format_exception(exc)))

        def _decode(self, msg, role: str, t_recv: float) -> _Cloud:
            from msg_adapters.pointcloud2 import pointcloud2_to_arrays

            topic = self.resolve_topic_name(role)
            if int(msg.width) * int(msg.height) == 0 and len(msg.data) == 0:
                raise _BadInput("empty_cloud", f"{topic}: empty PointCloud2 (width * height = 0, no data)")
            try:
                arr = pointcloud2_to_arrays(msg)
            except PointCloudFormatError as err:
                raise _BadInput("malformed_cloud", f"{topic}: {err}") from err
            n_decl = int(msg.width) * int(msg.height)
            n = int(arr.xyz.shape[0])
            if n_decl == 0:
                raise _BadInput("empty_cloud", f"{topic}: empty PointCloud2 (width * height = 0)")
            if n == 0:
                raise _BadInput("no_valid_points", f"{topic}: none of the {n_decl} points is finite (NaN-only cloud)")
            if n < self.cfg.node.min_points:
                need = self.cfg.node.min_points
                raise _BadInput("too_few_points", f"{topic}: {n} valid points, fewer than node.min_points={need}")
            frame = arr.frame_id
            if not frame:
                raise _BadInput("missing_frame", f"{topic}: header.frame_id is empty")
            return _Cloud(arr.xyz, int(arr.stamp_ns), frame, t_recv)

        def _check_frame(self, role: str, frame: str) -> None:
            with self._lock:
                known = self._frames.setdefault(role, frame)
            if known != frame:
                raise _BadInput(
                    "mismatched_frame",
                    f"{self.resolve_topic_name(role)}: frame_id {frame!r} differs from {known!r} seen before "
                    "(call ~/reset after a deliberate change)",
                )

        def _preprocess(self, cloud: _Cloud):
            # same frame and stamp is not enough (two inputs may carry both): add the content's CRC
            key = (cloud.frame_id, cloud.stamp_ns, cloud.xyz.shape[0], zlib.crc32(cloud.xyz))
            with self._lock:
                hit = self._pp_cache.get(key)
            if hit is not None:
                return hit, 0.0
            t0 = time.perf_counter()
            try:
                pp = self.reg.preprocess(cloud.xyz)
            except RegistrationError as err:
                raise _BadInput("preprocess_failed", f"{cloud.frame_id}@{cloud.stamp_ns}: {err}") from err
            ms = (time.perf_counter() - t0) * 1e3
            with self._lock:
                self._pp_cache[key] = pp
                while len(self._pp_cache) > _PP_CACHE:
                    self._pp_cache.popitem(last=False)
            return pp, ms

        def _process(self, job) -> None:
            mode, a, b, t_in = job
            t_start = time.perf_counter()
            timings = {"queue_wait": (t_start - t_in) * 1e3}
            try:
                if mode == "pair":
                    src = self._decode(a, "source_cloud", t_in)
                    tgt = self._decode(b, "target_cloud", t_in)
                    self._check_frame("source_cloud", src.frame_id)
                    self._check_frame("target_cloud", tgt.frame_id)
                else:
                    src = self._decode(a, ODOM_INPUT, t_in)
                    self._check_frame(ODOM_INPUT, src.frame_id)
                    with self._lock:
                        tgt = self._odom_prev
                    if tgt is not None and src.stamp_ns <= tgt.stamp_ns:
                        raise _BadInput(
                            "stamp_not_increasing",
                            f"{self.resolve_topic_name(ODOM_INPUT)}: stamp {src.stamp_ns} ns is not after the "
                            f"previous scan's {tgt.stamp_ns} ns (call ~/reset after a time jump)",
                        )
                timings["decode"] = (time.perf_counter() - t_start) * 1e3
                src_pp, ms_s = self._preprocess(src)
                if tgt is None:  # first odometry scan: it becomes the reference
                    with self._lock:
                        self._odom_prev, self._odom_prev_pp = src, src_pp
                        self._T_odom = np.eye(4)
                        self._counts["processed"] += 1
                    self._publish_odometry_pose(src, np.eye(4), None, None)
                    return
                tgt_pp, ms_t = self._preprocess(tgt)
                timings["preprocess"] = ms_s + ms_t
                t0 = time.perf_counter()
                try:
                    result = self.reg.register(*_reg_inputs(src_pp, tgt_pp), preprocessed=True)
                except RegistrationError as err:
                    raise _BadInput("registration_failed", str(err)) from err
                timings["register"] = (time.perf_counter() - t0) * 1e3
                for k, v in (result.timings_ms or {}).items():
                    if k != "total":
                        timings[f"register.{k}"] = float(v)
                T = np.asarray(result.T_target_source, dtype=np.float64)
                if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                    raise _BadInput("registration_failed", "registration returned a non-finite transform")
                t0 = time.perf_counter()
                if mode == "pair":
                    self._publish_pair(src, tgt, src_pp, tgt_pp, T, result)
                else:
                    self._publish_odometry_step(src, tgt, src_pp, tgt_pp, T, result)
                timings["publish"] = (time.perf_counter() - t0) * 1e3
                timings["total"] = (time.perf_counter() - t_in) * 1e3
                self._stages.add(timings)
                with self._lock:
                    self._counts["processed"] += 1
                    self._last_result = {
                        "inlier_ratio": float(getattr(result, "inlier_ratio", float("nan"))),
                        "converged": float(bool(getattr(result, "converged", False))),
                    }
            except _BadInput as bad:
                with self._lock:
                    self._counts["rejected"] += 1
                self._errors.log(bad.kind, str(bad))

        # -- publishing ---------------------------------------------------------------------------
        def _quality(self, src_pp, tgt_pp, T, result):
            from deepbbs_ros.node.covariance import alignment_quality

            return alignment_quality(
                src_pp.points,
                tgt_pp.points,
                T,
                weights=getattr(result, "gamma", None),
                converged=bool(getattr(result, "converged", True)),
            )

        def _publish_pose_and_transform(self, T, stamp_ns, frame, child) -> None:
            from msg_adapters.transforms import matrix_to_pose_stamped, matrix_to_transform_stamped

            self.pub_pose.publish(matrix_to_pose_stamped(T, stamp_ns, frame))
            ts = matrix_to_transform_stamped(T, stamp_ns, frame, child)
            self.pub_transform.publish(ts)
            if self.pub_tf is not None:
                from tf2_msgs.msg import TFMessage

                if frame == child:
                    self._errors.log("tf_same_frame", f"not broadcasting {frame} -> {child} on /tf: same frame")
                else:
                    self.pub_tf.publish(TFMessage(transforms=[ts]))
            with self._lock:
                self._counts["published"] += 1

        def _publish_pair(self, src, tgt, src_pp, tgt_pp, T, result) -> None:
            self._publish_pose_and_transform(T, src.stamp_ns, tgt.frame_id, src.frame_id)
            if self.pub_odom is not None:
                from deepbbs_ros.node.covariance import twist_from_delta
                from msg_adapters.transforms import matrix_to_odometry

                q = self._quality(src_pp, tgt_pp, T, result)
                dt = (src.stamp_ns - tgt.stamp_ns) * 1e-9
                if abs(dt) > 1e-3:
                    twist, twist_cov = twist_from_delta(T, dt), q.covariance / dt**2
                else:  # same instant: no velocity information
                    twist, twist_cov = np.zeros(6), np.eye(6) * 1e6
                child = self.cfg.node.base_frame or src.frame_id
                self.pub_odom.publish(
                    matrix_to_odometry(T, src.stamp_ns, tgt.frame_id, child, twist, q.covariance, twist_cov)
                )
            self._publish_aligned(src, T, tgt.frame_id)

        def _publish_odometry_step(self, src, prev, src_pp, prev_pp, T_prev_src, result) -> None:
            from deepbbs_ros.node.covariance import adjoint

            need_cov = self.pub_odom is not None
            q = self._quality(src_pp, prev_pp, T_prev_src, result) if need_cov else None
            with self._lock:
                if need_cov:
                    Ad = adjoint(self._T_odom)
                    self._cov_odom = self._cov_odom + Ad @ q.covariance @ Ad.T
                self._T_odom = self._T_odom @ T_prev_src
                T_odom = self._T_odom.copy()
                cov = self._cov_odom.copy()
                self._odom_prev, self._odom_prev_pp = src, src_pp
            dt = (src.stamp_ns - prev.stamp_ns) * 1e-9
            self._publish_odometry_pose(src, T_odom, (T_prev_src, dt, q), cov)
            self._publish_aligned(src, T_prev_src, prev.frame_id)

        def _publish_odometry_pose(self, src, T_odom, step, cov) -> None:
            child = self.cfg.node.base_frame or src.frame_id
            self._publish_pose_and_transform(T_odom, src.stamp_ns, self.cfg.node.odom_frame, child)
            if self.pub_odom is None:
                return
            from deepbbs_ros.node.covariance import twist_from_delta
            from msg_adapters.transforms import matrix_to_odometry

            if step is None:  # first scan: pose known exactly (the origin), velocity unknown
                twist, twist_cov, cov = np.zeros(6), np.eye(6) * 1e6, np.zeros((6, 6))
            else:
                T_prev_src, dt, q = step
                twist, twist_cov = twist_from_delta(T_prev_src, dt), q.covariance / dt**2
            self.pub_odom.publish(
                matrix_to_odometry(T_odom, src.stamp_ns, self.cfg.node.odom_frame, child, twist, cov, twist_cov)
            )

        def _publish_aligned(self, src, T, frame) -> None:
            if self.pub_aligned is None:
                return
            from msg_adapters.pointcloud2 import arrays_to_pointcloud2

            xyz = (src.xyz.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
            self.pub_aligned.publish(arrays_to_pointcloud2(xyz, stamp_ns=src.stamp_ns, frame_id=frame))

        # -- diagnostics --------------------------------------------------------------------------
        def stats(self) -> dict[str, Any]:
            """Counters of the node, the synchroniser and the worker (also on /diagnostics)."""
            with self._lock:
                out: dict[str, Any] = dict(self._counts)
                out.update(self._last_result)
            out["dropped"] = self.worker.dropped
            out["sync"] = dict(self.sync.stats)
            out["sync_queue"] = list(self.sync.queue_lengths())
            out["errors"] = dict(self._errors.counts)
            out["latency_ms"] = self._stages.summary()
            return out

        def _publish_diagnostics(self) -> None:
            from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

            s = self.stats()
            values = {
                "mode": self.cfg.node.mode,
                "device": self._device,
                "weights": self._weights,
                "messages received": s["received"],
                "pairs synchronised": s["pairs"],
                "pairs processed": s["processed"],
                "pairs dropped (newest wins)": s["dropped"],
                "pairs rejected (bad input)": s["rejected"],
                "sync overflow / stale / late": "{overflow} / {stale} / {late}".format(**s["sync"]),
                "sync queue lengths": ",".join(map(str, s["sync_queue"])),
            }
            for kind, n in sorted(s["errors"].items()):
                values[f"errors.{kind}"] = n
            for stage, st in sorted(s["latency_ms"].items()):
                values[f"latency_ms.{stage}"] = f"median {st['median']:.1f} p99 {st['p99']:.1f} max {st['max']:.1f}"
            for k in ("inlier_ratio", "converged"):
                if k in s:
                    values[f"last.{k}"] = f"{s[k]:.3f}"
            level, message = DiagnosticStatus.OK, "running"
            if s["errors"]:
                level, message = DiagnosticStatus.WARN, f"{sum(s['errors'].values())} bad inputs / errors so far"
            status = DiagnosticStatus(
                level=level,
                name=f"{self.get_name()}: registration",
                message=message,
                hardware_id=self._device,
                values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
            )
            arr = DiagnosticArray(status=[status])
            arr.header.stamp = self.get_clock().now().to_msg()
            self.pub_diag.publish(arr)

        def destroy_node(self):
            self.worker.stop()
            return super().destroy_node()

    return RegistrationNode


def _reg_inputs(src_pp, tgt_pp) -> tuple[Any, Any]:
    """What ``register(..., preprocessed=True)`` gets: the PreprocessResults themselves when both carry
    ``dense_points`` (so the dense refinement runs, exactly as ``register(raw_src, raw_tgt)`` does
    offline), else their sampled ``points`` (M, 3) float32."""
    if getattr(src_pp, "dense_points", None) is not None and getattr(tgt_pp, "dense_points", None) is not None:
        return src_pp, tgt_pp
    return src_pp.points, tgt_pp.points


def _errors_for(node, period: float):
    from deepbbs_ros.node.diagnostics import RateLimitedErrors

    return RateLimitedErrors(lambda text: node.get_logger().error(text), period)


def _stage_times():
    from deepbbs_ros.node.diagnostics import StageTimes

    return StageTimes()


def RegistrationNode(*args, **kwargs):  # noqa: N802 - behaves like the class
    """Create the node (``rclpy.init`` must have been called)."""
    return make_node_class()(*args, **kwargs)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="deepbbs-node",
        description="Live DeepBBS++ registration node. ROS arguments go after --ros-args "
        "(remaps, -p name:=value, --params-file FILE).",
    )
    g = p.add_argument_group("configuration")
    g.add_argument("--config", metavar="YAML", help="config file (plain sections or a ROS parameter file); "
                   "ROS parameters given with --ros-args override it")
    g = p.add_argument_group("transport")
    g.add_argument("--no-shm-profile", action="store_true",
                   help="do not apply the shipped Fast DDS shared-memory profile (resources/fastdds_shm.xml)")
    return p


@cli_entry("deepbbs-node")
def main(argv: list[str] | None = None) -> int:
    """``deepbbs-node [--config YAML] [--ros-args ...]``: run until Ctrl-C."""
    full = list(sys.argv) if argv is None else ["deepbbs-node", *argv]
    user_args = _strip_ros_args(full)[1:]
    args = _parser().parse_args(user_args)
    defaults = Config.from_yaml(args.config) if args.config else Config()
    if not args.no_shm_profile:
        apply_default_profile()

    import rclpy
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

    try:
        rclpy.init(args=full)
    except Exception as err:  # rclpy's RCLError: bad --ros-args (remap rules, parameter syntax)
        first = str(err).split(", at ")[0].replace("failed to initialize rcl: ", "")
        raise NodeError(f"invalid ROS arguments: {first}") from err
    node = None
    try:
        node = RegistrationNode(defaults)
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


def _strip_ros_args(argv: list[str]) -> list[str]:
    """argv without the ``--ros-args ... [--]`` sections (rclpy's remove_ros_args, without rclpy)."""
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
