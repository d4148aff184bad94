#!/usr/bin/env python3
"""How MapLocalizer's build time, memory and search time grow with the map, for a map given without its trajectory.

The map of ``--km`` km: the localization benchmark's cached 1 km simulated maps of the four scene types (built by
``localization.py``, same ``--cache``), tiled side by side, 1.4 km apart, each copy turned (a copy of a scene four
maps on stands elsewhere, at another yaw, and mirrored: no rigid motion puts a scan of the first copy on it, as on
another town's streets). Measured in one process per size (the peak resident memory is the
process's): the map's build (``MapLocalizer``: voxel grid, height grid, places, descriptors, GICP cloud) in seconds,
the bytes it holds (``MapLocalizer.nbytes``) and the growth of the peak resident memory while it is built, the
places, the time to describe and rank a query against every place (p50 of ``--queries`` scans of the first copy),
and with ``--localize`` the whole global search of those scans (p50, and how many were placed within 1 deg / 0.3 m).
One JSON line on stdout per run.

    python scripts/benchmarks/localization_scale.py --km 10 --cache ~/.cache/deepbbs_ros/bench --localize
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import localization as bench  # noqa: E402  (puts the checkout first on sys.path)
from _localization_data import transform, yaw_move  # noqa: E402

SCENES = ("urban", "suburban", "highway", "open_road")
SLOT = 1400.0  # m between the copies' corners (a 1 km map spans at most about 1.1 km at any yaw)


def tiled_map(km: int, args) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """(points (N, 3) float32 of ``km`` tiled 1 km maps, [(query points, T_map_scan)] of the first copy)."""
    from deepbbs_ros.sim import SCENES as ALL
    from deepbbs_ros.train.cache import TEST_SEED_BASE

    gen = argparse.Namespace(map_length=1000.0, map_step=2.5, map_range=50.0, map_voxel=0.2,
                             prefixes=[250.0, 500.0], queries=30, repetitive=6, boot_scans=args.boot_scans,
                             boot_step=1.0, cache=args.cache)
    cols = int(np.ceil(np.sqrt(km)))
    parts, queries = [], []
    for i in range(km):
        scene = SCENES[i % len(SCENES)]
        d = bench.sim_map(scene, TEST_SEED_BASE + 500 + ALL.index(scene), gen)
        pts = d.points * np.array([1.0, -1.0, 1.0], np.float32) if i >= len(SCENES) else d.points  # mirrored
        R = yaw_move(0.7 * i, 0.0, 0.0)
        lo = transform(pts, R)[:, :2].min(axis=0).astype(np.float64)
        slot = np.array([(i % cols) * SLOT, (i // cols) * SLOT])
        M = yaw_move(0.0, *(slot - lo)) @ R
        parts.append(transform(pts, M))
        if i == 0:
            queries = [(q.points, M @ q.T_map_scan) for q in d.queries[:args.queries]]
    return np.concatenate(parts), queries


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--km", type=int, default=1, help="km of simulated road (tiled 1 km maps)")
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="the localization benchmark's cache")
    p.add_argument("--boot-scans", type=int, default=0, help="as the benchmark's run that made the cache")
    p.add_argument("--queries", type=int, default=8, help="query scans of the first copy")
    p.add_argument("--localize", action="store_true", help="also the whole global search of the queries")
    args = p.parse_args(argv)
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.localization import MapLocalizer
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.metrics import pair_errors

    points, queries = tiled_map(args.km, args)
    cfg = Config()
    reg = DeepBBSRegistration(cfg)
    reg.warmup()
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MB (Linux: KB)
    t0 = time.perf_counter()
    loc = MapLocalizer(points, cfg, registration=reg)
    build = time.perf_counter() - t0
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    c = loc.description_centres
    rank = []
    for pts, _ in queries:
        t0 = time.perf_counter()
        loc.rank(loc.describe(pts, c), None, c)
        rank.append(time.perf_counter() - t0)
    search, placed = [], 0
    if args.localize:
        for pts, T in queries:
            t0 = time.perf_counter()
            r = loc.localize(pts)
            search.append(time.perf_counter() - t0)
            rot, trans = pair_errors(r.T_map_scan[None], T[None])
            placed += bool(r.valid and rot[0] <= bench.ROT_OK_DEG and trans[0] <= bench.TRANS_OK_M)
    print(json.dumps({"km": args.km, "map_points": len(loc.points), "places": len(loc.places), "build_s": build,
                      "held_mb": loc.nbytes / 1e6, "peak_rss_growth_mb": rss1 - rss0, "peak_rss_mb": rss1,
                      "rank_s_p50": float(np.median(rank)),
                      "search_s_p50": float(np.median(search)) if search else None,
                      "placed": placed if search else None, "queries": len(queries)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
