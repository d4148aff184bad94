#!/usr/bin/env python3
"""What a training cache teaches: its pairs drawn as training draws them, and what the network makes of them.

    python scripts/mix_pairs_check.py runs/cache/mix_span_train --per-drive 20 --by mount    # the shipped model
    python scripts/mix_pairs_check.py runs/cache/mix_train --weights runs/mix_keep/model_best.pt   # and another

Per mount, sensor and place (each drive's ``meta``): how far apart its pairs are (quartiles and 90 %, the
distance of the two frames' ground-truth positions), whether their labels are right (GICP on the cached clouds
started at the ground truth: how far it moves, median and 90 %), and the network's one pass on them (the
training's forward pass, augmentation included): success within 1 deg / 0.3 m, median rotation error, the share of
pairs over 10 deg off and how much of the loss's rotation term those carry, and the rotation term's share of the
pose loss (rotation + ``train.trans_weight`` x translation, in the network's scaled units). Pairs are drawn with
``train.pair_balance`` from ``--set`` (default "distance"), ``--per-drive`` from each drive, seeded.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def pair_rows(drives, weights: list[str], per_drive: int, cfg, seed: int) -> tuple[list[str], list[dict]]:
    """One row per drawn pair: the drive's groups, the pair's distance, the label check and each model's errors."""
    import small_gicp
    import torch

    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors
    from deepbbs_ros.train.pairs import AugmentConfig, PairSampler, collate, inv_T

    names, models = [], []
    for w in weights:
        model = DeepBBSRegistration(cfg, weights=w or None).model.eval()
        names.append(Path(w).name if w else "shipped")
        models.append(model)
    aug = AugmentConfig.from_train(cfg.train, cfg.preprocess.num_points)
    rng = np.random.default_rng(seed)
    rows = []
    for d in drives:
        sampler = PairSampler([d], aug)
        sensor = d.meta.get("sensor", {})
        groups = {"mount": sensor.get("mount", "car"), "sensor": sensor.get("preset", "?"), "place": d.scene}
        for _ in range(per_drive):
            p = sampler.draw(rng)
            i, j = (int(x) for x in p.ref.split(":")[-1].split("->"))
            T = inv_T(d.T_world_lidar[j]) @ d.T_world_lidar[i]
            g = small_gicp.align(d.frame(j).astype(np.float64), d.frame(i).astype(np.float64), T,
                                 downsampling_resolution=0.1, max_correspondence_distance=0.5, max_iterations=30)
            src, tgt, _, _ = collate([p])
            errs = []
            with torch.no_grad():
                for m in models:
                    out = m(src, tgt)
                    est = np.eye(4)
                    est[:3, :3], est[:3, 3] = out.R[0].numpy(), out.t[0].numpy()
                    errs.append(pair_errors(est, p.T_target_source))
            rows.append({**groups, "dist": float(np.linalg.norm(T[:3, 3])), "label": pair_errors(g.T_target_source, T),
                         "errs": errs})
    return names, rows


def summary(rows: list[dict], names: list[str], scale: float, trans_weight: float) -> str:
    dist = np.array([r["dist"] for r in rows])
    lab = np.array([r["label"] for r in rows])
    q = np.percentile(dist, [25, 50, 75, 90])
    out = (f"n={len(rows):4d} | pairs {q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f} / {q[3]:.2f} m | label moved "
           f"{np.median(lab[:, 0]):.2f} deg {np.median(lab[:, 1]):.2f} m (90 %: {np.percentile(lab[:, 0], 90):.2f} / "
           f"{np.percentile(lab[:, 1], 90):.2f})")
    for k, name in enumerate(names):
        e = np.array([r["errs"][k] for r in rows])
        th = np.radians(e[:, 0])
        rot = 4.0 * (1.0 - np.cos(th))  # ||R_gt^T R - I||_F^2, the loss's rotation term
        trans = trans_weight * (scale * e[:, 1]) ** 2
        big = e[:, 0] > 10.0
        out += (f" | {name}: ok {100 * np.mean((e[:, 0] <= 1) & (e[:, 1] <= 0.3)):.0f} %, rot med "
                f"{np.median(e[:, 0]):.2f} deg, >10 deg {100 * big.mean():.0f} % carrying "
                f"{100 * rot[big].sum() / max(rot.sum(), 1e-12):.0f} % of the rotation term, rotation "
                f"{100 * rot.sum() / max(rot.sum() + trans.sum(), 1e-12):.0f} % of the pose loss")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cache", nargs="+", help="training cache folder(s) (deepbbs-train cache --out)")
    ap.add_argument("--weights", action="append", default=[],
                    help="checkpoint(s) compared with the shipped model (repeatable)")
    ap.add_argument("--per-drive", type=int, default=12, help="pairs drawn from each drive")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="config override, e.g. train.pair_balance=pairs (default: distance, trans_weight 5)")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--by", default="mount,sensor,place", help="groups reported, comma-separated")
    args = ap.parse_args(argv)

    import torch

    from deepbbs_ros.config import Config
    from deepbbs_ros.train.cache import load_cache

    torch.set_num_threads(1)
    sets = {"train.pair_balance": "distance", "train.trans_weight": 5.0}
    for kv in args.set:
        k, v = kv.split("=", 1)
        sets[k] = v if k == "train.pair_balance" else float(v)
    cfg = Config().replace(**sets).validate()
    names, rows = pair_rows(load_cache(args.cache), ["", *args.weights], args.per_drive, cfg, args.seed)
    for key in [k.strip() for k in args.by.split(",") if k.strip()]:
        for value in sorted({str(r[key]) for r in rows}):
            sel = [r for r in rows if str(r[key]) == value]
            print(f"{key}={value:12s} " + summary(sel, names, cfg.model.scale, cfg.train.trans_weight))
    print(f"{'all':19s} " + summary(rows, names, cfg.model.scale, cfg.train.trans_weight))
    return 0


if __name__ == "__main__":
    sys.exit(main())
