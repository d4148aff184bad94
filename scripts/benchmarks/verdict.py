#!/usr/bin/env python3
"""The calibrated verdict per sensor family: reliability, wrong poses accepted, right ones rejected.

Figures (``verdict.json`` under ``--out``), for the pair verdict (the sampled points: ``RegistrationResult.valid``)
and the good-start verdict (a spread subset of the GICP voxels):

* ``sim``: simulated pairs of every sensor, mount and place (``scripts/calibrate_verdict.py``'s rigs and poses with
  another seed than the fit's: GICP answers from near and far starts, the truth moved beyond 2 deg / 0.5 m, another
  place), per family (``dense``: 64-128 beams, ``sparse``: 16-32 beams, ``solid``: Livox Avia / Mid-360), and with
  ``--sim-low-pairs`` the low-overlap pairs (``low_overlap``: the target can judge 10-40 % of the source) and with
  ``--sim-turned-pairs`` the turned pairs (``turned``: a solid-state sensor turned and moved between its scans) apart;
  with ``--sim-slid`` also the truth slid 2.5-6 tolerances along its least pinned direction (``slid``: every pose
  wrong, one that a scene's free direction hides), apart; ``<verdict>_answers/<family>``: the same counts on the
  answers a registration gives alone (:data:`ANSWERS`: GICP's, the pipeline's), the poses its verdicts judge, without
  the truth moved by hand (beyond 2 deg / 0.5 m, or within 0.5 deg / 0.1 m on the low-overlap pairs);
* ``real``: the real sets given (KITTI-style folders with ground truth: the pair protocol, ``--stride`` /
  ``--max-dist`` per set; a reference pair folder with ``relative.txt``: ``--trials`` starts perturbed by up to 45
  deg / 5 m). The pair verdict judges the whole pipeline's answer (``register`` from identity, or the perturbed
  start); the good start's judges GICP answers from the truth moved a little and far (as in the simulation).

With ``registration.skew_check`` (on by default) a simulated pose whose raw Livox-like sweeps' own motion says it
cannot be right is counted as rejected by both verdicts (core/sweep_skew.py; the real sets carry no per-point times:
nothing runs); ``<verdict>_without_skew`` (``_with_skew`` when off) judges the same poses the other way, ``skew_cost``
gives the check's time per pose where it runs and its ratio to GICP from the truth on the same pair (median).
The verdicts that ``registration.verdict_within`` names ("pair", "all"; "off" by default) multiply the probability by
P(within 1 deg / 0.3 m | the pose's covariance) (core/within.py); ``<verdict>_without_within`` /
``<verdict>_with_within`` judge the same poses the other way (the real pair verdict: the pipeline's answers as
registered, the second-minimum check as it ran); ``cost/<set>``: the verdict's CPU per pose (one thread) without and
with the factor, on the pipeline's answers. Both verdicts judge a spread subset of the source's GICP voxels with
the same coefficients; the old ones differed (the
pair verdict: the fitness of the sampled points). Both count a pose the registration's second-minimum check turns away
(core/second_minimum.py) as rejected; the pair verdict runs that check, the good start on its loose poses
(``registration.good_start_second_minimum``). ``good_start_checks``
gives the good start's counts on the same poses with the check: ``none`` (never), ``slides`` (only on a
pose that can slide: :func:`slides`), ``loose`` (looser than 5 tolerances, or 2 when not sure:
``registration.good_start_second_minimum``) and ``all`` (on every pose it takes). Per set and verdict: the poses, right
(1 deg / 0.3 m) and wrong; wrong accepted and right rejected by the fixed fitness thresholds (0.35 sampled, 0.65 voxels)
and by the probability (``registration.verdict_probability``, ``good_start_probability``); and the reliability curve:
per predicted-probability bin (0-0.1, ..., 0.9-1) the poses and the share right. A wrong pose here is anything beyond 1
deg / 0.3 m; ``wrong_accepted_near_gicp_truth`` counts the wrong poses accepted that are within 1 deg / 0.3 m of GICP
started at the truth (on real sets the recorded truth's resolution, on simulated ones the pattern's: the scans' own
optimum is there, and the precision stage cannot land closer), ``wrong_accepted_max_err`` their largest errors (deg, m).
``classes`` splits the poses in three, as the figures are counted against the goal: right (within 1 deg / 0.3 m), wrong
(beyond 2 deg or 0.5 m) and in between (neither: shown apart, not counted as a success nor as a wrong pose accepted),
each with its accepted / rejected count; the ``wrong`` and ``wrong_accepted`` above it keep the older count (anything
not right). ``roughness/<set>``: how rough the targets' own surfaces are (core/target_surface.py's ``roughness``: the
distance 90 % of a target's points keep from their neighbour's tangent plane, and its ``self_planarity``; medians over
the set's targets), to compare the simulation with real scans. ::

    python scripts/benchmarks/verdict.py --real PATH/nuscenes_hdl32:1:5 PATH/livox_avia_loop:4:2 \\
        PATH/kitti/00:1:5 PATH/kitti/02:1:5 --pair PATH/hdl32_pair --out results/benchmarks
    python scripts/benchmarks/verdict.py --sim-pairs 2 --out results/v      # simulation only, quick
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import _common  # noqa: E402
import numpy as np  # noqa: E402

from deepbbs_ros.core.visibility import FEATURES  # noqa: E402

OLD = {"pair": 0.35, "good_start": 0.65}  # the fixed fitness thresholds the probability replaced
#: the simulated poses that are answers a registration gives (calibrate_verdict.py's kinds): GICP's from starts near
#: and far, the whole pipeline's, GICP's against another place. The others ("moved": the truth moved beyond
#: 2 deg / 0.5 m, "truth": within 0.5 deg / 0.1 m, "slid") are placed by hand: no run of the registration gives them
ANSWERS = ("near", "far", "pipeline", "other")
FAMILY = {"hdl64": "dense", "ouster64": "dense", "os0_64": "dense", "os0_128": "dense", "os1_64": "dense",
          "os1_128": "dense", "avia": "solid", "mid360": "solid"}  # every other simulated sensor: sparse


def summary(y: np.ndarray, score: np.ndarray, prob: np.ndarray, old: float, bar: float,
            near_ref: np.ndarray | None = None, err: np.ndarray | None = None, veto: np.ndarray | None = None) -> dict:
    """Counts and the reliability curve of one set of poses (labels y, fitness score, probability prob; ``near_ref``:
    whether each is within 1 deg / 0.3 m of GICP started at the truth, the truth's resolution on real scans;
    ``veto``: poses turned away whatever their probability, the pair verdict's second minimum: counted as rejected,
    and apart as ``vetoed``; the reliability curve reads the probability alone)."""
    y = np.asarray(y, bool)
    veto = np.zeros(len(y), bool) if veto is None else np.asarray(veto, bool)
    bins = []
    for lo in np.arange(0.0, 1.0, 0.1):
        m = (prob >= lo) & ((prob < lo + 0.1) | (lo >= 0.9))
        if m.any():
            bins.append({"p": f"{lo:.1f}-{lo + 0.1:.1f}", "n": int(m.sum()), "right": round(float(y[m].mean()), 3)})
    out = {"poses": len(y), "right": int(y.sum()), "wrong": int((~y).sum()),
            "old_wrong_accepted": int(np.sum(~y & (score >= old))),
            "old_right_rejected": int(np.sum(y & (score < old))),
            "wrong_accepted": int(np.sum(~y & (prob >= bar) & ~veto)),
            "right_rejected": int(np.sum(y & ((prob < bar) | veto))),
            "vetoed": {"right": int(np.sum(y & (prob >= bar) & veto)), "wrong": int(np.sum(~y & (prob >= bar) & veto))},
            "max_wrong_p": round(float(prob[~y].max()), 3) if (~y).any() else None,
            "min_right_p": round(float(prob[y].min()), 3) if y.any() else None, "reliability": bins}
    if err is not None:  # three classes: right, wrong beyond 2 deg / 0.5 m, and in between (neither)
        e = np.asarray(err, float).reshape(-1, 2)
        far, acc = (e[:, 0] > 2.0) | (e[:, 1] > 0.5), (prob >= bar) & ~veto
        mid = ~y & ~far
        out["classes"] = {"right": int(y.sum()), "right_rejected": int(np.sum(y & ~acc)),
                          "in_between": int(mid.sum()), "in_between_accepted": int(np.sum(mid & acc)),
                          "wrong": int(far.sum()), "wrong_accepted": int(np.sum(far & acc)),
                          "max_wrong_p": round(float(prob[far].max()), 3) if far.any() else None}
    if near_ref is not None:  # wrong by the recorded truth, right by GICP from it: at the truth's resolution
        out["wrong_accepted_near_gicp_truth"] = int(np.sum(~y & (prob >= bar) & ~veto & np.asarray(near_ref, bool)))
    if err is not None and np.any(~y & (prob >= bar) & ~veto):  # the largest errors of the wrong poses accepted
        e = np.asarray(err, float)[~y & (prob >= bar) & ~veto]
        out["wrong_accepted_max_err"] = [round(float(e[:, 0].max()), 2), round(float(e[:, 1].max()), 2)]
    return out


def slides(row: np.ndarray) -> bool:
    """Whether the pose of a good-start feature row (``core.visibility.FEATURES``) is one the fit does not hold where
    it is, by the bound of the shipped coefficients' ``_relative`` models (``verdict_model.json`` "relative":
    ``pinned`` under ``held_pinned`` 0.02, free by more than seven tolerances, and ``anchored_far`` under
    ``held_anchored_far`` 0.1); False when the file sets no such bound."""
    held_pin, held_far = _held()
    row = np.asarray(row, np.float64).ravel()
    return bool(row[FEATURES.index("pinned")] < held_pin and row[FEATURES.index("anchored_far")] < held_far)


@functools.lru_cache(maxsize=1)
def _held() -> tuple[float, float]:
    """(held_pinned, held_anchored_far) of the coefficients judged (0, 1 with no ``"relative"`` models: none slides)."""
    from deepbbs_ros.core import calibrated

    spec = json.loads(Path(calibrated.DEFAULT_PATH).read_text()).get("relative", {})
    if not spec.get("shares"):
        return 0.0, 1.0
    return float(spec.get("held_pinned", 0.0)), float(spec.get("held_anchored_far", 1.0))


def checks(y: np.ndarray, prob: np.ndarray, bar: float, ambiguous: np.ndarray, slides: np.ndarray,
           err: np.ndarray, rows: np.ndarray | None = None, sure: float = 0.95) -> dict:
    """The good start's wrong (beyond 2 deg / 0.5 m) accepted and right rejected with no second-minimum check
    (``none``, as shipped), with it where the pose slides (``slides``), where the weakest direction is looser than 5
    tolerances, or than 2 with a probability under ``sure`` (``registration.verdict_sure``) (``loose``,
    ``registration.good_start_second_minimum``; needs ``rows``) and on every pose taken (``all``); and how many poses
    the verdict takes (``taken``) and how many of them slide (``taken_sliding``: the check's two GICP runs each, where
    their uncertainty exceeds a tolerance; ``taken_loose``: those ``loose`` checks); ``found``:
    the poses taken where the check finds a second minimum, each (right, deg, m, probability, ``pinned``,
    ``anchored_far``; the last two from ``rows``)."""
    y, ok = np.asarray(y, bool), np.asarray(prob) >= bar
    e = np.asarray(err, float).reshape(-1, 2)
    far = (e[:, 0] > 2.0) | (e[:, 1] > 0.5)
    loose = np.zeros(len(y), bool) if rows is None else loose_poses(rows, prob, sure)
    out = {"taken": int(ok.sum()), "taken_sliding": int(np.sum(ok & slides)), "taken_loose": int(np.sum(ok & loose))}
    for mode, veto in (("none", np.zeros(len(y), bool)), ("slides", ambiguous & slides), ("loose", ambiguous & loose),
                       ("all", ambiguous)):
        acc = ok & ~np.asarray(veto, bool)
        out[mode] = {"wrong_accepted": int(np.sum(far & acc)), "right_rejected": int(np.sum(y & ~acc))}
    pin, anc = FEATURES.index("pinned"), FEATURES.index("anchored_far")
    out["found"] = [[bool(y[i]), round(float(e[i, 0]), 2), round(float(e[i, 1]), 2), round(float(prob[i]), 3),
                     *([round(float(rows[i, pin]), 3), round(float(rows[i, anc]), 3)] if rows is not None else [])]
                    for i in np.flatnonzero(ok & np.asarray(ambiguous, bool))]
    return out


def loose_poses(rows: np.ndarray, prob: np.ndarray, sure: float) -> np.ndarray:
    """Which good-start poses ``registration.good_start_second_minimum`` checks (core/good_start.py _slides): looser
    than STEPS[-1] tolerances, or than STEPS[0] where the probability is under ``sure``; from the feature rows'
    ``pinned`` = 1 / (1 + uncertainty^2) (core/plane_matches.py pinned)."""
    from deepbbs_ros.core.anchoring import STEPS

    return np.asarray(rows)[:, FEATURES.index("pinned")] < 1.0 / (
        1.0 + np.where(np.asarray(prob) < sure, STEPS[0], STEPS[-1]) ** 2)


def scene_flow(data: dict, m: np.ndarray, bar: float) -> dict:
    """The good start on the GICP answers (``near`` / ``far``) of the rows ``m`` (``--sim-scene-grid``): taken on
    GICP's grid, else finished on the scans' scene-sized grids (core/polish.py finish) and judged again on GICP's
    grid (``gicp_grid``, ``registration.good_start_finish_grid`` "gicp", the default) or on the scene's grids with
    ``verdict_dist`` scaled with them, then the second-minimum check there (``scene_grid``, "scene"), or on GICP's
    grid, then where it neither takes nor holds the pose on both (``both_grids``, "both", core/finish_verdict.py;
    these and, tried, not shipped: ``scene_within``, its probability times P(within | the pose's covariance) there,
    core/within.py, ``scene_within_weak`` with the spread along a weak direction): wrong (beyond 2 deg / 0.5 m)
    accepted, right rejected (the answer or its finish right), right accepted, and the accepted poses that the
    finish made (deg, m, probability)."""
    from deepbbs_ros.core import calibrated, visibility

    g = m & np.isin(data["kind"], ["near", "far"])
    p0 = calibrated.probability(data["good"], "good_start")
    fy, done = data["fin_y"], np.isfinite(data["fin_y"][:, 0])
    far0, y0 = (data["rot"] > 2.0) | (data["trans"] > 0.5), data["y"] == 1
    ffar, fright = done & ((fy[:, 1] > 2.0) | (fy[:, 2] > 0.5)), done & (fy[:, 0] == 1)
    out = {"answers": int(g.sum()), "finished": int(np.sum(g & (p0 < bar) & done))}
    for name, col in (("gicp_grid", 0), ("scene_grid", 1), ("both_grids", 1), ("scene_within", 1),
                      ("scene_within_weak", 1)):
        pf = np.zeros(len(p0))
        pf[done] = calibrated.probability(data["fin"][done, col], "good_start")
        if name == "both_grids":  # "both" (core/finish_verdict.py): where GICP's grid does not take nor hold the pose,
            both = np.array(data["fin"][:, 0])  # also GICP's grid with pinned read on the scene's; else GICP's grid
            pin = visibility.FEATURES.index("pinned")
            both[:, pin] = data["fin"][:, 1, pin]
            pg = np.zeros(len(p0))
            pg[done] = calibrated.probability(data["fin"][done, 0], "good_start")
            free = done & (pg < bar) & (data["fin"][:, 0, pin] < calibrated.anchored_below())
            pb = np.zeros(len(p0))
            pb[free] = calibrated.probability(both[free], "good_start")
            pf = np.where(free, np.minimum(pf, pb), pg)
        if name.startswith("scene_within"):  # times P(within | the pose's covariance) on the scene's grids (tried);
            # _weak: that covariance with the spread along a weak direction (core/within.py pose_covariance weak)
            pf = pf * np.nan_to_num(np.asarray(data["fin_within"], np.float64)[:, int(name.endswith("weak"))], nan=0.0)
        amb = data["fin_amb"].astype(bool) & (free if name == "both_grids" else True) if col else False
        first, then = p0 >= bar, (p0 < bar) & (pf >= bar) & ~amb
        out[name] = {"wrong_accepted": int(np.sum(g & ((first & far0) | (then & ffar)))),
                     "right_rejected": int(np.sum(g & ~first & ~then & (y0 | fright))),
                     "right_accepted": int(np.sum(g & ((first & y0) | (then & fright)))),
                     "accepted_finished": [[round(float(fy[i, 1]), 2), round(float(fy[i, 2]), 2),
                                            round(float(pf[i]), 3)] for i in np.flatnonzero(g & then)]}
    return out


def sim_parts(pairs: int, seed: int, low_pairs: int = 0, turned_pairs: int = 0, **kw) -> list[dict]:
    """calibrate_verdict.py ``collect`` on the simulated rigs (``pairs`` each), the low-overlap rigs (``low_pairs``)
    and the turned rigs (``turned_pairs``), each with its own rig indices (:func:`family`) -> their rows."""
    import calibrate_verdict as cv

    parts = [cv.collect(cv.RIGS, seed, pairs, **kw)]
    if low_pairs:  # low-overlap pairs (the source's share the target can judge at the truth 10-40 %), apart
        parts.append(cv.collect(cv.LOW_RIGS, seed, low_pairs, low=True, rig0=len(cv.RIGS), **kw))
    if turned_pairs:  # a sensor turned and moved between its scans (sim/turned.py), apart
        parts.append(cv.collect(cv.TURNED_RIGS, seed, turned_pairs, turned=True, rig0=len(cv.RIGS) + len(cv.LOW_RIGS),
                                **kw))
    return parts


def family(rig: int) -> str:
    """The family of the simulated rig index ``rig`` (:func:`sim_parts`): "dense", "sparse" or "solid"."""
    import calibrate_verdict as cv

    return FAMILY.get((cv.RIGS + cv.LOW_RIGS + cv.TURNED_RIGS)[rig][0], "sparse")


def sim_figures(pairs: int, seed: int, rc, low_pairs: int = 0, turned_pairs: int = 0, slid: bool = False,
                config=None, dump: Path | None = None, scene: bool = False) -> dict:
    import calibrate_verdict as cv

    from deepbbs_ros.core import calibrated, within

    kw = {"slid": slid, "config": config, "second": True, "scene": scene}  # the pair verdict's second-minimum check
    parts = sim_parts(pairs, seed, low_pairs, turned_pairs, **kw)
    data = {k: np.concatenate([d[k] for d in parts if len(d["y"])]) for k in parts[0]}
    fam = np.array([family(r) for r in data["rig"]])
    low = data["rig"] >= len(cv.RIGS)
    turned = data["rig"] >= len(cv.RIGS) + len(cv.LOW_RIGS)
    slide = data["kind"] == "slid"
    out = {}
    p = calibrated.probability(data["good"], "good_start")  # both verdicts judge the spread voxel subset
    free = np.array([slides(r) for r in data["good"]], bool)
    # P(within the tolerance | the pose's covariance) (core/within.py): the verdicts that registration.verdict_within
    # names multiply by it; the other rows (``<verdict>_with_within`` / ``_without_within``) judge the same poses
    # the other way
    w = np.array([within.probability(None if np.isnan(c).any() else c, rc.success_trans, rc.success_rot_deg)
                  for c in data["cov"]])
    bent = skew_bent(data["skew"], rc)
    if dump:
        np.savez(dump, p=p, within=w, fam=fam, low=low, turned=turned, **data)
    for name, key, bar in (("pair", "pair", rc.verdict_probability), ("good_start", "good", rc.good_start_probability)):
        on = rc.verdict_within in ("all", name)
        for f in ("dense", "sparse", "solid", "all", "low_overlap", "turned", "slid"):
            m = turned if f == "turned" else low & ~turned if f == "low_overlap" else ~low if f == "all" else \
                slide if f == "slid" else (fam == f) & ~low
            m = m if f == "slid" else m & ~slide
            if not m.any():
                continue
            # vetoes: the pair verdict's second minimum; the skew check (core/sweep_skew.py) where
            # registration.skew_check is on (``<verdict>_with_skew`` / ``_without_skew``: the same poses the other way)
            amb = data["ambiguous"][m] if name == "pair" else good_start_veto(data["ambiguous"][m], np.asarray(
                data["good"])[m], (p * (w if on else 1.0))[m], rc)
            veto = amb | (bent[m] if rc.skew_check else False)
            for row, factor in ((name, w if on else 1.0), (f"{name}_{'without' if on else 'with'}_within",
                                                           1.0 if on else w)):
                out[f"{row}/{f}"] = summary(data["y"][m] == 1, data[key][m, 0], (p * factor)[m], OLD[name], bar,
                                            data["near_ref"][m], np.c_[data["rot"][m], data["trans"][m]], veto)
            p_on = p * w if on else p
            if f != "slid":  # the answers a registration gives alone: the poses its verdicts judge (ANSWERS)
                a = np.isin(data["kind"][m], ANSWERS)
                out[f"{name}_answers/{f}"] = summary(data["y"][m][a] == 1, data[key][m, 0][a], p_on[m][a], OLD[name],
                                                     bar, data["near_ref"][m][a],
                                                     np.c_[data["rot"][m], data["trans"][m]][a], veto[a])
            out[f"{name}_{'without' if rc.skew_check else 'with'}_skew/{f}"] = summary(
                data["y"][m] == 1, data[key][m, 0], p_on[m], OLD[name], bar, data["near_ref"][m],
                np.c_[data["rot"][m], data["trans"][m]], amb | (False if rc.skew_check else bent[m]))
            if name == "good_start" and scene:
                out[f"good_start_scene_grid/{f}"] = scene_flow(data, m, bar)
            if name == "good_start":  # the same poses with no check, and with the check on every pose taken
                out[f"good_start_checks/{f}"] = checks(data["y"][m] == 1, p_on[m], bar, data["ambiguous"][m],
                                                       free[m], np.c_[data["rot"][m], data["trans"][m]],
                                                       np.asarray(data["good"])[m], rc.verdict_sure)
    ran = np.isfinite(data["skew"][:, 0]) & (p >= rc.verdict_probability)  # where the registration runs it
    out["skew_cost"] = {"poses": int(ran.sum()), "ms": round(float(np.median(data["skew"][ran, 6])), 2) if ran.any()
                        else None, "ratio_to_gicp": round(float(np.median(data["skew"][ran, 6] / data["skew"][ran, 7])),
                                                          3) if ran.any() else None}
    for f in ("dense", "sparse", "solid", "all"):  # how rough the targets' own surfaces are (real sets: the same)
        m = (~low if f == "all" else (fam == f) & ~low) & ~slide
        q = np.median(np.array([data["rough"][m], data["self_plane"][m]]), axis=1)
        out[f"roughness/{f}"] = {"self_residual_q90_m": round(float(q[0]), 3), "self_planarity": round(float(q[1]), 3)}
    return out


def _cost(pts: np.ndarray, T: np.ndarray, src, tgt, rc, repeats: int = 3) -> tuple[float, float]:
    """CPU ms (one thread, medians of ``repeats``, alternated) of the verdict's probability of the pose ``T`` and of
    the same times P(within | covariance) (core/within.py), where ``verdict_within`` computes it (an accepted pose)."""
    import time

    from deepbbs_ros.core import verdict, within

    tpc, old, new = tgt.polish_cloud, [], []
    for _ in range(repeats):
        t0 = time.process_time()
        verdict.probability(pts, T, tpc, rc.verdict_dist, "good_start")
        t1 = time.process_time()
        verdict.probability(pts, T, tpc, rc.verdict_dist, "good_start")
        within.within(src.polish_cloud, tpc, T, rc)
        t2 = time.process_time()
        old.append(t1 - t0)
        new.append(t2 - t1)
    return 1e3 * float(np.median(old)), 1e3 * float(np.median(new))


def good_start_veto(ambiguous: np.ndarray, rows: np.ndarray, prob: np.ndarray, rc) -> np.ndarray:
    """The good start's second-minimum veto as registered: the check's finding on the loose poses where
    ``registration.good_start_second_minimum`` is on, none where it is off."""
    if not rc.good_start_second_minimum:
        return np.zeros(len(ambiguous), bool)
    return np.asarray(ambiguous, bool) & loose_poses(rows, prob, rc.verdict_sure)


def skew_bent(skew: np.ndarray, rc) -> np.ndarray:
    """Which poses the skew check turns away (core/sweep_skew.py: half the motion within a sweep, less
    ``registration.skew_sigmas`` standard errors, beyond ``success_rot_deg`` / ``success_trans``) from the rows'
    ``skew`` columns (calibrate_verdict.py: the least rotation / translation error at the run's sigmas, the estimates,
    their standard errors, ms, the pair's GICP ms; NaN where the scans carry no times): (N,) bool."""
    s = np.asarray(skew, np.float64).reshape(-1, 8)
    with np.errstate(invalid="ignore"):
        rot = s[:, 2] - rc.skew_sigmas * s[:, 4]
        tr = s[:, 3] - rc.skew_sigmas * s[:, 5]
        return np.nan_to_num((rot > rc.success_rot_deg) | (tr > rc.success_trans)).astype(bool)


def real_pairs(spec: str):
    """'FOLDER:stride:max_dist' -> (name, [(src Scan, tgt Scan, None)])."""
    from deepbbs_ros.datasets import open_source
    from deepbbs_ros.replay.runner import iter_pairs

    path, stride, dist = spec.rsplit(":", 2) if spec.count(":") >= 2 else (spec, "1", "5")
    return Path(path).name, list(iter_pairs(open_source(path), int(stride), float(dist)))


def real_figures(specs: list[str], pair: str | None, trials: int, reg, dump: Path | None = None) -> dict:
    import calibrate_verdict as cv

    from deepbbs_ros.core import calibrated, second_minimum, visibility, within

    rc, rng, out, feats = reg.config.registration, np.random.default_rng(7), {}, []
    sets = [real_pairs(s) for s in specs]
    if pair:
        tgt, src, T_ref = _common.read_reference_pair(pair)
        sets.append((Path(pair).name, [("ref", src, tgt, T_ref)]))
    for name, pairs in sets:
        rows, rough, cost = {"pair": [], "good": []}, [], []
        for item in pairs:
            if item[0] == "ref":
                _, sp, tp, T_gt = item
                starts = [cv.perturb(rng, (0, 45), (0, 5), 0.0) for _ in range(trials)]
                ps, pt = reg.preprocess(sp), reg.preprocess(tp)
            else:
                s, t = item
                T_gt = np.linalg.inv(t.T_world_lidar) @ s.T_world_lidar
                starts = [None]
                ps = reg.preprocess(s.points, s.point_times(), s.stamp_ns)
                pt = reg.preprocess(t.points, t.point_times(), t.stamp_ns)
            rough.append(visibility.roughness(pt.polish_cloud, rc.verdict_dist))
            motion = (*cv.label(T_gt, np.eye(4))[1:], len(ps.polish_cloud.points()), len(pt.polish_cloud.points()))
            ref = cv.good_start_gicp(ps.polish_cloud, pt.polish_cloud, T_gt, rc)  # GICP from the truth
            T_ref = ref.T_target_source if ref.applied else T_gt
            for T0 in starts:
                res = reg.register(ps, pt, T_init=T0, preprocessed=True)
                y, r, t = cv.label(res.T_target_source, T_gt)
                pts = cv.good_start_points(ps.polish_cloud, rc)
                f = visibility.pose_features(pts, res.T_target_source, pt.polish_cloud,
                                             rc.verdict_dist)  # what the pipeline's verdict judged
                cost.append(_cost(pts, res.T_target_source, ps, pt, rc))
                rows["pair"].append((y == 1, res.score, res.probability,
                                     cv.label(res.T_target_source, T_ref)[0] == 1, r, t,
                                     res.probability >= rc.verdict_probability and not res.valid,
                                     calibrated.probability(f, "good_start"),
                                     within.within(ps.polish_cloud, pt.polish_cloud, res.T_target_source, rc)))
                y = y == 1
                feats.append((name, "pair", y, r, t, res.score, *motion, *f))
            for yaw, tr in (((0, 3), (0, 0.5)), ((10, 45), (1, 4))):  # GICP from near and from far
                pol = cv.good_start_gicp(ps.polish_cloud, pt.polish_cloud, cv.perturb(rng, yaw, tr) @ T_gt, rc)
                if pol.applied:
                    f = cv.rows_of(ps, pt, pol.T_target_source, rc)[1]
                    y, r, t = cv.label(pol.T_target_source, T_gt)
                    y, p = y == 1, calibrated.probability(f, "good_start")
                    # the second-minimum check on every pose taken (the good start's veto: good_start_veto)
                    amb = bool(rc.second_minimum and p >= rc.good_start_probability and second_minimum.check(
                        cv.good_start_points(ps.polish_cloud, rc), pol.T_target_source, ps.polish_cloud,
                        pt.polish_cloud, rc).ambiguous)
                    rows["good"].append((y, f[0], p, cv.label(pol.T_target_source, T_ref)[0] == 1, r, t, False,
                                         amb, slides(f), f[FEATURES.index("pinned")],
                                         f[FEATURES.index("anchored_far")],
                                         within.within(ps.polish_cloud, pt.polish_cloud, pol.T_target_source, rc)))
                    feats.append((name, "good", y, r, t, f[0], *motion, *f))
        for verdict, key, bar in (("pair", "pair", rc.verdict_probability),
                                  ("good_start", "good", rc.good_start_probability)):
            a = np.array(rows[key], float).reshape(-1, 9 if key == "pair" else 12)
            on = rc.verdict_within in ("all", verdict)
            # the pair verdict as registered (with or without the factor, the second-minimum check as it ran); the
            # good start's on GICP's poses; then the same poses judged the other way
            plain = a[:, 7] if key == "pair" else a[:, 2]
            p_on = a[:, 2] if key == "pair" else a[:, 2] * (a[:, -1] if on else 1.0)
            r = np.zeros((len(a), len(FEATURES)))
            if key == "good":
                r[:, [FEATURES.index("pinned"), FEATURES.index("anchored_far")]] = a[:, 9:11]
            veto = a[:, 6] > 0 if key == "pair" else good_start_veto(a[:, 7] > 0, r, p_on, rc)
            out[f"{verdict}/{name}"] = summary(a[:, 0] > 0, a[:, 1], p_on, OLD[verdict], bar, a[:, 3] > 0,
                                               a[:, 4:6], veto)
            out[f"{verdict}_{'without' if on else 'with'}_within/{name}"] = summary(
                a[:, 0] > 0, a[:, 1], plain * (1.0 if on else a[:, -1]), OLD[verdict], bar, a[:, 3] > 0, a[:, 4:6],
                veto)
            if key == "good":
                out[f"good_start_checks/{name}"] = checks(a[:, 0] > 0, p_on, bar, a[:, 7] > 0, a[:, 8] > 0,
                                                            a[:, 4:6], r, rc.verdict_sure)
        c = np.median(np.array(cost).reshape(-1, 2), axis=0)
        out[f"cost/{name}"] = {"verdict_ms": round(float(c[0]), 3), "verdict_within_ms": round(float(c[1]), 3),
                               "ratio": round(float(c[1] / max(c[0], 1e-9)), 2)}
        q = np.median(np.array(rough).reshape(-1, 2), axis=0)
        out[f"roughness/{name}"] = {"self_residual_q90_m": round(float(q[0]), 3),
                                    "self_planarity": round(float(q[1]), 3)}
        print(name, {k: {kk: v.get(kk) for kk in [*list(v)[:9], "wrong_accepted_near_gicp_truth",
                                                  "wrong_accepted_max_err", "classes", "self_residual_q90_m",
                                                  "self_planarity", "verdict_ms", "verdict_within_ms", "ratio"]
                         if kk in v}
                     for k, v in out.items() if k.endswith("/" + name)},
              flush=True)
    if dump:
        np.savez(dump, set=np.array([f[0] for f in feats]), verdict=np.array([f[1] for f in feats]),
                 y=np.array([f[2] for f in feats]), err=np.array([f[3:5] for f in feats], float),
                 score=np.array([f[5] for f in feats], float), motion=np.array([f[6:10] for f in feats], float),
                 x=np.array([f[10:] for f in feats], float))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--real", nargs="*", default=[], metavar="FOLDER:STRIDE:MAX_DIST",
                    help="real sets with ground truth (KITTI-style folders), pair protocol per set")
    ap.add_argument("--pair", help="a reference pair folder (two .pcd and relative.txt)")
    ap.add_argument("--trials", type=int, default=10, help="perturbed starts of the reference pair (default 10)")
    ap.add_argument("--sim-pairs", type=int, default=4, help="simulated pairs per rig (0: none; default 4)")
    ap.add_argument("--sim-low-pairs", type=int, default=0,
                    help="low-overlap simulated pairs per rig of the fit's low-overlap rigs, judged apart (default 0)")
    ap.add_argument("--sim-turned-pairs", type=int, default=0,
                    help="turned simulated pairs per rig of the fit's turned rigs, judged apart (default 0)")
    ap.add_argument("--sim-slid", action="store_true",
                    help="also the truth slid along its least pinned direction on every simulated pair, judged apart")
    ap.add_argument("--sim-scene-grid", action="store_true",
                    help="also the good start's GICP answers finished on the scans' scene-sized grids and judged "
                    "there, the verdict's distance scaled with the grid (good_start_scene_grid; tried, not shipped)")
    ap.add_argument("--seed", type=int, default=39, help="simulation seed (the fit's is 38; default 39)")
    ap.add_argument("--out", type=Path, default=Path("results/benchmarks"))
    ap.add_argument("--dump", type=Path, help="also write the real poses' features (those the verdict judged), labels, "
                    "errors (deg, m), scores, the pairs' motion (deg, m) and GICP voxels (source, target) here (.npz)")
    ap.add_argument("--dump-sim", type=Path, help="also write the simulated poses' rows (.npz)")
    ap.add_argument("--config", type=Path, help="config YAML of the registration (default: the defaults)")
    ap.add_argument("--model", type=Path, help="judge with these coefficients (a verdict_model.json; default: the "
                    "shipped ones), to compare a fit with the shipped one on the same poses")
    args = ap.parse_args(argv)
    if args.model:
        from deepbbs_ros.core import calibrated

        calibrated.DEFAULT_PATH = args.model.resolve()

    from deepbbs_ros.config import Config, load_config
    from deepbbs_ros.core.registration import DeepBBSRegistration

    config = load_config(args.config) if args.config else Config()
    reg = DeepBBSRegistration(config)
    figures = {"thresholds": {"old": OLD, "pair": reg.config.registration.verdict_probability,
                              "good_start": reg.config.registration.good_start_probability},
               "model": str(args.model or "shipped")}
    if args.sim_pairs > 0:
        figures["sim"] = sim_figures(args.sim_pairs, args.seed, reg.config.registration,
                                     args.sim_low_pairs, args.sim_turned_pairs, args.sim_slid, config,
                                     args.dump_sim, args.sim_scene_grid)
        for k, v in figures["sim"].items():
            print("sim", k, v if k.startswith(("roughness", "good_start_checks", "good_start_scene", "skew_cost")) else
                  ({kk: v.get(kk) for kk in [*list(v)[:9], "wrong_accepted_near_gicp_truth", "wrong_accepted_max_err",
                                             "classes"]}, v["reliability"]), flush=True)
    if args.real or args.pair:
        figures["real"] = real_figures(args.real, args.pair, args.trials, reg, args.dump)
    _common.write_json(args.out, "verdict.json", figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
