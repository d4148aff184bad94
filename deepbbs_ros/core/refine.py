"""DeepBBS++ refinement: SoftBBS in 3D space (xyz instead of features), iterated to convergence.

Every iteration moves the source with the current estimate, computes ``B~`` from the 3D distances
(alpha = xi * median nearest-neighbour distance of the source xyz, T = 1 in scaled units), maps every
source point to its soft match ``q^_i`` and solves the weighted Procrustes problem from the
*unmoved* source to ``q^`` (so the estimate is a fresh solution each time, not an accumulation).
It stops when the change of the estimate is below the rotation AND translation tolerances.

Two variants, the same equations:

* dense (``k = 0``): the full N x M matrices (the reference implementation; 31-46 iterations there);
* sparse (``k > 0``): only the k nearest target points of every moved source point (a scipy
  cKDTree on the CPU, built once for the target; ``cdist`` + top-k on other devices; each point
  keeps 2k candidates and is searched again only when they can no longer hold its exact k nearest
  as it moves, see ``_MovingKnn``). The
  per-column log-sum-exp runs over the pairs in the kNN graph; dropped pairs have weight ~0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from deepbbs_ros.core import softbbs
from deepbbs_ros.core.procrustes import apply_transform, weighted_procrustes
from deepbbs_ros.reprs import short_repr

__all__ = ["RefineResult", "refine", "rotation_angle_deg", "NeighbourSearch"]


@dataclass
class RefineResult:
    """R (3, 3), t (3,) (scaled units; p_target = R p_source + t), iterations, converged, gamma (N,)."""

    __repr__ = short_repr  # one readable line: arrays as shape and dtype (deepbbs_ros/reprs.py)

    R: torch.Tensor
    t: torch.Tensor
    iterations: int
    converged: bool
    gamma: torch.Tensor


def rotation_angle_deg(R: torch.Tensor) -> float:
    """Angle of a rotation matrix (3, 3) in degrees."""
    c = (float(torch.diagonal(R).sum()) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


class NeighbourSearch:
    """k nearest target points of query points: cKDTree on the CPU, dense top-k elsewhere.

    target: (M, 3) float tensor. ``query(points (N, 3), k) -> (dist (N, k), idx (N, k) int64)``.
    """

    def __init__(self, target: torch.Tensor) -> None:
        self.target = target
        self.tree = None
        if target.device.type == "cpu":
            from scipy.spatial import cKDTree

            self.tree = cKDTree(target.detach().numpy().astype(np.float64))

    def query(self, points: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        k = min(k, self.target.shape[0])
        if self.tree is not None:
            d, i = self.tree.query(points.detach().numpy().astype(np.float64), k=k)
            d = d.reshape(points.shape[0], k)
            i = i.reshape(points.shape[0], k)
            return torch.from_numpy(d.astype(np.float32)).to(points.dtype), torch.from_numpy(i.astype(np.int64))
        d = softbbs.pairwise_distances(points[None], self.target[None])[0]
        dk, idx = d.topk(k, dim=1, largest=False)
        return dk, idx

    def nearest_distance(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) distance to the nearest target point."""
        return self.query(points, 1)[0][:, 0]


class _MovingKnn:
    """Exact k nearest targets of points that move a little between calls (the refinement's source).

    Every point keeps ``kc > k`` candidate targets from its last tree query at ``anchor``; a target
    outside them is at least ``r_kc - |p - anchor|`` from the point's new position p, so when the k-th
    nearest candidate is closer than that, the candidates hold the exact k nearest (ties aside). Only
    points that fail this test are queried again: a few per iteration once the estimate settles.
    """

    def __init__(self, search: NeighbourSearch, k: int) -> None:
        self.search, self.k = search, k
        m = search.target.shape[0]
        self.kc = min(2 * k, m)
        self.complete = self.kc >= m  # every target is a candidate: always exact
        self.anchor: torch.Tensor | None = None

    def _requery(self, points: torch.Tensor, rows: torch.Tensor | None) -> None:
        d, i = self.search.query(points if rows is None else points[rows], self.kc)
        r = d[:, -1] if not self.complete else torch.full_like(d[:, -1], float("inf"))
        if rows is None:
            self.anchor, self.cand, self.radius = points.clone(), i, r
        else:
            self.anchor[rows], self.cand[rows], self.radius[rows] = points[rows], i, r

    def query(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points (N, 3) -> (dist (N, k), idx (N, k) int64) of the k nearest targets."""
        if self.anchor is None:
            self._requery(points, None)
        shift = (points - self.anchor).norm(dim=1)
        dk, pos = self._nearest(points, self.cand)
        stale = (dk.amax(dim=1) > self.radius - shift).nonzero()[:, 0]
        if stale.numel():
            self._requery(points, stale)
            dk[stale], pos[stale] = self._nearest(points[stale], self.cand[stale])
        return dk, self.cand.gather(1, pos)

    def _nearest(self, points: torch.Tensor, cand: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """k nearest among the candidates (unordered: the SoftBBS sums do not depend on the order)."""
        n, kc = cand.shape
        g = self.search.target.index_select(0, cand.reshape(-1)).reshape(n, kc, 3)
        d2 = g.sub_(points[:, None, :]).square_().sum(dim=2)
        d2k, pos = d2.topk(self.k, dim=1, largest=False, sorted=False)
        return d2k.sqrt_(), pos


def source_alpha(src: torch.Tensor, xi: float) -> torch.Tensor:
    """``xi * median_i min_{k != i} ||p_i - p_k||`` of src (N, 3) -> scalar tensor (kd-tree on CPU)."""
    if src.device.type == "cpu":
        from scipy.spatial import cKDTree

        pts = src.detach().numpy().astype(np.float64)
        d, _ = cKDTree(pts).query(pts, k=2)
        return torch.tensor(xi * float(np.median(d[:, 1])), dtype=src.dtype).clamp_min(1e-8)
    return softbbs.bbs_alpha(src[None], xi)[0]


def refine(
    src: torch.Tensor,
    tgt: torch.Tensor,
    R: torch.Tensor,
    t: torch.Tensor,
    *,
    k: int = 16,
    max_iters: int = 46,
    rot_tol_deg: float = 0.005,
    trans_tol: float = 1e-4,
    xi: float = 0.4,
    temperature: float = 1.0,
    use_gamma: bool = True,
    spatial_gamma: bool = True,
    search: NeighbourSearch | None = None,
    alpha_start: float = 1.0,
) -> RefineResult:
    """Iterate SoftBBS on xyz from the initial estimate (R, t).

    Args:
        src: (N, 3) source points, tgt: (M, 3) target points, both scaled (same device/dtype).
        R: (3, 3), t: (3,) initial estimate (scaled units).
        k: nearest target points per source point; 0 = dense N x M (reference).
        max_iters: iteration cap; stops earlier once the increment is below rot_tol_deg AND
            trans_tol (scaled units).
        xi: alpha = xi * median nearest-neighbour distance of the source xyz.
        temperature: T of gamma's spatial term (scaled units; 1 in DeepBBS++).
        search: a prebuilt :class:`NeighbourSearch` on ``tgt`` (sparse only).
        alpha_start: coarse-to-fine schedule: the iterations start with ``alpha_start * alpha``
            (softer matches, a wider basin) and halve the factor each time the increment falls below
            the tolerances, down to 1 (the paper's alpha), where convergence ends the loop.
            1 = the paper's fixed alpha.
    Returns:
        :class:`RefineResult`.
    """
    alpha = source_alpha(src, xi)
    mult = max(1.0, float(alpha_start))
    dense = k <= 0
    if not dense and search is None:
        search = NeighbourSearch(tgt)
    knn = None if dense else _MovingKnn(search, k)
    m = tgt.shape[0]
    gamma = src.new_ones(src.shape[0])
    converged = False
    it = 0
    for it in range(1, max_iters + 1):  # noqa: B007 - the count is returned
        moved = apply_transform(src[None], R[None], t[None])[0]
        if dense:
            d = softbbs.pairwise_distances(moved[None], tgt[None])
            log_b = softbbs.soft_bbs_log(d, alpha[None] * mult)
            q_hat = softbbs.soft_map(log_b, tgt[None])[0]
            gamma = softbbs.bbs_gamma(log_b, d if spatial_gamma else None, d.new_full((1,), temperature))[0]
        else:
            dk, idx = knn.query(moved)
            log_b = softbbs.sparse_soft_bbs_log(dk[None], idx[None], m, alpha[None] * mult)
            q_hat = softbbs.sparse_soft_map(log_b, idx[None], tgt[None])[0]
            gamma = softbbs.sparse_gamma(log_b, dk[None] if spatial_gamma else None, temperature)[0]
        weights = gamma if use_gamma else torch.ones_like(gamma)
        R_new, t_new = weighted_procrustes(src, q_hat, weights, warn_degenerate=False)
        dR = R_new @ R.T
        dt = t_new - dR @ t
        R, t = R_new, t_new
        if rotation_angle_deg(dR) < rot_tol_deg and float(dt.norm()) < trans_tol:
            if mult <= 1.0:
                converged = True
                break
            mult = max(1.0, 0.5 * mult)  # next, sharper level of the coarse-to-fine schedule
    return RefineResult(R, t, it, converged, gamma)
