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


def _nearest(target, moved: np.ndarray, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """(index, squared distance) of the nearest target point of each of ``moved`` (N, 3) in a precision-stage cloud's
    k-d tree; the last answer is kept on the cloud, so that the same points asked again (the verdict's features,
    then the good start's score of the same pose) cost one search. Kept whole (the points' bytes with the answer) and
    compared exactly: threads asking side by side get a right answer either way."""
    key = moved.tobytes()
    last = getattr(target, "_nearest_last", None)
    if last is not None and last[0] == key:
        return last[1], last[2]
    idx, sq = anchoring.nearest(target.tree, moved, threads)
    target._nearest_last = (key, idx, sq)
    return idx, sq


def _cell_table(az: np.ndarray, el: np.ndarray) -> tuple[float, tuple | None]:
    """:func:`cell_size`, and the :func:`_occupied` table of the cell chosen when it was computed on every direction
    (no subsample: then :func:`directions` reuses it), else None. A subsample of every ``step``-th direction with
    ``step >= _PER_CELL`` takes the first cell without a table: its cells hold at least ``step`` returns each."""
    step = max(1, -(-len(az) // _SHAPE_POINTS))
    if len(az) and step >= _PER_CELL:
        return float(_CELLS[0]), None
    az, el = az[::step], el[::step]
    if not len(az):
        return float(_CELLS[-1]), None
    # every cell's _occupied table at once, side by side in one array (the same keys: the same operations)
    i = ((az + np.pi) / _CELLS[:, None]).astype(np.int64)  # :func:`_keys`' cells (never negative: no floor needed)
    j = ((el + np.pi / 2) / _CELLS[:, None]).astype(np.int64)
    i0, j0 = i.min(axis=1), j.min(axis=1)
    rows = j.max(axis=1) - j0 + 1
    sizes = (i.max(axis=1) - i0 + 1) * rows
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    i *= rows[:, None]  # in place: each cell's table index (i - i0) * rows + j - j0, offset by its table's start
    i += j
    i += (starts - i0 * rows - j0)[:, None]
    tables = np.zeros(int(sizes.sum()), bool)
    tables[i.ravel()] = True
    for k, cell in enumerate(_CELLS):
        table = tables[starts[k]:starts[k] + sizes[k]]
        if len(az) * step / np.count_nonzero(table) >= _PER_CELL or k == len(_CELLS) - 1:
            return float(cell), (table, i[k] - starts[k], int(rows[k]), int(i0[k]), int(j0[k])) if step == 1 else None


#: the features :func:`features` returns, in order
FEATURES = ("fitness", "fitness_close", "plane_close", "consistency", "observable", "violations", "plane_rel",
            "plane_own", "violations_nb", "consistency_nb", "pinned", "in_view", "observable_rel", "anchored",
            "anchored_far")
_CELLS = np.radians([0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0])  # rad; the direction cells to choose from
_SELF_POINTS = 256  # target points whose fit to their own neighbours' planes measures how rough the target is
_SHAPE_POINTS = 4000  # the cell size is chosen on an even subsample of the target of at most this many points
_PER_CELL = 3.0  # target returns a direction cell should hold on average
_NEIGHBOURS = np.array([di + dj for di in (-100_000, 0, 100_000) for dj in (-1, 0, 1)], np.int64)  # the 3 x 3 cells
_OWN_Q = 0.9  # the target's own plane residual at this quantile is ``plane_own``'s tolerance (within dist/5..dist/2)
_PIN_MIN = 6  # close plane matches ``pinned`` needs (fewer: 0)
_VIEW_CELL = np.radians(5.0)  # rad; ``in_view``'s direction cells: the target's field of view at this resolution


def _angles(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth, elevation (rad) and range (m) of points (N, 3); the range is np.linalg.norm's to the last bit (the
    same products, summed in the same order) in a sixth of its time."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    r = np.sqrt(x * x + y * y + z * z)
    az = np.arctan2(y, x)
    el = np.arcsin(np.clip(z / np.maximum(r, 1e-9), -1.0, 1.0))
    return az, el, r


def _keys(az: np.ndarray, el: np.ndarray, cell: float) -> np.ndarray:
    """Direction cell keys ``i * 100_000 + j`` of azimuths ``az`` and elevations ``el`` (rad, :func:`_angles`) on a
    ``cell`` rad grid: ``az + pi`` and ``el + pi / 2`` are never negative, so the integer cast is the floor."""
    i = ((az + np.pi) / cell).astype(np.int64)
    j = ((el + np.pi / 2) / cell).astype(np.int64)
    return i * 100_000 + j


def cell_size(az: np.ndarray, el: np.ndarray) -> float:
    """The smallest direction cell (rad) of :data:`_CELLS` in which the target's occupied cells hold about
    ``_PER_CELL`` returns on average (measured on an even subsample of at most ``_SHAPE_POINTS``)."""
    return _cell_table(az, el)[0]


def _occupied(az: np.ndarray, el: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """The direction cells of a ``cell`` rad grid, over the span of directions the target has, as a flat table (no
    sort: a few tens of thousands of bytes for a spinning sensor's 30-degree band at 0.5 degrees): (True where a
    direction falls (the table), each direction's index in it, the elevation cells per azimuth cell (``rows``), the
    first azimuth cell ``i0``, the first elevation cell ``j0``); index ``k`` is :func:`_keys`'
    ``(k // rows + i0) * 100_000 + k % rows + j0``, in the same order."""
    if not len(az):
        return np.zeros(0, bool), np.zeros(0, np.int64), 1, 0, 0
    i = ((az + np.pi) / cell).astype(np.int64)
    j = ((el + np.pi / 2) / cell).astype(np.int64)
    i0, j0 = int(i.min()), int(j.min())
    rows = int(j.max()) - j0 + 1
    table = np.zeros((int(i.max()) - i0 + 1) * rows, bool)
    i *= rows  # in place: the index (i - i0) * rows + j - j0
    i += j
    i -= i0 * rows + j0
    table[i] = True
    return table, i, rows, i0, j0


def directions(target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The target's direction cells: (cell size (rad), the occupied cells' keys (sorted), the nearest return's range
    in each (m))."""
    taz, tel, tr = _angles(np.asarray(target, np.float64))
    cell, occupied = _cell_table(taz, tel)
    table, idx, rows, i0, j0 = _occupied(taz, tel, cell) if occupied is None else occupied
    nearest = np.full(len(table), np.inf)
    np.minimum.at(nearest, idx, tr)
    occupied = np.flatnonzero(table)  # in the order of _keys: the same sorted keys as a sort of them
    return cell, (occupied // rows + i0) * 100_000 + occupied % rows + j0, nearest[occupied]


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
    anchoring (the same plane matches)."""
    T = np.asarray(T, np.float64)
    moved = np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]
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
    nidx = normals[idx]
    plane = np.einsum("ij,ij->i", moved - tpts[idx], nidx)
    m = (sq <= dist * dist) & (np.abs(plane) <= 0.2 * dist)  # the plane matches (``pinned``'s: features' on_plane)
    pm, nm = moved[m], nidx[m]
    info = anchoring.information(pm, nm) if len(pm) >= _PIN_MIN else None
    pin = pinned(pm, nm, 0.2 * dist, info)
    held = None
    if anchor:
        bound = None if isinstance(anchor, (bool, np.bool_)) else float(anchor)
        if bound is None:
            held = anchoring.anchored(moved, sq, tree, pm, nm, dist, threads, info=info)
        elif pin < bound:  # what the bound reads: anchored_far alone
            held = (1.0, *anchoring.anchored(moved, sq, tree, pm, nm, dist, threads, anchoring.STEPS[-1:], info))
    return features(moved, sq, table, dist, plane, own, tol, nidx, held, view, pin)


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
    if cached is not None and cached[0] == dist:
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
        target._visibility = (dist, out)
    return out


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


_VIEW: tuple = (None, 0.0, np.zeros(0, bool))  # (a target's direction keys, their cell, :func:`in_view`'s table)


def in_view(moved: np.ndarray, cell: float, ukey: np.ndarray, keys: np.ndarray | None = None) -> float:
    """The share of ``moved`` (N, 3) (the target's sensor frame) whose direction falls in the target's field of view:
    the :data:`_VIEW_CELL` direction cells (a whole multiple of ``cell``) holding a target return, from the target's
    :func:`directions` keys ``ukey`` (``cell`` rad). Measured on the target's returns (no sensor's constants): a
    70-degree view turned by 35 degrees keeps about half of the source in it, a 360-degree one all of it. ``keys``:
    the points' :func:`_keys` on the ``cell`` grid, when the caller has them."""
    if len(moved) == 0 or len(ukey) == 0 or cell <= 0:
        return 0.0
    global _VIEW
    f = max(1, int(round(_VIEW_CELL / cell)))
    rows = int(np.pi / cell) // f + 2  # the coarse cells as a flat table (no sort), as :func:`_occupied`
    kept = _VIEW  # the last target's table (a target is judged several times in a row); one assignment below
    if kept[0] is not ukey or kept[1] != cell:
        table = np.zeros((int(2 * np.pi / cell) // f + 2) * rows, bool)
        table[(ukey // 100_000 // f) * rows + ukey % 100_000 // f] = True
        kept = _VIEW = (ukey, cell, table)
    table = kept[2]
    if keys is None:
        az, el, _ = _angles(np.asarray(moved, np.float64))
        keys = _keys(az, el, cell)
    return float(np.mean(table[(keys // 100_000 // f) * rows + keys % 100_000 // f]))
