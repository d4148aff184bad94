"""Soft best-buddy similarity (SoftBBS), soft map and confidence weights (DeepBBS, section 3).

For source points p_i and target points q_j with distances ``D*_ij`` (in feature space for the
network, in 3D for the DeepBBS++ refinement)::

    B~_ij   = softmin_i(D*_ij / alpha) * softmin_j(D*_ij / alpha)
    alpha   = xi * median_i( min_{k != i} ||phi_p_i - phi_p_k|| )          (over the source)
    q^_i    = sum_j (B~_ij / sum_j' B~_ij') q_j                              (soft map)
    gamma_i = sum_j B~_ij * exp(-D_ij / T)                                   (D: 3D distance)

Both softmins are evaluated in the log domain with their own log-sum-exp, per column and per row:
``log B~ = (-D*/alpha - lse_i) + (-D*/alpha - lse_j)``. (The reference code subtracts one global
maximum before exponentiating, which underflows for far-apart points.) ``B~_ij`` tends to the hard
best-buddy indicator (i and j are each other's nearest neighbour) as alpha -> 0.

Dense functions work on (B, N, M) matrices; the ``sparse_*`` functions work on the k nearest targets
of every source point, (B, N, k) distances with (B, N, k) target indices, for the fast refinement.

Inference (``*_inference``, no gradients): ``B~`` is the product of a row softmax and a column
softmax of the logits ``-D*/alpha``, each computed with its own maximum (as stable as the log
domain), so the whole match + soft map + gamma costs three exponentials over the N x M matrix
instead of four log-sum-exps plus maxima. Exponents are clamped at ``-87`` first: float32 ``exp``
of smaller arguments yields subnormal numbers, which the vectorised CPU kernel computes ~10-40x
slower, and each such term changes a sum by < 1.7e-38 (float round-off). The training path keeps
the log domain and its gradients.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

__all__ = [
    "pairwise_distances",
    "squared_distances",
    "self_nn_distance",
    "bbs_alpha",
    "soft_bbs_log",
    "soft_bbs",
    "soft_map",
    "bbs_gamma",
    "hard_best_buddies",
    "sparse_soft_bbs_log",
    "sparse_soft_map",
    "sparse_gamma",
    "SoftBBSInference",
    "soft_bbs_inference",
    "soft_map_gamma_inference",
]

_MIN_ALPHA = 1e-8
# exp(x) for x < _EXP_FLOOR is subnormal in float32 (slow on CPUs) and below float round-off of any
# sum it enters here; inference clamps exponents at this floor.
_EXP_FLOOR = -87.0


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


def soft_bbs_log(d: torch.Tensor, alpha: torch.Tensor | float) -> torch.Tensor:
    """``log B~``: d (B, N, M) distances, alpha (B,) or float -> (B, N, M), per-row/column log-sum-exp."""
    if not torch.is_tensor(alpha):
        alpha = d.new_full((d.shape[0],), float(alpha))
    logits = -d / alpha.clamp_min(_MIN_ALPHA)[:, None, None]
    log_row = logits - torch.logsumexp(logits, dim=2, keepdim=True)  # softmin over targets j, per source i
    log_col = logits - torch.logsumexp(logits, dim=1, keepdim=True)  # softmin over sources i, per target j
    return log_row + log_col


def soft_bbs(d: torch.Tensor, alpha: torch.Tensor | float) -> torch.Tensor:
    """``B~`` (B, N, M) in [0, 1]; see :func:`soft_bbs_log`."""
    return soft_bbs_log(d, alpha).exp()


def soft_map(log_b: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``q^_i = sum_j softmax_j(log B~_i) q_j``: log_b (B, N, M), target (B, M, 3) -> (B, N, 3).

    The row normalisation ``B~_ij / sum_j B~_ij`` is a softmax of ``log B~`` over j: stable even when
    every ``B~_ij`` of a row underflows.
    """
    return torch.softmax(log_b, dim=2) @ target


def bbs_gamma(
    log_b: torch.Tensor, d3: torch.Tensor | None = None, temperature: torch.Tensor | None = None
) -> torch.Tensor:
    """``gamma_i = sum_j B~_ij exp(-D_ij / T)``: (B, N).

    Args:
        log_b: (B, N, M) ``log B~``.
        d3: (B, N, M) 3D distances D_ij, or None for ``gamma_i = sum_j B~_ij`` (no spatial term).
        temperature: (B,) T > 0 (same units as ``d3``); required with ``d3``.
    """
    if d3 is None:
        return torch.logsumexp(log_b, dim=2).exp()
    return torch.logsumexp(log_b - d3 / temperature[:, None, None], dim=2).exp()


def hard_best_buddies(d: torch.Tensor) -> torch.Tensor:
    """Hard best buddies: bool (B, N, M), True where j = argmin_j d_ij and i = argmin_i d_ij."""
    row = d.argmin(dim=2, keepdim=True)  # (B, N, 1)
    col = d.argmin(dim=1, keepdim=True)  # (B, 1, M)
    m = d.shape[2]
    n = d.shape[1]
    is_row_min = torch.arange(m, device=d.device)[None, None, :] == row
    is_col_min = torch.arange(n, device=d.device)[None, :, None] == col
    return is_row_min & is_col_min


# -- inference (no gradients): B~ as a product of two softmaxes -----------------------------------


class SoftBBSInference(NamedTuple):
    """``B~`` for inference. b: (B, N, M) B~_ij; logits: (B, N, M) ``-D*/alpha``; lse_col: (B, M)
    per-column log-sum-exp of the logits (the soft map's fallback for rows whose B~ underflows)."""

    b: torch.Tensor
    logits: torch.Tensor
    lse_col: torch.Tensor


def _softmax_parts(logits: torch.Tensor, dim: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """exp(logits - max) (exponent clamped at the floor), its sum and the max along ``dim`` (keepdim)."""
    m = logits.amax(dim=dim, keepdim=True)
    e = torch.sub(logits, m).clamp_min_(_EXP_FLOOR).exp_()
    return e, e.sum(dim=dim, keepdim=True), m


@torch.no_grad()
def soft_bbs_inference(d: torch.Tensor, alpha: torch.Tensor | float, *, inplace: bool = False) -> SoftBBSInference:
    """``B~ = softmax_j(-D*/alpha) * softmax_i(-D*/alpha)`` with two exponentials (no gradients).

    Equals ``soft_bbs_log(d, alpha).exp()`` to float round-off. d: (B, N, M), alpha: (B,) or float;
    ``inplace``: d's storage becomes the returned logits (d is a scratch matrix of the caller).
    """
    if not torch.is_tensor(alpha):
        alpha = d.new_full((d.shape[0],), float(alpha))
    scale = (-1.0 / alpha.clamp_min(_MIN_ALPHA))[:, None, None]
    logits = d.mul_(scale) if inplace else d * scale
    e_row, s_row, _ = _softmax_parts(logits, 2)
    e_col, s_col, m_col = _softmax_parts(logits, 1)
    b = e_row.mul_(e_col).mul_(s_row.reciprocal_()).mul_(s_col.reciprocal())
    del e_col
    lse_col = (s_col.log_() + m_col)[:, 0, :]
    return SoftBBSInference(b, logits, lse_col)


@torch.no_grad()
def soft_map_gamma_inference(
    sb: SoftBBSInference,
    target: torch.Tensor,
    d3: torch.Tensor | None = None,
    temperature: torch.Tensor | None = None,
    *,
    tiny: float = 1e-20,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Soft map and gamma from :func:`soft_bbs_inference` (equal to :func:`soft_map` and :func:`bbs_gamma`
    of ``log B~`` to float round-off).

    ``q^_i = (B~ Q)_i / sum_j B~_ij`` with one (B, N, M) x (B, M, 4) matmul; rows whose sum is below
    ``tiny`` (every B~_ij of the row tiny) are recomputed exactly as the softmax over j of
    ``log B~_ij = 2 logits_ij - lse_col_j - lse_row_i`` (lse_row cancels in the normalisation).
    ``gamma_i = sum_j B~_ij exp(-D_ij / T)`` (or ``sum_j B~_ij`` when d3 is None).

    Args:
        sb: from :func:`soft_bbs_inference`; target: (B, M, 3); d3: (B, N, M) 3D distances or None;
        temperature: (B,) T (units of d3), required with d3.
    Returns:
        q_hat (B, N, 3), gamma (B, N).
    """
    b = sb.b
    ones = target.new_ones(target.shape[:-1] + (1,))
    num = torch.bmm(b, torch.cat([target, ones], dim=-1))  # (B, N, 4): sum_j B~_ij q_j, sum_j B~_ij
    row_sum = num[..., 3]
    q_hat = num[..., :3] / row_sum.clamp_min(tiny)[..., None]
    low = row_sum < tiny
    if bool(low.any()):
        for k in range(b.shape[0]):
            rows = low[k].nonzero()[:, 0]
            if rows.numel():
                w = torch.softmax(2.0 * sb.logits[k, rows] - sb.lse_col[k][None], dim=1)
                q_hat[k, rows] = w @ target[k]
    if d3 is None:
        return q_hat, row_sum
    h = d3.mul((-1.0 / temperature)[:, None, None]).clamp_min_(_EXP_FLOOR).exp_()
    return q_hat, h.mul_(b).sum(dim=2)


# -- sparse (k nearest targets per source point) --------------------------------------------------


def sparse_soft_bbs_log(d: torch.Tensor, idx: torch.Tensor, m: int, alpha: torch.Tensor | float) -> torch.Tensor:
    """``log B~`` restricted to the k nearest targets of each source point.

    Args:
        d: (B, N, k) distances from source point i to its k nearest targets.
        idx: (B, N, k) int64 indices of those targets in [0, m).
        m: number of target points.
        alpha: (B,) or float.

    Returns:
        (B, N, k) ``log B~_ij`` for the listed pairs. The column log-sum-exp runs over the source
        points that list target j (a per-column maximum, then a scatter-add), i.e. the dense value
        with the pairs outside the kNN graph treated as zero.
    """
    b, n, k = d.shape
    if not torch.is_tensor(alpha):
        alpha = d.new_full((b,), float(alpha))
    logits = -d / alpha.clamp_min(_MIN_ALPHA)[:, None, None]
    log_row = logits - torch.logsumexp(logits, dim=2, keepdim=True)
    flat_idx = idx.reshape(b, n * k)
    flat = logits.reshape(b, n * k)
    col_max = torch.full((b, m), float("-inf"), dtype=d.dtype, device=d.device)
    col_max = col_max.scatter_reduce(1, flat_idx, flat, reduce="amax", include_self=True)
    shift = col_max.gather(1, flat_idx)
    col_sum = torch.zeros((b, m), dtype=d.dtype, device=d.device).scatter_add(1, flat_idx, (flat - shift).exp())
    col_lse = col_sum.clamp_min(1e-30).log() + col_max.clamp_min(-1e30)
    log_col = flat - col_lse.gather(1, flat_idx)
    return log_row + log_col.reshape(b, n, k)


def sparse_soft_map(log_b: torch.Tensor, idx: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Soft map over the kNN lists: log_b (B, N, k), idx (B, N, k), target (B, M, 3) -> (B, N, 3)."""
    b, n, k = idx.shape
    w = torch.softmax(log_b, dim=2)
    q = target.gather(1, idx.reshape(b, n * k, 1).expand(-1, -1, 3)).reshape(b, n, k, 3)
    return (w[..., None] * q).sum(dim=2)


def sparse_gamma(log_b: torch.Tensor, d3: torch.Tensor | None = None, temperature: float | None = None) -> torch.Tensor:
    """``gamma_i`` over the kNN lists: log_b, d3 (B, N, k), temperature float -> (B, N)."""
    if d3 is None:
        return torch.logsumexp(log_b, dim=2).exp()
    return torch.logsumexp(log_b - d3 / temperature, dim=2).exp()
