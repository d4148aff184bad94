"""Simulator sensors, mounts and places beyond the car-roof spinning LiDAR on roads.

Known-geometry checks against hand-built scenes (ground plane + walls) with the real Embree caster;
places and mounts are checked against their own ground truth (floor at z = 0, ceiling height,
mount heights and motions). The road drives' regression check pins one scan of an existing preset.
"""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim import DriveSimulator, LidarConfig, RayCaster
from deepbbs_ros.sim.geometry import MeshBuilder, box
from deepbbs_ros.sim.lidar import lidar_sweep
from deepbbs_ros.sim.mounts import MountTrajectory
from deepbbs_ros.sim.patterns import SENSORS, avia, driver_fields, make_sensor, mid360
from deepbbs_ros.sim.places import PLACES, build_place
from deepbbs_ros.sim.rig import RigSimulator, make_simulator
from deepbbs_ros.sim.solid_state import coverage, pattern_sweep


def wall_scene(x: float = 10.0):
    b = MeshBuilder()
    b.add(box([0, 0, -1.0], (400, 400, 1.0)), 0.2)
    b.add(box([x + 0.1, 0, -1.0], (0.2, 200, 60.0)), 0.5)
    v, f, a = b.build()
    return RayCaster(v, f), a


def pose(x=0.0, z=1.9) -> np.ndarray:
    T = np.eye(4)
    T[0, 3], T[2, 3] = x, z
    return T


@pytest.mark.parametrize("name,lo,hi", [("xt32", -16.0, 15.0), ("os0_32", -45.0, 45.0), ("os1_128", -22.5, 22.5),
                                        ("helios32", -55.0, 15.0)])
def test_spinning_presets_fire_their_datasheet_beams(name, lo, hi):
    lid = make_sensor(name, azimuth_step_deg=2.0, range_noise=0.0, dropout=0.0)
    el = np.rad2deg(lid.elevations())
    assert el[0] == pytest.approx(lo) and el[-1] == pytest.approx(hi)
    T = np.broadcast_to(pose(), (lid.columns, 4, 4))
    pts, f = lidar_sweep(lid, T, wall_scene(), np.random.default_rng(0))
    got = np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1]))
    assert np.allclose(got, lid.elevations()[f["ring"]], atol=1e-5)
    if name == "helios32":  # denser round the horizon than below
        d = np.diff(el)
        assert d[-10:].mean() < 0.5 * d[:7].mean()


def test_livox_patterns_fov_rate_and_no_repeat():
    a = avia()
    d0, t0, line = a.pattern(0.0, 0.1)
    assert len(d0) == 24_000 and set(np.unique(line)) == set(range(6))
    assert np.all(np.diff(t0) > 0) and t0[0] == 0.0 and t0[-1] < 0.1
    az = np.rad2deg(np.arctan2(d0[:, 1], d0[:, 0]))
    el = np.rad2deg(np.arcsin(d0[:, 2]))
    assert np.abs(az).max() <= 35.2 + 1e-6 and np.abs(el).max() <= 38.6 + 1e-6
    assert np.ptp(az) > 0.95 * 70.4 and np.ptp(el) > 0.95 * 77.2
    d1, _, _ = a.pattern(0.1, 0.1)
    assert not np.allclose(d0, d1, atol=1e-3)  # the next frame scans other directions
    cov_1 = coverage(d0, 0.25)
    cov_10 = coverage(np.concatenate([a.pattern(0.1 * k, 0.1)[0] for k in range(10)]), 0.25)
    assert cov_10 > 2.0 * cov_1  # non-repetitive: one second covers more than one frame
    m = mid360()
    dm, _, lm = m.pattern(0.0, 0.1)
    assert len(dm) == 20_000 and set(np.unique(lm)) == {0, 1, 2, 3}
    el = np.rad2deg(np.arcsin(dm[:, 2]))
    assert el.min() >= -7.0 - 1e-6 and el.max() <= 52.0 + 1e-6
    az = np.rad2deg(np.arctan2(dm[:, 1], dm[:, 0]))
    assert np.histogram(az, bins=36, range=(-180, 180))[0].min() > 0  # all round
    cov_m10 = coverage(np.concatenate([m.pattern(0.1 * k, 0.1)[0] for k in range(10)]), 0.25)
    assert cov_m10 > 2.0 * coverage(dm, 0.25)  # coverage fills in over time


def test_livox_sweep_hits_a_known_wall_with_motion():
    cfg = avia(range_noise=0.0, dropout=0.0)
    dirs, times, line = cfg.pattern(0.0, 0.1)
    v = 5.0
    T_rays = np.stack([pose(x=v * t) for t in times])
    pts, f = pattern_sweep(cfg, dirs, times, line, T_rays, wall_scene(), np.random.default_rng(1))
    assert f["time"].dtype == np.float32 and f["line"].dtype == np.uint8
    wall = pts[:, 2] > -1.8
    assert wall.sum() > 5000
    assert np.allclose(pts[wall, 0] + v * f["time"][wall], 10.0, atol=1e-3)  # own firing pose puts it on x = 10


def test_driver_time_fields_give_back_the_relative_times():
    t = np.array([0.0, 0.025, 0.0999], np.float32)
    stamp = 1_600_000_000 * 10**9 + 123_456_789
    for name, field, dtype in (("os1_64", "t", np.uint32), ("avia", "timestamp", np.float64),
                               ("xt32", "timestamp", np.float64), ("helios32", "timestamp", np.float64)):
        f = driver_fields(name, {"time": t, "intensity": np.ones(3, np.float32)}, stamp)
        assert "time" not in f and f[field].dtype == dtype
        scan = Scan(0, stamp, np.zeros((3, 3), np.float32), f)
        assert np.allclose(scan.point_times(), t, atol=2e-6)
    assert "time" in driver_fields("hdl64", {"time": t}, stamp)  # Velodyne and the older presets keep ``time``
    assert "time" in driver_fields("ouster64", {"time": t}, stamp)


def _yaw_pitch_roll(T: np.ndarray):
    R = T[..., :3, :3]
    return np.unwrap(np.arctan2(R[..., 1, 0], R[..., 0, 0])), -np.arcsin(R[..., 2, 0]), np.arctan2(R[..., 2, 1],
                                                                                                  R[..., 2, 2])


def test_mounts_move_as_robots_and_hands_do():
    path = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 10.0], [0.0, 10.0]])

    def floor(x, y):
        return 0.1 * x

    t = np.arange(0.0, 60.0, 0.01)
    wheeled = MountTrajectory("wheeled", path, floor, 0, 60.0).poses(t)
    yaw, pitch, roll = _yaw_pitch_roll(wheeled)
    h = wheeled[:, 2, 3] - floor(wheeled[:, 0, 3], wheeled[:, 1, 3])
    assert 0.3 <= h[0] <= 1.0 and np.allclose(h, h[0]) and np.allclose(pitch, 0) and np.allclose(roll, 0)
    step = np.linalg.norm(np.diff(wheeled[:, :2, 3], axis=0), axis=1)
    turning = np.abs(np.diff(yaw)) > 1e-4
    assert (turning & (step < 1e-9)).sum() > 100  # turns in place at the corners
    assert np.rad2deg(np.abs(np.diff(yaw)).max() / 0.01) <= 60.0 + 1e-6
    legged = MountTrajectory("legged", path, floor, 0, 60.0).poses(t)
    _, pitch, roll = _yaw_pitch_roll(legged)
    assert 1.0 <= np.rad2deg(np.ptp(pitch)) / 2 <= 3.0 + 1e-6 and 1.5 <= np.rad2deg(np.ptp(roll)) / 2 <= 4.0 + 1e-6
    hand = MountTrajectory("handheld", path, floor, 0, 60.0).poses(t)
    yaw, pitch, _ = _yaw_pitch_roll(hand)
    x_axis_down = np.rad2deg(np.arcsin(-hand[:, 2, 0]))
    assert 5.0 < np.median(x_axis_down) < 40.0  # pointed forward and down
    rate = np.rad2deg(np.abs(np.diff(yaw)) / 0.01)
    assert 45.0 < rate.max() < 150.0 and np.median(rate) > 10.0


@pytest.mark.parametrize("name", PLACES)
def test_places_have_ceilings_or_sky_and_a_flat_floor(name):
    place = build_place(name, 3)
    cfg = mid360(range_noise=0.0, dropout=0.0)
    dirs, times, line = cfg.pattern(0.0, 0.1)
    T = np.eye(4)
    T[:2, 3], T[2, 3] = place.path[0], 1.0
    pts, _ = pattern_sweep(cfg, dirs, times, line, np.broadcast_to(T, (len(dirs), 4, 4)),
                           (RayCaster(place.vertices, place.faces), place.albedo), np.random.default_rng(2))
    w = pts.astype(np.float64) + T[:3, 3]
    steep = np.sin(np.deg2rad(30.0))
    up_rays = int((dirs[:, 2] > steep).sum())
    up_hits = pts[:, 2] / np.linalg.norm(pts, axis=1) > steep  # noiseless: a point lies along its ray
    assert up_rays > 1000
    if place.ceiling is None:
        assert up_hits.sum() < 0.6 * up_rays  # open sky
    else:
        assert up_hits.sum() > 0.98 * up_rays  # indoors every ray going up hits something...
        assert (np.abs(w[up_hits, 2] - place.ceiling) < 1e-3).sum() > 300  # ...the ceiling among them
    assert (np.abs(w[:, 2]) < 1e-3).sum() > 200  # the floor at z = 0
    again = build_place(name, 3)
    assert np.array_equal(again.vertices, place.vertices) and not np.array_equal(build_place(name, 4).vertices,
                                                                                  place.vertices)


def test_rig_drive_is_reproducible_and_compensation_uses_its_own_ground_truth():
    lid = make_sensor("os0_32", azimuth_step_deg=2.0, range_noise=0.0, dropout=0.0)
    sim = RigSimulator("garage", 5, lid, "handheld", frames=4, compensate=True)
    a, b = sim.scan_at(3), RigSimulator("garage", 5, lid, "handheld", frames=4, compensate=True).scan_at(3)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.T_world_lidar, b.T_world_lidar)
    assert "time" not in a.fields and "t" not in a.fields
    w = a.points.astype(np.float64) @ a.T_world_lidar[:3, :3].T + a.T_world_lidar[:3, 3]
    near_floor = np.abs(w[:, 2]) < 0.3
    on_floor = np.abs(w[:, 2]) < 2e-3  # deskewed with the true poses: the floor stays a plane
    assert near_floor.sum() > 500 and on_floor.sum() > 0.9 * near_floor.sum()
    still = RigSimulator("garage", 5, lid, "handheld", frames=4, motion_distortion=False, compensate=True).scan_at(3)
    w = still.points.astype(np.float64) @ still.T_world_lidar[:3, :3].T + still.T_world_lidar[:3, 3]
    assert (np.abs(w[:, 2]) < 2e-3).sum() > 0.9 * (np.abs(w[:, 2]) < 0.3).sum()  # an instantaneous scan stays put
    raw = RigSimulator("corridor", 5, avia(), "legged", frames=2).scan_at(1)
    assert raw.fields["timestamp"].dtype == np.float64 and raw.point_times().max() < 0.1


def test_make_simulator_keeps_car_drives_on_roads_unchanged():
    lid = LidarConfig(beams=16, azimuth_step_deg=2.0, name="test")
    sim = make_simulator("urban", 3, lid, "car", frames=3)
    assert isinstance(sim, DriveSimulator)
    s = sim.scan_at(2)  # pinned: the same scan as before the new sensors, mounts and places existed
    assert len(s) == 2790
    assert np.bincount(s.fields["ring"], minlength=16).tolist() == PINNED_RINGS
    assert np.allclose(s.points.astype(np.float64).mean(0), PINNED_MEAN, atol=1e-4)
    assert np.allclose(s.T_world_lidar[:3, 3], PINNED_T, atol=1e-9)
    assert isinstance(make_simulator("urban", 3, "avia", "car", frames=2), RigSimulator)
    with pytest.raises(SimulationError, match="unknown sensor"):
        make_sensor("hdl128")
    with pytest.raises(SimulationError, match="unknown place"):
        build_place("moon", 0)
    assert len(SENSORS) == len(set(SENSORS)) == 14


# measured on the simulator before sensors, mounts and places were added (mean point, position, returns per ring)
PINNED_MEAN = (0.20589273200774277, 0.9610648349942272, -1.3198116226502323)
PINNED_T = (-76.8163257479286, -27.63021667116382, 2.0491050215663353)
PINNED_RINGS = [176, 176, 178, 178, 178, 176, 178, 178, 177, 173, 176, 177, 179, 165, 165, 160]


def test_cli_new_sensor_mount_and_place(tmp_path, capsys):
    from deepbbs_ros.cli import sim as cli
    from deepbbs_ros.datasets import open_source
    from deepbbs_ros.sim.mounts import MOUNTS
    from deepbbs_ros.sim.rig import ALL_PLACES

    assert cli.SCENES + cli.PLACES == ALL_PLACES and cli.PRESETS == SENSORS and cli.MOUNTS == MOUNTS
    out = tmp_path / "walk"
    argv = ["--scene", "garage", "--mount", "wheeled", "--lidar", "os1_32", "--azimuth-step", "4", "--raw",
            "--frames", "2", "--seed", "2", "--out", str(out), "--quiet"]
    assert cli.main(argv) == 0
    lid = make_sensor("os1_32", azimuth_step_deg=4.0)
    ref = RigSimulator("garage", 2, lid, "wheeled", frames=2)
    got = list(open_source(out))
    assert len(got) == 2
    for scan in got:
        exp = next(ref.scan_at(k) for k in range(2) if ref.stamp_ns(k) == scan.stamp_ns)
        assert np.allclose(scan.points, exp.points, atol=1e-6) and np.array_equal(scan.fields["t"], exp.fields["t"])
        assert np.allclose(scan.T_world_lidar, exp.T_world_lidar, atol=1e-6)
    assert cli.main(["--lidar", "avia", "--beams", "4", "--out", str(tmp_path / "x"), "--quiet"]) == 1
    assert "do not apply to avia" in capsys.readouterr().err


def test_training_cache_can_mix_sensors_mounts_and_places(tmp_path):
    from deepbbs_ros.config import Config
    from deepbbs_ros.errors import DatasetError
    from deepbbs_ros.train.cache import load_drive
    from deepbbs_ros.train.sim_cache import sim_drive_specs, simulate_cached_drive

    default = sim_drive_specs(["urban", "garage"], [10, 11], 2)
    assert [(s.name, s.sensor, s.mount) for s in default] == [("urban_10", None, "car"), ("garage_11", None, "car")]
    mixed = sim_drive_specs(["corridor"], [12], 2, sensors=["mid360"], mounts=["handheld"])
    assert mixed[0].name == "corridor_handheld_mid360_12"
    path = simulate_cached_drive(mixed[0], tmp_path, Config().preprocess, 256)
    drive = load_drive(path)
    assert len(drive) == 2 and drive.meta["sensor"] == {"preset": "mid360", "mount": "handheld"}
    with pytest.raises(DatasetError, match="unknown sensor 'hdl128'"):
        sim_drive_specs(["urban"], [1], 2, sensors=["hdl128"])


@pytest.mark.parametrize("sensor,mount,tol", [("avia", "car", 1e-4), ("xt32", "car", 1e-4),
                                              ("os0_32", "handheld", 0.01)])
def test_raw_scans_deskew_with_their_driver_time_fields(sensor, mount, tol):
    """The pipeline's constant-velocity deskew, fed the driver's own time field through Scan.point_times,
    gives back the compensated scan (exactly at constant velocity; within 1 cm for a hand's turning)."""
    from deepbbs_ros.core.preprocess import deskew

    kw = {"azimuth_step_deg": 1.0} if sensor != "avia" else {}
    lid = make_sensor(sensor, **kw)
    raw = RigSimulator("courtyard", 1, lid, mount, frames=26)
    comp = RigSimulator("courtyard", 1, lid, mount, frames=26, compensate=True)
    a, b = raw.scan_at(25), comp.scan_at(25)
    assert "time" not in a.fields
    delta = np.linalg.inv(raw.pose_at(25)) @ raw.T_world_lidar(26 * raw.period)
    before = np.linalg.norm(a.points - b.points, axis=1)
    after = np.linalg.norm(deskew(a.points, a.point_times(), delta, raw.period) - b.points, axis=1)
    assert np.percentile(before, 99) > 0.1 and np.percentile(after, 99) < tol


@pytest.mark.parametrize("sensor,field", [("avia", "timestamp"), ("xt32", "timestamp"), ("os0_32", "t")])
def test_cli_writes_the_drivers_own_layout(tmp_path, sensor, field):
    from deepbbs_ros.cli.sim import main
    from deepbbs_ros.datasets import open_source

    step = [] if sensor == "avia" else ["--azimuth-step", "4"]
    out = tmp_path / sensor
    assert main(["--scene", "hall", "--mount", "legged", "--lidar", sensor, *step, "--raw", "--driver-layout",
                 "--frames", "2", "--out", str(out), "--quiet"]) == 0
    kw = {} if sensor == "avia" else {"azimuth_step_deg": 4.0}
    ref = RigSimulator("hall", 0, make_sensor(sensor, **kw), "legged", frames=2)
    for scan in open_source(out):
        exp = next(ref.scan_at(k) for k in range(2) if ref.stamp_ns(k) == scan.stamp_ns)
        valid = np.any(scan.points != 0, axis=1)  # the organised Ouster cloud holds zeros where nothing returned
        assert valid.sum() == len(exp) and field in scan.fields
        got = scan.points[valid]
        order = np.lexsort(got.T) if sensor == "os0_32" else np.arange(len(got))
        ref_order = np.lexsort(exp.points.T) if sensor == "os0_32" else order
        assert np.allclose(got[order], exp.points[ref_order], atol=1e-6)
        times = Scan(0, scan.stamp_ns, got, {k: v[valid] for k, v in scan.fields.items()}).point_times()
        assert np.allclose(times[order], exp.point_times()[ref_order], atol=1e-6)
