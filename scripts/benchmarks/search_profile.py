#!/usr/bin/env python3
"""Where a global search's CPU time goes: per stage of ``MapLocalizer``'s search from no guess, CPU ms per query.

The localization benchmark's cached maps (``localization.py --cache``: build them there first) and its queries, the
map given without its trajectory (``--grid-places``'s case); ``--outside N`` adds N queries of the next map (no pose
is right). Everything runs in this process on one thread (the network in-process, torch and GICP on one thread:
``registration.network_process off``, ``registration.threads 1``, ``registration.polish_threads 1``,
``registration.exact_gicp``), so a stage's CPU time is about its time on a quiet core, whatever the machine's load.
Stages are timed exclusively (a stage inside another counts for the inner one only)::

    describe, rank          the scan's descriptors and the places' ranking
    crop                    a candidate's crop (its network points; the map's GICP cloud is shared)
    network                 DeepBBS++'s passes on a candidate (register() less its GICP and verdict)
    deep.gicp               the GICP precision stage inside register()
    gicp                    GICP alone (beside an answer, a retry, a slid start)
    verdict                 the map verdict's probability of an answer
    retry.*                 the same, inside the retries when no place was accepted
    probe, refine, covariance   the accepted answer's probes, refinement and covariance

    python scripts/benchmarks/search_profile.py --cache PATH/TO/cache --scenes urban --outside 8 --out PATH/TO/out
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)


class StageClock:
    """Exclusive CPU (``time.process_time``) and wall ms per stage path (``"retry/gicp"``): :meth:`wrap` a function so
    that its calls are a stage; the time of a stage called inside another counts for the inner one only."""

    def __init__(self) -> None:
        self.reset()
        self.stack: list[str] = []
        self.cpu: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._t = time.process_time()

    def _switch(self) -> None:
        now = time.process_time()
        key = "/".join(self.stack) or "other"
        self.cpu[key] = self.cpu.get(key, 0.0) + (now - self._t) * 1e3
        self._t = now

    def wrap(self, name: str, fn):
        def timed(*a, **kw):
            self._switch()
            self.stack.append(name)
            key = "/".join(self.stack)
            self.calls[key] = self.calls.get(key, 0) + 1
            try:
                return fn(*a, **kw)
            finally:
                self._switch()
                self.stack.pop()
        return timed

    def reset(self) -> None:
        self.cpu, self.calls, self._t = {}, {}, time.process_time()
        self.ranked: list[tuple[int, float]] = []  # (place, descriptor distance) of the search's candidates
        self.answers: list[tuple[int, float, float, bool]] = []  # first-round DeepBBS++ (place, prob, score, ok)
        self.gicps: list[tuple[int, float, float, bool, bool]] = []  # GICP alone (place, prob, score, ok, in a retry)


def _stage(path: str) -> str:
    """A stage path -> its row: the innermost stage, ``retry.`` before it inside the retries."""
    parts = path.split("/")
    inner = parts[-1]
    if inner == "polish":  # GICP: inside register() the precision stage, else GICP alone
        inner = "deep.gicp" if "register" in parts else "gicp"
    elif inner == "register":
        inner = "network"
    outer = [p for p in parts[:-1] if p in ("retry", "probe")]
    return (f"{outer[0]}." if outer else "") + inner


def instrument(clock: StageClock, reg) -> None:
    """Wrap the stages the search calls in the modules (once per process) and of the shared registration ``reg``."""
    from deepbbs_ros.core import acceptance, place_probe, place_retry, registration_precision

    reg.register = clock.wrap("register", reg.register)
    acceptance.probability = clock.wrap("verdict", acceptance.probability)
    place_retry.polish = clock.wrap("polish", place_retry.polish)
    place_probe.polish = clock.wrap("polish", place_probe.polish)
    registration_precision.polish = clock.wrap("polish", registration_precision.polish)


def instrument_map(loc, clock: StageClock) -> None:
    """Wrap the search's stages of the MapLocalizer ``loc`` (its instance's methods)."""
    for name in ("describe", "_crop", "_retry", "_probe", "_refine", "_covariance"):
        setattr(loc, name, clock.wrap(name.strip("_"), getattr(loc, name)))
    rank, deep = clock.wrap("rank", loc.rank), loc._deep

    def ranked(*a, **kw):  # the candidates in rank order, and each first-round answer
        out = rank(*a, **kw)
        clock.ranked += [(int(p), float(d)) for p, d, *_ in out]  # the levelled round's after the upright's
        return out

    def answered(src, crop, T_init, place, timings, **kw):
        ans = deep(src, crop, T_init, place, timings, **kw)
        if "retry" not in clock.stack:
            clock.answers.append((int(place), float(ans.prob), float(ans.score), bool(ans.ok)))
        return ans

    gicp = loc._gicp

    def alone(src, crop, T, place):  # each GICP alone's answer (None: not applied, stopped at its check)
        ans = gicp(src, crop, T, place)
        clock.gicps.append((int(place), float(ans.prob) if ans else -1.0, float(ans.score) if ans else -1.0,
                            bool(ans.ok) if ans else False, "retry" in clock.stack))
        return ans

    loc.rank, loc._deep, loc._gicp = ranked, answered, alone


def profile(loc, clock: StageClock, queries, label: str, log=print) -> list[dict]:
    """One row per query: outcome, CPU ms of the whole search and per stage."""
    from deepbbs_ros.metrics import pair_errors

    rows = []
    for n, q in enumerate(queries):
        clock.reset()
        t0, c0 = time.perf_counter(), time.process_time()
        r = loc.localize(q.points)
        wall, cpu = time.perf_counter() - t0, (time.process_time() - c0) * 1e3
        stages: dict[str, float] = {}
        for k, v in clock.cpu.items():
            stages[_stage(k)] = stages.get(_stage(k), 0.0) + v
        calls: dict[str, int] = {}
        for k, v in clock.calls.items():
            calls[_stage(k)] = calls.get(_stage(k), 0) + v
        ok = False
        if q.T_map_scan is not None and r.valid:
            e_r, e_t = pair_errors(np.asarray(r.T_map_scan)[None], q.T_map_scan[None])
            ok = bool(e_r[0] <= 1.0 and e_t[0] <= 0.3)
        outcome = ("placed" if ok else "wrong") if r.valid else "none"
        rows.append({"set": label, "outcome": outcome, "cpu_ms": cpu, "wall_s": wall, "stages": stages,
                     "calls": calls, "reason": r.reason, "probability": float(r.probability),
                     "candidates": int(r.candidates), "ranked": clock.ranked, "answers": clock.answers,
                     "gicps": clock.gicps,
                     "place": int(r.place) if r.place is not None else -1})
        log(f"  {label} {n + 1}/{len(queries)}: {outcome} cpu {cpu:.0f} ms wall {wall:.2f} s "
            + " ".join(f"{k} {v:.0f}" for k, v in sorted(stages.items(), key=lambda kv: -kv[1]) if v >= 5)
            + f" | {r.reason[:60]}")
    return rows


def summary(rows: list[dict]) -> dict:
    """Per set: queries, placed / wrong / none, CPU p50 / p95, mean CPU ms per stage and calls per query."""
    cpu = np.array([r["cpu_ms"] for r in rows])
    keys = sorted({k for r in rows for k in r["stages"]})
    return {"queries": len(rows), **{k: sum(r["outcome"] == k for r in rows) for k in ("placed", "wrong", "none")},
            "cpu_ms_p50": float(np.percentile(cpu, 50)), "cpu_ms_p95": float(np.percentile(cpu, 95)),
            "stage_cpu_ms_mean": {k: float(np.mean([r["stages"].get(k, 0.0) for r in rows])) for k in keys},
            "stage_calls_mean": {k: float(np.mean([r["calls"].get(k, 0) for r in rows])) for k in keys}}


def _cached(cache: Path, scene: str):
    from _localization_data import _load

    from deepbbs_ros.sim import WORLDS_VERSION

    hits = sorted(cache.glob(f"loc_sim_{scene}_*_w{WORLDS_VERSION}_*.npz"))  # the current simulator's worlds only
    if not hits:
        raise SystemExit(f"no cached map of {scene!r} in {cache} of the simulator's worlds version {WORLDS_VERSION} "
                         f"(build it with localization.py --generate-only)")
    return _load(hits[0], scene)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cache", required=True, help="the localization benchmark's cache of maps and queries")
    p.add_argument("--scenes", nargs="+", default=["urban"], help="cached simulated scenes")
    p.add_argument("--kitti", nargs="*", default=[], help="KITTI folders pooled into the real map (as localization.py)")
    p.add_argument("--kitti-scans", type=int, default=40, help="the first scans of each KITTI sequence")
    p.add_argument("--pair", default=None, help="a real pair's folder, its target into the real map")
    p.add_argument("--queries", type=int, default=0, help="profile this many queries per map, spread (0 = all)")
    p.add_argument("--outside", type=int, default=0, help="also this many queries of the next map (no pose right)")
    p.add_argument("--out", default="results/benchmarks", help="folder for search_profile.json")
    args = p.parse_args(argv)
    import torch

    from deepbbs_ros.config import Config
    from deepbbs_ros.core.localization import MapLocalizer
    from deepbbs_ros.core.registration import DeepBBSRegistration

    torch.set_num_threads(1)
    cfg = Config().replace(**{"registration.network_process": "off", "registration.threads": 1,
                              "registration.polish_threads": 1, "registration.exact_gicp": True})
    reg = DeepBBSRegistration(cfg)
    reg.warmup()
    maps = {s: _cached(Path(args.cache).expanduser(), s) for s in args.scenes}
    if args.kitti or args.pair:
        import localization as bench

        maps["real"] = bench.real_map(argparse.Namespace(kitti=args.kitti, kitti_scans=args.kitti_scans,
                                                         pair=args.pair, seed=1, spacing=300.0, map_range=50.0,
                                                         map_voxel=0.2))
    names = list(maps)
    out: dict = {"load_before": os.getloadavg(), "sets": {}}
    clock = StageClock()
    instrument(clock, reg)
    for i, name in enumerate(names):
        data = maps[name]
        t0 = time.perf_counter()
        loc = MapLocalizer(data.points, cfg, registration=reg)
        print(f"{name}: map built in {time.perf_counter() - t0:.1f} s, {len(loc.places)} places")
        instrument_map(loc, clock)
        qs = data.queries
        if args.queries:
            qs = [qs[j] for j in np.unique(np.linspace(0, len(qs) - 1, args.queries).round().astype(int))]
        sets = {name: qs}
        if args.outside and len(names) > 1:
            other = maps[names[(i + 1) % len(names)]].queries
            pick = np.unique(np.linspace(0, len(other) - 1, min(args.outside, len(other))).round().astype(int))
            sets[f"{name} outside"] = [type(o)(o.points, None, o.place, o.kind) for o in (other[j] for j in pick)]
        for label, qq in sets.items():
            rows = profile(loc, clock, qq, label)
            s = summary(rows)
            out["sets"][label] = {**s, "rows": rows}
            _common.write_json(Path(args.out), "search_profile.json", out)  # what is done so far
            print(f"{label}: {s['placed']} placed, {s['wrong']} wrong, {s['none']} none of {s['queries']}; CPU p50 "
                  f"{s['cpu_ms_p50']:.0f} ms p95 {s['cpu_ms_p95']:.0f} ms; per query: "
                  + ", ".join(f"{k} {v:.0f} ms ({s['stage_calls_mean'][k]:.1f})"
                              for k, v in sorted(s["stage_cpu_ms_mean"].items(), key=lambda kv: -kv[1])))
    out["load_after"] = os.getloadavg()
    _common.write_json(Path(args.out), "search_profile.json", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
