"""The localization benchmark's simulated maps (scripts/benchmarks/localization.py, module docstring): a map of a first
drive's scans and queries from second drives through the same world, built once and cached."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from _localization_data import GEN_VERSION, KINDS, MapData, Query, _load, _save, transform, voxel_down

LANE_SHIFT = {"urban": -3.6, "suburban": -1.5, "highway": 3.6, "open_road": 1.2}  # m, the other lane's offset
SAME_LANE_SHIFT = 0.4  # m: "same-lane" queries drive the map drive's lane on a slightly different line


def _frame_at(sim, s_target: float) -> int:
    """The frame of ``sim`` whose stamp is closest to the moment its trajectory passes arc length ``s_target``."""
    tr = sim.trajectory
    s = -tr.s_grid if tr.reverse else tr.s_grid
    i = int(np.searchsorted(s, -s_target if tr.reverse else s_target))
    t = tr.t_grid[min(i, len(tr.t_grid) - 1)]
    return int(np.clip(round(t / sim.period), 0, sim.frames - 1))


def _straight_stretches(world, lo: float, hi: float, half: float = 60.0) -> np.ndarray:
    """Arc lengths in [lo, hi] with no curvature and no junction within ``half`` m: long straight stretches."""
    r = world.route
    straight = np.abs(r.kappa) < 1e-9
    ok = np.ones(len(r.s), bool)
    w = int(half / r.DS)
    bad = ~straight
    if bad.any():  # dilate the curved samples by +-half
        c = np.convolve(bad.astype(np.int64), np.ones(2 * w + 1, np.int64), mode="same")
        ok &= c == 0
    for j in world.junctions:
        ok &= np.abs(r.s - j["s"]) > half
    for si, _ in world.intersections:
        ok &= np.abs(r.s - si) > half
    ok &= (r.s >= lo) & (r.s <= hi)
    return r.s[ok]


def sim_map(scene: str, seed: int, args, log=print, lidar=None) -> MapData:
    """Build (or load from the cache) the map and the queries of one simulated scene; see the module docstring.
    ``args``: map_length, map_step, map_range, map_voxel, prefixes, queries, repetitive, cache; ``lidar``: a
    LidarConfig (default HDL-64)."""
    from deepbbs_ros.sim import WORLDS_VERSION
    from deepbbs_ros.sim.simulator import DriveSimulator

    lid = f"_{lidar.name}{lidar.beams}" if lidar is not None else ""
    key = (f"loc_sim_{scene}_{seed}{lid}_L{args.map_length:g}_st{args.map_step:g}_r{args.map_range:g}"
           f"_v{args.map_voxel:g}"
           f"_q{args.queries}_rep{args.repetitive}_b{args.boot_scans}x{args.boot_step:g}_w{WORLDS_VERSION}"
           f"_g{GEN_VERSION}.npz")
    path = Path(args.cache).expanduser() / key
    if path.is_file():
        return _load(path, scene)
    t0 = time.perf_counter()
    world_frames = int(np.ceil(args.map_length / 6.0 * 10)) + 100  # a drive long enough at >= 6 m/s on average
    sim = DriveSimulator(scene, seed, lidar, frames=world_frames, compensate=True)
    P = np.array([sim.pose_at(k) for k in range(world_frames)])
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1))])
    if dist[-1] < args.map_length:
        raise SystemExit(f"{scene}: the drive covers only {dist[-1]:.0f} m (< --map-length)")
    last = int(np.searchsorted(dist, args.map_length))
    keys, prev = [], -1e9
    for k in range(last + 1):
        if dist[k] - prev >= args.map_step:
            keys.append(k)
            prev = dist[k]
    bounds = sorted({int(b) for b in args.prefixes if b < args.map_length} | {int(args.map_length)})
    chunks: dict[int, list[np.ndarray]] = {b: [] for b in bounds}
    key_bound: list[int] = []
    for n, k in enumerate(keys):
        pts = sim.scan_at(k).points
        r = np.linalg.norm(pts, axis=1)
        pts = pts[(r > 2.0) & (r < args.map_range)]
        b = next((b for b in bounds if dist[k] <= b + 1e-6), bounds[-1])  # the last scan may pass the length
        key_bound.append(b)
        chunks[b].append(transform(pts, P[k]))
        if len(chunks[b]) >= 40:  # keep memory bounded
            chunks[b] = [voxel_down(np.concatenate(chunks[b]), args.map_voxel)]
        if n % 100 == 0:
            log(f"  {scene}: map scan {n + 1}/{len(keys)} ({time.perf_counter() - t0:.0f} s)")
    parts = {b: voxel_down(np.concatenate(chunks[b]), args.map_voxel) for b in bounds}
    prefixes = {}
    for b in bounds:
        pts = voxel_down(np.concatenate([parts[c] for c in bounds if c <= b]), args.map_voxel)
        prefixes[b] = (pts, P[[k for k, kb in zip(keys, key_bound) if kb <= b]])
    full_pts, full_traj = prefixes[bounds[-1]]
    # queries: second drives through the same world on other days, spread over the map's stretch of road
    s_map = np.interp(np.array([k * sim.period for k in (0, last)]), sim.trajectory.t_grid, sim.trajectory.s_grid)
    lo, hi = float(s_map[0]) + 20.0, float(s_map[1]) - 20.0
    ego = sim.world.style.ego_offset
    drives = {}
    for frames in range(last + 1, 10, -max(1, last // 10)):
        try:
            drives["reverse"] = DriveSimulator(scene, seed, lidar, frames=frames, compensate=True,
                                               world_frames=world_frames, reverse=True, s_start=float(s_map[1]), day=1)
            break
        except Exception:  # the route ends before the drive does: a shorter one
            continue
    drives["lane"] = DriveSimulator(scene, seed, lidar, frames=last + 1, compensate=True, world_frames=world_frames,
                                    lane_offset=ego + LANE_SHIFT[scene], day=2)
    drives["same-lane"] = DriveSimulator(scene, seed, lidar, frames=last + 1, compensate=True,
                                         world_frames=world_frames, lane_offset=ego + SAME_LANE_SHIFT, day=3)
    kinds = list(KINDS)
    targets = [(float(s), kinds[i % len(kinds)], "") for i, s in enumerate(np.linspace(lo, hi, args.queries))]
    straight = _straight_stretches(sim.world, lo, hi)
    label = {"highway": "straight highway", "suburban": "suburban street (row of houses)"}.get(scene, "")
    if label and args.repetitive > 0 and len(straight):
        # spread inside the straight stretches (not at their ends, where an evenly spread query may be already), and
        # none where a query of the same kind is already (the same scan twice would count twice)
        picks = np.unique(np.round(np.linspace(0, len(straight) - 1, args.repetitive + 2)[1:-1]).astype(int))
        for j, i in enumerate(picks):
            s, kind = float(straight[i]), kinds[j % len(kinds)]
            if all(k != kind or abs(s - t) >= 5.0 for t, k, _ in targets):
                targets.append((s, kind, label))
    queries = []
    for s, kind, rep in targets:
        d = drives[kind]
        if d.trajectory.reverse and s < d.trajectory.s_grid.min():
            continue  # the shortened reverse drive does not get there
        k = _frame_at(d, s)
        if not rep and label and len(straight) and np.min(np.abs(straight - s)) < 5.0:
            rep = label  # an evenly spread query that happens to be on a straight stretch
        follow = []
        for j in range(1, args.boot_scans + 1):  # the scans the node would take next while it is not placed yet
            kj = k + int(round(j * args.boot_step / d.period))
            if kj < d.frames:
                follow.append((j * args.boot_step, d.scan_at(kj).points.astype(np.float32), d.pose_at(kj)))
        queries.append(Query(d.scan_at(k).points.astype(np.float32), d.pose_at(k), scene, kind, s - lo + 20.0, rep,
                             follow))
    data = MapData(scene, full_pts, full_traj, queries, {b: prefixes[b] for b in bounds[:-1]}, float(dist[last]))
    path.parent.mkdir(parents=True, exist_ok=True)
    _save(path, data)
    log(f"  {scene}: map {len(full_pts)} points from {len(keys)} scans over {dist[last]:.0f} m, "
        f"{len(queries)} queries ({time.perf_counter() - t0:.0f} s, cached in {path})")
    return data
