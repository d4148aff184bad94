#!/usr/bin/env python3
"""The LiDAR drive simulator's speed: HDL-64 frames per second per scene type and where the time goes.

Figures (``simulator.json``, ``simulator.png`` under ``--out``): frames/s per scene type and overall (simulation
only, no writing), the time a 100-frame drive takes at that rate, points per frame, and the per-frame split
between building the ray-casting scene, casting and post-processing (noise, intensity, packing).

    python scripts/benchmarks/simulator.py --frames 30 --out results/benchmarks
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", default=["urban", "suburban", "highway", "open_road"])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--lidar", default="hdl64")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--out", default="results/benchmarks", help="folder for simulator.json and simulator.png")
    args = p.parse_args(argv)

    from rich.console import Console
    from rich.table import Table

    from deepbbs_ros.sim import DriveSimulator, LidarConfig
    from deepbbs_ros.sim.simulator import iter_frames

    table = Table(title=f"deepbbs_ros simulator, {args.lidar}, {args.frames} frames, {args.workers} process(es)")
    for col, unit in [("scene", ""), ("world build", "s"), ("throughput", "frames/s"), ("points", "per frame"),
                      ("scene build", "ms/frame"), ("cast", "ms/frame"), ("post", "ms/frame")]:  # fmt: skip
        table.add_column(f"{col} ({unit})" if unit else col, justify="right")
    total_frames, total_time, rows = 0, 0.0, {}
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
        rows[scene] = {"world_build_s": t_build, "fps": args.frames / dt, "points_per_frame": npts / args.frames}
        if args.workers == 1:
            rows[scene].update({f"{k}_ms_per_frame": per[k] for k in ("build", "cast", "post")})
        table.add_row(scene, f"{t_build:.2f}", f"{args.frames / dt:.2f}", f"{npts / args.frames:.0f}", *split)
    Console(width=130).print(table)
    fps = total_frames / total_time
    print(f"overall: {fps:.2f} frames/s; a 100-frame drive in {100 / fps:.1f} s")
    out = Path(args.out)
    _common.write_json(out, "simulator.json", {"lidar": args.lidar, "frames": args.frames, "workers": args.workers,
                                               "overall_fps": fps, "seconds_per_100_frames": 100 / fps,
                                               "scenes": rows})
    plt = _common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.bar(list(rows), [r["fps"] for r in rows.values()])
    ax.axhline(5.0, color="k", ls="--", label="goal: >= 5 frames/s")
    ax.set_ylabel(f"frames/s ({args.lidar}, {args.workers} process)")
    ax.legend(fontsize=8)
    _common.save(fig, out, "simulator.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
