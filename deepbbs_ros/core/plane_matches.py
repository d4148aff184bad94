"""The plane matches of a pose's points on a scan's precision-stage cloud, and how well they pin it (no ROS).

A point moved by the pose matches a plane where it lies within the verdict's distance of its nearest target point
and within a fifth of it of that point's tangent plane; ``pinned`` (core/visibility.py's feature, the second-minimum
check's weakest direction) reads how well those matches hold the pose. The nearest-neighbour search they come from is
kept on the cloud (:func:`_nearest`): the good start reads the same pose's matches several times.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core import anchoring
from deepbbs_ros.core.target_surface import _same_voxels

_PIN_MIN = 6  # close plane matches ``pinned`` needs (fewer: 0)
_KEPT = 4  # poses whose search a precision-stage cloud keeps


def _nearest(target, moved: np.ndarray, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """(index, squared distance) of the nearest target point of each of ``moved`` (N, 3) in a precision-stage cloud's
    k-d tree; the answers for the last :data:`_KEPT` point sets are kept on the cloud, so that the same points asked
    again (the verdict's features, the good start's score of the same pose, the second-minimum check's weakest
    direction and fitness, after other poses were judged) cost one search. Kept whole (the points' bytes with the
    answer), compared exactly and replaced in one assignment: threads asking side by side get a right answer either
    way."""
    key = moved.tobytes()
    kept = getattr(target, "_nearest_kept", ())
    for k, idx, sq in kept:
        if k == key:
            return idx, sq
    idx, sq = anchoring.nearest(target.tree, moved, threads)
    target._nearest_kept = ((key, idx, sq), *kept[:_KEPT - 1])
    return idx, sq


def pinned(points: np.ndarray, normals: np.ndarray, tol: float, info: np.ndarray | None = None) -> float:
    """How well point-to-plane matches pin a pose: ``s^2 / (s^2 + tol^2)`` (its log-odds: ``2 log(s / tol)``).

    ``s`` (m) is the root-mean-square change of the matches' point-to-plane residuals when the pose moves by one
    unit along its weakest direction, a unit being a right pose's tolerance (0.3 m, 1 degree): the smallest eigenvalue
    of the per-point information ``mean(a a^T)``, ``a = [n, p x n]`` (the target's normal ``n`` at the match, the moved
    point ``p``), scaled to those units. Equivalently ``tol / s`` is the pose's uncertainty along that direction in
    those units, when each residual is known to ``tol``. A single wall or a corridor leaves a direction free (near 0);
    a box corner or a street with cross walls pins every one. Per point, so that it means the same for 3,000 points as
    for 120,000; below :data:`_PIN_MIN` matches, 0.

    Args:
        points: (K, 3) the matched points moved into the target's frame, metres.
        normals: (K, 3) the target's unit normals at their matches.
        tol: m, the residual tolerance (``plane_close``'s, ``dist / 5``).
        info: their ``anchoring.information``, when the caller has it (None: computed here).
    """
    if len(points) < _PIN_MIN:
        return 0.0
    s2 = max(float(np.linalg.eigvalsh(anchoring.information(points, normals) if info is None else info)[0]), 0.0)
    return s2 / (s2 + tol * tol)


def _plane_matches(moved: np.ndarray, idx: np.ndarray, sq: np.ndarray, tpts: np.ndarray, normals: np.ndarray,
                   dist: float) -> tuple:
    """(the normals at the nearest target points ``idx``, the moved points' distances to their tangent planes, the plane
    matches' points and normals (``pinned``'s: :func:`features`' on_plane), their ``anchoring.information`` (None under
    :data:`_PIN_MIN`), ``pinned``) of ``moved`` (N, 3) against ``tpts`` / ``normals`` (M, 3), ``sq`` the squared
    distances."""
    nidx = normals[idx]
    plane = np.einsum("ij,ij->i", moved - tpts[idx], nidx)
    m = (sq <= dist * dist) & (np.abs(plane) <= 0.2 * dist)
    pm, nm = moved[m], nidx[m]
    info = anchoring.information(pm, nm) if len(pm) >= _PIN_MIN else None
    return nidx, plane, pm, nm, info, pinned(pm, nm, 0.2 * dist, info)


def surface(target) -> tuple[np.ndarray, np.ndarray | None]:
    """(points (M, 3) float64, unit normals (M, 3) or None where it has none) of a scan's precision-stage cloud
    (``core.polish.PolishCloud``): those its verdict tables hold (:func:`_target`), else read from it."""
    kept = getattr(target, "_visibility", None)
    if kept is not None and _same_voxels(target, kept[2]):
        return kept[1][0], kept[1][3]
    tpts = np.asarray(target.points(), np.float64)[:, :3]
    nrm = np.asarray(target.cloud.normals())[:, :3]
    return tpts, (nrm if len(nrm) == len(tpts) and np.any(nrm) else None)


def pose_pinned(points: np.ndarray, T: np.ndarray, target, dist: float, threads: int = 1) -> float:
    """:func:`pose_features`' ``pinned`` alone (the same number) of ``points`` (N, 3) (source frame) under ``T`` (4, 4)
    against a scan's precision-stage cloud: one nearest-neighbour search (kept: :func:`_nearest`) and the target's
    normals, without the direction tables, the own roughness and the anchoring's searches the other features read."""
    T = np.asarray(T, np.float64)
    moved = np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]
    tpts, normals = surface(target)
    if len(moved) == 0 or len(tpts) == 0:
        return 0.0  # as :func:`features` of nothing
    if normals is None:
        return 1.0  # as :func:`features` without normals
    idx, sq = _nearest(target, moved, threads)
    return _plane_matches(moved, np.asarray(idx, np.int64), np.asarray(sq, np.float64), tpts, normals, dist)[-1]
