"""``deepbbs-ros``: what a ROS user does with ``ros2`` on the node, for pip installs that have no ``ros2``.

Real rclpy underneath (the same DDS graph as ``ros2``)::

    deepbbs-ros topic list                                     # topics and types
    deepbbs-ros topic echo /deepbbs_registration/pose          # messages, with rate and latency
    deepbbs-ros topic hz /deepbbs_registration/odometry        # rate and latency (receive time - header.stamp)
    deepbbs-ros param list /deepbbs_registration
    deepbbs-ros param get /deepbbs_registration node.mode
    deepbbs-ros param set /deepbbs_registration use_sim_time true
    deepbbs-ros reset                                          # calls /deepbbs_registration/reset
    deepbbs-ros relocalize                                     # localization: search the whole map again
    deepbbs-ros lifecycle set /deepbbs_localizer configure     # the managed node's transitions (ros2 lifecycle)
    deepbbs-ros static-tf --z 1.8 --frame-id base_link --child-frame-id velodyne   # on /tf_static until stopped
    deepbbs-ros map-server site.pcd --topic /map/points --frame map             # latched until stopped
    deepbbs-ros dds-profile                                    # the shipped Fast DDS profile, for your driver
    deepbbs-ros build-interfaces                               # tf2_msgs for /tf, bond for Nav2 (no PyPI wheels)

Latency is the receive time minus the message's ``header.stamp``: meaningful when the stamps are
wall-clock time (a live driver). A recording played with ``deepbbs-play`` keeps its recorded stamps (and
simulated time has its own clock): when the stamps are more than a minute away from the wall clock, no
latency is printed, only how far away they are. ``topic echo`` / ``hz`` wait for the topic to appear (a node
takes seconds to start); Ctrl-C or SIGTERM ends them with exit code 0.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from typing import Any

from deepbbs_ros.cli import map_server
from deepbbs_ros.cli.common import cli_entry
from deepbbs_ros.errors import NodeError

DEFAULT_NODE = "/deepbbs_registration"
LIFECYCLE_NODE = "/deepbbs_localizer"  # deepbbs-localizer, the managed node
TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")
DEFAULT_TIMEOUT = 30.0  # s; deepbbs-node takes 4-8 s to start (torch, the model, the warm-up)
NOT_WALL_CLOCK_S = 60.0  # s; stamps further than this from the wall clock are a recording's or sim time


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="deepbbs-ros", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="The node's topics, parameters, ~/reset and ~/relocalize from a pip install (no ros2 command "
                    "needed).",
        epilog="examples:\n" + __doc__.split("\n\n")[2] + "\n\n" + __doc__.split("\n\n")[3],
    )
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT, metavar="S",
                   help="seconds to wait for a topic, node or service to appear; a node takes seconds to start "
                        f"(default {DEFAULT_TIMEOUT:g})")
    sub = p.add_subparsers(dest="command", required=True)

    topic = sub.add_parser("topic", help="list, echo, hz").add_subparsers(dest="action", required=True)
    topic.add_parser("list", help="topics and their types")
    for name, text in (("echo", "print messages (a summary line each) with rate and latency"),
                       ("hz", "rate and latency once a second")):
        t = topic.add_parser(name, help=text)
        t.add_argument("topic")
        t.add_argument("--count", type=int, default=0, metavar="N", help="stop after N messages (0 = Ctrl-C)")
        t.add_argument("--duration", type=float, default=0.0, metavar="S", help="stop after S seconds (0 = Ctrl-C)")
        t.add_argument("--latched", action="store_true",
                       help="transient-local, reliable subscription (a map, /tf_static); automatic for /tf_static")
        if name == "echo":
            t.add_argument("--full", action="store_true", help="the whole message instead of a summary")

    param = sub.add_parser("param", help="list, get, set").add_subparsers(dest="action", required=True)
    pl = param.add_parser("list", help="parameter names of a node")
    pl.add_argument("node", nargs="?", default=DEFAULT_NODE)
    pg = param.add_parser("get", help="a parameter's value")
    pg.add_argument("node")
    pg.add_argument("name")
    ps = param.add_parser("set", help="set a parameter (value in YAML: true, 0.1, [1, 2], text)")
    ps.add_argument("node")
    ps.add_argument("name")
    ps.add_argument("value")

    r = sub.add_parser("reset", help="call the node's ~/reset (odometry restarts at identity)")
    r.add_argument("node", nargs="?", default=DEFAULT_NODE)
    r = sub.add_parser("relocalize", help="call the node's ~/relocalize (node.target_mode localization: forget the "
                                          "pose, search the whole map on the next scan)")
    r.add_argument("node", nargs="?", default=DEFAULT_NODE)
    lc = sub.add_parser("lifecycle", help="get, set: a managed node's state and transitions (as ros2 lifecycle)")
    lc = lc.add_subparsers(dest="action", required=True)
    lc.add_parser("get", help="the node's state").add_argument("node", nargs="?", default=LIFECYCLE_NODE)
    ls = lc.add_parser("set", help="trigger a transition: configure, activate, deactivate, cleanup, shutdown")
    ls.add_argument("node")
    ls.add_argument("transition", choices=TRANSITIONS)
    st = sub.add_parser(
        "static-tf", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="publish a static transform on /tf_static until stopped (tf2_ros static_transform_publisher's flags)",
        description="Publish frame-id -> child-frame-id on /tf_static (transient local, reliable: latched for late "
                    "subscribers) until Ctrl-C / SIGTERM; the flags of tf2_ros static_transform_publisher. Rotation "
                    "from --roll --pitch --yaw (rad, about the fixed x, y, z axes) or --qx --qy --qz --qw, not both.",
        epilog="example:\n  deepbbs-ros static-tf --x 0.5 --z 1.8 --yaw 0.1 --frame-id base_link "
               "--child-frame-id velodyne",
    )
    for axis in ("x", "y", "z"):
        st.add_argument(f"--{axis}", type=float, default=0.0, help=f"translation {axis} (m)")
    for angle in ("roll", "pitch", "yaw"):
        st.add_argument(f"--{angle}", type=float, default=None, help=f"{angle} (rad)")
    for comp in ("qx", "qy", "qz", "qw"):
        st.add_argument(f"--{comp}", type=float, default=None, help=f"quaternion {comp[1]}")
    st.add_argument("--frame-id", required=True, help="parent frame")
    st.add_argument("--child-frame-id", required=True, help="child frame")
    map_server.add_parser(sub)
    sub.add_parser("dds-profile", help="print the shipped Fast DDS profile path (and the line to export it)")
    b = sub.add_parser("build-interfaces",
                       help="build and install tf2_msgs and bond from their definitions (gcc, g++)")
    b.add_argument("--force", action="store_true", help="rebuild even when installed")
    return p


@cli_entry("deepbbs-ros")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "dds-profile":
        from deepbbs_ros.node.dds import PROFILE_ENV_VARS, default_profile_path

        path = default_profile_path()
        print(path)
        print("# give your driver the same transport:", file=sys.stderr)
        for var in PROFILE_ENV_VARS:
            print(f"export {var}={path}", file=sys.stderr)
        return 0
    if args.command == "build-interfaces":
        from deepbbs_ros import interfaces

        return interfaces.main(["--force"] if args.force else [])
    return _with_node(args)


# -- rclpy ----------------------------------------------------------------------------------------
def _with_node(args: argparse.Namespace) -> int:
    from deepbbs_ros.node.dds import apply_default_profile

    apply_default_profile()
    import rclpy
    from rclpy.executors import ExternalShutdownException

    static_tf = None
    if args.command == "static-tf":
        static_tf = _static_transform(args)  # bad flags: one line before any DDS
    served = map_server.load(args) if args.command == "map-server" else None  # a bad map: one line, no DDS
    rclpy.init(args=[])  # rclpy's handlers: SIGINT / SIGTERM shut the context down, which ends the spin below
    node = rclpy.create_node(f"deepbbs_ros_cli_{int(time.time() * 1000) % 100000}")
    try:
        if static_tf is not None:
            return _static_tf(node, static_tf)
        if served is not None:
            return map_server.serve(node, served[0], args, served[1])
        if args.command == "topic":
            return _topic(node, args)
        if args.command == "param":
            return _param(node, args)
        if args.command == "lifecycle":
            return _lifecycle(node, args)
        return _reset(node, args)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    except Exception:
        # a signal that lands while rclpy builds its wait set raises RCLError ("context is not valid"):
        # a clean stop too; anything else with the context still valid is a real error
        if rclpy.ok():
            raise
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def _node_name(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def _spin_until(node: Any, future: Any, timeout: float, what: str) -> Any:
    import rclpy

    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    if not future.done():
        raise NodeError(f"{what}: no answer within {timeout} s")
    if future.exception() is not None:
        raise NodeError(f"{what}: {future.exception()}")
    return future.result()


def _client(node: Any, srv_type: Any, name: str, timeout: float) -> Any:
    cli = node.create_client(srv_type, name)
    if not cli.wait_for_service(timeout_sec=min(timeout, 1.0)):
        _waiting(f"service {name}", timeout)
        if not cli.wait_for_service(timeout_sec=max(timeout - 1.0, 0.0)):
            raise NodeError(f"service {name} not available within {timeout:g} s (is the node running, "
                            "same ROS_DOMAIN_ID?)")
    return cli


def _waiting(what: str, timeout: float) -> None:
    print(f"waiting up to {timeout:g} s for {what} to appear (--timeout; a node takes seconds to start) ...",
          file=sys.stderr, flush=True)


def _reset(node: Any, args: argparse.Namespace) -> int:
    from std_srvs.srv import Trigger

    name = _node_name(args.node) + ("/relocalize" if args.command == "relocalize" else "/reset")
    res = _spin_until(node, _client(node, Trigger, name, args.timeout).call_async(Trigger.Request()),
                      args.timeout, name)  # fmt: skip
    print(f"{name}: {'ok' if res.success else 'failed'}: {res.message}")
    return 0 if res.success else 1


def _lifecycle(node: Any, args: argparse.Namespace) -> int:
    """``lifecycle get NODE``: its state; ``lifecycle set NODE TRANSITION``: the transition by its label (as ros2
    lifecycle), then the state it reached; exit code 1 when the node refused or failed it (its log says why)."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    name = _node_name(args.node)
    get = _client(node, GetState, name + "/get_state", args.timeout)
    ok = True
    if args.action == "set":
        change = _client(node, ChangeState, name + "/change_state", args.timeout)
        request = ChangeState.Request(transition=Transition(label=args.transition))
        ok = _spin_until(node, change.call_async(request), args.timeout, f"{name} {args.transition}").success
    state = _spin_until(node, get.call_async(GetState.Request()), args.timeout, name + "/get_state").current_state
    if args.action == "set":
        print(f"{name}: {args.transition} {'ok' if ok else 'failed (the node logs why)'}; now {state.label}")
    else:
        print(f"{name}: {state.label} [{state.id}]")
    return 0 if ok else 1


def _param(node: Any, args: argparse.Namespace) -> int:
    from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
    from rclpy.parameter import Parameter, parameter_value_to_python

    target = _node_name(args.node)
    if args.action == "list":
        res = _spin_until(node, _client(node, ListParameters, f"{target}/list_parameters", args.timeout)
                          .call_async(ListParameters.Request()), args.timeout, f"{target}/list_parameters")
        for name in sorted(res.result.names):
            print(name)
        return 0
    if args.action == "get":
        req = GetParameters.Request(names=[args.name])
        res = _spin_until(node, _client(node, GetParameters, f"{target}/get_parameters", args.timeout)
                          .call_async(req), args.timeout, f"{target}/get_parameters")
        if not res.values or res.values[0].type == 0:
            raise NodeError(f"{target}: parameter {args.name!r} is not set{_did_you_mean(node, target, args)}")
        print(_format_value(parameter_value_to_python(res.values[0])))
        return 0
    import yaml

    try:
        value = yaml.safe_load(args.value)
    except yaml.YAMLError:
        value = args.value
    if value is None:
        value = args.value
    try:
        msg = Parameter(args.name, value=value).to_parameter_msg()
    except (TypeError, ValueError) as err:
        raise NodeError(f"{args.name}: cannot send {args.value!r} as a parameter value ({err})") from err
    res = _spin_until(node, _client(node, SetParameters, f"{target}/set_parameters", args.timeout)
                      .call_async(SetParameters.Request(parameters=[msg])), args.timeout, f"{target}/set_parameters")
    result = res.results[0]
    if not result.successful:
        raise NodeError(f"{target}: setting {args.name} refused: {result.reason or 'no reason given'}")
    print(f"{target}: {args.name} = {_format_value(value)}")
    return 0


def _did_you_mean(node: Any, target: str, args: argparse.Namespace) -> str:
    """``; did you mean node.mode?`` from the node's own parameters (the config schema it declared), with the
    did-you-mean of the node's -p check and of config files (:func:`deepbbs_ros.config.did_you_mean`); a config
    key the node does not declare says so."""
    from rcl_interfaces.srv import ListParameters

    from deepbbs_ros.config import Config, did_you_mean

    try:
        res = _spin_until(node, _client(node, ListParameters, f"{target}/list_parameters", args.timeout)
                          .call_async(ListParameters.Request()), args.timeout, f"{target}/list_parameters")
    except NodeError:
        return ""
    names = list(res.result.names)
    if args.name in Config().to_flat():
        return " (a config key this node does not declare: see deepbbs-ros param list)"
    return did_you_mean(args.name, names)


def _format_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)) or type(value).__name__ == "ndarray":
        return "[" + ", ".join(_format_value(v) for v in list(value)) + "]"
    return str(value)


# -- topics ---------------------------------------------------------------------------------------
def _msg_class(type_name: str) -> Any:
    pkg, _, name = type_name.replace("/msg/", "/").partition("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), name)
    except (ImportError, AttributeError) as err:
        hint = " (deepbbs-ros build-interfaces)" if pkg == "tf2_msgs" else ""
        raise NodeError(f"message type {type_name} is not installed here{hint}") from err


def _topic_type(node: Any, topic: str, timeout: float) -> str:
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
            _waiting(f"topic {topic}", timeout)
            said = True
        rclpy.spin_once(node, timeout_sec=0.1)  # a signal shuts the context down: ExternalShutdownException


def _topic(node: Any, args: argparse.Namespace) -> int:
    if args.action == "list":
        time.sleep(min(args.timeout, 1.0))  # discovery
        for name, types in sorted(node.get_topic_names_and_types()):
            print(f"{name} [{', '.join(types)}]")
        return 0
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    topic = args.topic if args.topic.startswith("/") else "/" + args.topic
    cls = _msg_class(_topic_type(node, topic, args.timeout))
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

    node.create_subscription(cls, topic, on_msg, qos)
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


# -- static-tf ------------------------------------------------------------------------------------
def _static_transform(args: argparse.Namespace) -> tuple[Any, str, str]:
    """(``T_parent_child`` (4, 4), parent, child) from static_transform_publisher's flags; NodeError on a
    mix of roll/pitch/yaw and quaternion, a zero quaternion, or a frame id that is empty, equal or starts with /."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from deepbbs_ros.datasets.base import xyzquat_to_T

    for key in ("frame_id", "child_frame_id"):
        frame = getattr(args, key)
        if not frame or frame.startswith("/") or any(c.isspace() for c in frame):
            raise NodeError(f"--{key.replace('_', '-')}: invalid frame id {frame!r} (not empty, no leading '/', "
                            "no spaces)")
    if args.frame_id == args.child_frame_id:
        raise NodeError(f"--frame-id and --child-frame-id are the same frame {args.frame_id!r}")
    rpy = [args.roll, args.pitch, args.yaw]
    quat = [args.qx, args.qy, args.qz, args.qw]
    if any(v is not None for v in rpy) and any(v is not None for v in quat):
        raise NodeError("give the rotation as --roll --pitch --yaw or as --qx --qy --qz --qw, not both")
    T = np.eye(4)
    T[:3, 3] = [args.x, args.y, args.z]
    if any(v is not None for v in quat):
        q = [0.0 if v is None else v for v in quat[:3]] + [1.0 if quat[3] is None else quat[3]]
        try:
            T[:3, :3] = xyzquat_to_T([0.0, 0.0, 0.0, *q])[:3, :3]  # normalised, as every pose reader's
        except ValueError:
            raise NodeError(f"--qx --qy --qz --qw: not a rotation {q}") from None
    else:  # tf2's setRPY: roll about x, then pitch about y, then yaw about z (fixed axes)
        T[:3, :3] = Rotation.from_euler("xyz", [0.0 if v is None else v for v in rpy]).as_matrix()
    if not np.all(np.isfinite(T)):
        raise NodeError("the transform has a non-finite value")
    return T, args.frame_id, args.child_frame_id


def _static_tf(node: Any, transform: tuple[Any, str, str]) -> int:
    """Publish the transform once on ``/tf_static`` (reliable, transient local, as tf2_ros's static broadcaster:
    late subscribers get it) and keep the publisher until Ctrl-C / SIGTERM (exit code 0)."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    try:
        from tf2_msgs.msg import TFMessage
    except ImportError as err:
        raise NodeError("tf2_msgs is not installed: build it with `deepbbs-ros build-interfaces`") from err
    from msg_adapters.transforms import matrix_to_transform_stamped

    T, parent, child = transform
    qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub = node.create_publisher(TFMessage, "/tf_static", qos)
    stamp = node.get_clock().now().nanoseconds
    pub.publish(TFMessage(transforms=[matrix_to_transform_stamped(T, stamp, parent, child)]))
    t, yaw = T[:3, 3], _yaw_deg(T)
    print(f"/tf_static: {parent} -> {child} xyz [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] yaw {yaw:.2f} deg "
          "(latched; Ctrl-C to stop)", flush=True)
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.5)
    return 0


def _yaw_deg(T: Any) -> float:
    import numpy as np

    return float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))


if __name__ == "__main__":
    sys.exit(main())
