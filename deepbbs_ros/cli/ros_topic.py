"""``deepbbs-ros topic list`` / ``echo`` / ``hz``: a topic's type once it appears, its messages as one-line
summaries, and their rate and latency (receive time - ``header.stamp``; none for stamps that are not
wall-clock time)."""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from typing import Any

from deepbbs_ros.cli.ros_calls import waiting
from deepbbs_ros.errors import NodeError

NOT_WALL_CLOCK_S = 60.0  # s; stamps further than this from the wall clock are a recording's or sim time


def msg_class(type_name: str) -> Any:
    pkg, _, name = type_name.replace("/msg/", "/").partition("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), name)
    except (ImportError, AttributeError) as err:
        hint = " (deepbbs-ros build-interfaces)" if pkg == "tf2_msgs" else ""
        raise NodeError(f"message type {type_name} is not installed here{hint}") from err


def topic_type(node: Any, topic: str, timeout: float) -> str:
    """The type of ``topic`` once a publisher of it is discovered, waiting up to ``timeout`` s (saying so on
    stderr after 1 s: the node may still be starting)."""
    import rclpy

    start = time.monotonic()
    said = False
    while True:
        types = dict(node.get_topic_names_and_types())
        if topic in types:
            return types[topic][0]
        waited = time.monotonic() - start
        if waited > timeout:
            raise NodeError(f"topic {topic} not found within {timeout:g} s (deepbbs-ros topic list shows the graph; "
                            "--timeout S waits longer)")
        if waited > 1.0 and not said:
            waiting(f"topic {topic}", timeout)
            said = True
        rclpy.spin_once(node, timeout_sec=0.1)  # a signal shuts the context down: ExternalShutdownException


def topic(node: Any, args: argparse.Namespace) -> int:
    if args.action == "list":
        time.sleep(min(args.timeout, 1.0))  # discovery
        for name, types in sorted(node.get_topic_names_and_types()):
            print(f"{name} [{', '.join(types)}]")
        return 0
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    topic = args.topic if args.topic.startswith("/") else "/" + args.topic
    cls = msg_class(topic_type(node, topic, args.timeout))
    latched = args.latched or topic == "/tf_static"
    qos = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE if latched else ReliabilityPolicy.BEST_EFFORT,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)
    stats = TopicStats()
    echo = args.action == "echo"

    def on_msg(msg: Any) -> None:
        stats.add(time.time_ns(), _stamp_ns(msg))
        if echo:
            print(str(msg) if args.full else summary(msg), flush=True)

    from rclpy.executors import ExternalShutdownException

    from deepbbs_ros.node.callbacks import guard
    from deepbbs_ros.node.diagnostics import RateLimitedErrors

    # a message the summary cannot read is one line (every 5 s at most), not the end of the command
    errors = RateLimitedErrors(lambda text: print(text, file=sys.stderr, flush=True), 5.0)
    node.create_subscription(cls, topic, guard(on_msg, topic, lambda kind, text, exc: errors.log(kind, text)), qos)
    start = last_report = time.monotonic()
    stopped = False
    try:
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
            now = time.monotonic()
            if now - last_report >= 1.0:
                last_report = now
                print(stats.line(topic), file=sys.stderr if echo else sys.stdout, flush=True)
            if (args.count and stats.n >= args.count) or (args.duration and now - start >= args.duration):
                break
    except (KeyboardInterrupt, ExternalShutdownException):
        stopped = True  # Ctrl-C / SIGTERM: the summary below, exit code 0
    except Exception:
        if rclpy.ok():  # RCLError from a signal landing in the wait set: stopped too
            raise
        stopped = True
    stopped = stopped or not rclpy.ok()  # the context shut down between two spins
    if not echo or args.count or args.duration or stopped:
        print(stats.line(topic), file=sys.stderr if echo else sys.stdout, flush=True)
    return 0


class TopicStats:
    """Message count, rate over the last ``window`` messages and latency (receive time - header.stamp)."""

    def __init__(self, window: int = 100) -> None:
        self.window = window
        self.n = 0
        self._recv: list[int] = []
        self._lat_ms: list[float] = []

    @property
    def clock_offset_s(self) -> float | None:
        """Median receive time - stamp (s) when the stamps are not wall-clock time (more than
        ``NOT_WALL_CLOCK_S`` from it: a recording's stamps, simulated time); None when they are (or none)."""
        if not self._lat_ms:
            return None
        import numpy as np

        offset = float(np.median(self._lat_ms)) * 1e-3
        return offset if abs(offset) > NOT_WALL_CLOCK_S else None

    def add(self, recv_ns: int, stamp_ns: int | None) -> None:
        self.n += 1
        self._recv = (self._recv + [recv_ns])[-self.window:]
        if stamp_ns:
            self._lat_ms = (self._lat_ms + [(recv_ns - stamp_ns) * 1e-6])[-self.window:]

    @property
    def rate_hz(self) -> float:
        if len(self._recv) < 2:
            return 0.0
        return (len(self._recv) - 1) / max((self._recv[-1] - self._recv[0]) * 1e-9, 1e-9)

    def line(self, topic: str) -> str:
        text = f"{topic}: {self.n} messages, {self.rate_hz:.2f} Hz"
        offset = self.clock_offset_s
        if offset is not None:
            side = "behind" if offset > 0 else "ahead of"
            text += (f", stamps {abs(offset):.1f} s {side} the wall clock (a recording's stamps or sim time): "
                     "no latency figure")
        elif self._lat_ms:
            import numpy as np

            lat = np.asarray(self._lat_ms)
            text += f", latency p50 {np.median(lat):.1f} ms, p99 {np.percentile(lat, 99):.1f} ms (now - stamp)"
        return text


def _stamp_ns(msg: Any) -> int | None:
    header = getattr(msg, "header", None)
    if header is None:
        transforms = getattr(msg, "transforms", None)
        header = transforms[0].header if transforms else None
    if header is None:
        return None
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def summary(msg: Any) -> str:
    """One line per message for the node's outputs (pose, transform, odometry, TF, clouds, diagnostics)."""
    name = type(msg).__name__
    stamp = _stamp_ns(msg)
    head = f"{name} {stamp * 1e-9:.3f}" if stamp is not None else name
    if hasattr(msg, "pose") and hasattr(msg.pose, "pose"):  # Odometry / PoseWithCovarianceStamped
        return f"{head} {msg.header.frame_id} -> {getattr(msg, 'child_frame_id', '')} {_pose_text(msg.pose.pose)}"
    if name == "PoseStamped":
        return f"{head} {msg.header.frame_id} {_pose_text(msg.pose)}"
    if name == "TransformStamped":
        return f"{head} {_tf_text(msg)}"
    if name == "TFMessage":
        return f"{head} " + "; ".join(_tf_text(t) for t in msg.transforms)
    if name == "PointCloud2":
        fields = ",".join(f.name for f in msg.fields)
        return f"{head} {msg.header.frame_id} {msg.width * msg.height} points [{fields}]"
    if name == "DiagnosticArray":
        return "\n".join(f"{head} {s.name}: {s.message}\n" + "\n".join(f"  {kv.key}: {kv.value}" for kv in s.values)
                         for s in msg.status)
    text = str(msg)
    return text if len(text) <= 300 else text[:300] + "..."


def _pose_text(p: Any) -> str:
    import numpy as np

    q = p.orientation
    yaw = np.degrees(np.arctan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z)))
    return f"xyz [{p.position.x:.3f}, {p.position.y:.3f}, {p.position.z:.3f}] yaw {yaw:.2f} deg"


def _tf_text(t: Any) -> str:
    import numpy as np

    tr, q = t.transform.translation, t.transform.rotation
    yaw = np.degrees(np.arctan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z)))
    return f"{t.header.frame_id} -> {t.child_frame_id} xyz [{tr.x:.3f}, {tr.y:.3f}, {tr.z:.3f}] yaw {yaw:.2f} deg"
