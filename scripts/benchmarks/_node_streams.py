"""node_latency.py's clouds: the scans of a simulated drive or of KITTI sequences in a real driver's layout, what is
published each period (:class:`Stream`), and the prior map of localization runs."""

from __future__ import annotations

import array
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.errors import DeepBBSError

SEC = 1_000_000_000
STAMP0_NS = 1_000 * SEC


@dataclass
class Stream:
    """Messages and what is published each period: ``pairs[k % len(pairs)]`` = (source, target) indices."""

    msgs: list
    pairs: list[tuple[int, int]]
    desc: str
    map_path: str = ""  # --mode localization: the map file (PCD, trajectory beside it)
    map_msg: Any = None  # ... the same map as a PointCloud2 in the map frame (the anchor's latched target)
    initial_pose: list[float] = field(default_factory=list)  # ... the first published scan's x y z roll pitch yaw


def _lidar(layout: str, ouster_beams: int):
    from deepbbs_ros.sim.lidar import LidarConfig

    if layout == "velodyne":
        return LidarConfig.hdl64()
    if ouster_beams == 128:  # OS1-128: 45 deg vertical field of view
        return LidarConfig.ouster64(beams=128, vfov_min_deg=-22.5, vfov_max_deg=22.5, name="os1-128")
    return LidarConfig.ouster64(name="os1-64")


def playback_order(n_frames: int, n_total: int) -> list[int]:
    """Frame index of every published scan: 0, 1, ..., n-1, n-2, ..., 1, 0, 1, ... (neighbours only)."""
    if n_frames < 2:
        raise DeepBBSError("a stream needs at least 2 frames")
    cycle = list(range(n_frames)) + list(range(n_frames - 2, 0, -1))
    return [cycle[k % len(cycle)] for k in range(n_total)]


FIXED_SOURCES = 4  # --stream fixed: the sources are frames 1..4 (KITTI: 1-6 m from the target)


def stream_pairs(n_frames: int, stream: str) -> list[tuple[int, int]]:
    """(source, target) frame indices per period: consecutive neighbours back and forth; frame 0 as a fixed
    target of frames 1, 2, .., FIXED_SOURCES, .., 2 (back and forth); or the same pair (1, 0) every period."""
    if stream == "same":
        return [(1, 0)]
    if stream == "fixed":
        m = min(FIXED_SOURCES, n_frames - 1)
        return [(1 + i, 0) for i in playback_order(m, max(1, 2 * m - 2))] if m > 1 else [(1, 0)]
    order = playback_order(n_frames, 2 * n_frames - 1)
    return [(order[k + 1], order[k]) for k in range(len(order) - 1)]


def _describe(msgs: list, n_valid: float, sensor: str, layout: str) -> str:
    m = msgs[0]
    return (f"{sensor} ({layout} driver layout, point_step {m.point_step}, {m.height}x{m.width}, "
            f"{n_valid:.0f} valid points, {len(m.data) / 1e6:.1f} MB)")  # fmt: skip


def sim_stream(args, layout: str, stream: str) -> Stream:
    from deepbbs_ros.sim import simulate_drive
    from msg_adapters.layouts import driver_cloud

    lidar = _lidar(layout, args.ouster_beams)
    t0 = time.perf_counter()
    scans = list(simulate_drive(args.scene, args.seed, args.scans, lidar=lidar))
    frame = "velodyne" if layout == "velodyne" else "os_sensor"
    msgs = [driver_cloud(layout, s.points, s.fields, beams=lidar.beams, columns=lidar.columns, frame_id=frame)
            for s in scans]  # fmt: skip
    desc = _describe(msgs, np.mean([len(s.points) for s in scans]), f"simulated {lidar.name}", layout)
    print(f"  simulated {len(scans)} frames of {desc} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    out = Stream(msgs, stream_pairs(len(msgs), stream), desc)
    if args.mode == "localization":
        from deepbbs_ros.sim.simulator import DriveSimulator

        sim = DriveSimulator(args.scene, args.seed, lidar, frames=args.scans, motion_distortion=False)
        keys = list(range(0, args.scans, max(1, args.map_every)))
        add_map(args, out, [s.T_world_lidar for s in scans], [(sim.scan_at(k).points, sim.pose_at(k),
                                                                sim.stamp_ns(k)) for k in keys],
                f"map_{args.scene}_{args.seed}_{args.scans}")
    return out


def add_map(args, stream: Stream, poses: list[np.ndarray], keys: list[tuple[np.ndarray, np.ndarray, int]],
            name: str) -> None:
    """--mode localization: the drive's map (``keys``: (points, true pose, stamp) of every ``--map-every``-th frame,
    simulated ones without motion distortion, on a ``--map-voxel`` grid) as a PCD with its trajectory (without:
    ``--no-trajectory``; under ``--out`` or a temporary folder) and as a PointCloud2 in ``map``; the anchor's initial
    pose = the first published scan's (``poses``: every frame's true pose)."""
    from scipy.spatial.transform import Rotation

    from deepbbs_ros.core.localization import voxel_downsample
    from deepbbs_ros.datasets.maps import write_map
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2

    t0 = time.perf_counter()
    parts = [np.asarray(pts[:, :3], np.float64) @ P[:3, :3].T + P[:3, 3] for pts, P, _ in keys]
    points = voxel_downsample(np.concatenate(parts).astype(np.float32), args.map_voxel)
    folder = args.out if args.out is not None else Path(tempfile.mkdtemp(prefix="deepbbs_map_"))
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}{'_alone' if args.no_trajectory else ''}.pcd"
    write_map(path, points, *((None, None) if args.no_trajectory else
                              (np.stack([P for _, P, _ in keys]), np.array([s for *_, s in keys]))))
    stream.map_path = str(path)
    stream.map_msg = arrays_to_pointcloud2(points, stamp_ns=STAMP0_NS, frame_id="map")
    first = poses[stream.pairs[0][0]]
    rpy = Rotation.from_matrix(first[:3, :3]).as_euler("ZYX")[::-1]
    stream.initial_pose = [*map(float, first[:3, 3]), *map(float, rpy)]
    stream.desc += (f"; map {len(points)} points from {len(keys)} frames"
                    + (", no trajectory" if args.no_trajectory else ", with its trajectory"))
    print(f"  map of {len(points)} points ({len(keys)} frames) in {time.perf_counter() - t0:.1f} s: {path}",
          file=sys.stderr)


def kitti_sequences(path: Path) -> list[Path]:
    """The KITTI sequence folders at ``path``: itself when it holds ``velodyne/``, else its sub-folders that do."""
    path = Path(path).expanduser()
    if (path / "velodyne").is_dir():
        return [path]
    seqs = sorted(p for p in path.iterdir() if (p / "velodyne").is_dir()) if path.is_dir() else []
    if not seqs:
        raise DeepBBSError(f"--kitti {path}: no KITTI sequence folder (velodyne/NNNNNN.bin) there")
    return seqs


def kitti_rings(xyz: np.ndarray) -> np.ndarray:
    """(N,) ring (0 = the last laser of the file) of a KITTI scan: each laser's points sweep the azimuth once
    in file order, so a ring ends where the azimuth wraps around."""
    az = np.mod(np.arctan2(xyz[:, 1], xyz[:, 0]), 2 * np.pi)
    k = np.concatenate(([0], np.cumsum(np.diff(az) < -np.pi)))
    return (k.max() - k).astype(np.uint16)


def kitti_stream(args, layout: str, stream: str, seq: Path) -> Stream:
    """Real HDL-64E scans of one sequence in a driver's layout, with a per-point time field that is all 0
    (KITTI has no per-point time; Ouster: the 64 rings organised, each ring's points in file order)."""
    from deepbbs_ros.datasets import open_source
    from msg_adapters.layouts import driver_cloud

    with open_source(seq) as src:
        scans = list(src)
    msgs = []
    for s in scans:
        xyz = np.ascontiguousarray(s.points, dtype=np.float32)
        ring = kitti_rings(xyz)
        n = len(xyz)
        fields = {"intensity": np.asarray(s.fields["intensity"], np.float32), "ring": ring,
                  "time": np.zeros(n, np.float32)}  # fmt: skip
        if layout == "ouster":
            order = np.argsort(ring, kind="stable")
            starts = np.searchsorted(ring[order], np.arange(int(ring.max()) + 1))
            column = np.empty(n, np.int64)
            column[order] = np.arange(n) - np.repeat(starts, np.diff(np.append(starts, n)))
            fields["column"] = column
        msgs.append((xyz, fields))
    beams = int(max(f["ring"].max() for _, f in msgs)) + 1
    columns = int(max(f.get("column", np.zeros(1, np.int64)).max() for _, f in msgs)) + 1
    frame = "velodyne" if layout == "velodyne" else "os_sensor"
    out = [driver_cloud(layout, xyz, f, beams=beams, columns=columns, frame_id=frame) for xyz, f in msgs]
    desc = _describe(out, np.mean([len(x) for x, _ in msgs]), f"KITTI {seq.name} HDL-64E, time field 0", layout)
    res = Stream(out, stream_pairs(len(out), stream), desc)
    if getattr(args, "mode", "") == "localization":
        keys = range(0, len(scans), max(1, args.map_every))
        add_map(args, res, [s.T_world_lidar for s in scans],
                [(scans[k].points, scans[k].T_world_lidar, scans[k].stamp_ns) for k in keys], f"map_kitti_{seq.name}")
    return res


class FreshSources:
    """Makes a replayed frame a new scan: a real sensor never sends the same cloud twice, and the node keeps its
    recent clouds' preprocessing by content (a fixed target, or the previous source as the next target: both
    real). The stream has only a few frames, played back and forth, so without this the node would find a
    source it saw a few periods earlier in its cache (2 of 3 periods of the fixed stream) and skip its work.
    :meth:`apply` moves one point of the message (a return more than 2 m away) by ``(k % 1000) * 10 um`` along
    x, in place: different bytes every period, the same cloud to within 1 cm at one of ~120k points. The frame
    keeps its last content until it is published again, so when it is the next period's target it is the
    cloud the node just saw (the cache hit a real stream gets)."""

    def __init__(self) -> None:
        self._where: dict[int, tuple[int, float]] = {}  # id(msg) -> (byte offset of the point's x, its x)

    def _find(self, msg) -> tuple[int, float]:
        off = {f.name: f.offset for f in msg.fields}
        step = msg.point_step
        n = msg.width * msg.height
        xyz = np.stack([np.ndarray((n,), dtype="<f4", buffer=msg.data, offset=off[c], strides=(step,)) for c in "xyz"],
                       axis=1)
        i = int(np.flatnonzero(np.isfinite(xyz).all(axis=1) & (np.linalg.norm(xyz, axis=1) > 2.0))[0])
        return i * step + off["x"], float(xyz[i, 0])

    def apply(self, msg, k: int) -> None:
        key = id(msg)
        if key not in self._where:
            self._where[key] = self._find(msg)
        at, x0 = self._where[key]
        msg.data[at:at + 4] = array.array("B", np.float32(x0 + (k % 1000) * 1e-5).tobytes())
