"""Pairs of scans of a sensor turned and moved between them, as a hand-held walk takes them (no ROS).

A narrow sensor (a Livox Avia's 70 degrees) carried by hand sees a different part of the place after each turn of
the walker: on a real hand-held Avia walk, keyframes four apart are 0.3-1.3 m and 8-33 degrees apart (10-90 %) and
overlap in part only. A pair here renders both scans from a recording's place at two poses of the walk (``frame``
and a later frame ``move`` metres on), the second turned about the vertical so that the relative heading is
``yaw_deg``: the overlap follows from the place and the sensor (measure it; nothing cuts the scans). Each scan is
cast from one pose (no motion skew), so the truth ``T_target_source`` is exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.sim.trajectory import euler_to_matrix

YAW_DEG = (8.0, 50.0)  # deg, relative heading between the scans (real hand-held Avia keyframes: 8-33, 10-90 %)
MOVE_M = (0.3, 2.5)  # m between the scans (real hand-held Avia keyframes 4 apart: 0.26-1.31 m, 10-90 %)


@dataclass
class TurnedPair:
    """Two scans (sensor frames, ``T_world_lidar`` set) and the exact ``T_target_source``."""

    target: Scan
    source: Scan
    T_target_source: np.ndarray
    yaw_deg: float  # relative heading (deg)
    move_m: float  # distance between the two sensor positions (m)


def render_at(sim, frame: int, T_world_lidar: np.ndarray) -> Scan:
    """Scan ``frame`` of ``sim`` (a :class:`~deepbbs_ros.sim.rig.RigSimulator`) cast from the fixed pose
    ``T_world_lidar`` (4, 4) instead of its trajectory's: the pattern (and noise) of that frame, no motion skew."""
    T = np.asarray(T_world_lidar, np.float64).copy()
    saved = sim.motion_distortion, sim.compensate
    sim.T_world_lidar = lambda t: T.copy() if np.ndim(t) == 0 else np.broadcast_to(T, (len(t), 4, 4)).copy()
    sim.motion_distortion, sim.compensate = False, False
    try:
        scan = sim.scan_at(frame)
    finally:
        del sim.T_world_lidar  # back to the class's trajectory
        sim.motion_distortion, sim.compensate = saved
    scan.T_world_lidar = T
    return scan


def turned_pair(sim, frame: int, rng: np.random.Generator, yaw_deg: tuple[float, float] = YAW_DEG,
                move_m: tuple[float, float] = MOVE_M) -> TurnedPair | None:
    """The target at ``frame``'s pose; the source at the first later frame at least a drawn distance within
    ``move_m`` away, turned about the vertical through the sensor so that the relative heading is a drawn
    magnitude within ``yaw_deg`` (either sign). None if the recording ends first."""
    Tt = sim.pose_at(frame)
    d = rng.uniform(*move_m)
    j = frame + 1
    while j < sim.frames and np.linalg.norm(sim.pose_at(j)[:3, 3] - Tt[:3, 3]) < d:
        j += 1
    if j >= sim.frames or np.linalg.norm(sim.pose_at(j)[:3, 3] - Tt[:3, 3]) > move_m[1]:
        return None
    Ts = sim.pose_at(j).copy()
    heading = lambda T: np.arctan2(T[1, 0], T[0, 0])  # noqa: E731
    want = np.radians(rng.uniform(*yaw_deg)) * rng.choice([-1.0, 1.0])
    Ts[:3, :3] = euler_to_matrix(0.0, 0.0, want - (heading(Ts) - heading(Tt))) @ Ts[:3, :3]
    tgt, src = render_at(sim, frame, Tt), render_at(sim, j, Ts)
    rel = np.linalg.inv(Tt) @ Ts
    return TurnedPair(tgt, src, rel, float(np.degrees(abs(want))), float(np.linalg.norm(rel[:3, 3])))
