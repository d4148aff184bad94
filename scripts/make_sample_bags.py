#!/usr/bin/env python3
"""Regenerate the committed samples in bags/ from the simulator (deterministic: fixed seeds).

    python scripts/make_sample_bags.py [--out bags] [--force]

* ``urban_drive_hdl64/``: rosbag2 (mcap, zstd chunks), 50 frames at 10 Hz, scene ``urban`` seed 7,
  HDL-64E beam layout with a 1.0 degree azimuth step (decimated from 0.18 to keep the repository
  small: ~22k points per frame), PointCloud2 on /apollo/sensor/velodyne64/compensator/PointCloud2
  (x y z intensity time ring, frame velodyne64) and PoseStamped ground truth on /ground_truth/pose.
* ``apollo_suburban_10/``: Apollo-SouthBay folder, 10 frames, scene ``suburban`` seed 11, same sensor,
  binary PCDs (x y z intensity) + poses/gt_poses.txt.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

SAMPLES = (
    # (folder, format, scene, seed, frames)
    ("urban_drive_hdl64", "mcap", "urban", 7, 50),
    ("apollo_suburban_10", "apollo", "suburban", 11, 10),
)
AZIMUTH_STEP_DEG = 1.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="bags", help="output folder (default: bags)")
    parser.add_argument("--force", action="store_true", help="replace existing samples")
    args = parser.parse_args(argv)

    from deepbbs_ros.datasets import write_scans
    from deepbbs_ros.datasets.base import SizedIterable
    from deepbbs_ros.sim import LidarConfig, simulate_drive

    lidar = LidarConfig.hdl64(azimuth_step_deg=AZIMUTH_STEP_DEG)
    for name, fmt, scene, seed, frames in SAMPLES:
        out = Path(args.out) / name
        if out.exists():
            if not args.force:
                print(f"{out} exists (use --force to regenerate)", file=sys.stderr)
                continue
            shutil.rmtree(out)
        scans = simulate_drive(scene, seed, frames, lidar=lidar, motion_distortion=True, rate_hz=10.0)
        n = write_scans(SizedIterable(scans, frames), out, fmt, progress=True)
        size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
        print(f"{out}: {n} frames, {size / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
