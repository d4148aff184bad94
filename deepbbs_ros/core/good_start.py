"""``register(..., good_start=True)``: GICP from a start the caller vouches for, before the full pipeline (no ROS).

The caller vouches for ``T_init`` (consecutive scans, a fixed mounting, a map from the last pose)::

    gicp first  precision-stage clouds only (the sampling waits: PreprocessResult.sample), GICP from T_init with
                GICP's own settings (core/start_gicp.py; registration.polish_*: its iterations, no limit on how far
                it moves), judged by the verdict on a spread subset of the source's voxels (registration.
                good_start_probability) wherever it ended; converged beyond registration.good_start_max_trans /
                _rot_deg or only after good_start_max_iters, the answer says so ("beyond the good start's limits"); with
                registration.good_start_second_minimum a loose pose is also checked for a second minimum as good
                along its weakest direction (core/second_minimum.py), and one that has it is not taken
    finish      converged, not accepted: GICP's pose finished on the scans' scene-sized grids (registration.
                polish_voxel_angle, core/polish.py finish: a narrow place GICP's grid blends), judged again, on
                both grids where GICP's does not hold it (registration.good_start_finish_grid, core/finish_verdict.py)
    degenerate  not accepted, and GICP's grid takes the finished pose but for the hold of its weakest direction
                that the scene's grids give it (core/finish_verdict.py degenerate, registration.good_start_degenerate):
                that pose, not valid, "not valid: degenerate along ..." (no other start makes the verdict take one:
                the coarse try took none of them, scripts/benchmarks/good_start_degenerate.py seeds 39-43)
    coarse      still not accepted: GICP coarse to fine from T_init (core/coarse_rescue.py), taken when the verdict
                is sure (registration.verdict_sure) within the coarse try's reach
    else        the full pipeline on the same clouds (:class:`Attempt` hands them over)

Why the first GICP is judged by the verdict alone, however far it moved: the verdict is a probability that the pose
is right read from the pose's own fit, and it separates GICP's answers by itself. From neighbouring scans and from
starts turned 20-60 degrees and shifted 1.5-4 m off the truth, on every family of docs/sensors.md (940 GICP answers,
547 of them wrong), no wrong answer scored above 0.33; the verdict takes 351 of the 373 right ones, where a cap on the
iterations (20) and on the move (10 degrees, 3 m; twice that when sure) took 147 (a handheld Livox turns tens of
degrees between keyframes): ``scripts/benchmarks/good_start_reach.py --quick`` with the real sets.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from deepbbs_ros.core import coarse_rescue, finish_verdict, second_minimum, sweep_skew, verdict
from deepbbs_ros.core.good_start_answer import answer
from deepbbs_ros.core.points import as_transform, as_xyz
from deepbbs_ros.core.polish import PolishCloud, finish
from deepbbs_ros.core.polish_view import PolishView
from deepbbs_ros.core.preprocess import PreprocessResult
from deepbbs_ros.core.result import RegistrationResult
from deepbbs_ros.core.start_gicp import from_start, good_start_gicp, orthonormal
from deepbbs_ros.core.verdict import good_start_points
from deepbbs_ros.core.visibility import FEATURES

__all__ = ["Attempt", "attempt", "from_start", "good_start_gicp", "good_start_points"]

_PINNED = FEATURES.index("pinned")


@dataclass
class Attempt:
    """The good start's attempt: the clouds it built (reused by the full pipeline), why it was not accepted
    ("accepted" when it was) and its result (None when the full pipeline must answer)."""

    source: Any
    target: Any
    reason: str = ""
    result: RegistrationResult | None = None


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
    pol = from_start(spc, tpc, T0, rc)  # GICP's own budget, wherever it goes: the verdict judges where it ended
    prob, sure = _probability(pol, "", pts, tpc, rc, spc), max(rc.good_start_probability, rc.verdict_sure)
    if verdict.is_valid(prob, rc.good_start_probability) and not _slides(pol, prob, pts, spc, tpc, rc):
        beyond = _beyond(pol, rc)
        accepted = f"accepted, beyond the good start's limits (GICP from the start: {beyond})" if beyond else "accepted"
    elif (fine := _finished(pol, spc, tpc, pts, rc))[1] is not None:  # GICP's minimum on its grid off the place's
        pol, prob = fine
        accepted = f"accepted on the scene's grid (GICP from the start: verdict < {rc.good_start_probability})"
    else:  # not converged, or a pose the verdict does not take (outside GICP's basin, or a wrong one)
        first = "GICP from the start: " + (
            pol.reason if not pol.applied else f"verdict {prob:.2f} < registration.good_start_probability "
            f"{rc.good_start_probability}" if not verdict.is_valid(prob, rc.good_start_probability) else
            "a second minimum as good along its weakest direction (registration.good_start_second_minimum)")
        stuck = "" if fine[0] is None or not rc.good_start_degenerate else finish_verdict.degenerate(
            pts, fine[0].T_target_source, spc, tpc, rc, rc.good_start_probability)
        if stuck:  # before the coarse try (see the module)
            clock.lap("good_start")
            reg._searched.append(False)  # the finished pose, not valid: no search can pin it either
            res = answer(src, tgt, fine[0], _probability(fine[0], "", pts, tpc, rc), pts, tpc, rc, stuck, clock)
            res.valid = False
            return Attempt(src, tgt, stuck, res)
        pol, why = coarse_rescue.coarse_then_fine(spc, tpc, T0, rc, reg.gicp_threads())  # coarse to fine, when sure
        prob = _probability(pol, why, pts, tpc, rc, spc)
        if not verdict.is_valid(prob, sure):
            clock.lap("good_start")
            then = why or f"verdict {prob:.2f} < registration.verdict_sure {sure}"
            return Attempt(src, tgt, reason=f"{first}; coarse to fine: {then}")
        accepted = f"accepted after coarse to fine ({first})"
    reg._searched.append(False)
    res = answer(src, tgt, pol, prob, pts, tpc, rc, accepted, clock)
    if rc.skew_check and res.deskew != "deskewed":  # per-point times: does a sweep's own motion bend the pose?
        bends, res.skew = sweep_skew.judge(src, tgt, res.T_target_source, rc, reg.config.preprocess.min_range)
        res.valid = not bends  # bent: no other start unbends it (not valid, not the full pipeline)
    return Attempt(src, tgt, accepted, res)


def _finished(pol: Any, spc: PolishCloud, tpc: PolishCloud, pts: np.ndarray, rc: Any) -> tuple[Any, float | None]:
    """GICP from the start converged but not taken: finished on the scans' scene-sized grids
    (``registration.polish_voxel_angle``, :func:`core.polish.finish`; a narrow place's walls, floor and ceiling that
    GICP's grid blends) and judged again: on the same points and target (GICP's grid, ``good_start_finish_grid``
    "gicp"), or on the grids it was finished on with the verdict's distance scaled with them
    (:func:`core.verdict.on_scene_grid`; "scene"), where taken then checked there for a second minimum as good along
    its weakest direction (core/second_minimum.py, ``registration.second_minimum``), or on GICP's grid, then where
    that grid does not hold it, on both (core/finish_verdict.py; "both") -> (the finished result, None when there is
    none; its probability when the verdict takes it, else None: not taken, or ambiguous)."""
    fine = finish(spc, tpc, pol.T_target_source, rc) if pol.applied else None
    if fine is None or not fine.applied:
        return None, None
    fine = dataclasses.replace(orthonormal(fine), iterations=pol.iterations + fine.iterations, converged=pol.converged)
    if rc.good_start_finish_grid != "scene":
        prob = _probability(fine, "", pts, tpc, rc)
        if verdict.is_valid(prob, rc.good_start_probability) and not _slides(fine, prob, pts, spc, tpc, rc):
            return fine, prob
        if rc.good_start_finish_grid == "gicp":
            return fine, None
        prob, why = finish_verdict.judge(pts, fine.T_target_source, spc, tpc, rc, rc.good_start_probability)
        return fine, None if why else prob  # "both": GICP's grid, pinned on the scene's, and the scene's grids
    pts, target, dist = verdict.on_scene_grid(spc, tpc, rc)  # finished: both scans have a finer grid
    prob = _probability(fine, "", pts, target, rc, dist=dist)
    if not verdict.is_valid(prob, rc.good_start_probability):
        return fine, None
    scene = dataclasses.replace(rc, verdict_dist=dist)
    if rc.second_minimum and second_minimum.check(pts, fine.T_target_source, spc.finer(), target, scene).ambiguous:
        return fine, None
    return fine, prob


def _slides(pol: Any, prob: float, pts: np.ndarray, spc: PolishCloud, tpc: PolishCloud, rc: Any) -> bool:
    """Whether the pose of ``pol`` taken on GICP's grid (its probability ``prob``) has a second minimum as good along
    its weakest direction (core/second_minimum.py), where ``registration.good_start_second_minimum`` asks (and
    ``second_minimum``): checked where the fit leaves the pose freer than a slide's distance (anchoring.STEPS[-1], 5
    tolerances: 1.5 m / 5 degrees), or than a wrong pose's (STEPS[0], 2: 0.6 m / 2 degrees) when the verdict is not
    sure (``registration.verdict_sure``); a pose held closer costs nothing more: the verdict's ``pinned`` (the same
    plane matches, ``s^2 / (s^2 + tol^2)``) gives the check's uncertainty ``tol / s`` already."""
    loose = second_minimum.STEPS[0] if prob < rc.verdict_sure else second_minimum.STEPS[-1]
    if not (rc.good_start_second_minimum and rc.second_minimum):
        return False
    if not isinstance(tpc, PolishView):  # a scan's cloud: the features are kept on it (a map crop's: not checked)
        pin = float(verdict.features(pts, pol.T_target_source, tpc, rc.verdict_dist, "good_start")[_PINNED])
        if 0.0 < pin <= 1.0 and np.sqrt((1.0 - pin) / pin) < max(loose, second_minimum.WRONG) * (1.0 - 1e-6):
            return False  # held within ``loose``: the check stops there (its own eigenvalue: the margin is rounding's)
    return bool(second_minimum.check(pts, pol.T_target_source, spc, tpc, rc, loose=loose).ambiguous)


def _beyond(pol: Any, rc: Any) -> str:
    """How GICP from the start went beyond the good start's limits (``registration.good_start_max_*``: how far a
    vouched start may plausibly be off, and the iterations it should need): "" when it did not."""
    if pol.delta_trans_m > rc.good_start_max_trans:
        return f"moved {pol.delta_trans_m:.2f} m > registration.good_start_max_trans {rc.good_start_max_trans} m"
    if pol.delta_rot_deg > rc.good_start_max_rot_deg:
        return (f"turned {pol.delta_rot_deg:.2f} deg > registration.good_start_max_rot_deg "
                f"{rc.good_start_max_rot_deg} deg")
    if pol.iterations > rc.good_start_max_iters:
        return (f"converged in {pol.iterations} iterations > registration.good_start_max_iters "
                f"{rc.good_start_max_iters}")
    return ""


def _probability(pol: Any, why: str, pts: np.ndarray, tpc: PolishCloud, rc: Any, spc: Any = None,
                 dist: float | None = None) -> float:
    """The good-start verdict's probability of the GICP result ``pol``; 0 when ``why`` says it is not taken (or GICP
    did not converge within its limits). ``spc``: the source's cloud (``registration.verdict_within``); ``dist``: the
    verdict's distance (``registration.verdict_dist`` when None)."""
    if why or not pol.applied:
        return 0.0
    d = rc.verdict_dist if dist is None else dist
    prob = verdict.probability(pts, pol.T_target_source, tpc, d, "good_start")
    return verdict.times_within(prob, spc, tpc, pol.T_target_source, rc, rc.good_start_probability, "good_start")
