"""The odometry's accumulated pose covariance (node/odometry_pipeline.py ``LocalMapOdometry``): the steps' GICP parts
compose along the chain, and each scan's own sweep error is counted once, for the current scan, not once per step.

A drive with known truth and known errors: each step's GICP error is drawn from its covariance and accumulates;
each scan's own sweep error (``SCAN_FLOOR_SHARE`` of the step's floor, ``OdometryStep.covariance_floor``) is drawn
for that scan alone, so the next step undoes it. The steps are scripted (the errors have to be known and drawn from
the claimed covariances; the real odometry cannot be told to make a given sweep error): what is checked is the
pipeline's bookkeeping, frames and sums, over many drives. The real odometry's floor is checked on a simulated
drive in tests/test_covariance_odometry.py and the figures on simulated and real drives are in docs/node.md."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from deepbbs_ros.config import Config
from deepbbs_ros.core.covariance import compose, pose_error
from deepbbs_ros.core.odometry_step import OdometryStep
from deepbbs_ros.node.inputs import Cloud
from deepbbs_ros.node.pipeline import SCAN_FLOOR_SHARE, LocalMapOdometry

STEPS, DRIVES = 20, 200
G = np.diag([0.01 ** 2] * 3 + [0.0005 ** 2] * 3)  # a step's GICP error, scan k-1's frame (m, rad)
F = np.diag([0.05 ** 2, 0.03 ** 2, 0.02 ** 2, 0.004 ** 2, 0.004 ** 2, 0.001 ** 2])  # a step's floor, scan axes


def _moved(d: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``T`` with the error ``d`` (core/covariance.py's convention: position in the parent frame, rotation left)."""
    out = T.copy()
    out[:3, :3] = Rotation.from_rotvec(d[3:]).as_matrix() @ T[:3, :3]
    out[:3, 3] += d[:3]
    return out


def _rot(T: np.ndarray, C: np.ndarray) -> np.ndarray:
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = T[:3, :3]
    return B @ C @ B.T


class _Script:
    """Stands in for the odometry: hands out the scripted steps."""

    def __init__(self, steps: list[OdometryStep]) -> None:
        self.steps = steps

    def reset(self) -> None:
        pass

    def register_frame(self, xyz, times, stamp_ns) -> OdometryStep:
        return self.steps.pop(0)


def _drive(rng) -> tuple[list[OdometryStep], list[np.ndarray]]:
    """A car turning gently at 1 m a step: the steps the odometry reports, and the true poses."""
    S = np.eye(4)
    S[:3, :3] = Rotation.from_euler("z", 0.03).as_matrix()
    S[:3, 3] = [1.0, 0.0, 0.0]
    truth, chain = [np.eye(4)], np.eye(4)  # chain: the true pose with the GICP errors so far
    steps, est = [OdometryStep(np.eye(4), np.eye(4))], [np.eye(4)]
    for _ in range(STEPS):
        g = rng.multivariate_normal(np.zeros(6), G)
        chain = chain @ _moved(g, S)
        truth.append(truth[-1] @ S)
        floor = _rot(chain, F)  # odometry frame, like OdometryStep.covariance
        own = rng.multivariate_normal(np.zeros(6), SCAN_FLOOR_SHARE * floor)
        est.append(_moved(own, chain))
        cov = _rot(est[-2], G) + floor  # the pose's against the map: the step's GICP part and its floor
        steps.append(OdometryStep(est[-1], np.linalg.solve(est[-2], est[-1]), covariance=cov, covariance_floor=floor))
    return steps, truth


def test_accumulated_pose_covariance_counts_each_scans_own_error_once():
    """Over 200 drives of 20 steps the mean NEES of the published pose at steps 1, 5 and 20 lies inside the 99.9 %
    band of chi2(6)'s mean (not overconfident, not growing faster than the error: the band, not the 95 % one, so
    that three checks of one seeded sample do not fail by chance); composing every step's whole covariance (its
    floor included) as a random walk, as the node did, is cautious by step 20 (below the band)."""
    rng = np.random.default_rng(3)
    odo = LocalMapOdometry(Config(), None)
    checked = (1, 5, STEPS)
    nees = {k: [] for k in checked}
    walk_nees = []
    for _ in range(DRIVES):
        steps, truth = _drive(rng)
        odo.odometry = _Script(list(steps))
        odo.reset()
        walk, prev = np.zeros((6, 6)), np.eye(4)
        for k, step in enumerate(steps):
            out = odo.step(Cloud(np.zeros((8, 3), np.float32), int(k * 1e8), "lidar", 0.0))
            d = pose_error(truth[k], out.T_odom)
            if k:  # the step's covariance in scan k-1's frame, as the node moves it
                walk = compose(prev, walk, step.T_prev_k, _rot(np.linalg.inv(prev), step.covariance))
            prev = step.T_first_k
            if k in nees:
                nees[k].append(float(d @ np.linalg.solve(out.pose_covariance, d)))
        walk_nees.append(float(d @ np.linalg.solve(walk, d)))
    n = DRIVES
    lo, hi = chi2.ppf(0.0005, 6 * n) / n, chi2.ppf(0.9995, 6 * n) / n
    for k in checked:
        assert lo <= np.mean(nees[k]) <= hi, (k, np.mean(nees[k]), lo, hi)
    assert np.mean(walk_nees) < lo, (np.mean(walk_nees), lo)


def test_the_odometry_hands_over_its_floor_and_the_pose_counts_it_once():
    """The real odometry on a simulated VLP-16 street (raw sweeps): no floor at the first motion (its quantisation
    stays in the chain), then a floor that is part of the step's covariance (the rest, the GICP part, positive
    definite; the floor positive semidefinite: zero along an axis whose deviations are all registration noise); the
    node's pose covariance is the GICP parts composed plus the scan's share of its own floor, so below the random
    walk of the whole steps, and positive definite."""
    from deepbbs_ros.core.covariance import is_covariance
    from deepbbs_ros.sim.patterns import make_sensor
    from deepbbs_ros.sim.simulator import DriveSimulator

    sim = DriveSimulator("suburban", 8, make_sensor("vlp16"), frames=5)
    cfg = Config().replace(**{"odometry.threads": 1, "odometry.deepbbs_init": "never"})
    odo = LocalMapOdometry(cfg, None)
    walk, prev = np.zeros((6, 6)), None
    for k in range(5):
        s = sim.scan_at(k)
        out = odo.step(Cloud(s.points.astype(np.float32), s.stamp_ns, "lidar", 0.0, s.fields.get("time")))
        step = out.registered.result if k else None
        if k == 1:
            assert step.covariance is not None and step.covariance_floor is None
        if k >= 2:
            fl = step.covariance_floor
            # positive semidefinite: along an axis whose deviations are all registration noise the floor is zero
            assert fl is not None and np.linalg.eigvalsh(fl)[0] > -1e-15 and np.trace(fl) > 0
            assert np.linalg.eigvalsh(step.covariance - fl)[0] > 0
        if k:
            walk = compose(prev, walk, step.T_prev_k, _rot(np.linalg.inv(prev), step.covariance))
            assert is_covariance(out.pose_covariance)
            if k >= 2:  # the earlier scans' floors are not carried: below the walk, by more than rounding
                assert np.all(np.linalg.eigvalsh(walk - out.pose_covariance) > -1e-12), k
                assert np.trace(walk) - np.trace(out.pose_covariance) > 1e-3 * np.trace(walk), k
        prev = out.T_odom


def _held_drive(rng, s: float, held: range) -> tuple[list[OdometryStep], list[np.ndarray]]:
    """The same car, its position along the road held on the steps ``held`` (a stretch in a row): there the velocity
    along the road is not measured and the motion changes by ``a_i`` (standard deviation ``s``) each held step, so the
    ``j``-th held step is off along the road by ``a_1 + ... + a_j``; its covariance holds its own ``j s^2`` and
    ``covariance_held`` its share with the held steps before it, ``j (j - 1) s^2`` (core/motion_floor.py)."""
    S = np.eye(4)
    S[:3, :3] = Rotation.from_euler("z", 0.03).as_matrix()
    S[:3, 3] = [1.0, 0.0, 0.0]
    truth, est = [np.eye(4)], [np.eye(4)]
    steps, v, j = [OdometryStep(np.eye(4), np.eye(4))], 0.0, 0
    x = np.diag([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    for k in range(1, STEPS + 1):
        j = j + 1 if k in held else 0
        v = v + rng.normal(0.0, s) if j else 0.0
        e = rng.multivariate_normal(np.zeros(6), G)
        e[0] += v
        est.append(est[-1] @ _moved(e, S))
        truth.append(truth[-1] @ S)
        cov = _rot(est[-2], G + j * s ** 2 * x)
        steps.append(OdometryStep(est[-1], np.linalg.solve(est[-2], est[-1]), covariance=cov,
                                  covariance_held=_rot(est[-2], j * (j - 1) * s ** 2 * x) if j > 1 else None))
    return steps, truth


def test_the_pose_counts_the_held_steps_shared_velocity_error():
    """Ten steps held in a row (steps 6 to 15 of 20): the published pose's mean NEES at the stretch's end and at the
    drive's end lies inside the 99.9 % band with the held steps' shared error (``OdometryStep.covariance_held``), and
    the steps composed as independent (without it) are overconfident."""
    rng = np.random.default_rng(4)
    odo = LocalMapOdometry(Config(), None)
    checked = (15, STEPS)
    nees = {(k, w): [] for k in checked for w in (True, False)}
    for _ in range(DRIVES):
        steps, truth = _held_drive(rng, 0.05, range(6, 16))
        for with_held in (True, False):
            script = [s if with_held else OdometryStep(s.T_first_k, s.T_prev_k, covariance=s.covariance)
                      for s in steps]
            odo.odometry = _Script(script)
            odo.reset()
            for k in range(len(script)):
                out = odo.step(Cloud(np.zeros((8, 3), np.float32), int(k * 1e8), "lidar", 0.0))
                if k in checked:
                    d = pose_error(truth[k], out.T_odom)
                    nees[(k, with_held)].append(float(d @ np.linalg.solve(out.pose_covariance, d)))
    n = DRIVES
    lo, hi = chi2.ppf(0.0005, 6 * n) / n, chi2.ppf(0.9995, 6 * n) / n
    for k in checked:
        assert lo <= np.mean(nees[(k, True)]) <= hi, (k, np.mean(nees[(k, True)]), lo, hi)
        assert np.mean(nees[(k, False)]) > hi, (k, np.mean(nees[(k, False)]), hi)
