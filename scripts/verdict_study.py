#!/usr/bin/env python3
"""Calibrate and check the verdict (``RegistrationResult.valid``): acceptance of true pairs, rejection of pairs
of two different places and of wrong poses, for candidate scores and thresholds.

Cases (frame sets of scripts/study_frames.py: real KITTI 00 / 02 and the HDL-32E pair from ``--realdata``,
held-out simulated drives of every scene type):

* true pairs: pairs of one set up to ``--max-dist`` m apart (every pair of the real sets, ``--sim-pairs``
  random ones per simulated drive), registered from the given start (identity) and from a bad start (yaw
  of 90-180 degrees either way and up to 10 m); a result within 1 deg / 0.3 m is a *correct* result, one
  outside is a *wrong pose* (which the verdict should reject as well);
* different places: pairs across sets (KITTI 00 x 02, simulated drives of other seeds or scenes, HDL-32E x
  KITTI, simulated x real), registered from identity and from a 180 degree start; the higher score of the two
  counts (a global search keeps the best-scoring hypothesis).

Every registration runs the default configuration on the raw scans (each scan preprocessed once); the scores
of every candidate are kept in ``--out``/verdict_cases.jsonl (rerunning continues from it) and the script
prints, per candidate, the acceptance of correct results, the rejection of different places and of wrong
poses per threshold, the best threshold, and saves the curves (``verdict_curve.png``).

Usage::

    python scripts/verdict_study.py --realdata ../shared/realdata --out /tmp/verdict
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

CANDIDATES = ("fit_0.5", "fit_0.3", "fit_1.0", "dense_fit_0.5", "inlier_ratio", "gamma_mean")


def scores(reg, res, src_pre, tgt_pre) -> dict[str, float]:
    """Every candidate score of one result."""
    from deepbbs_ros.core.verdict import fitness

    T = res.T_target_source
    tree = tgt_pre.polish_cloud.complete().tree
    out = {f"fit_{d}": fitness(res.source, tree, T, d) for d in (0.3, 0.5, 1.0)}
    out["dense_fit_0.5"] = fitness(src_pre.polish_cloud.points(), tree, T, 0.5)
    out["inlier_ratio"] = float(res.inlier_ratio)
    out["gamma_mean"] = float(np.mean(res.gamma))
    if getattr(res, "score", None) is not None:
        out["score"] = float(res.score)
    return out


def plan(sets: dict, args, rng: np.random.Generator) -> list[dict]:
    cases = []
    for name, frames in sets.items():
        pairs = study_frames.true_pairs(frames, args.max_dist)
        if name.startswith("sim") and len(pairs) > args.sim_pairs:
            pairs = [pairs[k] for k in sorted(rng.choice(len(pairs), args.sim_pairs, replace=False))]
        for i, j, _, d in pairs:
            yaw = float(rng.uniform(90, 180) * rng.choice([-1, 1]))
            phi, r = rng.uniform(0, 2 * np.pi), rng.uniform(0, 10)
            for start in ([0.0, 0.0, 0.0], [yaw, r * np.cos(phi), r * np.sin(phi)]):
                cases.append({"kind": "true", "src": [name, i], "tgt": [name, j], "dist": d, "start": start})
    names = list(sets)
    cross = [(a, b) for a in names for b in names if a != b and not (a.startswith("sim") and b.startswith("sim")
             and a.split("_")[-1] == b.split("_")[-1])]
    quota = {("kitti", "kitti"): args.neg_real, ("sim", "sim"): args.neg_sim, ("hdl32", "kitti"): 6,
             ("kitti", "sim"): 6, ("sim", "kitti"): 6, ("hdl32", "sim"): 3}
    for (ka, kb), n in quota.items():
        pool = [(a, b) for a, b in cross if a.startswith(ka) and b.startswith(kb)]
        if not pool:
            continue
        for k in range(n):
            a, b = pool[int(rng.integers(len(pool)))]
            i, j = int(rng.integers(len(sets[a]))), int(rng.integers(len(sets[b])))
            for start in ([0.0, 0.0, 0.0], [180.0, 0.0, 0.0]):
                cases.append({"kind": "different", "src": [a, i], "tgt": [b, j], "dist": float("nan"),
                              "start": start, "pair": f"{ka}{kb}{k}"})
    order = rng.permutation(len(cases))  # a run cut short still holds every kind of case
    return [cases[k] for k in order]


def collect(args) -> list[dict]:
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "verdict_cases.jsonl"
    done = [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []
    sets = study_frames.all_sets(Path(args.realdata), Path(args.cache), args.drives_per_scene)
    cases = plan(sets, args, np.random.default_rng(args.seed))
    if len(done) >= len(cases):
        return done
    reg = DeepBBSRegistration(Config(), weights=args.weights)
    reg.warmup()
    pre: dict = {}

    def prep(key):
        k = tuple(key)
        if k not in pre:
            pre[k] = reg.preprocess(sets[k[0]][k[1]][0])
        return pre[k]

    with path.open("a") as fh:
        for n, case in enumerate(cases):
            if n < len(done):
                continue
            s, t = prep(case["src"]), prep(case["tgt"])
            P = study_frames.yaw_shift(case["start"][0], np.array(case["start"][1:]))
            t0 = time.perf_counter()
            res = reg.register(s, t, T_init=P)
            ms = (time.perf_counter() - t0) * 1e3
            rec = dict(case, ms=ms, **scores(reg, res, s, t))
            if case["kind"] == "true":
                T_gt = np.linalg.inv(sets[case["tgt"][0]][case["tgt"][1]][1]) @ sets[case["src"][0]][case["src"][1]][1]
                rot, tr = pair_errors(res.T_target_source, T_gt)
                rec.update(rot=float(rot), trans=float(tr), correct=bool(rot <= 1.0 and tr <= 0.3))
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            done.append(rec)
            if n % 20 == 0:
                print(f"{n}/{len(cases)} cases", flush=True)
    reg.close()
    return done


def groups(recs: list[dict], cand: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(scores of correct results, of different places (best of the starts per pair), of wrong poses)."""
    pos = np.array([r[cand] for r in recs if r["kind"] == "true" and r["correct"]])
    wrong = np.array([r[cand] for r in recs if r["kind"] == "true" and not r["correct"]])
    best: dict = {}
    for r in recs:
        if r["kind"] == "different":
            best[r["pair"]] = max(best.get(r["pair"], -1.0), r[cand])
    return pos, np.array(list(best.values())), wrong


def report(recs: list[dict], out: Path, candidates) -> None:
    n_true = sum(r["kind"] == "true" for r in recs)
    pos, neg, wrong = groups(recs, candidates[0])
    print(f"\n{n_true} true-pair registrations: {len(pos)} correct results, {len(wrong)} wrong poses; "
          f"{len(neg)} pairs of different places")
    by_set: dict = {}
    for r in recs:
        if r["kind"] == "true":
            k = r["src"][0].split("_")[0] if not r["src"][0].startswith("sim") else "sim_" + r["src"][0].split("_")[1]
            by_set.setdefault(k, []).append(r)
    rows = []
    for cand in candidates:
        pos, neg, wrong = groups(recs, cand)
        ths = np.unique(np.concatenate([pos, neg, wrong, [0.0, 1.0]]))
        bad = np.concatenate([neg, wrong])
        if len(pos) and len(bad) and bad.max() < pos.min():  # separated: the middle of the gap
            best = float(0.5 * (bad.max() + pos.min()))
        else:  # the threshold with the best min(acceptance, rejections)
            best = max(ths, key=lambda t: (min(np.mean(pos >= t), np.mean(neg < t),
                                                np.mean(wrong < t) if len(wrong) else 1.0), -t))
        rows.append((cand, best, np.mean(pos >= best), np.mean(neg < best),
                     np.mean(wrong < best) if len(wrong) else float("nan"),
                     float(pos.min()) if len(pos) else float("nan"), float(neg.max()) if len(neg) else float("nan")))
    print(f"\n{'score':>14} {'threshold':>9} {'correct accepted':>16} {'different rejected':>18} "
          f"{'wrong pose rejected':>19} {'min correct':>11} {'max different':>13}")
    for cand, th, a, b, c, lo, hi in rows:
        print(f"{cand:>14} {th:9.3f} {100 * a:15.1f}% {100 * b:17.1f}% {100 * c:18.1f}% {lo:11.3f} {hi:13.3f}")
    cand = candidates[0]  # fit_0.5: the configured score (registration.verdict_dist 0.5 m)
    pos, neg, wrong = groups(recs, cand)
    from deepbbs_ros.config import Config

    th = Config().registration.verdict_threshold
    print(f"\nat the configured threshold {th} of {cand}: correct accepted {100 * np.mean(pos >= th):.1f} % "
          f"({len(pos)}), different places rejected {100 * np.mean(neg < th):.1f} % ({len(neg)}), wrong poses "
          f"rejected {100 * np.mean(wrong < th) if len(wrong) else float('nan'):.1f} % ({len(wrong)})")
    print(f"\nrate curve of {cand}: threshold, correct accepted %, different places rejected %, wrong poses rejected %")
    for th in np.round(np.arange(0.0, 0.62, 0.02), 2):
        print(f"  {th:4.2f}  {100 * np.mean(pos >= th):6.1f}  {100 * np.mean(neg < th):6.1f}  "
              f"{100 * np.mean(wrong < th) if len(wrong) else float('nan'):6.1f}")
    print(f"\ncorrect results per set ({cand} min / p5 / median):")
    for k, rs in sorted(by_set.items()):
        v = np.array([r[cand] for r in rs if r["correct"]])
        if len(v):
            print(f"  {k:>14}: n={len(v):3d}  {v.min():.3f} / {np.percentile(v, 5):.3f} / {np.median(v):.3f}")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        th = np.linspace(0, 1, 201)
        for c in candidates[:4]:
            p, n, _ = groups(recs, c)
            axes[0].plot(th, [100 * np.mean(p >= x) for x in th], label=f"{c}: correct accepted")
            axes[0].plot(th, [100 * np.mean(n < x) for x in th], "--", label=f"{c}: different rejected")
        axes[0].set_xlabel("threshold")
        axes[0].set_ylabel("%")
        axes[0].legend(fontsize=6)
        axes[0].grid(alpha=0.3)
        bins = np.linspace(0, 1, 51)
        axes[1].hist(pos, bins, alpha=0.6, label="correct results")
        axes[1].hist(neg, bins, alpha=0.6, label="different places")
        if len(wrong):
            axes[1].hist(wrong, bins, alpha=0.6, label="wrong poses")
        axes[1].set_xlabel(cand)
        axes[1].legend()
        fig.tight_layout()
        fig.savefig(out / "verdict_curve.png", dpi=110)
        print(f"\nplot: {out / 'verdict_curve.png'}")
    except ImportError:
        pass


def main(argv: list[str] | None = None) -> int:
    here = Path(__file__).resolve().parents[1]
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--realdata", default=str(here.parent / "shared" / "realdata"))
    p.add_argument("--cache", default="/tmp/deepbbs_study/sim_frames.npz", help="simulated frames (npz)")
    p.add_argument("--out", default="/tmp/deepbbs_study/verdict")
    p.add_argument("--weights", default="")
    p.add_argument("--max-dist", type=float, default=15.0)
    p.add_argument("--drives-per-scene", type=int, default=2)
    p.add_argument("--sim-pairs", type=int, default=6, help="true pairs per simulated drive")
    p.add_argument("--neg-real", type=int, default=20, help="KITTI 00 x 02 pairs")
    p.add_argument("--neg-sim", type=int, default=24, help="pairs of two simulated drives")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--candidates", default=",".join(CANDIDATES))
    args = p.parse_args(argv)
    recs = collect(args)
    cands = [c for c in args.candidates.split(",") if c in recs[0]]
    report(recs, Path(args.out), cands)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
