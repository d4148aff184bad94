"""``deepbbs-ros map-server`` in its own process over real DDS: a subscriber that joins after the map was published
still gets it (reliable, transient local, depth 1), every point and the frame; a bad map is one line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from deepbbs_ros.datasets.maps import write_map
from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()
rclpy = pytest.importorskip("rclpy")

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402

from msg_adapters.pointcloud2 import pointcloud2_to_xyz  # noqa: E402

LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _server(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "deepbbs_ros.cli.ros", "map-server", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ))


@pytest.mark.parametrize("offset, voxel", [(0.0, None), (587_000.0, "0.5")])
def test_map_server_latches_the_map_for_a_late_subscriber(tmp_path, offset, voxel):
    rng = np.random.default_rng(3)
    pts = rng.uniform(-20, 20, (2000, 3)) + [offset, 0.0, 0.0]
    path = tmp_path / "site.pcd"
    write_map(path, pts)
    topic = f"/map_server_test/points_{int(offset)}"
    proc = _server(str(path), "--topic", topic, "--frame", "site", *(["--voxel", voxel] if voxel else []))
    rclpy.init()
    node = rclpy.create_node("map_server_listener")
    try:
        line = proc.stdout.readline()  # published before this line: the subscriber below joins late
        assert line.startswith(f"{topic}: {path}: 2000 points"), (line, proc.stderr.read() if proc.poll() else "")
        got = []
        node.create_subscription(PointCloud2, topic, got.append, LATCHED)
        deadline = time.monotonic() + 30
        while not got and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        assert len(got) == 1 and got[0].header.frame_id == "site"
        xyz = pointcloud2_to_xyz(got[0]).astype(np.float64)
        if voxel is None:
            np.testing.assert_allclose(xyz, pts, atol=1e-5)
        else:  # far from the origin: float64 coordinates keep the millimetres; every voxel's centroid
            assert "float64" in line and 0 < len(xyz) < 2000
            cells = {tuple(c) for c in np.floor((pts - pts.min(axis=0)) / 0.5).astype(int)}
            assert len(xyz) == len(cells)
            assert np.abs(xyz[:, 0] - offset).max() <= 20.0
        assert proc.poll() is None  # still serving until stopped
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill() if proc.poll() is None else None
        node.destroy_node()
        rclpy.try_shutdown()
    assert proc.returncode == 0 and "Traceback" not in err, err


@pytest.mark.parametrize("extra, text", [
    (["missing.pcd"], "no such map file"),
    (["map.xyz"], "a .pcd or .ply point cloud"),
    (["site.pcd", "--frame", "/map"], "invalid frame id"),
    (["site.pcd", "--topic", "bad topic"], "--topic 'bad topic'"),
])
def test_map_server_bad_input_is_one_line(tmp_path, extra, text):
    write_map(tmp_path / "site.pcd", np.random.default_rng(0).uniform(-5, 5, (200, 3)))
    argv = [str(tmp_path / extra[0]), *extra[1:]]
    res = subprocess.run([sys.executable, "-m", "deepbbs_ros.cli.ros", "map-server", *argv], capture_output=True,
                         text=True, timeout=60)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 1 and len(lines) == 1 and lines[0].startswith("deepbbs-ros: error:"), res.stderr
    assert text in lines[0], lines
