"""The base's pose covariance in localization mode (node/rep105.py): a covariance whose rotation turns about one point
moved to another (the sensor's estimate -> the base's pose), checked against sampled perturbations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("rclpy")

from deepbbs_ros.node.rep105 import base_pose_covariance, move_pivot  # noqa: E402


def _sampled(T_map_sensor, T_sensor_base, cov, pivot, n=40000, seed=0):
    """Covariance of the base's (position, rotation in map axes) when the sensor's pose is perturbed by
    ``delta ~ N(0, cov)``, the rotation turning about ``pivot`` (map frame)."""
    rng = np.random.default_rng(seed)
    d = rng.multivariate_normal(np.zeros(6), cov, size=n)
    T_b = T_map_sensor @ T_sensor_base
    dR = Rotation.from_rotvec(d[:, 3:])
    t = dR.apply(T_map_sensor[:3, 3] - pivot) + pivot + d[:, :3]  # the sensor's position, perturbed
    R = dR * Rotation.from_matrix(T_map_sensor[:3, :3])
    out = np.empty((n, 6))
    out[:, :3] = R.apply(T_sensor_base[:3, 3]) + t - T_b[:3, 3]
    out[:, 3:] = (R * Rotation.from_matrix(T_sensor_base[:3, :3]) * Rotation.from_matrix(T_b[:3, :3]).inv()).as_rotvec()
    return np.cov(out.T)


def test_moving_the_pivot_matches_sampled_perturbations():
    T_ms = np.eye(4)
    T_ms[:3, :3] = Rotation.from_euler("xyz", [0.02, -0.01, 2.1]).as_matrix()
    T_ms[:3, 3] = [120.0, -40.0, 1.7]
    T_sb = np.eye(4)
    T_sb[:3, :3] = Rotation.from_euler("z", -0.07).as_matrix()
    T_sb[:3, 3] = [-0.9, -0.1, -1.3]
    A = np.random.default_rng(1).normal(size=(6, 6))
    cov = A @ A.T * 1e-5 + np.diag([4e-4, 4e-4, 1e-4, 1e-5, 1e-5, 4e-5])
    T_mb = T_ms @ T_sb
    for pivot in (T_ms[:3, 3], np.zeros(3)):  # about the sensor (the localizer's), about the map origin (residuals')
        moved = move_pivot(cov, T_mb[:3, 3] - pivot)
        np.testing.assert_allclose(moved, _sampled(T_ms, T_sb, cov, pivot), atol=0.05 * np.abs(moved).max())


def test_the_localizers_covariance_is_used_when_given():
    class Result:
        covariance = np.diag([1e-4, 2e-4, 3e-4, 1e-6, 1e-6, 1e-5])

    T_ms, T_mb = np.eye(4), np.eye(4)
    T_mb[:3, 3] = [-1.0, 0.0, -1.5]
    cov = base_pose_covariance(Result(), None, None, None, T_ms, T_mb)
    np.testing.assert_allclose(cov, move_pivot(Result.covariance, T_mb[:3, 3]))
    assert cov[1, 1] > Result.covariance[1, 1]  # the yaw's uncertainty moves a base behind the sensor sideways
