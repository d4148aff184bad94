"""scripts/benchmarks/sweep_velocity.py: a solid-state sweep's own velocity (its late half registered to its early
half) against the simulator's truth, and none for a spinning sensor."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts" / "benchmarks"))

import sweep_velocity as sv  # noqa: E402

from deepbbs_ros.sim.patterns import driver_of  # noqa: E402
from deepbbs_ros.sim.rig import make_simulator  # noqa: E402


def test_a_swaying_mid360_sweep_measures_its_own_turn():
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.scans import prepare_scan

    config = Config()
    sim = make_simulator("hall", 39, "mid360", "legged", frames=8, compensate=False)
    scan = sim.scan_at(5)  # turning at 26 deg/s (measured 3.6 deg/s off)
    pre = prepare_scan(config, scan.points, scan.point_times(), scan.stamp_ns, driver=driver_of("mid360"))
    v = sv.sweep_velocity(config, pre)
    assert v is not None and not np.allclose(v[0], np.eye(4))
    t = scan.point_times()
    t0, h = 5 * sim.period, float(np.median(t))  # the simulator's clock
    a, b = np.median(t[t < h]), np.median(t[t >= h])
    truth = np.linalg.inv(sim.T_world_lidar(t0 + a)) @ sim.T_world_lidar(t0 + b)  # the sensor's turn between the halves
    rate = Rotation.from_matrix(v[0][:3, :3]).as_rotvec() / v[1]
    true_rate = Rotation.from_matrix(truth[:3, :3]).as_rotvec() / (b - a)
    assert np.degrees(np.linalg.norm(true_rate)) > 10.0  # the sway turns the sensor within the sweep
    assert np.linalg.norm(rate - true_rate) < 0.5 * np.linalg.norm(true_rate)


def test_a_spinning_sweep_has_no_sweep_velocity():
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.scans import prepare_scan

    config = Config()
    sim = make_simulator("corridor", 39, "os1_32", "legged", frames=3, compensate=False)
    scan = sim.scan_at(1)
    pre = prepare_scan(config, scan.points, scan.point_times(), scan.stamp_ns, driver=driver_of("os1_32"))
    assert pre.times is not None and sv.sweep_velocity(config, pre) is None
