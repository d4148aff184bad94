"""The map verdict (core/map_verdict.py): the probability that a scan's pose in a prior map is right, on known
geometry: a simulated urban street's map (three noiseless HDL-64E scans at their true poses) and a scan of the same
drive between them. The right pose is likely, a pose 2 m / 5 degrees off is not, and a short map that covers only a
third of the scan leaves the right pose likely; the shipped coefficients load once, a damaged file is one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sim_maps import world_points

from deepbbs_ros.config import Config
from deepbbs_ros.core import map_verdict
from deepbbs_ros.errors import VerdictModelError


@pytest.fixture(scope="module")
def street():
    from deepbbs_ros.core.polish import prepare_polish_cloud
    from deepbbs_ros.core.registration import good_start_points
    from deepbbs_ros.sim.simulator import DriveSimulator

    rc = Config().registration
    sim = DriveSimulator("urban", 3, frames=70, motion_distortion=False)
    world = world_points(sim, (40, 52, 64)).astype(np.float64)
    T_gt = sim.pose_at(46)
    scan = sim.scan_at(46).points
    spc = prepare_polish_cloud(scan, rc.polish_voxel, rc.polish_neighbors, threads=1)
    pts = good_start_points(spc, rc)

    def cloud(local):
        """A crop's GICP cloud of map points in the place's frame (the scan's own position, gravity-aligned)."""
        return prepare_polish_cloud(local, rc.polish_voxel, rc.polish_neighbors, threads=1)

    T_place_scan = np.eye(4)
    T_place_scan[:3, :3] = T_gt[:3, :3]
    return pts, cloud, world - T_gt[:3, 3], T_place_scan, rc.verdict_dist


def _off(T: np.ndarray, metres: float, deg: float) -> np.ndarray:
    a = np.radians(deg)
    D = np.eye(4)
    D[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    D[:3, 3] = [metres, 0.0, 0.0]
    return T @ D


def test_right_pose_likely_wrong_pose_not(street):
    pts, cloud, world, T, dist = street
    tgt = cloud(world)
    right = map_verdict.probability(map_verdict.features(pts, T, tgt, dist))
    off = map_verdict.probability(map_verdict.features(pts, _off(T, 2.0, 5.0), tgt, dist))
    assert right >= Config().localization.min_probability and off < 0.2, (right, off)
    assert len(map_verdict.features(pts, T, tgt, dist)) == len(map_verdict.names())


def test_a_short_map_covering_a_third_keeps_the_right_pose_likely(street):
    """The map: only the part of the street in a 120-degree sector ahead of the scan (a few metres of road seen from
    its end): a third of the scan is covered, its right pose stays likely, a wrong one does not."""
    pts, cloud, world, T, dist = street
    local = world @ T[:3, :3]  # the map in the scan's frame
    sector = np.abs(np.arctan2(local[:, 1], local[:, 0])) < np.radians(60.0)
    tgt = cloud(world[sector])
    row = map_verdict.features(pts, T, tgt, dist)
    covered = row[map_verdict.names().index("covered")]
    assert 0.15 < covered < 0.6, covered  # the map covers a part of the scan only
    right = map_verdict.probability(row)
    off = map_verdict.probability(map_verdict.features(pts, _off(T, 2.0, 5.0), tgt, dist))
    assert right >= Config().localization.min_probability and off < 0.2, (right, off)


def test_model_file_errors_are_one_line(tmp_path):
    cols, coef, _ = map_verdict.load()
    assert len(cols) == len(coef) > 0
    bad = tmp_path / "m.json"
    for text in ("{", json.dumps({"features": ["nonexistent"], "transform": "logit(clip(x, 0.005, 0.995))",
                                  "coef": [1.0], "intercept": 0.0})):
        bad.write_text(text)
        with pytest.raises(VerdictModelError) as e:
            map_verdict.load(str(bad))
        assert "\n" not in str(e.value) and "calibrate_map_verdict" in str(e.value)
    with pytest.raises(VerdictModelError):
        map_verdict.load(str(tmp_path / "missing.json"))


def _cast(origin: np.ndarray, planes, az_deg: np.ndarray, el_deg: np.ndarray, max_range: float = 40.0) -> np.ndarray:
    """The points a sensor at ``origin`` sees of ``planes`` [(axis, value, lo, hi)]: the plane x[axis] = value,
    bounded to [lo, hi] along the other horizontal axis (walls: up to 3 m high), in the directions ``az_deg`` x
    ``el_deg`` (the nearest hit within ``max_range``)."""
    a, e = np.meshgrid(np.radians(az_deg), np.radians(el_deg), indexing="ij")
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    best = np.full(len(d), np.inf)
    for axis, value, lo, hi in planes:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (value - origin[axis]) / d[:, axis]
            hit = origin + t[:, None] * d
        other = 1 - axis if axis < 2 else 0
        ok = (t > 0.1) & (t < max_range) & (hit[:, other] >= lo) & (hit[:, other] <= hi)
        if axis < 2:
            ok &= hit[:, 2] <= 3.0
        best = np.where(ok & (t < best), t, best)
    ok = np.isfinite(best)
    return origin + best[ok, None] * d[ok]


def _wall_scene(corner: bool):
    """A floor 1.5 m under the sensor and a wall 4 m to its left along x (with ``corner``: a cross wall 6 m ahead):
    (the scan's spread GICP points, the map's GICP cloud (seen from seven origins along the wall), the verdict's
    distance). The scan looks at the wall (a narrow 140 x 76 degree field of view)."""
    from deepbbs_ros.core.polish import prepare_polish_cloud
    from deepbbs_ros.core.registration import good_start_points

    rc = Config().registration
    planes = [(2, -1.5, -50.0, 50.0), (1, 4.0, -50.0, 50.0)] + ([(0, 6.0, -50.0, 4.0)] if corner else [])
    world = np.concatenate([_cast(np.array([x, 0.0, 0.0]), planes, np.arange(-180.0, 180.0, 0.4),
                                  np.arange(-25.0, 15.0, 0.5)) for x in np.arange(-20.0, 5.0, 4.0)])
    az0 = -30.0 if corner else 20.0  # the corner: the scan sees the cross wall as much as the long one
    scan = _cast(np.zeros(3), planes, np.arange(az0, az0 + 140.0, 0.2), np.arange(-38.0, 38.0, 0.3))
    spc = prepare_polish_cloud(scan, rc.polish_voxel, rc.polish_neighbors, threads=1)
    tgt = prepare_polish_cloud(world, rc.polish_voxel, rc.polish_neighbors, threads=1)
    return good_start_points(spc, rc), tgt, rc.verdict_dist


def test_a_crop_that_is_a_view_of_the_map_cloud_is_judged_with_the_map_normals(street):
    """A map crop is a view of the map's GICP cloud (``localization.shared_cloud``): its features use the map's
    normals and tangent planes, as a crop with a cloud of its own does (``pinned`` is not the 1 of a cloud without
    normals, the plane shares are not ``fitness_close``)."""
    from deepbbs_ros.core.polish import PolishView, prepare_polish_cloud, prepared_cloud

    pts, _, world, T, dist = street
    rc = Config().registration
    offset = np.array([120.0, -40.0, 3.0])  # the map frame: the place 120 m from its origin
    base = prepare_polish_cloud(world + offset, rc.polish_voxel, rc.polish_neighbors, threads=1)
    T_map_place = np.eye(4)
    T_map_place[:3, 3] = offset
    view = PolishView.of(base, base.points() - offset, T_map_place)  # the crop: the whole (small) map
    own = prepared_cloud(view.points(), rc.polish_neighbors, threads=1)
    names = map_verdict.names()
    for D in (np.eye(4), _off(np.eye(4), 1.2, 0.0)):
        a = map_verdict.features(pts, T @ D, view, dist, map_normals=True)
        b = map_verdict.features(pts, T @ D, own, dist)
        assert a[names.index("pinned")] < 0.9, a
        for name in ("fitness", "plane_close", "plane_own", "pinned", "violations", "covered"):
            assert abs(a[names.index(name)] - b[names.index(name)]) < 0.05, (name, a, b)


@pytest.mark.xfail(strict=True, reason="known gap: the shipped fit accepts it; a fit with poses slid "
                   "along their weakest direction rejects it but also right poses on straight highways")
def test_a_scan_slid_along_a_wall_with_a_cross_wall_in_view_is_not_likely():
    """A scan that sees a floor, a wall along it and a cross wall: its right pose is likely; slid 1.2 m along the
    wall (its points on the cross wall come into the space the map saw through), it is not."""
    slid = np.eye(4)
    slid[0, 3] = -1.2  # along the wall, away from the cross wall
    pts, tgt, dist = _wall_scene(corner=True)
    right = map_verdict.probability(map_verdict.features(pts, np.eye(4), tgt, dist))
    off = map_verdict.probability(map_verdict.features(pts, slid, tgt, dist))
    assert right >= Config().localization.min_probability and off < 0.2, (right, off)


@pytest.mark.xfail(strict=True, reason="known gap: on noiseless planes every other feature is perfect and the "
                   "shipped fit does not weigh pinned (the slid pose scores about 1.0)")
def test_a_scan_slid_along_a_single_wall_is_not_likely():
    """A scan that sees a floor and one wall fits as tightly 1.2 m along the wall as where it was taken (every point
    on the map's planes): nothing in it says where along the wall it is, and ``pinned`` (core/visibility.py) says so
    (under 0.05); the map verdict should not accept it there."""
    names = map_verdict.names()
    slid = np.eye(4)
    slid[0, 3] = -1.2  # along the wall
    pts, tgt, dist = _wall_scene(corner=False)
    row = map_verdict.features(pts, slid, tgt, dist)
    assert row[names.index("fitness")] > 0.95 and row[names.index("pinned")] < 0.05, row
    assert map_verdict.probability(row) < 0.2, map_verdict.probability(row)


def test_the_acceptance_turns_away_a_pose_slid_along_a_corridor_and_keeps_the_true_one():
    """A corridor 4 m wide closed by a wall 6 m ahead, the map a view of its GICP cloud 120 m from the map's origin
    (a map crop, core/polish_view.py), a 70-degree scan looking down it: slid 0.6 or 1.2 m along the corridor, the scan
    still lies on the map's walls and floor (the map verdict accepts it), but the fit leaves the pose free along the
    corridor and GICP from it, moved along that direction both ways, settles on the true pose with a better fit: the
    acceptance (core/acceptance.py) turns it away. The true pose: both starts come back, it is kept."""
    from types import SimpleNamespace

    from deepbbs_ros.core import acceptance
    from deepbbs_ros.core.polish import PolishView, prepare_polish_cloud

    cfg = Config()
    rc = cfg.registration
    planes = [(2, -1.5, -50.0, 50.0), (1, 2.0, -50.0, 6.0), (1, -2.0, -50.0, 6.0), (0, 6.0, -2.0, 2.0)]
    world = np.concatenate([_cast(np.array([x, 0.0, 0.0]), planes, np.arange(-180.0, 180.0, 0.4),
                                  np.arange(-25.0, 15.0, 0.5)) for x in np.arange(-20.0, 5.0, 4.0)])
    scan = _cast(np.zeros(3), planes, np.arange(-35.0, 35.0, 0.2), np.arange(-38.0, 38.0, 0.3))
    offset = np.array([120.0, -40.0, 3.0])
    base = prepare_polish_cloud(world + offset, rc.polish_voxel, rc.polish_neighbors, threads=1)
    T_map_place = np.eye(4)
    T_map_place[:3, 3] = offset
    crop = SimpleNamespace(T_map_place=T_map_place, pre=SimpleNamespace(
        polish_cloud=PolishView.of(base, base.points() - offset, T_map_place)))
    src = SimpleNamespace(polish_cloud=prepare_polish_cloud(scan, rc.polish_voxel, rc.polish_neighbors, threads=1))
    for dx in (0.0, -0.6, -1.2, 1.2):
        T = T_map_place.copy()
        T[0, 3] += dx
        assert acceptance.accepts(cfg, acceptance.probability(src, crop, T, cfg)), dx  # the map verdict alone
        a = acceptance.second_minimum(src, crop, T, cfg)
        assert a.step > 0, a  # checked: free along the corridor
        if dx == 0.0:
            assert not a.ambiguous and acceptance.accepts_pose(src, crop, T, cfg), a
        else:
            assert a.ambiguous and a.other_score > a.score, (dx, a)
            assert np.linalg.norm(a.other[:3, 3]) < 0.1, (dx, a.other)  # the other minimum: the true pose
            assert not acceptance.accepts_pose(src, crop, T, cfg)
            off = cfg.replace(**{"localization.second_minimum": False})
            assert acceptance.accepts_pose(src, crop, T, off)  # the map verdict alone accepts it
