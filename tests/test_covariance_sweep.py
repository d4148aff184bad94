"""The odometry's model error where the residuals cannot show it (core/covariance.py MotionFloor), with known truth:
a sweep that rolls more than the deskew assumed (its pose lands half the missed roll off, the sweep floor covers
it and the prediction's floor does not), and a corridor, where the covariance along the axis the odometry's
degeneracy check finds weak is the motion model's, not the Hessian's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from deepbbs_ros.core import degeneracy as _deg
from deepbbs_ros.core.covariance import SWEEP_SPREAD, MotionFloor, pose_error
from deepbbs_ros.core.polish import prepare_polish_cloud

small_gicp = pytest.importorskip("small_gicp")

import test_covariance as _tc  # noqa: E402


def _roll(angle: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([angle, 0.0, 0.0]).as_matrix()
    return T


def _swept_scan(rng, world: np.ndarray, centre: np.ndarray, missed: float, period: float = 0.1) -> np.ndarray:
    """The points of ``world`` seen from ``centre`` by a spinning sensor that rolls by ``missed`` rad during its sweep
    (times -period..0 by azimuth, the stamp at the sweep's end, roll 0 there), not deskewed: the sensor frame's
    points as they are recorded."""
    rel = world - centre
    az = np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi)
    t = -period * (1.0 - az / (2 * np.pi))
    R = Rotation.from_rotvec(np.outer(missed * t / period, [1.0, 0.0, 0.0])).as_matrix()  # the sensor at time t
    return np.einsum("nji,nj->ni", R, rel) + rng.normal(0, 0.01, rel.shape)


def test_sweep_floor_covers_a_roll_the_deskew_missed():
    """A sensor in a room rolls 0.6 deg during its sweep (its previous stamp at -0.6 deg, this one at 0) and the
    deskew assumed no motion. GICP of the raw scan on the room lands the pose about half the missed roll off (the
    sweep's middle) and the registered motion the other half off the deskew's; the sweep floor (sqrt(2) / 2 of twice
    that deviation) covers the roll error, while the prediction's floor alone (the motion repeats the last: no
    deviation) would be zero."""
    rng = np.random.default_rng(11)
    world = _tc._scene(rng, 30000)
    centre = np.array([0.5, -0.3, 1.5])
    missed = np.radians(0.6)
    scan = _swept_scan(rng, world, centre, missed)
    tc, sc = prepare_polish_cloud(world, 0.25, 20, threads=1), prepare_polish_cloud(scan, 0.25, 20, threads=1)
    T_true = np.eye(4)
    T_true[:3, 3] = centre
    res = small_gicp.align(tc.cloud, sc.cloud, tc.tree, init_T_target_source=T_true, max_correspondence_distance=1.0,
                           max_iterations=50)
    T_est = np.asarray(res.T_target_source)
    err = pose_error(T_true, T_est)
    T_prev = T_true @ _roll(-missed)  # the previous stamp's pose (exact)
    step = np.linalg.solve(T_prev, T_est)  # the registered motion over the period
    shown = Rotation.from_matrix(step[:3, :3]).as_rotvec()[0]  # its deviation from the deskew's (none)
    assert 0.3 * missed < abs(err[3]) < 0.7 * missed, (np.degrees(err[3]), np.degrees(missed))
    assert 0.3 * missed < shown < 0.7 * missed, (np.degrees(shown), np.degrees(missed))
    f = MotionFloor()
    floor = f.update(T_est, T_est, step, np.eye(4))  # the prediction was right; the sweep was not deskewed for it
    assert floor[3] == pytest.approx(SWEEP_SPREAD * 2.0 * abs(shown))
    assert (err[3] / floor[3]) ** 2 < chi2.ppf(0.95, 1), (err[3], floor[3])
    assert MotionFloor().update(T_est, T_est, step, None)[3] == 0.0  # not deskewed: nothing to compare with


def test_corridor_covariance_along_the_axis_is_the_motion_models():
    """A 4 m corridor along x and GICP started 30 cm off along it: the odometry's degeneracy check (core/degeneracy.py
    on the GICP Hessian at ``odometry.degenerate_ratio``) finds x weak, and the covariance along x is the motion
    model's: its deviations along x (20 cm rms on the steps not held) times the square root of the three steps held
    in a row, on top of the Hessian's; across the corridor it stays the Hessian's. The NEES covers the error."""
    from deepbbs_ros.config import OdometryConfig
    from deepbbs_ros.core.covariance import gicp_hessian, sandwich_covariance

    rng = np.random.default_rng(5)
    T, Te, _, _, pairs = _tc._trial(rng, _tc._scene(rng, 20000, corridor=True), np.array([0.3, 0.0, 0.0]))
    H, _, _ = gicp_hessian(pairs_cloud(pairs[0]), _Target(pairs[2]), pairs[4], max_corr_dist=2.0)
    deg = _deg.analyse(H, Te[:3, :3], OdometryConfig().degenerate_ratio)
    assert len(deg.axes) == 1, deg
    weak = deg.weak @ Te[:3, :3]  # the scan's frame
    model = MotionFloor()
    for dx in (0.2, -0.2, 0.2, -0.2):  # steps not held: the prediction's deviations along the corridor
        model.update(_shift(dx * weak[0]), np.eye(4))
    for _ in range(3):  # three steps held along it in a row
        model.update(np.eye(4), np.eye(4), held=True)
    sigma = model.weak_sigma(weak[0])
    assert sigma == pytest.approx(0.2 * np.sqrt(3), rel=1e-6)
    held_only = MotionFloor()
    held_only.update(np.eye(4), np.eye(4), held=True)
    assert np.isnan(held_only.weak_sigma(weak[0]))  # never measured along it: the caller's default stands
    cov = sandwich_covariance(pairs, Te, 1.0, weak_sigma=sigma, weak=weak)
    alone = sandwich_covariance(pairs, Te, 1.0, weak=np.zeros((0, 3)))  # the Hessian's only
    x = np.array([1.0, 0.0, 0.0])
    assert float(x @ cov[:3, :3] @ x) - float(x @ alone[:3, :3] @ x) == pytest.approx(sigma ** 2, rel=0.05)
    assert np.sqrt(cov[0, 0]) > 10 * np.sqrt(alone[0, 0]), (cov[0, 0], alone[0, 0])
    assert cov[1, 1] < 2 * alone[1, 1] + 1e-6 and cov[2, 2] < 2 * alone[2, 2] + 1e-6
    d = pose_error(T, Te)
    assert abs(d[0]) > 0.05  # GICP did not find its way back along the corridor
    assert float(d @ np.linalg.solve(cov, d)) < chi2.ppf(0.99, 6)
    assert float(d @ np.linalg.solve(alone, d)) > chi2.ppf(0.999, 6)  # the Hessian alone: overconfident


def pairs_cloud(points: np.ndarray):
    return prepare_polish_cloud(points, 0.25, 20, threads=1).cloud


class _Target:
    """A prepared target from the pairs' target points (GICP's Hessian at the estimate)."""

    def __init__(self, points: np.ndarray) -> None:
        c = prepare_polish_cloud(points, 0.25, 20, threads=1)
        self.cloud, self.tree = c.cloud, c.tree


def _shift(d: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = d
    return T
