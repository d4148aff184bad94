"""``deepbbs-play SOURCE``: publish a recording's clouds (and ``/clock``) at real or scaled rate.

For pip-only installs that have no ``ros2 bag play``: any source :func:`deepbbs_ros.datasets.open_source`
reads (ROS 1/2 bags, mcap, Apollo-style and KITTI folders) drives the live node::

    deepbbs-play bags/sample.mcap --rate 0.5 --cloud-topic /points
    deepbbs-node --ros-args -p node.mode:=odometry -p use_sim_time:=true -r cloud:=/points

Clouds keep their recorded stamps and frames; ``/clock`` follows the recording's time (scaled by
``--rate``) so nodes with ``use_sim_time`` see the recording's clock. Ground truth, when present, is
published as ``geometry_msgs/PoseStamped`` on ``--gt-topic``. SIGTERM stops it cleanly between two
messages (exit code 0); Ctrl-C exits with 130.

The node's pair mode from one recording (each scan against the one before it)::

    deepbbs-play bags/urban_drive_hdl64 --cloud-topic /lidar/points --previous-topic /lidar/previous
    deepbbs-node --ros-args -r source_cloud:=/lidar/points -r target_cloud:=/lidar/previous

``--previous-topic`` publishes scan k-1 beside scan k, restamped with scan k's stamp (its points and frame
unchanged), so the two inputs pair by stamp: the published pose is the motion from scan k-1 to scan k.

``--wait S`` (default 30) waits for a subscriber on every cloud topic (start the node first, or both at once);
when none appears within S s nothing is played and the exit code is 1 (``--wait 0``: start at once).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from deepbbs_ros.cli.common import cli_entry, local_ros_env
from deepbbs_ros.errors import ConfigError, NodeError

DEFAULT_WAIT_S = 30.0  # s; deepbbs-node takes 4-12 s to start (torch, the model, the warm-up)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="deepbbs-play", description=__doc__.split("\n\n")[0].split(": ", 1)[1])
    p.add_argument("source", help="bag (.bag, rosbag2 folder, .mcap, .db3), Apollo-style or KITTI folder")
    g = p.add_argument_group("input")
    g.add_argument("--topic", help="PointCloud2 topic to read (needed when the bag has several)")
    g.add_argument("--start", type=int, default=0, metavar="N", help="skip the first N frames")
    g.add_argument("--frames", type=int, default=0, metavar="N", help="publish at most N frames (0 = all)")
    g = p.add_argument_group("output")
    g.add_argument("--cloud-topic", help="topic to publish clouds on (default: the recording's topic)")
    g.add_argument(
        "--previous-topic", metavar="TOPIC",
        help="also publish the previous scan on TOPIC, restamped with the current scan's stamp (pair mode: "
             "-r source_cloud:=CLOUD_TOPIC -r target_cloud:=TOPIC)",
    )
    g.add_argument("--gt-topic", default=None, help="ground-truth PoseStamped topic (default /ground_truth/pose)")
    g.add_argument("--no-gt", action="store_true", help="do not publish ground truth")
    g.add_argument("--no-clock", action="store_true", help="do not publish /clock")
    g.add_argument("--clock-hz", type=float, default=100.0, metavar="HZ", help="/clock rate between frames (Hz)")
    g.add_argument(
        "--reliability", choices=("best_effort", "reliable"), default="reliable",
        help="QoS of the cloud publisher (reliable also reaches best-effort subscribers)",
    )
    g = p.add_argument_group("timing")
    g.add_argument("--rate", type=float, default=1.0, help="speed factor: 1 = real time, 0.5 = half speed")
    g.add_argument("--loop", action="store_true", help="start again at the end (stamps repeat: nodes reset)")
    g.add_argument(
        "--wait", type=float, default=DEFAULT_WAIT_S, metavar="S",
        help="wait up to S seconds for a subscriber on the cloud topic(s) before starting (the node takes seconds "
             f"to start); none by then is an error (exit 1); 0 = start at once (default {DEFAULT_WAIT_S:g})",
    )
    g = p.add_argument_group("transport")
    g.add_argument("--no-shm-profile", action="store_true", help="do not apply the shipped Fast DDS profile")
    g.add_argument("--local", action="store_true", help="keep DDS on loopback in a per-run domain (demos, tests)")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


@cli_entry("deepbbs-play")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.rate <= 0:
        raise ConfigError(f"--rate must be > 0, got {args.rate}")
    if args.clock_hz <= 0:
        raise ConfigError(f"--clock-hz must be > 0, got {args.clock_hz}")
    if args.wait < 0:
        raise ConfigError(f"--wait must be >= 0, got {args.wait}")
    from deepbbs_ros.datasets import GT_POSE_TOPIC, open_source
    from deepbbs_ros.node.dds import apply_default_profile

    source = open_source(args.source, topic=args.topic)
    if args.local:
        local_ros_env()
    if not args.no_shm_profile:
        apply_default_profile()

    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2
    from tqdm import tqdm

    from msg_adapters.pointcloud2 import arrays_to_pointcloud2
    from msg_adapters.transforms import matrix_to_pose_stamped, ns_to_stamp

    cloud_topic = args.cloud_topic or source.topic
    if args.previous_topic is not None and args.previous_topic in ("", cloud_topic):
        raise ConfigError(f"--previous-topic must name a topic other than the cloud topic {cloud_topic}")
    gt_topic = args.gt_topic or GT_POSE_TOPIC
    # SIGTERM (a launch file, systemd, `kill`) stops the loop between two messages; rclpy's own handler would
    # invalidate the context under a publish() and end in an RCLError traceback. Ctrl-C stays KeyboardInterrupt.
    from rclpy.signals import SignalHandlerOptions

    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    # Ctrl-C is KeyboardInterrupt even when the parent started us with SIGINT ignored (a job put in the background
    # by a non-interactive shell), so that `kill -INT` stops the player too
    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    rclpy.init(args=None, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("deepbbs_play")
    try:
        qos = QoSProfile(
            depth=5,
            history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy.RELIABLE if args.reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
        )
        pub_cloud = node.create_publisher(PointCloud2, cloud_topic, qos)
        pub_prev = None if args.previous_topic is None else node.create_publisher(PointCloud2, args.previous_topic, qos)
        cloud_pubs = [pub_cloud] + ([pub_prev] if pub_prev is not None else [])
        pub_gt = None if args.no_gt or not source.has_ground_truth else node.create_publisher(PoseStamped, gt_topic, 10)
        pub_clock = None if args.no_clock else node.create_publisher(Clock, "/clock", 10)

        if args.wait > 0:
            start = time.monotonic()
            deadline, said = start + args.wait, False
            while not stop.is_set() and any(p.get_subscription_count() == 0 for p in cloud_pubs):
                if not said and not args.quiet and time.monotonic() - start > 1.0:
                    topics = ", ".join(p.topic_name for p in cloud_pubs)
                    print(f"deepbbs-play: waiting up to {args.wait:g} s for a subscriber on {topics} (--wait) ...",
                          file=sys.stderr, flush=True)
                    said = True
                if time.monotonic() >= deadline:
                    missing = [p.topic_name for p in cloud_pubs if p.get_subscription_count() == 0]
                    raise NodeError(
                        f"no subscriber on {', '.join(missing)} within --wait {args.wait:g} s: nothing played "
                        "(is the node running, on these topics, with the same ROS_DOMAIN_ID?)"
                    )
                time.sleep(0.05)

        def clock(ns: int) -> None:
            if pub_clock is not None:
                pub_clock.publish(Clock(clock=ns_to_stamp(ns)))

        sent = 0
        total = len(source) - args.start
        if args.frames:
            total = min(total, args.frames)
        bar = tqdm(total=max(total, 0), unit="frames", disable=args.quiet, desc=f"play -> {cloud_topic}")
        while not stop.is_set():
            t0_wall = None
            stamp0 = 0
            prev_msg = None  # --previous-topic: the scan before, restamped with each new scan's stamp
            for k, scan in enumerate(source):
                if k < args.start:
                    continue
                if args.frames and k - args.start >= args.frames:
                    break
                if t0_wall is None:
                    t0_wall, stamp0 = time.monotonic(), scan.stamp_ns
                due = t0_wall + (scan.stamp_ns - stamp0) * 1e-9 / args.rate
                while not stop.is_set():  # /clock ticks while waiting for the frame's time
                    now = time.monotonic()
                    if now >= due:
                        break
                    clock(stamp0 + int((now - t0_wall) * args.rate * 1e9))
                    time.sleep(min(1.0 / args.clock_hz, due - now))
                if stop.is_set():
                    break
                clock(scan.stamp_ns)
                msg = arrays_to_pointcloud2(
                    scan.points, dict(scan.fields), stamp_ns=scan.stamp_ns, frame_id=scan.frame_id
                )
                if pub_prev is not None and prev_msg is not None:
                    prev_msg.header.stamp = ns_to_stamp(scan.stamp_ns)  # published already: reuse the message
                    pub_prev.publish(prev_msg)
                pub_cloud.publish(msg)
                prev_msg = msg
                if pub_gt is not None and scan.T_world_lidar is not None:
                    from deepbbs_ros.datasets import WORLD_FRAME

                    pub_gt.publish(matrix_to_pose_stamped(scan.T_world_lidar, scan.stamp_ns, WORLD_FRAME))
                sent += 1
                bar.update(1)
            if not args.loop:
                break
            bar.reset()
        bar.close()
        time.sleep(0.2)  # let the last messages leave before the participant goes away
        where = cloud_topic + (f" (and the previous scan on {args.previous_topic})" if pub_prev is not None else "")
        node.get_logger().info(f"published {sent} frames on {where}" + (" (stopped by SIGTERM)" if stop.is_set()
                                                                       else ""))
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)
    return 0


if __name__ == "__main__":
    sys.exit(main())
