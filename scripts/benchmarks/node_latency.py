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
import array
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # run from a checkout without installing

from deepbbs_ros.entry import cli_entry  # noqa: E402
from deepbbs_ros.errors import DeepBBSError  # noqa: E402

SEC = 1_000_000_000
STAMP0_NS = 1_000 * SEC
METHODS = {  # name -> (module run with -m, node name = pose topic namespace)
    "deepbbs": ("deepbbs_ros.node.registration_node", "deepbbs_registration"),
    "gicp": ("deepbbs_ros.node.gicp_anchor", "gicp_anchor"),
    "managed": ("deepbbs_ros.node.managed", "deepbbs_localizer"),  # the lifecycle node: configured, then activated
}
ANCHOR = "gicp"
STAGES = ("input_wait", "decode", "preprocess", "queue_wait", "register", "register.preprocess",
          "register.good_start", "register.network_wait", "register.polish", "register.global", "register.crop",
          "register.register", "map_crop", "publish", "total")  # fmt: skip


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


# -- the clouds -----------------------------------------------------------------------------------------
@dataclass
class Stream:
    """Messages and what is published each period: ``pairs[k % len(pairs)]`` = (source, target) indices."""

    msgs: list
    pairs: list[tuple[int, int]]
    desc: str
    map_path: str = ""  # --mode localization: the map file (PCD, trajectory beside it)
    map_msg: Any = None  # ... the same map as a PointCloud2 in the map frame (the anchor's latched target)
    initial_pose: list[float] = field(default_factory=list)  # ... the first published scan's x y z roll pitch yaw


def _lidar(layout: str, ouster_beams: int):
    from deepbbs_ros.sim.lidar import LidarConfig

    if layout == "velodyne":
        return LidarConfig.hdl64()
    if ouster_beams == 128:  # OS1-128: 45 deg vertical field of view
        return LidarConfig.ouster64(beams=128, vfov_min_deg=-22.5, vfov_max_deg=22.5, name="os1-128")
    return LidarConfig.ouster64(name="os1-64")


def playback_order(n_frames: int, n_total: int) -> list[int]:
    """Frame index of every published scan: 0, 1, ..., n-1, n-2, ..., 1, 0, 1, ... (neighbours only)."""
    if n_frames < 2:
        raise DeepBBSError("a stream needs at least 2 frames")
    cycle = list(range(n_frames)) + list(range(n_frames - 2, 0, -1))
    return [cycle[k % len(cycle)] for k in range(n_total)]


FIXED_SOURCES = 4  # --stream fixed: the sources are frames 1..4 (KITTI: 1-6 m from the target)


def stream_pairs(n_frames: int, stream: str) -> list[tuple[int, int]]:
    """(source, target) frame indices per period: consecutive neighbours back and forth; frame 0 as a fixed
    target of frames 1, 2, .., FIXED_SOURCES, .., 2 (back and forth); or the same pair (1, 0) every period."""
    if stream == "same":
        return [(1, 0)]
    if stream == "fixed":
        m = min(FIXED_SOURCES, n_frames - 1)
        return [(1 + i, 0) for i in playback_order(m, max(1, 2 * m - 2))] if m > 1 else [(1, 0)]
    order = playback_order(n_frames, 2 * n_frames - 1)
    return [(order[k + 1], order[k]) for k in range(len(order) - 1)]


def _describe(msgs: list, n_valid: float, sensor: str, layout: str) -> str:
    m = msgs[0]
    return (f"{sensor} ({layout} driver layout, point_step {m.point_step}, {m.height}x{m.width}, "
            f"{n_valid:.0f} valid points, {len(m.data) / 1e6:.1f} MB)")  # fmt: skip


def sim_stream(args, layout: str, stream: str) -> Stream:
    from deepbbs_ros.sim import simulate_drive
    from msg_adapters.layouts import driver_cloud

    lidar = _lidar(layout, args.ouster_beams)
    t0 = time.perf_counter()
    scans = list(simulate_drive(args.scene, args.seed, args.scans, lidar=lidar))
    frame = "velodyne" if layout == "velodyne" else "os_sensor"
    msgs = [driver_cloud(layout, s.points, s.fields, beams=lidar.beams, columns=lidar.columns, frame_id=frame)
            for s in scans]  # fmt: skip
    desc = _describe(msgs, np.mean([len(s.points) for s in scans]), f"simulated {lidar.name}", layout)
    print(f"  simulated {len(scans)} frames of {desc} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    out = Stream(msgs, stream_pairs(len(msgs), stream), desc)
    if args.mode == "localization":
        from deepbbs_ros.sim.simulator import DriveSimulator

        sim = DriveSimulator(args.scene, args.seed, lidar, frames=args.scans, motion_distortion=False)
        keys = list(range(0, args.scans, max(1, args.map_every)))
        add_map(args, out, [s.T_world_lidar for s in scans], [(sim.scan_at(k).points, sim.pose_at(k),
                                                                sim.stamp_ns(k)) for k in keys],
                f"map_{args.scene}_{args.seed}_{args.scans}")
    return out


def add_map(args, stream: Stream, poses: list[np.ndarray], keys: list[tuple[np.ndarray, np.ndarray, int]],
            name: str) -> None:
    """--mode localization: the drive's map (``keys``: (points, true pose, stamp) of every ``--map-every``-th frame,
    simulated ones without motion distortion, on a ``--map-voxel`` grid) as a PCD with its trajectory (without:
    ``--no-trajectory``; under ``--out`` or a temporary folder) and as a PointCloud2 in ``map``; the anchor's initial
    pose = the first published scan's (``poses``: every frame's true pose)."""
    from scipy.spatial.transform import Rotation

    from deepbbs_ros.core.localization import voxel_downsample
    from deepbbs_ros.datasets.maps import write_map
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2

    t0 = time.perf_counter()
    parts = [np.asarray(pts[:, :3], np.float64) @ P[:3, :3].T + P[:3, 3] for pts, P, _ in keys]
    points = voxel_downsample(np.concatenate(parts).astype(np.float32), args.map_voxel)
    folder = args.out if args.out is not None else Path(tempfile.mkdtemp(prefix="deepbbs_map_"))
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}{'_alone' if args.no_trajectory else ''}.pcd"
    write_map(path, points, *((None, None) if args.no_trajectory else
                              (np.stack([P for _, P, _ in keys]), np.array([s for *_, s in keys]))))
    stream.map_path = str(path)
    stream.map_msg = arrays_to_pointcloud2(points, stamp_ns=STAMP0_NS, frame_id="map")
    first = poses[stream.pairs[0][0]]
    rpy = Rotation.from_matrix(first[:3, :3]).as_euler("ZYX")[::-1]
    stream.initial_pose = [*map(float, first[:3, 3]), *map(float, rpy)]
    stream.desc += (f"; map {len(points)} points from {len(keys)} frames"
                    + (", no trajectory" if args.no_trajectory else ", with its trajectory"))
    print(f"  map of {len(points)} points ({len(keys)} frames) in {time.perf_counter() - t0:.1f} s: {path}",
          file=sys.stderr)


def kitti_sequences(path: Path) -> list[Path]:
    """The KITTI sequence folders at ``path``: itself when it holds ``velodyne/``, else its sub-folders that do."""
    path = Path(path).expanduser()
    if (path / "velodyne").is_dir():
        return [path]
    seqs = sorted(p for p in path.iterdir() if (p / "velodyne").is_dir()) if path.is_dir() else []
    if not seqs:
        raise DeepBBSError(f"--kitti {path}: no KITTI sequence folder (velodyne/NNNNNN.bin) there")
    return seqs


def kitti_rings(xyz: np.ndarray) -> np.ndarray:
    """(N,) ring (0 = the last laser of the file) of a KITTI scan: each laser's points sweep the azimuth once
    in file order, so a ring ends where the azimuth wraps around."""
    az = np.mod(np.arctan2(xyz[:, 1], xyz[:, 0]), 2 * np.pi)
    k = np.concatenate(([0], np.cumsum(np.diff(az) < -np.pi)))
    return (k.max() - k).astype(np.uint16)


def kitti_stream(args, layout: str, stream: str, seq: Path) -> Stream:
    """Real HDL-64E scans of one sequence in a driver's layout, with a per-point time field that is all 0
    (KITTI has no per-point time; Ouster: the 64 rings organised, each ring's points in file order)."""
    from deepbbs_ros.datasets import open_source
    from msg_adapters.layouts import driver_cloud

    with open_source(seq) as src:
        scans = list(src)
    msgs = []
    for s in scans:
        xyz = np.ascontiguousarray(s.points, dtype=np.float32)
        ring = kitti_rings(xyz)
        n = len(xyz)
        fields = {"intensity": np.asarray(s.fields["intensity"], np.float32), "ring": ring,
                  "time": np.zeros(n, np.float32)}  # fmt: skip
        if layout == "ouster":
            order = np.argsort(ring, kind="stable")
            starts = np.searchsorted(ring[order], np.arange(int(ring.max()) + 1))
            column = np.empty(n, np.int64)
            column[order] = np.arange(n) - np.repeat(starts, np.diff(np.append(starts, n)))
            fields["column"] = column
        msgs.append((xyz, fields))
    beams = int(max(f["ring"].max() for _, f in msgs)) + 1
    columns = int(max(f.get("column", np.zeros(1, np.int64)).max() for _, f in msgs)) + 1
    frame = "velodyne" if layout == "velodyne" else "os_sensor"
    out = [driver_cloud(layout, xyz, f, beams=beams, columns=columns, frame_id=frame) for xyz, f in msgs]
    desc = _describe(out, np.mean([len(x) for x, _ in msgs]), f"KITTI {seq.name} HDL-64E, time field 0", layout)
    res = Stream(out, stream_pairs(len(out), stream), desc)
    if getattr(args, "mode", "") == "localization":
        keys = range(0, len(scans), max(1, args.map_every))
        add_map(args, res, [s.T_world_lidar for s in scans],
                [(scans[k].points, scans[k].T_world_lidar, scans[k].stamp_ns) for k in keys], f"map_kitti_{seq.name}")
    return res


class FreshSources:
    """Makes a replayed frame a new scan: a real sensor never sends the same cloud twice, and the node keeps its
    recent clouds' preprocessing by content (a fixed target, or the previous source as the next target: both
    real). The stream has only a few frames, played back and forth, so without this the node would find a
    source it saw a few periods earlier in its cache (2 of 3 periods of the fixed stream) and skip its work.
    :meth:`apply` moves one point of the message (a return more than 2 m away) by ``(k % 1000) * 10 um`` along
    x, in place: different bytes every period, the same cloud to within 1 cm at one of ~120k points. The frame
    keeps its last content until it is published again, so when it is the next period's target it is the
    cloud the node just saw (the cache hit a real stream gets)."""

    def __init__(self) -> None:
        self._where: dict[int, tuple[int, float]] = {}  # id(msg) -> (byte offset of the point's x, its x)

    def _find(self, msg) -> tuple[int, float]:
        off = {f.name: f.offset for f in msg.fields}
        step = msg.point_step
        n = msg.width * msg.height
        xyz = np.stack([np.ndarray((n,), dtype="<f4", buffer=msg.data, offset=off[c], strides=(step,)) for c in "xyz"],
                       axis=1)
        i = int(np.flatnonzero(np.isfinite(xyz).all(axis=1) & (np.linalg.norm(xyz, axis=1) > 2.0))[0])
        return i * step + off["x"], float(xyz[i, 0])

    def apply(self, msg, k: int) -> None:
        key = id(msg)
        if key not in self._where:
            self._where[key] = self._find(msg)
        at, x0 = self._where[key]
        msg.data[at:at + 4] = array.array("B", np.float32(x0 + (k % 1000) * 1e-5).tobytes())


# -- one run ---------------------------------------------------------------------------------------------
@dataclass
class RunResult:
    pairs: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    periods: list[int] = field(default_factory=list)  # the measured period of each answer (0 = the first measured)
    frames: list[tuple[int, int]] = field(default_factory=list)  # its (source, target) frames (odometry: (k, k))
    diagnostics: dict[str, str] = field(default_factory=dict)
    error: str = ""
    cpu: str = ""  # CPU ms per period per thread group (cpu_line)
    cpu_ms: float = float("nan")  # CPU ms per period, every process of the node together (cpu_total)
    first_pose_s: float = float("nan")  # localization: first scan published -> first pose received (s)
    after_first: tuple[int, int] = (0, 0)  # localization: scans published after the first pose: (answered, all)
    ready_s: float = float("nan")  # node process started -> its input subscribed (plain node: map built; managed:
    #: the configure and activate transitions requested as soon as its services answer)
    configure_s: float = float("nan")  # managed node: the configure transition (the map and the model loaded)
    activate_s: float = float("nan")  # managed node: the activate transition (subscribed)
    published: dict[int, float] = field(default_factory=dict)  # localization: every stamp -> s after the first scan
    poses: dict[int, float] = field(default_factory=dict)  # localization: answered stamp -> s after the first scan
    xyz: dict[int, tuple[float, float, float]] = field(default_factory=dict)  # answered stamp -> the pose's position

    @property
    def answered(self) -> float:
        return len(self.latencies_ms) / self.pairs if self.pairs else 0.0

    def pct(self, q: float) -> float:
        return float(np.percentile(self.latencies_ms, q)) if self.latencies_ms else float("nan")


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


# -- report ----------------------------------------------------------------------------------------------
def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if b > 0 and np.isfinite(a) and np.isfinite(b) else "-"


def stage_line(d: dict[str, str]) -> str:
    """The node's median / p99 per stage and its drop counters, from its last /diagnostics message."""
    stages = [k for k in STAGES if f"latency_ms.{k}" in d]
    parts = [f"{k} {d[f'latency_ms.{k}'].replace('median ', '').replace(' p99 ', ' / ').split(' max')[0]}"
             for k in stages]  # fmt: skip
    drops = (f"pairs dropped {d.get('pairs dropped (newest wins)', '?')}, clouds dropped before preprocessing "
             f"{d.get('clouds dropped before preprocessing (oldest first)', '?')}, preprocessing cache hits / "
             f"misses {d.get('preprocessing cache hits / misses', '?')}, poses the verdict rejected "
             f"{d.get('poses not published (the verdict rejected them)', '?')}")  # fmt: skip
    paths = [f"{k.removeprefix('paths.')} {v}" for k, v in d.items() if k.startswith("paths.")]
    if paths:  # pair mode: which registration path answered (GICP from the good start, the deep passes, the search)
        drops += f"; paths: {', '.join(paths)}"
    return f"median / p99 ms: {', '.join(parts) or 'no diagnostics'}; {drops}"


def save_runs(out: Path, layout: str, stream: str, runs: list[tuple[str, bool, dict[str, RunResult]]]) -> list[dict]:
    """Append each (run, node) of one configuration to ``out``/runs.jsonl; -> the records."""
    recs = []
    for label, busy, results in runs:
        for method, r in results.items():
            recs.append({
                "layout": layout, "stream": stream, "run": label, "busy": busy, "method": method,
                "pairs": r.pairs, "answered": r.answered, "p50_ms": r.pct(50), "p99_ms": r.pct(99),
                "error": r.error, "cpu": r.cpu,
                "cpu_ms": round(r.cpu_ms, 2) if np.isfinite(r.cpu_ms) else None, "diagnostics": r.diagnostics,
                "first_pose_s": r.first_pose_s if np.isfinite(r.first_pose_s) else None,
                "answered_after_first_pose": list(r.after_first),
                "samples": [{"period": k, "source": f[0], "target": f[1], "latency_ms": round(v, 2)}
                            for k, v, f in zip(r.periods, r.latencies_ms, r.frames)],
            })  # fmt: skip
    with (out / "runs.jsonl").open("a") as f:
        for rec in recs:
            f.write(json.dumps(rec, default=float) + "\n")
    return recs


def plot_runs(args, recs: list[dict]) -> Path | str:
    """``args.out``/latency.png: per configuration (layout, stream), each run's latency per measured period
    (left) and its sorted latencies (right: the share of pairs answered within a time), the goal's p99 line
    drawn in; -> the path, or why there is none."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "none (matplotlib is not installed)"
    configs = sorted({(r["layout"], r["stream"]) for r in recs})
    fig, axes = plt.subplots(len(configs), 2, figsize=(13, 3.2 * len(configs)), squeeze=False)
    for row, (layout, stream) in zip(axes, configs):
        for r in (r for r in recs if (r["layout"], r["stream"]) == (layout, stream) and r["samples"]):
            k = [s["period"] for s in r["samples"]]
            v = np.array([s["latency_ms"] for s in r["samples"]])
            name = f"{r['method']} {r['run']}"
            style = "--" if r["method"] == ANCHOR else "-"
            row[0].plot(k, v, style, lw=0.8, label=name)
            share = np.arange(1, len(v) + 1) / max(r["pairs"], 1)  # of the pairs published: drops stay below 1
            row[1].plot(np.sort(v), share, style, lw=1.0, label=f"{name} ({100 * r['answered']:.0f} %)")
        for ax in row:
            ax.grid(alpha=0.3)
        row[0].axhline(args.goal_p99, color="k", lw=0.8, ls=":")
        row[1].axvline(args.goal_p99, color="k", lw=0.8, ls=":")
        row[0].set(title=f"{layout}, {stream}: latency per period", xlabel="measured period", ylabel="ms")
        row[1].set(title=f"{layout}, {stream}: share of pairs answered within", xlabel="ms", ylabel="share",
                   ylim=(0, 1.02))
        row[1].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    path = args.out / "latency.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


@dataclass
class Judged:
    label: str
    busy: bool
    result: RunResult

    def failures(self, args) -> list[str]:
        r = self.result
        if r.error:
            return ["node failed"]
        p50, p99, ans = r.pct(50), r.pct(99), 100 * r.answered
        need_ans, need_p99 = (args.busy_answered, args.busy_p99) if self.busy else (args.goal_answered, args.goal_p99)
        out = []
        if ans < need_ans:
            out.append(f"answered {ans:.0f} % < {need_ans:g} %")
        if not p99 <= need_p99:
            out.append(f"p99 {p99:.0f} ms > {need_p99:g} ms")
        if not self.busy and not p99 <= args.goal_ratio * p50:
            out.append(f"p99 / p50 {p99 / p50:.2f} > {args.goal_ratio:g}")
        return out


def report(title: str, args, runs: list[tuple[str, bool, dict[str, RunResult]]]) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console(width=160)
    t = Table(title=f"{title}\n{args.mode} mode, {args.rate:g} Hz, {args.seconds:g} s measured per run (after "
                    f"{args.warmup:g} s warm-up); latency = source published -> PoseStamped received")  # fmt: skip
    for c in ("run", "method", "pairs", "answered", "p50 ms", "p99 ms", "p99 / p50", "p50 / anchor",
              "p99 / anchor", "CPU ms", "CPU / anchor"):  # fmt: skip
        t.add_column(c, justify="left" if c in ("run", "method") else "right")
    for label, _, results in runs:
        anchor = results.get(ANCHOR)
        ok = anchor and not anchor.error
        a50, a99, acpu = (anchor.pct(50), anchor.pct(99), anchor.cpu_ms) if ok else (np.nan, np.nan, np.nan)
        for method, r in results.items():
            if r.error:
                t.add_row(label, method, "-", "failed", "-", "-", "-", "-", "-", "-", "-")
                continue
            t.add_row(label, method + (" (anchor)" if method == ANCHOR else ""), str(r.pairs),
                      f"{100 * r.answered:.0f} %", f"{r.pct(50):.1f}", f"{r.pct(99):.1f}",
                      _ratio(r.pct(99), r.pct(50)), _ratio(r.pct(50), a50), _ratio(r.pct(99), a99),
                      f"{r.cpu_ms:.1f}", _ratio(r.cpu_ms, acpu))  # fmt: skip
    con.print(t)
    for label, _, results in runs:
        for method, r in results.items():
            if r.error:
                con.print(f"[red]{label} {method}: node failed[/red]: {r.error[-2000:]}")
            else:
                con.print(f"  {label} {method}: {stage_line(r.diagnostics)}", soft_wrap=True)
                if args.mode == "localization" and method != ANCHOR:
                    n, m, d = *r.after_first, r.diagnostics
                    con.print(f"  {label} {method}: boot: first pose {r.first_pose_s:.2f} s after the first scan; "
                              f"scans published after it answered: {n} of {m} ({100 * n / max(m, 1):.1f} %); "
                              f"followed after the search {d.get('localization.scans followed after a search', '-')}, "
                              f"dropped unanswered {d.get('localization.scans dropped unanswered', '-')}",
                              soft_wrap=True)
                if r.cpu:
                    con.print(f"  {label} {method}: {r.cpu}", soft_wrap=True)


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
