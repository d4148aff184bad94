#!/usr/bin/env python3
"""Registration of raw scan pairs: accuracy, speed against small_gicp GICP, the verdict, KISS-Matcher.

Figures (``registration.json``, ``registration.png``, ``verdict.png`` under ``--out``): for three protocols, the
source as recorded ("as they come", no initial guess), the source moved by a random yaw up to 45 deg and up to
5 m ("45 deg / 5 m") and by any yaw and up to 10 m ("any start"), on real KITTI pairs up to ``--max-dist`` m
apart (``--kitti``), an optional real reference pair (``--pair``) and held-out simulated drives of every scene
type: success (within 1 deg / 0.3 m), mean errors of the successes, p50 / p95 time per raw pair (preprocessing
of both scans included) and its ratio to GICP's p50 in the same run, for the shipped pipeline (``deepbbs++``),
the paper's DeepBBS++ (deep passes and its spatial-BBS refinement, no GICP: ``registration.refine: true``,
``registration.polish: none``), the fast preset (``config/deepbbs_ros_fast.yaml``), small_gicp GICP from
identity (the speed anchor) and, from any start, KISS-Matcher and KISS-Matcher + GICP (every ``--kiss-every``-th
case). The verdict: the share of correct results it accepts and of wrong poses it rejects (the shipped pipeline
and, from any start, the same pipeline without its global search, which gives wrong poses), and the share of
pairs of two different places (KITTI 00 x 02, simulated drives x each other) it rejects. Every answer is the same on
any machine and in every run (``--inexact``: not): each method is timed on every core, as a user runs it, and a
second call answers exactly (DeepBBS++ with ``registration.exact_gicp``, GICP on one thread, KISS-Matcher in a
child process on one CPU). The summary, its printout and the plots: ``_registration_figures.py``.

    python scripts/benchmarks/registration.py --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 --out results/benchmarks
"""

from __future__ import annotations

import argparse
import json
import sys
from itertools import islice
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)
from _registration_figures import PROTOCOLS, group, plot, report, summarise  # noqa: E402

DEEP = {  # method -> config overrides of DeepBBSRegistration (a str: a config file of the repository)
    "deepbbs++": {},
    "deepbbs++paper": {"registration.refine": True, "registration.polish": "none"},
    "deepbbs++fast": "config/deepbbs_ros_fast.yaml",
    "deepbbs++local": {"registration.global_search": "off"},
}
ANY_ONLY = ("deepbbs++local", "kiss-matcher", "kiss-matcher+gicp")
DEFAULT_METHODS = "deepbbs++,deepbbs++paper,deepbbs++fast,deepbbs++local,gicp,kiss-matcher,kiss-matcher+gicp"


def yaw_shift(yaw_deg: float, dx: float, dy: float) -> np.ndarray:
    T = np.eye(4)
    a = np.radians(yaw_deg)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:2, 3] = dx, dy
    return T


def frame_sets(args) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """name -> [(raw points (N, 3) float32, T_world_lidar)]: one place per set."""
    from deepbbs_ros.datasets import open_source

    sets: dict[str, list] = {}
    for folder in args.kitti:
        scans = islice(open_source(folder), args.kitti_scans)
        sets[f"kitti_{Path(folder).name}"] = [(np.asarray(s.points, np.float32), np.asarray(s.T_world_lidar))
                                              for s in scans]
    if args.pair:
        target, source, T = _common.read_reference_pair(args.pair)
        sets["pair"] = [(target, np.eye(4)), (source, T)]
    sets.update(sim_sets(args))
    return sets


def sim_sets(args) -> dict[str, list]:
    """Held-out simulated drives (test seeds 90000 + i, every scene type), sweeps compensated to their stamps,
    ``--sim-frames`` scans about 2 m apart; cached in ``--cache``."""
    if args.sim_drives_per_scene <= 0:
        return {}
    from deepbbs_ros.sim import SCENES, WORLDS_VERSION
    from deepbbs_ros.sim.simulator import DriveSimulator
    from deepbbs_ros.train.cache import TEST_SEED_BASE

    cache = Path(args.cache).expanduser() / (f"registration_sim_{args.sim_drives_per_scene}x{args.sim_frames}"
                                             f"_w{WORLDS_VERSION}.npz")
    if cache.is_file():
        return np.load(cache, allow_pickle=True)["sets"].item()
    sets: dict[str, list] = {}
    for d in range(args.sim_drives_per_scene * len(SCENES)):
        scene, seed = SCENES[d % len(SCENES)], TEST_SEED_BASE + d
        sim = DriveSimulator(scene, seed, frames=200, compensate=True)
        picks = sim.frames_apart(2.0, args.sim_frames, start=20)
        sets[f"sim_{scene}_{seed}"] = [(sim.scan_at(k).points.astype(np.float32), sim.pose_at(k)) for k in picks]
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, sets=np.array(sets, dtype=object))
    return sets


def plan(sets: dict, args) -> list[dict]:
    """True pairs (source i, target j < i, at most --max-dist apart; at most --pairs-per-set per set), each under
    every protocol with its own random move, and pairs of two different places."""
    rng = np.random.default_rng(args.seed)
    cases = []
    for name, frames in sets.items():
        pairs = []
        for i in range(len(frames)):
            for j in range(i):
                d = float(np.linalg.norm((np.linalg.inv(frames[j][1]) @ frames[i][1])[:3, 3]))
                if d <= args.max_dist:
                    pairs.append((i, j, d))
        if len(pairs) > args.pairs_per_set:
            pairs = [pairs[k] for k in sorted(rng.choice(len(pairs), args.pairs_per_set, replace=False))]
        for proto, (yaw, shift) in PROTOCOLS.items():
            for i, j, d in pairs:
                for _ in range(args.pair_trials if name == "pair" and shift else 1):
                    phi, r = rng.uniform(0, 2 * np.pi), rng.uniform(0, shift)
                    cases.append({"kind": "true", "protocol": proto, "set": name, "i": i, "j": j, "dist": d,
                                  "move": [float(rng.uniform(-yaw, yaw)), r * np.cos(phi), r * np.sin(phi)]})
    names = list(sets)
    cross = [(a, b) for a in names for b in names if a < b and group(a) == group(b) and group(a) != "pair"]
    for k in range(args.different if cross else 0):
        a, b = cross[k % len(cross)]
        cases.append({"kind": "different", "protocol": "different", "set": a, "i": int(rng.integers(len(sets[a]))),
                      "tset": b, "j": int(rng.integers(len(sets[b]))), "dist": None, "move": [0.0, 0.0, 0.0]})
    seen: dict[str, int] = {}
    for n, c in enumerate(cases):
        c["n"], c["k"] = n, seen.get(c["protocol"], 0)  # k: the case's index within its protocol
        seen[c["protocol"]] = c["k"] + 1
    return cases


class MatcherSolver:
    """KISS-Matcher (or KISS-Matcher + GICP) as a solver of :class:`_common.Isolated`: ``solve(src, tgt)`` -> its
    ``T_target_source`` (4, 4). In a child on one CPU from its start its thread pool has one thread, so that its
    answers are the same on any machine."""

    def __init__(self, method: str, config) -> None:
        from deepbbs_ros.baselines import KissMatcherRegistration

        self.reg = KissMatcherRegistration(method, config)

    def solve(self, src: np.ndarray, tgt: np.ndarray) -> np.ndarray:
        return self.reg.align(self.reg.preprocess(src), self.reg.preprocess(tgt)).T_target_source


def make_methods(names: list[str], args) -> dict:
    """method -> (the registration timed, the registration whose answer counts or None: the timed one's). By default
    the answers are exact (the same on any machine) and the times are those of every core, as a user runs each
    method: DeepBBS++ answers with ``registration.exact_gicp``, GICP with one thread and KISS-Matcher from a child
    on one CPU (:class:`MatcherSolver`); ``--inexact``: one call on every core answers and is timed."""
    from deepbbs_ros.baselines import KissMatcherRegistration, SmallGicpRegistration
    from deepbbs_ros.config import load_config
    from deepbbs_ros.core.registration import DeepBBSRegistration

    base = load_config(args.config)
    # the baselines timed on every core, as DeepBBS++'s precision stage (registration.polish_threads 0); eval.threads
    # 1, the replay's fixed thread count, gives their exact answers
    every = base.replace(**{"eval.threads": 0})
    exact = not getattr(args, "inexact", False)
    regs = {}
    for m in names:
        if m in DEEP:
            over = DEEP[m]
            cfg = load_config(_common.ROOT / over) if isinstance(over, str) else base.replace(**over)
            pair = [DeepBBSRegistration(cfg, weights=args.weights)]
            if exact:
                pair.append(DeepBBSRegistration(cfg.replace(**{"registration.exact_gicp": True}), weights=args.weights))
            for reg in pair:
                reg.warmup()
            regs[m] = (pair[0], pair[1] if exact else None)
        elif m == "gicp":
            regs[m] = (SmallGicpRegistration("gicp", every),
                       SmallGicpRegistration("gicp", base.replace(**{"eval.threads": 1})) if exact else None)
        elif m in ("kiss-matcher", "kiss-matcher+gicp"):
            regs[m] = (KissMatcherRegistration(m, every),
                      _common.Isolated(MatcherSolver, m, every, one_cpu=True) if exact else None)
        else:
            raise SystemExit(f"unknown method {m!r}; choose from {DEFAULT_METHODS}")
    return regs


def _register(m: str, reg, src: np.ndarray, tgt: np.ndarray):
    if isinstance(reg, _common.Isolated):
        reply = reg.ask(src, tgt)
        if reply.error:
            raise RuntimeError(reply.error)
        return reply.value, {}
    if m in DEEP:
        res = reg.register(src, tgt)
        return res.T_target_source, {"valid": bool(res.valid), "score": float(res.score), "starts": int(res.starts)}
    return reg.align(reg.preprocess(src), reg.preprocess(tgt)).T_target_source, {}


def run_case(m: str, regs, src: np.ndarray, tgt: np.ndarray) -> dict:
    """One method on one pair: the timed registration's wall time, the answering one's pose (and verdict)."""
    (T, extra), ms, _ = _common.timed_then_answered(lambda reg: _register(m, reg, src, tgt), *regs)
    return {"ms": ms, "T": T, **extra}


def collect(cases, sets, names, args, path: Path) -> list[dict]:
    from deepbbs_ros.metrics import pair_errors

    done = [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []
    if len(done) >= len(cases):
        return done
    regs = make_methods(names, args)
    with path.open("a") as fh:
        for case in cases[len(done):]:
            P = yaw_shift(*case["move"])
            src = (sets[case["set"]][case["i"]][0] @ P[:3, :3].T + P[:3, 3]).astype(np.float32)  # the moved source
            tset = case.get("tset", case["set"])
            tgt = sets[tset][case["j"]][0]
            T_gt = np.linalg.inv(sets[tset][case["j"]][1]) @ sets[case["set"]][case["i"]][1]
            rec = dict(case)
            for m in names:
                if case["kind"] == "different" and m != "deepbbs++":
                    continue
                if m in ANY_ONLY and case["protocol"] != "any-start":
                    continue
                if m.startswith("kiss") and case["k"] % args.kiss_every:
                    continue
                r = run_case(m, regs[m], src, tgt)
                T = r.pop("T")
                if case["kind"] == "true":
                    rot, tr = pair_errors(T @ P, T_gt)  # the answer for the moved source, the move undone
                    r.update(rot=float(rot), trans=float(tr), ok=bool(rot <= 1.0 and tr <= 0.3))
                rec[m] = r
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            done.append(rec)
            print(f"case {case['n'] + 1}/{len(cases)} {case['protocol']} {case['set']}: " + ", ".join(
                f"{m} {'ok' if rec[m].get('ok', not rec[m].get('valid')) else 'FAIL'} {rec[m]['ms']:.0f} ms"
                for m in names if m in rec), flush=True)
    for pair in regs.values():
        for r in pair:
            if hasattr(r, "close"):
                r.close()
    return done


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kitti", nargs="*", default=[], help="KITTI odometry sequence folders (velodyne/, poses.txt, "
                   "calib.txt), e.g. PATH/TO/kitti/00 PATH/TO/kitti/02")
    p.add_argument("--kitti-scans", type=int, default=10, help="the first scans of each KITTI sequence")
    p.add_argument("--pair", default=None, help="optional folder with a real pair: two .pcd files (target, source in "
                   "name order) and relative.txt (the reference T_target_source, 4x4)")
    p.add_argument("--out", default="results/benchmarks", help="folder for registration.json, the plots and "
                   "registration_cases.jsonl (a rerun continues from it)")
    p.add_argument("--methods", default=DEFAULT_METHODS, help=f"comma list of {DEFAULT_METHODS}")
    p.add_argument("--max-dist", type=float, default=5.0, help="m between the scans of a true pair")
    p.add_argument("--pairs-per-set", type=int, default=12, help="true pairs drawn per sequence or drive")
    p.add_argument("--pair-trials", type=int, default=3, help="moves of the --pair pair per moved protocol")
    p.add_argument("--sim-drives-per-scene", type=int, default=1, help="held-out simulated drives per scene type")
    p.add_argument("--sim-frames", type=int, default=6, help="scans per simulated drive, about 2 m apart")
    p.add_argument("--different", type=int, default=8, help="pairs of two different places")
    p.add_argument("--kiss-every", type=int, default=3, help="KISS-Matcher on every n-th any-start case")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--config", default=None, help="config YAML of the shipped pipeline (default: the defaults)")
    p.add_argument("--weights", default="", help="checkpoint ('' = the shipped model)")
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="cache of the simulated scans")
    p.add_argument("--inexact", action="store_true", help="one call per method on every core answers and is timed "
                   "(default: exact answers, the same on any machine, from a second call; the time is that of every "
                   "core)")
    args = p.parse_args(argv)
    names = [m for m in args.methods.split(",") if m]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sets = frame_sets(args)
    cases = plan(sets, args)
    recs = collect(cases, sets, names, args, out / "registration_cases.jsonl")
    fig = summarise(recs, names)
    fig["settings"] = {k: v for k, v in vars(args).items()}
    report(fig, names)
    _common.write_json(out, "registration.json", fig)
    plot(fig, recs, names, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
