"""DeepBBSNet: shapes, batched == unbatched, gradients to every parameter, CPU == CUDA."""

from __future__ import annotations

import pytest
import torch

from deepbbs_ros.config import ModelConfig
from deepbbs_ros.core.model import DeepBBSNet, EdgeConv, NetOutput, knn_indices

TINY = ModelConfig(k=6, dgcnn_widths=[8, 8, 16], emb_dims=16, n_heads=2, ff_dims=32)


def _pair(rng, b=2, n=64, m=64):
    src = torch.tensor(rng.uniform(-20, 20, size=(b, n, 3)), dtype=torch.float32)
    tgt = torch.tensor(rng.uniform(-20, 20, size=(b, m, 3)), dtype=torch.float32)
    return src, tgt


def _model(seed=0, cfg=TINY):
    torch.manual_seed(seed)
    return DeepBBSNet(cfg).eval()


def test_forward_shapes_and_rotation(rng):
    src, tgt = _pair(rng, n=64, m=48)
    out = _model()(src, tgt)
    assert isinstance(out, NetOutput)
    assert out.R.shape == (2, 3, 3) and out.t.shape == (2, 3)
    assert out.q_hat.shape == (2, 64, 3) and out.gamma.shape == (2, 64) and out.temperature.shape == (2,)
    torch.testing.assert_close(torch.det(out.R), torch.ones(2), atol=1e-5, rtol=0)
    assert ((out.temperature >= TINY.temperature_min) & (out.temperature <= TINY.temperature_max)).all()
    # q_hat is a convex combination of target points (metres, target frame)
    assert (out.q_hat.amax(dim=1) <= tgt.amax(dim=1) + 1e-4).all()


def test_edge_conv_equals_explicit_w_xj_xi(rng):
    """max_j W[x_j, x_i] computed per point before gathering == the explicit edge features."""
    torch.manual_seed(0)
    conv = EdgeConv(3, 5)
    x = torch.tensor(rng.normal(size=(2, 30, 3)), dtype=torch.float32)
    idx = knn_indices(x, 4)
    xj = torch.stack([x[b][idx[b]] for b in range(2)])  # (B, N, k, 3)
    xi = x[:, :, None].expand_as(xj)
    h = (xj @ conv.neighbour.weight.T + xi @ conv.centre.weight.T + conv.centre.bias).amax(dim=2)
    expected = torch.nn.functional.leaky_relu(conv.norm(h), 0.2)
    torch.testing.assert_close(conv(x, idx), expected)


def test_knn_includes_self_and_matches_dense(rng):
    x = torch.tensor(rng.normal(size=(1, 50, 3)), dtype=torch.float32)
    idx = knn_indices(x, 5)
    d = torch.cdist(x, x)
    expected = d.topk(5, dim=2, largest=False).indices
    assert torch.equal(idx.sort(dim=2).values, expected.sort(dim=2).values)


def test_batched_equals_unbatched(rng):
    model = _model()
    src, tgt = _pair(rng, b=3)
    with torch.inference_mode():
        out = model(src, tgt)
        for i in range(3):
            one = model(src[i : i + 1], tgt[i : i + 1])
            torch.testing.assert_close(one.R[0], out.R[i], atol=1e-5, rtol=0)
            torch.testing.assert_close(one.t[0], out.t[i], atol=1e-4, rtol=0)
            torch.testing.assert_close(one.gamma[0], out.gamma[i], atol=1e-5, rtol=1e-4)


def test_different_sizes_use_both_transformer_directions(rng):
    src, tgt = _pair(rng, b=1, n=40, m=55)
    out = _model()(src, tgt)
    assert out.q_hat.shape == (1, 40, 3)


def test_gradients_reach_every_parameter(rng):
    model = _model().train()
    src, tgt = _pair(rng)
    tgt = src @ torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]).T + 1.0
    out = model(src, tgt)
    loss = (out.R - torch.eye(3)).square().sum() + out.t.square().sum() + out.gamma.mean()
    loss.backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not torch.isfinite(p.grad).all()]
    assert not missing, missing
    zero = [n for n, p in model.named_parameters() if p.grad.abs().sum() == 0]
    assert not zero, zero


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cpu_and_cuda_agree(rng):
    model = _model()
    src, tgt = _pair(rng)
    with torch.inference_mode():
        cpu = model(src, tgt)
        gpu = model.to("cuda")(src.cuda(), tgt.cuda())
    for a, b in zip(cpu, gpu):
        torch.testing.assert_close(b.cpu(), a, atol=1e-3, rtol=1e-3)
