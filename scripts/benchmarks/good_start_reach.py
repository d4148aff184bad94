#!/usr/bin/env python3
"""How far the good start's GICP may go: GICP from vouched starts on every family, judged by the verdict alone.

``register(..., good_start=True)`` runs GICP from the caller's start with GICP's own settings and takes its answer
whenever the good-start verdict accepts it (``registration.good_start_probability``), however far GICP moved
(core/good_start.py). This benchmark measures what that rests on. For every pair of the families benchmark's data
sets (``families.py``'s real and simulated sets, the same options) and for every start of ``--moves`` (the pair as
recorded, and the truth turned by a yaw of random sign and shifted in a random direction), it runs GICP with the
precision stage's settings (``registration.polish_*``: ``polish_max_iters`` iterations, no limit on the move) on the
scans' GICP clouds and records the iterations, how far GICP moved, its error against the truth (right: within 1 deg /
0.3 m; wrong: beyond 2 deg or 0.5 m) and the good-start verdict's probability of its answer.

Per set and kind of start (``identity`` / ``moved``) it prints the right and wrong answers and how many of each two
acceptance rules take: ``verdict`` (the shipped rule: converged within ``polish_max_iters``, probability at least
``good_start_probability``) and ``capped`` (the rule before it: converged within twice ``good_start_max_iters``,
within ``good_start_max_trans`` / ``good_start_max_rot_deg`` of the start at ``good_start_probability``, within
twice those at ``verdict_sure``); then the highest probability of a wrong answer and the lowest of a right one.
``good_start_reach.json`` and ``good_start_reach_cases.jsonl`` under ``--out``. ::

    python scripts/benchmarks/good_start_reach.py --quick --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 \\
        --pair PATH/TO/hdl32_pair --nuscenes PATH/TO/nuscenes_hdl32 --livox PATH/TO/livox_avia_loop --out results/reach
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402,F401  (puts the checkout first on sys.path)
import families  # noqa: E402
import registration as _reg  # noqa: E402

RULES = ("verdict", "capped")


def kind(rec: dict) -> str:
    """right (within 1 deg / 0.3 m), wrong (beyond 2 deg or 0.5 m) or between."""
    if rec["rot"] <= 1.0 and rec["trans"] <= 0.3:
        return "right"
    return "wrong" if rec["rot"] > families.WRONG_DEG or rec["trans"] > families.WRONG_M else "between"


def takes(rule: str, rec: dict, rc) -> bool:
    """Whether ``rule`` (:data:`RULES`) takes GICP's answer ``rec`` (a case)."""
    if not rec["applied"]:
        return False
    if rule == "verdict":
        return rec["prob"] >= rc.good_start_probability

    def within(k: float) -> bool:
        return rec["moved_m"] <= k * rc.good_start_max_trans and rec["moved_deg"] <= k * rc.good_start_max_rot_deg

    sure = max(rc.good_start_probability, rc.verdict_sure)
    return rec["iterations"] <= 2 * rc.good_start_max_iters and (
        (within(1.0) and rec["prob"] >= rc.good_start_probability) or (within(2.0) and rec["prob"] >= sure))


def run(sets: dict, moves: list[tuple[float, float]], args, path: Path) -> list[dict]:
    from deepbbs_ros.config import load_config
    from deepbbs_ros.core import verdict
    from deepbbs_ros.core.good_start import from_start, good_start_points
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors

    cfg = load_config(args.config).replace(**{"registration.exact_gicp": True, "registration.network_process": "off"})
    reg = DeepBBSRegistration(cfg, weights=args.weights)
    rc = cfg.registration
    rng = np.random.default_rng(args.seed)
    out = []
    with path.open("w") as fh:
        for name, s in sets.items():
            fr = s["frames"]
            for i, j in s["pairs"]:
                T_gt = np.linalg.inv(fr[j][1]) @ fr[i][1]
                src, tgt = (reg.preprocess(np.asarray(fr[k][0], np.float32)[:, :3], lazy=True) for k in (i, j))
                spc, tpc = src.polish_cloud.complete(1), tgt.polish_cloud.complete(1)
                pts = good_start_points(spc, rc)
                for yaw, shift in moves:
                    phi = rng.uniform(0, 2 * np.pi)
                    T0 = (_reg.yaw_shift(yaw * rng.choice([-1, 1]), shift * np.cos(phi), shift * np.sin(phi)) @ T_gt
                          if yaw or shift else np.eye(4))
                    pol = from_start(spc, tpc, T0, rc)
                    rot, tr = pair_errors(pol.T_target_source, T_gt)
                    prob = verdict.probability(pts, pol.T_target_source, tpc, rc.verdict_dist, "good_start") \
                        if pol.applied else 0.0
                    rec = {"set": name, "i": int(i), "j": int(j), "start": "identity" if not (yaw or shift) else
                           f"{yaw:g} deg / {shift:g} m", "applied": bool(pol.applied),
                           "iterations": int(pol.iterations), "moved_m": pol.delta_trans_m,
                           "moved_deg": pol.delta_rot_deg, "rot": float(rot), "trans": float(tr), "prob": float(prob)}
                    fh.write(json.dumps(rec) + "\n")
                    out.append(rec)
            print(f"{name}: {len(s['pairs'])} pairs", flush=True)
    reg.close()
    return out


def summarise(recs: list[dict], rc) -> dict:
    cells: dict = defaultdict(lambda: defaultdict(int))
    for r in recs:
        k = kind(r)
        for key in ((r["set"], "identity" if r["start"] == "identity" else "moved"), ("all", "all")):
            cells[key][k] += 1
            for rule in RULES:
                cells[key][f"{rule}_{k}"] += takes(rule, r, rc)
    conv = [r for r in recs if r["applied"]]
    wrong = [r["prob"] for r in conv if kind(r) == "wrong"]
    right = [r["prob"] for r in conv if kind(r) == "right"]
    return {"cells": {f"{a} {b}": dict(v) for (a, b), v in cells.items()},
            "highest_wrong_probability": max(wrong, default=float("nan")),
            "lowest_right_probability": min(right, default=float("nan")),
            "right_under_threshold": sum(p < rc.good_start_probability for p in right)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    families.add_set_args(p)  # the families benchmark's data sets, read by its real_sets / sim_sets
    p.add_argument("--quick", action="store_true", help="5 simulated scans (the families benchmark's --quick sets)")
    p.add_argument("--moves", default="0:0,20:1.5,30:2,45:3,60:4",
                   help="starts: yaw deg:shift m, comma separated (0:0 = the pair as recorded)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--config", default=None, help="config YAML (default: the defaults)")
    p.add_argument("--weights", default="", help="checkpoint ('' = the shipped model)")
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="cache of the simulated scans")
    p.add_argument("--out", default="results/benchmarks", help="folder of good_start_reach.json")
    args = p.parse_args(argv)
    if args.quick:
        args.sim_frames = 5
    from deepbbs_ros.config import load_config

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    moves = [tuple(float(x) for x in m.split(":")) for m in args.moves.split(",")]
    sets = {**families.real_sets(args), **families.sim_sets(args)}
    recs = run(sets, moves, args, out / "good_start_reach_cases.jsonl")
    fig = summarise(recs, load_config(args.config).registration)
    print("set / start: right, wrong | taken right / wrong / between: " + ", ".join(RULES))
    for key, c in fig["cells"].items():
        print(f"  {key}: {c.get('right', 0)}, {c.get('wrong', 0)} | " + ", ".join(
            f"{rule} {c.get(rule + '_right', 0)} / {c.get(rule + '_wrong', 0)} / {c.get(rule + '_between', 0)}"
            for rule in RULES))
    print(f"highest probability of a wrong answer {fig['highest_wrong_probability']:.3f}, lowest of a right one "
          f"{fig['lowest_right_probability']:.3f} ({fig['right_under_threshold']} right ones under the threshold)")
    _common.write_json(out, "good_start_reach.json", {**fig, "settings": vars(args)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
