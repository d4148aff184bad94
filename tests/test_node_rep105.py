"""REP-105 in localization mode, over real DDS: the node's TF tree beside a robot's odometry, poses of the base,
/initialpose and the odometry sources ``node.localization_odom``.

A map is built from a simulated drive (as tests/test_node_localization.py builds one); the sensor is mounted on the
base off its origin (``base_link -> lidar`` on /tf_static). In "tf" mode another process
(tests/rep105_odometry_source.py) publishes that mounting and a drifting ``odom -> base_link`` on /tf; the test
collects /tf and /tf_static from every publisher and checks one parent per frame and that the node's map -> odom
composed with the other process's odom -> base_link is the true base pose.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("tf2_msgs")

import test_node  # noqa: E402
import test_node_localization  # noqa: E402
from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from test_node import Harness, _check_pose  # noqa: E402
from test_node_localization import _config, _registration, _write_map  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from msg_adapters.transforms import (  # noqa: E402
    matrix_to_pose,
    matrix_to_transform_stamped,
    pose_stamped_to_matrix,
    pose_to_matrix,
    stamp_to_ns,
    transform_stamped_to_matrix,
)

ros = test_node.ros  # the module fixture: rclpy context
drive = test_node_localization.drive  # the module fixture: the simulated drive and its map

STATIC = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
FRAMES = (12, 13, 14)
TOLERANCE_NS = 1_000_000_000  # node.transform_tolerance (default 1.0 s): map -> odom is stamped this after its scan


def _mount() -> np.ndarray:
    """T_base_lidar: the sensor 0.9 m ahead, 0.1 m left, 1.3 m up, turned 4 deg about z."""
    yaw = np.radians(4.0)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:3, 3] = [0.9, 0.1, 1.3]
    return T


class TfTree:
    """Every /tf and /tf_static message seen (all publishers): (parent, child, stamp ns, T, static)."""

    def __init__(self, node) -> None:
        self.items: list[tuple[str, str, int, np.ndarray, bool]] = []
        # the odometry stand-in floods /tf at 40 Hz: a deep queue, so that a loaded machine's slow executor drops none
        node.create_subscription(TFMessage, "/tf", lambda m: self._add(m, False), 5000)
        node.create_subscription(TFMessage, "/tf_static", lambda m: self._add(m, True), STATIC)

    def _add(self, msg, static: bool) -> None:
        for ts in msg.transforms:
            T, stamp, parent, child = transform_stamped_to_matrix(ts)
            self.items.append((parent, child, stamp, T, static))

    def parents(self) -> dict[str, set[str]]:
        out: dict[str, set[str]] = {}
        for parent, child, *_ in list(self.items):
            out.setdefault(child, set()).add(parent)
        return out

    def edge(self, parent: str, child: str) -> dict[int, np.ndarray]:
        return {s: T for p, c, s, T, _ in list(self.items) if p == parent and c == child}


def _harness(cfg, name: str, drive_data, tmp_path):
    sim, points, poses, scan = drive_data
    _write_map(tmp_path / "map.pcd", points, poses)
    cfg = cfg.replace(**{"localization.map_path": str(tmp_path / "map.pcd")})
    h = Harness(cfg, name, registration=_registration(cfg))
    h.tf = TfTree(h.client)
    h.pwc: list[PoseWithCovarianceStamped] = []
    qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    h.client.create_subscription(PoseWithCovarianceStamped, f"/{name}/pose_with_covariance", h.pwc.append, qos)
    h.initialpose = h.client.create_publisher(PoseWithCovarianceStamped, "/initialpose", 10)
    return h


def _send(h, sim, scan, frames, start: int = 0) -> None:
    for i, k in enumerate(frames):
        pts, _ = scan(k)
        h.send("source_cloud", pts, sim.stamp_ns(k), "lidar")
        h.wait_processed(start + i + 1, timeout=90.0)
    assert h.wait_for(lambda: len(h.poses) >= h.node.outputs.published, 5.0)


def _one_parent(h) -> dict[str, set[str]]:
    parents = h.tf.parents()
    assert all(len(p) == 1 for p in parents.values()), parents
    return parents


def test_map_to_odom_beside_a_drifting_odometry(ros, drive, tmp_path):
    """"tf" (the default): another process publishes base_link -> lidar (/tf_static) and a drifting odom ->
    base_link (/tf). The node publishes map -> odom only: one parent per frame, the sensor and base_link never a
    child of the node's transforms; map -> odom (stamped its scan's stamp + transform_tolerance) composed with
    odom -> base_link at the scan's stamp is the true base pose; ~/pose, ~/pose_with_covariance are base poses."""
    sim, points, poses, scan = drive
    T_bl = _mount()
    stamps = np.array([sim.stamp_ns(k) for k in range(10, 18)], dtype=np.int64)
    truth = {sim.stamp_ns(k): sim.pose_at(k) @ np.linalg.inv(T_bl) for k in range(10, 18)}  # T_map_base
    np.savez(tmp_path / "poses.npz", stamps=stamps, T_map_base=np.stack([truth[s] for s in stamps]),
             T_base_sensor=T_bl, sensor_frame="lidar")
    script = Path(__file__).with_name("rep105_odometry_source.py")
    path = os.pathsep.join([str(Path(__file__).parents[1]), os.environ.get("PYTHONPATH", "")])
    env = dict(os.environ, PYTHONPATH=path)
    log = tmp_path / "odometry_source.log"
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, str(script), "--poses", str(tmp_path / "poses.npz"), "--seconds",
                                 "150"], stdout=subprocess.PIPE, stderr=err, text=True, env=env)
    h = None
    try:
        assert proc.stdout.readline().strip() == "ready", log.read_text()
        h = _harness(_config(), "rep105_tf", drive, tmp_path)
        # robot_state_publisher runs before the robot drives: its latched mounting reaches the node first
        assert h.wait_for(lambda: h.node.static_tf.lookup("base_link", "lidar") is not None, 20.0)
        assert h.wait_for(lambda: h.node.static_tf.has_edge("odom", "base_link"), 20.0)
        # /tf is volatile and the stand-in replays its stamps in a loop: wait until the node heard every scan's (a real
        # odometry's stamps only go forward; on a loaded machine the first scans could otherwise come before theirs)
        assert h.wait_for(lambda: all(h.node.static_tf.lookup("odom", "base_link", sim.stamp_ns(k)) is not None
                                      for k in FRAMES), 20.0)
        _send(h, sim, scan, FRAMES)
        assert len(h.poses) == len(FRAMES), h.node.localization.diagnostics()
        # every scan's map -> odom (stamped its scan's stamp + the tolerance); the re-broadcasts between scans are
        # stamped with the clock, so counting the edge's transforms could be satisfied before the last scan's arrived
        assert h.wait_for(lambda: all(sim.stamp_ns(k) + TOLERANCE_NS in h.tf.edge("map", "odom") for k in FRAMES),
                          30.0), sorted(h.tf.edge("map", "odom"))
        parents = _one_parent(h)
        assert parents["odom"] == {"map"} and parents["base_link"] == {"odom"} and parents["lidar"] == {"base_link"}
        map_odom, odom_base = h.tf.edge("map", "odom"), h.tf.edge("odom", "base_link")
        for k in FRAMES:
            s = sim.stamp_ns(k)
            assert s + TOLERANCE_NS in map_odom, sorted(map_odom)  # post-dated as AMCL's
            _check_pose(map_odom[s + TOLERANCE_NS] @ odom_base[s], truth[s])
            # the pose topics: the base in the map frame
            T, stamp, frame = next(pose_stamped_to_matrix(m) for m in h.poses if pose_stamped_to_matrix(m)[1] == s)
            assert frame == "map"
            _check_pose(T, truth[s])
        assert h.odoms and all(m.child_frame_id == "base_link" for m in h.odoms)
        assert h.wait_for(lambda: h.pwc, 30.0)
        last = h.pwc[-1]
        assert last.header.frame_id == "map" and stamp_to_ns(last.header.stamp) == sim.stamp_ns(FRAMES[-1])
        _check_pose(pose_to_matrix(last.pose.pose), truth[sim.stamp_ns(FRAMES[-1])])
        cov = np.asarray(last.pose.covariance).reshape(6, 6)
        assert np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0) and np.allclose(cov, cov.T), np.diag(cov)
        # between scans the last map -> odom goes out again (node.map_odom_period)
        n = len(h.tf.edge("map", "odom"))
        assert h.wait_for(lambda: len(h.tf.edge("map", "odom")) > n, 30.0)
        d = h.diagnostics()
        assert d.get("localization.map -> odom") == "ok", d
    finally:
        if h is not None:
            h.close()
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def test_no_odometry_source_says_so_and_still_publishes_poses(ros, drive, tmp_path, capfd):
    """"tf" with nothing publishing odom -> base_link: no map -> odom, one warning, /diagnostics says so, the pose is
    published on the topics (the sensor mounting is identity: base_link = the cloud frame here, no /tf_static)."""
    sim, _, _, scan = drive
    h = _harness(_config(**{"node.base_frame": "", "node.tf_timeout": 0.2}), "rep105_noodom", drive, tmp_path)
    try:
        _send(h, sim, scan, FRAMES[:2])
        assert len(h.poses) == 2
        _check_pose(pose_stamped_to_matrix(h.poses[-1])[0], scan(FRAMES[1])[1])
        assert h.tf.edge("map", "odom") == {} and "lidar" not in h.tf.parents()
        assert h.wait_for(lambda: h.diagnostics().get("localization.map -> odom", "").startswith("no odom"), 5.0)
        log = capfd.readouterr().err
        assert log.count("no transform odom -> lidar on /tf") == 1, log  # rate-limited
    finally:
        h.close()


@pytest.mark.parametrize("source", ["lidar", "none"])
def test_own_lidar_odometry_or_map_to_base(ros, drive, tmp_path, source):
    """"lidar": the node's own LiDAR odometry publishes odom -> base_link at each scan's stamp and map -> odom
    composed with it is the true base pose; "none": map -> base_link directly, no odom frame. One parent each, with
    node.pair_tf set too (pair mode's map -> sensor frame does not apply here)."""
    sim, _, _, scan = drive
    T_bl = _mount()
    mount = rclpy.create_node(f"rep105_{source}_rsp")  # robot_state_publisher's part, before the node starts
    pub = mount.create_publisher(TFMessage, "/tf_static", STATIC)
    pub.publish(TFMessage(transforms=[matrix_to_transform_stamped(T_bl, 0, "base_link", "lidar")]))
    h = _harness(_config(**{"node.localization_odom": source, "node.base_frame": "base_link", "node.pair_tf": True}),
                 f"rep105_{source}", drive, tmp_path)
    try:
        assert h.wait_for(lambda: h.node.static_tf.lookup("base_link", "lidar") is not None, 20.0)
        _send(h, sim, scan, FRAMES)
        assert len(h.poses) == len(FRAMES), h.node.localization.diagnostics()
        time.sleep(0.3)
        parents = _one_parent(h)
        truth = {sim.stamp_ns(k): sim.pose_at(k) @ np.linalg.inv(T_bl) for k in FRAMES}
        if source == "none":
            assert parents["base_link"] == {"map"} and "odom" not in parents, parents
            map_base = h.tf.edge("map", "base_link")
            for s, T in truth.items():
                _check_pose(map_base[s], T)
        else:
            assert parents["odom"] == {"map"} and parents["base_link"] == {"odom"}, parents
            map_odom, odom_base = h.tf.edge("map", "odom"), h.tf.edge("odom", "base_link")
            for s, T in truth.items():
                _check_pose(map_odom[s + TOLERANCE_NS] @ odom_base[s], T)
            # odom starts at the base's first pose: odom -> base_link is the identity at the first scan
            _check_pose(odom_base[sim.stamp_ns(FRAMES[0])], np.eye(4), 0.01, 0.01)
        assert parents["lidar"] == {"base_link"}
    finally:
        h.close()
        mount.destroy_node()


def test_initialpose_is_a_hint(ros, drive, tmp_path, capfd):
    """/initialpose near the truth: the scan is found near it (the places around it searched first); a hint far
    off (frame 120's pose): the search near it rejects, the whole map finds the right pose all the same."""
    sim, _, _, scan = drive
    h = _harness(_config(**{"node.base_frame": ""}), "rep105_hint", drive, tmp_path)
    try:
        def hint(T: np.ndarray) -> None:
            msg = PoseWithCovarianceStamped()
            msg.header.frame_id = "map"
            msg.pose.pose = matrix_to_pose(T)
            cov = np.zeros((6, 6))
            cov[0, 0] = cov[1, 1] = 0.25  # RViz's 2D Pose Estimate
            cov[5, 5] = 0.0685
            msg.pose.covariance = cov.reshape(-1).tolist()
            n = h.node.rep105.hints
            h.initialpose.publish(msg)
            assert h.wait_for(lambda: h.node.rep105.hints > n, 5.0)

        near = sim.pose_at(40).copy()
        near[:3, 3] += [1.0, -0.5, -near[2, 3]]  # on the ground, 1.1 m off
        hint(near)
        _send(h, sim, scan, [40])
        _check_pose(pose_stamped_to_matrix(h.poses[-1])[0], scan(40)[1])
        log = capfd.readouterr().err
        assert "found near the initial pose" in log, log
        far = sim.pose_at(120).copy()
        hint(far)
        _send(h, sim, scan, [42], start=1)
        assert len(h.poses) == 2 and pose_stamped_to_matrix(h.poses[-1])[1] == sim.stamp_ns(42)
        _check_pose(pose_stamped_to_matrix(h.poses[-1])[0], scan(42)[1])
        log = capfd.readouterr().err
        assert "localization found: " in log and "found near" not in log, log
        assert h.node.stats()["errors"] == {}, h.node.stats()
    finally:
        h.close()
