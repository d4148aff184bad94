#!/usr/bin/env python3
"""Global localization in a prior map: MapLocalizer beside KISS-Matcher and FPFH + RANSAC, same queries, same run.

Data (generated once, cached as npz under ``--cache``; a rerun only measures):

* simulated, every scene type: a map of ``--map-length`` m of road (1 km) built from a first drive's scans at
  their ground-truth poses (one scan every ``--map-step`` m, cropped to ``--map-range`` m, voxel-downsampled to
  ``--map-voxel`` m); queries from second drives through the same world that never contributed to the map,
  spread evenly over it, in turn: driving back the other way in the opposite lane ("reverse"), in another lane of
  the same direction ("lane", 1.2-3.6 m over) and in the map drive's lane 0.4 m off its line ("same-lane"), each on
  another day (other parked cars, other traffic). Sweeps are
  compensated to their stamps. Highway and suburban drives get ``--repetitive`` extra queries on long
  straight stretches (away from curves and junctions): the repetitive places, reported apart.
* real (``--kitti``, ``--pair``): one pooled map of several places, each moved far from the others (``--spacing``
  m apart, a random yaw, fixed seed): the even scans of each KITTI sequence, and the target of the reference
  pair; the odd scans and the pair's source are the queries (a query must find its place as well as its pose).

Methods, from no initial guess (each query alone): ``maplocalizer`` (deepbbs_ros.core.localization.MapLocalizer,
built once per map with the map drive's keyframe poses; its verdict accepts or says why not);
``kiss-matcher+gicp`` (KISS-Matcher registering the scan against the whole map, then small_gicp GICP against
the whole map; accepted when KISS-Matcher says its solution is valid); ``fpfh-ransac+gicp`` (Open3D's
FPFH features and registration_ransac_based_on_feature_matching against the whole map, then GICP; Open3D has
no acceptance test: every answer counts as published). The baselines run on every ``--baseline-every``-th
query, each in a child process with a ``--baseline-timeout`` s limit (a timeout counts as no pose);
``--baseline-prior R`` gives them the map within R m of a coarse prior instead (context only).
``--grid-places``: MapLocalizer without the map drive's trajectory (candidate places over the map's drivable space);
``--outside N``: each map also answers N queries of another map (no pose is right, timed). Every method is
timed as a user runs it and every answer is the same on any machine and in every run: MapLocalizer is timed as
configured (GICP on every core) and answered by a twin that solves GICP on one thread (``registration.exact_gicp``;
its k-d trees and covariances, the same on any number of threads, use every core), whose own time is reported too
(``exact_time_s_*``); a baseline answers from a child process on one CPU (Open3D's RANSAC seeded) and is timed by a
second child on every core (:class:`ExactTimed`). ``--inexact``: the timed calls answer, one child per baseline.

Figures (``localization.json`` under ``--out``), per method and map: share placed within 1 deg / 0.3 m (valid
and right), wrong poses accepted (valid but off), no pose (and how many of those "ambiguous"), timeouts, time per
query from no guess (the time to a first pose) p50 / p95, the same for the repetitive places, and how the time
grows with the map (the queries of the first ``--prefixes`` m against maps of those lengths). Each query is one
scan alone; the boot protocol (``boot`` in the figures, MapLocalizer only) is the node's case: a simulated query
with no pose goes on with the same drive's scans ``--boot-step`` s later (up to ``--boot-scans`` of them), each
searched once it has arrived and the search before it has ended, until one is placed or wrong; its time to the
first pose counts from the query scan's arrival. ``localization.png``
beside it: placed / wrong / no pose and the time p50 / p95 per map and method.

    python scripts/benchmarks/localization.py --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 --pair PATH/TO/pair \\
        --cache ~/.cache/deepbbs_ros/bench --out results/benchmarks
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

GEN_VERSION = 4  # bumped whenever the generated maps / queries change (cache key)
ROT_OK_DEG, TRANS_OK_M = 1.0, 0.3
METHODS = ("maplocalizer", "kiss-matcher+gicp", "fpfh-ransac+gicp")
LABELS = {"maplocalizer": "MapLocalizer (DeepBBS++)", "kiss-matcher+gicp": "KISS-Matcher + GICP (scan to map)",
          "fpfh-ransac+gicp": "FPFH + RANSAC (Open3D) + GICP (scan to map)"}
LANE_SHIFT = {"urban": -3.6, "suburban": -1.5, "highway": 3.6, "open_road": 1.2}  # m, the other lane's offset
SAME_LANE_SHIFT = 0.4  # m: "same-lane" queries drive the map drive's lane on a slightly different line
RANSAC_SEED = 1  # Open3D's random generator, seeded before every RANSAC
KINDS = ("reverse", "lane", "same-lane")  # the simulated queries' drives, in turn along the map


# ---- data --------------------------------------------------------------------------------------------------------
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


# ---- methods -----------------------------------------------------------------------------------------------------
@dataclass
class Answer:
    """What a method said about one query: ``T_map_scan`` (4, 4) or None, ``valid`` (it would publish it),
    ``reason`` (why not, when it says), ``time_s`` (wall clock of the call), ``timeout``."""

    T_map_scan: np.ndarray | None
    valid: bool
    reason: str = ""
    time_s: float = float("nan")
    timeout: bool = False
    exact_time_s: float = float("nan")  # MapLocalizer: the time of the twin that answered (GICP on one thread)
    cpu_s: float = float("nan")  # MapLocalizer: the timed call's CPU time (this process and its network process)
    exact_cpu_s: float = float("nan")  # the twin's CPU time
    probability: float = float("nan")  # MapLocalizer: the map verdict's probability of its answer


_REGISTRATION: dict = {}  # one DeepBBSRegistration (model loaded and warmed up once) shared by every map


def _registration(config):
    """One DeepBBSRegistration per distinct config (model loaded and warmed up once), shared by every map."""
    from deepbbs_ros.core.registration import DeepBBSRegistration

    key = config.to_yaml()
    if key not in _REGISTRATION:
        reg = DeepBBSRegistration(config)
        reg.warmup()
        _REGISTRATION[key] = reg
    return _REGISTRATION[key]


def cpu_seconds(loc) -> float:
    """CPU seconds used so far by this process and by the network process of ``loc``'s registration (when it has
    one): a search's CPU time is the difference around it, a figure the machine's load hardly changes."""
    cpu = time.process_time()
    proc = getattr(getattr(getattr(loc, "registration", None), "runner", None), "worker", None)
    if proc is not None:
        try:
            fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
            cpu += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime
        except (OSError, ValueError, IndexError):
            pass
    return cpu


class MapLocalizerMethod:
    """deepbbs_ros.core.localization.MapLocalizer, built once per map (``build_s``: the map's part, places,
    descriptors and GICP cloud; the model is loaded and warmed up once per run, before any query, and shared by every
    map). Each query is timed as configured; with ``exact`` (True unless ``--inexact``) a twin with
    ``registration.exact_gicp`` (GICP's solve on one thread: the same answer on any machine) answers it, its own time
    in ``exact_time_s``."""

    name = "maplocalizer"

    def __init__(self, points: np.ndarray, trajectory: np.ndarray | None, config=None, exact: bool = True) -> None:
        from deepbbs_ros.config import Config

        config = config or Config()
        twin = config.replace(**{"registration.exact_gicp": True}) if exact and not config.registration.exact_gicp \
            else None
        for cfg in (config, twin):  # the model loaded and warmed up before any map is timed
            if cfg is not None:
                _registration(cfg)
        t0 = time.perf_counter()
        self.loc = self._localizer(points, trajectory, config)
        self.build_s = time.perf_counter() - t0
        self.exact = None if twin is None else self._localizer(points, trajectory, twin)

    @staticmethod
    def _localizer(points: np.ndarray, trajectory: np.ndarray | None, config):
        from deepbbs_ros.core.localization import MapLocalizer

        return MapLocalizer(points, config, registration=_registration(config), trajectory=trajectory)

    def __call__(self, scan: np.ndarray) -> Answer:
        t0, c0 = time.perf_counter(), cpu_seconds(self.loc)
        r = self.loc.localize(scan)
        dt, cpu = time.perf_counter() - t0, cpu_seconds(self.loc) - c0
        if self.exact is None:
            return Answer(np.asarray(r.T_map_scan, np.float64), bool(r.valid), str(r.reason), dt, cpu_s=cpu,
                          probability=float(getattr(r, "probability", np.nan)))
        t0, c0 = time.perf_counter(), cpu_seconds(self.exact)
        r = self.exact.localize(scan)
        return Answer(np.asarray(r.T_map_scan, np.float64), bool(r.valid), str(r.reason), dt, cpu_s=cpu,
                      exact_time_s=time.perf_counter() - t0, exact_cpu_s=cpu_seconds(self.exact) - c0,
                      probability=float(getattr(r, "probability", np.nan)))


class Isolated(_common.Isolated):
    """A baseline in a child process (:class:`_common.Isolated`), one query at a time, ``timeout`` s each: the child
    builds ``solver_cls(points, **kwargs)`` (the map's preparation, ``build_s``) and answers
    ``solver.solve(scan, prior)`` -> (T_map_scan, accepted, reason)."""

    def __init__(self, name: str, solver_cls, points: np.ndarray, timeout: float, one_cpu: bool = False,
                 **kwargs) -> None:
        super().__init__(solver_cls, points, timeout=timeout, one_cpu=one_cpu, **kwargs)
        self.name = name

    def __call__(self, scan: np.ndarray, prior: tuple[np.ndarray, float] | None = None) -> Answer:
        """``prior``: optional (xy (2,), radius m): register against the map within radius of xy only."""
        r = self.ask(np.ascontiguousarray(scan), prior)
        if r.error:  # a timeout, a dead child or the solver's exception: no pose, with its message
            return Answer(None, False, r.error, r.seconds, r.timeout)
        T, ok, why = r.value
        return Answer(T, bool(ok), why, r.seconds)


EXACT_GUARD = 10.0  # the one-CPU child's time per query, in time limits of the every-core child


class ExactTimed:
    """A baseline's answer from a child on one CPU (its answers the same on any machine: TBB's and OpenMP's sums
    follow the CPUs), its time from a second child on every core (as a user runs it). The query times out when the
    every-core call does alone. The one-CPU call, asked only when the every-core one has answered in time, has
    ``EXACT_GUARD`` times as long: a guard against a hung child, not a time limit (with twice the time, a query the
    every-core call answered in 9 s timed out on one CPU in one run and answered in another)."""

    def __init__(self, name: str, solver_cls, points: np.ndarray, timeout: float, **kwargs) -> None:
        self.name = name
        self.exact = Isolated(name, solver_cls, points, EXACT_GUARD * timeout, True, **kwargs)
        self.timed = Isolated(name, solver_cls, points, timeout, False, **kwargs)

    @property
    def build_s(self) -> float:
        return self.timed.build_s

    def start(self) -> None:
        self.exact.start()
        self.timed.start()

    def close(self) -> None:
        self.exact.close()
        self.timed.close()

    def __call__(self, scan: np.ndarray, prior: tuple[np.ndarray, float] | None = None) -> Answer:
        timed = self.timed(scan, prior)
        if timed.timeout:
            return timed
        a = self.exact(scan, prior)
        return Answer(a.T_map_scan, a.valid, a.reason, timed.time_s, a.timeout)


class _Sleeper:
    """A stand-in solver that takes ``seconds`` per query (tests of the time limit)."""

    def __init__(self, points: np.ndarray, seconds: float = 30.0) -> None:
        self.seconds = seconds

    def solve(self, scan, prior=None):
        time.sleep(self.seconds)
        import os

        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 0
        return np.eye(4), True, f"{cpus} cpus"


def _map_gicp(points: np.ndarray, config):
    """The whole map as small_gicp's GICP target (no range crop), the baseline's voxel and neighbours."""
    from deepbbs_ros.core.polish import prepare_polish_cloud

    ev = config.eval
    return prepare_polish_cloud(points, ev.baseline_voxel_size, ev.baseline_neighbors, registration_type="GICP")


class KissMatcherSolver:
    """KISS-Matcher registering the scan against the whole map (voxel ``voxel`` m: its outdoor default 0.3 m
    takes over 30 s per query against a 300 m map here), then GICP (the project's small_gicp baseline) against
    the whole map; accepted when KISS-Matcher calls its solution valid. KISS-Matcher computes the map's
    features inside every call (its API takes two clouds), which is part of its time."""

    def __init__(self, points: np.ndarray, config=None, voxel: float = 1.0) -> None:
        from deepbbs_ros.baselines import KissMatcherRegistration, SmallGicpRegistration
        from deepbbs_ros.config import Config

        self.config = config or Config()
        self.km = KissMatcherRegistration("kiss-matcher", self.config)
        self.voxel = float(voxel)
        self.gicp = SmallGicpRegistration("gicp", self.config)
        self.map_points = np.ascontiguousarray(points, np.float32)
        self.map_gicp = _map_gicp(points, self.config)

    def solve(self, scan, prior=None):
        import kiss_matcher

        from deepbbs_ros.baselines import PreparedCloud

        src = self.km.preprocess(scan).points  # the preprocess crop, as the scan-to-scan baseline
        matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel_size=self.voxel))
        tgt = self.map_points
        if prior is not None:  # a coarse prior: the map within its radius only
            tgt = np.ascontiguousarray(tgt[np.linalg.norm(tgt[:, :2] - prior[0], axis=1) <= prior[1]])
        sol = matcher.estimate(src, tgt)
        T = np.eye(4)
        T[:3, :3] = np.asarray(sol.rotation, dtype=np.float64)
        T[:3, 3] = np.asarray(sol.translation, dtype=np.float64).reshape(3)
        g = self.gicp.align(self.gicp.preprocess(scan), PreparedCloud(self.map_gicp.cloud, self.map_gicp.tree,
                                                                      self.map_gicp.n_points, 0.0), T)
        ok = bool(sol.valid)
        return g.T_target_source, ok, "" if ok else \
            f"KISS-Matcher: solution not valid ({matcher.get_num_final_inliers()} inliers)"


class FpfhRansacSolver:
    """Open3D: FPFH features (voxel ``voxel`` m, normals within 2 voxels, features within 5) of the scan and the
    whole map (the map's once), registration_ransac_based_on_feature_matching (mutual filter off, edge-length
    and distance checkers, 1.5 voxels), then GICP against the whole map. No acceptance test of its own."""

    def __init__(self, points: np.ndarray, config=None, voxel: float = 1.0, iterations: int = 100000) -> None:
        import open3d as o3d  # noqa: F401  (ImportError / OSError: the caller skips this baseline)

        from deepbbs_ros.baselines import SmallGicpRegistration
        from deepbbs_ros.config import Config

        self.config = config or Config()
        self.voxel, self.iterations = float(voxel), int(iterations)
        self.map_down, self.map_fpfh = self._features(points)
        self.gicp = SmallGicpRegistration("gicp", self.config)
        self.map_gicp = _map_gicp(points, self.config)

    def _features(self, points: np.ndarray):
        import open3d as o3d

        reg = o3d.pipelines.registration
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
        down = pc.voxel_down_sample(self.voxel)
        down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * self.voxel, max_nn=30))
        fpfh = reg.compute_fpfh_feature(down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * self.voxel, max_nn=100))
        return down, fpfh

    def solve(self, scan, prior=None):
        import open3d as o3d

        from deepbbs_ros.baselines import PreparedCloud
        from deepbbs_ros.core.preprocess import crop_range

        reg = o3d.pipelines.registration
        pp = self.config.preprocess
        pts = scan[crop_range(scan, pp.min_range, pp.max_range)]
        down, fpfh = self._features(pts)
        d = 1.5 * self.voxel
        tgt, tgt_fpfh = self.map_down, self.map_fpfh
        if prior is not None:  # a coarse prior: the map within its radius only
            xy = np.asarray(self.map_down.points)[:, :2]
            idx = np.flatnonzero(np.linalg.norm(xy - prior[0], axis=1) <= prior[1])
            tgt = self.map_down.select_by_index(idx.tolist())
            tgt_fpfh = reg.Feature()
            tgt_fpfh.data = np.ascontiguousarray(self.map_fpfh.data[:, idx])
        o3d.utility.random.seed(RANSAC_SEED)  # each query's draws the same on every run
        res = reg.registration_ransac_based_on_feature_matching(
            down, tgt, fpfh, tgt_fpfh, False, d,
            reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(d)],
            reg.RANSACConvergenceCriteria(self.iterations, 0.999))
        T = np.asarray(res.transformation, np.float64)
        g = self.gicp.align(self.gicp.preprocess(scan), PreparedCloud(self.map_gicp.cloud, self.map_gicp.tree,
                                                                      self.map_gicp.n_points, 0.0), T)
        return g.T_target_source, True, ""  # no acceptance test: every answer is published


# ---- evaluation --------------------------------------------------------------------------------------------------
def judge(ans: Answer, q: Query) -> dict:
    """One row: errors against the truth and the verdict class (placed / wrong / none)."""
    from deepbbs_ros.metrics import pair_errors

    row = {"place": q.place, "kind": q.kind, "s": q.s, "repetitive": q.repetitive, "valid": ans.valid,
           "reason": ans.reason, "time_s": ans.time_s, "exact_time_s": ans.exact_time_s, "timeout": ans.timeout,
           "cpu_s": ans.cpu_s, "exact_cpu_s": ans.exact_cpu_s,
           "rot_err_deg": None,
           "trans_err_m": None, "probability": ans.probability}
    close = False
    if ans.T_map_scan is not None and np.all(np.isfinite(ans.T_map_scan)):
        r, t = pair_errors(ans.T_map_scan[None], q.T_map_scan[None])
        row["rot_err_deg"], row["trans_err_m"] = float(r[0]), float(t[0])
        close = bool(r[0] <= ROT_OK_DEG and t[0] <= TRANS_OK_M)
    row["close"] = close  # the pose is right, published or not
    row["outcome"] = ("placed" if close else "wrong") if ans.valid else "none"
    return row


def summarize(rows: list[dict]) -> dict:
    """Shares over ``rows`` (one method, one set of queries): placed, wrong accepted, no pose, ambiguous,
    timeouts, right but rejected; time per query p50 / p95 (all queries) and of the placed ones."""
    n = len(rows)
    if n == 0:
        return {"queries": 0}
    out = {"queries": n}
    for k in ("placed", "wrong", "none"):
        out[f"{k}_share"] = sum(r["outcome"] == k for r in rows) / n
    out["wrong_count"] = sum(r["outcome"] == "wrong" for r in rows)
    out["ambiguous_share"] = sum(r["outcome"] == "none" and r["reason"].startswith("ambiguous") for r in rows) / n
    out["timeout_count"] = sum(bool(r["timeout"]) for r in rows)
    out["right_but_rejected_share"] = sum(r["outcome"] == "none" and r["close"] for r in rows) / n
    t = np.array([r["time_s"] for r in rows if r["time_s"] is not None and np.isfinite(r["time_s"])])
    if len(t):
        out["time_s_p50"], out["time_s_p95"], out["time_s_max"] = (float(np.percentile(t, 50)),
                                                                   float(np.percentile(t, 95)), float(t.max()))
    te = np.array([r.get("exact_time_s", np.nan) for r in rows], dtype=np.float64)
    te = te[np.isfinite(te)]
    if len(te):  # MapLocalizer's exact twin (GICP on one thread)
        out["exact_time_s_p50"], out["exact_time_s_p95"] = float(np.percentile(te, 50)), float(np.percentile(te, 95))
    for k in ("cpu_s", "exact_cpu_s"):  # CPU time per query (this process and its network process)
        c = np.array([r.get(k, np.nan) for r in rows], dtype=np.float64)
        c = c[np.isfinite(c)]
        if len(c):
            out[f"{k}_p50"], out[f"{k}_p95"] = float(np.percentile(c, 50)), float(np.percentile(c, 95))
    tp = np.array([r["time_s"] for r in rows if r["outcome"] == "placed"])
    if len(tp):
        out["placed_time_s_p50"], out["placed_time_s_p95"] = float(np.percentile(tp, 50)), float(np.percentile(tp, 95))
    placed = [r for r in rows if r["outcome"] == "placed"]
    if placed:
        out["placed_rot_err_deg_mean"] = float(np.mean([r["rot_err_deg"] for r in placed]))
        out["placed_trans_err_m_mean"] = float(np.mean([r["trans_err_m"] for r in placed]))
    return out


def reliability(rows: list[dict], edges=(0.0, 0.05, 0.2, 0.5, 0.7, 0.9, 1.0)) -> dict:
    """The map verdict's reliability over ``rows``: per bin of the answer's probability, [answers, share right
    (within 1 deg / 0.3 m of the truth, published or not)]."""
    out = {}
    p = np.array([r.get("probability", np.nan) for r in rows], np.float64)
    right = np.array([r["close"] for r in rows], bool)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (p >= lo) & ((p < hi) | (hi >= 1.0) & (p <= 1.0))
        if m.any():
            out[f"{lo:g}-{hi:g}"] = [int(m.sum()), float(right[m].mean())]
    return out


def boot_rows(method, rows: list[dict], queries: list[Query], log=print, name: str = "") -> list[dict]:
    """The boot protocol (the node's case: it takes the next scans while it is not placed yet): a query that got no
    pose goes on with its drive's ``follow`` scans, each searched from no guess once it has arrived and the search
    before it has ended, until one is placed; -> per query the first pose's row, ``time_s`` from the query scan's
    arrival to that pose (the searches and the waits), ``scans`` how many were searched. A first answer that was
    placed or wrong stands (the node would publish it)."""
    out = []
    for row, q in zip(rows, queries):
        b = dict(row, scans=1)
        t = row["time_s"]
        if row["outcome"] == "none":
            for n, (dt, pts, T) in enumerate(q.follow, 2):
                ans = method(pts)
                start = max(dt, t)
                b = dict(judge(ans, Query(pts, T, q.place, q.kind, q.s, q.repetitive)), query=row["query"], scans=n)
                t = start + ans.time_s
                b["time_s"] = t
                if b["outcome"] != "none":
                    break
            log(f"  {name} boot [{q.kind}]: {b['outcome']} after {b['scans']} scan(s), {t:.2f} s")
        out.append(b)
    return out


def baseline_subset(n: int, every: int) -> list[int]:
    """Every ``every``-th of ``n`` queries, stepping one further each round of the query kinds, so that the subset
    holds every kind (plain multiples of 3 would all be one kind of 3)."""
    every = max(1, int(every))
    return [i for i in range(n) if (i + i // len(KINDS)) % every == 0]


def _prior(q: Query, i: int, radius: float) -> tuple[np.ndarray, float]:
    """A coarse position prior for query ``i``: within radius / 4 of the truth (fixed seed), with ``radius``."""
    rng = np.random.default_rng([i, 77])
    a, r = rng.uniform(0, 2 * np.pi), radius / 4 * np.sqrt(rng.uniform())
    return q.T_map_scan[:2, 3] + r * np.array([np.cos(a), np.sin(a)]), float(radius)


def make_method(name: str, points: np.ndarray, trajectory: np.ndarray | None, args, config=None, factories=None):
    """The method ``name`` prepared for this map, or a string saying why it cannot run here. ``factories``:
    optional name -> callable(points, trajectory) replacing the built-in methods (tests)."""
    try:
        if factories and name in factories:
            return factories[name](points, trajectory)
        exact = not getattr(args, "inexact", False)
        if name == "maplocalizer":
            return MapLocalizerMethod(points, None if args.grid_places else trajectory, config, exact=exact)
        kind = ExactTimed if exact else Isolated
        if name == "kiss-matcher+gicp":
            m = kind(name, KissMatcherSolver, points, args.baseline_timeout, config=config, voxel=args.km_voxel)
        elif name == "fpfh-ransac+gicp":
            m = kind(name, FpfhRansacSolver, points, args.baseline_timeout, config=config, voxel=args.fpfh_voxel)
        else:
            raise SystemExit(f"unknown method {name!r} (known: {', '.join(METHODS)})")
        m.start()  # build the map's side now (its own time, not a query's)
        return m
    except (ImportError, OSError) as err:
        return f"skipped: {err}"


def evaluate_map(data: MapData, methods: list[str], args, config=None, log=print, factories=None) -> dict:
    """Every method on the queries of one map (baselines on every ``--baseline-every``-th), then the map-size
    scaling of MapLocalizer: the queries within the shortest prefix against every prefix. The core function
    of the benchmark (tests/test_bench_localization.py runs it on a tiny map)."""
    fig: dict = {"map_points": len(data.points), "map_keyframes": len(data.trajectory), "map_length_m": data.length_m,
                 "queries": len(data.queries), "methods": {}, "rows": {}}
    for name in methods:
        idx = list(range(len(data.queries))) if name == "maplocalizer" else \
            baseline_subset(len(data.queries), args.baseline_every)
        m = make_method(name, data.points, data.trajectory, args, config, factories)
        if isinstance(m, str):
            fig["methods"][name] = {"note": m}
            log(f"  {name}: {m}")
            continue
        rows = []
        for n, i in enumerate(idx):
            q = data.queries[i]
            if name != "maplocalizer" and getattr(args, "baseline_prior", 0.0) > 0:
                row = judge(m(q.points, prior=_prior(q, i, args.baseline_prior)), q)
            else:
                row = judge(m(q.points), q)
            row["query"] = i
            rows.append(row)
            err = "" if row["rot_err_deg"] is None else f" {row['rot_err_deg']:.2f} deg {row['trans_err_m']:.2f} m"
            cpu = f" (CPU {row['cpu_s']:.2f} s)" if np.isfinite(row["cpu_s"]) else ""
            log(f"  {data.name} {name} {n + 1}/{len(idx)} [{q.kind}{' ' + q.repetitive if q.repetitive else ''}]: "
                f"{row['outcome']}{err} {row['time_s']:.2f} s{cpu} {row['reason'][:80]}")
        boot = boot_rows(m, rows, [data.queries[i] for i in idx], log, data.name) if name == "maplocalizer" else []
        if hasattr(m, "close"):
            m.close()
        s = summarize(rows)
        if name == "maplocalizer":
            s["reliability"] = reliability(rows)
            log(f"  {data.name} map verdict reliability (answer's probability: queries, share right): "
                + ", ".join(f"{k} {v[0]} {v[1]:.2f}" for k, v in s["reliability"].items()))
        if boot:
            s["boot"] = summarize(boot)
            fig.setdefault("boot_rows", {})[name] = boot
        s["build_s"] = m.build_s
        rep = [r for r in rows if r["repetitive"]]
        if rep:
            s["repetitive"] = summarize(rep)
        kinds = sorted({r["kind"] for r in rows})
        if len(kinds) > 1:
            s["by_kind"] = {k: summarize([r for r in rows if r["kind"] == k]) for k in kinds}
        fig["methods"][name] = s
        fig["rows"][name] = rows
    if "maplocalizer" in fig["rows"] and args.baseline_every > 1:  # the baselines' subset, for a like comparison
        sub = set(baseline_subset(len(data.queries), args.baseline_every))
        fig["methods"]["maplocalizer"]["baseline_subset"] = summarize(
            [r for r in fig["rows"]["maplocalizer"] if r["query"] in sub])
    if data.prefixes and args.scaling_queries > 0 and "maplocalizer" in fig["rows"]:
        shortest = min(data.prefixes)
        near = [i for i, q in enumerate(data.queries) if q.s <= shortest - 20.0][:args.scaling_queries]
        scaling = {}
        sizes = [(L, *data.prefixes[L]) for L in sorted(data.prefixes)] + [(int(round(data.length_m)), data.points,
                                                                            data.trajectory)]
        for L, pts, traj in sizes:
            m = make_method("maplocalizer", pts, traj, args, config, factories)
            if isinstance(m, str):
                break
            rows = [judge(m(data.queries[i].points), data.queries[i]) for i in near]
            s = summarize(rows)
            s.update(build_s=m.build_s, map_points=len(pts))
            scaling[str(L)] = s
            log(f"  {data.name} scaling {L} m: {len(pts)} points, build {m.build_s:.1f} s, "
                f"p50 {s.get('time_s_p50', float('nan')):.2f} s, placed {s.get('placed_share', 0):.2f}")
        fig["scaling"] = {"queries": near, "by_map_length_m": scaling}
    return fig


def evaluate_outside(data: MapData, outside: list[Query], args, config=None, log=print) -> dict:
    """MapLocalizer on scans from places that are not in the map (``outside``: other maps' queries): the right answer
    is no pose. -> {"queries", "none_share", "wrong_count", "time_s_p50", "time_s_p95", "time_s_max"} (the time to
    the "no pose")."""
    m = make_method("maplocalizer", data.points, data.trajectory, args, config)
    if isinstance(m, str):
        return {"note": m}
    times, cpus, wrong, probs = [], [], 0, []
    for n, q in enumerate(outside):
        ans = m(q.points)
        probs.append(ans.probability)
        times.append(ans.time_s)
        cpus.append(ans.cpu_s)
        wrong += bool(ans.valid)
        log(f"  {data.name} outside {n + 1}/{len(outside)} [{q.place}]: {'WRONG' if ans.valid else 'none'} "
            f"{ans.time_s:.2f} s (CPU {ans.cpu_s:.2f} s) {ans.reason[:70]}")
    t, c = np.array(times), np.array(cpus)
    return {"queries": len(outside), "none_share": 1.0 - wrong / max(len(outside), 1), "wrong_count": wrong,
            "time_s_p50": float(np.percentile(t, 50)), "time_s_p95": float(np.percentile(t, 95)),
            "cpu_s_p50": float(np.nanpercentile(c, 50)), "cpu_s_p95": float(np.nanpercentile(c, 95)),
            "time_s_max": float(t.max()), "probability_max": float(np.nanmax(probs)) if np.any(np.isfinite(probs))
            else float("nan")}


# ---- report ------------------------------------------------------------------------------------------------------
def report(figs: dict, methods: list[str]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="Global localization from no guess (placed: valid and within 1 deg / 0.3 m)")
    for col in ("map", "method", "queries", "placed", "wrong", "no pose", "ambiguous", "timeouts", "p50 s",
                "p95 s", "CPU p50 s", "CPU p95 s", "build s"):
        table.add_column(col, justify="right")

    def pct(v):
        return "-" if v is None else f"{100 * v:.0f} %"

    for mapname, fig in figs.items():
        for name in methods:
            s = fig["methods"].get(name, {})
            if "note" in s:
                table.add_row(mapname, name, s["note"][:40], *[""] * 10)
                continue
            for label, x in ((name, s), (f"{name} (repetitive)", s.get("repetitive"))):
                if not x or not x.get("queries"):
                    continue
                table.add_row(mapname, label, str(x["queries"]), pct(x.get("placed_share")), str(x.get("wrong_count")),
                              pct(x.get("none_share")), pct(x.get("ambiguous_share")), str(x.get("timeout_count")),
                              f"{x.get('time_s_p50', float('nan')):.2f}", f"{x.get('time_s_p95', float('nan')):.2f}",
                              f"{x.get('cpu_s_p50', float('nan')):.2f}", f"{x.get('cpu_s_p95', float('nan')):.2f}",
                              f"{s.get('build_s', float('nan')):.1f}" if x is s else "")
    Console(width=150).print(table)


def aggregate(figs: dict, methods: list[str]) -> dict:
    """Every map's rows pooled per method (simulated maps only, and everything)."""
    out = {}
    for name in methods:
        for label, maps in (("sim", [k for k in figs if k != "real"]), ("all", list(figs))):
            rows = [r for k in maps for r in figs[k]["rows"].get(name, [])]
            if rows:
                out.setdefault(name, {})[label] = summarize(rows)
            boot = [r for k in maps for r in figs[k].get("boot_rows", {}).get(name, [])]
            if boot:
                out[name][f"{label}_boot"] = summarize(boot)
    return out


def plot(fig: dict, out: Path) -> Path:
    """``out``/localization.png: per map and method the shares placed, wrong and with no pose (left) and the time
    to a first pose p50 / p95 (right), from ``fig`` (the figures of localization.json)."""
    plt = _common.pyplot()
    maps = list(fig["maps"])
    methods = [m for m in METHODS if any(m in fig["maps"][k]["methods"] for k in maps)]
    f, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    width = 0.8 / max(len(methods), 1)
    colors = {"placed": "tab:green", "wrong": "tab:red", "none": "0.75"}
    for j, name in enumerate(methods):
        x = np.arange(len(maps)) + (j - (len(methods) - 1) / 2) * width
        s = [fig["maps"][k]["methods"].get(name) or {} for k in maps]
        placed, wrong, none = (np.array([100 * (c.get(key) or 0.0) for c in s])
                               for key in ("placed_share", "wrong_share", "none_share"))
        for bottom, h, key in ((0, placed, "placed"), (placed, wrong, "wrong"), (placed + wrong, none, "none")):
            a.bar(x, h, width * 0.95, bottom=bottom, color=colors[key], edgecolor="k", lw=0.3,
                  label={"placed": "placed", "wrong": "wrong pose", "none": "no pose"}[key] if j == 0 else None)
        for xi in x:
            a.text(xi, 101, str(j + 1), ha="center", va="bottom", fontsize=7)
        p50 = [c.get("time_s_p50") or np.nan for c in s]
        p95 = [c.get("time_s_p95") or np.nan for c in s]
        b.bar(x, p95, width * 0.95, color=f"C{j}", alpha=0.35)
        b.bar(x, p50, width * 0.95, color=f"C{j}", label=f"{j + 1}: {LABELS.get(name, name)}")
    for ax in (a, b):
        ax.set_xticks(np.arange(len(maps)), maps)
    a.set_ylabel("% of the queries")
    a.set_ylim(0, 110)
    a.set_title("placed (1 deg / 0.3 m), wrong, no pose (bars: methods 1, 2, 3)")
    a.legend(fontsize=7, loc="lower left")
    b.axhline(1.0, color="k", lw=0.8, ls=":")
    b.axhline(3.0, color="k", lw=0.8, ls="--")
    b.set_ylabel("s per query from no guess")
    b.set_title("time to a first pose: p50 (dark), p95 (light); goal lines 1 s, 3 s")
    b.legend(fontsize=7, loc="upper left")
    return _common.save(f, out, "localization.png")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="*", default=["urban", "suburban", "highway", "open_road"],
                   help="simulated scene types, one 1 km map each")
    p.add_argument("--kitti", nargs="*", default=[], help="KITTI odometry sequence folders (velodyne/, poses.txt, "
                   "calib.txt) pooled into the real map, e.g. PATH/TO/kitti/00 PATH/TO/kitti/02")
    p.add_argument("--kitti-scans", type=int, default=10, help="the first scans of each KITTI sequence")
    p.add_argument("--pair", default=None, help="optional folder with a real pair: two .pcd files (target, source in "
                   "name order) and relative.txt (T_target_source); the target goes into the real map")
    p.add_argument("--livox", default=None, help="optional KITTI-layout folder of a handheld recording's keyframes: a "
                   "map of every other one at its pose, the others localized in it (a map of its own)")
    p.add_argument("--livox-every", type=int, default=8, help="with --livox: every n-th of the other keyframes is "
                   "a query")
    p.add_argument("--out", default="results/benchmarks", help="folder for localization.json")
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="cache of the generated maps and queries")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma list of {','.join(METHODS)}")
    p.add_argument("--queries", type=int, default=30, help="query scans per simulated scene, spread over the map")
    p.add_argument("--repetitive", type=int, default=6, help="extra queries on straight stretches (highway, "
                   "suburban)")
    p.add_argument("--map-length", type=float, default=1000.0, help="m of road per simulated map")
    p.add_argument("--map-step", type=float, default=2.5, help="m between the scans the map is built from")
    p.add_argument("--map-range", type=float, default=50.0, help="m, the map keeps each scan's points this close")
    p.add_argument("--map-voxel", type=float, default=0.2, help="m, voxel size of the map")
    p.add_argument("--prefixes", type=float, nargs="*", default=[250.0, 500.0], help="shorter maps (m) for the "
                   "time-versus-map-size figure")
    p.add_argument("--scaling-queries", type=int, default=4, help="queries per scene for the map-size figure")
    p.add_argument("--spacing", type=float, default=300.0, help="m between the real places in the pooled map")
    p.add_argument("--baseline-every", type=int, default=3, help="the baselines run on every n-th query")
    p.add_argument("--baseline-timeout", type=float, default=10.0, help="s per query and baseline")
    p.add_argument("--km-voxel", type=float, default=1.0, help="m, voxel of KISS-Matcher against the map")
    p.add_argument("--baseline-prior", type=float, default=0.0, help="m; > 0: the baselines register against the "
                   "map within this radius of a coarse prior (drawn within a quarter of it from the truth) instead "
                   "of the whole map; MapLocalizer never gets one")
    p.add_argument("--fpfh-voxel", type=float, default=1.0, help="m, voxel of the FPFH + RANSAC baseline")
    p.add_argument("--boot-scans", type=int, default=2, help="the boot protocol: a simulated query with no pose "
                   "goes on with up to this many later scans of its drive (0: single scans only)")
    p.add_argument("--boot-step", type=float, default=1.0, help="s between those scans (a search takes up to ~1 s; "
                   "the node takes the newest scan when it is free)")
    p.add_argument("--seed", type=int, default=1, help="seed of the real places' moves")
    p.add_argument("--sim-seed", type=int, default=None, help="world seed of the first scene (default: a held-out "
                   "test seed); the others follow")
    p.add_argument("--config", default=None, help="config YAML for MapLocalizer and the baselines")
    p.add_argument("--grid-places", action="store_true", help="MapLocalizer without the map drive's trajectory "
                   "(candidate places over the map's drivable space instead of keyframes)")
    p.add_argument("--inexact", action="store_true", help="the timed calls answer (MapLocalizer's GICP solve and "
                   "the baselines on every core): answers that can change from run to run (default: answered by "
                   "twins with registration.exact_gicp and baselines on one CPU, the same on any machine)")
    p.add_argument("--outside", type=int, default=0, help="also this many scans from places not in each map (the "
                   "next map's queries, spread over it; the last map gets the first's): no pose is right, "
                   "timed to the answer")
    p.add_argument("--outside-only", action="store_true", help="with --outside: measure only the scans outside")
    p.add_argument("--generate-only", action="store_true", help="build the cached maps and queries, measure nothing")
    p.add_argument("--quick", action="store_true", help="a smoke test: one scene, a 300 m map, 4 queries, no real "
                   "data unless given, baselines on 2 queries")
    args = p.parse_args(argv)
    if args.quick:
        args.scenes, args.map_length, args.queries, args.repetitive = args.scenes[:1], 300.0, 6, 0
        args.prefixes, args.scaling_queries, args.baseline_every = [150.0], 2, 2
    methods = [m for m in args.methods.split(",") if m]
    for m in methods:
        if m not in METHODS:
            raise SystemExit(f"unknown method {m!r} (known: {', '.join(METHODS)})")
    from deepbbs_ros.config import Config, load_config

    config = load_config(args.config) if args.config else Config()
    from deepbbs_ros.sim import SCENES
    from deepbbs_ros.train.cache import TEST_SEED_BASE

    base = TEST_SEED_BASE + 500 if args.sim_seed is None else args.sim_seed
    t_start = time.perf_counter()
    maps = {}
    for scene in args.scenes:
        maps[scene] = sim_map(scene, base + SCENES.index(scene), args)
    real = real_map(args)
    if real is not None:
        maps["real"] = real
    livox = livox_map(args)
    if livox is not None:
        maps["livox"] = livox
    t_gen = time.perf_counter() - t_start
    print(f"data ready in {t_gen:.0f} s: " + ", ".join(f"{k} {len(v.points)} pts / {len(v.queries)} queries"
                                                      for k, v in maps.items()))
    if args.generate_only:
        return 0
    figs = {}
    for name, data in maps.items():
        figs[name] = {"methods": {}, "rows": {}} if args.outside_only else evaluate_map(data, methods, args, config)
    if args.outside > 0 and len(maps) > 1:  # each map against another map's queries (every one out of it)
        names = list(maps)
        for i, name in enumerate(names):
            other = maps[names[(i + 1) % len(names)]].queries
            pick = np.unique(np.linspace(0, len(other) - 1, min(args.outside, len(other))).round().astype(int))
            figs[name]["outside"] = evaluate_outside(maps[name], [other[j] for j in pick], args, config)
            o = figs[name]["outside"]
            print(f"{name}: outside the map, {o.get('queries')} scans: no pose {100 * o.get('none_share', 0):.0f} %, "
                  f"wrong {o.get('wrong_count')}, p50 {o.get('time_s_p50', float('nan')):.2f} s, "
                  f"p95 {o.get('time_s_p95', float('nan')):.2f} s (CPU {o.get('cpu_s_p50', float('nan')):.2f} / "
                  f"{o.get('cpu_s_p95', float('nan')):.2f} s, load {os.getloadavg()[0]:.1f})")
    fig = {"maps": figs, "pooled": aggregate(figs, methods), "labels": LABELS,
           "tolerance": {"rot_deg": ROT_OK_DEG, "trans_m": TRANS_OK_M},
           "settings": {k: v for k, v in vars(args).items()},
           "data_s": t_gen, "measure_s": time.perf_counter() - t_start - t_gen}
    report(figs, methods)
    _common.write_json(Path(args.out), "localization.json", fig)
    plot(fig, Path(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
