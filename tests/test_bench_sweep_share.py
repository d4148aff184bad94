"""Each scan's share of its sweep's bend (scripts/benchmarks/_sweep_share.py, ``--sweep-floor share`` of
scripts/benchmarks/covariance.py), with known truth: the pairs' Hessian weighted by time in the sweep is the
Gauss-Newton move of a bent scan, and a sensor that rolls during its sweep lands its pose that share of the missed
roll off, twice as far at twice the rate."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepbbs_ros.core.covariance import pose_error
from deepbbs_ros.core.gicp_pairs import cell_terms, matched_pairs
from deepbbs_ros.core.polish import prepare_polish_cloud

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
import _sweep_share as share  # noqa: E402

small_gicp = pytest.importorskip("small_gicp")

import test_covariance as _tc  # noqa: E402
import test_covariance_sweep as _sw  # noqa: E402


def test_point_times_are_the_voxels_mean_times():
    frame = np.array([[0.1, 0.1, 0.1], [0.2, 0.3, 0.4], [1.1, 0.2, 0.3], [5.0, 5.0, 5.0]])
    times = np.array([0.01, 0.03, 0.07, 0.09])
    t = share.point_times(frame, times, 0.5, np.array([[0.15, 0.2, 0.25], [1.2, 0.1, 0.1], [3.0, 3.0, 3.0]]))
    assert t[0] == pytest.approx(0.02) and t[1] == pytest.approx(0.07) and np.isnan(t[2])


def test_share_matrix_is_the_gauss_newton_move_of_a_bent_scan():
    """Source points each perturbed by ``s_i e`` (a right twist of the source): one Gauss-Newton step of GICP's cost
    moves the pose by ``-H^-1 H_s e``, the share matrix times the bend; a constant ``s`` gives ``s I``."""
    rng = np.random.default_rng(5)
    n = 400
    a = rng.uniform(-20, 20, (n, 3))
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    C = np.eye(3) - 0.999 * np.einsum("ni,nj->nij", normals, normals)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    T[:3, 3] = [1.0, 2.0, 3.0]
    b = a @ T[:3, :3].T + T[:3, 3]
    s = rng.uniform(0.0, 1.0, n)
    A = share.share_matrix((a, C, b, C, T), s)
    assert np.allclose(share.share_matrix((a, C, b, C, T), np.full(n, 0.3)), 0.3 * np.eye(6))
    e = np.array([2e-4, -1e-4, 3e-4, 1e-3, -2e-3, 5e-4])  # [rot, trans]
    bent = np.array([Rotation.from_rotvec(si * e[:3]).apply(p) + si * e[3:] for si, p in zip(s, a)])
    H, g, _ = cell_terms(bent, C, b, C, T, 1e9)
    move = -np.linalg.solve(H, g.sum(axis=0))
    assert np.allclose(move, -A @ e, rtol=0.02, atol=1e-7), (move, -A @ e)


@pytest.mark.parametrize("degrees", [0.3, 0.6])
def test_a_rolling_sweep_lands_its_share_of_the_missed_roll_off(degrees):
    """A sensor in a room rolls ``degrees`` during its sweep (times -0.1..0 s by azimuth) and is not deskewed: GICP
    of the scan on the room lands the pose off by the scan's share of the missed roll (measured from its pairs and
    per-point times), its error proportional to the rate."""
    rng = np.random.default_rng(11)
    world = _tc._scene(rng, 30000)
    centre = np.array([0.5, -0.3, 1.5])
    missed = np.radians(degrees)
    scan = _sw._swept_scan(rng, world, centre, missed)
    rel = world - centre
    times = -0.1 * (1.0 - np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi) / (2 * np.pi))
    tc, sc = prepare_polish_cloud(world, 0.25, 20, threads=1), prepare_polish_cloud(scan, 0.25, 20, threads=1)
    T_true = np.eye(4)
    T_true[:3, 3] = centre
    res = small_gicp.align(tc.cloud, sc.cloud, tc.tree, init_T_target_source=T_true, max_correspondence_distance=1.0,
                           max_iterations=50)
    err = pose_error(T_true, np.asarray(res.T_target_source))
    pairs = matched_pairs(sc, tc, np.asarray(res.T_target_source), 1.0)
    a = share.sweep_share(pairs, scan, times, 0.1, 0.25)
    assert 0.3 < a[0] < 0.7, a
    assert abs(err[3]) == pytest.approx(a[0] * missed, rel=0.1), (np.degrees(err[3]), a[0] * degrees)


def test_white_floor_is_the_deviation_where_every_share_is_a_half():
    d = np.array([[1e-3, -2e-3, 0.0], [-1e-3, 2e-3, 1e-4]])
    assert np.allclose(share.white_floor(d, np.full((2, 3), 0.5)), np.sqrt(np.mean(d ** 2, axis=0)))
    assert np.all(share.white_floor(2 * d, np.full((2, 3), 0.4)) == pytest.approx(
        2 * share.white_floor(d, np.full((2, 3), 0.4))))
