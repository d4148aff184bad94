#!/usr/bin/env python3
"""Statistics of the simulated worlds per scene type, compared with what real drives look like.

    python scripts/sim_stats.py                              # HDL-64, 3 seeds, all scene types
    python scripts/sim_stats.py --scenes highway --pairs 30
    python scripts/sim_stats.py --pictures docs/sim          # also one PNG per scene type

Per scene type: the share of returns farther than 0.3 m from the ground plane (RANSAC fit to the
points within 20 m, as ``deepbbs_ros.core.preprocess`` does; real HDL-64E drives keep 28-55 %),
points per scan, GICP (``SmallGicpRegistration("gicp")``) started at the ground truth on pairs up
to 5 m apart: share of pairs that stay within 1 deg / 0.3 m, and simulation throughput (frames/s).
Scans are motion-distorted and compensated (``compensate=True``), as the training data is.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def off_ground_share(points: np.ndarray, seed: int = 0) -> float:
    """Share of ``points`` (N, 3) farther than 0.3 m from the RANSAC ground plane (fit within 20 m)."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.preprocess import fit_ground_plane

    pp = Config().preprocess
    plane = fit_ground_plane(points, pp, seed=seed)
    d = points.astype(np.float64) @ plane[:3] + plane[3]
    return float(np.mean(np.abs(d) > 0.3))


def picture(path, scene: str, sim, scan) -> None:
    """One scan from above (colour = height) beside the static mesh from above around the sensor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    T = scan.T_world_lidar
    w = scan.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    c = T[:2, 3]
    R = 80.0
    fig, ax = plt.subplots(1, 2, figsize=(12, 6), dpi=70)
    p = w[:, :2] - c
    z = w[:, 2] - (T[2, 3] - sim.lidar.mount_height)
    o = np.argsort(z)
    ax[0].scatter(p[o, 0], p[o, 1], c=np.clip(z[o], -2, 12), s=0.15, cmap="viridis", linewidths=0, rasterized=True)
    ax[0].set_title(f"{scene}: one HDL-64 scan ({len(w)} points), colour = height (-2..12 m)")
    v, f, _ = sim.world.static_mesh(c, R * 1.5)
    tri = v[f]
    zmax = tri[:, :, 2].max(1)
    ground = sim.world.terrain.height(tri[:, :, 0].mean(1), tri[:, :, 1].mean(1))
    hgt = zmax - ground
    keep = (np.abs(tri[:, :, :2] - c).max((1, 2)) < R * 1.3) & (hgt > 0.25)
    o = np.argsort(zmax[keep])
    polys = tri[keep][o][:, :, :2] - c
    pc = PolyCollection(polys, array=np.clip(hgt[keep][o], 0, 15), cmap="terrain_r", edgecolors="none")
    ax[1].add_collection(pc)
    rt = sim.world.route
    ax[1].plot(rt.xy[:, 0] - c[0], rt.xy[:, 1] - c[1], "k-", lw=0.6)
    ax[1].set_title("static mesh from above (objects > 0.25 m, colour = height 0..15 m)")
    for a in ax:
        a.set_xlim(-R, R)
        a.set_ylim(-R, R)
        a.set_aspect("equal")
        a.plot([0], [0], "r^", ms=6)
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", default=None)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--scans", type=int, default=4, help="scans per seed for the off-ground share")
    p.add_argument("--pairs", type=int, default=30, help="GICP pairs per scene type (spread over the seeds)")
    p.add_argument("--frames", type=int, default=120, help="frames per drive (pairs and scans are picked in it)")
    p.add_argument("--bench-frames", type=int, default=20, help="frames timed for the throughput")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--pictures", default="", help="folder for one PNG per scene type ('' = none)")
    args = p.parse_args(argv)

    from deepbbs_ros.baselines import SmallGicpRegistration
    from deepbbs_ros.config import Config
    from deepbbs_ros.metrics import pair_errors
    from deepbbs_ros.sim import SCENES, DriveSimulator, LidarConfig

    scenes = args.scenes or list(SCENES)
    cfg = Config().replace(**{"eval.threads": args.threads})
    gicp = SmallGicpRegistration("gicp", cfg)
    rows = []
    for scene in scenes:
        shares, npts, ok, n_pairs, errs = [], [], 0, 0, []
        t_build, fps = 0.0, 0.0
        for si, seed in enumerate(args.seeds):
            t0 = time.perf_counter()
            sim = DriveSimulator(scene, seed, LidarConfig.hdl64(), frames=args.frames, motion_distortion=True,
                                 compensate=True)
            t_build += time.perf_counter() - t0
            rng = np.random.default_rng([seed, 99])
            cache: dict[int, object] = {}

            def scan(k, sim=sim, cache=cache):
                if k not in cache:
                    cache[k] = sim.scan_at(k)
                return cache[k]

            if si == 0:  # throughput on consecutive frames
                t0 = time.perf_counter()
                for k in range(args.bench_frames):
                    scan(k)
                fps = args.bench_frames / (time.perf_counter() - t0)
            for k in np.linspace(0, args.frames - 1, args.scans).astype(int):
                s = scan(int(k))
                shares.append(off_ground_share(s.points, seed=int(k)))
                npts.append(len(s))
            n_here = args.pairs // len(args.seeds) + (1 if si < args.pairs % len(args.seeds) else 0)
            drawn: set[tuple[int, int]] = set()  # each pair once (a repeated bad pair would count twice)
            for _ in range(n_here):
                for _try in range(200):
                    a = int(rng.integers(0, args.frames))
                    b = int(rng.integers(max(0, a - 40), min(args.frames, a + 41)))
                    dist = np.linalg.norm(sim.pose_at(a)[:3, 3] - sim.pose_at(b)[:3, 3])
                    if a != b and dist <= 5.0 and (a, b) not in drawn:
                        break
                drawn.add((a, b))
                src, tgt = scan(b), scan(a)
                T_gt = np.linalg.inv(tgt.T_world_lidar) @ src.T_world_lidar
                T = gicp.register(src.points, tgt.points, T_init=T_gt).T_target_source
                r, t = pair_errors(T, T_gt)
                errs.append((float(r), float(t)))
                ok += int(r <= 1.0 and t <= 0.3)
                n_pairs += 1
            if si == 0 and args.pictures:
                from pathlib import Path

                Path(args.pictures).mkdir(parents=True, exist_ok=True)
                picture(Path(args.pictures) / f"{scene}.png", scene, sim, scan(args.frames // 2))
        e = np.array(errs).reshape(-1, 2)
        rows.append((scene, np.mean(shares), np.min(shares), np.max(shares), np.mean(npts), ok, n_pairs,
                     float(np.max(e[:, 0])) if len(e) else 0.0, float(np.max(e[:, 1])) if len(e) else 0.0,
                     fps, t_build / len(args.seeds)))
        r = rows[-1]
        print(f"{r[0]}: off-ground {100 * r[1]:.1f}% ({100 * r[2]:.1f}-{100 * r[3]:.1f}) over {len(shares)} scans, "
              f"{r[4]:.0f} pts, GICP from GT {r[5]}/{r[6]} (max {r[7]:.2f} deg / {r[8]:.2f} m), {r[9]:.2f} frames/s, "
              f"world {r[10]:.2f} s", file=sys.stderr, flush=True)
    print("| scene | off-ground share mean (min-max) | points/scan | GICP from GT within 1 deg / 0.3 m "
          "| worst pair (deg / m) | sim frames/s | world build (s) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {100 * r[1]:.1f} % ({100 * r[2]:.1f}-{100 * r[3]:.1f}) | {r[4]:.0f} | "
              f"{r[5]}/{r[6]} ({100 * r[5] / max(r[6], 1):.0f} %) | {r[7]:.2f} / {r[8]:.2f} | {r[9]:.2f} "
              f"| {r[10]:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
