#!/usr/bin/env python3
"""Benchmark the LiDAR drive simulator: frames per second per scene and where the time goes.

    python scripts/bench_sim.py                      # HDL-64, 30 frames per scene, 1 process
    python scripts/bench_sim.py --workers 2 --frames 60
    taskset -c 0 python scripts/bench_sim.py --scenes urban   # pinned to one core

Reports frames/s (simulation only, no writing), points per frame, and the per-frame split between
building the ray-casting scene, casting, and post-processing (noise, intensity, packing).
"""

from __future__ import annotations

import argparse
import sys
import time


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", default=["urban", "suburban", "highway", "open_road"])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--lidar", default="hdl64")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1)
    args = p.parse_args(argv)

    from rich.console import Console
    from rich.table import Table

    from deepbbs_ros.sim import DriveSimulator, LidarConfig
    from deepbbs_ros.sim.simulator import iter_frames

    table = Table(title=f"deepbbs_ros simulator, {args.lidar}, {args.frames} frames, {args.workers} process(es)")
    for col, unit in [("scene", ""), ("world build", "s"), ("throughput", "frames/s"), ("points", "per frame"),
                      ("scene build", "ms/frame"), ("cast", "ms/frame"), ("post", "ms/frame")]:  # fmt: skip
        table.add_column(f"{col} ({unit})" if unit else col, justify="right")
    total_frames, total_time = 0, 0.0
    for scene in args.scenes:
        lid = LidarConfig.preset(args.lidar)
        t0 = time.perf_counter()
        sim = DriveSimulator(scene, args.seed, lid, frames=args.frames)
        t_build = time.perf_counter() - t0
        t0 = time.perf_counter()
        npts = 0
        for scan in iter_frames(sim, workers=args.workers):
            npts += len(scan)
        dt = time.perf_counter() - t0
        total_frames, total_time = total_frames + args.frames, total_time + dt
        per = {k: 1000 * v / args.frames for k, v in sim.timings_s.items()}  # only filled in-process
        split = [f"{per[k]:.0f}" if args.workers == 1 else "-" for k in ("build", "cast", "post")]
        table.add_row(scene, f"{t_build:.2f}", f"{args.frames / dt:.2f}", f"{npts / args.frames:.0f}", *split)
    Console(width=130).print(table)
    print(f"overall: {total_frames / total_time:.2f} frames/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
