"""What a pose says the target sensor should have seen, against what it saw (no ROS).

A right pose puts the source's surfaces where the target sensor saw surfaces; a wrong one puts some of them
in space the target sensor saw through. With the moved source points in the target's sensor frame (a scan's
frame is its sensor's origin; a map crop's is the place it was cut round), every point is:

* **seen**: within ``dist`` m of a target point;
* **violating**: clearly in front of the nearest target return in its direction cell (the target's rays
  there all went further: the source says there is a surface where the target saw free space);
* **unknown**: behind the target's returns (occluded), or in a direction with no target return (outside the
  target's field of view or range): it says nothing either way.

Direction cells (azimuth x elevation) are sized from the target cloud's own angular density, so that a
64-beam ring, a 16-beam ring and a Livox rosette get cells holding a few returns each. :func:`features`
gives the numbers the calibrated verdict (core/calibrated.py) turns into a probability; each is a share,
so it means the same for a 3,000-point handheld cloud and a 120,000-point car scan.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core import anchoring
from deepbbs_ros.core.directions import (  # noqa: F401  (re-exported)
    _CELLS,
    _PER_CELL,
    _SHAPE_POINTS,
    _VIEW_CELL,
    _angles,
    _cell_table,
    _keys,
    _occupied,
    cell_size,
    directions,
    in_view,
)
from deepbbs_ros.core.plane_matches import (  # noqa: F401  (re-exported)
    _PIN_MIN,
    _nearest,
    _plane_matches,
    pinned,
    pose_pinned,
    surface,
)
from deepbbs_ros.core.target_surface import (  # noqa: F401  (re-exported)
    _OWN_Q,
    _SELF_POINTS,
    _pca_normals,
    _quantile,
    _same_voxels,
    _target,
    _voxels,
    own_tolerance,
    roughness,
    self_planarity,
    self_residuals,
    spread_points,
    target_points,
)

#: the features :func:`features` returns, in order
FEATURES = ("fitness", "fitness_close", "plane_close", "consistency", "observable", "violations", "plane_rel",
            "plane_own", "violations_nb", "consistency_nb", "pinned", "in_view", "observable_rel", "anchored",
            "anchored_far")
_NEIGHBOURS = np.array([di + dj for di in (-100_000, 0, 100_000) for dj in (-1, 0, 1)], np.int64)  # the 3 x 3 cells


def features(moved: np.ndarray, sq_dist: np.ndarray, target: np.ndarray, dist: float,
             plane_dist: np.ndarray | None = None, self_plane: float | None = None,
             own_tol: float | None = None, normals: np.ndarray | None = None,
             anchored: tuple[float, float] | None = None, view: bool = True,
             pin: float | None = None) -> np.ndarray:
    """The verdict's features of a pose -> (len(FEATURES),) float64.

    Args:
        moved: (N, 3) source points moved into the target's sensor frame by the pose, metres.
        sq_dist: (N,) squared distance of each to its nearest target point (the k-d tree's answer).
        target: (M, 3) the target cloud in its sensor frame, metres (its precision-stage voxels, or a map crop), or
            its :func:`directions` table.
        dist: m, the verdict's distance (``registration.verdict_dist``).
        plane_dist: (N,) distance of each to its nearest target point's tangent plane (None: no normals).
        self_plane: the same share as ``plane_close`` for target points against their nearest other target point
            (:func:`self_planarity`): how close the target's own surfaces come to planes (None: 1).
        own_tol: m, ``plane_own``'s tolerance (:func:`own_tolerance`; None: ``dist / 5``).
        normals: (N, 3) the target's unit normal at each point's nearest target point (None: ``pinned`` is 1).
        anchored: ``anchored`` and ``anchored_far`` (core/anchoring.py: how firmly the pose is held along its weakest
            direction, moved by a wrong pose's distance and by a slide's; None: 1, 1).
        view: measure ``in_view``; False (a model that does not read it or ``observable_rel``): 1, as for a target
            that sees every direction (``observable_rel`` is then ``observable``).
        pin: ``pinned`` of these matches, when the caller measured it (:func:`pose_features`); None: measured here.

    ``fitness``: share of the points seen (within ``dist``); ``fitness_close``: the share within ``dist / 2``
    among those (how tightly they fit); ``plane_close``: the share within ``dist / 5`` of the nearest target point's
    tangent plane among those (``fitness_close`` without normals); ``consistency``: seen / (seen + violating);
    ``observable``:
    (seen + violating) / N, the share the target could judge (the overlap); ``violations``: violating / N;
    ``plane_rel``: ``plane_close`` over ``self_plane`` (at most 1): as tight as the target's own surfaces allow, so
    that a rough real scene (trees, motion) is not taken for a loose fit; ``plane_own``: ``plane_close`` with the
    tolerance widened to the target's own roughness (``own_tol``: the residual of the target's own points to their
    neighbours' planes that :data:`_OWN_Q` of them stay within, from ``dist / 5`` to ``dist / 2``): a right pose on a
    rough surface fits as its own points do, and scores as a right pose on a smooth one; ``violations_nb`` and
    ``consistency_nb``: ``violations`` and ``consistency`` with a point violating only when it is also in front of
    the nearest return of the 8 neighbouring direction cells (a sparse ring's cell holds the ground of one ring only:
    a right source point on the ground a ring lower is closer than that return, not in the target's free space);
    ``pinned``: how well the points on the target's planes (``plane_close``'s) pin all six degrees of freedom
    (:func:`pinned`): a pose that slides along a wall, a corridor or a floor and one wall fits as tightly as a right
    one, but the fit does not tell where along them it is (without tangent plane distances, of the points within
    ``dist / 2``); ``in_view``: the share of the points whose direction from the target's sensor falls in the target's
    field of view (:func:`in_view`: the overlap the pose itself expects; a narrow sensor turned by half its view
    between the scans: about one half, a pose slid along a corridor: about one); ``observable_rel``: ``observable``
    over ``in_view`` (at most 1): the overlap measured against the one expected, so that a right pose of a sensor
    that turned is not taken for a loose one.
    """
    n = len(moved)
    if n == 0 or len(target) == 0 or (isinstance(target, tuple) and len(target[1]) == 0):
        return np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    sq = np.asarray(sq_dist, np.float64)
    seen = sq <= dist * dist
    n_seen = np.count_nonzero(seen)
    close = np.count_nonzero(sq <= 0.25 * dist * dist)
    off = None if plane_dist is None else np.abs(plane_dist)  # from the tangent planes
    on_plane = None if off is None else seen & (off <= 0.2 * dist)
    plane = close if on_plane is None else np.count_nonzero(on_plane)
    matched = seen & (sq <= 0.25 * dist * dist) if on_plane is None else on_plane  # no tangent planes: close points
    if pin is None:
        pin = 1.0 if normals is None else pinned(moved[matched], normals[matched], 0.2 * dist)
    tol = 0.2 * dist if own_tol is None else own_tol
    own = close if off is None else np.count_nonzero(seen & (off <= tol))
    cell, ukey, nearest = target if isinstance(target, tuple) else directions(target)
    un = ~seen
    viol = viol_nb = 0
    # every point's direction cell once, when in_view reads them all (elementwise: the same numbers for the unseen)
    every = _angles(np.asarray(moved, np.float64)) if view else None
    keys = None if every is None else _keys(every[0], every[1], cell)
    if un.any():
        if every is None:
            saz, sel, sr = _angles(np.asarray(moved, np.float64)[un])
            skey = _keys(saz, sel, cell)
        else:
            sr, skey = every[2][un], keys[un]
        idx = np.clip(np.searchsorted(ukey, skey), 0, len(ukey) - 1)
        hit = ukey[idx] == skey
        margin = np.maximum(2.0 * dist, 0.05 * nearest[idx])  # clearly in front: noise and the cell's spread
        bad = hit & (sr < nearest[idx] - margin)
        viol = np.count_nonzero(bad)
        if viol:  # a subset of these (the neighbours' nearest return is no farther than the cell's own)
            near = _around(ukey, nearest, skey[bad])
            viol_nb = np.count_nonzero(sr[bad] < near - np.maximum(2.0 * dist, 0.05 * near))
    judged, judged_nb = n_seen + viol, n_seen + viol_nb
    plane_close = plane / max(n_seen, 1)
    rel = min(1.0, plane_close / max(self_plane if self_plane is not None else 1.0, 0.05))
    view = in_view(moved, cell, ukey, keys) if view else 1.0
    return np.array([n_seen / n, close / max(n_seen, 1), plane_close, n_seen / judged if judged else 0.0,
                     judged / n, viol / n, rel, own / max(n_seen, 1), viol_nb / n,
                     n_seen / judged_nb if judged_nb else 0.0, pin, view, min(1.0, judged / n / view) if view else 0.0,
                     *((1.0, 1.0) if anchored is None else anchored)])


def _around(ukey: np.ndarray, nearest: np.ndarray, skey: np.ndarray) -> np.ndarray:
    """The nearest target return (m) in each of the cells ``skey`` and their 8 neighbours (inf where none)."""
    k = (skey[None, :] + _NEIGHBOURS[:, None]).ravel()
    idx = np.clip(np.searchsorted(ukey, k), 0, len(ukey) - 1)
    return np.where(ukey[idx] == k, nearest[idx], np.inf).reshape(9, -1).min(axis=0)


def pose_features(points: np.ndarray, T: np.ndarray, target, dist: float, threads: int = 1,
                  anchor: bool | float = True, view: bool = True) -> np.ndarray:
    """:func:`features` of ``points`` (N, 3) (source frame) under ``T`` (4, 4) ``T_target_source`` against
    ``target``: a precision-stage cloud (``core.polish.PolishCloud``: its voxels, k-d tree and normals) or a
    plain (M, 3) cloud (a ``scipy`` k-d tree is built; no tangent planes: ``pinned`` takes the normals of the matched
    points' 8 nearest neighbours). ``anchor``: measure ``anchored`` and ``anchored_far`` (two more nearest-neighbour
    searches each, against a precision-stage cloud; else 1, as without one); a number: only ``anchored_far`` (what a
    bound reads; ``anchored`` 1, as unmeasured), only for a pose whose ``pinned`` is under it. ``view``: measure
    ``in_view`` (else 1: :func:`features`). ``pinned`` is measured once, here, for both :func:`features` and the
    anchoring (the same plane matches). Against a scan's precision-stage cloud the last few answers are kept on it
    (the good start judges a pose on it again: its second-minimum check, the finished pose's verdicts, its answer)."""
    T = np.asarray(T, np.float64)
    moved = np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]
    tree = getattr(target, "tree", None)
    if tree is None or hasattr(tree, "base"):  # a plain cloud, or a map crop's view (many of them: nothing kept)
        return _pose_features(moved, target, dist, threads, anchor, view)
    flag = ("b", bool(anchor)) if isinstance(anchor, (bool, np.bool_)) else ("f", float(anchor))
    key = (moved.tobytes(), float(dist), flag, bool(view))
    kept = getattr(target, "_features_kept", None)
    if kept is not None and _same_voxels(target, kept[0]):
        for k, f in kept[1]:
            if k == key:  # the same points, pose and settings, compared exactly: the same features
                return f.copy()
    f = _pose_features(moved, target, dist, threads, anchor, view)
    old = kept[1] if kept is not None and _same_voxels(target, kept[0]) else ()
    target._features_kept = (_voxels(target), ((key, f.copy()), *old[:_KEPT - 1]))  # one assignment: thread-safe
    return f


_KEPT = 4  # poses whose features a precision-stage cloud keeps


def _pose_features(moved: np.ndarray, target, dist: float, threads: int, anchor: bool | float,
                   view: bool) -> np.ndarray:
    """:func:`pose_features` of the points already moved (``moved`` (N, 3), the target's frame)."""
    tree = getattr(target, "tree", None)
    tpts, table, own, normals, tol = _target(target, dist)
    if len(moved) == 0 or len(tpts) == 0:
        return features(moved, np.zeros(0), tpts, dist)
    if tree is None:
        from scipy.spatial import cKDTree

        ktree = cKDTree(tpts)
        d, idx = ktree.query(moved, k=1)
        sq = d * d
        normals = _pca_normals(tpts, ktree, idx)
    else:
        idx, sq = _nearest(target, moved, threads)
    idx = np.asarray(idx, np.int64)
    if tree is None:  # normals of a plain cloud's matched points (``pinned`` only)
        return features(moved, np.asarray(sq, np.float64), table, dist, normals=normals, view=view)
    sq = np.asarray(sq, np.float64)
    if normals is None:
        return features(moved, sq, table, dist, None, own, tol, view=view)
    nidx, plane, pm, nm, info, pin = _plane_matches(moved, idx, sq, tpts, normals, dist)
    held = None
    if anchor:
        bound = None if isinstance(anchor, (bool, np.bool_)) else float(anchor)
        if bound is None:
            held = anchoring.anchored(moved, sq, tree, pm, nm, dist, threads, info=info)
        elif pin < bound:  # what the bound reads: anchored_far alone
            held = (1.0, *anchoring.anchored(moved, sq, tree, pm, nm, dist, threads, anchoring.STEPS[-1:], info))
    return features(moved, sq, table, dist, plane, own, tol, nidx, held, view, pin)
