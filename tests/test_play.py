"""deepbbs-play publishes a recording over real DDS; played into the live node, poses match ground truth."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()
rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402

from deepbbs_ros.datasets import Scan, write_scans  # noqa: E402
from deepbbs_ros.metrics import pair_errors  # noqa: E402
from deepbbs_ros.node.synthetic import SyntheticTown, pose  # noqa: E402
from msg_adapters.pointcloud2 import pointcloud2_to_xyz  # noqa: E402
from msg_adapters.transforms import pose_stamped_to_matrix, stamp_to_ns  # noqa: E402

SEC = 1_000_000_000
REPO = Path(__file__).resolve().parents[1]


def _drive(n: int, n_points: int = 20_000) -> list[Scan]:
    town = SyntheticTown(seed=7)
    scans = []
    for k in range(n):
        T = pose(1.0 * k, 0.1 * k, 0.0, np.deg2rad(1.0 * k))
        xyz = town.scan(T, n_points, seed=100 + k)
        scans.append(Scan(k, 1_700_000_000 * SEC + k * SEC // 10, xyz, T_world_lidar=T))
    return scans


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def _spin_until(node, cond, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not cond():
        rclpy.spin_once(node, timeout_sec=0.05)
    return cond()


def test_play_publishes_every_frame_with_clock(ros, tmp_path):
    scans = _drive(6)
    bag = tmp_path / "drive.mcap"
    write_scans(scans, bag, "mcap")
    node = rclpy.create_node("play_listener")
    clouds, clocks = [], []
    node.create_subscription(PointCloud2, "/played/points", clouds.append, 20)
    node.create_subscription(Clock, "/clock", lambda m: clocks.append(stamp_to_ns(m.clock)), 100)
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "deepbbs_ros.cli.play", str(bag), "--cloud-topic", "/played/points",
         "--rate", "2.0", "--wait", "10", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert _spin_until(node, lambda: len(clouds) == len(scans) or proc.poll() is not None, 60)
        _spin_until(node, lambda: proc.poll() is not None, 20)
    finally:
        proc.kill() if proc.poll() is None else None
        node.destroy_node()
    out, err = proc.communicate()
    assert proc.returncode == 0, err
    assert [stamp_to_ns(c.header.stamp) for c in clouds] == [s.stamp_ns for s in scans]
    for c, s in zip(clouds, scans):
        assert c.header.frame_id == s.frame_id
        np.testing.assert_allclose(pointcloud2_to_xyz(c), s.points, atol=1e-6)
    assert clocks and clocks == sorted(clocks) and scans[0].stamp_ns <= clocks[0] and clocks[-1] == scans[-1].stamp_ns
    assert time.monotonic() - t0 >= 0.5 / 2.0  # 0.5 s of recording at rate 2 takes >= 0.25 s


def test_play_errors_are_one_line(tmp_path):
    res = subprocess.run([sys.executable, "-m", "deepbbs_ros.cli.play", str(tmp_path / "missing.mcap")],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 1 and res.stderr.startswith("deepbbs-play: error:"), res.stderr
    res = subprocess.run([sys.executable, "-m", "deepbbs_ros.cli.play", str(tmp_path), "--rate", "0"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 1 and "--rate must be > 0" in res.stderr, res.stderr


def _shipped_weights() -> Path | None:
    try:
        from deepbbs_ros.core.checkpoint import default_weights_path
    except ImportError:
        return None
    p = Path(default_weights_path())
    return p if p.is_file() else None


@pytest.mark.skipif(_shipped_weights() is None, reason="shipped weights deepbbs_ros/models/deepbbspp_lidar.pt missing")
def test_bag_played_into_node_matches_ground_truth(ros, tmp_path):
    """Odometry mode with the shipped weights: each published relative pose within 1 deg / 0.3 m of truth."""
    sample = sorted((REPO / "bags").glob("*"))
    if sample:
        from deepbbs_ros.datasets import open_source

        src = open_source(sample[0])
        scans = [s for _, s in zip(range(12), src)]
        bag = sample[0]
    else:
        scans = _drive(10, 120_000)
        bag = tmp_path / "drive.mcap"
        write_scans(scans, bag, "mcap")
    assert all(s.T_world_lidar is not None for s in scans)
    listener = rclpy.create_node("e2e_listener")
    poses = []
    listener.create_subscription(PoseStamped, "/deepbbs_registration/pose", poses.append, 50)
    env = dict(os.environ)
    node = subprocess.Popen(
        [sys.executable, "-m", "deepbbs_ros.node.registration_node", "--ros-args", "-p", "node.mode:=odometry",
         "-p", "registration.device:=cpu", "-r", "cloud:=/e2e/points"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    play = None
    try:
        # slow enough that the worker keeps up on 2 shared cores: every scan is registered
        play = subprocess.run(
            [sys.executable, "-m", "deepbbs_ros.cli.play", str(bag), "--cloud-topic", "/e2e/points",
             "--rate", "0.2", "--wait", "30", "--quiet", "--frames", str(len(scans))],
            capture_output=True, text=True, timeout=240,
        )
        assert play.returncode == 0, play.stderr
        _spin_until(listener, lambda: len(poses) >= len(scans), 60)
    finally:
        node.terminate()
        out, err = node.communicate(timeout=30)
        listener.destroy_node()
    assert len(poses) >= 2, err
    by_stamp = {s.stamp_ns: s.T_world_lidar for s in scans}
    got = [(stamp, T) for T, stamp, _ in map(pose_stamped_to_matrix, poses)]
    for (s0, P0), (s1, P1) in zip(got, got[1:]):
        rot, trans = pair_errors(np.linalg.inv(P0) @ P1, np.linalg.inv(by_stamp[s0]) @ by_stamp[s1])
        assert rot <= 1.0 and trans <= 0.3, (s0, s1, rot, trans)
