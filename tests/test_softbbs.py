"""SoftBBS: limits, stability, gamma on cut-away partners, sparse == dense."""

from __future__ import annotations

import numpy as np
import torch

from deepbbs_ros.core import softbbs


def _clouds(rng, b=2, n=60, m=50):
    x = torch.tensor(rng.normal(size=(b, n, 3)), dtype=torch.float64)
    y = torch.tensor(rng.normal(size=(b, m, 3)), dtype=torch.float64)
    return x, y


def test_pairwise_distances_match_cdist(rng):
    x, y = _clouds(rng)
    torch.testing.assert_close(softbbs.pairwise_distances(x, y), torch.cdist(x, y), atol=1e-6, rtol=0)


def test_alpha_is_xi_times_median_nn_distance(rng):
    x, _ = _clouds(rng, b=1, n=40)
    d = torch.cdist(x[0], x[0]) + torch.diag(torch.full((40,), np.inf, dtype=torch.float64))
    expected = 0.4 * d.min(dim=1).values.median()
    torch.testing.assert_close(softbbs.bbs_alpha(x, 0.4)[0], expected, atol=1e-6, rtol=0)


def test_soft_bbs_tends_to_hard_best_buddies(rng):
    x, y = _clouds(rng)
    d = softbbs.pairwise_distances(x, y)
    hard = softbbs.hard_best_buddies(d)
    assert hard.any()
    errs = [(softbbs.soft_bbs(d, a) - hard.double()).abs().max().item() for a in (0.3, 0.03, 0.003, 0.0003)]
    assert errs[-1] < 1e-6, errs
    assert all(e2 <= e1 + 1e-12 for e1, e2 in zip(errs, errs[1:])), errs


def test_soft_bbs_is_stable_for_far_points_and_tiny_alpha():
    """Per-row/column log-sum-exp: a point 1e4 units away still gets a finite, exact row."""
    x = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0], [1e4, 0, 0]]])
    y = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0], [1e4 + 0.5, 0, 0]]])
    d = softbbs.pairwise_distances(x, y)
    log_b = softbbs.soft_bbs_log(d, 1e-3)
    assert torch.isfinite(log_b[d < 1e3]).all()
    b = log_b.exp()
    torch.testing.assert_close(b.diagonal(dim1=1, dim2=2), torch.ones(1, 3))
    q_hat = softbbs.soft_map(log_b, y)
    torch.testing.assert_close(q_hat, y)


def test_soft_map_is_row_normalised_product(rng):
    x, y = _clouds(rng, b=1, n=20, m=30)
    d = softbbs.pairwise_distances(x, y)
    b = softbbs.soft_bbs(d, 0.5)
    expected = (b / b.sum(dim=2, keepdim=True)) @ y
    torch.testing.assert_close(softbbs.soft_map(softbbs.soft_bbs_log(d, 0.5), y), expected)
    # the product of the two softmins, computed directly
    direct = torch.softmax(-d / 0.5, dim=1) * torch.softmax(-d / 0.5, dim=2)
    torch.testing.assert_close(b, direct)


def test_gamma_low_where_partner_was_cut_away(rng):
    """Target = the source shifted slightly, minus a cut-away block: those source points get low gamma."""
    src = torch.tensor(rng.uniform(-5, 5, size=(1, 400, 3)))
    cut = src[0, :, 0] > 2.5
    tgt = (src + 0.02 * torch.tensor(rng.normal(size=(1, 400, 3))))[:, ~cut]
    d = softbbs.pairwise_distances(src, tgt)
    alpha = softbbs.bbs_alpha(src)
    log_b = softbbs.soft_bbs_log(d, alpha)
    gamma = softbbs.bbs_gamma(log_b, d, torch.tensor([1.0], dtype=torch.float64))[0]
    assert gamma[~cut].median() > 5 * gamma[cut].median()
    assert gamma[cut].mean() < 0.2 and gamma[~cut].mean() > 0.5
    # the spatial term only lowers gamma
    no_spatial = softbbs.bbs_gamma(log_b)[0]
    assert (no_spatial >= gamma - 1e-12).all()


def _knn(x, y, k):
    d = softbbs.pairwise_distances(x, y)
    dk, idx = d.topk(k, dim=2, largest=False)
    return d, dk, idx


def test_sparse_equals_dense_when_k_covers_all(rng):
    x, y = _clouds(rng, b=2, n=30, m=25)
    d, dk, idx = _knn(x, y, 25)
    dense = softbbs.soft_bbs_log(d, 0.2)
    sparse = softbbs.sparse_soft_bbs_log(dk, idx, 25, 0.2)
    torch.testing.assert_close(sparse, dense.gather(2, idx))
    torch.testing.assert_close(softbbs.sparse_soft_map(sparse, idx, y), softbbs.soft_map(dense, y))
    dense_gamma = softbbs.bbs_gamma(dense, d, torch.ones(2).double())
    torch.testing.assert_close(softbbs.sparse_gamma(sparse, dk, 1.0), dense_gamma)


def test_sparse_close_to_dense_with_few_neighbours(rng):
    x = torch.tensor(rng.uniform(-5, 5, size=(1, 300, 3)))
    y = x + 0.05 * torch.tensor(rng.normal(size=(1, 300, 3)))
    alpha = softbbs.bbs_alpha(x)
    d, dk, idx = _knn(x, y, 8)
    dense_map = softbbs.soft_map(softbbs.soft_bbs_log(d, alpha), y)
    sparse_map = softbbs.sparse_soft_map(softbbs.sparse_soft_bbs_log(dk, idx, 300, alpha), idx, y)
    err = (dense_map - sparse_map).norm(dim=2)
    spacing = softbbs.self_nn_distance(x).median()  # ~0.5 here
    assert err.max() < 0.02 * spacing and err.mean() < 0.002 * spacing, (err.max(), err.mean(), spacing)


def test_gradients_flow_through_soft_bbs(rng):
    x, y = _clouds(rng, b=1, n=20, m=20)
    x.requires_grad_(True)
    d = softbbs.pairwise_distances(x, y)
    log_b = softbbs.soft_bbs_log(d, softbbs.bbs_alpha(x))
    softbbs.soft_map(log_b, y).sum().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
