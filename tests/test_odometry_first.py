"""The first motion searched along its weakest direction above the floor (core/odometry_first.py)."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core import odometry_first as F

small_gicp = pytest.importorskip("small_gicp")

POSTS = np.array([-31.0, -22.5, -17.0, -9.4, -3.1, 4.2, 9.9, 17.6, 26.0, 33.3])


def _road_scan(x: float, rng: np.random.Generator, n: int = 8000) -> np.ndarray:
    """A scan (sensor frame, 1.8 m above a flat road) from ``x`` along a straight road: the road, two rails at y = +-6 m
    (0-0.8 m high) and posts beside them at irregular places; a new draw each scan."""
    u, kind = rng.uniform(-35, 35, n), rng.integers(0, 4, n)
    y = np.where(kind == 0, rng.uniform(-6, 6, n), np.where(kind == 1, -6.0, 6.0))
    z = np.where(kind == 0, -1.8, -1.8 + rng.uniform(0, 0.8, n))
    pts = np.c_[u, y, z]
    m = kind == 3
    k = rng.integers(0, len(POSTS), m.sum())
    pts[m] = np.c_[POSTS[k] + rng.normal(0, 0.1, m.sum()), np.where(rng.random(m.sum()) < 0.5, -6.5, 6.5),
                   -1.8 + rng.uniform(0, 3, m.sum())]
    pts[:, 0] -= x
    return pts + rng.normal(0, 0.01, pts.shape)


def test_above_floor_drops_the_road_and_keeps_a_scan_without_one():
    rng = np.random.default_rng(0)
    scan = _road_scan(0.0, rng)
    above = F.above_floor(scan, Config().preprocess)
    assert 0.5 * len(scan) < len(above) < 0.65 * len(scan)  # the road (a quarter) and the rails' lowest 0.25 m
    assert above[:, 2].min() > -1.8 + 0.2
    wall = np.c_[rng.uniform(-5, 5, 2000), np.full(2000, 3.0), rng.uniform(0, 2, 2000)]  # no floor seen
    assert len(F.above_floor(wall, Config().preprocess)) == len(wall)


def test_search_finds_the_motion_beyond_gicps_reach_along_the_road():
    """Known truth: 1.6 m along the road, beyond GICP's reach from identity (the correspondence distance, 1 m)."""
    rng = np.random.default_rng(0)
    first, scan = _road_scan(0.0, rng), _road_scan(1.6, rng)
    t, _ = small_gicp.preprocess_points(first, downsampling_resolution=0.4)
    s, _ = small_gicp.preprocess_points(scan, downsampling_resolution=0.4)
    vmap = small_gicp.GaussianVoxelMap(0.8)
    vmap.insert(t)
    plain = small_gicp.align(vmap, s, np.eye(4), max_correspondence_distance=1.0).T_target_source
    assert abs(plain[0, 3]) < 0.2  # GICP alone stays at identity
    pp = Config().preprocess
    res = F.search_along(F.above_floor(first, pp), F.above_floor(scan, pp), np.eye(4), np.array([1.0, 0.0, 0.0]),
                         4.0, 0.8, 1.0, 0.02, 20, 1)
    assert res.won and res.fit > res.fit_before + 0.02
    assert np.allclose(res.pose[:3, 3], [1.6, 0.0, 0.0], atol=0.05)
    assert res.sigma < 0.5  # one place fits clearly best
    # the same from the truth: nothing wins, the answer stays
    T = np.eye(4)
    T[0, 3] = 1.6
    stay = F.search_along(F.above_floor(first, pp), F.above_floor(scan, pp), T, np.array([1.0, 0.0, 0.0]), 4.0,
                          0.8, 1.0, 0.02, 20, 1)
    assert not stay.won and np.allclose(stay.pose, T)
