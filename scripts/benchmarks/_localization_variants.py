"""The localization covariance's checks for scripts/benchmarks/covariance.py (models tried, not shipped, and the
per-direction diagnostic): installed around core/candidate_checks.py's ``scan_covariance`` for one run.

* ``estimator="cr2"``: the bias-reduced cluster-robust covariance (CR2, Bell and McCaffrey) in place of the node's
  leave-one-cell-out one (CR3): each cell's gradient times ``(I - H_c H^-1)^-1/2`` instead of ``^-1`` (the pose's
  move when the cell is left out). Under independent cells whose errors vary as their share of the Hessian it is
  unbiased, where the jackknife is biased up by about ``1 / (1 - leverage)`` per cell; with Student's t, the
  effective cells are taken with CR2's weights.
* ``coarse``: the covariance along each direction the larger of the ``CLUSTER_CELL`` cells' and these coarser cells'
  (errors correlated over more than a cell; the matrix maximum in the first's metric).
* ``directions``: each pose's covariance eigen-directions (before the weak directions' start uncertainty, the scan's
  axes) with their effective cells, to tell which directions are cautious (:func:`direction_rows`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

LAST: dict = {}  # the last localization covariance's directions (``directions``): "U", "lam", "nu", "T_out"


def _terms(pairs: tuple, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """core/covariance.py's cells (``clustered_terms``), each cell's Hessian symmetrised."""
    import deepbbs_ros.core.covariance as cm

    H, Gc, Hc = cm.clustered_terms(pairs, cell)
    return H, Gc, 0.5 * (Hc + Hc.transpose(0, 2, 1))


def _weights(H: np.ndarray, Hc: np.ndarray, estimator: str) -> np.ndarray:
    """(G, 6, 6) ``A_c`` with the cell's term ``d_c = A_c g_c``: CR3 ``(H - H_c)^-1``, CR2 ``H^-1/2 (I - H^-1/2 H_c
    H^-1/2)^-1/2 H^-1/2`` (= ``H^-1 (I - H_c H^-1)^-1/2`` by the push-through identity)."""
    if estimator != "cr2":
        return np.linalg.inv(H[None] - Hc)
    w, V = np.linalg.eigh(H)
    Li = (V / np.sqrt(w)) @ V.T
    ws, Vs = np.linalg.eigh(np.eye(6)[None] - Li[None] @ Hc @ Li[None])
    return Li[None] @ ((Vs / np.sqrt(np.maximum(ws, 1e-12))[:, None, :]) @ Vs.transpose(0, 2, 1)) @ Li[None]


def _one(pairs: tuple, cell: float, estimator: str, student: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray] | None:
    """(covariance [rot, trans], H, eigen-directions U, their effective cells) at one cell size."""
    import deepbbs_ros.core.cluster_robust as cr

    H, Gc, Hc = _terms(pairs, cell)
    G = len(Gc)
    w = np.linalg.eigvalsh(H)
    if G <= 6 or not np.isfinite(w).all() or w[-1] <= 0 or w[0] <= w[-1] * 1e-14:
        return None
    A = _weights(H, Hc, estimator)
    d = np.einsum("cij,cj->ci", A, Gc)
    cov = d.T @ d * ((G - 1) / G if estimator != "cr2" else 1.0)
    lam, U = np.linalg.eigh(0.5 * (cov + cov.T))
    Y = np.matmul(A.transpose(0, 2, 1), U)
    li = np.einsum("cki,cki->ci", Y, Hc @ Y)
    nu = np.square(li.sum(0)) / np.maximum(np.square(li).sum(0), 1e-300)
    if student:
        n = np.maximum(nu, cr.MIN_EFFECTIVE_CELLS)
        lam = lam * n / (n - 2.0)
    return (U * lam) @ U.T, H, U, nu


def _matrix_max(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The smallest covariance at least ``A`` and ``B`` along ``A``'s and ``B``'s joint eigen-directions."""
    w, V = np.linalg.eigh(A)
    Ah, Aih = (V * np.sqrt(w)) @ V.T, (V / np.sqrt(w)) @ V.T
    lam, U = np.linalg.eigh(Aih @ B @ Aih)
    out = Ah @ (U * np.maximum(lam, 1.0)) @ U.T @ Ah
    return 0.5 * (out + out.T)


def install(estimator: str = "jackknife", coarse: float = 0.0, directions: bool = False) -> None:
    """Route the localization's covariance (core/candidate_checks.py ``scan_covariance``) through the models above."""
    import deepbbs_ros.core.candidate_checks as locmod
    import deepbbs_ros.core.cluster_robust as cr
    import deepbbs_ros.core.covariance as cm

    own_scan, own_sandwich = locmod.scan_covariance, cm.sandwich_covariance

    def sandwich(pairs: Any, T_out: np.ndarray, inflation: float, cell: float | None = None, weak_sigma: Any = 0.0,
                 weak: np.ndarray | None = None, jackknife: bool = True, student: bool = False) -> np.ndarray | None:
        if pairs is None:
            return None
        cells = [float(cell or cr.CLUSTER_CELL)] + ([float(coarse)] if coarse > 0 else [])
        parts = [_one(pairs, c, estimator, student) for c in cells]  # (the localization always jackknifes)
        if parts[0] is None:
            return None
        cov, H, U, nu = parts[0]
        for p in parts[1:]:
            if p is not None:
                cov = _matrix_max(cov, p[0])
        cov = inflation * cov
        if directions:
            LAST.update(U=U, lam=np.einsum("ki,kl,li->i", U, cov, U), nu=nu, T_out=np.asarray(T_out))
        c = cov[np.ix_(cm._PERM, cm._PERM)]
        cm._add_weak(c, H, weak_sigma, weak)
        return cm._to_parent(c, T_out)

    def scan(*a: Any, **k: Any) -> np.ndarray | None:
        cm.sandwich_covariance = sandwich
        try:
            return own_scan(*a, **k)
        finally:
            cm.sandwich_covariance = own_sandwich

    locmod.scan_covariance = scan


def direction_rows(delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The last pose's error ``delta`` (ROS order, map frame) along its covariance's eigen-directions: (effective
    cells (6,), ``(u^T delta)^2 / lambda`` (6,): 1 on average where the direction's variance is honest)."""
    import deepbbs_ros.core.covariance as cm

    R = LAST["T_out"][:3, :3]
    d = np.concatenate([R.T @ delta[:3], R.T @ delta[3:]])[cm._PERM]  # the scan's axes, [rot, trans]
    return LAST["nu"], (LAST["U"].T @ d) ** 2 / LAST["lam"]


#: effective-cell bins of the per-direction table
BINS = (0.0, 5.0, 8.0, 12.0, 20.0, np.inf)


def direction_table(rows: list[tuple[np.ndarray, np.ndarray]]) -> str:
    """One line: per bin of effective cells, the directions' count and mean ``(u^T delta)^2 / lambda``."""
    if not rows:
        return ""
    nu, r = (np.concatenate(x) for x in zip(*rows))
    parts = []
    for lo, hi in zip(BINS[:-1], BINS[1:]):
        m = (nu >= lo) & (nu < hi)
        if m.any():
            parts.append(f"[{lo:.0f}, {hi:.0f}): {r[m].mean():.2f} ({m.sum()})")
    return "per direction by effective cells, mean (u^T d)^2 / lambda (1 when honest): " + ", ".join(parts)


def install_map_planes() -> None:
    """The localization against the map's planes alone (a model tried): its refinement point-to-plane on the map crop's
    normals (small_gicp ``PLANE_ICP``, the scan's own covariances out of GICP's weight ``(C_b + R C_a R^T)^-1``) and
    its covariance from the same pairs with ``C_a = 0`` (the map's planes, as the estimate weighs them)."""
    import dataclasses

    import deepbbs_ros.core.covariance as cm
    import deepbbs_ros.core.localization as locmod

    own_refine, own_pairs = locmod.MapLocalizer._refine, cm.matched_pairs

    def refine(self: Any, src: Any, crop: Any, T_map_scan: np.ndarray, timings: dict) -> np.ndarray:
        rc = self.config.registration
        self.config.registration = dataclasses.replace(rc, polish="plane_icp")
        try:
            return own_refine(self, src, crop, T_map_scan, timings)
        finally:
            self.config.registration = rc

    def pairs(*a: Any, **k: Any) -> tuple[np.ndarray, ...] | None:
        p = own_pairs(*a, **k)
        return None if p is None else (p[0], np.zeros_like(p[1]), *p[2:])

    locmod.MapLocalizer._refine = refine
    cm.matched_pairs = pairs
