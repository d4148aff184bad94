#!/usr/bin/env python3
"""Latency of the live node: PointCloud2 in -> PoseStamped out, 120k-point HDL-64-like clouds at 10 Hz.

Starts ``deepbbs-node`` in odometry mode as a subprocess (shipped weights unless --weights), publishes
synthetic 120k-point scans at --rate Hz, and times each PoseStamped against the wall time its source
scan was published (same host, same clock). Prints median / p99 and the node's per-stage breakdown
(from /diagnostics). Goals on the reference machine: median <= 100 ms, p99 <= 200 ms.

    python scripts/bench_node_latency.py --seconds 30 [--weights W.pt] [--device cpu] [--threads 1]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = p.add_argument_group("run")
    g.add_argument("--seconds", type=float, default=30.0, help="publishing time (s)")
    g.add_argument("--rate", type=float, default=10.0, help="scan rate (Hz)")
    g.add_argument("--points", type=int, default=120_000, help="points per scan")
    g.add_argument("--scans", type=int, default=20, help="distinct scans generated (cycled, poses continue)")
    g = p.add_argument_group("node")
    g.add_argument("--weights", default="", help="checkpoint (default: the shipped model)")
    g.add_argument("--device", default="auto", help="auto | cpu | cuda")
    g.add_argument("--threads", type=int, default=0, help="torch CPU threads of the node (0 = torch default)")
    g.add_argument("--config", help="extra config YAML for the node")
    args = p.parse_args(argv)

    from deepbbs_ros.cli.common import local_ros_env
    from deepbbs_ros.node.dds import apply_default_profile
    from deepbbs_ros.node.synthetic import SyntheticTown, pose

    local_ros_env()
    apply_default_profile()
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import qos_profile_sensor_data
    from rich.console import Console
    from rich.table import Table
    from sensor_msgs.msg import PointCloud2

    from msg_adapters.pointcloud2 import arrays_to_pointcloud2
    from msg_adapters.transforms import ns_to_stamp, stamp_to_ns

    town = SyntheticTown(seed=5)
    print(f"generating {args.scans} scans of {args.points} points ...", file=sys.stderr)
    step = pose(1.2, 0.0, 0.0, np.deg2rad(0.8))  # ~12 m/s, turning
    T = np.eye(4)
    msgs = []
    for k in range(args.scans):
        msgs.append(arrays_to_pointcloud2(town.scan(T, args.points, seed=k), frame_id="velodyne64"))
        T = T @ step
    cmd = [sys.executable, "-m", "deepbbs_ros.node.registration_node"]
    if args.config:
        cmd += ["--config", args.config]
    cmd += ["--ros-args", "-p", "node.mode:=odometry", "-p", f"registration.device:={args.device}",
            "-p", f"registration.threads:={args.threads}",
            "-p", "node.diagnostics_period:=1.0", "-r", "cloud:=/bench/points"]
    if args.weights:
        cmd += ["-p", f"registration.weights:={args.weights}"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    rclpy.init()
    node = rclpy.create_node("bench_node_latency")
    sent: dict[int, float] = {}
    lat: list[float] = []
    diags: list[DiagnosticArray] = []

    def on_pose(msg: PoseStamped) -> None:
        t = time.perf_counter()
        s = stamp_to_ns(msg.header.stamp)
        if s in sent:
            lat.append((t - sent.pop(s)) * 1e3)

    node.create_subscription(PoseStamped, "/deepbbs_registration/pose", on_pose, 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    pub = node.create_publisher(PointCloud2, "/bench/points", qos_profile_sensor_data)
    try:
        deadline = time.monotonic() + 120
        while pub.get_subscription_count() == 0:
            if proc.poll() is not None or time.monotonic() > deadline:
                print(proc.stderr.read(), file=sys.stderr)
                return 1
            rclpy.spin_once(node, timeout_sec=0.1)
        n_total = int(args.seconds * args.rate)
        t0 = time.perf_counter()
        for k in range(n_total):
            due = t0 + k / args.rate
            while time.perf_counter() < due:
                rclpy.spin_once(node, timeout_sec=max(0.0, min(0.005, due - time.perf_counter())))
            m = msgs[k % len(msgs)]
            stamp = 1_000_000_000_000 + k * int(1e9 / args.rate)
            m.header.stamp = ns_to_stamp(stamp)
            sent[stamp] = time.perf_counter()
            pub.publish(m)
        end = time.perf_counter() + 3.0
        while time.perf_counter() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        node.destroy_node()
        rclpy.try_shutdown()
    if not lat:
        print("no pose received", file=sys.stderr)
        return 1
    a = np.asarray(lat[1:] or lat)  # the first scan only initialises odometry
    con = Console()
    t = Table(title=f"deepbbs-node latency, {args.points} points @ {args.rate:g} Hz, odometry mode")
    for c in ("quantity", "value", "unit"):
        t.add_column(c)
    t.add_row("scans sent", str(n_total), "scans")
    t.add_row("poses received", str(len(lat)), "poses")
    t.add_row("scans without pose (dropped: newest wins)", str(n_total - len(lat)), "scans")
    t.add_row("in -> out median", f"{np.median(a):.1f}", "ms")
    t.add_row("in -> out p99", f"{np.percentile(a, 99):.1f}", "ms")
    t.add_row("in -> out max", f"{a.max():.1f}", "ms")
    if diags:
        for kv in diags[-1].status[0].values:
            if kv.key.startswith("latency_ms.") or kv.key in ("device", "weights"):
                t.add_row(f"node {kv.key}", kv.value, "ms" if kv.key.startswith("latency") else "")
    con.print(t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
