"""Every public entry point that takes a cloud checks it the same way (deepbbs_ros/core/points.py).

(N, 3) only (a KITTI (N, 4) scan is refused naming the shape, never reshaped into a wrong pose), real
numbers only, no empty clouds; NaN/Inf rows of raw scans are dropped like missing returns, preprocessed
clouds must be finite.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from deepbbs_ros.config import Config, ModelConfig
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.points import as_transform, as_xyz
from deepbbs_ros.core.registration import DeepBBSRegistration
from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.replay.synthetic import MOUNT_HEIGHT, pose, scan_at, structured_world

TINY = ModelConfig(k=6, dgcnn_widths=[8, 8], emb_dims=16, n_heads=2, ff_dims=16)


@pytest.fixture(scope="module")
def scans():
    """Two scans of the toy street 0.5 m apart: (source, target, T_target_source)."""
    world = structured_world(3, length=80.0)
    T_w_t, T_w_s = pose(0.0, 0.0, MOUNT_HEIGHT, 0.0), pose(0.5, 0.0, MOUNT_HEIGHT, np.deg2rad(1.0))
    rng = np.random.default_rng(0)
    tgt = scan_at(world, T_w_t, rng, n_points=8000)
    src = scan_at(world, T_w_s, rng, n_points=8000)
    return src, tgt, np.linalg.inv(T_w_t) @ T_w_s


@pytest.fixture(scope="module")
def reg():
    torch.manual_seed(0)
    cfg = Config().replace(**{"registration.device": "cpu", "preprocess.num_points": 128})
    return DeepBBSRegistration(cfg, model=DeepBBSNet(TINY).eval())


#: (bad cloud, what the message must say); the good cloud has 8000 points
BAD = [
    ("kitti", lambda p: np.c_[p, np.ones(len(p), np.float32)],
     r"got shape \(8000, 4\); pass xyz only .*points\[:, :3\]"),
    ("one_d", lambda p: p.reshape(-1), r"expected an \(N, 3\) point array, got shape \(24000,\)"),
    ("single_point", lambda p: p[0], r"got shape \(3,\)"),
    ("organised", lambda p: p.reshape(80, 100, 3), r"got shape \(80, 100, 3\); flatten .*reshape\(-1, 3\)"),
    ("two_columns", lambda p: p[:, :2], r"got shape \(8000, 2\)"),
    ("empty", lambda p: p[:0], r"empty point cloud \(shape \(0, 3\)\)"),
    ("bool", lambda p: p > 0, r"real numeric .* dtype bool"),
    ("complex", lambda p: p.astype(np.complex64), r"dtype complex64"),
    ("strings", lambda p: p.astype(str), r"dtype <U"),
    ("objects", lambda p: p.astype(object), r"dtype object"),
    ("structured", lambda p: np.zeros(len(p), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]), r"structured"),
    ("ragged", lambda p: [[1.0, 2.0, 3.0], [1.0, 2.0]], r"expected an \(N, 3\) point array"),
]


def _entry_points(reg, scans):
    """name -> call(bad_cloud): every public entry point that takes a raw cloud, with a good partner."""
    from deepbbs_ros.baselines import KissICPOdometry, SmallGicpRegistration
    from deepbbs_ros.core.odometry import DeepBBSOdometry
    from deepbbs_ros.core.pair import register_pair
    from deepbbs_ros.core.polish import polish, prepare_polish_cloud
    from deepbbs_ros.core.preprocess import preprocess

    src, tgt, _ = scans
    cfg = reg.config
    return {
        "register source": lambda bad: reg.register(bad, tgt),
        "register target": lambda bad: reg.register(src, bad),
        "register preprocessed": lambda bad: reg.register(bad, tgt[:128], preprocessed=True),
        "register_pair": lambda bad: register_pair(bad, tgt, cfg, model=reg.model),
        "DeepBBSRegistration.preprocess": reg.preprocess,
        "DeepBBSRegistration.polish_cloud": reg.polish_cloud,
        "core.preprocess.preprocess": lambda bad: preprocess(bad, cfg.preprocess),
        "prepare_polish_cloud": lambda bad: prepare_polish_cloud(bad, 0.5, 20),
        "polish": lambda bad: polish(bad, tgt, np.eye(4), cfg.registration),
        "DeepBBSOdometry.register_frame": lambda bad: DeepBBSOdometry(cfg, registration=reg).register_frame(bad),
        "gicp": lambda bad: SmallGicpRegistration("gicp", cfg).register(bad, tgt),
        "kiss-icp": lambda bad: KissICPOdometry(cfg).register(bad),
    }


@pytest.mark.parametrize("kind, make, match", BAD, ids=[b[0] for b in BAD])
def test_every_entry_point_refuses_the_same_clouds(reg, scans, kind, make, match):
    src = scans[0]
    for name, call in _entry_points(reg, scans).items():
        with pytest.raises(RegistrationError, match=match):
            call(make(src))
            pytest.fail(f"{name} accepted a {kind} cloud")


def test_kitti_scan_is_refused_not_registered_wrongly(reg, scans):
    """(N, 4) x, y, z, reflectance used to be reshaped to (-1, 3) by the precision stage: a wrong pose with
    converged=True. Now it is refused, and the xyz columns register to the ground truth."""
    src, tgt, T_gt = scans
    kitti = [np.c_[p, np.random.default_rng(1).uniform(0, 1, len(p)).astype(np.float32)] for p in (src, tgt)]
    with pytest.raises(RegistrationError, match=r"target: expected an \(N, 3\) point array, got shape \(8000, 4\)"):
        reg.register(*kitti)
    res = reg.register(kitti[0][:, :3], kitti[1][:, :3])
    assert np.linalg.norm(res.T_target_source[:3, 3] - T_gt[:3, 3]) < 0.1, res


def test_nan_rows_of_raw_scans_are_dropped_everywhere(reg, scans):
    """A raw scan with NaN / Inf rows (missing returns) gives the same answer as the scan without them, on
    every raw entry point; a preprocessed cloud with one is refused."""
    from deepbbs_ros.baselines import KissICPOdometry, SmallGicpRegistration
    from deepbbs_ros.core.preprocess import preprocess

    src, tgt, _ = scans
    holes = src.copy()
    holes[::7] = np.nan
    holes[3::11, 1] = np.inf
    clean = holes[np.isfinite(holes).all(axis=1)]
    cfg = reg.config
    np.testing.assert_array_equal(preprocess(holes, cfg.preprocess).points, preprocess(clean, cfg.preprocess).points)
    np.testing.assert_array_equal(reg.preprocess(holes).points, reg.preprocess(clean).points)
    np.testing.assert_allclose(reg.register(holes, tgt).T_target_source, reg.register(clean, tgt).T_target_source,
                               atol=1e-9)
    gicp = SmallGicpRegistration("gicp", cfg)
    np.testing.assert_allclose(gicp.register(holes, tgt).T_target_source, gicp.register(clean, tgt).T_target_source,
                               atol=1e-9)
    a, b = KissICPOdometry(cfg), KissICPOdometry(cfg)
    for x, y in ((tgt, tgt), (holes, clean)):
        np.testing.assert_allclose(a.register(x)[0], b.register(y)[0], atol=1e-9)
    with pytest.raises(RegistrationError, match=r"source: the point cloud contains NaN .*\(\d+ of 128 points\)"):
        reg.register(holes[:128], tgt[:128], preprocessed=True)
    # an all-NaN raw scan: the stage says how many points it found
    with pytest.raises(RegistrationError, match=r"only 0 of 8000 points are finite"):
        reg.preprocess(np.full_like(src, np.nan))


def test_integer_and_float64_clouds_are_accepted():
    pts = np.arange(30).reshape(10, 3)
    assert as_xyz(pts).dtype == np.float32 and as_xyz(pts, dtype=None).dtype == np.float64
    f64 = pts.astype(np.float64)
    assert as_xyz(f64, dtype=None) is f64  # no copy when nothing changes
    assert as_xyz(pts.tolist()).shape == (10, 3)


def test_T_init_is_checked(reg, scans):
    src, tgt, _ = scans
    with pytest.raises(RegistrationError, match=r"T_init: expected a \(4, 4\) transform, got shape \(16,\)"):
        reg.register(src[:128], tgt[:128], preprocessed=True, T_init=np.eye(4).reshape(-1))
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(RegistrationError, match="T_init: the transform contains NaN"):
        as_transform(bad)
