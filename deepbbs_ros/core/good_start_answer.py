"""The good start's answer (core/good_start.py; no ROS): GICP's pose as a :class:`RegistrationResult`, scored with one
nearest-neighbour search for both shares (the verdict's and the inliers'), again on both scans deskewed when they
are."""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core import pair_deskew, visibility
from deepbbs_ros.core.polish import PolishCloud
from deepbbs_ros.core.preprocess import PreprocessResult
from deepbbs_ros.core.result import RegistrationResult
from deepbbs_ros.core.verdict import good_start_points

__all__ = ["answer", "shares"]


def shares(pts: np.ndarray, tpc: PolishCloud, T: np.ndarray, dists: tuple[float, ...]) -> list[float]:
    """:func:`core.verdict.fitness` of ``pts`` under ``T`` at each of ``dists`` m, from one nearest-neighbour search
    (the verdict's on the same pose: kept on the cloud)."""
    if len(pts) == 0:
        return [0.0 for _ in dists]
    T = np.asarray(T, np.float64)
    moved = np.asarray(pts, np.float64) @ T[:3, :3].T + T[:3, 3]  # as the verdict moved them: its search's answer
    _, sq = visibility._nearest(tpc, moved, 1)
    sq = np.asarray(sq, np.float64)
    return [float(np.mean(sq <= d * d)) for d in dists]


def answer(src: PreprocessResult, tgt: PreprocessResult, pol: Any, prob: float, pts: np.ndarray, tpc: PolishCloud,
           rc: Any, text: str, clock: Any) -> RegistrationResult:
    """The good start's answer: GICP's pose (again on both scans deskewed, when they are), its verdict."""
    T = pol.T_target_source
    score, inliers = shares(pts, tpc, T, (rc.verdict_dist, rc.inlier_dist))
    clock.lap("good_start")
    T, deskew, more = pair_deskew.again(src, tgt, T, rc)  # both scans deskewed (node.pair_deskew): again on them
    if more:
        clock.lap("deskew")
    timings = dict(clock.ms)
    timings["total"] = sum(timings.values())
    # the target's points: kept on its cloud (drawn when it was a stream's source)
    return RegistrationResult(
        T_target_source=T, converged=bool(pol.converged),
        iterations={"deep": 0, "refine": 0, "dense": 0, "polish": int(pol.iterations) + more},
        gamma=np.ones(len(pts), np.float32), inlier_ratio=float(inliers), temperature=0.0, timings_ms=timings,
        source=pts.astype(np.float32), target=good_start_points(tpc, rc).astype(np.float32), polish="ok",
        deskew=deskew, valid=True, score=float(score), starts=1, path="gicp", good_start=text,
        probability=float(prob))
