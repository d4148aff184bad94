#!/usr/bin/env python3
"""Latency of the live node against a GICP anchor: real driver layouts streamed at a fixed rate.

For each ``--layout`` the simulator (:func:`deepbbs_ros.sim.simulate_drive`) drives ``--scans`` frames
through an urban scene with the matching sensor model, and every frame is encoded in the field layout
its real driver publishes (:mod:`msg_adapters.layouts`):

* ``velodyne``: HDL-64E, ``velodyne_pointcloud`` PointXYZIRT (packed, point_step 22, unorganised,
  firing order; ~120k points);
* ``ouster``: OS1-128 (or OS1-64, ``--ouster-beams``), ouster-ros PointOS (point_step 48, organised
  ``beams x 1024`` with zeros where no return came back, like the driver).

This process publishes the frames at ``--rate`` Hz (frames played forwards then backwards, so that
consecutive scans are always neighbours) to a node running in its own process, first ``deepbbs-node``
(DeepBBS++), then the GICP anchor ``python -m deepbbs_ros.node.gicp_anchor`` (small_gicp GICP, the same
node plumbing and topics), and times every PoseStamped against the wall time at which its source cloud
was published (same host, same clock). ``--mode odometry``: one input; deepbbs-node runs its local-map
odometry (DeepBBSOdometry, DeepBBS++ only on stamp gaps, fit drops and the first motion), the anchor
chains GICP scan k against scan k-1;
``--mode pair``: scan k on ``source_cloud`` and scan k-1 on ``target_cloud``, both stamped like scan k.

Per layout and method it prints the pairs published (after ``--warmup`` seconds), the fraction
answered, p50 / p99 latency and their ratio to the anchor, then the node's own stage breakdown (from
/diagnostics). DDS stays on loopback in a run-specific domain. Quick check (about a minute):

    python scripts/bench_node_latency.py --seconds 5 --layout both --mode odometry
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from deepbbs_ros.entry import cli_entry  # noqa: E402
from deepbbs_ros.errors import DeepBBSError  # noqa: E402

SEC = 1_000_000_000
STAMP0_NS = 1_000 * SEC
METHODS = {  # name -> (module run with -m, node name = pose topic namespace)
    "deepbbs": ("deepbbs_ros.node.registration_node", "deepbbs_registration"),
    "gicp": ("deepbbs_ros.node.gicp_anchor", "gicp_anchor"),
}
ANCHOR = "gicp"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = p.add_argument_group("stream")
    g.add_argument("--layout", choices=("velodyne", "ouster", "both"), default="both", help="driver layout(s)")
    g.add_argument("--ouster-beams", type=int, choices=(64, 128), default=128, help="OS1-64 or OS1-128")
    g.add_argument("--mode", choices=("pair", "odometry"), default="odometry", help="node mode")
    g.add_argument("--seconds", type=float, default=30.0, help="measured streaming time per run (s)")
    g.add_argument("--warmup", type=float, default=2.0, help="streaming time before the measurement (s)")
    g.add_argument("--rate", type=float, default=10.0, help="scan rate (Hz)")
    g.add_argument("--scans", type=int, default=20, help="distinct simulated frames (played back and forth)")
    g.add_argument("--scene", default="urban", help="simulator scene")
    g.add_argument("--seed", type=int, default=5, help="simulator seed")
    g = p.add_argument_group("nodes")
    g.add_argument("--methods", default="deepbbs,gicp", help="comma-separated: deepbbs, gicp (the anchor)")
    g.add_argument("--weights", default="", help="DeepBBS++ checkpoint (default: the shipped model)")
    g.add_argument("--device", default="auto", help="auto | cpu | cuda")
    g.add_argument("--threads", type=int, default=None,
                   help="registration.threads of the node (torch threads of the network; default: the config's)")
    g.add_argument("--config", help="config YAML for both nodes")
    g.add_argument("--startup-timeout", type=float, default=120.0, help="s to wait for a node to come up")
    return p


# -- the clouds -----------------------------------------------------------------------------------------
def _lidar(layout: str, ouster_beams: int):
    from deepbbs_ros.sim.lidar import LidarConfig

    if layout == "velodyne":
        return LidarConfig.hdl64()
    if ouster_beams == 128:  # OS1-128: 45 deg vertical field of view
        return LidarConfig.ouster64(beams=128, vfov_min_deg=-22.5, vfov_max_deg=22.5, name="os1-128")
    return LidarConfig.ouster64(name="os1-64")


def layout_message(layout: str, scan, lidar, frame_id: str):
    """A simulated :class:`~deepbbs_ros.datasets.base.Scan` as the driver of ``layout`` publishes it
    (rclpy PointCloud2, stamp set later)."""
    from msg_adapters.layouts import driver_cloud

    return driver_cloud(layout, scan.points, scan.fields, beams=lidar.beams, columns=lidar.columns,
                        frame_id=frame_id)


def make_stream(args, layout: str) -> tuple[list, str]:
    from deepbbs_ros.sim import simulate_drive

    lidar = _lidar(layout, args.ouster_beams)
    t0 = time.perf_counter()
    scans = list(simulate_drive(args.scene, args.seed, args.scans, lidar=lidar))
    frame = "velodyne" if layout == "velodyne" else "os_sensor"
    msgs = [layout_message(layout, s, lidar, frame) for s in scans]
    n = np.mean([len(s.points) for s in scans])
    m = msgs[0]
    desc = (f"{lidar.name} ({layout} driver layout, point_step {m.point_step}, {m.height}x{m.width}, "
            f"{n:.0f} valid points, {len(m.data) / 1e6:.1f} MB)")  # fmt: skip
    print(f"  simulated {len(scans)} frames of {desc} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return msgs, desc


def playback_order(n_frames: int, n_total: int) -> list[int]:
    """Frame index of every published scan: 0, 1, ..., n-1, n-2, ..., 1, 0, 1, ... (neighbours only)."""
    if n_frames < 2:
        raise DeepBBSError("--scans must be >= 2")
    cycle = list(range(n_frames)) + list(range(n_frames - 2, 0, -1))
    return [cycle[k % len(cycle)] for k in range(n_total)]


# -- one run ---------------------------------------------------------------------------------------------
@dataclass
class RunResult:
    pairs: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    diagnostics: dict[str, str] = field(default_factory=dict)
    error: str = ""

    @property
    def answered(self) -> float:
        return len(self.latencies_ms) / self.pairs if self.pairs else 0.0

    def pct(self, q: float) -> float:
        return float(np.percentile(self.latencies_ms, q)) if self.latencies_ms else float("nan")


def run_method(args, method: str, msgs: list) -> RunResult:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2

    from msg_adapters.transforms import ns_to_stamp, stamp_to_ns

    module, name = METHODS[method]
    cmd = [sys.executable, "-m", module]
    if args.config:
        cmd += ["--config", args.config]
    cmd += ["--ros-args", "-r", f"__node:={name}", "-p", f"node.mode:={args.mode}",
            "-p", "node.diagnostics_period:=1.0", "-r", "cloud:=/bench/points",
            "-r", "source_cloud:=/bench/source", "-r", "target_cloud:=/bench/target"]  # fmt: skip
    if method == "deepbbs":
        cmd += ["-p", f"registration.device:={args.device}"]
        if args.threads is not None:
            cmd += ["-p", f"registration.threads:={args.threads}"]
        if args.weights:
            cmd += ["-p", f"registration.weights:={args.weights}"]
    log = tempfile.TemporaryFile("w+")  # not a pipe: a chatty node must never block on a full one
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log, text=True)
    node = rclpy.create_node(f"bench_{method}")
    res = RunResult()
    sent: dict[int, float] = {}  # stamp -> publication time of the source cloud (measured pairs only)
    diags: list[DiagnosticArray] = []

    def on_pose(msg: PoseStamped) -> None:
        t = time.perf_counter()
        s = stamp_to_ns(msg.header.stamp)
        if s in sent:
            res.latencies_ms.append((t - sent.pop(s)) * 1e3)

    pose_sub = node.create_subscription(PoseStamped, f"/{name}/pose", on_pose, 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    topics = ("/bench/points",) if args.mode == "odometry" else ("/bench/target", "/bench/source")
    pubs = [node.create_publisher(PointCloud2, t, qos_profile_sensor_data) for t in topics]
    try:
        deadline = time.monotonic() + args.startup_timeout
        while not (all(p.get_subscription_count() for p in pubs) and pose_sub.get_publisher_count()):
            if proc.poll() is not None or time.monotonic() > deadline:
                res.error = "node exited" if proc.poll() is not None else "node did not come up in time"
                return res
            rclpy.spin_once(node, timeout_sec=0.1)
        n_warm = int(round(args.warmup * args.rate))
        n_total = n_warm + int(round(args.seconds * args.rate))
        order = playback_order(len(msgs), n_total + 1)
        t0 = time.perf_counter()
        for k in range(n_total):
            due = t0 + k / args.rate
            while (now := time.perf_counter()) < due:
                rclpy.spin_once(node, timeout_sec=min(0.005, due - now))
            stamp = STAMP0_NS + k * int(SEC / args.rate)
            src = msgs[order[k + 1]]
            src.header.stamp = ns_to_stamp(stamp)
            if args.mode == "pair":
                tgt = msgs[order[k]]
                tgt.header.stamp = ns_to_stamp(stamp)  # same stamp: the pair is synchronised at once
                pubs[0].publish(tgt)
            measured = k >= n_warm
            if measured:
                res.pairs += 1
                sent[stamp] = time.perf_counter()
            pubs[-1].publish(src)
        end = time.perf_counter() + 3.0
        while time.perf_counter() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
        node.destroy_node()
        if res.error:
            log.seek(0)
            res.error += ": " + log.read().strip()[-3000:]
        log.close()
    ours = [d.status[0] for d in diags if d.status and d.status[0].name.startswith(f"{name}:")]
    if ours:
        res.diagnostics = {kv.key: kv.value for kv in ours[-1].values}
    return res


# -- report ----------------------------------------------------------------------------------------------
def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if b > 0 and np.isfinite(a) and np.isfinite(b) else "-"


def report(layout_desc: str, args, results: dict[str, RunResult]) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console(width=120)
    t = Table(title=f"{layout_desc}\n{args.mode} mode, {args.rate:g} Hz, {args.seconds:g} s measured (after "
                    f"{args.warmup:g} s warm-up); latency = source published -> PoseStamped received")  # fmt: skip
    for c in ("method", "pairs published", "answered", "p50 ms", "p99 ms", "p50 / anchor", "p99 / anchor"):
        t.add_column(c, justify="left" if c == "method" else "right")
    anchor = results.get(ANCHOR)
    for method, r in results.items():
        if r.error:
            t.add_row(method, "-", "-", "-", "-", "-", "-")
            continue
        a50, a99 = (anchor.pct(50), anchor.pct(99)) if anchor and not anchor.error else (np.nan, np.nan)
        t.add_row(method + (" (anchor)" if method == ANCHOR else ""), str(r.pairs), f"{100 * r.answered:.0f} %",
                  f"{r.pct(50):.1f}", f"{r.pct(99):.1f}", _ratio(r.pct(50), a50), _ratio(r.pct(99), a99))  # fmt: skip
    con.print(t)
    for method, r in results.items():
        if r.error:
            con.print(f"[red]{method}: node failed[/red]: {r.error[-2000:]}")
            continue
        d = r.diagnostics
        stages = [k for k in ("input_wait", "decode", "preprocess", "queue_wait", "register", "publish", "total")
                  if f"latency_ms.{k}" in d]  # fmt: skip
        parts = [f"{k} {d[f'latency_ms.{k}'].replace('median ', '').replace(' p99 ', ' / ')}" for k in stages]
        drops = (f"pairs dropped {d.get('pairs dropped (newest wins)', '?')}, clouds dropped before preprocessing "
                 f"{d.get('clouds dropped before preprocessing (oldest first)', '?')}")  # fmt: skip
        con.print(f"  {method} node median / p99 (ms): {', '.join(parts) or 'no diagnostics'}; {drops}")


@cli_entry("bench_node_latency")
def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise DeepBBSError(f"--methods: unknown {unknown or methods}; choose from {', '.join(METHODS)}")
    if args.seconds <= 0 or args.rate <= 0 or args.warmup < 0:
        raise DeepBBSError("--seconds and --rate must be > 0, --warmup >= 0")

    from deepbbs_ros.cli.common import local_ros_env
    from deepbbs_ros.node.dds import apply_default_profile

    local_ros_env()  # loopback and a run-specific domain, inherited by the node processes
    apply_default_profile()
    import rclpy

    layouts = ("velodyne", "ouster") if args.layout == "both" else (args.layout,)
    streams = {layout: make_stream(args, layout) for layout in layouts}
    rclpy.init()
    try:
        for layout in layouts:
            msgs, desc = streams[layout]
            results = {}
            for method in methods:
                print(f"  {layout}: {method} ...", file=sys.stderr)
                results[method] = run_method(args, method, msgs)
            report(desc, args, results)
    finally:
        rclpy.try_shutdown()
    load = os.getloadavg()[0]
    print(f"load average {load:.1f} on {os.cpu_count()} CPUs"
          + (": figures disturbed by other work" if load > 0.5 * (os.cpu_count() or 1) else ""))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
