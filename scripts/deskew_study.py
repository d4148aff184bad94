#!/usr/bin/env python3
"""What the per-point times buy a pairwise registration: raw sweeps deskewed with the stream's velocity
(``core.deskew.StreamDeskew``: each scan aligned to the one before it), raw sweeps as they are, raw
sweeps deskewed with the pair's own mean motion, and the same sweeps compensated to their stamps with
the true poses (the ceiling), against the ground truth.

    python scripts/deskew_study.py [--drives-per-scene 3] [--frames 60] [--stride 10] [--threads 1]

Held-out simulated HDL-64E drives (test seeds 90000 + i, the model card's protocol: sources every
``stride`` frames, target = the last frame within 5 m, identity start), every scene type. Each pair is
registered by the default pipeline (DeepBBS++ + GICP precision stage) four ways; GICP from identity on
the raw sweeps is the baseline. Prints success and mean / p95 errors on the pairs every variant solves,
and the time the stream deskew adds per scan.
"""

from __future__ import annotations

import argparse
import sys
import time

import deepbbs_ros  # noqa: F401  (first: sets OMP_WAIT_POLICY=PASSIVE before torch loads, as the CLIs do)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--drives-per-scene", type=int, default=3)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--stride", type=int, default=10)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--weights", default="")
    p.add_argument("--scenes", default=None, help="comma-separated scene types (default: all)")
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
    for name, rs_ in rows.items():
        for scene in [*scenes, "all"]:
            sel = [k for k, row in enumerate(rs_) if scene == "all" or row[0] == scene]
            r = np.array([rs_[k][1] for k in sel])
            t = np.array([rs_[k][2] for k in sel])
            both = np.array([solved_all[k] for k in sel])
            succ = np.mean((r < ok_rot) & (t < ok_tr)) * 100
            print(f"{name:<14} {scene:<10} {len(sel):>5} {succ:>7.1f}% {r[both].mean():>8.4f}d "
                  f"{t[both].mean():>10.4f}m {np.percentile(t[both], 95):>9.4f}m")
    if deskew_ms:
        print(f"stream deskew per scan (velocity alignment + deskewed GICP cloud): "
              f"median {np.median(deskew_ms):.1f} ms, p95 {np.percentile(deskew_ms, 95):.1f} ms "
              f"({args.threads} thread(s)); outcomes {reasons}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
