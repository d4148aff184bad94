"""The odometry's statistical hold (core/odometry_hold.py): where the data pin a direction less than the prediction
does, the position there is the two's inverse-variance mean, and the step's covariance is wide there."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core import odometry_hold as K
from deepbbs_ros.core.odometry import DeepBBSOdometry

pytest.importorskip("small_gicp")


def test_data_sigma_is_at_least_the_shared_gradient_errors():
    cov = np.diag([1e-6, 1e-6, 1e-6, 1e-8, 1e-8, 1e-8])
    dirs, lam = np.eye(3), np.array([1.0, 100.0, 100.0])
    sd = K.data_sigmas(cov, dirs, lam)
    assert sd == pytest.approx([0.1, 1e-3, 1e-3])  # 1 mm where best pinned, 100 times that at 1 % of its information


def test_held_only_beyond_the_limit_and_where_the_data_pin_less():
    start, pose = np.eye(4), np.eye(4)
    pose[:3, 3] = [0.5, 0.002, 0.0]
    dirs = (np.eye(3), np.array([1.0, 100.0, 100.0]))
    cov = np.diag([1e-6] * 3 + [1e-8] * 3)
    held, sig = K.held_directions(pose, start, dirs, 0.1, lambda: cov, lambda d: 0.01)
    assert held.shape == (1, 3) and abs(held[0, 0]) == 1.0 and sig[0] == pytest.approx((0.1, 0.01))
    assert len(K.held_directions(pose, start, dirs, 0.6, lambda: cov, lambda d: 0.01)[0]) == 0  # within the gate
    assert len(K.held_directions(pose, start, dirs, 0.1, lambda: cov, lambda d: 0.5)[0]) == 0  # prediction worse
    assert len(K.held_directions(pose, start, dirs, 0.1, lambda: cov, lambda d: float("nan"))[0]) == 0
    assert len(K.held_directions(pose, start, dirs, 0.1, lambda: None, lambda d: 0.01)[0]) == 0
    out = K.blend(pose, start, held, sig)
    assert out[0, 3] == pytest.approx(0.5 * 0.01 ** 2 / (0.01 ** 2 + 0.1 ** 2))  # the inverse-variance mean
    assert out[1, 3] == pose[1, 3]


def test_corridor_step_keeps_the_prediction_and_is_wide_along_the_axis():
    """Known truth: constant speed, 0.2 m a scan, along a corridor whose closed end is seen for the first eight scans;
    with the Hessian's ratio test off (odometry.degenerate_ratio 0) only the statistical hold acts."""
    from test_degeneracy import _corridor_scan

    def drive(gate_sigmas: float):
        cfg = Config()
        cfg.preprocess.min_range, cfg.preprocess.max_range = 0.5, 25.0
        oc = cfg.odometry
        oc.deepbbs_init, oc.threads, oc.voxel_size = "never", 1, 0.5
        oc.degenerate_ratio, oc.gate_sigmas = 0.0, gate_sigmas
        odo, rng = DeepBBSOdometry(cfg), np.random.default_rng(1)
        return [odo.register_frame(_corridor_scan(k * 0.2, rng, end_wall=k < 8), stamp_ns=k * 100_000_000)
                for k in range(12)]

    free, held = drive(0.0), drive(4.0)
    assert abs(free[8].T_prev_k[0, 3] - 0.2) > 0.1  # without the hold the scan after the end wall slides
    marked = [s for s in held if s.degenerate]
    assert marked and held[8].degenerate.startswith("corridor-like, weak axis x")
    for s in marked:
        assert abs(s.T_prev_k[0, 3] - 0.2) < 0.02  # the prediction's step, not the slide
        assert np.sqrt(s.covariance[0, 0]) > 5 * np.sqrt(s.covariance[1, 1])  # wide along the axis
