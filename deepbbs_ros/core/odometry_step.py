"""What the odometry returns for each scan, and its stage timer (no ROS import)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.core.covariance import floor_term
from deepbbs_ros.reprs import short_repr

__all__ = ["Laps", "OdometryStep", "cloud_points", "floor_covariance"]


@dataclass
class OdometryStep:
    """One frame of :class:`DeepBBSOdometry`.

    T_first_k: (4, 4) float64 pose of the scan (at its stamp) in the first scan's frame.
    T_prev_k: (4, 4) float64 motion since the previous frame (``T_{k-1}_k``).
    deepbbs: DeepBBS++ was consulted (why in ``reason``); won: its start was kept (its alignment fit better than the
        prediction's, at the first motion the coarse-to-fine start's, by more than ``odometry.fit_margin``).
    fit: share of the scan's points with a map correspondence (``odometry.max_corr_dist``) after alignment.
    timings_ms: "deskew", "prepare", "align", "deepbbs" (only when consulted; at the first scan: its preprocessing
        for the first motion's DeepBBS++), "total".
    points: (M, 3) float64 the scan as it was registered (deskewed, cropped, on the ``voxel_size / 2`` grid),
        sensor frame: what a caller needs to score the step (the node's covariance) without redoing it.
    path: which path answered: "gicp" (GICP against the local map from the prediction, DeepBBS++ not consulted or
        not kept), "deepbbs" or "search" (DeepBBS++'s answer kept: its deep passes, or its any-start search);
        "" at the first scan.
    covariance: (6, 6) float64 covariance of ``T_first_k`` against the local map (the map held fixed), from the
        VGICP's Hessian and residuals at the pose (core/covariance.py: position error in the first scan's frame,
        rotation error a left perturbation); None at the first scan or when the VGICP gives none.
    degenerate: "" in a well-constrained place, else what the VGICP's Hessian says, e.g. "corridor-like, weak axis x
        (ratio 2.1e-03)" (the scan's axes; core/degeneracy.py): along it the prediction's position was kept.
    deviation: metres between the pose and the constant-velocity prediction; gate: the gate's limit then (inf while
        it has too few steps or is off).
    covariance_floor: (6, 6) float64 the part of ``covariance`` that is the sweep's model error
        (core/motion_floor.py ``MotionFloor``: this scan's own error, which the next step undoes), in the same
        frame; the rest is the GICP's and accumulates along the chain. None when ``covariance`` is None or has no
        such part (the first motion: the voxel map's quantisation).
    covariance_held: (6, 6) float64 what the accumulated pose's covariance gains at this step beyond ``covariance``'s
        GICP part, in the same frame: along the directions held (``degenerate``) the held steps share the velocity's
        error, and this is the step's covariance with the held steps before it in a row (core/motion_floor.py
        ``MotionFloor.held_cross``); None where there is none (not held, or the first held step).
    """

    __repr__ = short_repr  # one readable line: arrays as shape and dtype (deepbbs_ros/reprs.py)

    T_first_k: np.ndarray
    T_prev_k: np.ndarray
    deepbbs: bool = False
    won: bool = False
    reason: str = ""
    fit: float = float("nan")
    timings_ms: dict[str, float] = field(default_factory=dict)
    points: np.ndarray | None = None
    path: str = ""
    covariance: np.ndarray | None = None
    degenerate: str = ""
    deviation: float = float("nan")
    gate: float = float("inf")
    covariance_floor: np.ndarray | None = None
    covariance_held: np.ndarray | None = None


def floor_covariance(floor: np.ndarray | None, T_map_scan: np.ndarray, cov: np.ndarray | None) -> np.ndarray | None:
    """(6, 6) the sweep floor's term of the odometry covariance ``cov`` (core/covariance.py ``odometry_covariance``):
    ``floor`` (6,) standard deviations along the scan's axes, rotated into the map frame; None without either."""
    return None if floor is None or cov is None else floor_term(floor, T_map_scan)


def cloud_points(cloud: Any) -> np.ndarray | None:
    try:
        return np.asarray(cloud.points(), dtype=np.float64)[:, :3]
    except Exception:  # noqa: BLE001 - a cloud type without points(): the caller does without
        return None


class Laps:
    """Milliseconds per named stage of one scan, and the total."""

    def __init__(self) -> None:
        self.t0 = self.t = time.perf_counter()
        self.ms: dict[str, float] = {}

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.ms[name] = self.ms.get(name, 0.0) + (now - self.t) * 1e3
        self.t = now

    def done(self) -> dict[str, float]:
        self.ms["total"] = (time.perf_counter() - self.t0) * 1e3
        return self.ms
