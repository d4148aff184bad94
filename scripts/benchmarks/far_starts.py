#!/usr/bin/env python3
"""The whole pipeline from far starts: wrong poses accepted where the any-start search runs.

verdict.py judges poses near the truth; here ``register()`` runs from the truth moved by the families table's basin
offsets (:data:`BASIN`: a yaw about the source's origin of either sign and a shift in a random horizontal direction,
30 deg / 2 m up to 180 deg / 10 m), where the global search (core/global_search.py) answers. On verdict.py's
simulated pairs (the same draws: :func:`verdict.sim_parts`; families ``dense``, ``sparse``, ``solid``,
``low_overlap``, ``turned``) and on real sets (KITTI-style folders with ground truth, ``--real FOLDER:STRIDE:MAX_DIST``,
``--real-pairs`` pairs each, evenly spread; a reference pair folder, ``--pair``). Each pair gets ``--levels`` of the
offsets, taken in turn from pair to pair. Per family: right (1 deg / 0.3 m) accepted and rejected, in between accepted
and rejected, wrong (beyond 2 deg / 0.5 m) accepted and rejected; ``wrong_accepted_rows``: each wrong pose accepted
(deg, m, probability, the offset, path, starts); ``rows``: every run. With ``--compare`` the same starts also run
with ``registration.search_ambiguity`` (``--toggle``: another key) the other way (``off`` / ``on`` counts;
``changed``: the runs whose class differs). ``--good-start``: ``register(..., good_start=True)`` (GICP from the
start first, core/good_start.py); ``--identity``: once per pair from the recorded start (identity) instead, what a
stream of neighbouring scans pays (``ms_p50``). ::

    python scripts/benchmarks/far_starts.py --seed 39 --sim-pairs 1 --sim-low-pairs 1 --sim-turned-pairs 1 \\
        --compare --out results/far39
    python scripts/benchmarks/far_starts.py --sim-pairs 0 --real PATH/livox_avia_loop:4:2 PATH/nuscenes_hdl32:1:5 \\
        PATH/kitti/00:1:5 --pair PATH/hdl32_pair --compare --out results/far_real
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import _common  # noqa: E402
import families  # noqa: E402
import numpy as np  # noqa: E402
import registration as _reg  # noqa: E402
import verdict  # noqa: E402

#: the families table's basin offsets beyond the good start: (|yaw| deg, shift m)
BASIN = families.BASIN[1:]  # the families table's basin offsets, less its first (the start as recorded)
CLASSES = ("right_accepted", "right_rejected", "between_accepted", "between_rejected", "wrong_accepted",
           "wrong_rejected")


def offset(rng: np.random.Generator, level: int) -> np.ndarray:
    """(4, 4) the basin offset ``level``: its yaw (random sign) about the source's origin, its shift in a random
    horizontal direction."""
    yaw, shift = BASIN[level]
    yaw, phi = yaw * rng.choice([-1, 1]), rng.uniform(0, 2 * np.pi)
    return _reg.yaw_shift(yaw, shift * np.cos(phi), shift * np.sin(phi))


def classify(res, T_gt: np.ndarray) -> tuple[str, float, float]:
    """(the class of a result (:data:`CLASSES`), its error deg, m)."""
    import calibrate_verdict as cv

    y, r, t = cv.label(res.T_target_source, T_gt)
    cls = "right" if y == 1 else "wrong" if y == 0 else "between"
    return f"{cls}_{'accepted' if res.valid else 'rejected'}", r, t


class Runs:
    """The pipeline from far starts on each pair (the ``starts`` callback of verdict.py's :func:`sim_parts`, and
    :meth:`pair` for the real ones): ``regs`` {setting: DeepBBSRegistration}."""

    def __init__(self, regs: dict, levels: int, seed: int, good_start: bool = False, identity: bool = False):
        self.good_start, self.identity = good_start, identity
        self.regs, self.levels, self.rng, self.rows, self.turn = regs, levels, np.random.default_rng(seed), [], 0
        self.last: dict = {}
        self.rig = ""
        _spy(self)

    def __call__(self, kind: str, src, tgt, T0: np.ndarray, T_gt: np.ndarray, rig: int) -> None:
        import good_start_degenerate as gsd

        if kind == "near":  # once per pair (verdict.py's near and far starts are not used)
            import calibrate_verdict as cv

            self.rig = "/".join((cv.RIGS + cv.LOW_RIGS + cv.TURNED_RIGS)[rig][:3])
            self.pair(gsd.family(rig), src, tgt, T_gt)

    def pair(self, family: str, src, tgt, T_gt: np.ndarray) -> None:
        """``--levels`` basin offsets from the truth ``T_gt`` of one prepared pair, each registered with every
        setting (both clouds' GICP trees built first, as a stream's target is: every setting sees the same)."""
        for pc in (getattr(src, "polish_cloud", None), getattr(tgt, "polish_cloud", None)):
            if pc is not None:
                pc.complete()
        for k in range(1 if self.identity else self.levels):
            level = -1 if self.identity else (self.turn + k) % len(BASIN)
            P = np.eye(4) if self.identity else offset(self.rng, level)
            row = {"family": family, "rig": self.rig, "level": level, "offset": [round(float(v), 2) for v in (
                np.degrees(np.arctan2(P[1, 0], P[0, 0])), P[0, 3], P[1, 3])]}
            for name, reg in self.regs.items():
                t0, self.last = time.perf_counter(), {}
                T0 = P if self.identity else T_gt @ P
                res = reg.register(src, tgt, T_init=T0, preprocessed=True, good_start=self.good_start)
                cls, r, t = classify(res, T_gt)
                row[name] = {"class": cls, "deg": round(r, 2), "m": round(t, 2), "p": round(float(res.probability), 3),
                             "path": res.path, "starts": res.starts, "ms": round((time.perf_counter() - t0) * 1e3),
                             **self.last}
                if res.valid and not cls.startswith("right") and getattr(src, "polish_cloud", None) is not None:
                    row[name]["features"] = features(src, tgt, res.T_target_source, reg.config.registration)
            self.rows.append(row)
            print(family, BASIN[level] if level >= 0 else "recorded start",
                  {n: (row[n]["class"], row[n]["deg"], row[n]["m"], row[n]["p"], row[n]["ms"]) for n in self.regs},
                  flush=True)
        self.turn += self.levels


def features(src, tgt, T: np.ndarray, rc) -> dict:
    """The good-start verdict's features (core/visibility.py) of an accepted pose that is not right: what it looked
    like (``fitness``, ``observable``, ``in_view``, ``pinned``, ``anchored_far``)."""
    from deepbbs_ros.core import visibility
    from deepbbs_ros.core.good_start import good_start_points

    f = visibility.pose_features(good_start_points(src.polish_cloud, rc), T, tgt.polish_cloud, rc.verdict_dist)
    return {k: round(float(f[visibility.FEATURES.index(k)]), 3)
            for k in ("fitness", "observable", "in_view", "pinned", "anchored_far")}


def _spy(runs: Runs) -> None:
    """Record, on ``runs.last``, what the search's end (core/search_ambiguity.py ``settle``) saw: its candidates through
    the verdict, the most probable one distinct from the answer (``rival``: probability, deg, m) and why the answer
    was made not valid (``why``)."""
    from deepbbs_ros.core import search_ambiguity
    from deepbbs_ros.metrics import pair_errors

    settle = search_ambiguity.settle

    def spy(best, seen, rc):
        other = search_ambiguity.rival(best, seen, rc)
        out = settle(best, seen, rc)
        runs.last = {"candidates": len(seen), "why": out.rival, "rival": None if other is None else [
            round(float(other.probability), 3), *(round(float(v), 2) for v in pair_errors(other.T, best.T))],
            "rivals_p": sorted(round(float(c.probability), 3) for c in seen
                               if c is not best and search_ambiguity.distinct(best.T, c.T))[::-1][:3]}
        return out

    search_ambiguity.settle = spy


def tally(rows: list[dict], name: str) -> dict:
    """Per family: each class's count, and the wrong poses accepted (deg, m, probability, offset, path, starts)."""
    out = {}
    for fam in sorted({r["family"] for r in rows}):
        rs = [r[name] | {"level": r["level"]} for r in rows if r["family"] == fam and name in r]
        out[fam] = {"runs": len(rs), **{c: sum(r["class"] == c for r in rs) for c in CLASSES},
                    "wrong_accepted_rows": [[r["deg"], r["m"], r["p"], _level(r["level"]), r["path"], r["starts"]]
                                            for r in rs if r["class"] == "wrong_accepted"],
                    "ms_p50": round(float(np.median([r["ms"] for r in rs])))}
    return out


def _level(level: int) -> list:
    return list(BASIN[level]) if level >= 0 else []


def real_pairs(specs: list[str], pair: str | None, n: int) -> list[tuple]:
    """(set name, [(source Scan or cloud, target, T_gt)]) of the real sets, ``n`` pairs each, evenly spread."""
    sets = []
    for spec in specs:
        name, pairs = verdict.real_pairs(spec)
        pick = np.unique(np.linspace(0, len(pairs) - 1, min(n, len(pairs))).round().astype(int))
        sets.append((name, [(s, t, np.linalg.inv(t.T_world_lidar) @ s.T_world_lidar)
                            for s, t in (pairs[k] for k in pick)]))
    if pair:
        tgt, src, T_ref = _common.read_reference_pair(pair)
        sets.append((Path(pair).name, [(src, tgt, T_ref)] * max(1, n // 2)))
    return sets


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=39, help="simulation seed (verdict.py's; default 39)")
    ap.add_argument("--sim-pairs", type=int, default=1, help="simulated pairs per rig (0: none; default 1)")
    ap.add_argument("--sim-low-pairs", type=int, default=1, help="low-overlap pairs per rig (default 1)")
    ap.add_argument("--sim-turned-pairs", type=int, default=1, help="turned pairs per rig (default 1)")
    ap.add_argument("--levels", type=int, default=2, help="basin offsets per pair, in turn (default 2 of 5)")
    ap.add_argument("--real", nargs="*", default=[], metavar="FOLDER:STRIDE:MAX_DIST", help="real sets")
    ap.add_argument("--real-pairs", type=int, default=4, help="pairs per real set (default 4)")
    ap.add_argument("--pair", help="a reference pair folder (two .pcd and relative.txt)")
    ap.add_argument("--good-start", action="store_true",
                    help="register(..., good_start=True): GICP from the start first, then the full pipeline")
    ap.add_argument("--identity", action="store_true",
                    help="once per pair from the recorded start (identity) instead of the basin offsets: the cost")
    ap.add_argument("--compare", action="store_true",
                    help="also run registration.search_ambiguity the other way on the same starts")
    ap.add_argument("--toggle", default="search_ambiguity",
                    help="the registration key (bool) --compare turns the other way (default search_ambiguity)")
    ap.add_argument("--threads", type=int, default=1, help="torch / GICP threads (default 1)")
    ap.add_argument("--config", type=Path, help="config YAML of the registration (default: the defaults)")
    ap.add_argument("--out", type=Path, default=Path("results/benchmarks"))
    args = ap.parse_args(argv)

    from deepbbs_ros.config import Config, load_config
    from deepbbs_ros.core.registration import DeepBBSRegistration

    config = load_config(args.config) if args.config else Config()
    config = dataclasses.replace(config, registration=dataclasses.replace(
        config.registration, threads=args.threads, polish_threads=args.threads, network_process="off"))
    rc = config.registration
    regs = {"shipped": DeepBBSRegistration(config)}
    if args.compare:
        other = dataclasses.replace(rc, **{args.toggle: not getattr(rc, args.toggle)})
        regs["other"] = DeepBBSRegistration(dataclasses.replace(config, registration=other))
    runs = Runs(regs, args.levels, args.seed, args.good_start, args.identity)
    if args.sim_pairs or args.sim_low_pairs or args.sim_turned_pairs:
        verdict.sim_parts(args.sim_pairs, args.seed, args.sim_low_pairs, args.sim_turned_pairs, config=config,
                          starts=runs)
    if args.real or args.pair:
        reg = regs["shipped"]
        for name, pairs in real_pairs(args.real, args.pair, args.real_pairs):
            for s, t, T_gt in pairs:
                if hasattr(s, "points"):
                    ps, pt = (reg.preprocess(x.points, x.point_times(), x.stamp_ns) for x in (s, t))
                else:
                    ps, pt = reg.preprocess(s), reg.preprocess(t)
                runs.pair(name, ps, pt, T_gt)
    on = getattr(rc, args.toggle)
    names = {"shipped": "on" if on else "off", "other": "off" if on else "on"}
    figures = {"seed": args.seed, "toggle": args.toggle, "good_start": args.good_start, "basin": BASIN,
               "levels": args.levels, "load": _load(),
               **{names[n]: tally(runs.rows, n) for n in regs},
               "changed": [r for r in runs.rows if "other" in r and r["shipped"]["class"] != r["other"]["class"]],
               "rows": runs.rows}
    for n in regs:
        print(names[n], {f: {c: v[c] for c in (*CLASSES, "wrong_accepted_rows")} for f, v in
                         figures[names[n]].items()}, flush=True)
    _common.write_json(args.out, f"far_starts_{args.seed}{'_good_start' if args.good_start else ''}.json", figures)
    return 0


def _load() -> str:
    try:
        return Path("/proc/loadavg").read_text().split(" ", 3)[:3].__str__()
    except OSError:
        return ""


if __name__ == "__main__":
    sys.exit(main())
