"""Preprocessing of recordings, dumped and compared bit for bit between two checkouts, with per-recording counts.

Run it once with each checkout first on PYTHONPATH, then compare::

    PYTHONPATH=/path/to/a python scripts/preprocess_compare.py dump a.npz SOURCE [SOURCE ...] [--every 3]
    PYTHONPATH=/path/to/b python scripts/preprocess_compare.py dump b.npz SOURCE [SOURCE ...] [--every 3]
    python scripts/preprocess_compare.py compare a.npz b.npz

SOURCE is anything ``deepbbs-replay`` reads (a KITTI folder, a bag, ...) or ``sim:SCENE:LIDAR`` (two frames of a
simulated drive, seed 3). Each scan is prepared with the default configuration (``prepare_scan`` and ``preprocess``
on the raw points); the dump holds the sampled points, the ground plane, the counts, the dense points and the GICP
cloud. ``dump`` also prints, per source, the median counts and how the ground was found.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter

import numpy as np


def _scans(source: str, every: int):
    if source.startswith("sim:"):
        from deepbbs_ros.sim.lidar import LidarConfig
        from deepbbs_ros.sim.simulator import DriveSimulator

        _, scene, lidar = source.split(":")
        sim = DriveSimulator(scene, 3, getattr(LidarConfig, lidar)(), frames=20)
        yield from ((k, sim.scan_at(k).points) for k in (0, 10))
        return
    from deepbbs_ros.datasets import open_source

    for k, scan in enumerate(open_source(source)):
        if k % every == 0:
            yield k, scan.points


def dump(out: str, sources: list[str], every: int) -> None:
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.preprocess import preprocess
    from deepbbs_ros.core.scans import prepare_scan

    cfg, arrays = Config(), {}
    for source in sources:
        rows, status = [], Counter()
        for k, pts in _scans(source, every):
            res = prepare_scan(cfg, pts, threads=1)
            for tag, r in (("scan", res), ("pp", preprocess(pts, cfg.preprocess))):
                key = f"{source}/{k}|{tag}"
                arrays[key + "|points"], arrays[key + "|dense"] = r.points, r.dense_points
                arrays[key + "|plane"] = np.array([]) if r.ground_plane is None else r.ground_plane
                arrays[key + "|n"] = np.array([r.n_valid, r.n_nonground, r.n_voxels])
            arrays[f"{source}/{k}|gicp"] = res.polish_cloud.points()
            status[getattr(res, "ground_status", "upright" if res.ground_plane is not None else "none")] += 1
            rows.append((len(pts), res.n_valid, res.n_nonground, res.n_voxels, res.polish_cloud.n_points))
        med = np.median(np.array(rows), axis=0).astype(int)
        print(f"{source}: {len(rows)} scans; median input {med[0]}, valid {med[1]}, non-ground {med[2]}, "
              f"FPS candidates {med[3]}, GICP voxels {med[4]}; ground {dict(status)}")
    np.savez_compressed(out, **arrays)


def compare(a_path: str, b_path: str) -> int:
    """Print, per source, how many scans differ in any array; 1 when any does."""
    a, b = np.load(a_path), np.load(b_path)
    scans, bad = Counter(), Counter()
    for scan in sorted({k.split("|")[0] for k in a.files}):
        source = scan.rsplit("/", 1)[0]
        scans[source] += 1
        keys = [k for k in a.files if k.split("|")[0] == scan]
        bad[source] += any(k not in b.files or a[k].shape != b[k].shape or not np.array_equal(a[k], b[k])
                           for k in keys)
    for source in scans:
        print(f"{source}: {scans[source]} scans, {bad[source]} differ")
    return 1 if sum(bad.values()) else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump", help="prepare the scans of SOURCEs and write them to OUT (.npz)")
    d.add_argument("out")
    d.add_argument("sources", nargs="+")
    d.add_argument("--every", type=int, default=1, help="every N-th scan of a recording (default 1)")
    c = sub.add_parser("compare", help="exit 1 when two dumps differ")
    c.add_argument("a")
    c.add_argument("b")
    args = parser.parse_args(argv)
    if args.cmd == "dump":
        dump(args.out, args.sources, args.every)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
