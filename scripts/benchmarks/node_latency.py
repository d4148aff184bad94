#!/usr/bin/env python3
"""Latency of the live node against a GICP anchor: real driver layouts streamed at a fixed rate.

Figures (``runs.jsonl`` and ``latency.png`` under ``--out``): per run and node, the share of pairs answered and
the p50 / p99 latency from publication to PoseStamped of the DeepBBS++ node and, in the same run on the same
clouds, of the GICP anchor node ``deepbbs_ros.node.gicp_anchor`` (small_gicp GICP), with the ratio of the two,
the node's stage breakdown and CPU, and a pass / fail line against the goal.

Clouds (``--data``):

* ``sim`` (default): the simulator (:func:`deepbbs_ros.sim.simulate_drive`) drives ``--scans`` frames through
  an urban scene with the sensor model of the layout (raw sweeps with per-point times);
* ``kitti``: real HDL-64E scans of the KITTI odometry sequences under ``--kitti`` (a sequence folder, or a
  folder of them; read at run time, ~120k points, not motion-compensated, no per-point time: the time
  field is written as 0, as a driver without timing does). Run ``r`` streams sequence ``r mod n``.

Every frame is encoded in the field layout its real driver publishes (:mod:`msg_adapters.layouts`):

* ``velodyne``: ``velodyne_pointcloud`` PointXYZIRT (packed, point_step 22, unorganised, firing order);
* ``ouster``: ouster-ros PointOS (point_step 48, organised ``beams x columns`` with zeros where no return
  came back; simulated OS1-128 / OS1-64 (``--ouster-beams``), or the KITTI scans' 64 rings).

This process publishes the frames at ``--rate`` Hz to a node running in its own process, first
``deepbbs-node`` (DeepBBS++), then the GICP anchor ``python -m deepbbs_ros.node.gicp_anchor`` (small_gicp
GICP, the same node plumbing and topics), one node start per run, and times every PoseStamped against the
wall time at which its source cloud was published (same host, same clock). ``--mode odometry``: one
input, consecutive scans; deepbbs-node runs its local-map odometry, the anchor chains GICP scan k against
scan k-1. ``--mode pair``: two inputs, both stamped alike, ``--stream``:

* ``consecutive``: scan k on ``source_cloud`` and scan k-1 on ``target_cloud`` (frames played forwards
  then backwards, so that consecutive scans are always neighbours);
* ``fixed``: a fixed target cloud (a map, a reference scan: frame 0 every period) for sources that move
  (frames 1 to 4 and back);
* ``same``: the same pair every period.

``--mode localization``: one input, consecutive scans, and a prior map of the same drive (``--data sim``: the frames
without motion distortion at their ground-truth poses, every ``--map-every``-th, voxelised, written as a PCD with
its trajectory beside it): deepbbs-node runs ``node.target_mode: localization`` on the map file (no initial pose: the
whole map is searched, within the warm-up, then the scans are tracked); the anchor runs ``node.target_mode:
latched`` on the same map, published once on a latched topic, from ``node.initial_pose`` = the first scan's true
pose, each scan registered by GICP on the map's crop from the last answer. The node's map crop refresh is in its
stage breakdown (``register.crop``; the anchor's ``map_crop``). With ``--data kitti`` the map is the sequence's
every ``--map-every``-th scan at its ground-truth pose (the real scans: not motion-compensated). ``--no-trajectory``
writes the map alone (a map from another tool: the node searches the places of its drivable space). Localization runs
also print the node's boot: the time from the first scan published to the first pose received (the whole map searched
while the scans keep coming at ``--rate``; set ``--warmup`` longer than that so that the measured periods are
tracking) and the share of the scans published after that first pose that were answered.

``--runs N`` repeats every configuration (a fresh node each run); ``--busy-runs M`` adds M runs with one
CPU-bound background process on the machine. Every run prints the pairs published (after ``--warmup``
seconds), the share answered, p50 / p99 latency, p99 / p50, the ratios of p50, p99 and CPU per period (the
node's processes together) to the anchor's of the same run, and the node's own stage breakdown (from
/diagnostics; in pair mode also which registration path answered: ``gicp`` from the good start, ``deepbbs``,
``search``); the last lines judge the DeepBBS++ node against the
goal (``--goal-*``, ``--busy-*``). ``--out DIR`` also keeps every run: ``runs.jsonl`` (one line per run and
node: its summary, the node's stage breakdown and CPU, and every answered pair's latency with its period and
frames), ``node_<method>.log`` (the last run's log of each node) and ``latency.png`` (each run's latency per period
and its distribution, the goal's lines drawn in), to see
whether a tail is a few stalls or a drift. DDS stays on loopback in a run-specific domain. Quick check (a minute):

    python scripts/benchmarks/node_latency.py --seconds 5 --layout both --mode odometry

The real-scan pair-mode goal (about 25 minutes):

    python scripts/benchmarks/node_latency.py --data kitti --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 \\
        --mode pair --stream both --layout both --runs 5 --busy-runs 1
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # run from a checkout without installing
sys.path.insert(0, str(Path(__file__).resolve().parent))  # its parts: _node_streams.py, _node_report.py

from _node_report import ANCHOR, Judged, RunResult, plot_runs, report, save_runs  # noqa: E402
from _node_streams import (  # noqa: E402 - kitti_rings, stream_pairs: the tests reach them here
    SEC,
    STAMP0_NS,
    FreshSources,
    Stream,
    kitti_rings,  # noqa: F401
    kitti_sequences,
    kitti_stream,
    sim_stream,
    stream_pairs,  # noqa: F401
)

from deepbbs_ros.entry import cli_entry  # noqa: E402
from deepbbs_ros.errors import DeepBBSError  # noqa: E402

METHODS = {  # name -> (module run with -m, node name = pose topic namespace)
    "deepbbs": ("deepbbs_ros.node.registration_node", "deepbbs_registration"),
    "gicp": ("deepbbs_ros.node.gicp_anchor", "gicp_anchor"),
    "managed": ("deepbbs_ros.node.managed", "deepbbs_localizer"),  # the lifecycle node: configured, then activated
}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = p.add_argument_group("clouds")
    g.add_argument("--data", choices=("sim", "kitti"), default="sim", help="simulated or real (KITTI) scans")
    g.add_argument("--kitti", type=Path, nargs="+", default=None,
                   help="KITTI sequence folders, or folders of them (needed with --data kitti)")
    g.add_argument("--layout", choices=("velodyne", "ouster", "both"), default="both", help="driver layout(s)")
    g.add_argument("--ouster-beams", type=int, choices=(64, 128), default=128, help="simulated OS1-64 or OS1-128")
    g.add_argument("--scans", type=int, default=20, help="distinct simulated frames (played back and forth)")
    g.add_argument("--scene", default="urban", help="simulator scene")
    g.add_argument("--seed", type=int, default=5, help="simulator seed")
    g = p.add_argument_group("stream")
    g.add_argument("--mode", choices=("pair", "odometry", "localization"), default="odometry",
                   help="node mode; localization: tracking in a prior map of the drive (the anchor: a latched map)")
    g.add_argument("--map-every", type=int, default=2, help="localization: every k-th frame goes into the map")
    g.add_argument("--map-voxel", type=float, default=0.2, help="localization: the map's voxel grid (m)")
    g.add_argument("--no-trajectory", action="store_true",
                   help="localization: the map file without its trajectory (the node's places from the map alone)")
    g.add_argument("--stream", choices=("consecutive", "fixed", "same", "both"), default="consecutive",
                   help="pair mode: consecutive scans; a fixed target (frame 0) for frames 1-4; the same pair every "
                        "period; both = consecutive and fixed")
    g.add_argument("--seconds", type=float, default=10.0, help="measured streaming time per run (s)")
    g.add_argument("--warmup", type=float, default=2.0, help="streaming time before the measurement (s)")
    g.add_argument("--rate", type=float, default=10.0, help="scan rate (Hz)")
    g.add_argument("--repeat-sources", action="store_true",
                   help="publish a source frame seen before byte for byte (default: each period's source differs from "
                        "every earlier one in one point by at most 1 cm, as a sensor's scans do: a node that caches "
                        "by content must not find it again)")
    g.add_argument("--runs", type=int, default=1, help="runs per configuration, a fresh node each")
    g.add_argument("--busy-runs", type=int, default=0,
                   help="further runs per configuration with one CPU-bound background process")
    g = p.add_argument_group("nodes")
    g.add_argument("--methods", default="deepbbs,gicp", help="comma-separated: deepbbs, gicp (the anchor)")
    g.add_argument("--weights", default="", help="DeepBBS++ checkpoint (default: the shipped model)")
    g.add_argument("--device", default="auto", help="auto | cpu | cuda")
    g.add_argument("--threads", type=int, default=None,
                   help="registration.threads of the node (torch threads of the network; default: the config's)")
    g.add_argument("--config", help="config YAML for both nodes")
    g.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                   help="a ROS parameter for the DeepBBS++ node (repeatable)")
    g.add_argument("--startup-timeout", type=float, default=120.0, help="s to wait for a node to come up")
    g = p.add_argument_group("goal (the DeepBBS++ node, every run)")
    g.add_argument("--goal-answered", type=float, default=99.0, help="%% of pairs answered, at least")
    g.add_argument("--goal-p99", type=float, default=150.0, help="p99 latency (ms), at most")
    g.add_argument("--goal-ratio", type=float, default=1.5, help="p99 / p50, at most")
    g.add_argument("--busy-answered", type=float, default=95.0, help="busy runs: %% answered, at least")
    g.add_argument("--busy-p99", type=float, default=250.0, help="busy runs: p99 latency (ms), at most")
    p.add_argument("--out", type=Path, help="folder for runs.jsonl (every run, every pair's latency) and latency.png")
    return p


# -- one run ---------------------------------------------------------------------------------------------
def _descendants(pid: int) -> list[int]:
    """``pid`` and every process below it (Linux /proc)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                todo += [int(c) for c in (task / "children").read_text().split()]
            except OSError:
                pass
    return out


def cpu_snapshot(pid: int) -> dict[str, float]:
    """CPU seconds (user + system) of every thread of ``pid`` and its child processes, summed per
    ``"process: thread name"`` (the node names its worker threads; unnamed threads are the executor's, DDS's
    and OpenMP's). Empty where /proc is not there."""
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    out: dict[str, float] = {}
    for i, p in enumerate(_descendants(pid)):
        proc = "node" if i == 0 else "child"
        try:
            cmdline = Path(f"/proc/{p}/cmdline").read_text()
            if "deepbbs_ros.core.network_process" in cmdline:
                proc = "network process"
            elif "deepbbs_ros.node.registration_process" in cmdline:  # node.registration_process
                proc = "registration process"
        except OSError:
            continue
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                name = (task / "comm").read_text().strip()
                fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            name = name if name.startswith(("input", "registration")) else "other"
            key = f"{proc}: {name}"
            out[key] = out.get(key, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return out


def cpu_total(before: dict[str, float], after: dict[str, float], periods: int) -> float:
    """CPU ms per period of the node and its child processes between two :func:`cpu_snapshot` s (nan: none)."""
    if not before or not after or periods <= 0:
        return float("nan")
    return sum(after.get(k, 0.0) - before.get(k, 0.0) for k in after) * 1e3 / periods


def cpu_line(before: dict[str, float], after: dict[str, float], periods: int) -> str:
    """CPU ms per period per thread group between two :func:`cpu_snapshot` s."""
    if not before or not after or periods <= 0:
        return ""
    d = {k: (after.get(k, 0.0) - before.get(k, 0.0)) * 1e3 / periods for k in after}
    parts = [f"{k} {v:.1f}" for k, v in sorted(d.items(), key=lambda kv: -kv[1]) if v >= 0.05]
    return f"CPU ms per period: {', '.join(parts)}; total {sum(d.values()):.1f}"


def _busy_process() -> subprocess.Popen:
    """One CPU-bound process (a Python busy loop) until killed."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)  # fmt: skip


class _Lifecycle:
    """Plays nav2_lifecycle_manager for the managed node: configure once its services answer, then activate, each
    transition timed (:meth:`step`, called while waiting for the node to come up)."""

    def __init__(self, node, name: str) -> None:
        from lifecycle_msgs.srv import ChangeState

        self.client = node.create_client(ChangeState, f"/{name}/change_state")
        self.todo = ["configure", "activate"]
        self.future, self.t0 = None, 0.0

    def step(self, res: RunResult) -> bool:
        """Request the next transition, or time the one that answered; False when one failed."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        if self.future is not None and self.future.done():
            ok = bool(self.future.result() and self.future.result().success)
            took = time.perf_counter() - self.t0
            if self.todo.pop(0) == "configure":
                res.configure_s = took
            else:
                res.activate_s = took
            self.future = None
            if not ok:
                return False
        if self.future is None and self.todo and self.client.service_is_ready():
            tid = Transition.TRANSITION_CONFIGURE if self.todo[0] == "configure" else Transition.TRANSITION_ACTIVATE
            self.t0 = time.perf_counter()
            self.future = self.client.call_async(ChangeState.Request(transition=Transition(id=tid)))
        return True


def run_method(args, method: str, stream: Stream) -> RunResult:
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
    localization = args.mode == "localization"
    cmd += ["--ros-args", "-r", f"__node:={name}", "-p", f"node.mode:={'pair' if localization else args.mode}",
            "-p", "node.diagnostics_period:=1.0", "-r", "cloud:=/bench/points",
            "-r", "source_cloud:=/bench/source", "-r", "target_cloud:=/bench/target"]  # fmt: skip
    map_pub = None
    if localization and method == ANCHOR:  # the anchor tracks the same map, latched, from the first true pose
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        map_node = rclpy.create_node(f"bench_map_{method}")
        map_pub = map_node.create_publisher(PointCloud2, "/bench/target", latched)
        map_pub.publish(stream.map_msg)
        cmd += ["-p", "node.target_mode:=latched", "-p", f"node.initial_pose:={stream.initial_pose}"]
    elif localization:
        cmd += ["-p", "node.target_mode:=localization", "-p", f"localization.map_path:={stream.map_path}",
                # no robot here (no /tf_static mounting, no odometry on /tf): the scan's own pose, as the anchor's,
                # without the first scan's wait for transforms that never come
                "-p", "node.localization_odom:=none", "-p", "node.base_frame:=''"]
    if method != ANCHOR:
        cmd += ["-p", f"registration.device:={args.device}"]
        if args.threads is not None:
            cmd += ["-p", f"registration.threads:={args.threads}"]
        if args.weights:
            cmd += ["-p", f"registration.weights:={args.weights}"]
        for p in args.param:
            cmd += ["-p", p]
    # not a pipe: a chatty node must never block on a full one; kept under --out (the last run's of each node)
    log = (args.out / f"node_{method}.log").open("w+") if args.out is not None else tempfile.TemporaryFile("w+")
    t_start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log, text=True)
    node = rclpy.create_node(f"bench_{method}")
    res = RunResult()
    lifecycle = _Lifecycle(node, name) if method == "managed" else None
    sent: dict[int, float] = {}  # stamp -> publication time of the source cloud (measured pairs only)
    diags: list[DiagnosticArray] = []
    boot: dict[int, float] = {}  # localization: every stamp -> its publication time
    answered: set[int] = set()
    first: list[float] = []  # the first pose's arrival

    def on_pose(msg: PoseStamped) -> None:
        t = time.perf_counter()
        s = stamp_to_ns(msg.header.stamp)
        answered.add(s)
        res.poses.setdefault(s, t)
        res.xyz.setdefault(s, (msg.pose.position.x, msg.pose.position.y, msg.pose.position.z))
        if not first:
            first.append(t)
        if s in sent:
            res.latencies_ms.append((t - sent.pop(s)) * 1e3)
            k = (s - STAMP0_NS) // int(SEC / args.rate)
            res.periods.append(k - n_warm)
            res.frames.append(tuple(pairs[k % len(pairs)]))

    pose_sub = node.create_subscription(PoseStamped, f"/{name}/pose", on_pose, 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    topics = {"odometry": ("/bench/points",), "localization": ("/bench/source",)}.get(
        args.mode, ("/bench/target", "/bench/source"))
    pubs = [node.create_publisher(PointCloud2, t, qos_profile_sensor_data) for t in topics]
    msgs, pairs = stream.msgs, stream.pairs
    n_warm = int(round(args.warmup * args.rate))
    fresh = FreshSources()
    try:
        deadline = time.monotonic() + args.startup_timeout
        while not (all(p.get_subscription_count() for p in pubs) and pose_sub.get_publisher_count()):
            if proc.poll() is not None or time.monotonic() > deadline:
                res.error = "node exited" if proc.poll() is not None else "node did not come up in time"
                return res
            if lifecycle is not None and not lifecycle.step(res):
                res.error = "a lifecycle transition failed"
                return res
            rclpy.spin_once(node, timeout_sec=0.1)
        res.ready_s = time.perf_counter() - t_start
        while lifecycle is not None and lifecycle.future is not None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)  # subscribed: the activate transition's answer (timed) is next
            lifecycle.step(res)
        n_total = n_warm + int(round(args.seconds * args.rate))
        t0 = time.perf_counter()
        cpu0, cpu_self0 = {}, 0.0
        for k in range(n_total):
            # a bag played slower (node_boot.py --play): the stamps keep the sensor's rate, the wall clock slows
            due = t0 + k / (args.rate * getattr(args, "play", 1.0))
            while (now := time.perf_counter()) < due:
                rclpy.spin_once(node, timeout_sec=due - now)  # returns on a pose (timed at once) or when due
            stamp = STAMP0_NS + k * int(SEC / args.rate)
            i_src, i_tgt = pairs[k % len(pairs)]
            src = msgs[i_src]
            src.header.stamp = ns_to_stamp(stamp)
            if not args.repeat_sources:
                fresh.apply(src, k)
            if args.mode == "pair":
                tgt = msgs[i_tgt]
                tgt.header.stamp = ns_to_stamp(stamp)  # same stamp: the pair is synchronised at once
                pubs[0].publish(tgt)
            measured = k >= n_warm
            if k == n_warm:
                cpu0, cpu_self0 = cpu_snapshot(proc.pid), time.process_time()
            if measured:
                res.pairs += 1
                sent[stamp] = time.perf_counter()
            boot[stamp] = time.perf_counter()
            pubs[-1].publish(src)
        end = time.perf_counter() + 3.0
        while time.perf_counter() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        periods = n_total - n_warm
        if first and localization:
            res.first_pose_s = first[0] - min(boot.values())
            after = [s for s, t in boot.items() if t > first[0]]
            res.after_first = (sum(s in answered for s in after), len(after))
        if localization and boot:
            t_first = min(boot.values())
            res.published = {s: t - t_first for s, t in boot.items()}
            res.poses = {s: t - t_first for s, t in res.poses.items()}
        cpu1 = cpu_snapshot(proc.pid)
        res.cpu, res.cpu_ms = cpu_line(cpu0, cpu1, periods), cpu_total(cpu0, cpu1, periods)
        if res.cpu:
            res.cpu += f"; this publisher {(time.process_time() - cpu_self0) * 1e3 / max(periods, 1):.1f}"
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
        node.destroy_node()
        if map_pub is not None:
            map_node.destroy_node()
        if res.error:
            log.seek(0)
            res.error += ": " + log.read().strip()[-3000:]
        log.close()
    ours = [d.status[0] for d in diags if d.status and d.status[0].name.startswith(f"{name}:")]
    if ours:
        res.diagnostics = {kv.key: kv.value for kv in ours[-1].values}
    return res


@cli_entry("node_latency")
def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise DeepBBSError(f"--methods: unknown {unknown or methods}; choose from {', '.join(METHODS)}")
    if args.seconds <= 0 or args.rate <= 0 or args.warmup < 0:
        raise DeepBBSError("--seconds and --rate must be > 0, --warmup >= 0")
    if args.runs < 0 or args.busy_runs < 0 or args.runs + args.busy_runs == 0:
        raise DeepBBSError("--runs and --busy-runs must be >= 0, one of them > 0")
    if args.mode in ("odometry", "localization") and args.stream != "consecutive":
        raise DeepBBSError(f"--stream {args.stream} is a pair-mode stream (odometry mode takes consecutive scans)")
    if args.data == "kitti" and args.kitti is None:
        raise DeepBBSError("--data kitti needs --kitti PATH (a KITTI sequence folder, or a folder of them)")
    seqs = [s for k in args.kitti for s in kitti_sequences(k)] if args.data == "kitti" else []

    from deepbbs_ros.cli.common import local_ros_env
    from deepbbs_ros.node.dds import apply_default_profile

    local_ros_env()  # loopback and a run-specific domain, inherited by the node processes
    apply_default_profile()
    import rclpy

    layouts = ("velodyne", "ouster") if args.layout == "both" else (args.layout,)
    streams = ("consecutive", "fixed") if args.stream == "both" else (args.stream,)
    plan = [False] * args.runs + [True] * args.busy_runs
    judged: list[Judged] = []
    kept: list[dict] = []
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "runs.jsonl").write_text("")  # this command's runs only
    rclpy.init()
    try:
        for layout in layouts:
            for kind in streams:
                runs = []
                sim = sim_stream(args, layout, kind) if args.data == "sim" else None
                for i, busy in enumerate(plan):
                    st = sim or kitti_stream(args, layout, kind, seqs[i % len(seqs)])
                    label = f"{i + 1}{' busy' if busy else ''}" + ("" if sim else f" ({seqs[i % len(seqs)].name})")
                    results = {}
                    hog = _busy_process() if busy else None
                    try:
                        for method in methods:
                            print(f"  {layout} {kind} run {label}: {method} ...", file=sys.stderr)
                            results[method] = run_method(args, method, st)
                    finally:
                        if hog is not None:
                            hog.kill()
                            hog.wait()
                    runs.append((label, busy, results))
                    if "deepbbs" in results:
                        judged.append(Judged(f"{layout} {kind} run {label}", busy, results["deepbbs"]))
                desc = (sim or kitti_stream(args, layout, kind, seqs[0])).desc
                report(f"{desc}, {kind} {'pairs' if args.mode == 'pair' else 'scans'}", args, runs)
                if args.out is not None:
                    kept += save_runs(args.out, layout, kind, runs)
    finally:
        rclpy.try_shutdown()
    if args.out is not None and kept:
        print(f"runs: {args.out / 'runs.jsonl'}; plot: {plot_runs(args, kept)}")
    load = os.getloadavg()[0]
    print(f"load average {load:.1f} on {os.cpu_count()} CPUs"
          + (": figures disturbed by other work" if load > 0.5 * (os.cpu_count() or 1) else ""))  # fmt: skip
    if judged and args.mode == "pair":  # the goal is pair mode's
        bad = [(j, f) for j in judged if (f := j.failures(args))]
        print(f"goal: DeepBBS++ >= {args.goal_answered:g} % answered, p99 <= {args.goal_p99:g} ms and <= "
              f"{args.goal_ratio:g} x p50 in every run (busy runs: >= {args.busy_answered:g} %, p99 <= "
              f"{args.busy_p99:g} ms): {'PASS' if not bad else 'FAIL'} ({len(judged) - len(bad)} of {len(judged)} "
              "runs)")  # fmt: skip
        for j, f in bad:
            print(f"  {j.label}: {'; '.join(f)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
