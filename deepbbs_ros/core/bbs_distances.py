"""The distances SoftBBS works on and its temperature (DeepBBS, section 3): ``||x_i - y_j||`` of feature or 3D
points (one GEMM), each point's distance to its nearest other point, and ``alpha = xi * median_i min_{k != i}
||x_i - x_k||`` over the source (:func:`bbs_alpha`). Matching on them: core/softbbs.py.
"""

from __future__ import annotations

import torch

_MIN_ALPHA = 1e-8


def _no_grad(*tensors: torch.Tensor) -> bool:
    return not torch.is_grad_enabled() or not any(t.requires_grad for t in tensors)


def pairwise_distances(x: torch.Tensor, y: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """Euclidean distances ``||x_i - y_j||``: x (B, N, C), y (B, M, C) -> (B, N, M).

    Uses ``|x|^2 + |y|^2 - 2 x.y`` (one matmul), clamped at ``eps`` before the square root so the
    gradient stays finite for coincident points.
    """
    if _no_grad(x, y):  # inference: one GEMM, then in place
        return squared_distances(x, y).clamp_min_(eps).sqrt_()
    xx = (x * x).sum(-1, keepdim=True)
    yy = (y * y).sum(-1)[:, None, :]
    d2 = torch.baddbmm(xx + yy, x, y.transpose(1, 2), alpha=-2.0)
    return d2.clamp_min(eps).sqrt()


def squared_distances(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``|x_i|^2 + |y_j|^2 - 2 x_i.y_j`` as one GEMM of augmented vectors ``[-2x, |x|^2, 1] . [y, 1, |y|^2]``:
    x (B, N, C), y (B, M, C) -> (B, N, M) (may be slightly negative by round-off; no broadcast copies)."""
    xx = (x * x).sum(-1, keepdim=True)
    yy = (y * y).sum(-1, keepdim=True)
    xa = torch.cat([x * -2.0, xx, torch.ones_like(xx)], dim=-1)
    ya = torch.cat([y, torch.ones_like(yy), yy], dim=-1)
    return torch.bmm(xa, ya.transpose(1, 2))


def self_nn_distance(x: torch.Tensor) -> torch.Tensor:
    """Distance of every point to its nearest *other* point: x (B, N, C) -> (B, N)."""
    n = x.shape[1]
    if _no_grad(x):
        # min then sqrt (monotone: the same numbers) on squared distances, diagonal excluded in place
        d2 = squared_distances(x, x)
        d2.diagonal(dim1=1, dim2=2).fill_(float("inf"))
        return d2.amin(dim=2).clamp_min_(1e-12).sqrt_()
    d = pairwise_distances(x, x)
    d = d + torch.diag(x.new_full((n,), float("inf")))[None]
    return d.min(dim=2).values


def bbs_alpha(x: torch.Tensor, xi: float = 0.4) -> torch.Tensor:
    """``alpha = xi * median_i min_{k != i} ||x_i - x_k||`` over the source: x (B, N, C) -> (B,)."""
    return (xi * self_nn_distance(x).median(dim=1).values).clamp_min(_MIN_ALPHA)
