#!/usr/bin/env python3
"""What a kidnap costs the localization tracker (``MapTracker``, in this process): how many scans it takes to say
the pose is lost, whether any wrong pose slips out meanwhile, and the wall time of the scans rejected after it and of
the scan that finds the pose again, beside a tracked scan's in the same run.

A map of a simulated urban drive (every 2nd frame, noiseless, at its true poses, with its trajectory), tracked over
``--track`` scans, then the sensor is kidnapped for two scans, either into another world (``other``: a highway drive
of another seed) or elsewhere in the same map (``same``: ``JUMP`` frames ahead, about 170 m, turned 115 deg), then
back on the drive. ``--reps`` kidnaps per kind. Figures (``kidnap.json`` under ``--out``): per kind, the seconds of
each tracked scan before the kidnap, of each rejected scan and of each relocalization, scans until lost, scans back
on the drive until relocalized, the kidnap's distance, wrong poses published (any valid pose more than 1 deg / 0.3 m
off, or any valid pose in another world: must be 0). GICP solves on one thread (``registration.exact_gicp``): every
figure but the times is the same on any x86-64 computer with AVX2. ::

    python scripts/benchmarks/kidnap.py --out results/benchmarks
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

KIDNAP_YAW = np.radians(115.0)
FRAMES = 330  # of the urban drive; the map: frames 30 on
JUMP = 150  # frames ahead, elsewhere in the same map


def run(kind: str, reps: int, track: int) -> dict:
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.localization import MapLocalizer, voxel_downsample
    from deepbbs_ros.core.tracking import MapTracker
    from deepbbs_ros.metrics import pair_errors
    from deepbbs_ros.sim.simulator import DriveSimulator

    clean = DriveSimulator("urban", 5, frames=FRAMES, motion_distortion=False)
    parts = []
    for k in range(30, FRAMES, 2):
        s = clean.scan_at(k)
        p = s.points[np.linalg.norm(s.points, axis=1) < 60.0]
        parts.append(p @ s.T_world_lidar[:3, :3].T + s.T_world_lidar[:3, 3])
    trajectory = np.stack([clean.pose_at(k) for k in range(30, FRAMES)])
    cfg = Config().replace(**{"registration.network_process": "off", "registration.exact_gicp": True})
    loc = MapLocalizer(voxel_downsample(np.concatenate(parts), 0.2), cfg, trajectory=trajectory)
    drive = DriveSimulator("urban", 5, frames=FRAMES, compensate=True)
    other = DriveSimulator("highway", 11, frames=12, compensate=True)
    c, s = np.cos(KIDNAP_YAW), np.sin(KIDNAP_YAW)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], np.float32)
    tracked, rejected, relocalized, lost_after, back_after, moved, wrong = [], [], [], [], [], [], 0
    for rep in range(reps):
        start = 31 + (rep * 7) % max(1, 48 - track)
        tracker = MapTracker(loc)
        seq = [("drive", k) for k in range(start, start + track)]
        end = start + track
        seq += [("kidnap", end), ("kidnap", end + 1)] + [("drive", k) for k in range(end + 2, end + 5)]
        lost_at = found_at = None
        if kind == "same":
            there = drive.pose_at(min(end + JUMP, FRAMES - 1))
            moved.append(float(np.linalg.norm(there[:3, 3] - drive.pose_at(end)[:3, 3])))
        for i, (what, k) in enumerate(seq):
            if what == "drive":
                scan = drive.scan_at(k).points
            elif kind == "other":
                scan = other.scan_at(1 + k - end).points
            else:
                scan = drive.scan_at(min(k + JUMP, FRAMES - 1)).points @ turn.T
            t0 = time.perf_counter()
            res = tracker.step(scan, drive.stamp_ns(start + i))
            dt = time.perf_counter() - t0
            if res.valid and (what == "kidnap" or not np.all(np.array(pair_errors(
                    res.T_map_scan, drive.pose_at(k))) < (1.0, 0.3))):
                wrong += 1
            if what == "kidnap":
                rejected.append(dt)
                if res.event == "lost" and lost_at is None:
                    lost_at = k - end + 1
            elif res.event == "relocalized":
                relocalized.append(dt)
                if found_at is None:
                    found_at = k - end - 1  # scans back on the drive, this one included
            elif k < end and res.event == "tracking" and res.valid and i > 0:
                tracked.append(dt)
        lost_after.append(lost_at)
        back_after.append(found_at)
    p50 = {name: float(np.median(v)) if v else None
           for name, v in (("tracked", tracked), ("rejected", rejected), ("relocalize", relocalized))}
    return {"tracked_scan_s": tracked, "tracked_scan_p50_s": p50["tracked"],
            "rejected_scan_s": rejected, "rejected_scan_p50_s": p50["rejected"],
            "rejected_over_tracked": (p50["rejected"] / p50["tracked"] if p50["rejected"] and p50["tracked"]
                                      else None),
            "relocalize_s": relocalized, "relocalize_p50_s": p50["relocalize"],
            "lost_after_scans": lost_after, "relocalized_after_scans": back_after,
            "kidnap_distance_m": moved or None, "wrong_poses": wrong, "kidnaps": reps}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("results/benchmarks"), help="folder for kidnap.json")
    ap.add_argument("--reps", type=int, default=2, help="kidnaps per kind")
    ap.add_argument("--track", type=int, default=12, help="scans tracked before each kidnap")
    ap.add_argument("--kinds", nargs="+", choices=("other", "same"), default=["other", "same"],
                    help="where the sensor is carried: another world, or elsewhere in the map")
    args = ap.parse_args(argv)
    figures = {}
    for kind in args.kinds:
        figures[kind] = run(kind, args.reps, args.track)
        f = figures[kind]
        print(f"{kind}: tracked scan p50 {f['tracked_scan_p50_s'] or float('nan'):.3f} s, rejected scan p50 "
              f"{f['rejected_scan_p50_s']:.3f} s, relocalized p50 "
              f"{f['relocalize_p50_s'] or float('nan'):.2f} s, lost after {f['lost_after_scans']} scans, "
              f"relocalized after {f['relocalized_after_scans']} scans back, wrong poses {f['wrong_poses']}")
    _common.write_json(args.out, "kidnap.json", figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
