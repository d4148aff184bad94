#!/usr/bin/env python3
"""Raw pair -> T_target_source: accuracy and speed of DeepBBS++ presets against small_gicp GICP (issues 10, 11).

Every registration starts from two raw scans (preprocessing of both included in the time, as a user
calls ``DeepBBSRegistration.register(raw_source, raw_target)``), from identity, on:

* held-out simulated pairs (test seeds 90000+, every scene type, sweeps compensated to their stamps, the
  pair protocol: sources every ``--stride`` frames, target = the last frame within 5 m);
* the real KITTI scans in ``--realdata``/kitti/* (pairs up to 5 m apart) and the real HDL-32E pair
  (read from the shared folder, never copied);

each as it comes and with the source moved by a random yaw up to 45 deg and shift up to 5 m (the wide
basin). Printed per set: success (<= 1 deg and <= 0.3 m), mean rotation / translation error on the pairs
that both the method and GICP solve (beside GICP's on the same pairs), p50 / p95 runtime and the p50
ratio to GICP's p50 in the same run.

    python scripts/pipeline_study.py [--threads 2] [--drives-per-scene 2] [--presets default,paper,fast]

Run it with nothing else on the machine: the times are wall-clock.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import deepbbs_ros  # noqa: F401  (first: sets OMP_WAIT_POLICY=PASSIVE before torch loads, as the CLIs do)

PRESETS = {
    # the shipped defaults: 512 points, 2 deep passes, GICP precision stage
    "default": {},
    # the defaults before issue 10's last session: a second voxel grid for the network's points, torch's own
    # thread count (the script sets --threads), the network in this process
    "old": {"preprocess.share_grid": False, "registration.threads": 0, "registration.network_process": "off"},
    # one deep pass (saves ~14 ms; 47 of 48 simulated pairs from 45 deg / 5 m instead of 48)
    "1pass": {"registration.max_deep_iters": 1},
    # the network in this process instead of its worker process
    "in-process": {"registration.network_process": "off"},
    # config/deepbbs_ros_fast.yaml
    "fast": {"preprocess.num_points": 256, "registration.max_deep_iters": 1},
    # the paper's pipeline as shipped before (1000 points, up to 5 deep passes, SoftBBS refinement, no GICP)
    "paper": {"preprocess.num_points": 1000, "registration.max_deep_iters": 5, "registration.refine": True,
              "registration.polish": "none"},
}


def build_pairs(args) -> list[dict]:
    from deepbbs_ros.datasets import open_source
    from deepbbs_ros.datasets.pcd import read_pcd_points
    from deepbbs_ros.replay.runner import iter_pairs, random_perturbation
    from deepbbs_ros.sim import SCENES
    from deepbbs_ros.sim.simulator import DriveSimulator
    from deepbbs_ros.train.cache import TEST_SEED_BASE, Drive
    from deepbbs_ros.train.pairs import inv_T, protocol_pairs

    out = []
    seeds = range(TEST_SEED_BASE, TEST_SEED_BASE + args.drives_per_scene * len(SCENES))
    for i, seed in enumerate(seeds):
        scene = SCENES[i % len(SCENES)]
        sim = DriveSimulator(scene, seed, frames=args.frames, compensate=True)
        poses = np.stack([sim.pose_at(k) for k in range(args.frames)])
        fake = Drive(name="plan", points=np.zeros((0, 3), np.float32), offsets=np.zeros(args.frames + 1, np.int64),
                     T_world_lidar=poses, stamps_ns=np.zeros(args.frames, np.int64), meta={})
        cache: dict[int, np.ndarray] = {}
        for a, b in protocol_pairs(fake, args.stride, 5.0):
            for k in (a, b):
                if k not in cache:
                    cache[k] = sim.scan_at(k).points.astype(np.float32)
            out.append({"set": "sim-" + scene, "src": cache[a], "tgt": cache[b], "T_gt": inv_T(poses[b]) @ poses[a]})
    real = Path(args.realdata)
    for seq in sorted((real / "kitti").glob("*")) if (real / "kitti").is_dir() else []:
        scans = list(open_source(seq))
        for s, t in iter_pairs(scans, 1, 5.0):
            out.append({"set": "kitti", "src": s.points.astype(np.float32), "tgt": t.points.astype(np.float32),
                        "T_gt": inv_T(t.T_world_lidar) @ s.T_world_lidar})
    pair = real / "hdl32_pair"
    if pair.is_dir():
        out.append({"set": "hdl32", "src": read_pcd_points(pair / "251371071.pcd")[0].astype(np.float32),
                    "tgt": read_pcd_points(pair / "251370668.pcd")[0].astype(np.float32),
                    "T_gt": np.loadtxt(pair / "relative.txt").reshape(4, 4)})
    rng = np.random.default_rng(args.seed)
    for p in out:
        p["A"] = random_perturbation(rng, 45.0, 5.0)
    return out


def main(argv: list[str] | None = None) -> int:
    here = Path(__file__).resolve().parent.parent
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--presets", default="default,fast,paper", help=f"comma list of {', '.join(PRESETS)}")
    p.add_argument("--realdata", default=str(here.parent / "shared" / "realdata"))
    p.add_argument("--drives-per-scene", type=int, default=2)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--stride", type=int, default=10)
    p.add_argument("--threads", type=int, default=2, help="torch and small_gicp threads")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--weights", default="", help="checkpoint ('' = the shipped model)")
    args = p.parse_args(argv)

    import torch
    from rich.console import Console
    from rich.table import Table

    from deepbbs_ros.baselines import SmallGicpRegistration
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors
    from deepbbs_ros.train.pairs import inv_T, transform

    torch.set_num_threads(args.threads)
    cfg = Config().replace(**{"eval.threads": args.threads, "registration.polish_threads": args.threads})
    names = [n.strip() for n in args.presets.split(",") if n.strip()]
    regs, base = {}, None
    for n in names:
        r = DeepBBSRegistration(cfg.replace(**PRESETS[n]), weights=args.weights,
                                **({"model": base.model} if base else {}))
        r.warmup()
        regs[n], base = r, base or r
    gicp = SmallGicpRegistration("gicp", cfg)
    t0 = time.perf_counter()
    pairs = build_pairs(args)
    print(f"{len(pairs)} pairs built in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    rows = []
    for pert in (False, True):
        for p_ in pairs:
            src = transform(p_["src"], p_["A"]).astype(np.float32) if pert else p_["src"]
            T_gt = p_["T_gt"] @ inv_T(p_["A"]) if pert else p_["T_gt"]
            t = time.perf_counter()
            T = gicp.register(src, p_["tgt"]).T_target_source
            rows.append({"set": p_["set"], "pert": pert, "m": "gicp", "ms": (time.perf_counter() - t) * 1e3,
                         **dict(zip(("r", "t"), pair_errors(T, T_gt))), "id": id(p_)})
            for n, reg in regs.items():
                t = time.perf_counter()
                res = reg.register(src, p_["tgt"])
                rows.append({"set": p_["set"], "pert": pert, "m": n, "ms": (time.perf_counter() - t) * 1e3,
                             **dict(zip(("r", "t"), pair_errors(res.T_target_source, T_gt))), "id": id(p_),
                             "stages": res.timings_ms})

    def ok(x):
        return x["r"] <= 1.0 and x["t"] <= 0.3

    console = Console(width=140)
    sets = [("sim (all scenes)", lambda s: s.startswith("sim"))]
    sets += [(s, lambda x, s=s: x == s) for s in sorted({p_["set"] for p_ in pairs})]
    for pert in (False, True):
        tab = Table(title="raw pairs from identity" + (", source moved by up to 45 deg / 5 m" if pert else ""))
        for col in ("set", "method", "pairs", "success %", "both ok", "rot deg", "GICP rot", "trans m", "GICP trans",
                    "p50 ms", "p95 ms", "p50 / GICP"):
            tab.add_column(col, justify="left" if col in ("set", "method") else "right")
        for label, f in sets:
            G = {x["id"]: x for x in rows if x["m"] == "gicp" and x["pert"] == pert and f(x["set"])}
            g50 = np.median([x["ms"] for x in G.values()]) if G else float("nan")
            for m in ["gicp", *names]:
                R = [x for x in rows if x["m"] == m and x["pert"] == pert and f(x["set"])]
                if not R:
                    continue
                both = [(x, G[x["id"]]) for x in R if ok(x) and ok(G[x["id"]])]

                def mean(v):
                    return f"{np.mean(v):.4f}" if v else "-"

                ms = [x["ms"] for x in R]
                tab.add_row(label, m, str(len(R)), f"{100 * np.mean([ok(x) for x in R]):.1f}", str(len(both)),
                            mean([a["r"] for a, _ in both]), mean([b["r"] for _, b in both]),
                            mean([a["t"] for a, _ in both]), mean([b["t"] for _, b in both]),
                            f"{np.median(ms):.0f}", f"{np.percentile(ms, 95):.0f}",
                            f"{np.median(ms) / g50:.2f}", end_section=m == names[-1])
        console.print(tab)
    stages = Table(title="stage medians (ms) of DeepBBSRegistration.register on the raw pairs, every set and start")
    names_st = ["preprocess", "embed", "match", "solve", "polish", "deskew", "total"]
    for col in ("preset", *names_st):
        stages.add_column(col, justify="left" if col == "preset" else "right")
    for n in names:
        st = [x["stages"] for x in rows if x["m"] == n]
        stages.add_row(n, *[f"{np.median([s.get(k, 0.0) for s in st]):.1f}" for k in names_st])
    console.print(stages)
    load = Path("/proc/loadavg").read_text().split()[0] if Path("/proc/loadavg").exists() else "?"
    console.print(f"threads={args.threads} load average (1 min) after: {load}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
