"""Ground removal that assumes no car: tilted and handheld sensors, low robots indoors (floor, not ceiling), no floor
at all, and today's car-roof scans unchanged. Scenes are ray cast analytically (tests/test_preprocess.py's street,
and a box room here), so the true floor is known."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_preprocess import GROUND, make_scan

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.core.ground import find_floor, plausible_floor
from deepbbs_ros.core.preprocess import fit_ground_plane, preprocess


def room_scan(height: float, *, ceiling: float = 2.6, half: tuple[float, float] = (12.0, 6.0),
              R_sensor_level: np.ndarray | None = None, rays: int = 20000,
              seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Ray cast a box room (floor z = 0, ceiling z = ``ceiling``, walls at x = +-half[0], y = +-half[1], level frame)
    from a sensor ``height`` m above the floor at the room's centre, rotated by ``R_sensor_level`` (the sensor frame's
    axes in the level frame: a tilt); rays uniform over the sphere. Returns ((rays, 3) float32 points in the sensor
    frame, (4,) the true floor plane in the sensor frame, normal towards the sensor)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(rays, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)  # level-frame directions
    with np.errstate(divide="ignore"):
        t = np.full(rays, np.inf)
        for axis, lo, hi in ((0, -half[0], half[0]), (1, -half[1], half[1]), (2, -height, ceiling - height)):
            for bound in (lo, hi):
                ti = bound / u[:, axis]
                t = np.where((ti > 0) & (ti < t), ti, t)
    p_level = u * (t + rng.normal(0.0, 0.01, rays))[:, None]
    R = np.eye(3) if R_sensor_level is None else R_sensor_level
    pts = (p_level @ R).astype(np.float32)  # p_sensor = R^T p_level
    n = R.T @ np.array([0.0, 0.0, 1.0])
    return pts, np.concatenate([n, [height]])


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a[:3] @ b[:3] / np.linalg.norm(a[:3]) / np.linalg.norm(b[:3]), -1, 1))))


def test_tilted_handheld_sensor_finds_the_floor():
    # a street scan seen by a sensor rolled 40 deg and pitched 15 deg: beyond the upright fit's 20 deg
    pts, labels, plane = make_scan(beams=32, azimuths=720, sensor_height=1.4, pitch_deg=0.0, roll_deg=0.0, seed=2)
    R = Rotation.from_euler("xy", [40.0, 15.0], degrees=True).as_matrix()
    tilted = (pts @ R).astype(np.float32)  # the sensor frame's axes are R's columns in the level frame
    true = np.concatenate([R.T @ plane[:3], [plane[3]]])
    res = preprocess(tilted, PreprocessConfig(min_range=1.0))
    assert res.ground_status == "floor_search" and res.ground_found
    assert angle_deg(res.ground_plane, true) < 1.0
    assert abs(res.ground_plane[3] - true[3]) < 0.05
    valid = np.isfinite(tilted).all(axis=1) & (np.linalg.norm(tilted, axis=1) >= 1.0)
    assert res.n_nonground < valid.sum() - 0.9 * (labels[valid] == GROUND).sum()  # the floor's layer went
    # the upright-only setting keeps today's rule: no plane within 20 deg of +z holds the floor
    upright = preprocess(tilted, PreprocessConfig(min_range=1.0, ground_search="upright"))
    assert upright.ground_plane is None or angle_deg(upright.ground_plane, true) > 10.0


@pytest.mark.parametrize("height", [0.3, 1.0])
def test_low_robot_indoors_removes_the_floor_not_the_ceiling(height):
    pts, true = room_scan(height)
    res = preprocess(pts, PreprocessConfig(min_range=0.3))
    assert res.ground_found
    assert angle_deg(res.ground_plane, true) < 1.0
    assert abs(abs(res.ground_plane[3]) - height) < 0.03
    h = pts @ true[:3] + true[3]
    near_floor = np.abs(h) < 0.1
    assert res.n_nonground <= len(pts) - near_floor.sum()


def mid360_view(pts: np.ndarray) -> np.ndarray:
    """The returns of ``pts`` (N, 3) inside a Livox Mid-360's field of view (elevation -7 to +52 degrees)."""
    el = np.degrees(np.arcsin(pts[:, 2] / np.linalg.norm(pts, axis=1)))
    return pts[(el > -7.0) & (el < 52.0)]


def test_a_ceiling_taken_by_the_upright_fit_is_rejected():
    # a Mid-360 0.3 m above the floor of a 2.4 m room: it sees the ceiling near it and the floor only far away
    pts, true = room_scan(0.3, ceiling=2.4, rays=40000)
    pts = mid360_view(pts)
    cfg = PreprocessConfig(min_range=0.3)
    upright_fit = fit_ground_plane(pts, cfg)
    assert upright_fit[3] < 0  # the upright rule picks the ceiling (the sensor is under it) ...
    assert not plausible_floor(pts, upright_fit, cfg)  # ... which is no floor
    res = preprocess(pts, cfg)
    assert res.ground_status == "floor_search"
    assert angle_deg(res.ground_plane, true) < 1.0 and abs(res.ground_plane[3] - 0.3) < 0.03


def test_no_floor_keeps_every_point():
    # a Mid-360 0.8 m above the floor of a 2 m high, 12 m wide room sees no floor (its lowest ray meets the floor
    # beyond the walls); a sensor on a 5 m mast sees its floor out of the plausible mount heights: keep everything
    low, _ = room_scan(0.8, ceiling=2.0, rays=40000)
    mast, _ = room_scan(5.0, ceiling=8.0, rays=20000)
    for pts, cfg in ((mid360_view(low), PreprocessConfig(min_range=0.3)),
                     (mast, PreprocessConfig(min_range=0.3, ground_search="any"))):
        res = preprocess(pts, cfg)
        assert not res.ground_found and res.ground_status == "none" and res.ground_plane is None
        assert res.n_nonground == res.n_valid
        assert find_floor(pts, cfg) is None


def test_ground_search_setting_and_removal_off():
    pts, true = room_scan(0.6)
    res = preprocess(pts, PreprocessConfig(min_range=0.3, ground_search="any"))
    assert res.ground_status == "floor_search" and angle_deg(res.ground_plane, true) < 1.0
    off = preprocess(pts, PreprocessConfig(min_range=0.3, remove_ground=False))
    assert off.ground_status == "off" and not off.ground_found


def test_car_roof_scan_keeps_the_upright_fit_bit_for_bit():
    # today's input: the default (auto) gives exactly the upright-only result (the same plane, points, samples)
    pts, _, _ = make_scan(beams=32, azimuths=720, pitch_deg=6.0, roll_deg=-2.0, seed=1)
    new = preprocess(pts, PreprocessConfig())
    old = preprocess(pts, replace(PreprocessConfig(), ground_search="upright", min_candidates=0))
    assert new.ground_status == "upright"
    np.testing.assert_array_equal(new.ground_plane, old.ground_plane)
    np.testing.assert_array_equal(new.points, old.points)
    np.testing.assert_array_equal(new.dense_points, old.dense_points)
