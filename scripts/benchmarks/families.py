#!/usr/bin/env python3
"""Registration per LiDAR family: real scans where there are some, simulated pairs of every sensor on its mounts.

For each data set (real: KITTI HDL-64E sequences ``--kitti``, a reference pair ``--pair``, nuScenes HDL-32E
``--nuscenes``, a Livox Avia walk ``--livox``; simulated: every ``--sims`` entry ``sensor:mount:place``, sweeps
compensated to their stamps) and each method (DeepBBS++ as shipped, small_gicp GICP, KISS-Matcher + GICP), from a
good start (the source as recorded: neighbouring scans) and from starts moved by a yaw and a shift up to 180 deg /
10 m (the basin): success (within 1 deg / 0.3 m), the pairs DeepBBS++ misses with their overlap (the share of
source points within 0.5 m of the target at the truth), the median errors of DeepBBS++ and GICP on the pairs both
get right, the verdict's accepted wrong poses and rejected right ones, and p50 / p95 time per raw pair (both scans
preprocessed) with the ratio to GICP's p50 in the same run (and of the CPU times: this process and its children).
``good_start=True`` (DeepBBS++ told that the start is good) is also summarised over the pairs whose start is good by
a physical criterion, GICP from it lands within 1 deg / 0.3 m (the start lies in GICP's basin), with the path each
took (``good_start_in_basin``); there, both are also timed again on each pair, alternately (``--timing-repeats``:
neither in the other's wake), and the ratio of their medians is given beside the first timings'. Real pairs follow
``deepbbs-replay --mode pairs`` (``--stride``, ``--max-dist``). Answers are exact as in registration.py
(``--inexact``: not).

    python scripts/benchmarks/families.py --quick --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 --pair PATH/TO/hdl32_pair \
        --nuscenes PATH/TO/nuscenes_hdl32 --livox PATH/TO/livox_avia_loop --out results/benchmarks
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import zlib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)
import _good_start_parts as _parts  # noqa: E402
import registration as _reg  # noqa: E402

METHODS = "deepbbs++,deepbbs++good,gicp,kiss-matcher+gicp"
GOOD = "deepbbs++good"  # register(src, tgt, T_init=identity, good_start=True): from the good start only
#: start offsets of the basin: (|yaw| deg, shift m); the first is the good start
BASIN = [(0.0, 0.0), (30.0, 2.0), (60.0, 4.0), (90.0, 6.0), (135.0, 8.0), (180.0, 10.0)]
#: simulated sensor on the mounts and places it is used in (sensor:mount:place)
SIMS = ("hdl64:car:urban", "hdl32:car:suburban", "vlp16:wheeled:courtyard", "os0_64:legged:corridor",
        "os1_32:wheeled:garage", "os1_64:wheeled:hall", "os1_128:car:suburban", "xt32:wheeled:courtyard",
        "helios32:car:open_road", "avia:handheld:courtyard", "avia:handheld:hall", "mid360:legged:garage",
        "mid360:handheld:corridor")
REAL = {"kitti": "hdl64", "pair": "hdl32", "nuscenes": "hdl32", "livox": "avia"}  # real set -> its sensor
OVERLAP_M = 0.5
WRONG_DEG, WRONG_M = 2.0, 0.5  # a pose beyond either is wrong (right: within 1 deg / 0.3 m)


def overlap(src: np.ndarray, tgt: np.ndarray, T: np.ndarray, max_points: int = 20000) -> float:
    """Share of the finite source points (an even subsample) within 0.5 m of a target point at the truth ``T``."""
    from scipy.spatial import cKDTree

    s = src[np.isfinite(src).all(axis=1)]
    s = s[:: max(1, len(s) // max_points)] @ T[:3, :3].T + T[:3, 3]
    t = tgt[np.isfinite(tgt).all(axis=1)]
    d, _ = cKDTree(t).query(s, distance_upper_bound=OVERLAP_M)
    return float(np.mean(np.isfinite(d))) if len(s) else 0.0


def truth_check(src: np.ndarray, tgt: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """How far GICP started at the truth ``T`` moves from it (deg, m): on real scans the resolution of the recorded
    truth on this pair (a miss by about that much is the truth's); on simulated ones (an exact truth) GICP's own
    error, which DeepBBS++'s GICP precision stage shares."""
    from deepbbs_ros.baselines import SmallGicpRegistration
    from deepbbs_ros.config import Config
    from deepbbs_ros.metrics import pair_errors

    g = SmallGicpRegistration("gicp", Config().replace(**{"eval.threads": 1}))
    rot, tr = pair_errors(g.align(g.preprocess(src), g.preprocess(tgt), T).T_target_source, T)
    return float(rot), float(tr)


def real_sets(args) -> dict[str, dict]:
    """name -> {"sensor", "source", "frames": [(points, T_world_lidar)], "pairs": [(i, j)]} of the real data."""
    from deepbbs_ros.datasets import open_source
    from deepbbs_ros.replay.runner import iter_pairs

    sets = {}
    folders = [("kitti", f) for f in args.kitti] + [(k, getattr(args, k)) for k in ("nuscenes", "livox")
                                                    if getattr(args, k)]
    for kind, folder in folders:
        scans = list(open_source(folder))
        index = {id(s): k for k, s in enumerate(scans)}
        stride, dist = (args.livox_stride, args.livox_max_dist) if kind == "livox" else (1, args.max_dist)
        pairs = [(index[id(s)], index[id(t)]) for s, t in iter_pairs(scans, stride, dist)]
        sets[f"{kind}_{Path(folder).name}"] = {
            "sensor": REAL[kind], "source": "real", "mount": "handheld" if kind == "livox" else "car",
            "frames": [(np.asarray(s.points, np.float32), np.asarray(s.T_world_lidar)) for s in scans],
            "pairs": pairs}
    if args.pair:
        target, source, T = _common.read_reference_pair(args.pair)
        sets["pair_" + Path(args.pair).name] = {"sensor": "hdl32", "source": "real", "mount": "car",
                                               "frames": [(target, np.eye(4)), (source, T)], "pairs": [(1, 0)]}
    return sets


def sim_seed(spec: str) -> int:
    """The held-out seed of the ``--sims`` entry ``spec`` (sensor:mount:place): the same whatever the list."""
    from deepbbs_ros.train.cache import TEST_SEED_BASE

    return TEST_SEED_BASE + 500 + zlib.crc32(spec.encode()) % 1000


def sim_picks(sim, mount: str, count: int) -> list[int]:
    """The frames of a set: ``count`` frames from frame 10 on, about 2 m (car) or 1 m (else) apart."""
    return sim.frames_apart(2.0 if mount == "car" else 1.0, count, start=10)


def sim_sets(args) -> dict[str, dict]:
    """The ``--sims`` recordings (held-out seeds), ``--sim-frames`` scans about 2 m (car) or 1 m apart; pairs of
    neighbours; cached in ``--cache``."""
    from deepbbs_ros.sim import WORLDS_VERSION
    from deepbbs_ros.sim.rig import make_simulator

    sets = {}
    for spec in args.sims:
        sensor, mount, place = spec.split(":")
        seed = sim_seed(spec)
        key = f"{spec.replace(':', '_')}_{seed}x{args.sim_frames}_w{WORLDS_VERSION}"
        cache = Path(args.cache).expanduser() / f"families_{key}.npz"
        if cache.is_file():
            frames = list(np.load(cache, allow_pickle=True)["frames"])
        else:
            sim = make_simulator(place, seed, sensor, mount, frames=300, compensate=True)
            picks = sim_picks(sim, mount, args.sim_frames)
            frames = [(sim.scan_at(k).points.astype(np.float32), sim.pose_at(k)) for k in picks]
            cache.parent.mkdir(parents=True, exist_ok=True)
            np.savez(cache, frames=np.array(frames, dtype=object))
        sets[f"sim_{sensor}_{mount}_{place}"] = {"sensor": sensor, "source": "sim", "mount": mount, "place": place,
                                                 "frames": [tuple(f) for f in frames],
                                                 "pairs": [(k, k - 1) for k in range(1, len(frames))]}
    return sets


def plan(sets: dict, args) -> list[dict]:
    """Every set's pairs (at most ``--pairs-per-set``, evenly spread) from the good start, and its first
    ``--basin-pairs`` of them (the reference pair: ``--pair-trials`` times) from every basin offset, each with its
    own random sign of the yaw and direction of the shift."""
    rng = np.random.default_rng(args.seed)
    cases = []
    for name, s in sets.items():
        pairs = s["pairs"]
        if len(pairs) > args.pairs_per_set:
            pairs = [pairs[k] for k in np.linspace(0, len(pairs) - 1, args.pairs_per_set).round().astype(int)]
        s["pairs"] = pairs
        for level, (yaw, shift) in enumerate(BASIN):
            chosen = pairs if level == 0 else pairs[:: max(1, len(pairs) // args.basin_pairs)][: args.basin_pairs]
            trials = args.pair_trials if name.startswith("pair_") and level else 1
            for i, j in chosen:
                for _ in range(trials):
                    phi = rng.uniform(0, 2 * np.pi)
                    cases.append({"set": name, "i": int(i), "j": int(j), "level": level,
                                  "move": [float(yaw * rng.choice([-1, 1])), shift * np.cos(phi), shift * np.sin(phi)]})
    return cases


def collect(cases, sets, names, args, path: Path) -> list[dict]:
    from deepbbs_ros.metrics import pair_errors

    recorded = [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []
    by_key = {_key(r): r for r in recorded}
    todo = [c for c in cases if any(m not in by_key.get(_key(c), {}) for m in _applicable(c, names))]
    if not todo or args.report_only:
        return [by_key[_key(c)] for c in cases if _key(c) in by_key]
    regs = _reg.make_methods([m for m in names if m != GOOD], args)
    if GOOD in names:
        regs[GOOD] = regs["deepbbs++"] if "deepbbs++" in regs else _reg.make_methods(["deepbbs++"], args)["deepbbs++"]
    overlaps: dict = {}
    with path.open("a") as fh:
        for n, case in enumerate(todo, start=len(cases) - len(todo)):
            frames = sets[case["set"]]["frames"]
            P = _reg.yaw_shift(*case["move"])
            raw, tgt = frames[case["i"]][0], frames[case["j"]][0]
            src = (raw @ P[:3, :3].T + P[:3, 3]).astype(np.float32)
            T_gt = np.linalg.inv(frames[case["j"]][1]) @ frames[case["i"]][1]
            key = (case["set"], case["i"], case["j"])
            if key not in overlaps:
                overlaps[key] = overlap(raw, tgt, T_gt)
            rec = by_key.get(_key(case)) or {**case, "overlap": overlaps[key],
                                             "dist": float(np.linalg.norm(T_gt[:3, 3]))}
            for m in (m for m in _applicable(case, names) if m not in rec):
                r = run_good(regs[m], src, tgt) if m == GOOD else run_case(m, regs[m], src, tgt)
                rot, tr = pair_errors(r.pop("T") @ P, T_gt)
                rec[m] = {**r, "rot": float(rot), "trans": float(tr), "ok": bool(rot <= 1.0 and tr <= 0.3)}
            if (case["level"] == 0 and args.timing_repeats and GOOD in rec and rec.get("gicp", {}).get("ok")
                    and "timing" not in rec):  # a start in GICP's basin (in_basin): timed again, alternately
                rec["timing"] = alternate(regs[GOOD][0], regs["gicp"][0], src, tgt, args.timing_repeats,
                                         getattr(args, "stream_timing", False), getattr(args, "node_timing", False))
            if (case["level"] == 0 and getattr(args, "parts", 0) and GOOD in rec and rec.get("gicp", {}).get("ok")
                    and "parts" not in rec):  # in GICP's basin: where the good start's CPU time goes
                rec["parts"] = _parts.parts(regs[GOOD][0], regs["gicp"][0], src, tgt, args.parts)
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            by_key[_key(rec)] = rec
            print(f"case {n + 1}/{len(cases)} {case['set']} level {case['level']}: " + ", ".join(
                f"{m} {'ok' if rec[m]['ok'] else 'FAIL'} {rec[m]['ms']:.0f} ms" for m in names if m in rec), flush=True)
    for pair in regs.values():
        for r in pair:
            if hasattr(r, "close"):
                r.close()
    # a case no method applies to (a basin offset when the good start is the only method) has no record
    return [by_key[_key(c)] for c in cases if _key(c) in by_key]


def _applicable(case: dict, names: list[str]) -> list[str]:
    return [m for m in names if m != GOOD or case["level"] == 0]


def _cpu() -> tuple[float, float]:
    """(this process's CPU seconds, to the nanosecond; its children's (the network process), to the clock tick)."""
    return time.process_time(), _common.children_cpu_seconds()


def timed(call, timed_reg, answering=None) -> tuple:
    """``_common.timed_then_answered`` with the CPU time of this process to the nanosecond (a GICP call takes a few
    clock ticks): -> (the answer, wall ms, CPU ms of this process and its children)."""
    c0 = _cpu()
    t0 = time.perf_counter()
    out = call(timed_reg)
    wall = (time.perf_counter() - t0) * 1e3
    cpu = sum(b - a for a, b in zip(c0, _cpu())) * 1e3
    return (call(answering) if answering is not None else out), wall, cpu


def run_case(m: str, regs, src: np.ndarray, tgt: np.ndarray) -> dict:
    """One method on one pair (registration.py's ``run_case``), with its CPU time as well (``cpu_ms``: this process
    and its children, the network process included)."""
    (T, extra), ms, cpu = timed(lambda reg: _reg._register(m, reg, src, tgt), *regs)
    return {"ms": ms, "cpu_ms": cpu, "T": T, **extra}


def run_good(regs, src: np.ndarray, tgt: np.ndarray) -> dict:
    """DeepBBS++ told that the start (identity) is good: GICP first, its stricter verdict, the full pipeline only
    when that rejects (``path``)."""
    def call(reg):
        res = reg.register(src, tgt, T_init=np.eye(4), good_start=True)
        return res.T_target_source, {"valid": bool(res.valid), "score": float(res.score), "path": res.path,
                                     "why": res.good_start, "stages_ms": {k: round(float(v), 1) for k, v in
                                                                          res.timings_ms.items()}}

    (T, extra), ms, cpu = timed(call, *regs)
    return {"ms": ms, "cpu_ms": cpu, "T": T, **extra}


def alternate(good_reg, gicp_reg, src: np.ndarray, tgt: np.ndarray, repeats: int,
              stream: bool = False, node: bool = False) -> dict[str, list[float]]:
    """``good_start=True`` and GICP timed on the same pair ``repeats`` times each, back to back in alternating order
    (GICP first in even rounds, the good start first in odd ones): neither is timed in the other's wake (after the
    full pipeline, or on scans the other just read) more often -> {"good_ms", "gicp_ms", "good_cpu_ms",
    "gicp_cpu_ms"}: each timing (wall, and CPU of this process and its children). ``stream``: each round also times
    both as in a stream ("good_stream_ms", "gicp_stream_ms", "good_stream_cpu_ms", "gicp_stream_cpu_ms"), the target
    prepared before the clock starts (afresh each time, as the previous scan was when it was the source) and the
    source raw, copied just before (as a driver's message is converted just before the call: in the CPU's caches,
    where the raw pair's scans were last read a call ago): one scan prepared per call, where the raw pair prepares
    both. ``node``: each round also times both as the node's registration process runs a stream ("good_node_ms",
    ...): both scans prepared before the clock starts (k-d trees and covariances built on their arrival; the target,
    the last pair's source, with what the verdict reads of it alone, built once that pair was answered:
    core.scans.ready_to_judge), the registration alone timed (GICP: its alignment)."""
    calls = {"good": lambda reg: reg.register(src, tgt, T_init=np.eye(4), good_start=True),
             "gicp": lambda reg: _reg._register("gicp", reg, src, tgt)}
    ready = {"good": lambda reg: reg.preprocess(tgt, lazy=True), "gicp": lambda reg: reg.preprocess(tgt)}
    streamed = {"good": lambda reg, s, t: reg.register(s, t, T_init=np.eye(4), good_start=True),
                "gicp": lambda reg, s, t: reg.align(reg.preprocess(s), t)}
    arrived = {"good": _arrived, "gicp": lambda reg, s, target: reg.preprocess(s)}
    registered = {"good": lambda reg, s, t: reg.register(s, t, T_init=np.eye(4), good_start=True),
                  "gicp": lambda reg, s, t: reg.align(s, t)}
    kinds = ("",) + (("_stream",) if stream else ()) + (("_node",) if node else ())
    out: dict[str, list[float]] = {f"{m}{s}_{k}": [] for s in kinds for m in calls for k in ("ms", "cpu_ms")}
    for k in range(repeats):
        for s in kinds:
            for m in ("gicp", "good") if k % 2 == 0 else ("good", "gicp"):
                reg = good_reg if m == "good" else gicp_reg
                if s == "_node":  # both scans as the node's registration process holds them
                    c, t = arrived[m](reg, src, False), arrived[m](reg, tgt, True)
                    _, ms, cpu = timed(lambda r, c=c, t=t, m=m: registered[m](r, c, t), reg)
                elif s:
                    t, c = ready[m](reg), src.copy()  # the target as a stream holds it, the source as it arrives
                    _, ms, cpu = timed(lambda r, c=c, t=t, m=m: streamed[m](r, c, t), reg)
                else:
                    _, ms, cpu = timed(calls[m], reg)
                out[f"{m}{s}_ms"].append(ms)
                out[f"{m}{s}_cpu_ms"].append(cpu)
    return out


def _arrived(reg, points: np.ndarray, target: bool):
    """A raw scan prepared as the node's registration process holds it in a stream: lazy sampling, k-d tree and
    covariances built on its arrival; a ``target`` (the last pair's source) also made ready to judge once that pair was
    answered (``core.scans.ready_to_judge``, where the checkout has it)."""
    from deepbbs_ros.core import scans

    pre = reg.preprocess(points, lazy=True)
    if getattr(pre, "polish_cloud", None) is not None:
        pre.polish_cloud.complete(reg.gicp_threads())
    return getattr(scans, "ready_to_judge", lambda cfg, p: p)(reg.config, pre) if target else pre


def _alternated(inside: list[dict]) -> dict:
    """The in-basin pairs' :func:`alternate` timings: each pair's median per method, their p50 over the pairs and the
    ratios (wall and CPU); {} when a pair has none (recorded before they were taken)."""
    if not inside or not all(r.get("timing") for r in inside):
        return {}
    keys = set.intersection(*(set(r["timing"]) for r in inside))  # a pair timed before the stream timings: none
    med = {k: [float(np.median(r["timing"][k])) for r in inside] for k in keys}
    p50 = {k: float(np.median(v)) for k, v in med.items()}
    out = {"repeats": len(inside[0]["timing"]["good_ms"]), "p50_ms": {GOOD: p50["good_ms"], "gicp": p50["gicp_ms"]},
           "p50_over_gicp": p50["good_ms"] / p50["gicp_ms"],
           "cpu_p50_over_gicp": p50["good_cpu_ms"] / p50["gicp_cpu_ms"]}
    if "good_stream_ms" in p50:  # as in a stream: the target prepared before (alternate)
        out["stream"] = {"p50_ms": {GOOD: p50["good_stream_ms"], "gicp": p50["gicp_stream_ms"]},
                         "p50_over_gicp": p50["good_stream_ms"] / p50["gicp_stream_ms"],
                         "cpu_p50_over_gicp": p50["good_stream_cpu_ms"] / p50["gicp_stream_cpu_ms"]}
    if "good_node_ms" in p50:  # both scans prepared on arrival, the registration alone (alternate)
        out["node"] = {"p50_ms": {GOOD: p50["good_node_ms"], "gicp": p50["gicp_node_ms"]},
                       "p50_over_gicp": p50["good_node_ms"] / p50["gicp_node_ms"],
                       "cpu_p50_over_gicp": p50["good_node_cpu_ms"] / p50["gicp_node_cpu_ms"]}
    return out


def _whys(texts: list[str]) -> dict[str, int]:
    """Why the good-start path fell back, counted by the first try's reason and the coarse-to-fine try's."""
    import good_start

    out: dict[str, int] = {}
    for t in texts:
        k = " / ".join(good_start.reason_kind(part) for part in t.split("; coarse to fine: "))
        out[k] = out.get(k, 0) + 1
    return out


def _stages(ran: list[dict]) -> dict[str, float]:
    """The good start's time per stage of ``register()`` (``timings_ms``: preprocess, good_start, the network's, global,
    ...), the median over the pairs (0 where a stage did not run): where the time goes."""
    names = sorted({k for x in ran for k in x.get("stages_ms", {}) if k != "startup"})
    return {k: float(np.median([x.get("stages_ms", {}).get(k, 0.0) for x in ran])) for k in names}


#: how an answer GICP from the start gave beyond the good start's limits is named (and was, before GICP's answer was
#: judged by the verdict alone wherever it ended: within the coarse try's reach, when sure)
BEYOND = ("beyond the good start's limits", "within the coarse try's reach")


def path_taken(x: dict) -> str:
    """Which path answered one ``good_start=True`` call: "gicp" (GICP from the start within the good start's limits),
    "beyond limits" (converged beyond them, or only after good_start_max_iters, taken by the verdict), "coarse to
    fine" (core/coarse_rescue.py), "degenerate" (GICP's finished pose answered at once, not valid:
    core/finish_verdict.py), or the full pipeline after the good start was not taken ("deepbbs", "search")."""
    why = x.get("why", "")
    if x.get("path") != "gicp":
        return x.get("path", "?")
    if why.startswith("not valid: degenerate"):
        return "degenerate"
    if "coarse to fine" in why:
        return "coarse to fine"
    return "beyond limits" if any(b in why for b in BEYOND) else "gicp"


def in_basin(good: list[dict]) -> dict:
    """The good-start pairs whose start is good by a physical criterion: GICP from the start (the ``gicp`` method on
    the same pair) converges within 1 deg / 0.3 m of the truth, the start lies in GICP's basin. -> {"pairs", "others"
    (the pairs where it does not), and over the pairs: "p50_ms" of the good start and GICP, "p50_over_gicp",
    "cpu_p50_over_gicp" (when CPU times were recorded), "paths" (:func:`path_taken`), "fallback_why",
    "accepted_wrong", "rejected_right", and "alternated" (:func:`_alternated`) when the pairs were timed again}."""
    ran = [r for r in good if GOOD in r and "gicp" in r]
    inside = [r for r in ran if r["gicp"]["ok"]]
    out: dict = {"pairs": len(inside), "others": len(ran) - len(inside)}
    if not inside:
        return out
    ms = {m: float(np.median([r[m]["ms"] for r in inside])) for m in (GOOD, "gicp")}
    out["p50_ms"], out["p50_over_gicp"] = ms, ms[GOOD] / ms["gicp"]
    if all("cpu_ms" in r[m] for r in inside for m in (GOOD, "gicp")):
        cpu = {m: float(np.median([r[m]["cpu_ms"] for r in inside])) for m in (GOOD, "gicp")}
        out["cpu_p50_ms"], out["cpu_p50_over_gicp"] = cpu, cpu[GOOD] / cpu["gicp"]
    paths: dict[str, int] = {}
    for r in inside:
        k = path_taken(r[GOOD])
        paths[k] = paths.get(k, 0) + 1
    out["paths"] = paths
    out["fallback_why"] = _whys([r[GOOD].get("why", "") for r in inside if r[GOOD]["path"] != "gicp"])
    rep = _alternated(inside)
    if rep:
        out["alternated"] = rep
    if part := _parts.summary(inside):
        out["parts_cpu_p50_ms"] = part
    out["accepted_wrong"] = sum(r[GOOD]["valid"] and not r[GOOD]["ok"] for r in inside)
    out["rejected_right"] = sum(r[GOOD]["ok"] and not r[GOOD]["valid"] for r in inside)
    return out


def _key(case: dict) -> str:
    """A case's identity in families_cases.jsonl: a rerun runs only the cases it lacks (delete a set's lines to run
    that set again)."""
    return json.dumps([case["set"], case["i"], case["j"], case["level"], [round(v, 9) for v in case["move"]]])


def summarise(recs: list[dict], sets: dict, names: list[str]) -> dict:
    out = {}
    for name, s in sets.items():
        rs = [r for r in recs if r["set"] == name]
        good = [r for r in rs if r["level"] == 0]
        if not good:
            continue
        cell = {"sensor": s["sensor"], "source": s["source"], "mount": s["mount"], "place": s.get("place"),
                "pairs": len(good), "overlap_median": float(np.median([r["overlap"] for r in good])),
                "success_pct": {}, "p50_ms": {}, "p95_ms": {}, "p50_over_gicp": {}}
        for m in names:
            ran = [r[m] for r in good if m in r]
            if not ran:
                continue
            ms = np.array([x["ms"] for x in ran])
            cell["success_pct"][m] = 100.0 * np.mean([x["ok"] for x in ran])
            cell["p50_ms"][m], cell["p95_ms"][m] = float(np.median(ms)), float(np.percentile(ms, 95))
            if m == GOOD:  # answered by GICP and the good-start verdict, or by the full pipeline after it rejected
                cell["good_start"] = {"pairs": len(ran), "gicp_path": sum(x["path"] == "gicp" and path_taken(x) !=
                                                                          "degenerate" for x in ran),
                                      "degenerate": sum(path_taken(x) == "degenerate" for x in ran),
                                      "coarse_to_fine": sum("coarse to fine" in x.get("why", "") and x["path"] == "gicp"
                                                            for x in ran),
                                      "fallback_why": _whys([x.get("why", "") for x in ran if x["path"] != "gicp"]),
                                      "beyond_limits": sum(path_taken(x) == "beyond limits" for x in ran),
                                      "stages_p50_ms": _stages(ran),
                                      "accepted_wrong": sum(x["valid"] and not x["ok"] for x in ran),
                                      "rejected_right": sum(x["ok"] and not x["valid"] for x in ran)}
        g50 = cell["p50_ms"].get("gicp")
        cell["p50_over_gicp"] = {m: v / g50 for m, v in cell["p50_ms"].items()} if g50 else {}
        cpu = {m: float(np.median([r[m]["cpu_ms"] for r in good if m in r])) for m in names
               if any(m in r for r in good) and all("cpu_ms" in r[m] for r in good if m in r)}
        if cpu.get("gicp"):  # CPU of this process and its children (the network process): less the machine's load
            cell["cpu_p50_over_gicp"] = {m: v / cpu["gicp"] for m, v in cpu.items()}
        if GOOD in names and "gicp" in names:
            cell["good_start_in_basin"] = in_basin(good)
        if "deepbbs++" in names:
            frames = s["frames"]
            cell["missed"] = [{"i": r["i"], "j": r["j"], "overlap": r["overlap"], "dist_m": r["dist"],
                               "rot_deg": r["deepbbs++"]["rot"], "trans_m": r["deepbbs++"]["trans"],
                               "accepted": r["deepbbs++"].get("valid"), "gicp_ok": r.get("gicp", {}).get("ok"),
                               "truth_gicp_deg_m": truth_check(frames[r["i"]][0], frames[r["j"]][0], np.linalg.inv(
                                   frames[r["j"]][1]) @ frames[r["i"]][1])}
                              for r in good if not r["deepbbs++"]["ok"]]
            both = [r for r in good if r["deepbbs++"]["ok"] and r.get("gicp", {}).get("ok")]
            cell["both_right"] = {"pairs": len(both), **{
                f"{m}_{e}_median": float(np.median([r[m][e] for r in both])) if both else None
                for m in ("deepbbs++", "gicp") if m in names for e in ("rot", "trans")}}
            deep = [r["deepbbs++"] for r in rs]
            # the verdict's classes: right within 1 deg / 0.3 m, wrong beyond 2 deg or 0.5 m, in between counted apart
            wrong = [x["rot"] > WRONG_DEG or x["trans"] > WRONG_M for x in deep]
            kept = [x["valid"] and not x["ok"] for x in deep]  # accepted, not right
            cell["verdict"] = {"cases": len(deep), "accepted_wrong": sum(k and w for k, w in zip(kept, wrong)),
                               "accepted_between": sum(k and not w for k, w in zip(kept, wrong)),
                               "rejected_right": sum(x["ok"] and not x["valid"] for x in deep),
                               "right": sum(x["ok"] for x in deep)}
        cell["basin"] = []
        for level, (yaw, shift) in enumerate(BASIN):
            lv = [r for r in rs if r["level"] == level]
            if lv:
                cell["basin"].append({"yaw_deg": yaw, "shift_m": shift, "cases": len(lv), "success_pct": {
                    m: 100.0 * np.mean([r[m]["ok"] for r in lv]) for m in names if m != GOOD and m in lv[0]}})
        out[name] = cell
    return out


def report(fig: dict, names: list[str]) -> None:
    for name, c in fig.items():
        succ = ", ".join(f"{m} {v:.0f} %" for m, v in c["success_pct"].items())
        times = ", ".join(f"{m} {v:.0f}/{c['p95_ms'][m]:.0f} ms" for m, v in c["p50_ms"].items())
        print(f"{name} ({c['pairs']} pairs, overlap p50 {c['overlap_median']:.2f}): {succ}; {times}")
        for x in c.get("missed", []):
            print(f"   missed {x['i']}->{x['j']}: overlap {x['overlap']:.2f}, {x['dist_m']:.1f} m apart, "
                  f"error {x['rot_deg']:.2f} deg / {x['trans_m']:.2f} m, accepted {x['accepted']}, "
                  f"GICP ok {x['gicp_ok']}, "
                  "GICP from the truth moves {:.2f} deg / {:.2f} m".format(*x["truth_gicp_deg_m"]))
        if "verdict" in c:
            print(f"   both right: {c['both_right']}; verdict: {c['verdict']}; good start: {c.get('good_start')}")
        b = c.get("good_start_in_basin")
        if b:
            ratio = "-" if "p50_over_gicp" not in b else f"x{b['p50_over_gicp']:.2f}"
            cpu = "" if "cpu_p50_over_gicp" not in b else f" (CPU x{b['cpu_p50_over_gicp']:.2f})"
            a = b.get("alternated")
            alt = "" if not a else (f"; alternated x{a['p50_over_gicp']:.2f} (CPU x{a['cpu_p50_over_gicp']:.2f}, "
                                    f"{a['repeats']} each)")
            if a and "stream" in a:
                st = a["stream"]
                alt += f"; in a stream x{st['p50_over_gicp']:.2f} (CPU x{st['cpu_p50_over_gicp']:.2f})"
            if a and "node" in a:
                nd = a["node"]
                alt += f"; scans prepared on arrival x{nd['p50_over_gicp']:.2f} (CPU x{nd['cpu_p50_over_gicp']:.2f})"
            print(f"   good start where GICP from the start is right ({b['pairs']} pairs, {b['others']} others): "
                  f"p50 / GICP's {ratio}{cpu}{alt}; paths {b.get('paths', {})}; fallbacks {b.get('fallback_why', {})}")
        print("   basin: " + "; ".join(f"{b['yaw_deg']:.0f} deg/{b['shift_m']:.0f} m " + "/".join(
            f"{v:.0f}" for v in b["success_pct"].values()) for b in c["basin"]))


def add_set_args(p: argparse.ArgumentParser) -> None:
    """The options of the data sets :func:`real_sets` and :func:`sim_sets` read: the real recordings, the simulated
    sets and how their pairs are drawn."""
    p.add_argument("--kitti", nargs="*", default=[], help="KITTI odometry folders (HDL-64E), e.g. PATH/TO/kitti/00")
    p.add_argument("--pair", default=None, help="a folder with a real HDL-32E pair (two .pcd, relative.txt)")
    p.add_argument("--nuscenes", default=None, help="nuScenes HDL-32E scans in the KITTI layout")
    p.add_argument("--livox", default=None, help="Livox Avia keyframes in the KITTI layout")
    p.add_argument("--sims", nargs="*", default=list(SIMS), help="simulated sets sensor:mount:place")
    p.add_argument("--max-dist", type=float, default=5.0, help="m between the scans of a real pair (not Livox)")
    p.add_argument("--livox-stride", type=int, default=4, help="every n-th Livox keyframe is a source")
    p.add_argument("--livox-max-dist", type=float, default=2.0, help="m between the scans of a Livox pair")
    p.add_argument("--sim-frames", type=int, default=7, help="scans per simulated set")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_set_args(p)
    p.add_argument("--pairs-per-set", type=int, default=16, help="pairs per set from the good start (evenly spread)")
    p.add_argument("--basin-pairs", type=int, default=4, help="pairs per set from each basin offset")
    p.add_argument("--pair-trials", type=int, default=3, help="random moves of the --pair pair per basin offset")
    p.add_argument("--quick", action="store_true", help="8 pairs per set, 2 per basin offset, 5 simulated scans: "
                   "a few minutes per family")
    p.add_argument("--methods", default=METHODS, help=f"comma list of {METHODS}")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", default="results/benchmarks", help="folder for families.json and families_cases.jsonl "
                   "(a rerun runs only the cases it lacks)")
    p.add_argument("--config", default=None, help="config YAML of DeepBBS++ (default: the defaults)")
    p.add_argument("--weights", default="", help="checkpoint ('' = the shipped model)")
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="cache of the simulated scans")
    p.add_argument("--report-only", action="store_true", help="summarise the cases already in families_cases.jsonl "
                   "without running more (a data set without any has no row)")
    p.add_argument("--inexact", action="store_true", help="one call per method answers and is timed")
    p.add_argument("--timing-repeats", type=int, default=3, help="good-start pairs: good_start=True and GICP timed "
                   "again this many times each, alternately (0 = not)")
    p.add_argument("--stream-timing", action="store_true", help="with --timing-repeats: also timed as in a stream "
                   "(the target prepared before the clock starts, the source raw: one scan prepared per call)")
    p.add_argument("--node-timing", action="store_true", help="with --timing-repeats: also timed as the node's "
                   "registration process runs a stream (both scans prepared before, the target's verdict tables "
                   "too: the registration alone)")
    p.add_argument("--parts", type=int, default=0, help="good-start pairs in GICP's basin: where its CPU time goes "
                   "beyond GICP's, part by part, over this many calls of each (0 = not; _good_start_parts.py)")
    args = p.parse_args(argv)
    if args.quick:
        args.pairs_per_set, args.basin_pairs, args.sim_frames = 8, 2, 5
    names = [m for m in args.methods.split(",") if m]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sets = {**real_sets(args), **sim_sets(args)}
    cases = plan(sets, args)
    recs = collect(cases, sets, names, args, out / "families_cases.jsonl")
    fig = summarise(recs, sets, names)
    report(fig, names)
    _common.write_json(out, "families.json", {"sets": fig, "basin": BASIN, "methods": names,
                                              "settings": {k: v for k, v in vars(args).items()}})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
