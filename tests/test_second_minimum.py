"""The second-minimum check (core/second_minimum.py): a pose that GICP can slide to another minimum as good along its
weakest direction is not sure; a pose that GICP brings back from both sides is."""

from __future__ import annotations

import numpy as np
from plane_scenes import STREET, scene

from deepbbs_ros.config import Config
from deepbbs_ros.core import second_minimum
from deepbbs_ros.core.good_start import good_start_points
from deepbbs_ros.core.polish import prepare_polish_cloud


def _hall(rng: np.random.Generator, n: int, every: float, radius: float = 12.0, size: float = 1.0) -> np.ndarray:
    """A round hall (a wall of ``radius`` m around the sensor, 3 m high, a floor) with square pillars of ``size`` m
    against the wall every ``every`` degrees: yaw is held by the pillars alone, and turned by part of their spacing
    they still line up with the wall and the floor within the verdict's distance."""
    th = rng.uniform(0, 2 * np.pi, n)
    out = [np.c_[radius * np.cos(th), radius * np.sin(th), rng.uniform(-1, 2, n)]]
    fl = rng.uniform(-radius, radius, (n, 2))
    fl = fl[np.hypot(fl[:, 0], fl[:, 1]) < radius]
    out.append(np.c_[fl, np.full(len(fl), -1.0)])
    centres = np.radians(np.arange(0.0, 360.0, every))
    m = n // len(centres) // 2 + 10
    for c in centres:
        face = rng.integers(0, 3, m)  # the inner face and the two sides
        u = np.where(face == 1, size / 2, np.where(face == 2, -size / 2, rng.uniform(-size / 2, size / 2, m)))
        r = np.where(face == 0, radius - size, rng.uniform(radius - size, radius, m))
        out.append(np.c_[r * np.cos(c) - u * np.sin(c), r * np.sin(c) + u * np.cos(c), rng.uniform(-1, 2, m)])
    p = np.vstack(out)
    return p + rng.normal(0.0, 0.01, p.shape)


def _yaw(deg: float) -> np.ndarray:
    a = np.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return T


def _check(target: np.ndarray, source: np.ndarray, T: np.ndarray) -> second_minimum.Ambiguity:
    rc = Config().registration
    tpc, spc = (prepare_polish_cloud(c, rc.polish_voxel, rc.polish_neighbors, threads=1) for c in (target, source))
    return second_minimum.check(good_start_points(spc, rc), T, spc, tpc, rc)


def test_a_pose_slid_between_two_minima_along_yaw_is_not_sure_the_right_one_is():
    """Pillars every 10 degrees: GICP minima 10 degrees apart along yaw. Slid 2-5 degrees towards the next one, the
    pose still fits (the verdict's fitness 0.98-1.0), but GICP from it both ways finds a minimum as good (the truth or
    the next pillar's) beyond a right pose's tolerance; from the truth, it comes back to the truth both ways."""
    target, source = (_hall(np.random.default_rng(s), 20000, every=10.0) for s in (0, 1))
    right = _check(target, source, np.eye(4))
    assert not right.ambiguous and all(d <= second_minimum.WRONG for d, _ in right.found), right
    for yaw in (2.0, 3.0, 4.0, 5.0):
        a = _check(target, source, _yaw(yaw))
        assert a.score > 0.97 and a.uncertainty > second_minimum.WRONG, a  # fits; yaw held by the pillars alone
        assert a.ambiguous and a.offset > second_minimum.WRONG and a.other_score >= a.score, a
        assert second_minimum.offset(_yaw(yaw), a.other) == a.offset
        truth_or_next = min(abs(np.degrees(np.arctan2(a.other[1, 0], a.other[0, 0])) - c) for c in (0.0, 10.0))
        assert truth_or_next < 0.2, a.other  # the other minimum is the truth's or the next pillar's


def test_a_well_pinned_pair_is_still_sure():
    target, source = scene(STREET, np.random.default_rng(0), 6000), scene(STREET, np.random.default_rng(1), 3000)
    a = _check(target, source, np.eye(4))
    assert not a.ambiguous and a.other is None, a
    assert all(d <= second_minimum.WRONG for d, _ in a.found), a  # GICP came back to the pose from both sides


def test_offset_in_tolerances():
    T = _yaw(2.0)
    T[:3, 3] = [0.6, 0.0, 0.0]
    assert abs(second_minimum.offset(np.eye(4), T) - 2.0) < 1e-9  # 0.6 m = 2 tolerances, 2 degrees = 2
    assert second_minimum.offset(T, T) == 0.0


def test_nothing_to_check_without_points():
    rc = Config().registration
    tpc = prepare_polish_cloud(scene(STREET, np.random.default_rng(0), 3000), rc.polish_voxel, rc.polish_neighbors,
                               threads=1)
    a = second_minimum.check(np.zeros((0, 3)), np.eye(4), tpc, tpc, rc)
    assert not a.ambiguous and a.step == 0.0


def test_a_start_back_after_the_first_iterations_is_not_run_further(monkeypatch):
    """The right pose in the hall: both starts come back within BACK tolerances in LEG iterations and no whole GICP
    run follows; a slid pose's starts that settle on the next pillar are run whole (the ambiguity found as before)."""
    runs = []
    whole = second_minimum.polish
    monkeypatch.setattr(second_minimum, "polish", lambda *a, **k: runs.append(1) or whole(*a, **k))
    target, source = (_hall(np.random.default_rng(s), 20000, every=10.0) for s in (0, 1))
    right = _check(target, source, np.eye(4))
    assert right.step > 0 and not right.ambiguous and runs == [], (right, runs)  # checked, both starts back at once
    assert all(d <= second_minimum.BACK for d, _ in right.found), right
    slid = _check(target, source, _yaw(4.0))
    assert slid.ambiguous and len(runs) >= 1, (slid, runs)


def test_a_start_converged_within_the_first_iterations_is_that_run_whole(monkeypatch):
    """A start GICP's first LEG iterations bring to convergence (one a few centimetres off the right pose in the
    hall) is not run again: its answer is the whole run's from the start, bit for bit (one thread, as
    registration.exact_gicp), from the same iterations."""
    rc = Config().replace(**{"registration.exact_gicp": True}).registration
    target, source = (_hall(np.random.default_rng(s), 20000, every=10.0) for s in (0, 1))
    tpc, spc = (prepare_polish_cloud(c, rc.polish_voxel, rc.polish_neighbors, threads=1) for c in (target, source))
    start = np.eye(4)
    start[:3, 3] = [0.03, -0.02, 0.01]
    whole = second_minimum.polish(spc, tpc, start, rc)
    assert whole.applied and whole.iterations < second_minimum.LEG, whole  # converged within the leg
    runs = []
    monkeypatch.setattr(second_minimum, "polish", lambda *a, **k: runs.append(1) or whole)
    leg, pol = second_minimum._from(spc, tpc, np.eye(4), start, rc)
    assert runs == [] and pol is not None, runs
    for k in ("applied", "reason", "converged", "iterations", "num_inliers", "delta_trans_m", "delta_rot_deg"):
        assert getattr(pol, k) == getattr(whole, k), k
    np.testing.assert_array_equal(pol.T_target_source, whole.T_target_source)
    np.testing.assert_array_equal(pol.hessian[0], whole.hessian[0])
    assert pol.hessian[1:] == whole.hessian[1:]
    assert leg == second_minimum.offset(np.eye(4), whole.T_target_source)
