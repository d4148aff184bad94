"""LiDAR drive simulator: determinism, occlusion, noise, motion distortion, ground truth, beams, scenes.

Known-geometry tests use a hand-built scene (ground plane + walls) and the real Embree ray caster;
drive tests use small sensors (few beams, coarse azimuth) so the whole file stays fast.
"""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim import SCENES, DriveSimulator, LidarConfig, RayCaster, simulate_drive
from deepbbs_ros.sim.geometry import MeshBuilder, box
from deepbbs_ros.sim.lidar import lidar_sweep
from deepbbs_ros.sim.scene import ROAD_DZ


def small_lidar(**kw) -> LidarConfig:
    """32 beams over the HDL-64 field of view, 1 degree azimuth: 11.5k rays per sweep."""
    return LidarConfig(**{"beams": 32, "azimuth_step_deg": 1.0, "name": "test", **kw})


def wall_scene(walls_x=(10.0,), back_wall_x: float | None = None):
    """Ground plane z=0 (400 m square) and walls 0.2 m thick, 40 m wide, 30 m tall at x = walls_x."""
    b = MeshBuilder()
    b.add(box([0, 0, -1.0], (400, 400, 1.0)), 0.2)
    for x in walls_x:
        b.add(box([x + 0.1, 0, -1.0], (0.2, 40, 31.0)), 0.5)
    if back_wall_x is not None:
        b.add(box([back_wall_x + 0.1, 0, -1.0], (0.2, 40, 31.0)), 0.5)
    v, f, a = b.build()
    return RayCaster(v, f), a


def sensor_pose(x=0.0, y=0.0, z=1.9, yaw=0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [x, y, z]
    return T


def test_embree_is_used():
    import trimesh

    assert trimesh.ray.has_embree
    caster, _ = wall_scene()
    assert caster._scene is not None and type(caster._scene).__module__.startswith("embreex")


def test_no_return_behind_a_wall():
    lid = small_lidar(range_noise=0.0, dropout=0.0)
    T = np.broadcast_to(sensor_pose(), (lid.columns, 4, 4))
    rng = np.random.default_rng(0)
    # without the front wall, the back wall at x=20 is seen...
    pts, _ = lidar_sweep(lid, T, wall_scene(walls_x=(), back_wall_x=20.0), rng)
    on_back = (np.abs(pts[:, 0] - 20.0) < 1e-3) & (pts[:, 2] > -1.8)
    assert on_back.sum() > 100
    # ...with it, nothing at all lies behind the front wall's plane where it blocks the view
    pts, _ = lidar_sweep(lid, T, wall_scene(walls_x=(10.0,), back_wall_x=20.0), rng)
    hidden = (pts[:, 0] > 10.0 + 1e-3) & (np.abs(pts[:, 1]) < 20.0 * pts[:, 0] / 10.2 - 0.5)
    assert not ((np.abs(pts[:, 0] - 20.0) < 1e-3) & (pts[:, 2] > -1.8)).any()
    assert not hidden.any()
    # the wall itself is hit where expected
    on_wall = np.abs(pts[:, 0] - 10.0) < 1e-3
    assert on_wall.sum() > 300


def test_range_noise_statistics():
    sigma = 0.02
    lid = small_lidar(range_noise=sigma, dropout=0.0, azimuth_step_deg=0.2)
    T = np.broadcast_to(sensor_pose(), (lid.columns, 4, 4))
    pts, _ = lidar_sweep(lid, T, wall_scene(), np.random.default_rng(1))
    r = np.linalg.norm(pts, axis=1)
    u = pts / r[:, None]
    with np.errstate(divide="ignore"):
        to_wall = np.where(u[:, 0] > 0, 10.0 / u[:, 0], np.inf)  # ray-plane distance to x = 10
        to_ground = np.where(u[:, 2] < 0, 1.9 / -u[:, 2], np.inf)
    wall = (to_wall < to_ground - 0.5) & (np.abs(u[:, 1] * to_wall) < 19.0)
    exact = to_wall[wall]
    res = r[wall] - exact
    assert wall.sum() > 2000
    assert abs(res.mean()) < 4 * sigma / np.sqrt(wall.sum())
    assert res.std() == pytest.approx(sigma, rel=0.1)


def test_dropout_rate():
    lid = small_lidar(range_noise=0.0, dropout=0.2)
    T = np.broadcast_to(sensor_pose(), (lid.columns, 4, 4))
    n_full = len(lidar_sweep(small_lidar(range_noise=0.0, dropout=0.0), T, wall_scene(), np.random.default_rng(2))[0])
    n_drop = len(lidar_sweep(lid, T, wall_scene(), np.random.default_rng(2))[0])
    assert n_drop / n_full == pytest.approx(0.8, abs=0.03)


def test_motion_distortion_known_scene():
    """Sensor moving at 10 m/s towards a wall: each distorted point sits on the wall when mapped
    with the pose of its own firing time, and is off by v * time when mapped with the stamp pose."""
    lid = small_lidar(range_noise=0.0, dropout=0.0)
    period, v = 0.1, 10.0
    t_col = np.arange(lid.columns) * period / lid.columns
    T_cols = np.stack([sensor_pose(x=v * t) for t in t_col])
    pts, fields = lidar_sweep(lid, T_cols, wall_scene(), np.random.default_rng(3), period=period)
    t = fields["time"]
    assert t.dtype == np.float32 and t.min() >= 0.0 and t.max() < period
    assert np.all(np.diff(t) >= 0)  # Velodyne firing order
    front = (np.abs(pts[:, 1]) < 5.0) & (pts[:, 0] > 5.0) & (pts[:, 2] > -1.8)  # wall, not ground
    wall_x_true = pts[front, 0] + v * t[front]  # own pose: x shifted by v t
    assert front.sum() > 100 and np.allclose(wall_x_true, 10.0, atol=1e-3)
    wall_x_stamp = pts[front, 0]  # stamp pose: short by v t
    assert np.allclose(10.0 - wall_x_stamp, v * t[front], atol=1e-3)
    # the same scene without motion: every wall point at x = 10
    pts0, _ = lidar_sweep(lid, np.broadcast_to(T_cols[0], T_cols.shape), wall_scene(), np.random.default_rng(3))
    f0 = (np.abs(pts0[:, 1]) < 5.0) & (pts0[:, 0] > 5.0) & (pts0[:, 2] > -1.8)
    assert f0.sum() > 100 and np.allclose(pts0[f0, 0], 10.0, atol=1e-3)


def test_ring_and_beam_angles():
    lid = LidarConfig.hdl64(azimuth_step_deg=1.0, range_noise=0.0, dropout=0.0)
    assert lid.beams == 64 and lid.elevations_deg[0] == pytest.approx(-24.8) and lid.elevations_deg[-1] == 2.0
    T = np.broadcast_to(sensor_pose(), (lid.columns, 4, 4))
    pts, f = lidar_sweep(lid, T, wall_scene(walls_x=(10.0, -10.0)), np.random.default_rng(4))
    ring = f["ring"]
    assert ring.dtype == np.uint16 and ring.max() == 63
    el = np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1]))
    assert np.allclose(el, lid.elevations()[ring], atol=1e-5)
    az = np.arctan2(pts[:, 1], pts[:, 0])
    col = np.round(np.mod(np.pi - az, 2 * np.pi) / np.deg2rad(1.0)).astype(int) % lid.columns
    assert np.allclose(f["time"], col * 0.1 / lid.columns, atol=1e-6)
    # ground rings: ring 0 (lowest beam) lands 1.9 / tan(24.8 deg) = 4.1 m away
    r0 = np.hypot(pts[ring == 0, 0], pts[ring == 0, 1])
    assert np.allclose(r0, 1.9 / np.tan(np.deg2rad(24.8)), atol=1e-3)


def test_presets_and_organized_order():
    assert LidarConfig.hdl32().beams == 32 and LidarConfig.vlp16().beams == 16
    os64 = LidarConfig.ouster64(azimuth_step_deg=2.0, dropout=0.0)
    assert os64.organized
    T = np.broadcast_to(sensor_pose(), (os64.columns, 4, 4))
    _, f = lidar_sweep(os64, T, wall_scene(walls_x=(10.0, -10.0)), np.random.default_rng(5))
    key = f["ring"].astype(np.int64) * os64.columns + f["column"]
    assert np.all(np.diff(key) > 0)  # ring-major, row by row
    with pytest.raises(SimulationError, match="unknown LiDAR preset"):
        LidarConfig.preset("hdl128")
    with pytest.raises(SimulationError, match="elevations_deg has 2 values"):
        LidarConfig(beams=3, elevations_deg=(0.0, 1.0)).validate()


def test_same_seed_bit_identical_and_random_access():
    lid = small_lidar()
    a = list(simulate_drive("urban", 7, 3, lidar=lid))
    sim = DriveSimulator("urban", 7, lid, frames=3)
    b2 = sim.scan_at(2)  # random access first
    b = [sim.scan_at(0), sim.scan_at(1), b2]
    for x, y in zip(a, b):
        assert x.stamp_ns == y.stamp_ns and x.index == y.index
        assert np.array_equal(x.points, y.points)
        assert np.array_equal(x.T_world_lidar, y.T_world_lidar)
        for k in ("intensity", "time", "ring"):
            assert x.fields[k].dtype == y.fields[k].dtype
            assert np.array_equal(x.fields[k], y.fields[k])
    c = next(simulate_drive("urban", 8, 1, lidar=lid))
    assert not np.array_equal(c.T_world_lidar, a[0].T_world_lidar)


def test_ground_truth_pose_puts_points_on_surfaces():
    """Undistorted, noiseless scans mapped by T_world_lidar land on the scene's surfaces."""
    lid = small_lidar(range_noise=0.0, dropout=0.0)
    sim = DriveSimulator("suburban", 3, lid, frames=20, motion_distortion=False)
    scan = sim.scan_at(15)
    T = scan.T_world_lidar
    w = scan.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    caster, _ = sim._static_caster(15 * sim.period)
    # a ray started 0.3 m before each world point, pointing at it, hits a surface 0.3 m later
    d = w - T[:3, 3]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dist, face, _ = caster.cast(w - 0.3 * d, d, 10.0)
    static = face >= 0
    assert static.mean() > 0.95  # the rest hit moving cars (not in the static scene)
    assert np.allclose(dist[static & (dist < 1.0)], 0.3, atol=2e-3)
    assert np.mean(np.abs(dist[static] - 0.3) < 2e-3) > 0.95
    # the lowest ring hits the road near the car: z = terrain + road offset
    near = (scan.fields["ring"] == 0) & (np.abs(scan.points[:, 1]) < 1.0)
    g = sim.world.terrain.height(w[near, 0], w[near, 1]) + ROAD_DZ
    assert near.sum() >= 2 and np.allclose(w[near, 2], g, atol=0.02)
    # pose: LiDAR 1.9 m above the road, nearly level
    base = T[:3, 3] - T[:3, 2] * lid.mount_height
    assert base[2] == pytest.approx(sim.world.terrain.height(base[0], base[1]) + ROAD_DZ, abs=0.02)
    assert T[2, 2] > np.cos(np.deg2rad(6))


def test_motion_distortion_switch_in_a_drive():
    lid = small_lidar(range_noise=0.0, dropout=0.0)
    on = DriveSimulator("highway", 2, lid, frames=5, motion_distortion=True).scan_at(4)
    off = DriveSimulator("highway", 2, lid, frames=5, motion_distortion=False).scan_at(4)
    assert np.array_equal(on.T_world_lidar, off.T_world_lidar)
    t = on.fields["time"]
    assert t.min() >= 0 and t.max() < 0.1
    # at highway speed the last columns are ~1.7 m further along: the clouds differ
    assert len(on) != len(off) or not np.allclose(on.points, off.points, atol=0.05)


def test_compensated_sweep_lies_on_surfaces_at_its_stamp():
    """A motion-distorted sweep compensated with the true column poses (Apollo's compensator) lands
    on the scene's surfaces when mapped by the stamp pose, as an undistorted scan does; the raw one
    does not, and only the raw one carries per-point time."""
    lid = small_lidar(range_noise=0.0, dropout=0.0)
    raw_sim = DriveSimulator("highway", 2, lid, frames=5, motion_distortion=True)
    comp_sim = DriveSimulator("highway", 2, lid, frames=5, motion_distortion=True, compensate=True)
    raw, comp = raw_sim.scan_at(4), comp_sim.scan_at(4)
    assert "time" in raw.fields and "time" not in comp.fields
    assert np.array_equal(raw.T_world_lidar, comp.T_world_lidar) and len(raw) == len(comp)
    caster, _ = comp_sim._static_caster(4 * comp_sim.period)

    def on_surface(scan):
        T = scan.T_world_lidar
        w = scan.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        d = w - T[:3, 3]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        dist, face, _ = caster.cast(w - 0.3 * d, d, 10.0)
        return np.mean((face >= 0) & (np.abs(dist - 0.3) < 5e-3))

    assert on_surface(comp) > 0.9
    assert on_surface(raw) < 0.5  # ~1.7 m of travel over the sweep at highway speed


@pytest.mark.parametrize("scene", SCENES)
def test_scene_types_produce_plausible_scans(scene):
    lid = small_lidar()
    sim = DriveSimulator(scene, 11, lid, frames=30)
    scans = [sim.scan_at(0), sim.scan_at(29)]
    rays = lid.columns * lid.beams
    for s in scans:
        r = np.linalg.norm(s.points, axis=1)
        assert 0.5 * rays < len(s) <= rays
        assert s.points.dtype == np.float32 and s.fields["intensity"].dtype == np.float32
        assert r.min() >= lid.min_range and r.max() < lid.max_range and np.percentile(r, 90) > 20.0
        assert 0 <= s.fields["intensity"].min() and s.fields["intensity"].max() <= 255
        above = s.points[:, 2] > 0.5 - lid.mount_height  # > 0.5 m above the road
        min_above = 0.003 if scene == "open_road" else 0.02
        assert above.mean() > min_above, f"{scene}: too little vertical structure"
    moved = np.linalg.norm(scans[1].T_world_lidar[:3, 3] - scans[0].T_world_lidar[:3, 3])
    assert moved < 20.0 * 2.9 + 1e-6  # speed <= 20 m/s
    v = sim.trajectory.v_grid
    assert v.min() >= -1e-6 and v.max() <= 20.0 + 1e-6


@pytest.mark.parametrize("scene", SCENES)
def test_off_ground_share_like_real_drives(scene):
    """Real HDL-64E drives keep 28-55 % of returns more than 0.3 m off the ground plane (RANSAC fit
    within 20 m, as the preprocessing does); the simulated worlds stay inside a slightly wider band
    on a small sensor (seed 11, two scans)."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.preprocess import fit_ground_plane

    sim = DriveSimulator(scene, 11, small_lidar(azimuth_step_deg=0.5), frames=40, compensate=True)
    for k in (5, 35):
        pts = sim.scan_at(k).points
        plane = fit_ground_plane(pts, Config().preprocess, seed=k)
        share = np.mean(np.abs(pts.astype(np.float64) @ plane[:3] + plane[3]) > 0.3)
        assert 0.22 < share < 0.6, f"{scene} frame {k}: {100 * share:.0f} % off the ground"


@pytest.mark.parametrize("scene", SCENES)
def test_world_structure(scene):
    """Curved roads, junctions with side roads, porous vegetation, roadside relief off the road."""
    from deepbbs_ros.sim.scene import World

    w = World(scene, 3, 1500.0)
    kap = np.abs(w.route.kappa)
    curved = kap[(kap > 0) & (kap < 1 / 90)]  # not a 90-degree street corner
    assert len(curved) and 1 / curved.max() >= 99.0 and 1 / curved.min() <= 2001.0
    assert len(w.junctions) >= 1
    for j in w.junctions:  # side roads leave the road and stay off it
        far = j["xy"][j["free_from"]:]
        assert w.route.clearance(far) > w.style.half_width
    # the road corridor is untouched by the relief, the land beside it is not
    s = np.arange(100.0, 1400.0, 7.0)
    on = w.route.lateral(s, w.style.half_width * 0.5)
    assert np.allclose(w.terrain.height(on[:, 0], on[:, 1]), w.terrain._base(on[:, 0], on[:, 1]))
    off = w.route.lateral(s, w.style.half_width + 25.0)
    relief = w.terrain.height(off[:, 0], off[:, 1]) - w.terrain._base(off[:, 0], off[:, 1])
    assert np.abs(relief).max() > (0.05 if scene == "urban" else 0.5)
    # porous crowns: rays through a tree's crown region partly reach beyond it
    v, f, _ = w.static_mesh(w.route.lateral(700.0, 0.0), 150.0)
    assert len(f) > 20000


@pytest.mark.parametrize("scene", SCENES)
def test_junctions_leave_the_carriageway_flat(scene):
    """A side road's corridor is narrower than the main road's, and where it starts, points of the main road lie
    nearer its centreline than the main road's: its ditch and banks must still stay off the main road (the relief is
    zero across the whole carriageway, up to its verges, round every junction)."""
    from deepbbs_ros.sim.scene import World

    w = World(scene, 8, 1200.0)
    st = w.style
    edge = st.half_width + (st.sidewalk + 0.6 if st.sidewalk > 0 else 2.0)
    offs = np.arange(-edge, edge + 1e-9, 0.5)
    for j in w.junctions:
        s = np.arange(max(j["s"] - 30.0, 0.0), j["s"] + 30.0, 0.5)
        p = w.route.lateral(s[:, None], offs[None, :])
        relief = w.terrain.height(p[..., 0], p[..., 1]) - w.terrain._base(p[..., 0], p[..., 1])
        assert np.abs(relief).max() == 0.0, f"junction at s = {j['s']:.1f} m: {np.abs(relief).max():.3f} m relief"


def test_ground_truth_attitude_is_smooth_past_a_slip_road():
    """The VLP-16 highway drive, seed 8, passes the start of a slip road on its own side at frame 145: its pose
    there follows its neighbours (the ditch of the slip road once tilted it by 19 deg roll and 23 deg pitch and
    dropped it 0.55 m)."""
    sim = DriveSimulator("highway", 8, LidarConfig.preset("vlp16"), frames=150)
    T = np.stack([sim.pose_at(k) for k in range(136, 150)])
    R = T[:, :3, :3]
    roll, pitch = np.arctan2(R[:, 2, 1], R[:, 2, 2]), -np.arcsin(R[:, 2, 0])
    for x, tol in ((np.degrees(roll), 0.5), (np.degrees(pitch), 0.5), (T[:, 2, 3], 0.02)):
        assert np.abs(x[1:-1] - 0.5 * (x[:-2] + x[2:])).max() < tol  # deg, deg, m off the neighbours' mean


def test_porous_crown_lets_rays_through():
    from deepbbs_ros.sim.geometry import clusters

    rng = np.random.default_rng(0)
    b = MeshBuilder()
    b.add(box([0, 0, -1.0], (400, 400, 1.0)), 0.2)
    b.add(box([15.1, 0, -1.0], (0.2, 40, 31.0)), 0.5)  # wall behind the crown
    b.add(clusters([8.0, 0.0, 1.0], (2.5, 2.5, 2.5), rng, 27, 0.38), 0.4)  # as World._tree makes them
    v, f, a = b.build()
    lid = small_lidar(range_noise=0.0, dropout=0.0, azimuth_step_deg=0.2)
    T = np.broadcast_to(sensor_pose(), (lid.columns, 4, 4))
    pts, _ = lidar_sweep(lid, T, (RayCaster(v, f), a), np.random.default_rng(0))
    cone = (pts[:, 0] > 4.0) & (np.abs(pts[:, 1]) < pts[:, 0] * 1.5 / 8.0) & (pts[:, 2] > -1.0) & (pts[:, 2] < 0.5)
    crown = cone & (pts[:, 0] < 11.0)
    behind = cone & (np.abs(pts[:, 0] - 15.0) < 0.05)
    assert crown.sum() > 50 and behind.sum() > 0.15 * cone.sum()  # partly transmissive


def test_bad_arguments():
    with pytest.raises(SimulationError, match="unknown scene 'mars'"):
        simulate_drive("mars", 0, 1)
    with pytest.raises(SimulationError, match="frames must be >= 1"):
        simulate_drive("urban", 0, 0)
    with pytest.raises(SimulationError, match="out of range"):
        DriveSimulator("open_road", 0, small_lidar(), frames=2).scan_at(2)


def test_parallel_frames_are_identical():
    from deepbbs_ros.sim.simulator import iter_frames

    sim = DriveSimulator("suburban", 5, small_lidar(), frames=4)
    serial = list(iter_frames(sim, workers=1))
    parallel = list(iter_frames(DriveSimulator("suburban", 5, small_lidar(), frames=4), workers=2))
    assert [s.index for s in parallel] == [0, 1, 2, 3]
    for a, b in zip(serial, parallel):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.fields["intensity"], b.fields["intensity"])


def test_cli_writes_a_readable_drive(tmp_path, capsys):
    from deepbbs_ros.cli.sim import main
    from deepbbs_ros.datasets import open_source

    out = tmp_path / "drive"
    argv = ["--scene", "open_road", "--seed", "4", "--frames", "3", "--format", "mcap", "--out", str(out),
            "--lidar", "hdl64", "--beams", "16", "--azimuth-step", "2.0", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    src = open_source(out)
    assert len(src) == 3 and src.has_ground_truth
    lid = LidarConfig.hdl64(azimuth_step_deg=2.0)
    keep = np.unique(np.round(np.linspace(0, 63, 16)).astype(int))  # the CLI's beam decimation
    lid.elevations_deg, lid.beams = tuple(np.rad2deg(lid.elevations())[keep].tolist()), 16
    ref = list(simulate_drive("open_road", 4, 3, lidar=lid, compensate=True))  # default: compensated
    for got in src:
        assert got.points.shape[0] > 0 and "time" not in got.fields
        exp = next(r for r in ref if r.stamp_ns == got.stamp_ns)
        assert np.allclose(got.T_world_lidar, exp.T_world_lidar, atol=1e-6)
        assert len(got) == len(exp) and np.allclose(got.points, exp.points, atol=1e-6)
        if "ring" in got.fields:
            assert int(got.fields["ring"].max()) < 16
    raw_out = tmp_path / "raw"
    raw_argv = [str(raw_out) if a == str(out) else a for a in argv] + ["--raw"]
    assert main(raw_argv) == 0
    raw_ref = {r.stamp_ns: r for r in simulate_drive("open_road", 4, 3, lidar=lid)}
    for got in open_source(raw_out):
        exp = raw_ref[got.stamp_ns]
        assert np.allclose(got.points, exp.points, atol=1e-6) and np.allclose(got.fields["time"], exp.fields["time"])
    assert main(["--frames", "0", "--out", str(tmp_path / "x"), "--quiet"]) == 1
    assert "deepbbs-sim: error: frames must be >= 1" in capsys.readouterr().err
    assert main(["--beams", "65", "--out", str(tmp_path / "y"), "--quiet"]) == 1
    assert "--beams must be in [1, 64]" in capsys.readouterr().err


def test_moving_cars_keep_out_of_the_ego_vehicle():
    """A drive in a lane the moving cars use (the other way) never has its sensor inside one: a car whose body would
    overlap the ego vehicle is left out; one alongside in the next lane, or ahead, is not."""
    from deepbbs_ros.sim.scene import EGO_HALF_SIZE, World

    world = World("suburban", 4, 400.0, day=1)
    row = world.movers[(world.movers[:, 0] > 100) & (world.movers[:, 0] < 300)][0]
    s0, off, length = float(row[0]), float(row[1]), float(row[4])
    xy = world.route.lateral(s0, off)
    _, h, _ = world.route.sample(s0)
    ahead, left = np.array([np.cos(h), np.sin(h)]), np.array([-np.sin(h), np.cos(h)])
    faces = len(world.moving_mesh(0.0, xy, 200.0)[1])
    assert faces > 0
    assert len(world.moving_mesh(0.0, xy, 200.0, ego_xy=xy)[1]) == faces - 24  # that car's body and cab gone
    inside = xy + (length / 2 + EGO_HALF_SIZE[0] - 0.2) * ahead  # the ego's tail over its nose
    assert len(world.moving_mesh(0.0, xy, 200.0, ego_xy=inside)[1]) == faces - 24
    for ego in (xy + 3.5 * left, xy + (length / 2 + EGO_HALF_SIZE[0] + 0.5) * ahead):  # the next lane; just ahead of it
        assert len(world.moving_mesh(0.0, xy, 200.0, ego_xy=ego)[1]) == faces


def test_second_drive_through_the_same_world():
    """Another lane, the opposite direction, another day: the same static world, the same road, other cars."""
    lid = small_lidar(range_noise=0.0, dropout=0.0)
    first = DriveSimulator("suburban", 4, lid, frames=40, motion_distortion=False)
    again = DriveSimulator("suburban", 4, lid, frames=40, motion_distortion=False, world_frames=40)
    assert np.array_equal(first.scan_at(7).points, again.scan_at(7).points)  # defaults: the same drive
    back = DriveSimulator("suburban", 4, lid, frames=30, world_frames=40, reverse=True, day=1,
                          motion_distortion=False)
    shifted = DriveSimulator("suburban", 4, lid, frames=5, world_frames=40, lane_offset=1.75)
    route = first.world.route
    for sim in (back, shifted):  # roads, buildings, trees: identical (parked cars may differ)
        assert np.array_equal(sim.world.route.xy, route.xy)
        assert np.array_equal(sim.world.terrain.tile(0, 0)[0], first.world.terrain.tile(0, 0)[0])
    # the reversed drive starts where the first one ended, in the mirrored lane, facing back
    P0, P1 = first.pose_at(39), back.pose_at(0)
    assert np.linalg.norm(P0[:2, 3] - P1[:2, 3]) < 2 * abs(first.world.style.ego_offset) + 1.5
    assert P0[:2, 0] @ P1[:2, 0] < -0.95
    d = back.pose_at(29)[:3, 3] - P1[:3, 3]
    assert d[:2] @ P1[:2, 0] > 5.0  # it moves forward, i.e. back along the route
    _, i = route._tree.query(P1[:2, 3])
    _, h, _ = route.sample(route.s[::2][i])
    left = np.array([-np.sin(h), np.cos(h)])
    assert (P1[:2, 3] - route.xy[::2][i]) @ left == pytest.approx(-first.world.style.ego_offset, abs=0.3)
    # the lane offset moves the car sideways by the offset's difference
    assert np.linalg.norm(shifted.pose_at(0)[:2, 3] - first.pose_at(0)[:2, 3]) == pytest.approx(3.5, abs=0.05)
    # reversed scans lie on the static surfaces at their ground-truth pose
    scan = back.scan_at(10)
    T = scan.T_world_lidar
    w = scan.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    caster, _ = back._static_caster(10 * back.period)
    dvec = (w - T[:3, 3]) / np.linalg.norm(w - T[:3, 3], axis=1, keepdims=True)
    dist, face, _ = caster.cast(w - 0.3 * dvec, dvec, 10.0)
    assert np.mean((face >= 0) & (np.abs(dist - 0.3) < 2e-3)) > 0.9
    # another day: some parked cars gone, other traffic; every other mesh unchanged
    day0 = first.world
    from deepbbs_ros.sim.scene import World

    day1 = World("suburban", 4, len(route.s) * route.DS, day=1)
    day1b = World("suburban", 4, len(route.s) * route.DS, day=1)
    assert not np.array_equal(day1.movers, day0.movers) and np.array_equal(day1.movers, day1b.movers)
    n0 = sum(len(c[1]) for c in day0.chunks)
    n1 = sum(len(c[1]) for c in day1.chunks)
    assert n1 < n0  # cars gone today (each is 24 faces)
    assert (n0 - n1) % 24 == 0
    with pytest.raises(SimulationError):
        DriveSimulator("urban", 1, lid, frames=5, world_frames=0)


def test_frames_apart_are_spaced_by_ground_truth():
    sim = DriveSimulator("urban", 7, LidarConfig.vlp16(), frames=60)
    picks = sim.frames_apart(2.0, 5, start=3)
    assert len(picks) == 5 and picks[0] == 3 and picks == sorted(picks)
    pos = np.array([sim.pose_at(k)[:3, 3] for k in range(60)])
    for a, b in zip(picks, picks[1:]):
        assert np.linalg.norm(pos[b] - pos[a]) >= 2.0  # far enough from the last pick ...
        assert np.all(np.linalg.norm(pos[a + 1:b] - pos[a], axis=1) < 2.0)  # ... and the first frame that is
    assert sim.frames_apart(1e6, 5) == [0]
