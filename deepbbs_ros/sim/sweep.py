"""What the drive simulator does to a sweep besides casting it (no ROS): which rays can reach the moving boxes (the
rest are not cast against them), and the compensation of a raw sweep to its stamp, as Apollo's compensator does."""

from __future__ import annotations

import numpy as np

from deepbbs_ros.sim.lidar import LidarConfig


def rays_towards(lidar: LidarConfig, vertices: np.ndarray, T_first: np.ndarray, T_last: np.ndarray,
                 nb: int) -> np.ndarray:
    """Indices of the rays of ``lidar``'s columns whose world azimuth can reach one of the boxes in
    ``vertices`` ((8 M, 3) world, 8 corners per box), seen from the sensor at the start
    (``T_first``) and the end (``T_last``) of the sweep."""
    ncol = lidar.columns
    yaw0 = np.arctan2(T_first[1, 0], T_first[0, 0])
    dyaw = abs(np.angle(np.exp(1j * (np.arctan2(T_last[1, 0], T_last[0, 0]) - yaw0))))
    pad = np.deg2rad(1.0) + dyaw
    nbins = 720
    bins = np.zeros(nbins, bool)
    for T in (T_first, T_last):
        rel = vertices[:, :2] - T[:2, 3]
        if np.min(np.hypot(rel[:, 0], rel[:, 1])) < 1.5:
            return np.arange(ncol * nb)  # (nearly) touching the sensor: no culling
        a = np.arctan2(rel[:, 1], rel[:, 0]).reshape(-1, 8)
        da = np.angle(np.exp(1j * (a - a[:, :1])))
        lo = (a[:, 0] + da.min(1) - pad + np.pi) / (2 * np.pi) * nbins
        hi = (a[:, 0] + da.max(1) + pad + np.pi) / (2 * np.pi) * nbins
        for x0, x1 in zip(np.floor(lo).astype(int), np.floor(hi).astype(int)):
            bins[np.arange(x0, x1 + 1) % nbins] = True
    col_az = np.mod(lidar.azimuths() + yaw0 + np.pi, 2 * np.pi)
    cols = np.flatnonzero(bins[(col_az / (2 * np.pi) * nbins).astype(np.int64) % nbins])
    return (cols[:, None] * nb + np.arange(nb)[None, :]).reshape(-1)


def compensate(pts: np.ndarray, fields: dict, T_cols: np.ndarray, period: float, columns: int,
               ) -> tuple[np.ndarray, dict]:
    """Express every point in the sensor frame at the stamp with the true pose of its column (what
    Apollo's compensator does with its localisation; ``T_cols`` (C, 4, 4) the pose at each of the ``columns``
    firings of a sweep of ``period`` s); the ``time`` field goes, since re-applying it would distort the scan again."""
    fields = dict(fields)
    t = fields.pop("time")
    col = np.minimum(np.rint(t.astype(np.float64) / (period / columns)).astype(np.int64), columns - 1)
    T_rel = np.linalg.inv(T_cols[0]) @ T_cols  # (C, 4, 4) T_lidar0_lidarc
    p = np.einsum("nij,nj->ni", T_rel[col, :3, :3], pts.astype(np.float64)) + T_rel[col, :3, 3]
    return p.astype(np.float32), fields
