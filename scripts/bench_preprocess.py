#!/usr/bin/env python3
"""Benchmark scan preprocessing on a synthetic HDL-64-like sweep.

Builds a 64-beam x 1875-azimuth sweep (120,000 rays; those without a return are NaN) of a
sloped street with buildings and poles -- the ray caster of ``tests/test_preprocess.py`` -- or, with
``--sim``, a frame of ``deepbbs_ros.sim.simulate_drive``, and reports median and p95 wall time per
preprocessing stage over ``--repeat`` runs.

    python scripts/bench_preprocess.py --repeat 50
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _load_make_scan():
    spec = importlib.util.spec_from_file_location("_test_preprocess", ROOT / "tests" / "test_preprocess.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.make_scan


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="bench_preprocess.py", description=__doc__.split("\n\n")[0])
    g = parser.add_argument_group("input")
    g.add_argument("--sim", metavar="SCENE", default=None, help="use deepbbs_ros.sim.simulate_drive(SCENE) instead")
    g.add_argument("--seed", type=int, default=0)
    g = parser.add_argument_group("preprocessing (overrides of PreprocessConfig)")
    g.add_argument("--num-points", type=int, default=1000)
    g.add_argument("--voxel-size", type=float, default=None, help="m")
    g.add_argument("--ground-method", choices=("ransac", "seeded_lsq"), default=None)
    g.add_argument("--fps-max-candidates", type=int, default=None, help="0 = FPS on all voxels")
    g = parser.add_argument_group("timing")
    g.add_argument("--repeat", type=int, default=50)
    g.add_argument("--warmup", type=int, default=3)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from rich.console import Console
    from rich.table import Table
    from tqdm import tqdm

    from deepbbs_ros.config import PreprocessConfig
    from deepbbs_ros.core.preprocess import preprocess

    if args.sim:
        from deepbbs_ros.sim import simulate_drive

        points = next(iter(simulate_drive(args.sim, args.seed, 1))).points
    else:
        points = _load_make_scan()(seed=args.seed)[0]
    overrides = {"num_points": args.num_points}
    for key in ("voxel_size", "ground_method", "fps_max_candidates"):
        if getattr(args, key) is not None:
            overrides[key] = getattr(args, key)
    cfg = PreprocessConfig(**overrides)
    cfg.validate()

    for i in range(args.warmup):
        preprocess(points, cfg, seed=i)
    stages: dict[str, list[float]] = {}
    res = None
    for i in tqdm(range(args.repeat), unit="scans", desc="preprocess"):
        c0 = time.process_time()
        res = preprocess(points, cfg, seed=i)
        # CPU time of this process: close to the wall time of an idle machine when the pipeline is
        # single-threaded, and not inflated when other jobs share the cores.
        stages.setdefault("total (process CPU)", []).append((time.process_time() - c0) * 1e3)
        for k, v in res.timings_ms.items():
            stages.setdefault(k, []).append(v)
    stages["total (process CPU)"] = stages.pop("total (process CPU)")

    console = Console()
    console.print(
        f"input {res.n_input} points ({res.n_input - np.isfinite(points).all(axis=1).sum()} NaN), "
        f"valid+cropped {res.n_valid}, non-ground {res.n_nonground}, voxels {res.n_voxels}, "
        f"sampled {len(res.points)}; plane {np.round(res.ground_plane, 4) if res.ground_plane is not None else None}"
    )
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    table = Table(title=f"preprocess, {args.repeat} runs ({os.cpu_count()} cores, load average {load:.1f})")
    for col in ("stage", "median", "p95", "max", "unit"):
        table.add_column(col, justify="right" if col != "stage" else "left")
    for k, v in stages.items():
        a = np.asarray(v)
        table.add_row(k, f"{np.median(a):.2f}", f"{np.percentile(a, 95):.2f}", f"{a.max():.2f}", "ms")
    console.print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
