"""The localization benchmark's data (scripts/benchmarks/localization.py): a query scan, a prior map with its queries,
their npz cache, and the real maps (KITTI places and a reference pair pooled far apart; a handheld Livox walk). The
simulated maps are _localization_sim.py's."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

GEN_VERSION = 4  # bumped whenever the generated maps / queries change (cache key)
KINDS = ("reverse", "lane", "same-lane")  # the simulated queries' drives, in turn along the map


@dataclass
class Query:
    """One query scan: ``points`` (N, 3) float32 in its sensor frame, ``T_map_scan`` (4, 4) its true pose in the
    map frame; ``place`` the map place it belongs to (scene or sequence), ``kind`` how it was taken
    ("reverse", "lane", "kitti-odd", "pair-source"), ``s`` metres along the map drive (nan for real data),
    ``repetitive`` a label of a repetitive place ("" if none)."""

    points: np.ndarray
    T_map_scan: np.ndarray
    place: str
    kind: str
    s: float = float("nan")
    repetitive: str = ""
    #: the same drive's scans ``--boot-step`` s, 2 x ``--boot-step`` s, ... later: (seconds after the query, points,
    #: T_map_scan) (the node's next scans while it is not placed yet: the boot protocol)
    follow: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)


@dataclass
class MapData:
    """A prior map and its queries. ``points`` (M, 3) float32 map frame; ``trajectory`` (K, 4, 4) T_map_sensor of
    the scans the map was built from (keyframes); ``prefixes``: length (m) -> (points, trajectory) of the map
    built from the first metres of the drive only."""

    name: str
    points: np.ndarray
    trajectory: np.ndarray
    queries: list[Query]
    prefixes: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    length_m: float = float("nan")


def voxel_down(points: np.ndarray, voxel: float) -> np.ndarray:
    """(N, 3) -> (M, 3) float32, one point per ``voxel`` m cell (kiss_icp's voxel_down_sample)."""
    from kiss_icp.voxelization import voxel_down_sample

    if len(points) == 0:
        return np.zeros((0, 3), np.float32)
    return np.asarray(voxel_down_sample(np.ascontiguousarray(points, dtype=np.float64), float(voxel)), np.float32)


def transform(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    return (points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)


def _save(path: Path, data: MapData) -> None:
    q = data.queries
    pre = sorted(data.prefixes)
    np.savez_compressed(
        path, points=data.points, trajectory=data.trajectory, length_m=data.length_m,
        q_points=np.concatenate([x.points for x in q]) if q else np.zeros((0, 3), np.float32),
        q_sizes=np.array([len(x.points) for x in q], np.int64),
        q_T=np.array([x.T_map_scan for x in q]).reshape(-1, 4, 4),
        q_place=np.array([x.place for x in q]), q_kind=np.array([x.kind for x in q]),
        q_s=np.array([x.s for x in q], np.float64), q_rep=np.array([x.repetitive for x in q]),
        prefix_lengths=np.array(pre, np.int64),
        f_of=np.array([i for i, x in enumerate(q) for _ in x.follow], np.int64),
        f_dt=np.array([f[0] for x in q for f in x.follow], np.float64),
        f_sizes=np.array([len(f[1]) for x in q for f in x.follow], np.int64),
        f_points=np.concatenate([f[1] for x in q for f in x.follow] or [np.zeros((0, 3), np.float32)]),
        f_T=np.array([f[2] for x in q for f in x.follow]).reshape(-1, 4, 4),
        **{f"prefix_{L}_points": data.prefixes[L][0] for L in pre},
        **{f"prefix_{L}_trajectory": data.prefixes[L][1] for L in pre},
    )  # fmt: skip


def _load(path: Path, name: str) -> MapData:
    z = dict(np.load(path))  # every array read (and decompressed) once
    offs = np.concatenate([[0], np.cumsum(z["q_sizes"])])
    queries = [Query(z["q_points"][offs[i]:offs[i + 1]], z["q_T"][i], str(z["q_place"][i]), str(z["q_kind"][i]),
                     float(z["q_s"][i]), str(z["q_rep"][i])) for i in range(len(z["q_sizes"]))]
    prefixes = {int(L): (z[f"prefix_{L}_points"], z[f"prefix_{L}_trajectory"]) for L in z["prefix_lengths"]}
    foffs = np.concatenate([[0], np.cumsum(z["f_sizes"])])
    for j, i in enumerate(z["f_of"]):
        queries[int(i)].follow.append((float(z["f_dt"][j]), z["f_points"][foffs[j]:foffs[j + 1]], z["f_T"][j]))
    return MapData(name, z["points"], z["trajectory"], queries, prefixes, float(z["length_m"]))


def yaw_move(yaw: float, x: float, y: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:2, 3] = x, y
    return T


def real_map(args) -> MapData | None:
    """One map pooled from the real places (read from their folders, never copied): even KITTI scans and the
    pair's target, each place moved ``--spacing`` m from the last with a random yaw; odd scans and the pair's
    source as queries."""
    from deepbbs_ros.datasets import open_source

    places = []  # (name, [(points, T_place_scan, is_map)])
    for folder in args.kitti:
        scans = []
        for i, s in enumerate(open_source(folder)):
            if i >= args.kitti_scans:
                break
            scans.append((np.asarray(s.points, np.float32), np.asarray(s.T_world_lidar, np.float64), i % 2 == 0))
        places.append((f"kitti_{Path(folder).name}", scans))
    if args.pair:
        target, source, T = _common.read_reference_pair(args.pair)
        places.append(("pair", [(target, np.eye(4), True), (source, T, False)]))
    if not places:
        return None
    rng = np.random.default_rng(args.seed)
    pts, traj, queries = [], [], []
    for n, (name, scans) in enumerate(places):
        first = np.linalg.inv(scans[0][1])  # each place starts at its first scan...
        move = yaw_move(rng.uniform(-np.pi, np.pi), n * args.spacing, 0.0) @ first  # ...moved far away
        for p, T, is_map in scans:
            T_map = move @ T
            if is_map:
                r = np.linalg.norm(p, axis=1)
                pts.append(transform(p[(r > 1.0) & (r < args.map_range)], T_map))
                traj.append(T_map)
            else:
                queries.append(Query(p, T_map, name, "pair-source" if name == "pair" else "kitti-odd"))
    return MapData("real", voxel_down(np.concatenate(pts), args.map_voxel), np.array(traj), queries)


def livox_map(args) -> MapData | None:
    """A map of a handheld recording's every other keyframe at its pose (``--livox``: a KITTI-layout folder, read
    from it, never copied), its other keyframes, every ``--livox-every``-th, as queries ("livox-odd")."""
    from deepbbs_ros.datasets import open_source

    if not args.livox:
        return None
    pts, traj, queries = [], [], []
    for i, s in enumerate(open_source(args.livox)):
        p, T = np.asarray(s.points, np.float32), np.asarray(s.T_world_lidar, np.float64)
        if i % 2 == 0:
            r = np.linalg.norm(p, axis=1)
            pts.append(transform(p[(r > 1.0) & (r < args.map_range)], T))
            traj.append(T)
        elif (i // 2) % args.livox_every == 0:
            queries.append(Query(p, T, "livox", "livox-odd"))
    return MapData("livox", voxel_down(np.concatenate(pts), args.map_voxel), np.array(traj), queries)
