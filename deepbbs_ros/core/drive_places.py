"""The candidate places of a map with its drive's trajectory (no ROS): keyframes along the drive and a lattice beside
it.

A keyframe every ``localization.place_spacing`` m of the trajectory, then places on a ``place_band_step`` m lattice
up to ``place_band`` m to either side of the drive (other lanes, the other way) where the map's height grid
(core/descriptors.py) has free ground. A map without trajectory gets a grid of places instead (core/places.py).
Used by :class:`~deepbbs_ros.core.localization.MapLocalizer`.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.config import LocalizationConfig
from deepbbs_ros.core.descriptors import _HeightGrid
from deepbbs_ros.errors import LocalizationError

OBSTACLE_BAND = (0.3, 2.5)  # m above the local ground: what makes a grid cell an obstacle (the lattice's places)


def keyframe_places(trajectory: np.ndarray, grid: _HeightGrid, lc: LocalizationConfig) -> tuple[np.ndarray, int]:
    """(P, 4, 4) places along a drive ``trajectory`` (K, 4, 4) (``T_map_sensor``), and how many of them are its
    keyframes (the first ones): a keyframe every ``place_spacing`` m, then the :func:`band_places` beside the drive
    (``place_band`` > 0). Raises LocalizationError for a trajectory that is not (K, 4, 4) finite poses."""
    traj = np.asarray(trajectory, dtype=np.float64)
    if traj.ndim != 3 or traj.shape[1:] != (4, 4) or len(traj) == 0 or not np.isfinite(traj).all():
        raise LocalizationError(f"trajectory: expected (K, 4, 4) finite poses, got shape {traj.shape}")
    xyz = traj[:, :3, 3]
    keep, last = [0], xyz[0]
    for k in range(1, len(xyz)):
        if np.linalg.norm(xyz[k] - last) >= lc.place_spacing:
            keep.append(k)
            last = xyz[k]
    out = np.repeat(np.eye(4)[None], len(keep), axis=0)
    out[:, :3, 3] = xyz[keep]
    keyframes = len(out)  # the first places: the keyframes; then the lattice beside the drive
    if lc.place_band <= 0:
        return out, keyframes
    return np.concatenate([out, band_places(traj, out[:, :2, 3], grid, lc)]), keyframes


def band_places(traj: np.ndarray, taken: np.ndarray, grid: _HeightGrid, lc: LocalizationConfig) -> np.ndarray:
    """(B, 4, 4) places on a ``place_band_step`` m lattice along and across the drive, up to ``place_band`` m to
    either side of it (the other lanes, the other direction), where the map has free ground; none within half a
    step of another or of the places ``taken`` (K, 2). The Scan Context distance grows fast with the distance
    from the place (a place 3.5 m off ranks far below look-alikes 100s of m away), hence the fine lattice."""
    step = lc.place_band_step
    xyz = traj[:, :3, 3]
    keep, last = [0], xyz[0]
    for k in range(1, len(xyz)):
        if np.linalg.norm(xyz[k] - last) >= step:
            keep.append(k)
            last = xyz[k]
    nxt = np.minimum(np.arange(len(xyz)) + 1, len(xyz) - 1)
    prv = np.maximum(np.arange(len(xyz)) - 1, 0)
    head = (xyz[nxt] - xyz[prv])[keep, :2]  # the direction of travel at the samples
    norm = np.linalg.norm(head, axis=1, keepdims=True)
    head = np.where(norm > 1e-6, head / np.maximum(norm, 1e-6), traj[keep][:, :2, 0])
    side = np.stack([-head[:, 1], head[:, 0]], axis=1)  # left of the heading
    n = int(np.floor(lc.place_band / step + 1e-9))
    offsets = step * np.r_[np.arange(-n, 0), np.arange(0, n + 1)]
    xy = (xyz[keep, None, :2] + offsets[None, :, None] * side[:, None]).reshape(-1, 2)
    z_own = np.repeat(xyz[keep, 2] - grid.ground_at(xyz[keep, :2], np.nan), len(offsets))  # sensor height
    ix, iy, inside = grid.index(xy)
    ok = inside & free_space(grid, lc, lc.offset_clearance)[ix, iy]
    xy, z_own = xy[ok], z_own[ok]
    # one place per half-step cell, none next to a place taken already
    key = np.floor(xy / (0.5 * step)).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    xy, z_own = xy[first], z_own[first]
    if len(taken):
        from scipy.spatial import cKDTree

        d, _ = cKDTree(taken).query(xy)
        xy, z_own = xy[d >= 0.5 * step], z_own[d >= 0.5 * step]
    out = np.repeat(np.eye(4)[None], len(xy), axis=0)
    out[:, :2, 3] = xy
    g = grid.ground_at(xy, np.nan)
    out[:, 2, 3] = np.where(np.isfinite(g) & np.isfinite(z_own), g + z_own, lc.sensor_height)  # as high as own
    return out


def free_space(g: _HeightGrid, lc: LocalizationConfig, clearance_m: float) -> np.ndarray:
    """(shape of the grid) bool: cells with ground and no obstacle (OBSTACLE_BAND) within ``clearance_m``."""
    from scipy.ndimage import distance_transform_edt

    above = np.where(g.occupied, g.zmax - np.nan_to_num(g.ground, nan=np.inf), -np.inf)
    obstacle = (above > OBSTACLE_BAND[0]) & (above < max(OBSTACLE_BAND[1], lc.sensor_height))
    clearance = distance_transform_edt(~obstacle) * g.cell  # m to the nearest obstacle cell
    return g.occupied & (above <= OBSTACLE_BAND[0]) & (clearance >= clearance_m)
