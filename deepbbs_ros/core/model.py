"""The DeepBBS embedding network: DGCNN + a shared cross-attention transformer + a temperature head.

Pipeline of one deep pass (all in *scaled* coordinates, ``x_scaled = model.scale * x_metres``)::

    f_src, f_tgt     = DGCNN(src), DGCNN(tgt)                 edge convs on a kNN graph of the xyz
    phi_src          = f_src + Transformer(f_src | f_tgt)     each cloud attends to the other
    phi_tgt          = f_tgt + Transformer(f_tgt | f_src)     (one set of weights, both directions)
    T                = clamp(head(mean_i phi_src - mean_j phi_tgt), T_min, T_max)
    log B~           = SoftBBS(||phi_src_i - phi_tgt_j||, alpha from phi_src)
    q^, gamma        = soft map, gamma_i = sum_j B~_ij exp(-||p_i - q_j|| / T)
    R, t             = weighted Procrustes(src -> q^, gamma)

The DGCNN is in core/dgcnn.py, the inference-only transformer (nn.Transformer's weights, fused attention) in
core/fast_transformer.py with its cached target in core/cached_cross.py, the solve (soft map, gamma, weighted
Procrustes) in core/solve.py.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from deepbbs_ros.config import ModelConfig
from deepbbs_ros.core import softbbs
from deepbbs_ros.core.cached_cross import CachedCross, TargetCache
from deepbbs_ros.core.dgcnn import DGCNN, EdgeConv, knn_indices
from deepbbs_ros.core.solve import solve_transform, solve_transform_inference

__all__ = [
    "NetOutput",
    "DeepBBSNet",
    "TargetCache",
    "DGCNN",
    "EdgeConv",
    "knn_indices",
    "solve_transform",
    "solve_transform_inference",
    "count_parameters",
]


class NetOutput(NamedTuple):
    """One deep pass.

    R: (B, 3, 3) rotation, t: (B, 3) translation in metres (p_target = R p_source + t);
    q_hat: (B, N, 3) soft-mapped target point of every source point, metres (target frame);
    gamma: (B, N) confidence weights; temperature: (B,) T in scaled units.
    """

    R: torch.Tensor
    t: torch.Tensor
    q_hat: torch.Tensor
    gamma: torch.Tensor
    temperature: torch.Tensor


class DeepBBSNet(CachedCross, nn.Module):
    """DGCNN + transformer point embedding and temperature head; :meth:`forward` is one deep pass."""

    def __init__(self, cfg: ModelConfig | None = None) -> None:
        super().__init__()
        cfg = cfg or ModelConfig()
        cfg.validate()
        self.cfg = cfg
        self.scale = float(cfg.scale)
        self.dgcnn = DGCNN(list(cfg.dgcnn_widths), cfg.emb_dims, cfg.k)
        self.transformer = None
        if cfg.n_blocks > 0:
            self.transformer = nn.Transformer(
                d_model=cfg.emb_dims,
                nhead=cfg.n_heads,
                num_encoder_layers=cfg.n_blocks,
                num_decoder_layers=cfg.n_blocks,
                dim_feedforward=cfg.ff_dims,
                dropout=cfg.dropout,
                batch_first=True,
            )
        hidden = max(16, cfg.emb_dims // 2)
        self.temp_head = nn.Sequential(nn.Linear(cfg.emb_dims, hidden), nn.ReLU(), nn.Linear(hidden, 1))

    # -- the pieces (scaled coordinates) ---------------------------------------------------------
    def point_features(self, xyz: torch.Tensor, idx: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """DGCNN features of one cloud: xyz (B, N, 3) scaled -> (B, N, E), kNN indices (B, N, k)."""
        return self.dgcnn(xyz, idx)

    def cross(self, f_src: torch.Tensor, f_tgt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``phi = f + Transformer(f | other cloud)`` for both clouds with shared weights."""
        if self.transformer is None:
            return f_src, f_tgt
        if self._fast_transformer():
            return self.cross_cached(f_src, self.target_cache(f_tgt))
        if f_src.shape == f_tgt.shape:  # both directions in one batch
            b = f_src.shape[0]
            memory_from = torch.cat([f_tgt, f_src], dim=0)
            queries = torch.cat([f_src, f_tgt], dim=0)
            delta = self.transformer(memory_from, queries)
            return f_src + delta[:b], f_tgt + delta[b:]
        return f_src + self.transformer(f_tgt, f_src), f_tgt + self.transformer(f_src, f_tgt)

    def predict_temperature(self, phi_src: torch.Tensor, phi_tgt: torch.Tensor) -> torch.Tensor:
        """T (B,) from ``mean_i phi_src - mean_j phi_tgt``, clamped to [temperature_min, temperature_max]."""
        x = phi_src.mean(dim=1) - phi_tgt.mean(dim=1)
        t = nn.functional.softplus(self.temp_head(x)[:, 0])
        return t.clamp(self.cfg.temperature_min, self.cfg.temperature_max)

    def embed(
        self, src: torch.Tensor, tgt: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """src (B, N, 3), tgt (B, M, 3), already scaled -> phi_src (B, N, E), phi_tgt (B, M, E), T (B,)."""
        f_src, _ = self.point_features(src)
        f_tgt, _ = self.point_features(tgt)
        phi_src, phi_tgt = self.cross(f_src, f_tgt)
        return phi_src, phi_tgt, self.predict_temperature(phi_src, phi_tgt)

    def match(self, phi_src: torch.Tensor, phi_tgt: torch.Tensor) -> torch.Tensor:
        """``log B~`` (B, N, M): SoftBBS on feature distances, alpha = xi * median NN distance of phi_src."""
        alpha = softbbs.bbs_alpha(phi_src, self.cfg.xi)
        return softbbs.soft_bbs_log(softbbs.pairwise_distances(phi_src, phi_tgt), alpha)

    def match_inference(self, phi_src: torch.Tensor, phi_tgt: torch.Tensor) -> softbbs.SoftBBSInference:
        """:meth:`match` for inference: ``B~`` (B, N, M) as a product of two softmaxes (no log domain).

        ``result.b`` equals ``match(...).exp()`` to float round-off; use with :func:`solve_transform_inference`.
        """
        alpha = softbbs.bbs_alpha(phi_src, self.cfg.xi)
        return softbbs.soft_bbs_inference(softbbs.pairwise_distances(phi_src, phi_tgt), alpha, inplace=True)

    # -- one deep pass, in metres ----------------------------------------------------------------
    def forward(
        self,
        src: torch.Tensor,
        tgt: torch.Tensor,
        *,
        temperature: torch.Tensor | float | None = None,
        use_gamma: bool = True,
        spatial_gamma: bool = True,
    ) -> NetOutput:
        """One differentiable deep pass: src (B, N, 3), tgt (B, M, 3) in metres -> :class:`NetOutput`.

        ``temperature`` (scaled units) replaces the predicted T when given (ablation / halving).
        """
        s = src * self.scale
        q = tgt * self.scale
        phi_src, phi_tgt, t_pred = self.embed(s, q)
        log_b = self.match(phi_src, phi_tgt)
        temp = t_pred if temperature is None else torch.as_tensor(temperature, dtype=s.dtype, device=s.device)
        temp = temp.expand(s.shape[0]) if temp.dim() == 0 else temp
        R, t, q_hat, gamma = solve_transform(s, q, log_b, temp, use_gamma=use_gamma, spatial_gamma=spatial_gamma)
        return NetOutput(R, t / self.scale, q_hat / self.scale, gamma, t_pred if temperature is None else temp)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
