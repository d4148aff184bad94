"""Does a trajectory fit its map? The check behind a map's candidate places (no ROS import).

A prior map may come with the trajectory of the drive that built it (``map.tum`` beside ``map.pcd``); the localizer
takes that trajectory's keyframes as its candidate places. A map moved after it was made (re-anchored, cropped into
another frame) with its old ``.tum`` left beside it, or the ``.tum`` of another drive, gives places where no sensor
ever was: every search then fails. The rule here says whether the sensor could physically have been at the
trajectory's poses in this map:

a pose **fits** when

1. the map is there: at least ``SUPPORT_POINTS`` map points lie in the 3 x 3 ``CELL`` m square cells around it
   (8 to 16 m away, horizontally);
2. it stands at a plausible height above the map's local ground: ``HEIGHT_BAND`` m above the ground, the
   ``GROUND_PERCENTILE``-th percentile of the heights of the map points within ``CELL`` m (horizontally;
   a LiDAR on a car, a robot or carried by hand sits 0.3 to 3 m above the road it drives on);
3. it is in free space: fewer than ``FREE_POINTS`` map points lie within ``FREE_RADIUS`` m of it (3D; a sensor is
   not inside a wall, a parked car or the ground).

The trajectory fits its map when at least ``FIT_SHARE`` of its poses fit (a few poses on a bridge over a gap in the
map, or next to a parked car the map kept, are forgiven). At most ``MAX_CHECKED`` poses, evenly spread along the
trajectory, are checked; the map's points are read once (binned in cells), so a 10 km map costs seconds at most.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepbbs_ros.errors import LocalizationError

CELL = 8.0  # m; the neighbourhood of a pose: its 3 x 3 cells of this size (support), points within this (ground, free)
SUPPORT_POINTS = 50  # map points in the 3 x 3 cells around a pose: the map is there
GROUND_PERCENTILE = 5.0  # %: the local ground under a pose, of the heights within CELL m (its blind circle inside)
HEIGHT_BAND = (-0.5, 5.0)  # m above the local ground: where a sensor of a ground vehicle or a person can be
FREE_RADIUS, FREE_POINTS = 0.3, 3  # m, points: a sensor is in free space (a map may keep its vehicle's roof nearby)
FIT_SHARE = 0.8  # share of the checked poses that must fit
MAX_CHECKED = 200  # poses checked at most (evenly spread)


@dataclass
class TrajectoryFit:
    """Outcome of :func:`check_trajectory`: ``fits``; of ``checked`` poses, how many failed each rule; ``message``,
    one line for the user ("" when it fits)."""

    fits: bool
    checked: int
    off_map: int
    bad_height: int
    occupied: int
    message: str = ""
    on_map: np.ndarray | None = None  # (K,) bool, every pose of the trajectory: the map has points around it (rule 1)


def check_trajectory(points: np.ndarray, trajectory: np.ndarray) -> TrajectoryFit:
    """Whether ``trajectory`` (K, 4, 4) ``T_map_sensor`` can be the drive that built the map ``points`` (N, 3) (map
    frame, metres): the rule in the module docstring. Raises LocalizationError on a trajectory that is not (K, 4, 4)
    finite poses. Cost: one pass over the points to bin them in ``CELL`` m cells, then only the points in the cells
    around the checked poses."""
    traj = np.asarray(trajectory, dtype=np.float64)
    if traj.ndim != 3 or traj.shape[1:] != (4, 4) or len(traj) == 0 or not np.isfinite(traj).all():
        raise LocalizationError(f"trajectory: expected (K, 4, 4) finite poses, got shape {traj.shape}")
    pos = traj[np.unique(np.linspace(0, len(traj) - 1, min(len(traj), MAX_CHECKED)).round().astype(int)), :3, 3]
    pts = np.asarray(points)[:, :3]
    cells = _Cells(pos[:, :2])
    key = cells.key(pts[:, :2])  # one pass over the map; points away from every pose share the last key
    # 1. the map around each pose: points in its 3 x 3 cells
    counts = np.bincount(key, minlength=cells.total + 1)
    support = counts[cells.around(pos[:, :2])].sum(axis=1)
    off = support < SUPPORT_POINTS
    # 2. and 3. from the points within CELL m of each pose: those of the wanted cells, sorted by cell once
    want = np.zeros(cells.total + 1, bool)
    want[cells.around(pos[:, :2]).ravel()] = True
    sel = np.flatnonzero(want[key])
    order = np.argsort(key[sel], kind="stable")
    near_pts, near_key = pts[sel[order]].astype(np.float64), key[sel[order]]
    height = np.zeros(len(pos), bool)
    occupied = np.zeros(len(pos), bool)
    for k in np.flatnonzero(~off):
        parts = [near_pts[np.searchsorted(near_key, q, "left"):np.searchsorted(near_key, q, "right")]
                 for q in cells.around(pos[k:k + 1, :2])[0]]
        around = np.concatenate(parts)
        around = around[np.linalg.norm(around[:, :2] - pos[k, :2], axis=1) <= CELL]
        ground = np.percentile(around[:, 2], GROUND_PERCENTILE) if len(around) else np.nan
        height[k] = not HEIGHT_BAND[0] <= pos[k, 2] - ground <= HEIGHT_BAND[1]  # NaN (no ground near) fails too
        occupied[k] = int((np.linalg.norm(around - pos[k], axis=1) < FREE_RADIUS).sum()) >= FREE_POINTS
    bad = off | height | occupied
    n = len(pos)
    fits = (n - int(bad.sum())) >= FIT_SHARE * n
    # rule 1 for every pose, not only the checked ones (a pose beyond the cells of the checked ones: kept)
    xy = traj[:, :2, 3]
    ij = np.floor((xy - cells.lo) / CELL).astype(np.int64)
    known = ((ij >= 1) & (ij <= cells.shape - 2)).all(axis=1)
    on_map = np.ones(len(traj), bool)
    on_map[known] = counts[cells.around(xy[known])].sum(axis=1) >= SUPPORT_POINTS
    fit = TrajectoryFit(bool(fits), n, int(off.sum()), int(height.sum()), int(occupied.sum()), on_map=on_map)
    if not fits:
        fit.message = (f"the map's trajectory does not fit the map: {int(bad.sum())} of {n} poses checked are not "
                       f"where a sensor could have been ({fit.off_map} off the map, {fit.bad_height} not "
                       f"{HEIGHT_BAND[0]:g} to {HEIGHT_BAND[1]:g} m above its ground, {fit.occupied} inside map "
                       "points): was the map moved after it was made, or is this another drive's trajectory? "
                       "Candidate places come from the map's free space instead")
    return fit


class _Cells:
    """``CELL`` m square cells over the poses' bounding box (one cell of margin); ``total`` cells, numbered row by
    row; :meth:`key` of a position outside them is ``total``."""

    def __init__(self, xy: np.ndarray) -> None:
        self.lo = xy.min(axis=0) - 2 * CELL
        self.shape = np.floor((xy.max(axis=0) + 2 * CELL - self.lo) / CELL).astype(np.int64) + 1
        self.total = int(self.shape.prod())

    def key(self, xy: np.ndarray) -> np.ndarray:
        ij = np.floor((xy - self.lo.astype(xy.dtype)) / CELL).astype(np.int64)
        inside = (ij >= 0).all(axis=1) & (ij < self.shape).all(axis=1)
        return np.where(inside, ij[:, 0] * self.shape[1] + ij[:, 1], self.total)

    def around(self, xy: np.ndarray) -> np.ndarray:
        """(K, 9) the keys of the 3 x 3 cells around each position (K, 2) (inside the box by construction)."""
        ij = np.floor((xy - self.lo) / CELL).astype(np.int64)
        return np.stack([(ij[:, 0] + di) * self.shape[1] + ij[:, 1] + dj for di in (-1, 0, 1) for dj in (-1, 0, 1)],
                        axis=1)
