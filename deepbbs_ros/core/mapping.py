"""A prior map from a recording: every scan moved to its pose and accumulated on a voxel grid.

``build_map`` reads top-down::

    pose        the scan's ground-truth pose T_map_sensor (``source="truth"``), or the project's odometry
                (:class:`~deepbbs_ros.core.odometry.DeepBBSOdometry`, ``source="odometry"``) anchored at the
                first ground-truth pose when the recording has one (else the first scan's frame)
    deskew      scans with per-point times: to the stamp with the motion since the previous kept scan
                (constant velocity, :func:`deepbbs_ros.core.preprocess.deskew`)
    crop        [``preprocess.min_range``, ``preprocess.max_range``] (the ego vehicle, far sparse returns)
    accumulate  p_map = R p_scan + t, into a voxel grid of ``voxel`` metres (KISS-ICP's voxel down-sampling:
                the first point seen in each voxel is kept, so the grid stays the same as it grows)

The result is a :class:`MapBuild`: (N, 3) map points and the (K, 4, 4) ``T_map_sensor`` poses of the scans
used, which a :class:`~deepbbs_ros.core.localization.MapLocalizer` takes as its ``trajectory``. Frames: see
CONVENTIONS.md (``T_map_sensor``: p_map = R p_sensor + t). No ROS import, no file I/O (see
:mod:`deepbbs_ros.datasets.maps`). The voxel grid: :mod:`deepbbs_ros.core.voxel_map` (imported from here too).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.voxel_map import VoxelMap, voxel_down_sample  # noqa: F401  (re-exported)
from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.errors import DatasetError, DeepBBSError
from deepbbs_ros.reprs import short_repr

__all__ = ["MAP_SOURCES", "MapBuild", "VoxelMap", "build_map"]

#: where a map's poses come from: ``auto`` = the ground truth when the recording has it, else the odometry
MAP_SOURCES = ("auto", "truth", "odometry")


@dataclass
class MapBuild:
    """A map built by :func:`build_map`.

    points: (M, 3) float64 map points, metres, map frame (one per ``voxel`` cell).
    T_map_sensor: (K, 4, 4) float64 poses of the scans accumulated (the map's trajectory).
    stamps_ns: (K,) int64 their stamps.
    source: "truth" or "odometry": where the poses came from.
    frames_read: scans read from the recording; frames_used: scans accumulated (K).
    skipped: one line per scan left out (the odometry failed on it, too few points, no ground truth).
    interrupted: Ctrl-C stopped the reading; the map holds the scans before it.
    map_frame: what the map frame is, in words.
    timings_ms: "pose" (odometry), "accumulate", "total".
    """

    __repr__ = short_repr

    points: np.ndarray
    T_map_sensor: np.ndarray
    stamps_ns: np.ndarray
    source: str
    voxel: float
    frames_read: int = 0
    frames_used: int = 0
    skipped: list[str] = field(default_factory=list)
    interrupted: bool = False
    map_frame: str = ""
    timings_ms: dict[str, float] = field(default_factory=dict)


def build_map(
    scans: Iterable[Scan],
    config: Config | None = None,
    *,
    voxel: float = 0.2,
    source: str = "auto",
    stride: int = 1,
    has_ground_truth: bool | None = None,
    odometry: object | None = None,
    progress: Callable[[int], None] | None = None,
    max_frames: int | None = None,
) -> MapBuild:
    """Accumulate ``scans`` at their poses into a voxel map (see the module docstring).

    Args:
        scans: the recording in stamp order (a :class:`~deepbbs_ros.datasets.base.ScanSource` or any iterable).
        config: ``preprocess.min_range`` / ``max_range`` (crop) and, for the odometry, its sections.
        voxel: the map's voxel size, metres.
        source: "truth" (every scan needs its ground-truth pose), "odometry", or "auto" (truth when
            ``has_ground_truth``, else odometry).
        stride: every ``stride``-th scan is used (the odometry registers only those).
        has_ground_truth: whether the recording has ground truth (``ScanSource.has_ground_truth``; read from
            ``scans`` when None).
        odometry: a :class:`~deepbbs_ros.core.odometry.DeepBBSOdometry` to use (built from ``config`` when None).
        progress: called with 1 per scan read.
        max_frames: stop after this many scans used.

    Raises:
        DatasetError: ``source`` unknown, "truth" without ground truth, a bad ``stride`` / ``voxel``, no scan
            read, or no scan usable. Ctrl-C while reading ends the reading: the map holds the scans before it
            (``interrupted``).
    """
    from deepbbs_ros.core.preprocess import crop_mask, deskew

    cfg = (config or Config()).validate()
    if source not in MAP_SOURCES:
        raise DatasetError(f"map source must be one of {', '.join(MAP_SOURCES)}, got {source!r}")
    if stride < 1:
        raise DatasetError(f"stride must be >= 1, got {stride}")
    if has_ground_truth is None:
        has_ground_truth = bool(getattr(scans, "has_ground_truth", False))
    if source == "auto":
        source = "truth" if has_ground_truth else "odometry"
    if source == "truth" and not has_ground_truth:
        raise DatasetError("the recording has no ground-truth poses to build the map from; use the odometry "
                           "(--from odometry)")
    grid = VoxelMap(voxel)
    pp = cfg.preprocess
    out = MapBuild(np.zeros((0, 3)), np.zeros((0, 4, 4)), np.zeros(0, dtype=np.int64), source, float(voxel))
    poses: list[np.ndarray] = []
    stamps: list[int] = []
    T_map_first: np.ndarray | None = None  # odometry: its first frame in the map frame
    anchored = source == "truth"  # the map frame is the ground truth's world frame
    prev: tuple[np.ndarray, int] | None = None  # (T_map_sensor, stamp) of the last scan used
    t_pose = t_acc = 0.0
    t_start = time.perf_counter()
    try:
        for pos, scan in enumerate(scans):
            out.frames_read += 1
            if progress:
                progress(1)
            if pos % stride:
                continue
            if max_frames is not None and out.frames_used >= max_frames:
                break
            t0 = time.perf_counter()
            if source == "truth":
                if scan.T_world_lidar is None:
                    out.skipped.append(f"frame {scan.index}: no ground-truth pose")
                    continue
                T = scan.T_world_lidar
            else:
                if odometry is None:
                    from deepbbs_ros.core.odometry import DeepBBSOdometry

                    odometry = DeepBBSOdometry(cfg)
                if T_map_first is None:
                    anchored = scan.T_world_lidar is not None
                    T_map_first = scan.T_world_lidar if anchored else np.eye(4)
                try:
                    T = T_map_first @ odometry.register_frame(scan.points, scan.point_times(), scan.stamp_ns).T_first_k
                except DeepBBSError as err:
                    out.skipped.append(f"frame {scan.index}: {err}")
                    continue
            t1 = time.perf_counter()
            pts = np.asarray(scan.points, dtype=np.float64)
            times = scan.point_times()
            if prev is not None and times is not None and len(times) == len(pts) and scan.stamp_ns > prev[1]:
                dt = (scan.stamp_ns - prev[1]) * 1e-9
                pts = deskew(pts, times, np.linalg.inv(prev[0]) @ T, dt)  # the motion since the last scan used
            pts = pts[crop_mask(pts, pp)]
            if len(pts) == 0:
                out.skipped.append(f"frame {scan.index}: no point within {pp.min_range:g}-{pp.max_range:g} m")
                continue
            grid.add(pts @ T[:3, :3].T + T[:3, 3])
            poses.append(np.array(T, dtype=np.float64))
            stamps.append(int(scan.stamp_ns))
            prev = (poses[-1], stamps[-1])
            out.frames_used += 1
            t_pose += t1 - t0
            t_acc += time.perf_counter() - t1
    except KeyboardInterrupt:  # the scans so far make the map; the caller says it is incomplete
        out.interrupted = True
    if out.frames_read == 0:
        raise DatasetError("the recording holds no scan")
    if out.frames_used == 0:
        why = f" ({out.skipped[0]}{' ...' if len(out.skipped) > 1 else ''})" if out.skipped else ""
        raise DatasetError(f"no scan of {out.frames_read} could be placed in the map{why}")
    t2 = time.perf_counter()
    out.points = grid.points
    out.T_map_sensor = np.stack(poses)
    out.stamps_ns = np.asarray(stamps, dtype=np.int64)
    out.map_frame = "the ground truth's world frame" if anchored else "the first scan's sensor frame"
    out.timings_ms = {"pose": t_pose * 1e3, "accumulate": (t_acc + time.perf_counter() - t2) * 1e3,
                      "total": (time.perf_counter() - t_start) * 1e3}
    return out
