"""The live node localizing itself in a prior map (``node.target_mode: localization``), over real DDS.

A map is built from a simulated drive (HDL-32E-like scans at their ground-truth poses, every 5th frame, voxelised)
and written as a PCD with its trajectory beside it, as ``deepbbs-bag map`` writes one. Held-out scans (frames not
in the map) are sent with no initial pose: the node finds, tracks, loses a kidnapped sensor within 2 scans and
finds it again, with the shipped weights (the global search needs them).
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from test_node import Harness, _check_pose  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.core.checkpoint import default_weights_path  # noqa: E402
from deepbbs_ros.errors import NodeError  # noqa: E402
from msg_adapters.pointcloud2 import arrays_to_pointcloud2  # noqa: E402
from msg_adapters.transforms import pose_stamped_to_matrix  # noqa: E402

ros = test_node.ros  # the module fixture: rclpy context

LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
FRAMES = 150  # ~130 m of urban road
MAP_EVERY = 5  # map scans: every 5th frame; the others are held out
KIDNAP_YAW = np.radians(115.0)


@pytest.fixture(scope="module")
def drive():
    """(sim, map points (N, 3) float32 world frame, keyframe poses (K, 4, 4), scan(k, yaw=0) -> (points, T_world))."""
    from deepbbs_ros.core.localization import voxel_downsample
    from deepbbs_ros.sim.lidar import LidarConfig
    from deepbbs_ros.sim.simulator import DriveSimulator

    sim = DriveSimulator("urban", 5, LidarConfig.hdl32(), frames=FRAMES, motion_distortion=False)
    keys = list(range(0, FRAMES, MAP_EVERY))
    parts = []
    for k in keys:
        P = sim.pose_at(k)
        parts.append(sim.scan_at(k).points @ P[:3, :3].T + P[:3, 3])
    points = voxel_downsample(np.concatenate(parts), 0.2)

    @functools.cache
    def points_at(k: int) -> np.ndarray:  # made once: a simulated scan takes most of a 10 Hz period to make
        return sim.scan_at(k).points

    def scan(k: int, yaw: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Frame k's scan, the sensor turned by ``yaw`` about its z axis (a kidnap), and its true pose."""
        J = np.eye(4)
        J[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        pts = points_at(k)
        return ((pts - J[:3, 3]) @ J[:3, :3]).astype(np.float32), sim.pose_at(k) @ J

    return sim, points, np.stack([sim.pose_at(k) for k in keys]), scan


def _config(**extra) -> Config:
    return Config().replace(**{"registration.network_process": "off", "node.target_mode": "localization",
                               "node.diagnostics_period": 0.3, "node.warmup": False, **extra})


def _registration(cfg: Config):
    if not default_weights_path().is_file():
        pytest.skip("shipped weights missing")
    from deepbbs_ros.core.registration import DeepBBSRegistration

    return DeepBBSRegistration(cfg)


def _write_map(path, points: np.ndarray, poses: np.ndarray) -> None:
    from deepbbs_ros.datasets.maps import write_map

    write_map(path, points, poses, np.arange(len(poses), dtype=np.int64) * 500_000_000)


def test_finds_tracks_loses_and_finds_again(ros, drive, tmp_path, capfd):
    """Map file, no initial pose: a held-out scan is placed within 1 deg / 0.3 m and the next ones tracked; the
    sensor teleported ~80 m along the drive and turned 115 deg: nothing is published for it, lost within 2 scans
    (one log line, /diagnostics 'lost'), then found again (one line) with the right pose; ~/relocalize makes the
    next scan search the whole map."""
    sim, points, poses, scan = drive
    _write_map(tmp_path / "map.pcd", points, poses)
    cfg = _config(**{"localization.map_path": str(tmp_path / "map.pcd")})
    h = Harness(cfg, "loc_node", registration=_registration(cfg))
    try:
        assert [i.topic for i in h.node.inputs] == ["/source_cloud"]  # the map is the file's: no map topic
        frames = [(12, 0.0), (13, 0.0), (14, 0.0), (96, KIDNAP_YAW), (97, KIDNAP_YAW), (98, KIDNAP_YAW),
                  (99, KIDNAP_YAW)]
        published_before: list[int] = []
        states: list[str] = []
        for i, (k, yaw) in enumerate(frames):
            pts, _ = scan(k, yaw)
            published_before.append(len(h.poses))
            h.send("source_cloud", pts, sim.stamp_ns(k), "lidar")
            h.wait_processed(i + 1, timeout=90.0)
            assert h.wait_for(lambda: len(h.poses) >= h.node.outputs.published, 5.0)
            states.append(h.node.localization.state)
        time.sleep(0.2)
        stamps = [pose_stamped_to_matrix(m)[1] for m in h.poses]
        by_stamp = {pose_stamped_to_matrix(m)[1]: pose_stamped_to_matrix(m) for m in h.poses}
        # placed with no initial pose, then tracked; every published pose is right
        for k, yaw in frames:
            if sim.stamp_ns(k) in by_stamp:
                T, _, frame = by_stamp[sim.stamp_ns(k)]
                assert frame == "map"
                _check_pose(T, scan(k, yaw)[1])
        assert sim.stamp_ns(12) in stamps and sim.stamp_ns(14) in stamps
        # the kidnap: the first two scans after it are not published, and the tracker is lost after them
        assert sim.stamp_ns(96) not in stamps and sim.stamp_ns(97) not in stamps
        assert states[4] == "lost" or states[3] == "lost", states
        # found again at the new place
        assert sim.stamp_ns(99) in stamps, (states, h.node.localization.diagnostics())
        assert h.wait_for(lambda: h.diagnostics().get("localization.recoveries") == "1", 5.0), h.diagnostics()
        d = h.diagnostics()
        assert d["localization.state"] == "tracking" and int(d["localization.rejected"]) >= 2, d
        assert d["localization.time to first pose (s)"] != "-" and d["localization.map places"] != "0", d
        log = capfd.readouterr().err
        assert log.count("localization lost") == 1 and log.count("localization relocalized") == 1, log
        assert log.count("localization found") == 1, log
        # the kidnap is rejected cheaply (its GICP score far below the tracked ones: no retry, no local search)
        assert "no local search" in log, log
        # the scans were prepared on arrival (their input thread), the worker only registers them
        assert h.node.localization.prepared >= 3 and d["localization.scans prepared on arrival"] != "0", d
        # the map crop the tracking will use a second later is ready before a scan gets there: the crop tracked now
        # still reaches that pose, or the place nearest it was prepared in the background (or kept from the search)
        loc, m = h.node.localization, h.node.localization.localizer
        ahead = loc.tracker.predict(sim.stamp_ns(99) + 1_000_000_000)
        d = np.linalg.norm(m.places[:, :2, 3] - ahead[:2, 3], axis=1)
        reach = max(cfg.localization.place_spacing, 0.25 * m.crop_radius)
        ready = lambda: (m._track_place >= 0 and d[m._track_place] <= reach) or int(np.argmin(d)) in m._crops  # noqa: E731
        assert h.wait_for(ready, 10.0), (m._track_place, int(np.argmin(d)), list(m._crops))
        # ~/relocalize (deepbbs-ros relocalize, its own process): the pose is forgotten, the next scan is searched
        # in the whole map (found, not tracked)
        cmd = [sys.executable, "-m", "deepbbs_ros.cli.ros", "--timeout", "10", "relocalize", "/loc_node"]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=dict(os.environ))
        assert res.returncode == 0 and "/loc_node/relocalize: ok" in res.stdout, res.stdout + res.stderr
        n = len(frames)
        pts, T_true = scan(100, KIDNAP_YAW)
        h.send("source_cloud", pts, sim.stamp_ns(100), "lidar")
        h.wait_processed(n + 1, timeout=90.0)
        assert h.node.localization.last_event == "found", h.node.localization.diagnostics()
        assert h.wait_for(lambda: pose_stamped_to_matrix(h.poses[-1])[1] == sim.stamp_ns(100), 5.0)
        _check_pose(pose_stamped_to_matrix(h.poses[-1])[0], T_true)
        assert h.node.stats()["errors"] == {}, h.node.stats()
    finally:
        h.close()


def test_map_from_the_latched_topic(ros, drive):
    """No map file: the map published once (transient local) on the map topic; a held-out scan is placed."""
    sim, points, _, scan = drive
    name = "loc_topic"
    pub_node = rclpy.create_node(f"{name}_map")
    map_pub = pub_node.create_publisher(PointCloud2, "/loc_map/points", LATCHED)
    map_pub.publish(arrays_to_pointcloud2(points, stamp_ns=1, frame_id="world"))
    cfg = _config()
    h = Harness(cfg, name, registration=_registration(cfg),
                cli_args=["--ros-args", "-r", "target_cloud:=/loc_map/points"])
    try:
        assert h.wait_for(lambda: h.node.localization.has_map, 30.0), "map not received"
        pts, T_true = scan(42)
        h.send("source_cloud", pts, sim.stamp_ns(42), "lidar")
        h.wait_processed(1, timeout=90.0)
        assert h.wait_for(lambda: h.poses, 5.0), h.node.localization.diagnostics()
        T, stamp, frame = pose_stamped_to_matrix(h.poses[0])
        assert frame == "world" and stamp == sim.stamp_ns(42)
        _check_pose(T, T_true)
    finally:
        h.close()
        pub_node.destroy_node()


@pytest.mark.parametrize("content, match", [
    (None, r"localization.map_path: .*no such map file"),
    (b"# .PCD v0.7\nFIELDS x y z\nnonsense", r"localization.map_path: .*map\.pcd"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n", r"localization.map_path: .*"),
])
def test_bad_map_file_is_one_line(ros, tmp_path, content, match):
    """A missing or damaged map file stops the node before the model loads, with one line naming the parameter."""
    path = tmp_path / ("map.ply" if content and content.startswith(b"ply") else "map.pcd")
    if content is not None:
        path.write_bytes(content)
    cfg = _config(**{"localization.map_path": str(path)})
    from deepbbs_ros.node.registration_node import RegistrationNode

    with pytest.raises(NodeError, match=match) as err:
        RegistrationNode(cfg, registration=object(), node_name="loc_bad")
    assert "\n" not in str(err.value)


def test_cli_bad_map_file(tmp_path):
    """deepbbs-node with a missing map file: exit code 1 and one error line, no traceback."""
    res = test_node._run_cli("--ros-args", "-p", "node.target_mode:=localization",
                             "-p", f"localization.map_path:={tmp_path / 'nope.pcd'}")
    assert res.returncode != 0
    assert "Traceback" not in res.stderr, res.stderr
    errors = [line for line in res.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "localization.map_path" in errors[0] and "nope.pcd" in errors[0], res.stderr


def test_gicp_anchor_tracks_the_same_map(ros, drive):
    """The GICP anchor node, latched on the same map from the first scan's true pose (node.initial_pose), tracks
    the next scans from its last answer (GicpRegistration.register with T_init): the baseline of the node's
    tracking latency."""
    from scipy.spatial.transform import Rotation

    from deepbbs_ros.node.gicp_anchor import GicpRegistration

    sim, points, _, scan = drive
    name = "loc_anchor"
    pub_node = rclpy.create_node(f"{name}_map")
    map_pub = pub_node.create_publisher(PointCloud2, "/loc_anchor_map/points", LATCHED)
    map_pub.publish(arrays_to_pointcloud2(points, stamp_ns=1, frame_id="map"))
    start = sim.pose_at(30)
    rpy = Rotation.from_matrix(start[:3, :3]).as_euler("ZYX")[::-1]
    cfg = Config().replace(**{"node.target_mode": "latched", "node.initial_pose": [*map(float, start[:3, 3]),
                                                                                    *map(float, rpy)]})
    h = Harness(cfg, name, registration=GicpRegistration(cfg),
                cli_args=["--ros-args", "-r", "target_cloud:=/loc_anchor_map/points"])
    try:
        assert h.wait_for(lambda: h.node._map_target.map is not None, 30.0), "map not received"
        for i, k in enumerate((31, 32, 33)):
            h.send("source_cloud", scan(k)[0], sim.stamp_ns(k), "lidar")
            h.wait_processed(i + 1, timeout=60.0)
        assert h.wait_for(lambda: len(h.poses) == 3, 5.0), h.node.stats()
        for k, msg in zip((31, 32, 33), h.poses):
            T, stamp, frame = pose_stamped_to_matrix(msg)
            assert frame == "map" and stamp == sim.stamp_ns(k)
            _check_pose(T, sim.pose_at(k))
    finally:
        h.close()
        pub_node.destroy_node()


def test_map_file_ply_and_pcd_read_alike(tmp_path):
    """load_map_file: a PLY (binary, as point cloud tools write one) and a PCD of the same points give the same map,
    in node.map_frame; the trajectory beside the PCD comes along."""
    import trimesh

    from deepbbs_ros.node.map_data import load_map_file

    rng = np.random.default_rng(0)
    pts = rng.uniform(-50, 50, (500, 3)).astype(np.float32)
    poses = np.stack([np.eye(4)] * 3)
    poses[:, 0, 3] = [0.0, 4.0, 8.0]
    _write_map(tmp_path / "m.pcd", pts, poses)
    trimesh.PointCloud(pts).export(tmp_path / "other.ply")
    pcd, ply = load_map_file(tmp_path / "m.pcd", "map"), load_map_file(tmp_path / "other.ply", "world")
    np.testing.assert_allclose(pcd.points, pts, atol=1e-6)
    np.testing.assert_allclose(ply.points, pts, atol=1e-6)
    assert (pcd.frame_id, ply.frame_id) == ("map", "world") and ply.trajectory is None
    np.testing.assert_allclose(pcd.trajectory, poses, atol=1e-6)


def test_prefetch_prepares_the_crop_tracking_reaches_next(drive):
    """MapLocalizer.prefetch (the node's background thread): nothing while the crop tracked now still reaches the
    pose; past it, the crop of the place nearest the pose, which the next tracked scan there then finds kept."""
    from deepbbs_ros.core.localization import MapLocalizer

    sim, points, poses, scan = drive
    cfg = _config()
    m = MapLocalizer(points, cfg, registration=_registration(cfg), trajectory=poses)
    res = m.localize(scan(100)[0], sim.pose_at(100))
    assert res.valid and m._track_place >= 0
    assert m.prefetch(sim.pose_at(101)) == -1  # a metre on: the same crop serves
    far = sim.pose_at(130)  # ~35 m on: beyond the tracked crop's reach
    place = m.prefetch(far)
    assert place >= 0 and place in m._crops and m.prefetch(far) == -1  # prepared once, kept
    res = m.localize(scan(130)[0], far)
    assert res.valid and res.place == place and res.timings_ms["crop"] < 50.0, res.timings_ms
    _check_pose(res.T_map_scan, sim.pose_at(130))
