"""Inference fast paths == the reference (training) computations, to float round-off.

The inference code replaces nn.Transformer by a functional SDPA version with target-side caching,
the log-domain SoftBBS / soft map / gamma by a product of two softmaxes, and the broadcast distance
computations by one GEMM. Each replacement is checked against the reference on the same inputs.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from deepbbs_ros.config import ModelConfig
from deepbbs_ros.core import softbbs
from deepbbs_ros.core.model import DeepBBSNet, solve_transform, solve_transform_inference

SMALL = ModelConfig(k=6, dgcnn_widths=[8, 8, 16], emb_dims=16, n_heads=2, ff_dims=32)


def _model(cfg=SMALL, seed=0):
    torch.manual_seed(seed)
    return DeepBBSNet(cfg).eval()


def _reference_cross(model, f_src, f_tgt):
    """phi = f + nn.Transformer(...) exactly as in training (autograd on: no fast path)."""
    with torch.enable_grad():
        tr = model.transformer
        return (f_src + tr(f_tgt, f_src)).detach(), (f_tgt + tr(f_src, f_tgt)).detach()


@pytest.mark.parametrize("n_blocks,norm_first", [(1, False), (2, False), (1, True)])
def test_functional_transformer_equals_nn_transformer(rng, n_blocks, norm_first):
    cfg = ModelConfig(k=6, dgcnn_widths=[8, 16], emb_dims=32, n_heads=4, n_blocks=n_blocks, ff_dims=48)
    model = _model(cfg)
    if norm_first:
        for layer in [*model.transformer.encoder.layers, *model.transformer.decoder.layers]:
            layer.norm_first = True
    f_src = torch.tensor(rng.normal(size=(2, 70, 32)), dtype=torch.float32)
    f_tgt = torch.tensor(rng.normal(size=(2, 55, 32)), dtype=torch.float32)
    ref = _reference_cross(model, f_src, f_tgt)
    with torch.inference_mode():
        fast = model.cross(f_src, f_tgt)  # functional path, cache built on the fly
        cache = model.target_cache(f_tgt)
        for _ in range(2):  # the cache is reusable across deep iterations
            cached = model.cross_cached(f_src, cache)
    for r, a, b in zip(ref, fast, cached):
        torch.testing.assert_close(a, r, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(b, r, atol=1e-5, rtol=1e-5)


def test_cross_cached_with_a_moving_source(rng):
    """Deep iterations: a new source each time, one target cache."""
    model = _model()
    f_tgt = torch.tensor(rng.normal(size=(1, 40, 16)), dtype=torch.float32)
    with torch.inference_mode():
        cache = model.target_cache(f_tgt)
    for _ in range(3):
        f_src = torch.tensor(rng.normal(size=(1, 50, 16)), dtype=torch.float32)
        ref = _reference_cross(model, f_src, f_tgt)
        with torch.inference_mode():
            got = model.cross_cached(f_src, cache)
        for r, g in zip(ref, got):
            torch.testing.assert_close(g, r, atol=1e-5, rtol=1e-5)


def test_training_mode_keeps_nn_transformer(rng):
    """Gradients still flow through nn.Transformer (the fast path is inference-only)."""
    model = _model().train()
    f_src = torch.tensor(rng.normal(size=(1, 30, 16)), dtype=torch.float32, requires_grad=True)
    f_tgt = torch.tensor(rng.normal(size=(1, 30, 16)), dtype=torch.float32)
    assert not model._fast_transformer()
    phi_src, _ = model.cross(f_src, f_tgt)
    phi_src.sum().backward()
    assert f_src.grad is not None and torch.isfinite(f_src.grad).all()


def test_distances_gemm_equal_reference(rng):
    x = torch.tensor(rng.normal(size=(2, 80, 64)), dtype=torch.float32)
    y = torch.tensor(rng.normal(size=(2, 60, 64)), dtype=torch.float32)
    ref = torch.cdist(x.double(), y.double()).float()
    with torch.inference_mode():
        fast = softbbs.pairwise_distances(x, y)
        nn_fast = softbbs.self_nn_distance(x)
    torch.testing.assert_close(fast, ref, atol=1e-4, rtol=1e-5)
    d_self = torch.cdist(x.double(), x.double()) + torch.diag(torch.full((80,), np.inf, dtype=torch.float64))
    torch.testing.assert_close(nn_fast, d_self.min(dim=2).values.float(), atol=1e-4, rtol=1e-5)
    # with autograd the reference formula runs (training numerics unchanged)
    xg = x.clone().requires_grad_(True)
    torch.testing.assert_close(softbbs.self_nn_distance(xg).detach(), nn_fast, atol=1e-4, rtol=1e-5)


def _features(rng, b=2, n=300, m=250, c=16, shift=0.0):
    x = torch.tensor(rng.normal(size=(b, n, c)), dtype=torch.float32)
    y = torch.tensor(rng.normal(size=(b, m, c)), dtype=torch.float32) + shift
    return x, y


@pytest.mark.parametrize("alpha", [1.0, 0.1, 0.01, 1e-4])
def test_soft_bbs_inference_equals_log_domain(rng, alpha):
    x, y = _features(rng)
    d = softbbs.pairwise_distances(x, y)
    with torch.inference_mode():
        ref = softbbs.soft_bbs_log(d, alpha).exp()
        fast = softbbs.soft_bbs_inference(d, alpha)
        exact = softbbs.soft_bbs_log(d.double(), alpha).exp()  # float64 truth for the same distances
    if alpha >= 0.01:
        torch.testing.assert_close(fast.b, ref, atol=1e-6, rtol=1e-4)
    # |d/alpha| ~ 5e4 at alpha = 1e-4: float32 logits carry ~4e-3 absolute error in both paths
    err_ref = (ref.double() - exact).abs().max().item()
    err_fast = (fast.b.double() - exact).abs().max().item()
    assert err_fast <= 2 * err_ref + 1e-6, (err_fast, err_ref)


@pytest.mark.parametrize("alpha", [0.5, 0.05, 1e-3])
@pytest.mark.parametrize("spatial", [True, False])
def test_soft_map_gamma_inference_equals_log_domain(rng, alpha, spatial):
    """Soft map, gamma and the Procrustes solution, including far points whose rows of B~ underflow."""
    src = torch.tensor(rng.uniform(-1, 1, size=(2, 200, 3)), dtype=torch.float32)
    tgt = src[:, :150] + 0.01 * torch.tensor(rng.normal(size=(2, 150, 3)), dtype=torch.float32)
    src[:, -5:] += 50.0  # far away: B~ rows ~ 0, the exact fallback row softmax runs
    d = softbbs.pairwise_distances(src, tgt)
    temp = torch.tensor([0.3, 0.05])
    with torch.inference_mode():
        log_b = softbbs.soft_bbs_log(d, alpha)
        sb = softbbs.soft_bbs_inference(d, alpha)
        assert (sb.b.sum(dim=2) < 1e-20).any()
        q_ref = softbbs.soft_map(log_b, tgt)
        g_ref = softbbs.bbs_gamma(log_b, d if spatial else None, temp)
        q, g = softbbs.soft_map_gamma_inference(sb, tgt, d if spatial else None, temp)
        R0, t0, _, _ = solve_transform(src, tgt, log_b, temp, spatial_gamma=spatial)
        R1, t1, _, _ = solve_transform_inference(src, tgt, sb, temp, spatial_gamma=spatial)
    torch.testing.assert_close(q, q_ref, atol=2e-5, rtol=1e-4)
    torch.testing.assert_close(g, g_ref, atol=1e-6, rtol=1e-4)
    torch.testing.assert_close(R1, R0, atol=1e-5, rtol=0)
    torch.testing.assert_close(t1, t0, atol=1e-5, rtol=0)


def test_one_deep_pass_fast_equals_forward(rng):
    """A whole deep pass (embed, match, solve) of the inference path == DeepBBSNet.forward."""
    model = _model(ModelConfig(k=8, dgcnn_widths=[8, 16], emb_dims=16, n_heads=2, ff_dims=32))
    src = torch.tensor(rng.uniform(-20, 20, size=(1, 120, 3)), dtype=torch.float32)
    tgt = src + torch.tensor([0.5, -0.3, 0.1])
    with torch.enable_grad():  # reference: nn.Transformer and the log domain
        ref = model(src, tgt)
    with torch.inference_mode():
        s, q = src * model.scale, tgt * model.scale
        f_src, _ = model.point_features(s)
        f_tgt, _ = model.point_features(q)
        phi_src, phi_tgt = model.cross_cached(f_src, model.target_cache(f_tgt))
        temp = model.predict_temperature(phi_src, phi_tgt)
        R, t, q_hat, gamma = solve_transform_inference(s, q, model.match_inference(phi_src, phi_tgt), temp)
    torch.testing.assert_close(temp, ref.temperature.detach(), atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(R, ref.R.detach(), atol=1e-4, rtol=0)
    torch.testing.assert_close(t / model.scale, ref.t.detach(), atol=1e-3, rtol=0)
    torch.testing.assert_close(gamma, ref.gamma.detach(), atol=1e-5, rtol=1e-3)
    torch.testing.assert_close(q_hat / model.scale, ref.q_hat.detach(), atol=1e-3, rtol=0)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_inference_paths_on_cuda(rng):
    model = _model()
    f_src, f_tgt = _features(rng, b=1, n=64, m=48)
    ref = _reference_cross(model, f_src, f_tgt)
    with torch.inference_mode():
        got = model.to("cuda").cross(f_src.cuda(), f_tgt.cuda())
        sb_cpu = softbbs.soft_bbs_inference(softbbs.pairwise_distances(f_src, f_tgt), 0.1)
        sb_gpu = softbbs.soft_bbs_inference(softbbs.pairwise_distances(f_src.cuda(), f_tgt.cuda()), 0.1)
    for r, g in zip(ref, got):
        torch.testing.assert_close(g.cpu(), r, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(sb_gpu.b.cpu(), sb_cpu.b, atol=1e-5, rtol=1e-3)


def test_moving_knn_equals_tree_query(rng):
    """The refinement's candidate cache returns the exact k nearest targets as the source moves."""
    from deepbbs_ros.core.refine import NeighbourSearch, _MovingKnn

    tgt = torch.tensor(rng.uniform(-1, 1, size=(400, 3)), dtype=torch.float32)
    pts = torch.tensor(rng.uniform(-1, 1, size=(300, 3)), dtype=torch.float32)
    search = NeighbourSearch(tgt)
    knn = _MovingKnn(search, 8)
    for step in range(6):
        moved = pts + 0.02 * step * torch.tensor([1.0, -0.5, 0.2])  # drifts by up to 0.1
        d, i = knn.query(moved)
        d_ref, i_ref = search.query(moved, 8)
        assert torch.equal(i.sort(dim=1).values, i_ref.sort(dim=1).values)
        torch.testing.assert_close(d.sort(dim=1).values, d_ref, atol=1e-5, rtol=1e-5)
