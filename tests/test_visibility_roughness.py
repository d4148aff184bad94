"""The verdict's ``plane_own`` feature (core/visibility.py): the source's fit to the target's tangent planes within
the target's own roughness, so that a right pose on a rough scene scores like a right pose on a smooth one."""

from __future__ import annotations

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import visibility
from deepbbs_ros.core.polish import prepare_polish_cloud


def _room(rng: np.random.Generator, n: int, rough: float) -> np.ndarray:
    """Returns of a sensor at the origin in a 16 x 10 x 3 m room with a pillar, each moved by ``rough`` m (sigma)
    along its ray: a rough surface (bushes, rough walls, range noise) of known roughness."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.min(np.array([8.0, 5.0, 1.5]) / np.maximum(np.abs(d), 1e-9), axis=1)
    return d * (t + rng.normal(0.0, rough, n))[:, None] if rough else d * t[:, None]


def _features(rough: float, T: np.ndarray) -> dict[str, float]:
    rc = Config().registration
    target = prepare_polish_cloud(_room(np.random.default_rng(0), 30000, rough), rc.polish_voxel, rc.polish_neighbors,
                                  threads=1)
    source = _room(np.random.default_rng(1), 3000, rough)
    return dict(zip(visibility.FEATURES, visibility.pose_features(source, T, target, rc.verdict_dist), strict=True))


def test_a_right_pose_on_a_rough_scene_scores_like_one_on_a_smooth_scene():
    smooth, rough = _features(0.0, np.eye(4)), _features(0.12, np.eye(4))
    assert rough["plane_close"] < smooth["plane_close"] - 0.08, (smooth, rough)  # plane_close reads rough as loose
    assert abs(rough["plane_own"] - smooth["plane_own"]) < 0.03, (smooth, rough)
    assert smooth["plane_own"] >= smooth["plane_close"] > 0.9, smooth


def test_plane_own_still_tells_a_wrong_pose_on_a_rough_scene():
    T = np.eye(4)
    c, s = np.cos(0.06), np.sin(0.06)
    T[:2, :2], T[:3, 3] = [[c, -s], [s, c]], [0.6, -0.4, 0.0]  # 3.4 deg, 0.72 m: wrong
    right, wrong = _features(0.12, np.eye(4)), _features(0.12, T)
    assert wrong["plane_own"] < right["plane_own"] - 0.05, (right, wrong)
    assert wrong["plane_own"] < _features(0.0, np.eye(4))["plane_own"] - 0.05, wrong


def test_own_tolerance_follows_the_target_and_stays_bounded():
    assert visibility.own_tolerance(np.zeros(100), 0.5) == 0.1  # clean planes: plane_close's tolerance
    assert visibility.own_tolerance(np.full(100, 3.0), 0.5) == 0.25  # trees never make everything fit
    assert abs(visibility.own_tolerance(np.linspace(0, 0.2, 101), 0.5) - 0.18) < 1e-9
    assert visibility.own_tolerance(np.zeros(0), 0.5) == 0.1


def _rings(origin: np.ndarray, beams: int = 16) -> np.ndarray:
    """A sparse spinning sensor at ``origin`` (1.8 m above a flat floor) in a 60 m long street with walls 8 m to
    each side: its rings (-15 to +1 deg, 1 deg apart in azimuth), in the world frame."""
    el = np.radians(np.linspace(-15.0, 1.0, beams))
    az = np.radians(np.arange(-180.0, 180.0, 1.0))
    E, A = np.meshgrid(el, az)
    d = np.c_[(np.cos(E) * np.cos(A)).ravel(), (np.cos(E) * np.sin(A)).ravel(), np.sin(E).ravel()]
    with np.errstate(divide="ignore"):
        t_floor = np.where(d[:, 2] < 0, -1.8 / d[:, 2], np.inf)
        t_wall = np.where(np.abs(d[:, 1]) > 1e-6, 8.0 / np.abs(d[:, 1]), np.inf)
    t = np.minimum(np.minimum(t_floor, t_wall), 60.0)
    return (d * t[:, None])[t < 60.0] + origin


def test_a_sparse_ring_sensor_moved_along_the_road_does_not_violate_its_own_free_space():
    """A right pose two metres further along: the source's floor returns fall between the target's rings, in
    direction cells whose only target return is a farther ring; ``violations`` counts some of them, ``violations_nb``
    (the neighbouring cells' nearest return) none, and still sees a wall put where the target saw through."""
    rc = Config().registration
    target = prepare_polish_cloud(_rings(np.zeros(3)), rc.polish_voxel, rc.polish_neighbors, threads=1)
    source = _rings(np.array([2.0, 0.0, 0.0])) - np.array([2.0, 0.0, 0.0])  # its own frame
    T = np.eye(4)
    T[0, 3] = 2.0  # the truth
    f = dict(zip(visibility.FEATURES, visibility.pose_features(source, T, target, rc.verdict_dist), strict=True))
    assert f["violations_nb"] <= 0.005 and f["consistency_nb"] >= 0.99, f
    assert f["violations"] >= 0.01 and f["violations"] > 2 * f["violations_nb"], f
    W = np.eye(4)
    W[1, 3] = 4.0  # 4 m sideways: the left wall in the middle of the street, where the target saw the far wall
    w = dict(zip(visibility.FEATURES, visibility.pose_features(source, W, target, rc.verdict_dist), strict=True))
    assert w["violations_nb"] > 0.05 and w["consistency_nb"] < 0.9, w
