"""The verdict's ``pinned`` feature (core/visibility.py): how well the source's matches on the target's planes pin
all six degrees of freedom. A pose that slides along a wall or a corridor fits as tightly as the right one; only
geometry with planes facing every way (a box corner, a street with cross walls) tells where along them it is."""

from __future__ import annotations

import numpy as np
from plane_scenes import FLOOR as _FLOOR
from plane_scenes import STREET as _STREET
from plane_scenes import scene as _scene

from deepbbs_ros.config import Config
from deepbbs_ros.core import visibility
from deepbbs_ros.core.polish import prepare_polish_cloud

# planes as (axis, offset, (lo, hi) of the two other axes): points with coordinate ``axis`` = offset
_WALL = [(0, 5.0, (-10, 10), (-1, 2))]
_CORRIDOR = [(0, 2.0, (-15, 15), (-1, 2)), (0, -2.0, (-15, 15), (-1, 2)), (2, -1.0, (-2, 2), (-15, 15))]
_CORNER = [(0, 5.0, (-6, 6), (-1, 2)), (1, 6.0, (-5, 5), (-1, 2)), (2, -1.0, (-5, 5), (-6, 6))]



def _features(planes, T: np.ndarray = np.eye(4)) -> dict[str, float]:
    rc = Config().registration
    target = prepare_polish_cloud(_scene(planes, np.random.default_rng(0), 6000), rc.polish_voxel,
                                  rc.polish_neighbors, threads=1)
    source = _scene(planes, np.random.default_rng(1), 600)
    return dict(zip(visibility.FEATURES, visibility.pose_features(source, T, target, rc.verdict_dist), strict=True))


def test_a_wall_or_a_corridor_does_not_pin_the_pose_a_corner_or_a_street_with_cross_walls_does():
    loose = {name: _features(p)["pinned"] for name, p in (("wall", _WALL), ("floor and wall", _WALL + _FLOOR),
                                                          ("corridor", _CORRIDOR))}
    pinned = {name: _features(p)["pinned"] for name, p in (("corner", _CORNER), ("street", _STREET))}
    # (not 0 where a floor meets a wall: the normals estimated at the edge lean every way)
    assert max(loose.values()) < 0.04 < 0.06 < min(pinned.values()), (loose, pinned)


def test_a_pose_sliding_along_a_corridor_fits_like_the_right_one_but_is_not_pinned():
    T = np.eye(4)
    T[1, 3] = 1.5  # 1.5 m along the corridor: wrong, and every point still on a wall or the floor
    right, slid = _features(_CORRIDOR), _features(_CORRIDOR, T)
    for f in ("fitness", "plane_close", "consistency"):  # what the other features see: as good as the right pose
        assert slid[f] > right[f] - 0.15 and slid[f] > 0.8, (f, right, slid)
    assert slid["pinned"] < 0.05, slid


def test_pinned_of_exact_planes():
    rng = np.random.default_rng(2)
    p = rng.uniform(-5, 5, (300, 3))
    p[:, 0] = 4.0
    n = np.tile([1.0, 0.0, 0.0], (300, 1))
    assert visibility.pinned(p, n, 0.1) < 1e-9  # one plane: two shifts and a turn are free
    q = np.vstack([p, p[:, [1, 0, 2]], p[:, [1, 2, 0]]])
    m = np.vstack([n, n[:, [1, 0, 2]], n[:, [1, 2, 0]]])
    assert 0.1 < visibility.pinned(q, m, 0.1) < 1.0  # three orthogonal planes
    assert visibility.pinned(q, m, 0.05) > visibility.pinned(q, m, 0.1)  # a tighter residual pins more
    assert visibility.pinned(q[:5], m[:5], 0.1) == 0.0  # too few matches


def test_a_plain_target_cloud_gets_its_normals_from_its_neighbours():
    """Without a precision stage's normals, ``pinned`` takes them from the target's nearest points."""
    rc = Config().registration

    def pin(planes):
        target = _scene(planes, np.random.default_rng(0), 3000)
        f = visibility.pose_features(_scene(planes, np.random.default_rng(1), 400), np.eye(4), target, rc.verdict_dist)
        return dict(zip(visibility.FEATURES, f, strict=True))["pinned"]

    assert pin(_CORRIDOR) < 0.04 < 0.06 < pin(_CORNER), (pin(_CORRIDOR), pin(_CORNER))
