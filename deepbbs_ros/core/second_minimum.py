"""Can an accepted pose slide to a second minimum along its weakest direction? (no ROS)

In a corridor, a garage or a hall the verdict's features cannot tell a right pose from one slid along the direction
the scene leaves nearly free: both fit the planes as tightly, and the structure that would pin them (a pillar, a door
frame) is as well lined up 2-4 tolerances away. GICP can: started from the pose moved along that direction, it falls
back to the pose when the pose is the only minimum there, and settles somewhere else when the scene has another one.

The check, on an accepted pose with the precision stage's clouds:

1. the weakest direction and its stiffness, from the target's normals at the plane matches of the verdict's points
   (core/anchoring.py's information, the ``pinned`` feature's): ``uncertainty = tol / s`` tolerances (0.3 m, 1
   degree), ``s`` the rms change of a match's point-to-plane residual per tolerance moved along it, ``tol`` the
   residual tolerance (``verdict_dist / 5``). At most one tolerance (``pinned`` >= 0.5): the fit holds the pose
   within a right pose's tolerance along every direction, nothing to check.
2. GICP (the precision stage's settings) from the pose moved ``k`` tolerances both ways along it, ``k`` the
   uncertainty clipped to [2, 5] tolerances (core/anchoring.py's STEPS: a wrong pose's distance, a slide's): as far
   as the fit leaves the pose free, at least beyond the wrong-pose tolerance.
3. ambiguous when a start settles more than one tolerance from the pose (so one of the two is wrong) with a fitness
   (the verdict's, at ``verdict_dist``) as good as the pose's: not below it by more than two standard errors of a
   share of ``n`` points, ``2 sqrt(p (1 - p) / n)``, ``p = (f n + 1) / (n + 2)`` (the rule of succession).

Cost: two nearest-neighbour searches and two GICP runs on the poses it checks (none on well-pinned ones); a start whose
first two iterations bring it back within a quarter tolerance of the pose stops there (``LEG``, ``BACK``: GICP from it
would only settle on the pose), one they bring to convergence is that run whole, any other is run whole.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.core import anchoring, plane_matches, verdict
from deepbbs_ros.core.polish import MIN_POLISH_POINTS, SMALL_GICP_TYPE, correspondence_distance, gicp_align, polish
from deepbbs_ros.core.polish_result import outcome
from deepbbs_ros.core.polish_view import PolishView

__all__ = ["Ambiguity", "check", "offset", "weakest"]

WRONG = 1.0  # tolerances: two minima further apart than this cannot both be right
STEPS = anchoring.STEPS  # tolerances: the shortest and the longest move along the weakest direction
SIGMAS = 2.0  # standard errors of the fitness within which another minimum fits as well
# a start GICP's first LEG iterations bring within BACK tolerances of the pose is back in its basin, not run further
# (the OS0-64 corridor's, 5 tolerances out: 0.00-0.15 after two, 0.08-0.82 after one); one iteration within WRONG
# is not enough: a pose slid along a free corridor is passed by a start that settles beyond it
LEG, BACK = 2, 0.25


@dataclass
class Ambiguity:
    """What :func:`check` found. ``uncertainty``: tolerances along the weakest direction (inf: too few plane
    matches); ``step``: tolerances the starts were moved by (0: not checked); ``other``: the other minimum (4, 4) or
    None; ``offset``: its distance from the pose in tolerances; ``score`` / ``other_score``: their fitness."""

    ambiguous: bool = False
    uncertainty: float = 0.0
    step: float = 0.0
    other: np.ndarray | None = None
    offset: float = 0.0
    score: float = float("nan")
    other_score: float = float("nan")
    found: list = field(default_factory=list)  # (offset, fitness) of each start's minimum, in the order tried


def weakest(moved: np.ndarray, tgt_pc, dist: float, threads: int = 1,
            translation: bool = False) -> tuple[np.ndarray | None, float]:
    """The twist (6,) of one tolerance along the weakest direction of the pose that moved the verdict's points to
    ``moved`` (N, 3), and the uncertainty along it in tolerances (see the module); (None, inf) with too few plane
    matches on the target's normals. ``translation``: the weakest of the translations alone (a slide; the rotation
    held), whose twist has no rotation."""
    if isinstance(tgt_pc, PolishView):  # a map crop: the map's points and normals, in the crop's frame
        idx, sq = tgt_pc.tree.batch_nearest_neighbor_search(moved, num_threads=max(1, threads))
        idx, sq = np.asarray(idx, np.int64), np.asarray(sq, np.float64)
        tpts, normals = tgt_pc.at(idx)
    else:  # a scan's cloud: the verdict's search of the same points and its normals, kept on it
        tpts, normals = plane_matches.surface(tgt_pc)
        if normals is None:
            return None, float("inf")
        idx, sq = plane_matches._nearest(tgt_pc, moved, threads)
        tpts, normals = tpts[idx], normals[idx]
    plane = np.einsum("ij,ij->i", moved - tpts, normals)
    m = (sq <= dist * dist) & (np.abs(plane) <= 0.2 * dist)  # the plane matches (``pinned``'s)
    if m.sum() < anchoring.MIN_MATCHES:
        return None, float("inf")
    info = anchoring.information(moved[m], normals[m])
    w, v = np.linalg.eigh(info[:3, :3] if translation else info)
    s = float(np.sqrt(max(w[0], 0.0)))
    twist = np.r_[v[:, 0], np.zeros(3)] if translation else v[:, 0]
    return twist * anchoring.SCALE, (0.2 * dist / s if s > 0 else float("inf"))


def offset(T: np.ndarray, T2: np.ndarray) -> float:
    """Tolerances between two poses (4, 4): the larger of their distance / 0.3 m and their angle / 1 degree."""
    d = np.linalg.solve(T, T2)
    ang = float(np.arccos(np.clip((np.trace(d[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return max(float(np.linalg.norm(d[:3, 3])) / anchoring.SCALE[0], ang / anchoring.SCALE[3])


def _moved_by(twist: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``T`` (4, 4) moved by ``twist`` (6,) (translation, rotation about the target's origin)."""
    D = np.eye(4)
    D[:3, :3] = anchoring._rotation(twist[3:])
    D[:3, 3] = twist[:3]
    return D @ T


def check(points: np.ndarray, T: np.ndarray, src_pc, tgt_pc, rc, threads: int = 1, loose: float = WRONG,
          crop: bool = False, reach: bool = False) -> Ambiguity:
    """Whether the pose ``T`` (4, 4) ``T_target_source`` has a second minimum as good along its weakest direction
    (see the module). ``points``: the verdict's points (N, 3), source frame; ``src_pc`` / ``tgt_pc``: the precision
    stage's clouds (``core.polish.PolishCloud``); ``rc``: the registration section (its ``verdict_dist`` and
    ``polish*`` keys); ``loose``: tolerances of uncertainty from which the pose is checked (at most that: not);
    ``crop``: a map crop (``core.polish.PolishView``) is checked too (the map verdict's acceptance, core/acceptance.py),
    else not; ``reach``: where the first two starts find no other minimum and the fit leaves a slide free (the weakest
    translation, the rotation held, looser than ``loose``), starts moved along that slide 2, 4, ... times as far both
    ways are tried too, up to the target cloud's extent along it (:func:`reaches`)."""
    T = np.asarray(T, np.float64)
    pts = np.asarray(points, np.float64)
    if len(pts) == 0 or (isinstance(tgt_pc, PolishView) and not crop) or rc.polish not in SMALL_GICP_TYPE:
        # no points, a map crop (core.polish.PolishView: localization judges its own way), or no GICP to run
        # (registration.polish "none")
        return Ambiguity()
    dist = rc.verdict_dist
    moved = pts @ T[:3, :3].T + T[:3, 3]
    twist, unc = weakest(moved, tgt_pc, dist, threads)
    if twist is None or unc <= max(loose, WRONG):
        return Ambiguity(uncertainty=unc)
    k = float(np.clip(unc, STEPS[0], STEPS[-1]))
    if isinstance(tgt_pc, PolishView):
        f = verdict.fitness(pts, tgt_pc.tree, T, dist, threads)
    else:  # the same share from the search :func:`weakest` read (kept on the cloud)
        f = float(np.mean(plane_matches._nearest(tgt_pc, moved, threads)[1] <= dist * dist))
    n = len(pts)
    p = (f * n + 1.0) / (n + 2.0)  # the share's estimate by the rule of succession: a spread even at 0 or 1
    margin = SIGMAS * np.sqrt(p * (1.0 - p) / n)
    out = Ambiguity(uncertainty=unc, step=k, score=f)
    _try(out, k, twist, pts, T, f, margin, src_pc, tgt_pc, rc, threads)
    if not reach or out.ambiguous:
        return out
    slide, unc_t = weakest(moved, tgt_pc, dist, threads, translation=True)
    if slide is None or unc_t <= max(loose, WRONG):
        return out  # the fit holds every slide within a tolerance
    k_t = float(np.clip(unc_t, STEPS[0], STEPS[-1]))
    for step in reaches(k_t, slide, tgt_pc)[1:]:  # 2, 4, ... times as far, each minimum within half a step of its start
        _try(out, step, slide, pts, T, f, margin, src_pc, tgt_pc, rc, threads, near=step / 2)
        if out.ambiguous:
            break
    return out


def reaches(k: float, twist: np.ndarray, tgt_pc) -> list[float]:
    """The steps (tolerances) ``k``, ``2 k``, ``4 k``, ... along ``twist`` (6,) (one tolerance) while the move stays
    within the target cloud's extent along its translation (max - min of the points' projections) and half a turn."""
    t, r = float(np.linalg.norm(twist[:3])), float(np.linalg.norm(twist[3:]))
    pts = np.asarray(tgt_pc.cloud.points())[:, :3]
    limit = np.pi / r if r > 0 else float("inf")
    if t > 0 and len(pts):
        proj = pts @ (twist[:3] / t)
        limit = min(limit, float(proj.max() - proj.min()) / t)
    steps = [k]
    while steps[-1] * 2.0 <= limit:
        steps.append(steps[-1] * 2.0)
    return steps


def _try(out: Ambiguity, k: float, twist: np.ndarray, pts: np.ndarray, T: np.ndarray, f: float, margin: float,
         src_pc, tgt_pc, rc, threads: int, near: float = float("inf")) -> None:
    """GICP from ``T`` moved ``k`` tolerances both ways along ``twist``; what it finds goes into ``out`` (a minimum
    further than ``near`` tolerances from its start is not one along the direction: left out)."""
    dist = rc.verdict_dist
    for sign in (1.0, -1.0):
        start = _moved_by(sign * k * twist, T)
        leg, pol = _from(src_pc, tgt_pc, T, start, rc)
        if pol is None:
            out.found.append((leg, f))
            continue  # GICP's first iterations brought it back to the pose: its own basin
        if not pol.applied:
            continue  # not converged (or moved implausibly far): no minimum found from there
        T2 = pol.T_target_source
        d = offset(T, T2)
        if d <= WRONG:
            out.found.append((d, f))
            continue  # back to the pose: its own basin
        if offset(start, T2) > near:
            continue  # settled far from its start: not a minimum along the direction
        f2 = verdict.fitness(pts, tgt_pc.tree, T2, dist, threads)
        out.found.append((d, f2))
        if f2 >= f - margin and (out.other is None or f2 > out.other_score):
            out.ambiguous, out.other, out.offset, out.other_score = True, T2, d, f2


def _from(src_pc, tgt_pc, T: np.ndarray, start: np.ndarray, rc) -> tuple[float, Any]:
    """GICP from ``start`` (4, 4): its first ``LEG`` iterations (core/polish.py's settings), then, unless they brought
    it within ``BACK`` tolerances of the pose ``T`` (4, 4), the whole run from ``start`` again (the very run without
    the leg; converged within the leg, the leg is that run: the same iterations, not run again) -> (tolerances from
    ``T`` after the leg, the :func:`core.polish.polish` result or None: came back)."""
    if rc.polish_max_iters <= LEG:  # no shorter leg than the run itself
        return 0.0, polish(src_pc, tgt_pc, start, rc)
    corr = correspondence_distance([src_pc, tgt_pc], rc)
    view = isinstance(tgt_pc, PolishView)
    base = tgt_pc.T_base if view else np.eye(4)  # a map crop: aligned in the map's frame
    tree = tgt_pc.tree.base if view else tgt_pc.tree
    res = gicp_align(tgt_pc.cloud, src_pc.cloud, tree, base @ start, LEG, rc, corr)
    leg = offset(T, np.linalg.solve(base, np.asarray(res.T_target_source, np.float64)))
    if not res.converged:
        return leg, None if leg <= BACK else polish(src_pc, tgt_pc, start, rc)  # not back: the whole run
    if any(c.pending is not None or c.n_points < MIN_POLISH_POINTS for c in (src_pc, tgt_pc)):
        return leg, polish(src_pc, tgt_pc, start, rc)  # a cloud still to prepare, or too few points: polish's answer
    return leg, outcome(res, np.asarray(start, np.float64), rc, corr, base if view else None)  # the whole run's
