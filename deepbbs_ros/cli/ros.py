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
import sys
import time

from deepbbs_ros.cli import map_server, ros_calls, ros_topic, static_tf
from deepbbs_ros.cli.common import cli_entry

DEFAULT_NODE = "/deepbbs_registration"
LIFECYCLE_NODE = "/deepbbs_localizer"  # deepbbs-localizer, the managed node
TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")
DEFAULT_TIMEOUT = 30.0  # s; deepbbs-node takes 4-8 s to start (torch, the model, the warm-up)


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
    static_tf.add_parser(sub)
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

    transform = None
    if args.command == "static-tf":
        transform = static_tf.transform(args)  # bad flags: one line before any DDS
    served = map_server.load(args) if args.command == "map-server" else None  # a bad map: one line, no DDS
    rclpy.init(args=[])  # rclpy's handlers: SIGINT / SIGTERM shut the context down, which ends the spin below
    node = rclpy.create_node(f"deepbbs_ros_cli_{int(time.time() * 1000) % 100000}")
    try:
        if transform is not None:
            return static_tf.serve(node, transform)
        if served is not None:
            return map_server.serve(node, served[0], args, served[1])
        if args.command == "topic":
            return ros_topic.topic(node, args)
        if args.command == "param":
            return ros_calls.param(node, args)
        if args.command == "lifecycle":
            return ros_calls.lifecycle(node, args)
        return ros_calls.reset(node, args)
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


if __name__ == "__main__":
    sys.exit(main())
