"""The DGCNN point features of the DeepBBS embedding (core/model.py): edge convolutions on a kNN graph of the xyz.

Edge convolution: ``h_i = max_j W [x_j, x_i] = max_j (W1 x_j) + W2 x_i`` (exact, because W2 x_i does
not depend on j): the two linear maps run per point *before* the neighbours are gathered, then a
LayerNorm (no batch statistics: the same numbers in training and inference, at any batch size)
and a LeakyReLU(0.2), which is monotone and therefore commutes with the max.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["DGCNN", "EdgeConv", "knn_indices"]


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
