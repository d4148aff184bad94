"""core/visibility.py on a crop that is a view of a map's GICP cloud (core/polish.py ``PolishView``)."""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core import visibility
from deepbbs_ros.core.polish import PolishView, prepare_polish_cloud


def test_a_view_holding_every_voxel_of_its_map_is_judged_as_any_view():
    """A view holding all of a small map's voxels (as many as the map's normals) is judged like a view of part of it
    (the map's normals are not its own: before, it raised AttributeError on the view's framed tree)."""
    rng = np.random.default_rng(3)
    ground = np.c_[rng.uniform(-20, 20, (4000, 2)), rng.normal(0, 0.02, 4000)]
    wall = np.c_[rng.uniform(-20, 20, 2000), np.full(2000, 8.0), rng.uniform(0, 3, 2000)]
    base = prepare_polish_cloud(np.r_[ground, wall], 0.5, 20)
    T = np.eye(4)
    T[:3, 3] = (1.0, 2.0, 0.0)  # the view's frame A: the map moved by -T
    local = base.points() - T[:3, 3]
    whole = PolishView.of(base, local, T)
    part = PolishView.of(base, local[:-1], T)
    scan = local[::7]
    a = visibility.pose_features(scan, np.eye(4), whole, 0.5, anchor=False)
    b = visibility.pose_features(scan, np.eye(4), part, 0.5, anchor=False)
    assert np.all(np.isfinite(a)) and np.allclose(a, b, atol=0.02)
