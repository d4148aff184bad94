#!/usr/bin/env python3
"""Raw sweeps and the deskew: what the per-point times buy a pairwise registration.

Figures (``deskew.json``, ``deskew.png`` under ``--out``): success and mean / p95 errors (on the pairs every
variant solves) of the shipped pipeline on held-out raw HDL-64E sweeps (test seeds 90000 + i, every scene type;
sources every ``--stride`` frames, target = the last frame within 5 m, identity start), four ways: each scan
deskewed with its stream's velocity (``core.deskew.StreamDeskew``, the default), raw as they are, both deskewed
with the pair's own mean motion, and compensated with the true poses (the ceiling); GICP from identity on the raw
sweeps beside them; and the time the stream deskew adds per scan.

    python scripts/benchmarks/deskew.py --drives-per-scene 1 --threads 1 --out results/benchmarks
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--drives-per-scene", type=int, default=3)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--stride", type=int, default=10)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--weights", default="")
    p.add_argument("--scenes", default=None, help="comma-separated scene types (default: all)")
    p.add_argument("--out", default="results/benchmarks", help="folder for deskew.json and deskew.png")
    args = p.parse_args(argv)

    import numpy as np
    import torch  # after deepbbs_ros (module top), which sets OMP_WAIT_POLICY first

    from deepbbs_ros.baselines import SmallGicpRegistration
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors
    from deepbbs_ros.sim import SCENES, DriveSimulator
    from deepbbs_ros.train.cache import TEST_SEED_BASE

    torch.set_num_threads(args.threads)
    cfg = Config().replace(**{"registration.threads": args.threads, "registration.polish_threads": args.threads})
    reg = DeepBBSRegistration(cfg, weights=args.weights)
    reg.warmup()
    gicp = SmallGicpRegistration("gicp", cfg)
    from deepbbs_ros.core.deskew import StreamDeskew
    from deepbbs_ros.core.preprocess import deskew

    variants = ("stream deskew", "raw", "pair deskew", "compensated", "gicp raw")
    rows: dict[str, list[tuple[str, float, float]]] = {k: [] for k in variants}
    deskew_ms, reasons = [], {}

    def streamed(sim, k):
        """Scan k preprocessed after scan k - 1 went through the same StreamDeskew (its velocity)."""
        stream = StreamDeskew(reg)
        prev = sim.scan_at(k - 1)
        stream.apply(reg.preprocess(prev.points, prev.point_times(), prev.stamp_ns))
        cur = sim.scan_at(k)
        pre = reg.preprocess(cur.points, cur.point_times(), cur.stamp_ns)
        t0 = time.perf_counter()
        pre = stream.apply(pre)
        deskew_ms.append((time.perf_counter() - t0) * 1e3)
        reasons[pre.deskew] = reasons.get(pre.deskew, 0) + 1
        return pre
    scenes = args.scenes.split(",") if args.scenes else list(SCENES)
    for scene in scenes:
        for d in range(args.drives_per_scene):
            seed = TEST_SEED_BASE + d * len(SCENES) + SCENES.index(scene)  # the model card's seed of this scene
            raw_sim = DriveSimulator(scene, seed, frames=args.frames)
            comp_sim = DriveSimulator(scene, seed, frames=args.frames, compensate=True)
            poses = [raw_sim.pose_at(k) for k in range(args.frames)]
            for s in range(1, args.frames, args.stride):
                far = [k for k in range(s + 1, args.frames)
                       if np.linalg.norm(poses[k][:3, 3] - poses[s][:3, 3]) <= cfg.eval.max_dist]
                if not far:
                    continue
                t = far[-1]
                T_gt = np.linalg.inv(poses[t]) @ poses[s]
                rs, rt = raw_sim.scan_at(s), raw_sim.scan_at(t)
                cs, ct = comp_sim.scan_at(s), comp_sim.scan_at(t)
                res = reg.register(streamed(raw_sim, s), streamed(raw_sim, t))
                rows["stream deskew"].append((scene, *pair_errors(res.T_target_source, T_gt)))
                first = reg.register(reg.preprocess(rs.points), reg.preprocess(rt.points))
                rows["raw"].append((scene, *pair_errors(first.T_target_source, T_gt)))
                dt = (rs.stamp_ns - rt.stamp_ns) * 1e-9  # the pair's own estimate as one twist for both
                res = reg.register(
                    reg.preprocess(deskew(rs.points, rs.point_times(), first.T_target_source, dt).astype("float32")),
                    reg.preprocess(deskew(rt.points, rt.point_times(), first.T_target_source, dt).astype("float32")))
                rows["pair deskew"].append((scene, *pair_errors(res.T_target_source, T_gt)))
                res = reg.register(reg.preprocess(cs.points), reg.preprocess(ct.points))
                rows["compensated"].append((scene, *pair_errors(res.T_target_source, T_gt)))
                g = gicp.align(gicp.preprocess(rs.points), gicp.preprocess(rt.points), None)
                rows["gicp raw"].append((scene, *pair_errors(g.T_target_source, T_gt)))
        print(f"  {scene}: done ({time.strftime('%H:%M:%S')})", file=sys.stderr)

    ok_rot, ok_tr = cfg.eval.success_rot_deg, cfg.eval.success_trans
    print(f"\n{len(rows['raw'])} held-out pairs, {args.drives_per_scene} drives per scene type, "
          f"success = within {ok_rot} deg / {ok_tr} m")
    print(f"{'variant':<14} {'scene':<10} {'pairs':>5} {'success':>8} {'rot mean':>9} {'trans mean':>11} "
          f"{'trans p95':>10}   (both-solve means: pairs every variant solves)")
    solved_all = None
    for rs_ in rows.values():
        ok = np.array([r < ok_rot and t < ok_tr for _, r, t in rs_])
        solved_all = ok if solved_all is None else solved_all & ok
    figures: dict = {"pairs": len(rows["raw"]), "variants": {}}
    for name, rs_ in rows.items():
        for scene in [*scenes, "all"]:
            sel = [k for k, row in enumerate(rs_) if scene == "all" or row[0] == scene]
            r = np.array([rs_[k][1] for k in sel])
            t = np.array([rs_[k][2] for k in sel])
            both = np.array([solved_all[k] for k in sel])
            succ = np.mean((r < ok_rot) & (t < ok_tr)) * 100
            figures["variants"].setdefault(name, {})[scene] = {
                "pairs": len(sel), "success_pct": succ, "rot_deg_mean": r[both].mean() if both.any() else None,
                "trans_m_mean": t[both].mean() if both.any() else None,
                "trans_m_p95": np.percentile(t[both], 95) if both.any() else None}
            print(f"{name:<14} {scene:<10} {len(sel):>5} {succ:>7.1f}% {r[both].mean():>8.4f}d "
                  f"{t[both].mean():>10.4f}m {np.percentile(t[both], 95):>9.4f}m")
    if deskew_ms:
        print(f"stream deskew per scan (velocity alignment + deskewed GICP cloud): "
              f"median {np.median(deskew_ms):.1f} ms, p95 {np.percentile(deskew_ms, 95):.1f} ms "
              f"({args.threads} thread(s)); outcomes {reasons}")
        figures["stream_deskew_ms"] = {"p50": np.median(deskew_ms), "p95": np.percentile(deskew_ms, 95)}
    out = Path(args.out)
    _common.write_json(out, "deskew.json", figures)
    plt = _common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    names = list(figures["variants"])
    vals = [figures["variants"][n]["all"]["trans_m_mean"] or np.nan for n in names]
    ax.bar(names, vals)
    ax.set_ylabel("mean translation error (m)")
    ax.set_title(f"{figures['pairs']} held-out raw sweep pairs, pairs every variant solves")
    ax.tick_params(axis="x", labelsize=8)
    _common.save(fig, out, "deskew.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
