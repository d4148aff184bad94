"""Scan preprocessing: range crop, ground plane, voxel grid, FPS, the whole pipeline and its errors.

Scans come from a small analytic ray caster (:func:`make_scan`): a spinning multi-beam LiDAR over a
sloped ground plane with box buildings and cylindrical poles, every return labelled with the surface
it hit, so ground removal is checked against ground truth.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.core.preprocess import (
    PreprocessResult,
    canonical_order,
    crop_range,
    farthest_point_sample,
    fit_ground_plane,
    preprocess,
    remove_ground,
    voxel_downsample,
)
from deepbbs_ros.errors import RegistrationError

NONE, GROUND, BUILDING, POLE = 0, 1, 2, 3


def ground_plane_from_slope(pitch_deg: float, roll_deg: float, height: float) -> np.ndarray:
    """(4,) plane ``[a, b, c, d]`` (unit normal, c > 0) ``height`` m below the sensor, tilted."""
    p, r = np.deg2rad(pitch_deg), np.deg2rad(roll_deg)
    normal = np.array([-np.sin(p), np.sin(r) * np.cos(p), np.cos(r) * np.cos(p)])
    normal /= np.linalg.norm(normal)
    return np.concatenate([normal, [normal @ np.array([0.0, 0.0, height])]])


DEFAULT_BUILDINGS = (
    # (x_min, y_min, x_max, y_max, top z) in the sensor frame, metres: a street canyon along x,
    # with one large building close to the sensor.
    (-60.0, 9.0, -15.0, 30.0, 12.0),
    (-10.0, 6.0, 25.0, 25.0, 15.0),
    (30.0, 9.0, 70.0, 30.0, 10.0),
    (-70.0, -30.0, -5.0, -10.0, 20.0),
    (5.0, -28.0, 60.0, -9.0, 9.0),
)
DEFAULT_POLES = ((8.0, -5.0), (-12.0, 4.5), (20.0, 4.0), (35.0, -6.0), (-30.0, -6.0), (50.0, 5.0))


def make_scan(
    *,
    beams: int = 64,
    azimuths: int = 1875,
    vfov_deg: tuple[float, float] = (-24.8, 2.0),
    sensor_height: float = 1.9,
    pitch_deg: float = 3.0,
    roll_deg: float = 1.0,
    buildings=DEFAULT_BUILDINGS,
    poles=DEFAULT_POLES,
    pole_radius: float = 0.2,
    pole_top: float = 4.0,
    max_range: float = 120.0,
    noise: float = 0.02,
    dropout: float = 0.02,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ray-cast one sweep (sensor frame at the origin, z up).

    Returns:
        points: (beams * azimuths, 3) float32; rays without a return (sky, dropout) are NaN.
        labels: (beams * azimuths,) int8: NONE, GROUND, BUILDING or POLE.
        plane: (4,) float64 true ground plane ``[a, b, c, d]``.
    """
    rng = np.random.default_rng(seed)
    plane = ground_plane_from_slope(pitch_deg, roll_deg, sensor_height)
    elev = np.deg2rad(np.linspace(vfov_deg[0], vfov_deg[1], beams))
    azim = np.linspace(0.0, 2 * np.pi, azimuths, endpoint=False)
    el, az = np.meshgrid(elev, azim, indexing="ij")
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)
    n_rays = len(u)
    best_t = np.full(n_rays, np.inf)
    labels = np.zeros(n_rays, dtype=np.int8)

    def _take(t: np.ndarray, label: int) -> None:
        hit = (t > 0) & (t < best_t)
        best_t[hit] = t[hit]
        labels[hit] = label

    with np.errstate(divide="ignore", invalid="ignore"):
        # ground: n . (t u) + d = 0 (the sensor is above it: d > 0)
        nu = u @ plane[:3]
        _take(np.where(nu < 0, -plane[3] / nu, np.inf), GROUND)
        # buildings: slab test on axis-aligned boxes reaching below the ground
        inv = 1.0 / u
        for x0, y0, x1, y1, top in buildings:
            lo, hi = np.array([x0, y0, -50.0]), np.array([x1, y1, top])
            t1, t2 = lo * inv, hi * inv
            t_near = np.nanmax(np.minimum(t1, t2), axis=1)
            t_far = np.nanmin(np.maximum(t1, t2), axis=1)
            _take(np.where((t_far >= t_near) & (t_near > 0), t_near, np.inf), BUILDING)
        # poles: vertical cylinders |xy(t) - c| = r, below pole_top
        uxy2 = np.einsum("ij,ij->i", u[:, :2], u[:, :2])
        for cx, cy in poles:
            b = -(u[:, 0] * cx + u[:, 1] * cy)
            disc = b * b - uxy2 * (cx * cx + cy * cy - pole_radius**2)
            t = (-b - np.sqrt(disc)) / uxy2
            ok = (disc >= 0) & (t * u[:, 2] <= pole_top)
            _take(np.where(ok, t, np.inf), POLE)
    best_t += rng.normal(0.0, noise, n_rays)
    miss = ~np.isfinite(best_t) | (best_t > max_range) | (rng.random(n_rays) < dropout)
    labels[miss] = NONE
    best_t[miss] = 0.0
    points = (u * best_t[:, None]).astype(np.float32)
    points[miss] = np.nan
    return points, labels, plane


def height_above(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    return points.astype(np.float64) @ plane[:3] + plane[3]


def plane_errors(est: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """(normal angle in degrees, height difference of the planes below the sensor in metres)."""
    angle = np.degrees(np.arccos(np.clip(est[:3] @ true[:3], -1.0, 1.0)))
    # Height of each plane along z at the sensor's xy: z = -d / c.
    return float(angle), float(abs(est[3] / est[2] - true[3] / true[2]))


@pytest.fixture(scope="module")
def small_scan():
    """A 32 x 720 sweep on a 6 deg / 2 deg slope with buildings and poles (about 23k rays)."""
    return make_scan(beams=32, azimuths=720, pitch_deg=6.0, roll_deg=-2.0, seed=1)


# -- range crop and invalid points ----------------------------------------------------------------
def test_crop_range_keeps_band_and_drops_non_finite():
    pts = np.array(
        [[1.0, 0, 0], [3.0, 0, 0], [0, 4.0, 3.0], [50.0, 0, 0], [np.nan, 0, 0], [np.inf, 0, 0], [0, -np.inf, 1]],
        dtype=np.float32,
    )
    mask = crop_range(pts, 2.0, 10.0)
    assert mask.dtype == bool
    np.testing.assert_array_equal(mask, [False, True, True, False, False, False, False])


def test_preprocess_drops_nan_and_out_of_range(small_scan):
    points, labels, _ = small_scan
    cfg = PreprocessConfig(min_range=3.0, max_range=40.0, num_points=256)
    res = preprocess(points, cfg, seed=0)
    r = np.linalg.norm(points, axis=1)
    assert res.n_input == len(points)
    assert res.n_valid == int(np.sum(np.isfinite(r) & (r >= 3.0) & (r <= 40.0)))
    assert res.points.shape == (256, 3) and res.points.dtype == np.float32
    assert np.isfinite(res.points).all()
    rr = np.linalg.norm(res.points, axis=1)
    # Voxel centroids may sit a fraction of a voxel beyond the crop band.
    assert rr.min() >= 3.0 - cfg.voxel_size and rr.max() <= 40.0 + cfg.voxel_size


# -- ground plane -----------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["ransac", "seeded_lsq"])
def test_ground_plane_recovered_on_slope_with_buildings(small_scan, method):
    points, labels, true_plane = small_scan
    pts = points[np.isfinite(points).all(axis=1)]
    cfg = PreprocessConfig(ground_method=method)
    plane = fit_ground_plane(pts, cfg, seed=0)
    assert plane.shape == (4,) and plane.dtype == np.float64
    assert np.isclose(np.linalg.norm(plane[:3]), 1.0) and plane[2] > 0
    angle, offset = plane_errors(plane, true_plane)
    assert angle < 0.3, f"{method}: normal off by {angle:.3f} deg"
    assert offset < 0.05, f"{method}: plane height off by {offset:.3f} m"

    # The scene is adversarial: a plain least-squares plane over the near points is pulled away.
    near = pts[np.linalg.norm(pts[:, :2], axis=1) <= cfg.ground_seed_radius].astype(np.float64)
    c = near.mean(axis=0)
    normal = np.linalg.eigh((near - c).T @ (near - c))[1][:, 0]
    normal *= np.sign(normal[2])
    naive_angle, naive_offset = plane_errors(np.concatenate([normal, [-normal @ c]]), true_plane)
    assert naive_angle > 1.5 and naive_offset > 0.3


@pytest.mark.parametrize("method", ["ransac", "seeded_lsq"])
def test_remove_ground_removes_ground_keeps_walls_and_poles(small_scan, method):
    points, labels, true_plane = small_scan
    ok = np.isfinite(points).all(axis=1)
    pts, lab = points[ok], labels[ok]
    cfg = PreprocessConfig(ground_method=method, ground_layer=0.5)
    keep, plane = remove_ground(pts, cfg, seed=0)
    assert keep.shape == (len(pts),) and keep.dtype == bool
    h = height_above(pts, true_plane)
    ground = lab == GROUND
    assert np.mean(~keep[ground]) > 0.995, "ground points left"
    above = (lab == BUILDING) | (lab == POLE)
    clearly_above = above & (h > cfg.ground_layer / 2 + 0.1)
    assert clearly_above.sum() > 1000
    assert np.mean(keep[clearly_above]) > 0.995, "wall/pole points removed"
    assert keep[(lab == POLE) & (h > 0.5)].all()


def test_ground_layer_thickness_is_a_parameter(small_scan):
    points, labels, true_plane = small_scan
    pts = points[np.isfinite(points).all(axis=1)]
    thin, _ = remove_ground(pts, PreprocessConfig(ground_layer=0.5), seed=0)
    thick, _ = remove_ground(pts, PreprocessConfig(ground_layer=3.0), seed=0)
    h = height_above(pts, true_plane)
    assert thick.sum() < thin.sum()
    assert not thick[np.abs(h) < 1.4].any()
    assert thin[(h > 0.4) & (h < 1.4)].all()


def test_ground_fit_is_deterministic_for_a_seed(small_scan):
    pts = small_scan[0][np.isfinite(small_scan[0]).all(axis=1)]
    a = fit_ground_plane(pts, PreprocessConfig(), seed=5)
    b = fit_ground_plane(pts, PreprocessConfig(), seed=5)
    np.testing.assert_array_equal(a, b)


def test_ground_fit_needs_points_near_the_sensor_and_a_horizontal_plane(rng):
    far = rng.uniform(50, 60, size=(100, 3)).astype(np.float32)
    with pytest.raises(RegistrationError, match="ground_seed_radius"):
        fit_ground_plane(far, PreprocessConfig())
    # a cloud of vertical walls only: no near-horizontal plane
    walls = np.concatenate(
        [np.column_stack([np.full(500, x), rng.uniform(-10, 10, 500), rng.uniform(-2, 10, 500)]) for x in (-6.0, 7.0)]
    ).astype(np.float32)
    with pytest.raises(RegistrationError, match="near-horizontal plane"):
        fit_ground_plane(walls, PreprocessConfig())
    # preprocess then keeps every point and reports no plane
    res = preprocess(walls, PreprocessConfig(num_points=200, voxel_size=0.0), seed=0)
    assert res.ground_plane is None and res.n_nonground == res.n_valid == len(walls)


# -- voxel grid ----------------------------------------------------------------------------------
def test_voxel_downsample_one_centroid_per_occupied_voxel(rng):
    v = 0.5
    cells = np.array([[0, 0, 0], [1, 0, 0], [0, 3, -2], [-4, 7, 1]])
    # 1..20 points per cell, strictly inside it
    pts = np.concatenate([(c + rng.uniform(0.01, 0.99, size=(1 + 5 * i, 3))) * v for i, c in enumerate(cells)])
    rng.shuffle(pts)
    out = voxel_downsample(pts, v)
    assert out.shape == (len(cells), 3) and out.dtype == np.float32
    out_cells = np.floor(out / v).astype(int)
    assert sorted(map(tuple, out_cells)) == sorted(map(tuple, cells))
    for c in cells:
        members = pts[(np.floor(pts / v).astype(int) == c).all(axis=1)]
        got = out[(out_cells == c).all(axis=1)][0]
        np.testing.assert_allclose(got, members.mean(axis=0), atol=1e-5)
    # voxel_size 0 is a pass-through
    np.testing.assert_array_equal(voxel_downsample(pts, 0.0), pts.astype(np.float32))


def test_voxel_downsample_counts_occupied_voxels_of_a_scan(small_scan):
    pts = small_scan[0][np.isfinite(small_scan[0]).all(axis=1)]
    out = voxel_downsample(pts, 0.3)
    occupied = np.unique(np.floor(pts / np.float32(0.3)).astype(np.int64), axis=0)
    assert len(out) == len(occupied)
    assert len(np.unique(np.floor(out / np.float32(0.3)).astype(np.int64), axis=0)) == len(out)


# -- farthest-point sampling -----------------------------------------------------------------------
def _min_pairwise(q: np.ndarray) -> float:
    d = np.linalg.norm(q[:, None] - q[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(d.min())


def test_fps_is_deterministic_and_covers_better_than_random(rng):
    pts = rng.uniform(-20, 20, size=(5000, 3)).astype(np.float32)
    a = farthest_point_sample(pts, 300, seed=3)
    b = farthest_point_sample(pts, 300, seed=3)
    c = farthest_point_sample(pts, 300, seed=4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.shape == (300,) and len(np.unique(a)) == 300
    assert a.min() >= 0 and a.max() < len(pts)
    # Max-min distance property: FPS spreads the samples far better than a random subset,
    # and every input point has a sample nearby.
    rand = rng.choice(len(pts), 300, replace=False)
    assert _min_pairwise(pts[a]) > 3.0 * _min_pairwise(pts[rand])

    def cover(idx):
        return np.linalg.norm(pts[:, None] - pts[idx][None], axis=-1).min(axis=1).max()

    assert cover(a) < 0.75 * cover(rand)


def test_fps_with_fewer_points_repeats_cyclically(rng):
    pts = rng.normal(size=(40, 3)).astype(np.float32)
    idx = farthest_point_sample(pts, 100, seed=0)
    assert idx.shape == (100,)
    np.testing.assert_array_equal(np.sort(idx[:40]), np.arange(40))
    np.testing.assert_array_equal(idx[40:80], idx[:40])
    counts = np.bincount(idx, minlength=40)
    assert counts.min() == 2 and counts.max() == 3
    tiny = farthest_point_sample(pts[:5], 7, seed=1)  # below fpsample's bucket size
    np.testing.assert_array_equal(np.sort(tiny[:5]), np.arange(5))


# -- the pipeline ------------------------------------------------------------------------------------
def test_preprocess_pipeline_on_a_scan(small_scan):
    points, labels, true_plane = small_scan
    cfg = PreprocessConfig(num_points=500)
    res = preprocess(points, cfg, seed=0)
    assert isinstance(res, PreprocessResult)
    assert res.points.shape == (500, 3) and res.points.dtype == np.float32
    assert res.n_input > res.n_valid > res.n_nonground >= res.n_voxels >= 500
    angle, offset = plane_errors(res.ground_plane, true_plane)
    assert angle < 0.3 and offset < 0.05
    # no sampled point lies in the ground layer
    assert np.abs(height_above(res.points, res.ground_plane)).min() > cfg.ground_layer / 2 - 1e-3
    assert set(res.timings_ms) == {"valid_crop", "ground", "voxel", "fps", "total"}
    assert all(v >= 0 for v in res.timings_ms.values())
    again = preprocess(points, cfg, seed=0)
    np.testing.assert_array_equal(res.points, again.points)
    other = preprocess(points, cfg, seed=1)
    assert not np.array_equal(res.points, other.points)


def test_preprocess_without_ground_removal_and_voxels(small_scan):
    points = small_scan[0]
    cfg = PreprocessConfig(remove_ground=False, voxel_size=0.0, num_points=128)
    res = preprocess(points, cfg, seed=0)
    assert res.ground_plane is None and res.n_nonground == res.n_valid
    assert res.points.shape == (128, 3)


def test_preprocess_too_few_points_pads_deterministically(rng):
    # 50 points on a pole-like column, well off any ground: fewer than num_points.
    pts = np.column_stack([np.full(50, 5.0), np.zeros(50), np.linspace(0.0, 3.0, 50)]).astype(np.float32)
    cfg = PreprocessConfig(remove_ground=False, voxel_size=0.0, num_points=120)
    res = preprocess(pts, cfg, seed=0)
    assert res.points.shape == (120, 3)
    assert len(np.unique(res.points, axis=0)) == 50
    np.testing.assert_array_equal(res.points, preprocess(pts, cfg, seed=0).points)


def test_preprocess_falls_back_to_raw_points_when_voxels_are_too_few(rng):
    pts = rng.uniform(-0.5, 0.5, size=(600, 3)).astype(np.float32) + np.float32([10.0, 0.0, 0.0])
    cfg = PreprocessConfig(remove_ground=False, voxel_size=1.0, num_points=300)
    res = preprocess(pts, cfg, seed=0)
    assert len(np.unique(res.points, axis=0)) == 300


@pytest.mark.parametrize(
    ("points", "match"),
    [
        (np.zeros((0, 3), dtype=np.float32), "empty point cloud"),
        (np.full((100, 3), np.nan, dtype=np.float32), r"only 0 of 100 points are finite"),
        (np.array([[5.0, 0, 0], [0, 5.0, 0], [np.nan, 1, 1]], dtype=np.float32), r"only 2 of 3 points"),
        (np.array([[0.5, 0, 0]] * 10 + [[200.0, 0, 0]] * 10, dtype=np.float32), r"only 0 of 20 points"),
        (np.ones((10, 2), dtype=np.float32), r"expected an \(N, 3\) point array"),
    ],
)
def test_preprocess_errors(points, match):
    with pytest.raises(RegistrationError, match=match):
        preprocess(points, PreprocessConfig())


def test_preprocess_error_when_everything_is_ground():
    g = np.random.default_rng(0).uniform(-15, 15, size=(2000, 2))
    pts = np.column_stack([g, np.full(len(g), -1.9)]).astype(np.float32)
    with pytest.raises(RegistrationError, match="off the ground layer"):
        preprocess(pts, PreprocessConfig())
    # without ground removal the same cloud is fine
    cfg = replace(PreprocessConfig(), remove_ground=False)
    assert preprocess(pts, cfg).points.shape == (cfg.num_points, 3)


def test_canonical_order_is_the_same_for_any_order_of_a_set():
    """small_gicp's threaded voxel grid returns its centroids in a run-dependent order: sorted, any order of
    one set gives one array (x first; equal x fall back to a full lexsort on x, y, z)."""
    rng = np.random.default_rng(3)
    pts = rng.uniform(-40, 40, (2000, 3))
    ref = canonical_order(pts)
    assert np.all(np.diff(ref[:, 0]) >= 0)
    for _ in range(3):
        np.testing.assert_array_equal(canonical_order(rng.permutation(pts)), ref)
    ties = np.round(pts, 0)  # many equal x
    ref = canonical_order(ties)
    np.testing.assert_array_equal(canonical_order(rng.permutation(ties)), ref)
    np.testing.assert_array_equal(ref, ties[np.lexsort((ties[:, 2], ties[:, 1], ties[:, 0]))])
