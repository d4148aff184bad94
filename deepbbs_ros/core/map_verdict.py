"""The calibrated verdict of a scan in a prior map: the probability that a pose in the map is right (no ROS).

A map crop is dense, complete and seen from many origins, and a map may cover only part of what a scan sees (a
few metres of road seen from its end): the scan-to-scan verdict's probability (core/calibrated.py) means something
else there. This one is fitted on simulated map localizations (``scripts/calibrate_map_verdict.py``: right answers,
the search's own wrong answers at look-alike places, poses moved beyond 2 degrees / 0.5 m (optionally slid along the
direction their fit pins least), scans from outside the map; every road scene and indoor place, several sensors and
mounts).

Its features (:func:`names`) are those of core/visibility.py (:data:`~deepbbs_ros.core.visibility.FEATURES`, among
them ``pinned``: how well the fit pins all six degrees of freedom) for a spread subset of the scan's GICP voxels
(``registration.good_start_points``) against the crop's GICP cloud (its origin at the place, the crop's sensor; a
crop that is a view of the map's cloud is judged with the map's normals and tangent planes when the coefficients were
fitted so, :func:`uses_map_normals`), and two of this module's, normalised by what the map covers of the scan:

* ``covered``: the share of those points within :data:`COVER_DIST` m of the map;
* ``sharp``: among the covered, the share within ``registration.verdict_dist`` (a right pose fits closely wherever
  the map covers the scan, whatever the share it covers).

The coefficients ship in ``deepbbs_ros/resources/map_verdict_model.json`` (the features they use, by name, and a
logistic regression on :func:`~deepbbs_ros.core.calibrated.design` of them), read once; a missing or damaged file,
or one fitted for features that no longer exist, raises :class:`~deepbbs_ros.errors.VerdictModelError`.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.core import calibrated, visibility
from deepbbs_ros.core.polish import PolishView
from deepbbs_ros.core.polish_view import base_arrays
from deepbbs_ros.core.verdict import good_start_points
from deepbbs_ros.errors import VerdictModelError

DEFAULT_PATH = Path(__file__).resolve().parents[1] / "resources" / "map_verdict_model.json"
#: this module's features, after core/visibility.py's
EXTRA = ("covered", "sharp")
COVER_DIST = 1.0  # m; a scan point with the map this close counts as covered by the map


def names() -> tuple[str, ...]:
    """Every feature :func:`features` returns, in order: core/visibility.py's, then :data:`EXTRA`."""
    return (*visibility.FEATURES, *EXTRA)


def features(points: np.ndarray, T_place_scan: np.ndarray, cloud: Any, dist: float, threads: int = 1,
             map_normals: bool | None = None) -> np.ndarray:
    """The features (:func:`names`) of ``points`` (N, 3) (scan frame) under ``T_place_scan`` (4, 4) against a crop's
    GICP cloud ``cloud`` (a ``core.polish.PolishCloud`` or view, in the place's frame; its k-d tree) with the
    verdict's distance ``dist`` (m) -> (len(names()),) float64. ``map_normals``: a view is judged with the map's
    normals (else as a cloud without normals: the plane shares are ``fitness_close``'s, ``pinned`` 1); None: as the
    shipped coefficients were fitted (:func:`uses_map_normals`)."""
    pts = np.asarray(points, np.float64)
    T = np.asarray(T_place_scan, np.float64)
    moved = pts @ T[:3, :3].T + T[:3, 3]
    if map_normals is None:
        map_normals = uses_map_normals()
    if map_normals and isinstance(cloud, PolishView) and len(pts) and len(cloud.local):
        vis, sq = _view_features(moved, cloud, dist, threads)
    else:
        vis = visibility.pose_features(points, T_place_scan, cloud, dist, threads=threads, anchor=False)
        if len(pts) == 0:
            return np.r_[vis, 0.0, 0.0]
        _, sq = cloud.tree.batch_nearest_neighbor_search(moved, num_threads=max(1, threads))
    sq = np.asarray(sq, np.float64)
    covered = int(np.sum(sq <= COVER_DIST ** 2))
    close = int(np.sum(sq <= dist * dist))
    return np.r_[vis, covered / len(pts), close / covered if covered else 0.0]


def _view_target(view: PolishView, dist: float) -> tuple:
    """A crop view's visibility target, kept on the view: (its direction cells (core/directions.py
    ``directions``), self planarity, ``plane_own``'s tolerance), the last two from an even subset of the crop's points
    against their nearest other map point's tangent plane (core/target_surface.py's ``self_residuals`` on the map's
    cloud)."""
    kept = getattr(view, "_map_verdict", None)
    if kept is not None and kept[0] == dist:
        return kept[1]
    local = np.asarray(view.local, np.float64)
    P, N = base_arrays(view.cloud)
    R, t = view.tree.R, view.tree.t
    sub = local[:: max(1, len(local) // visibility._SELF_POINTS)] @ R.T + t
    idx, sq = view.tree.base.batch_knn_search(sub, 2, num_threads=1)
    j, sq = np.asarray(idx, np.int64)[:, 1], np.asarray(sq, np.float64)[:, 1]
    ok = (sq <= dist * dist) & (j >= 0) & (j < len(P))
    res = np.abs(np.einsum("ij,ij->i", sub[ok] - P[j[ok]], N[j[ok]]))
    out = (visibility.directions(local), float(np.mean(res <= 0.2 * dist)) if len(res) else 1.0,
           visibility.own_tolerance(res, dist))
    view._map_verdict = (dist, out)
    return out


def _view_features(moved: np.ndarray, view: PolishView, dist: float, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """core/visibility.py's features of ``moved`` (N, 3) (the place's frame) against a crop that is a view of the
    map's GICP cloud, with the map's tangent planes and normals (the view's own cloud is the whole map's: its normals
    do not line up with the crop's points) -> (features, squared distances (N,))."""
    table, own, tol = _view_target(view, dist)
    P, N = base_arrays(view.cloud)
    R, t = view.tree.R, view.tree.t
    at = moved @ R.T + t  # the map's frame
    idx, sq = view.tree.base.batch_nearest_neighbor_search(at, num_threads=max(1, threads))
    idx, sq = np.asarray(idx, np.int64), np.asarray(sq, np.float64)
    plane = np.einsum("ij,ij->i", at - P[idx], N[idx])
    return visibility.features(moved, sq, table, dist, plane, own, tol, N[idx].astype(np.float64) @ R), sq


def answer_features(src: Any, crop: Any, T_map_scan: np.ndarray, config: Any, threads: int = 1,
                    map_normals: bool | None = None) -> np.ndarray:
    """:func:`features` of a localization answer: the scan's PreprocessResult ``src`` at ``T_map_scan`` (4, 4) on a
    map crop (``_Crop``: ``T_map_place`` and its PreprocessResult); the scan's points are a spread subset of its GICP
    voxels (``registration.good_start_points``). -> an all-zero row when either has no GICP cloud."""
    spc, tpc = getattr(src, "polish_cloud", None), getattr(crop.pre, "polish_cloud", None)
    if spc is None or tpc is None:
        return np.zeros(len(names()))
    spc, tpc = spc.complete(threads=threads), tpc.complete(threads=threads)
    rc = config.registration
    T = np.linalg.inv(crop.T_map_place) @ np.asarray(T_map_scan, np.float64)
    return features(good_start_points(spc, rc), T, tpc, rc.verdict_dist, threads, map_normals)


@functools.lru_cache(maxsize=4)
def load(path: str | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """(the columns of :func:`names` the model uses (F,) int, coef (F,), intercept) from ``path`` (the shipped file
    when None); read once."""
    p = Path(path) if path else DEFAULT_PATH
    try:
        doc = json.loads(p.read_text())
        if doc["transform"] != calibrated.TRANSFORM:
            raise ValueError("fitted with another transform")
        have = names()
        missing = [n for n in doc["features"] if n not in have]
        if missing:
            raise ValueError(f"fitted for features that no longer exist: {', '.join(missing)}")
        cols = np.array([have.index(n) for n in doc["features"]], np.int64)
        coef = np.asarray(doc["coef"], np.float64)
        if coef.shape != cols.shape or not np.all(np.isfinite(coef)) or not np.isfinite(doc["intercept"]):
            raise ValueError(f"not {len(cols)} finite coefficients")
        return cols, coef, float(doc["intercept"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise VerdictModelError(f"map verdict {p}: {e} (refit: python scripts/calibrate_map_verdict.py)") from None


@functools.lru_cache(maxsize=4)
def uses_map_normals(path: str | None = None) -> bool:
    """The coefficients at ``path`` (the shipped file when None) were fitted on features of crop views with the map's
    normals (``"map_normals": true``; :func:`features`)."""
    load(path)  # a damaged file: VerdictModelError
    p = Path(path) if path else DEFAULT_PATH
    return bool(json.loads(p.read_text()).get("map_normals", False))


def probability(rows: np.ndarray, path: str | None = None) -> np.ndarray | float:
    """P(right) of feature rows (K, len(names())) -> (K,), or of one row -> float."""
    cols, coef, icpt = load(path)
    z = calibrated.design(np.atleast_2d(rows)[:, cols]) @ coef + icpt
    p = 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))
    return float(p[0]) if np.ndim(rows) == 1 else p


def answer_probability(src: Any, crop: Any, T_map_scan: np.ndarray, config: Any, threads: int = 1) -> float:
    """P(right) of a localization answer (:func:`answer_features`); 0 when it has no features."""
    row = answer_features(src, crop, T_map_scan, config, threads)
    return probability(row) if row.any() else 0.0
