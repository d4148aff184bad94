"""GICP's pairs at a pose and the cluster-robust terms of its cost (no ROS import): what
:mod:`deepbbs_ros.core.covariance` makes a covariance of.

small_gicp's cost ``E = 1/2 sum_i r_i^T M_i r_i``, ``r_i = b_i - T a_i``, ``M_i = (C_b + R C_a R^T)^-1``, for a right
perturbation ``T exp(xi)``, ``xi = [rot (3), trans (3)]``: ``J_i = R [skew(a_i), -I]``. The pairs are small_gicp's own
(the nearest target point within the correspondence distance; for VGICP the source point's voxel), and the point
covariances are read from the normals (small_gicp's are ``I - 0.999 n n^T``: a cloud's ``covs()`` is a slow list).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["cell_terms", "cells", "matched_pairs", "voxel_pairs"]


def _rot(R: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``R @ C[i] @ R.T`` for (n, 3, 3) ``C`` (two matrix products over the whole stack)."""
    return np.tensordot(np.tensordot(C, R.T, axes=([2], [0])), R, axes=([1], [1])).transpose(0, 2, 1)


_SYM = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _inverse_entries(S: np.ndarray) -> list[list[np.ndarray]]:
    """The entries ``m[i][j]`` (each (n,)) of the inverses of a stack (n, 3, 3) of symmetric matrices (the adjugate
    over the determinant), one contiguous array per entry: the products below run on whole vectors, not on strided
    slices of a stack."""
    a, b, c, d, e, f = (np.ascontiguousarray(S[:, i, j]) for i, j in _SYM)
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A + b * B + c * C
    m01, m02, m12 = B / det, C / det, E / det
    return [[A / det, m01, m02], [m01, D / det, m12], [m02, m12, F / det]]


def cells(points: np.ndarray, cell: float) -> tuple[np.ndarray, int]:
    """Each of ``points`` (n, 3)'s ``cell``-m cell, numbered in the order of its (x, y, z) index -> ((n,) cell
    numbers, the number of cells)."""
    c = np.floor(points / cell).astype(np.int64)
    c -= c.min(axis=0)
    dims = c.max(axis=0) + 1
    index = (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]
    if int(np.prod(dims)) > 8 * len(points) + 4096:  # a sparse grid: sort instead of a table
        _, number = np.unique(index, return_inverse=True)
        return number.ravel(), int(number.max()) + 1
    occupied = np.bincount(index, minlength=int(np.prod(dims))) > 0
    return (np.cumsum(occupied) - 1)[index], int(occupied.sum())


def cell_terms(a: np.ndarray, Ca: np.ndarray, b: np.ndarray, Cb: np.ndarray, T: np.ndarray,
               cell: float, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GICP's Hessian ``H = sum J^T M J`` (6, 6) of the pairs ``a`` (source points (n, 3), covariances ``Ca``
    (n, 3, 3)) and ``b`` (their target points and ``Cb``) at ``T = T_target_source``, for small_gicp's right
    perturbation ``[rot, trans]``, and per cell of a ``cell``-m grid (by the pair's target point) the sum of its pairs'
    gradients ``J^T M r`` (G, 6) and its pairs' share of the Hessian (G, 6, 6): the terms of the cluster-robust
    covariance (core/covariance.py) -> (H, gradients, Hessians). ``weights`` (n,): each pair's terms times its weight
    (scripts/benchmarks/_sweep_share.py: the Hessian weighted by each point's time in the sweep)."""
    R, t = T[:3, :3], T[:3, 3]
    if len(a) == 0:
        return np.zeros((6, 6)), np.zeros((0, 6)), np.zeros((0, 6, 6))
    m = _inverse_entries(_rot(R.T, Cb) + Ca)  # R^T M R, M in the source's axes: J = R [skew(a), -I]
    v = (b - (a @ R.T + t)) @ R
    x, y, z = (np.ascontiguousarray(a[:, i]) for i in range(3))
    # per pair, one row each: J^T M r = [u x a, -u] (u = R^T M r), then J^T M J = [[S^T P, -P^T], [-P, M]] with
    # P = M S, S = skew(a), entry by entry over whole vectors
    u = [m[i][0] * v[:, 0] + m[i][1] * v[:, 1] + m[i][2] * v[:, 2] for i in range(3)]
    P = [[m[i][1] * z - m[i][2] * y, m[i][2] * x - m[i][0] * z, m[i][0] * y - m[i][1] * x] for i in range(3)]
    Q = [[z * P[1][j] - y * P[2][j] for j in range(3)], [x * P[2][j] - z * P[0][j] for j in range(3)],
         [y * P[0][j] - x * P[1][j] for j in range(3)]]
    rows = [u[1] * z - u[2] * y, u[2] * x - u[0] * z, u[0] * y - u[1] * x, -u[0], -u[1], -u[2]]
    rows += [X[i][j] for X in (Q, P, m) for i in range(3) for j in range(3)]
    if weights is not None:
        rows = [row * weights for row in rows]
    cluster, G = cells(b, cell)
    tot = np.stack([np.bincount(cluster, weights=row, minlength=G) for row in rows], axis=1)  # (G, 33)
    q, p, mm = (tot[:, k:k + 9].reshape(G, 3, 3) for k in (6, 15, 24))
    hess = np.empty((G, 6, 6))
    hess[:, :3, :3] = q
    hess[:, :3, 3:] = -p.transpose(0, 2, 1)
    hess[:, 3:, :3] = -p
    hess[:, 3:, 3:] = mm
    return hess.sum(axis=0), tot[:, :6], hess


def _plane_covs(normals: np.ndarray) -> np.ndarray:
    """(n, 3) normals -> (n, 3, 3) small_gicp's normalised point covariances, eigenvalues (1e-3, 1, 1) with the
    smallest along the normal: ``I - 0.999 n n^T`` (read from the normals: a cloud's ``covs()`` is a Python list)."""
    return np.eye(3) - 0.999 * np.einsum("ni,nj->nij", normals, normals)


def _stride(n: int, max_points: int) -> int:
    """Every how many-th of ``n`` source points the pairs keep: at most ``max_points`` of them (> 0; 0 = all)."""
    return max(1, -(-n // max_points)) if max_points > 0 else 1


_ARRAYS: dict[int, tuple[Any, np.ndarray, np.ndarray]] = {}


def _arrays(cloud: Any) -> tuple[np.ndarray, np.ndarray]:
    """A prepared cloud's points and normals (n, 3) float64, copied once per cloud (a map's: 48 bytes a voxel, about
    a fifth of its GICP cloud) and kept for the last two clouds asked (the map, a newer map replacing it)."""
    hit = _ARRAYS.get(id(cloud))
    if hit is None or hit[0] is not cloud:
        hit = (cloud, np.asarray(cloud.points(), dtype=np.float64)[:, :3].copy(),
               np.asarray(cloud.normals(), dtype=np.float64)[:, :3].copy())
        while len(_ARRAYS) >= 2:
            _ARRAYS.pop(next(iter(_ARRAYS)))
        _ARRAYS[id(cloud)] = hit
    return hit[1], hit[2]


def matched_pairs(source: Any, target: Any, T_target_source: np.ndarray, max_corr_dist: float,
                  threads: int = 1, max_points: int = 0) -> tuple[np.ndarray, ...] | None:
    """GICP's pairs at ``T_target_source``: the source's points and covariances (n, 3), (n, 3, 3), their nearest
    target points within ``max_corr_dist`` and those points' covariances, and the pose in the target cloud's own
    frame. ``source``: a prepared small_gicp cloud (or one with a ``.cloud``); ``target``: a prepared cloud with
    ``.cloud`` and ``.tree`` (a ``PolishView``: its base cloud, in the base's frame). ``max_points`` (> 0): every
    k-th source point only, at most that many (the covariance of that thinner estimate, a little more cautious)."""
    T = np.asarray(T_target_source, dtype=np.float64)
    T_base = getattr(target, "T_base", None)
    tree = target.tree if T_base is None else target.tree.base
    T = T if T_base is None else np.asarray(T_base, dtype=np.float64) @ T
    src = getattr(source, "cloud", source)
    a = np.asarray(src.points(), dtype=np.float64)[:, :3]
    step = _stride(len(a), max_points)
    a = a[::step]
    idx, d2 = tree.batch_nearest_neighbor_search(a @ T[:3, :3].T + T[:3, 3], num_threads=max(1, int(threads)))
    idx, d2 = np.asarray(idx, dtype=np.int64).ravel(), np.asarray(d2, dtype=np.float64).ravel()
    keep = (idx >= 0) & (d2 <= max_corr_dist ** 2)
    if keep.sum() < 7:
        return None
    tb, tn = _arrays(target.cloud)
    b, Cb = tb[idx[keep]], _plane_covs(tn[idx[keep]])
    Ca = _plane_covs(np.asarray(src.normals(), dtype=np.float64)[::step][keep, :3])
    return a[keep], Ca, b, Cb, T


def _keys(cells: np.ndarray) -> np.ndarray:
    """(n, 3) integer cells -> (n,) int64 keys (21 bits per axis: +-1e6 cells)."""
    c = (cells.astype(np.int64) + (1 << 20)) & ((1 << 21) - 1)
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]


def voxel_pairs(source: Any, vmap: Any, T_map_source: np.ndarray, voxel_size: float,
                max_points: int = 0) -> tuple[np.ndarray, ...] | None:
    """:func:`matched_pairs` for VGICP on a ``small_gicp.GaussianVoxelMap`` of ``voxel_size``: each source point's
    voxel (its mean and covariance), as VGICP pairs them; of every k-th source point when there are more than
    ``max_points`` (> 0): the covariance of that thinner estimate, a little more cautious."""
    T = np.asarray(T_map_source, dtype=np.float64)
    means = np.asarray(vmap.voxel_points(), dtype=np.float64)[:, :3]
    if len(means) == 0:
        return None
    keys = _keys(np.floor(means / voxel_size))
    order = np.argsort(keys)
    step = _stride(source.size(), max_points)
    a = np.asarray(source.points(), dtype=np.float64)[::step, :3]
    q = _keys(np.floor((a @ T[:3, :3].T + T[:3, 3]) / voxel_size))
    pos = np.minimum(np.searchsorted(keys[order], q), len(order) - 1)
    hit = keys[order][pos] == q
    if hit.sum() < 7:
        return None
    idx = order[pos[hit]]
    covs = np.asarray(vmap.voxel_covs(), dtype=np.float64).reshape(-1, 4, 4)
    Ca = _plane_covs(np.asarray(source.normals(), dtype=np.float64)[::step][hit, :3])
    return a[hit], Ca, means[idx], covs[idx][:, :3, :3], T
