#!/usr/bin/env python3
"""What tracking a scan in a prior map costs, beside the GICP anchor's work on the same scan and map, in one process.

Per scan, in turn on the same scan (so that both see the same load on the machine): the localization's work
(``MapLocalizer.prepare``: the scan's GICP cloud, as the node's input thread does on arrival; then ``MapTracker.step``
from the constant-velocity prediction: GICP on the map crop, the verdict, the refinement and the covariance) and the
GICP anchor's (``deepbbs_ros.node.gicp_anchor.GicpRegistration``: its preprocessing, then GICP on a crop of the same
map, prepared once per 10 m, from its last answer: what ``gicp_anchor`` in ``node.target_mode: latched`` does).
The tracker starts from the first scan's true pose (the search is not timed here: see localization.py and
node_latency.py for the boot). Prints the p50 / p95 ms of each part and of the whole per scan, the ratios to the
anchor's, the localization's stage medians and how many scans it placed within 1 deg / 0.3 m.

Drives, forwards only (the order a vehicle drives them):

* ``--kitti PATH ...``: KITTI sequence folders (``velodyne/``, ``poses.txt``, ``calib.txt``); the map is every
  ``--map-every``-th scan at its true pose, voxelised, without its trajectory (``--trajectory``: with it);
* ``--sim-frames N`` (0: none): a simulated urban drive (HDL-32E), the same way.

``--back-and-forth N``: N scans of each drive played forwards and back instead (0, 1, .., n-1, n-2, .., 1, 0, 1, ..,
every scan stamped a period after the last: node_boot.py's KITTI stream), so that the tracker meets the turns (its
constant-velocity prediction two scans off there); the scans at the turns are timed apart as well.

    python scripts/benchmarks/tracking_cost.py --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 --sim-frames 150
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402, F401  (puts the checkout first on sys.path)

from deepbbs_ros.entry import cli_entry  # noqa: E402

CROP_REACH = 10.0  # m: the anchor prepares a new crop of the map when its pose is this far from the last crop's


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kitti", type=Path, nargs="*", default=[], help="KITTI sequence folders")
    p.add_argument("--sim-frames", type=int, default=150, help="frames of a simulated urban drive (0: none)")
    p.add_argument("--map-every", type=int, default=2, help="every k-th scan goes into the map")
    p.add_argument("--map-voxel", type=float, default=0.2, help="the map's voxel grid (m)")
    p.add_argument("--trajectory", action="store_true", help="give the localizer the map's trajectory")
    p.add_argument("--back-and-forth", type=int, default=0, metavar="N",
                   help="N scans played forwards and back (the turns of node_boot.py's KITTI stream); 0: forwards once")
    return p


def kitti_drive(path: Path) -> tuple[str, list[np.ndarray], list[np.ndarray], list[int]]:
    from deepbbs_ros.datasets import open_source

    with open_source(path) as src:
        scans = list(src)
    return (f"KITTI {path.name}", [np.asarray(s.points[:, :3], np.float32) for s in scans],
            [s.T_world_lidar for s in scans], [int(s.stamp_ns) for s in scans])


def sim_drive(frames: int) -> tuple[str, list[np.ndarray], list[np.ndarray], list[int]]:
    from deepbbs_ros.sim.lidar import LidarConfig
    from deepbbs_ros.sim.simulator import DriveSimulator

    sim = DriveSimulator("urban", 5, LidarConfig.hdl32(), frames=frames, motion_distortion=False)
    scans = [sim.scan_at(k).points.astype(np.float32) for k in range(frames)]
    return (f"simulated urban HDL-32E, {frames} frames", scans, [sim.pose_at(k) for k in range(frames)],
            [int(sim.stamp_ns(k)) for k in range(frames)])


def measure(name: str, scans, poses, stamps, args, registration, config) -> dict:
    from deepbbs_ros.core.localization import MapLocalizer, voxel_downsample
    from deepbbs_ros.core.tracking import MapTracker
    from deepbbs_ros.node.gicp_anchor import GicpRegistration

    keys = list(range(0, len(scans), max(1, args.map_every)))
    pts = voxel_downsample(np.concatenate([scans[k] @ poses[k][:3, :3].T + poses[k][:3, 3] for k in keys])
                           .astype(np.float32), args.map_voxel)
    loc = MapLocalizer(pts, config, registration=registration,
                       trajectory=np.stack([poses[k] for k in keys]) if args.trajectory else None)
    tracker = MapTracker(loc, config)
    tracker.state, tracker._poses = "tracking", [(stamps[0], poses[0].copy())]  # found at the first scan
    anchor, T_anchor, crop = GicpRegistration(config), poses[0].copy(), None
    rows = {"ours.prepare": [], "ours.track": [], "anchor.prepare": [], "anchor.register": []}
    stages: dict[str, list[float]] = {}
    right = 0
    order = list(range(len(scans)))
    if args.back_and_forth > 0:  # 0, 1, .., n-1, n-2, .., 1, 0, 1, ..: stamped a period apart
        cycle = order + order[-2:0:-1]
        order = [cycle[i % len(cycle)] for i in range(args.back_and_forth)]
        period = int(np.median(np.diff(stamps)))
        stamps = [stamps[0] + i * period for i in range(len(order))]
        scans, poses = [scans[i] for i in order], [poses[i] for i in order]
    turns = [i for i in range(1, len(order) - 1) if (order[i + 1] - order[i]) * (order[i] - order[i - 1]) < 0]
    for k in range(1, len(scans)):
        t0 = time.perf_counter()
        prepared = loc.prepare(scans[k], None, stamps[k])
        t1 = time.perf_counter()
        res = tracker.step(prepared, stamps[k])
        t2 = time.perf_counter()
        rows["ours.prepare"].append((t1 - t0) * 1e3)
        rows["ours.track"].append((t2 - t1) * 1e3)
        for stage, ms in (res.timings_ms or {}).items():
            stages.setdefault(stage, []).append(ms)
        d = np.linalg.inv(poses[k]) @ res.T_map_scan
        rot = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
        right += bool(res.valid) and rot <= 1.0 and np.linalg.norm(d[:3, 3]) <= 0.3
        t0 = time.perf_counter()
        src = anchor.preprocess(scans[k])
        t1 = time.perf_counter()
        if crop is None or np.linalg.norm(crop[0][:2, 3] - T_anchor[:2, 3]) > CROP_REACH:
            C = np.eye(4)
            C[:3, 3] = T_anchor[:3, 3]
            crop = (C, anchor.preprocess(loc.crop_points(C).astype(np.float32)))
        T_anchor = crop[0] @ anchor.register(src, crop[1], np.linalg.inv(crop[0]) @ T_anchor).T_target_source
        rows["anchor.prepare"].append((t1 - t0) * 1e3)
        rows["anchor.register"].append((time.perf_counter() - t1) * 1e3)
    ours = np.add(rows["ours.prepare"], rows["ours.track"])
    theirs = np.add(rows["anchor.prepare"], rows["anchor.register"])
    q = {k: (np.percentile(v, 50), np.percentile(v, 95)) for k, v in rows.items()}
    q["ours"], q["anchor"] = (np.percentile(ours, 50), np.percentile(ours, 95)), (np.percentile(theirs, 50),
                                                                                 np.percentile(theirs, 95))
    print(f"{name}: {len(scans) - 1} scans tracked, map {len(pts)} points from {len(keys)} scans "
          f"({'with' if args.trajectory else 'without'} its trajectory); placed within 1 deg / 0.3 m: {right}")
    for a, b in (("ours.prepare", "anchor.prepare"), ("ours.track", "anchor.register"), ("ours", "anchor")):
        print(f"  {a:13s} p50 / p95 {q[a][0]:6.1f} / {q[a][1]:6.1f} ms   {b:15s} {q[b][0]:6.1f} / {q[b][1]:6.1f} ms   "
              f"ratio x{q[a][0] / q[b][0]:.2f} / x{q[a][1] / q[b][1]:.2f}")
    if turns:  # the scan after each turn (the prediction two scans off)
        at = [k - 1 for k in (t + 1 for t in turns) if k < len(scans)]
        o = [rows["ours.prepare"][i] + rows["ours.track"][i] for i in at]
        a = [rows["anchor.prepare"][i] + rows["anchor.register"][i] for i in at]
        print(f"  the {len(at)} scans after a turn: ours p50 / max {np.median(o):6.1f} / {max(o):6.1f} ms, anchor "
              f"{np.median(a):6.1f} / {max(a):6.1f} ms, ratio of the sums x{sum(o) / sum(a):.2f}")
    print("  localization stages, median ms: " + ", ".join(f"{s} {np.median(v):.1f}" for s, v in sorted(stages.items())
                                                          if s != "total"))
    return q


@cli_entry("tracking_cost")
def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.registration import DeepBBSRegistration

    config = Config().replace(**{"registration.network_process": "off"})
    registration = DeepBBSRegistration(config)
    drives = [kitti_drive(p) for p in args.kitti] + ([sim_drive(args.sim_frames)] if args.sim_frames > 0 else [])
    for name, scans, poses, stamps in drives:
        measure(name, scans, poses, stamps, args, registration, config)
    print(f"load average {__import__('os').getloadavg()[0]:.1f} on {__import__('os').cpu_count()} CPUs "
          "(the figures are wall-clock; each scan's two measurements are taken one after the other)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
