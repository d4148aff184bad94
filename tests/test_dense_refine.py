"""The final dense refinement (registration.dense_refine), the coarse-to-fine alpha and their config."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from deepbbs_ros.config import Config, ModelConfig, PreprocessConfig
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.preprocess import (
    PreprocessResult,
    dense_subsample,
    farthest_point_sample,
    preprocess,
    voxel_downsample,
)
from deepbbs_ros.core.refine import refine
from deepbbs_ros.core.registration import DeepBBSRegistration
from deepbbs_ros.errors import ConfigError

TINY = ModelConfig(k=6, dgcnn_widths=[8, 8], emb_dims=16, n_heads=2, ff_dims=16)


def _prep(p: np.ndarray, seed: int) -> PreprocessResult:
    """The pipeline's steps after ground removal: 1000 FPS points and the dense voxels."""
    v = voxel_downsample(p, 0.3)
    return PreprocessResult(v[farthest_point_sample(v, 1000, seed=1)], None, len(p), len(p), len(p),
                            dense_points=dense_subsample(v, 3000, seed=seed))


def _pair(street_pair, seed: int):
    """Two independent samplings of the street; the source seen from T_target_source (0.8 m, 1.5 deg)."""
    src, tgt, T = street_pair(seed, 60000, [1.5, 0.2, -0.2], [0.8, 0.3, 0.02])
    return _prep(src, seed), _prep(tgt, seed), T


def _err(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(T_gt) @ T_est
    return float(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))), float(np.linalg.norm(E[:3, 3]))


def _reg(**flat) -> DeepBBSRegistration:
    torch.manual_seed(0)
    cfg = Config().replace(**{"registration.device": "cpu", "registration.deep": False, "registration.threads": 1,
                              "registration.refine": True, "registration.polish": "none",
                              **flat})
    return DeepBBSRegistration(cfg, model=DeepBBSNet(TINY).eval())


def _offset() -> np.ndarray:
    D = np.eye(4)
    D[:3, :3] = Rotation.from_euler("z", 0.8, degrees=True).as_matrix()
    D[:3, 3] = [0.4, -0.3, 0.0]
    return D


@pytest.mark.xfail(
    reason="known limitation (accuracy study): on 0.3 m voxel centroids the dense point-to-point fixed point is not "
    "reliably closer than the 1000-point one (seed 3: 0.037 m vs 0.016 m); hence dense_refine defaults to false",
    strict=False,
)
@pytest.mark.parametrize("seed", [3, 11])
def test_dense_refinement_beats_the_sparse_one(street_pair, seed):
    src, tgt, T = _pair(street_pair, seed)
    T0 = T @ _offset()
    sparse = _reg(**{"registration.dense_refine": False}).register(src, tgt, T_init=T0)
    dense = _reg(**{"registration.dense_refine": True}).register(src, tgt, T_init=T0)
    rs, ts = _err(sparse.T_target_source, T)
    rd, td = _err(dense.T_target_source, T)
    assert dense.iterations["dense"] >= 1 and sparse.iterations["dense"] == 0
    assert "dense" in dense.timings_ms and dense.gamma.shape == (1000,)
    assert td < 0.05 and rd < 0.15, (rd, td)
    assert td < 0.7 * ts, (td, ts)  # denser points: clearly closer than the 1000-point fixed point


@pytest.mark.parametrize("seed", [3, 11])
def test_dense_refinement_runs_and_stays_close(street_pair, seed):
    src, tgt, T = _pair(street_pair, seed)
    res = _reg(**{"registration.dense_refine": True}).register(src, tgt, T_init=T @ _offset())
    assert res.iterations["dense"] >= 1 and res.gamma.shape == (1000,) and "dense" in res.timings_ms
    rot, trans = _err(res.T_target_source, T)
    assert trans < 0.06 and rot < 0.3, (rot, trans)  # from 0.5 m / 0.8 deg off


def test_plain_arrays_skip_the_dense_stage(street_pair):
    src, tgt, T = _pair(street_pair, 3)
    res = _reg().register(src.points, tgt.points, preprocessed=True, T_init=T @ _offset())
    assert res.iterations["dense"] == 0


def test_coarse_to_fine_alpha_converges_at_the_paper_alpha(street_pair):
    src, tgt, T = _pair(street_pair, 5)
    s, t = torch.from_numpy(src.points) * 0.025, torch.from_numpy(tgt.points) * 0.025
    T0 = T @ _offset()
    R0 = torch.tensor(T0[:3, :3], dtype=torch.float32)
    t0 = torch.tensor(T0[:3, 3] * 0.025, dtype=torch.float32)
    paper = refine(s, t, R0, t0, max_iters=200)
    c2f = refine(s, t, R0, t0, max_iters=200, alpha_start=8.0)
    assert paper.converged and c2f.converged
    assert c2f.iterations > paper.iterations  # it went through the coarser levels first
    for r in (paper, c2f):
        Te = np.eye(4)
        Te[:3, :3], Te[:3, 3] = r.R.double().numpy(), r.t.double().numpy() / 0.025
        assert _err(Te, T)[1] < 0.3


def test_preprocess_dense_points(street_scene):
    rng = np.random.default_rng(0)
    ground = np.c_[rng.uniform(-30, 30, (40000, 2)), rng.normal(-1.8, 0.02, 40000)]
    pts = np.concatenate([ground, street_scene(rng, 30000)[0] - [0, 0, 1.8]]).astype(np.float32)
    cfg = PreprocessConfig(dense_max_points=2500)
    res = preprocess(pts, cfg)
    assert res.points.shape == (cfg.num_points, 3)
    assert res.dense_points.shape == (2500, 3) and res.dense_points.dtype == np.float32
    assert res.n_voxels > 2500 and res.dense_points[:, 2].min() > -1.8 + cfg.ground_layer / 2 - 0.2
    np.testing.assert_array_equal(preprocess(pts, cfg).dense_points, res.dense_points)  # deterministic
    full = preprocess(pts, PreprocessConfig(dense_max_points=0))
    assert len(full.dense_points) == full.n_voxels
    np.testing.assert_array_equal(full.points, res.points)  # the sampled points do not depend on the cap


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("preprocess.dense_max_points", -1, "preprocess.dense_max_points"),
        ("registration.dense_refine_k", 0, "registration.dense_refine_k"),
        ("registration.dense_refine_max_iters", 0, "registration.dense_refine_max_iters"),
        ("registration.dense_refine_xi", 0.0, "registration.dense_refine_xi"),
        ("registration.dense_refine_temperature", 0.0, "registration.dense_refine_temperature"),
        ("registration.refine_alpha_start", 0.5, "registration.refine_alpha_start"),
        ("registration.refine_temperature", -1.0, "registration.refine_temperature"),
    ],
)
def test_config_validation(key, value, match):
    with pytest.raises(ConfigError, match=match):
        Config().replace(**{key: value}).validate()


def test_shipped_param_file_has_the_new_fields():
    from pathlib import Path

    cfg = Config.from_yaml(Path(__file__).resolve().parents[1] / "config" / "deepbbs_ros.yaml")
    assert cfg.registration == Config().registration
    assert cfg.preprocess.dense_max_points == Config().preprocess.dense_max_points
