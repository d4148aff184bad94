"""The good start's fixed cost above GICP made smaller with the same numbers: the verdict's own quantile, the reuse of
its direction table and of its nearest-neighbour search, the sensor guess's column-wise finite test. Each is checked
against the code it replaced (kept here as the reference) on clouds of every kind, to the last bit."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core import good_start, good_start_answer, sensors, verdict, visibility
from deepbbs_ros.core.scans import prepare_scan


def _scan(seed: int, n: int = 6000, narrow: bool = False) -> np.ndarray:
    """A small room-and-street scene seen from the origin (walls, floor, boxes); ``narrow``: a 70-degree cone."""
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(-25, 25, (n // 2, 2)), np.full(n // 2, -1.2)]
    walls = np.c_[rng.uniform(-25, 25, n // 4), np.where(rng.random(n // 4) < 0.5, -6.0, 6.0),
                  rng.uniform(-1.2, 3.0, n // 4)]
    boxes = rng.normal(0, 0.8, (n - len(floor) - len(walls), 3)) + rng.choice([-12.0, 4.0, 15.0], (
        n - len(floor) - len(walls), 1)) * np.array([1.0, 0.0, 0.0])
    pts = np.vstack([floor, walls, boxes]).astype(np.float32)
    if narrow:
        pts = pts[np.abs(np.arctan2(pts[:, 1], pts[:, 0])) < np.radians(35)]
    return pts


def _old_coverage(points: np.ndarray) -> float:
    """The sensor guess's azimuth coverage as it was (a row-wise finite test)."""
    pts = np.asarray(points)[:: max(1, len(points) // sensors._MAX_SHAPE_POINTS)]
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        return 0.0
    az = np.arctan2(pts[:, 1], pts[:, 0])
    hist = np.bincount(((az + np.pi) / (2 * np.pi) * sensors._AZ_BINS).astype(int) % sensors._AZ_BINS,
                       minlength=sensors._AZ_BINS)
    return float(np.count_nonzero(hist >= 0.002 * len(pts))) / sensors._AZ_BINS


def test_quantile_is_numpys_to_the_last_bit():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 9, 10, 11, 101, 256, 257, 1000):
        for x in (rng.uniform(0, 0.3, n), rng.exponential(0.05, n), np.round(rng.uniform(0, 1, n), 1)):
            for q in (0.0, 0.1, 0.5, 0.9, 0.95, 1.0):
                assert visibility._quantile(x, q) == float(np.quantile(x, q)), (n, q)
    assert np.isnan(visibility._quantile(np.array([0.1, np.nan, 0.2]), 0.9))


@pytest.mark.parametrize("kind", ["spinning", "narrow", "missing", "float64", "tiny"])
def test_azimuth_coverage_is_the_row_wise_ones(kind):
    pts = _scan(1, 30000, narrow=kind == "narrow")
    if kind == "missing":
        pts = pts.copy()
        pts[::7, 2] = np.nan
        pts[::11, 0] = np.inf
    if kind == "float64":
        pts = pts.astype(np.float64)
    if kind == "tiny":
        pts = pts[:5]
    assert sensors.azimuth_coverage(pts) == _old_coverage(pts)
    assert sensors.azimuth_coverage(np.full((10, 3), np.nan)) == 0.0


def _sphere_table(az: np.ndarray, el: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The direction cells of a ``cell`` rad grid over the whole sphere as a flat table (what visibility._occupied
    computed before it kept to the span of the target's directions): (the table, each direction's index, rows)."""
    rows = int(np.pi / cell) + 2
    idx = np.floor((az + np.pi) / cell).astype(np.int64) * rows + np.floor((el + np.pi / 2) / cell).astype(np.int64)
    table = np.zeros((int(2 * np.pi / cell) + 2) * rows, bool)
    table[idx] = True
    return table, idx, rows


@pytest.mark.parametrize("n", [150, 3000, 4001, 7999, 8000, 12001, 40000])
def test_direction_tables_of_every_subsample_are_the_old_ones(n):
    """cell_size / directions on either side of the subsample steps (1, 2, 3 and more) as computed before: every cell
    tried on the subsample, then the chosen cell's table on every direction."""
    rng = np.random.default_rng(n)
    az, el = rng.uniform(-np.pi, np.pi, n), rng.uniform(-0.5, 0.5, n)
    r = rng.uniform(0.5, 60.0, n)
    target = np.c_[r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)]
    taz, tel, tr = visibility._angles(target)
    step = max(1, -(-n // visibility._SHAPE_POINTS))
    cell = float(visibility._CELLS[-1])
    for c in visibility._CELLS:
        if len(taz[::step]) * step / np.count_nonzero(_sphere_table(taz[::step], tel[::step], c)[0]) >= \
                visibility._PER_CELL:
            cell = float(c)
            break
    assert visibility.cell_size(taz, tel) == cell
    table, idx, rows = _sphere_table(taz, tel, cell)
    nearest = np.full(len(table), np.inf)
    np.minimum.at(nearest, idx, tr)
    occupied = np.flatnonzero(table)
    got = visibility.directions(target)
    assert got[0] == cell
    np.testing.assert_array_equal(got[1], (occupied // rows) * 100_000 + occupied % rows)
    np.testing.assert_array_equal(got[2], nearest[occupied])


def test_good_start_score_and_features_from_one_search_are_the_two_searches_ones():
    """The verdict's nearest-neighbour answer kept on the target cloud: the good start's score and inlier share of the
    same pose, and the features judged again, are those of searches of their own."""
    cfg = Config().replace(**{"registration.exact_gicp": True})
    rc = cfg.registration
    src, tgt = prepare_scan(cfg, _scan(5)).polish_cloud, prepare_scan(cfg, _scan(6)).polish_cloud
    pts = good_start.good_start_points(src, rc)
    for T in (np.eye(4), np.array([[0.99, -0.141, 0, 0.3], [0.141, 0.99, 0, -0.2], [0, 0, 1, 0.05], [0, 0, 0, 1]])):
        fresh = prepare_scan(cfg, _scan(6)).polish_cloud  # no kept answer
        first = visibility.pose_features(pts, T, tgt, rc.verdict_dist)
        np.testing.assert_array_equal(first, visibility.pose_features(pts, T, fresh, rc.verdict_dist))
        np.testing.assert_array_equal(first, visibility.pose_features(pts, T, tgt, rc.verdict_dist))  # kept answer
        moved = pts @ T[:3, :3].T + T[:3, 3]
        _, sq = fresh.tree.batch_nearest_neighbor_search(moved, num_threads=1)
        want = [float(np.mean(np.asarray(sq) <= d * d)) for d in (rc.verdict_dist, rc.inlier_dist)]
        assert good_start_answer.shares(pts, tgt, T, (rc.verdict_dist, rc.inlier_dist)) == want
        assert want[0] == verdict.fitness(pts, fresh.tree, T, rc.verdict_dist)
    other = pts[::2]  # other points on the same cloud: searched again, not the kept answer
    _, sq = tgt.tree.batch_nearest_neighbor_search(other, num_threads=1)
    assert good_start_answer.shares(other, tgt, np.eye(4), (rc.verdict_dist,)) == [
        float(np.mean(np.asarray(sq) <= rc.verdict_dist ** 2))]
