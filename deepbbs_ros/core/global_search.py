"""The global search: registration from any start by several start yaws (no ROS).

DeepBBS++'s basin is a cone of about +-70 degrees of yaw around the start (its training augmentation is 45
degrees). ``registration.global_yaws`` starts ``360 / global_yaws`` degrees apart (4: 90 degree steps, inside
the cone with margin) cover the whole circle: each runs the deep passes from the start guess turned about the
source's z axis, is ranked by its fitness before the precision stage (:func:`deepbbs_ros.core.verdict.fitness`
at twice ``registration.verdict_dist``: the deep estimate is good to decimetres), and the
``registration.global_polish`` best get the precision stage and the verdict; the result with the best verdict
score is kept. ``DeepBBSRegistration.register`` runs the search when the answer from the given start fails the
verdict (``registration.global_search: auto``), so a good start (consecutive scans, odometry) pays nothing more.
The target's network state is computed once for every start (the target memo of ``DeepBBSRegistration``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["yaw_starts", "shift_starts", "rank_starts"]


def yaw_starts(T_start: np.ndarray, n: int) -> list[np.ndarray]:
    """The ``n - 1`` other starts: ``T_start @ Rz(k * 360 / n)``, k = 1 .. n - 1 ((4, 4) float64 each)."""
    out = []
    for k in range(1, n):
        a = 2.0 * np.pi * k / n
        Rz = np.eye(4)
        Rz[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        out.append(np.asarray(T_start, dtype=np.float64) @ Rz)
    return out


def shift_starts(T: np.ndarray, shift: float) -> list[np.ndarray]:
    """Eight starts ``shift`` and ``2 * shift`` m from the pose T (4, 4) along +x, -x, +y, -y of the target frame
    (a pose of the right yaw slid along a road by more than the deep passes' reach)."""
    out = []
    for r in (shift, 2.0 * shift):
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            S = np.asarray(T, dtype=np.float64).copy()
            S[:2, 3] += (r * dx, r * dy)
            out.append(S)
    return out


def rank_starts(starts: list[np.ndarray], passes: Callable[[np.ndarray], Any],
                score: Callable[[np.ndarray], float]) -> list[tuple[float, Any, np.ndarray]]:
    """Run ``passes(T_start) -> (output, T_estimate)`` from every start and rank them by ``score(T_estimate)``:
    -> [(score, output, T_estimate)] best first."""
    ranked = []
    for T0 in starts:
        out, T = passes(T0)
        ranked.append((float(score(T)), out, T))
    ranked.sort(key=lambda r: -r[0])
    return ranked
