"""deepbbs_ros.metrics against hand-computed values on synthetic trajectories with known errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepbbs_ros import metrics
from deepbbs_ros.errors import DatasetError


def _T(yaw_deg: float = 0.0, t=(0.0, 0.0, 0.0), rotvec=None) -> np.ndarray:
    T = np.eye(4)
    if rotvec is not None:
        T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    else:
        T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = t
    return T


def _straight(n: int, step: float = 1.0) -> np.ndarray:
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, 0, 3] = np.arange(n) * step
    return P


# -- pair errors -----------------------------------------------------------------------------------
def test_pair_errors_known_values():
    T_gt = _T(10.0, (1.0, 2.0, 0.0))
    T_est = _T(13.0, (1.3, 2.4, 0.0))
    rot, tr = metrics.pair_errors(T_est, T_gt)
    assert rot == pytest.approx(3.0, abs=1e-9)
    assert tr == pytest.approx(0.5, abs=1e-12)  # 3-4-5 triangle
    # batched gives the same
    rots, trs = metrics.pair_errors(np.stack([T_est, T_gt]), np.stack([T_gt, T_gt]))
    np.testing.assert_allclose(rots, [3.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(trs, [0.5, 0.0], atol=1e-12)
    # arbitrary axis: the geodesic angle
    rv = np.array([0.3, -0.2, 0.5])
    rv = rv / np.linalg.norm(rv) * np.radians(7.0)
    assert metrics.rotation_error_deg(_T(rotvec=rv)[:3, :3], np.eye(3)) == pytest.approx(7.0, abs=1e-9)
    with pytest.raises(ValueError, match="expected"):
        metrics.pair_errors(np.eye(3), np.eye(4))


def test_summarize_success_and_runtime():
    e = [1.0, 2.0, 3.0, 4.0, float("nan")]
    s = metrics.summarize(e)
    assert s["mean"] == pytest.approx(2.5)
    assert s["rmse"] == pytest.approx(np.sqrt(30.0 / 4.0))
    assert s["median"] == pytest.approx(2.5)
    assert s["p95"] == pytest.approx(3.85)  # linear interpolation between 3 and 4
    assert s["max"] == 4.0
    assert all(np.isnan(v) for v in metrics.summarize([]).values())
    rot = np.array([0.5, 1.0, 1.01, 0.2, np.nan])
    tr = np.array([0.1, 0.3, 0.1, 0.31, 0.1])
    np.testing.assert_array_equal(metrics.success_mask(rot, tr), [True, True, False, False, False])
    assert metrics.success_rate(rot, tr) == pytest.approx(0.4)
    assert metrics.success_rate(rot, tr, rot_thresh_deg=2.0, trans_thresh_m=0.5) == pytest.approx(0.8)
    r = metrics.runtime_summary([10.0, 20.0, 30.0])
    assert r == {"mean": 20.0, "p50": 20.0, "p95": pytest.approx(29.0)}


# -- KITTI drift -----------------------------------------------------------------------------------
def _kitti_expected(n_frames: int, err_of_segment) -> tuple[float, float, int]:
    """Hand enumeration of the devkit on a 1 m/frame straight line: a segment of length L starting at f
    ends at f + L + 1 (first frame whose distance is strictly greater than L)."""
    t_errs, r_errs = [], []
    for f in range(0, n_frames, 10):
        for L in metrics.KITTI_LENGTHS:
            last = f + int(L) + 1
            if last >= n_frames:
                continue
            t, r = err_of_segment(f, last, L)
            t_errs.append(t / L)
            r_errs.append(r / L)
    return float(np.mean(t_errs) * 100), float(np.degrees(np.mean(r_errs)) * 100), len(t_errs)


def test_kitti_drift_scale_error():
    """Estimate moves 1 % too far: every segment's error is 0.01 (L + 1) m over L m."""
    n = 1001
    gt = _straight(n)
    est = _straight(n, step=1.01)
    t_pct, r_deg, count = _kitti_expected(n, lambda f, last, L: (0.01 * (last - f), 0.0))
    d = metrics.kitti_drift(est, gt)
    assert d["segments"] == count
    assert d["t_err_pct"] == pytest.approx(t_pct, rel=1e-9)
    assert d["r_err_deg_per_100m"] == pytest.approx(0.0, abs=1e-6)
    assert 1.0 < d["t_err_pct"] < 1.02  # ~1 % by construction


def test_kitti_drift_heading_error():
    """Estimate positions are right but the heading drifts eps per frame: the segment rotation error is
    (last - f) eps; the translation error is |p_l - p_f| * 2 sin(f eps / 2)."""
    n, eps = 901, np.radians(0.01)
    gt = _straight(n)
    est = gt.copy()
    for k in range(n):
        est[k, :3, :3] = Rotation.from_euler("z", k * eps).as_matrix()
    t_pct, r_deg, count = _kitti_expected(
        n, lambda f, last, L: ((last - f) * 2.0 * np.sin(f * eps / 2.0), (last - f) * eps)
    )
    d = metrics.kitti_drift(est, gt)
    assert d["segments"] == count
    assert d["r_err_deg_per_100m"] == pytest.approx(r_deg, rel=1e-7)
    assert d["t_err_pct"] == pytest.approx(t_pct, rel=1e-6)
    # about 1 deg/100 m: 0.01 deg per metre travelled
    assert d["r_err_deg_per_100m"] == pytest.approx(1.0, rel=0.02)


def test_kitti_drift_matches_kiss_icp_devkit_port():
    """Cross-check against KISS-ICP's C++ port of the devkit on a curved noisy trajectory."""
    kiss_metrics = pytest.importorskip("kiss_icp.metrics")
    rng = np.random.default_rng(3)
    n = 400
    gt = np.tile(np.eye(4), (n, 1, 1))
    est = gt.copy()
    for k in range(1, n):
        step = _T(0.3, (1.5, 0.0, 0.0))
        gt[k] = gt[k - 1] @ step
        noise = _T(rotvec=rng.normal(0, 0.002, 3), t=rng.normal(0, 0.02, 3))
        est[k] = est[k - 1] @ step @ noise
    d = metrics.kitti_drift(est, gt)
    t_kiss, r_kiss = kiss_metrics.sequence_error(gt, est)
    assert d["segments"] > 0
    assert d["t_err_pct"] == pytest.approx(t_kiss, rel=1e-3)
    # KISS-ICP reports the rotation error in deg/m
    assert d["r_err_deg_per_100m"] / 100.0 == pytest.approx(r_kiss, rel=1e-3)


def test_kitti_drift_short_trajectory_is_nan():
    d = metrics.kitti_drift(_straight(50), _straight(50))
    assert d["segments"] == 0 and np.isnan(d["t_err_pct"]) and np.isnan(d["r_err_deg_per_100m"])
    with pytest.raises(ValueError, match="estimated poses"):
        metrics.kitti_drift(_straight(5), _straight(6))


# -- ATE / RPE -------------------------------------------------------------------------------------
def test_umeyama_recovers_rigid_transform(rng):
    src = rng.normal(size=(50, 3)) * 10
    T = _T(rotvec=rng.normal(size=3), t=rng.normal(size=3) * 5)
    dst = src @ T[:3, :3].T + T[:3, 3]
    T_est, s = metrics.umeyama_alignment(src, dst)
    np.testing.assert_allclose(T_est, T, atol=1e-9)
    assert s == 1.0
    T_s, s2 = metrics.umeyama_alignment(src, 2.0 * dst, with_scale=True)
    assert s2 == pytest.approx(2.0)


def test_ate_known_error(rng):
    """A planar loop driven twice, +0.1 m in z the first time and -0.1 m the second: the z offsets are
    uncorrelated with x, y, so the best alignment is the rigid motion applied and ATE = 0.1 exactly."""
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    loop = np.stack([20 * np.cos(ang), 20 * np.sin(ang), np.zeros_like(ang)], 1)
    pos = np.concatenate([loop, loop])
    sign = np.concatenate([np.ones(16), -np.ones(16)])
    gt = np.tile(np.eye(4), (32, 1, 1))
    gt[:, :3, 3] = pos
    est = gt.copy()
    est[:, 2, 3] += 0.1 * sign
    G = _T(rotvec=[0.1, -0.2, 1.0], t=[5.0, -3.0, 1.0])  # arbitrary world offset of the estimate
    est = G @ est
    assert metrics.ate_rmse(est, gt) == pytest.approx(0.1, abs=1e-9)
    assert metrics.ate_rmse(G @ gt, gt) == pytest.approx(0.0, abs=1e-9)


def test_rpe_single_bad_step():
    n = 20
    step = _T(1.0, (1.0, 0.1, 0.0))
    bad = _T(2.0, (0.0, 0.2, 0.0))
    gt = np.tile(np.eye(4), (n, 1, 1))
    est = gt.copy()
    for k in range(1, n):
        gt[k] = gt[k - 1] @ step
        est[k] = est[k - 1] @ step @ (bad if k == 5 else np.eye(4))
    trans, rot = metrics.rpe(est, gt)
    assert trans.shape == (n - 1,)
    expected_t = np.zeros(n - 1)
    expected_t[4] = 0.2
    expected_r = np.zeros(n - 1)
    expected_r[4] = 2.0
    np.testing.assert_allclose(trans, expected_t, atol=1e-9)
    np.testing.assert_allclose(rot, expected_r, atol=1e-6)


# -- trajectory files ------------------------------------------------------------------------------
def test_tum_and_kitti_round_trip(tmp_path, rng):
    n = 7
    poses = np.stack([_T(rotvec=rng.normal(size=3), t=rng.normal(size=3) * 100) for _ in range(n)])
    stamps = 1.7e9 + np.arange(n) * 0.1
    metrics.write_tum(tmp_path / "a.tum", stamps, poses)
    s2, p2 = metrics.read_tum(tmp_path / "a.tum")
    np.testing.assert_allclose(s2, stamps, atol=1e-6)
    np.testing.assert_allclose(p2, poses, atol=1e-7)
    first = (tmp_path / "a.tum").read_text().splitlines()[0].split()
    assert len(first) == 8 and float(first[7]) >= 0  # qw last and non-negative
    metrics.write_kitti(tmp_path / "a.kitti", poses)
    np.testing.assert_allclose(metrics.read_kitti(tmp_path / "a.kitti"), poses, atol=1e-7)
    assert len((tmp_path / "a.kitti").read_text().splitlines()[0].split()) == 12


def test_trajectory_readers_errors(tmp_path):
    bad = tmp_path / "bad.tum"
    bad.write_text("# comment\n0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0\n")
    with pytest.raises(DatasetError, match=r"bad.tum:3: TUM line must hold 8 numbers"):
        metrics.read_tum(bad)
    bad.write_text("0 1 2 3 0 0 0 0\n")
    with pytest.raises(DatasetError, match="invalid quaternion"):
        metrics.read_tum(bad)
    k = tmp_path / "bad.kitti"
    k.write_text("1 0 0 0 0 1 0 0 0 0 1 x\n")
    with pytest.raises(DatasetError, match=r"bad.kitti:1: KITTI pose line must hold 12 numbers"):
        metrics.read_kitti(k)
    with pytest.raises(DatasetError, match="cannot read KITTI trajectory"):
        metrics.read_kitti(tmp_path / "missing.txt")
