#!/usr/bin/env python3
"""Registration from any start: DeepBBS++ (default configuration: the verdict and the global search), DeepBBS++
from the given start only (``registration.global_search: off``), small_gicp GICP, KISS-Matcher and
KISS-Matcher + GICP side by side, on raw scans, in one run.

Every true pair of each frame set (scripts/study_frames.py: real KITTI 00 / 02 and the HDL-32E pair from
``--realdata``, held-out simulated drives of every scene type, ``--sim-pairs`` per drive) up to ``--max-dist``
m apart: the source points are moved by a random yaw in [-180, 180] degrees and a horizontal shift of up to
``--shift`` m and every method registers the raw pair with no initial guess (its time includes the
preprocessing of both scans); success = within 1 deg / 0.3 m of the ground truth (the known move undone).
``--good-start``: the same pairs unmoved (what consecutive scans and odometry see), to show what the default
pays there. ``--config-b``: DeepBBS++ with a second configuration as one more method, run before or after the
first by turns on every case (an A/B on a machine whose speed drifts). KISS-Matcher runs on every
``--kiss-every``-th case (about ten times slower). Results go to
``--out``/global_cases.jsonl (rerunning continues from it); the script prints success per data group and
pair distance (up to 5 m, 5-15 m), accepted shares (``valid``), and p50 / p95 time per method.

Usage::

    python scripts/global_study.py --realdata ../shared/realdata --out /tmp/global
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import deepbbs_ros  # noqa: F401  (first: OMP_WAIT_POLICY before torch loads, as the CLIs do)

sys.path.insert(0, str(Path(__file__).resolve().parent))
import study_frames  # noqa: E402

METHODS = ("deepbbs++", "deepbbs++local", "gicp", "kiss-matcher", "kiss-matcher+gicp")
B = "deepbbs++(b)"  # --config-b: DeepBBS++ with a second configuration, interleaved case by case


def plan(sets: dict, args, rng: np.random.Generator) -> list[dict]:
    cases = []
    for name, frames in sets.items():
        pairs = study_frames.true_pairs(frames, args.max_dist)
        if name.startswith("sim") and len(pairs) > args.sim_pairs:
            pairs = [pairs[k] for k in sorted(rng.choice(len(pairs), args.sim_pairs, replace=False))]
        trials = args.hdl_trials if name == "hdl32" else 1
        for i, j, _, d in pairs:
            for _ in range(trials):
                yaw = 0.0 if args.good_start else float(rng.uniform(-180, 180))
                phi, r = rng.uniform(0, 2 * np.pi), 0.0 if args.good_start else rng.uniform(0, args.shift)
                cases.append({"set": name, "i": i, "j": j, "dist": d,
                              "move": [yaw, r * np.cos(phi), r * np.sin(phi)]})
    order = rng.permutation(len(cases))
    out = [cases[k] for k in order]
    for n, c in enumerate(out):
        c["n"] = n
    return out


def main(argv: list[str] | None = None) -> int:
    here = Path(__file__).resolve().parents[1]
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--realdata", default=str(here.parent / "shared" / "realdata"))
    p.add_argument("--cache", default="/tmp/deepbbs_study/sim_frames.npz", help="simulated frames (npz)")
    p.add_argument("--out", default="/tmp/deepbbs_study/global")
    p.add_argument("--weights", default="")
    p.add_argument("--max-dist", type=float, default=15.0)
    p.add_argument("--shift", type=float, default=10.0)
    p.add_argument("--drives-per-scene", type=int, default=2)
    p.add_argument("--sim-pairs", type=int, default=6)
    p.add_argument("--hdl-trials", type=int, default=5)
    p.add_argument("--kiss-every", type=int, default=3)
    p.add_argument("--methods", default=",".join(METHODS))
    p.add_argument("--good-start", action="store_true")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--config", default=None, help="config YAML for DeepBBS++ (default: the shipped defaults)")
    p.add_argument("--config-b", default=None,
                   help="a second config YAML: DeepBBS++ with it runs as the method deepbbs++(b) on every case, "
                        "before or after deepbbs++ by turns (an A/B whose halves share the machine's state)")
    args = p.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    if args.config_b and B not in methods:
        methods.insert(methods.index("deepbbs++") + 1 if "deepbbs++" in methods else 0, B)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / ("good_start_cases.jsonl" if args.good_start else "global_cases.jsonl")
    done = [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []
    sets = study_frames.all_sets(Path(args.realdata), Path(args.cache), args.drives_per_scene)
    cases = plan(sets, args, np.random.default_rng(args.seed))
    if len(done) < len(cases):
        run(cases[len(done):], sets, methods, args, path)
        done = [json.loads(line) for line in path.read_text().splitlines()]
    report(done, methods)
    return 0


def run(cases, sets, methods, args, path: Path) -> None:
    from deepbbs_ros.baselines import KissMatcherRegistration, SmallGicpRegistration
    from deepbbs_ros.config import load_config
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors

    cfg = load_config(args.config)
    regs = {}
    if "deepbbs++" in methods:
        regs["deepbbs++"] = DeepBBSRegistration(cfg, weights=args.weights)
    if "deepbbs++local" in methods:
        regs["deepbbs++local"] = DeepBBSRegistration(cfg.replace(**{"registration.global_search": "off"}),
                                                     weights=args.weights)
    if B in methods:
        regs[B] = DeepBBSRegistration(load_config(args.config_b), weights=args.weights)
    for r in regs.values():
        r.warmup()
    every = cfg.replace(**{"eval.threads": 0})  # the baselines on every core, as DeepBBS++'s precision stage
    base = {m: (SmallGicpRegistration(m, every) if m == "gicp" else KissMatcherRegistration(m, every))
            for m in methods if m in ("gicp", "kiss-matcher", "kiss-matcher+gicp")}
    with path.open("a") as fh:
        for case in cases:
            frames = sets[case["set"]]
            P = study_frames.yaw_shift(case["move"][0], np.array(case["move"][1:]))
            src = (frames[case["i"]][0] @ P[:3, :3].T + P[:3, 3]).astype(np.float32)  # the moved source
            tgt = frames[case["j"]][0]
            T_gt = np.linalg.inv(frames[case["j"]][1]) @ frames[case["i"]][1]
            rec = dict(case)
            order = list(methods)
            if B in order and "deepbbs++" in order and case["n"] % 2:  # the A/B pair in turns
                a, b = order.index("deepbbs++"), order.index(B)
                order[a], order[b] = order[b], order[a]
            for m in order:
                if m.startswith("kiss") and case["n"] % args.kiss_every:
                    continue
                t0 = time.perf_counter()
                if m in regs:
                    res = regs[m].register(src, tgt)
                    T, extra = res.T_target_source, {"valid": res.valid, "score": res.score, "starts": res.starts}
                else:
                    b = base[m]
                    res = b.align(b.preprocess(src), b.preprocess(tgt))
                    T, extra = res.T_target_source, {}
                ms = (time.perf_counter() - t0) * 1e3
                rot, tr = pair_errors(T @ P, T_gt)  # the answer for the moved source, the move undone
                rec[m] = {"ms": ms, "rot": float(rot), "trans": float(tr), "ok": bool(rot <= 1.0 and tr <= 0.3),
                          **extra}
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            print(f"case {case['n']}: " + ", ".join(f"{m} {'ok' if rec[m]['ok'] else 'FAIL'} {rec[m]['ms']:.0f} ms"
                                                    for m in methods if m in rec), flush=True)
    for r in regs.values():
        r.close()


def group(name: str) -> str:
    return "sim" if name.startswith("sim") else ("kitti" if name.startswith("kitti") else name)


def report(recs: list[dict], methods: list[str]) -> None:
    print(f"\n{len(recs)} cases; success % (cases) per data group and pair distance")
    cells = [(g, lo, hi) for g in ("kitti", "hdl32", "sim", "all") for lo, hi in ((0, 5), (5, 15.01))]
    print(f"{'data, pair distance':>22} " + " ".join(f"{m:>18}" for m in methods))
    for g, lo, hi in cells:
        sel = [r for r in recs if (g == "all" or group(r["set"]) == g) and lo <= r["dist"] < hi]
        if not sel:
            continue
        row = []
        for m in methods:
            v = [r[m]["ok"] for r in sel if m in r]
            row.append(f"{100 * np.mean(v):6.1f} % ({len(v):3d})" if v else f"{'-':>18}")
        print(f"{g + f', {lo:g}-{min(hi, 15):g} m':>22} " + " ".join(f"{x:>18}" for x in row))
    print(f"{'time p50 / p95 ms':>22} " + " ".join(
        f"{np.percentile([r[m]['ms'] for r in recs if m in r], 50):8.0f} / "
        f"{np.percentile([r[m]['ms'] for r in recs if m in r], 95):6.0f}" if any(m in r for r in recs) else f"{'-':>18}"
        for m in methods))
    pairs = [(r["deepbbs++"], r[B]) for r in recs if "deepbbs++" in r and B in r]
    if pairs:
        d = np.array([b["ms"] - a["ms"] for a, b in pairs])
        both = np.array([a["starts"] > 1 and b["starts"] > 1 for a, b in pairs])
        print(f"{B} - deepbbs++, case by case: median {np.median(d):+.0f} ms, mean {d.mean():+.0f} ms ({len(d)} "
              f"cases)" + (f"; where both searched: median {np.median(d[both]):+.0f} ms ({both.sum()})"
                           if both.any() else ""))
    for m in ("deepbbs++", B, "deepbbs++local"):
        sel = [r[m] for r in recs if m in r]
        if sel:
            ok = np.array([s["ok"] for s in sel])
            valid = np.array([s["valid"] for s in sel])
            glob = np.array([s["starts"] > 1 for s in sel])
            print(f"{m}: valid {100 * valid.mean():.1f} % of results; correct results accepted "
                  f"{100 * valid[ok].mean() if ok.any() else float('nan'):.1f} %, wrong results rejected "
                  f"{100 * (~valid[~ok]).mean() if (~ok).any() else float('nan'):.1f} % ({(~ok).sum()}); "
                  f"global search ran on {100 * glob.mean():.1f} %")
            fails = [(r["set"], r["i"], r["j"], round(r["move"][0]), round(r[m]["rot"], 2), round(r[m]["trans"], 2))
                     for r in recs if m in r and not r[m]["ok"]]
            if fails:
                print(f"  {m} failures (set, i, j, yaw, rot err, trans err): {fails[:12]}")


if __name__ == "__main__":
    raise SystemExit(main())
