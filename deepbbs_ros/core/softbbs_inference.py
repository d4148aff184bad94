"""SoftBBS for inference (no gradients; core/softbbs.py's module docstring gives the equations): ``B~`` as the
product of a row softmax and a column softmax of the logits ``-D*/alpha`` (:func:`soft_bbs_inference`), then the
soft map and gamma with one matmul (:func:`soft_map_gamma_inference`). Exponents are clamped at ``_EXP_FLOOR``.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from deepbbs_ros.core.bbs_distances import _MIN_ALPHA

# exp(x) for x < _EXP_FLOOR is subnormal in float32 (slow on CPUs) and below float round-off of any
# sum it enters here; inference clamps exponents at this floor.
_EXP_FLOOR = -87.0


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
