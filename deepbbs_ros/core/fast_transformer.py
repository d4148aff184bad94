"""The inference-only transformer of the DeepBBS embedding (core/model.py): the weights of nn.Transformer, fused
attention (no ROS).

nn.Transformer's decoder has no fused inference path and its encoder's fast path still materialises
the attention matrices; ``F.scaled_dot_product_attention`` (a tiled flash kernel on the CPU) does
not. The functions below compute exactly nn.Transformer's post-/pre-norm layers from its modules'
weights (tests/test_inference_equivalence.py checks equality to ~1e-5); they are used only without
autograd, so training runs nn.Transformer unchanged.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["decoder_rest", "decoder_self", "encode", "project_kv", "project_q", "transformer_supported"]


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


def project_kv(attn: nn.MultiheadAttention, mem: torch.Tensor) -> torch.Tensor:
    """Keys and values of ``mem`` (B, S, E): (2, B, H, S, hd)."""
    e, h = attn.embed_dim, attn.num_heads
    bias = attn.in_proj_bias
    kv = nn.functional.linear(mem, attn.in_proj_weight[e:], None if bias is None else bias[e:])
    k, v = kv.split(e, dim=-1)
    return torch.stack([_heads(k, h), _heads(v, h)])


def project_q(attn: nn.MultiheadAttention, x: torch.Tensor) -> torch.Tensor:
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


def encode(enc: nn.TransformerEncoder, x: torch.Tensor) -> torch.Tensor:
    for layer in enc.layers:
        nf = layer.norm_first
        x = _sublayer(layer.norm1, x, lambda y, a=layer.self_attn: _attention(a, None, None, x=y), nf)
        x = _sublayer(layer.norm2, x, lambda y, lay=layer: _ff(lay, y), nf)
    return x if enc.norm is None else enc.norm(x)


def decoder_self(layer: nn.TransformerDecoderLayer, x: torch.Tensor) -> torch.Tensor:
    """The decoder layer's first sublayer (self-attention): depends on the queries only."""
    return _sublayer(layer.norm1, x, lambda y: _attention(layer.self_attn, None, None, x=y), layer.norm_first)


def decoder_rest(
    layer: nn.TransformerDecoderLayer, x: torch.Tensor, kv: torch.Tensor, q: torch.Tensor | None = None
) -> torch.Tensor:
    """Cross-attention (keys/values ``kv`` of the memory) and feed-forward sublayers of a decoder layer.

    ``q``: the cross-attention's projected queries when they are already known (post-norm only).
    """
    nf = layer.norm_first
    x = _sublayer(layer.norm2, x, lambda y: _attention(layer.multihead_attn, q, kv, x=y), nf)
    return _sublayer(layer.norm3, x, lambda y: _ff(layer, y), nf)


def transformer_supported(tr: nn.Transformer) -> bool:
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
