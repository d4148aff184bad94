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

Modules: the distances and alpha in core/bbs_distances.py, inference in core/softbbs_inference.py (every name is
imported from here too); the dense and sparse training functions here.
"""

from __future__ import annotations

import torch

from deepbbs_ros.core.bbs_distances import (
    _MIN_ALPHA,
    bbs_alpha,
    pairwise_distances,
    self_nn_distance,
    squared_distances,
)
from deepbbs_ros.core.softbbs_inference import SoftBBSInference, soft_bbs_inference, soft_map_gamma_inference

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
