"""The prediction floor's position part from a chi-square estimate (scripts/benchmarks/_position_floor.py,
``--position-floor`` of scripts/benchmarks/covariance.py), with known geometry: a window whose deviations are the
registration noise alone leaves a small floor, not 0; extra motion the model misses makes it grow to about that."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import deepbbs_ros.core.motion_floor as floormod
from deepbbs_ros.core.motion_floor import SWEEP_SPREAD, MotionFloor

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
import _position_floor as pf  # noqa: E402

G = 1e-4  # m^2: a step's GICP variance (10 mm)


def test_noise_alone_leaves_a_small_floor():
    # the deviations' mean square is exactly the noise they carry (2 g): the clip says 0, the posterior a little
    s = pf.posterior(np.array([2 * G]), np.array([2 * G]), 10)[0]
    assert 0.1 * G < s < G
    assert pf.median(np.array([2 * G]), np.array([2 * G]), 10)[0] < s


def test_extra_motion_grows_the_floor():
    # missed motion of 4 g on top: the estimates near m - 2 g (the shipped clip's), the posterior a bit above it
    noise, small, big = np.array([2 * G]), np.array([2 * G]), np.array([6 * G])
    s_small, s_big = pf.posterior(small, noise, 10)[0], pf.posterior(big, noise, 10)[0]
    assert s_big > 4 * s_small
    assert 4 * G < s_big < 6 * G
    assert pf.posterior(big, noise, 40)[0] < s_big  # more deviations, less room
    assert pf.posterior(np.array([G]), np.array([0.0]), 10)[0] == pytest.approx(10 * G / 9.342, rel=1e-3)


def _floor(devs: np.ndarray) -> np.ndarray:
    model, floor = MotionFloor(), None
    for d in devs:
        model.add_noise(np.array([G] * 3 + [1e-8] * 3))
        pose = np.eye(4)
        pose[:3, 3] = d
        floor = model.update(pose, np.eye(4))
    return floor


def test_installed_on_the_motion_floor(monkeypatch):
    monkeypatch.setattr(floormod.MotionFloor, "_missed", floormod.MotionFloor._missed)
    signs = np.array([1.0, -1.0] * 5)
    noise_only = np.outer(signs, [(2 * G) ** 0.5, 0.0, 0.0])  # mean square along x: 2 g
    extra = np.outer(signs, [(6 * G) ** 0.5, 0.0, 0.0])
    assert _floor(noise_only)[0] == 0.0  # the module's clip
    pf.install(floormod, "posterior")
    low, high = _floor(noise_only)[0], _floor(extra)[0]
    assert 0.0 < low < SWEEP_SPREAD * G ** 0.5
    assert high > 2 * low and high == pytest.approx(SWEEP_SPREAD * pf.posterior(np.array([6 * G]),
                                                                                  np.array([2 * G]), 10)[0] ** 0.5)


def test_position_line_reads_the_rows():
    # steps of 10 mm error along x with a published 10 mm, constant steps (no difference), no floor
    steps = [(np.array([0.01, 0, 0, 0, 0, 0]), np.eye(6) * 1e-4) for _ in range(6)]
    step = np.eye(4)
    step[0, 3] = 1.0
    chain = [(np.eye(4), step, step, step) for _ in range(6)]
    line = pf.position_line(steps, chain, [np.zeros((6, 6))] * 6)
    assert "step error rms 10.0, 0.0, 0.0; published sd rms 10.0, 10.0, 10.0" in line
    assert "sqrt 2 0.0, 0.0, 0.0; prediction floor under 1 mm on 100%, 100%, 100%" in line
