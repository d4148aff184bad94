"""P(a pose within the tolerance | its covariance) (core/within.py), and the verdict that multiplies by it: a pose
the scene pins is within the tolerance, a pose that can slide along a corridor is not sure to be."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from plane_scenes import STREET, scene
from scipy.stats import norm

from deepbbs_ros.config import Config
from deepbbs_ros.core import verdict, within
from deepbbs_ros.core.polish import prepare_polish_cloud


def test_the_probability_is_the_gaussian_mass_within_the_tolerance():
    """A covariance far tighter than the tolerance: 1; one metre along x alone: P(|N(0, 1)| <= 0.3) (0.236); one
    degree about z alone: P(|N(0, 1)| <= 1) (0.683); no covariance: 0. The same covariance, the same answer."""
    tight = np.diag([1e-6] * 3 + [1e-9] * 3)
    assert within.probability(tight) == 1.0
    x = tight.copy()
    x[0, 0] = 1.0
    assert abs(within.probability(x) - (2 * norm.cdf(0.3) - 1)) < 0.02
    yaw = tight.copy()
    yaw[5, 5] = np.radians(1.0) ** 2
    assert abs(within.probability(yaw) - (2 * norm.cdf(1.0) - 1)) < 0.02
    assert within.probability(yaw) == within.probability(yaw.copy())
    assert within.probability(None) == 0.0 and within.probability(np.full((6, 6), np.nan)) == 0.0
    assert within.probability(x, trans=3.0) > 0.99  # a wider tolerance holds it


def _clouds(planes, seeds=(0, 1)):
    rc = Config().registration
    return [prepare_polish_cloud(scene(planes, np.random.default_rng(s), 3000), rc.polish_voxel, rc.polish_neighbors,
                                 threads=1) for s in seeds]


def _along(dy: float) -> np.ndarray:
    T = np.eye(4)
    T[1, 3] = dy
    return T


def test_a_pinned_pose_is_within_and_a_slid_one_is_not_sure():
    """A street closed at both ends (the end walls pin the pose along it): at the truth the pose's covariance is
    millimetres and P(within) is 1. Slid 1 m along the street the pose still fits both side walls and the floor, but
    the end walls no longer agree with them: leaving their cells out moves the pose by about as much as it slid, and
    P(within) falls under a third (0.27; with one end wall only, 0.11)."""
    rc = Config().registration
    tgt, src = _clouds(STREET)
    cov = within.pose_covariance(src, tgt, np.eye(4), rc.polish_max_corr_dist)
    assert cov is not None and np.sqrt(np.diag(cov)[:3]).max() < 0.05, cov
    assert within.within(src, tgt, np.eye(4), rc) > 0.95
    assert within.within(src, tgt, _along(1.0), rc) < 0.35
    tgt, src = _clouds(STREET[:4])  # one end wall
    assert within.within(src, tgt, np.eye(4), rc) > 0.95
    assert within.within(src, tgt, _along(1.0), rc) < 0.2


@pytest.mark.xfail(strict=True, reason="known gap: on a corridor that nothing pins along (two noiseless walls and a "
                   "floor) GICP's in-plane terms hold the data's own covariance to centimetres anywhere along it; the "
                   "localization's spread along a weak direction (weak=True) says 0.21 there, but rejects right poses "
                   "too (docs/sensors.md)")
def test_a_pose_slid_along_a_corridor_that_nothing_pins_is_not_sure():
    rc = Config().registration
    tgt, src = _clouds(STREET[:3])  # the two walls and the floor
    assert within.within(src, tgt, _along(1.0), rc) < 0.5


def test_the_verdict_multiplies_only_where_it_can_change_the_decision():
    """``registration.verdict_within``: "pair" multiplies the registration's verdict, not the good start's ("all"
    both, "off", the default, neither); under the bar the probability is returned as it is (the product cannot reach
    the bar)."""
    rc = dataclasses.replace(Config().registration, verdict_within="pair")
    tgt, src = _clouds(STREET)
    slid = _along(1.0)
    assert verdict.times_within(0.9, src, tgt, slid, rc, 0.7) < 0.35
    assert verdict.times_within(0.9, src, tgt, slid, rc, 0.7, "good_start") == 0.9
    assert verdict.times_within(0.5, src, tgt, slid, rc, 0.7) == 0.5  # under the bar: not computed
    every = dataclasses.replace(rc, verdict_within="all")
    assert verdict.times_within(0.9, src, tgt, slid, every, 0.7, "good_start") < 0.35
    assert verdict.times_within(0.9, src, tgt, slid, Config().registration, 0.7) == 0.9  # "off", the default
    assert verdict.times_within(0.9, src, tgt, np.eye(4), rc, 0.7) > 0.85  # the truth: the probability itself
