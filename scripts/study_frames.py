"""Frame sets for scripts/verdict_study.py and scripts/global_study.py (real and simulated raw scans).

A *set* is one place: a list of raw scans (N, 3) float32 with their ground-truth poses ``T_world_lidar``.
Pairs within a set are true pairs (the same place seen twice); pairs across sets are pairs of two different
places. Real sets are read from a folder outside the repository (``--realdata``: ``kitti/00``, ``kitti/02``,
``hdl32_pair``; never copied into the project); simulated sets are held-out drives of every scene type
(test seeds ``90000 + i``), 8 frames about 2 m apart each, cached as an npz file (``--cache``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def kitti_set(folder: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    from deepbbs_ros.datasets import open_source

    return [(np.asarray(s.points, np.float32), np.asarray(s.T_world_lidar, np.float64)) for s in open_source(folder)]


def hdl32_set(folder: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """Target at the origin, source at the reference ``relative.txt`` (T_target_source)."""
    from deepbbs_ros.datasets.pcd import read_pcd_points

    T = np.loadtxt(folder / "relative.txt").reshape(4, 4)
    tgt = read_pcd_points(folder / "251370668.pcd")[0].astype(np.float32)
    src = read_pcd_points(folder / "251371071.pcd")[0].astype(np.float32)
    return [(tgt, np.eye(4)), (src, T)]


def sim_sets(cache: Path, drives_per_scene: int = 2, frames: int = 8, spacing: float = 2.0,
             seed_base: int = 90_000) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Held-out simulated drives (raw sweeps with motion distortion), ``frames`` scans ``spacing`` m apart."""
    if cache.is_file():
        data = np.load(cache, allow_pickle=True)
        return data["sets"].item()
    from deepbbs_ros.sim import SCENES
    from deepbbs_ros.sim.simulator import DriveSimulator

    sets: dict[str, list] = {}
    for d in range(drives_per_scene * len(SCENES)):
        scene, seed = SCENES[d % len(SCENES)], seed_base + d
        sim = DriveSimulator(scene, seed, frames=200)
        picks, last = [], None
        for k in range(20, 200):
            p = sim.pose_at(k)[:3, 3]
            if last is None or np.linalg.norm(p - last) >= spacing:
                picks.append(k)
                last = p
            if len(picks) == frames:
                break
        sets[f"sim_{scene}_{seed}"] = [(sim.scan_at(k).points.astype(np.float32), sim.pose_at(k)) for k in picks]
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, sets=np.array(sets, dtype=object))
    return sets


def all_sets(realdata: Path, cache: Path, drives_per_scene: int = 2) -> dict[str, list]:
    sets: dict[str, list] = {}
    for seq in ("00", "02"):
        if (realdata / "kitti" / seq).is_dir():
            sets[f"kitti_{seq}"] = kitti_set(realdata / "kitti" / seq)
    if (realdata / "hdl32_pair").is_dir():
        sets["hdl32"] = hdl32_set(realdata / "hdl32_pair")
    sets.update(sim_sets(cache, drives_per_scene))
    return sets


def true_pairs(frames: list, max_dist: float) -> list[tuple[int, int, np.ndarray, float]]:
    """Every (source i, target j < i) of one set at most ``max_dist`` m apart: (i, j, T_target_source, dist)."""
    out = []
    for i in range(len(frames)):
        for j in range(i):
            T = np.linalg.inv(frames[j][1]) @ frames[i][1]
            d = float(np.linalg.norm(T[:3, 3]))
            if d <= max_dist:
                out.append((i, j, T, d))
    return out


def yaw_shift(yaw_deg: float, shift: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    a = np.radians(yaw_deg)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:2, 3] = shift
    return T
