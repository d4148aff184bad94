"""A target cloud's own surfaces (no ROS): its points, normals and direction cells as the verdict judges against them
(kept on a precision-stage cloud), and how rough its surfaces are (the residual of its points to their neighbours'
tangent planes): what core/visibility.py's ``plane_rel`` and ``plane_own`` measure a pose's fit against; and the
spread subset of a cloud's voxels the verdict judges as a source (:func:`spread_subset`, kept by
:func:`spread_points`).
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core.directions import directions

_SELF_POINTS = 256  # target points whose fit to their own neighbours' planes measures how rough the target is
_OWN_Q = 0.9  # the target's own plane residual at this quantile is ``plane_own``'s tolerance (within dist/5..dist/2)


def _quantile(x: np.ndarray, q: float) -> float:
    """``np.quantile(x, q)`` (its default, linear method) of a non-empty 1-D float64 array, to the last bit, without
    its overhead (about a third of its time on a few hundred values): the same index, weight and interpolation."""
    s = np.sort(np.asarray(x, np.float64))
    if np.isnan(s[-1]):
        return float("nan")
    n = len(s)
    v = (n - 1) * q
    if v >= n - 1:
        return float(s[-1])
    lo = int(np.floor(v))
    a, b, g = float(s[lo]), float(s[lo + 1]), v - np.floor(v)
    return b - (b - a) * (1 - g) if g >= 0.5 else a + (b - a) * g


def _pca_normals(tpts: np.ndarray, ktree, idx: np.ndarray, k: int = 8) -> np.ndarray:
    """(len(idx), 3) the normal of a plain cloud at each of its points ``idx``: the least-spread direction of the
    point's ``k`` nearest neighbours."""
    u, inv = np.unique(idx, return_inverse=True)
    _, nb = ktree.query(tpts[u], k=min(k, len(tpts)))
    q = tpts[np.asarray(nb).reshape(len(u), -1)]
    q = q - q.mean(axis=1, keepdims=True)
    return np.linalg.eigh(np.einsum("kni,knj->kij", q, q))[1][:, :, 0][inv.ravel()]


def _target(target, dist: float) -> tuple:
    """(points (M, 3), :func:`directions`, :func:`self_planarity` or None, normals or None, :func:`own_tolerance` or
    None) of a target; kept on a
    precision-stage cloud (its voxels never change), so that a cloud judged again (the good start, then the full
    pipeline; a scan that is the next pair's target) pays for them once."""
    cached = getattr(target, "_visibility", None)
    if cached is not None and cached[0] == dist and _same_voxels(target, cached[2]):
        return cached[1]
    tree = getattr(target, "tree", None)
    tpts = np.asarray(target.points() if hasattr(target, "points") else target, np.float64)[:, :3]
    normals = None
    if tree is not None and not hasattr(tree, "base"):  # a crop's view of a map's cloud: its normals are the map's
        nrm = np.asarray(target.cloud.normals())[:, :3]
        normals = nrm if len(nrm) == len(tpts) and np.any(nrm) else None
    res = None if normals is None or len(tpts) < 2 else self_residuals(tpts, tree, normals, dist)
    own = None if res is None else (float(np.mean(res <= 0.2 * dist)) if len(res) else 1.0)
    tol = None if res is None else own_tolerance(res, dist)
    out = (tpts, directions(tpts) if len(tpts) else (0.0, np.zeros(0, np.int64), np.zeros(0)), own, normals, tol)
    if tree is not None:
        target._visibility = (dist, out, _voxels(target))
    return out


def _voxels(cloud) -> tuple:
    """What a precision-stage cloud's voxels are read from (its small_gicp cloud; a map crop's view: its own
    centroids): the identity a table kept on the cloud is checked against, so that a cloud whose voxels were replaced
    has its tables built again."""
    return getattr(cloud, "cloud", None), getattr(cloud, "local", None)


def _same_voxels(cloud, kept: tuple) -> bool:
    return all(a is b for a, b in zip(_voxels(cloud), kept))


def spread_subset(points: np.ndarray, n: int, cell: float) -> np.ndarray:
    """About ``n`` of ``points`` (N, 3) (voxel centroids, metres), chosen by a hash of their ``cell`` m grid cell:
    the same subset for the same set of points in any order (small_gicp's threaded voxel grid returns its centroids
    in a run-dependent order), evenly spread, O(N) with no sort. All of them when N <= n. -> (K, 3) float64."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) <= n:
        return pts
    ijk = np.floor(pts / max(cell, 1e-6)).astype(np.int64)
    h = (ijk[:, 0] * 73856093) ^ (ijk[:, 1] * 19349663) ^ (ijk[:, 2] * 83492791)
    h = (h * 2654435761) & 0xFFFFF  # mixed, 20 bits
    return pts[h < int(n / len(pts) * 0x100000)]


def spread_points(cloud, n: int, cell: float) -> np.ndarray:
    """:func:`spread_subset` of a precision-stage cloud's voxels (``points()``), kept on the cloud
    (read-only; drawn again when its voxels were replaced): a scan judged as the source of one pair and as the target
    of the next (a stream), or against every crop of a map, draws it once. -> (K, 3) float64."""
    kept = getattr(cloud, "_spread", None)
    if kept is not None and kept[0] == (n, cell) and _same_voxels(cloud, kept[1]):
        return kept[2]
    pts = spread_subset(cloud.points(), n, cell)
    pts.flags.writeable = False  # shared by every caller
    cloud._spread = ((n, cell), _voxels(cloud), pts)
    return pts


def target_points(target, dist: float) -> np.ndarray:
    """A target's points (M, 3) float64 as the verdict judged against them: a precision-stage cloud's voxels kept
    with its direction cells (:func:`_target`), not copied again."""
    return _target(target, dist)[0]


def self_residuals(tpts: np.ndarray, tree, normals: np.ndarray, dist: float) -> np.ndarray:
    """Of an even subset of the target's points (at most about ``_SELF_POINTS``), the distance (m) of each to its
    nearest other point's tangent plane, for those with one within ``dist`` -> (K,): how rough the target is."""
    sub = tpts[:: max(1, len(tpts) // _SELF_POINTS)]
    idx, sq = tree.batch_knn_search(sub, 2, num_threads=1)
    j, sq = np.asarray(idx, np.int64)[:, 1], np.asarray(sq, np.float64)[:, 1]
    ok = (sq <= dist * dist) & (j >= 0) & (j < len(tpts))
    return np.abs(np.einsum("ij,ij->i", sub[ok] - tpts[j[ok]], normals[j[ok]]))


def own_tolerance(residuals: np.ndarray, dist: float) -> float:
    """``plane_own``'s tolerance (m): the :data:`_OWN_Q` quantile of the target's :func:`self_residuals`, kept
    within ``dist / 5`` (``plane_close``'s) and ``dist / 2`` (``fitness_close``'s: trees never make everything fit)."""
    q = _quantile(residuals, _OWN_Q) if len(residuals) else 0.0
    return float(np.clip(q, 0.2 * dist, 0.5 * dist))


def self_planarity(tpts: np.ndarray, tree, normals: np.ndarray, dist: float) -> float:
    """Of an even subset of the target's points, the share within ``dist / 5`` of their nearest other point's
    tangent plane (among those with one within ``dist``): 1 for clean walls, lower for trees and smeared scans."""
    res = self_residuals(tpts, tree, normals, dist)
    return float(np.mean(res <= 0.2 * dist)) if len(res) else 1.0


def roughness(target, dist: float) -> tuple[float, float]:
    """How rough a precision-stage cloud's surfaces are: (the :data:`_OWN_Q` quantile of its :func:`self_residuals`
    (m, unclipped), its :func:`self_planarity`); (0, 1) without normals. For benchmarks: real scans against
    simulated ones."""
    tpts, _, own, normals, _ = _target(target, dist)
    if normals is None:
        return 0.0, 1.0
    res = self_residuals(tpts, target.tree, normals, dist)
    return (float(np.quantile(res, _OWN_Q)) if len(res) else 0.0), float(own)
