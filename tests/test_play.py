"""deepbbs-play publishes a recording over real DDS; played into the live node, poses match ground truth."""

from __future__ import annotations

import os
import signal
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
from deepbbs_ros.replay.synthetic import synthetic_drive  # noqa: E402
from msg_adapters.pointcloud2 import pointcloud2_to_xyz  # noqa: E402
from msg_adapters.transforms import pose_stamped_to_matrix, stamp_to_ns  # noqa: E402

SEC = 1_000_000_000
REPO = Path(__file__).resolve().parents[1]


def _drive(n: int) -> list[Scan]:
    return synthetic_drive(n, seed=7, keep=0.5)  # ~20k points per scan with intensity, 10 Hz, ground truth


def _bag(tmp_path: Path, n: int) -> tuple[list[Scan], Path]:
    """``n`` scans of the drive and the mcap bag they are written to."""
    scans = _drive(n)
    bag = tmp_path / "drive.mcap"
    write_scans(scans, bag, "mcap")
    return scans, bag


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
    scans, bag = _bag(tmp_path, 6)
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


def test_play_wait_that_expires_is_an_error(tmp_path):
    """--wait S with no subscriber by then plays nothing and exits 1 with one line naming the topics; never
    'published N frames' to nobody."""
    scans, bag = _bag(tmp_path, 2)
    res = subprocess.run(
        [sys.executable, "-m", "deepbbs_ros.cli.play", str(bag), "--cloud-topic", "/nobody/points",
         "--previous-topic", "/nobody/previous", "--wait", "1", "--quiet", "--local"],
        capture_output=True, text=True, timeout=120,
    )
    assert res.returncode == 1, res.stderr
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("deepbbs-play: error: no subscriber on "), res.stderr
    assert "/nobody/points" in lines[0] and "/nobody/previous" in lines[0] and "--wait 1 s" in lines[0]
    assert "published" not in res.stdout + res.stderr
    res = subprocess.run([sys.executable, "-m", "deepbbs_ros.cli.play", str(bag), "--cloud-topic", "/a",
                          "--previous-topic", "/a"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 1 and "--previous-topic must name a topic other than" in res.stderr, res.stderr


def test_play_previous_topic_restamps_the_scan_before(ros, tmp_path):
    """--previous-topic: scan k on the cloud topic and scan k-1 (its points and frame) with scan k's stamp on
    the previous topic, so that the node's two pair inputs pair by stamp."""
    scans, bag = _bag(tmp_path, 4)
    node = rclpy.create_node("play_previous_listener")
    clouds, previous = [], []
    node.create_subscription(PointCloud2, "/pp/points", clouds.append, 20)
    node.create_subscription(PointCloud2, "/pp/previous", previous.append, 20)
    proc = subprocess.Popen(
        [sys.executable, "-m", "deepbbs_ros.cli.play", str(bag), "--cloud-topic", "/pp/points",
         "--previous-topic", "/pp/previous", "--rate", "2.0", "--wait", "30", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        _spin_until(node, lambda: proc.poll() is not None, 90)
        _spin_until(node, lambda: len(previous) == len(scans) - 1, 5)
    finally:
        proc.kill() if proc.poll() is None else None
        node.destroy_node()
    out, err = proc.communicate()
    assert proc.returncode == 0, err
    assert [stamp_to_ns(c.header.stamp) for c in clouds] == [s.stamp_ns for s in scans]
    assert [stamp_to_ns(c.header.stamp) for c in previous] == [s.stamp_ns for s in scans[1:]]
    for c, s in zip(previous, scans[:-1]):
        assert c.header.frame_id == s.frame_id
        np.testing.assert_allclose(pointcloud2_to_xyz(c), s.points, atol=1e-6)


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 0), (signal.SIGINT, 130)])
def test_play_stops_cleanly_on_sigterm_and_sigint(ros, tmp_path, sig, code):
    """SIGTERM (launch, systemd, kill) ends the playback between two messages with exit code 0; Ctrl-C with
    130; never an RCLError traceback from a publish() on a context the signal shut down."""
    scans, bag = _bag(tmp_path, 3)
    node = rclpy.create_node("play_stop_listener")
    clouds = []
    node.create_subscription(PointCloud2, "/stopped/points", clouds.append, 20)
    proc = subprocess.Popen(
        [sys.executable, "-m", "deepbbs_ros.cli.play", str(bag), "--cloud-topic", "/stopped/points", "--loop",
         "--rate", "0.5", "--clock-hz", "500", "--wait", "10", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert _spin_until(node, lambda: len(clouds) >= 2 or proc.poll() is not None, 60) and proc.poll() is None
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill() if proc.poll() is None else None
        node.destroy_node()
    assert proc.returncode == code, err
    assert "Traceback" not in err and "RCLError" not in err, err


def _shipped_weights() -> Path | None:
    try:
        from deepbbs_ros.core.checkpoint import default_weights_path
    except ImportError:
        return None
    p = Path(default_weights_path())
    return p if p.is_file() else None


SAMPLE_BAG = REPO / "bags" / "urban_drive_hdl64"
E2E_FRAMES = 10
needs_weights = pytest.mark.skipif(
    _shipped_weights() is None or not SAMPLE_BAG.is_dir(),
    reason="shipped weights deepbbs_ros/models/deepbbspp_lidar.pt or bags/urban_drive_hdl64 missing",
)


@pytest.fixture(scope="module")
def e2e(ros):
    """The first E2E_FRAMES scans of bags/urban_drive_hdl64 played by deepbbs-play into deepbbs-node
    (odometry mode, shipped weights, one torch thread); returns (scans by stamp, [(stamp, T_odom)], steps)
    where steps are (s0, s1, inv(T_odom_s0) @ T_odom_s1) of consecutive published poses (a dropped scan
    just lengthens a step: the odometry sees a stamp gap)."""
    from deepbbs_ros.datasets import open_source

    scans = [s for _, s in zip(range(E2E_FRAMES), open_source(SAMPLE_BAG))]
    assert all(s.T_world_lidar is not None for s in scans)
    listener = rclpy.create_node("e2e_listener")
    poses: list[PoseStamped] = []
    sub = listener.create_subscription(PoseStamped, "/deepbbs_registration/pose", poses.append, 50)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    node = subprocess.Popen(
        [sys.executable, "-m", "deepbbs_ros.node.registration_node", "--ros-args", "-p", "node.mode:=odometry",
         "-p", "registration.device:=cpu", "-p", "registration.threads:=1", "-r", "cloud:=/e2e/points"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        # the first pose (the odometry origin) is published ~1 s after the first scan: make sure the
        # listener has discovered the node's publisher before anything is played, else a slow discovery
        # (busy CPU) loses it and the origin check below fails for the test's sake, not the node's
        assert _spin_until(listener, lambda: sub.get_publisher_count() > 0, 60), "node's ~/pose never appeared"
        _spin_until(listener, lambda: False, 0.5)  # let the node's side of the match settle too
        # 1 s per scan: the worker (~0.7 s per pair on one thread) mostly keeps up; drops are harmless
        play = subprocess.run(
            [sys.executable, "-m", "deepbbs_ros.cli.play", str(SAMPLE_BAG), "--cloud-topic", "/e2e/points",
             "--rate", "0.1", "--wait", "60", "--quiet", "--frames", str(len(scans)), "--no-gt"],
            capture_output=True, text=True, timeout=240, env=env,
        )
        assert play.returncode == 0, play.stderr
        last = scans[-1].stamp_ns
        _spin_until(listener, lambda: any(stamp_to_ns(p.header.stamp) == last for p in poses), 30)
    finally:
        node.terminate()
        _, err = node.communicate(timeout=30)
        listener.destroy_node()
    got = [(stamp, T) for T, stamp, _ in map(pose_stamped_to_matrix, poses)]
    assert len(got) >= E2E_FRAMES // 2, f"only {len(got)} poses for {len(scans)} scans\n{err[-3000:]}"
    steps = [(s0, s1, np.linalg.inv(P0) @ P1) for (s0, P0), (s1, P1) in zip(got, got[1:])]
    return {s.stamp_ns: s for s in scans}, got, steps


@needs_weights
def test_node_equals_offline_odometry(e2e):
    """Every pose the live node published is exactly what replay's odometry (DeepBBSOdometry, the pipeline
    of ``deepbbs-replay --mode odometry --method deepbbs++``) computes offline on the scans the node
    processed, in order (same config, same weights, one torch thread; the bag's per-point ``time`` field
    deskews both): the node adds no error of its own."""
    import torch

    from deepbbs_ros.config import Config
    from deepbbs_ros.core.odometry import DeepBBSOdometry
    from deepbbs_ros.core.registration import DeepBBSRegistration

    scans, got, _ = e2e
    stamps = [s for s, _ in got]
    assert stamps == sorted(set(stamps)) and set(stamps) <= set(scans)  # source stamps, in order, no repeat
    assert np.allclose(got[0][1], np.eye(4))  # the first scan processed is the odometry origin
    threads = torch.get_num_threads()
    try:
        cfg = Config().replace(**{"registration.device": "cpu", "registration.threads": 1})
        odo = DeepBBSOdometry(cfg, registration=DeepBBSRegistration(cfg, weights=""))
        for stamp, T in got:
            scan = scans[stamp]
            offline = odo.register_frame(scan.points, scan.fields.get("time"), scan.stamp_ns).T_first_k
            np.testing.assert_allclose(T, offline, rtol=0, atol=1e-6, err_msg=f"scan at {stamp}")
    finally:
        torch.set_num_threads(threads)


@needs_weights
def test_bag_played_into_node_rotation_matches_ground_truth(e2e):
    """Urban sample bag (scans ~0.9 m, < 1 deg apart): every published step's rotation within 1 deg."""
    scans, _, steps = e2e
    for s0, s1, step in steps:
        gt = np.linalg.inv(scans[s0].T_world_lidar) @ scans[s1].T_world_lidar
        rot, trans = pair_errors(step, gt)
        assert rot <= 1.0, (s0, s1, rot, trans)


@needs_weights
def test_bag_played_into_node_translation_matches_ground_truth(e2e):
    """The issue's goal: every published step within 0.3 m of ground truth (success threshold): met by the
    local-map odometry since its first motion takes the GICP-precise DeepBBS++ result."""
    scans, _, steps = e2e
    errors = []
    for s0, s1, step in steps:
        gt = np.linalg.inv(scans[s0].T_world_lidar) @ scans[s1].T_world_lidar
        errors.append(pair_errors(step, gt)[1])
    assert max(errors) <= 0.3, "translation errors (m): " + ", ".join(f"{e:.3f}" for e in errors)


PAIR_FRAMES = 8


@needs_weights
def test_bag_played_with_previous_topic_into_pair_mode_matches_ground_truth(ros):
    """The README's pair example fed from a recording: deepbbs-play --previous-topic into deepbbs-node in pair
    mode (-r source_cloud:=... -r target_cloud:=...); every published pose is T_target_source = the motion from
    scan k-1 to scan k, within 1 deg and 0.3 m of ground truth, and the inputs pair (no stamp gap reported)."""
    from deepbbs_ros.datasets import open_source

    scans = {s.stamp_ns: s for _, s in zip(range(PAIR_FRAMES), open_source(SAMPLE_BAG))}
    order = sorted(scans)
    listener = rclpy.create_node("pair_e2e_listener")
    poses: list[PoseStamped] = []
    sub = listener.create_subscription(PoseStamped, "/deepbbs_registration/pose", poses.append, 50)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    node = subprocess.Popen(
        [sys.executable, "-m", "deepbbs_ros.node.registration_node", "--ros-args", "-p", "registration.device:=cpu",
         "-r", "source_cloud:=/pair_e2e/points", "-r", "target_cloud:=/pair_e2e/previous"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        assert _spin_until(listener, lambda: sub.get_publisher_count() > 0, 90), "node's ~/pose never appeared"
        play = subprocess.run(
            [sys.executable, "-m", "deepbbs_ros.cli.play", str(SAMPLE_BAG), "--cloud-topic", "/pair_e2e/points",
             "--previous-topic", "/pair_e2e/previous", "--rate", "0.1", "--wait", "90", "--quiet",
             "--frames", str(PAIR_FRAMES), "--no-gt"],
            capture_output=True, text=True, timeout=240, env=env,
        )
        assert play.returncode == 0, play.stderr
        _spin_until(listener, lambda: any(stamp_to_ns(p.header.stamp) == order[-1] for p in poses), 30)
    finally:
        node.send_signal(signal.SIGINT)
        try:
            out, err = node.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            node.kill()
            out, err = node.communicate()
        listener.destroy_node()
    log = out + err
    assert len(poses) >= (PAIR_FRAMES - 1) // 2, f"only {len(poses)} poses for {PAIR_FRAMES - 1} pairs\n{log[-3000:]}"
    # no stamp gap between the inputs (the friction: "stamps are +0.900 s from ..."); at this slow rate the first
    # scan, which has no previous one, may be reported as waiting alone for 3 s, and that is all
    assert "stamps are" not in log and "beyond node.slop" not in log, log[-3000:]
    # Ctrl-C: the node's own last line, then nothing (no rosout failure, no traceback), exit code 0
    assert node.returncode == 0 and "stopping: " in log, log[-3000:]
    assert "Failed to publish" not in log and "Traceback" not in log, log[-3000:]
    for p in poses:
        T, stamp, frame = pose_stamped_to_matrix(p)
        k = order.index(stamp)
        assert k >= 1, "the first scan has no previous scan: no pose"
        src, tgt = scans[stamp], scans[order[k - 1]]
        assert frame == tgt.frame_id
        gt = np.linalg.inv(tgt.T_world_lidar) @ src.T_world_lidar
        rot, trans = pair_errors(T, gt)
        assert rot <= 1.0 and trans <= 0.3, (k, rot, trans)
