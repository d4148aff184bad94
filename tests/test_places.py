"""Candidate places of a map given without its trajectory (core/places.py), on tiny synthetic maps (no model).

The street: a 60 x 14 m yard of ground on a 0.2 m grid (what a mapping sensor passing along y = 0 sees densely),
walls along y = +-7 m, a parked car (a box with its ground unseen) at x = 20, and what must not block the road: the
mapping car's own roof returns 0.9-1.8 m over the path, tree canopy 4 m up, and a handful of returns 3 m below the road
(multipath). Ground seen only from afar (the rings' lines 1 m apart) lies beyond the walls.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core.places import drivable_columns, grid_places, robust_ground

VOXEL, CELL = 0.2, 1.0
ROAD_Z = 10.0  # m, the road's height in the map frame


def _street(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(0, 60, VOXEL), np.arange(-7, 7, VOXEL), indexing="ij")
    ground = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, ROAD_Z)], axis=1)
    car = (ground[:, 0] > 18) & (ground[:, 0] < 23) & (ground[:, 1] > 2.5) & (ground[:, 1] < 4.5)
    ground = ground[~car]  # the parked car hides its ground
    wz = np.arange(0.0, 3.0, VOXEL)
    wx = np.arange(0, 60, VOXEL)
    walls = [np.stack([xx.ravel(), np.full(xx.size, y), ROAD_Z + zz.ravel()], axis=1)
             for y in (-7.2, 7.2) for xx, zz in [np.meshgrid(wx, wz, indexing="ij")]]
    cx, cz = np.meshgrid(np.arange(18, 23, VOXEL), np.arange(0.3, 1.5, VOXEL), indexing="ij")
    car_side = np.stack([cx.ravel(), np.full(cx.size, 2.5), ROAD_Z + cz.ravel()], axis=1)
    px = np.arange(0, 60, VOXEL)
    roof = np.stack([px, rng.uniform(-0.8, 0.8, len(px)), ROAD_Z + rng.uniform(0.9, 1.8, len(px))], axis=1)
    canopy = np.stack([rng.uniform(30, 40, 400), rng.uniform(-3, 3, 400), np.full(400, ROAD_Z + 4.0)], axis=1)
    below = np.stack([rng.uniform(0, 60, 20), rng.uniform(-5, 5, 20), np.full(20, ROAD_Z - 3.0)], axis=1)
    lx, ly = np.meshgrid(np.arange(0, 60, VOXEL), np.arange(9, 20, 1.0), indexing="ij")  # far ground: ring lines
    far = np.stack([lx.ravel(), ly.ravel(), np.full(lx.size, ROAD_Z)], axis=1)
    return np.concatenate([ground, *walls, car_side, roof, canopy, below, far]).astype(np.float32)


def _grid(points: np.ndarray, pad: float = 5.0) -> tuple[np.ndarray, tuple[int, int]]:
    origin = points[:, :2].min(axis=0).astype(np.float64) - pad
    shape = tuple(int(v) for v in np.ceil((points[:, :2].max(axis=0) + pad - origin) / CELL).astype(int) + 1)
    return origin, shape


def test_ground_ignores_a_few_returns_below_the_road():
    pts = _street()
    origin, shape = _grid(pts)
    ground = robust_ground(pts, origin, CELL, shape)
    ix, iy = int((30 - origin[0]) // CELL), int((0 - origin[1]) // CELL)
    assert abs(ground[ix, iy] - ROAD_Z) < 0.05  # the window's minimum would be 3 m lower
    top = ground[int((20 - origin[0]) // CELL), int((3.5 - origin[1]) // CELL)]  # under the parked car
    assert abs(top - ROAD_Z) < 0.05


def test_places_on_the_road_not_in_walls_cars_or_far_ground():
    pts = _street()
    origin, shape = _grid(pts)
    free, dist, *_ = drivable_columns(pts, origin, CELL, shape, 1.5, VOXEL)
    places = grid_places(pts, origin, CELL, shape, 2.5, 1.5, 1.8, VOXEL)
    xy = places[:, :2, 3]
    assert len(places) > 20
    assert np.all(np.abs(xy[:, 1]) < 7.0 - 1.5 + 0.5)  # inside the walls, clear of them
    assert not np.any((xy[:, 0] > 17) & (xy[:, 0] < 24) & (xy[:, 1] > 1.5))  # not at the parked car
    assert not np.any(xy[:, 1] > 8)  # ground seen from afar only (the rings' lines) is no place
    # the path itself stays drivable under the mapping car's roof returns and the canopy
    path = np.floor((np.stack([np.arange(3, 57, 1.0), np.zeros(54)], axis=1) - origin) / CELL).astype(int)
    assert free[path[:, 0], path[:, 1]].mean() > 0.9
    # every 2.5 m block of the road's middle has its place
    assert np.all(np.diff(np.sort(xy[np.abs(xy[:, 1]) < 1.5, 0])) <= 2.5 + 1e-6 + CELL)


def test_a_place_stands_its_height_above_its_ground():
    pts = _street()
    origin, shape = _grid(pts)
    places = grid_places(pts, origin, CELL, shape, 2.5, 1.5, 0.7, VOXEL)
    np.testing.assert_allclose(places[:, 2, 3], ROAD_Z + 0.7, atol=0.05)
    np.testing.assert_allclose(places[:, :3, :3], np.repeat(np.eye(3)[None], len(places), axis=0))


def test_no_drivable_space_no_places():
    pts = _street()
    walls_only = pts[pts[:, 2] > ROAD_Z + 0.5]
    origin, shape = _grid(walls_only)
    assert grid_places(walls_only, origin, CELL, shape, 2.5, 1.5, 1.8, VOXEL).shape == (0, 4, 4)
