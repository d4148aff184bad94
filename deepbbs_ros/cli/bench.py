"""``deepbbs-bench``: time DeepBBS++ on one pair of clouds, per stage.

    deepbbs-bench [--weights PATH] [--device auto] [--repeats 30] [--threads N] [--scene urban]

Two measurements, each the median and 95th percentile over ``--repeats`` runs after warm-up:

1. registration of one pair of preprocessed ``preprocess.num_points``-point clouds (no dense scans, so no
   GICP precision stage; goal: <= 60 ms median);
2. preprocessing plus registration of two raw ~120k-point scans (goal: <= 100 ms median).

The scans come from the LiDAR simulator (two consecutive frames, HDL-64-like) with their ground
truth, so the table also shows the registration error. The shipped model is used when present,
else a randomly initialised network of the default size (timings are the same; the errors are not
meaningful then): the output says which. Other processes on the machine disturb the numbers: the
load average is printed with them.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from deepbbs_ros.cli.common import cli_entry

# embed / match / solve run in the network process when there is one (registration.network_process), overlapping
# "preprocess"; "network_wait" is what register() then waited for them; "total" is the wall time of register()
STAGES = ("preprocess", "embed", "match", "solve", "network_wait", "refine", "polish", "total")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deepbbs-bench", description=__doc__.split("\n\n")[0])
    g = parser.add_argument_group("model")
    g.add_argument("--config", default=None, help="YAML config (plain sections or ROS parameter file)")
    g.add_argument("--weights", default=None, help="checkpoint (default: the shipped model if present, else random)")
    g.add_argument("--device", default=None, help="auto | cpu | cuda | cuda:N (default: registration.device)")
    g.add_argument("--threads", type=int, default=0,
                   help="torch CPU threads of the network (registration.threads) and small_gicp's "
                        "(registration.polish_threads); default 0: the config's (1 and every core)")
    g = parser.add_argument_group("data")
    g.add_argument("--scene", default="urban", help="simulated scene (urban, suburban, highway, open_road)")
    g.add_argument("--seed", type=int, default=0, help="simulator seed")
    g.add_argument("--synthetic", action="store_true", help="use a built-in synthetic scan instead of the simulator")
    g = parser.add_argument_group("timing")
    g.add_argument("--repeats", type=int, default=30, help="timed runs per measurement (default 30)")
    g.add_argument("--warmup", type=int, default=3, help="untimed runs first (default 3)")
    g.add_argument("--skip-raw", action="store_true", help="only the preprocessed-pair measurement")
    g.add_argument("--json", default=None, metavar="PATH", help="also write the figures as JSON")
    return parser


def _scans(args):
    """Two consecutive raw scans (N, 3) float32 and T_target_source ground truth (or None), a label."""
    import numpy as np

    if not args.synthetic:
        try:
            from deepbbs_ros.sim import simulate_drive

            src_scan, tgt_scan = None, None
            for scan in simulate_drive(args.scene, args.seed, 2):
                tgt_scan, src_scan = src_scan, scan
            T_gt = np.linalg.inv(tgt_scan.T_world_lidar) @ src_scan.T_world_lidar
            note = f"simulator: scene {args.scene!r}, seed {args.seed}, frames 1 -> 0"
            return src_scan.points, tgt_scan.points, T_gt, note
        except ImportError:
            pass
    return (*_synthetic_pair(args.seed), "built-in synthetic scan (walls, poles, ground)")


def _synthetic_pair(seed: int):
    """A ~120k-point scan of a synthetic street (ground, two facades, poles), 1 m ahead / 1 deg apart."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)

    def scan(n):
        g = n // 2
        ground = np.c_[rng.uniform(-60, 60, (g, 2)), rng.normal(scale=0.03, size=g) - 1.9]
        k = (n - g) // 3
        left = np.c_[rng.uniform(-60, 60, k), 9.0 + rng.normal(scale=0.03, size=k), rng.uniform(-1.9, 8, k)]
        right = np.c_[rng.uniform(-60, 60, k), np.full(k, -11.0), rng.uniform(-1.9, 12, k)]
        m = n - g - 2 * k
        ang = rng.uniform(0, 2 * np.pi, m)
        cx = rng.integers(-6, 6, m) * 10.0
        poles = np.c_[cx + 0.2 * np.cos(ang), 6.0 + 0.2 * np.sin(ang), rng.uniform(-1.9, 4, m)]
        return np.concatenate([ground, left, right, poles])

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 1.0, degrees=True).as_matrix()
    T[:3, 3] = [1.0, 0.05, 0.0]
    tgt = scan(120_000).astype(np.float32)
    src_world = scan(120_000)
    src = ((src_world - T[:3, 3]) @ T[:3, :3]).astype(np.float32)
    return src, tgt, T


def _stats(values):
    import numpy as np

    arr = np.asarray(values, dtype=float)
    return float(np.median(arr)), float(np.percentile(arr, 95))


def _time(reg, src, tgt, preprocessed, args, label):
    from tqdm import tqdm

    for _ in range(args.warmup):
        reg.register(src, tgt, preprocessed=preprocessed)
    runs, wall, res = [], [], None
    for _ in tqdm(range(args.repeats), desc=label, unit="runs", leave=False):
        t0 = time.perf_counter()
        res = reg.register(src, tgt, preprocessed=preprocessed)
        wall.append((time.perf_counter() - t0) * 1e3)
        runs.append(res.timings_ms)
    per_stage = {s: _stats([r.get(s, 0.0) for r in runs]) for s in STAGES}
    per_stage["wall"] = _stats(wall)
    return per_stage, res


@cli_entry("deepbbs-bench")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import torch
    from rich.console import Console
    from rich.table import Table

    from deepbbs_ros.config import load_config
    from deepbbs_ros.core.checkpoint import default_weights_path
    from deepbbs_ros.core.model import DeepBBSNet, count_parameters
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors

    console = Console()
    cfg = load_config(args.config)
    if args.threads > 0:
        cfg = cfg.replace(**{"registration.threads": args.threads, "registration.polish_threads": args.threads})
    weights = args.weights or cfg.registration.weights or str(default_weights_path())
    if args.weights or os.path.isfile(weights):
        reg = DeepBBSRegistration(cfg, weights=weights, device=args.device)
        model_note = f"trained weights {weights}"
    else:
        torch.manual_seed(0)
        reg = DeepBBSRegistration(cfg, model=DeepBBSNet(cfg.model).eval(), device=args.device)
        model_note = f"RANDOM network of the default size (no {weights}): timings only, errors meaningless"
    n_params = count_parameters(reg.model)
    src_raw, tgt_raw, T_gt, data_note = _scans(args)
    src = reg.preprocess(src_raw).points
    tgt = reg.preprocess(tgt_raw).points

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    console.print(f"[bold]deepbbs-bench[/] device={reg.device} network threads={cfg.registration.threads} "
                  f"cpus={os.cpu_count()} load average (1 min)={load:.2f}")
    console.print(f"model: {model_note}; {n_params / 1e6:.3f} M parameters ({n_params * 4 / 2**20:.2f} MB float32)")
    console.print(f"data: {data_note}; raw {len(src_raw)} / {len(tgt_raw)} points -> {len(src)} / {len(tgt)}")

    figures = {}
    pair, res_pair = _time(reg, src, tgt, True, args, "pair")
    figures["pair_1000"] = pair
    if not args.skip_raw:
        raw, res_raw = _time(reg, src_raw, tgt_raw, False, args, "raw")
        figures["raw_120k"] = raw
    load_after = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")

    table = Table(title=f"DeepBBS++ timings, median / p95 over {args.repeats} runs")
    table.add_column("stage")
    cols = [("pair_1000", f"{len(src)}-pt pair")] + ([] if args.skip_raw else [("raw_120k", "2 raw scans")])
    for _, title in cols:
        table.add_column(f"{title} median", justify="right")
        table.add_column(f"{title} p95", justify="right")
    table.add_column("units")
    for stage in (*STAGES, "wall"):
        row = [stage]
        for key, _ in cols:
            med, p95 = figures[key][stage]
            row += [f"{med:.1f}", f"{p95:.1f}"]
        table.add_row(*row, "ms")
    console.print(table)

    goals = [("pair_1000", 60.0, f"registration of one {len(src)}-point pair"),
             ("raw_120k", 100.0, "preprocess + register")]
    for key, goal, what in goals:
        if key in figures:
            med = figures[key]["total"][0]
            verdict = "[green]meets[/]" if med <= goal else "[red]misses[/]"
            console.print(f"{what}: median {med:.1f} ms {verdict} the {goal:.0f} ms goal")
    its = res_pair.iterations
    console.print(f"sampled pair (no precision stage): deep {its['deep']}, refine {its['refine']}; "
                  f"converged={res_pair.converged}; "
                  f"inlier ratio {res_pair.inlier_ratio:.2f}")
    if T_gt is not None:
        rot, trans = pair_errors(res_pair.T_target_source, T_gt)
        console.print(f"error vs ground truth (sampled pair): {rot:.3f} deg, {trans:.3f} m")
        figures["error"] = {"rot_deg": float(rot), "trans_m": float(trans)}
        if not args.skip_raw:
            rot, trans = pair_errors(res_raw.T_target_source, T_gt)
            console.print(f"error vs ground truth (raw scans, full pipeline): {rot:.3f} deg, {trans:.3f} m")
            figures["error_raw"] = {"rot_deg": float(rot), "trans_m": float(trans)}
    console.print(f"load average (1 min) after: {load_after:.2f} on {os.cpu_count()} CPUs "
                  "(other processes share these CPUs: figures are disturbed when it exceeds the CPU count)")
    if args.json:
        meta = {"device": str(reg.device), "threads": cfg.registration.threads, "model": model_note,
                "params": n_params, "data": data_note, "load_before": load, "load_after": load_after,
                "iterations": its, "repeats": args.repeats}
        with open(args.json, "w") as fh:
            json.dump({"meta": meta, "figures": figures}, fh, indent=2, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
