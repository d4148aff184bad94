"""Does a trajectory fit its map? The check behind a map's candidate places (no ROS import).

A prior map may come with the trajectory of the drive that built it (``map.tum`` beside ``map.pcd``); the localizer
takes that trajectory's keyframes as its candidate places. A map moved after it was made (re-anchored, cropped into
another frame) with its old ``.tum`` left beside it, or the ``.tum`` of another drive, gives places where no sensor
ever was: every search then fails. The rule here says whether the sensor could physically have been at the
trajectory's poses in this map:

a pose **fits** when

1. the map is there: at least ``SUPPORT_POINTS`` map points lie within ``SUPPORT_RADIUS`` m of it (horizontally);
2. it stands at a plausible height above the map's local ground: ``HEIGHT_BAND`` m above the ground, the
   ``GROUND_PERCENTILE``-th percentile of the heights of the map points within ``GROUND_RADIUS`` m (horizontally;
   a LiDAR on a car, a robot or carried by hand sits 0.3 to 3 m above the road it drives on);
3. it is in free space: fewer than ``FREE_POINTS`` map points lie within ``FREE_RADIUS`` m of it (3D; a sensor is
   not inside a wall, a parked car or the ground).

The trajectory fits its map when at least ``FIT_SHARE`` of its poses fit (a few poses on a bridge over a gap in the
map, or next to a parked car the map kept, are forgiven). At most ``MAX_CHECKED`` poses, evenly spread along the
trajectory, are checked, so that the check stays well under a second on a large map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepbbs_ros.errors import LocalizationError

SUPPORT_RADIUS, SUPPORT_POINTS = 20.0, 50  # m, points: the map around a pose
GROUND_RADIUS, GROUND_PERCENTILE = 8.0, 5.0  # m, %: the local ground under a pose (the sensor's blind circle inside)
HEIGHT_BAND = (-0.5, 5.0)  # m above the local ground: where a sensor of a ground vehicle or a person can be
FREE_RADIUS, FREE_POINTS = 0.3, 3  # m, points: a sensor is in free space (a map may keep its vehicle's roof nearby)
FIT_SHARE = 0.8  # share of the checked poses that must fit
MAX_CHECKED = 500  # poses checked at most (evenly spread)


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


def check_trajectory(points: np.ndarray, trajectory: np.ndarray) -> TrajectoryFit:
    """Whether ``trajectory`` (K, 4, 4) ``T_map_sensor`` can be the drive that built the map ``points`` (N, 3) (map
    frame, metres): the rule in the module docstring. Raises LocalizationError on a trajectory that is not (K, 4, 4)
    finite poses."""
    from scipy.spatial import cKDTree

    traj = np.asarray(trajectory, dtype=np.float64)
    if traj.ndim != 3 or traj.shape[1:] != (4, 4) or len(traj) == 0 or not np.isfinite(traj).all():
        raise LocalizationError(f"trajectory: expected (K, 4, 4) finite poses, got shape {traj.shape}")
    pos = traj[np.unique(np.linspace(0, len(traj) - 1, min(len(traj), MAX_CHECKED)).round().astype(int)), :3, 3]
    pts = _near(np.asarray(points, dtype=np.float64)[:, :3], pos[:, :2], SUPPORT_RADIUS)
    off = np.ones(len(pos), bool)
    height = np.zeros(len(pos), bool)
    occupied = np.zeros(len(pos), bool)
    if len(pts):
        tree = cKDTree(pts[:, :2])
        support = tree.query_ball_point(pos[:, :2], SUPPORT_RADIUS, return_length=True)
        off = support < SUPPORT_POINTS
        for k, idx in enumerate(tree.query_ball_point(pos[:, :2], GROUND_RADIUS)):
            if off[k]:
                continue
            near = pts[np.asarray(idx, dtype=np.int64)]
            ground = np.percentile(near[:, 2], GROUND_PERCENTILE) if len(near) else np.nan
            h = pos[k, 2] - ground
            height[k] = not HEIGHT_BAND[0] <= h <= HEIGHT_BAND[1]  # NaN (no ground within reach) fails too
            occupied[k] = int((np.linalg.norm(near - pos[k], axis=1) < FREE_RADIUS).sum()) >= FREE_POINTS
    bad = off | height | occupied
    n = len(pos)
    fits = (n - int(bad.sum())) >= FIT_SHARE * n
    fit = TrajectoryFit(bool(fits), n, int(off.sum()), int((height & ~off).sum()), int((occupied & ~off).sum()))
    if not fits:
        fit.message = (f"the map's trajectory does not fit the map: {int(bad.sum())} of {n} poses checked are not "
                       f"where a sensor could have been ({fit.off_map} off the map, {fit.bad_height} not "
                       f"{HEIGHT_BAND[0]:g} to {HEIGHT_BAND[1]:g} m above its ground, {fit.occupied} inside map "
                       "points): was the map moved after it was made, or is this another drive's trajectory? "
                       "Candidate places come from the map's free space instead")
    return fit


def _near(points: np.ndarray, xy: np.ndarray, radius: float) -> np.ndarray:
    """The rows of ``points`` (N, 3) in the ``radius`` m square cells around any of ``xy`` (K, 2) (and the 8 cells
    beside each): every point within ``radius`` of one of them, and a few more."""
    if not len(points):
        return points
    own = np.floor(points[:, :2] / radius).astype(np.int64)
    key = own[:, 0] * 2_000_003 + own[:, 1]
    ring = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)])
    around = np.floor(xy / radius).astype(np.int64)[:, None, :] + ring[None]
    wanted = np.unique(around[..., 0] * 2_000_003 + around[..., 1])
    return points[np.isin(key, wanted)]
