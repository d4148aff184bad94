"""The verdict's ``in_view`` and ``observable_rel`` features (core/visibility.py): the overlap a pose expects (the
share of the source that the pose puts in the target's field of view, measured on the target's returns) and the
measured overlap against it. A narrow sensor turned by half its view keeps about half of the source in view; a pose
slid along a corridor keeps all of it."""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core import visibility
from deepbbs_ros.sim.trajectory import euler_to_matrix

_HALF = np.radians(35.0)  # a 70 x 70 degree view (a Livox Avia's is 70 x 77)


def _room_scan(position: np.ndarray, yaw: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """A narrow sensor at ``position`` (world) heading ``yaw`` (rad) in a 40 x 8 x 6 m hall: its returns (sensor
    frame), cast along rays drawn evenly in its 70 x 70 degree view."""
    az, el = rng.uniform(-_HALF, _HALF, n), rng.uniform(-_HALF, _HALF, n)
    d = np.c_[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]
    R = euler_to_matrix(0.0, 0.0, yaw)
    dw = d @ R.T
    lo, hi = np.array([-20.0, -4.0, -1.5]), np.array([20.0, 4.0, 4.5])
    with np.errstate(divide="ignore"):
        t = np.where(dw > 0, (hi - position) / dw, (lo - position) / dw)
    r = np.min(np.where(np.isfinite(t) & (t > 0), t, np.inf), axis=1)
    return d * r[:, None]


def _pose_features(source: np.ndarray, T: np.ndarray, target: np.ndarray) -> dict[str, float]:
    return dict(zip(visibility.FEATURES, visibility.pose_features(source, T, target, 0.5), strict=True))


def test_turned_by_half_its_view_expects_half_and_observes_what_it_expects():
    rng = np.random.default_rng(0)
    target = _room_scan(np.zeros(3), 0.0, 6000, rng)
    source = _room_scan(np.zeros(3), _HALF, 1500, rng)  # turned by half its 70-degree view
    T = np.eye(4)
    T[:3, :3] = euler_to_matrix(0.0, 0.0, _HALF)  # the right pose
    f = _pose_features(source, T, target)
    assert 0.4 <= f["in_view"] <= 0.6
    assert f["observable"] <= f["in_view"] + 0.05  # the pose cannot observe more than it puts in view
    assert f["observable_rel"] >= 0.9  # what the right pose puts in view, the target saw
    assert f["observable"] < 0.6  # while the overlap itself is low


def test_slid_pose_expects_all_of_the_source_in_view():
    rng = np.random.default_rng(1)
    target = _room_scan(np.zeros(3), 0.0, 6000, rng)
    source = _room_scan(np.array([1.0, 0.0, 0.0]), 0.0, 1500, rng)  # walked 1 m down the hall, not turned
    wrong = np.eye(4)
    wrong[0, 3] = 3.0  # answered 2 m too far along the hall
    f = _pose_features(source, wrong, target)
    assert f["in_view"] >= 0.9
    assert abs(f["observable_rel"] - min(1.0, f["observable"] / f["in_view"])) < 1e-9


def test_in_view_of_nothing():
    assert visibility.in_view(np.zeros((0, 3)), np.radians(1.0), np.arange(3)) == 0.0
    f = dict(zip(visibility.FEATURES, visibility.features(np.ones((4, 3)), np.zeros(4), np.zeros((0, 3)), 0.5),
                 strict=True))
    assert f["in_view"] == 0.0 and f["observable_rel"] == 0.0
