"""A tilted sensor in a map without its trajectory (core/place_search.py, core/descriptors.py ``levelling``): a
simulated suburban street mapped by one drive (five noiseless HDL-64E scans at their true poses, no trajectory given:
places over the drivable space), and a scan from the same stretch rolled 14 degrees about the sensor (a car on a
kerb), its low side seeing the road within 7 m only. The descriptor assumes an upright sensor: when the upright
search accepts no place, the scan is described levelled by its own ground plane, compared on the bins it saw and
started with its roll. Shipped weights, default configuration (network in this process)."""

from __future__ import annotations

import numpy as np
import pytest
from sim_maps import world_points

from deepbbs_ros.config import Config
from deepbbs_ros.metrics import pair_errors

MAP_FRAMES = (4, 10, 16, 22, 28)
ROLL_DEG = 14.0
LOW_SIDE_M = 7.0


def _roll(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    T = np.eye(4)
    T[1:3, 1:3] = [[c, -s], [s, c]]
    return T


@pytest.fixture(scope="module")
def street():
    from deepbbs_ros.core.checkpoint import default_weights_path
    from deepbbs_ros.core.localization import voxel_downsample
    from deepbbs_ros.sim.simulator import DriveSimulator

    if not default_weights_path().is_file():
        pytest.skip("shipped weights missing")
    sim = DriveSimulator("suburban", 12, frames=30, motion_distortion=False)
    return voxel_downsample(world_points(sim, MAP_FRAMES, 50.0), 0.25), sim


def test_levelling_turns_the_fitted_ground_level():
    from deepbbs_ros.core.descriptors import levelling

    n = _roll(ROLL_DEG)[:3, :3] @ np.array([0.0, 0.0, 1.0])  # the ground's normal seen by the rolled sensor
    R = levelling(np.r_[n, 1.7], 0.25, 20.0)
    np.testing.assert_allclose(R @ n, [0.0, 0.0, 1.0], atol=1e-12)
    assert levelling(np.r_[_roll(0.3)[:3, :3] @ [0.0, 0.0, 1.0], 1.7], 0.25, 20.0) is None  # within the fit's band
    assert levelling(None, 0.25, 20.0) is None


def test_observed_bins_only_leave_out_what_the_scan_did_not_see():
    from deepbbs_ros.core.descriptors import _match, _match_observed

    rng = np.random.default_rng(3)
    right = rng.uniform(0.5, 3.0, (18, 60)).astype(np.float32)  # the place the scan was taken at
    seen = np.ones((18, 60), bool)
    seen[6:, 3:27] = False  # a tilted sensor's low side: its inner rings only
    scan = np.roll(np.where(seen, right, 0.0), -7, axis=1).astype(np.float32)  # yawed by 7 columns
    seen = np.roll(seen, -7, axis=1)
    bare = np.where(np.roll(seen, 7, axis=1), right + rng.normal(0, 0.3, right.shape), 0.0)  # nothing far: a look-alike
    places = np.stack([right, bare.astype(np.float32)])
    d, _ = _match(places, scan)
    assert d[1] < d[0]  # every bin compared: the bare place looks more alike
    d, shift = _match_observed(places, scan, seen)
    assert d[0] < 1e-6 < d[1] and shift[0] == 7  # the bins seen only: the right place, at its yaw


def test_observed_match_is_the_per_shift_definition():
    """Every shift at once (matrix products, in chunks of places) gives the per-shift definition: the mean, over
    the columns either side has, of the cosine of the place's column s + k and the query's column s on the bins the
    query saw (0 where one of the two is empty)."""
    from deepbbs_ros.core.descriptors import _match_observed

    rng = np.random.default_rng(5)
    places = rng.uniform(0.0, 3.0, (37, 18, 60)).astype(np.float32)
    places[rng.random(places.shape) < 0.5] = 0.0
    places[3, :, :20] = 0.0  # empty columns
    query = rng.uniform(0.0, 3.0, (18, 60)).astype(np.float32)
    query[rng.random(query.shape) < 0.3] = 0.0
    seen = rng.random((18, 60)) < 0.7
    seen[:, 40:] = False  # columns the query did not see
    q = np.where(seen, query, 0.0)
    want = np.empty((len(places), 60))
    for k in range(60):
        p = np.roll(places, -k, axis=2) * seen[None]
        pn, qn = np.linalg.norm(p, axis=1), np.linalg.norm(q, axis=0)[None]
        both = (pn > 1e-6) & (qn > 1e-6)
        cos = np.where(both, np.einsum("prs,rs->ps", p, q) / np.where(both, pn * qn, 1.0), 0.0)
        want[:, k] = cos.sum(axis=1) / np.maximum(((pn > 1e-6) | (qn > 1e-6)).sum(axis=1), 1)
    d, shift = _match_observed(places, query, seen, chunk=8)
    np.testing.assert_allclose(d, 1.0 - want.max(axis=1), atol=1e-5)
    np.testing.assert_allclose(want[np.arange(len(places)), shift], want.max(axis=1), atol=1e-5)


def test_a_tilted_scan_is_placed_levelled(street):
    from deepbbs_ros.core.localization import MapLocalizer

    map_points, sim = street
    k = 13  # between mapped scans
    tilt = _roll(ROLL_DEG)
    p = sim.scan_at(k).points
    # the rolled sensor's low side (-y, 144 degrees of it) sees the road within LOW_SIDE_M only (its beams hit it)
    low = (np.abs(np.arctan2(p[:, 0], -p[:, 1])) < np.radians(72.0)) & (np.hypot(p[:, 0], p[:, 1]) > LOW_SIDE_M)
    pts = p[~low] @ tilt[:3, :3].T  # the sensor rolled: a point p of the upright frame is at R p
    T_gt = sim.pose_at(k) @ np.linalg.inv(tilt)
    loc = MapLocalizer(map_points, Config().replace(**{"registration.network_process": "off"}))
    try:
        src = loc.prepare(pts).pre
        level = loc._levelling(src)
        assert level is not None
        scan = pts @ level[:3, :3].T
        centres = loc.description_centres
        ranked = loc.rank(loc.describe(scan, centres), None, centres, seen=loc.seen(scan))
        assert np.linalg.norm(loc._places[ranked[0][0]][:2, 3] - T_gt[:2, 3]) < 5.0
        answers, failed = [], []
        loc._round(src, ranked, level, answers, failed, {})  # the levelled round (the search's second)
        res = loc.localize(pts)  # and the whole search
    finally:
        loc.registration.close()
    best = max((a for a in answers if a.ok), key=lambda a: a.score)
    rot, trans = pair_errors(best.T, T_gt)
    assert rot < 1.0 and trans < 0.3, (rot, trans)
    rot, trans = pair_errors(res.T_map_scan, T_gt)
    assert res.valid and rot < 1.0 and trans < 0.3, (rot, trans, res.reason)
