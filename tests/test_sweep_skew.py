"""The skew check (core/sweep_skew.py): a swaying sweep with known per-point times and a known turn within the sweep,
against a hall's surfaces seen from a still sensor: a 3 degree turn within the sweep bends the pose beyond the
tolerance and is flagged, a 0.2 degree one is not; two sweeps that turn alike pass; scans without times, and a spinning
sensor's, are skipped; the registration's verdict and the good start turn a bent pose away with the reason."""

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
    """GICP of the sweep to the target cloud from identity: the rigid pose the verdict judges."""
    src = prepare_polish_cloud(points, rc.polish_voxel, rc.polish_neighbors, threads=1)
    return polish(src, target, np.eye(4), rc).T_target_source


def _pre(points: np.ndarray, times: np.ndarray | None = None, cloud=None) -> PreprocessResult:
    """A prepared scan with only what the check reads: its raw points and times (None: none kept), its cloud."""
    return PreprocessResult(np.zeros((0, 3), np.float32), None, len(points), len(points), 0, polish_cloud=cloud,
                            raw_points=None if times is None else points, times=times,
                            stamp_ns=None if times is None else 1)


def _rot_deg(T: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1))))


@pytest.mark.parametrize(("turn", "flagged"), [(3.0, True), (0.2, False)])
def test_a_turn_within_the_sweep_bends_the_pose(hall, turn, flagged):
    rc, rng, target = hall
    points, times = _sweep(rng, turn)
    T = _fit(rc, target, points)
    sk = sweep_skew.check(_pre(points, times), _pre(points, cloud=target), T, rc)
    assert sk is not None and sk.scans == "source" and sk.n > 1000
    # half the turn, as the rigid pose is off by (GICP's pose is off by it too: the still target's truth is identity)
    assert sk.rot_est_deg == pytest.approx(turn / 2, abs=0.25)
    assert _rot_deg(T) == pytest.approx(turn / 2, abs=0.25)
    assert sk.trans_est_m < 0.05  # no translation within the sweep
    assert sk.bends(rc.success_rot_deg, rc.success_trans) is flagged


def test_two_sweeps_that_turn_alike_pass(hall):
    """Both scans turn 3 degrees within their sweeps, alike: the pose between them is right, and the check says so."""
    rc, rng, _ = hall
    (ps, ts), (pt, tt) = _sweep(rng, 3.0), _sweep(rng, 3.0)
    cloud = prepare_polish_cloud(pt, rc.polish_voxel, rc.polish_neighbors, threads=1)
    src = prepare_polish_cloud(ps, rc.polish_voxel, rc.polish_neighbors, threads=1)
    T = _fit(rc, cloud, ps)
    assert _rot_deg(T) < 0.3
    sk = sweep_skew.check(_pre(ps, ts, src), _pre(pt, tt, cloud), T, rc)
    assert sk is not None and sk.scans == "both" and sk.rot_est_deg < 0.3
    assert not sk.bends(rc.success_rot_deg, rc.success_trans)
    alone = sweep_skew.check(_pre(ps, ts, src), _pre(pt, None, cloud), T, rc)  # the target's motion unknown
    assert alone.scans == "source" and alone.bends(rc.success_rot_deg, rc.success_trans)


def test_scans_without_times_or_spinning_are_skipped(hall):
    rc, rng, target = hall
    points, times = _sweep(rng, 3.0)
    assert sweep_skew.check(_pre(points, cloud=target), _pre(points, cloud=target), np.eye(4), rc) is None
    assert sweep_skew.sweep_motion(points, np.zeros(len(points)), np.eye(4), target, 2.0) is None  # no time span
    # times that follow the azimuth (a spinning sensor): the motion within the sweep and the scene's shape along the
    # azimuth cannot be told apart, so nothing is judged
    spin = np.mod(-np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi) / (2 * np.pi) * 0.1
    assert sweep_skew.spinning(points, spin) and not sweep_skew.spinning(points, times)
    assert sweep_skew.check(_pre(points, spin), _pre(points, cloud=target), _fit(rc, target, points), rc) is None


def test_the_verdict_turns_a_bent_pose_away(hall):
    """VerdictStages._skew on a pose the probability took: not valid, with the reason."""
    from deepbbs_ros.core.registration_state import State
    from deepbbs_ros.core.registration_verdict import VerdictStages

    rc, rng, target = hall
    points, times = _sweep(rng, 3.0)
    st = State(*([None] * 4), _pre(points, times), _pre(points, cloud=target), None, target, *([None] * 6),
               T=_fit(rc, target, points), valid=True)
    stages = VerdictStages()
    stages.config = Config()
    stages._skew(st)
    assert not st.valid and st.skew.startswith("rejected: sweep skew (source)")


def test_the_good_start_turns_a_bent_pose_away(hall):
    """register(..., good_start=True) on a 3-degree sweep against the still hall: GICP's pose, not valid, the reason;
    with the check off, the same pose valid."""
    from deepbbs_ros.core.registration import DeepBBSRegistration

    rc, rng, _ = hall
    points, times = _sweep(rng, 3.0)
    still = _hall(rng, 40000)
    for on in (True, False):
        reg = DeepBBSRegistration(Config().replace(**{"registration.skew_check": on, "registration.threads": 1,
                                                      "registration.network_process": "off"}))
        src, tgt = reg.preprocess(points, times, 1), reg.preprocess(still, np.zeros(len(still)), 1)
        res = reg.register(src, tgt, T_init=np.eye(4), preprocessed=True, good_start=True)
        assert res.path == "gicp" and _rot_deg(res.T_target_source) == pytest.approx(1.5, abs=0.3)
        assert res.valid is not on and res.skew.startswith("rejected" if on else "")
        assert on or res.skew == ""
