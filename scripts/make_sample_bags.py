#!/usr/bin/env python3
"""Regenerate the committed samples in bags/ from the simulator (deterministic: fixed seeds).

    python scripts/make_sample_bags.py [--out bags] [--force] [--only NAME]

* ``urban_drive_hdl64/``: rosbag2 (mcap, zstd chunks), 15 frames, scene ``urban`` seed 7, the HDL-64E at its real
  resolution (64 beams, 0.18 degree azimuth step: ~100k points per sweep), raw sweeps as the Velodyne
  driver publishes them (``velodyne_pointcloud`` PointXYZIRT: x y z intensity ring time, unorganised,
  motion-distorted, per-point ``time`` in s since the stamp) on /apollo/sensor/velodyne64/PointCloud2,
  PoseStamped ground truth (the sensor at the stamp) on /ground_truth/pose.
* ``suburban_drive_os64/``: rosbag2 (mcap), 15 frames, scene ``suburban`` seed 13, an Ouster OS1-64-like sensor
  (64 beams, 1024 columns) in the ouster-ros layout (organised 64 x 1024, no return = zeros, ``t`` in ns,
  point_step 48) on /ouster/points, frame ``os_sensor``, raw sweeps.
* The mcap files carry chunk, data-section and summary CRCs (``deepbbs_ros.datasets.write_scans``).
* ``apollo_suburban_5/``: Apollo-SouthBay folder, 5 frames, scene ``suburban`` seed 11, HDL-64E at real
  resolution, motion-compensated to each stamp as Apollo's compensator publishes it; binary PCDs
  (x y z intensity) + poses/gt_poses.txt.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
from pathlib import Path


@dataclasses.dataclass(frozen=True)
class Sample:
    name: str
    fmt: str
    scene: str
    seed: int
    frames: int
    lidar: str  # LidarConfig preset
    compensate: bool  # motion-compensated to the stamp (Apollo) or raw sweeps with per-point time
    driver: str | None = None  # rosbag2 cloud layout (msg_adapters.layouts.driver_cloud)
    topic: str = ""
    frame_id: str = ""


SAMPLES = (
    Sample("urban_drive_hdl64", "mcap", "urban", 7, 15, "hdl64", False, "velodyne",
           "/apollo/sensor/velodyne64/PointCloud2", "velodyne64"),
    Sample("suburban_drive_os64", "mcap", "suburban", 13, 15, "ouster64", False, "ouster", "/ouster/points",
           "os_sensor"),
    Sample("apollo_suburban_5", "apollo", "suburban", 11, 5, "hdl64", True),
)  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="bags", help="output folder (default: bags)")
    parser.add_argument("--force", action="store_true", help="replace existing samples")
    parser.add_argument("--only", default=None, help="regenerate only this sample")
    args = parser.parse_args(argv)

    from deepbbs_ros.datasets import write_scans
    from deepbbs_ros.datasets.base import SizedIterable
    from deepbbs_ros.sim import LidarConfig, simulate_drive

    for s in SAMPLES:
        if args.only and s.name != args.only:
            continue
        out = Path(args.out) / s.name
        if out.exists():
            if not args.force:
                print(f"{out} exists (use --force to regenerate)", file=sys.stderr)
                continue
            shutil.rmtree(out)
        lidar = LidarConfig.preset(s.lidar)
        scans = simulate_drive(s.scene, s.seed, s.frames, lidar=lidar, motion_distortion=True, rate_hz=10.0,
                               compensate=s.compensate)
        if s.frame_id:
            scans = (dataclasses.replace(scan, frame_id=s.frame_id) for scan in scans)
        kw = {"topic": s.topic, "driver": s.driver, "shape": (lidar.beams, lidar.columns)} if s.fmt != "apollo" else {}
        n = write_scans(SizedIterable(scans, s.frames), out, s.fmt, progress=True, **kw)
        size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
        print(f"{out}: {n} frames, {size / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
