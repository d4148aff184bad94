"""Is a pose held where it is along its weakest direction? The verdict's ``anchored`` feature (no ROS).

A pose that slides along a corridor, a wall or a floor and one wall fits the planes as tightly as the right one
(core/visibility.py's ``pinned`` is low for both). What can still tell them apart is everything else the two scans
share along that free direction: a door frame, a pillar, a kerb, a corridor's end. Move the pose along the direction
its plane matches pin least, both ways, by :data:`STEPS` tolerances (0.6 m or 2 degrees: a wrong pose's distance;
1.5 m or 5 degrees: a slide's), and count the source points that stay within ``dist / 2`` of the target: a right
pose held by such structure loses many of them either way; a pose in the middle of a slide loses few, or gains some
(the fit is better elsewhere).

``anchored`` (``anchored_far``: the longer step) = 1 - (the better of the two moved poses' close points) / (the
pose's own), within [0, 1]: a share, so that it means the same for 500 points as for 50,000. Two nearest-neighbour
searches of the verdict's points per step (one where the first side keeps every close point: 0 whatever the other).
"""

from __future__ import annotations

import numpy as np

#: m, rad: one tolerance of a right pose along each of the six degrees of freedom (``pinned``'s units)
SCALE = np.array([0.3, 0.3, 0.3, *np.radians([1.0, 1.0, 1.0])])
#: tolerances the pose is moved by along its weakest direction: 0.6 m or 2 degrees (``anchored``: a wrong pose's
#: distance), 1.5 m or 5 degrees (``anchored_far``: a slide's)
STEPS = (2.0, 5.0)
MIN_MATCHES = 6  # plane matches needed to find the weakest direction (fewer: every direction is weak, 0)


def information(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The per-match information of point-to-plane matches in tolerance units: ``mean(a a^T)`` with
    ``a = [n, p x n] * SCALE`` (the target's unit normal ``n`` at the match of the moved point ``p``) -> (6, 6)."""
    p, n = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    a = np.empty((len(p), 6))
    a[:, :3] = n
    a[:, 3] = p[:, 1] * n[:, 2] - p[:, 2] * n[:, 1]  # p x n
    a[:, 4] = p[:, 2] * n[:, 0] - p[:, 0] * n[:, 2]
    a[:, 5] = p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0]
    a *= SCALE
    return a.T @ a / len(a)


def weakest(points: np.ndarray, normals: np.ndarray, info: np.ndarray | None = None) -> np.ndarray | None:
    """The twist (6,) (m, rad: translation, rotation about the target's origin) of one tolerance unit along the
    direction the matches pin least (``info``: their :func:`information`, when known); None below
    :data:`MIN_MATCHES` matches."""
    if len(points) < MIN_MATCHES:
        return None
    w, v = np.linalg.eigh(information(points, normals) if info is None else info)
    return v[:, 0] * SCALE


def _rotation(w: np.ndarray) -> np.ndarray:
    """The rotation matrix of the rotation vector ``w`` (3,) (rad; Rodrigues)."""
    a = float(np.linalg.norm(w))
    if a < 1e-12:
        return np.eye(3)
    k = w / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def nearest(tree, points: np.ndarray, threads: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """((N,) int64 index, (N,) float64 squared distance) of the nearest point in ``tree`` to each of ``points``
    (N, 3): a ``small_gicp.KdTree``'s k = 1 search, which answers in arrays, the same numbers as its nearest-neighbour
    search's lists without building them; anything else with ``batch_nearest_neighbor_search`` (a map crop's view of
    the map's tree): that."""
    knn = getattr(tree, "batch_knn_search", None)
    if knn is None:
        idx, sq = tree.batch_nearest_neighbor_search(points, num_threads=max(1, threads))
        return np.asarray(idx, np.int64), np.asarray(sq, np.float64)
    idx, sq = knn(points, 1, num_threads=max(1, threads))
    return idx[:, 0].astype(np.int64), sq[:, 0]


def sq_dists(tree, points: np.ndarray, threads: int = 1) -> np.ndarray:
    """(N,) float64 squared distance of each of ``points`` (N, 3) to its nearest point in ``tree`` (:func:`nearest`)."""
    return nearest(tree, points, threads)[1]


def anchored(moved: np.ndarray, sq_dist: np.ndarray, tree, matched: np.ndarray, normals: np.ndarray, dist: float,
             threads: int = 1, steps: tuple[float, ...] = STEPS,
             info: np.ndarray | None = None) -> tuple[float, ...]:
    """How firmly the pose is held along its weakest direction (see the module), for each of ``steps`` (of
    :data:`STEPS`: ``anchored``, ``anchored_far``; only the last, where nothing reads the first) -> [0, 1].

    Args:
        moved: (N, 3) the verdict's source points moved into the target's frame by the pose, metres.
        sq_dist: (N,) their squared distances to the nearest target point.
        tree: the target's ``small_gicp.KdTree`` (``batch_nearest_neighbor_search``).
        matched: (K, 3) the moved points matched on the target's planes, and ``normals`` (K, 3) the target's unit
            normals at their matches (``pinned``'s matches: they give the weakest direction).
        dist: m, the verdict's distance (``registration.verdict_dist``); close is within ``dist / 2``.
        info: :func:`information` of ``matched`` and ``normals``, when the caller has it (None: computed here).
    """
    moved = np.asarray(moved, np.float64)
    close = float(np.sum(np.asarray(sq_dist, np.float64) <= 0.25 * dist * dist))
    twist = weakest(matched, normals, info)
    if close == 0 or twist is None:
        return (0.0,) * len(steps)
    out = []
    for k in steps:
        best = 0.0
        for sign in (1.0, -1.0):
            if best >= close:  # one side keeps every close point already: 0 whatever the other keeps
                break
            step = sign * k * twist
            q = moved @ _rotation(step[3:]).T + step[:3]
            best = max(best, float(np.sum(sq_dists(tree, q, threads) <= 0.25 * dist * dist)))
        out.append(float(np.clip(1.0 - best / close, 0.0, 1.0)))
    return tuple(out)
