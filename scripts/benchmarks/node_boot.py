#!/usr/bin/env python3
"""A robot boots anywhere in a map without its trajectory: the live node's time to its first pose and to tracking.

The map: the localization benchmark's simulated 1 km map of ``--scene`` (``localization.py``'s cache under
``--cache``, built there once when missing: a few minutes), written as a ``.pcd`` alone (no trajectory: the node's
candidate places come from the map). Each of ``--starts`` runs drives another day's car through the same world from
a random place of the map (seeded, ``--seed``; odd starts in the next lane), raw HDL-64E sweeps with per-point times
in the Velodyne driver's layout, published at ``--rate`` Hz for ``--warmup`` + ``--seconds`` s from the first scan.
``--kitti``: real KITTI sequences instead, the map of every second scan (``node_latency.py --data kitti``'s stream).

Nodes (``--nodes``), each in its own process, one start after the other: ``deepbbs`` (``deepbbs-node``,
``node.target_mode: localization``, no initial pose: the whole map searched while the scans keep coming),
``managed`` (the lifecycle node ``deepbbs-localizer``: configure, which loads the map and the model, then activate;
on the first ``--managed-runs`` starts) and the GICP anchor ``gicp`` (the same map latched, from the first scan's
true pose). Per run and node: the map's load (plain node: process start to its input subscribed, the map built in
``map build``; managed: the configure and activate transitions, before the first scan), the first pose after the
first scan and its error, the time to steady tracking (the answer of the first scan answered within
:data:`LIVE_S` s of its publication and followed by an answer to every later scan), the scans published after the
first pose that were answered, the drops the node counted (/diagnostics), and the tracking CPU per scan (the node's
processes, over the ``--seconds`` after the warm-up) against the anchor's. One JSON line per run and node under
``--out`` (``boot.jsonl``).

    python scripts/benchmarks/node_boot.py --scene urban --starts 5 --cache ~/.cache/deepbbs_ros/bench
    python scripts/benchmarks/node_boot.py --kitti PATH/TO/kitti/00 PATH/TO/kitti/02
    python scripts/benchmarks/node_boot.py --kitti PATH/TO/kitti/02 --play 0.2 --warmup 10 --seconds 30  # a fifth
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import localization as bench  # noqa: E402  (puts the checkout first on sys.path)
import node_latency as nl  # noqa: E402
from _localization_sim import LANE_SHIFT  # noqa: E402

LIVE_S = 0.3  # s: an answer this soon after its scan's publication is live tracking (3 periods at 10 Hz)
MAP_GEN = dict(map_length=1000.0, map_step=2.5, map_range=50.0, map_voxel=0.2, prefixes=[250.0, 500.0], queries=30,
               repetitive=6, boot_scans=0, boot_step=1.0)  # localization_scale.py's 1 km maps (the same cache)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="urban", choices=("urban", "suburban", "highway", "open_road"))
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="the localization benchmark's cache")
    p.add_argument("--starts", type=int, default=5, help="simulated drives, each from a random place of the map")
    p.add_argument("--seed", type=int, default=0, help="the start places' random generator")
    p.add_argument("--kitti", type=Path, nargs="+", default=None, help="real KITTI sequences instead (one run each)")
    p.add_argument("--nodes", default="deepbbs,managed,gicp", help="comma-separated: deepbbs, managed, gicp")
    p.add_argument("--rate", type=float, default=10.0, help="scan rate (Hz)")
    p.add_argument("--play", type=float, default=1.0,
                   help="play the scans this much slower or faster than real time (0.2: a fifth, as 'ros2 bag play "
                        "-r 0.2'; the stamps keep --rate): a slow machine's load is then not why scans are dropped")
    p.add_argument("--warmup", type=float, default=5.0, help="s of scans before the tracking CPU is measured")
    p.add_argument("--seconds", type=float, default=5.0, help="s of scans over which the tracking CPU is measured")
    p.add_argument("--managed-runs", type=int, default=1,
                   help="the lifecycle node runs on the first N starts only (its search is the plain node's; what it "
                        "adds is the configure transition)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                   help="a ROS parameter for the DeepBBS++ nodes (repeatable)")
    p.add_argument("--startup-timeout", type=float, default=240.0, help="s to wait for a node (and its map)")
    p.add_argument("--out", type=Path, help="folder for boot.jsonl and the nodes' logs (default: a temporary one)")
    return p


def sim_streams(args) -> list[tuple[str, nl.Stream, list[np.ndarray]]]:
    """(label, stream, true poses per frame) of each start (module docstring)."""
    from scipy.spatial.transform import Rotation

    from deepbbs_ros.datasets.maps import write_map
    from deepbbs_ros.sim import SCENES
    from deepbbs_ros.sim.simulator import DriveSimulator
    from deepbbs_ros.train.cache import TEST_SEED_BASE
    from msg_adapters.layouts import driver_cloud
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2

    seed = TEST_SEED_BASE + 500 + SCENES.index(args.scene)  # localization_scale.py's maps
    data = bench.sim_map(args.scene, seed, argparse.Namespace(cache=args.cache, **MAP_GEN),
                         log=lambda t: print(t, file=sys.stderr))
    path = args.out / f"map_{args.scene}_1km_alone.pcd"
    write_map(path, data.points, None, None)
    map_msg = arrays_to_pointcloud2(data.points, stamp_ns=nl.STAMP0_NS, frame_id="map")
    # the map drive's stretch of road (arc length), as localization.py's queries
    world_frames = int(np.ceil(MAP_GEN["map_length"] / 6.0 * 10)) + 100
    sim = DriveSimulator(args.scene, seed, None, frames=world_frames, compensate=True)
    P = np.array([sim.pose_at(k) for k in range(world_frames)])
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1))])
    last = int(np.searchsorted(dist, MAP_GEN["map_length"]))
    s_map = np.interp([0.0, last * sim.period], sim.trajectory.t_grid, sim.trajectory.s_grid)
    frames = int(round((args.warmup + args.seconds) * args.rate))
    rng = np.random.default_rng(args.seed)
    out = []
    for i in range(args.starts):
        s0 = float(rng.uniform(s_map[0] + 30.0, s_map[1] - 150.0))  # room to drive on inside the map
        lane = sim.world.style.ego_offset + (LANE_SHIFT[args.scene] if i % 2 else 0.0)
        t0 = time.perf_counter()
        drive = DriveSimulator(args.scene, seed, None, frames=frames, rate_hz=args.rate, world_frames=world_frames,
                               s_start=s0, lane_offset=lane, day=4 + i)
        scans = [drive.scan_at(k) for k in range(frames)]
        lidar = drive.lidar
        msgs = [driver_cloud("velodyne", s.points, s.fields, beams=lidar.beams, columns=lidar.columns,
                             frame_id="velodyne") for s in scans]
        poses = [drive.pose_at(k) for k in range(frames)]
        first = poses[0]
        rpy = Rotation.from_matrix(first[:3, :3]).as_euler("ZYX")[::-1]
        desc = (f"simulated 1 km {args.scene} map ({len(data.points)} points, no trajectory), drive from "
                f"s = {s0:.0f} m{', next lane' if i % 2 else ''}, {frames} HDL-64E scans")
        st = nl.Stream(msgs, [(k, k) for k in range(frames)], desc, str(path), map_msg,
                       [*map(float, first[:3, 3]), *map(float, rpy)])
        print(f"  start {i + 1}: {desc} ({time.perf_counter() - t0:.0f} s to simulate)", file=sys.stderr)
        out.append((f"{args.scene} {i + 1}", st, poses))
    return out


def kitti_streams(args) -> list[tuple[str, nl.Stream, list[np.ndarray]]]:
    from deepbbs_ros.datasets import open_source

    ns = argparse.Namespace(mode="localization", map_every=2, map_voxel=0.2, no_trajectory=True, out=args.out)
    out = []
    for seq in (s for k in args.kitti for s in nl.kitti_sequences(k)):
        st = nl.kitti_stream(ns, "velodyne", "consecutive", seq)
        with open_source(seq) as src:
            truth = [s.T_world_lidar for s in src]
        out.append((f"KITTI {seq.name}", st, [truth[i] for i, _ in st.pairs]))
    return out


def steady_s(r: nl.RunResult) -> float:
    """Seconds from the first scan to the answer of the first live scan after which every scan is answered (nan:
    never). The last half second's scans may still be on their way when the run ends: not required."""
    stamps = sorted(r.published)
    end = max(r.published.values()) - 0.5
    for i, s in enumerate(stamps):
        lat = r.poses.get(s, np.inf) - r.published[s]
        if lat <= LIVE_S and all(t in r.poses for t in stamps[i:] if r.published[t] <= end):
            return r.poses[s]
    return float("nan")


def record(label: str, method: str, r: nl.RunResult, truth: list[np.ndarray], period_ns: int, anchor_cpu: float,
           pairs: list[tuple[int, int]] | None = None):
    d = r.diagnostics
    err = float("nan")
    if r.poses:
        s = min(r.poses, key=r.poses.get)  # the first pose received
        k = (s - nl.STAMP0_NS) // period_ns
        err = float(np.linalg.norm(np.array(r.xyz[s]) - truth[k % len(truth)][:3, 3]))
    n, m = r.after_first
    return {"run": label, "node": method, "error": r.error[-300:] if r.error else "",
            "ready_s": r.ready_s, "configure_s": r.configure_s, "activate_s": r.activate_s,
            "map_build_s": d.get("localization.map build (s)"), "first_pose_s": r.first_pose_s,
            "first_pose_error_m": err, "steady_s": steady_s(r) if r.published else float("nan"),
            "answered_after_first": [n, m], "followed": d.get("localization.scans followed after a search"),
            "dropped": d.get("localization.scans dropped unanswered"), "cpu_ms": r.cpu_ms,
            "cpu_vs_anchor": r.cpu_ms / anchor_cpu if anchor_cpu > 0 else float("nan"),
            "latency_p50_ms": r.pct(50), "latency_p99_ms": r.pct(99),
            "unanswered_after_first_s": [round(t, 2) for s, t in sorted(r.published.items(), key=lambda kv: kv[1])
                                         if s not in r.poses and t > r.first_pose_s],
            # the same scans as (published index k, the stream's frame): KITTI's ten scans turn back every 9
            "unanswered_after_first_k": [[int((s - nl.STAMP0_NS) // period_ns), int(pairs[((s - nl.STAMP0_NS) //
                                          period_ns) % len(pairs)][0]) if pairs else -1]
                                         for s, t in sorted(r.published.items(), key=lambda kv: kv[1])
                                         if s not in r.poses and t > r.first_pose_s],
            "stages": nl.stage_line(d) if d and not r.error else "", "cpu_threads": r.cpu}


def _f(v, fmt=".2f") -> str:
    try:
        return format(float(v), fmt) if np.isfinite(float(v)) else "-"
    except (TypeError, ValueError):
        return "-"


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    methods = [m.strip() for m in args.nodes.split(",") if m.strip()]
    if not methods or any(m not in nl.METHODS for m in methods):
        raise SystemExit(f"--nodes: choose from {', '.join(nl.METHODS)}")
    args.out = args.out or Path(tempfile.mkdtemp(prefix="deepbbs_boot_"))
    args.out.mkdir(parents=True, exist_ok=True)
    from deepbbs_ros.cli.common import local_ros_env
    from deepbbs_ros.node.dds import apply_default_profile

    runs = kitti_streams(args) if args.kitti else sim_streams(args)
    local_ros_env()
    apply_default_profile()
    import rclpy

    ns = argparse.Namespace(mode="localization", config=None, warmup=args.warmup, seconds=args.seconds,
                            rate=args.rate, play=args.play, repeat_sources=False,
                            startup_timeout=args.startup_timeout, device="cpu", threads=None, weights="",
                            param=args.param, out=args.out)
    rows = []
    rclpy.init()
    try:
        for i, (label, st, truth) in enumerate(runs):
            results = {}
            these = [m for m in methods if m != "managed" or i < args.managed_runs]
            for method in sorted(these, key=lambda m: m != nl.ANCHOR):  # the anchor first: its CPU is the ratio's
                print(f"  {label}: {method} ...", file=sys.stderr)
                results[method] = nl.run_method(ns, method, st)
            anchor = results.get(nl.ANCHOR)
            a_cpu = anchor.cpu_ms if anchor is not None and not anchor.error else float("nan")
            for method in these:
                rows.append(record(label, method, results[method], truth, int(nl.SEC / args.rate), a_cpu,
                                   st.pairs))
                print(json.dumps(rows[-1], default=float), flush=True)
    finally:
        rclpy.try_shutdown()
    with (args.out / "boot.jsonl").open("w") as f:
        f.writelines(json.dumps(r, default=float) + "\n" for r in rows)
    print(f"\n{'run':<12} {'node':<8} {'ready s':>8} {'config s':>8} {'map s':>6} {'1st pose s':>10} {'err m':>6} "
          f"{'steady s':>8} {'answered after':>15} {'dropped':>7} {'CPU ms':>7} {'x anchor':>8}")
    for r in rows:
        n, m = r["answered_after_first"]
        print(f"{r['run']:<12} {r['node']:<8} {_f(r['ready_s'], '.1f'):>8} {_f(r['configure_s'], '.1f'):>8} "
              f"{_f(r['map_build_s'], '.1f'):>6} {_f(r['first_pose_s']):>10} {_f(r['first_pose_error_m']):>6} "
              f"{_f(r['steady_s']):>8} {f'{n}/{m}':>15} {str(r['dropped'] or '-'):>7} {_f(r['cpu_ms'], '.1f'):>7} "
              f"{_f(r['cpu_vs_anchor']):>8}" + (f"  FAILED: {r['error'][:80]}" if r["error"] else ""))
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; rows: {args.out / 'boot.jsonl'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
