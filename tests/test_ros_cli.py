"""``deepbbs-ros`` (its own process, real rclpy + DDS) against publishers and subscribers of this process:
latency only for wall-clock stamps, a clean stop on SIGINT / SIGTERM, ``topic echo`` waiting for a topic that
appears late, and ``static-tf`` (tf2_ros static_transform_publisher's flags) read back by a latched subscriber."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()
rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

from deepbbs_ros.cli.ros_topic import TopicStats  # noqa: E402
from msg_adapters.transforms import matrix_to_pose_stamped, transform_stamped_to_matrix  # noqa: E402

SEC = 1_000_000_000
RECORDED_NS = 1_600_000_000 * SEC  # the sample bags' first stamp
LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def _cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "deepbbs_ros.cli.ros", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ))


def _publish_until(pub, stamp_ns, proc: subprocess.Popen, timeout: float, period: float = 0.1) -> None:
    """Publish a PoseStamped every ``period`` s (stamp from ``stamp_ns()``) until ``proc`` ends or ``timeout``."""
    deadline = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        pub.publish(matrix_to_pose_stamped(np.eye(4), stamp_ns(), "odom"))
        time.sleep(period)


def test_topic_stats_latency_only_for_wall_clock_stamps():
    now = time.time_ns()
    live, recorded = TopicStats(), TopicStats()
    for k in range(5):
        live.add(now + k * SEC // 10, now + k * SEC // 10 - 30_000_000)  # 30 ms old
        recorded.add(now + k * SEC // 10, RECORDED_NS + k * SEC // 10)
    assert "latency p50 30.0 ms" in live.line("/a") and "wall clock" not in live.line("/a")
    line = recorded.line("/b")
    assert "latency" not in line.replace("no latency figure", "") and "ms" not in line, line
    offset = (now - RECORDED_NS) * 1e-9
    assert f"stamps {offset:.1f} s behind the wall clock" in line or f"{offset - 0.1:.1f} s behind" in line, line
    assert recorded.clock_offset_s == pytest.approx(offset, abs=0.1) and live.clock_offset_s is None


def test_topic_hz_says_recorded_stamps_are_not_wall_clock(ros):
    node = rclpy.create_node("rc_recorded_pub")
    pub_rec = node.create_publisher(PoseStamped, "/rc/recorded", 10)
    pub_live = node.create_publisher(PoseStamped, "/rc/live", 10)
    try:
        rec = _cli("topic", "hz", "/rc/recorded", "--count", "5", "--duration", "60")
        _publish_until(pub_rec, lambda: RECORDED_NS, rec, 90)
        out, err = rec.communicate(timeout=30)
        assert rec.returncode == 0, err
        last = out.strip().splitlines()[-1]
        assert "behind the wall clock" in last and "no latency figure" in last and "p50" not in last, out
        live = _cli("topic", "hz", "/rc/live", "--count", "5", "--duration", "60")
        _publish_until(pub_live, time.time_ns, live, 90)
        out, err = live.communicate(timeout=30)
        assert live.returncode == 0, err
        assert "latency p50" in out.strip().splitlines()[-1] and "wall clock" not in out, out
    finally:
        node.destroy_node()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_topic_echo_stops_cleanly_on_a_signal(ros, sig):
    """SIGINT / SIGTERM from a script: exit code 0, the summary line, no traceback."""
    node = rclpy.create_node(f"rc_sig_pub_{sig.name.lower()}")
    pub = node.create_publisher(PoseStamped, "/rc/sig", 10)
    try:
        echo = _cli("topic", "echo", "/rc/sig")
        publishing = threading.Thread(target=_publish_until, args=(pub, time.time_ns, echo, 90), daemon=True)
        publishing.start()
        first = echo.stdout.readline()  # the first message printed (or "" if the tool ended)
        assert first.startswith("PoseStamped "), (first, echo.poll())
        echo.send_signal(sig)
        out, err = echo.communicate(timeout=30)
        publishing.join(timeout=10)
    finally:
        echo.kill() if echo.poll() is None else None
        node.destroy_node()
    assert echo.returncode == 0, err
    assert "Traceback" not in err and "Exception" not in err, err
    assert "/rc/sig: " in err and " messages" in err, err  # the summary at the end


def test_topic_echo_waits_for_a_topic_that_appears_late(ros):
    """A node takes seconds to start: echo started first waits for the topic (saying so), longer than the old
    5 s, and prints the message once a publisher appears."""
    echo = _cli("topic", "echo", "/rc/late", "--count", "1")
    node = None
    try:
        time.sleep(7.0)
        assert echo.poll() is None, echo.communicate()
        node = rclpy.create_node("rc_late_pub")
        pub = node.create_publisher(PoseStamped, "/rc/late", 10)
        _publish_until(pub, time.time_ns, echo, 60)
        out, err = echo.communicate(timeout=30)
    finally:
        echo.kill() if echo.poll() is None else None
        if node is not None:
            node.destroy_node()
    assert echo.returncode == 0, err
    assert "waiting up to 30 s for topic /rc/late to appear" in err, err
    assert out.startswith("PoseStamped "), out


def test_topic_echo_gives_up_with_one_line():
    res = subprocess.run([sys.executable, "-m", "deepbbs_ros.cli.ros", "--timeout", "2", "topic", "echo",
                          "/rc/never"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 1, res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith("deepbbs-ros: error: topic /rc/never not found within 2 s")


def _static_tf_received(node, timeout: float = 30.0) -> list:
    from tf2_msgs.msg import TFMessage

    got = []
    node.create_subscription(TFMessage, "/tf_static", lambda m: got.extend(m.transforms), LATCHED)
    deadline = time.monotonic() + timeout
    while not got and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    return got


@pytest.mark.parametrize("rotation, sig", [
    (["--roll", "0.1", "--pitch", "-0.2", "--yaw", "0.5"], signal.SIGTERM),
    (["--qx", "0.0", "--qy", "0.0", "--qz", "0.24740396", "--qw", "0.96891242"], signal.SIGINT),  # yaw 0.5 rad
])
def test_static_tf_is_latched_on_tf_static(ros, rotation, sig):
    """``deepbbs-ros static-tf`` with static_transform_publisher's flags: a subscriber that joins after the
    publication (transient local) gets T_parent_child; a signal stops it with exit code 0."""
    pytest.importorskip("tf2_msgs")
    from scipy.spatial.transform import Rotation

    proc = _cli("static-tf", "--x", "1.5", "--y", "-0.25", "--z", "1.8", *rotation,
                "--frame-id", "base_link", "--child-frame-id", "velodyne")
    node = rclpy.create_node(f"rc_tf_listener_{sig.name.lower()}")
    try:
        line = proc.stdout.readline()  # published before this line: the subscriber below joins late
        assert line.startswith("/tf_static: base_link -> velodyne"), (line, proc.stderr.read() if proc.poll() else "")
        got = _static_tf_received(node)
        assert len(got) == 1
        T, _, parent, child = transform_stamped_to_matrix(got[0])
        assert (parent, child) == ("base_link", "velodyne")
        expected = np.eye(4)
        expected[:3, 3] = [1.5, -0.25, 1.8]
        if rotation[0] == "--roll":  # tf2's setRPY: fixed axes x, y, z
            expected[:3, :3] = Rotation.from_euler("xyz", [0.1, -0.2, 0.5]).as_matrix()
        else:
            expected[:3, :3] = Rotation.from_euler("z", 0.5).as_matrix()
        np.testing.assert_allclose(T, expected, atol=1e-6)
        assert proc.poll() is None  # still publishing until stopped
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill() if proc.poll() is None else None
        node.destroy_node()
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err


def test_static_tf_bad_flags_are_one_line():
    base = [sys.executable, "-m", "deepbbs_ros.cli.ros", "static-tf", "--frame-id", "base_link"]
    cases = [
        (["--child-frame-id", "velodyne", "--yaw", "1", "--qw", "1"], "not both"),
        (["--child-frame-id", "base_link"], "are the same frame"),
        (["--child-frame-id", "/velodyne"], "invalid frame id"),
        (["--child-frame-id", "velodyne", "--qx", "0", "--qy", "0", "--qz", "0", "--qw", "0"], "not a rotation"),
    ]
    for extra, text in cases:
        res = subprocess.run([*base, *extra], capture_output=True, text=True, timeout=60)
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 1 and len(lines) == 1 and lines[0].startswith("deepbbs-ros: error:"), res.stderr
        assert text in lines[0], (extra, lines)
