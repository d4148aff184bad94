"""The cluster-robust covariance of a GICP solution (no ROS): the M-estimator's sandwich with the residual gradients
summed per cell of a grid, its leave-one-cell-out (jackknife) form, Student's t widening by the effective number of
cells, the start's uncertainty along weak directions, and the move to the parent frame's axes. The entry points and
the reasoning are in core/covariance.py.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.gicp_pairs import cell_terms

#: m; the cells whose pairs' residual gradients are summed before their outer products (the correlation length of
#: GICP's residual errors: neighbouring points see the same surface, ring and voxel grid, and their errors move
#: together); halved (down to 1 m) until a scan has :data:`MIN_CLUSTERS` cells (a small room). Chosen, not fitted:
#: on simulated HDL-64E and VLP-16 drives the sets' mean NEES are closest to one another from 10 to 20 m
CLUSTER_CELL = 12.0
MIN_CLUSTERS = 24
#: a translation direction is weak (:func:`sandwich_covariance`) where the Hessian's eigenvalue along it is below
#: this share of the largest (a synthetic 4 m corridor: 2e-3 to 5e-3; a simulated highway 1e-2 to 5e-2)
WEAK_RATIO = 0.01
#: effective cells below which Student's t has no variance to speak of (:func:`student_widened`): the factor stops at
#: t_3's, 3 (under 2 % of the directions on simulated drives; 5 or 1,000 there left every set's count the same)
MIN_EFFECTIVE_CELLS = 3.0
#: variance floor, m^2 / rad^2 on the diagonal: noise-free synthetic scenes must not give a singular covariance
VARIANCE_FLOOR = 1e-10

# [rot, trans] (small_gicp) -> [trans, rot] (ROS)
_PERM = np.array([3, 4, 5, 0, 1, 2])


def sandwich_covariance(pairs: tuple[np.ndarray, ...] | None, T_out: np.ndarray, inflation: float,
                        cell: float | None = None, weak_sigma: Any = 0.0,
                        weak: np.ndarray | None = None, jackknife: bool = True,
                        student: bool = False) -> np.ndarray | None:
    """(6, 6) covariance (the module's convention, axes of ``T_out``'s parent) of the GICP solution whose matched
    pairs are ``pairs`` (:func:`matched_pairs`, :func:`voxel_pairs`): ``inflation`` times the leave-one-cell-out
    covariance (:func:`jackknife_meat`; ``jackknife=False``: ``H^-1 B H^-1 * G / (G - 6)``) of the pairs'
    (:func:`cell_terms`) on ``cell``-m cells, :data:`CLUSTER_CELL` halved down to 1 m until there are
    :data:`MIN_CLUSTERS` of them; ``G`` the cells); along each weak translation direction (an eigen-direction of
    the Hessian's translation block below :data:`WEAK_RATIO` of its largest: a corridor, a straight road with little
    beside it) the variance grows by ``weak_sigma ** 2`` (m^2: the start's own uncertainty, where the answer along it
    is where the start left it; ``weak``: (K, 3) unit directions in the scan's frame found weak by the caller, the
    odometry's degeneracy check, instead of that test, with ``weak_sigma`` one value or (K,) per direction).
    ``student``: each direction widened as Student's t with its effective number of cells (:func:`student_widened`).
    None without pairs or with a singular Hessian."""
    robust = _robust(pairs, inflation, cell, jackknife, student)
    if robust is None:
        return None
    cov_right, H = robust
    _add_weak(cov_right, H, weak_sigma, weak)
    return _to_parent(cov_right, T_out)


def _robust(pairs: tuple[np.ndarray, ...] | None, inflation: float, cell: float | None = None,
            jackknife: bool = True, student: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """The cluster-robust covariance of :func:`sandwich_covariance` in the scan's axes, ROS order, nothing added
    along weak directions, and small_gicp's Hessian ``H`` (6, 6, ``[rot, trans]``); None without pairs or with a
    singular Hessian. ``jackknife``: :func:`jackknife_meat`'s instead of ``G / (G - 6) * H^-1 B H^-1``; ``student``:
    :func:`student_widened`."""
    if pairs is None:
        return None
    H, Gc, Hc = clustered_terms(pairs, cell)
    G = len(Gc)
    w, V = np.linalg.eigh(H)
    if G <= 6 or not np.isfinite(w).all() or w[-1] <= 0 or w[0] <= w[-1] * 1e-14:
        return None
    cov = jackknife_meat(H, Gc, Hc) if jackknife else None
    left_out = cov is not None
    if cov is None:
        Hi = (V / w) @ V.T
        cov = G / (G - 6) * (Hi @ (Gc.T @ Gc) @ Hi)
    if student:
        cov = student_widened(cov, H, Hc, left_out)
    return (inflation * cov)[np.ix_(_PERM, _PERM)], H


def clustered_terms(pairs: tuple[np.ndarray, ...], cell: float | None = None) -> tuple[np.ndarray, np.ndarray,
                                                                                       np.ndarray]:
    """small_gicp's Hessian ``H`` (6, 6, ``[rot, trans]``, symmetrised) of the GICP ``pairs`` and each cell's gradient
    ``Gc`` (G, 6) and Hessian ``Hc`` (G, 6, 6) (:func:`core.gicp_pairs.cell_terms`), the cells ``cell`` m
    (:data:`CLUSTER_CELL` when None), halved down to 1 m until there are :data:`MIN_CLUSTERS` of them."""
    a, Ca, b, Cb, T = pairs
    cell = float(cell or CLUSTER_CELL)
    H, Gc, Hc = cell_terms(a, Ca, b, Cb, T, cell)
    while len(Gc) < MIN_CLUSTERS and cell > 1.0:
        cell = max(1.0, cell / 2)
        H, Gc, Hc = cell_terms(a, Ca, b, Cb, T, cell)
    return 0.5 * (H + H.T), Gc, Hc


def jackknife_meat(H: np.ndarray, grads: np.ndarray, hessians: np.ndarray) -> np.ndarray | None:
    """(6, 6) the leave-one-cell-out (jackknife) covariance of the GICP solution, small_gicp's ``[rot, trans]``:
    ``(G - 1) / G * sum_c d_c d_c^T``, ``d_c = (H - H_c)^-1 g_c`` the pose's move when cell ``c`` is left out (one
    Newton step from the solution, where the gradients sum to zero), from the cells' gradients ``g_c`` (G, 6) and
    Hessians ``H_c`` (G, 6, 6) (:func:`~deepbbs_ros.core.gicp_pairs.cell_terms`). ``H^-1 B H^-1`` weighs each cell's
    gradient by the whole Hessian, which holds that cell's own pairs, and so is too small where few cells pin the
    pose (a cell that pins a direction pulls the solution towards its own error); the jackknife's ``(H - H_c)^-1``
    is that cell's leverage, so no factor needs fitting for it (CR3 in the cluster-robust literature). None where
    leaving a cell out leaves a singular Hessian (the caller keeps ``H^-1 B H^-1``)."""
    G = len(grads)
    w = np.linalg.eigvalsh(H)
    rest = H[None] - 0.5 * (hessians + hessians.transpose(0, 2, 1))
    try:
        d = np.linalg.solve(rest, grads[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        return None
    if not np.isfinite(d).all() or np.linalg.eigvalsh(rest)[:, 0].min() <= w[-1] * 1e-12:
        return None
    return (G - 1) / G * (d.T @ d)


def effective_cells(H: np.ndarray, hessians: np.ndarray, basis: np.ndarray, left_out: bool = True) -> np.ndarray:
    """(K,) how many cells' worth of information the cluster-robust variance along each column of ``basis`` (6, K;
    small_gicp's ``[rot, trans]``) rests on: Satterthwaite's ``(sum_c l_c)^2 / sum_c l_c^2`` with ``l_c`` the variance
    cell ``c``'s term adds along the direction when a cell's gradient varies as its share of the Hessian, ``H_c``
    (the errors GICP's cost weighs; the design's, not the residuals', so not itself noisy): ``w^T A_c H_c A_c^T w``,
    ``A_c = (H - H_c)^-1`` (``left_out``, :func:`jackknife_meat`) or ``H^-1``. G equal cells give G; one cell that
    pins the direction, about 1 (as Bell and McCaffrey's degrees of freedom for cluster-robust variances)."""
    Hc = 0.5 * (hessians + hessians.transpose(0, 2, 1))
    A = np.linalg.inv(H[None] - Hc) if left_out else np.broadcast_to(np.linalg.inv(H), Hc.shape)
    Y = np.matmul(A.transpose(0, 2, 1), basis)  # (G, 6, K): A_c^T w
    lam = np.einsum("cki,cki->ci", Y, Hc @ Y)  # (G, K): (A_c^T w)^T H_c (A_c^T w)
    return np.square(lam.sum(axis=0)) / np.maximum(np.square(lam).sum(axis=0), 1e-300)


def student_widened(cov: np.ndarray, H: np.ndarray, hessians: np.ndarray, left_out: bool = True) -> np.ndarray:
    """(6, 6) ``cov`` (a cluster-robust covariance, small_gicp's ``[rot, trans]``, rad and m) widened along each of
    its eigen-directions to Student's t's variance, ``nu / (nu - 2)`` (at most 3, :data:`MIN_EFFECTIVE_CELLS`), with
    ``nu`` the direction's effective number of cells (:func:`effective_cells`): the covariance is estimated from a few
    dozen cells, and with a variance estimated on ``nu`` degrees of freedom taken as exact, the error over its
    standard deviation is a t, whose square averages ``nu / (nu - 2)``, not 1: most where a direction rests on a few
    cells."""
    w, U = np.linalg.eigh(0.5 * (cov + cov.T))
    nu = np.maximum(effective_cells(H, hessians, U, left_out), MIN_EFFECTIVE_CELLS)
    return (U * (w * nu / (nu - 2.0))) @ U.T


def _add_weak(cov_right: np.ndarray, H: np.ndarray, weak_sigma: Any, weak: np.ndarray | None) -> None:
    """:func:`sandwich_covariance`'s weak directions added to ``cov_right`` (scan axes, ROS order) in place."""
    if weak is None:
        wt, Vt = np.linalg.eigh(H[3:, 3:])
        weak = Vt[:, wt < WEAK_RATIO * wt[-1]].T  # (K, 3), the scan's frame
    weak = np.asarray(weak, dtype=np.float64).reshape(-1, 3)
    sig2 = np.square(np.broadcast_to(np.asarray(weak_sigma, dtype=np.float64), (len(weak),)))
    cov_right[:3, :3] += (weak.T * sig2) @ weak


def _to_parent(cov_right: np.ndarray, T_out: np.ndarray) -> np.ndarray:
    """``cov_right`` (scan axes, ROS order) in the axes of ``T_out``'s parent, symmetric, with the variance floor."""
    R = np.asarray(T_out, dtype=np.float64)[:3, :3]
    Bm = np.zeros((6, 6))
    Bm[:3, :3] = Bm[3:, 3:] = R
    out = Bm @ cov_right @ Bm.T
    out = 0.5 * (out + out.T)
    out[np.diag_indices(6)] += VARIANCE_FLOOR
    return out
