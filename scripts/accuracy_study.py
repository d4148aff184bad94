#!/usr/bin/env python3
"""Where do DeepBBS++'s pair errors come from? An inference-only accuracy study on held-out pairs.

Protocol (CONVENTIONS.md, as ``deepbbs-train evaluate``): simulated HDL-64 drives with motion
distortion from the *test* seeds (90000 + i, scene ``SCENES[i % 4]``), sources every ``stride``
frames, target = the last frame within 5 m, no initial guess; optionally an extra random yaw of up
to ``--yaw-deg`` on every source. Every frame is preprocessed once (``preprocess``: 1000 FPS points
plus the voxelised non-ground cloud ``dense_points``) and cached in ``--cache`` (npz).

For every pair the deep stage (network iterations, no refinement) runs once; each refinement
variant then starts from the deep estimate (``T_init``, ``registration.deep = false``), so the
variants differ only in the refinement. ``oracle-*`` variants start the refinement from the
ground truth: their error is the accuracy floor of that refinement (sampling, motion distortion),
independent of its basin. Errors are split into the along-track (direction of travel), cross-track
and vertical components of the translation error, in the target frame.

Usage (one core, one torch thread, next to a training run)::

    OMP_NUM_THREADS=1 taskset -c 1 python scripts/accuracy_study.py \
        --weights runs/default/model_latest.pt --drives-per-scene 2 --variants current,dense

Prints one table per yaw setting: variant x scene, mean/median/p95 errors, success, refine time.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import deepbbs_ros  # noqa: F401  (first: sets OMP_WAIT_POLICY=PASSIVE before torch loads, as the CLIs do)

VARIANTS: dict[str, dict] = {
    # the paper's DeepBBS++ refinement on the 1000 sampled points (before this study: the default)
    "paper": {"registration.dense_refine": False, "registration.refine_alpha_start": 1.0,
              "registration.refine_temperature": 0.0, "registration.refine_overlap_crop": False},
    # coarse-to-fine alpha on the 1000 points only
    "anneal": {"registration.dense_refine": False, "registration.refine_temperature": 0.0,
               "registration.refine_overlap_crop": False},
    # the shipped configuration (whatever the current defaults are)
    "current": {},
    # a final refinement on the dense (voxelised non-ground) cloud, after the 1000-point one
    "dense": {"registration.dense_refine": True},
    # (the GICP precision stage needs the whole raw scan, which this study's frame cache does not keep:
    # it is measured by scripts/pipeline_study.py)
}


def build_frames(args, cfg) -> dict:
    """Simulate the needed frames of the held-out drives once; returns the cache dict."""
    from deepbbs_ros.core.preprocess import preprocess
    from deepbbs_ros.sim import SCENES
    from deepbbs_ros.sim.simulator import DriveSimulator
    from deepbbs_ros.train.cache import TEST_SEED_BASE, Drive
    from deepbbs_ros.train.pairs import protocol_pairs

    path = Path(args.cache)
    if path.is_file():
        data = dict(np.load(path, allow_pickle=True))
        return data["frames"].item()
    pcfg = cfg.preprocess.__class__(**{**cfg.preprocess.__dict__, "dense_max_points": 0})  # keep every voxel
    frames: dict = {"pairs": []}
    scenes = list(SCENES)
    for d in range(args.drives_per_scene * len(scenes)):
        seed, scene = TEST_SEED_BASE + d, scenes[d % len(scenes)]
        sim = DriveSimulator(scene, seed, frames=args.frames, motion_distortion=not args.no_distortion)
        poses = np.stack([sim.pose_at(k) for k in range(args.frames)])
        fake = Drive(name=f"{scene}_{seed}", points=np.zeros((0, 3), np.float32),
                     offsets=np.zeros(args.frames + 1, np.int64), T_world_lidar=poses,
                     stamps_ns=np.zeros(args.frames, np.int64), meta={"scene": scene})
        for i, j in protocol_pairs(fake, args.stride, 5.0):
            for k in (i, j):
                key = f"{seed}_{k}"
                if key not in frames:
                    r = preprocess(sim.scan_at(k).points, pcfg)
                    frames[key] = (r.points, r.dense_points, poses[k])
            frames["pairs"].append((scene, seed, i, j))
        print(f"drive {seed} {scene}: {len(frames['pairs'])} pairs so far", flush=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, frames=np.array(frames, dtype=object))
    return frames


def subsample(dense: np.ndarray, cap: int, seed: int) -> np.ndarray:
    from deepbbs_ros.core.preprocess import dense_subsample

    return dense_subsample(dense, cap, seed=seed)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    g = p.add_argument_group("data")
    g.add_argument("--drives-per-scene", type=int, default=2)
    g.add_argument("--frames", type=int, default=60)
    g.add_argument("--stride", type=int, default=10)
    g.add_argument("--yaw-deg", type=float, default=0.0, help="extra random source yaw (0 = plain pairs only)")
    g.add_argument("--cache", default="runs/accuracy_study/frames.npz")
    g.add_argument("--no-distortion", action="store_true", help="de-skewed scans (simulator motion_distortion off)")
    g = p.add_argument_group("method")
    g.add_argument("--dense-cap", type=int, default=-1, help="dense points per cloud (-1: preprocess.dense_max_points)")
    g.add_argument("--weights", default="runs/default/model_latest.pt")
    g.add_argument("--variants", default="paper,current", help=f"comma list of {', '.join(VARIANTS)} or "
                   "NAME:key=val;key=val (registration.* overrides), oracle-NAME starts at the ground truth")
    g.add_argument("--gicp", action="store_true", help="also small_gicp GICP on the dense clouds, from identity and GT")
    g.add_argument("--set", action="append", default=[], help="registration.key=value for every variant")
    g = p.add_argument_group("output")
    g.add_argument("--json", default="", help="write every pair's errors here")
    g.add_argument("--show-fail", type=int, default=0, help="print the N worst pairs of each variant")
    args = p.parse_args(argv)

    import torch
    from rich.console import Console
    from rich.table import Table

    from deepbbs_ros.config import Config
    from deepbbs_ros.core.preprocess import PreprocessResult
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors
    from deepbbs_ros.train.pairs import inv_T, make_T, transform, yaw_matrix

    torch.set_num_threads(1)
    cfg = Config()
    for s in args.set:
        k, v = s.split("=", 1)
        cfg = cfg.replace(**{k: type(getattr(cfg.registration, k.split(".")[1]))(json.loads(v))})
    frames = build_frames(args, cfg)
    deep = DeepBBSRegistration(cfg.replace(**{"registration.refine": False}), weights=args.weights, device="cpu")
    shared = {"model": deep.model, "device": "cpu"}
    regs = {}
    for spec in args.variants.split(","):
        name, _, over = spec.partition(":")
        base = name.removeprefix("oracle-")
        kv = dict(VARIANTS.get(base, {}))
        for item in filter(None, over.split(";")):
            k, v = item.split("=", 1)
            kv[k] = type(getattr(cfg.registration, k.split(".")[1]))(json.loads(v))
        c = deep.config.replace(**{"registration.deep": False, "registration.refine": True, **kv})
        regs[spec] = DeepBBSRegistration(c, **shared)

    variants = [("plain", 0.0)] + ([("yaw", args.yaw_deg)] if args.yaw_deg > 0 else [])
    rng = np.random.default_rng([90000, 45])
    recs = []
    t_start = time.perf_counter()
    for scene, seed, i, j in frames["pairs"]:
        ps, ds, Ts, *_ = frames[f"{seed}_{i}"]  # older caches carry a fourth item (ground points), unused
        pt, dt_, Tt, *_ = frames[f"{seed}_{j}"]
        cap = cfg.preprocess.dense_max_points if args.dense_cap < 0 else args.dense_cap
        ds, dt_ = subsample(ds, cap, cfg.preprocess.seed), subsample(dt_, cap, cfg.preprocess.seed)
        T_gt0 = inv_T(Tt) @ Ts
        for variant, ydeg in variants:
            A = make_T(yaw_matrix(np.deg2rad(rng.uniform(-ydeg, ydeg))), np.zeros(3)) if ydeg else np.eye(4)
            T_gt = T_gt0 @ inv_T(A)
            src = PreprocessResult(transform(ps, A), None, 0, 0, 0, dense_points=transform(ds, A))
            tgt = PreprocessResult(pt, None, 0, 0, 0, dense_points=dt_)
            t0 = time.perf_counter()
            res = deep.register(src, tgt, preprocessed=True)
            deep_ms = (time.perf_counter() - t0) * 1e3
            outs = {"deep": (res.T_target_source, deep_ms, res.iterations)}
            polish_ms: dict[str, float] = {}
            polish_ok: dict[str, bool] = {}
            for name, reg in regs.items():
                T0 = T_gt if name.startswith("oracle-") else res.T_target_source
                t0 = time.perf_counter()
                r2 = reg.register(src, tgt, preprocessed=True, T_init=T0)
                outs[name] = (r2.T_target_source, (time.perf_counter() - t0) * 1e3, r2.iterations)
                polish_ms[name] = r2.timings_ms.get("polish", 0.0)
                polish_ok[name] = r2.polish in ("ok", "")
            # along-track axis: the direction of travel between the two frames (target frame)
            along = T_gt0[:3, 3] / max(np.linalg.norm(T_gt0[:3, 3]), 1e-6)
            up = np.array([0.0, 0.0, 1.0])
            cross = np.cross(up, along)
            cross /= max(np.linalg.norm(cross), 1e-6)
            if args.gicp:
                import small_gicp

                for gname, T0 in (("gicp", np.eye(4)), ("oracle-gicp", T_gt)):
                    t0 = time.perf_counter()
                    g = small_gicp.align(dt_.astype(np.float64), transform(ds, A).astype(np.float64), T0,
                                         registration_type="GICP", num_threads=1, max_correspondence_distance=1.0)
                    outs[gname] = (g.T_target_source, (time.perf_counter() - t0) * 1e3, {"gicp": g.iterations})
            for name, (T, ms, its) in outs.items():
                r, t = pair_errors(T, T_gt)
                e = T[:3, 3] - T_gt[:3, 3]
                recs.append({"variant": variant, "method": name, "scene": scene, "seed": int(seed), "i": int(i),
                             "j": int(j), "rot": float(r), "trans": float(t), "along": float(e @ along),
                             "cross": float(e @ cross), "up": float(e[2]), "ms": ms, "iters": dict(its),
                             "dist": float(np.linalg.norm(T_gt0[:3, 3])), "polish_ms": polish_ms.get(name, 0.0),
                             "polish_ok": polish_ok.get(name, True)})
    print(f"{len(frames['pairs'])} pairs in {time.perf_counter() - t_start:.0f} s (machine shared: times disturbed)")
    console = Console(width=150)
    methods = ["deep", *regs] + (["gicp", "oracle-gicp"] if args.gicp else [])
    for variant, _ in variants:
        tab = Table(title=f"{variant}: held-out pairs, refinement variants from the deep estimate")
        for col in ("method", "scene", "n", "MAE rot [deg]", "MTE [m]", "med t [m]", "p95 t [m]", "|along| [m]",
                    "|cross| [m]", "|up| [m]", "success [%]", "ms", "polish ms", "polish kept [%]", "iters"):
            tab.add_column(col, justify="left" if col in ("method", "scene") else "right")
        for m in methods:
            for sc in [*sorted({r["scene"] for r in recs}), "all"]:
                sel = [r for r in recs if r["variant"] == variant and r["method"] == m and sc in ("all", r["scene"])]
                if not sel:
                    continue
                R = np.array([r["rot"] for r in sel])
                Tt = np.array([r["trans"] for r in sel])
                succ = np.mean((R <= 1.0) & (Tt <= 0.3))
                it = np.mean([sum(r["iters"].values()) for r in sel])
                tab.add_row(m, sc, str(len(sel)), f"{R.mean():.4f}", f"{Tt.mean():.4f}", f"{np.median(Tt):.4f}",
                            f"{np.percentile(Tt, 95):.3f}", f"{np.mean([abs(r['along']) for r in sel]):.3f}",
                            f"{np.mean([abs(r['cross']) for r in sel]):.3f}",
                            f"{np.mean([abs(r['up']) for r in sel]):.3f}", f"{100 * succ:.1f}",
                            f"{np.median([r['ms'] for r in sel]):.0f}",
                            f"{np.median([r['polish_ms'] for r in sel]):.1f}",
                            f"{100 * np.mean([r['polish_ok'] for r in sel]):.0f}", f"{it:.1f}", end_section=sc == "all")
        console.print(tab)
        for m in methods if args.show_fail else []:
            worst = sorted((r for r in recs if r["variant"] == variant and r["method"] == m),
                           key=lambda r: -r["trans"])[: args.show_fail]
            for r in worst:
                console.print(f"  {m:>10} {r['scene']:>9} {r['seed']} {r['i']:>2}->{r['j']:>2} dist {r['dist']:.1f} m "
                              f"rot {r['rot']:.3f} t {r['trans']:.3f} (along {r['along']:+.3f} cross "
                              f"{r['cross']:+.3f} up {r['up']:+.3f})")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(recs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
