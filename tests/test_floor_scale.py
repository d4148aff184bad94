"""The innovation-based scale of the odometry's rotation floor (core/floor_scale.py): on a synthetic stream whose
steps are off by a known share of the fixed floor it converges to that share; the bound lies above it; inside
MotionFloor it scales the rotation floor alone."""

import numpy as np
import pytest

from deepbbs_ros.core.floor_scale import InnovationScale, nis_root
from deepbbs_ros.core.motion_floor import MOTION_WINDOW, MotionFloor


def _stream(true_scale: float, steps: int, seed: int, bound: bool = False) -> np.ndarray:
    """The scales read over a stream of ``steps`` steps (no motion change: the premise ``q = 0``), each step's
    rotation error per axis normal with its GICP variance ``g`` plus ``true_scale`` times the fixed floor's ``f``
    (independent steps: ``c = 0``); the innovation the difference of two consecutive steps' errors."""
    rng = np.random.default_rng(seed)
    model, prev, out = InnovationScale(MOTION_WINDOW, bound=bound), None, []
    for _ in range(steps):
        f = np.square(np.radians(rng.uniform(0.03, 0.08, 3)))  # the fixed floor's variance, as on the drives
        g = 0.1 * true_scale * f * rng.uniform(0.5, 1.5, 3)  # the GICP part, a tenth of the true floor
        err = rng.normal(0.0, np.sqrt(g + true_scale * f))
        out.append(model.scale())
        model.add_step(None if prev is None else err - prev, None if prev is None else f)
        model.add_noise(g)
        prev = err
    return np.array(out)


@pytest.mark.parametrize("true_scale", [0.25, 2.0])
def test_the_scale_converges_to_the_missed_rotations_share(true_scale):
    """0.25: the fixed floor counts the missed rotation twice (the HDL-64E drives); 2: the steps carry twice what
    it counts. One window's mean NIS (N = MOTION_WINDOW innovations, three axes) moves by about 1 / sqrt(N) of
    itself; the median over the stream's ~M = steps / N windows by about 1.25 / sqrt(N M) (a median's standard
    error), and the GICP part (a tenth) widens the scale's by 1.1: within four of those."""
    steps = 400
    lam = _stream(true_scale, steps, seed=3)
    assert lam[0] == 1.0 and lam[1] == 1.0  # no innovation with both steps known yet: the fixed floor
    tol = 4 * 1.1 * 1.25 / np.sqrt(MOTION_WINDOW * steps / MOTION_WINDOW)
    assert abs(np.median(lam[MOTION_WINDOW + 2:]) / true_scale - 1.0) < tol
    # one window's spread about the truth is of the size the window gives (not a tuned tolerance)
    rel = np.log(lam[MOTION_WINDOW + 2:] / true_scale)
    assert 0.5 / np.sqrt(MOTION_WINDOW) < np.std(rel) < 2.0 / np.sqrt(MOTION_WINDOW)


def test_the_bound_lies_above_the_estimate():
    point, bound = _stream(0.5, 200, seed=5), _stream(0.5, 200, seed=5, bound=True)
    assert np.all(bound[2:] >= point[2:])
    assert 1.2 < np.median(bound[MOTION_WINDOW + 2:] / point[MOTION_WINDOW + 2:]) < 3.0


def test_nis_root():
    nu = np.array([[1.0, 2.0, 0.5], [0.5, 1.0, 1.0]])
    a, b = np.full((2, 3), 0.1), np.ones((2, 3))
    lam = nis_root(nu, a, b)
    assert np.mean(np.sum(nu ** 2 / (a + lam * b), axis=1)) == pytest.approx(3.0, rel=1e-5)
    assert nis_root(nu, np.full((2, 3), 10.0), b) == 0.0  # the GICP parts explain the innovations
    assert nis_root(nu, a, np.zeros((2, 3))) == 0.0  # no floor to scale
    # an axis without a floor is left out with its degree of freedom: its innovations, however large, move nothing
    b0 = b.copy()
    b0[:, 1] = 0.0
    big = nu.copy()
    big[:, 1] = 100.0
    lam0 = nis_root(big, a, b0)
    kept = [0, 2]
    assert np.mean(np.sum(nu[:, kept] ** 2 / (a[:, kept] + lam0 * b[:, kept]), axis=1)) == pytest.approx(2.0, rel=1e-5)
    assert nis_root(big, a, b0, bound=True) >= lam0


def _turn(rotvec) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    return T


def test_motion_floor_scales_the_rotation_floor_alone():
    rng = np.random.default_rng(0)
    fixed, adaptive = MotionFloor(), MotionFloor("adaptive")
    for k in range(30):
        pose, pred = _turn(rng.normal(0, 1e-3, 3)), np.eye(4)
        pose[:3, 3] = rng.normal(0, 0.01, 3)
        swept, motion = _turn(rng.normal(0, 1e-3, 3)), _turn(rng.normal(0, 1e-3, 3))
        first = k == 0
        a = fixed.update(pose, None if first else pred, None if first else motion, swept)
        b = adaptive.update(pose, None if first else pred, None if first else motion, swept)
        noise = np.full(6, 1e-8)
        fixed.add_noise(noise)
        adaptive.add_noise(noise)
        if a is None:
            assert b is None
            continue
        assert np.allclose(a[:3], b[:3])  # the position floor is the fixed one
        assert np.allclose(b[3:], np.sqrt(adaptive.last_scale) * a[3:])
    assert adaptive.last_scale != 1.0 and fixed.last_scale == 1.0
