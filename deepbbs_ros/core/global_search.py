"""The global search: registration from any start by several start yaws (no ROS).

DeepBBS++'s basin is a cone of about +-70 degrees of yaw around the start (its training augmentation is 45
degrees). ``registration.global_yaws`` starts ``360 / global_yaws`` degrees apart (4: 90 degree steps, inside
the cone with margin) cover the whole circle: each runs the deep passes from the start guess turned about the
source's z axis, is ranked by its fitness before the precision stage (:func:`deepbbs_ros.core.verdict.fitness`
at twice ``registration.verdict_dist``: the deep estimate is good to decimetres), and the
``registration.global_polish`` best get the precision stage and the verdict; the most probable result is kept. The
search stops early only at an answer that is sure (``registration.verdict_sure``, above the validity bar): in a nearly
symmetric place a flip can be valid, so a valid answer that is not sure is weighed against the next best start's,
the given start's GICP answer (then GICP coarse to fine from the given start, core/coarse_rescue.py's pyramid: a
start outside GICP's fine basin where every deep answer missed) and its own 180-degree twin (:func:`twin`), and the
most probable kept; an answer from another start is valid only with a fitness of ``registration.search_min_score``
(a flip that lays the ground on the ground fits little else). The ranking passes run on the first
``registration.global_rank_points`` of the sampled points (a prefix of the farthest-point order is a farthest-point
sample itself: the same coverage at a quarter of the network's cost at 256 of 512); the start kept gets its remaining
passes on all of them. When none is valid, the starts are ranked again on all the points and the best finished.
When still none passes, the best pose turned by 180 degrees (a road seen backwards) and starts
``registration.global_shift`` and twice that m around both (a right yaw slid along a road: pairs 10-15 m apart)
get the same treatment: a pair that does not overlap pays for all 21 starts. With ``registration.search_ambiguity``
the given start's valid answer that is not sure goes through the same weighing, and the answer kept is not valid
where another candidate, beyond 2 degrees / 0.5 m of it, is one the verdict would accept too
(core/search_ambiguity.py). ``DeepBBSRegistration.register`` runs the search when the answer from the given start
does not fit (``registration.global_search: auto``), so a good start (consecutive scans, odometry) pays nothing more.

Where the deep passes run: with a network process (a CPU, core/network_process.py) the other start yaws' first
passes run there right after the given start's, while the caller still builds the GICP clouds
(``registration.global_speculate``: "auto" once the search ran in one of the last 8 registrations), one start at
a time, stopped within a network stage when the given start's answer fits; it gets the first half of them, and
the caller runs the others once it knows the search is needed, while the worker is still at it. Starts still to
run (the 180-degree and shifted ones, or all of them without a speculation) go as one batch to the network process
and another in this process (:func:`network_starts`, ``DeepBBSNetwork.starts``: the same numbers as
single passes). The target's network state is computed once for every start (the target memo of
``DeepBBSNetwork``, core/network.py). The starts, their ranking and the batch sizes are core/search_starts.py's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from deepbbs_ros.core import coarse_rescue, search_ambiguity
from deepbbs_ros.core.network import Clock, matrix
from deepbbs_ros.core.search_starts import (  # noqa: F401  (re-exported)
    SHIFT_STARTS,
    SPECULATE_WINDOW,
    batch_sizes,
    full_gamma,
    rank_outputs,
    rank_size,
    shift_starts,
    speculative_starts,
    yaw_starts,
)

__all__ = ["yaw_starts", "shift_starts", "rank_outputs", "rank_size", "batch_sizes", "before_precision", "retry"]

def network_starts(reg: Any, st: Any, starts: list[np.ndarray], n_passes: int | None = None, *, away: bool = True,
                   points: int | None = None) -> list[Any]:
    """``n_passes`` deep passes (default: the configured number) from each of ``starts`` ((4, 4) metres
    T_target_source guesses) on the pair of the registration state ``st`` (``points``: on the first ones of both
    clouds only, the ranking prefix), split between the network process and this one (``NetworkRunner.starts``;
    ``away`` False: all here). -> NetworkOutput s in the order of the starts."""
    src_np, tgt_np, src, tgt = st.src_np, st.tgt_np, st.src, st.tgt
    if points is not None and points < max(len(src_np), len(tgt_np)):
        src_np, tgt_np, src, tgt = src_np[:points], tgt_np[:points], src[:, :points], tgt[:, :points]
    n = reg.network.n_deep if n_passes is None else n_passes
    return reg.runner.starts(src_np, tgt_np, src, tgt, starts, n, away=away)


# -- the stages of DeepBBSRegistration.register (core/registration.py) -----------------------------------------
def before_precision(reg: Any, st: Any, clock: Any, force: bool = False, full: bool = False) -> None:
    """The search before the precision stage (``register`` calls it in its torch inference context): when the
    deep answer's fitness (at twice ``verdict_dist``) is below ``verdict_threshold`` (``auto``), or always: one
    deep pass from each other start yaw on the ranking prefix (all the points with ``full``; those the network
    process ran speculatively are taken from it, the rest run as a batch per process; the target's network state
    computed once), the start with the best fitness finished with the remaining passes on all the points; it
    replaces the answer when it fits better (with ``full``, a second ranking after the answer failed: always)."""
    rc, scale = reg.config.registration, reg.model.scale
    if (rc.global_search == "off" or not st.yaw_search or rc.global_yaws < 2 or not reg.network.n_deep
            or not rc.deep):
        return
    rank_dist = 2.0 * rc.verdict_dist
    T_deep = matrix(st.R, st.t, scale)
    here = reg._score(st, T_deep, rank_dist)
    if rc.global_search == "auto" and here >= rc.verdict_threshold and not force:
        spec, st.spec = st.spec, None
        reg.runner.drop(spec)  # the network process's passes from the other starts are not needed
        return

    n_all = len(st.src_np)
    k = n_all if full else rank_size(rc, min(n_all, len(st.tgt_np)))  # the ranking passes' points: a prefix

    def posed(outs: list[Any]) -> list[tuple[Any, np.ndarray]]:
        return [(full_gamma(out, n_all), matrix(out.R, out.t, scale)) for out in outs]

    def passes(starts: list[np.ndarray], n: int, points: int | None = None) -> list[tuple[Any, np.ndarray]]:
        # one batch per process: the network process runs a share while this one runs the rest
        return posed(network_starts(reg, st, starts, n, points=points))

    starts = yaw_starts(st.T_start, rc.global_yaws)
    n_spec = st.spec_n if st.spec is not None else 0  # the first ones run in the network process meanwhile
    mine = posed(network_starts(reg, st, starts[n_spec:], 1, away=False, points=k)) if n_spec else []  # the rest here
    spec, st.spec = reg.runner.speculated(st.spec), None  # what it ran (all, some or none)
    outputs = posed(spec) + passes(starts[len(spec):n_spec or None], 1, k) + mine
    ranked = rank_outputs(outputs, lambda T: reg._score(st, T, rank_dist))
    st.starts = rc.global_yaws
    st.others = ranked
    if ranked and (ranked[0][0] > here or full):  # full: a second ranking, the answer already failed
        out, T = ranked[0][1], ranked[0][2]
        rest = reg.network.n_deep - 1 if k >= n_all else max(1, reg.network.n_deep - 1)  # on all the points
        if rest > 0:
            out, T = passes([T], rest)[0]
        st.replaced = (st.R, st.t, st.gamma)
        reg._apply_network(st, out)
        st.iters["deep"] += 1
        st.inlier_ratio = reg._inlier_ratio(st, st.R, st.t)
    clock.lap("global")


def retry(reg: Any, st: Any, clock: Any) -> Any:
    """The answer still fails the verdict after the precision stage, or came from another start and is not sure
    (:func:`sure`): the next best starts of the search (the given one included, ``global_polish`` in all) through the
    precision stage and the verdict, then (still not sure) the given start's GICP answer, GICP coarse to fine from the
    given start and the best one's twin; the most probable valid answer wins, unless another candidate makes it
    ambiguous (``registration.search_ambiguity``: then also on the given start's valid answer that is not sure). Runs
    the search first if it did not run (``auto`` and a fitting deep answer)."""
    rc = reg.config.registration
    if st.replaced is not None:
        _floor(st, rc)  # the answer came from another start: the search's fitness floor
    if (rc.global_search == "off" or not st.yaw_search or rc.global_yaws < 2 or not reg.network.n_deep or not rc.deep
            or st.skew.startswith("rejected")):  # the sweep's own motion bends any start's pose: no other start helps
        return st
    if st.valid and (sure(st, rc) or (st.replaced is None and not search_ambiguity.weighed(st, rc))):
        return st  # a sure answer, or the given start's valid answer (unless weighed)
    seen = [st]  # every candidate through the verdict

    def tensors(out: Any) -> tuple:
        return tuple(torch.as_tensor(x, dtype=torch.float32, device=reg.device) for x in (out.R, out.t, out.gamma))

    if st.others is None:  # the deep answer fitted, the precision stage's pose does not: rank the others now
        probe = dataclasses.replace(st, iters=dict(st.iters))
        with torch.inference_mode(), reg.network.torch_threads():
            before_precision(reg, probe, clock, force=True)
        ranked, replaced = probe.others or [], probe.replaced is not None
        others = [(probe.R, probe.t, probe.gamma)] if replaced else []
    else:
        ranked, replaced = st.others, st.replaced is not None
        others = [st.replaced] if replaced else []
    others += [tensors(out) for _, out, _ in ranked[1 if replaced else 0:]]
    st.starts = rc.global_yaws
    def from_tensors(cand: Any, start: tuple) -> None:
        cand.R, cand.t, cand.gamma = start

    best = _finish_best(reg, st, st, others[: max(0, rc.global_polish - 1)], from_tensors, seen)
    if not sure(best, rc):  # the given start itself, and the best answer's 180-degree twin, through the precision stage
        flip = twin(best.T, st.src_np)
        best = _finish_best(reg, st, best, [st.T_start], _from_pose(reg), seen)
        if (not sure(best, rc) and st.src_pc is not None and st.tgt_pc is not None and st.polish_check is None
                and rc.polish != "none"):
            # outside GICP's fine basin but near: the given start coarse to fine (the network's answers missed it); not
            # in a search over candidate places (a polish_check: most are wrong, each kept cheap), and not without a
            # precision stage (registration.polish "none": the network alone runs no GICP)
            best = _finish_best(reg, st, best, [coarse_rescue.pyramid(st.src_pc, st.tgt_pc, st.T_start, rc,
                                                                      reg.gicp_threads())], _from_pose(reg), seen)
        best = _finish_best(reg, st, best, [flip], _from_pose(reg), seen) if not sure(best, rc) else best
    n = min(len(st.src_np), len(st.tgt_np))
    if not best.valid and rank_size(rc, n) < n:  # ranked on a prefix: the yaw starts ranked again on all the points
        probe = dataclasses.replace(st, iters=dict(st.iters), spec=None, replaced=None)
        with torch.inference_mode(), reg.network.torch_threads():
            before_precision(reg, probe, clock, force=True, full=True)
        if probe.replaced is not None:
            best = _finish_best(reg, st, best, [(probe.R, probe.t, probe.gamma)], from_tensors, seen)
    if not best.valid and rc.global_shift > 0:  # right yaw, slid along a road: starts shifted around the best
        best = _shift_retry(reg, best, st, seen)
    clock.lap("global")
    return search_ambiguity.settle(best, seen, rc)


def _finish_best(reg: Any, st: Any, best: Any, starts: list, apply: Any, seen: list | None = None) -> Any:
    """Each deep answer of ``starts`` (in order) set on a copy of ``st`` by ``apply(cand, start)``, then the
    precision stage, the deskew stage and the verdict (each appended to ``seen``); the most probable so far is kept,
    and the first sure one (:func:`sure`) ends the loop."""
    for start in starts:
        cand = dataclasses.replace(st, iters=dict(st.iters), polish_reason="", deskew="")
        apply(cand, start)
        reg._polish(cand, Clock(reg.device))
        reg._deskew(cand, Clock(reg.device))
        reg._verdict(cand)
        _floor(cand, reg.config.registration)
        if seen is not None:
            seen.append(cand)
        if (cand.valid, cand.probability, cand.score) > (best.valid, best.probability, best.score):
            best = cand
        if sure(best, reg.config.registration):
            break
    return best


def twin(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The pose T (4, 4) turned by 180 degrees about the vertical through the centroid of ``points`` (N, 3) (source
    frame) moved by it: in a place symmetric about a vertical axis, a flip and the right pose are each other's
    twin about the part of the place both scans see."""
    pts = np.asarray(points, np.float64)
    c = pts.mean(axis=0) @ T[:3, :3].T + T[:3, 3] if len(pts) else T[:3, 3]
    S = np.diag([-1.0, -1.0, 1.0, 1.0])
    S[:2, 3] = 2.0 * c[:2]  # p -> 2c - p horizontally: a half turn about c
    return S @ np.asarray(T, np.float64)


def _from_pose(reg: Any) -> Callable[[Any, np.ndarray], None]:
    """``apply`` for :func:`_finish_best` from a pose (4, 4) metres: the precision stage starts there."""
    def apply(cand: Any, T: np.ndarray) -> None:
        cand.R = torch.as_tensor(T[:3, :3], dtype=torch.float32, device=reg.device)
        cand.t = torch.as_tensor(T[:3, 3] * reg.model.scale, dtype=torch.float32, device=reg.device)
    return apply


def _floor(st: Any, rc: Any) -> None:
    """A search answer (from another start than the given one) is valid only when its fitness also reaches
    ``registration.search_min_score``: a flip that lays the ground on the ground but nothing else is not."""
    if st.valid and st.score < rc.search_min_score:
        st.valid = False


def sure(st: Any, rc: Any) -> bool:
    """A search answer ends the search: valid, and its probability reaches ``registration.verdict_sure`` (a
    symmetric place's flip can be valid; the search then tries its remaining starts and keeps the most probable)."""
    if st.src_pc is None or st.tgt_pc is None:  # no precision stage: an uncalibrated probability, the score decides
        return bool(st.valid)
    return bool(st.valid and st.probability >= rc.verdict_sure)


def _shift_retry(reg: Any, best: Any, st: Any, seen: list | None = None) -> Any:
    """The best pose so far turned by 180 degrees (a road seen backwards), and starts ``registration.global_shift``
    and twice that m from both (four horizontal directions, in the target frame): the full deep passes from
    each (17 starts), the best fitting ones through the precision stage."""
    rc, scale = reg.config.registration, reg.model.scale
    T_best = best.T.copy()
    outs = []
    flip = T_best @ np.diag([-1.0, -1.0, 1.0, 1.0])  # the best pose turned by 180 deg (a road seen backwards)
    starts = [flip] + shift_starts(T_best, rc.global_shift) + shift_starts(flip, rc.global_shift)
    with torch.inference_mode(), reg.network.torch_threads():
        for out in network_starts(reg, st, starts):  # a batch in the network process, another here
            T = matrix(out.R, out.t, scale)
            outs.append((reg._score(st, T, 2.0 * rc.verdict_dist), out))
    outs.sort(key=lambda o: -o[0])
    best = _finish_best(reg, st, best, [out for _, out in outs[: rc.global_polish]], reg._apply_network, seen)
    best.starts = rc.global_yaws + len(outs)
    return best
