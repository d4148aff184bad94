"""The skew check (core/sweep_skew.py): a swaying sweep with known per-point times and a known turn within the sweep,
against a hall's surfaces seen from a still sensor: a 3 degree turn within the sweep bends the pose beyond the
tolerance and is flagged, a 0.2 degree one is not; a scan without times is skipped; the registration's verdict turns a
bent pose away with its reason."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core import sweep_skew
from deepbbs_ros.core.polish import polish
from deepbbs_ros.core.polish_cloud import prepare_polish_cloud
from deepbbs_ros.core.preprocess import PreprocessResult


def _hall(rng: np.random.Generator, n: int) -> np.ndarray:
    """Points on a 20 x 12 m hall's walls and floor and two pillars (sensor at the origin, 1 m over the floor)."""
    k = n // 8
    x, y = rng.uniform(-10, 10, k), rng.uniform(-6, 6, k)
    z1, z2 = rng.uniform(-1, 3, k), rng.uniform(-1, 3, k)
    faces = [np.c_[x, np.full(k, -6.0), z1], np.c_[x, np.full(k, 6.0), z2], np.c_[np.full(k, -10.0), y, z1],
             np.c_[np.full(k, 10.0), y, z2],
             np.c_[rng.uniform(-10, 10, 2 * k), rng.uniform(-6, 6, 2 * k), np.full(2 * k, -1.0)]]
    for cx, cy in ((3.0, 2.0), (-4.0, -3.0)):
        a = rng.uniform(0, 2 * np.pi, k)
        faces.append(np.c_[cx + 0.4 * np.cos(a), cy + 0.4 * np.sin(a), rng.uniform(-1, 3, k)])
    return np.vstack(faces)


def _sweep(rng: np.random.Generator, turn_deg: float, period: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A Livox-like sweep of the hall (any direction at any time) while the sensor turns by ``turn_deg`` about a
    tilted axis at a constant rate: (points (N, 3) each in the sensor frame at its time, times (N,) s)."""
    from scipy.spatial.transform import Rotation

    axis = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    world = _hall(rng, 40000)
    t = rng.uniform(0, period, len(world))
    R = Rotation.from_rotvec(np.outer(t / period * np.radians(turn_deg), axis))
    return R.inv().apply(world), t


@pytest.fixture(scope="module")
def hall():
    rc = Config().registration
    rng = np.random.default_rng(3)
    target = prepare_polish_cloud(_hall(rng, 40000), rc.polish_voxel, rc.polish_neighbors, threads=1)
    return rc, rng, target


def _fit(rc, target, points: np.ndarray) -> np.ndarray:
    """GICP of the sweep to the still hall from identity: the rigid pose the verdict judges."""
    src = prepare_polish_cloud(points, rc.polish_voxel, rc.polish_neighbors, threads=1)
    return polish(src, target, np.eye(4), rc).T_target_source


@pytest.mark.parametrize(("turn", "flagged"), [(3.0, True), (0.2, False)])
def test_a_turn_within_the_sweep_bends_the_pose(hall, turn, flagged):
    rc, rng, target = hall
    points, times = _sweep(rng, turn)
    T = _fit(rc, target, points)
    sk = sweep_skew.sweep_skew(points, times, T, target, rc.polish_max_corr_dist, rc.skew_sigmas)
    assert sk is not None and sk.n > 1000
    # half the turn, as the rigid pose is off by (GICP's pose is off by it too)
    assert sk.rot_est_deg == pytest.approx(turn / 2, abs=0.25)
    assert sk.trans_est_m < 0.05  # no translation within the sweep
    assert sk.bends(rc.success_rot_deg, rc.success_trans) is flagged


def test_scans_without_times_are_skipped(hall):
    rc, rng, target = hall
    points, times = _sweep(rng, 3.0)
    pre = PreprocessResult(np.zeros((0, 3), np.float32), None, len(points), len(points), 0, polish_cloud=target)
    assert sweep_skew.check(pre, pre, np.eye(4), rc) is None  # neither scan kept times: nothing runs
    raw = PreprocessResult(np.zeros((0, 3), np.float32), None, len(points), len(points), 0, raw_points=points,
                           times=times, stamp_ns=1)
    sk = sweep_skew.check(raw, pre, _fit(rc, target, points), rc)  # the source's sweep only
    assert sk is not None and sk.scan == "source" and sk.bends(rc.success_rot_deg, rc.success_trans)
    assert sweep_skew.sweep_skew(points, np.zeros(len(points)), np.eye(4), target, 2.0) is None  # no time span


def test_a_spinning_sweep_is_not_judged(hall):
    """Times that follow the azimuth (a spinning sensor): the motion within the sweep and the scene's shape along the
    azimuth cannot be told apart, so nothing is judged."""
    rc, rng, target = hall
    points, _ = _sweep(rng, 3.0)
    times = np.mod(-np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi) / (2 * np.pi) * 0.1
    assert sweep_skew.sweep_skew(points, times, _fit(rc, target, points), target, rc.polish_max_corr_dist) is None


def test_the_verdict_turns_a_bent_pose_away(hall):
    """VerdictStages._skew on a pose the probability took: not valid, with the reason; off: untouched."""
    from deepbbs_ros.core.registration_state import State
    from deepbbs_ros.core.registration_verdict import VerdictStages

    rc, rng, target = hall
    points, times = _sweep(rng, 3.0)
    src = PreprocessResult(np.zeros((0, 3), np.float32), None, len(points), len(points), 0, raw_points=points,
                           times=times, stamp_ns=1)
    tgt = PreprocessResult(np.zeros((0, 3), np.float32), None, 1, 1, 0, polish_cloud=target)
    st = State(*([None] * 4), src, tgt, None, target, *([None] * 6), T=_fit(rc, target, points), valid=True)
    stages = VerdictStages()
    stages.config = Config()
    stages._skew(st)
    assert not st.valid and st.skew.startswith("rejected: sweep skew of the source")
