"""The solve of a deep pass (core/model.py): soft map, gamma weights, weighted Procrustes (no ROS)."""

from __future__ import annotations

import torch

from deepbbs_ros.core import softbbs
from deepbbs_ros.core.procrustes import weighted_procrustes

__all__ = ["solve_transform", "solve_transform_inference"]


def solve_transform(
    src: torch.Tensor,
    tgt: torch.Tensor,
    log_b: torch.Tensor,
    temperature: torch.Tensor,
    *,
    use_gamma: bool = True,
    spatial_gamma: bool = True,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Soft map + gamma + weighted Procrustes.

    Args:
        src: (B, N, 3), tgt: (B, M, 3) in the same (scaled) units; log_b: (B, N, M) ``log B~``;
        temperature: (B,) T in those units.
    Returns:
        R (B, 3, 3), t (B, 3), q_hat (B, N, 3), gamma (B, N) (Procrustes uses uniform weights when
        ``use_gamma`` is False).
    """
    q_hat = softbbs.soft_map(log_b, tgt)
    d3 = softbbs.pairwise_distances(src, tgt) if spatial_gamma else None
    gamma = softbbs.bbs_gamma(log_b, d3, temperature)
    weights = gamma if use_gamma else torch.ones_like(gamma)
    R, t = weighted_procrustes(src, q_hat, weights, warn_degenerate=not torch.is_grad_enabled())
    return R, t, q_hat, gamma


@torch.no_grad()
def solve_transform_inference(
    src: torch.Tensor,
    tgt: torch.Tensor,
    sb: softbbs.SoftBBSInference,
    temperature: torch.Tensor,
    *,
    use_gamma: bool = True,
    spatial_gamma: bool = True,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`solve_transform` from :meth:`DeepBBSNet.match_inference` (no gradients; same results to
    float round-off). src (B, N, 3), tgt (B, M, 3) scaled; temperature (B,) -> R, t, q_hat, gamma."""
    d3 = softbbs.pairwise_distances(src, tgt) if spatial_gamma else None
    q_hat, gamma = softbbs.soft_map_gamma_inference(sb, tgt, d3, temperature)
    weights = gamma if use_gamma else torch.ones_like(gamma)
    R, t = weighted_procrustes(src, q_hat, weights, warn_degenerate=True)
    return R, t, q_hat, gamma
