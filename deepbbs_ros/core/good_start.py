"""``register(..., good_start=True)``: GICP from a start the caller vouches for, before the full pipeline (no ROS).

The caller vouches for ``T_init`` (consecutive scans, a fixed mounting, a map from the last pose)::

    gicp first  precision-stage clouds only (the sampling waits: PreprocessResult.sample), GICP from T_init with
                registration.good_start_max_iters, judged by the verdict on a spread subset of the source's voxels
                (registration.good_start_probability)
    reach       converged beyond registration.good_start_max_trans / _rot_deg but within the coarse try's reach
                (core/coarse_rescue.py REACH times them), or only after good_start_max_iters, within as many again
                (GICP goes on from where it stopped): taken when the verdict is sure (registration.verdict_sure), as
                the coarse try's answer would be (a car at 2 Hz moving 3-4.5 m, scans a few apart)
    coarse      not accepted: GICP coarse to fine from T_init (core/coarse_rescue.py), taken when the verdict is
                sure (registration.verdict_sure)
    else        the full pipeline on the same clouds (:class:`Attempt` hands them over)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from deepbbs_ros.core import coarse_rescue, pair_deskew, verdict, visibility
from deepbbs_ros.core.network import orthonormalize
from deepbbs_ros.core.points import as_transform, as_xyz
from deepbbs_ros.core.polish import PolishCloud, polish
from deepbbs_ros.core.preprocess import PreprocessResult
from deepbbs_ros.core.result import RegistrationResult

__all__ = ["Attempt", "attempt", "good_start_gicp", "good_start_points"]


@dataclass
class Attempt:
    """The good start's attempt: the clouds it built (reused by the full pipeline), why it was not accepted
    ("accepted" when it was) and its result (None when the full pipeline must answer)."""

    source: Any
    target: Any
    reason: str = ""
    result: RegistrationResult | None = None


def good_start_gicp(src_pc: PolishCloud, tgt_pc: PolishCloud, T_init: np.ndarray, rc: Any, reach: float = 1.0,
                    more: int = 0) -> Any:
    """GICP from a vouched start ``T_init`` (4, 4) within the good start's limits (``registration.good_start_max_*``,
    times ``reach``, in place of ``polish_max_*``) -> the :func:`core.polish.polish` result, its rotation
    orthonormalised when applied (``register(..., good_start=True)`` and the localization's tracking). ``more``: not
    converged within ``good_start_max_iters``, GICP goes on from where it stopped for up to this many iterations
    (then the result's ``check_score`` is finite: :func:`core.polish.polish`'s check)."""
    cfg = dataclasses.replace(rc, polish_max_iters=rc.good_start_max_iters + more,
                              polish_max_trans=reach * rc.good_start_max_trans,
                              polish_max_rot_deg=reach * rc.good_start_max_rot_deg)
    pol = polish(src_pc, tgt_pc, T_init, cfg, check=(rc.good_start_max_iters, 0.0) if more > 0 else None)
    if pol.applied:
        pol.T_target_source[:3, :3] = orthonormalize(pol.T_target_source[:3, :3])
    return pol


def good_start_points(pc: PolishCloud, rc: Any) -> np.ndarray:
    """The points the good start's verdict scores: a spread, order-independent subset of the cloud's GICP voxels
    (``registration.good_start_points``; :func:`core.verdict.spread_subset`)."""
    return verdict.spread_subset(pc.points(), rc.good_start_points, rc.polish_voxel or 0.5)


def attempt(reg: Any, source: Any, target: Any, T_init: np.ndarray, preprocessed: bool, clock: Any) -> Attempt:
    """The good start of ``reg`` (a ``DeepBBSRegistration``) on ``source`` / ``target`` (raw scans or
    PreprocessResults) from ``T_init`` -> :class:`Attempt`: its result when accepted, else why not and the clouds
    built (PreprocessResults) for the full pipeline."""
    rc = reg.config.registration
    T0 = as_transform(T_init)
    if preprocessed and not (isinstance(source, PreprocessResult) and isinstance(target, PreprocessResult)):
        return Attempt(source, target, reason="preprocessed arrays: no precision-stage clouds")
    src, tgt = (p if isinstance(p, PreprocessResult) else reg.preprocess(as_xyz(p, name), lazy=True)
                for p, name in ((source, "source"), (target, "target")))
    if rc.polish == "none" or src.polish_cloud is None or tgt.polish_cloud is None:
        return Attempt(src, tgt, reason="no precision-stage clouds (registration.polish none)")
    spc, tpc = src.polish_cloud.complete(reg.gicp_threads()), tgt.polish_cloud.complete(reg.gicp_threads())
    clock.lap("preprocess")
    pts = good_start_points(spc, rc)
    # from the vouched start, iterations capped (a fallback stays cheap); converged beyond the good start's limits, or
    # only in up to as many iterations again, but within the coarse try's reach: the coarse try's bar (sure) takes it
    # without the pyramid
    pol = good_start_gicp(spc, tpc, T0, rc, reach=coarse_rescue.REACH, more=rc.good_start_max_iters)
    why = _limits(pol, rc)
    prob, sure = _probability(pol, "", pts, tpc, rc), max(rc.good_start_probability, rc.verdict_sure)
    accepted = "accepted"
    if why and pol.applied and verdict.is_valid(prob, sure):
        accepted = f"accepted, sure, within the coarse try's reach (GICP from the start: {why})"
    elif why or not verdict.is_valid(prob, rc.good_start_probability):  # outside GICP's fine basin (or a wrong one)
        first = f"GICP from the start: {why}" if why else \
            f"verdict {prob:.2f} < registration.good_start_probability {rc.good_start_probability}"
        pol, why = coarse_rescue.coarse_then_fine(spc, tpc, T0, rc, reg.gicp_threads())  # coarse to fine, when sure
        prob, bar = _probability(pol, why, pts, tpc, rc), sure
        if not verdict.is_valid(prob, bar):
            clock.lap("good_start")
            then = why or f"verdict {prob:.2f} < registration.verdict_sure {bar}"
            return Attempt(src, tgt, reason=f"{first}; coarse to fine: {then}")
        accepted = f"accepted after coarse to fine ({first})"
    reg._searched.append(False)
    return Attempt(src, tgt, accepted, _result(src, tgt, pol, prob, pts, tpc, rc, accepted, clock))


def _limits(pol: Any, rc: Any) -> str:
    """Why GICP from the start (run within the coarse try's reach, with a second leg) is not the good start's answer as
    it is: "" when it converged within ``registration.good_start_max_*``, else the text :func:`core.polish.polish`
    gives with them, or that it converged only in the second leg."""
    if pol.applied and np.isfinite(pol.check_score):  # the first leg did not converge, the second did
        return (f"not converged in registration.good_start_max_iters {rc.good_start_max_iters} iterations "
                f"(converged going on, {pol.iterations} in all)")
    if pol.applied or pol.reason.startswith(("moved", "turned")):
        if pol.delta_trans_m > rc.good_start_max_trans:
            return f"moved {pol.delta_trans_m:.2f} m > registration.good_start_max_trans {rc.good_start_max_trans} m"
        if pol.delta_rot_deg > rc.good_start_max_rot_deg:
            return (f"turned {pol.delta_rot_deg:.2f} deg > registration.good_start_max_rot_deg "
                    f"{rc.good_start_max_rot_deg} deg")
        return ""
    return pol.reason.replace("polish_max_", "registration.good_start_max_")


def _probability(pol: Any, why: str, pts: np.ndarray, tpc: PolishCloud, rc: Any) -> float:
    """The good-start verdict's probability of the GICP result ``pol``; 0 when ``why`` says it is not taken (or GICP
    did not converge within its limits)."""
    if why or not pol.applied:
        return 0.0
    return verdict.probability(pts, pol.T_target_source, tpc, rc.verdict_dist, "good_start")


def _shares(pts: np.ndarray, tpc: PolishCloud, T: np.ndarray, dists: tuple[float, ...]) -> list[float]:
    """:func:`core.verdict.fitness` of ``pts`` under ``T`` at each of ``dists`` m, from one nearest-neighbour search
    (the verdict's on the same pose: kept on the cloud)."""
    if len(pts) == 0:
        return [0.0 for _ in dists]
    T = np.asarray(T, np.float64)
    moved = np.asarray(pts, np.float64) @ T[:3, :3].T + T[:3, 3]  # as the verdict moved them: its search's answer
    _, sq = visibility._nearest(tpc, moved, 1)
    sq = np.asarray(sq, np.float64)
    return [float(np.mean(sq <= d * d)) for d in dists]


def _target_points(tpc: PolishCloud, rc: Any) -> np.ndarray:
    """:func:`good_start_points` of the target, from the voxels its verdict kept (core/visibility.py): no copy of the
    cloud's points again."""
    return verdict.spread_subset(visibility.target_points(tpc, rc.verdict_dist), rc.good_start_points,
                                 rc.polish_voxel or 0.5)


def _result(src: PreprocessResult, tgt: PreprocessResult, pol: Any, prob: float, pts: np.ndarray, tpc: PolishCloud,
            rc: Any, text: str, clock: Any) -> RegistrationResult:
    """The good start's answer: GICP's pose (again on both scans deskewed, when they are), its verdict."""
    T = pol.T_target_source
    score, inliers = _shares(pts, tpc, T, (rc.verdict_dist, rc.inlier_dist))
    clock.lap("good_start")
    T, deskew, more = pair_deskew.again(src, tgt, T, rc)  # both scans deskewed (node.pair_deskew): again on them
    if more:
        clock.lap("deskew")
    timings = dict(clock.ms)
    timings["total"] = sum(timings.values())
    return RegistrationResult(
        T_target_source=T, converged=bool(pol.converged),
        iterations={"deep": 0, "refine": 0, "dense": 0, "polish": int(pol.iterations) + more},
        gamma=np.ones(len(pts), np.float32), inlier_ratio=float(inliers), temperature=0.0, timings_ms=timings,
        source=pts.astype(np.float32), target=_target_points(tpc, rc).astype(np.float32), polish="ok",
        deskew=deskew, valid=True, score=float(score), starts=1, path="gicp", good_start=text,
        probability=float(prob))
