#!/usr/bin/env python3
"""What the simulator's sensors, mounts and places produce: points, coverage, motion, ceilings.

    python scripts/sim_sensor_stats.py                         # every sensor, mount and place, 10 frames each
    python scripts/sim_sensor_stats.py --real-livox PATH       # also a real handheld Livox recording's motion
    python scripts/sim_sensor_stats.py --pictures docs/sim     # also one PNG per place and one of the patterns

Sensors (each on a wheeled robot in the courtyard): points per scan, share of 0.5 deg x 0.5 deg cells of the
field of view that the rays of one frame and of ten frames hit (the pattern, before any surface), median
range. Mounts (in the courtyard): speed, rotation rate between poses 0.1 s and 0.4 s apart, roll and pitch
ranges, sensor height. Places (OS1-64 on a wheeled robot): points per scan, share of upward rays (> 30 deg
elevation, Mid-360) that return (1 under a ceiling), median range; with ``--gicp-pairs``, GICP from the truth
on pairs 0.5 s apart per place and rig. ``--real-livox``: a KITTI-layout folder
(``poses.txt``, ``times.txt``) of a handheld recording; its speeds and rotation rates between keyframes are
printed beside the simulated handheld walk's at the same spacing.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def rot_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    c = (np.einsum("nji,nji->n", Ra, Rb) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def motion_stats(T: np.ndarray, dt: np.ndarray) -> tuple[float, float, float, float, float]:
    """speed median / p90 (m/s), rotation rate median / p90 / max (deg/s) between consecutive poses."""
    v = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1) / dt
    w = rot_deg(T[:-1, :3, :3], T[1:, :3, :3]) / dt
    return float(np.median(v)), float(np.percentile(v, 90)), float(np.median(w)), float(np.percentile(w, 90)), \
        float(w.max())


def pattern_coverage(lid, frames: int, rate: float = 10.0) -> float:
    """Share of the field of view's 0.5 deg cells the rays of ``frames`` frames hit."""
    from deepbbs_ros.sim.patterns import SolidStateConfig
    from deepbbs_ros.sim.solid_state import coverage

    if isinstance(lid, SolidStateConfig):
        d = np.concatenate([lid.pattern(k / rate, 1.0 / rate)[0] for k in range(frames)])
        lo, hi, width = lid.vfov_min_deg, lid.vfov_max_deg, lid.hfov_deg  # rosettes: of the bounding box
    else:
        d = lid.directions().reshape(-1, 3)
        el = np.rad2deg(lid.elevations())
        lo, hi, width = el[0], el[-1], 360.0
    cells = (np.floor(hi / 0.5) - np.floor(lo / 0.5) + 1) * min(width / 0.5 + 1, 720)
    return coverage(d, 0.5) / cells


def picture_place(path, sim, scan) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    place = sim.world
    T = scan.T_world_lidar
    w = scan.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    fig, ax = plt.subplots(1, 2, figsize=(12, 6), dpi=70)
    tri = place.vertices[place.faces]
    top, low = tri[:, :, 2].max(1), tri[:, :, 2].min(1)
    keep = (top > 0.05) & (low < (place.ceiling or 1e9) - 0.01)  # not the floor, not the ceiling slab
    o = np.argsort(top[keep])
    ax[0].add_collection(PolyCollection(tri[keep][o][:, :, :2], array=np.clip(top[keep][o], 0, 12),
                                        cmap="viridis", edgecolors="face", linewidths=0.6))
    loop = np.vstack([place.path, place.path[:1]])
    ax[0].plot(loop[:, 0], loop[:, 1], "k--", lw=0.8)
    ax[0].set_title(f"{place.name}: mesh from above (colour = height), dashed = the loop")
    o = np.argsort(w[:, 2])
    ax[1].scatter(w[o, 0], w[o, 1], c=np.clip(w[o, 2], 0, 8), s=0.2, cmap="viridis", linewidths=0, rasterized=True)
    ax[1].set_title(f"one {sim.lidar.name} scan, {sim.mount} mount ({len(w)} points)")
    lim = np.abs(place.path).max() + 12.0
    for a in ax:
        a.set_xlim(-lim, lim)
        a.set_ylim(-lim, lim)
        a.set_aspect("equal")
        a.plot([T[0, 3]], [T[1, 3]], "r^", ms=6)
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


def picture_patterns(path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from deepbbs_ros.sim.patterns import avia, mid360

    fig, ax = plt.subplots(2, 2, figsize=(12, 8), dpi=70)
    for row, lid in enumerate((avia(), mid360())):
        for col, frames in enumerate((1, 10)):
            d = np.concatenate([lid.pattern(k / 10.0, 0.1)[0] for k in range(frames)])
            az, el = np.degrees(np.arctan2(d[:, 1], d[:, 0])), np.degrees(np.arcsin(d[:, 2]))
            ax[row, col].scatter(az, el, s=0.05, c="k", linewidths=0, rasterized=True)
            ax[row, col].set_title(f"{lid.name}: ray directions of {frames * 100} ms ({len(d)} rays)")
            ax[row, col].set_xlabel("azimuth (deg)")
            ax[row, col].set_ylabel("elevation (deg)")
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frames", type=int, default=10, help="frames simulated per sensor / mount / place")
    p.add_argument("--real-livox", default="", help="a KITTI-layout handheld recording to compare motion with")
    p.add_argument("--pictures", default="", help="folder for the PNGs ('' = none)")
    p.add_argument("--gicp-pairs", type=int, default=0,
                   help="also register this many pairs (0.5 s apart) per place and rig with GICP from the truth")
    p.add_argument("--gicp-voxel", type=float, default=0.0, help="GICP voxel size, m (0 = eval.baseline_voxel_size)")
    p.add_argument("--gicp-max-corr", type=float, default=0.0,
                   help="GICP max correspondence distance, m (0 = eval.baseline_max_corr_dist)")
    args = p.parse_args(argv)

    from deepbbs_ros.sim.mounts import MOUNTS
    from deepbbs_ros.sim.patterns import SENSORS, make_sensor
    from deepbbs_ros.sim.places import PLACES
    from deepbbs_ros.sim.rig import RigSimulator

    print("| sensor | points/scan | FoV cells hit in 0.1 s | in 1 s | median range (m) | ms/frame |")
    print("|---|---|---|---|---|---|")
    for name in SENSORS:
        lid = make_sensor(name)
        sim = RigSimulator("courtyard", args.seed, lid, "wheeled", frames=args.frames)
        t0 = time.perf_counter()
        scans = list(sim)
        ms = 1000 * (time.perf_counter() - t0) / len(scans)
        n = np.mean([len(s) for s in scans])
        r = np.median(np.concatenate([np.linalg.norm(s.points, axis=1) for s in scans]))
        print(f"| {name} | {n:.0f} | {100 * pattern_coverage(lid, 1):.1f} % | {100 * pattern_coverage(lid, 10):.1f} % "
              f"| {r:.1f} | {ms:.0f} |", flush=True)

    print("\n| mount | speed median / p90 (m/s) | rotation 0.1 s: median / p90 / max (deg/s) | 0.4 s: median / p90 / "
          "max | roll range (deg) | pitch range (deg) | height (m) |")
    print("|---|---|---|---|---|---|---|")
    for mount in MOUNTS:
        sim = RigSimulator("courtyard", args.seed, make_sensor("os1_64"), mount, frames=600)
        T = sim.T_world_lidar(np.arange(0.0, 60.0, 0.1))
        a = motion_stats(T, np.full(len(T) - 1, 0.1))
        b = motion_stats(T[::4], np.full(len(T[::4]) - 1, 0.4))
        roll = np.degrees(np.arctan2(T[:, 2, 1], T[:, 2, 2]))
        pitch = np.degrees(-np.arcsin(T[:, 2, 0]))
        print(f"| {mount} | {a[0]:.2f} / {a[1]:.2f} | {a[2]:.1f} / {a[3]:.1f} / {a[4]:.1f} | {b[2]:.1f} / {b[3]:.1f} / "
              f"{b[4]:.1f} | {roll.min():.1f}..{roll.max():.1f} | {pitch.min():.1f}..{pitch.max():.1f} "
              f"| {np.median(T[:, 2, 3]):.2f} |", flush=True)
    if args.real_livox:
        from pathlib import Path

        d = Path(args.real_livox)
        P = np.loadtxt(d / "poses.txt").reshape(-1, 3, 4)
        t = np.loadtxt(d / "times.txt")
        T = np.tile(np.eye(4), (len(P), 1, 1))
        T[:, :3, :] = P
        dt = np.diff(t)
        real = motion_stats(T, dt)
        sim = RigSimulator("courtyard", args.seed, make_sensor("avia"), "handheld", frames=600)
        ts = np.cumsum(np.concatenate([[0.0], dt]))
        ts = ts[ts < 60.0]
        simm = motion_stats(sim.T_world_lidar(ts), np.diff(ts))
        print(f"\nreal handheld recording ({len(P)} keyframes, median spacing {np.median(dt):.2f} s): "
              f"speed median / p90 {real[0]:.2f} / {real[1]:.2f} m/s, "
              f"rotation median / p90 / max {real[2]:.1f} / {real[3]:.1f} / {real[4]:.1f} deg/s")
        print(f"simulated handheld walk at the same spacing ({len(ts)} poses): "
              f"speed {simm[0]:.2f} / {simm[1]:.2f} m/s, rotation {simm[2]:.1f} / {simm[3]:.1f} / {simm[4]:.1f} deg/s")

    print("\n| place | points/scan (OS1-64, wheeled) | upward rays returning (Mid-360, > 30 deg) | median range (m) |")
    print("|---|---|---|---|")
    for place in PLACES:
        sim = RigSimulator(place, args.seed, make_sensor("os1_64"), "wheeled", frames=args.frames)
        scans = list(sim)
        up_sim = RigSimulator(place, args.seed, make_sensor("mid360", dropout=0.0), "wheeled", frames=1)
        pts = up_sim.scan_at(0).points
        dirs = up_sim.lidar.pattern(0.0, 0.1)[0]
        steep = np.sin(np.deg2rad(30.0))
        up = (pts[:, 2] / np.linalg.norm(pts, axis=1) > steep).sum() / max((dirs[:, 2] > steep).sum(), 1)
        r = np.median(np.concatenate([np.linalg.norm(s.points, axis=1) for s in scans]))
        print(f"| {place} | {np.mean([len(s) for s in scans]):.0f} | {100 * up:.1f} % | {r:.1f} |", flush=True)
        if args.pictures:
            from pathlib import Path

            Path(args.pictures).mkdir(parents=True, exist_ok=True)
            picture_place(Path(args.pictures) / f"place_{place}.png", sim, scans[len(scans) // 2])
    if args.pictures:
        from pathlib import Path

        picture_patterns(Path(args.pictures) / "livox_patterns.png")
    if args.gicp_pairs:
        gicp_table(args.seed, args.gicp_pairs, args.gicp_voxel, args.gicp_max_corr)
    return 0


def gicp_table(seed: int, pairs: int, voxel: float = 0.0, max_corr: float = 0.0) -> None:
    """GICP (``SmallGicpRegistration("gicp")``) started at the truth on compensated pairs 0.5 s apart: the share
    that stays within 1 deg / 0.3 m (a place too poor in structure slides away) and the worst pair."""
    from deepbbs_ros.baselines import SmallGicpRegistration
    from deepbbs_ros.config import Config
    from deepbbs_ros.metrics import pair_errors
    from deepbbs_ros.sim.patterns import make_sensor
    from deepbbs_ros.sim.places import PLACES
    from deepbbs_ros.sim.rig import RigSimulator

    sets = {"eval.threads": 1, **({"eval.baseline_voxel_size": voxel} if voxel else {}),
            **({"eval.baseline_max_corr_dist": max_corr} if max_corr else {})}
    gicp = SmallGicpRegistration("gicp", Config().replace(**sets))
    rigs = (("os1_64", "wheeled"), ("mid360", "legged"), ("avia", "handheld"))
    print("\n| place | " + " | ".join(f"{s} {m}: within 1 deg / 0.3 m (worst deg / m)" for s, m in rigs) + " |")
    print("|---|" + "---|" * len(rigs))
    for place in PLACES:
        cells = []
        for sensor, mount in rigs:
            sim = RigSimulator(place, seed, make_sensor(sensor), mount, frames=10 * pairs + 6, compensate=True)
            ok, worst = 0, (0.0, 0.0)
            for i in range(pairs):
                a, b = sim.scan_at(10 * i), sim.scan_at(10 * i + 5)
                T_gt = np.linalg.inv(a.T_world_lidar) @ b.T_world_lidar
                r, t = pair_errors(gicp.register(b.points, a.points, T_init=T_gt).T_target_source, T_gt)
                ok += int(r <= 1.0 and t <= 0.3)
                worst = max(worst, (float(r), float(t)), key=lambda e: max(e[0], e[1] / 0.3))
            cells.append(f"{ok}/{pairs} ({worst[0]:.2f} / {worst[1]:.2f})")
        print(f"| {place} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
