"""The node's published covariances over real DDS: in odometry mode and in localization mode every ``~/odometry``
pose covariance (and odometry's twist covariance) is finite, symmetric, positive definite and small on a
well-constrained synthetic scene: never the 1e6 placeholder of a covariance that was not computed."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402
import test_node_localization as tnl  # noqa: E402
from test_node import SEC, Harness, at, scan, tiny_config, tiny_registration  # noqa: E402

from deepbbs_ros.core.covariance import is_covariance  # noqa: E402
from msg_adapters.transforms import odometry_covariances  # noqa: E402

ros = test_node.ros  # the module fixture: rclpy context
world = test_node.world  # the structured street
drive = tnl.drive  # a simulated urban drive, its map and held-out scans

MAX_VARIANCE = 1.0  # m^2 / rad^2: far above an honest covariance here, far below a placeholder


def _check(cov: np.ndarray, what: str) -> None:
    assert is_covariance(cov, MAX_VARIANCE), (what, np.diag(cov))


def test_odometry_mode_covariances_are_computed(ros, world):
    """Odometry mode (the local map): from the second scan on, the pose covariance (accumulated) and the twist
    covariance are real ones, and the pose covariance grows along the drive."""
    cfg = tiny_config(**{"node.mode": "odometry", "node.publish_odometry": True})
    h = Harness(cfg, "cov_odom", registration=tiny_registration(cfg))
    try:
        for k in range(4):
            h.send("cloud", scan(world, at(0.8 * k, 0.04 * k, np.deg2rad(1.2 * k)), seed=60 + k), (400 + k) * SEC // 10)
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: len(h.odoms) == 4), h.node.stats()
        traces = []
        for k, msg in enumerate(h.odoms[1:], start=1):
            pose_cov, twist_cov = odometry_covariances(msg)
            _check(pose_cov, f"pose {k}")
            _check(twist_cov, f"twist {k}")
            traces.append(float(np.trace(pose_cov)))
        assert traces == sorted(traces), traces
    finally:
        h.close()


def test_localization_mode_covariances_are_computed(ros, drive, tmp_path):
    """Localization mode: a held-out scan found in the map, the next one tracked; each ~/odometry carries the
    localization's covariance (tracking and search alike), not 1e6 on the diagonal."""
    sim, points, poses, scan_k = drive
    tnl._write_map(tmp_path / "map.pcd", points, poses)
    cfg = tnl._config(**{"localization.map_path": str(tmp_path / "map.pcd"), "node.publish_odometry": True})
    h = Harness(cfg, "cov_loc", registration=tnl._registration(cfg))
    try:
        for i, k in enumerate((20, 21)):
            h.send("source_cloud", scan_k(k)[0], sim.stamp_ns(k), "lidar")
            h.wait_processed(i + 1, timeout=90.0)
        assert h.wait_for(lambda: len(h.odoms) == 2, 10.0), (h.node.stats(), h.node.localization.diagnostics())
        for msg in h.odoms:
            _check(odometry_covariances(msg)[0], "localization pose")
    finally:
        h.close()
