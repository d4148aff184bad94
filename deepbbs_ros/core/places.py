"""Candidate places of a map given without its trajectory: where a sensor like the scan's could stand (no ROS).

A map from FAST-LIO, LIO-SAM, KISS-ICP or a survey comes as points only. The places a global search tries are then
read off the map itself::

    ground      per ``cell`` m column, the ground height: a low order statistic of the column's points (the
                GROUND_RANK-th lowest), not its minimum (a few returns below the road, multipath or reflections, would
                drop the ground by metres), then the lowest such value within GROUND_WINDOW cells (a column on a wall
                or a car roof takes the ground beside it)
    obstacles   columns holding at least OBSTACLE_POINTS points in OBSTACLE_BAND above their ground (below knee
                height: what a wheel or a walker would hit); points higher up (the mapping vehicle's own roof, tree
                canopy, a sign over the road) do not block a column, nor do a few stray returns
    drivable    columns with ground seen from close by (a ground return in GROUND_FILL of the column's map-voxel
                sub-squares, relative to this map's best-seen column, or to its SPARSE_QUANTILE column on a map too
                sparse for any place so; over GROUND_COVERAGE of the columns around: where the mapping sensor passed;
                ground seen from afar holds the rings' lines only), no obstacle and
                ``clearance`` m to the nearest obstacle column
    places      one per ``spacing`` m square block of drivable columns, the column farthest from obstacles
    peaks       where the map has no such place within GAP m (the ends of a drive, where the sensor's blind spot and
                its own car's returns leave no column drivable; a map of a single scan), the peaks of its ground
                coverage (the share of ground seen in a PEAK_WINDOW m square: highest where a sensor stood) reaching
                PEAK_SHARE of the coverage at its drivable places (of its own highest peak without any) and PEAK_MIN,
                the best-covered column of each PEAK_SEPARATION m square block

A place's pose is gravity-aligned (map axes) at ``height`` m above its ground. The sensor's own height above the
ground is measured from each query scan at search time (its ground plane), so the height here only names where the
place's descriptor is centred.
"""

from __future__ import annotations

import numpy as np

__all__ = ["OBSTACLE_BAND", "coverage_peaks", "drivable_columns", "grid_places", "robust_ground"]

# m above the ground: returns there make a column an obstacle (a wall, a parked car, a pole, a bush), unless the
# column's ground is seen densely all the same (the mapping vehicle's own roof and body over the road, seen from a roof
# sensor: 0.9-1.8 m above the road on nuScenes' car; a car passing while the map was made)
OBSTACLE_BAND = (0.3, 2.0)
GROUND_STEP = 0.5  # m; a column whose own ground lies this much above the lowest around it stands on something
OBSTACLE_POINTS = 3  # points in the band that make a column an obstacle (fewer: stray returns, a passing car)
GROUND_RANK = 3  # the ground of a column: its GROUND_RANK-th lowest point (fewer points: its highest)
GROUND_WINDOW = 5  # columns; the local ground is the lowest column ground within this window
# the ground is "seen from close by" in a column with a ground return in GROUND_FILL of its map-voxel sub-squares, and
# a place needs GROUND_COVERAGE of such columns around it
GROUND_FILL, GROUND_COVERAGE = 0.5, 0.7
SPARSE_QUANTILE = 0.9  # a sparse map's reference coverage: this quantile of its columns' (_close_coverage)
# a map's stretches with no drivable place within GAP m get places at their ground coverage's peaks (PEAK_WINDOW m
# squares reaching PEAK_SHARE of the coverage at the drivable places, one per PEAK_SEPARATION m): the drive's ends (the
# search registers a scan taken up to ~5 m from a place), a one-scan map's sensor; and at least PEAK_MIN (a map of walls
# alone: 0.04; the real one-scan HDL-32E map's peak: 0.38)
GAP, PEAK_WINDOW, PEAK_SHARE, PEAK_SEPARATION, PEAK_MIN = 5.0, 7, 0.5, 5.0, 0.15


def robust_ground(points: np.ndarray, origin: np.ndarray, cell: float, shape: tuple[int, int]) -> np.ndarray:
    """The local ground height (m) of every column of a grid (``origin`` (2,) its corner, ``cell`` m, ``shape``
    (nx, ny)) over ``points`` (N, 3): the GROUND_RANK-th lowest z of each column, the lowest of those within
    GROUND_WINDOW columns; nan where no column near has points. -> (nx, ny) float32."""
    from scipy.ndimage import minimum_filter

    ij = np.floor((points[:, :2].astype(np.float64) - origin) / cell).astype(np.int64)
    flat = ij[:, 0] * shape[1] + ij[:, 1]
    order = np.lexsort((points[:, 2], flat))
    flat_s, z_s = flat[order], points[order, 2].astype(np.float32)
    starts = np.flatnonzero(np.r_[True, flat_s[1:] != flat_s[:-1]])
    ends = np.r_[starts[1:], len(flat_s)]
    pick = np.minimum(starts + GROUND_RANK - 1, ends - 1)
    col = np.full(shape[0] * shape[1], np.inf, np.float32)
    col[flat_s[starts]] = z_s[pick]
    col = col.reshape(shape)
    low = minimum_filter(col, size=GROUND_WINDOW, mode="constant", cval=np.inf)
    with np.errstate(invalid="ignore"):
        ground = np.where(np.isfinite(col) & (col - low < GROUND_STEP), col, low)  # a roof, a wall: the ground beside
    return np.where(np.isfinite(ground), ground, np.nan).astype(np.float32)


def drivable_columns(points: np.ndarray, origin: np.ndarray, cell: float, shape: tuple[int, int],
                     clearance: float, voxel: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(drivable (nx, ny) bool, clearance to the nearest obstacle (nx, ny) m, ground (nx, ny) m, ground coverage
    (nx, ny): :func:`_ground_coverage`) of the grid over
    ``points`` (N, 3) on a ``voxel`` m grid (module docstring; a map too sparse for any drivable column so is judged
    against its own typical column: :func:`_close_coverage`)."""
    from scipy.ndimage import distance_transform_edt, uniform_filter

    ground = robust_ground(points, origin, cell, shape)
    ij = np.floor((points[:, :2].astype(np.float64) - origin) / cell).astype(np.int64)
    flat = ij[:, 0] * shape[1] + ij[:, 1]
    n = shape[0] * shape[1]
    g = ground.reshape(-1)[flat]
    h = points[:, 2] - g  # height above the local ground (nan: no ground near)
    with np.errstate(invalid="ignore"):
        in_band = (h > OBSTACLE_BAND[0]) & (h < OBSTACLE_BAND[1])
        on_ground = np.abs(h) <= OBSTACLE_BAND[0]
    covered = _ground_coverage(points[on_ground], origin, cell, shape, voxel)
    near_band = (np.bincount(flat[in_band], minlength=n) >= OBSTACLE_POINTS).reshape(shape)

    def free_of(full: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        obstacle = near_band & ~full
        dist = distance_transform_edt(~obstacle) * cell  # m to the nearest obstacle column
        free = full & (dist >= max(clearance, cell))
        free &= uniform_filter(full.astype(np.float32), size=GROUND_WINDOW + 2) >= GROUND_COVERAGE
        return free, dist

    free, dist = free_of(covered >= GROUND_FILL * _close_coverage(covered))
    if not free.any():  # a sparse map: ground coverage judged against its own typical column's
        free, dist = free_of(covered >= GROUND_FILL * _close_coverage(covered, sparse=True))
    return free, dist, ground, covered


def _ground_coverage(on_ground: np.ndarray, origin: np.ndarray, cell: float, shape: tuple[int, int],
                     voxel: float) -> np.ndarray:
    """(nx, ny) the share of each column's ``voxel`` m sub-squares holding a ground return of ``on_ground`` (M, 3):
    where the mapping sensor passed its ground is seen densely (ground seen from afar: the rings' lines only), whatever
    the sensor's density."""
    sub = max(int(round(cell / voxel)), 1) if voxel > 0 else 5
    sq = np.floor((on_ground[:, :2].astype(np.float64) - origin) * (sub / cell)).astype(np.int64)
    ny = shape[1] * sub
    key = np.unique(sq[:, 0] * ny + sq[:, 1])  # the occupied sub-squares, once each
    cols = (key // ny) // sub * shape[1] + (key % ny) // sub  # the column of each
    return np.bincount(cols, minlength=shape[0] * shape[1]).reshape(shape) / float(sub * sub)


def coverage_peaks(covered: np.ndarray, ground: np.ndarray, taken: np.ndarray, cell: float) -> np.ndarray:
    """(K, 2) int the columns of the ground coverage's peaks (module docstring: ``peaks``) farther than GAP m from
    every column of ``taken`` (nx, ny) bool (the drivable places), with a ground under them."""
    from scipy.ndimage import distance_transform_edt, uniform_filter

    dens = uniform_filter(covered.astype(np.float32), size=max(1, int(round(PEAK_WINDOW / cell))), mode="constant")
    ref = float(np.median(dens[taken])) if taken.any() else float(dens.max())
    far = distance_transform_edt(~taken) * cell > GAP if taken.any() else np.ones_like(taken)
    cand = (dens >= max(PEAK_SHARE * ref, PEAK_MIN)) & far & np.isfinite(ground)
    ix, iy = np.nonzero(cand)
    first = _best_per_block(ix, iy, dens[ix, iy], max(1, int(round(PEAK_SEPARATION / cell))), taken.shape[1])
    return np.stack([ix[first], iy[first]], axis=1).astype(np.int64)


def _best_per_block(ix: np.ndarray, iy: np.ndarray, score: np.ndarray, step: int, ny: int) -> np.ndarray:
    """Indices into the columns ``(ix, iy)`` (K,) of the highest-``score`` column of each ``step`` x ``step`` block of
    a grid ``ny`` columns wide, in block order."""
    block = (ix // step) * (ny // step + 1) + iy // step
    order = np.lexsort((-score, block))  # by block, the best column first
    return order[np.r_[True, block[order][1:] != block[order][:-1]]] if len(order) else order


def _close_coverage(covered: np.ndarray, sparse: bool = False) -> float:
    """The share of sub-squares with a ground return where this map's sensor passed closest: its best-seen column's
    (1 on a dense map, as a roof LiDAR's on a 0.2 m grid); on a map too sparse for that to give any place (thinned,
    or made by a sparse sensor: its ground coverage is patchy even under the sensor's path), the SPARSE_QUANTILE of
    its columns with any ground return. GROUND_FILL is a share of what this map can show, not of an ideal density."""
    seen = covered[covered > 0]
    if not len(seen):
        return 1.0
    return float(np.quantile(seen, SPARSE_QUANTILE)) if sparse else float(seen.max())


def grid_places(points: np.ndarray, origin: np.ndarray, cell: float, shape: tuple[int, int], spacing: float,
                clearance: float, height: float, voxel: float) -> np.ndarray:
    """(P, 4, 4) float64 place poses ``T_map_place`` over the drivable columns of the grid over ``points`` (N, 3):
    one per ``spacing`` m square block, the column farthest from obstacles, then the ground coverage's peaks away from
    them (:func:`coverage_peaks`), ``height`` m above its ground (module docstring)."""
    free, dist, ground, covered = drivable_columns(points, origin, cell, shape, clearance, voxel)
    ix, iy = np.nonzero(free)
    first = _best_per_block(ix, iy, dist[ix, iy], max(1, int(round(spacing / cell))), shape[1])  # the clearest
    ix, iy = ix[first], iy[first]
    taken = np.zeros(shape, bool)
    taken[ix, iy] = True
    peaks = coverage_peaks(covered, ground, taken, cell)  # the drive's ends, a one-scan map
    ix, iy = np.r_[ix, peaks[:, 0]].astype(np.int64), np.r_[iy, peaks[:, 1]].astype(np.int64)
    if len(ix) == 0:
        return np.zeros((0, 4, 4))
    out = np.repeat(np.eye(4)[None], len(ix), axis=0)
    out[:, :2, 3] = np.asarray(origin, np.float64) + (np.stack([ix, iy], axis=1) + 0.5) * cell
    out[:, 2, 3] = ground[ix, iy] + height
    return out
