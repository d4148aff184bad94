"""Weighted Procrustes (Kabsch/Umeyama without scale), batched and differentiable.

Model: find R in SO(3) and t minimising ``sum_i w_i ||R x_i + t - y_i||^2``. With the weighted
centroids ``x_bar = sum_i w_i x_i / sum_i w_i`` (same for ``y_bar``) and the weighted cross-covariance
``H = sum_i w_i (x_i - x_bar)(y_i - y_bar)^T = U S V^T``, the solution is
``R = V diag(1, 1, det(V U^T)) U^T`` (a reflection is turned into the nearest rotation, det R = +1)
and ``t = y_bar - R x_bar``.
"""

from __future__ import annotations

import warnings

import torch

__all__ = ["weighted_procrustes", "apply_transform", "compose"]


def weighted_procrustes(
    source: torch.Tensor,
    target: torch.Tensor,
    weights: torch.Tensor | None = None,
    *,
    eps: float = 1e-8,
    warn_degenerate: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rigid transform that moves ``source`` onto ``target`` (p_target = R p_source + t).

    Args:
        source: (B, N, 3) or (N, 3) float points x_i.
        target: same shape as ``source``, the corresponding points y_i.
        weights: (B, N) or (N,) non-negative weights w_i, or None for uniform weights. Zero weights
            drop points; a batch element whose weights sum to ~0 falls back to uniform weights.
        eps: weight-sum and singular-value threshold.
        warn_degenerate: warn (like pytorch3d) when the cross-covariance has rank < 2 (collinear or
            coincident points): the rotation is then not unique. Costs one device sync.

    Returns:
        R: (B, 3, 3) (or (3, 3) for unbatched input) rotation, det R = +1.
        t: (B, 3) (or (3,)) translation, in the units of the points.
    """
    unbatched = source.dim() == 2
    if unbatched:
        source, target = source[None], target[None]
        weights = None if weights is None else weights[None]
    if source.shape != target.shape or source.dim() != 3 or source.shape[-1] != 3:
        raise ValueError(
            f"source and target must both be (B, N, 3), got {tuple(source.shape)} and {tuple(target.shape)}"
        )
    b, n, _ = source.shape
    if weights is None:
        weights = source.new_ones(b, n)
    elif weights.shape != (b, n):
        raise ValueError(f"weights must be (B, N) = {(b, n)}, got {tuple(weights.shape)}")
    weights = weights.to(source.dtype).clamp_min(0)
    wsum = weights.sum(dim=1, keepdim=True)
    # all-zero weights: uniform weights instead of a division by zero
    w = torch.where(wsum > eps, weights / wsum.clamp_min(eps), torch.full_like(weights, 1.0 / max(n, 1)))
    x_bar = torch.einsum("bn,bnc->bc", w, source)
    y_bar = torch.einsum("bn,bnc->bc", w, target)
    xc = source - x_bar[:, None]
    yc = target - y_bar[:, None]
    h = torch.einsum("bn,bni,bnj->bij", w, xc, yc)  # (B, 3, 3) weighted cross-covariance
    u, s, vh = torch.linalg.svd(h)
    if warn_degenerate:
        if n < 3 or bool((s[:, 1] <= eps * s[:, 0].clamp_min(eps)).any()):
            warnings.warn(
                "weighted_procrustes: the cross-covariance has rank < 2 (fewer than 3 weighted points, or "
                "collinear points): the rotation is not unique",
                RuntimeWarning,
                stacklevel=2,
            )
    v = vh.transpose(1, 2)
    ut = u.transpose(1, 2)
    d = torch.det(v @ ut)  # -1 for a reflection
    diag = torch.ones_like(s)
    diag = torch.cat([diag[:, :2], torch.sign(d)[:, None] + (d == 0).to(d.dtype)[:, None]], dim=1)
    r = v @ (diag[:, :, None] * ut)
    t = y_bar - torch.einsum("bij,bj->bi", r, x_bar)
    if unbatched:
        return r[0], t[0]
    return r, t


def apply_transform(points: torch.Tensor, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """``R p + t`` for points (B, N, 3) with R (B, 3, 3), t (B, 3)."""
    return points @ R.transpose(-1, -2) + t[..., None, :]


def compose(
    R2: torch.Tensor, t2: torch.Tensor, R1: torch.Tensor, t1: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``T2 @ T1``: first (R1, t1), then (R2, t2). Shapes (B, 3, 3), (B, 3)."""
    return R2 @ R1, torch.einsum("bij,bj->bi", R2, t1) + t2
