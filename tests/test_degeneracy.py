"""Degenerate places (core/degeneracy.py) and the odometry's hold along their weak direction (core/odometry.py)."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core import degeneracy as D
from deepbbs_ros.core.odometry import DeepBBSOdometry
from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

small_gicp = pytest.importorskip("small_gicp")
rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402

ros = test_node.ros  # the module fixture: rclpy context


def _corridor_scan(x: float, rng: np.random.Generator, n: int = 6000, width: float = 2.0,
                   reach: float = 20.0, end_wall: bool = False) -> np.ndarray:
    """A scan (sensor frame) of a straight featureless corridor (walls at y = +-width, floor 1 m below, ceiling
    1.5 m above, no end within ``reach``) from ``x`` on its axis: ``n`` points spread over its surfaces within
    ``reach`` along it, a new draw each scan. ``x`` does not show: the corridor looks the same everywhere."""
    u = rng.uniform(-reach, reach, n)
    side = rng.integers(0, 4, n)
    across = rng.uniform(-1.0, 1.0, n)
    y = np.where(side < 2, np.where(side == 0, -width, width), across * width)
    z = np.where(side < 2, -1.0 + (across + 1.0) * 1.25, np.where(side == 2, -1.0, 1.5))
    pts = np.c_[u, y, z]
    if end_wall:  # the corridor's closed end, 4 m behind the start
        pts = np.concatenate([pts, np.c_[np.full(n, -4.0 - x), rng.uniform(-width, width, n),
                                         rng.uniform(-1.0, 1.5, n)]])
    return pts + rng.normal(0.0, 0.01, pts.shape)


def _hessian(points: np.ndarray) -> np.ndarray:
    """small_gicp's Hessian of ``points`` on a local map of themselves (at the truth), as the odometry's VGICP."""
    src, _ = small_gicp.preprocess_points(points, downsampling_resolution=0.25)
    vmap = small_gicp.GaussianVoxelMap(0.5)
    vmap.insert(src, np.eye(4))
    return np.asarray(small_gicp.align(vmap, src, np.eye(4), max_iterations=1).H)


def test_corridor_plane_and_room_are_told_apart():
    rng = np.random.default_rng(0)
    R = np.eye(4)[:3, :3]
    corridor = D.analyse(_hessian(_corridor_scan(0.0, rng, n=20000)), R, 0.005)
    assert corridor.axes == ("x",) and corridor.label.startswith("corridor-like, weak axis x")
    assert abs(corridor.weak[0] @ [1, 0, 0]) > 0.99
    g = rng.uniform(-15, 15, (4000, 2))
    plane = np.c_[g, rng.normal(0, 0.01, len(g))]  # an open field: only the ground
    field = D.analyse(_hessian(plane), R, 0.005)
    assert sorted(field.axes) == ["x", "y"] and field.label.startswith("open-field-like")
    room = np.concatenate([_corridor_scan(0.0, rng), np.c_[np.full(500, 6.0), rng.uniform(-2, 2, (500, 2))]])
    assert D.analyse(_hessian(room), R, 0.005).label == ""  # an end wall: every direction constrained


def test_hold_keeps_the_start_along_weak_directions_beyond_the_limit():
    start, pose = np.eye(4), np.eye(4)
    pose[:3, 3] = [2.0, 0.3, 0.05]
    weak = np.array([[1.0, 0.0, 0.0]])
    assert np.allclose(D.hold(pose, start, weak)[:3, 3], [0.0, 0.3, 0.05])
    assert np.allclose(D.hold(pose, start, weak, limit=2.5)[:3, 3], [2.0, 0.3, 0.05])  # within the gate: kept
    assert np.allclose(D.hold(pose, start, np.zeros((0, 3))), pose)


def test_gate_adapts_to_the_observed_deviation():
    gate = D.MotionGate(4.0, 20, floor=0.05)
    assert gate.limit() == float("inf")
    for d in (0.1, 0.1, 0.1):
        gate.update(d)
    assert gate.limit() == pytest.approx(0.4)
    assert D.MotionGate(4.0, 20, floor=0.5, min_steps=1).limit() == float("inf")
    quiet = D.MotionGate(4.0, 20, floor=0.05, min_steps=1)
    quiet.update(0.001)
    assert quiet.limit() == 0.05
    assert D.MotionGate(0.0, 20, floor=0.05).limit() == float("inf")  # off


def _drive(degenerate_ratio: float, gate_sigmas: float, frames: int = 30, speed: float = 0.2):
    cfg = Config()
    cfg.preprocess.min_range, cfg.preprocess.max_range = 0.5, 25.0
    oc = cfg.odometry
    oc.deepbbs_init, oc.threads, oc.voxel_size = "never", 1, 0.5
    oc.degenerate_ratio, oc.gate_sigmas = degenerate_ratio, gate_sigmas
    odo, rng = DeepBBSOdometry(cfg), np.random.default_rng(1)
    steps = [odo.register_frame(_corridor_scan(k * speed, rng, end_wall=k < 8), stamp_ns=k * 100_000_000)
             for k in range(frames)]
    return steps, speed * (frames - 1)


def test_corridor_drive_does_not_slide_with_the_hold():
    """Known truth: constant speed along a corridor whose closed end is seen for the first eight scans (the motion
    is measured), then nothing tells where along the axis the sensor is."""
    def run(ratio, sigmas):
        steps, truth = _drive(ratio, sigmas)
        return steps, abs(steps[-1].T_first_k[0, 3] - truth)

    steps_off, err_off = run(0.0, 0.0)
    steps_on, err_on = run(0.005, 4.0)
    print(f"along-axis error after the drive: {err_off:.2f} m without the hold, {err_on:.2f} m with it")
    assert all(s.degenerate.startswith("corridor-like, weak axis x") for s in steps_on[9:])
    assert not any(s.degenerate for s in steps_off[:1])
    assert err_on < 0.5 * err_off
    steps = [np.linalg.norm(s.T_prev_k[:3, 3]) for s in steps_on[3:]]
    assert max(steps) < 2 * 0.2  # no step jumps


def test_node_diagnostics_warn_in_a_degenerate_place(ros):
    """Odometry mode over real DDS: in the featureless corridor /diagnostics names the weak axis and warns."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from test_node import SEC, Harness, tiny_config

    cfg = tiny_config(**{"node.mode": "odometry", "node.diagnostics_period": 0.2, "odometry.deepbbs_init": "never",
                         "odometry.voxel_size": 0.5, "preprocess.min_range": 0.5, "preprocess.max_range": 25.0})
    h = Harness(cfg, "reg_degenerate")
    rng = np.random.default_rng(3)
    try:
        for k in range(4):
            h.send("cloud", _corridor_scan(0.2 * k, rng, n=20000).astype(np.float32), (300 + k) * SEC // 10)
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: h.diagnostics().get("degenerate", "no").startswith("corridor-like, weak axis x"))
        status = h.diags[-1].status[0]
        assert status.level == DiagnosticStatus.WARN and status.message.startswith("degenerate place: corridor-like")
        assert int(h.diagnostics()["odometry: scans in degenerate places"]) >= 1
    finally:
        h.close()
