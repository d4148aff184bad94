"""Preprocessing defaults per sensor, the driver and shape that pick them, the self-filter box and the sparse-cloud
voxel rule; and the default preparation of a simulated HDL-64E scan unchanged bit for bit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from deepbbs_ros.config import Config, PreprocessConfig
from deepbbs_ros.config.preprocess import SENSORS
from deepbbs_ros.core.preprocess import crop_mask, preprocess, voxel_downsample
from deepbbs_ros.core.scans import prepare_scan
from deepbbs_ros.core.sensors import azimuth_coverage, guess_sensor, resolve
from deepbbs_ros.errors import ConfigError
from msg_adapters.layouts import FLOAT64_XYZ, HESAI, LIVOX, OUSTER, VELODYNE, build_cloud, recognise_driver


def rosette(n: int, rng: np.random.Generator, fov_deg: float = 70.0) -> np.ndarray:
    """(n, 3) float32 points of a narrow forward-looking sensor (Avia-like field of view) on a wall 15 m ahead, a
    floor 1.2 m below and scattered boxes."""
    az = np.deg2rad(rng.uniform(-fov_deg / 2, fov_deg / 2, n))
    el = np.deg2rad(rng.uniform(-35.0, 35.0, n))
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    with np.errstate(divide="ignore"):
        t_wall = np.where(u[:, 0] > 0, 15.0 / u[:, 0], np.inf)
        t_floor = np.where(u[:, 2] < 0, -1.2 / u[:, 2], np.inf)
    return (u * np.minimum(t_wall, t_floor)[:, None]).astype(np.float32)


def test_recognise_driver_from_the_fields():
    assert recognise_driver(VELODYNE) == "velodyne"
    assert recognise_driver(OUSTER) == "ouster"
    assert recognise_driver(LIVOX) == "livox"
    assert recognise_driver(HESAI) == "hesai"
    assert recognise_driver(FLOAT64_XYZ) is None
    assert recognise_driver(["x", "y", "z", "intensity"]) is None
    msg = build_cloud(LIVOX, {"x": np.zeros(2, np.float32)})
    assert recognise_driver(msg.fields) == "livox"


def test_guess_from_driver_and_shape(rng):
    spinning = rng.normal(size=(5000, 3)).astype(np.float32)
    narrow = rosette(5000, rng)
    assert azimuth_coverage(spinning) == 1.0
    assert azimuth_coverage(narrow) < 0.25
    assert guess_sensor(spinning) is None  # a spinning sensor: the defaults
    assert guess_sensor(narrow) == "livox_avia"
    assert guess_sensor(spinning, "livox") == "livox_mid360"
    assert guess_sensor(narrow, "ouster") == "ouster"
    assert guess_sensor(narrow, "velodyne") is None  # a cropped Velodyne cloud: the defaults


@pytest.mark.parametrize("mount, place", [("handheld", "corridor"), ("wheeled", "courtyard")])
def test_guess_from_the_shape_of_every_simulated_sensor(mount, place):
    # plain xyz (no driver fields) of every simulated sensor, raw and deskewed to the stamp: a narrow rosette is an
    # Avia, any spinning sensor (16-128 beams) keeps the defaults; with its driver's name each gets its row (a
    # 360-degree rosette with a Livox driver: a Mid-360; without one its shape is not told from a spinning sensor's)
    from deepbbs_ros.sim.patterns import SENSORS as SIMULATED
    from deepbbs_ros.sim.patterns import driver_of
    from deepbbs_ros.sim.rig import make_simulator

    by_driver = {"velodyne": None, "ouster": "ouster", "hesai": "hesai", "robosense": "robosense"}
    for name in SIMULATED:
        with_driver = {"avia": "livox_avia", "mid360": "livox_mid360"}.get(name) or by_driver[driver_of(name)]
        for compensate in (False, True):
            scan = make_simulator(place, 5, name, mount, frames=3, compensate=compensate).scan_at(1).points
            # the guess's subsample says what every point says
            full, kept = azimuth_coverage(scan, len(scan)), azimuth_coverage(scan)
            assert (kept < 0.5) == (full < 0.5), (name, kept, full)
            if name != "mid360":
                assert guess_sensor(scan) == ("livox_avia" if name == "avia" else None), (name, compensate)
            assert guess_sensor(scan, driver_of(name)) == with_driver, (name, compensate)


def test_resolve_applies_a_row_and_user_settings_win():
    base = PreprocessConfig()
    assert resolve(base) is base  # "auto" alone changes nothing
    for name in ("hdl64", "hdl32", "vlp16", "ouster", "hesai", "robosense"):
        assert replace(resolve(base, name), sensor="auto") == base  # spinning sensors: today's defaults
    avia = resolve(base, "livox_avia")
    assert avia.sensor == "livox_avia"
    assert avia.min_range == SENSORS["livox_avia"]["min_range"][0] and avia.voxel_size == 0.2
    mine = resolve(replace(base, min_range=0.7), "livox_avia")
    assert mine.min_range == 0.7 and mine.voxel_size == 0.2  # the user's setting wins
    assert resolve(avia, "livox_avia") == avia  # idempotent
    explicit = replace(base, sensor="livox_mid360")
    assert preprocess(rosette(3000, np.random.default_rng(1)), explicit).sensor == "livox_mid360"


def test_unknown_sensor_and_bad_box_are_config_errors():
    with pytest.raises(ConfigError, match="preprocess.sensor"):
        Config.from_dict({"preprocess": {"sensor": "velodyne64"}}).validate()
    with pytest.raises(ConfigError, match="preprocess.self_filter_box"):
        Config.from_dict({"preprocess": {"self_filter_box": [0, 1, 0, 1]}}).validate()
    with pytest.raises(ConfigError, match="preprocess.self_filter_box"):
        Config.from_dict({"preprocess": {"self_filter_box": [1, 0, -1, 1, -1, 1]}}).validate()


def test_prepare_scan_settles_auto_from_driver_or_shape(rng):
    cfg = Config()
    narrow = rosette(4000, rng)
    res = prepare_scan(cfg, narrow)
    assert res.sensor == "livox_avia"
    assert res.n_valid == np.count_nonzero(np.linalg.norm(narrow, axis=1) >= 1.0)  # the Avia's 1 m, not 2 m
    assert prepare_scan(cfg, narrow, driver="ouster").sensor == "ouster"


def test_self_filter_box_drops_the_robots_body(rng):
    scene = rng.uniform(-20, 20, size=(4000, 3)).astype(np.float32)
    body = rng.uniform([-1.0, -0.5, -0.6], [0.5, 0.5, 0.2], size=(500, 3)).astype(np.float32)
    pts = np.concatenate([scene, body])
    box = [-1.05, 0.55, -0.55, 0.55, -0.65, 0.25]
    cfg = PreprocessConfig(min_range=0.1, self_filter_box=box, remove_ground=False)
    keep = crop_mask(pts, cfg)
    inside = np.all((pts >= np.float32(box[::2])) & (pts <= np.float32(box[1::2])), axis=1)
    assert not keep[len(scene):].any()  # every body point goes
    np.testing.assert_array_equal(keep, ~inside & (np.linalg.norm(pts, axis=1) >= 0.1))
    assert preprocess(pts, cfg).n_valid == np.count_nonzero(keep)
    full = Config().replace(**{"preprocess.self_filter_box": box, "preprocess.min_range": 0.1})
    res = prepare_scan(full, pts)
    assert res.polish_cloud.n_cropped == np.count_nonzero(keep)  # the GICP cloud drops it too


def test_sparse_cloud_gets_a_finer_grid(rng):
    # 3,000 points over a 40 m x 12 m wall: 1 m voxels leave few candidates; the rule shrinks the voxel
    pts = np.column_stack([rng.uniform(-20, 20, 3000), np.full(3000, 10.0), rng.uniform(-2, 10, 3000)])
    pts = pts.astype(np.float32)
    cfg = PreprocessConfig(remove_ground=False, voxel_size=1.0, num_points=256)
    n_old = len(voxel_downsample(pts, 1.0))
    assert n_old < cfg.min_candidates
    res = preprocess(pts, cfg)
    expected = len(voxel_downsample(pts, max(0.25, np.sqrt(n_old / cfg.min_candidates)) * 1.0))
    assert res.n_voxels == expected and expected > n_old
    assert preprocess(pts, replace(cfg, min_candidates=0)).n_voxels == n_old  # off: as before


def test_default_preparation_of_a_simulated_hdl64_scan_is_unchanged():
    # today's input: a simulated HDL-64E scan on a car roof; the defaults give exactly what the legacy rules give
    # (upright ground fit only, no sparse-cloud rule, no sensor row): same points, plane, samples and GICP cloud
    from deepbbs_ros.sim.lidar import LidarConfig
    from deepbbs_ros.sim.simulator import DriveSimulator

    scan = DriveSimulator("suburban", 3, LidarConfig.hdl64(), frames=2).scan_at(0).points
    legacy = Config().replace(**{"preprocess.ground_search": "upright", "preprocess.min_candidates": 0})
    for lazy in (False, True):
        new, old = prepare_scan(Config(), scan, lazy=lazy), prepare_scan(legacy, scan, lazy=lazy)
        assert new.sensor == "auto" and new.ground_status == "upright"
        for name in ("points", "ground_plane", "dense_points"):
            np.testing.assert_array_equal(getattr(new, name), getattr(old, name))
        assert (new.n_valid, new.n_nonground, new.n_voxels) == (old.n_valid, old.n_nonground, old.n_voxels)
        np.testing.assert_array_equal(new.polish_cloud.points(), old.polish_cloud.points())
