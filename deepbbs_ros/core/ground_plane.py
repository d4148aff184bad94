"""Preprocessing step 2, the upright ground fit: one plane ``a x + b y + c z + d = 0`` under a car-roof sensor.

Two robust seedings (``preprocess.ground_method``): "ransac", near-horizontal planes through random triples near
the sensor scored by their inliers, and "seeded_lsq", the dominant height near the sensor grown outwards by least
squares; both are refined by least squares on the points close to the estimate (see core/preprocess.py). The
floor search at any tilt is core/ground.py. No ROS import.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.errors import RegistrationError

MIN_POINTS = 3  # fewer valid (or non-ground) points than this cannot be registered
_FIT_SAMPLES = 4096  # the ground plane is fitted on at most this many points near the sensor
_FIT_TOL = 0.25  # m; widest inlier band of the ground-plane fit
_MIN_SUPPORT = 0.10  # a RANSAC ground plane must hold this fraction of the points near the sensor


def fit_band(cfg: PreprocessConfig) -> float:
    """The ground-plane fit's inlier band (m): the removed half-layer, but never wider than ``_FIT_TOL`` so that a
    thick removal layer does not let wall bottoms into the fit."""
    return min(cfg.ground_layer / 2.0, _FIT_TOL)


def fit_ground_plane(points: np.ndarray, cfg: PreprocessConfig, *, seed: int | None = None) -> np.ndarray:
    """Robust ground plane of a scan.

    Args:
        points: (N, 3) finite xyz, sensor frame, metres (z roughly up).
        cfg: uses ``ground_method``, ``ground_layer``, ``ground_seed_radius``,
            ``ground_max_tilt_deg`` and ``seed``.
        seed: overrides ``cfg.seed`` for the random steps (RANSAC triples, fit subsample).

    Returns:
        (4,) float64 ``[a, b, c, d]``, ``a x + b y + c z + d = 0``, ``||(a, b, c)|| = 1``, ``c > 0``.

    Raises:
        RegistrationError: fewer than 3 points within ``ground_seed_radius`` (horizontally), or no
            near-horizontal plane found.
    """
    pts = as_xyz(points, "preprocess")
    rng = np.random.default_rng(cfg.seed if seed is None else seed)
    near_idx = np.flatnonzero(_r2_xy(pts) <= np.float32(cfg.ground_seed_radius**2))
    if len(near_idx) < MIN_POINTS:
        raise RegistrationError(
            f"ground fit: only {len(near_idx)} points within ground_seed_radius={cfg.ground_seed_radius} m "
            f"of the sensor (need {MIN_POINTS})"
        )
    if len(near_idx) > _FIT_SAMPLES:
        near_idx = np.sort(rng.choice(near_idx, _FIT_SAMPLES, replace=False))
    near = np.take(pts, near_idx, axis=0).astype(np.float64)
    min_nz = float(np.cos(np.deg2rad(cfg.ground_max_tilt_deg)))
    tol = fit_band(cfg)
    if cfg.ground_method == "ransac":
        plane = _ransac_plane(near, tol, min_nz, cfg.ground_ransac_iters, rng)
    else:
        plane = _seeded_plane(near, tol, min_nz, cfg.ground_seed_radius)
    # Least-squares refinement on the points close to the robust estimate, tightening the band.
    return _refine_plane(near, plane, (tol, 0.5 * tol), min_nz)


def remove_ground(
    points: np.ndarray, cfg: PreprocessConfig, *, seed: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Fit the ground plane and mark the points outside its layer.

    Args:
        points: (N, 3) finite xyz, sensor frame, metres.
        cfg: see :func:`fit_ground_plane`; the removed layer is ``|signed distance| <= ground_layer / 2``.

    Returns:
        ``(nonground_mask (N,) bool, plane (4,) float64)``.
    """
    pts = as_xyz(points, "preprocess")
    plane = fit_ground_plane(pts, cfg, seed=seed)
    dist = signed_dist(pts, plane.astype(np.float32))
    return np.abs(dist) > cfg.ground_layer / 2.0, plane


def _lsq_plane(pts: np.ndarray) -> np.ndarray:
    """Total least-squares plane of (K, 3) float64 points: smallest principal axis, ``c >= 0``."""
    centroid = np.array([pts[:, 0].mean(), pts[:, 1].mean(), pts[:, 2].mean()])
    q = pts - centroid
    _, vecs = np.linalg.eigh(np.einsum("ki,kj->ij", q, q))
    normal = vecs[:, 0]
    if normal[2] < 0:
        normal = -normal
    return np.concatenate([normal, [-normal @ centroid]])


def _refit_plane(pts: np.ndarray, plane: np.ndarray, band: float, min_nz: float) -> np.ndarray | None:
    """Least-squares plane of the points of ``pts`` within ``band`` of ``plane``.

    None when fewer than MIN_POINTS are in the band or the fit tilts further than ``min_nz`` allows.
    """
    inl = np.compress(np.abs(signed_dist(pts, plane)) <= band, pts, axis=0)
    if len(inl) < MIN_POINTS:
        return None
    cand = _lsq_plane(inl)
    return None if cand[2] < min_nz else cand


def _refine_plane(pts: np.ndarray, plane: np.ndarray, bands: tuple[float, ...], min_nz: float) -> np.ndarray:
    """:func:`_refit_plane` once per band in turn, each from the last plane; stops at the first that fails."""
    for band in bands:
        cand = _refit_plane(pts, plane, band, min_nz)
        if cand is None:
            break
        plane = cand
    return plane


def _ransac_plane(pts: np.ndarray, tol: float, min_nz: float, iters: int, rng: np.random.Generator) -> np.ndarray:
    """Near-horizontal RANSAC plane (all hypotheses scored at once) of (K, 3) float64 points."""
    # Triples come from the lower half of the points (ground lies below most walls and poles);
    # hypotheses are scored on every other point, in float32.
    low = np.compress(pts[:, 2] <= np.median(pts[:, 2]), pts, axis=0)
    if len(low) < MIN_POINTS:
        low = pts
    tri = low[rng.integers(0, len(low), size=(iters, 3))]  # (H, 3 points, 3)
    normals, ok = triple_normals(tri)
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    ok &= normals[:, 2] >= min_nz
    if not ok.any():
        raise RegistrationError(
            f"ground fit: RANSAC found no plane within the allowed tilt of the horizontal among {len(pts)} points"
        )
    normals = normals[ok]
    d = -np.einsum("hj,hj->h", normals, tri[ok, 0])
    # Score: inliers within tol; ties broken towards the lower plane (smaller height offset d).
    sc = pts[::2].astype(np.float32)
    nf, df = normals.astype(np.float32), d.astype(np.float32)
    dist = sc[:, 0:1] * nf[:, 0] + sc[:, 1:2] * nf[:, 1] + sc[:, 2:3] * nf[:, 2] + df
    counts = np.count_nonzero(np.abs(dist) <= tol, axis=0)
    if counts.max() < _MIN_SUPPORT * len(sc):
        raise RegistrationError(
            f"ground fit: the best near-horizontal plane holds only {counts.max()} of {len(sc)} points "
            f"near the sensor (need {_MIN_SUPPORT:.0%})"
        )
    best = np.flatnonzero(counts == counts.max())
    best = best[np.argmax(d[best])]  # d = -height of the plane at the origin: largest d = lowest plane
    return np.concatenate([normals[best], [d[best]]])


def _seeded_plane(pts: np.ndarray, tol: float, min_nz: float, radius: float) -> np.ndarray:
    """Plane seeded by the dominant height near the sensor, grown outwards by least squares."""
    r2 = _r2_xy(pts)
    inner = np.compress(r2 <= (0.5 * radius) ** 2, pts, axis=0)
    if len(inner) < MIN_POINTS:
        inner = pts
    z = inner[:, 2]
    bin_w = max(tol / 2.0, 0.05)
    edges = np.arange(z.min(), z.max() + 2 * bin_w, bin_w)
    hist, edges = np.histogram(z, bins=edges)
    z0 = 0.5 * (edges[np.argmax(hist)] + edges[np.argmax(hist) + 1])
    plane = np.array([0.0, 0.0, 1.0, -z0])
    for frac in (0.25, 0.5, 1.0):
        sel = np.compress(r2 <= (frac * radius) ** 2, pts, axis=0)
        plane = _refine_plane(sel, plane, (2.0 * tol, 2.0 * tol), min_nz)
    return plane



def triple_normals(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (H, 3) of the planes through point triples ``tri`` (H, 3 points, 3), and the (H,) bool mask of
    the triples that span a plane (a degenerate triple's normal is left unnormalised)."""
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    normals[ok] /= norm[ok, None]
    return normals, ok


def signed_dist(pts: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """(N,) signed distance of (N, 3) points to ``plane`` (4,) (column ops: no BLAS threads)."""
    return pts[:, 0] * plane[0] + pts[:, 1] * plane[1] + pts[:, 2] * plane[2] + plane[3]



def _r2_xy(pts: np.ndarray) -> np.ndarray:
    """(N,) squared horizontal distance from the sensor of (N, 3) points."""
    return pts[:, 0] * pts[:, 0] + pts[:, 1] * pts[:, 1]
