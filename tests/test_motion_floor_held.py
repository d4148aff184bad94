"""The accumulated pose over steps held along a weak direction (core/motion_floor.py ``MotionFloor.held_cross``), with
known truth: a constant-velocity prediction held along a corridor, whose velocity error along it persists from held
step to held step while the motion it misses changes, drawn many times."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.core.covariance import MotionFloor


def _shift(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def _held_model(s: float, k: int) -> tuple[list[float], list[float]]:
    """A MotionFloor that saw deviations of +-``s`` along x on steps not held, then ``k`` steps held in a row ->
    (each held step's variance along x, ``weak_sigma ** 2``; what the pose gains beyond it, ``held_cross``)."""
    model = MotionFloor()
    for i in range(6):
        model.update(_shift(s if i % 2 else -s), np.eye(4))
    own, cross = [], []
    x = np.array([1.0, 0.0, 0.0])
    for _ in range(k):
        model.update(np.eye(4), np.eye(4), held=True)
        own.append(model.weak_sigma(x) ** 2)
        cross.append(model.held_cross(x))
    return own, cross


def test_held_cross_is_the_held_steps_shared_velocity_error():
    """The velocity along a held direction is not measured; each held step the motion changes by ``a_i`` (standard
    deviation ``s``, what the deviations of the steps not held show), so held step ``j`` is off by ``a_1 + ... + a_j``.
    Drawn 20,000 times: each held step's own variance is ``weak_sigma ** 2`` (``j s^2``), and the accumulated position
    error over the stretch is the steps' own variances plus ``held_cross`` (``s^2 k (k + 1) (2 k + 1) / 6``), where
    the steps' variances composed as independent understate it (2k + 1) / 3 times."""
    s, k = 0.05, 8
    own, cross = _held_model(s, k)
    np.testing.assert_allclose(own, s ** 2 * np.arange(1, k + 1), rtol=1e-9)
    assert cross[0] == 0.0  # the first held step shares nothing yet
    rng = np.random.default_rng(3)
    a = rng.normal(0.0, s, (20000, k))
    step_err = np.cumsum(a, axis=1)  # held step j: the velocity error so far
    np.testing.assert_allclose(step_err.var(axis=0), own, rtol=0.05)
    total = step_err.sum(axis=1)  # the pose's error along x at the stretch's end
    want = float(np.sum(own) + np.sum(cross))
    assert want == pytest.approx(s ** 2 * k * (k + 1) * (2 * k + 1) / 6, rel=1e-9)
    assert total.var() == pytest.approx(want, rel=0.05)
    assert total.var() > 5 * float(np.sum(own))  # the steps as independent: (2k + 1) / 3 = 5.7 times too confident
    # the accumulated position's NEES over the stretch: chi-square(1)'s mean with the shared error, not without
    assert np.mean(total ** 2 / want) == pytest.approx(1.0, abs=0.05)


def test_held_cross_needs_a_measured_direction_and_a_stretch():
    """Nothing before a step that was not held (the direction never measured) and nothing while not held."""
    x = np.array([1.0, 0.0, 0.0])
    model = MotionFloor()
    model.update(np.eye(4), np.eye(4), held=True)
    model.update(np.eye(4), np.eye(4), held=True)
    assert model.held_cross(x) == 0.0
    model.update(_shift(0.1), np.eye(4))
    assert model.held_cross(x) == 0.0  # not held
    model.update(np.eye(4), np.eye(4), held=True)
    model.update(np.eye(4), np.eye(4), held=True)
    assert model.held_cross(x) == pytest.approx(2 * 0.1 ** 2)  # k (k - 1) s^2 with k = 2
    assert model.held_cross(np.array([0.0, 1.0, 0.0])) == 0.0  # no deviation across it
