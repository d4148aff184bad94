"""The second-minimum check's reach (core/second_minimum.py ``reach``, ``registration.second_minimum_reach``): a pose
slid metres along a corridor, beyond the check's 5 tolerances, is turned away; the right pose and a pinned one stay.
In the corridor the weakest direction is a roll about its axis; the slide is the weakest translation."""

from __future__ import annotations

import numpy as np
from plane_scenes import STREET, scene

from deepbbs_ros.config import Config
from deepbbs_ros.core import second_minimum
from deepbbs_ros.core.good_start import good_start_points
from deepbbs_ros.core.polish import polish, prepare_polish_cloud

PERIOD = 6.0  # m between the corridor's pillars


def _corridor(rng: np.random.Generator, n: int, half: float = 20.0) -> np.ndarray:
    """A corridor 3 m wide and 3 m high seen ``half`` m both ways along x, with thin pillars on both walls every
    ``PERIOD`` m: slid by a period, the walls and the pillars line up again; only the ends do not."""
    x = rng.uniform(-half, half, n)
    side = rng.integers(0, 4, n)  # two walls, floor, ceiling
    u = rng.uniform(-1.5, 1.5, n)
    p = np.where(side[:, None] == 0, np.c_[x, np.full(n, 1.5), u],
                 np.where(side[:, None] == 1, np.c_[x, np.full(n, -1.5), u],
                          np.c_[x, u, np.where(side == 2, -1.5, 1.5)]))
    out = [p]
    m = 600
    for c in np.arange(-half + PERIOD / 2, half, PERIOD):
        for wall in (1.5, -1.5):
            face = rng.integers(0, 3, m)  # the inner face and the two sides of a 0.3 x 0.3 m pillar
            px = np.where(face == 1, c + 0.5, np.where(face == 2, c - 0.5, rng.uniform(c - 0.5, c + 0.5, m)))
            py = np.where(face == 0, wall - np.sign(wall) * 0.5, wall - np.sign(wall) * rng.uniform(0, 0.5, m))
            out.append(np.c_[px, py, rng.uniform(-1.5, 1.5, m)])
    p = np.vstack(out)
    return p + rng.normal(0.0, 0.01, p.shape)


def _shift(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def _check(target: np.ndarray, source: np.ndarray, T: np.ndarray, reach: bool) -> second_minimum.Ambiguity:
    rc = Config().registration
    tpc, spc = (prepare_polish_cloud(c, rc.polish_voxel, rc.polish_neighbors, threads=1) for c in (target, source))
    return second_minimum.check(good_start_points(spc, rc), T, spc, tpc, rc, reach=reach)


def test_a_pose_slid_a_pillar_period_along_a_corridor_is_turned_away_with_reach():
    target, source = (_corridor(np.random.default_rng(s), 20000) for s in (0, 1))
    rc = Config().registration
    tpc, spc = (prepare_polish_cloud(c, rc.polish_voxel, rc.polish_neighbors, threads=1) for c in (target, source))
    slid = polish(spc, tpc, _shift(PERIOD), rc).T_target_source  # the minimum a pillar period along the corridor
    assert abs(slid[0, 3] - PERIOD) < 0.1, slid
    near = _check(target, source, slid, reach=False)
    far = _check(target, source, slid, reach=True)
    assert far.uncertainty > second_minimum.WRONG, far  # the fit leaves the pose free along the corridor
    assert far.ambiguous and far.offset > second_minimum.STEPS[-1], far  # a minimum as good beyond 5 tolerances
    assert abs(far.other[1:3, 3]).max() < 0.1, far.other  # along the corridor
    assert not near.ambiguous, near  # 5 tolerances (1.5 m) do not reach it


def test_the_right_pose_and_a_pinned_pair_stay_accepted_with_reach():
    target, source = (_corridor(np.random.default_rng(s), 20000) for s in (0, 1))
    right = _check(target, source, np.eye(4), reach=True)
    assert not right.ambiguous, right
    target, source = scene(STREET, np.random.default_rng(0), 6000), scene(STREET, np.random.default_rng(1), 3000)
    a = _check(target, source, np.eye(4), reach=True)
    assert not a.ambiguous and a.other is None, a


def test_the_reach_grows_to_the_scene_extent():
    rc = Config().registration
    tpc = prepare_polish_cloud(_corridor(np.random.default_rng(0), 5000), rc.polish_voxel, rc.polish_neighbors,
                               threads=1)
    twist = np.array([0.3, 0, 0, 0, 0, 0])  # one tolerance along the corridor
    assert second_minimum.reaches(5.0, twist, tpc) == [5.0, 10.0, 20.0, 40.0, 80.0]  # 40 m: 133 tolerances
