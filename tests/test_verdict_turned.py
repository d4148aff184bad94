"""Turned pairs (sim/turned.py): a sensor turned and moved between its two scans, with an exact truth, as the
verdict's calibration set uses them (scripts/calibrate_verdict.py ``--turned-pairs``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from deepbbs_ros.core import visibility
from deepbbs_ros.sim.patterns import mid360
from deepbbs_ros.sim.rig import RigSimulator
from deepbbs_ros.sim.turned import MOVE_M, YAW_DEG, render_at, turned_pair


def _sim(noise: float = 0.0) -> RigSimulator:
    return RigSimulator("hall", 5, mid360(range_noise=noise, dropout=0.0), "handheld", frames=100,
                        motion_distortion=False, compensate=True)


def _heading(T: np.ndarray) -> float:
    return float(np.arctan2(T[1, 0], T[0, 0]))


def test_render_at_the_trajectory_pose_is_the_simulators_own_scan():
    sim = _sim(0.02)
    own, again = sim.scan_at(7), render_at(sim, 7, sim.pose_at(7))
    assert np.array_equal(own.points, again.points)
    assert np.array_equal(again.T_world_lidar, sim.pose_at(7))
    assert np.array_equal(sim.T_world_lidar(7 * sim.period), sim.pose_at(7))  # the trajectory is back


def test_turned_pair_is_turned_and_moved_within_its_ranges_and_the_truth_is_exact():
    sim, rng = _sim(), np.random.default_rng(3)
    pairs = [p for p in (turned_pair(sim, i, rng) for i in (0, 10, 20, 30)) if p is not None]
    assert len(pairs) >= 3
    for p in pairs:
        Tt, Ts = p.target.T_world_lidar, p.source.T_world_lidar
        assert np.allclose(p.T_target_source, np.linalg.inv(Tt) @ Ts)
        assert YAW_DEG[0] <= p.yaw_deg <= YAW_DEG[1] and MOVE_M[0] <= p.move_m <= MOVE_M[1]
        dyaw = (_heading(Ts) - _heading(Tt) + np.pi) % (2 * np.pi) - np.pi
        assert abs(abs(np.degrees(dyaw)) - p.yaw_deg) < 1e-6
        # noiseless scans of the same walls: at the truth the source lands on the target's surfaces; 0.1 m off, not
        near, off = _on_surface(p, p.T_target_source), p.T_target_source.copy()
        off[:3, 3] += [0.1, 0.0, 0.0]
        assert near < 0.005 and _on_surface(p, off) > 5 * near, (near, _on_surface(p, off))


def _on_surface(p, T: np.ndarray) -> float:
    """Median distance (m) of the source's points under ``T`` to the target's local planes (8 neighbours within
    0.3 m, flat ones only)."""
    tgt = p.target.points.astype(np.float64)
    tree = cKDTree(tgt)
    moved = p.source.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    d, nb = tree.query(moved, k=8, distance_upper_bound=0.3)
    ok = np.all(np.isfinite(d), axis=1)
    q = tgt[nb[ok]]
    c = q.mean(axis=1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("kni,knj->kij", q - c, q - c))
    flat = w[:, 0] < 1e-4 * w[:, 1]
    res = np.abs(np.einsum("ki,ki->k", moved[ok] - c[:, 0], v[:, :, 0]))
    return float(np.median(res[flat]))


def test_calibration_turned_pairs_have_the_overlap_they_state():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import calibrate_verdict as cv

    from deepbbs_ros.config import Config
    from deepbbs_ros.core.registration import DeepBBSRegistration, good_start_points
    from deepbbs_ros.sim.patterns import avia, driver_of

    reg, rng = DeepBBSRegistration(Config()), np.random.default_rng(4)
    rc = reg.config.registration
    sim = RigSimulator("hall", 38, avia(), "handheld", frames=100)
    scan = cv._Scans(sim, reg, driver_of("avia"), rng, None, False)
    got = [cv._turned(scan, 0, rng, rc)]
    assert any(g is not None for g in got)
    for (tgt, Tt), (src, Ts) in (g for g in got if g is not None):
        f = visibility.pose_features(good_start_points(src.polish_cloud, rc), np.linalg.inv(Tt) @ Ts,
                                     tgt.polish_cloud, rc.verdict_dist)
        assert cv.TURNED_OVERLAP[0] <= f[visibility.FEATURES.index("observable")] <= cv.TURNED_OVERLAP[1]
