"""The node in a robot's ROS graph, over real DDS: REP-105 TF (the base's motion from the static base <- sensor
transform on /tf_static, read back from /tf), a latched map as the target, an input that never pairs,
the odometry restarted by a backward time jump, and the ``deepbbs-ros`` tool (param get/set, reset).

Same toy world and tiny network as test_node.py (the node is what is tested, not the weights).
"""

from __future__ import annotations

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
from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from test_node import SEC, Harness, _check_pose, at, scan, tiny_config  # noqa: E402

from deepbbs_ros.node.tf_static import StaticTransforms, base_motion  # noqa: E402
from deepbbs_ros.replay.synthetic import pose  # noqa: E402
from msg_adapters.pointcloud2 import arrays_to_pointcloud2  # noqa: E402
from msg_adapters.transforms import (  # noqa: E402
    matrix_to_transform_stamped,
    pose_stamped_to_matrix,
    transform_stamped_to_matrix,
)

ros, world = test_node.ros, test_node.world  # the module fixtures: rclpy context, the toy street

LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _rot(roll: float, pitch: float, yaw: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    return T


def test_static_transforms_compose_chains():
    st = StaticTransforms()
    A, B, C = pose(1.0, 2.0, 0.0, 0.3), pose(0.2, 0.0, 1.5, -0.1) @ _rot(0.05, 0.0, 0.0), pose(0.5, 0.0, 0.0, -1.0)
    st.add("base_link", "chassis", A)
    st.add("chassis", "lidar", B)
    st.add("base_link", "imu", C)
    np.testing.assert_allclose(st.lookup("base_link", "lidar"), A @ B, atol=1e-12)
    np.testing.assert_allclose(st.lookup("imu", "lidar"), np.linalg.inv(C) @ A @ B, atol=1e-12)
    np.testing.assert_allclose(st.lookup("lidar", "base_link"), np.linalg.inv(A @ B), atol=1e-12)
    assert st.lookup("base_link", "camera") is None and st.wait("base_link", "camera", 0.05) is None
    # the base's motion is the sensor's seen from the base: a pure yaw of the robot about its own origin
    T_bs = pose(1.2, 0.0, 1.8, 0.0)
    yaw = pose(0.0, 0.0, 0.0, 0.2)
    np.testing.assert_allclose(base_motion(T_bs, np.linalg.inv(T_bs) @ yaw @ T_bs), yaw, atol=1e-12)


@pytest.mark.parametrize("invert", [False, True])
def test_tf_odom_to_base_from_tf_static(ros, world, invert):
    """A static base_link -> lidar transform published on /tf_static (transient local, before the node starts,
    as robot_state_publisher does); the node in odometry mode on a short drive; /tf read back over DDS: odom ->
    base_link is the base's motion T_base_lidar @ T_odom_lidar @ inv(T_base_lidar) (the inverse with
    node.invert_tf), and ~/pose carries the same."""
    from tf2_msgs.msg import TFMessage  # built by `make venv` (deepbbs-ros build-interfaces)

    # the lidar mounted turned 90 deg (its x to the base's left), 1.2 m ahead: the base's motion and the
    # sensor's differ by far more than the tolerances below
    T_base_lidar = pose(1.2, 0.1, 1.4, np.deg2rad(90.0)) @ _rot(np.deg2rad(1.0), np.deg2rad(-2.0), 0.0)
    name = f"reg_tf_{int(invert)}"
    static = rclpy.create_node(f"{name}_static")
    static_pub = static.create_publisher(TFMessage, "/tf_static", LATCHED)
    static_pub.publish(TFMessage(transforms=[matrix_to_transform_stamped(T_base_lidar, 0, "base_link", "lidar")]))
    cfg = tiny_config(**{"node.mode": "odometry", "node.invert_tf": invert, "node.tf_timeout": 10.0})
    assert cfg.node.publish_tf and cfg.node.publish_odometry and cfg.node.base_frame == "base_link"  # defaults
    h = Harness(cfg, name)
    tf: list = []
    h.client.create_subscription(TFMessage, "/tf", lambda m: tf.extend(m.transforms), 50)
    try:
        # the sensor's poses in the world: the base drives forward and turns, the lidar rides on it
        T_w_base = [at(0.8 * k, 0.05 * k, np.deg2rad(1.5 * k)) for k in range(4)]
        T_w = [T @ T_base_lidar for T in T_w_base]
        stamps = [(500 + k) * SEC // 10 for k in range(4)]
        for k, T in enumerate(T_w):
            h.send("cloud", scan(world, T, seed=60 + k), stamps[k])
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: len(tf) >= 4 and len(h.poses) >= 4 and len(h.odoms) >= 4), h.node.stats()
        from deepbbs_ros.metrics import pair_errors

        sensor_motion = np.linalg.inv(T_w[0]) @ T_w[3]
        assert pair_errors(sensor_motion, np.linalg.inv(T_w_base[0]) @ T_w_base[3])[1] > 3 * 0.9  # discriminates
        for k in range(4):
            want = np.linalg.inv(T_w_base[0]) @ T_w_base[k]  # odom = the base at the first scan
            T_tf, stamp, frame, child = transform_stamped_to_matrix(tf[k])
            assert stamp == stamps[k]
            if invert:
                assert (frame, child) == ("base_link", "odom")
                T_tf = np.linalg.inv(T_tf)
            else:
                assert (frame, child) == ("odom", "base_link")
            _check_pose(T_tf, want, rot_deg=1.0 * max(k, 1), trans_m=0.3 * max(k, 1))
            T_pose, _, pose_frame = pose_stamped_to_matrix(h.poses[k])
            assert pose_frame == "odom" and h.transforms[k].child_frame_id == "base_link"
            np.testing.assert_allclose(T_pose, T_tf, atol=1e-6)
        # the lidar's own odometry, conjugated: what the node computes is exactly the base motion of it
        T_lidar = np.linalg.inv(T_base_lidar) @ pose_stamped_to_matrix(h.poses[3])[0] @ T_base_lidar
        _check_pose(T_lidar, np.linalg.inv(T_w[0]) @ T_w[3], rot_deg=3.0, trans_m=0.9)
        assert h.node.stats()["errors"] == {}
    finally:
        h.close()
        static.destroy_node()


@pytest.mark.parametrize("process", ["off", "on"])
def test_latched_map_target(ros, world, process):
    """node.target_mode: latched: a map (the whole toy street, larger than a scan) published once with transient
    local durability before the node starts; later scans (stamps unrelated to the map's) are each registered
    against the map cropped around the last answer, and answered in the map frame (their world pose). The same
    with the registration in a process of its own (node.registration_process: on: the crop is a scan kept
    there)."""
    name = f"reg_map_{process}"
    pub_node = rclpy.create_node(f"{name}_map")
    map_pub = pub_node.create_publisher(PointCloud2, "/map/points", LATCHED)
    map_pub.publish(arrays_to_pointcloud2(world.astype(np.float32), stamp_ns=SEC, frame_id="map"))
    start = at(2.0, 0.3, np.deg2rad(1.0))
    from scipy.spatial.transform import Rotation

    rpy = Rotation.from_matrix(start[:3, :3]).as_euler("ZYX")[::-1]
    cfg = tiny_config(**{"node.target_mode": "latched", "node.map_crop_radius": 40.0,
                         "node.initial_pose": [*map(float, start[:3, 3]), *map(float, rpy)],
                         "node.registration_process": process})  # fmt: skip
    proc = None
    if process == "on":  # the node's own proxy needs a checkpoint file (the shipped one; the stages stay TINY's)
        from deepbbs_ros.core.checkpoint import default_weights_path
        from deepbbs_ros.node.parameters import node_registration_config
        from deepbbs_ros.node.registration_process import RegistrationProcess

        proc = RegistrationProcess(node_registration_config(cfg), default_weights_path())
    h = Harness(cfg, name, registration=proc, cli_args=["--ros-args", "-r", "target_cloud:=/map/points"])
    try:
        assert h.wait_for(lambda: h.node._map_target.map is not None, 15.0), "latched map not received"
        T_w = [at(2.0 + 0.9 * k, 0.3 + 0.05 * k, np.deg2rad(1.0 + 1.5 * k)) for k in range(4)]
        for k, T in enumerate(T_w):
            h.send("source_cloud", scan(world, T, seed=80 + k), (900 + k) * SEC)
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: len(h.poses) == 4), h.node.stats()
        for k, msg in enumerate(h.poses):
            T, stamp, frame = pose_stamped_to_matrix(msg)
            assert frame == "map" and stamp == (900 + k) * SEC
            _check_pose(T, T_w[k])
        assert h.node.stats()["errors"] == {}
        if proc is not None:  # answered there: the process is alive and keeps the crop and the scans
            assert h.node.reg is proc and proc.alive and proc.kept() >= 1, proc.state
    finally:
        h.close()
        pub_node.destroy_node()
        if proc is not None:
            proc.close()


def test_unpaired_input_is_reported(ros, world):
    """Stamped pairs whose stamps lie 10 s apart (far beyond the slop) never pair: the node says so in the log
    and on /diagnostics within a few seconds, naming the stamp gap, instead of queueing silently."""
    cfg = tiny_config(**{"node.unpaired_warn_after": 1.0, "node.diagnostics_period": 0.5})
    h = Harness(cfg, "reg_unpaired")
    try:
        xyz = scan(world, at(), seed=1)
        t0 = time.monotonic()
        k = 0
        while time.monotonic() - t0 < 6.0 and "warnings.unpaired_input" not in h.diagnostics():
            h.send("source_cloud", xyz, (100 + k) * SEC)
            h.send("target_cloud", xyz, (90 + k) * SEC)
            k += 1
            time.sleep(0.25)
        assert "warnings.unpaired_input" in h.diagnostics(), h.diagnostics()
        assert h.diags[-1].status[0].level == DiagnosticStatus.WARN
        assert h.node.stats()["pairs"] == 0 and not h.poses
    finally:
        h.close()


def test_a_stamp_gap_seen_once_before_a_pair_is_not_reported(ros):
    """A check that finds the inputs one scan apart before the first pair (scan k waits on one input's thread while
    the other has it) stays silent; the same gap at the next check with still no pair is reported."""
    cfg = tiny_config(**{"node.unpaired_warn_after": 1.0, "node.diagnostics_period": 60.0})
    h = Harness(cfg, "reg_gap_once")
    try:
        node = h.node
        now = time.monotonic()
        with node._lock:
            node._arrivals = {0: (now, 100 * SEC), 1: (now, 101 * SEC)}
            node._last_pair_t = now - 5.0
        node._check_unpaired()
        assert node.stats()["warnings"].get("unpaired_input", 0) == 0
        node._check_unpaired()
        assert node.stats()["warnings"].get("unpaired_input", 0) == 1
        with node._lock:
            node._last_pair_t = time.monotonic() - 2.0  # a pair since: the next gap is a first sighting again
        node._check_unpaired()
        assert node.stats()["warnings"].get("unpaired_input", 0) == 1
    finally:
        h.close()


def test_time_jump_restarts_odometry(ros, world):
    """A backward time jump in odometry mode (the bag played again) restarts the odometry at identity, once,
    instead of rejecting every later scan."""
    cfg = tiny_config(**{"node.mode": "odometry", "node.base_frame": ""})
    h = Harness(cfg, "reg_jump")
    try:
        T_w = [at(0.8 * k, 0.0, 0.0) for k in range(3)]
        for rnd in range(2):  # the same drive, played twice with the same stamps
            for k, T in enumerate(T_w):
                h.send("cloud", scan(world, T, seed=90 + k), (40 + 6 * k) * SEC // 10)  # 0.6 s apart: 1.2 s back
                h.wait_processed(3 * rnd + k + 1)
        assert h.wait_for(lambda: len(h.poses) == 6), h.node.stats()
        for k in range(3):
            T1, T2 = pose_stamped_to_matrix(h.poses[k])[0], pose_stamped_to_matrix(h.poses[3 + k])[0]
            _check_pose(T2, np.linalg.inv(T_w[0]) @ T_w[k], rot_deg=1.0 * max(k, 1), trans_m=0.3 * max(k, 1))
            _check_pose(T2, T1, rot_deg=0.5, trans_m=0.1)
        np.testing.assert_allclose(pose_stamped_to_matrix(h.poses[3])[0], np.eye(4), atol=1e-9)
        s = h.node.stats()
        assert s["time_jumps"] == 1 and s["rejected"] == 0 and s["errors"] == {}
    finally:
        h.close()


def _ros_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "deepbbs_ros.cli.ros", "--timeout", "10", *args],
                          capture_output=True, text=True, timeout=60, env=dict(os.environ))


def test_deepbbs_ros_param_and_reset(ros, world):
    """`deepbbs-ros` (its own process, real rclpy) against a running node: param get, param set (a settable ROS
    parameter; the node's own ones answer why not), ~/reset."""
    h = Harness(tiny_config(**{"node.mode": "odometry", "node.base_frame": ""}), "reg_cli")
    try:
        h.send("cloud", scan(world, at(), seed=3), 7 * SEC)
        h.wait_processed(1)
        res = _ros_cli("param", "get", "/reg_cli", "node.mode")
        assert res.returncode == 0 and res.stdout.strip() == "odometry", res.stderr
        res = _ros_cli("param", "set", "/reg_cli", "use_sim_time", "true")
        assert res.returncode == 0, res.stderr
        assert h.node.get_parameter("use_sim_time").value is True
        assert _ros_cli("param", "get", "reg_cli", "use_sim_time").stdout.strip() == "true"
        res = _ros_cli("param", "set", "/reg_cli", "node.slop", "0.2")
        assert res.returncode == 1 and "restart the node" in res.stderr and "Traceback" not in res.stderr
        res = _ros_cli("param", "get", "/reg_cli", "node.mod")  # a misspelt name: the node's -p did-you-mean
        assert res.returncode == 1 and "did you mean node.mode?" in res.stderr and "Traceback" not in res.stderr
        res = _ros_cli("param", "get", "/reg_cli", "base_frame")  # a flat (KISS-ICP style) name
        assert res.returncode == 1 and "did you mean node.base_frame?" in res.stderr, res.stderr
        res = _ros_cli("param", "get", "/reg_cli", "train.lr")  # a config key the node does not declare
        assert res.returncode == 1 and "a config key this node does not declare" in res.stderr, res.stderr
        res = _ros_cli("param", "list", "/reg_cli")
        assert res.returncode == 0 and "node.target_mode" in res.stdout.split()
        res = _ros_cli("reset", "/reg_cli")
        assert res.returncode == 0 and "ok" in res.stdout, res.stderr
        h.send("cloud", scan(world, at(0.8), seed=4), 8 * SEC)
        assert h.wait_for(lambda: len(h.poses) == 2)
        np.testing.assert_allclose(pose_stamped_to_matrix(h.poses[1])[0], np.eye(4), atol=1e-9)  # restarted
        res = _ros_cli("reset", "/no_such_node")
        assert res.returncode == 1 and "not available" in res.stderr
        # topic echo: a summary line per message, the rate / latency line at the end
        cmd = [sys.executable, "-m", "deepbbs_ros.cli.ros", "--timeout", "20", "topic", "echo", "/reg_cli/pose",
               "--count", "1", "--duration", "40"]  # fmt: skip
        echo = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ))
        try:
            assert h.wait_for(lambda: h.node.count_subscribers("/reg_cli/pose") >= 2, 30)  # the harness + the tool
            h.send("cloud", scan(world, at(1.6), seed=5), 9 * SEC)
            out, err = echo.communicate(timeout=60)
        finally:
            echo.kill()
        assert echo.returncode == 0, err
        assert out.splitlines()[0].startswith("PoseStamped 9.000 odom xyz [") and "yaw" in out, out
        # the pose's stamp is the scan's, 9 s after the epoch: not wall-clock time, so no latency figure
        assert "/reg_cli/pose: 1 messages" in err and "behind the wall clock" in err and "p50" not in err, err
    finally:
        h.close()


def test_deepbbs_ros_dds_profile():
    res = _ros_cli("dds-profile")
    assert res.returncode == 0 and res.stdout.strip().endswith("fastdds_shm.xml")
    assert os.path.isfile(res.stdout.strip())


@pytest.mark.parametrize("mode", ["odometry", "pair"])
def test_warmup_with_the_shipped_model(ros, world, mode):
    """The node with its own registration (the shipped weights) runs every stage once before it reports ready
    (decode, preprocessing, GICP, the network process, the odometry / pair path) and forgets it: the first real
    scan is the odometry's origin."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.node.registration_node import RegistrationNode

    cfg = Config().replace(**{"node.mode": mode, "node.base_frame": "", "registration.device": "cpu"})
    node = RegistrationNode(cfg, node_name=f"reg_warm_{mode}")
    try:
        assert node.warmed_up and node.startup_s > 0
        if mode == "odometry":
            assert node.odometry.odometry.frames == 0 and node.odometry.consulted == 0  # reset after the warm-up
        state = node.reg.network_process_state
        assert state.startswith("running") or state == "off", state  # started during the warm-up where it is used
        assert node.stats()["processed"] == 0 and node.stats()["errors"] == {}
    finally:
        node.destroy_node()
