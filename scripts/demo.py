#!/usr/bin/env python3
"""``make demo``: replay the bundled sample drives through DeepBBS++ and the baselines.

For each of ``bags/urban_drive_hdl64`` (HDL-64E, Velodyne layout) and ``bags/suburban_drive_os64``
(Ouster OS1-64 layout), raw sweeps with per-point times:

1. pairs mode (Apollo pair protocol, stride 1, max 5 m): DeepBBS++ vs point-to-point ICP vs GICP
   from identity;
2. odometry mode on the same drive: DeepBBS++ vs KISS-ICP vs scan-to-scan GICP.

Each prints its comparison table (with units) and the folder holding metrics.json, the plots,
trajectories and the results bag (``results/demo/<sample>/<mode>/latest``). Without the sample bags (a
stripped checkout) a small drive is simulated into a temporary folder first.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = (ROOT / "bags" / "urban_drive_hdl64", ROOT / "bags" / "suburban_drive_os64")


def _simulated_drive(tmp: Path, frames: int = 40) -> Path:
    from deepbbs_ros.datasets import write_scans
    from deepbbs_ros.sim import LidarConfig, simulate_drive

    out = tmp / "urban_drive"
    print(f"sample bags not found ({SAMPLES[0]}); simulating a {frames}-frame urban drive into {out}")
    scans = simulate_drive("urban", 7, frames, lidar=LidarConfig.hdl64())
    write_scans(scans, out, "mcap", progress=True)
    return out


def _deepbbs_available() -> bool:
    try:
        import deepbbs_ros.core.registration  # noqa: F401
        from deepbbs_ros.core.checkpoint import default_weights_path

        return default_weights_path().exists()
    except ImportError:
        return False


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--source", default=None, help="recording to replay (default: the bundled sample bags)")
    p.add_argument("--out", default=str(ROOT / "results" / "demo"), help="results root")
    p.add_argument("--skip-odometry", action="store_true")
    args = p.parse_args(argv)

    from deepbbs_ros.cli.common import local_ros_env
    from deepbbs_ros.cli.replay import main as replay

    local_ros_env()
    with tempfile.TemporaryDirectory(prefix="deepbbs_demo_") as tmp:
        if args.source:
            sources = [Path(args.source)]
        else:
            sources = [p for p in SAMPLES if p.exists()] or [_simulated_drive(Path(tmp))]
        deep = _deepbbs_available()
        if not deep:
            print("note: DeepBBS++ (core registration or shipped weights) is not available in this checkout; "
                  "running the baselines only")
        lead = "deepbbs++," if deep else ""
        runs = [("pairs", ["--mode", "pairs", "--method", lead + "icp,gicp", "--stride", "1", "--max-dist", "5"])]
        if not args.skip_odometry:
            runs.append(("odometry", ["--mode", "odometry", "--method", lead + "kiss-icp,gicp"]))
        rc = 0
        for source in sources:
            for mode, extra in runs:
                out = Path(args.out) / source.name / mode
                print(f"\n$ deepbbs-replay {source} {' '.join(extra)} --out {out}")
                rc = replay([str(source), *extra, "--out", str(out)]) or rc
                print(f"plots and metrics.json: {out / 'latest'}/")
    return rc


if __name__ == "__main__":
    sys.exit(main())
