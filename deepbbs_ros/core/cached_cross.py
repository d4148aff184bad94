"""The transformer's inference path with the target's own parts kept (no autograd, eval mode): :class:`TargetCache`
and :class:`CachedCross` (``target_cache``, ``cross_cached``, and whether the functional SDPA transformer of
core/fast_transformer.py runs), a mixin of core/model.py's ``DeepBBSNet``, whose ``cross`` it falls back to."""

from __future__ import annotations

from typing import NamedTuple

import torch

from deepbbs_ros.core.fast_transformer import (
    decoder_rest,
    decoder_self,
    encode,
    project_kv,
    project_q,
    transformer_supported,
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


class CachedCross:
    """The cached cross-attention of a :class:`~deepbbs_ros.core.model.DeepBBSNet` (which holds ``transformer``)."""

    def _fast_transformer(self) -> bool:
        """Use the functional SDPA transformer: no autograd, eval mode (dropout off), standard layers."""
        tr = self.transformer
        if tr is None or torch.is_grad_enabled() or self.training:
            return False
        ok = getattr(self, "_fast_ok", None)
        if ok is None:
            ok = self._fast_ok = transformer_supported(tr)
        return ok

    def target_cache(self, f_tgt: torch.Tensor) -> TargetCache:
        """Precompute the target-only parts of :meth:`cross` (inference: no autograd, eval mode).

        The encoder output of the target, its keys/values for the source's cross-attention, and the
        target queries' self-attention sublayer do not depend on the source, so the deep iterations
        compute them once. f_tgt: (B, M, E) DGCNN features of the target.
        """
        if not self._fast_transformer():
            return TargetCache(f_tgt)
        tr = self.transformer
        mem = encode(tr.encoder, f_tgt)
        memory_kv = [project_kv(layer.multihead_attn, mem) for layer in tr.decoder.layers]
        first = tr.decoder.layers[0]
        tgt_self = decoder_self(first, f_tgt)
        tgt_q = None if first.norm_first else project_q(first.multihead_attn, tgt_self)
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
        mem_src = encode(tr.encoder, f_src)
        # source queries attend to the (cached) encoded target; target queries to the encoded source
        y_src = f_src
        y_tgt = f_tgt
        kvs, first_self = [], None
        for i, layer in enumerate(dec):
            kv_src = project_kv(layer.multihead_attn, mem_src)
            kvs.append(kv_src)
            if i == 0:
                y_tgt = decoder_rest(layer, cache.tgt_self, kv_src, cache.tgt_q)
            else:
                y_tgt = decoder_rest(layer, decoder_self(layer, y_tgt), kv_src)
            self_out = decoder_self(layer, y_src)
            first_self = self_out if i == 0 else first_self
            y_src = decoder_rest(layer, self_out, cache.memory_kv[i])
        if source_cache is not None and first_self is not None:
            # tgt_q None: the first cross-attention projects its queries itself (the same numbers)
            source_cache.append(TargetCache(f_src, kvs, first_self, None))
        if tr.decoder.norm is not None:
            y_src, y_tgt = tr.decoder.norm(y_src), tr.decoder.norm(y_tgt)
        return f_src + y_src, f_tgt + y_tgt
