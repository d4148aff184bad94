"""The DeepBBS embedding network: DGCNN + a shared cross-attention transformer + a temperature head.

Pipeline of one deep pass (all in *scaled* coordinates, ``x_scaled = model.scale * x_metres``)::

    f_src, f_tgt     = DGCNN(src), DGCNN(tgt)                 edge convs on a kNN graph of the xyz
    phi_src          = f_src + Transformer(f_src | f_tgt)     each cloud attends to the other
    phi_tgt          = f_tgt + Transformer(f_tgt | f_src)     (one set of weights, both directions)
    T                = clamp(head(mean_i phi_src - mean_j phi_tgt), T_min, T_max)
    log B~           = SoftBBS(||phi_src_i - phi_tgt_j||, alpha from phi_src)
    q^, gamma        = soft map, gamma_i = sum_j B~_ij exp(-||p_i - q_j|| / T)
    R, t             = weighted Procrustes(src -> q^, gamma)

Edge convolution: ``h_i = max_j W [x_j, x_i] = max_j (W1 x_j) + W2 x_i`` (exact, because W2 x_i does
not depend on j): the two linear maps run per point *before* the neighbours are gathered, then a
LayerNorm (no batch statistics: the same numbers in training and inference, at any batch size)
and a LeakyReLU(0.2), which is monotone and therefore commutes with the max.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from deepbbs_ros.config import ModelConfig
from deepbbs_ros.core import softbbs
from deepbbs_ros.core.procrustes import weighted_procrustes

__all__ = [
    "NetOutput",
    "DeepBBSNet",
    "TargetCache",
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


def knn_indices(xyz: torch.Tensor, k: int) -> torch.Tensor:
    """Indices of the k nearest points of every point (itself included): (B, N, 3) -> (B, N, k) int64.

    A scipy cKDTree on the CPU (a dense top-k of N x N distances is ~20x slower there), a dense
    top-k on other devices. Indices carry no gradient.
    """
    k = min(k, xyz.shape[1])
    if xyz.device.type == "cpu":
        from scipy.spatial import cKDTree

        pts = xyz.detach().numpy()
        idx = [cKDTree(p).query(p, k=k)[1].reshape(p.shape[0], k) for p in pts]
        return torch.from_numpy(np.stack(idx)).long()
    xx = (xyz * xyz).sum(-1)
    d2 = xx[:, :, None] + xx[:, None, :] - 2.0 * xyz @ xyz.transpose(1, 2)
    return d2.topk(k, dim=2, largest=False, sorted=False).indices


class EdgeConv(nn.Module):
    """``LeakyReLU(LayerNorm(max_{j in kNN(i)} W1 x_j + W2 x_i))``: (B, N, C_in) -> (B, N, C_out)."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.neighbour = nn.Linear(c_in, c_out, bias=False)
        self.centre = nn.Linear(c_in, c_out)
        self.norm = nn.LayerNorm(c_out)

    def forward(self, x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        b, n, k = idx.shape
        a = self.neighbour(x)  # (B, N, C) per point, before gathering
        c = a.shape[-1]
        offset = (torch.arange(b, device=x.device) * n)[:, None, None]
        gathered = a.reshape(b * n, c).index_select(0, (idx + offset).reshape(-1)).reshape(b, n, k, c)
        h = gathered.amax(dim=2) + self.centre(x)
        return nn.functional.leaky_relu(self.norm(h), 0.2)


class DGCNN(nn.Module):
    """Edge-conv stack on a kNN graph of the xyz; layer outputs concatenated, then a linear map."""

    def __init__(self, widths: list[int], emb_dims: int, k: int) -> None:
        super().__init__()
        self.k = k
        dims = [3, *widths]
        self.layers = nn.ModuleList(EdgeConv(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.out = nn.Linear(sum(widths), emb_dims)

    def forward(self, xyz: torch.Tensor, idx: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """xyz (B, N, 3) scaled -> features (B, N, E), kNN indices (B, N, k) (reusable: rigid-invariant)."""
        if idx is None:
            idx = knn_indices(xyz, self.k)
        x, outs = xyz, []
        for layer in self.layers:
            x = layer(x, idx)
            outs.append(x)
        return self.out(torch.cat(outs, dim=-1)), idx


# -- inference-only transformer: the weights of nn.Transformer, fused attention -----------------------
#
# nn.Transformer's decoder has no fused inference path and its encoder's fast path still materialises
# the attention matrices; ``F.scaled_dot_product_attention`` (a tiled flash kernel on the CPU) does
# not. The functions below compute exactly nn.Transformer's post-/pre-norm layers from its modules'
# weights (tests/test_inference_equivalence.py checks equality to ~1e-5); they are used only without
# autograd, so training runs nn.Transformer unchanged.


def _heads(x: torch.Tensor, n_heads: int) -> torch.Tensor:
    """(B, L, E) -> (B, H, L, E / H)."""
    b, n, e = x.shape
    return x.reshape(b, n, n_heads, e // n_heads).transpose(1, 2)


def _attention(
    attn: nn.MultiheadAttention, q: torch.Tensor, kv: torch.Tensor | None = None, *, x: torch.Tensor | None = None
) -> torch.Tensor:
    """Multi-head attention of ``x`` (B, L, E) onto keys/values; returns (B, L, E) after out_proj.

    ``q``: the already projected queries (B, H, L, hd) or None (then projected from ``x``);
    ``kv``: the projected keys and values stacked (2, B, H, S, hd), or None for self-attention on x.
    """
    e, h = attn.embed_dim, attn.num_heads
    w, bias = attn.in_proj_weight, attn.in_proj_bias
    if kv is None and q is None:  # self-attention: one matmul for q, k, v
        qkv = nn.functional.linear(x, w, bias)
        q, k, v = (_heads(t, h) for t in qkv.split(e, dim=-1))
    else:
        if q is None:
            q = _heads(nn.functional.linear(x, w[:e], None if bias is None else bias[:e]), h)
        k, v = kv[0], kv[1]
    o = nn.functional.scaled_dot_product_attention(q, k, v)
    b, _, n, _ = o.shape
    return attn.out_proj(o.transpose(1, 2).reshape(b, n, e))


def _project_kv(attn: nn.MultiheadAttention, mem: torch.Tensor) -> torch.Tensor:
    """Keys and values of ``mem`` (B, S, E): (2, B, H, S, hd)."""
    e, h = attn.embed_dim, attn.num_heads
    bias = attn.in_proj_bias
    kv = nn.functional.linear(mem, attn.in_proj_weight[e:], None if bias is None else bias[e:])
    k, v = kv.split(e, dim=-1)
    return torch.stack([_heads(k, h), _heads(v, h)])


def _project_q(attn: nn.MultiheadAttention, x: torch.Tensor) -> torch.Tensor:
    e, h = attn.embed_dim, attn.num_heads
    bias = attn.in_proj_bias
    return _heads(nn.functional.linear(x, attn.in_proj_weight[:e], None if bias is None else bias[:e]), h)


def _ff(layer: nn.Module, x: torch.Tensor) -> torch.Tensor:
    return layer.linear2(layer.activation(layer.linear1(x)))


def _sublayer(norm: nn.LayerNorm, x: torch.Tensor, f, norm_first: bool) -> torch.Tensor:
    """Residual sublayer as in nn.TransformerEncoderLayer/DecoderLayer (dropout is identity here)."""
    if norm_first:
        return x + f(norm(x))
    return norm(x + f(x))


def _encoder(enc: nn.TransformerEncoder, x: torch.Tensor) -> torch.Tensor:
    for layer in enc.layers:
        nf = layer.norm_first
        x = _sublayer(layer.norm1, x, lambda y, a=layer.self_attn: _attention(a, None, None, x=y), nf)
        x = _sublayer(layer.norm2, x, lambda y, lay=layer: _ff(lay, y), nf)
    return x if enc.norm is None else enc.norm(x)


def _decoder_self(layer: nn.TransformerDecoderLayer, x: torch.Tensor) -> torch.Tensor:
    """The decoder layer's first sublayer (self-attention): depends on the queries only."""
    return _sublayer(layer.norm1, x, lambda y: _attention(layer.self_attn, None, None, x=y), layer.norm_first)


def _decoder_rest(
    layer: nn.TransformerDecoderLayer, x: torch.Tensor, kv: torch.Tensor, q: torch.Tensor | None = None
) -> torch.Tensor:
    """Cross-attention (keys/values ``kv`` of the memory) and feed-forward sublayers of a decoder layer.

    ``q``: the cross-attention's projected queries when they are already known (post-norm only).
    """
    nf = layer.norm_first
    x = _sublayer(layer.norm2, x, lambda y: _attention(layer.multihead_attn, q, kv, x=y), nf)
    return _sublayer(layer.norm3, x, lambda y: _ff(layer, y), nf)


def _transformer_supported(tr: nn.Transformer) -> bool:
    """Layers whose computation the functional path reproduces (standard nn.Transformer layers)."""
    layers = [*tr.encoder.layers, *tr.decoder.layers]
    return all(
        type(layer) in (nn.TransformerEncoderLayer, nn.TransformerDecoderLayer)
        and all(
            a._qkv_same_embed_dim and a.bias_k is None and not a.add_zero_attn and a.batch_first
            for a in (getattr(layer, "self_attn", None), getattr(layer, "multihead_attn", None))
            if a is not None
        )
        for layer in layers
    )


class TargetCache(NamedTuple):
    """What the deep iterations reuse of a target cloud that does not move (inference only).

    f_tgt: (B, M, E) DGCNN features; memory_kv: per decoder layer, the keys/values of the encoded
    target (the memory the source attends to); tgt_self: per decoder layer, the output of the target
    queries' self-attention sublayer, and tgt_q: its cross-attention queries (None with norm_first).
    Only ``f_tgt`` is set when the model has no transformer or the functional path is unavailable.
    """

    f_tgt: torch.Tensor
    memory_kv: list[torch.Tensor] | None = None
    tgt_self: torch.Tensor | None = None
    tgt_q: torch.Tensor | None = None


class DeepBBSNet(nn.Module):
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

    def _fast_transformer(self) -> bool:
        """Use the functional SDPA transformer: no autograd, eval mode (dropout off), standard layers."""
        tr = self.transformer
        if tr is None or torch.is_grad_enabled() or self.training:
            return False
        ok = getattr(self, "_fast_ok", None)
        if ok is None:
            ok = self._fast_ok = _transformer_supported(tr)
        return ok

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

    def target_cache(self, f_tgt: torch.Tensor) -> TargetCache:
        """Precompute the target-only parts of :meth:`cross` (inference: no autograd, eval mode).

        The encoder output of the target, its keys/values for the source's cross-attention, and the
        target queries' self-attention sublayer do not depend on the source, so the deep iterations
        compute them once. f_tgt: (B, M, E) DGCNN features of the target.
        """
        if not self._fast_transformer():
            return TargetCache(f_tgt)
        tr = self.transformer
        mem = _encoder(tr.encoder, f_tgt)
        memory_kv = [_project_kv(layer.multihead_attn, mem) for layer in tr.decoder.layers]
        first = tr.decoder.layers[0]
        tgt_self = _decoder_self(first, f_tgt)
        tgt_q = None if first.norm_first else _project_q(first.multihead_attn, tgt_self)
        return TargetCache(f_tgt, memory_kv, tgt_self, tgt_q)

    def cross_cached(self, f_src: torch.Tensor, cache: TargetCache, *, source_cache: list | None = None
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`cross` with the target-only parts from :meth:`target_cache` (same numbers, to round-off).

        f_src: (B, N, E) source DGCNN features -> phi_src (B, N, E), phi_tgt (B, M, E).
        ``source_cache``: a list that receives the source's own :class:`TargetCache` (what
        :meth:`target_cache` would compute for these features: its encoder output's keys/values and its
        first self-attention sublayer are computed here anyway), for when this cloud becomes a target.
        """
        f_tgt = cache.f_tgt
        if cache.memory_kv is None or not self._fast_transformer():
            return self.cross(f_src, f_tgt)
        tr = self.transformer
        dec = tr.decoder.layers
        mem_src = _encoder(tr.encoder, f_src)
        # source queries attend to the (cached) encoded target; target queries to the encoded source
        y_src = f_src
        y_tgt = f_tgt
        kvs, first_self = [], None
        for i, layer in enumerate(dec):
            kv_src = _project_kv(layer.multihead_attn, mem_src)
            kvs.append(kv_src)
            if i == 0:
                y_tgt = _decoder_rest(layer, cache.tgt_self, kv_src, cache.tgt_q)
            else:
                y_tgt = _decoder_rest(layer, _decoder_self(layer, y_tgt), kv_src)
            self_out = _decoder_self(layer, y_src)
            first_self = self_out if i == 0 else first_self
            y_src = _decoder_rest(layer, self_out, cache.memory_kv[i])
        if source_cache is not None and first_self is not None:
            # tgt_q None: the first cross-attention projects its queries itself (the same numbers)
            source_cache.append(TargetCache(f_src, kvs, first_self, None))
        if tr.decoder.norm is not None:
            y_src, y_tgt = tr.decoder.norm(y_src), tr.decoder.norm(y_tgt)
        return f_src + y_src, f_tgt + y_tgt

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


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
